"""Where the articulated wire's joints lie when each routing push ends, against its outcome:

    python research/routing_push_joints.py --num-clips 3 --episodes 50 --first-seed 2000
        [--robot panda] [--set FIELD=VALUE ...] [--json FILE]

Runs the routing expert (as ``eval_routing_expert.py`` does) and, at the end of every push of
clips 2 and 3, records the joint nearest the slot centre (its offset along the wire from the
slot centre's point: negative = before it, towards the clamp), whether the pads hold a joint
(one within 8 mm of the TCP along the slot axis: the aslant grasp at a joint took hold),
the angle between the hop from the previous clip and the slot, and whether the clip holds the
wire once the release (and any press) is over.  Prints, for steep hops (over 15 deg) and the
rest, how many pushes seated, by joint held or not and by the nearest joint's offset
(docs/experts.md, "Steep hops: a joint in the pads").
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from tqdm import tqdm

import wirecraft
from wirecraft.experts.routing import RoutingExpert, RoutingExpertConfig
from wirecraft.geometry import arc_lengths, resample
from wirecraft.rl.config import parse_override

OFFSET_BINS_MM = (-17, -12, -9, -5, -1, 3, 6, 9, 12, 17)
STEEP_DEG = 15.0
PRESS_PHASES = ("retreat", "press_over", "press", "press_up")
HELD_REACH = 0.008  # m along the slot axis between the TCP and a joint held between the pads


def push_record(env, expert) -> dict:
    """The state of environment 0 as its push ends (see the module docstring)."""
    k = int(expert.clip[0])
    clip = env.task.placed_clips(env.data)[k]
    points = env.wire_points()
    node_arc = arc_lengths(points)
    line = resample(points, 0.001)
    line_arc = arc_lengths(line)
    radius = env.task.assembly.wire.config.radius
    centre = np.array(clip.pos) + [0.0, 0.0, clip.config.base_height + radius]
    slot_arc = line_arc[np.argmin(np.linalg.norm(line - centre, axis=1))]
    offsets = node_arc - slot_arc
    along = clip.to_local(points)[:, 0]
    tcp = clip.to_local(env.data.site_xpos[env.task.tcp_site][None])[0, 0]
    return {
        "clip": k,
        "routing": int(expert.tries[0, k]),
        "hop_deg": float(np.degrees(expert._hop_angle(0))),
        "nearest_joint_mm": float(1000 * offsets[np.argmin(np.abs(offsets))]),
        "joint_held": bool(np.min(np.abs(along - tcp)) < HELD_REACH),
    }


def run(args, config) -> list[dict]:
    env = wirecraft.make("routing", num_clips=args.num_clips, robot=args.robot)
    expert = RoutingExpert(env, config)
    records = []
    seeds = range(args.first_seed, args.first_seed + args.episodes)
    for seed in tqdm(seeds, desc="routing pushes"):
        env.reset(seed=seed)
        expert.reset()
        before, pending = None, None
        while True:
            _, _, terminated, truncated, _ = env.step(expert.act()[0])
            phase = expert.phase_names[0]
            if before == "push" and phase != "push" and expert.clip[0] > 0:
                pending = {"seed": seed, **push_record(env.unwrapped, expert)}
            # the routing of that clip is over once its retreat, or its press, hands on
            if pending and before in ("retreat", "press_up") and phase not in PRESS_PHASES:
                pending["seated"] = bool(expert.seated(0)[pending["clip"]])
                records.append(pending)
                pending = None
            before = phase
            if terminated or truncated:
                break
    return records


def summarize(records) -> None:
    for steep in (True, False):
        group = [r for r in records if (r["hop_deg"] > STEEP_DEG) == steep]
        print(
            f"{'steep' if steep else 'shallow'} hops (> {STEEP_DEG:g} deg: {steep}): {len(group)}"
        )
        for held in (True, False):
            sub = [r for r in group if r["joint_held"] == held]
            seated = sum(r["seated"] for r in sub)
            print(f"  joint held between the pads: {held}: {seated}/{len(sub)} seated")
        bins = np.digitize([r["nearest_joint_mm"] for r in group], OFFSET_BINS_MM)
        edges = (-np.inf, *OFFSET_BINS_MM, np.inf)
        for b in range(len(edges) - 1):
            sub = [r for r, rb in zip(group, bins, strict=True) if rb == b]
            if sub:
                seated = sum(r["seated"] for r in sub)
                print(
                    f"  nearest joint {edges[b]:g} .. {edges[b + 1]:g} mm: {seated}/{len(sub)}"
                    " seated"
                )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-clips", "--clips", type=int, default=3, choices=(2, 3))
    parser.add_argument("--episodes", "--seeds", type=int, default=50)
    parser.add_argument("--first-seed", type=int, default=2000)
    parser.add_argument("--robot", default="ur5")
    parser.add_argument("--set", nargs="*", default=[], metavar="FIELD=VALUE")
    parser.add_argument("--json", default=None, help="also write every push's record here")
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error("--episodes must be at least 1")
    if args.first_seed < 0:
        parser.error("--first-seed must be >= 0 (reset seeds are non-negative)")
    overrides = dict(parse_override(item, RoutingExpertConfig()) for item in args.set)
    records = run(args, RoutingExpertConfig(**overrides))
    summarize(records)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(records, f, indent=1)


if __name__ == "__main__":
    main()
