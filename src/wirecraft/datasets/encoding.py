"""Video encoding for ``EpisodeWriter``: lerobot's streaming encoder, with cheap image statistics.

Why: lerobot 0.6.1's ``StreamingVideoEncoder`` feeds every frame of every camera through
``RunningQuantileStats`` (float32 copies, per-channel reductions over a (H*W, 3) array and a
5000-bin ``np.histogram`` per channel): ~6.5 ms per 224 x 224 frame, ~2.3 s of CPU for a
180-frame two-camera episode, more than the physics (0.9 s) or the rendering (1.3 s).  Its
other paths are not cheaper: without streaming, every frame is written as PNG, read back to
encode, and 100 sampled frames go through the same statistics in one batch (~0.9 s per camera).

How: ``WireCraftLeRobotDataset`` overrides ``LeRobotDataset._build_streaming_encoder``, the
factory ``create``, ``resume`` and ``__init__`` call, to return an ``EpisodeVideoEncoder``:
the same ``StreamingVideoEncoder`` interface (``start_episode`` / ``feed_frame`` /
``finish_episode`` / ``cancel_episode`` / ``close``) and the same PyAV encoding (lerobot's
``RGBEncoderConfig`` codec options, pixel format, 1/fps time base), but

- frames are encoded as they arrive, in the calling thread: ``EpisodeWriter`` holds the whole
  episode already, so lerobot's queue and thread per camera buy nothing, and no frame can be
  dropped (lerobot drops frames when its queue is full);
- the statistics are exact counts of the 256 levels of each channel over every pixel of every
  frame (one ``np.bincount`` per frame, ~0.3 ms), from which ``finish_episode`` returns what
  lerobot's tracker returns (``min``, ``max``, ``mean``, ``std``, ``count`` = pixels, and the
  ``q01`` ... ``q99`` quantiles, on the 0..255 scale; lerobot divides by 255).  min, max, mean,
  std and count are exact; a quantile is the lowest level whose cumulative count reaches the
  fraction, where lerobot interpolates inside one of 5000 bins spanning [min, max]: they differ
  by less than one bin, (max - min) / 5000 (< 2e-4 after the division by 255).

Everything else (moving or concatenating the episode's video into the dataset's files, the
per-episode and aggregated statistics, ``info.json``) stays lerobot's own code.  Only RGB
cameras are supported (WireCraft records no depth video).

One patch (``install_embed_shortcut``, applied by ``WireCraftLeRobotDataset.create`` /
``resume``): lerobot's ``save_episode`` passes every episode's table through
``io_utils.embed_images``, a per-row ``datasets.Dataset.map(embed_table_storage)`` that embeds
image files into the parquet rows.  Its output equals its input when no feature needs embedding
(``datasets.features.features.require_storage_embed``), as in WireCraft's datasets, whose
images are videos; it still costs ~4 ms per frame (0.7 s per 180-frame episode).  The
replacement returns the dataset unchanged in that case and calls lerobot's function otherwise.

This module imports lerobot and PyAV: import it only when writing.
"""

from __future__ import annotations

import shutil
import tempfile
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
from lerobot.datasets.compute_stats import DEFAULT_QUANTILES
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.datasets.video_utils import StreamingVideoEncoder

from wirecraft.lerobot_compat import quiet_torchcodec
from wirecraft.numerics import matvec

quiet_torchcodec()  # lerobot's torchcodec traceback where FFmpeg is missing
LEVELS = 256  # uint8 intensity levels


