"""Demonstration datasets: the LeRobot v3 schema, ``wirecraft collect`` and its safety nets.

The truth each check compares against: lerobot's own loader (``LeRobotDataset``), an
independent run of the same seeded episode through the plain gymnasium API (states, servo
targets, success flags and the environment's own rendered images), and a replay of the stored
environment actions.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import mujoco
import numpy as np
import pytest

import wirecraft
from wirecraft.cli import main
from wirecraft.datasets import schema
from wirecraft.datasets.collect import (
    CollectSettings,
    collect,
    episode_sources,
    run_episode,
    run_episodes,
    summary_lines,
)
from wirecraft.datasets.recorder import Episode
from wirecraft.datasets.writer import DEFAULT_REPO_ID, EpisodeWriter, read_commit
from wirecraft.envs.vector import env_seed
from wirecraft.experts import InsertionExpert
from wirecraft.geometry import quat_near
from wirecraft.golden import golden_file_sha256

SEED = 7
SIZE = 64  # small images keep the tests fast; the pipeline is the same at 224
SETTINGS = CollectSettings(
    task="insertion", env_kwargs={"connector": "ethernet"}, image_size=SIZE, seed=SEED
)
CLI_ARGS = [
    "collect",
    "--task",
    "insertion",
    "--connector",
    "ethernet",
    "--image-size",
    str(SIZE),
    "--seed",
    str(SEED),
]
# Decoded video vs. rendered frames, mean absolute error per frame on the 0..255 scale
# (h264, CRF 18, yuv420p: chroma subsampling and quantization).  Measured up to ~4 at 64 x 64
# (wrist camera, sharp edges at a small size), ~1.6 at 224 x 224.
VIDEO_TOLERANCE = 6.0


def load(root):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(DEFAULT_REPO_ID, root=root, video_backend="pyav")


def column(dataset, key: str, episode: int) -> np.ndarray:
    """One episode's values of a non-video feature, as stored (no dtype conversion)."""
    table = dataset.hf_dataset.with_format("arrow")[:]
    rows = np.flatnonzero(table.column("episode_index").to_numpy() == episode)
    values = table.column(key).to_numpy(zero_copy_only=False)[rows]
    return np.stack(values) if values.dtype == object else values


