"""MP4 files from RGB frames (H.264 through PyAV, which bundles FFmpeg): the demo's and the
evaluation's videos."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def _codec() -> str:
    import av

    for name in ("libx264", "h264", "libopenh264", "mpeg4"):
        try:
            av.codec.Codec(name, "w")
            return name
        except Exception:  # noqa: BLE001 - PyAV raises several kinds for a missing encoder
            continue
    raise RuntimeError("PyAV has no H.264 or MPEG-4 encoder")


class VideoWriter:
    """Frames (H, W, 3 uint8) to an MP4 file. The frames go to ``PATH.partial`` first, which
    ``close`` renames to ``PATH`` and ``discard`` removes: a crash never leaves half a video
    under the real name."""

    def __init__(self, path: str | Path, width: int, height: int, fps: int) -> None:
        import av

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.partial = self.path.with_name(self.path.name + ".partial")
        self.container = av.open(str(self.partial), mode="w", format="mp4")
        codec = _codec()
        self.stream = self.container.add_stream(codec, rate=fps)
        self.stream.width, self.stream.height = width, height
        self.stream.pix_fmt = "yuv420p"
        if codec == "libx264":
            self.stream.options = {"crf": "26", "preset": "veryfast"}

    def add(self, frame: np.ndarray) -> None:
        import av

        video_frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")
        for packet in self.stream.encode(video_frame):
            self.container.mux(packet)

    def close(self) -> None:
        for packet in self.stream.encode():
            self.container.mux(packet)
        self.container.close()
        os.replace(self.partial, self.path)

    def discard(self) -> None:
        self.container.close()
        self.partial.unlink(missing_ok=True)


def write_mp4(frames, path: str | Path, fps: int) -> Path:
    """Write RGB frames (T, H, W, 3) uint8 as an MP4 (H and W even)."""
    frames = np.asarray(frames)
    writer = VideoWriter(path, frames.shape[2], frames.shape[1], fps)
    try:
        for frame in frames:
            writer.add(frame)
    except BaseException:
        writer.discard()
        raise
    writer.close()
    return writer.path
