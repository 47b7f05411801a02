"""The scripted experts' vectorized state machine, driven by synthetic sequences (no physics)."""

from __future__ import annotations

import numpy as np
import pytest

from wirecraft.experts import Phase, VectorFSM


def _fsm(num_envs: int = 3) -> VectorFSM:
    return VectorFSM(
        [Phase("a", pos_tol=0.01, rot_tol=0.1, dwell=3), Phase("b", dwell=1), Phase("end")],
        num_envs,
    )


def test_phase_does_not_advance_before_its_dwell():
    fsm = _fsm(1)
    inside = fsm.within([0.005], [0.05])
    assert inside.tolist() == [True]
    for _ in range(2):
        assert not fsm.advance_if(inside).any()
        assert fsm.names == ["a"]
    assert fsm.advance_if(inside).tolist() == [True]
    assert fsm.names == ["b"] and fsm.steps[0] == 0 and fsm.dwell[0] == 0


def test_tolerances_are_those_of_each_environments_phase():
    fsm = _fsm(2)
    for _ in range(3):
        fsm.advance_if([True, False])
    assert fsm.names == ["b", "a"]
    # 6 mm / 0.06 rad: outside phase b's 5 mm, inside phase a's 10 mm / 0.1 rad.
    assert fsm.within([0.006, 0.006], [0.06, 0.06]).tolist() == [False, True]
    assert fsm.within([0.004, 0.004], [0.06, 0.2]).tolist() == [False, False]


def test_leaving_tolerance_restarts_the_dwell():
    fsm = _fsm(1)
    assert fsm.within([0.02], [0.0]).tolist() == [False]  # position out of tolerance
    assert fsm.within([0.0], [0.2]).tolist() == [False]  # orientation out of tolerance
    fsm.advance_if([True])
    fsm.advance_if([True])
    fsm.advance_if([False])  # dwell back to 0
    fsm.advance_if([True])
    fsm.advance_if([True])
    assert fsm.names == ["a"]
    fsm.advance_if([True])
    assert fsm.names == ["b"]


def test_environments_advance_independently():
    fsm = _fsm(3)
    reached = np.array([True, False, True])
    for _ in range(3):
        fsm.advance_if(reached)
    assert fsm.names == ["b", "a", "b"]
    assert fsm.steps.tolist() == [0, 3, 0]
    fsm.advance_if(np.array([True, True, False]))
    assert fsm.names == ["end", "a", "b"]
    for _ in range(5):  # the last phase is terminal
        fsm.advance_if(np.ones(3, bool))
    assert fsm.names == ["end", "end", "end"] and fsm.done.all()
    fsm.reset([1])
    assert fsm.names == ["end", "a", "end"]


def test_timeout_advances_and_is_flagged():
    fsm = VectorFSM([Phase("wait", dwell=100, timeout=4), Phase("next")], 2)
    for _ in range(3):
        assert not fsm.advance_if([False, True]).any()  # a dwell of 100 is far off
    assert fsm.advance_if([False, True]).all()
    assert fsm.timed_out.all()  # neither reached its dwell: both timed out
    assert fsm.names == ["next", "next"]


def test_reached_on_the_timeout_step_is_not_a_timeout():
    fsm = VectorFSM([Phase("wait", dwell=2, timeout=2), Phase("next")], 1)
    fsm.advance_if([True])
    assert fsm.advance_if([True]).all() and not fsm.timed_out[0]


def test_snapshots_goto_and_reset():
    fsm = VectorFSM([Phase("wait"), Phase("next")], 2)
    fsm.snapshot("pose", np.array([[1.0, 2.0], [3.0, 4.0]]), [True, False])
    assert fsm.get("pose")[0].tolist() == [1.0, 2.0] and np.isnan(fsm.get("pose")[1]).all()
    fsm.goto("next", [1])
    assert fsm.names == ["wait", "next"]
    fsm.reset()
    assert np.isnan(fsm.get("pose")).all() and fsm.names == ["wait", "wait"]


def test_next_skips_a_branch_phase_that_is_only_entered_by_goto():
    fsm = VectorFSM(
        [Phase("lift", next="insert"), Phase("drop", next="lift"), Phase("insert"), Phase("end")],
        2,
    )
    fsm.advance_if([True, False])
    assert fsm.names == ["insert", "lift"]  # lift -> insert, drop skipped
    fsm.goto("drop", [False, True])
    fsm.advance_if([False, True])
    assert fsm.names == ["insert", "lift"]  # drop -> lift
    fsm.advance_if([True, True])
    assert fsm.names == ["end", "insert"]