def episode_rows(dataset, episode: int) -> np.ndarray:
    index = np.asarray(dataset.hf_dataset.with_format("arrow")[:]["episode_index"])
    return np.flatnonzero(index == episode)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Two episodes collected in this process: the uninterrupted run others compare with."""
    root = tmp_path_factory.mktemp("datasets") / "reference"
    report = collect(SETTINGS, root, 2, workers=0, progress_bar=False)
    return root, report


def independent_run(attempt: int, frames: int):
    """The same seeded episode through the gymnasium API with the environment's own images:
    per frame the state, rendered side / wrist images and success flags before the frame's
    two control steps, and the servo targets after them."""
    env = wirecraft.make("insertion", connector="ethernet", obs_mode="state_rgb", image_size=SIZE)
    u = env.unwrapped
    seed = env_seed(SEED, attempt)
    obs, info = env.reset(seed=seed)
    expert = InsertionExpert(env, seed=seed)  # its random choices follow the episode seed
    run = {k: [] for k in ("state", "action", "side", "wrist", "success", "insert_success")}
    for _ in range(frames):
        run["state"].append(
            np.concatenate(
                [
                    u.data.qpos[u.controller.index.arm_qpos],
                    [u.robot.gripper_opening(u.model, u.data)],
                ]
            )
        )
        run["side"].append(obs["rgb_side"])
        run["wrist"].append(obs["rgb_wrist"])
        run["success"].append(info["success"])
        run["insert_success"].append(info["insert_success"])
        for _ in range(2):  # 60 Hz control, 30 fps
            obs, _, _, _, info = env.step(expert.act(obs)[0])
        run["action"].append(
            np.concatenate([u.controller.joint_targets, [u.controller.gripper_target]])
        )
    env.close()
    return {k: np.asarray(v) for k, v in run.items()}


# -- schema ------------------------------------------------------------------------------------
@pytest.mark.parametrize("robot, dof", [("ur5", 6), ("panda", 7), ("wxai", 6)])
def test_features_follow_the_robot(robot, dof):
    features = schema.features_for(robot, 96, task="insertion", control="cartesian")
    assert features["observation.state"]["shape"] == (dof + 1,)
    assert features["action"]["shape"] == (dof + 1,)
    assert features["observation.cartesian_state"]["shape"] == (7,)
    assert features["observation.images.cam_side"]["shape"] == (96, 96, 3)
    assert features["action.env"]["shape"] == (2 * 7,)
    assert {"success", "reach_success", "insert_success", "source", "seed"} <= set(features)


@pytest.mark.parametrize("control", ["joint", "cartesian", "cartesian_fixed"])
def test_environment_action_size_matches_the_environment(control):
    env = wirecraft.make("seating", robot="panda", control=control)
    size = env.action_space.shape[0]
    assert schema.env_action_dim("panda", control) == size
    features = schema.features_for("panda", 32, task="seating", control=control, steps_per_frame=3)
    assert features["action.env"]["shape"] == (3 * size,)
    assert "insert_success" not in features


def test_source_codes_round_trip_and_reject_unknown_names():
    assert [schema.source_name(schema.source_code(s)) for s in schema.SOURCES] == list(
        schema.SOURCES
    )
    with pytest.raises(ValueError, match="unknown data source"):
        schema.source_code("simulated")
    with pytest.raises(ValueError, match="image_size"):
        schema.features_for("ur5", 8, task="insertion")


def test_quaternion_is_unit_and_near_the_reference_hemisphere():
    from scipy.spatial.transform import Rotation

    home = np.diag([-1.0, 1.0, -1.0])  # TCP pointing down: w = 0, where a w >= 0 rule flips
    for rotvec in np.random.default_rng(0).normal(scale=0.3, size=(20, 3)):
        rot = Rotation.from_rotvec(rotvec).as_matrix() @ home
        q = quat_near(rot, home)
        x, y, z, w = Rotation.from_matrix(rot).as_quat()
        assert np.allclose(np.abs(q @ [w, x, y, z]), 1.0)  # same rotation, (w, x, y, z) order
        assert q[2] > 0.5  # the home quaternion is (0, 0, 1, 0)


# -- writing and reading back --------------------------------------------------------------------
def test_dataset_loads_with_lerobot_with_the_schema(reference):
    root, report = reference
    assert report.saved == 2 and report.new_attempts >= 2 and not report.interrupted
    dataset = load(root)
    assert dataset.num_episodes == 2
    expected = schema.features_for("ur5", SIZE, task="insertion", control="cartesian")
    for key, feature in expected.items():
        assert dataset.features[key]["dtype"] == feature["dtype"], key
        assert tuple(dataset.features[key]["shape"]) == feature["shape"], key
    assert dataset.fps == 30
    records = read_commit(root)["progress"]["episodes"]
    for e, record in enumerate(records):
        rows = episode_rows(dataset, e)
        assert len(rows) == record["frames"] == int(dataset.meta.episodes[e]["length"])
        assert record["control_steps"] == 2 * record["frames"]
        assert column(dataset, "seed", e).tolist() == [env_seed(SEED, record["attempt"])] * len(
            rows
        )
        timestamps = column(dataset, "timestamp", e)
        assert np.allclose(timestamps, np.arange(len(rows)) / 30.0, atol=1e-5)
    item = dataset[0]
    assert item["task"] == "Pick up the ethernet plug and insert it into the port."
    assert item["observation.images.cam_wrist"].shape == (3, SIZE, SIZE)
    assert episode_sources(dataset) == ["scripted", "scripted"]


def test_states_actions_flags_and_images_match_an_independent_run(reference):
    root, _ = reference
    dataset = load(root)
    record = read_commit(root)["progress"]["episodes"][0]
    rows = episode_rows(dataset, 0)
    run = independent_run(record["attempt"], len(rows))
    assert np.array_equal(column(dataset, "observation.state", 0), run["state"].astype(np.float32))
    assert np.array_equal(column(dataset, "action", 0), run["action"].astype(np.float32))
    assert np.array_equal(column(dataset, "success", 0), run["success"])
    assert np.array_equal(column(dataset, "insert_success", 0), run["insert_success"])
    # The episode ends once success held 0.5 s (30 control steps: the last 14 observed
    # frames at least); it starts without.
    assert run["success"][-14:].all() and not run["success"][0]
    for camera in ("side", "wrist"):
        key = f"observation.images.cam_{camera}"
        errors, shifted = [], []
        for j in range(0, len(rows), 7):
            decoded = dataset[int(rows[j])][key].numpy().transpose(1, 2, 0) * 255.0
            errors.append(np.abs(decoded - run[camera][j]).mean())
            shifted.append(np.abs(decoded - run[camera][(j + 40) % len(rows)]).mean())
        assert max(errors) < VIDEO_TOLERANCE, (camera, max(errors))
        # The images change over the episode: frames 40 apart (1.3 s) differ far more.
        assert np.mean(shifted) > 2 * np.mean(errors), (camera, errors, shifted)


def test_stored_environment_actions_replay_the_episode_exactly(reference):
    root, _ = reference
    dataset = load(root)
    episode = 1
    env_actions = column(dataset, "action.env", episode)
    assert env_actions.dtype == np.float64
    seed = int(column(dataset, "seed", episode)[0])
    env = wirecraft.make("insertion", connector="ethernet")
    u = env.unwrapped
    env.reset(seed=seed)
    states = []
    for actions in env_actions:
        states.append(u.robot.dataset_state(u.model, u.data))
        for action in actions.reshape(2, -1):
            env.step(action)
    assert np.array_equal(np.asarray(states, np.float32), column(dataset, "observation.state", 1))


def test_worker_processes_write_the_same_episodes(reference, tmp_path):
    root, _ = reference
    report = collect(SETTINGS, tmp_path / "pool", 1, workers=2, progress_bar=False)
    assert report.saved == 1
    ours, theirs = load(tmp_path / "pool"), load(root)
    for key in ("observation.state", "action", "action.env", "observation.cartesian_state"):
        assert np.array_equal(column(ours, key, 0), column(theirs, key, 0)), key


ROUTING_FEATURES = schema.features_for("ur5", 32, task="routing", control="cartesian")


def random_episode(rng, source: str = "rl", n: int = 5) -> Episode:
    """A routing episode of random values in ``ROUTING_FEATURES``' schema."""
    return Episode(
        task="route the wire",
        source=source,
        seed=schema.NO_SEED,
        state=rng.normal(size=(n, 7)),
        action=rng.normal(size=(n, 7)),
        cartesian_state=rng.normal(size=(n, 7)),
        env_action=rng.uniform(-1, 1, size=(n, 14)),
        images={c: rng.integers(0, 255, (n, 32, 32, 3), dtype=np.uint8) for c in schema.CAMERAS},
        flags={"success": np.arange(n) > 2},
    )


