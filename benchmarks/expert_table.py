"""The status table: the scripted experts' success in every cell, under the evaluation
protocol (``wirecraft.evaluation.run_evaluation``, policy ``scripted``), on a held-out seed list.

    python benchmarks/expert_table.py --out DIR [--tasks FAMILY,...] [--robots ur5,panda,wxai]
        [--wires articulated,rod,fem] [--seeds 4] [--episodes 25] [--seed 1000] [--workers 1]
        [--only ROBOT/WIRE,...] [--readme README.md]

Cells: every standard variant of every registered family (``TaskMetrics.standard_variants``)
for the UR5 with the articulated wire, and for each other robot (articulated wire) and each
other wire (UR5).  Each cell's payload is written to ``OUT/<task>-<variant>-<robot>-<wire>.json``
as soon as it finishes; a rerun skips cells already there (delete a file to redo it), so an
interrupted table resumes.  At the end it prints a Markdown table: success at some step and at
the end of the episode (mean over seeds), against the target (98 % for the UR5 with the
articulated wire, 95 % otherwise, on success at some step).  ``--readme`` writes that table
into the file between ``<!-- status-table -->`` and ``<!-- /status-table -->``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

from wirecraft.assets.robots import ROBOTS
from wirecraft.assets.wires import WIRE_MODELS
from wirecraft.cli_args import write_block
from wirecraft.evaluation.protocol import run_evaluation
from wirecraft.tasks import TASKS

VARIANTS = {name: TASKS.get(name).metrics.standard_variants() for name in TASKS}
MARKERS = ("<!-- status-table -->", "<!-- /status-table -->")
BASE = ("ur5", "articulated")
TARGETS = {BASE: 0.98}
OTHER_TARGET = 0.95


def cells(tasks, robots, wires, only=None):
    """(task, variant kwargs, robot, wire): the base pair plus one change of robot or wire."""
    pairs = [BASE] + [(r, BASE[1]) for r in robots if r != BASE[0]]
    pairs += [(BASE[0], w) for w in wires if w != BASE[1]]
    if only:
        pairs = [p for p in pairs if f"{p[0]}/{p[1]}" in only]
    for robot, wire in pairs:
        for task in tasks:
            for variant in VARIANTS[task]:
                yield task, variant, robot, wire


def cell_path(out: Path, task, variant, robot, wire) -> Path:
    tag = "-".join(f"{v}" for v in variant.values())
    return out / f"{task}-{tag}-{robot}-{wire}.json"


def write_atomic(path: Path, payload: dict) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(payload, indent=1) + "\n")
    os.replace(tmp, path)


def percent(metric: dict) -> str:
    return f"{100 * metric['mean']:.1f} +/- {100 * metric['std']:.1f}"


def table(rows) -> str:
    lines = [
        "| task | variant | robot | wire | episodes | success (some step) | at end | target "
        "| reached |",
        "|---|---|---|---|---:|---:|---:|---:|---|",
    ]
    for task, variant, robot, wire, payload in rows:
        target = TARGETS.get((robot, wire), OTHER_TARGET)
        if payload is None:
            lines.append(
                f"| {task} | {variant} | {robot} | {wire} | - | not run | | {target:.0%} | |"
            )
            continue
        m = payload["metrics"]
        n = len(payload["episodes"])
        reached = "yes" if m["success"]["mean"] >= target else "**no**"
        lines.append(
            f"| {task} | {variant} | {robot} | {wire} | {n} | {percent(m['success'])} | "
            f"{percent(m['success_at_end'])} | {target:.0%} | {reached} |"
        )
    return "\n".join(lines)


def matrix(rows, pairs) -> str:
    """Variants down, robot / wire pairs across; each cell success at some step / at the end
    (%, mean over seeds), bold where the target is missed, - where not run."""
    head = " | ".join("UR5 + articulated" if p == BASE else f"{p[0]} + {p[1]}" for p in pairs)
    lines = [f"| variant | {head} |", "|---|" + "---:|" * len(pairs)]
    cells = {}
    for task, variant, robot, wire, payload in rows:
        cells[(task, variant, (robot, wire))] = payload
    for task, variant in dict.fromkeys((r[0], r[1]) for r in rows):
        out = []
        for pair in pairs:
            payload = cells.get((task, variant, pair))
            if payload is None:
                out.append("-")
                continue
            m = payload["metrics"]
            text = f"{100 * m['success']['mean']:.0f} / {100 * m['success_at_end']['mean']:.0f}"
            missed = m["success"]["mean"] < TARGETS.get(pair, OTHER_TARGET)
            out.append(f"**{text}**" if missed else text)
        lines.append(f"| {task}, {variant} | " + " | ".join(out) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, type=Path, help="directory of per-cell JSON")
    parser.add_argument("--tasks", default=",".join(TASKS), help="families (default: all)")
    parser.add_argument("--robots", default="ur5,panda,wxai")
    parser.add_argument("--wires", default="articulated,rod,fem")
    parser.add_argument("--only", default="", help="ROBOT/WIRE pairs, e.g. panda/articulated")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--episodes", type=int, default=25, help="episodes per seed")
    parser.add_argument("--seed", type=int, default=1000, help="held-out seed list")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--dry-run", action="store_true", help="print the table of done cells")
    parser.add_argument("--readme", type=Path, help="write the table into this file's block")
    args = parser.parse_args()
    tasks = [t for t in args.tasks.split(",") if t]
    unknown = [t for t in tasks if t not in VARIANTS]
    if unknown:
        raise SystemExit(f"unknown task(s) {unknown}; valid: {', '.join(VARIANTS)}")
    robots, wires = args.robots.split(","), args.wires.split(",")
    for name in robots:
        ROBOTS.get(name)  # ValueError listing the valid names
    for name in wires:
        WIRE_MODELS.get(name)
    for name in ("seeds", "episodes", "workers"):
        if getattr(args, name) < 1:
            raise SystemExit(f"--{name} must be >= 1, got {getattr(args, name)}")
    only = {p for p in args.only.split(",") if p}
    todo = list(cells(tasks, robots, wires, only))
    if not todo:
        raise SystemExit(
            f"--only {args.only!r} matches no cell (ROBOT/WIRE, e.g. panda/articulated)"
        )
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for i, (task, variant, robot, wire) in enumerate(todo, 1):
        path = cell_path(args.out, task, variant, robot, wire)
        label = f"[{i}/{len(todo)}] {task} {variant} {robot} {wire}"
        if path.exists():
            payload = json.loads(path.read_text())
        elif args.dry_run:
            payload = None
        else:
            print(label, flush=True)
            start = time.time()
            payload = run_evaluation(
                task,
                "scripted",
                seeds=args.seeds,
                episodes=args.episodes,
                seed=args.seed,
                workers=args.workers,
                robot=robot,
                wire=wire,
                **variant,
            ).payload
            payload["wall_seconds"] = round(time.time() - start, 1)
            write_atomic(path, payload)
            m = payload["metrics"]
            print(
                f"    success {percent(m['success'])} %, at end {percent(m['success_at_end'])} %"
                f" ({payload['wall_seconds']:.0f} s)",
                flush=True,
            )
        variant_text = ", ".join(f"{k}={v}" for k, v in variant.items())
        rows.append((task, variant_text, robot, wire, payload))
    print(table(rows))
    if args.readme:
        pairs = list(dict.fromkeys((r[2], r[3]) for r in rows))
        try:
            write_block(args.readme, MARKERS, matrix(rows, pairs))
        except ValueError as err:
            raise SystemExit(str(err)) from None
        print(f"wrote the status table into {args.readme}")


if __name__ == "__main__":
    main()
