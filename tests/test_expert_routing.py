"""The routing expert routes the cable through 1, 2 and 3 clips (UR5, articulated wire), and its
geometric helpers agree with the gripper's and the clips' own geometry."""

from __future__ import annotations

import numpy as np
import pytest

import wirecraft
from wirecraft.assets.robots.grippers import GRIPPERS
from wirecraft.experts.base import rotation_angle
from wirecraft.experts.routing import RoutingExpert


def run_episode(num_clips: int, seed: int):
    env = wirecraft.make("routing", num_clips=num_clips)
    expert = RoutingExpert(env)
    env.reset(seed=seed)
    expert.reset()
    for _ in range(env.unwrapped.max_steps):
        _, _, terminated, truncated, info = env.step(expert.act()[0])
        if terminated or truncated:
            break
    return env, info, expert


@pytest.mark.parametrize("seed", [0, 7])
def test_routes_one_clip(seed):
    env, info, expert = run_episode(1, seed)
    assert info["success"], (seed, expert.phase_names, info["clips_routed"])
    assert expert.phase_names == ["done"]
    # The expert's own slot check is stricter than the task's: what it calls seated is routed.
    u = env.unwrapped
    assert np.all(u.task.routed(u.model, u.data) >= expert.seated(0))
    env.close()


# Seed 4 failed before the press, the sideways correction at the slot and the push on the
# slot's own link (benchmarks/eval_routing_expert.py, seeds 0-19: 2 clips 16/20 -> 19/20).
def test_routes_two_clips_seed_that_used_to_fail():
    env, info, expert = run_episode(2, 4)
    assert info["success"], (expert.phase_names, info["clips_routed"])
    env.close()


# Measured with benchmarks/eval_routing_expert.py (seeds 0-19): 3 clips about half; seed 1 is
# one that still fails (the push into clip 2 does not pass the lips, the retries run out of
# time), so this stays a non-strict xfail until the expert reaches the >= 98 % target.
@pytest.mark.slow
@pytest.mark.xfail(reason="routing expert: 3 clips 45 % (9/20 seeds), target 98 %")
def test_routes_three_clips_seed_that_still_fails():
    env, info, expert = run_episode(3, 1)
    assert info["success"], (expert.phase_names, info["clips_routed"])
    env.close()


def test_pad_ends_match_the_gripper_geometry():
    """The press places a pad's end by ``_pad_tip_offsets``: with the gripper open, the two
    ends lie ``tip_margin`` below the TCP, one either side, a pad thickness plus the pad gap
    apart (the gripper spec, not the expert, says so)."""
    env = wirecraft.make("routing")
    env.reset(seed=0)
    expert = RoutingExpert(env)
    u = env.unwrapped
    spec = GRIPPERS.get("2f85")
    offsets = expert._pad_tip_offsets(0)
    up = expert._up(0)
    assert np.allclose(offsets @ up, -spec.tip_margin, atol=1e-4)
    across = offsets[0] - offsets[1]
    gap = u.robot.gripper_opening(u.model, u.data)
    assert np.linalg.norm(across) == pytest.approx(gap + spec.pad_thickness, abs=1e-4)
    assert np.allclose(offsets[0] + offsets[1] - 2 * (offsets[0] @ up) * up, 0.0, atol=1e-4)
    env.close()


def test_grasp_rotation_points_down_across_the_wire_with_the_shorter_turn():
    env = wirecraft.make("routing")
    env.reset(seed=3)
    expert = RoutingExpert(env)
    up = expert._up(0)
    tangent = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    slot_axis = np.array([0.0, 1.0, 0.0])
    rot = expert._grasp_rot(0, tangent, slot_axis)
    assert np.allclose(rot[:, 2], -up, atol=1e-9)  # TCP z (approach) points down
    assert abs(rot[:, 1] @ tangent) < 1e-9  # pads close across the wire
    _, now = expert._ctl_target(0)
    slots = expert._down_rots(0, slot_axis)

    def turn(r):
        return rotation_angle(r, now) + min(rotation_angle(r, s) for s in slots)

    assert all(turn(rot) <= turn(other) + 1e-9 for other in expert._down_rots(0, tangent))
    env.close()


def test_wire_crossing_lies_on_the_wire_and_in_the_clip_mid_plane():
    """Where ``_wire_across_slot`` says the wire crosses clip 0's mid-plane, the centre line
    (its nodes joined by straight links) passes within a fraction of a millimetre."""
    env = wirecraft.make("routing")
    env.reset(seed=0)
    expert = RoutingExpert(env)
    u = env.unwrapped
    clip = u.task.placed_clips(u.data)[0]
    # a straight wire laid through the slot, 5 mm above its floor, 3 mm to one side
    yaw = clip.yaw
    along = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    side = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    centre = np.array(clip.pos) + [0.0, 0.0, clip.config.base_height + 0.005] + 0.003 * side
    nodes = centre + np.outer(np.linspace(-0.05, 0.05, 4), along)
    u.wire_points = lambda: nodes  # the expert reads the centre line through this
    lateral, height = expert._wire_across_slot(0)
    assert lateral == pytest.approx(0.003, abs=2e-4)
    assert height == pytest.approx(0.005, abs=2e-4)
    env.close()


def test_needs_the_routing_task_and_cartesian_control():
    with pytest.raises(ValueError, match="cartesian"):
        RoutingExpert(wirecraft.make("routing", control="joint"))
    with pytest.raises(ValueError, match="routing task"):
        RoutingExpert(wirecraft.make("insertion"))
