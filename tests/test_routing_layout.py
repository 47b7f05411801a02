"""Routing task layout and clip retention: the route fits the cable, the fallen cable clears
the clips, and a seated wire stays in a lipped clip under a modest upward pull."""

from __future__ import annotations

import itertools

import mujoco
import numpy as np
import pytest

import wirecraft
from wirecraft import physics
from wirecraft.assets.fixtures import ClipConfig, add_clip
from wirecraft.geometry import resample
from wirecraft.scene import compile_spec, new_spec
from wirecraft.tasks.routing.task import (
    LANE_JITTER,
    LANE_X,
    LAYOUTS,
    LIP_INTERFERENCE,
    MAX_ROUTE,
)

WIRE_RADIUS = 0.004  # m, the articulated wire's
# Upward pull a seated wire must survive: twice the weight of the whole cable (0.4 m of 8 mm
# wire at 2000 kg/m^3 plus a 10 g plug is ~0.5 N), applied to the 6 cm piece in the slot.
PULL = 1.0  # N


@pytest.mark.parametrize("num_clips", [2, 3])
def test_widest_allowed_zigzag_fits_the_cable(num_clips):
    layout = LAYOUTS[num_clips]
    offsets = np.linspace(-LANE_JITTER, LANE_JITTER, 13)
    worst = max(
        layout.route_length(xs)
        for xs in itertools.product(offsets, repeat=num_clips)
        if np.all(np.abs(np.diff(xs)) <= layout.max_across + 1e-9)
    )
    assert worst <= MAX_ROUTE
    # Without the neighbour limit the widest zigzag would not fit: the limit is needed.
    assert max(layout.route_length(xs) for xs in itertools.product(offsets, repeat=num_clips)) > (
        worst
    )


@pytest.mark.parametrize("num_clips", [2, 3])
def test_sampled_clips_respect_the_ranges_and_the_fallen_cable_clears_them(num_clips):
    env = wirecraft.make("routing", num_clips=num_clips)
    task = env.unwrapped.task
    for seed in range(3):
        env.reset(seed=seed)
        xs = np.array([c[0] for c in task.sampled["clips"]])
        assert np.all(np.abs(xs - LANE_X) <= LANE_JITTER)
        assert np.all(np.abs(np.diff(xs)) <= task.layout.max_across)
        assert not any(task.routed(env.unwrapped.model, env.unwrapped.data))
        line = resample(env.unwrapped.wire_points(), 0.002)
        for clip in task.placed_clips(env.unwrapped.data):
            local = clip.to_local(line)
            half = (clip.config.length / 2, clip.config.slot_width / 2 + clip.config.wall)
            outside = np.hypot(
                np.maximum(np.abs(local[:, 0]) - half[0], 0.0),
                np.maximum(np.abs(local[:, 1]) - half[1], 0.0),
            )
            assert outside.min() > WIRE_RADIUS + 0.005, (seed, outside.min())
    env.close()


@pytest.mark.parametrize("num_clips", [1, 2, 3])
def test_widowx_clips_lie_within_its_reach_with_the_same_draws(num_clips):
    """The WidowX AI's lane is moved towards its base; the rest of the layout is the UR5's,
    draw for draw, and its fallen cable touches no part of the arm."""
    sampled = {}
    for robot in ("ur5", "wxai"):
        env = wirecraft.make("routing", num_clips=num_clips, robot=robot)
        task, model, data = env.unwrapped.task, env.unwrapped.model, env.unwrapped.data
        base = model.body(env.unwrapped.robot.base_site).id
        arm = {g for g in range(model.ngeom) if model.body_rootid[model.geom_bodyid[g]] == base}
        sampled[robot] = []
        for seed in range(4):
            env.reset(seed=seed)
            clips = np.array(task.sampled["clips"])
            sampled[robot].append((clips, task.sampled["angle"], task.sampled["pitch"]))
            base_x = data.xpos[base][0]
            reach = clips[:, 0] - base_x
            if robot == "wxai":
                assert reach.max() <= 0.40 + 1e-9, (seed, reach)
            touching = [
                (model.geom(c.geom1).name, model.geom(c.geom2).name)
                for c in data.contact[: data.ncon]
                if (c.geom1 in arm) != (c.geom2 in arm)
                and "table" not in (model.geom(c.geom1).name, model.geom(c.geom2).name)
            ]
            assert not touching, (robot, seed, touching)
        env.close()
    shift = 0.04 - LANE_X  # the WidowX AI's lane: its workspace ends at x = 0.10 m
    assert shift < 0
    for (ur5_clips, *ur5_rest), (wx_clips, *wx_rest) in zip(
        sampled["ur5"], sampled["wxai"], strict=True
    ):
        np.testing.assert_allclose(wx_clips[:, 0], ur5_clips[:, 0] + shift, atol=1e-12)
        np.testing.assert_allclose(wx_clips[:, 1:], ur5_clips[:, 1:], atol=1e-12)
        np.testing.assert_allclose(wx_rest, ur5_rest, atol=1e-12)


def seated_wire_after_pull(opening: float, pull: float) -> bool:
    """A 6 cm piece of wire resting on the slot floor, pulled up slowly (the pull grows to
    ``pull`` N over 0.5 s, as a taut cable loads a clip, then holds 0.5 s) and let go for
    0.3 s: is it back inside the slot (below the lips), not out on top?"""
    config = ClipConfig(slot_width=2 * WIRE_RADIUS + 0.002, opening=opening)
    spec = new_spec()
    placed = add_clip(spec, config)
    body = spec.worldbody.add_body(name="piece", pos=(0, 0, config.base_height + WIRE_RADIUS))
    body.add_freejoint()
    geom = body.add_geom(
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        size=(WIRE_RADIUS, 0.03, 0.0),
        quat=(np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0),  # along the slot (clip x)
        density=2000.0,
    )
    physics.stiff_contact(geom, friction=physics.TABLE_FRICTION)
    model = compile_spec(spec)
    data = mujoco.MjData(model)
    piece = model.body("piece").id
    while data.time < 1.3:
        data.xfrc_applied[piece, 2] = pull * min(data.time / 0.5, 1.0) if data.time < 1.0 else 0
        mujoco.mj_step(model, data)
    return bool(placed.contains(data.xpos[piece][None])[0])


def test_the_default_lip_retains_a_seated_wire_under_a_modest_pull():
    default = 2 * WIRE_RADIUS - LIP_INTERFERENCE
    assert seated_wire_after_pull(default, PULL)
    # The same pull lifts it out of a clip without lips (opening wider than the slot).
    assert not seated_wire_after_pull(2 * WIRE_RADIUS + 0.004, PULL)
