"""``wirecraft train act|diffusion`` (LeRobot's training on a ``wirecraft collect`` dataset) and
``wirecraft eval --policy RUN --checkpoints ...`` (checkpoint sweeps), end to end on the CPU:

- a tiny ACT trains 2 steps (checkpoint every 2), ``--resume`` continues it to 4 (LeRobot's
  resume: the step grows, nothing restarts), the run records its provenance;
- the policy reads ``observation.state`` and both cameras only, the in-training environment
  matches the dataset (image size, frame rate, task options), no pretrained weights;
- the sweep gives one row per checkpoint, and both selection methods pick one;
- bad input exits 2 naming the flag and leaves nothing behind;
- a tiny Diffusion Policy trains 2 steps.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("lerobot", reason="LeRobot is not installed (pip install 'wirecraft[il]')")
if importlib.util.find_spec("accelerate") is None:
    pytest.skip(
        "lerobot-train needs accelerate: pip install 'wirecraft[il]'", allow_module_level=True
    )

from wirecraft.cli import main  # noqa: E402

SIZE, FPS, SEED = 32, 10, 7
BIN = Path(sys.executable).parent
TINY_ACT = [
    "dim_model=32",
    "n_heads=2",
    "dim_feedforward=64",
    "n_encoder_layers=1",
    "n_decoder_layers=1",
    "chunk_size=5",
    "n_action_steps=5",
    "use_vae=false",
]
QUICK = ["save_freq=2", "log_freq=1", "num_workers=0", "env_eval_freq=0"]


def _run(args, cwd, timeout=300, ok=True) -> subprocess.CompletedProcess:
    env = dict(os.environ, HF_HUB_OFFLINE="1", HF_DATASETS_OFFLINE="1", WANDB_MODE="disabled")
    proc = subprocess.run(
        [str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )
    if ok:
        assert proc.returncode == 0, (
            f"{args[:3]} exited {proc.returncode}:\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}"
        )
    return proc


def _flags(name: str, values: list[str]) -> list[str]:
    return [x for v in values for x in (name, v)]


@pytest.fixture(scope="module")
def dataset(quick_dataset):
    """Two scripted insertion episodes written by ``wirecraft collect`` (conftest)."""
    return quick_dataset


def _train_act(dataset, out, *extra):
    return _run(
        [
            BIN / "wirecraft", "train", "act", "--dataset", dataset, "--out", out,
            "--device", "cpu", "--steps", "2", "--batch-size", "4",
            *_flags("--policy-arg", TINY_ACT), *_flags("--train-arg", QUICK), *extra,
        ],
        cwd=dataset.parent,
    )  # fmt: skip


@pytest.fixture(scope="module")
def run(dataset):
    """A tiny ACT: 2 steps, then resumed to 4 (checkpoints at 2 and 4)."""
    out = dataset.parent / "act"
    first = _train_act(dataset, out)
    step_2 = json.loads(
        (out / "checkpoints" / "last" / "pretrained_model" / "config.json").read_text()
    )
    resumed = _run(
        [
            BIN / "wirecraft",
            "train",
            "act",
            "--out",
            out,
            "--resume",
            "--steps",
            "4",
            "--torch-threads",
            "1",
        ],
        cwd=dataset.parent,
    )
    return out, first.stdout + first.stderr, resumed.stdout + resumed.stderr, step_2


def test_act_trains_and_resumes(run):
    out, first, resumed, _ = run
    assert "step:2 " in first
    assert "Resuming" in resumed and "step:3 " in resumed and "step:4 " in resumed
    assert "step:1 " not in resumed  # continued, not restarted
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["000002", "000004", "last"]
    state = json.loads((out / "checkpoints/last/training_state/training_step.json").read_text())
    assert state["step"] == 4


def test_the_policy_and_environment_match_the_dataset(run, dataset):
    out, _, _, config = run
    assert set(config["input_features"]) == {
        "observation.state",
        "observation.images.cam_side",
        "observation.images.cam_wrist",
    }
    assert config["input_features"]["observation.images.cam_side"]["shape"] == [3, SIZE, SIZE]
    assert config["pretrained_backbone_weights"] is None
    assert config["dim_model"] == 32 and config["chunk_size"] == 5
    assert config["optimizer_lr"] == 1e-5  # the reference's
    train = json.loads((out / "checkpoints/last/pretrained_model/train_config.json").read_text())
    env = train["env"]
    assert env["type"] == "wirecraft_insertion"
    assert (env["image_size"], env["fps"], env["connector"], env["robot"]) == (
        SIZE,
        FPS,
        "ethernet",
        "ur5",
    )
    assert env["clearance"] == pytest.approx(0.003)
    assert Path(train["dataset"]["root"]) == dataset.resolve()


def test_the_run_records_its_provenance(run, dataset):
    out = run[0]
    record = json.loads((out / "wirecraft_il.json").read_text())
    assert record["algorithm"] == "act"
    assert record["dataset"] == str(dataset.resolve())
    assert record["dataset_collect"]["settings"]["fps"] == FPS
    assert record["dataset_provenance"]
    first, second = record["sessions"]
    assert first["command"][:3] == ["wirecraft", "train", "act"]
    assert (first["last_step"], second["resumed_from_step"], second["last_step"]) == (2, 2, 4)
    assert (first["torch_threads"], second["torch_threads"]) == (None, 1)
    assert first["provenance"]["packages"]["lerobot"]


def test_torch_threads_reach_the_training_process(dataset, tmp_path, monkeypatch):
    """``--torch-threads N`` is torch's thread count in lerobot-train's process (torch reads
    OMP_NUM_THREADS at start); without it the variables are left as they are."""
    from wirecraft.il import train as il_train

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    seen = []
    monkeypatch.setattr(il_train, "run_lerobot_train", lambda args, env: seen.append(env) or 0)
    for threads in (1, None):
        il_train.train("act", dataset, tmp_path / f"run{threads}", steps=2, torch_threads=threads)
    assert (seen[0]["OMP_NUM_THREADS"], seen[0]["MKL_NUM_THREADS"]) == ("1", "1")
    assert "OMP_NUM_THREADS" not in seen[1]
    with pytest.raises(ValueError, match="torch_threads: must be an integer >= 1"):
        il_train.train("act", dataset, tmp_path / "bad", torch_threads=0)


def test_eval_sweeps_the_checkpoints(run, tmp_path):
    out = run[0]
    common = ["--episodes", "1", "--seeds", "1", "--episode-seconds", "0.2", "--quiet"]
    result = tmp_path / "sweep.json"
    _run(
        [BIN / "wirecraft", "eval", "--policy", out, "--checkpoints", "all", "--json", result]
        + ["--curve", tmp_path / "curve.png", *common],
        cwd=tmp_path,
    )
    rows = json.loads(result.read_text())["checkpoints"]
    assert [r["step"] for r in rows] == [2, 4]
    from PIL import Image

    assert Image.open(tmp_path / "curve.png").size[0] > 300  # the learning curve
    for r in rows:
        assert set(r["metrics"]) == {"reach_success", "insert_success", "success"}
        assert set(r["metrics"]["success"]) == {"mean", "std"}
    _run(
        [BIN / "wirecraft", "eval", "--policy", out, "--select", "validation", "--seed", "3"]
        + ["--checkpoints", "2,4", "--json", result]
        + common,
        cwd=tmp_path,
    )
    selection = json.loads(result.read_text())["selection"]
    assert selection["method"] == "validation" and selection["chosen_step"] in (2, 4)
    assert selection["score"]["seeds"] == "public"


def _bad(argv, capsys, flag):
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert flag in err, err
    return err


def test_bad_input_is_refused_before_any_work(dataset, tmp_path, capsys):
    out = tmp_path / "run"
    base = ["train", "act", "--out", str(out)]
    _bad(base + ["--dataset", str(tmp_path / "missing")], capsys, "--dataset")
    (tmp_path / "plain").mkdir()
    _bad(base + ["--dataset", str(tmp_path / "plain")], capsys, "--dataset")
    _bad(base, capsys, "--dataset")
    _bad(base + ["--dataset", str(dataset), "--policy-arg", "no_such=1"], capsys, "--policy-arg")
    _bad(base + ["--dataset", str(dataset), "--policy-arg", "dim_model"], capsys, "--policy-arg")
    _bad(base + ["--dataset", str(dataset), "--train-arg", "nope=1"], capsys, "--train-arg")
    _bad(
        base + ["--dataset", str(dataset), "--pretrained", str(tmp_path / "w.pth")],
        capsys,
        "--pretrained",
    )
    _bad(base + ["--dataset", str(dataset), "--num-envs", "4"], capsys, "--num-envs")
    _bad(base + ["--dataset", str(dataset), "--torch-threads", "0"], capsys, "--torch-threads")
    _bad(["train", "ppo", "--out", str(out), "--torch-threads", "1"], capsys, "--torch-threads")
    _bad(["train", "smolvla", "--dataset", str(dataset), "--out", str(out)], capsys, "--pretrained")
    _bad(["train", "pi05", "--dataset", str(dataset), "--out", str(out)], capsys, "--pretrained")
    _bad(base + ["--resume"], capsys, "--resume")
    assert not out.exists()
    _bad(["train", "ppo", "--out", str(out), "--dataset", str(dataset)], capsys, "--dataset")
    out.mkdir()
    _bad(base + ["--dataset", str(dataset)], capsys, "--out")
    _bad(base + ["--resume"], capsys, "--resume")
    assert list(out.iterdir()) == []


def test_bad_sweeps_are_refused(run, tmp_path, capsys):
    out = run[0]
    _bad(["eval", "--policy", str(out), "--checkpoints", "7"], capsys, "--checkpoints")
    _bad(["eval", "--policy", str(out), "--select", "validation"], capsys, "--seed")
    _bad(["eval", "--policy", "scripted", "--checkpoints", "all"], capsys, "--checkpoints")
    _bad(["eval", "--policy", "scripted", "--curve", "c.png"], capsys, "--curve")
    _bad(["eval", "--policy", str(out), "--label", "x"], capsys, "--label")


def test_resume_needs_a_larger_step_count(run, capsys):
    _bad(["train", "act", "--out", str(run[0]), "--resume", "--steps", "4"], capsys, "--steps")


def test_diffusion_trains(dataset):
    if importlib.util.find_spec("diffusers") is None:
        pytest.skip("Diffusion Policy needs diffusers: pip install 'wirecraft[il]'")
    out = dataset.parent / "diffusion"
    tiny = [
        "down_dims=[16,32]",
        "horizon=8",
        "n_action_steps=4",
        "drop_n_last_frames=3",
        "diffusion_step_embed_dim=16",
        "spatial_softmax_num_keypoints=8",
        "num_inference_steps=2",
    ]
    proc = _run(
        [
            BIN / "wirecraft", "train", "diffusion", "--dataset", dataset, "--out", out,
            "--device", "cpu", "--steps", "2", "--batch-size", "2",
            *_flags("--policy-arg", tiny), *_flags("--train-arg", QUICK),
        ],
        cwd=dataset.parent,
    )  # fmt: skip
    assert "step:2 " in proc.stdout + proc.stderr
    config = json.loads((out / "checkpoints/last/pretrained_model/config.json").read_text())
    assert config["type"] == "diffusion" and config["n_obs_steps"] == 2
    assert config["pretrained_backbone_weights"] is None
