"""Bad command-line input: exit status 2, a message naming the flag, no traceback, and nothing
written (each refused before any work starts)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from wirecraft.cli import main

AS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0


@pytest.fixture
def place(tmp_path, monkeypatch):
    """tmp_path as the working folder, with a file, an empty folder, a read-only folder, a
    non-empty folder and a fake RL run to aim paths at."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "file").write_text("x")
    (tmp_path / "dir").mkdir()
    (tmp_path / "dir.parquet").mkdir()
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "a").write_text("x")
    (tmp_path / "ro").mkdir()
    (tmp_path / "ro").chmod(0o555)
    run = {"format": 1, "algorithm": "ppo", "task": "insertion", "env_kwargs": {"robot": "ur5"}}
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "wirecraft_rl.json").write_text(json.dumps(run))
    yield tmp_path
    (tmp_path / "ro").chmod(0o755)


def refused(place, capsys, argv: list[str], flag: str) -> None:
    argv = [a.replace("{tmp}", str(place)) for a in argv]
    before = sorted(place.rglob("*"))
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert flag in err, err
    assert "Traceback" not in err
    assert sorted(place.rglob("*")) == before
    assert not (place / "MUJOCO_LOG.TXT").exists()


def cases(command: str, table: list[tuple]) -> list:
    marks = {"ro": pytest.mark.skipif(AS_ROOT, reason="root writes anywhere")}
    return [
        pytest.param(
            [command, *args.split()] if isinstance(args, str) else [command, *args],
            flag,
            marks=[marks[m] for m in extra],
            id=f"{command} {args if isinstance(args, str) else ' '.join(args)}",
        )
        for args, flag, *extra in table
    ]


LIST = [
    ("--json dir", "--json"),
    ("--json file/x.json", "--json"),
    ("--json ro/x.json", "--json", "ro"),
    (["--json", ""], "--json"),
    ("--bogus", "--bogus"),
]

VIEW = [
    ("--headless --settle 1e9", "--settle"),
    ("--headless --settle inf", "--settle"),
    ("--headless --settle nan", "--settle"),
    ("--headless --settle -1", "--settle"),
    ("--headless --settle soon", "--settle"),
    ("--headless --width 0", "--width"),
    ("--headless --width 5000", "--width"),
    ("--headless --width 1.5", "--width"),
    ("--headless --height 2000", "--height"),
    ("--headless --height -3", "--height"),
    ("--out x.png", "--out"),
    ("--settle 2", "--settle"),
    ("--width 100", "--width"),
    ("--height 100", "--height"),
    ("--headless --out dir", "--out"),
    ("--headless --out file/x.png", "--out"),
    ("--headless --out x.txt", "--out"),
    ("--headless --out ro/x.png", "--out", "ro"),
    ("--headless --scene garage", "garage"),
]

EXPORT = [
    ("--part hdmi_port --out x.stl", "--part"),
    ("--part cuboid_port --out dir", "--out"),
    ("--part cuboid_port --out x.txt", "--out"),
    ("--part cuboid_port --out file/x.stl", "--out"),
    ("--all --out file", "--out"),
    ("--all --out file/sub", "--out"),
    ("--part cuboid_port --clearance -1 --out x.stl", "--clearance"),
    ("--part cuboid_port --clearance nan --out x.stl", "--clearance"),
    ("--part cuboid_port --clearance 1 --out x.stl", "--clearance"),
    ("--part cuboid_port --all --out dir", "--all"),
    ("--out x.stl", "--part"),
]

BENCH = [
    ("--suite gpu", "--suite"),
    ("--seconds 0", "--seconds"),
    ("--seconds -1", "--seconds"),
    ("--seconds inf", "--seconds"),
    ("--seconds nan", "--seconds"),
    ("--seconds 1e9", "--seconds"),
    ("--seconds abc", "--seconds"),
    ("--task routing --num-envs 16", "--task"),
    ("--num-envs 16", "--num-envs"),
    ("--threads 2", "--threads"),
    ("--warmup 1", "--warmup"),
    ("--full-info", "--full-info"),
    ("--out bench", "--out"),
    ("--suite robots --wire fem", "--wire"),
    ("--suite robots --task routing", "--task"),
    ("--suite envs --num-envs 0", "--num-envs"),
    ("--suite envs --num-envs 1,,2", "--num-envs"),
    ("--suite envs --num-envs 100000", "--num-envs"),
    ("--suite envs --num-envs abc", "--num-envs"),
    ("--suite envs --threads 0", "--threads"),
    ("--suite envs --warmup -1", "--warmup"),
    ("--suite envs --warmup inf", "--warmup"),
    ("--suite envs --task knitting", "knitting"),
    ("--suite envs --wire spaghetti", "spaghetti"),
    ("--suite envs --out file", "--out"),
    ("--suite envs --out file/sub", "--out"),
    ("--wire spaghetti", "spaghetti"),
    ("--wire", "--wire"),
    ("--json dir", "--json"),
    ("--json file/x.json", "--json"),
]

