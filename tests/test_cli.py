"""The ``wirecraft`` program: sub-commands, machine-readable output, clear errors."""

from __future__ import annotations

import json
import subprocess
import sys

import mujoco
import numpy as np
import pytest
from PIL import Image

from wirecraft.assets.connectors import CONNECTORS
from wirecraft.assets.wires import WIRE_MODELS
from wirecraft.cli import COMMANDS, main
from wirecraft.golden import golden_file_sha256


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "wirecraft.cli", *args], capture_output=True, text=True, timeout=300
    )


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_subcommand_has_help(name):
    result = run_cli(name, "--help")
    assert result.returncode == 0 and "usage: wirecraft" in result.stdout


def test_required_subcommands_exist():
    assert {"bench", "demo", "list", "view", "export-stl"} <= set(COMMANDS)


def test_list_json_names_every_registered_asset(tmp_path, capsys):
    path = tmp_path / "list.json"
    assert main(["list", "--json", str(path)]) == 0
    listing = json.loads(path.read_text())
    assert set(listing["connectors"]) == set(CONNECTORS.names())
    assert listing["wire_models"] == WIRE_MODELS.names()
    assert "displayport_port" in listing["parts"]
    assert "ethernet" in capsys.readouterr().out


@pytest.mark.parametrize("scene", ["wires", "connectors", "fixtures"])
def test_headless_view_renders_the_scene(scene, tmp_path):
    out = tmp_path / f"{scene}.png"
    assert (
        main(
            [
                "view",
                "--scene",
                scene,
                "--headless",
                "--out",
                str(out),
                "--settle",
                "0.1",
                "--width",
                "320",
                "--height",
                "240",
            ]
        )
        == 0
    )
    image = np.asarray(Image.open(out))
    assert image.shape == (240, 320, 3)
    assert image.std() > 10  # a scene, not a blank frame


def test_view_unknown_scene_is_a_clear_error(capsys):
    assert main(["view", "--scene", "garage", "--headless"]) == 2
    err = capsys.readouterr().err
    assert "unknown scene 'garage'" in err and "wires" in err


def test_export_stl_bad_input_writes_nothing(tmp_path, capsys):
    out = tmp_path / "x.stl"
    assert main(["export-stl", "--part", "hdmi_port", "--out", str(out)]) == 2
    assert "valid:" in capsys.readouterr().err
    assert (
        main(["export-stl", "--part", "cuboid_port", "--clearance", "-0.001", "--out", str(out)])
        == 2
    )
    assert "clearance" in capsys.readouterr().err
    assert not out.exists()


def test_export_stl_all_parts(tmp_path):
    assert main(["export-stl", "--all", "--out", str(tmp_path)]) == 0
    assert len(list(tmp_path.glob("*.stl"))) >= 2 * len(CONNECTORS) + 4


