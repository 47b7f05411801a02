"""Writing ``Episode``s into a LeRobot v3 dataset with lerobot's own API, crash-safely.

Every data source (scripted demonstrations, RL rollouts, teleoperation, real-robot imports)
writes through ``EpisodeWriter``: ``create`` (or ``open`` to append), ``add_episode`` per
episode, ``close`` at the end.  Underneath: ``LeRobotDataset.create`` / ``resume``,
``add_frame`` per frame, ``save_episode``, ``finalize``; videos are encoded while the frames
are added, through lerobot's streaming-encoder interface by ``encoding.EpisodeVideoEncoder``
(in the calling thread, so no frame is ever dropped, with exact image statistics from level
counts instead of lerobot's ~6.5 ms-per-frame histograms; see ``encoding.py``).

What survives what (lerobot 0.6.1, read from its source):
- ``save_episode`` rewrites ``meta/info.json`` and ``meta/stats.json`` and appends the frames
  to an open ``pyarrow.ParquetWriter``; the episode index is buffered and also written through
  an open ParquetWriter.  A parquet file gets its footer only when its writer closes
  (``finalize``), so after a hard kill (SIGKILL, power loss) the open data and episode files
  are unreadable and ``info.json`` counts episodes that cannot be loaded: nothing loads.
- Hence commits: every ``commit_every`` episodes (and on ``close``) the writer finalizes the
  dataset, which leaves it loadable, then reopens it with ``LeRobotDataset.resume``, which
  always starts new data, episode-index and video files: committed files are never touched
  again.  The commit record ``meta/wirecraft_commit.json`` (written atomically) lists the
  committed files with their sizes and holds copies of ``info.json``, ``stats.json``, the
  task list and the caller's progress.  ``open`` (and ``recover``) roll a dataset back to its
  last commit: files written after it are deleted and the metadata restored.  A hard kill
  therefore loses at most the episodes since the last commit.  Committing after every episode
  would lose none, but ``resume`` re-reads every episode-index file (~6 ms each, growing with
  the dataset), so the default is every 10 episodes.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from wirecraft.datasets.recorder import Episode
from wirecraft.lerobot_compat import quiet_torchcodec

quiet_torchcodec()  # lerobot's torchcodec traceback where FFmpeg is missing

COMMIT_FILE = "meta/wirecraft_commit.json"
COMMIT_FORMAT = 1
DEFAULT_REPO_ID = "wirecraft/local"
INFO_FILE = "meta/info.json"
STATS_FILE = "meta/stats.json"
TASKS_FILE = "meta/tasks.parquet"
# lerobot's per-episode files: everything else at the top level of a dataset is either
# metadata restored from the commit record or a temporary folder of an unfinished episode.
EPISODE_DIRS = ("data", "meta/episodes", "videos")
VIDEO_BACKEND = "pyav"  # decoding; torchcodec needs the system FFmpeg libraries (lerobot_compat)
# Video encoders (lerobot ``RGBEncoderConfig`` fields).  Both keep lerobot's 2-frame GOP (fast
# random access when training) and yuv420p.  Measured on 224 x 224 frames of this task, one
# thread: h264 (veryfast, CRF 18) ~1 ms per frame, mean abs error ~1.6 / 255, ~2 kB per frame;
# lerobot's default AV1 (SVT, preset 12, CRF 30) ~3.4-4.4 ms per frame, same error and size.
# AV1 would add ~1 s of CPU per demonstration (~3 s in all), hence h264 by default.
VIDEO_CODECS = {
    "h264": {"vcodec": "h264", "preset": "veryfast", "crf": 18, "g": 2},
    "libsvtav1": {"vcodec": "libsvtav1", "preset": 12, "crf": 30, "g": 2},
}
DEFAULT_VCODEC = "h264"


def write_json_atomic(path: Path, payload) -> None:
    """Write JSON so that a crash leaves either the old or the new file, never half of one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w") as f:
        json.dump(payload, f, indent=2, sort_keys=True)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def quiet_writing() -> None:
    """Keep the terminal for our progress bar: SVT-AV1 prints its configuration for every video,
    FFmpeg a line per video concatenation, and Hugging Face datasets a bar per episode."""
    import av.logging
    import datasets

    os.environ.setdefault("SVT_LOG", "1")  # errors only
    # lerobot hands logging back to FFmpeg's own logger after each video: set that one's level.
    av.logging.set_libav_level(av.logging.ERROR)
    datasets.disable_progress_bars()