DEMO = [
    ("--seconds 0", "--seconds"),
    ("--seconds -1", "--seconds"),
    ("--seconds inf", "--seconds"),
    ("--seconds nan", "--seconds"),
    ("--seconds 1e6", "--seconds"),
    ("--out file", "--out"),
    ("--out file/sub", "--out"),
    ("--out ro/sub", "--out", "ro"),
    ("--json dir", "--json"),
]

COLLECT = [
    ("--out ds --episodes 0", "--episodes"),
    ("--out ds --episodes -1", "--episodes"),
    ("--out ds --episodes 1.5", "--episodes"),
    ("--out ds --workers -1", "--workers"),
    ("--out ds --workers many", "--workers"),
    ("--out ds --fps 0", "--fps"),
    ("--out ds --fps 7", "fps"),
    ("--out ds --fps 120", "--fps"),
    ("--out ds --seed -1", "--seed"),
    ("--out ds --success-hold -1", "--success-hold"),
    ("--out ds --success-hold nan", "--success-hold"),
    ("--out ds --success-hold inf", "--success-hold"),
    ("--out ds --vcodec mpeg2", "--vcodec"),
    ("--out ds --commit-every 0", "--commit-every"),
    ("--out ds --max-attempts 0", "--max-attempts"),
    ("--out ds --image-size 2000", "--image-size"),
    ("--out ds --image-size 8", "--image-size"),
    ("--out ds --image-size big", "--image-size"),
    ("--out ds --resume", "--resume"),
    ("--out dir --resume", "--resume"),
    ("--out full", "--out"),
    ("--out file", "--out"),
    ("--out file/ds", "--out"),
    ("--out ro/ds", "--out", "ro"),
    ("--out ds --json dir", "--json"),
    ("--out ds --json file/x.json", "--json"),
    ("--out ds --ray nosuchhost.invalid:1", "--ray"),
    ("--out ds --ray 127.0.0.1:1", "--ray"),
    ("--out ds --ray 127.0.0.1:99999", "--ray"),
    ("--out ds --ray somewhere", "--ray"),
    ("--out ds --ray auto --workers 3", "--workers"),
    ("--out ds --task knitting", "--task"),
    ("--out ds --task routing --clearance 0.01", "--clearance"),
    ("--out ds --num-clips 2", "--num-clips"),
    ("--out ds --task seating --connector usb_c", "--connector"),
    ("--out ds --channel curved", "--channel"),
    ("--out ds --robot r2d2", "--robot"),
    ("--out ds --wire spaghetti", "--wire"),
    ("--out ds --control telepathy", "--control"),
    ("--out ds --control joint", "control"),
    ("--out ds --connector hdmi", "--connector"),
    ("--out ds --clearance nan", "--clearance"),
    ("--out ds --clearance -0.001", "--clearance"),
    ("--out ds --task routing --num-clips 0", "--num-clips"),
    ("--out ds --task routing --clip-opening 0", "--clip-opening"),
    ("--out ds --task seating --channel zigzag", "--channel"),
]

