"""``WireHandle.set_centerline``: put any wire model into a given shape (task resets, tests).

Checks, for every registered wire model: the as-built straight line round-trips exactly; L, arc
and zigzag polylines (translated and yawed) are followed, the state is consistent with the
model's constraints (nothing jumps, attached plugs placed at the returned poses stay put); a
wire laid into a channel stays in it under gravity; the call is deterministic.

"Nothing jumps" is checked with gravity *and elasticity* off (``mjDSBL_SPRING``): the wires'
rest shape is straight, so a bent wire is elastically loaded and, with nothing holding it (no
gravity, so no friction), springs back by 5-20 cm within 0.5 s.  That is physics, not an
inconsistent state; what set_centerline guarantees is that constraints (edge lengths, joint
limits, attachments) are satisfied.  See docs/physics.md.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from wirecraft import scene
from wirecraft.assets.connectors import add_plug, make_connector
from wirecraft.assets.fixtures import ChannelConfig, add_channel
from wirecraft.assets.wires import WIRE_MODELS, WireConfig, add_wire, shape

MODELS = WIRE_MODELS.names()
# m: centre-line height of the shapes "on the table": the ethernet plug (whose shell reaches
# 5.5-10 mm from its axis) clears the table top at any roll, so only the wire and its
# attachments act.
LINE_Z = 0.012
YAW = 0.7
SHIFT = np.array([-0.1, 0.15, 0.0])
SEG_FEM = 0.02  # m, FEM cell length (default 0.4 m wire, 20 cells)


def _shape(name: str, z: float) -> np.ndarray:
    """Polylines in a local frame starting at the origin along +x, all longer than 0.4 m."""
    if name == "L":  # 0.12 m, a quarter circle of radius 80 mm (60 points), 0.2 m
        arc = [
            (0.12 + 0.08 * math.sin(a), 0.08 - 0.08 * math.cos(a), z)
            for a in np.linspace(0.0, math.pi / 2, 60)
        ]
        return np.array([(0.0, 0.0, z), *arc, (0.2, 0.3, z)])
    if name == "arc":  # radius 0.3 m, 0.42 m long
        return np.array(
            [(0.3 * math.sin(a), 0.3 - 0.3 * math.cos(a), z) for a in np.linspace(0, 1.4, 60)]
        )
    if name == "zigzag":  # legs of 95 and 4 x 90 mm, kinks of +-20 degrees (between nodes)
        points, heading = [np.zeros(2)], 0.0
        for bend, leg in zip((0.0, 20.0, -20.0, -20.0, 20.0), (0.095, *[0.09] * 4), strict=True):
            heading += math.radians(bend)
            points.append(points[-1] + leg * np.array([math.cos(heading), math.sin(heading)]))
        return np.array([(x, y, z) for x, y in points])
    raise ValueError(name)


def _placed(poly: np.ndarray, yaw: float = YAW, shift: np.ndarray = SHIFT) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return poly @ rot.T + shift


def _build(model: str, *, plugs=(), table=True, channel=None, pos=(0.0, 0.0, 0.05), quat=None):
    spec = scene.new_spec()
    if table:
        scene.add_table(spec)
    placed = add_channel(spec, channel[0], pos=channel[1], yaw=channel[2]) if channel else None
    quat = (1.0, 0.0, 0.0, 0.0) if quat is None else quat
    wire = add_wire(spec, WireConfig(model=model), name="cable", pos=pos, quat=quat)
    connector = make_connector("ethernet")
    for end in plugs:
        p, q = wire.end_pose(end)
        add_plug(spec, connector, name=f"plug_{end}", pos=p.tolist(), quat=q.tolist())
        wire.attach(spec, end, f"plug_{end}")
    m = scene.compile_spec(spec)
    return m, mujoco.MjData(m), wire, placed


def _place_plugs(m, d, poses, plugs) -> None:
    for end in plugs:
        joint = m.joint(f"plug_{end}_free")
        adr, dof = joint.qposadr[0], joint.dofadr[0]
        d.qpos[adr : adr + 3] = poses[end][0]
        d.qpos[adr + 3 : adr + 7] = poses[end][1]
        d.qvel[dof : dof + 6] = 0.0
    mujoco.mj_forward(m, d)


QPOS_SIZE = {0: 7, 1: 4, 2: 1, 3: 1}  # free, ball, slide, hinge


def _wire_qpos(m, wire) -> np.ndarray:
    """qpos indices of the joints of the wire's bodies (flex vertex joints have no names)."""
    joints = [j for j in range(m.njnt) if m.body(m.jnt_bodyid[j]).name.startswith(wire.name)]
    adr = [m.jnt_qposadr[j] + k for j in joints for k in range(QPOS_SIZE[int(m.jnt_type[j])])]
    return np.asarray(adr)


