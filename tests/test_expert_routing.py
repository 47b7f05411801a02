"""The routing expert routes the cable through 1, 2 and 3 clips (UR5, articulated wire), and its
geometric helpers agree with the gripper's and the clips' own geometry."""

from __future__ import annotations

import numpy as np
import pytest

import wirecraft
from wirecraft.assets.robots.grippers import GRIPPERS
from wirecraft.experts.base import rotation_angle
from wirecraft.experts.routing import RoutingExpert, RoutingExpertConfig


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


# Seeds 29 and 35 failed (each episode run alone, as here) before the changes for a slot link
# that crosses the clip aslant (grasp at a joint, that joint between the pads past the slot,
# pads turned against the link's yaw); research/eval_routing_expert.py, seeds 0-49: 2 clips
# 46/50 -> 48/50 at the end.
@pytest.mark.parametrize("seed", [29, 35])
def test_routes_two_clips_seeds_that_used_to_fail(seed):
    env, info, expert = run_episode(2, seed)
    assert info["success"], (seed, expert.phase_names, info["clips_routed"])
    env.close()


# Seed 47: both hops from one clip to the next are steep (15 and 27 deg off the slot axis); run
# alone it failed before the aslant changes (clip 3 not seated in time) and passes with them.
@pytest.mark.slow
def test_routes_three_clips_with_steep_hops():
    env, info, expert = run_episode(3, 47)
    assert info["success"], (expert.phase_names, info["clips_routed"])
    assert expert._hop_angle(0) > expert.config.aslant_hop  # the last clip used the changes
    env.close()


# Seed 35 (3 clips) failed with the 20 s episode: the retry of clip 2 grasped where the wire had
# been while it still settled (the pads closed 2 cm above it), and the swing to clip 2 ran into
# clip 3's uprights until its 150-step timeout.  It passes with the grasp that follows the wire,
# the swing over a clip in the way and the re-routing of clips left empty.
@pytest.mark.slow
def test_routes_three_clips_after_a_retry():
    env, info, expert = run_episode(3, 35)
    assert info["success"], (expert.phase_names, info["clips_routed"])
    assert expert.tries[0, :3].sum() > 3  # a clip was routed again
    env.close()


# Measured with research/eval_routing_expert.py (tuning seeds 0-49, 1440-step episodes): 3 clips
# 86 % at the end; seed 1 still fails (the second clip routed 4 times: hops of 31 and 28 deg),
# so this stays a non-strict xfail until the expert reaches the >= 98 % target.
@pytest.mark.slow
@pytest.mark.xfail(reason="routing expert: 3 clips 86 % (43/50 tuning seeds), target 98 %")
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


def _lay_wire_through_clip(env, clip, yaw_off, lateral=0.0, height=0.005, spacing=0.033):
    """Replace the wire's centre line by straight nodes through ``clip``'s slot, ``yaw_off``
    (rad) off its axis, ``lateral`` (m) to the side and ``height`` above the slot floor."""
    yaw = clip.yaw + yaw_off
    along = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    side = np.array([-np.sin(clip.yaw), np.cos(clip.yaw), 0.0])
    centre = np.array(clip.pos) + [0.0, 0.0, clip.config.base_height + height] + lateral * side
    nodes = centre + np.outer(spacing * (np.arange(6) - 2.5), along)
    env.unwrapped.wire_points = lambda: nodes  # the expert reads the centre line through this
    return nodes


@pytest.mark.parametrize("yaw_deg", [-25.0, 0.0, 12.0])
def test_slot_link_yaw_is_the_angle_of_the_link_crossing_the_slot(yaw_deg):
    env = wirecraft.make("routing")
    env.reset(seed=0)
    expert = RoutingExpert(env)
    u = env.unwrapped
    clip = u.task.placed_clips(u.data)[0]
    nodes = _lay_wire_through_clip(env, clip, np.radians(yaw_deg), lateral=0.002)
    assert expert._slot_link_yaw(0) == pytest.approx(np.radians(yaw_deg), abs=1e-9)
    u.wire_points = lambda: nodes[::-1]  # a line: its direction along the wire does not count
    assert expert._slot_link_yaw(0) == pytest.approx(np.radians(yaw_deg), abs=1e-9)
    # a wire that passes far from the slot is not read
    _lay_wire_through_clip(env, clip, 0.0, height=0.2)
    assert expert._slot_link_yaw(0) is None
    env.close()