# -- retries: a synthetic insertion that jams ------------------------------------------------
PHASES = (
    Phase("pre_insert", dwell=2),
    Phase("insert", dwell=3, timeout=5, next="release"),
    Phase("release"),
    Phase("done"),
)


def _run(fsm: VectorFSM, seats, limit: int = 2, max_steps: int = 200) -> list[list[str]]:
    """Drive the machine: every goal is reached at once except in ``insert``, where
    ``seats(env, attempt)`` (attempt 0, 1, ...) says whether that insertion seats.  A failed
    (timed-out) insertion is retried through ``pre_insert`` at most ``limit`` times."""
    attempts = np.zeros(fsm.num_envs, int)
    trace = []
    insert = fsm.index("insert")
    for _ in range(max_steps):
        seated = [seats(env, attempt) for env, attempt in enumerate(attempts)]
        reached = np.where(fsm.phase == insert, seated, True)
        before = fsm.phase.copy()
        advanced = fsm.advance_if(reached)
        left_insert = advanced & (before == insert)
        attempts[left_insert] += 1
        fsm.retry("insert", "pre_insert", left_insert & fsm.timed_out, limit)
        trace.append(fsm.names)
        if fsm.done.all():
            break
    return trace


def _entered(trace: list[list[str]], env: int) -> list[str]:
    names = [step[env] for step in trace]
    return [b for a, b in zip(["pre_insert", *names], names, strict=False) if a != b]


def test_a_failed_insertion_is_retried_at_most_twice():
    fsm = VectorFSM(PHASES, 1)
    trace = _run(fsm, seats=lambda env, attempt: False)
    # Three insertions in all (the first, then two retries), then it gives up and releases.
    assert _entered(trace, 0) == [
        "insert",
        "pre_insert",
        "insert",
        "pre_insert",
        "insert",
        "release",
        "done",
    ]
    assert fsm.retry_count("insert").tolist() == [2]
    fsm.reset()
    assert fsm.retry_count("insert").tolist() == [0]


def test_a_retry_that_seats_goes_on_to_release():
    fsm = VectorFSM(PHASES, 3)
    needed = [0, 1, 2]  # env k seats on its attempt k
    trace = _run(fsm, seats=lambda env, attempt: attempt >= needed[env])
    assert fsm.retry_count("insert").tolist() == [0, 1, 2]
    assert _entered(trace, 0) == ["insert", "release", "done"]
    assert _entered(trace, 1) == ["insert", "pre_insert", "insert", "release", "done"]
    # A seating attempt spends its dwell (3 steps) in insert, a failed one its timeout (5).
    assert sum(step[0] == "insert" for step in trace) == 3
    assert sum(step[1] == "insert" for step in trace) == 5 + 3
    assert fsm.done.all()


def test_retry_counts_each_environment_and_respects_a_zero_limit():
    fsm = VectorFSM(PHASES, 3)
    fsm.goto("insert", None)
    sent = fsm.retry("insert", "pre_insert", [True, False, True], limit=2)
    assert sent.tolist() == [True, False, True]
    assert fsm.names == ["pre_insert", "insert", "pre_insert"]
    assert fsm.retry_count("insert").tolist() == [1, 0, 1]
    fsm.goto("insert", None)
    assert not fsm.retry("other", "pre_insert", [True, True, True], limit=0).any()
    assert fsm.names == ["insert", "insert", "insert"]
    with pytest.raises(ValueError, match="limit"):
        fsm.retry("insert", "pre_insert", None, limit=-1)


def test_validation():
    with pytest.raises(ValueError, match="dwell"):
        Phase("x", dwell=0)
    with pytest.raises(ValueError, match="timeout"):
        Phase("x", timeout=0)
    with pytest.raises(ValueError, match="unique"):
        VectorFSM([Phase("x"), Phase("x")], 1)
    with pytest.raises(ValueError, match="unknown phase"):
        _fsm().index("nope")
    with pytest.raises(ValueError, match="unknown phase"):
        VectorFSM([Phase("x", next="nowhere"), Phase("y")], 1)
    with pytest.raises(ValueError, match="shape"):
        _fsm(2).advance_if([True])
