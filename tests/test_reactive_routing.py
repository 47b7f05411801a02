"""ReactiveRoutingExpert: its action is a function of the routing state alone (no memory), it
routes one clip by the task's own success flag, its push comes down over the clip with the pads
across the slot, its goal-relative features agree with the simulation, and bad input is
refused (its DAgger run: test_dagger_init.py)."""

import numpy as np
import pytest

import wirecraft
from wirecraft.experts.reactive_routing import (
    FRONT,
    PHASES,
    ReactiveRoutingExpert,
    RoutingStateLayout,
)


def make_venv(num_envs, **options):
    options.setdefault("num_clips", 1)
    return wirecraft.make_vec("routing", num_envs, threads=1, control="cartesian", **options)


@pytest.fixture(scope="module")
def one_clip_run():
    venv = make_venv(4)
    expert = ReactiveRoutingExpert(venv)
    obs, _ = venv.reset(seed=31)
    states, actions, phases = [], [], []
    routed = np.zeros(venv.num_envs, bool)
    for _ in range(300):
        action = expert.act(obs)
        states.append(obs.copy())
        actions.append(action)
        phases.append(expert.phase.copy())
        obs, _, _, _, info = venv.step(action)
        routed |= np.asarray(info["success"], bool)
    venv.close()
    return expert, np.stack(states), np.stack(actions), np.stack(phases), routed


def test_reactive_routing_expert_routes_one_clip(one_clip_run):
    _, _, actions, phases, routed = one_clip_run
    # The task's own flag (the wire's centre line inside the slot, below the lips); a rate with
    # a margin, not one episode's outcome.
    assert routed.sum() >= 3
    assert np.all(np.abs(actions) <= 1.0)
    visited = {PHASES[k] for k in phases.ravel()}
    assert {"approach", "descend", "close", "lift", "carry", "push", "release"} <= visited


def test_the_push_comes_down_beside_the_slot_with_the_pads_across_it(one_clip_run):
    from wirecraft.geometry import quat_to_mat

    expert, states, _, phases, _ = one_clip_run
    lay = expert.layout
    for env in range(states.shape[1]):
        rows = np.flatnonzero(phases[:, env] == PHASES.index("push"))
        assert len(rows) > 3
        state = states[rows, env]
        clip = state[0, lay.clips][:7]
        slot, axis = clip[1:4], np.array([clip[4], clip[5], 0.0])
        tcp = state[:, lay.tcp_pos]
        # the pads' closing direction (the TCP's y) lies across the slot axis (within 0.1 rad)
        closing = np.stack([quat_to_mat(q)[:, 1] for q in state[:, lay.tcp_quat]])
        assert np.all(np.abs(closing @ axis) < np.sin(0.1))
        # over the slot axis, FRONT past the slot centre (within the sideways correction), and
        # the TCP comes down
        offset = tcp[-1] - slot
        assert abs(abs(offset @ axis) - FRONT) < 0.006
        assert abs(np.cross([0.0, 0.0, 1.0], axis) @ offset) < 0.013
        assert tcp[-1, 2] < tcp[0, 2] - 0.005


def test_reactive_routing_expert_has_no_memory(one_clip_run):
    _, states, actions, _, _ = one_clip_run
    width = states.shape[-1]
    flat_states, flat_actions = states.reshape(-1, width), actions.reshape(-1, 7)
    # Another expert built on other environments (2 clips), fed the same states shuffled, gives
    # the same actions row for row: nothing but the state decides them.
    other = make_venv(2, num_clips=2)
    other.reset(seed=99)
    order = np.random.default_rng(0).permutation(len(flat_states))
    again = ReactiveRoutingExpert(other).act(flat_states[order])
    other.close()
    np.testing.assert_array_equal(again, flat_actions[order])


