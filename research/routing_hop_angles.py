"""The steepest clip-to-clip hop of each routing layout, per seed:

    python research/routing_hop_angles.py --num-clips 3 --episodes 100 --first-seed 1000

For each seed (reset as ``eval_routing_expert.py`` resets it) prints the largest angle
between a clip's slot and the straight hop to a neighbouring clip, and the angle at which the
hop into the last clip meets its slot (degrees).  Next to that script's list of failed seeds it
shows how success depends on the layout (docs/experts.md, "Steep hops").
"""

from __future__ import annotations

import argparse
import math

import numpy as np

import wirecraft


def hop_turns(clips) -> np.ndarray:
    """rad: for each hop between neighbouring clips (x, y, yaw), the angle between the hop and
    the slot at either end."""
    turns = []
    for (x0, y0, yaw0), (x1, y1, yaw1) in zip(clips[:-1], clips[1:], strict=True):
        hop = math.atan2(y1 - y0, x1 - x0)  # the slots run along world +y at yaw pi / 2
        turns += [abs(yaw0 - hop), abs(yaw1 - hop)]
    return np.array(turns)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-clips", "--clips", type=int, default=3, choices=(2, 3))
    parser.add_argument("--episodes", "--seeds", type=int, default=100)
    parser.add_argument("--first-seed", type=int, default=0)
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error("--episodes must be at least 1")
    if args.first_seed < 0:
        parser.error("--first-seed must be >= 0 (reset seeds are non-negative)")
    env = wirecraft.make("routing", num_clips=args.num_clips)
    task = env.unwrapped.task
    print("seed  steepest_hop_deg  into_last_deg")
    for seed in range(args.first_seed, args.first_seed + args.episodes):
        env.reset(seed=seed)
        turns = np.degrees(hop_turns(task.sampled["clips"]))
        print(f"{seed}  {turns.max():.1f}  {turns[-1]:.1f}")
    env.close()


if __name__ == "__main__":
    main()
