"""Statistical parity of the two physics backends: the scripted experts' success on the same
frozen seeds, stepped on MuJoCo's C code (``backend="cpu"``) and on MuJoCo Warp.

MuJoCo Warp runs in float32 and is not bitwise deterministic, so single episodes part ways
(chaotic contacts); what must agree is the rate.  Each family's expert runs the evaluation
protocol's episodes (``--seeds`` x ``--episodes`` from the public list, or the held-out list of
``--seed``) on both backends; the script prints both success rates, their difference in points
and whether it is within ``--tolerance`` (the issue's 2 points), and writes the rows as JSON.

    python benchmarks/bench_warp_parity.py --device cuda:0 --seeds 4 --episodes 64 --batch 256
    python benchmarks/bench_warp_parity.py --device cpu --task insertion --seeds 1 --episodes 2

Paired episodes (same seeds) make the comparison sharper than two independent samples: the
difference counts only episodes whose outcome the backend changed (``changed`` in the rows).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

from wirecraft.evaluation.protocol import run_evaluation
from wirecraft.provenance import provenance
from wirecraft.tasks import TASKS


def success_by_episode(run) -> dict[tuple[int, int], bool]:
    return {(r.spec.seed_index, r.spec.episode): bool(r.summary["success"]) for r in run.results}


def compare(task: str, args) -> dict:
    common = dict(
        seeds=args.seeds,
        episodes=args.episodes,
        seed=args.seed,
        progress=not args.quiet,
        wire=args.wire,
    )
    start = time.perf_counter()
    cpu = run_evaluation(task, "scripted", workers=args.workers, **common)
    cpu_s = time.perf_counter() - start
    start = time.perf_counter()
    warp = run_evaluation(
        task, "scripted", batch=args.batch, backend="warp", device=args.device, **common
    )
    warp_s = time.perf_counter() - start
    on_cpu, on_warp = success_by_episode(cpu), success_by_episode(warp)
    rate_cpu = 100.0 * sum(on_cpu.values()) / len(on_cpu)
    rate_warp = 100.0 * sum(on_warp.values()) / len(on_warp)
    return {
        "task": task,
        "wire": args.wire,
        "episodes": len(on_cpu),
        "success_cpu": round(rate_cpu, 2),
        "success_warp": round(rate_warp, 2),
        "difference_points": round(rate_warp - rate_cpu, 2),
        "within_tolerance": abs(rate_warp - rate_cpu) <= args.tolerance,
        "changed": sum(on_cpu[k] != on_warp[k] for k in on_cpu),
        "seconds_cpu": round(cpu_s, 1),
        "seconds_warp": round(warp_s, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", nargs="+", default=list(TASKS.names()), help="(default: all)")
    parser.add_argument("--wire", default="articulated")
    parser.add_argument("--device", default=None, help="Warp device (default: Warp's choice)")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--episodes", type=int, default=16, help="episodes per seed")
    parser.add_argument("--seed", type=int, default=None, help="held-out list of this seed")
    parser.add_argument("--batch", type=int, default=None, help="Warp: worlds stepped together")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="CPU side")
    parser.add_argument("--tolerance", type=float, default=2.0, help="points (default: 2)")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args()
    for name in ("seeds", "episodes", "workers"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be >= 1")
    unknown = [t for t in args.task if t not in TASKS.names()]
    if unknown:
        parser.error(f"unknown task {unknown[0]!r}; valid: {', '.join(TASKS.names())}")
    rows = [compare(task, args) for task in args.task]
    print(f"{'task':10} {'episodes':>8} {'cpu %':>7} {'warp %':>7} {'diff':>6} {'changed':>7}  ok")
    for r in rows:
        print(
            f"{r['task']:10} {r['episodes']:>8} {r['success_cpu']:>7.1f} {r['success_warp']:>7.1f}"
            f" {r['difference_points']:>+6.1f} {r['changed']:>7}  {r['within_tolerance']}"
        )
    if args.json:
        from wirecraft.envs.warp_batch import warp_modules

        wp, _ = warp_modules()
        device = wp.get_device(args.device).name
        document = {"rows": rows, "warp_device": device, "provenance": provenance()}
        args.json.write_text(json.dumps(document, indent=2) + "\n")


if __name__ == "__main__":
    main()