class ChannelLevelCounts:
    """Per-channel counts of the 256 levels of uint8 images, and the statistics they give."""

    def __init__(self, channels: int = 3) -> None:
        self.channels = channels
        self.counts = np.zeros((channels, LEVELS), dtype=np.int64)

    def update(self, image: np.ndarray) -> None:
        """Count the levels of ``image`` (..., channels) uint8."""
        if image.dtype != np.uint8 or image.shape[-1] != self.channels:
            raise ValueError(
                f"expected uint8 images with {self.channels} channels last, "
                f"got {image.dtype} {image.shape}"
            )
        pixels = image.reshape(-1, self.channels)
        # One bincount per channel on a strided uint8 view: ~0.3 ms for 224 x 224, less than
        # offsetting the channels into one wider integer array and counting once.
        for channel in range(self.channels):
            self.counts[channel] += np.bincount(pixels[:, channel], minlength=LEVELS)

    @property
    def pixels(self) -> int:
        """Pixels counted (per channel)."""
        return int(self.counts[0].sum())

    def statistics(self, quantiles=DEFAULT_QUANTILES) -> dict[str, np.ndarray]:
        """lerobot's statistics keys, per channel, on the 0..255 scale (module docstring)."""
        total = self.pixels
        if total == 0:
            raise ValueError("no pixels counted")
        levels = np.arange(LEVELS, dtype=np.float64)
        present = self.counts > 0
        mean = matvec(self.counts, levels) / total
        mean_of_squares = matvec(self.counts, levels**2) / total
        cumulative = np.cumsum(self.counts, axis=1)
        stats = {
            "min": np.argmax(present, axis=1).astype(np.float64),
            "max": (LEVELS - 1 - np.argmax(present[:, ::-1], axis=1)).astype(np.float64),
            "mean": mean,
            "std": np.sqrt(np.maximum(mean_of_squares - mean**2, 0.0)),
            "count": np.array([total]),
        }
        for q in quantiles:
            # The lowest level whose cumulative count reaches q * total, per channel.
            reached = cumulative >= q * total
            stats[f"q{int(q * 100):02d}"] = np.argmax(reached, axis=1).astype(np.float64)
        return stats


class _CameraVideo:
    """One camera's video of the current episode: an MP4 encoded frame by frame, and counts."""

    def __init__(self, path: Path, fps: int, encoder, encoder_threads: int | None) -> None:
        self.path = path
        self.fps = fps
        self.encoder = encoder
        self.encoder_threads = encoder_threads
        self.container = None
        self.stream = None
        self.frames = 0
        self.counts = ChannelLevelCounts(3)

    def add(self, image: np.ndarray) -> None:
        image = np.asarray(image)
        if image.ndim == 3 and image.shape[-1] != 3 and image.shape[0] == 3:
            image = image.transpose(1, 2, 0)  # CHW -> HWC, as lerobot accepts both
        if image.dtype != np.uint8:  # floats in [0, 1], as lerobot's encoder converts them
            image = (image * 255).astype(np.uint8)
        if image.ndim != 3 or image.shape[-1] != 3:
            raise ValueError(f"expected an RGB image (H, W, 3), got shape {image.shape}")
        if self.container is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.container = av.open(str(self.path), "w")
            options = self.encoder.get_codec_options(self.encoder_threads, as_strings=True)
            self.stream = self.container.add_stream(self.encoder.vcodec, self.fps, options=options)
            self.stream.pix_fmt = self.encoder.pix_fmt
            self.stream.height, self.stream.width = image.shape[:2]
            self.stream.time_base = Fraction(1, self.fps)
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="rgb24")
        frame.pts = self.frames
        frame.time_base = Fraction(1, self.fps)
        for packet in self.stream.encode(frame):
            self.container.mux(packet)
        self.counts.update(image)
        self.frames += 1

    def finish(self) -> dict | None:
        """Flush and close the file; the statistics (None below 2 frames, as lerobot)."""
        if self.container is not None:
            for packet in self.stream.encode():
                self.container.mux(packet)
            self.container.close()
            self.container = None
        return self.counts.statistics() if self.frames >= 2 else None

    def abort(self) -> None:
        if self.container is not None:
            try:
                self.container.close()
            except Exception:  # an unfinished file is deleted anyway
                pass
            self.container = None


