"""``wirecraft demo``: the main job on a CPU, end to end, in about a minute.

1. Each task family (insertion, routing, seating; UR5, capsule-chain wire) is reset and
   driven by its scripted expert for a whole episode where one exists (insertion so far), else
   for a few seconds by a seeded random policy: the table reports control steps per second,
   reward and success, and ``tasks.png`` shows side views over time.
2. Each wire model, with an Ethernet plug on its end, is dropped into a channel on the task
   board: physics speed, divergence and how much of the wire came to rest in the channel
   (``wires.png``).
"""

from __future__ import annotations

import time
from pathlib import Path

import mujoco
import numpy as np
from tqdm import tqdm

from wirecraft.assets.connectors import add_plug, add_port, make_connector
from wirecraft.assets.fixtures import ChannelConfig, add_board, add_channel, add_clip
from wirecraft.assets.wires import WIRE_MODELS, WireConfig, add_wire
from wirecraft.render import FastRenderer, ViewPoint, save_png
from wirecraft.scene import add_table, compile_spec, new_spec

BOARD_TOP = 0.01
DROP_HEIGHT = 0.04  # m above the channel floor
VIEW = ViewPoint(lookat=(0.02, 0.0, 0.02), distance=0.55, azimuth=115, elevation=-30)
SHOT_TIMES = (0.05, 0.12, 0.25)  # s, plus the final state: the fall, the impact, the settling


def build_drop_scene(wire_model: str):
    spec = new_spec(f"demo_{wire_model}")
    add_table(spec)
    add_board(spec)
    channel = add_channel(spec, ChannelConfig(), pos=(-0.2, 0.0, BOARD_TOP))
    add_channel(spec, ChannelConfig.curved(), name="curved", pos=(-0.2, -0.09, BOARD_TOP))
    add_clip(spec, pos=(0.05, 0.09, BOARD_TOP))
    connector = make_connector("ethernet")
    add_port(spec, connector, pos=(0.25, 0.09, BOARD_TOP + 0.03))
    floor_z = BOARD_TOP + channel.config.floor
    wire = add_wire(
        spec, WireConfig(model=wire_model), name="wire", pos=(-0.2, 0.0, floor_z + DROP_HEIGHT)
    )
    pos, quat = wire.end_pose("end")
    add_plug(spec, connector, name="plug", pos=tuple(pos), quat=tuple(quat))
    wire.attach(spec, "end", "plug")
    return spec, wire, channel


# (task, keyword arguments, policy): "expert" runs the task's scripted expert for a whole
# episode; "random" a seeded random policy for ``seconds``.
DEMO_TASKS = (
    ("insertion", {"connector": "ethernet"}, "expert"),
    ("routing", {"num_clips": 2}, "random"),
    ("seating", {"channel": "curved"}, "random"),
)


def _policy(kind: str, env):
    if kind == "expert":
        from wirecraft.experts import InsertionExpert
        from wirecraft.experts.insertion import InsertionExpertConfig

        expert = InsertionExpert(env, InsertionExpertConfig(release=False))
        expert.reset()
        return lambda obs: expert.act(obs)[0]
    return lambda obs: env.action_space.sample()


def run_task_demo(out_dir: str | Path, seconds: float = 2.0, seed: int = 0) -> list[dict]:
    """A rollout of every task family (scripted expert where there is one, else a random
    policy); returns one summary row per task."""
    import wirecraft

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows, strips = [], []
    for task, kwargs, policy_kind in tqdm(DEMO_TASKS, desc="demo tasks", unit="task"):
        env = wirecraft.make(task, render_mode="rgb_array", image_size=240, **kwargs)
        env.action_space.seed(seed)
        obs, info = env.reset(seed=seed)
        policy = _policy(policy_kind, env)
        if policy_kind == "expert":
            steps = env.unwrapped.max_steps
        else:
            steps = max(1, int(seconds * wirecraft.envs.CONTROL_HZ))
        shots = set(np.linspace(0, steps - 1, 4).round().astype(int).tolist())
        images, total, stepping = [env.render()], 0.0, 0.0
        for step in range(steps):
            action = policy(obs)
            tic = time.perf_counter()
            obs, reward, _, truncated, info = env.step(action)
            stepping += time.perf_counter() - tic
            total += reward
            if step in shots:
                images.append(env.render())
            if truncated:
                break
        rows.append(
            {
                "task": task,
                **kwargs,
                "policy": policy_kind,
                "instruction": env.unwrapped.task.instruction,
                "control_steps_per_s": round((step + 1) / stepping, 1),
                "return": round(total, 2),
                "success": bool(info["success"]),
                "diverged": bool(info["diverged"]),
            }
        )
        strips.append(np.concatenate(images, axis=1))
        env.close()
    save_png(np.concatenate(strips, axis=0), out_dir / "tasks.png")
    return rows


def run_demo(out_dir: str | Path, seconds: float = 2.0) -> list[dict]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows, strips = [], []
    for wire_model in tqdm(WIRE_MODELS.names(), desc="demo", unit="wire model"):
        spec, wire, channel = build_drop_scene(wire_model)
        model = compile_spec(spec)
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        steps = int(seconds / model.opt.timestep)
        shots = {int(t / model.opt.timestep) for t in SHOT_TIMES if t < seconds} | {steps - 1}
        images, physics_time, diverged = [], 0.0, False
        with FastRenderer(model, height=240, width=320) as renderer:
            for step in range(steps):
                tic = time.perf_counter()
                mujoco.mj_step(model, data)
                physics_time += time.perf_counter() - tic
                if not np.all(np.isfinite(data.qpos)):
                    diverged = True
                    break
                if step in shots:
                    images.append(renderer.render(data, VIEW.camera()))
        points = wire.points(model, data)
        rows.append(
            {
                "wire": wire_model,
                "physics_steps_per_s": round(steps / physics_time) if physics_time else None,
                "realtime_factor": round(seconds / physics_time, 2) if physics_time else None,
                "diverged": diverged,
                "fraction_in_channel": round(channel.fraction_inside(points), 3),
                "lowest_point_mm": round(float(points[:, 2].min()) * 1000, 2),
            }
        )
        if images:
            strips.append(np.concatenate(images, axis=1))
    if strips:
        width = max(s.shape[1] for s in strips)
        padded = [np.pad(s, ((0, 0), (0, width - s.shape[1]), (0, 0))) for s in strips]
        save_png(np.concatenate(padded, axis=0), out_dir / "wires.png")
    return rows
