"""WireConfig validation and the builder API, for every registered wire model."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from wirecraft import scene
from wirecraft.assets.wires import WIRE_MODELS, WireConfig, add_wire, end_gap
from wirecraft.assets.wires.base import END_CLEARANCE

MODELS = WIRE_MODELS.names()


def test_registry_lists_the_three_models():
    assert set(MODELS) == {"articulated", "rod", "fem"}


def test_unknown_model_lists_valid_ones():
    with pytest.raises(ValueError, match="articulated.*rod.*fem|valid"):
        WireConfig(model="spaghetti")


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"length": 0.0}, "length"),
        ({"length": -0.1}, "length"),
        ({"radius": 0.0}, "radius"),
        ({"radius": -0.003}, "radius"),
        ({"poisson": 0.5}, "poisson"),
        ({"poisson": -0.1}, "poisson"),
        ({"segments": 1}, "segments"),
        ({"segments": 2.5}, "segments"),
        ({"density": 0.0}, "density"),
        ({"young": -1.0}, "young"),
        ({"damping": -1.0}, "damping"),
        ({"rgba": (1, 0, 0)}, "rgba"),
    ],
)
@pytest.mark.parametrize("model", MODELS)
def test_bad_config_names_the_field(model, kwargs, field):
    with pytest.raises(ValueError, match=field):
        WireConfig(model=model, **kwargs)


@pytest.mark.parametrize("model", MODELS)
def test_defaults_resolve(model):
    cfg = WireConfig(model=model).resolved()
    for name in ("radius", "segments", "density", "young", "poisson", "damping", "friction"):
        assert getattr(cfg, name) is not None
    assert cfg.length == pytest.approx(0.4)
    assert WireConfig(model=model, radius=0.002).resolved().radius == 0.002


def _build(model, pos=(0.1, -0.2, 0.3), quat=(1.0, 0.0, 0.0, 0.0), gravity=True):
    spec = scene.new_spec()
    if not gravity:
        spec.option.gravity = (0.0, 0.0, 0.0)
    wire = add_wire(spec, WireConfig(model=model), name="cable", pos=pos, quat=quat)
    return spec, wire


@pytest.mark.parametrize("model", MODELS)
def test_points_follow_the_wire_frame(model):
    # a wire turned 90 degrees about z runs along world +y from pos
    quat = (np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4))
    spec, wire = _build(model, quat=quat, gravity=False)
    model_, data = scene.compile_spec(spec), None
    data = mujoco.MjData(model_)
    mujoco.mj_forward(model_, data)
    pts = wire.points(model_, data)
    assert pts.shape == (wire.num_points, 3)
    np.testing.assert_allclose(pts[0], (0.1, -0.2, 0.3), atol=1e-6)
    np.testing.assert_allclose(pts[-1], (0.1, 0.2, 0.3), atol=1e-6)
    np.testing.assert_allclose(pts[:, 0], 0.1, atol=1e-6)


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("end", ["start", "end"])
def test_attach_holds_body_at_end_pose(model, end):
    spec, wire = _build(model, gravity=False)
    pos, quat = wire.end_pose(end)
    body = spec.worldbody.add_body(name="plug", pos=pos.tolist(), quat=quat.tolist())
    body.add_freejoint()
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=(0.01, 0.006, 0.004), pos=(0.01, 0, 0))
    wire.attach(spec, end, "plug")
    with pytest.raises(ValueError, match="already attached"):
        wire.attach(spec, end, "plug")
    m = scene.compile_spec(spec)
    d = mujoco.MjData(m)
    d.qvel[:] = 0.0
    for _ in range(100):
        mujoco.mj_step(m, d)
    pts = wire.points(m, d)
    tip = pts[-1] if end == "end" else pts[0]
    # the plug's +x points away from the wire, and its origin lies end_gap out along it
    x_axis = d.body("plug").xmat.reshape(3, 3)[:, 0]
    inward = pts[-2] - pts[-1] if end == "end" else pts[1] - pts[0]
    assert float(np.dot(x_axis, inward / np.linalg.norm(inward))) < -0.99
    np.testing.assert_allclose(d.body("plug").xpos, tip + wire.end_gap * x_axis, atol=2e-4)
    # the box's back face sits on the body's origin: it must not touch the wire (a flex's
    # end element cannot be excluded from contact, so only the gap keeps them apart)
    box = m.body("plug").geomadr[0]
    touching = [c for c in d.contact[: d.ncon] if box in c.geom]
    assert touching == [], [(c.geom, c.flex, c.elem, c.dist) for c in touching]


def test_attach_rejects_bad_end_and_body():
    spec, wire = _build("rod")
    with pytest.raises(ValueError, match="end"):
        wire.attach(spec, "middle", "world")
    with pytest.raises(ValueError, match="nope"):
        wire.attach(spec, "end", "nope")


def test_attaching_a_rod_of_two_segments_is_refused():
    """MuJoCo clamps a rod's last edge only when the rod has at least three edges."""
    spec = scene.new_spec()
    wire = add_wire(spec, WireConfig(model="rod", segments=2), name="wire")
    spec.worldbody.add_body(name="holder")
    with pytest.raises(ValueError, match=">= 3 segments"):
        wire.attach(spec, "end", "holder")


def test_two_wires_in_one_spec():
    spec = scene.new_spec()
    wires = [
        add_wire(spec, WireConfig(model=m), name=f"w{i}", pos=(0.0, 0.05 * i, 0.1))
        for i, m in enumerate(MODELS)
    ]
    m = scene.compile_spec(spec)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    for i, wire in enumerate(wires):
        np.testing.assert_allclose(wire.points(m, d)[:, 1], 0.05 * i, atol=1e-6)


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("radius", [0.002, 0.0045])
def test_end_gap_is_known_before_the_wire_is_built(model, radius):
    """A task places bodies by ``end_gap(config)`` before it builds the wire: it must equal the
    collision reach past the end point that the compiled flex has, plus the clearance."""
    config = WireConfig(model=model, radius=radius)
    spec = scene.new_spec()
    wire = add_wire(spec, config, name="w")
    m = scene.compile_spec(spec)
    flex_reach = float(m.flex_radius[0]) + END_CLEARANCE if m.nflex else 0.0
    assert end_gap(config) == pytest.approx(flex_reach, abs=1e-12)
    assert wire.end_gap == pytest.approx(flex_reach, abs=1e-12)


def test_end_gap_takes_the_default_config_as_add_wire_does():
    spec = scene.new_spec()
    assert end_gap() == add_wire(spec).end_gap == end_gap(WireConfig())
