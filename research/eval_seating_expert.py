"""Success of the seating expert over seeds, per channel shape:
python research/eval_seating_expert.py --channels straight,curved --seeds 100
[--wire articulated] [--robot ur5] [--first-seed 0] [--verbose] [--set lay_turn=false ...]
[--chained-expert-seed N]
(``--set`` overrides ``SeatingExpertConfig`` fields, for comparing variants).

Each episode's expert draws its diversity (settle delay, lay slow-down) from the episode's
seed, as ``wirecraft collect`` does: an episode depends on its seed only, so a failing seed
replays alone (``--first-seed S --seeds 1``).  ``--chained-expert-seed N`` instead runs one
expert whose generator, seeded N, goes on from episode to episode: the protocol of the
figures measured before 24 Nov 2026 (N = 0)."""

from __future__ import annotations

import argparse
import time

import numpy as np
from tqdm import tqdm

import wirecraft
from wirecraft.experts.seating import SeatingExpert, SeatingExpertConfig
from wirecraft.rl.config import parse_override


def run_episode(env, expert, seed: int, verbose: bool) -> dict:
    env.reset(seed=seed)
    expert.reset()
    first, log, last_phase, step = None, [], None, 0
    while True:
        step += 1
        _, _, terminated, truncated, info = env.step(expert.act()[0])
        phase = expert.phase_names[0]
        if verbose and phase != last_phase:
            log.append(f"{step}:{phase}")
            last_phase = phase
        if info["success"] and first is None:
            first = step
        if terminated or truncated:
            break
    return {
        "seed": seed,
        "success": bool(info["success"]),
        "fraction": float(info["fraction_inside"]),
        "first": first,
        "phase": expert.phase_names[0],
        "retries": int(expert.grasp_retries[0]),
        "diverged": bool(info["diverged"]),
        "log": " ".join(log),
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--channels", default="straight,curved")
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--robot", default="ur5")
    parser.add_argument("--wire", default="articulated")
    parser.add_argument("--chained-expert-seed", type=int, default=None)
    parser.add_argument("--verbose", action="store_true")
    parser.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="FIELD=VALUE",
        help="override SeatingExpertConfig fields (lists comma-separated, true/false)",
    )
    args = parser.parse_args()
    defaults = SeatingExpertConfig()
    overrides = dict(parse_override(item, defaults) for item in args.set)
    summary = []
    for channel in args.channels.split(","):
        env = wirecraft.make(
            "seating",
            channel=channel,
            robot=args.robot,
            wire=args.wire,
            control=SeatingExpert.CONTROL,
        )
        chained = args.chained_expert_seed
        if chained is not None:
            expert = SeatingExpert(env, SeatingExpertConfig(seed=chained, **overrides))
        start = time.time()
        episodes = []
        seeds = range(args.first_seed, args.first_seed + args.seeds)
        for seed in tqdm(seeds, desc=channel, disable=args.verbose):
            if chained is None:
                expert = SeatingExpert(env, SeatingExpertConfig(seed=seed, **overrides))
            ep = run_episode(env, expert, seed, args.verbose)
            episodes.append(ep)
            if args.verbose or not ep["success"]:
                tqdm.write(
                    f"{channel} seed {seed}: success {ep['success']} fraction "
                    f"{ep['fraction']:.3f} first success at step {ep['first']} phase "
                    f"{ep['phase']} retries {ep['retries']} diverged {ep['diverged']}"
                    + (f"\n   {ep['log']}" if args.verbose else "")
                )
        rate = np.mean([e["success"] for e in episodes])
        fractions = np.array([e["fraction"] for e in episodes])
        summary.append(
            f"{args.robot} {args.wire} {channel} {' '.join(args.set)}: success {rate:.1%} "
            f"over {len(episodes)} seeds, "
            f"fraction inside mean {fractions.mean():.3f} min {fractions.min():.3f} "
            f"({time.time() - start:.0f} s)"
        )
        print(summary[-1], flush=True)
    print("\n".join(summary))


if __name__ == "__main__":
    main()