def test_demo_writes_strip_and_summary(tmp_path):
    assert main(["demo", "--out", str(tmp_path), "--seconds", "0.4"]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    rows, tasks = summary["rows"], summary["tasks"]
    assert [r["wire"] for r in rows] == WIRE_MODELS.names()
    assert [t["task"] for t in tasks] == ["insertion", "routing", "seating"]
    assert not any(r["diverged"] for r in rows + tasks)
    assert all(t["control_steps_per_s"] > 0 for t in tasks)
    for name, count in (("wires.png", len(rows)), ("tasks.png", len(tasks))):
        strip = np.asarray(Image.open(tmp_path / name))
        assert strip.shape[0] == 240 * count and strip.std() > 10
    import av

    for t in tasks:  # a side-camera video per task: as many frames as 30 fps of its steps
        with av.open(str(tmp_path / t["video"])) as container:
            frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
        assert len(frames) == t["control_steps"] // 2 + 1
        assert frames[0].shape == (240, 240, 3)
        assert np.abs(frames[-1].astype(int) - frames[0]).mean() > 1  # the robot moved
    table = (tmp_path / "summary.md").read_text()
    assert all(f"| {t['task']} |" in table for t in tasks)


def test_demo_rejects_non_positive_duration(capsys):
    assert main(["demo", "--seconds", "0"]) == 2
    assert "--seconds" in capsys.readouterr().err


def test_bench_json_rows(tmp_path):
    path = tmp_path / "bench.json"
    assert main(["bench", "--wire", "articulated", "--seconds", "0.05", "--json", str(path)]) == 0
    written = json.loads(path.read_text())
    (row,) = written["rows"]
    assert row["wire"] == "articulated" and row["physics_steps_per_s"] > 0
    assert written["suite"] == "wires"
    assert written["provenance"]["packages"]["mujoco"] == mujoco.__version__
    assert written["provenance"]["golden_sha256"] == golden_file_sha256()
    assert row["realtime_factor"] == pytest.approx(row["physics_steps_per_s"] * 0.002, rel=0.01)


def test_bench_unknown_wire_is_a_clear_error(capsys):
    assert main(["bench", "--wire", "spaghetti", "--seconds", "0.05"]) == 2
    assert "unknown wire model 'spaghetti'" in capsys.readouterr().err


def test_bench_envs_rows_csv_and_plot(tmp_path):
    path = tmp_path / "rows.json"
    assert (
        main(
            [
                "bench",
                "--suite",
                "envs",
                "--num-envs",
                "2",
                "--threads",
                "1",
                "--seconds",
                "0.2",
                "--warmup",
                "0.05",
                "--out",
                str(tmp_path),
                "--json",
                str(path),
            ]
        )
        == 0
    )
    (row,) = json.loads(path.read_text())["rows"]
    for key in (
        "task",
        "wire",
        "num_envs",
        "threads",
        "control_steps_per_s",
        "physics_steps_per_s",
        "realtime_factor",
        "overhead_ratio",
    ):
        assert key in row
    assert row["physics_steps_per_s"] == pytest.approx(8 * row["control_steps_per_s"], rel=1e-3)
    assert row["overhead_ratio"] > 1.0  # the environment does more than the raw physics
    header = (tmp_path / "bench_envs.csv").read_text().splitlines()[0]
    assert header.startswith("task,options,info,wire,backend,device,num_envs")
    assert row["backend"] == "cpu" and row["bytes_per_step"] == 0
    assert np.asarray(Image.open(tmp_path / "bench_envs.png")).std() > 10


def test_bench_envs_bad_lists_are_clear_errors(capsys):
    assert main(["bench", "--suite", "envs", "--num-envs", "0"]) == 2
    assert "--num-envs" in capsys.readouterr().err
    assert main(["bench", "--suite", "envs", "--task", "knitting"]) == 2
    assert "unknown task 'knitting'" in capsys.readouterr().err
    assert main(["bench", "--suite", "envs", "--backend", "warp", "--threads", "2"]) == 2
    assert "--threads: applies only with --backend cpu" in capsys.readouterr().err
    assert main(["bench", "--suite", "envs", "--device", "cuda:0"]) == 2
    assert "--device: applies only with --backend warp" in capsys.readouterr().err
    assert main(["bench", "--suite", "wires", "--backend", "warp"]) == 2


def test_bench_envs_reports_a_case_whose_reset_keeps_diverging_and_goes_on(tmp_path, monkeypatch):
    from wirecraft.bench import envs
    from wirecraft.envs.env import ResetDiverged

    real = envs.measure

    def measure(task, wire, num_envs, *args):
        if num_envs == 2:
            raise ResetDiverged("the scene diverged while settling at reset, 3 times in a row")
        return real(task, wire, num_envs, *args)

    monkeypatch.setattr(envs, "measure", measure)
    path = tmp_path / "rows.json"
    argv = ["bench", "--suite", "envs", "--num-envs", "1,2", "--threads", "1", "--seconds"]
    argv += ["0.1", "--warmup", "0", "--out", str(tmp_path), "--json", str(path)]
    assert main(argv) == 0
    document = json.loads(path.read_text())
    assert [r["num_envs"] for r in document["rows"]] == [1]
    assert [r["num_envs"] for r in document["not_measured"]] == [2]
    assert "diverged" in document["not_measured"][0]["error"]
