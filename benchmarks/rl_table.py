"""The RL results table: every policy shipped in ``checkpoints/``, one row per cell (task
variant, robot, wire, recipe), mean +/- std across its training seeds.

    python benchmarks/rl_table.py [--checkpoints checkpoints] [--evaluate --workers 1]
        [--readme README.md] [--curves docs/img/rl_curves.png]
        [--sweep OPTION [--sweep-with EVAL.json ...] [--sweep-plot PNG] [--sweep-doc FILE]]

A folder's figures are the evaluations its record keeps (``shipped.evaluations``: the
``wirecraft eval --json`` documents given to ``python -m wirecraft.rl.export``, 4 x 16 public
seeds and the held-out list ``--seed 1000``).  ``--evaluate`` measures them again instead, with
``wirecraft.evaluation.run_evaluation`` on the same lists, and prints where they differ from the
record.  Across the folders of a cell (one per training seed): each folder's mean over its seed
list, then the mean and population std over the folders (``aggregate_runs``, as ``wirecraft eval
--policy A B C``).  ``--readme`` writes the table between ``<!-- rl-table -->`` and
``<!-- /rl-table -->``.  Its checkpoint column says how each folder's checkpoint was chosen:
the run's last, or the best of the run's checkpoints on a validation list
(``shipped.selection``).  ``--curves`` plots each cell's learning curves, one line per training
seed, from the ``progress.csv`` each folder keeps (training episodes' success at the end of the
episode against env steps; folders without it are named and left out).

``--sweep OPTION`` (a task option, e.g. ``clearance``): the cells that differ only in that
option, as a difficulty axis: a table of each cell's headline rate (public and held out, mean
+/- std across training seeds; a cell of one seed: std over its 4 seed groups) against the
option's value, ``--sweep-with`` adding other
policies' ``wirecraft eval --json`` documents on the same variants (e.g. the memoryless expert
the recipe learns from) as further columns; ``--sweep-plot`` draws it, ``--sweep-doc`` writes
the table between ``<!-- sweep:OPTION -->`` and ``<!-- /sweep:OPTION -->``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import textwrap
from pathlib import Path

import numpy as np

from wirecraft.cli_args import number, write_block
from wirecraft.evaluation.protocol import aggregate_runs, run_evaluation
from wirecraft.evaluation.seeds import variant_key
from wirecraft.rl import RUN_FILE
from wirecraft.rl.common import PROGRESS_FILE, ProgressTable
from wirecraft.rl.config import SACfDConfig

MARKERS = ("<!-- rl-table -->", "<!-- /rl-table -->")
PANELS_PER_ROW = 4  # of the curves' figure
TITLE_WIDTH = 60  # characters per line of a panel's title


def sweep_markers(option: str) -> tuple[str, str]:
    return (f"<!-- sweep:{option} -->", f"<!-- /sweep:{option} -->")


HELD_OUT_SEED = 1000
# The reference's figures (SR insert, or SR success where a task has no insert flag), by
# algorithm and evaluation variant.
REFERENCE = {
    "ppo": {
        variant_key("insertion", {"connector": "cylinder"}): 0.938,
        variant_key("insertion", {"connector": "cuboid"}): 0.950,
        variant_key("insertion", {"connector": "ethernet"}): 0.959,
        variant_key("insertion", {"connector": "displayport"}): 0.929,
        variant_key("routing", {"num_clips": 1}): 0.953,
        variant_key("seating", {"channel": "straight"}): 0.823,
    },
    "sacfd": {variant_key("insertion", {"connector": "ethernet"}): 0.924},
}


def recipe(record: dict) -> str:
    """Which of the documented recipes (docs/baselines.md) trained the run."""
    config = record["config"]
    if record["algorithm"] == "sacfd":

        def changed(option: str) -> bool:  # from SACfDConfig's default
            default = getattr(SACfDConfig, option)
            return config.get(option, default) != default

        extras = [
            text
            for text, used in (
                ("memoryless expert's demonstrations", config.get("demo_expert") == "reactive"),
                ("goal-relative inputs", config.get("inputs") == "relative"),
                ("DAgger warm start", config.get("dagger_init_iterations", 0) > 0),
                ("BC on relabelled replay", config.get("bc_states") == "replay"),
                (f"BC weight {config.get('bc_weight_start')}", changed("bc_weight_start")),
                ("critic warm-up", changed("critic_warmup_steps")),
                (f"fixed temperature {config.get('initial_alpha')}", changed("learn_entropy")),
                (f"log std <= {config.get('max_log_std')}", changed("max_log_std")),
            )
            if used
        ]
        return "SACfD" + (f" + {', '.join(extras)}" if extras else " (SPEC defaults)")
    if config.get("dagger_init_iterations", 0) > 0:
        inputs = "goal-relative inputs" if config.get("actor_inputs") == "relative" else "state"
        return f"PPO + DAgger warm start ({inputs})"
    return "PPO (SPEC defaults)"


def checkpoint_rule(record: dict) -> str:
    """How the folder's checkpoint was chosen: the run's last, or the best on a validation list
    (``shipped.selection``, ``python -m wirecraft.rl.export --selection``)."""
    chosen = record["shipped"].get("selection")
    if chosen is None:
        return "last"
    return f"best of {len(chosen['candidates'])} on --seed {chosen['validation_seed']}"


def checkpoint_column(runs: list) -> str:
    """Each training seed's checkpoint rule, seeds sharing a rule named together."""
    by_rule: dict[str, list[str]] = {}
    for _, record, _ in runs:
        by_rule.setdefault(checkpoint_rule(record), []).append(str(record["config"].get("seed", 0)))
    if len(by_rule) == 1:
        return next(iter(by_rule))
    return "; ".join(f"{rule} (seed {', '.join(seeds)})" for rule, seeds in by_rule.items())


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
        key += (recipe(record),)
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
        "| cell | robot, wire | recipe | training seeds | checkpoint | SR reach "
        "| SR insert / success | held out | reference | env steps, wall time per run |",
        "|---|---|---|---:|---|---:|---:|---:|---:|---|",
    ]
    for (variant, robot, wire, how), runs in grouped.items():
        metric = headline_metric(runs[0][2])
        seeds = ", ".join(str(r["config"].get("seed", 0)) for _, r, _ in runs)
        steps = sorted({r["env_steps"] for _, r, _ in runs})
        minutes = [r["wall_time_s"] / 60 for _, r, _ in runs]
        reference = REFERENCE.get(runs[0][1]["algorithm"], {}).get(variant)
        lines.append(
            f"| {variant} | {robot}, {wire} | {how} | {seeds} | {checkpoint_column(runs)} | "
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
    columns = min(PANELS_PER_ROW, len(panels))
    rows_of_panels = math.ceil(len(panels) / columns)
    fig, axes = plt.subplots(
        rows_of_panels, columns, figsize=(4.5 * columns, 3.9 * rows_of_panels), squeeze=False
    )
    for ax in axes.flat[len(panels) :]:
        ax.set_visible(False)
    for ax, ((variant, robot, wire, how), runs) in zip(axes.flat, panels.items(), strict=False):
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
        title = textwrap.fill(f"{robot}, {wire}; {how}", TITLE_WIDTH)
        ax.set_title(f"{variant}\n{title}", fontsize=8)
        ax.set_xlabel("env steps (M)")
        ax.set_ylim(-2, 102)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    for row in axes:
        row[0].set_ylabel("training episodes succeeding (%)")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return [folder for folder, rows in curves.items() if not rows]


def variant_options(variant: str) -> tuple[str, dict[str, str]]:
    """``family/key=value/...`` (``variant_key``) as (family, {key: value})."""
    family, *parts = variant.split("/")
    return family, dict(part.split("=", 1) for part in parts)


def _value(text: str):
    try:
        return float(text)
    except ValueError:
        return text


def sweep_series(grouped: dict, option: str, extra: list[dict]) -> dict:
    """The sweeps over task option ``option``: {(family, other options, robot, wire, recipe):
    {series name: {value: (mean, std, n)}}}.  A cell gives the series "trained, public" and
    "trained, held out" (its headline rate: mean and std across its n training seeds; with
    one seed, the std over its evaluation's seed groups); each ``extra`` evaluation document
    one point (n = 0) of the series named by its label and seed list, on the sweep whose other
    options, robot and wire it shares.  Only sweeps with two values or more; a ValueError if
    none."""
    sweeps: dict[tuple, dict] = {}
    found = set()
    for (variant, robot, wire, how), runs in grouped.items():
        family, options = variant_options(variant)
        if option not in options:
            continue
        found.add(family)
        value = _value(options.pop(option))
        key = (family, tuple(sorted(options.items())), robot, wire, how)
        metric = headline_metric(runs[0][2])
        for split, name in (("public", "trained, public"), ("held_out", "trained, held out")):
            means = [e[split][metric]["mean"] for _, _, e in runs if e[split]]
            if len(means) == len(runs):
                # one training seed: the spread over its evaluation's seed groups
                spread = np.std(means) if len(runs) > 1 else runs[0][2][split][metric]["std"]
                point = (float(np.mean(means)), float(spread), len(means))
                sweeps.setdefault(key, {}).setdefault(name, {})[value] = point
    if not found:
        raise ValueError(f"no shipped cell has the task option {option!r}")
    for document in extra:
        family, options = variant_options(document["variant"])
        value = _value(options.pop(option, "nan"))
        kwargs = document.get("env_kwargs", {})
        robot, wire = kwargs.get("robot", "ur5"), kwargs.get("wire", "articulated")
        split = "held out" if document["protocol"].get("held_out_seed") is not None else "public"
        name = f"{document.get('label', 'policy')}, {split}"
        metric = "insert_success" if "insert_success" in document["metrics"] else "success"
        rate = document["metrics"][metric]
        matches = [
            k
            for k in sweeps
            if k[0] == family and k[1:4] == (tuple(sorted(options.items())), robot, wire)
        ]
        if not matches:
            raise ValueError(
                f"{document.get('label')}: no sweep over {option} has the variant "
                f"{document['variant']} ({robot}, {wire})"
            )
        for key in matches:
            sweeps[key].setdefault(name, {})[value] = (rate["mean"], rate["std"], 0)
    kept = {k: v for k, v in sweeps.items() if len(set().union(*map(set, v.values()))) >= 2}
    if not kept:
        raise ValueError(f"no two shipped cells differ only in {option}: nothing to sweep")
    return kept


def sweep_table(sweeps: dict, option: str) -> str:
    blocks = []
    for (family, options, robot, wire, how), series in sweeps.items():
        values = sorted(set().union(*map(set, series.values())), key=str)
        values = sorted(values, key=lambda v: (isinstance(v, str), v))
        names = list(series)
        fixed = ", ".join(f"{k}={v}" for k, v in options)
        lines = [
            f"{family} ({fixed}), {robot}, {wire}; {how}:",
            "",
            f"| {option} | " + " | ".join(names) + " |",
            "|---|" + "---:|" * len(names),
        ]
        for value in values:
            cells_ = []
            for name in names:
                point = series[name].get(value)
                if point is None:
                    cells_.append("-")
                elif point[2]:
                    seeds = f"{point[2]} seed" + ("s" if point[2] > 1 else "")
                    cells_.append(f"{100 * point[0]:.1f} +/- {100 * point[1]:.1f} % ({seeds})")
                else:
                    cells_.append(f"{100 * point[0]:.1f} +/- {100 * point[1]:.1f} %")
            lines.append(f"| {value} | " + " | ".join(cells_) + " |")
        blocks.append("\n".join(lines))
    return "\n\n".join(blocks)


def plot_sweep(sweeps: dict, option: str, out: Path) -> None:
    """One panel per sweep: each series' rate (error bars: std over training seeds, or over
    the seed list for one run) against the option's value."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(sweeps), figsize=(5.0 * len(sweeps), 3.8), squeeze=False)
    for ax, ((family, options, robot, wire, how), series) in zip(
        axes[0], sweeps.items(), strict=True
    ):
        for name, points in series.items():
            values = sorted(points, key=lambda v: (isinstance(v, str), v))
            ax.errorbar(
                [str(v) if isinstance(v, str) else v for v in values],
                [100 * points[v][0] for v in values],
                yerr=[100 * points[v][1] for v in values],
                marker="o",
                capsize=3,
                label=name,
                linestyle="--" if "held out" in name else "-",
            )
        fixed = ", ".join(f"{k}={v}" for k, v in options)
        ax.set_title(f"{family} ({fixed})\n{robot}, {wire}; {how}", fontsize=8)
        ax.set_xlabel(option)
        ax.set_ylabel("SR (%)")
        ax.set_ylim(-2, 102)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)


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
    parser.add_argument("--sweep", metavar="OPTION", help="cells differing only in this option")
    parser.add_argument(
        "--sweep-with",
        type=Path,
        nargs="+",
        default=[],
        metavar="JSON",
        help="other policies' `wirecraft eval --json` documents drawn beside the sweep",
    )
    parser.add_argument("--sweep-plot", type=Path, help="draw the sweep (PNG)")
    parser.add_argument("--sweep-doc", type=Path, help="write the sweep table into FILE's block")
    args = parser.parse_args(argv)
    for flag in ("sweep_with", "sweep_plot", "sweep_doc"):
        if getattr(args, flag) and not args.sweep:
            parser.error(f"--{flag.replace('_', '-')} applies only with --sweep")
    for flag in ("curves", "sweep_plot"):
        path = getattr(args, flag)
        if path and path.suffix.lower() != ".png":
            parser.error(f"--{flag.replace('_', '-')} writes a PNG: give a .png file, got {path}")
    extra = []
    for path in args.sweep_with:
        try:
            document = json.loads(path.read_text())
            if not {"variant", "metrics", "protocol"} <= set(document):
                raise ValueError("not a `wirecraft eval --json` document")
        except (OSError, ValueError) as err:
            parser.error(f"--sweep-with {path}: {err}")
        extra.append(document)
    if not args.evaluate and args.workers is not None:
        parser.error("--workers applies only with --evaluate")
    if not shipped_folders(args.checkpoints):
        parser.error(f"no shipped policy (*/{RUN_FILE}) under {args.checkpoints}")
    grouped = cells(args.checkpoints, args.evaluate, args.workers or 1)
    if args.sweep:  # before anything is written
        try:
            sweeps = sweep_series(grouped, args.sweep, extra)
        except ValueError as err:
            parser.error(str(err))
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
    if args.sweep:
        text = sweep_table(sweeps, args.sweep)
        print(text)
        if args.sweep_plot:
            plot_sweep(sweeps, args.sweep, args.sweep_plot)
            print(f"wrote the {args.sweep} sweep to {args.sweep_plot}")
        if args.sweep_doc:
            try:
                write_block(args.sweep_doc, sweep_markers(args.sweep), text)
            except ValueError as err:
                parser.error(str(err))
            print(f"wrote the {args.sweep} sweep into {args.sweep_doc}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