TRAIN = [
    ("dqn --out r", "algorithm"),
    ("ppo --out r --num-envs 0", "--num-envs"),
    ("sacfd --out r --num-envs 1000000", "--num-envs"),
    ("ppo --out r --num-envs abc", "--num-envs"),
    ("ppo --out r --steps 0", "--steps"),
    ("ppo --out r --steps -5", "--steps"),
    ("ppo --out r --steps lots", "--steps"),
    ("ppo --out r --steps 1.5", "--steps"),
    ("ppo --out r --steps inf", "--steps"),
    ("ppo --out r --steps nan", "--steps"),
    ("ppo --out r --seed -1", "--seed"),
    ("ppo --out r --threads -1", "--threads"),
    ("ppo --out r --episode-seconds 0", "--episode-seconds"),
    ("ppo --out r --episode-seconds inf", "--episode-seconds"),
    ("ppo --out r --episode-seconds nan", "--episode-seconds"),
    ("ppo --out r --resume", "--resume"),
    ("ppo --out dir --resume", "--resume"),
    ("ppo --out run", "--resume"),
    ("ppo --out run --resume --task routing", "--task"),
    ("ppo --out run --resume --robot panda", "--robot"),
    ("ppo --out run --resume --episode-seconds 4", "--episode-seconds"),
    ("ppo --out full", "full"),
    ("ppo --out r --set bogus=1", "bogus"),
    ("ppo --out r --set num_envs", "--set"),
    ("ppo --out r --set learning_rate=abc", "learning_rate"),
    ("ppo --out r --set num_envs=0", "num_envs"),
    ("ppo --out file", "--out"),
    ("ppo --out file/r", "--out"),
    ("ppo --out ro/r", "--out", "ro"),
    ("ppo --out r --json dir", "--json"),
    ("ppo --out r --task knitting", "--task"),
    ("ppo --out r --task routing --clearance 0.001", "--clearance"),
    ("ppo --out r --robot r2d2", "--robot"),
    ("ppo --out r --image-size 4000", "--image-size"),
]

EVAL = [
    ("--seeds 0", "--seeds"),
    ("--seeds -1", "--seeds"),
    ("--seeds four", "--seeds"),
    ("--episodes 0", "--episodes"),
    ("--seed -1", "--seed"),
    ("--episode-seconds 0", "--episode-seconds"),
    ("--episode-seconds -1", "--episode-seconds"),
    ("--episode-seconds inf", "--episode-seconds"),
    ("--episode-seconds nan", "--episode-seconds"),
    ("--episode-steps 0", "--episode-steps"),
    ("--episode-steps 1.5", "--episode-steps"),
    ("--episode-steps 800 --episode-seconds 8", "--episode-seconds"),
    ("--retain-force -1", "--retain-force"),
    ("--retain-force nan", "--retain-force"),
    ("--retain-force inf", "--retain-force"),
    ("--task routing --retain-force 5", "--retain-force"),
    ("--task seating --retain-force 1", "--retain-force"),
    ("--workers 0", "--workers"),
    ("--workers 2 --ray local", "--ray"),
    ("--ray nosuchhost.invalid:1", "--ray"),
    ("--ray 127.0.0.1:1", "--ray"),
    ("--batch 0", "--batch"),
    ("--batch 1e9", "--batch"),
    ("--json dir", "--json"),
    ("--json file/x.json", "--json"),
    ("--traces x.csv", "--traces"),
    ("--traces dir.parquet", "--traces"),
    ("--traces file/x.parquet", "--traces"),
    ("--video file", "--video"),
    ("--video file/v", "--video"),
    ("--report file", "--report"),
    ("--report ro/r", "--report", "ro"),
    ("--video-episodes 0:0", "--video-episodes"),
    ("--video v --video-episodes 9:9", "--video-episodes"),
    ("--video v --video-episodes first", "--video-episodes"),
    ("--device cuda", "--device"),
    ("--policy random --device cuda", "--device"),
    ("--policy nosuch", "--policy"),
    ("--task knitting", "--task"),
    ("--robot r2d2", "--robot"),
    ("--task routing --clearance 0.001", "--clearance"),
    ("--task routing --num-clips 0", "--num-clips"),
    ("--task insertion --clip-opening 0.01", "--clip-opening"),
]


@pytest.mark.parametrize(("argv", "flag"), cases("list", LIST))
def test_list_bad_input(place, capsys, argv, flag):
    refused(place, capsys, argv, flag)


@pytest.mark.parametrize(("argv", "flag"), cases("view", VIEW))
def test_view_bad_input(place, capsys, argv, flag):
    refused(place, capsys, argv, flag)


@pytest.mark.parametrize(("argv", "flag"), cases("export-stl", EXPORT))
def test_export_stl_bad_input(place, capsys, argv, flag):
    refused(place, capsys, argv, flag)


@pytest.mark.parametrize(("argv", "flag"), cases("bench", BENCH))
def test_bench_bad_input(place, capsys, argv, flag):
    refused(place, capsys, argv, flag)


@pytest.mark.parametrize(("argv", "flag"), cases("demo", DEMO))
def test_demo_bad_input(place, capsys, argv, flag):
    refused(place, capsys, argv, flag)