# -- straight round trip --------------------------------------------------------------------------


@pytest.mark.parametrize("model", MODELS)
def test_straight_round_trip_equals_as_built(model):
    """Setting the as-built straight line gives back the as-built state and end_pose()."""
    quat = np.concatenate([[math.cos(0.4)], math.sin(0.4) * np.array([0.3, -0.2, 1.0]) / 1.08])
    quat /= np.linalg.norm(quat)
    m, d, wire, _ = _build(model, table=False, pos=(0.1, -0.2, 0.3), quat=quat)
    mujoco.mj_forward(m, d)
    built = wire.points(m, d).copy()
    # disturb the state first (another shape, some motion), then set the straight line
    wire.set_centerline(m, d, _placed(_shape("arc", 0.3)))
    for _ in range(5):
        mujoco.mj_step(m, d)
    start, end = wire.pos, wire.pos + wire.config.length * shape.quat_rotate(wire.quat, [1, 0, 0])
    poses = wire.set_centerline(m, d, np.array([start, end]))
    np.testing.assert_allclose(wire.points(m, d), built, atol=1e-9)
    qpos = _wire_qpos(m, wire)
    np.testing.assert_allclose(d.qpos[qpos], m.qpos0[qpos], atol=1e-9)
    assert not np.any(d.qvel)
    for end_name in ("start", "end"):
        pos, q = wire.end_pose(end_name)
        np.testing.assert_allclose(poses[end_name][0], pos, atol=1e-12)
        np.testing.assert_allclose(poses[end_name][1], q, atol=1e-12)
    # the as-built centre line itself (many points) gives the same
    again = wire.set_centerline(m, d, built)
    np.testing.assert_allclose(wire.points(m, d), built, atol=1e-9)
    np.testing.assert_allclose(again["end"][1], wire.end_pose("end")[1], atol=1e-12)


# -- stress-free shapes with full physics -------------------------------------------------------


def _jump_test(m, d, wire, plugs, seconds=0.5):
    """Max displacement of the centre line and of the plugs (m, rad) over ``seconds``."""
    pts = wire.points(m, d).copy()
    pos = {end: d.body(f"plug_{end}").xpos.copy() for end in plugs}
    mat = {end: d.body(f"plug_{end}").xmat.reshape(3, 3).copy() for end in plugs}
    jump = 0.0
    for _ in range(int(seconds / m.opt.timestep)):
        mujoco.mj_step(m, d)
        jump = max(jump, np.linalg.norm(wire.points(m, d) - pts, axis=1).max())
    assert np.all(np.isfinite(d.qpos))
    moved = max(np.linalg.norm(d.body(f"plug_{end}").xpos - pos[end]) for end in plugs)
    turned = max(
        math.acos(
            np.clip((np.trace(mat[e].T @ d.body(f"plug_{e}").xmat.reshape(3, 3)) - 1) / 2, -1, 1)
        )
        for e in plugs
    )
    return jump, moved, turned


