"""The scripted insertion expert: seating, diversity draws, retries, robots (FSM: test_fsm.py)."""

from __future__ import annotations

import numpy as np
import pytest

import wirecraft
from wirecraft.experts import InsertionExpert, InsertionExpertConfig

# -- insertion expert -----------------------------------------------------------------------
SEEDS = (0, 3, 5)  # fixed seeds; the expert seats the plug on each (measured: docs/experts.md)
HOLD = InsertionExpertConfig(release=False, diversity=False)


def test_insertion_expert_seats_the_plug():
    env = wirecraft.make("insertion", robot="ur5", wire="articulated", connector="ethernet")
    expert = InsertionExpert(env, HOLD)
    for seed in SEEDS:
        obs, _ = env.reset(seed=seed)
        expert.reset(seed=seed)
        reached = inserted = False
        for _ in range(env.unwrapped.max_steps):
            action = expert.act(obs)
            assert action.shape == (1, 7) and np.all(np.abs(action) <= 1.0)
            obs, _, _, truncated, info = env.step(action[0])
            reached |= info["reach_success"]
            inserted |= info["insert_success"]
            if truncated:
                break
        assert reached and inserted, f"seed {seed}: phase {expert.phase_names[0]}"
        assert info["insert_success"], f"seed {seed}: not seated at the end"
    env.close()


def test_insertion_expert_drives_a_vector_env():
    venv = wirecraft.make_vec("insertion", num_envs=2, threads=1)
    expert = InsertionExpert(venv)
    venv.reset(seed=0)
    expert.reset()
    for _ in range(40):
        actions = expert.act()
        assert actions.shape == (2, 7)
        venv.step(actions)
    assert set(expert.phase_names) <= {"approach", "descend"}
    venv.close()


def test_insertion_expert_needs_cartesian_control():
    env = wirecraft.make("insertion", control="joint")
    with pytest.raises(ValueError, match="cartesian"):
        InsertionExpert(env)


def _episode(env, expert, seed: int, steps: int | None = None):
    """Run one seeded episode; returns the actions, the phases entered and the last info."""
    env.reset(seed=seed)
    expert.reset(seed=seed)
    actions, phases, info = [], [], {}
    for _ in range(steps or env.unwrapped.max_steps):
        action = expert.act()[0]
        actions.append(action)
        if not phases or phases[-1] != expert.phase_names[0]:
            phases.append(expert.phase_names[0])
        _, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    return np.array(actions), phases, info


@pytest.fixture(scope="module")
def ethernet():
    env = wirecraft.make("insertion", connector="ethernet")
    yield env
    env.close()


# -- diversity ----------------------------------------------------------------------------------
def test_diversity_draws_come_from_the_seed(ethernet):
    expert = InsertionExpert(ethernet, InsertionExpertConfig(), seed=1)
    plans = []
    for seed in (4, 5, 4):
        expert.reset(seed=seed)
        plans.append(expert.episode_plan[0])
    assert plans[0] == plans[2] and plans[0] != plans[1]
    cfg = InsertionExpertConfig()
    for plan in plans:
        assert cfg.approach_pitch_range[0] <= plan["approach_pitch"] <= cfg.approach_pitch_range[1]
        assert cfg.grasp_back_range[0] <= plan["grasp_back"] <= cfg.grasp_back_range[1]
        assert cfg.close_pause[0] <= plan["close_pause"] <= cfg.close_pause[1]
    # The constructor's seed is the first episode's; without a seed reset continues the stream.
    a, b = InsertionExpert(ethernet, seed=9), InsertionExpert(ethernet, seed=9)
    a.reset()
    b.reset()
    assert a.episode_plan == b.episode_plan
    with pytest.raises(ValueError, match="seed"):
        InsertionExpert(ethernet, seed=-1)


def test_without_diversity_the_plan_is_the_fixed_configuration(ethernet):
    cfg = InsertionExpertConfig(diversity=False)
    expert = InsertionExpert(ethernet, cfg)
    for seed in range(20):
        expert.reset(seed=seed)
        plan = expert.episode_plan[0]
        assert not plan["pick_and_drop"]
        assert plan["approach_pitch"] == cfg.approach_pitch
        assert plan["grasp_back"] == cfg.grasp_back
        assert plan["descend_factor"] == plan["insert_factor"] == 1.0
        assert plan["close_pause"] == plan["insert_pause"] == 0