def test_hop_angle_and_when_the_aslant_changes_apply():
    """The hop angle is the angle between a clip's slot axis and the line from the previous clip
    (computed here from the clips' world positions and yaws); the changes for an aslant slot
    link apply from the second clip on, on a retry or when that angle is steep."""
    env = wirecraft.make("routing", num_clips=3)
    env.reset(seed=0)
    expert = RoutingExpert(env)
    u = env.unwrapped
    clips = u.task.placed_clips(u.data)
    assert not expert._retrying(0)  # first clip, first try
    expert.tries[0, 0] = 2
    assert not expert._retrying(0)  # the first clip never
    for k in (1, 2):
        hop = np.subtract(clips[k].pos, clips[k - 1].pos)[:2]
        axis = np.array([np.cos(clips[k].yaw), np.sin(clips[k].yaw)])
        truth = np.arccos(abs(hop @ axis) / np.linalg.norm(hop))
        expert.clip[0] = k
        expert.tries[0, k] = 1
        assert expert._hop_angle(0) == pytest.approx(truth, abs=1e-9)
        assert expert._retrying(0) == (truth > expert.config.aslant_hop)
        expert.tries[0, k] = 2
        assert expert._retrying(0)
    env.close()


def test_turn_is_the_rotation_about_the_axis():
    from wirecraft.experts.routing import _turn

    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    rot = _turn(axis, 0.7)
    assert np.allclose(rot @ rot.T, np.eye(3), atol=1e-12) and np.linalg.det(rot) > 0
    assert np.allclose(rot @ axis, axis, atol=1e-12)  # the axis stays
    side = np.cross(axis, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    assert np.arccos(np.clip(side @ (rot @ side), -1, 1)) == pytest.approx(0.7, abs=1e-12)
    assert np.allclose(np.cross(side, rot @ side), np.sin(0.7) * axis, atol=1e-12)  # right-handed


def test_an_episode_depends_on_its_seed_not_on_the_episodes_before_it():
    """One expert and environment running seed 0 and then seed 5 act on seed 5 exactly as a
    fresh pair does (the expert's per-episode estimates start afresh at reset)."""

    def actions(env, expert, seed, steps):
        obs, _ = env.reset(seed=seed)
        expert.reset()
        out = []
        for _ in range(steps):
            action = expert.act(obs[None])[0]
            out.append(action)
            obs, *_ = env.step(action)
        return np.array(out)

    env = wirecraft.make("routing", num_clips=2)
    expert = RoutingExpert(env, seed=0)
    actions(env, expert, 0, 480)  # a whole episode: grasps, measures and pushes the wire
    after = actions(env, expert, 5, 480)
    fresh_env = wirecraft.make("routing", num_clips=2)
    fresh = actions(fresh_env, RoutingExpert(fresh_env, seed=0), 5, 480)
    np.testing.assert_array_equal(after, fresh)


def test_next_clip_is_the_first_empty_one_with_routings_left():
    """Clips are routed again in route order (a clip's routing anchors the wire at the one
    before it), each at most ``max_clip_tries`` times; ``None`` ends the route."""
    env = wirecraft.make("routing", num_clips=3)
    env.reset(seed=0)
    expert = RoutingExpert(env)
    limit = expert.config.max_clip_tries
    for seated, tries, expected in (
        ([True, False, False], [1, 1, 0], 1),
        ([False, True, False], [1, 1, 1], 0),
        ([False, True, False], [limit, 1, 1], 2),
        ([False, True, True], [limit, 1, 1], None),
        ([True, True, True], [1, 1, 1], None),
    ):
        expert.seated = lambda i, margin=None, s=seated: np.array(s)
        expert.tries[0] = tries
        assert expert._next_clip(0) == expected, (seated, tries)
    env.close()


def test_done_goes_back_to_a_clip_the_wire_left():
    """In ``done``, a clip that reads empty for ``recheck_steps`` steps in a row is routed
    again (a shorter gap is not: the reading flickers while the wire settles)."""
    env = wirecraft.make("routing", num_clips=2)
    env.reset(seed=0)
    expert = RoutingExpert(env)
    fsm = expert.fsm
    fsm.goto("done", [0])
    expert.tries[0, :2] = [1, 1]
    expert.seated = lambda i, margin=None: np.array([True, False])
    for _ in range(expert.config.recheck_steps - 1):
        assert not expert._recheck(0)
    assert expert.phase_names == ["done"]
    assert expert._recheck(0)
    assert expert.phase_names == ["approach"] and expert.clip[0] == 1 and expert.tries[0, 1] == 2
    env.close()


def test_grasp_point_follows_the_wire_where_it_lies_now():
    """The grasp point is the point ``arc`` m along the current centre line (linear between
    nodes), at the grasp height above the table, or just above a wire lying raised."""
    env = wirecraft.make("routing")
    env.reset(seed=0)
    expert = RoutingExpert(env)
    u = env.unwrapped
    cfg = expert.config
    start = np.array([0.0, -0.1, 0.004])
    nodes = start + np.outer(np.arange(5) * 0.03, [0.0, 1.0, 0.0])
    u.wire_points = lambda: nodes
    world = expert._base(0)[0] + expert._base(0)[1] @ expert._grasp_point(0, 0.045)
    assert world == pytest.approx([0.0, -0.1 + 0.045, cfg.grasp_height], abs=1e-9)
    raised = nodes + [0.0, 0.0, 0.03]  # the same wire 3 cm higher (e.g. still settling)
    u.wire_points = lambda: raised
    world = expert._base(0)[0] + expert._base(0)[1] @ expert._grasp_point(0, 0.045)
    assert world[2] == pytest.approx(0.034 + cfg.wire_below_tcp, abs=1e-9)
    env.close()


def test_approach_follows_a_settling_wire_but_not_one_carried_away():
    """Approach and descend aim at the planned grasp point as the wire lies now: a wire that
    settles 2 cm, or springs 8 cm sideways along the table, is followed; for one lifted 15 cm
    (caught on an open pad, it rises with the TCP) the approach waits where it was, or the TCP
    would chase it off the table."""
    env = wirecraft.make("routing")
    env.reset(seed=0)
    expert = RoutingExpert(env)
    expert.reset()
    expert.act()
    assert expert.phase_names[0] == "approach"
    u = env.unwrapped
    up = expert._up(0)
    planned = expert.fsm.snapshots["grasp_pos"][0].copy()
    lying = u.wire_points().copy()
    for shift in ([0.0, 0.02, 0.0], [0.08, 0.0, 0.0]):  # settled; sprung off along the table
        moved = lying + shift
        u.wire_points = lambda moved=moved: moved
        goal, _, _, _, reached = expert._goals(0)
        followed = expert._grasp_point(0, expert.grasp_arc[0])
        assert np.linalg.norm(followed - planned) == pytest.approx(np.linalg.norm(shift), abs=1e-6)
        np.testing.assert_allclose(goal, followed + expert.config.hover * up, atol=1e-9)
        assert reached is None  # the pose decides when the approach ends
    carried = moved + [0.0, 0.0, 0.15]
    u.wire_points = lambda: carried
    goal, _, _, _, reached = expert._goals(0)
    np.testing.assert_allclose(goal, followed + expert.config.hover * up, atol=1e-9)
    assert reached is False  # waits for the wire to come down (or the phase's timeout)
    env.close()


def _routing_second_of_three_clips():
    """(env, expert, clips) of a 3-clip episode (seed 0) with the expert on the second clip."""
    env = wirecraft.make("routing", num_clips=3)
    env.reset(seed=0)
    expert = RoutingExpert(env)
    expert.clip[0] = 1
    return env, expert, env.unwrapped.task.placed_clips(env.unwrapped.data)


def test_swing_goes_over_a_clip_in_its_way():
    env, expert, clips = _routing_second_of_three_clips()
    cfg = expert.config
    beside = expert._to_base(0, np.array(clips[1].pos) + [0.05, 0.0, 0.0])
    expert._beside_goal = lambda i: beside
    # from beyond clip 2, straight across it: over it
    expert.fsm.snapshots["lift_from"][0] = expert._to_base(
        0, np.array(clips[2].pos) + [0.0, 0.05, 0.0]
    )
    assert expert._swing_height(0) == cfg.carry_height
    # from well beside the lane, clear of clips 0 and 2: low
    expert.fsm.snapshots["lift_from"][0] = expert._to_base(
        0, np.array(clips[1].pos) + [0.12, 0.0, 0.0]
    )
    assert expert._swing_height(0) == cfg.sweep_height
    env.close()


def test_swing_goes_high_when_the_wire_beyond_the_grasp_lies_near_a_later_clip():
    """Swung low, the articulated wire beyond the pads caught on the next clip's body and was
    pulled out of them (3-clip seed 36).  The ``trail_check`` m of a wire of rigid links
    beyond the grasp, read as the grasp closes, passing within ``clip_clearance`` of a later
    clip sends the swing over at the carry height; near an earlier clip, or farther, or a wire
    of short pieces (a rod: swung high, it pried the wire out of the clip before), it does
    not."""
    env, expert, clips = _routing_second_of_three_clips()
    u = env.unwrapped
    cfg = expert.config
    expert.grasp_arc[0] = 0.03

    def wire_beside(clip, offset, link=0.033):
        # along world x through the clip's x, `offset` to its side; the grasp 5 cm before it
        start = np.array(clip.pos) + [-0.08, offset, 0.004]
        nodes = start + np.outer(np.arange(0.0, 0.2, link), [1.0, 0.0, 0.0])
        u.wire_points = lambda: nodes

    wire_beside(clips[2], cfg.clip_clearance - 0.01)
    assert expert._trail_near_clip(0)
    wire_beside(clips[2], cfg.clip_clearance - 0.01, link=0.005)  # a rod's nodes
    assert not expert._trail_near_clip(0)
    wire_beside(clips[2], cfg.clip_clearance + 0.01)
    assert not expert._trail_near_clip(0)
    wire_beside(clips[0], 0.0)  # an earlier clip (the wire is already in it)
    assert not expert._trail_near_clip(0)
    # the swing from well beside the lane would go low; the trail sends it high
    expert._beside_goal = lambda i: expert._to_base(0, np.array(clips[1].pos) + [0.05, 0, 0])
    expert.fsm.snapshots["lift_from"][0] = expert._to_base(
        0, np.array(clips[1].pos) + [0.12, 0.0, 0.0]
    )
    assert expert._swing_height(0) == cfg.sweep_height
    expert.trail_near_clip[0] = True
    assert expert._swing_height(0) == cfg.carry_height
    env.close()


def test_a_wire_that_drops_into_the_clip_while_carried_is_released_there():
    """Lifting or turning the wire near the clip sometimes drops it into the slot; pulling on
    then drags it out of the pads (seed 1, 3 clips, looped so for 650 steps).  The expert lets
    go once its own check reads the clip seated ``seated_early_steps`` steps in a row (a
    reading that flickers starts the count again), where the TCP is."""
    env = wirecraft.make("routing", num_clips=2)
    env.reset(seed=0)
    expert = RoutingExpert(env)
    u = env.unwrapped
    tcp, rot = u.robot.tcp_pose_base(u.model, u.data)
    fsm = expert.fsm
    fsm.goto("raise", [0])
    snapshots = {"lift_from": tcp, "slot_rot": rot, "grasp_pos": tcp, "grasp_rot": rot}
    for name, value in snapshots.items():
        fsm.snapshots[name][0] = value
    fsm.snapshots["anchor"][0] = tcp - [0.1, 0.0, 0.0]
    fsm.snapshots["direction"][0] = [1.0, 0.0, 0.0]
    need = expert.config.seated_early_steps
    readings = [True] * (need - 1) + [False] + [True] * need
    for k, reading in enumerate(readings):
        expert.seated = lambda i, margin=None, r=reading: np.array([r, False])
        expert.act()
        released = k == len(readings) - 1
        assert expert.phase_names == ["release" if released else "raise"], k
    np.testing.assert_allclose(fsm.get("hold_pos")[0], tcp, atol=1e-9)
    env.close()


@pytest.mark.parametrize("beyond", [False, True])
def test_a_retry_grasps_at_a_joint_only_near_the_taut_length(beyond):
    """A retry grasps the articulated wire at a joint, the first one beyond the taut length
    (anchor to clip front), unless that joint lies more than ``retry_joint_spare`` beyond it:
    then it grasps the first point past the taut length, as a first try does (the wire to
    spare arched up between the clips)."""
    env = wirecraft.make("routing", num_clips=2)
    env.reset(seed=0)
    expert = RoutingExpert(env)
    cfg = expert.config
    u = env.unwrapped
    expert.clip[0] = 1
    expert.tries[0, 1] = 2  # a retry
    slot, _, _ = expert._clip_geometry(0)
    anchor_world = expert._base(0)[0] + expert._base(0)[1] @ expert._clip_geometry(0, 0)[0]
    need = expert._taut_length(0, slot, expert._anchor(0)[0]) + cfg.grasp_slack
    spare = cfg.retry_joint_spare + 0.01 if beyond else cfg.retry_joint_spare / 2
    link = (need + spare) / 4  # the fourth joint from the anchor lies `spare` past the need
    away = np.array([-1.0, 0.0, 0.0])  # off the route, clear of both clips
    nodes = anchor_world + np.outer(link * np.arange(9), away)
    u.wire_points = lambda: nodes
    assert expert._anchor(0)[1] == pytest.approx(0.0, abs=1e-9)
    expert._plan_grasp(0)
    if not beyond:
        assert abs(expert.grasp_arc[0] - 4 * link) <= cfg.retry_joint_reach
    else:
        assert need <= expert.grasp_arc[0] < need + cfg.grasp_spacing
        assert abs(expert.grasp_arc[0] - 4 * link) > cfg.retry_joint_reach
    env.close()


@pytest.mark.parametrize("joint_past_slot", [0.012, 0.020])
def test_a_joint_the_pads_cannot_bring_out_far_enough_goes_into_the_clip(joint_past_slot):
    """The push's pads go where the first joint past the slot centre lies ``link_joint`` past
    it.  With the pads already at ``max_front`` and that joint nearer (12 mm, just beyond the
    clip), the pads come back instead, until the joint lies between the clip's faces; a joint
    that can be brought out (20 mm) is brought out to ``link_joint``, as before."""
    env = wirecraft.make("routing")
    env.reset(seed=0)
    expert = RoutingExpert(env)
    cfg = expert.config
    u = env.unwrapped
    clip = u.task.placed_clips(u.data)[0]
    axis = np.array([np.cos(clip.yaw), np.sin(clip.yaw), 0.0])
    slot = np.array(clip.pos) + [0.0, 0.0, clip.config.base_height + 0.005]
    link = 0.033
    nodes = slot + np.outer(joint_past_slot + link * np.arange(-3, 3), axis)
    u.wire_points = lambda: nodes
    tcp_along = cfg.max_front
    u.data.site_xpos[u.task.tcp_site] = slot + tcp_along * axis  # the pads at max_front
    front = expert._link_front(0, 1.0)
    assert cfg.min_front <= front <= cfg.max_front
    joint_after = joint_past_slot + (front - tcp_along)  # the held link moves with the pads
    if tcp_along + cfg.link_joint - joint_past_slot <= cfg.max_front:
        assert joint_after == pytest.approx(cfg.link_joint, abs=1e-9)
    else:
        assert abs(joint_after) <= clip.config.length / 2
        kept = RoutingExpert(env, RoutingExpertConfig(joint_inside=False))
        assert kept._link_front(0, 1.0) == pytest.approx(cfg.max_front, abs=1e-9)
    env.close()


@pytest.mark.parametrize(
    "field, value",
    [
        ("retry_joint_spare", -0.01),
        ("trail_check", float("nan")),
        ("seated_early_steps", 0),
        ("seated_early_steps", 2.5),
        ("carry_height", 0.0),
        ("flex_carry_height", -0.03),
        ("follow_height", -0.01),
        ("follow_height", float("nan")),
        ("inside_joint", float("nan")),
        ("joint_inside", "yes"),
        ("retry_joint", float("nan")),
        ("push_force", float("inf")),
    ],
)
def test_refuses_bad_settings(field, value):
    with pytest.raises(ValueError, match=field):
        RoutingExpertConfig(**{field: value})


@pytest.mark.parametrize("wire", ["articulated", "rod"])
def test_a_wire_that_bends_anywhere_is_carried_lower(wire):
    """The stretch ends at the carry height: 3.8 cm for the articulated wire's rigid links,
    3.2 cm for the rod, which a higher carry bends up out of a clip it was seated in."""
    env = wirecraft.make("routing", num_clips=1, wire=wire)
    expert = RoutingExpert(env)
    env.reset(seed=0)
    expert.reset()
    for _ in range(300):
        env.step(expert.act()[0])
        if expert.phase_names[0] == "pull_back":
            break
    assert expert.phase_names[0] == "pull_back"
    cfg = expert.config
    expected = cfg.carry_height if wire == "articulated" else cfg.flex_carry_height
    tcp = env.unwrapped.data.site_xpos[env.unwrapped.task.tcp_site]
    assert tcp[2] == pytest.approx(expected, abs=0.002)  # the table top is at z = 0
    env.close()