def test_other_sources_write_the_same_schema(tmp_path):
    """An RL rollout or teleoperation episode goes through the same writer."""
    features = ROUTING_FEATURES
    rng = np.random.default_rng(0)
    episodes = [random_episode(rng, "rl"), random_episode(rng, "teleop")]
    with EpisodeWriter.create(tmp_path / "mixed", features, 30, commit_every=1) as writer:
        for e in episodes:
            writer.add_episode(e)
    dataset = load(tmp_path / "mixed")
    assert episode_sources(dataset) == ["rl", "teleop"]
    assert np.allclose(column(dataset, "observation.state", 1), episodes[1].state, atol=1e-6)
    assert column(dataset, "success", 0).tolist() == [False, False, False, True, True]


def test_failed_episodes_are_dropped_or_kept_and_counted(tmp_path):
    # A 1 s episode is too short for the expert: every attempt fails.
    short = dict(env_kwargs={"connector": "ethernet", "episode_seconds": 1.0}, image_size=32)
    dropped = collect(
        CollectSettings(**short),
        tmp_path / "drop",
        1,
        workers=0,
        max_attempts=2,
        progress_bar=False,
    )
    assert (dropped.saved, dropped.dropped_failures, dropped.attempts) == (0, 2, 2)
    assert dropped.gave_up and any("gave up" in line for line in summary_lines(dropped))
    kept = collect(
        CollectSettings(**short, keep_failures=True),
        tmp_path / "keep",
        1,
        workers=0,
        progress_bar=False,
    )
    assert (kept.saved, kept.saved_failures, kept.dropped_failures) == (1, 1, 0)
    dataset = load(tmp_path / "keep")
    assert dataset.num_frames == 30  # 60 control steps at 30 fps
    assert not column(dataset, "success", 0).any()
    assert read_commit(tmp_path / "keep")["progress"]["episodes"][0]["end"] == "time_limit"


# -- image statistics and video encoding (datasets/encoding.py) --------------------------------
def test_level_counts_give_numpys_statistics():
    from wirecraft.datasets.encoding import ChannelLevelCounts

    rng = np.random.default_rng(1)
    images = rng.integers(20, 230, (5, 17, 13, 3), dtype=np.uint8)
    images[..., 1] //= 3  # another distribution in each channel
    images[..., 2] = np.minimum(images[..., 2], 90)
    counts = ChannelLevelCounts(3)
    for image in images:
        counts.update(image)
    stats = counts.statistics()
    pixels = images.reshape(-1, 3).astype(np.float64)
    assert stats["count"].tolist() == [len(pixels)]
    assert np.array_equal(stats["min"], pixels.min(axis=0))
    assert np.array_equal(stats["max"], pixels.max(axis=0))
    assert np.allclose(stats["mean"], pixels.mean(axis=0), rtol=1e-12)
    assert np.allclose(stats["std"], pixels.std(axis=0), rtol=1e-9)
    for q in (0.01, 0.10, 0.50, 0.90, 0.99):
        expected = np.quantile(pixels, q, axis=0, method="inverted_cdf")
        assert np.array_equal(stats[f"q{round(q * 100):02d}"], expected), q
    with pytest.raises(ValueError, match="uint8"):
        counts.update(images[0].astype(np.float32))
    with pytest.raises(ValueError, match="no pixels"):
        ChannelLevelCounts(3).statistics()


