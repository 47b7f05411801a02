"""Success of the routing expert over seeds: python benchmarks/eval_routing_expert.py
--clips 1 --seeds 20 [--episode-seconds 8] [--verbose]."""

from __future__ import annotations

import argparse
import time

import numpy as np

import wirecraft
from wirecraft.experts.routing import RoutingExpert


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--clips", type=int, default=1)
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--episode-seconds", type=float, default=8.0)
    parser.add_argument("--robot", default="ur5")
    parser.add_argument("--wire", default="articulated")
    parser.add_argument("--verbose", action="store_true")
    args = parser.parse_args()
    env = wirecraft.make(
        "routing",
        num_clips=args.clips,
        robot=args.robot,
        wire=args.wire,
        episode_seconds=args.episode_seconds,
    )
    expert = RoutingExpert(env)
    ends, anys = [], []
    start = time.time()
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        env.reset(seed=seed)
        expert.reset()
        first, log, last_phase, step = None, [], None, 0
        while True:
            step += 1
            _, _, terminated, truncated, info = env.step(expert.act()[0])
            phase = expert.phase_names[0]
            if args.verbose and phase != last_phase:
                log.append(f"{step}:{phase}[c{expert.clip[0]}]")
                last_phase = phase
            if info["success"] and first is None:
                first = step
            if terminated or truncated:
                break
        ends.append(bool(info["success"]))
        anys.append(first is not None)
        print(
            f"seed {seed}: end {info['success']} first success at step {first} "
            f"routed {info['clips_routed']}/{args.clips} phase {expert.phase_names[0]} "
            f"clip {expert.clip[0]} grasp arc {expert.grasp_arc[0]:.3f} "
            f"retries {expert.grasp_retries[0]}" + (f"\n   {' '.join(log)}" if args.verbose else "")
        )
    print(
        f"clips {args.clips}: success at end {np.mean(ends):.0%}, at some step {np.mean(anys):.0%}"
        f" over {args.seeds} seeds ({time.time() - start:.0f} s)"
    )


if __name__ == "__main__":
    main()
