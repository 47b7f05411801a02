"""Physics steps per second of each wire model alone on the table, on one core.

Scene: the table, the default wire lying on it, its end attached to an Ethernet plug (10 g);
timestep 2 ms.  ``wirecraft bench --suite wires`` prints the table; ``--json PATH`` writes it.
"""

from __future__ import annotations

import time

import mujoco
import numpy as np

from wirecraft import scene
from wirecraft.assets.connectors import add_plug, make_connector
from wirecraft.assets.wires import WIRE_MODELS, WireConfig, add_wire

TARGETS = {"articulated": 15_000, "rod": 5_000, "fem": 1_000}  # steps/s


def build(model_name: str) -> tuple[mujoco.MjModel, mujoco.MjData]:
    spec = scene.new_spec(f"bench_{model_name}")
    scene.add_table(spec)
    config = WireConfig(model=model_name)
    radius = config.resolved().radius
    wire = add_wire(spec, config, name="wire", pos=(-0.2, 0.0, radius + 0.0005))
    pos, quat = wire.end_pose("end")
    add_plug(spec, make_connector("ethernet"), name="plug", pos=tuple(pos), quat=tuple(quat))
    wire.attach(spec, "end", "plug")
    model = scene.compile_spec(spec)
    return model, mujoco.MjData(model)


def measure(model_name: str, seconds: float, warmup: float = 1.0) -> dict:
    model, data = build(model_name)
    dt = model.opt.timestep
    for _ in range(int(warmup / dt)):
        mujoco.mj_step(model, data)
    steps = int(seconds / dt)
    t0 = time.perf_counter()
    for _ in range(steps):
        mujoco.mj_step(model, data)
    wall = time.perf_counter() - t0
    sps = steps / wall
    return {
        "wire": model_name,
        "timestep": dt,
        "nv": int(model.nv),
        "physics_steps_per_s": round(sps, 1),
        "realtime_factor": round(sps * dt, 2),
        "target_steps_per_s": TARGETS.get(model_name),
        "reached": bool(sps >= TARGETS.get(model_name, 0)),
        "finite": bool(np.all(np.isfinite(data.qpos))),
    }


def run(seconds: float = 5.0, models: list[str] | None = None) -> list[dict]:
    from tqdm import tqdm

    models = models or WIRE_MODELS.names()
    for name in models:
        WIRE_MODELS.get(name)  # unknown names fail before any timing
    return [measure(name, seconds) for name in tqdm(models, desc="bench wires", unit="model")]


def print_table(rows: list[dict]) -> None:
    print(f"{'wire':<12} {'nv':>4} {'steps/s':>10} {'x real time':>11} {'target':>8}  reached")
    for r in rows:
        print(
            f"{r['wire']:<12} {r['nv']:>4} {r['physics_steps_per_s']:>10.0f} "
            f"{r['realtime_factor']:>11.2f} {r['target_steps_per_s']:>8}  {r['reached']}"
        )
