"""Checkpoint sweeps of RL runs (``wirecraft eval --policy RUN --checkpoints/--select``).

The truth: a run made of a shipped cuboid checkpoint that inserts (100 % on the public and
held-out lists) and, saved after it, the same network with its output layer zeroed, which
commands no motion and so never inserts.  Validation selection must pick the working
checkpoint although ties and recency favour the later one; ``--policy RUN`` alone stays the
latest checkpoint; across runs, each run's pick is what enters the mean, and is what
``python -m wirecraft.rl.export --selection`` ships.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from wirecraft.cli import main
from wirecraft.evaluation import sweep as sweep_mod

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "checkpoints" / "ppo_insertion_cuboid_seed2"
TASK = ["--task", "insertion", "--connector", "cuboid"]
FEW = ["--seeds", "1", "--episodes", "2", "--workers", "1", "--quiet"]


def _run_with_a_broken_later_checkpoint(folder: Path) -> Path:
    import torch

    shutil.copytree(SHIPPED, folder)
    good = torch.load(folder / "checkpoints/model_39.pt", weights_only=False)
    for name in ("mlp.6.weight", "mlp.6.bias"):
        good["actor_state_dict"][name].zero_()
    torch.save(good, folder / "checkpoints/model_40.pt")
    run = json.loads((folder / "wirecraft_rl.json").read_text())
    run["checkpoints"] = ["checkpoints/model_39.pt", "checkpoints/model_40.pt"]
    run["latest_checkpoint"] = "checkpoints/model_40.pt"
    (folder / "wirecraft_rl.json").write_text(json.dumps(run))
    return folder


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    pytest.importorskip("rsl_rl")
    return _run_with_a_broken_later_checkpoint(tmp_path_factory.mktemp("rl") / "run")


def test_an_rl_run_lists_its_checkpoints_and_is_swept_only_when_asked(run, tmp_path):
    from wirecraft.rl import run_checkpoints

    found, unit = run_checkpoints(run)
    assert [n for n, _ in found] == [39, 40] and unit == "PPO iterations"
    assert run_checkpoints(run / "checkpoints/model_39.pt") == ([], "")
    assert sweep_mod.swept_run(run, sweep_flags=False) is None
    swept = sweep_mod.swept_run(run, sweep_flags=True)
    assert swept.rank_by == "success" and swept.unit == "PPO iterations"
    (run / "checkpoints/model_40.pt").rename(tmp_path / "gone.pt")  # a listed file removed
    try:
        assert [n for n, _ in run_checkpoints(run)[0]] == [39]
    finally:
        (tmp_path / "gone.pt").rename(run / "checkpoints/model_40.pt")


def test_validation_picks_the_checkpoint_that_inserts(run, tmp_path):
    out = tmp_path / "sweep.json"
    argv = ["eval", *TASK, "--policy", str(run), "--select", "validation", "--seed", "5"]
    assert main([*argv, *FEW, "--json", str(out), "--curve", str(tmp_path / "c.png")]) == 0
    result = json.loads(out.read_text())
    rows = {r["step"]: r["metrics"]["success"]["mean"] for r in result["checkpoints"]}
    assert rows[40] == 0.0 and rows[39] >= 0.5
    selection = result["selection"]
    assert (selection["chosen_step"], selection["ranked_by"]) == (39, "success")
    assert selection["score"]["seeds"] == "public" and selection["score"]["path"].endswith(
        "model_39.pt"
    )
    assert result["step_unit"] == "PPO iterations"
    assert (tmp_path / "c.png").stat().st_size > 0

    # alone, the run is its latest checkpoint: the broken one
    assert main(["eval", *TASK, "--policy", str(run), *FEW, "--json", str(out)]) == 0
    assert json.loads(out.read_text())["metrics"]["success"]["mean"] == 0.0


def test_across_runs_each_runs_pick_enters_the_mean(run, tmp_path):
    second = tmp_path / "second"
    shutil.copytree(run, second)
    (second / "checkpoints/model_40.pt").unlink()  # a run whose only checkpoint works
    out = tmp_path / "across.json"
    argv = ["eval", *TASK, "--policy", str(run), str(second), "--select", "validation"]
    assert main([*argv, "--seed", "5", *FEW, "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    picks = [r["selection"] for r in result["runs"]]
    assert [p["chosen_step"] for p in picks] == [39, 39]
    per_run = [p["score"]["metrics"]["success"]["mean"] for p in picks]
    across = result["across_runs"]["success"]
    assert across["per_run"] == per_run
    assert across["mean"] == pytest.approx(sum(per_run) / 2)

    # the pick is what gets shipped, with the choice in its record
    from wirecraft.rl.export import main as export

    assert export([str(run), "--selection", str(out), "--out", str(tmp_path / "shipped")]) == 0
    record = json.loads((tmp_path / "shipped/wirecraft_rl.json").read_text())
    assert record["latest_checkpoint"] == "checkpoints/model_39.pt"
    chosen = record["shipped"]["selection"]
    assert (chosen["chosen"], chosen["validation_seed"], sorted(chosen["candidates"])) == (
        39,
        5,
        ["39", "40"],
    )
    argv = [str(run), "--selection", str(out), "--checkpoint", "model_40.pt"]
    assert export([*argv, "--out", str(tmp_path / "no")]) == 2  # not the one chosen
    assert export([str(tmp_path), "--selection", str(out), "--out", str(tmp_path / "no")]) == 2
    assert not (tmp_path / "no").exists()


def _refused(argv, capsys, flag):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert flag in err, err


def test_bad_rl_sweeps_are_refused(run, tmp_path, capsys):
    base = ["eval", *TASK, "--policy", str(run)]
    _refused([*base, "--checkpoints", "7"], capsys, "--checkpoints")
    _refused([*base, "--select", "validation"], capsys, "--seed")
    _refused([*base, "--checkpoints", "39", "--video", str(tmp_path / "v")], capsys, "--video")
    checkpoint = str(run / "checkpoints/model_39.pt")
    _refused(
        ["eval", *TASK, "--policy", checkpoint, "--checkpoints", "all"], capsys, "--checkpoints"
    )
    across = ["eval", *TASK, "--policy", str(run), "scripted"]
    _refused([*across, "--select", "validation", "--seed", "1"], capsys, "--select")
    _refused([*across, "--checkpoints", "39"], capsys, "--checkpoints")
    both = ["eval", *TASK, "--policy", str(run), str(run.parent), "--select", "reference"]
    _refused(both, capsys, "--select")  # a folder that is no run
    second = tmp_path / "second"
    shutil.copytree(run, second)
    (second / "checkpoints/model_40.pt").unlink()
    argv = ["eval", *TASK, "--policy", str(run), str(second), "--select", "reference"]
    assert main([*argv, "--checkpoints", "39,40"]) == 2
    out, err = capsys.readouterr()
    assert "--checkpoints" in err and "40" in err, err
    assert out == ""  # refused before the first run was evaluated
    _refused([*across, "--select", "reference", "--curve", "c.png"], capsys, "--curve")