@pytest.mark.parametrize("yaw, roll", [(2.5, 0.4), (math.pi, 0.0)])
@pytest.mark.parametrize("model", MODELS)
def test_straight_wire_moved_anywhere_is_at_rest(model, yaw, roll):
    """A straight line is the wires' rest shape: moved, yawed (even reversed) and rolled, with
    plugs at both ends, it stays put with the full physics on (gravity off).  This also checks
    the rod's reference frames (data.plastic) and the FEM's cross-section."""
    plugs = ("start", "end")
    m, d, wire, _ = _build(model, plugs=plugs)
    m.opt.gravity[:] = 0.0
    poly = _placed(np.array([[0.0, 0.0, LINE_Z], [0.3, 0.0, LINE_Z]]), yaw)  # extended to 0.4
    poses = wire.set_centerline(m, d, poly, roll=roll)
    _place_plugs(m, d, poses, plugs)
    target = shape.resample_polyline(poly, wire.num_points, wire.config.length)
    np.testing.assert_allclose(wire.points(m, d), target, atol=1e-9)
    jump, moved, turned = _jump_test(m, d, wire, plugs)
    # the as-built wire with its plugs moves as much (0.2 mm: the plug attachments settling)
    assert jump < 2e-3 and moved < 2e-3 and turned < 0.01, (jump, moved, turned)


# -- shapes on the table --------------------------------------------------------------------------

# (shape, roll); tolerances: max |points - polyline resampled by arc length| and max distance of
# the points to the polyline, metres (docs/physics.md, "Setting a shape").  Nodes are placed on
# the polyline one segment apart, so after each kink they lag their arc-length position by up
# to l (1 - cos(kink / 2)); the FEM's centre line is straight inside each 20 mm cell, so a kink
# inside a cell is cut by up to (a / 2) sin(kink / 2) (1.7 mm at 20 degrees).
CASES = [("L", 0.0), ("arc", 0.4), ("zigzag", 0.0)]
TOL_RESAMPLED = {"articulated": 3e-3, "rod": 1e-3, "fem": 1e-3}
TOL_ON_LINE = {"articulated": 1e-6, "rod": 1e-6, "fem": 1e-3}
FEM_KINK = (SEG_FEM / 2) * math.sin(math.radians(20.0) / 2) + 1e-4


@pytest.mark.parametrize("shape_name, roll", CASES)
@pytest.mark.parametrize("model", MODELS)
def test_shape_on_the_table(model, shape_name, roll):
    plugs = ("start", "end")
    m, d, wire, _ = _build(model, plugs=plugs)
    m.opt.gravity[:] = 0.0
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_SPRING  # see the module docstring
    poly = _placed(_shape(shape_name, LINE_Z))
    poses = wire.set_centerline(m, d, poly, roll=roll)
    _place_plugs(m, d, poses, plugs)

    pts = wire.points(m, d).copy()
    target = shape.resample_polyline(poly, wire.num_points, wire.config.length)
    kinked = shape_name == "zigzag" and model == "fem"
    tol = max(TOL_RESAMPLED[model], FEM_KINK if kinked else 0.0)
    assert np.linalg.norm(pts - target, axis=1).max() < tol
    on_line = FEM_KINK if kinked else TOL_ON_LINE[model]
    assert shape.distance_to_polyline(pts, poly).max() < on_line
    # every equality (edge lengths, attachments) is satisfied as placed
    eq = d.efc_type[: d.nefc] == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    assert np.abs(d.efc_pos[: d.nefc][eq]).max() < 1e-6

    # the end plug's +x is the polyline's end tangent (L and zigzag end on a straight leg), and
    # roll turns it about that tangent
    if shape_name != "arc":
        tangent = poly[-1] - poly[-2]
        x_axis = shape.quat_rotate(poses["end"][1], [1.0, 0.0, 0.0])
        np.testing.assert_allclose(x_axis, tangent / np.linalg.norm(tangent), atol=1e-6)
    if roll:
        plain = wire.set_centerline(m, d, poly)["end"][1]
        turn = shape.axis_angle_quat([1.0, 0.0, 0.0], roll)
        np.testing.assert_allclose(poses["end"][1], shape.quat_mul(plain, turn), atol=1e-9)
        wire.set_centerline(m, d, poly, roll=roll)
        _place_plugs(m, d, poses, plugs)

    jump, moved, turned = _jump_test(m, d, wire, plugs)
    # Without elasticity the FEM is a loose cloud of nodes: even as built, its plugs turn by
    # 0.013 rad in 0.5 s with springs off.
    assert jump < 2e-3 and moved < 2e-3, (jump, moved)
    assert turned < (0.05 if model == "fem" else 0.01), turned


