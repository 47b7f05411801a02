"""The retention check: release, retreat, then pull the seated plug out along the socket axis."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import wirecraft
from wirecraft.evaluation import retention
from wirecraft.tasks.insertion.task import INSERTION_AXIS


def seated_plug(clearance: float, seed: int = 0, connector: str = "ethernet"):
    """An insertion environment whose plug sits fully home in the socket, aligned, the cable
    laid straight out behind it along the socket axis (a constructed state)."""
    env = wirecraft.make(
        "insertion", connector=connector, clearance=clearance, episode_seconds=30.0
    )
    env.reset(seed=seed)
    unwrapped = env.unwrapped
    task, model, data = unwrapped.task, unwrapped.model, unwrapped.data
    port_rot = data.xmat[task.port_id].reshape(3, 3)
    tip = data.site_xpos[task.seated_site].copy()
    plug_pos = tip - task.connector.plug_length * port_rot[:, 0]
    task.assembly.place(model, data, plug_pos, port_rot[:, 0], 0.0)
    mujoco.mj_forward(model, data)
    assert task.evaluate(model, data)["insert_success"]
    return env, unwrapped


def test_pull_points_out_of_the_socket_along_its_axis_and_ramps_up():
    _, env = seated_plug(0.003)
    pulling = retention.RELEASE_STEPS + retention.RETREAT_STEPS
    assert np.allclose(retention.pull_force(env, pulling - 1, 2.0), 0.0)  # not before the pull
    first = retention.pull_force(env, pulling, 2.0)
    full = retention.pull_force(env, retention.STEPS - 1, 2.0)
    # The port's socket axis is world +y (wirecraft.tasks.insertion): the pull is world -y.
    assert np.allclose(full, -2.0 * INSERTION_AXIS, atol=1e-9)
    assert 0 < np.linalg.norm(first) < 2.0  # ramped, not a step


def test_a_plug_released_in_a_tight_socket_is_retained_under_the_default_pull():
    _, env = seated_plug(0.0)
    retained, failure = retention.check_single(env, retention.DEFAULT_FORCE)
    assert (retained, failure) == (True, None)
    assert env.data.xfrc_applied[env.task.assembly.plug_id].tolist() == [0.0] * 6  # cleared


def test_a_pull_beyond_what_holds_the_plug_pulls_it_out():
    # A plain peg (no latch): at 1 mm clearance the cable's weight wedges it enough to hold
    # 2 N, not 10 N.
    _, env = seated_plug(0.001, connector="cylinder")
    assert retention.check_single(env, 2.0) == (True, None)
    _, env = seated_plug(0.001, connector="cylinder")
    retained, failure = retention.check_single(env, 10.0)
    assert not retained and failure == "pulled_out"
    err = env.task.seating_errors(env.data)
    assert err["axial"] > 0.002  # the tip left the seated target


def test_at_3mm_clearance_the_hanging_cable_tips_a_released_plug_out_before_any_pull():
    _, env = seated_plug(0.003, connector="cylinder")  # a plain peg: nothing holds it
    assert retention.check_single(env, 0.0) == (False, "unseated_on_release")


def test_a_latched_plug_is_retained_at_3mm_clearance_under_the_default_pull():
    _, env = seated_plug(
        0.003
    )  # ethernet: its latch engages once seated (wirecraft.tasks.insertion)
    assert retention.check_single(env, retention.DEFAULT_FORCE) == (True, None)
    assert env.data.eq_active[env.task.retention_eqs].tolist() == [1]


@pytest.mark.parametrize("control", ["joint", "cartesian"])
def test_retention_actions_open_the_gripper_and_only_cartesian_control_retreats(control):
    env = wirecraft.make("insertion", control=control).unwrapped
    release = retention.retention_action(env, 0)
    retreat = retention.retention_action(env, retention.RELEASE_STEPS)
    assert release[-1] == -1.0 and retreat[-1] == -1.0
    assert np.all(release[:-1] == 0.0)
    if control == "cartesian":
        assert retreat[2] > 0 and np.all(retreat[[0, 1, 3, 4, 5]] == 0.0)
    else:
        assert np.all(retreat[:-1] == 0.0)