def _episode_files(root: Path) -> dict[str, int]:
    files = {}
    for folder in EPISODE_DIRS:
        base = root / folder
        if base.is_dir():
            for path in base.rglob("*"):
                if path.is_file():
                    files[path.relative_to(root).as_posix()] = path.stat().st_size
    return files


def read_commit(root: str | os.PathLike) -> dict | None:
    """The last commit record of the dataset at ``root`` (None if it has none)."""
    path = Path(root) / COMMIT_FILE
    if not path.is_file():
        return None
    record = json.loads(path.read_text())
    if record.get("format") != COMMIT_FORMAT:
        raise ValueError(f"{path}: unknown commit record format {record.get('format')!r}")
    return record


def _read_or_none(path: Path, read):
    """``read(path)``, or None where the file is missing or half-written: lerobot rewrites
    ``info.json``, ``stats.json`` and ``tasks.parquet`` in place, so a hard kill during that
    write leaves a truncated file, which the commit record's copy replaces."""
    if not path.is_file():
        return None
    try:
        return read(path)
    except Exception:  # json.JSONDecodeError, pyarrow.ArrowInvalid, ...: the content is lost
        return None


def recover(root: str | os.PathLike) -> dict:
    """Roll the dataset at ``root`` back to its last commit; returns what was done:
    ``{"episodes": committed, "removed": [relative paths], "restored_metadata": bool}``.

    Raises ValueError when ``root`` has no commit record or a committed file is missing or
    changed (the dataset was damaged by something else)."""
    import pandas as pd
    from lerobot.datasets.io_utils import load_tasks, write_tasks

    root = Path(root)
    record = read_commit(root)
    if record is None:
        raise ValueError(f"{root}: no {COMMIT_FILE}; not a dataset written by EpisodeWriter")
    committed: dict[str, int] = record["files"]
    present = _episode_files(root)
    for rel, size in committed.items():
        if present.get(rel) != size:
            what = "missing" if rel not in present else f"{present[rel]} bytes, committed {size}"
            raise ValueError(f"{root}: committed file {rel} is {what}; the dataset is damaged")
    removed = sorted(rel for rel in present if rel not in committed)
    for rel in removed:
        (root / rel).unlink()
    for child in root.iterdir():  # unfinished episodes' temporary folders (images/, tmp*)
        if child.is_dir() and child.name not in ("data", "meta", "videos"):
            shutil.rmtree(child)
            removed.append(child.name + "/")
    for folder in EPISODE_DIRS:  # empty folders left by removed files
        base = root / folder
        if base.is_dir():
            for path in sorted(base.rglob("*"), reverse=True):
                if path.is_dir() and not any(path.iterdir()):
                    path.rmdir()
    restored = False
    for rel, content in ((INFO_FILE, record["info"]), (STATS_FILE, record["stats"])):
        path = root / rel
        current = _read_or_none(path, lambda p: json.loads(p.read_text()))
        if content is None:
            if path.exists():
                path.unlink()
                restored = True
        elif current != content:
            write_json_atomic(path, content)
            restored = True
    tasks = record["tasks"]
    tasks_path = root / TASKS_FILE
    current_tasks = _read_or_none(tasks_path, lambda _: list(load_tasks(root).index))
    if current_tasks != tasks and (tasks or tasks_path.exists()):
        if tasks:
            frame = pd.DataFrame({"task_index": range(len(tasks))}, index=pd.Index(tasks))
            frame.index.name = "task"
            write_tasks(frame, root)
        else:
            tasks_path.unlink()
        restored = True
    return {"episodes": record["episodes"], "removed": removed, "restored_metadata": restored}