# -- channel --------------------------------------------------------------------------------------


@pytest.mark.parametrize("curved", [False, True], ids=["straight", "curved"])
@pytest.mark.parametrize("model", MODELS)
def test_wire_laid_into_a_channel_stays_there(model, curved):
    """The channel's centre line (on its floor) as the polyline; then 1 s of full physics."""
    config = ChannelConfig.curved() if curved else ChannelConfig()
    pos, yaw = (0.05, -0.1, 0.0), 0.5
    m, d, wire, channel = _build(model, channel=(config, pos, yaw))
    local = config.centerline()
    local[:, 2] += wire.config.radius  # resting on the floor
    wire.set_centerline(m, d, _placed(local, yaw, np.asarray(pos)))
    assert channel.fraction_inside(wire.points(m, d)) > 0.95
    for _ in range(int(1.0 / m.opt.timestep)):  # gravity and elasticity on
        mujoco.mj_step(m, d)
    assert np.all(np.isfinite(d.qpos))
    assert channel.fraction_inside(wire.points(m, d)) > 0.9


# -- determinism and errors -----------------------------------------------------------------------


@pytest.mark.parametrize("model", MODELS)
def test_same_call_gives_bit_identical_state(model):
    m, d, wire, _ = _build(model, plugs=("end",))
    poly = _placed(_shape("zigzag", LINE_Z))
    first = wire.set_centerline(m, d, poly, roll=0.2)
    qpos, plastic = d.qpos.copy(), d.plastic.copy()
    for _ in range(20):
        mujoco.mj_step(m, d)
    second = wire.set_centerline(m, d, poly, roll=0.2)
    wq = _wire_qpos(m, wire)
    assert np.array_equal(d.qpos[wq], qpos[wq])
    assert np.array_equal(d.plastic, plastic)
    for end in ("start", "end"):
        assert np.array_equal(first[end][0], second[end][0])
        assert np.array_equal(first[end][1], second[end][1])
    fresh = mujoco.MjData(m)
    wire.set_centerline(m, fresh, poly, roll=0.2)
    assert np.array_equal(fresh.qpos[wq], qpos[wq])


@pytest.mark.parametrize("model", MODELS)
def test_bad_polylines_are_rejected(model):
    m, d, wire, _ = _build(model, table=False)
    for bad in (np.zeros((3, 2)), np.zeros((1, 3)), np.zeros((4, 3)), np.full((2, 3), np.nan)):
        with pytest.raises(ValueError, match="polyline"):
            wire.set_centerline(m, d, bad)
    with pytest.raises(ValueError, match="roll"):
        wire.set_centerline(m, d, np.array([[0, 0, 0], [1, 0, 0]]), roll=math.inf)


def test_capsule_chain_refuses_bends_over_its_joint_limit():
    m, d, wire, _ = _build("articulated", table=False)
    right_angle = np.array([[0.0, 0.0, 0.1], [0.2, 0.0, 0.1], [0.2, 0.2, 0.1]])
    with pytest.raises(ValueError, match="joint limit"):
        wire.set_centerline(m, d, right_angle)
