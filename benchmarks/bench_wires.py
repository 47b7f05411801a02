"""Physics steps per second of each wire model alone on the table, on one core.

Scene: the table, the default wire lying on it, its end attached to a 10 g free box (the plug
stand-in); timestep 2 ms.  Prints a table; ``--json PATH`` writes the rows.

    python benchmarks/bench_wires.py [--seconds 5] [--json out/bench_wires.json]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from wirecraft import physics, scene  # noqa: E402
from wirecraft.assets.wires import WIRE_MODELS, WireConfig, add_wire  # noqa: E402

TARGETS = {"articulated": 15_000, "rod": 5_000, "fem": 1_000}  # steps/s


def build(model_name: str) -> tuple[mujoco.MjModel, mujoco.MjData]:
    spec = scene.new_spec(f"bench_{model_name}")
    scene.add_table(spec)
    config = WireConfig(model=model_name)
    radius = config.resolved().radius
    wire = add_wire(spec, config, name="wire", pos=(-0.2, 0.0, radius + 0.0005))
    pos, quat = wire.end_pose("end")
    plug = spec.worldbody.add_body(name="plug", pos=pos.tolist(), quat=quat.tolist())
    plug.add_freejoint()
    geom = plug.add_geom(
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=(0.01, 0.006, 0.004),
        pos=(0.01, 0.0, 0.0),
        mass=physics.PLUG_MASS,
    )
    physics.stiff_contact(geom, friction=physics.PLUG_FRICTION)
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


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="simulated seconds timed")
    parser.add_argument("--models", nargs="*", default=WIRE_MODELS.names())
    parser.add_argument("--json", type=Path, default=None, help="write the rows as JSON")
    args = parser.parse_args(argv)
    rows = [measure(name, args.seconds) for name in args.models]
    print(f"{'wire':<12} {'nv':>4} {'steps/s':>10} {'RTF':>7} {'target':>8}  reached")
    for r in rows:
        print(
            f"{r['wire']:<12} {r['nv']:>4} {r['physics_steps_per_s']:>10.0f} "
            f"{r['realtime_factor']:>7.2f} {r['target_steps_per_s']:>8}  {r['reached']}"
        )
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rows, indent=2))
    return rows


if __name__ == "__main__":
    main()
