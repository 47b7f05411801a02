"""Torch's CPU threads in processes that step environments (never imports torch itself).

Torch starts as many intra-op threads as the machine has cores.  A process that steps
environments and queries a small network once per step gains nothing from them, and next to
other busy processes (evaluation or collection workers, MuJoCo's batch threads) the threads
contend for the cores: a one-episode Diffusion Policy evaluation took 89 s with torch's default
threads next to another process, 10 s with one thread.  Evaluation (``torch_threads``, default
1 per process) and collection run torch on one thread per process.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager

DEFAULT_TORCH_THREADS = 1


def set_torch_threads(threads: int | None) -> int | None:
    """Set torch's intra-op threads to ``threads`` if torch is loaded in this process (None or 0:
    leave them); returns the count before, or None when nothing was set."""
    torch = sys.modules.get("torch")
    if not threads or torch is None or not hasattr(torch, "set_num_threads"):
        return None
    before = torch.get_num_threads()
    if before != threads:
        torch.set_num_threads(int(threads))
    return before


@contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """``set_torch_threads(threads)`` for the block, the previous count restored after it."""
    before = set_torch_threads(threads)
    try:
        yield
    finally:
        if before is not None:
            sys.modules["torch"].set_num_threads(before)


def check_torch_threads(threads) -> int | None:
    """``threads`` if it is None or an integer >= 0 (0: torch's default), else ValueError."""
    if threads is None:
        return None
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 0:
        raise ValueError(
            f"torch_threads must be an integer >= 0 (0: torch's default), got {threads!r}"
        )
    return threads
