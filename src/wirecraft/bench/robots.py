"""Physics throughput of each robot on one core at 2 ms: alone, and with a wire and a plug.

    python benchmarks/bench_robots.py [--seconds 3] [--json PATH]

Rows: robot, scene ("robot" = table + robot holding its home pose; "robot+wire" = the same
plus a 12-capsule articulated wire with a plug on its end lying on the table under the
gripper), physics steps/s (``mj_step`` calls), and control steps/s with the ``cartesian``
controller in the loop (8 physics steps per control step).
"""

from __future__ import annotations

import time

import mujoco
import numpy as np

from wirecraft.assets.connectors import add_plug, make_connector
from wirecraft.assets.robots import ROBOTS, add_robot
from wirecraft.control import make_controller
from wirecraft.scene import add_table, new_spec

WIRE_LENGTH = 0.4  # m
WIRE_SEGMENTS = 12


def _add_capsule_chain(spec: mujoco.MjSpec, pos: np.ndarray) -> str:
    """Fallback when wirecraft.assets.wires is unavailable: 12 hinged capsules and a plug body."""
    seg = WIRE_LENGTH / WIRE_SEGMENTS
    parent = spec.worldbody.add_body(name="wire_0", pos=pos)
    parent.add_freejoint()
    for i in range(WIRE_SEGMENTS):
        body = parent if i == 0 else parent.add_body(name=f"wire_{i}", pos=(seg, 0.0, 0.0))
        if i:
            for axis in ((0, 1, 0), (0, 0, 1)):
                body.add_joint(
                    type=mujoco.mjtJoint.mjJNT_HINGE,
                    axis=axis,
                    stiffness=0.05,
                    damping=0.01,
                    range=(-0.5, 0.5),
                )
        body.add_geom(
            type=mujoco.mjtGeom.mjGEOM_CAPSULE,
            size=(0.004, seg / 2, 0.0),
            pos=(seg / 2, 0.0, 0.0),
            quat=(0.7071068, 0.0, 0.7071068, 0.0),
            density=2000.0,
        )
        parent = body
    return parent.name


def build(robot: str, with_wire: bool):
    spec = new_spec(f"bench_{robot}")
    add_table(spec)
    handle = add_robot(spec, robot, keyframe=False)
    wire_kind = "none"
    if with_wire:
        centre = np.asarray(handle.base_pos) + handle.home_tcp_pos
        start = np.array([centre[0] - WIRE_LENGTH - 0.02, centre[1] + 0.05, 0.006])
        connector = make_connector("ethernet")
        try:
            from wirecraft.assets.wires import WireConfig, add_wire

            wire = add_wire(
                spec,
                WireConfig(model="articulated", segments=WIRE_SEGMENTS),
                name="wire",
                pos=tuple(start),
            )
            pos, quat = wire.end_pose("end")
            add_plug(spec, connector, name="plug", pos=tuple(pos), quat=tuple(quat))
            wire.attach(spec, "end", "plug")
            wire_kind = "wirecraft articulated"
        except Exception:  # the wire module is optional here
            last = _add_capsule_chain(spec, start)
            add_plug(
                spec,
                connector,
                name="plug",
                parent=spec.body(last),
                free=False,
                pos=(WIRE_LENGTH / WIRE_SEGMENTS, 0.0, 0.0),
            )
            wire_kind = "benchmark capsule chain"
    model = spec.compile()
    data = mujoco.MjData(model)
    handle.reset_home(model, data)
    return handle, model, data, wire_kind


def measure(robot: str, with_wire: bool, seconds: float) -> dict:
    handle, model, data, wire_kind = build(robot, with_wire)
    mujoco.mj_step(model, data, nstep=500)  # settle
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        mujoco.mj_step(model, data, nstep=200)
        n += 200
    physics = n / (time.perf_counter() - t0)
    ctl = make_controller("cartesian", handle, model)
    ctl.reset(data)
    rng = np.random.default_rng(0)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        action = np.zeros(7)
        action[:6] = 0.2 * rng.uniform(-1, 1, 6) * (n % 40 < 20)
        ctl.step(data, action)
        n += 1
    control = n / (time.perf_counter() - t0)
    return {
        "robot": robot,
        "scene": "robot+wire" if with_wire else "robot",
        "wire": wire_kind,
        "nv": int(model.nv),
        "physics_steps_per_s": round(physics),
        "control_steps_per_s": round(control),
        "realtime_factor": round(physics * model.opt.timestep, 1),
        "finite": bool(np.all(np.isfinite(data.qpos))),
    }


def run(seconds: float = 3.0) -> list[dict]:
    from tqdm import tqdm

    cases = [(r, w) for r in ROBOTS.names() for w in (False, True)]
    return [measure(r, w, seconds) for r, w in tqdm(cases, desc="bench robots", unit="row")]


def print_table(rows: list[dict]) -> None:
    header = (
        f"{'robot':6} {'scene':11} {'nv':>3} {'physics/s':>10} {'control/s':>10} {'x realtime':>10}"
    )
    print(header)
    print("-" * len(header))
    for row in rows:
        print(
            f"{row['robot']:6} {row['scene']:11} {row['nv']:3d} {row['physics_steps_per_s']:10d} "
            f"{row['control_steps_per_s']:10d} {row['realtime_factor']:10.1f}"
        )
    print(f"wire: {rows[1]['wire']}; timestep 2 ms; control = 8 physics steps + cartesian IK")