@pytest.mark.parametrize("probability", [0.3, 0.7])
def test_pick_and_drop_is_drawn_at_the_configured_rate(ethernet, probability):
    expert = InsertionExpert(ethernet, InsertionExpertConfig(pick_and_drop_prob=probability))
    n = 3000
    drops = 0
    for seed in range(n):
        expert.reset(seed=seed)
        drops += expert.pick_and_drop[0]
    sigma = (probability * (1 - probability) / n) ** 0.5
    assert abs(drops / n - probability) < 4 * sigma


def test_same_seed_gives_the_same_actions_with_diversity_on():
    env_a, env_b = (wirecraft.make("insertion", connector="usb_a") for _ in range(2))
    actions = []
    for env in (env_a, env_b):
        expert = InsertionExpert(env, InsertionExpertConfig(diversity=True))
        actions.append(_episode(env, expert, seed=2, steps=150)[0])
    np.testing.assert_array_equal(actions[0], actions[1])
    # The same scene with another expert seed: another approach pitch, other actions.
    expert = InsertionExpert(env_a, InsertionExpertConfig(diversity=True))
    env_a.reset(seed=2)
    expert.reset(seed=3)
    other = []
    for _ in range(20):
        other.append(expert.act()[0])
        env_a.step(other[-1])
    assert not np.allclose(np.array(other), actions[0][:20])
    env_a.close()
    env_b.close()


def test_a_picked_and_dropped_plug_is_grasped_again_and_seated(ethernet):
    cfg = InsertionExpertConfig(release=False, pick_and_drop_prob=1.0)
    expert = InsertionExpert(ethernet, cfg)
    _, phases, info = _episode(ethernet, expert, seed=1)
    assert phases[:6] == ["approach", "descend", "close", "lift", "drop", "approach"], phases
    assert expert.dropped[0]
    assert info["insert_success"], phases


def test_a_failed_insertion_backs_out_and_retries_at_most_twice(ethernet):
    """The expert's branch on a stalled insertion, driven without stepping the physics."""
    expert = InsertionExpert(ethernet, InsertionExpertConfig(diversity=False))
    ethernet.reset(seed=0)
    expert.reset(seed=0)
    fsm = expert.fsm
    expert.views[0] = expert.read_state(0)
    fsm.snapshots["plug_goal_rot"][0] = expert._plug_goal_rot(0)
    entered = []
    for _ in range(3):
        fsm.goto("insert", [True])
        expert.stalled[0] = True  # no axial progress for stall_steps
        for _ in range(fsm.phases[fsm.index("insert")].dwell):  # the verdict must dwell
            before = fsm.phase.copy()
            expert._on_advance(fsm.advance_if([True]), before)
        entered.append(expert.phase_names[0])
        if entered[-1] == "back_out":
            # backs out along the socket axis to the pre-insertion distance, same rotation
            view = expert.views[0]
            back = fsm.get("back_pos")[0] - view.tcp_pos
            axis = view.port_rot[:, 0]
            assert np.allclose(back, -np.dot(-back, axis) * axis, atol=1e-9)
            assert np.dot(-back, axis) >= expert.config.pre_insert
    assert entered == ["back_out", "back_out", "tilt"]
    assert expert.insert_retries.tolist() == [2]
    expert.reset()
    assert expert.insert_retries.tolist() == [0]


def test_config_validation():
    with pytest.raises(ValueError, match="pick_and_drop_prob"):
        InsertionExpertConfig(pick_and_drop_prob=1.5)
    with pytest.raises(ValueError, match="grasp_back_range"):
        InsertionExpertConfig(grasp_back_range=(0.01, 0.0))
    with pytest.raises(ValueError, match="max_insert_retries"):
        InsertionExpertConfig(max_insert_retries=-1)
    with pytest.raises(ValueError, match="max_insertion_force"):
        InsertionExpertConfig(max_insertion_force=0.0)
    with pytest.raises(ValueError, match="force_hold"):
        InsertionExpertConfig(force_hold=1.5)
    with pytest.raises(ValueError, match="force_backoff"):
        InsertionExpertConfig(force_backoff=0.0)
    with pytest.raises(ValueError, match="sag_gain"):
        InsertionExpertConfig(sag_gain=-0.1)
    with pytest.raises(ValueError, match="sag_limit"):
        InsertionExpertConfig(sag_limit=-0.001)
    with pytest.raises(ValueError, match="sag_window"):
        InsertionExpertConfig(sag_window=float("nan"))


