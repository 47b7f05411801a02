"""Learning curve of an RL run directory: training-episode success against env steps and wall
time, from its ``progress.csv`` (written by ``wirecraft train``).

    python benchmarks/plot_learning_curve.py RUN_DIR [--out curve.png] [--table]

Success rates are means over the training episodes that finished in each logging period
(the stochastic training policy, not the evaluation protocol's deterministic one).
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

CURVES = (
    ("mean_reach_success_any", "reach (any step)"),
    ("mean_insert_success_any", "insert (any step)"),
    ("mean_insert_success", "insert (at the end)"),
)


def read_progress(run_dir: Path) -> list[dict[str, float]]:
    path = Path(run_dir) / "progress.csv"
    if not path.exists():
        raise SystemExit(f"{path} does not exist: is {run_dir} a wirecraft train run directory?")
    with path.open() as handle:
        rows = [
            {k: float(v) if v not in ("", None) else math.nan for k, v in r.items()}
            for r in csv.DictReader(handle)
        ]
    if not rows:
        raise SystemExit(f"{path} has no rows yet")
    return rows


def plot(rows, out: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, x_key, label in (
        (axes[0], "env_steps", "env steps"),
        (axes[1], "wall_time_s", "wall time (h)"),
    ):
        scale = 1 / 3600 if x_key == "wall_time_s" else 1.0
        for key, name in CURVES:
            # Most logging periods end no episode (NaN): join the periods that did.
            kept = [r for r in rows if not math.isnan(r[key])]
            xs, ys = [r[x_key] * scale for r in kept], [100 * r[key] for r in kept]
            ax.plot(xs, ys, ".-", label=name)
        if x_key == "wall_time_s" and rows[0][x_key] > 0.05 * rows[-1][x_key]:
            # A warm start (DAgger, behaviour cloning) runs before iteration 0's clock stops.
            ax.axvspan(0, rows[0][x_key] * scale, color="0.9", label="warm start")
        ax.set_xlabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("training episodes (%)")
    axes[0].set_ylim(-2, 102)
    axes[1].legend(loc="lower left")
    fig.suptitle(title)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--out", type=Path, default=None, help="PNG (default RUN_DIR/curve.png)")
    parser.add_argument("--table", action="store_true", help="print the rows as a table")
    args = parser.parse_args()
    rows = read_progress(args.run_dir)
    out = args.out or args.run_dir / "curve.png"
    plot(rows, out, f"{args.run_dir.name}: training-episode success")
    print(f"wrote {out}")
    if args.table:
        columns = ("env steps", "wall time (min)", "episodes", "return", "reach any")
        columns += ("insert any", "insert end")
        print("| " + " | ".join(columns) + " |")
        print("|---:|---:|---:|---:|---:|---:|---:|")
        for r in rows:
            if math.isnan(r["mean_return"]):  # no episode finished in this period
                continue
            print(
                f"| {r['env_steps']:,.0f} | {r['wall_time_s'] / 60:.0f} | "
                f"{'-' if math.isnan(r['episodes']) else round(r['episodes'])} | "
                f"{r['mean_return']:.0f} | {100 * r['mean_reach_success_any']:.0f} % | "
                f"{100 * r['mean_insert_success_any']:.0f} % | "
                f"{100 * r['mean_insert_success']:.0f} % |"
            )


if __name__ == "__main__":
    main()
