"""Wire + connector assemblies: every wire model with every plug falls, lands and settles; the
plug goes where an episode asks for it; the bodies on the cable's ends do not touch its wire."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import wirecraft
from wirecraft.assets.assembly import WireAssembly
from wirecraft.assets.connectors import CONNECTORS, add_plug, make_connector
from wirecraft.assets.wires import WIRE_MODELS, WireConfig, add_wire
from wirecraft.scene import add_table, compile_spec, new_spec

FALL_SECONDS = 10.0
SETTLED_AFTER = 9.0  # s: the last second must be calm


def drop(wire_model: str, connector_name: str, height: float = 0.10):
    spec = new_spec("drop")
    add_table(spec)
    # A small yaw and tilt so that the landing is not perfectly symmetric.
    quat = (0.9990482, 0.0, 0.0436194, 0.0)  # 5 degrees about y: the plug end lands first
    wire = add_wire(
        spec, WireConfig(model=wire_model), name="wire", pos=(-0.2, 0.0, height), quat=quat
    )
    pos, pquat = wire.end_pose("end")
    add_plug(spec, make_connector(connector_name), name="plug", pos=tuple(pos), quat=tuple(pquat))
    wire.attach(spec, "end", "plug")
    return spec, wire


@pytest.mark.parametrize("connector", CONNECTORS.names())
@pytest.mark.parametrize("wire_model", WIRE_MODELS.names())
def test_wire_with_plug_falls_and_settles(wire_model, connector):
    spec, wire = drop(wire_model, connector)
    model = compile_spec(spec)
    data = mujoco.MjData(model)
    plug = model.body("plug").id
    wire_site = model.site("plug_wire").id
    dt = model.opt.timestep
    late_speed, previous = 0.0, None
    for step in range(int(FALL_SECONDS / dt)):
        mujoco.mj_step(model, data)
        if step * dt >= SETTLED_AFTER:
            # Linear speeds of every wire point and of the plug, by finite differences.
            now = np.vstack([wire.points(model, data), data.xpos[plug]])
            if previous is not None:
                late_speed = max(
                    late_speed, float(np.linalg.norm(now - previous, axis=1).max() / dt)
                )
            previous = now
    assert np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel)), "diverged"
    assert late_speed < 10.0, f"still moving at {late_speed:.2f} m/s after {SETTLED_AFTER} s"
    points = wire.points(model, data)
    radius = WireConfig(model=wire_model).resolved().radius
    # Resting on the table: not below it, not floating.
    assert points[:, 2].min() > radius - 1e-3
    assert points[:, 2].max() < 0.03
    assert data.xpos[plug, 2] < 0.03
    # Still attached: the wire's last point lies end_gap behind the plug's wire site, along
    # the plug's axis (wires/base.py).
    plug_x = data.xmat[plug].reshape(3, 3)[:, 0]
    off = np.linalg.norm(points[-1] + wire.end_gap * plug_x - data.site_xpos[wire_site])
    assert off < 2e-3, f"wire end {off * 1000:.1f} mm from where the plug holds it"


@pytest.mark.parametrize("wire_model", WIRE_MODELS.names())
def test_place_puts_the_plug_where_asked_and_the_wire_behind_it(wire_model):
    """``place`` lays the cable straight and puts the plug's origin at the requested point (or
    straight above it, lifted clear of the table); the wire ends ``end_gap`` behind it."""
    env = wirecraft.make("insertion", wire=wire_model)
    env.reset(seed=0)
    u = env.unwrapped
    assembly = u.task.assembly
    axis = np.array([0.0, 1.0, 0.0])
    asked = np.array([0.45, 0.05, 0.05])
    placed = assembly.place(u.model, u.data, asked, axis, 0.0)
    np.testing.assert_allclose(placed[:2], asked[:2], atol=1e-9)
    plug_pos, plug_rot = assembly.plug_pose(u.data)
    np.testing.assert_allclose(plug_pos, placed, atol=1e-6)
    np.testing.assert_allclose(plug_rot[:, 0], axis, atol=1e-6)
    points = assembly.wire.points(u.model, u.data)
    np.testing.assert_allclose(points[-1], placed - assembly.wire.end_gap * axis, atol=1e-4)
    length = np.linalg.norm(np.diff(points, axis=0), axis=1).sum()
    assert length == pytest.approx(assembly.wire.config.length, rel=1e-3)


@pytest.mark.parametrize("connector", CONNECTORS.names())
@pytest.mark.parametrize("wire_model", WIRE_MODELS.names())
def test_no_plug_touches_its_own_wire_as_built(wire_model, connector):
    """Every plug, attached at ``end_pose``, clears its wire: a contact there would push the
    wire's end while the attachment holds it (a flex element's contact cannot be excluded;
    the rod's end capsule 2.6 mm inside the plug made the physics diverge)."""
    spec, wire = drop(wire_model, connector)
    model = compile_spec(spec)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    plug = model.body("plug").id
    wire_contacts = [
        c
        for c in data.contact[: data.ncon]
        if plug in (model.geom_bodyid[g] for g in c.geom if g >= 0)
    ]
    assert wire_contacts == [], [(c.geom, c.flex, c.elem, c.dist) for c in wire_contacts]


@pytest.mark.parametrize("wire_model", WIRE_MODELS.names())
def test_the_cable_as_built_touches_neither_its_plug_nor_its_clamp(wire_model):
    """The tasks' cable (``WireAssembly``: clamp block, wire, plug), as built in the air: no
    contact at all, so none between the wire and the bodies on its ends."""
    spec = new_spec("cable")
    WireAssembly.build(spec, WireConfig(model=wire_model), make_connector("ethernet"))
    model = compile_spec(spec)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    touching = [(c.geom, c.flex, c.elem, c.dist) for c in data.contact[: data.ncon]]
    assert touching == []


@pytest.mark.parametrize("wire_model", WIRE_MODELS.names())
def test_a_bolted_clamp_sits_where_the_wire_starts_as_built(wire_model):
    """``attach`` wants each body at the wire's ``end_pose`` when the spec is built: a rod end
    clamped in its body takes the as-built pose as its rest shape (a clamp bolted elsewhere
    gave the rod a 20 cm first edge, and the seating task diverged at reset)."""
    spec = new_spec("bolted")
    exit_point, yaw = (0.3, -0.2, 0.02), 0.7
    assembly = WireAssembly.build(
        spec,
        WireConfig(model=wire_model),
        make_connector("ethernet"),
        fixed_clamp=(exit_point, yaw),
    )
    model = compile_spec(spec)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    pos, quat = assembly.wire.end_pose("start")
    clamp = model.body("clamp").id
    assert np.allclose(data.xpos[clamp], exit_point, atol=1e-12)
    assert np.allclose(pos, exit_point, atol=1e-12)
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, quat)
    assert np.allclose(data.xmat[clamp], rot, atol=1e-12)
    # the wire leaves the exit along the heading, as built
    points = assembly.wire.points(model, data)
    heading = (points[-1] - points[0]) / np.linalg.norm(points[-1] - points[0])
    assert np.allclose(heading, (np.cos(yaw), np.sin(yaw), 0.0), atol=1e-9)


@pytest.mark.parametrize("seed", range(4))
def test_seating_with_the_rod_settles_at_the_first_attempt(seed):
    env = wirecraft.make("seating", channel="curved", wire="rod")
    _, info = env.reset(seed=seed)
    env.close()
    assert info["reset_attempts"] == 1 and not info["diverged"]
