"""ReactiveSeatingExpert: its action is a function of the seating state alone (no memory), it
lays the wire into the straight channel by the task's own success flag, its lay runs along the
channel towards the goal, and bad input is refused (its DAgger run: test_dagger_init.py)."""

import numpy as np
import pytest

import wirecraft
from wirecraft.experts.reactive_seating import PHASES, ReactiveSeatingExpert


def make_venv(num_envs, **options):
    options.setdefault("channel", "straight")
    return wirecraft.make_vec("seating", num_envs, threads=1, control="cartesian", **options)


def run(venv, expert, seed, steps=480):
    obs, _ = venv.reset(seed=seed)
    states, actions, phases = [], [], []
    seated = np.zeros(venv.num_envs, bool)
    for _ in range(steps):
        action = expert.act(obs)
        states.append(obs.copy())
        actions.append(action)
        phases.append(expert.phase.copy())
        obs, _, _, _, info = venv.step(action)
        seated |= np.asarray(info["success"], bool)
    return np.stack(states), np.stack(actions), np.stack(phases), seated


@pytest.fixture(scope="module")
def straight_run():
    venv = make_venv(4)
    expert = ReactiveSeatingExpert(venv)
    states, actions, phases, seated = run(venv, expert, seed=21, steps=300)
    venv.close()
    return expert, states, actions, phases, seated


def test_reactive_seating_expert_lays_the_wire(straight_run):
    _, _, actions, phases, seated = straight_run
    # The task's own success flag (80 % of the wire inside the channel); a rate with a margin,
    # not one episode's outcome.
    assert seated.sum() >= 3
    assert np.all(np.abs(actions) <= 1.0)
    visited = {PHASES[k] for k in phases.ravel()}
    assert {"approach", "descend", "close", "lift", "lay", "place", "release"} <= visited


def test_the_lay_runs_along_the_channel_to_its_end(straight_run):
    from wirecraft.geometry import quat_to_mat

    expert, states, actions, phases, _ = straight_run
    lay = expert.layout
    laying = phases == PHASES.index("lay")
    for env in range(states.shape[1]):
        rows = np.flatnonzero(laying[:, env])
        assert len(rows) > 5
        state = states[rows, env]
        # The straight channel's heading (entry to end) from the state's joint points.
        joints = state[0, lay.joints].reshape(-1, 3)
        heading = joints[-1] - joints[0]
        heading[2] = 0.0
        heading /= np.linalg.norm(heading)
        axes = np.stack([quat_to_mat(q)[:, 0] for q in state[:, lay.plug_quat]])
        wire_end = state[:, lay.plug_pos] - expert.end_gap * axes
        along = wire_end @ heading
        # The wire's end moves along the channel towards its end and comes down meanwhile.
        assert along[-1] - along[0] > 0.015
        assert wire_end[-1, 2] < wire_end[0, 2] - 0.01
        # Every commanded move of the lay has a forward component.
        moves = actions[rows, env, :3]
        assert np.mean(moves[:, :2] @ heading[:2] > 0) > 0.9


def test_reactive_seating_expert_has_no_memory(straight_run):
    _, states, actions, _, _ = straight_run
    width = states.shape[-1]
    flat_states, flat_actions = states.reshape(-1, width), actions.reshape(-1, 7)
    # Another expert built on other environments (the curved channel), fed the same states in
    # a shuffled order, gives the same actions row for row: nothing but the state decides them.
    other = make_venv(3, channel="curved")
    other.reset(seed=99)
    order = np.random.default_rng(0).permutation(len(flat_states))
    again = ReactiveSeatingExpert(other).act(flat_states[order])
    other.close()
    np.testing.assert_array_equal(again, flat_actions[order])


def test_reactive_seating_expert_refuses_bad_input():
    venv = make_venv(1)
    state = np.asarray(venv.reset(seed=0)[0], float)
    expert = ReactiveSeatingExpert(venv)
    with pytest.raises(ValueError, match="seating states"):
        expert.act(state[:, :40])
    state[0, 20] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        expert.act(state)
    for gain in (0.0, -0.5, 1.5, float("nan")):
        with pytest.raises(ValueError, match="gain"):
            ReactiveSeatingExpert(venv, gain=gain)
    venv.close()
    fixed = wirecraft.make_vec("seating", 1, threads=1)  # the task's default: cartesian_fixed
    with pytest.raises(ValueError, match="cartesian"):
        ReactiveSeatingExpert(fixed)
    fixed.close()
    insertion = wirecraft.make_vec("insertion", 1, threads=1, control="cartesian")
    with pytest.raises(ValueError, match="seating"):
        ReactiveSeatingExpert(insertion)
    insertion.close()


