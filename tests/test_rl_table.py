"""``benchmarks/rl_table.py``: shipped folders grouped into cells, aggregated across training
seeds as ``aggregate_runs`` does (mean and population std of the runs' means)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from wirecraft.rl import RUN_FILE

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def rl_table(load_benchmark):
    return load_benchmark("rl_table")


def shipped_copy(source: Path, out: Path, seed: int, insert: float, selection=None) -> None:
    shutil.copytree(source, out)
    record = json.loads((out / RUN_FILE).read_text())
    record["config"]["seed"] = seed
    if selection is not None:
        record["shipped"]["selection"] = selection
    for evaluation in record["shipped"]["evaluations"]:
        evaluation["insert_success"]["mean"] = insert
    (out / RUN_FILE).write_text(json.dumps(record))


def test_training_seeds_of_a_cell_are_one_row(rl_table, tmp_path):
    source = ROOT / "checkpoints" / "ppo_insertion_cylinder_seed0"
    shipped_copy(source, tmp_path / "a", 0, 0.9)
    chosen = {"method": "validation", "validation_seed": 1, "ranked_by": "success"}
    chosen.update(chosen=35, candidates={"30": 0.5, "35": 1.0, "39": 0.75})
    shipped_copy(source, tmp_path / "b", 1, 1.0, selection=chosen)
    shipped_copy(ROOT / "checkpoints" / "ppo_insertion_cuboid_seed0", tmp_path / "c", 0, 0.75)
    readme = tmp_path / "README.md"
    readme.write_text("intro\n<!-- rl-table -->\nold\n<!-- /rl-table -->\nend\n")
    assert rl_table.main(["--checkpoints", str(tmp_path), "--readme", str(readme)]) == 0
    rows = [line for line in readme.read_text().splitlines() if line.startswith("| insertion")]
    assert len(rows) == 2
    cylinder = next(r for r in rows if "connector=cylinder" in r)
    # mean 0.95, population std 0.05 of the two runs' means, on both seed lists
    assert "| 0, 1 | last (seed 0); best of 3 on --seed 1 (seed 1) |" in cylinder
    assert cylinder.count("95.0 +/- 5.0 %") == 2
    assert "93.8 %" in cylinder  # the reference's figure for the cell
    cuboid = next(r for r in rows if "connector=cuboid" in r)
    assert "| 0 | last |" in cuboid
    assert cuboid.count("75.0 %") == 2
    assert "old" not in readme.read_text() and readme.read_text().endswith("end\n")


def test_each_algorithm_is_its_own_cell_with_its_own_reference(rl_table, tmp_path):
    source = ROOT / "checkpoints" / "ppo_insertion_ethernet_seed0"
    shipped_copy(source, tmp_path / "ppo", 0, 0.9)
    shipped_copy(source, tmp_path / "sac", 0, 0.8)
    record = json.loads((tmp_path / "sac" / RUN_FILE).read_text())
    record["algorithm"] = "sacfd"
    record["config"] = {"seed": 0, "demo_expert": "reactive", "bc_states": "replay"}
    record["config"].update(learn_entropy=False, initial_alpha=0.001, max_log_std=-3.0)
    (tmp_path / "sac" / RUN_FILE).write_text(json.dumps(record))
    readme = tmp_path / "README.md"
    readme.write_text("<!-- rl-table -->\n<!-- /rl-table -->\n")
    assert rl_table.main(["--checkpoints", str(tmp_path), "--readme", str(readme)]) == 0
    rows = [line for line in readme.read_text().splitlines() if line.startswith("| insertion")]
    (ppo,) = [r for r in rows if "| PPO" in r]
    (sac,) = [r for r in rows if "| SACfD" in r]
    assert "95.9 %" in ppo and "90.0 %" in ppo
    assert (
        "| SACfD + memoryless expert's demonstrations, BC on relabelled replay, "
        "fixed temperature 0.001, log std <= -3.0 |" in sac
    )
    assert "92.4 %" in sac and "80.0 %" in sac


def test_bad_input_is_a_clear_error(rl_table, tmp_path, capsys):
    with pytest.raises(SystemExit):
        rl_table.main(["--checkpoints", str(tmp_path)])
    assert "no shipped policy" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        rl_table.main(["--workers", "2"])
    assert "--workers applies only with --evaluate" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        rl_table.main(["--curves", str(tmp_path / "curves.txt")])
    assert "--curves writes a PNG" in capsys.readouterr().err
    assert not (tmp_path / "curves.txt").exists()


def test_curves_plot_each_folder_with_a_learning_curve(rl_table, tmp_path, capsys):
    import matplotlib.image

    from wirecraft.rl.common import PROGRESS_FILE, ProgressTable

    root = tmp_path / "checkpoints"
    shipped_copy(ROOT / "checkpoints" / "ppo_insertion_cylinder_seed0", root / "a", 0, 0.9)
    shipped_copy(ROOT / "checkpoints" / "ppo_insertion_cylinder_seed0", root / "b", 1, 1.0)
    (root / "a" / PROGRESS_FILE).unlink(missing_ok=True)
    (root / "b" / PROGRESS_FILE).unlink(missing_ok=True)
    png = tmp_path / "curves.png"
    with pytest.raises(SystemExit):
        rl_table.main(["--checkpoints", str(root), "--curves", str(png)])
    assert "no shipped folder has a progress.csv" in capsys.readouterr().err
    assert not png.exists()

    table = ProgressTable(root / "b" / PROGRESS_FILE)
    for iteration in range(3):
        table.append(
            {
                "iteration": iteration,
                "env_steps": 32768.0 * (iteration + 1),
                "mean_insert_success": 0.3 * iteration,
            }
        )
    assert rl_table.main(["--checkpoints", str(root), "--curves", str(png)]) == 0
    out = capsys.readouterr().out
    assert f"no {PROGRESS_FILE} in {root / 'a'}" in out
    assert f"no {PROGRESS_FILE} in {root / 'b'}" not in out
    height, width, _ = matplotlib.image.imread(png).shape
    assert width > 300 and height > 300


def test_a_seating_cell_is_judged_and_drawn_by_its_success_flag(rl_table, tmp_path, monkeypatch):
    """Every task's progress.csv has a column per flag (seating's insert column is all zero):
    the table and the curve read the cell's own flag."""
    import matplotlib.axes

    root = tmp_path / "checkpoints"
    shutil.copytree(ROOT / "checkpoints" / "ppo_seating_straight_seed0", root / "s")
    grouped = rl_table.cells(root, evaluate=False, workers=1)
    ((_, runs),) = grouped.items()
    assert rl_table.headline_metric(runs[0][2]) == "success"
    drawn = []
    plot = matplotlib.axes.Axes.plot
    monkeypatch.setattr(
        matplotlib.axes.Axes, "plot", lambda ax, x, y, **kw: drawn.append(y) or plot(ax, x, y, **kw)
    )
    assert rl_table.plot_curves(grouped, tmp_path / "curves.png") == []
    (curve,) = drawn
    assert min(curve) > 50  # the training episodes' success (%), not the zero insert column


