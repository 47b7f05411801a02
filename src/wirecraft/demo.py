"""``wirecraft demo``: the main job on a CPU, end to end, in about a minute.

1. Each task family (insertion with an Ethernet plug, routing through 1 clip, seating in the
   straight channel; UR5, capsule-chain wire) is reset with a fixed seed and driven by its
   scripted expert until success has held 0.5 s or the 8 s episode ends.  Each episode's side
   camera is written as an MP4 video (``TASK.mp4``, 30 fps), ``tasks.png`` shows four side
   views per task, and the table (``summary.md``) reports success, the time of first success,
   control steps per second and the return.
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
from wirecraft.mp4 import write_mp4
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


def demo_tasks() -> list[tuple[str, dict]]:
    """(family, its ``demo_options``) of every registered family: each is driven by its
    scripted expert (``experts.expert_class``)."""
    from wirecraft.tasks import TASKS

    return [(name, dict(TASKS.get(name).demo_options)) for name in TASKS]


VIDEO_FPS = 30
VIDEO_SIZE = 240
SUCCESS_HOLD_STEPS = 30  # 0.5 s at 60 Hz: the episode (and its video) ends then


def run_task_demo(out_dir: str | Path, seed: int = 0) -> list[dict]:
    """One seeded episode of every task family with its scripted expert; writes a side-camera
    video per task and ``tasks.png``; returns one summary row per task."""
    import wirecraft
    from wirecraft.envs import CONTROL_HZ
    from wirecraft.experts import expert_class

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows, strips = [], []
    stride = CONTROL_HZ // VIDEO_FPS
    for task, kwargs in tqdm(demo_tasks(), desc="demo tasks", unit="task"):
        expert_cls = expert_class(task)
        env = wirecraft.make(task, control=expert_cls.CONTROL, **kwargs)
        u = env.unwrapped
        obs, info = env.reset(seed=seed)
        expert = expert_cls(env, seed=seed)
        renderer = FastRenderer(u.model, VIDEO_SIZE, VIDEO_SIZE)
        frames = [renderer.render(u.data, u.robot.side_camera)]
        total, stepping, held, first_success = 0.0, 0.0, 0, None
        for step in range(u.max_steps):
            action = expert.act(obs)[0]
            tic = time.perf_counter()
            obs, reward, terminated, truncated, info = env.step(action)
            stepping += time.perf_counter() - tic
            total += reward
            if (step + 1) % stride == 0:
                frames.append(renderer.render(u.data, u.robot.side_camera))
            held = held + 1 if info["success"] else 0
            if info["success"] and first_success is None:
                first_success = step + 1
            if terminated or truncated or held >= SUCCESS_HOLD_STEPS:
                break
        renderer.close()
        video = write_mp4(frames, out_dir / f"{task}.mp4", VIDEO_FPS)
        picks = np.linspace(0, len(frames) - 1, 4).round().astype(int)
        strips.append(np.concatenate([frames[i] for i in picks], axis=1))
        rows.append(
            {
                "task": task,
                **kwargs,
                "policy": expert_cls.__name__,
                "seed": seed,
                "instruction": u.task.instruction,
                "control_steps": step + 1,
                "control_steps_per_s": round((step + 1) / stepping, 1),
                "return": round(total, 2),
                "success": bool(info["success"]),
                "first_success_s": None
                if first_success is None
                else round(first_success / CONTROL_HZ, 2),
                "diverged": bool(info["diverged"]),
                "video": video.name,
            }
        )
        env.close()
    save_png(np.concatenate(strips, axis=0), out_dir / "tasks.png")
    return rows


def summary_markdown(tasks: list[dict], wires: list[dict]) -> str:
    """The demo's results as markdown tables."""
    lines = [
        "# WireCraft demo",
        "",
        "| task | expert | seed | success | first success (s) | steps | steps/s | return | video |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in tasks:
        first = "-" if r["first_success_s"] is None else r["first_success_s"]
        lines.append(
            f"| {r['task']} | {r['policy']} | {r['seed']} | {'yes' if r['success'] else 'no'} "
            f"| {first} | {r['control_steps']} | {r['control_steps_per_s']} | {r['return']} "
            f"| [{r['video']}]({r['video']}) |"
        )
    lines += [
        "",
        "| wire | physics steps/s | x real time | in channel | diverged |",
        "|---|---|---|---|---|",
    ]
    for r in wires:
        lines.append(
            f"| {r['wire']} | {r['physics_steps_per_s']} | {r['realtime_factor']} "
            f"| {r['fraction_in_channel']:.0%} | {'yes' if r['diverged'] else 'no'} |"
        )
    return "\n".join(lines) + "\n"


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