class EpisodeVideoEncoder(StreamingVideoEncoder):
    """lerobot's ``StreamingVideoEncoder`` interface, encoding in the caller's thread with
    cheap exact image statistics (see the module docstring)."""

    def __init__(
        self,
        fps: int,
        rgb_encoder=None,
        depth_encoder=None,
        queue_maxsize: int = 0,
        encoder_threads: int | None = None,
    ) -> None:
        super().__init__(
            fps,
            rgb_encoder=rgb_encoder,
            depth_encoder=depth_encoder,
            queue_maxsize=queue_maxsize,
            encoder_threads=encoder_threads,
        )
        self._videos: dict[str, _CameraVideo] = {}

    def start_episode(
        self, video_keys: list[str], temp_dir: Path, depth_video_keys: list[str] | None = None
    ) -> None:
        if depth_video_keys:
            raise ValueError(f"depth videos are not supported: {depth_video_keys}")
        if self._episode_active:
            self.cancel_episode()
        for key in video_keys:
            folder = Path(tempfile.mkdtemp(dir=temp_dir))  # lerobot removes it after the move
            path = folder / f"{key.replace('/', '_')}_streaming.mp4"
            self._videos[key] = _CameraVideo(
                path, self.fps, self._rgb_encoder, self._encoder_threads
            )
        self._episode_active = True

    def feed_frame(self, video_key: str, image: np.ndarray) -> None:
        if not self._episode_active:
            raise RuntimeError("No active episode. Call start_episode() first.")
        self._videos[video_key].add(image)

    def finish_episode(self) -> dict[str, tuple[Path, dict | None]]:
        if not self._episode_active:
            raise RuntimeError("No active episode to finish.")
        try:
            results = {key: (video.path, video.finish()) for key, video in self._videos.items()}
        except BaseException:
            self.cancel_episode()
            raise
        self._videos = {}
        self._episode_active = False
        return results

    def cancel_episode(self) -> None:
        for video in self._videos.values():
            video.abort()
            shutil.rmtree(video.path.parent, ignore_errors=True)
        self._videos = {}
        self._episode_active = False


def _needs_embedding(dataset) -> bool:
    from datasets.features.features import require_storage_embed

    return any(require_storage_embed(feature) for feature in dataset.features.values())


def install_embed_shortcut() -> None:
    """Skip lerobot's ``embed_images`` where it would change nothing (module docstring).
    Idempotent; affects lerobot's episode writing in this process only."""
    from lerobot.datasets import dataset_writer

    if getattr(dataset_writer.embed_images, "wirecraft_shortcut", False):
        return
    embed_images = dataset_writer.embed_images

    def embed_images_if_needed(dataset):
        return embed_images(dataset) if _needs_embedding(dataset) else dataset

    embed_images_if_needed.wirecraft_shortcut = True
    embed_images_if_needed.__wrapped__ = embed_images
    dataset_writer.embed_images = embed_images_if_needed


class WireCraftLeRobotDataset(LeRobotDataset):
    """``LeRobotDataset`` whose streaming encoder is an ``EpisodeVideoEncoder``; reading and
    everything else are lerobot's.  Use ``create`` / ``resume`` with ``streaming_encoding=True``."""

    @classmethod
    def create(cls, *args, **kwargs) -> WireCraftLeRobotDataset:
        install_embed_shortcut()
        return super().create(*args, **kwargs)

    @classmethod
    def resume(cls, *args, **kwargs) -> WireCraftLeRobotDataset:
        install_embed_shortcut()
        return super().resume(*args, **kwargs)

    @staticmethod
    def _build_streaming_encoder(
        fps, rgb_encoder, depth_encoder, encoder_queue_maxsize, encoder_threads
    ) -> EpisodeVideoEncoder:
        return EpisodeVideoEncoder(
            fps,
            rgb_encoder=rgb_encoder,
            depth_encoder=depth_encoder,
            queue_maxsize=encoder_queue_maxsize,
            encoder_threads=encoder_threads,
        )
