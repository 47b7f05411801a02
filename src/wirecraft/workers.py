"""Where jobs run: in this process, in a pool of worker processes, or on a Ray cluster.

``collect`` (one job per episode attempt) and ``eval`` (one job per chunk of episodes) submit
module-level functions with picklable arguments and take the results in submission order:

    with open_workers(workers, ray_address) as pool:
        for result in pool.map(func, argument_tuples): ...

``submit`` / ``result(handle, timeout)`` give finer control (``collect`` keeps a window of
attempts in flight and gives up on one that never returns).  Worker processes are spawned
(fresh interpreters: no inherited OpenGL or thread state) and ignore SIGINT, so that Ctrl-C in
a terminal reaches only the main process, which decides.
"""

from __future__ import annotations

import signal
import sys
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from typing import Any


class StopOnSignal:
    """SIGINT / SIGTERM set ``stop`` (the signal's name; the main loop ends cleanly) and print
    ``on_stop``; a second one interrupts at once.  Installed only in the main thread."""

    def __init__(self, on_stop: str) -> None:
        self.on_stop = on_stop
        self.stop: str | None = None
        self._previous: dict = {}

    def _handle(self, signum, frame) -> None:
        if self.stop is not None:
            raise KeyboardInterrupt
        self.stop = signal.Signals(signum).name
        print(
            f"\n{self.stop}: {self.on_stop} (send it again to stop at once)",
            file=sys.stderr,
            flush=True,
        )

    def __enter__(self) -> StopOnSignal:
        import threading

        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class InProcess:
    """Runs each job when its result is asked for."""

    window = 1

    def submit(self, func: Callable, *args) -> tuple:
        return func, args

    def result(self, handle, timeout: float | None = None):
        func, args = handle
        return func(*args)

    def close(self) -> None:
        pass


class ProcessPool:
    """``workers`` spawned worker processes."""

    def __init__(self, workers: int) -> None:
        import multiprocessing

        self.window = 2 * workers
        context = multiprocessing.get_context("spawn")
        self.pool = context.Pool(workers, initializer=_ignore_sigint)

    def submit(self, func: Callable, *args):
        return self.pool.apply_async(func, args)

    def result(self, handle, timeout: float | None = None):
        """The job's result, or None if it is not done within ``timeout`` seconds."""
        import multiprocessing

        try:
            return handle.get(timeout)
        except multiprocessing.TimeoutError:
            return None

    def close(self) -> None:
        self.pool.terminate()  # jobs still queued are not needed
        self.pool.join()


class RayWorkers:
    """Jobs as Ray tasks of one CPU each: on a cluster at ``address`` (HOST:PORT or auto), or
    on one started here (``local``, with ``local_cpus`` CPUs)."""

    def __init__(self, address: str, local_cpus: int) -> None:
        try:
            import ray
        except ImportError as err:
            raise RuntimeError(f"--ray needs the ray package (the cluster extra): {err}") from None
        self.ray = ray
        self.owns = not ray.is_initialized()
        if self.owns:
            quiet = {"log_to_driver": False, "logging_level": "warning"}
            if address == "local":
                ray.init(num_cpus=max(1, local_cpus), include_dashboard=False, **quiet)
            else:
                ray.init(address=address, **quiet)
        self.window = 2 * max(1, int(ray.cluster_resources().get("CPU", 1)))
        self.remotes: dict[Callable, Any] = {}
        self.pending: set = set()

    def submit(self, func: Callable, *args):
        if func not in self.remotes:
            self.remotes[func] = self.ray.remote(num_cpus=1)(func)
        ref = self.remotes[func].remote(*args)
        self.pending.add(ref)
        return ref

    def result(self, handle, timeout: float | None = None):
        """The job's result, or None if it is not done within ``timeout`` seconds."""
        ready, _ = self.ray.wait([handle], timeout=timeout)
        if not ready:
            return None
        self.pending.discard(handle)
        return self.ray.get(handle)

    def close(self) -> None:
        for ref in self.pending:
            self.ray.cancel(ref, force=True)
        self.pending.clear()
        if self.owns:
            self.ray.shutdown()


class Workers:
    """One of the three, with ``map`` and a context manager that closes it."""

    def __init__(self, backend) -> None:
        self.backend = backend
        self.window = backend.window

    def submit(self, func: Callable, *args):
        return self.backend.submit(func, *args)

    def result(self, handle, timeout: float | None = None):
        return self.backend.result(handle, timeout)

    def map(self, func: Callable, arguments: Iterable[tuple]) -> Iterator:
        """``func(*args)`` for every tuple of arguments, in order, at most ``window`` in
        flight."""
        arguments = iter(arguments)
        pending: deque = deque()
        while True:
            while len(pending) < self.window:
                args = next(arguments, _END)
                if args is _END:
                    break
                pending.append(self.submit(func, *args))
            if not pending:
                return
            yield self.result(pending.popleft())

    def close(self) -> None:
        self.backend.close()

    def __enter__(self) -> Workers:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


_END = object()


def open_workers(workers: int, ray_address: str | None = None) -> Workers:
    """Ray at ``ray_address`` if given (``local``: ``workers`` CPUs), else ``workers`` processes
    (0: this process)."""
    if ray_address is not None:
        return Workers(RayWorkers(ray_address, workers))
    if workers == 0:
        return Workers(InProcess())
    return Workers(ProcessPool(workers))
