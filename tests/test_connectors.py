"""Connector fit in simulation: aligned plugs seat; press fits and wrong orientations do not."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from wirecraft.assets.connectors import (
    CONNECTORS,
    FLIP_ABOUT_AXIS,
    add_plug,
    add_port,
    make_connector,
)
from wirecraft.scene import compile_spec, new_spec

PUSH = 5.0  # N along the insertion axis, at most
PUSH_SPEED = 0.05  # m/s: a hand or robot pushes slowly; a bare 5 N would fire the plug in
PORT_POS = np.array([0.0, 0.0, 0.2])
# "Does not enter": the tip stays in the first quarter of the socket (a blocked plug can still
# tilt into the rattle slack at the mouth by a millimetre or two; seated is the full depth).
BLOCKED_FRACTION = 0.25


def push_plug(connector, *, quat=(1.0, 0.0, 0.0, 0.0), offset=(0.0, 0.0), seconds=1.0):
    """Start the plug tip 2 mm before the socket mouth and push it along +x with a speed servo
    capped at PUSH newtons; return the tip's final position in the port frame and the largest
    speed seen."""
    spec = new_spec("fit")
    add_port(spec, connector, pos=tuple(PORT_POS))
    start = PORT_POS + np.array([-connector.plug_length - 0.002, offset[0], offset[1]])
    add_plug(spec, connector, pos=tuple(start), quat=quat)
    model = compile_spec(spec)
    model.opt.gravity[:] = 0.0  # nothing holds the plug before it enters: fit is geometry only
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    plug = model.body("plug").id
    tip = model.site("plug_tip").id
    top_speed = 0.0
    for _ in range(int(seconds / model.opt.timestep)):
        gain = model.body_mass[plug] / (10 * model.opt.timestep)  # closes a speed gap in ~10 steps
        data.xfrc_applied[plug, 0] = np.clip(gain * (PUSH_SPEED - data.qvel[0]), -PUSH, PUSH)
        mujoco.mj_step(model, data)
        top_speed = max(top_speed, float(np.linalg.norm(data.qvel[:3])))
    assert np.all(np.isfinite(data.qpos)), "simulation diverged"
    return data.site_xpos[tip] - PORT_POS, top_speed


@pytest.mark.parametrize("clearance", [0.0005, 0.003])
@pytest.mark.parametrize("name", CONNECTORS.names())
def test_aligned_plug_seats(name, clearance):
    connector = make_connector(name, clearance)
    # Start off-centre by 40% of the clearance, as a real aligned insertion would be.
    tip, _ = push_plug(connector, offset=(0.4 * clearance, -0.4 * clearance))
    assert tip[0] == pytest.approx(connector.cavity_depth, abs=0.001), f"tip at {tip}"
    assert np.hypot(tip[1], tip[2]) < clearance * 1.5 + 1e-4


@pytest.mark.parametrize("name", CONNECTORS.names())
def test_press_fit_does_not_enter(name):
    connector = make_connector(name, -0.0005, allow_interference=True)
    tip, _ = push_plug(connector)
    assert tip[0] < BLOCKED_FRACTION * connector.cavity_depth, f"entered a press fit: tip {tip}"


@pytest.mark.parametrize("clearance", [0.0005, 0.003])
@pytest.mark.parametrize("name", CONNECTORS.names())
def test_upside_down_plug_enters_only_if_symmetric(name, clearance):
    connector = make_connector(name, clearance)
    tip, _ = push_plug(connector, quat=FLIP_ABOUT_AXIS)
    if connector.symmetry == 1:
        assert tip[0] < BLOCKED_FRACTION * connector.cavity_depth, f"entered upside down: {tip}"
    else:
        assert tip[0] == pytest.approx(connector.cavity_depth, abs=0.001)


@pytest.mark.parametrize("name", CONNECTORS.names())
def test_sites_follow_frame_convention(name):
    connector = make_connector(name, 0.003)
    spec = new_spec()
    add_port(spec, connector)
    add_plug(
        spec, connector, free=False, pos=(connector.cavity_depth - connector.plug_length, 0.0, 0.0)
    )
    model = compile_spec(spec)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    # Placed seated: tip on the seated target, entry at the origin, grasp point on the tail.
    np.testing.assert_allclose(data.site("plug_tip").xpos, data.site("port_seated").xpos, atol=1e-9)
    np.testing.assert_allclose(data.site("port_entry").xpos, 0.0, atol=1e-12)
    grasp_x = data.site("plug_grasp").xpos[0] - data.site("plug_wire").xpos[0]
    assert 0 < grasp_x < connector.tail_length
    assert model.body("plug").mass[0] == pytest.approx(0.01, rel=1e-6)


def test_unknown_connector_lists_valid_names():
    with pytest.raises(ValueError, match="ethernet"):
        make_connector("hdmi")


@pytest.mark.parametrize("bad", [-0.001, float("nan"), 0.05])
def test_bad_clearance_names_the_field(bad):
    with pytest.raises(ValueError, match="clearance"):
        make_connector("cuboid", bad)
