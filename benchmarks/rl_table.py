"""The RL results table: every policy shipped in ``checkpoints/``, one row per cell (task
variant, robot, wire, recipe), mean +/- std across its training seeds.

    python benchmarks/rl_table.py [--checkpoints checkpoints] [--evaluate --workers 1]
        [--readme README.md] [--curves docs/img/rl_curves.png]

A folder's figures are the evaluations its record keeps (``shipped.evaluations``: the
``wirecraft eval --json`` documents given to ``python -m wirecraft.rl.export``, 4 x 16 public
seeds and the held-out list ``--seed 1000``).  ``--evaluate`` measures them again instead, with
``wirecraft.evaluation.run_evaluation`` on the same lists, and prints where they differ from the
record.  Across the folders of a cell (one per training seed): each folder's mean over its seed
list, then the mean and population std over the folders (``aggregate_runs``, as ``wirecraft eval
--policy A B C``).  ``--readme`` writes the table between ``<!-- rl-table -->`` and
``<!-- /rl-table -->``.  ``--curves`` plots each cell's learning curves, one line per training
seed, from the ``progress.csv`` each folder keeps (training episodes' success at the end of the
episode against env steps; folders without it are named and left out).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from wirecraft.cli_args import number, write_block
from wirecraft.evaluation.protocol import aggregate_runs, run_evaluation
from wirecraft.evaluation.seeds import variant_key
from wirecraft.rl import RUN_FILE
from wirecraft.rl.common import PROGRESS_FILE, ProgressTable

MARKERS = ("<!-- rl-table -->", "<!-- /rl-table -->")
HELD_OUT_SEED = 1000
# The reference's state-PPO figures (SR insert, or SR success where a task has no insert flag),
# by evaluation variant.
REFERENCE = {
    variant_key("insertion", {"connector": "cylinder"}): 0.938,
    variant_key("insertion", {"connector": "cuboid"}): 0.950,
    variant_key("insertion", {"connector": "ethernet"}): 0.959,
    variant_key("insertion", {"connector": "displayport"}): 0.929,
    variant_key("routing", {"num_clips": 1}): 0.953,
    variant_key("seating", {"channel": "straight"}): 0.823,
}


def recipe(config: dict) -> str:
    """Which of the documented recipes (docs/baselines.md) trained the run."""
    if config.get("dagger_init_iterations", 0) > 0:
        inputs = "goal-relative inputs" if config.get("actor_inputs") == "relative" else "state"
        return f"PPO + DAgger warm start ({inputs})"
    return "PPO (SPEC defaults)"


def shipped_folders(root: Path) -> list[Path]:
    return sorted(p.parent for p in root.glob(f"*/{RUN_FILE}"))


def folder_evaluations(folder: Path, record: dict, evaluate: bool, workers: int) -> dict:
    """{"public": metrics, "held_out": metrics} of one shipped folder (None where missing)."""
    stored = {
        "held_out" if e["held_out_seed"] is not None else "public": e
        for e in record["shipped"]["evaluations"]
    }
    if not evaluate:
        return {k: stored.get(k) for k in ("public", "held_out")}
    env_kwargs = {k: v for k, v in record["env_kwargs"].items() if k != "obs_mode"}
    fresh = {}
    for name, seed in (("public", None), ("held_out", HELD_OUT_SEED)):
        payload = run_evaluation(
            record["task"],
            str(folder),
            seeds=4,
            episodes=16,
            seed=seed,
            workers=workers,
            progress=False,
            **env_kwargs,
        ).payload
        fresh[name] = {"variant": payload["variant"], **payload["metrics"]}
        old = stored.get(name)
        for metric in ("reach_success", "insert_success", "success"):
            if old and metric in old and old[metric]["mean"] != fresh[name][metric]["mean"]:
                print(
                    f"{folder.name} {name} {metric}: recorded {old[metric]['mean']:.4f}, "
                    f"measured {fresh[name][metric]['mean']:.4f}",
                    file=sys.stderr,
                )
    return fresh


def cells(root: Path, evaluate: bool, workers: int) -> dict:
    """(variant, robot, wire, recipe) -> the folders' records and evaluations."""
    grouped: dict[tuple, list] = {}
    for folder in shipped_folders(root):
        record = json.loads((folder / RUN_FILE).read_text())
        evaluations = folder_evaluations(folder, record, evaluate, workers)
        variant = (evaluations["public"] or evaluations["held_out"])["variant"]
        kwargs = record["env_kwargs"]
        key = (variant, kwargs.get("robot", "ur5"), kwargs.get("wire", "articulated"))
        key += (recipe(record["config"]),)
        grouped.setdefault(key, []).append((folder, record, evaluations))
    return grouped


def headline_metric(evaluations: dict) -> str:
    """The flag a cell is judged by: ``insert_success`` where the task raises it (insertion),
    else ``success``."""
    first = evaluations["public"] or evaluations["held_out"]
    return "insert_success" if "insert_success" in first else "success"