@pytest.mark.parametrize(("argv", "flag"), cases("collect", COLLECT))
def test_collect_bad_input(place, capsys, argv, flag):
    refused(place, capsys, argv, flag)


@pytest.mark.parametrize(("argv", "flag"), cases("train", TRAIN))
def test_train_bad_input(place, capsys, argv, flag):
    refused(place, capsys, argv, flag)


@pytest.mark.parametrize(("argv", "flag"), cases("eval", EVAL))
def test_eval_bad_input(place, capsys, argv, flag):
    refused(place, capsys, argv, flag)


def test_unknown_command_and_missing_arguments(capsys):
    assert main(["knit"]) == 2
    assert main(["collect"]) == 2
    assert "--out" in capsys.readouterr().err


def test_failed_collect_start_leaves_nothing(tmp_path, monkeypatch, capsys):
    import importlib

    collect = importlib.import_module("wirecraft.datasets.collect")

    def broken(settings, attempts, slots):
        raise RuntimeError("renderer failed")

    monkeypatch.setattr(collect, "run_episodes", broken)
    out = tmp_path / "ds"
    argv = ["collect", "--out", str(out), "--episodes", "1", "--workers", "0"]
    assert main(argv) == 2
    assert "renderer failed" in capsys.readouterr().err
    assert not out.exists()


def test_failed_train_start_leaves_nothing(tmp_path, monkeypatch):
    import importlib

    train = importlib.import_module("wirecraft.rl.training")

    def broken(*args):
        raise RuntimeError("out of memory")

    monkeypatch.setattr(train, "_train_ppo_family", broken)
    monkeypatch.setattr(train, "_probe_spaces", lambda task, kw: {"obs": {}, "action_dim": 7})
    out = tmp_path / "run"
    with pytest.raises(RuntimeError, match="out of memory"):
        train.train("ppo", "insertion", {}, out, steps=10)
    assert not out.exists()
    out.mkdir()
    with pytest.raises(RuntimeError, match="out of memory"):
        train.train("ppo", "insertion", {}, out, steps=10)
    assert out.is_dir() and not any(out.iterdir())


def test_incomplete_dataset_names_resume(tmp_path):
    from wirecraft.datasets.writer import COMMIT_FILE, load_dataset

    with pytest.raises(ValueError, match="no LeRobot dataset"):
        load_dataset(tmp_path)
    (tmp_path / COMMIT_FILE).parent.mkdir(parents=True)
    (tmp_path / COMMIT_FILE).write_text(json.dumps({"format": 1, "files": {}}))
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "file-000.parquet").write_bytes(b"PAR1")
    with pytest.raises(ValueError, match="--resume"):
        load_dataset(tmp_path)


def test_results_are_written_atomically(tmp_path):
    from wirecraft.cli_args import atomic_path, write_json

    path = tmp_path / "r.json"
    write_json(path, {"a": 1})
    with pytest.raises(RuntimeError), atomic_path(path) as tmp:
        tmp.write_text("{half")
        raise RuntimeError
    assert json.loads(path.read_text()) == {"a": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]


WARN = (
    "import mujoco\n"
    "m = mujoco.MjModel.from_xml_string(\n"
    "    '<mujoco><worldbody><body><freejoint/><geom size=\"0.1\"/></body></worldbody></mujoco>')\n"
    "d = mujoco.MjData(m)\n"
    "d.qpos[0] = float('nan')\n"
    "mujoco.mj_step(m, d)\n"
)


@pytest.mark.parametrize("hooked", [False, True])
def test_mujoco_warnings_write_no_log_file(tmp_path, hooked):
    code = ("import wirecraft\n" if hooked else "") + WARN
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "MUJOCO_LOG.TXT").exists() != hooked
    if hooked:
        assert "Nan, Inf or huge value in QPOS" in result.stderr


def test_a_video_is_published_only_when_complete(tmp_path):
    from wirecraft.mp4 import VideoWriter, write_mp4

    frames = np.zeros((3, 16, 16, 3), np.uint8)
    assert write_mp4(frames, tmp_path / "ok.mp4", 10).stat().st_size > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ok.mp4"]
    writer = VideoWriter(tmp_path / "broken.mp4", 16, 16, 10)
    writer.add(frames[0])
    assert not (tmp_path / "broken.mp4").exists()  # frames go to broken.mp4.partial
    writer.discard()
    with pytest.raises(ValueError):
        write_mp4(np.zeros((2, 16, 16)), tmp_path / "bad.mp4", 10)  # not RGB
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ok.mp4"]
