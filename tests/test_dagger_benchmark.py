"""research/dagger_insertion.py: its labelling experts (the scripted one with diversity off,
unlimited retries and goals re-derived from the current state; the reactive one) solve insertion
on their own, and a state that carries stale expert memory starts the scripted expert over."""

import numpy as np
import pytest

import wirecraft
from wirecraft.experts import reactive
from wirecraft.experts.insertion import InsertionExpert


def make_venv(num_envs):
    return wirecraft.make_vec(
        "insertion", num_envs, threads=1, connector="ethernet", control=InsertionExpert.CONTROL
    )


@pytest.mark.parametrize("kind", ["scripted", "reactive"])
def test_the_labelling_expert_inserts_alone_and_labels_every_step(load_benchmark, kind):
    script = load_benchmark("dagger_insertion")
    venv = make_venv(2)
    expert = script.make_expert(kind, venv)
    states, labels, phases, stats = script.run_wave(
        venv, expert, None, 1.0, seed=3, rng=np.random.default_rng(0)
    )
    venv.close()
    assert stats["reach"] == 1.0 and stats["insert"] == 1.0  # the task's own success flags
    steps = 480
    assert states.shape == (2 * steps, 42) and labels.shape == (2 * steps, 7)
    assert np.all(np.abs(labels) <= 1.0)
    if kind == "scripted":
        names = {expert.fsm.phases[k].name for k in phases}
    else:
        names = {reactive.PHASES[k] for k in phases}
    assert {"approach", "descend", "close", "lift", "pre_insert", "insert"} <= names


def test_stale_expert_memory_is_rederived_from_the_state(load_benchmark):
    script = load_benchmark("dagger_insertion")
    venv = make_venv(3)
    venv.reset(seed=5)
    expert = script.labelling_expert(venv)
    expert.reset(seed=5)
    expert.act(None)  # reads every environment once; all start in approach, plug on the table
    fsm = expert.fsm
    # 0: "carrying" with empty pads; 1: "done" though nothing is seated; 2: lifting from
    # a point 5 cm to the side of where the TCP now is.
    fsm.goto("pre_insert", np.array([True, False, False]))
    fsm.goto("done", np.array([False, True, False]))
    fsm.goto("lift", np.array([False, False, True]))
    view = expert.read_state(2)
    side = np.cross(view.up, [1.0, 0.0, 0.0])
    fsm.snapshots["lift_from"][2] = view.tcp_pos + 0.05 * side / np.linalg.norm(side)
    script.refresh_expert(expert, seated=np.zeros(3, bool))
    assert [fsm.phases[k].name for k in fsm.phase] == ["approach", "approach", "lift"]
    offset = fsm.snapshots["lift_from"][2] - view.tcp_pos
    np.testing.assert_allclose(offset - np.dot(offset, view.up) * view.up, 0.0, atol=1e-12)
    # a seated plug keeps a finished expert finished
    fsm.goto("done", np.array([False, True, False]))
    script.refresh_expert(expert, seated=np.array([False, True, False]))
    assert fsm.phases[fsm.phase[1]].name == "done"
    venv.close()
