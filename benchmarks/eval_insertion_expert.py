"""Success of the scripted insertion expert over seeds (until ``wirecraft eval`` exists).

    python benchmarks/eval_insertion_expert.py [--connector ethernet] [--seeds 20] [--release]

Prints, per seed, whether the plug reached the socket, was ever inserted and is inserted at the
end of the 480-step episode, then the rates.
"""

from __future__ import annotations

import argparse
import time

import wirecraft
from wirecraft.assets.connectors import CONNECTORS
from wirecraft.experts import InsertionExpert
from wirecraft.experts.insertion import InsertionExpertConfig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connector", default="ethernet", choices=CONNECTORS.names())
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--robot", default="ur5")
    parser.add_argument("--wire", default="articulated")
    parser.add_argument("--release", action="store_true", help="let go of the plug when seated")
    args = parser.parse_args()
    env = wirecraft.make("insertion", robot=args.robot, wire=args.wire, connector=args.connector)
    expert = InsertionExpert(env, InsertionExpertConfig(release=args.release))
    totals = {"reach": 0, "insert_any": 0, "insert_end": 0}
    start = time.time()
    for seed in range(args.seeds):
        obs, info = env.reset(seed=seed)
        expert.reset()
        reach = inserted = False
        truncated = False
        while not truncated:
            obs, _, _, truncated, info = env.step(expert.act(obs)[0])
            reach |= bool(info["reach_success"])
            inserted |= bool(info["insert_success"])
        row = {"reach": reach, "insert_any": inserted, "insert_end": bool(info["insert_success"])}
        for key, value in row.items():
            totals[key] += value
        print(f"seed {seed:3d}: " + "  ".join(f"{k}={v}" for k, v in row.items()), flush=True)
    n = args.seeds
    print(
        f"{args.connector} ({args.robot}, {args.wire}, release={args.release}), {n} seeds: "
        + "  ".join(f"{k} {v / n:.0%}" for k, v in totals.items())
        + f"  ({time.time() - start:.0f} s)"
    )


if __name__ == "__main__":
    main()