def test_routing_relative_features_are_the_route_seen_from_the_tcp():
    from wirecraft.experts.reactive import FINE_SCALES

    env = wirecraft.make("routing", num_clips=1)
    obs, _ = env.reset(seed=3)
    u = env.unwrapped
    features = ReactiveRoutingExpert.relative_features(obs[None])[0]
    assert features.shape == (len(obs) + 33,)
    np.testing.assert_array_equal(features[: len(obs)], obs)
    extra = features[len(obs) :]
    # independent truth: the simulation's own poses (the base frame is the world shifted to the
    # base, which stands on the table facing +x)
    base = u.data.site_xpos[u.controller.index.base_site]
    tcp, tcp_rot = u.robot.tcp_pose_base(u.model, u.data)
    (clip,) = u.task.placed_clips(u.data)
    slot = np.array(clip.pos) + [0.0, 0.0, clip.config.base_height] - base
    clamp = u.data.xpos[u.model.body(u.task.assembly.clamp).id] - base
    axis = np.array([np.cos(clip.yaw), np.sin(clip.yaw), 0.0])
    axis *= np.sign(axis @ (slot - clamp))  # away from the clamp
    push = slot + FRONT * axis
    np.testing.assert_allclose(extra[0:3], tcp_rot.T @ axis, atol=1e-6)
    np.testing.assert_allclose(extra[6:9], push - tcp, atol=1e-6)
    # the grasp point lies on the polyline through the state's wire points, taut + slack along
    # it: the wire's length from the clamp to the push point with the wire held at carry height
    points = obs[RoutingStateLayout(6).wire].reshape(10, 3)
    grasp = extra[9:12] + tcp
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    gaps = [np.linalg.norm(np.cross(grasp - a, b - a)) / np.linalg.norm(b - a) for a, b in
            zip(points[:-1], points[1:], strict=True)]  # fmt: skip
    k = int(np.argmin(gaps))
    assert gaps[k] < 1e-9
    along = arc[k] + np.linalg.norm(grasp - points[k])
    from wirecraft.experts.reactive_routing import CARRY_HEIGHT, SLACK, WIRE_BELOW_TCP

    taut = np.hypot(np.linalg.norm((push - clamp)[:2]), CARRY_HEIGHT - WIRE_BELOW_TCP - clamp[2])
    assert along == pytest.approx(taut + SLACK, abs=1e-9)
    near = extra[6:15]
    np.testing.assert_allclose(extra[15:24], np.tanh(near / FINE_SCALES[0]), atol=1e-12)
    np.testing.assert_allclose(extra[24:33], np.tanh(near / FINE_SCALES[1]), atol=1e-12)
    env.close()
    with pytest.raises(ValueError, match="width of the routing task"):
        ReactiveRoutingExpert.relative_features(obs[None, :79])


def test_reactive_routing_expert_refuses_bad_input():
    venv = make_venv(1)
    state = np.asarray(venv.reset(seed=0)[0], float)
    expert = ReactiveRoutingExpert(venv)
    with pytest.raises(ValueError, match="routing states"):
        expert.act(state[:, :40])
    state[0, 30] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        expert.act(state)
    venv.close()
    joint = wirecraft.make_vec("routing", 1, threads=1, control="joint")
    with pytest.raises(ValueError, match="cartesian"):
        ReactiveRoutingExpert(joint)
    joint.close()


def test_wirecraft_eval_and_collect_run_the_reactive_routing_expert(tmp_path):
    from wirecraft.evaluation.policies import load_policy, policy_env_kwargs
    from wirecraft.experts import demonstrator_class

    assert policy_env_kwargs("reactive", "routing")["control"] == "cartesian"
    venv = make_venv(2)
    obs, _ = venv.reset(seed=5)
    policy = load_policy("reactive", venv)
    np.testing.assert_array_equal(policy.act(obs), ReactiveRoutingExpert(venv).act(obs))
    venv.close()
    assert demonstrator_class("routing", "reactive").reactive is ReactiveRoutingExpert
    with pytest.raises(ValueError, match="no reactive expert for task 'toy_family'"):
        demonstrator_class("toy_family", "reactive")
