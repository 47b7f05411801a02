"""Channel seating: the task's success predicate on hand-laid cables under physics, and the
scripted expert (action layout, phase sequence, success on the straight channel).

On the curved channel the expert presses the wire into the channel after laying it (up to two
passes); it succeeds on 40 of its 50 tuning seeds (docs/experts.md), so one seed that it seats
is tested and the general case stays an expected failure.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import wirecraft
from wirecraft.experts.seating import SeatingExpert, SeatingExpertConfig

EPISODE_STEPS = 480


def run(channel: str, seed: int):
    env = wirecraft.make("seating", channel=channel)
    expert = SeatingExpert(env)
    obs, info = env.reset(seed=seed)
    expert.reset()
    carried, phases = False, set()
    for _ in range(EPISODE_STEPS):
        action = expert.act(obs)
        assert action.shape == (1, 4)
        assert np.all(np.abs(action) <= 1.0)
        obs, _, terminated, truncated, info = env.step(action[0])
        phases.add(expert.phase_names[0])
        carried |= expert.phase_names[0] == "lay" and expert._held(0)
        if terminated or truncated:
            break
    return info, carried, phases, expert


def channel_path(task, height: float, offset: float = 0.0) -> np.ndarray:
    """World polyline from the clamp's exit along the channel's centre line, ``height`` above
    the floor and ``offset`` metres to the left of the centre."""
    placed = task.placed
    line = placed.config.centerline(samples_per_segment=40)
    tangent = np.gradient(line[:, :2], axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    left = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    xy = line[:, :2] + offset * left
    c, s = math.cos(placed.yaw), math.sin(placed.yaw)
    world = np.column_stack(
        [
            c * xy[:, 0] - s * xy[:, 1] + placed.pos[0],
            s * xy[:, 0] + c * xy[:, 1] + placed.pos[1],
            line[:, 2] + placed.pos[2] + height,
        ]
    )
    return np.vstack([task.clamp_exit, world]) if offset == 0.0 else world


def settle(env, steps: int):
    hold = np.zeros(env.action_space.shape)
    hold[-1] = -1.0
    info = None
    for _ in range(steps):
        _, _, _, _, info = env.step(hold)
    return info


@pytest.mark.parametrize("channel", ["straight", "curved"])
def test_hand_laid_wire_counts_as_seated_and_stays(channel):
    """A wire laid along the channel floor from the clamp is seated (the plug, wider than the
    channel, lies beyond its end) and still is after 1 s of physics."""
    env = wirecraft.make("seating", channel=channel)
    env.reset(seed=3)
    task, model, data = env.unwrapped.task, env.unwrapped.model, env.unwrapped.data
    radius = task.assembly.wire.config.radius
    task.assembly.lay_from_clamp(model, data, channel_path(task, radius + 0.0005))
    info = task.evaluate(model, data)
    channel_share = task.placed.config.segment_length * 5 / task.assembly.wire.config.length
    # The wire fills the channel: everything but the bits before the entry and past the end.
    assert info["fraction_inside"] == pytest.approx(channel_share, abs=0.05)
    assert info["success"]
    info = settle(env, 60)
    assert info["success"] and not info["diverged"]
    assert info["fraction_inside"] == pytest.approx(channel_share, abs=0.05)


def test_wire_beside_the_channel_does_not_count():
    """A wire lying on the table 3 cm beside the channel, parallel to it, is not seated."""
    env = wirecraft.make("seating", channel="straight")
    env.reset(seed=3)
    task, model, data = env.unwrapped.task, env.unwrapped.model, env.unwrapped.data
    radius = task.assembly.wire.config.radius
    beside = channel_path(task, -task.placed.config.floor + radius, offset=0.03)
    task.assembly.lay_from_clamp(model, data, beside)
    info = task.evaluate(model, data)
    assert info["fraction_inside"] == 0.0 and not info["success"]


@pytest.mark.parametrize("channel", ["straight", "curved"])
def test_settled_start_is_not_seated(channel):
    """At reset the cable drapes over a wall onto the table: only its first centimetres, out
    of the clamp, lie in the channel."""
    env = wirecraft.make("seating", channel=channel)
    for seed in range(3):
        _, info = env.reset(seed=seed)
        assert not info["success"] and info["fraction_inside"] < 0.4


def test_needs_cartesian_fixed():
    with pytest.raises(ValueError, match="cartesian_fixed"):
        SeatingExpert(wirecraft.make("seating", control="cartesian"))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_seats_the_wire_in_the_straight_channel(seed):
    info, carried, phases, expert = run("straight", seed)
    assert carried, "the plug must be held while laying"
    assert {"settle", "close", "carry", "lay", "place", "release"} <= phases
    # A wire that lies on the floor after the lay is not pressed: no time lost.
    assert not phases & {"press_approach", "press_descend", "press"}
    assert expert.phase_names[0] == "done"
    assert not info["diverged"]
    assert info["success"] and info["fraction_inside"] >= 0.8


def test_press_profile_keeps_the_pad_between_the_walls():
    """Wherever the pressing pad goes below the wall tops, its whole footprint (the pad's box,
    read from the model) lies over the channel floor between the walls (channel geometry)."""
    env = wirecraft.make("seating", channel="curved")
    expert = SeatingExpert(env)
    for seed in range(3):
        env.reset(seed=seed)
        expert.reset()
        task, model, data = env.unwrapped.task, env.unwrapped.model, env.unwrapped.data
        world, arc = expert._path(0)
        heights = expert._press_heights(0)
        wall_top = task.placed.config.wall_height
        deep = heights < wall_top
        assert deep.any() and (~deep).any()  # the curved channel has both kinds of stretch
        assert np.all(heights[~deep] > wall_top)
        gid = model.geom(env.unwrapped.robot.pad_geom_names[0]).id
        half = model.geom_size[gid][:2]
        axes = data.geom_xmat[gid].reshape(3, 3)[:2, :2]
        for point in world[deep]:
            corners = [
                np.array([*(point[:2] + axes @ (half * np.array([sx, sy]))), point[2] + 0.005])
                for sx in (-1, 1)
                for sy in (-1, 1)
            ]
            assert task.placed.contains(np.array(corners)).all()


def test_presses_the_wire_into_the_curved_channel():
    """Seed 2 (bends -10, -8, 13, -16 deg): the lay leaves the wire bridging the bends; the
    first pressing pass leaves a stretch raised (the expert's own check), the second seats it."""
    info, carried, phases, expert = run("curved", 2)
    assert carried
    assert {"press_descend", "press", "press_retreat"} <= phases
    assert expert.press_count[0] == 2
    assert expert.phase_names[0] == "done"
    assert not info["diverged"]
    assert info["success"]


def test_press_passes_follow_their_directions():
    """A pass runs from the entry side to the end side (+1) or back (-1), between the same two
    arcs; no more passes than directions."""
    env = wirecraft.make("seating", channel="curved")
    expert = SeatingExpert(env, SeatingExpertConfig(press_directions=(1, -1)))
    env.reset(seed=0)
    expert.reset()
    _, arc = expert._path(0)
    end_side = arc[-1] - env.unwrapped.task.plug_lead - expert.config.press_stop
    assert expert._press_span(0) == pytest.approx((expert.config.press_from, end_side))
    expert.press_count[0] = 1
    assert expert._press_span(0) == pytest.approx((end_side, expert.config.press_from))


@pytest.mark.parametrize("directions", [(), (0,), (1, 2)])
def test_press_directions_are_checked(directions):
    with pytest.raises(ValueError, match="press_directions"):
        SeatingExpertConfig(press_directions=directions)


def test_curved_runs_to_the_end_holding_the_plug():
    """Seed 1: the plug is carried and released; the episode's end may cut off the second
    pressing pass, but the expert is past the release and the physics stays sound."""
    info, carried, phases, expert = run("curved", 1)
    assert carried
    assert {"settle", "close", "carry", "lay", "place", "release", "press"} <= phases
    assert expert.phase_names[0] in {
        "press_approach",
        "press_descend",
        "press",
        "press_retreat",
        "done",
    }
    assert not info["diverged"]


@pytest.mark.xfail(
    reason="curved channel: 40/50 tuning seeds (docs/experts.md); seed 0's last two segments "
    "run 22 and 41 deg off x, where the pad cannot reach below the wall tops",
    strict=False,
)
def test_seats_the_wire_in_the_curved_channel():
    info, *_ = run("curved", 0)
    assert info["success"]