def clearance_copy(out: Path, clearance: float, seed: int, insert: float) -> None:
    """A shipped folder as if trained at ``clearance`` (its variant and its env keywords)."""
    shipped_copy(ROOT / "checkpoints" / "ppo_insertion_ethernet_seed0", out, seed, insert)
    record = json.loads((out / RUN_FILE).read_text())
    record["env_kwargs"]["clearance"] = clearance
    for evaluation in record["shipped"]["evaluations"]:
        evaluation["variant"] = f"insertion/clearance={clearance!r}/connector=ethernet"
    (out / RUN_FILE).write_text(json.dumps(record))


def test_a_sweep_lines_up_the_cells_that_differ_in_one_option(rl_table, tmp_path, capsys):
    import matplotlib.image

    root = tmp_path / "checkpoints"
    clearance_copy(root / "a", 0.001, 0, 0.5)
    clearance_copy(root / "b", 0.001, 1, 0.7)
    clearance_copy(root / "c", 0.003, 0, 1.0)
    shipped_copy(ROOT / "checkpoints" / "ppo_insertion_cuboid_seed0", root / "d", 0, 0.25)
    expert = {
        "variant": "insertion/clearance=0.001/connector=ethernet",
        "label": "reactive",
        "env_kwargs": {"connector": "ethernet", "clearance": 0.001},
        "protocol": {"held_out_seed": None},
        "metrics": {"insert_success": {"mean": 0.875, "std": 0.125}},
    }
    expert_json = tmp_path / "expert.json"
    expert_json.write_text(json.dumps(expert))
    doc, png = tmp_path / "baselines.md", tmp_path / "sweep.png"
    doc.write_text("a\n<!-- sweep:clearance -->\nold\n<!-- /sweep:clearance -->\nb\n")
    argv = ["--checkpoints", str(root), "--sweep", "clearance", "--sweep-with", str(expert_json)]
    assert rl_table.main([*argv, "--sweep-plot", str(png), "--sweep-doc", str(doc)]) == 0
    rows = {
        line.split("|")[1].strip(): line
        for line in doc.read_text().splitlines()
        if line.startswith("| 0.00")
    }
    assert set(rows) == {"0.001", "0.003"}  # the cuboid cell has no second clearance
    # 0.001: two training seeds, mean 0.6, population std 0.1, on both lists; the expert 87.5 %
    assert rows["0.001"].count("60.0 +/- 10.0 % (2 seeds)") == 2
    assert "87.5 +/- 12.5 %" in rows["0.001"]
    # 0.003: one training seed, its own evaluation's spread over the seed groups (2.7 %)
    assert rows["0.003"].count("100.0 +/- 2.7 % (1 seed)") == 2
    assert rows["0.003"].endswith("| - |")
    assert "old" not in doc.read_text()
    height, width, _ = matplotlib.image.imread(png).shape
    assert width > 300 and height > 300

    with pytest.raises(SystemExit):  # an option no cell has, and a sweep of one value
        rl_table.main(["--checkpoints", str(root), "--sweep", "num_clips"])
    assert "no shipped cell has the task option 'num_clips'" in capsys.readouterr().err
    shutil.rmtree(root / "a"), shutil.rmtree(root / "b")
    with pytest.raises(SystemExit):
        rl_table.main(["--checkpoints", str(root), "--sweep", "clearance"])
    assert "no two shipped cells differ only in clearance" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        rl_table.main(["--sweep-plot", str(png)])
    assert "--sweep-plot applies only with --sweep" in capsys.readouterr().err
    expert_json.write_text("{}")
    with pytest.raises(SystemExit):
        rl_table.main([*argv])
    assert "not a `wirecraft eval --json` document" in capsys.readouterr().err