@pytest.mark.parametrize("channel", ["straight", "curved"])
def test_seating_relative_features_are_the_plug_seen_from_the_tcp_and_the_goal(channel):
    from wirecraft.experts.reactive import FINE_SCALES
    from wirecraft.geometry import quat_to_mat
    from wirecraft.tasks.seating.task import PLUG_LEAD

    env = wirecraft.make("seating", channel=channel, control="cartesian")
    obs, _ = env.reset(seed=3)
    u = env.unwrapped
    features = ReactiveSeatingExpert.relative_features(obs[None])[0]
    assert features.shape == (len(obs) + 33,)
    np.testing.assert_array_equal(features[: len(obs)], obs)
    extra = features[len(obs) :]
    # From the simulation itself: the TCP and plug poses, the channel's centre line.
    tcp, tcp_rot = u.robot.tcp_pose_base(u.model, u.data)
    base = u.data.site_xpos[u.controller.index.base_site]
    base_rot = u.data.site_xmat[u.controller.index.base_site].reshape(3, 3)
    plug = base_rot.T @ (u.data.xpos[u.task.assembly.plug_id] - base)
    plug_rot = base_rot.T @ u.data.xmat[u.task.assembly.plug_id].reshape(3, 3)
    np.testing.assert_allclose(extra[:3], tcp_rot.T @ (plug - tcp), atol=1e-6)
    # (the quaternion's sign does not change the rotation)
    np.testing.assert_allclose(extra[3:12].reshape(3, 3), tcp_rot.T @ plug_rot, atol=1e-6)
    np.testing.assert_allclose(extra[12:15], plug - tcp, atol=1e-6)
    placed = u.task.placed
    line = placed.config.centerline(samples_per_segment=2)
    c, s = np.cos(placed.yaw), np.sin(placed.yaw)
    world = np.column_stack(
        [c * line[:, 0] - s * line[:, 1], s * line[:, 0] + c * line[:, 1], line[:, 2]]
    ) + np.asarray(placed.pos)
    heading = (world[-1] - world[-2]) / np.linalg.norm(world[-1] - world[-2])
    end = base_rot.T @ (world[-1] + PLUG_LEAD * heading - base)
    lay_start = end - ReactiveSeatingExpert.lay_back * (base_rot.T @ heading)
    near = np.concatenate([tcp_rot.T @ (plug - tcp), plug - end, plug - lay_start])
    np.testing.assert_allclose(extra[15:24], np.tanh(near / FINE_SCALES[0]), atol=1e-5)
    np.testing.assert_allclose(extra[24:33], np.tanh(near / FINE_SCALES[1]), atol=1e-5)
    assert np.allclose(quat_to_mat(obs[ReactiveSeatingExpert.layout_class(6).plug_quat]), plug_rot)
    env.close()
    with pytest.raises(ValueError, match="width of the seating task"):
        ReactiveSeatingExpert.relative_features(obs[None, :81])


def test_wirecraft_eval_runs_the_reactive_expert():
    from wirecraft.evaluation.policies import load_policy, policy_env_kwargs
    from wirecraft.evaluation.protocol import run_evaluation

    assert policy_env_kwargs("reactive", "seating")["control"] == "cartesian"
    with pytest.raises(ValueError, match="reactive expert 'toy_family'"):
        policy_env_kwargs("reactive", "toy_family")
    venv = make_venv(2)
    obs, _ = venv.reset(seed=5)
    policy = load_policy("reactive", venv)
    np.testing.assert_array_equal(policy.act(obs), ReactiveSeatingExpert(venv).act(obs))
    venv.close()
    # the protocol's own runner, 4 episodes of 4 s (the wire is laid in 2-3.5 s): a rate with a
    # margin
    run = run_evaluation(
        "seating", "reactive", seeds=1, episodes=4, episode_seconds=4.0, progress=False,
        channel="straight",
    )  # fmt: skip
    assert sum(r.summary["success"] for r in run.results) >= 3
