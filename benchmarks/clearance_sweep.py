"""Clearance as a difficulty axis: one insertion policy evaluated under the protocol at several
plug-socket clearances.

    python benchmarks/clearance_sweep.py --policy checkpoints/ppo_insertion_cylinder_seed0 \\
        --connector cylinder --clearances 0.5,1,2,3 --out out/clearance

Prints SR reach / insert (mean +/- std over seeds) and the failure labels per clearance (mm),
and writes ``clearance.json`` and ``clearance.png`` (SR against clearance) to ``--out``.  The
policy is whatever ``wirecraft eval --policy`` takes (``scripted``, a run directory, ...).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from wirecraft.evaluation.protocol import run_evaluation
from wirecraft.provenance import provenance


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", required=True)
    parser.add_argument("--connector", required=True)
    parser.add_argument("--clearances", default="0.5,1,2,3", help="mm, comma-separated")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--episodes", type=int, default=16)
    parser.add_argument("--seed", type=int, default=None, help="held-out list of this seed")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("out/clearance"))
    args = parser.parse_args()
    try:
        clearances = [float(c) for c in args.clearances.split(",")]
    except ValueError:
        parser.error(f"--clearances: expected numbers in mm, got {args.clearances!r}")
    if not all(0 < c < 20 for c in clearances):
        parser.error("--clearances: each must be in (0, 20) mm")
    rows = []
    for mm in clearances:
        run = run_evaluation(
            "insertion",
            args.policy,
            seeds=args.seeds,
            episodes=args.episodes,
            seed=args.seed,
            workers=args.workers,
            progress=False,
            connector=args.connector,
            clearance=mm / 1000.0,
        )
        metrics = run.payload["metrics"]
        row = {
            "clearance_mm": mm,
            **{k: metrics[k] for k in ("reach_success", "insert_success")},
            "failures": run.payload["failures"],
        }
        rows.append(row)
        reach, insert = row["reach_success"], row["insert_success"]
        print(
            f"{mm:5.2f} mm  reach {100 * reach['mean']:5.1f} +/- {100 * reach['std']:4.1f} %  "
            f"insert {100 * insert['mean']:5.1f} +/- {100 * insert['std']:4.1f} %  "
            f"failures {row['failures']}",
            flush=True,
        )
    args.out.mkdir(parents=True, exist_ok=True)
    document = {
        "policy": args.policy,
        "connector": args.connector,
        "held_out_seed": args.seed,
        "rows": rows,
        "provenance": provenance(threads=args.workers),
    }
    (args.out / "clearance.json").write_text(json.dumps(document, indent=2) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.8))
    for key, label in (("reach_success", "SR reach"), ("insert_success", "SR insert")):
        means = [100 * r[key]["mean"] for r in rows]
        stds = [100 * r[key]["std"] for r in rows]
        ax.errorbar(clearances, means, yerr=stds, marker="o", capsize=3, label=label)
    ax.set(
        xlabel="clearance (mm)",
        ylabel="success rate (%)",
        ylim=(-5, 105),
        title=f"{Path(args.policy).name}, {args.connector}",
    )
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.out / "clearance.png", dpi=120)
    print(f"wrote {args.out}/clearance.json and {args.out}/clearance.png")


if __name__ == "__main__":
    main()
