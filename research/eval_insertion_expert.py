"""Success of the scripted insertion expert over seeded episodes (until ``wirecraft eval`` exists).

    python research/eval_insertion_expert.py [--robot ur5] [--wire articulated]
        [--connector ethernet|all|a,b] [--episodes 20] [--seed-start 0] [--clearance 0.003]
        [--diversity | --no-diversity] [--hold] [--set name=value ...] [--json out.json] [-v]

Episode k resets the environment with seed ``seed_start + k`` and the expert with the same seed
(its diversity draws).  Per cell it prints the rates of: reach (``reach_success`` at some step),
inserted at some step, inserted at the end of the episode, and, with release, still seated at
the end among the episodes whose plug was seated when the pads opened; the episode length (the
step the expert reached ``done``, or "-" if it never did: p50 / p90 / max, and how many not
done by the end); how often pick-and-drop, insertion retries and grasp retries happened; and the
largest insertion force (``info["insertion_force"]``, N) of each episode, over all steps
(``force_p50`` / ``force_max`` across episodes) and over the steps the pads touch the plug
(``force_push_*``: what the robot pushes with).
``--set`` overrides an ``InsertionExpertConfig`` field (numbers, true/false, or lo,hi).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from tqdm import tqdm

import wirecraft
from wirecraft.assets.connectors import CONNECTORS
from wirecraft.experts import InsertionExpert
from wirecraft.experts.insertion import InsertionExpertConfig
from wirecraft.rl.config import parse_override


def config_from(args) -> InsertionExpertConfig:
    defaults = InsertionExpertConfig()
    overrides = {"diversity": args.diversity, "release": not args.hold}
    overrides.update(parse_override(item, defaults) for item in args.set)
    return InsertionExpertConfig(**overrides)


def run_episode(env, expert, seed: int) -> dict:
    env.reset(seed=seed)
    expert.reset(seed=seed)
    reach = inserted = False
    max_force = max_push = 0.0
    done_step = release_step = first_seated = None
    seated_at_release = False
    truncated = terminated = False
    step = 0
    info: dict = {}
    while not (truncated or terminated):
        action = expert.act()[0]
        phase = expert.phase_names[0]
        if phase == "release" and release_step is None:
            release_step, seated_at_release = step, bool(info.get("insert_success", False))
        if phase == "done" and done_step is None:
            done_step = step
        _, _, terminated, truncated, info = env.step(action)
        step += 1
        reach |= bool(info["reach_success"])
        if info["insert_success"] and first_seated is None:
            first_seated = step
        inserted |= bool(info["insert_success"])
        max_force = max(max_force, float(info["insertion_force"]))
        if info["grasp_force"] > 1.0:  # the pads on the plug: the robot's own push
            max_push = max(max_push, float(info["insertion_force"]))
    return {
        "seed": seed,
        "reach": reach,
        "insert_any": inserted,
        "insert_end": bool(info["insert_success"]),
        "seated_at_release": seated_at_release,
        "first_seated": first_seated,
        "release_step": release_step,
        "done_step": done_step,
        "phase_end": expert.phase_names[0],
        "pick_and_drop": bool(expert.dropped[0]),
        "insert_retries": int(expert.insert_retries[0]),
        "grasp_retries": int(expert.grasp_retries[0]),
        "depth_end": float(info["insertion_depth"]),
        "lateral_end": float(info["lateral_error"]),
        "yaw_end": float(info["yaw_error"]),
        "steps": step,
        "max_insertion_force": max_force,
        "max_push_force": max_push,
    }


def summarize(rows: list[dict]) -> dict:
    n = len(rows)
    done = [r["done_step"] for r in rows if r["done_step"] is not None]
    released = [r for r in rows if r["seated_at_release"]]
    out = {
        "episodes": n,
        "reach": sum(r["reach"] for r in rows) / n,
        "insert_any": sum(r["insert_any"] for r in rows) / n,
        "insert_end": sum(r["insert_end"] for r in rows) / n,
        "kept_after_release": (
            sum(r["insert_end"] for r in released) / len(released) if released else None
        ),
        "not_done": n - len(done),
        "done_p50": float(np.percentile(done, 50)) if done else None,
        "done_p90": float(np.percentile(done, 90)) if done else None,
        "done_max": max(done) if done else None,
        "pick_and_drop": sum(r["pick_and_drop"] for r in rows) / n,
        "insert_retries": sum(r["insert_retries"] for r in rows) / n,
        "grasp_retries": sum(r["grasp_retries"] for r in rows) / n,
        "force_p50": float(np.percentile([r["max_insertion_force"] for r in rows], 50)),
        "force_max": max(r["max_insertion_force"] for r in rows),
        "force_push_p50": float(np.percentile([r["max_push_force"] for r in rows], 50)),
        "force_push_max": max(r["max_push_force"] for r in rows),
    }
    return out


RATES = ("reach", "insert_any", "insert_end", "kept_after_release", "pick_and_drop")


def _fmt(key: str, value) -> str:
    if value is None:
        return "-"
    if key in RATES:
        return f"{value:.0%}"
    if key.startswith("force"):
        return f"{value:.0f}N"
    return f"{value:.2f}" if key.endswith("retries") else f"{value:g}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="ur5")
    parser.add_argument("--wire", default="articulated")
    parser.add_argument("--connector", default="ethernet", help="a name, a,b,... or all")
    parser.add_argument("--clearance", type=float, default=0.003)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed-start", type=int, default=0)
    parser.add_argument("--diversity", action=argparse.BooleanOptionalAction, default=True)
    parser.add_argument("--hold", action="store_true", help="keep holding the seated plug")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    parser.add_argument("--json", help="write the per-episode rows and summaries here")
    parser.add_argument("-v", "--verbose", action="store_true", help="print every episode")
    args = parser.parse_args()
    if args.connector == "all":
        connectors = CONNECTORS.names()
    else:
        connectors = args.connector.split(",")
        for name in connectors:
            CONNECTORS.get(name)  # ValueError listing the valid ones
    config = config_from(args)
    results = {}
    for connector in connectors:
        env = wirecraft.make(
            "insertion",
            robot=args.robot,
            wire=args.wire,
            connector=connector,
            clearance=args.clearance,
        )
        expert = InsertionExpert(env, config)
        rows = []
        start = time.time()
        seeds = range(args.seed_start, args.seed_start + args.episodes)
        for seed in tqdm(seeds, desc=connector, leave=False, disable=args.verbose):
            row = run_episode(env, expert, seed)
            rows.append(row)
            if args.verbose:
                print(" ".join(f"{k}={v}" for k, v in row.items()), flush=True)
        env.close()
        summary = summarize(rows)
        summary["seconds"] = round(time.time() - start, 1)
        results[connector] = {"summary": summary, "rows": rows}
        print(
            f"{connector} ({args.robot}, {args.wire}, clearance {args.clearance * 1000:g} mm, "
            f"diversity={config.diversity}, release={config.release}): "
            + "  ".join(f"{k} {_fmt(k, v)}" for k, v in summary.items()),
            flush=True,
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"args": vars(args), "results": results}, f, indent=1)


if __name__ == "__main__":
    main()
