"""``wirecraft mix``: datasets of several sources merged into one LeRobot dataset, weighted by
repeating episodes (LeRobot 0.6 samples every frame uniformly and has no per-source weights).

- scripted demonstrations (``wirecraft collect``) + RL rollouts (a tiny PPO's, ``source`` rl):
  the output loads with LeRobot's own ``LeRobotDataset``, has each input's episodes ``copies``
  times, its sources per episode, every frame equal to the input's, the recorded shares match
  the weights, ``meta/wirecraft_mix.json`` and ``meta/wirecraft_collect.json`` are written;
- ``wirecraft train act --dataset OUT`` trains a tiny ACT 2 steps on it;
- bad input exits 2 naming the flag, and a failure leaves nothing behind.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("lerobot", reason="LeRobot is not installed (pip install 'wirecraft[data]')")

from wirecraft.cli import main  # noqa: E402
from wirecraft.datasets import mix as mixmod  # noqa: E402
from wirecraft.datasets.schema import SOURCES  # noqa: E402

SIZE, FPS = 32, 10
BIN = Path(sys.executable).parent
ENV = dict(os.environ, HF_HUB_OFFLINE="1", HF_DATASETS_OFFLINE="1", WANDB_MODE="disabled")
# A tiny ACT and quick training options (as in tests/test_il_train.py).
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


def _run(args, cwd, timeout=300) -> subprocess.CompletedProcess:
    proc = subprocess.run(
        [str(a) for a in args], cwd=cwd, env=ENV, capture_output=True, text=True, timeout=timeout
    )
    assert proc.returncode == 0, (
        f"{args[:3]} exited {proc.returncode}:\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}"
    )
    return proc


def _flags(name: str, values: list[str]) -> list[str]:
    return [x for v in values for x in (name, v)]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """(scripted, rl): two scripted insertion episodes and two rollouts of a tiny PPO policy,
    both at 32 x 32 px, 10 fps, ethernet connector."""
    from wirecraft.rl import train
    from wirecraft.rl.record import record_rollouts

    work = tmp_path_factory.mktemp("mix")
    scripted = work / "scripted"
    _run(
        [
            BIN / "wirecraft", "collect", "--task", "insertion", "--connector", "ethernet",
            "--episodes", "2", "--out", scripted, "--image-size", SIZE, "--fps", FPS,
            "--seed", "7", "--workers", "0",
        ],
        cwd=work,
    )  # fmt: skip
    tiny = {
        "num_envs": 3,
        "num_steps_per_env": 8,
        "actor_hidden_dims": (16, 8),
        "critic_hidden_dims": (16,),
        "threads": 1,
    }
    env = {"episode_seconds": 0.4, "connector": "ethernet"}
    train("ppo", "insertion", env, work / "ppo", 24, overrides=tiny, progress=False)
    rl = work / "rl"
    record_rollouts(work / "ppo", rl, 2, image_size=SIZE, fps=FPS, progress=False)
    return scripted, rl


@pytest.fixture(scope="module")
def mixed(inputs, tmp_path_factory):
    scripted, rl = inputs
    out = tmp_path_factory.mktemp("mixed") / "out"
    proc = _run(
        [BIN / "wirecraft", "mix", "--input", f"{scripted}:1", "--input", f"{rl}:3", "--out", out],
        cwd=out.parent,
    )
    assert "episodes" in proc.stdout and "copies" in proc.stdout
    return out


def _load(root):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset("wirecraft/local", root=root, video_backend="pyav")


def _frames_equal(a: dict, b: dict) -> None:
    import torch

    for key, value in a.items():
        if key in ("index", "episode_index", "task_index"):
            continue
        if isinstance(value, torch.Tensor):
            assert torch.equal(value, b[key]), key
        else:
            assert value == b[key], key


def test_mix_keeps_sources_and_frames_and_realises_the_weights(inputs, mixed):
    from wirecraft.datasets.collect import episode_sources

    scripted, rl = (_load(p) for p in inputs)
    out = _load(mixed)
    record = json.loads((mixed / mixmod.MIX_FILE).read_text())
    first, second = record["inputs"]
    assert (first["source"], second["source"]) == ("scripted", "rl")
    assert (first["weight"], second["weight"]) == (1.0, 3.0)
    assert first["copies"] == 1  # the input with the most frames per unit of weight
    c = second["copies"]
    # the copies follow from the frame counts: rl gets 3x the scripted share, within 1 point
    frames = [scripted.num_frames, rl.num_frames]
    assert [first["frames"], second["frames"]] == frames
    assert [1, c] == mixmod.plan_copies(frames, [1.0, 3.0])
    share = c * rl.num_frames / (scripted.num_frames + c * rl.num_frames)
    assert math.isclose(second["share"], share) and abs(share - 0.75) <= mixmod.SHARE_TOLERANCE

    # LeRobot's own loader: every episode copied `copies` times, its source kept
    assert out.num_episodes == scripted.num_episodes + c * rl.num_episodes == record["episodes"]
    assert out.num_frames == scripted.num_frames + c * rl.num_frames == record["frames"]
    assert episode_sources(out) == ["scripted"] * 2 + ["rl"] * (2 * c)
    assert record["sources"] == {"scripted": 2, "rl": 2 * c}
    assert second["output_episodes"] == [2, 2 + 2 * c - 1]
    codes = np.asarray(out.hf_dataset["source"]).reshape(-1)
    assert np.bincount(codes, minlength=len(SOURCES)).tolist()[:2] == [
        scripted.num_frames,
        c * rl.num_frames,
    ]

    # frames equal the inputs' (data and decoded video): the scripted input, then the first
    # and the last copy of the rollouts
    for i in range(scripted.num_frames):
        _frames_equal(out[i], scripted[i])
    for copy in (0, c - 1):
        base = scripted.num_frames + copy * rl.num_frames
        for j in range(rl.num_frames):
            _frames_equal(out[base + j], rl[j])

    # metadata: provenance, and the collection settings of the only input that has them
    assert record["provenance"]["packages"]["lerobot"]
    collect = json.loads((mixed / mixmod.COLLECT_FILE).read_text())
    settings = json.loads((inputs[0] / mixmod.COLLECT_FILE).read_text())["settings"]
    assert collect["settings"] == settings and collect["source"] == "mix"
    assert record["collect_settings"] == "kept"
    assert not [p for p in mixed.parent.iterdir() if p.name != "out"]  # no temporary folder


def test_copies_realise_the_weights():
    assert mixmod.plan_copies([100, 100], [3, 1]) == [3, 1]
    assert mixmod.plan_copies([100, 10], [1, 1]) == [1, 10]
    assert mixmod.plan_copies([100, 10], [1, 0.1]) == [1, 1]
    copies = mixmod.plan_copies([97, 8, 30], [1, 1, 2])
    got = mixmod.shares([97, 8, 30], copies)
    assert all(abs(g - t) <= 0.01 for g, t in zip(got, [0.25, 0.25, 0.5], strict=True))
    with pytest.raises(ValueError, match="--max-copies"):
        mixmod.plan_copies([1000, 1], [1, 1], max_copies=10)
    assert mixmod.parse_input("a/b:2.5") == ("a/b", 2.5)
    assert mixmod.parse_input("a/b") == ("a/b", 1.0)


@pytest.mark.skipif(
    importlib.util.find_spec("accelerate") is None, reason="lerobot-train needs accelerate"
)
def test_train_act_reads_the_mixed_dataset(mixed, tmp_path):
    run = tmp_path / "run"
    _run(
        [
            BIN / "wirecraft", "train", "act", "--dataset", mixed, "--out", run,
            "--device", "cpu", "--steps", "2", "--batch-size", "4",
            *_flags("--policy-arg", TINY_ACT), *_flags("--train-arg", QUICK),
        ],
        cwd=tmp_path,
    )  # fmt: skip
    assert (run / "checkpoints" / "000002" / "pretrained_model" / "config.json").is_file()


def _bad(argv, capsys, flag):
    code = main(["mix", *[str(a) for a in argv]])
    err = capsys.readouterr().err
    assert code == 2, err
    assert flag in err, err
    return err


def test_bad_input_exits_2_and_leaves_nothing(inputs, mixed, tmp_path, capsys):
    scripted, rl = inputs
    out = tmp_path / "out"
    _bad(["--input", scripted, "--out", out], capsys, "at least two")
    _bad(["--input", scripted, "--input", tmp_path / "nope", "--out", out], capsys, "--input")
    for weight in ("0", "-1", "nan", "inf", "x"):
        _bad(["--input", scripted, "--input", f"{rl}:{weight}", "--out", out], capsys, "--input")
    _bad(["--input", scripted, "--input", rl, "--out", mixed], capsys, "--out")
    _bad(["--input", scripted, "--input", tmp_path, "--out", out], capsys, "no meta/info.json")
    _bad(["--input", scripted, "--input", rl, "--out", scripted / "x"], capsys, "--out")

    # an input of another shape (a copy whose state has one more entry)
    other = tmp_path / "other"
    shutil.copytree(rl, other)
    info = json.loads((other / "meta/info.json").read_text())
    info["features"]["observation.state"]["shape"] = [8]
    (other / "meta/info.json").write_text(json.dumps(info))
    err = _bad(["--input", scripted, "--input", other, "--out", out], capsys, "observation.state")
    assert "shape" in err
    info["fps"] = 30
    (other / "meta/info.json").write_text(json.dumps(info))
    _bad(["--input", scripted, "--input", other, "--out", out], capsys, "fps")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other"]


def test_a_failed_merge_leaves_nothing(inputs, tmp_path, capsys, monkeypatch):
    import lerobot.datasets.aggregate as aggregate

    def broken(*args, aggr_root, **kwargs):
        Path(aggr_root, "meta").mkdir(parents=True)
        raise OSError("disk full")

    monkeypatch.setattr(aggregate, "aggregate_datasets", broken)
    out = tmp_path / "out"
    _bad(["--input", inputs[0], "--input", inputs[1], "--out", out], capsys, "disk full")
    assert list(tmp_path.iterdir()) == []
