"""Fixtures: the containment predicates used for success agree with the simulated geometry."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from wirecraft.assets.fixtures import ChannelConfig, ClipConfig, add_channel, add_clip
from wirecraft.scene import compile_spec, new_spec

DOWN = np.array([0.0, 0.0, -1.0])


def ray_height(model, data, x, y, top=0.5):
    """Height of the first surface below (x, y), by MuJoCo's own ray caster."""
    geomid = np.zeros(1, dtype=np.int32)
    dist = mujoco.mj_ray(model, data, np.array([x, y, top]), DOWN, None, 1, -1, geomid)
    return top - dist if dist >= 0 else -np.inf


CHANNELS = {
    "straight": ChannelConfig(),
    "curved": ChannelConfig.curved(),
    "max_bends": ChannelConfig.curved((20.0, 20.0, -20.0, -20.0)),
}


@pytest.mark.parametrize("variant", CHANNELS)
def test_channel_floor_and_walls_where_the_predicate_says(variant):
    cfg = CHANNELS[variant]
    spec = new_spec()
    pos, yaw = (0.05, -0.02, 0.01), 0.3
    placed = add_channel(spec, cfg, pos=pos, yaw=yaw)
    model = compile_spec(spec)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    rot = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    for start, heading in cfg.segment_frames():
        direction = np.array([math.cos(heading), math.sin(heading)])
        normal = np.array([-direction[1], direction[0]])
        for u in np.linspace(0.1, 0.9, 5) * cfg.segment_length:
            for v, expect in (
                (0.0, "floor"),
                (0.8 * cfg.inner_width / 2, "floor"),
                (cfg.inner_width / 2 + cfg.wall / 2, "wall"),
            ):
                for side in (1.0, -1.0):
                    xy = rot @ (start + u * direction + side * v * normal) + np.asarray(pos[:2])
                    z = ray_height(model, data, *xy)
                    want = pos[2] + (
                        cfg.floor if expect == "floor" else cfg.floor + cfg.wall_height
                    )
                    assert z == pytest.approx(want, abs=1e-6), (variant, u, v, side)
                    inside = placed.contains(np.array([[*xy, z + 0.002]]))[0]
                    assert inside == (expect == "floor")


def test_channel_fraction_inside_measures_length():
    cfg = ChannelConfig()
    placed = add_channel(new_spec(), cfg)
    line = cfg.centerline(samples_per_segment=20) + np.array([0.0, 0.0, 0.004])
    assert placed.fraction_inside(line) == pytest.approx(1.0)
    lifted = line.copy()
    jump = 0.02  # the second half of the wire lies on top of the walls' height, outside
    lifted[line[:, 0] > 0.2, 2] += jump
    expected = 0.2 / (0.4 + jump)  # the jump itself is outside too
    assert placed.fraction_inside(lifted) == pytest.approx(expected, abs=0.01)


@pytest.mark.parametrize("opening", [0.007, 0.012])
def test_clip_slot_floor_lips_and_predicate(opening):
    cfg = ClipConfig(opening=opening)
    spec = new_spec()
    placed = add_clip(spec, cfg, pos=(0.1, 0.2, 0.0), yaw=0.4)
    model = compile_spec(spec)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    c, s = math.cos(0.4), math.sin(0.4)

    def world(u, v):
        return 0.1 + c * u - s * v, 0.2 + s * u + c * v

    assert ray_height(model, data, *world(0.0, 0.0)) == pytest.approx(cfg.base_height, abs=1e-6)
    lip_v = cfg.slot_width / 2 - 0.0005  # beside the upright: under the lip, if there is one
    expected = cfg.base_height + (cfg.slot_depth if cfg.has_lip else 0.0)
    assert ray_height(model, data, *world(0.0, lip_v)) == pytest.approx(expected, abs=1e-6)
    lips = [model.geom(i).name for i in range(model.ngeom) if "_lip_" in model.geom(i).name]
    assert len(lips) == (2 if cfg.has_lip else 0)
    inside = np.array([[*world(0.0, 0.0), cfg.base_height + 0.004]])
    above = np.array([[*world(0.0, 0.0), cfg.base_height + cfg.slot_depth + 0.002]])
    beside = np.array([[*world(0.0, cfg.slot_width), cfg.base_height + 0.004]])
    assert placed.contains(inside)[0] and not placed.contains(above)[0]
    assert not placed.contains(beside)[0]


def test_channel_rejects_bad_bends():
    with pytest.raises(ValueError, match=r"bends\[1\]"):
        ChannelConfig.curved((0.0, 25.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="bends"):
        ChannelConfig(bends=(0.0, 0.0))


@pytest.mark.parametrize("field", ["slot_width", "opening", "base_height"])
def test_clip_rejects_non_positive_sizes(field):
    with pytest.raises(ValueError, match=field):
        ClipConfig(**{field: -0.001})