class EpisodeWriter:
    """Appends ``Episode``s to a LeRobot v3 dataset; see the module docstring for commits.

    Build with ``EpisodeWriter.create(root, features, fps, ...)`` for a new dataset or
    ``EpisodeWriter.open(root)`` to append to one written before (rolled back to its last
    commit first).  ``progress``: any JSON-able dict the caller wants stored with each commit
    (e.g. the next episode seed), read back by ``open`` as ``writer.progress``."""

    def __init__(
        self, dataset, root: Path, repo_id: str, vcodec: str, commit_every: int, options: dict
    ):
        self._dataset = dataset
        self.root = root
        self.repo_id = repo_id
        self.vcodec = vcodec
        self.commit_every = commit_every
        self._options = options
        self._since_commit = 0
        self.progress: dict = {}
        self.closed = False

    @staticmethod
    def _open_options(vcodec: str, encoder_threads: int | None) -> dict:
        from lerobot.configs import RGBEncoderConfig

        if vcodec not in VIDEO_CODECS:
            raise ValueError(f"unknown vcodec {vcodec!r}; valid: {', '.join(VIDEO_CODECS)}")
        quiet_writing()
        return {
            "rgb_encoder": RGBEncoderConfig(**VIDEO_CODECS[vcodec]),
            "video_backend": VIDEO_BACKEND,
            "streaming_encoding": True,  # with encoding.EpisodeVideoEncoder: no queue
            "encoder_queue_maxsize": 0,
            "encoder_threads": encoder_threads,
        }

    @staticmethod
    def _check_commit_every(commit_every: int) -> int:
        if isinstance(commit_every, bool) or not isinstance(commit_every, int):
            raise ValueError(f"commit_every must be an integer, got {commit_every!r}")
        if commit_every < 1:
            raise ValueError(f"commit_every must be >= 1, got {commit_every}")
        return commit_every

    @classmethod
    def create(
        cls,
        root: str | os.PathLike,
        features: dict,
        fps: int,
        *,
        robot_type: str | None = None,
        repo_id: str = DEFAULT_REPO_ID,
        commit_every: int = 10,
        vcodec: str = DEFAULT_VCODEC,
        encoder_threads: int | None = 1,
        progress: dict | None = None,
    ) -> EpisodeWriter:
        """A new dataset at ``root`` (which must not exist, or be an empty folder).
        ``vcodec``: a key of ``VIDEO_CODECS``; ``encoder_threads``: per video."""
        from wirecraft.datasets.encoding import WireCraftLeRobotDataset

        root = Path(root)
        cls._check_commit_every(commit_every)
        if root.exists():
            if not root.is_dir() or any(root.iterdir()):
                raise ValueError(f"{root} exists and is not an empty folder")
        options = cls._open_options(vcodec, encoder_threads)
        if root.exists():
            root.rmdir()  # lerobot creates the folder itself
        dataset = WireCraftLeRobotDataset.create(
            repo_id,
            fps=fps,
            features=features,
            root=root,
            robot_type=robot_type,
            use_videos=True,
            **options,
        )
        writer = cls(dataset, root, repo_id, vcodec, commit_every, options)
        writer.progress = dict(progress or {})
        writer._write_commit()
        return writer

    @classmethod
    def open(
        cls,
        root: str | os.PathLike,
        *,
        commit_every: int = 10,
        encoder_threads: int | None = 1,
    ) -> EpisodeWriter:
        """Append to the dataset at ``root``, first rolled back to its last commit."""
        from wirecraft.datasets.encoding import WireCraftLeRobotDataset

        root = Path(root)
        cls._check_commit_every(commit_every)
        recover(root)
        record = read_commit(root)
        options = cls._open_options(record["vcodec"], encoder_threads)
        dataset = WireCraftLeRobotDataset.resume(record["repo_id"], root=root, **options)
        writer = cls(dataset, root, record["repo_id"], record["vcodec"], commit_every, options)
        writer.progress = dict(record.get("progress") or {})
        return writer

    # -- state ---------------------------------------------------------------------------------
    @property
    def num_episodes(self) -> int:
        return int(self._dataset.meta.total_episodes)

    @property
    def num_frames(self) -> int:
        return int(self._dataset.meta.total_frames)

    @property
    def features(self) -> dict:
        return self._dataset.meta.features

    @property
    def fps(self) -> int:
        return int(self._dataset.meta.fps)

    # -- writing -------------------------------------------------------------------------------
    def add_episode(self, episode: Episode, progress: dict | None = None) -> int:
        """Write one episode (its frames, then ``save_episode``); returns its index in the
        dataset.  ``progress`` replaces the caller's progress stored at the next commit."""
        if self.closed:
            raise RuntimeError("the writer is closed")
        if len(episode) == 0:
            raise ValueError("an episode needs at least one frame")
        index = self.num_episodes
        try:
            for frame in episode.frames():
                self._dataset.add_frame(frame)
            self._dataset.save_episode()
        except BaseException:
            if self._dataset.has_pending_frames():
                self._dataset.clear_episode_buffer()
            raise
        if progress is not None:
            self.progress = dict(progress)
        self._since_commit += 1
        if self._since_commit >= self.commit_every:
            self.commit()
        return index

    def commit(self, progress: dict | None = None) -> None:
        """Make every episode written so far survive a hard kill (finalize, record, reopen)."""
        from wirecraft.datasets.encoding import WireCraftLeRobotDataset

        if self.closed:
            raise RuntimeError("the writer is closed")
        if progress is not None:
            self.progress = dict(progress)
        self._dataset.finalize()
        self._write_commit()
        self._dataset = WireCraftLeRobotDataset.resume(
            self.repo_id, root=self.root, **self._options
        )
        self._since_commit = 0

    def close(self, progress: dict | None = None) -> None:
        """Commit and finalize: the dataset is complete and loadable.  Idempotent."""
        if self.closed:
            return
        if progress is not None:
            self.progress = dict(progress)
        if self._dataset.has_pending_frames():
            self._dataset.clear_episode_buffer()
        self._dataset.finalize()
        self._write_commit()
        self.closed = True

    def _write_commit(self) -> None:
        root = self.root
        stats_path = root / STATS_FILE
        tasks = []
        if (root / TASKS_FILE).is_file():
            from lerobot.datasets.io_utils import load_tasks

            tasks = list(load_tasks(root).index)
        record = {
            "format": COMMIT_FORMAT,
            "repo_id": self.repo_id,
            "vcodec": self.vcodec,
            "episodes": self.num_episodes,
            "frames": self.num_frames,
            "files": _episode_files(root),
            "info": json.loads((root / INFO_FILE).read_text()),
            "stats": json.loads(stats_path.read_text()) if stats_path.is_file() else None,
            "tasks": tasks,
            "progress": self.progress,
        }
        write_json_atomic(root / COMMIT_FILE, record)

    def __enter__(self) -> EpisodeWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def load_dataset(root: str | os.PathLike, **kwargs):
    """The dataset at ``root`` as a ``lerobot.datasets.lerobot_dataset.LeRobotDataset``."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = Path(root)
    record = read_commit(root)
    if record is None and not (root / INFO_FILE).is_file():
        raise ValueError(f"{root} holds no LeRobot dataset (no {INFO_FILE})")
    if record is not None and _episode_files(root) != record["files"]:
        raise ValueError(
            f"{root} is incomplete: it was written to after its last commit and not closed "
            f"(interrupted or killed?); `wirecraft collect --resume --out {root}` rolls it back "
            "to that commit and continues it (datasets.writer.recover only rolls it back)"
        )
    repo_id = record["repo_id"] if record else DEFAULT_REPO_ID
    kwargs.setdefault("video_backend", VIDEO_BACKEND)
    return LeRobotDataset(repo_id, root=root, **kwargs)