def test_image_statistics_match_lerobots_tracker_over_every_frame(reference):
    """The statistics stored for the videos against lerobot's own ``RunningQuantileStats``
    fed every pixel of every frame (what its streaming encoder computes), on the frames of
    an independent run of the same episodes."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from lerobot.datasets.compute_stats import RunningQuantileStats

    root, _ = reference
    dataset = load(root)
    records = read_commit(root)["progress"]["episodes"]
    # Per-episode statistics as stored (lerobot's loader leaves them out of meta.episodes).
    stored_episodes = pa.concat_tables(
        pq.read_table(path) for path in sorted((root / "meta" / "episodes").rglob("*.parquet"))
    ).to_pylist()
    stored_episodes.sort(key=lambda row: row["episode_index"])
    frames = {key: [] for key in schema.CAMERAS.values()}
    for e, record in enumerate(records):
        episode = run_episode(SETTINGS, record["attempt"])
        assert len(episode) == record["frames"]
        for camera, key in schema.CAMERAS.items():
            frames[key].append(episode.images[camera])
            tracker = RunningQuantileStats()
            for image in episode.images[camera]:
                tracker.update(image.reshape(-1, 3))
            truth = tracker.get_statistics()
            row = stored_episodes[e]
            for stat, value in truth.items():
                stored = np.asarray(row[f"stats/{key}/{stat}"], dtype=np.float64).reshape(-1)
                if stat == "count":
                    assert stored.tolist() == value.tolist()
                    continue
                # lerobot interpolates quantiles in 5000 bins over [min, max] (< 1 / 5000);
                # its float32 running means round at ~1e-6, its std (from E[x^2] - E[x]^2)
                # at ~2e-5; ours are exact (checked against float64 below).
                tolerance = {"std": 1e-4}.get(stat, 1e-3 if stat.startswith("q") else 1e-5)
                assert np.allclose(stored, value / 255.0, atol=tolerance), (key, stat)
    # The dataset-wide statistics (lerobot aggregates the episodes') are those of all frames.
    for key, parts in frames.items():
        pixels = np.concatenate(parts).reshape(-1, 3).astype(np.float64) / 255.0
        stats = dataset.meta.stats[key]
        assert np.asarray(stats["mean"]).shape == (3, 1, 1)
        assert np.allclose(np.ravel(stats["mean"]), pixels.mean(axis=0), atol=1e-6)
        assert np.allclose(np.ravel(stats["std"]), pixels.std(axis=0), atol=1e-6)
        assert np.allclose(np.ravel(stats["min"]), pixels.min(axis=0))
        assert np.allclose(np.ravel(stats["max"]), pixels.max(axis=0))


def test_our_encoder_writes_what_lerobots_streaming_encoder_writes(tmp_path):
    """The same episode through lerobot's own ``LeRobotDataset`` (its streaming encoder) and
    through ours: byte-identical videos, identical frames, the same statistics (images' close,
    see ``encoding.py``)."""
    import pyarrow.parquet as pq
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from wirecraft.datasets.encoding import WireCraftLeRobotDataset

    rng = np.random.default_rng(4)
    episode = random_episode(rng, n=12)
    x = np.arange(32)
    for camera in schema.CAMERAS:  # gradients plus noise: realistic statistics and video
        ramp = (x[:, None, None] * 5 + x[None, :, None] * 3 + [0, 60, 120]).astype(float)
        noise = rng.normal(0, 12, size=(12, 32, 32, 3))
        moving = np.arange(12)[:, None, None, None] * 7
        episode.images[camera] = np.clip(ramp + noise + moving, 0, 255).astype(np.uint8)
    options = EpisodeWriter._open_options("h264", 1)
    roots = {}
    for cls in (LeRobotDataset, WireCraftLeRobotDataset):
        roots[cls] = tmp_path / cls.__name__
        dataset = cls.create(
            DEFAULT_REPO_ID, fps=30, features=ROUTING_FEATURES, root=roots[cls], **options
        )
        for frame in episode.frames():
            dataset.add_frame(frame)
        dataset.save_episode()
        dataset.finalize()
    theirs, ours = roots.values()
    videos = sorted(p.relative_to(theirs) for p in theirs.rglob("*.mp4"))
    assert len(videos) == 2 and videos == sorted(p.relative_to(ours) for p in ours.rglob("*.mp4"))
    for video in videos:
        assert (theirs / video).read_bytes() == (ours / video).read_bytes(), video
    data = sorted(p.relative_to(theirs) for p in theirs.glob("data/**/*.parquet"))
    assert data
    for path in data:
        assert pq.read_table(theirs / path).equals(pq.read_table(ours / path)), path
    their_stats, our_stats = (
        json.loads((r / "meta" / "stats.json").read_text()) for r in roots.values()
    )
    assert their_stats.keys() == our_stats.keys()
    for key, stats in their_stats.items():
        for stat, value in stats.items():
            tolerance = 1e-3 if key in schema.CAMERAS.values() else 0.0
            assert np.allclose(our_stats[key][stat], value, atol=tolerance, rtol=0), (key, stat)


def test_skipped_image_embedding_writes_what_lerobot_writes(tmp_path):
    import datasets
    from lerobot.datasets import dataset_writer
    from lerobot.datasets.feature_utils import get_hf_features_from_features
    from PIL import Image

    from wirecraft.datasets.encoding import install_embed_shortcut

    install_embed_shortcut()
    install_embed_shortcut()  # idempotent: one wrapper around lerobot's function
    shortcut = dataset_writer.embed_images
    lerobots = shortcut.__wrapped__
    assert not hasattr(lerobots, "__wrapped__")
    rng = np.random.default_rng(2)
    plain = {
        "observation.state": {"dtype": "float32", "shape": (3,), "names": None},
        "success": {"dtype": "bool", "shape": (1,), "names": None},
    }
    columns = {
        "observation.state": rng.normal(size=(6, 3)).astype(np.float32),
        "success": [True, False] * 3,
    }
    data = datasets.Dataset.from_dict(columns, features=get_hf_features_from_features(plain))
    assert shortcut(data) is data  # nothing to embed: skipped
    ours = shortcut(data).with_format("arrow")[:]
    theirs = lerobots(data).with_format("arrow")[:]
    assert ours.equals(theirs)  # columns, types and values
    # The schema's Hugging Face metadata: the same features; ``map`` adds only a cache key.
    ours_info, theirs_info = (
        json.loads(table.schema.metadata[b"huggingface"]) for table in (ours, theirs)
    )
    assert set(theirs_info) - set(ours_info) <= {"fingerprint"}
    assert ours_info["info"] == theirs_info["info"]
    # With an image feature, lerobot's embedding runs: the PNG bytes land in the table.
    paths = []
    for i in range(2):
        paths.append(str(tmp_path / f"{i}.png"))
        Image.fromarray(rng.integers(0, 255, (8, 8, 3), dtype=np.uint8)).save(paths[-1])
    image = {"observation.image": {"dtype": "image", "shape": (8, 8, 3), "names": None}}
    with_images = datasets.Dataset.from_dict(
        {"observation.image": paths}, features=get_hf_features_from_features(image)
    )
    embedded = shortcut(with_images).with_format("arrow")[:]
    stored = embedded.column("observation.image").to_pylist()
    assert [row["bytes"] for row in stored] == [open(p, "rb").read() for p in paths]


def test_a_failed_episode_leaves_no_partial_video(tmp_path):
    """An episode that fails half-way is discarded (its unfinished videos deleted); the next
    one is written and the dataset loads."""

    class Broken(Episode):
        def frames(self):
            for t, frame in enumerate(super().frames()):
                if t == 3:
                    raise RuntimeError("the robot controller went away")
                yield frame

    rng = np.random.default_rng(3)
    root = tmp_path / "ds"
    good = random_episode(rng)
    # Smooth images (a colour gradient moving over the frames): video-friendly, unlike noise.
    x = np.arange(32)
    for camera in schema.CAMERAS:
        gradient = [(x[:, None, None] * 6 + x[None, :, None] * 2 + t * 40) % 256 for t in range(5)]
        gradient = np.broadcast_to(np.asarray(gradient), (5, 32, 32, 3)) + [0, 40, 80]
        good.images[camera] = np.clip(gradient, 0, 255).astype(np.uint8)
    broken = Broken(**{f: getattr(random_episode(rng), f) for f in Episode.__dataclass_fields__})
    with EpisodeWriter.create(root, ROUTING_FEATURES, 30, commit_every=1) as writer:
        with pytest.raises(RuntimeError, match="went away"):
            writer.add_episode(broken)
        assert sorted(p.name for p in root.iterdir()) == ["meta"]  # no temporary folders
        assert writer.add_episode(good) == 0
    dataset = load(root)
    assert dataset.num_episodes == 1
    assert np.allclose(column(dataset, "observation.state", 0), good.state, atol=1e-6)
    decoded = dataset[2]["observation.images.cam_side"].numpy().transpose(1, 2, 0) * 255.0
    assert np.abs(decoded - good.images["side"][2]).mean() < VIDEO_TOLERANCE
    assert np.abs(decoded - good.images["side"][3]).mean() > 2 * VIDEO_TOLERANCE


# -- interruptions ---------------------------------------------------------------------------------
def test_metadata_half_written_at_a_hard_kill_is_restored_from_the_commit(tmp_path):
    """lerobot rewrites info.json, stats.json and tasks.parquet in place: a SIGKILL during
    that write leaves them truncated (CI caught an empty info.json).  Reopening restores
    them from the commit record; the dataset then loads with every committed episode."""
    rng = np.random.default_rng(5)
    root = tmp_path / "ds"
    episodes = [random_episode(rng) for _ in range(3)]
    writer = EpisodeWriter.create(root, ROUTING_FEATURES, 30, commit_every=10)
    writer.add_episode(episodes[0])
    writer.commit()
    writer.add_episode(episodes[1])  # not committed: the writer is abandoned as at a kill
    for rel, keep in (("meta/info.json", 0), ("meta/stats.json", 40), ("meta/tasks.parquet", 9)):
        path = root / rel
        path.write_bytes(path.read_bytes()[:keep])
    with EpisodeWriter.open(root, commit_every=1) as reopened:
        assert reopened.num_episodes == 1
        assert reopened.add_episode(episodes[2]) == 1
    dataset = load(root)
    assert dataset.num_episodes == 2
    for index, episode in ((0, episodes[0]), (1, episodes[2])):
        assert np.allclose(column(dataset, "observation.state", index), episode.state, atol=1e-6)


# Subprocess runs use 10 fps and 32 x 32 images (a third of the rendering); they are compared
# with ``run_episode`` of the same settings, which is what an uninterrupted run writes.
QUICK = CollectSettings(
    task="insertion", env_kwargs={"connector": "ethernet"}, image_size=32, fps=10, seed=SEED
)
QUICK_ARGS = [*CLI_ARGS[:-3], "32", "--seed", str(SEED), "--fps", "10"]


def start_collect(out, *extra) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "wirecraft.cli", *QUICK_ARGS, "--out", str(out), *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,  # its own process group: the test can end it with its workers
    )


def wait_for_episodes(out, count: int, proc: subprocess.Popen, timeout: float = 180.0) -> int:
    """Wait until lerobot's info.json counts ``count`` saved episodes."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()[0]
        try:
            saved = json.loads((out / "meta" / "info.json").read_text())["total_episodes"]
        except (FileNotFoundError, json.JSONDecodeError, KeyError):
            saved = 0
        if saved >= count:
            return saved
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    raise AssertionError(f"fewer than {count} episodes after {timeout} s")


