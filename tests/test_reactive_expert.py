"""ReactiveInsertionExpert: its action is a function of the insertion state alone (no memory),
it seats the plug by the task's own success flag on the UR5 and on the 7-joint Panda (another
state layout), it drives the plug in along the socket's axis, and bad input is refused."""

import numpy as np
import pytest

import wirecraft
from wirecraft.experts.reactive import PHASES, ReactiveInsertionExpert


def make_venv(num_envs, **options):
    options.setdefault("connector", "ethernet")
    return wirecraft.make_vec("insertion", num_envs, threads=1, control="cartesian", **options)


def run(venv, expert, seed, steps=480):
    obs, _ = venv.reset(seed=seed)
    states, actions, phases = [], [], []
    inserted = np.zeros(venv.num_envs, bool)
    for _ in range(steps):
        action = expert.act(obs)
        states.append(obs.copy())
        actions.append(action)
        phases.append(expert.phase.copy())
        obs, _, _, _, info = venv.step(action)
        inserted |= np.asarray(info["insert_success"], bool)
    return np.stack(states), np.stack(actions), np.stack(phases), inserted


@pytest.mark.parametrize("robot", ["ur5", "panda"])
def test_reactive_expert_seats_the_plug(robot):
    venv = make_venv(2, robot=robot)
    expert = ReactiveInsertionExpert(venv)
    states, actions, phases, inserted = run(venv, expert, seed=11)
    venv.close()
    assert inserted.all()  # the task's own insert_success flag
    assert np.all(np.abs(actions) <= 1.0)
    visited = {PHASES[k] for k in phases.ravel()}
    assert {"approach", "descend", "close", "pre_insert", "insert", "release"} <= visited


def test_reactive_expert_has_no_memory():
    venv = make_venv(2)
    states, actions, _, _ = run(venv, ReactiveInsertionExpert(venv), seed=4, steps=300)
    venv.close()
    flat_states, flat_actions = states.reshape(-1, 42), actions.reshape(-1, 7)
    # Another expert built on other environments, fed the same states in a shuffled order,
    # gives the same actions row for row: nothing but the state decides them.
    other = make_venv(3)
    other.reset(seed=99)
    order = np.random.default_rng(0).permutation(len(flat_states))
    again = ReactiveInsertionExpert(other).act(flat_states[order])
    other.close()
    np.testing.assert_array_equal(again, flat_actions[order])


def test_reactive_expert_drives_in_along_the_socket_axis():
    venv = make_venv(2)
    expert = ReactiveInsertionExpert(venv)
    states, actions, phases, _ = run(venv, expert, seed=11, steps=320)
    venv.close()
    axis = expert.port_rot[:, 0]  # into the socket, base frame
    driving = phases == PHASES.index("insert")
    assert driving.any()
    moves = actions[driving][:, :3]
    moving = np.linalg.norm(moves, axis=1) > 1e-3
    cosines = moves[moving] @ axis / np.linalg.norm(moves[moving], axis=1)
    assert np.median(cosines) > 0.9


def test_reactive_expert_refuses_bad_input():
    venv = make_venv(1)
    venv.reset(seed=0)
    expert = ReactiveInsertionExpert(venv)
    state = np.asarray(venv.reset(seed=0)[0], float)
    with pytest.raises(ValueError, match="insertion states"):
        expert.act(state[:, :40])
    state[0, 20] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        expert.act(state)
    for gain in (0.0, -0.5, 1.5, float("nan")):
        with pytest.raises(ValueError, match="gain"):
            ReactiveInsertionExpert(venv, gain=gain)
    venv.close()
    joint = wirecraft.make_vec("insertion", 1, threads=1, control="joint")
    with pytest.raises(ValueError, match="cartesian"):
        ReactiveInsertionExpert(joint)
    joint.close()
