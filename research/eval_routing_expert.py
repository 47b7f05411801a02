"""Success of the routing expert over seeds:

    python research/eval_routing_expert.py --num-clips 3 --episodes 100 [--wire rod]
        [--first-seed 0] [--episode-seconds S] [--verbose] [--set FIELD=VALUE ...]

Each episode is reset with its seed (first-seed, first-seed + 1, ...) and run to the end (the
task's length by default: 8 s = 480 control steps per clip); "success at the end" is the
task's ``success`` on the last step, "at some step" whether it was ever true, "held" whether
it stayed true for ``--hold-steps`` steps in a row at some point (a wire pressed down on the
lips by the pads can read seated for a few steps and spring out on release).  Failures list
the seed, the clips routed at the end, the expert's phase and clip, how often it routed each
clip, and the step at which the physics diverged, if it did (the environment then rolls the
step back and truncates the episode); the summary counts divergences.  ``--set`` overrides
``RoutingExpertConfig`` fields, for comparing variants.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from tqdm import tqdm

import wirecraft
from wirecraft.experts.routing import RoutingExpert, RoutingExpertConfig
from wirecraft.rl.config import parse_override


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-clips", "--clips", type=int, default=1, choices=(1, 2, 3))
    parser.add_argument("--episodes", "--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument(
        "--episode-seconds", type=float, default=None, help="default: the task's (8 s per clip)"
    )
    parser.add_argument("--robot", default="ur5")
    parser.add_argument("--hold-steps", type=int, default=30, help="steps in a row for 'held'")
    parser.add_argument("--wire", default="articulated")
    parser.add_argument("--verbose", action="store_true", help="print every episode's phases")
    parser.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="FIELD=VALUE",
        help="override RoutingExpertConfig fields (lists comma-separated, true/false)",
    )
    args = parser.parse_args()
    overrides = dict(parse_override(item, RoutingExpertConfig()) for item in args.set)
    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    if args.hold_steps < 1:
        raise ValueError(f"--hold-steps must be >= 1, got {args.hold_steps}")
    env = wirecraft.make(
        "routing",
        num_clips=args.num_clips,
        robot=args.robot,
        wire=args.wire,
        episode_seconds=args.episode_seconds,
    )
    expert = RoutingExpert(env, RoutingExpertConfig(**overrides))
    ends, anys, helds, failures, diverged = [], [], [], [], []
    start = time.time()
    seeds = range(args.first_seed, args.first_seed + args.episodes)
    for seed in tqdm(seeds, desc=f"routing {args.num_clips} clip(s)", disable=args.verbose):
        env.reset(seed=seed)
        expert.reset()
        first, log, last_phase, step, run, longest = None, [], None, 0, 0, 0
        while True:
            step += 1
            _, _, terminated, truncated, info = env.step(expert.act()[0])
            phase = expert.phase_names[0]
            if args.verbose and phase != last_phase:
                log.append(f"{step}:{phase}[c{expert.clip[0]}]")
                last_phase = phase
            if info["success"] and first is None:
                first = step
            run = run + 1 if info["success"] else 0
            longest = max(longest, run)
            if terminated or truncated:
                break
        ends.append(bool(info["success"]))
        anys.append(first is not None)
        helds.append(longest >= args.hold_steps)
        diverged.append(bool(info["diverged"]))
        if not info["success"]:
            failures.append(
                f"seed {seed}: routed {info['clips_routed']}/{args.num_clips}, "
                f"phase {expert.phase_names[0]}, clip {expert.clip[0]}, "
                f"routings per clip {expert.tries[0, : args.num_clips].tolist()}, "
                + (
                    "never routed"
                    if first is None
                    else f"routed at step {first}, lost after (longest {longest} steps)"
                )
                + (f", diverged at step {step}" if info["diverged"] else "")
            )
        if args.verbose:
            print(
                f"seed {seed}: end {info['success']} first success at step {first} "
                f"routed {info['clips_routed']}/{args.num_clips}\n   {' '.join(log)}"
            )
    for line in failures:
        print(line)
    print(
        f"{args.robot} {args.wire}, {args.num_clips} clip(s): success at the end "
        f"{np.mean(ends):.0%} ({sum(ends)}/{len(ends)}), at some step {np.mean(anys):.0%}, "
        f"held {args.hold_steps} steps {np.mean(helds):.0%}, "
        f"{sum(diverged)} diverged, seeds {args.first_seed}-{args.first_seed + args.episodes - 1} "
        f"({time.time() - start:.0f} s)"
    )


if __name__ == "__main__":
    main()