# -- other robots ------------------------------------------------------------------------------
@pytest.mark.parametrize("robot", ["panda", "wxai"])
def test_other_robots_seat_the_plug(robot):
    env = wirecraft.make("insertion", robot=robot, connector="ethernet")
    expert = InsertionExpert(env, HOLD)
    for seed in (0, 2):
        _, phases, info = _episode(env, expert, seed=seed)
        assert info["insert_success"], (robot, seed, phases)
    env.close()


def _pre_insert_outcome(env, config, seed: int):
    """(steps spent in pre_insert, whether it ended by its timeout rather than its
    tolerance), for the first pre-insertion of a seeded episode."""
    expert = InsertionExpert(env, config)
    env.reset(seed=seed)
    expert.reset(seed=seed)
    steps = 0
    for _ in range(env.unwrapped.max_steps):
        before = expert.phase_names[0]
        env.step(expert.act()[0])
        if before == "pre_insert":
            steps += 1
            if expert.phase_names[0] != "pre_insert":
                return steps, bool(expert.fsm.timed_out[0])
    raise AssertionError(f"pre_insert never ended (phase {expert.phase_names[0]})")


def test_integral_action_brings_a_sagging_arm_within_the_pre_insert_tolerance(monkeypatch):
    """A WidowX AI with softer servos (kp 300 / 60 N m/rad, its gains before it was stiffened)
    sags ~2 mm under the held plug on seed 5, beyond the 1.5 mm tolerance of pre_insert: without
    the integral offset the phase runs into its timeout; with it, the tolerance is met well
    before."""
    import dataclasses

    from wirecraft.assets.robots.base import ROBOTS

    stiff = ROBOTS.get("wxai")
    soft = tuple(
        dataclasses.replace(joint, kp=300.0 if k < 3 else 60.0)
        for k, joint in enumerate(stiff.joints)
    )
    monkeypatch.setitem(ROBOTS._items, "wxai", dataclasses.replace(stiff, joints=soft))
    env = wirecraft.make("insertion", robot="wxai", connector="ethernet")
    plain = InsertionExpertConfig(release=False, diversity=False, sag_gain=0.0)
    steps, timed_out = _pre_insert_outcome(env, plain, seed=5)
    assert timed_out, steps
    steps, timed_out = _pre_insert_outcome(env, HOLD, seed=5)
    assert not timed_out and steps < 120, steps
    env.close()


# -- gentle insertion -------------------------------------------------------------------------
def test_the_push_is_held_then_backed_off_as_the_insertion_force_grows(ethernet):
    import dataclasses

    from wirecraft.geometry import rotation_error

    expert = InsertionExpert(ethernet, InsertionExpertConfig(diversity=False))
    ethernet.reset(seed=0)
    expert.reset(seed=0)
    view = expert.read_state(0)
    # A controller target leading the TCP by 4 mm and 0.1 rad, as when the plug is blocked.
    lead_rot = np.array(
        [[1.0, 0, 0], [0, np.cos(0.1), -np.sin(0.1)], [0, np.sin(0.1), np.cos(0.1)]]
    )
    view = dataclasses.replace(
        view, target_pos=view.tcp_pos + [0.004, 0, 0], target_rot=lead_rot @ view.tcp_rot
    )
    goal_pos, goal_rot = view.tcp_pos + [0.01, 0, 0], view.tcp_rot
    cfg = expert.config
    limit, hold = cfg.max_insertion_force, cfg.force_hold * cfg.max_insertion_force
    outcomes = {}
    for force in (0.0, 0.5 * hold, 0.5 * (hold + limit), 2.0 * limit):
        expert.views[0] = dataclasses.replace(view, insertion_force=force)
        outcomes[force] = expert._gentle(0, goal_pos, goal_rot, 0.0015)
    assert outcomes[0.0] == (goal_pos, goal_rot, 0.0015)  # no contact: unchanged
    pos, rot, speed = outcomes[0.5 * hold]  # light contact: same goal, approached slower
    assert pos is goal_pos and speed == pytest.approx(0.00075)
    pos, rot, _ = outcomes[0.5 * (hold + limit)]  # near the limit: the target stops
    assert np.allclose(pos, view.target_pos) and np.allclose(rot, view.target_rot)
    pos, rot, _ = outcomes[2.0 * limit]  # over it: the lead shrinks, position and rotation
    keep = 1.0 - cfg.force_backoff
    assert np.allclose(pos - view.tcp_pos, [0.004 * keep, 0, 0])
    assert np.linalg.norm(rotation_error(rot, view.tcp_rot)) == pytest.approx(0.1 * keep)
