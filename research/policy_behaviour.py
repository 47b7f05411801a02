"""What an insertion policy does, step window by step window: the grasp, the lift, the press.

    python research/policy_behaviour.py --policy RUN_DIR|CHECKPOINT|scripted
        [--connector ethernet] [--robot ur5] [--num-envs 16] [--seed 123] [--window 40]
        [--threads 2] [--json out.json]

One deterministic episode in each of ``--num-envs`` environments (reset seed ``--seed``).  After
every step it reads the simulation and, per window of ``--window`` steps, prints over the
environments still in their first episode:

- ``touch``: both pads touch the plug; ``squeeze``: the gripper command also closes them inside
  the tail (the task's ``squeezing``); ``held``: squeezed, the tip 2.5 cm up, nothing of the
  plug on the table or the stand and nothing of the robot on the fixture (the task's
  ``reward_held``: what grasp pays, and bring, align and the orientation terms need);
- ``tip_mm``: median height of the plug tip above the table; ``tcp_mm``: of the TCP;
- ``grasp_mm``: median distance from the TCP to the tail's grasp point;
- ``cross_deg``: median angle between the fingers' closing axis (TCP y) and the plug's long
  axis, folded to 0-90 deg: a grasp across the tail is ~90, a pinch end to end ~0;
- ``entry_cm``: median distance from the plug tip to the socket entry;
- ``grip``, ``z``: mean gripper and vertical (base z) action; ``table``, ``fixture``: the robot
  touching the table, the port or its stand (both paid by the ``collision`` term);
- ``reach``, ``insert``: fraction of environments with that success at some step so far.

The episode's last step is not measured (the vector environment's autoreset has already
replaced its state), nor is an environment after a divergence ends its episode early.

Made to diagnose PPO runs that learn to touch or squeeze the plug without carrying it
(docs/baselines.md); ``--policy scripted`` gives the expert's figures to compare against.
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
from tqdm import tqdm

import wirecraft
from wirecraft.evaluation.policies import load_policy, policy_env_kwargs
from wirecraft.tasks.frame import Frame

COLUMNS = (
    "touch",
    "squeeze",
    "held",
    "tip_mm",
    "tcp_mm",
    "grasp_mm",
    "cross_deg",
    "entry_cm",
    "grip",
    "z",
    "table",
    "fixture",
    "reach",
    "insert",
)


def measure(env, action: np.ndarray) -> dict[str, float]:
    """The figures of one environment after a step taken with ``action``."""
    task, data = env.task, env.data
    frame = Frame.of_data(data)
    touch = bool(task.pads_touching(frame).all())
    squeeze = touch and bool(task.squeezing(action[None])[0])
    tip = data.site_xpos[task.assembly.tip_site]
    tcp = data.site_xpos[task.tcp_site]
    closing = data.site_xmat[task.tcp_site].reshape(3, 3)[:, 1]
    plug_axis = data.xmat[task.assembly.plug_id].reshape(3, 3)[:, 0]
    cross = math.degrees(math.acos(min(1.0, abs(float(closing @ plug_axis)))))
    return {
        "touch": float(touch),
        "squeeze": float(squeeze),
        "held": float(task.reward_held(frame, action[None])[0]),
        "tip_mm": 1000 * float(tip[2]),  # the table's top is z = 0 (scene.add_table)
        "tcp_mm": 1000 * float(tcp[2]),
        "grasp_mm": 1000 * float(np.linalg.norm(tcp - data.site_xpos[task.assembly.grasp_site])),
        "cross_deg": cross,
        "entry_cm": 100 * float(np.linalg.norm(tip - data.site_xpos[task.entry_site])),
        "grip": float(action[-1]),
        "z": float(action[2]),
        "table": float(task.table_collision(frame)[0]),
        "fixture": float(task.fixture_collision(frame)[0]),
    }


def summarize(rows: list[dict[str, float]]) -> dict[str, float]:
    if not rows:
        return {}
    out = {}
    for key in rows[0]:
        values = np.array([row[key] for row in rows])
        median = key.endswith(("_mm", "_deg", "_cm"))
        out[key] = float(np.median(values) if median else np.mean(values))
    return out


def run(args) -> list[dict[str, float]]:
    kwargs = policy_env_kwargs(args.policy, "insertion")
    venv = wirecraft.make_vec(
        "insertion",
        args.num_envs,
        threads=args.threads,
        connector=args.connector,
        robot=args.robot,
        **kwargs,
    )
    envs = venv.envs
    policy = load_policy(args.policy, venv)
    obs, _ = venv.reset(seed=args.seed)
    policy.reset(None)
    steps = envs[0].max_steps
    active = np.ones(args.num_envs, bool)
    reached = np.zeros(args.num_envs, bool)
    inserted = np.zeros(args.num_envs, bool)
    windows, rows = [], []
    for t in tqdm(range(steps), desc="rollout", unit="step"):
        action = np.asarray(policy.act(obs))
        obs, _, terminated, truncated, info = venv.step(action)
        reached |= active & np.asarray(info["reach_success"], bool)
        inserted |= active & np.asarray(info["insert_success"], bool)
        done = np.asarray(terminated) | np.asarray(truncated)
        for i in np.flatnonzero(active & ~done):  # a done one already holds its next episode
            rows.append(measure(envs[i], action[i]))
        active &= ~done
        if (t + 1) % args.window == 0 or t + 1 == steps:
            summary = summarize(rows)
            summary.update(step=t + 1, reach=float(reached.mean()), insert=float(inserted.mean()))
            windows.append(summary)
            rows = []
    venv.close()
    return windows


def print_table(windows: list[dict[str, float]]) -> None:
    print(f"{'steps':>7s} " + " ".join(f"{c:>9s}" for c in COLUMNS))
    for w in windows:
        cells = " ".join(f"{w.get(c, float('nan')):9.2f}" for c in COLUMNS)
        print(f"{w['step']:7d} {cells}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", required=True)
    parser.add_argument("--connector", default="ethernet")
    parser.add_argument("--robot", default="ur5")
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--seed", type=int, default=123)
    parser.add_argument("--window", type=int, default=40)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--json", help="also write the windows to this file")
    args = parser.parse_args()
    if args.num_envs < 1 or args.window < 1:
        parser.error("--num-envs and --window must be >= 1")
    windows = run(args)
    print_table(windows)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(windows, f, indent=1)


if __name__ == "__main__":
    main()