def across(runs: list, split: str, metric: str) -> str:
    payloads = [
        {"metrics": {metric: e[split][metric]}}
        for _, _, e in runs
        if e[split] and metric in e[split]
    ]
    if len(payloads) < len(runs):
        return "-"
    value = aggregate_runs(payloads)[metric]
    if len(payloads) == 1:
        return f"{100 * value['mean']:.1f} %"
    return f"{100 * value['mean']:.1f} +/- {100 * value['std']:.1f} %"


def wall_range(minutes: list[float]) -> str:
    low, high = round(min(minutes)), round(max(minutes))
    return f"{low}" if low == high else f"{low}-{high}"


def table(grouped: dict) -> str:
    lines = [
        "| cell | robot, wire | recipe | training seeds | SR reach | SR insert / success "
        "| held out | reference | env steps, wall time per run |",
        "|---|---|---|---:|---:|---:|---:|---:|---|",
    ]
    for (variant, robot, wire, how), runs in grouped.items():
        metric = headline_metric(runs[0][2])
        seeds = ", ".join(str(r["config"].get("seed", 0)) for _, r, _ in runs)
        steps = sorted({r["env_steps"] for _, r, _ in runs})
        minutes = [r["wall_time_s"] / 60 for _, r, _ in runs]
        reference = REFERENCE.get(variant)
        lines.append(
            f"| {variant} | {robot}, {wire} | {how} | {seeds} | "
            f"{across(runs, 'public', 'reach_success')} | **{across(runs, 'public', metric)}** | "
            f"{across(runs, 'held_out', metric)} | "
            f"{'-' if reference is None else f'{100 * reference:.1f} %'} | "
            f"{'/'.join(f'{s / 1e6:.2f}M' for s in steps)}, "
            f"{wall_range(minutes)} min |"
        )
    return "\n".join(lines)


def plot_curves(grouped: dict, out: Path) -> list[Path]:
    """One panel per cell with a curve: each folder's training success (the cell's
    ``headline_metric``) at the end of its episodes against env steps; returns the folders without a
    curve (no ``progress.csv``, or one without rows)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves = {
        f: ProgressTable(f / PROGRESS_FILE).rows() for runs in grouped.values() for f, _, _ in runs
    }
    panels = {key: runs for key, runs in grouped.items() if any(curves[f] for f, _, _ in runs)}
    if not panels:
        raise ValueError(f"no shipped folder has a {PROGRESS_FILE}: no curve to plot")
    fig, axes = plt.subplots(1, len(panels), figsize=(4.5 * len(panels), 3.6), squeeze=False)
    for ax, ((variant, robot, wire, how), runs) in zip(axes[0], panels.items(), strict=True):
        for folder, record, evaluations in runs:
            rows = curves[folder]
            if not rows:
                continue
            # every task's progress.csv has every flag's column: the cell's own flag decides
            key = f"mean_{headline_metric(evaluations)}"
            kept = [r for r in rows if r[key] == r[key]]  # periods that ended an episode
            ax.plot(
                [r["env_steps"] / 1e6 for r in kept],
                [100 * r[key] for r in kept],
                label=f"seed {record['config'].get('seed', 0)}",
            )
        ax.set_title(f"{variant}\n{robot}, {wire}; {how}", fontsize=8)
        ax.set_xlabel("env steps (M)")
        ax.set_ylim(-2, 102)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[0][0].set_ylabel("training episodes succeeding (%)")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return [folder for folder, rows in curves.items() if not rows]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoints", type=Path, default=Path("checkpoints"))
    parser.add_argument(
        "--evaluate", action="store_true", help="measure every folder again (4 x 16, twice)"
    )
    parser.add_argument(
        "--workers", type=number(1, 1024, integer=True), default=None, help="with --evaluate"
    )
    parser.add_argument("--readme", type=Path, help="write the table into this file's block")
    parser.add_argument("--curves", type=Path, help="plot the cells' learning curves (PNG)")
    args = parser.parse_args(argv)
    if not args.evaluate and args.workers is not None:
        parser.error("--workers applies only with --evaluate")
    if args.curves and args.curves.suffix.lower() != ".png":
        parser.error(f"--curves writes a PNG: give a .png file, got {args.curves}")
    if not shipped_folders(args.checkpoints):
        parser.error(f"no shipped policy (*/{RUN_FILE}) under {args.checkpoints}")
    grouped = cells(args.checkpoints, args.evaluate, args.workers or 1)
    text = table(grouped)
    print(text)
    if args.curves:
        try:
            missing = plot_curves(grouped, args.curves)
        except (ValueError, OSError) as err:
            parser.error(str(err))
        print(f"wrote the learning curves to {args.curves}")
        for folder in missing:
            print(f"no {PROGRESS_FILE} in {folder}: its curve is not drawn")
    if args.readme:
        try:
            write_block(args.readme, MARKERS, text)
        except ValueError as err:
            parser.error(str(err))
        print(f"wrote the RL table into {args.readme}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
