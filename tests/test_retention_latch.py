"""Connector retention: latches and friction holds engage on seating, hold a seated plug under
the cable's weight and below their rated pull, let go above it, never latch a wrong
orientation, and live in the simulation state (snapshots, vector environment)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

import wirecraft
from wirecraft.assets.connectors import CONNECTORS, make_connector
from wirecraft.assets.connectors.base import RETENTION_PLAY
from wirecraft.envs import env_seed
from wirecraft.experts import InsertionExpert, InsertionExpertConfig
from wirecraft.tasks.insertion.task import AXIAL_TOLERANCE

OPEN = np.array([0, 0, 0, 0, 0, 0, -1.0])  # arm holds still, gripper open (far from the plug)
# Published or typical figures (docs/assets.md, Retention), written out independently here.
EXPECTED = {
    "ethernet": ("latch", 50.0),
    "displayport": ("latch", 30.0),
    "usb_a": ("friction", 10.0),
    "cylinder": ("none", 0.0),
    "cuboid": ("none", 0.0),
}


def seated(connector: str = "ethernet", clearance: float = 0.003, roll: float = 0.0, seed=0):
    """An insertion environment whose plug sits fully home in the socket with roll ``roll``
    about its axis, the cable laid straight out behind it (a constructed state, released: the
    robot is far away, gripper open)."""
    env = wirecraft.make(
        "insertion", connector=connector, clearance=clearance, episode_seconds=30.0
    ).unwrapped
    env.reset(seed=seed)
    place_seated(env, roll)
    return env


def place_seated(env, roll: float = 0.0) -> None:
    task, model, data = env.task, env.model, env.data
    port_rot = data.xmat[task.port_id].reshape(3, 3)
    tip = data.site_xpos[task.seated_site].copy()
    task.assembly.place(
        model, data, tip - task.connector.plug_length * port_rot[:, 0], port_rot[:, 0], roll
    )
    mujoco.mj_forward(model, data)
    assert task.evaluate(model, data)["insert_success"]


def retention_eq_active(env) -> list[int]:
    return env.data.eq_active[env.task.retention_eqs].tolist()


def pull(env, force_at, steps: int) -> list[tuple[float, dict]]:
    """Pull the plug out along the socket axis with ``force_at(k, infos)`` newtons at control
    step ``k`` (an external force on the plug body); returns (force, info) per step."""
    task, data = env.task, env.data
    plug = task.assembly.plug_id
    out = []
    for k in range(steps):
        force = float(force_at(k, [i for _, i in out]))
        axis = data.xmat[task.port_id].reshape(3, 3)[:, 0]  # into the socket
        data.xfrc_applied[plug, :3] = -force * axis
        _, _, _, _, info = env.step(OPEN)
        assert not info["diverged"], f"step {k}"
        out.append((force, info))
    data.xfrc_applied[plug] = 0.0
    return out


def pull_test(start: float, rated: float):
    """A pull-out test: the force rises from ``start`` at 30 N/s until the plug gives way (the
    latch's click), then follows through with 2 N.  A real pull drops once the latch yields; a
    10 g plug freed under tens of newtons would reach 20 m/s within one control step."""

    def force_at(k, infos):
        if infos and not infos[-1]["latched"]:
            return 2.0
        return min(start + 30.0 * (k + 1) / 60.0, 2.0 * rated)

    return force_at


# -- the connector descriptions -----------------------------------------------------------------
@pytest.mark.parametrize("name", CONNECTORS.names())
def test_every_family_declares_its_retention(name):
    connector = make_connector(name)
    assert (connector.retention_mechanism, connector.retention_force) == EXPECTED[name]
    assert connector.retains == (EXPECTED[name][1] > 0)


@pytest.mark.parametrize("name", CONNECTORS.names())
def test_one_inactive_weld_per_seating_orientation(name):
    env = wirecraft.make("insertion", connector=name).unwrapped
    model, connector = env.model, env.task.connector
    expected = connector.symmetry if connector.retains else 0
    assert len(env.task.retention_eqs) == expected
    for k, eq in enumerate(env.task.retention_eqs):
        assert model.eq_type[eq] == mujoco.mjtEq.mjEQ_WELD
        assert model.eq_active0[eq] == 0 and env.data.eq_active[eq] == 0
        # Its target: the seated tip, RETENTION_PLAY short of the back stop, rolled by k turns.
        site = model.site(f"port_retention{k}")
        assert site.pos == pytest.approx([connector.cavity_depth - RETENTION_PLAY, 0, 0])
        roll = 2 * math.atan2(site.quat[1], site.quat[0])
        assert roll == pytest.approx(2 * math.pi * k / connector.symmetry)


def test_bad_retention_declarations_are_refused():
    from wirecraft.assets.connectors import add_port, add_retention
    from wirecraft.assets.connectors.cylinder import CylinderConnector
    from wirecraft.assets.connectors.ethernet import EthernetConnector
    from wirecraft.scene import new_spec

    class LatchedPeg(CylinderConnector):
        retention_mechanism, retention_force = "latch", 5.0

    class Glued(EthernetConnector):
        retention_mechanism, retention_force = "glue", 5.0

    for connector, match in ((LatchedPeg(), "rotation-invariant"), (Glued(), "glue")):
        spec = new_spec("retention")
        add_port(spec, connector)
        with pytest.raises(ValueError, match=match):
            add_retention(spec, connector)


# -- holding ------------------------------------------------------------------------------------
def test_a_released_latched_ethernet_plug_stays_seated_for_two_seconds():
    env = seated("ethernet")
    for step in range(120):
        _, _, _, _, info = env.step(OPEN)
        assert info["latched"] and info["insert_success"], f"step {step}"
    err = env.task.seating_errors(env.data)
    # The weld holds the tip RETENTION_PLAY short of the stop, the plug aligned (the cable's
    # weight turns it by a degree or two on the weld's rotational stiffness), gently.
    assert err["axial"] == pytest.approx(RETENTION_PLAY, abs=2e-4)
    assert err["lateral"] < 2e-4 and err["axis_error"] < math.radians(3.0)
    assert abs(info["latch_force"]) < 5.0
    assert np.abs(env.data.qvel).max() < 1.0  # at rest, no jitter


def test_a_plain_peg_still_tips_out_under_the_cable_as_before():
    env = seated("cylinder")
    assert retention_eq_active(env) == []
    lost = False
    for _ in range(120):
        _, _, _, _, info = env.step(OPEN)
        assert not info["latched"]
        lost |= not info["insert_success"]
    assert lost


@pytest.mark.parametrize("name", ["ethernet", "displayport", "usb_a"])
def test_a_pull_below_the_retention_force_holds_and_above_it_pulls_the_plug_out(name):
    rated = make_connector(name).retention_force
    env = seated(name)
    env.step(OPEN)
    assert env.task.engaged_retention(env.data) == 0
    # The latch carries the pull plus the cable's own push or pull on the plug (a newton or
    # two, either way): "below" and "at" the rating are within that margin.
    cable = 2.5  # N
    held = pull(env, lambda k, _: min(rated - 2 * cable, 100.0 * (k + 1) / 60.0), 60)
    assert all(i["latched"] and i["insert_success"] for _, i in held)
    assert held[-1][1]["latch_force"] == pytest.approx(rated - 2 * cable, abs=cable)
    out = pull(env, pull_test(rated - 2 * cable, rated), 60)
    released = next(k for k, (_, i) in enumerate(out) if not i["latched"])
    # The force that made it let go (the weld's own lag adds up to a step of the ramp).
    assert out[released][0] == pytest.approx(rated, abs=cable + 1.0)
    assert not out[-1][1]["latched"] and not out[-1][1]["insert_success"]
    assert env.task.seating_errors(env.data)["axial"] > 0.01  # out of the socket


def test_a_pulled_out_plug_is_not_caught_again_until_it_left_the_seat():
    env = seated("ethernet")
    env.step(OPEN)
    assert env.task.retention_armed
    env.data.eq_active[env.task.retention_eqs] = 0  # as if just pulled free, still seated
    env.task.retention_armed = False
    env.task.after_step(env.model, env.data)
    assert retention_eq_active(env) == [0]
    # Once it has been out of the seated zone, seating it again latches it again.
    place_back = env.task.connector.plug_length + AXIAL_TOLERANCE + 0.003
    task, data = env.task, env.data
    axis = data.xmat[task.port_id].reshape(3, 3)[:, 0]
    tip = data.site_xpos[task.seated_site].copy()
    task.assembly.place(env.model, data, tip - place_back * axis, axis, 0.0)
    mujoco.mj_forward(env.model, data)
    task.after_step(env.model, data)
    assert task.retention_armed and retention_eq_active(env) == [0]
    place_seated(env)
    task.after_step(env.model, data)
    assert retention_eq_active(env) == [1]


# -- orientation --------------------------------------------------------------------------------
@pytest.mark.parametrize("roll", [math.pi, math.radians(25.0)])
def test_a_keyed_plug_in_a_wrong_orientation_does_not_latch(roll):
    # Constructed (the key stops a real upside-down plug at the mouth: test_connectors.py); the
    # latch decision alone, on a state whose tip is seated.
    env = seated("ethernet", roll=roll)
    assert env.task.evaluate(env.model, env.data)["insert_success"]
    env.task.after_step(env.model, env.data)
    assert retention_eq_active(env) == [0]


def test_a_two_fold_plug_latches_in_its_flipped_orientation_too():
    env = seated("usb_a", roll=math.pi)
    for _ in range(30):
        _, _, _, _, info = env.step(OPEN)
    assert retention_eq_active(env) == [0, 1] and info["insert_success"]
    roll = env.task.seating_errors(env.data)["roll"]
    assert abs(abs(roll) - math.pi) < 0.02  # held flipped, not turned over


# -- state ----------------------------------------------------------------------------------
def test_snapshots_replay_a_latch_engaging_and_releasing_bit_exactly():
    env = seated("usb_a")
    start = env.get_state()

    def run():
        trace = []
        for k in range(50):
            if k == 20:  # a hard pull: the latch lets go
                env.data.xfrc_applied[env.task.assembly.plug_id, 1] = -0.5
            obs, reward, _, _, info = env.step(OPEN)
            trace.append(np.concatenate([obs, [reward, info["latched"]], env.data.qpos]))
        return np.array(trace), info

    env.data.xfrc_applied[env.task.assembly.plug_id] = 0.0
    first, _ = run()
    assert first[:, -env.model.nq - 1].any()  # it latched at some point
    env.set_state(start)
    second, _ = run()
    np.testing.assert_array_equal(first, second)


def test_the_vector_env_latches_exactly_like_the_single_env():
    seed, steps = 3, 40
    venv = wirecraft.make_vec("insertion", 2, threads=2, connector="usb_a")
    venv.reset(seed=seed)
    single = wirecraft.make("insertion", connector="usb_a").unwrapped
    single.reset(seed=env_seed(seed, 0))
    for env in (venv.envs[0], single):
        place_seated(env)
    traces = {"vector": [], "single": []}
    for k in range(steps):
        for env in (venv.envs[0], single):
            # A pull above the rated 10 N from step 20: the latch lets go (an xfrc is state).
            env.data.xfrc_applied[env.task.assembly.plug_id, :3] = (
                [0.0, -12.0, 0.0] if 20 <= k < 24 else 0.0
            )
        obs, reward, _, _, infos = venv.step(np.tile(OPEN, (2, 1)))
        traces["vector"].append(
            np.concatenate([obs[0], [reward[0], infos["latched"][0]], venv.envs[0].data.eq_active])
        )
        obs1, reward1, _, _, info1 = single.step(OPEN)
        traces["single"].append(
            np.concatenate([obs1, [reward1, info1["latched"]], single.data.eq_active])
        )
    vector, alone = np.array(traces["vector"]), np.array(traces["single"])
    np.testing.assert_array_equal(vector, alone)
    latched = vector[:, -single.model.neq - 1]
    assert latched[:20].all() and not latched[-1]  # engaged, then released by the pull
    venv.close()


# -- the expert ---------------------------------------------------------------------------------
@pytest.mark.slow
def test_the_expert_latches_the_plug_with_a_gentle_push():
    env = wirecraft.make("insertion", connector="ethernet")
    expert = InsertionExpert(env, InsertionExpertConfig(diversity=False))
    env.reset(seed=0)
    expert.reset(seed=0)
    push = []
    for _ in range(env.unwrapped.max_steps):
        _, _, _, truncated, info = env.step(expert.act()[0])
        if info["grasp_force"] > 1.0:
            push.append(info["insertion_force"])
        if truncated:
            break
    assert info["latched"] and info["insert_success"], expert.phase_names
    assert expert.phase_names[0] == "done"
    # Gentle: the force limit (25 N) with a margin for the one-step lag of the limiter.
    assert max(push) < 2 * expert.config.max_insertion_force
    env.close()
