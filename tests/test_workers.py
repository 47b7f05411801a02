"""The one runner of collect and eval: results in submission order, whatever the backend, at
most a window of jobs in flight, and a timeout that says "not yet" instead of blocking."""

import operator
import subprocess

import pytest

from wirecraft.workers import InProcess, ProcessPool, Workers, open_workers


@pytest.mark.parametrize("workers", [0, 2])
def test_map_returns_results_in_submission_order(workers):
    arguments = [(k, 10 * k) for k in range(7)]
    with open_workers(workers) as pool:
        assert list(pool.map(operator.add, arguments)) == [11 * k for k in range(7)]
    assert isinstance(pool.backend, InProcess if workers == 0 else ProcessPool)


def test_map_keeps_at_most_a_window_in_flight():
    submitted = []

    class Recording(InProcess):
        window = 3

        def submit(self, func, *args):
            submitted.append(args)
            return super().submit(func, *args)

    pool = Workers(Recording())
    results = pool.map(operator.mul, [(k, k) for k in range(10)])
    assert next(results) == 0
    assert len(submitted) == 3  # the first three submitted, one taken
    assert list(results) == [k * k for k in range(1, 10)]


def test_a_pool_result_not_ready_within_the_timeout_is_none():
    with open_workers(1) as pool:
        handle = pool.submit(subprocess.getoutput, "sleep 1; echo done")
        assert pool.result(handle, timeout=0.05) is None
        assert pool.result(handle, timeout=30.0) == "done"
