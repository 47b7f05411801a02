"""Living with lerobot where the system's FFmpeg libraries are missing.

lerobot decodes videos with torchcodec when it can, and torchcodec needs the system's FFmpeg
shared libraries (libavcodec and friends, FFmpeg 4 to 8).  Where they are missing, each time
lerobot picks a default video backend (a ``LeRobotDataset`` or ``DatasetConfig`` made without
``video_backend``, a video decoded without a backend) it tries to load torchcodec, logs the
failure with the full loading traceback of every FFmpeg version (~100 lines, through the logger
``lerobot.utils.import_utils``), and falls back to PyAV.  WireCraft passes
``video_backend="pyav"`` itself wherever it opens a dataset; ``quiet_torchcodec`` drops that one
warning for everything else (the fallback to PyAV happens all the same).  The modules that load
lerobot (``wirecraft.datasets.writer``, ``wirecraft.datasets.encoding``,
``wirecraft.evaluation.policies``) install it when imported; it imports nothing heavy.
"""

from __future__ import annotations

import logging

LEROBOT_IMPORT_LOGGER = "lerobot.utils.import_utils"


class _TorchcodecFallback(logging.Filter):
    """Drops lerobot's "torchcodec cannot be loaded / is not available, falling back to pyav"
    warning; every other record passes."""

    def filter(self, record: logging.LogRecord) -> bool:
        try:
            message = record.getMessage()
        except Exception:  # a malformed record is not ours to judge
            return True
        return not ("torchcodec" in message and "pyav" in message)


def quiet_torchcodec() -> None:
    """Install the filter on lerobot's import-utilities logger (once; idempotent)."""
    logger = logging.getLogger(LEROBOT_IMPORT_LOGGER)
    if not any(isinstance(f, _TorchcodecFallback) for f in logger.filters):
        logger.addFilter(_TorchcodecFallback())