@pytest.mark.slow
@pytest.mark.parametrize("sig, workers", [(signal.SIGINT, "1"), (signal.SIGTERM, "0")])
def test_a_signal_leaves_every_finished_episode_loadable(tmp_path, sig, workers):
    out = tmp_path / "ds"
    proc = start_collect(out, "--episodes", "8", "--workers", workers)
    wait_for_episodes(out, 2, proc)
    proc.send_signal(sig)
    output = proc.communicate(timeout=120)[0]
    assert proc.returncode == 128 + sig, output
    assert "--resume" in output
    saved = json.loads((out / "meta" / "info.json").read_text())["total_episodes"]
    dataset = load(out)  # no recovery step: finalized on the signal
    assert 2 <= dataset.num_episodes == saved < 8
    assert read_commit(out)["episodes"] == saved
    last = dataset[len(dataset) - 1]  # the last frame of the last episode decodes
    assert int(last["episode_index"]) == saved - 1


@pytest.mark.slow
def test_resume_after_a_hard_kill_completes_with_the_same_content(tmp_path):
    out = tmp_path / "ds"
    proc = start_collect(out, "--episodes", "4", "--workers", "0", "--commit-every", "2")
    wait_for_episodes(out, 3, proc)  # the third is written, not committed
    os.killpg(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)
    assert read_commit(out)["episodes"] in (2, 4)  # 4 if it finished before the kill
    result = subprocess.run(
        [sys.executable, "-m", "wirecraft.cli", *QUICK_ARGS, "--out", str(out)]
        + ["--episodes", "4", "--workers", "0", "--resume"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    dataset = load(out)
    assert dataset.num_episodes == 4
    records = read_commit(out)["progress"]["episodes"]
    assert [r["index"] for r in records] == [0, 1, 2, 3]
    from wirecraft.datasets.collect import SETTINGS_FILE

    sessions = json.loads((out / SETTINGS_FILE).read_text())["provenance"]
    assert len(sessions) == 2  # the killed run and the resumed one
    for session in sessions:
        assert session["packages"]["mujoco"] == mujoco.__version__
        assert session["golden_sha256"] == golden_file_sha256()
        assert session["threads"] == 1 and session["cpu"]
    for e in (1, 3):  # one committed before the kill, one written after the resume
        fresh = run_episode(QUICK, records[e]["attempt"])
        assert np.array_equal(column(dataset, "observation.state", e), fresh.state)
        assert np.array_equal(column(dataset, "action.env", e), fresh.env_action)


@pytest.mark.slow
def test_ray_tasks_generate_the_same_episode(reference, tmp_path):
    ray = pytest.importorskip("ray")
    root, _ = reference
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        report = collect(SETTINGS, tmp_path / "ray", 1, ray_address="auto", progress_bar=False)
    finally:
        ray.shutdown()
    assert report.saved == 1
    assert np.array_equal(
        column(load(tmp_path / "ray"), "observation.state", 0),
        column(load(root), "observation.state", 0),
    )


# -- bad input -------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "args, message",
    [
        (["--task", "knitting"], "unknown task"),
        (["--connector", "hdmi"], "hdmi"),
        (["--episodes", "0"], "--episodes: must be"),
        (["--fps", "7"], "fps must divide"),
        (["--workers", "-1"], "--workers: must be"),
        (["--vcodec", "mpeg1"], "--vcodec: invalid choice"),
        (["--control", "joint"], "drives control='cartesian'"),
        (
            ["--task", "routing", "--expert", "reactive", "--control", "joint"],
            "reactive routing expert drives control='cartesian'",
        ),
        (["--expert", "oracle"], "--expert: invalid choice"),
        (["--expert", "reactive", "--policy", "runs/x"], "--expert: applies only with scripted"),
    ],
)
def test_bad_input_is_a_clear_error(args, message, tmp_path, capsys):
    argv = ["collect", "--out", str(tmp_path / "ds"), "--image-size", str(SIZE), *args]
    assert main(argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()


def test_existing_folder_needs_resume_and_the_same_settings(reference, tmp_path, capsys):
    root, _ = reference
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("mine")
    assert main([*CLI_ARGS, "--out", str(busy)]) == 2
    assert "--resume" in capsys.readouterr().err
    assert main([*CLI_ARGS, "--out", str(busy), "--resume"]) == 2
    assert "not a dataset written by wirecraft collect" in capsys.readouterr().err
    other_seed = [*CLI_ARGS[:-1], str(SEED + 1), "--out", str(root), "--resume"]
    assert main(other_seed) == 2
    assert "refusing to mix" in capsys.readouterr().err
    assert main([*CLI_ARGS, "--expert", "reactive", "--out", str(root), "--resume"]) == 2
    assert "expert: 'scripted' -> 'reactive'" in capsys.readouterr().err
    assert load(root).num_episodes == 2  # untouched

    # a dataset of another state revision (or one from before it was recorded) is not continued
    from wirecraft.datasets.collect import SETTINGS_FILE
    from wirecraft.tasks import STATE_REVISION

    stored = json.loads((root / SETTINGS_FILE).read_text())
    assert stored["state_revision"] == STATE_REVISION
    old = tmp_path / "old"
    shutil.copytree(root, old)
    for revision in (STATE_REVISION - 1, None):
        if revision is None:
            del stored["state_revision"]
        else:
            stored["state_revision"] = revision
        (old / SETTINGS_FILE).write_text(json.dumps(stored))
        assert main([*CLI_ARGS, "--out", str(old), "--resume"]) == 2
        assert f"collected on state revision {revision or 1};" in capsys.readouterr().err
    assert load(old).num_episodes == 2

    # a dataset from before the expert was a setting was scripted: it is continued as such
    stored["state_revision"] = STATE_REVISION
    del stored["settings"]["expert"]
    (old / SETTINGS_FILE).write_text(json.dumps(stored))
    assert main([*CLI_ARGS, "--episodes", "2", "--out", str(old), "--resume"]) == 0
    assert main([*CLI_ARGS, "--expert", "reactive", "--out", str(old), "--resume"]) == 2
    assert "expert: 'scripted' -> 'reactive'" in capsys.readouterr().err


def assert_same_episode(a: Episode, b: Episode) -> None:
    assert (a.seed, a.success, a.control_steps, a.info["end"]) == (
        b.seed,
        b.success,
        b.control_steps,
        b.info["end"],
    )
    for name in ("state", "action", "cartesian_state", "env_action"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    for camera in a.images:
        assert np.array_equal(a.images[camera], b.images[camera]), camera
    for flag in a.flags:
        assert np.array_equal(a.flags[flag], b.flags[flag]), flag


@pytest.mark.parametrize(
    "task, options",
    [("insertion", {"connector": "ethernet"}), ("routing", {"num_clips": 1}), ("seating", {})],
)
def test_episodes_stepped_side_by_side_are_the_single_episodes(task, options):
    """``run_episodes`` (a worker's vector environment, a finished attempt's slot taking the
    next) gives each attempt the episode ``run_episode`` gives it alone."""
    settings = CollectSettings(task=task, env_kwargs=options, image_size=32, seed=SEED)
    attempts = [0, 1, 2, 3]
    side_by_side = run_episodes(settings, attempts, 2)
    for attempt, episode in zip(attempts, side_by_side, strict=True):
        assert_same_episode(episode, run_episode(settings, attempt))


def test_the_reactive_expert_demonstrates_its_own_actions(tmp_path):
    """``expert="reactive"``: each stored environment action is what
    ``ReactiveInsertionExpert`` commands for the state an independent run of the same seeded
    episode reaches, and its episodes are the same stepped side by side."""
    from wirecraft.datasets.collect import SETTINGS_FILE
    from wirecraft.experts.reactive import ReactiveInsertionExpert

    settings = CollectSettings(
        task="insertion",
        env_kwargs={"connector": "ethernet"},
        image_size=32,
        seed=SEED,
        expert="reactive",
    )
    report = collect(settings, tmp_path / "ds", 2, workers=0, progress_bar=False)
    assert report.saved == 2
    stored = json.loads((tmp_path / "ds" / SETTINGS_FILE).read_text())
    assert stored["settings"]["expert"] == "reactive"
    assert stored["expert"]["class"] == "ReactiveInsertionExpertDemonstrator"
    dataset = load(tmp_path / "ds")
    for episode in range(2):
        actions = column(dataset, "action.env", episode).reshape(-1, 7)
        seed = int(column(dataset, "seed", episode)[0])
        env = wirecraft.make("insertion", connector="ethernet", control="cartesian")
        expert = ReactiveInsertionExpert(env)
        obs, _ = env.reset(seed=seed)
        expected = []
        for _ in range(len(actions)):
            expected.append(expert.act(obs[None])[0])
            obs, *_ = env.step(expected[-1])
        env.close()
        np.testing.assert_allclose(actions, expected, rtol=0, atol=1e-12)
        assert column(dataset, "insert_success", episode)[-1]
    side_by_side = run_episodes(settings, [0, 1, 2], 2)
    for attempt, episode in enumerate(side_by_side):
        assert_same_episode(episode, run_episode(settings, attempt))


@pytest.mark.parametrize("doomed_attempt", [1, 2], ids=["first-slots", "freed-slot"])
def test_a_reset_that_fails_in_a_run_of_episodes_fails_that_attempt_only(
    monkeypatch, doomed_attempt
):
    """An attempt whose scene keeps diverging while settling is a failed attempt, as alone;
    the attempts around it are unchanged (whether it was among the first attempts, reset
    together, or went into a slot another attempt left)."""
    from wirecraft.envs.vector import WireCraftVectorEnv

    settings = CollectSettings(
        task="insertion", env_kwargs={"connector": "ethernet"}, image_size=32, seed=SEED
    )
    doomed = settings.episode_seed(doomed_attempt)
    reset = WireCraftVectorEnv.reset

    def failing_reset(self, *, seed=None, options=None):
        mask = (options or {}).get("reset_mask", np.ones(self.num_envs, bool))
        if seed is not None and any(s == doomed for s, m in zip(seed, mask, strict=True) if m):
            raise RuntimeError("the scene diverged while settling at reset, 3 times in a row")
        return reset(self, seed=seed, options=options)

    monkeypatch.setattr(WireCraftVectorEnv, "reset", failing_reset)
    attempts = [0, 1, 2, 3]
    episodes = run_episodes(settings, attempts, 2)
    failed = episodes[doomed_attempt]
    assert len(failed) == 0 and not failed.success
    assert failed.info["end"].startswith("reset failed")
    monkeypatch.setattr(WireCraftVectorEnv, "reset", reset)
    for attempt in attempts:
        if attempt != doomed_attempt:
            assert_same_episode(episodes[attempt], run_episode(settings, attempt))
