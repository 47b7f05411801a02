"""The batched step: kernels against their per-environment forms and MuJoCo, contact sensors
against the contact list, and each row of the vector step against a single environment."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import wirecraft
from wirecraft import geometry as G
from wirecraft.assets.robots import kinematics as K
from wirecraft.envs import env_seed
from wirecraft.experts import expert_class
from wirecraft.tasks.frame import Frame

RNG = np.random.default_rng(0)


def random_rotations(n):
    return np.stack([G.axis_angle_to_mat(v) for v in RNG.normal(size=(n, 3)) * 1.5])


def test_batched_rotation_helpers_match_mujoco_and_the_scalar_forms():
    rots = random_rotations(64)
    # Rotations by ~pi exercise every branch of the quaternion extraction.
    rots = np.concatenate([rots, [G.axis_angle_to_mat(np.array(a) * np.pi) for a in np.eye(3)]])
    quats = G.mats_to_quats(rots)
    for rot, quat in zip(rots, quats, strict=True):
        reference = G.mat_to_quat(rot)  # mju_mat2Quat
        assert np.allclose(quat, reference, atol=1e-12) or np.allclose(quat, -reference, atol=1e-12)
    # Back through mju_quat2Mat, from q, from -q and from a quaternion of another length.
    for sign, scale in ((1.0, 1.0), (-1.0, 1.0), (1.0, 2.5)):
        mats = G.quats_to_mats(sign * scale * quats)
        for quat, mat in zip(quats, mats, strict=True):
            np.testing.assert_allclose(mat, G.quat_to_mat(quat), atol=1e-12)
    np.testing.assert_allclose(G.quats_to_mats(quats), rots, atol=1e-12)
    vecs = RNG.normal(size=(32, 3))
    vecs[0] = 0.0  # no rotation
    mats = G.axis_angle_to_mats(vecs)
    for vec, mat in zip(vecs, mats, strict=True):
        np.testing.assert_allclose(mat, G.axis_angle_to_mat(vec), atol=1e-14)
    other = random_rotations(len(rots))
    errors = G.rotation_errors(rots, other)
    for target, current, error in zip(rots, other, errors, strict=True):
        np.testing.assert_allclose(error, G.rotation_error(target, current), atol=1e-12)


def test_batched_damped_least_squares_matches_the_scalar_solver_at_joint_limits():
    jac = RNG.normal(size=(16, 6, 7))
    err = RNG.normal(size=(16, 6)) * 0.05
    lower, upper = -np.ones(7), np.ones(7)
    q = RNG.uniform(-1.0, 1.0, (16, 7))
    q[:8, 0] = 0.999  # half the rows start against a limit: the second solve runs
    batch = K.dls_limited_batch(jac, err, 0.02, q, lower, upper)
    limited = 0
    for r in range(16):
        single = K.dls_limited(jac[r], err[r], 0.02, q[r], lower, upper)
        np.testing.assert_allclose(batch[r], single, atol=1e-12)
        assert np.all(q[r] + batch[r] <= upper + 1e-12) and np.all(q[r] + batch[r] >= lower - 1e-12)
        limited += np.any(np.isclose(q[r] + batch[r], upper) | np.isclose(q[r] + batch[r], lower))
    assert limited > 0


@pytest.mark.parametrize("robot", ["ur5", "panda"])
def test_the_numpy_jacobian_is_mujocos(robot):
    env = wirecraft.make("insertion", robot=robot).unwrapped
    env.reset(seed=3)
    model, data, ctl = env.model, env.data, env.controller
    for _ in range(5):
        env.step(RNG.uniform(-1, 1, env.action_space.shape))
        site = ctl.index.tcp_site
        jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, data, jacp, jacr, site)
        reference = np.vstack([jacp, jacr])[:, ctl.index.arm_dof]
        ours = ctl.tcp_jacobian(data.cdof[None], data.subtree_com[None], data.site_xpos[site][None])
        np.testing.assert_array_equal(ours[0], reference)


CELLS = [
    ("insertion", "articulated", {}),
    ("insertion", "rod", {}),
    ("routing", "articulated", {"num_clips": 1}),
    ("routing", "rod", {"num_clips": 1}),
    ("routing", "fem", {"num_clips": 1}),
    ("seating", "fem", {"channel": "straight"}),
]


@pytest.mark.parametrize("task, wire, options", CELLS, ids=lambda c: str(c))
def test_contact_sensors_report_what_the_contact_list_holds(task, wire, options):
    """Pad-on-held-part and robot-on-table flags from the contact sensors against a walk over
    ``data.contact``, along an expert's grasp and a dive into the table (a flex wire's
    contacts carry no geom on its side: the sensors count them by elimination)."""
    cls = expert_class(task)
    env = wirecraft.make(task, control=cls.CONTROL, wire=wire, **options).unwrapped
    obs, _ = env.reset(seed=0)
    expert = cls(env, seed=0)
    expert.reset()
    task, model, data = env.task, env.model, env.data
    seen = {"pads": 0, "table": 0}

    def check():
        frame = Frame.of_data(data)
        pads = task.pads_touching(frame)[0]
        walked = task.pad_contacts(model, data, task.held_contacts)
        assert tuple(bool(p) for p in pads) == tuple(walked)
        table = bool(task.table_collision(frame)[0])
        assert table == task.gripper_collision(model, data)
        seen["pads"] += int(pads.all())
        seen["table"] += int(table)

    for _ in range(150):
        obs, *_ = env.step(expert.act(obs[None])[0])
        check()
    dive = np.zeros(env.action_space.shape)
    dive[2] = -1.0
    for _ in range(60):
        env.step(dive)
        check()
    assert seen["pads"] > 0 and seen["table"] > 0  # both kinds of contact were exercised


def vector_trace(task, options, num_envs=3, steps=40, **vec_options):
    venv = wirecraft.make_vec(
        task, num_envs, threads=2, episode_seconds=0.5, **options, **vec_options
    )
    obs, _ = venv.reset(seed=11)
    rng = np.random.default_rng(5)
    trace = []
    for _ in range(steps):
        obs, rewards, _, truncated, infos = venv.step(rng.uniform(-1, 1, venv.action_space.shape))
        trace.append((obs.copy(), rewards.copy(), truncated.copy(), infos))
    return trace


def single_traces(task, options, num_envs=3, steps=40, diagnostics=True):
    """What ``vector_trace`` should give, from single environments stepped one at a time
    (mj_step), each reset anew (continuing its seeded stream) when its episode ends."""
    envs = [
        wirecraft.make(task, episode_seconds=0.5, diagnostics=diagnostics, **options).unwrapped
        for _ in range(num_envs)
    ]
    for i, env in enumerate(envs):
        env.reset(seed=env_seed(11, i))
    rng = np.random.default_rng(5)
    trace = []
    for _ in range(steps):
        actions = rng.uniform(-1, 1, (num_envs, *envs[0].action_space.shape))
        rows = []
        for env, action in zip(envs, actions, strict=True):
            obs, reward, _, truncated, info = env.step(action)
            final = None
            if truncated:
                final, (obs, _) = obs, env.reset()
            rows.append((obs, reward, truncated, info, final))
        trace.append(rows)
    return trace


VEC_OPTIONS = {
    "full": {},
    "training": {"diagnostics": False, "sync_envs": False},
    "diagnostics-unsynced": {"sync_envs": False},
}
ROW_CASES = [
    *(
        (task, {"num_clips": 3} if task == "routing" else {}, name)
        for task in ("insertion", "routing", "seating")
        for name in VEC_OPTIONS
    ),
    # the flex wires, whose centre lines and pad contacts take other paths
    ("routing", {"wire": "rod"}, "training"),
    ("seating", {"wire": "fem", "channel": "curved"}, "training"),
    ("insertion", {"wire": "fem"}, "full"),
]


@pytest.mark.parametrize("task, options, config", ROW_CASES, ids=lambda c: str(c))
def test_row_i_of_the_vector_env_is_a_single_environment(task, options, config):
    """Observations, rewards, flags and every info key, through an autoreset (30-step
    episodes), bit for bit against single environments; ``training`` also stops the batch one
    stage earlier (no constraint solve at the new state)."""
    vec_options = VEC_OPTIONS[config]
    diagnostics = vec_options.get("diagnostics", True)
    batched = vector_trace(task, options, **vec_options)
    single = single_traces(task, options, diagnostics=diagnostics)
    resets = 0
    for (obs, rewards, truncated, infos), rows in zip(batched, single, strict=True):
        for i, (obs_i, reward_i, truncated_i, info_i, final_i) in enumerate(rows):
            np.testing.assert_array_equal(obs[i], obs_i)
            assert rewards[i] == reward_i and truncated[i] == truncated_i
            for key, value in info_i.items():
                assert infos[key][i] == value, key
            if final_i is not None:
                assert infos["_final_obs"][i]
                np.testing.assert_array_equal(infos["final_obs"][i], final_i)
                assert infos["final_info"]["success"][i] == info_i["success"]
                resets += 1
    assert resets == 3  # every environment finished one episode


def test_synced_environments_mirror_the_batch_and_unsynced_ones_do_not_cost_a_copy():
    synced = wirecraft.make_vec("insertion", 2, threads=1)
    lazy = wirecraft.make_vec("insertion", 2, threads=1, sync_envs=False, diagnostics=False)
    for venv in (synced, lazy):
        venv.reset(seed=2)
        for _ in range(3):
            venv.step(np.full(venv.action_space.shape, 0.5))
    from wirecraft.envs.env import STATE_SPEC

    def state_of(venv, i):
        out = np.empty(mujoco.mj_stateSize(venv.model, STATE_SPEC))
        mujoco.mj_getState(venv.model, venv.envs[i].data, out, STATE_SPEC)
        return out

    for i in range(2):
        np.testing.assert_array_equal(state_of(synced, i), synced.batch.state[i])
        np.testing.assert_array_equal(
            synced.envs[i].controller.target_pos, synced.controls.target_pos[i]
        )
        assert synced.envs[i].elapsed_steps == 3
        assert not np.array_equal(state_of(lazy, i), lazy.batch.state[i])
    lazy.render()  # rendering brings them up to date first
    for i in range(2):
        np.testing.assert_array_equal(state_of(lazy, i), lazy.batch.state[i])


def test_diagnostics_can_be_left_out_of_info():
    full = wirecraft.make_vec("insertion", 2, threads=1)
    lean = wirecraft.make_vec("insertion", 2, threads=1, diagnostics=False)
    keys = {}
    for name, venv in (("full", full), ("lean", lean)):
        venv.reset(seed=0)
        *_, infos = venv.step(np.zeros(venv.action_space.shape))
        keys[name] = {k for k in infos if not k.startswith("_")}
    dropped = {"insertion_force", "grasp_force", "wire_tension", "min_bend_radius"}
    dropped |= {"peak_contact_force"}
    assert keys["full"] - keys["lean"] == dropped
    assert {"success", "reach_success", "insert_success", "diverged"} <= keys["lean"]


def test_image_observations_need_synced_environments():
    with pytest.raises(ValueError, match="sync_envs=False needs obs_mode='state'"):
        wirecraft.make_vec("routing", 1, threads=1, sync_envs=False, obs_mode="rgb", image_size=32)


def test_a_latch_engages_and_lets_go_alike_in_every_configuration():
    """A seated USB-A plug latches, then a 12 N pull (rated 10 N) frees it: the single
    environment, the synced batched step (full forward pass in the batch) and the training
    one (the weld force from a forward pass of that environment alone) agree bit for bit."""
    from wirecraft.envs import env_seed
    from wirecraft.envs.env import STATE_SPEC

    seed, steps, hold = 3, 30, np.array([0, 0, 0, 0, 0, 0, -1.0])

    def seat(env):
        task, model, data = env.task, env.model, env.data
        axis = data.xmat[task.port_id].reshape(3, 3)[:, 0]
        tip = data.site_xpos[task.seated_site].copy()
        task.assembly.place(model, data, tip - task.connector.plug_length * axis, axis, 0.0)
        mujoco.mj_forward(model, data)

    single = wirecraft.make("insertion", connector="usb_a").unwrapped
    single.reset(seed=env_seed(seed, 0))
    seat(single)
    traces = {"single": []}
    plug = single.task.assembly.plug_id
    for k in range(steps):
        single.data.xfrc_applied[plug, :3] = [0.0, -12.0, 0.0] if 15 <= k < 19 else 0.0
        obs, reward, _, _, info = single.step(hold)
        traces["single"].append(np.concatenate([obs, [reward, info["latched"]]]))
    for name, options in (("synced", {}), ("training", {"sync_envs": False})):
        venv = wirecraft.make_vec(
            "insertion", 2, threads=1, connector="usb_a", diagnostics=False, **options
        )
        venv.reset(seed=seed)
        env = venv.envs[0]
        seat(env)
        if not venv.sync_envs:  # unsynced: the batch's row is the state
            mujoco.mj_getState(venv.model, env.data, venv.batch.state[0], STATE_SPEC)
            venv.batch.forward([0])
        traces[name] = []
        for k in range(steps):
            force = [0.0, -12.0, 0.0] if 15 <= k < 19 else 0.0
            if venv.sync_envs:
                env.data.xfrc_applied[plug, :3] = force
            else:
                venv.batch.xfrc_applied[0, plug, :3] = force
            obs, reward, _, _, infos = venv.step(np.tile(hold, (2, 1)))
            traces[name].append(np.concatenate([obs[0], [reward[0], infos["latched"][0]]]))
    latched = np.array(traces["single"])[:, -1]
    assert latched[:15].all() and not latched[-1]  # engaged, then freed by the pull
    for name in ("synced", "training"):
        np.testing.assert_array_equal(np.array(traces[name]), np.array(traces["single"]))
