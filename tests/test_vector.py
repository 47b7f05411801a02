"""The batched vector environment against the single environment, its own independent truth."""

from __future__ import annotations

import numpy as np
import pytest

import wirecraft
from wirecraft.envs import env_seed

SEED = 7


def actions_for(venv, steps, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-1, 1, (steps, *venv.action_space.shape))


def run(venv, actions):
    obs, _ = venv.reset(seed=SEED)
    trace = [obs.copy()]
    for a in actions:
        obs, reward, *_ = venv.step(a)
        trace.append(np.concatenate([obs.ravel(), reward]))
    return trace


@pytest.mark.parametrize("task", ["insertion", "routing", "seating"])
def test_environment_zero_is_the_same_whatever_num_envs_and_threads(task):
    steps = 25
    base = actions_for(wirecraft.make_vec(task, 8, threads=2), steps)
    traces = {}
    for num_envs, threads in ((1, 1), (8, 1), (8, 2)):
        venv = wirecraft.make_vec(task, num_envs, threads=threads)
        obs, _ = venv.reset(seed=SEED)
        first = [obs[0].copy()]
        for a in base:
            obs, reward, *_ = venv.step(a[:num_envs])
            first.append(np.append(obs[0], reward[0]))
        traces[(num_envs, threads)] = np.concatenate(first)
    reference = traces[(1, 1)]
    for key, trace in traces.items():
        np.testing.assert_array_equal(trace, reference, err_msg=str(key))
    # ... and it is the single environment with the derived seed, stepped by mj_step.
    env = wirecraft.make(task)
    obs, _ = env.reset(seed=env_seed(SEED, 0))
    single = [obs]
    for a in base:
        obs, reward, *_ = env.step(a[0])
        single.append(np.append(obs, reward))
    np.testing.assert_array_equal(np.concatenate(single), reference)


@pytest.mark.parametrize("task", ["insertion", "routing", "seating"])
@pytest.mark.parametrize("sync_envs", [True, False])
def test_a_diverging_environment_leaves_the_others_untouched(task, sync_envs):
    steps, victim = 6, 2
    actions = actions_for(wirecraft.make_vec(task, 4, threads=2), steps)

    def trajectories(inject):
        venv = wirecraft.make_vec(task, 4, threads=2, sync_envs=sync_envs)
        obs, _ = venv.reset(seed=SEED)
        out, flags = [obs.copy()], []
        for k, a in enumerate(actions):
            if inject and k == 3:
                env = venv.envs[victim]
                dof = env.task.assembly.plug_dof
                # Unsynced, the batched step's states live in the batch's rows only; otherwise
                # a write into an environment's MjData is its state.
                qvel = env.data.qvel if sync_envs else venv.batch.qvel[victim]
                qvel[dof : dof + 6] = 1e6
            obs, reward, terminated, truncated, infos = venv.step(a)
            out.append(obs.copy())
            flags.append((truncated.copy(), infos["diverged"].copy()))
        return np.stack(out), flags

    clean, _ = trajectories(False)
    hit, flags = trajectories(True)
    others = [i for i in range(4) if i != victim]
    np.testing.assert_array_equal(hit[:, others], clean[:, others])
    truncated, diverged = flags[3]
    assert diverged[victim] and truncated[victim]
    assert not diverged[others].any() and not truncated[others].any()
    assert np.all(np.isfinite(hit))


@pytest.mark.parametrize("task", ["insertion", "routing", "seating"])
def test_same_step_autoreset_reports_final_obs_and_starts_a_new_episode(task):
    venv = wirecraft.make_vec(task, 2, threads=1, episode_seconds=5 / 60)
    env = wirecraft.make(task, episode_seconds=5 / 60)
    actions = actions_for(venv, 5)
    venv.reset(seed=SEED)
    obs, _ = env.reset(seed=env_seed(SEED, 1))
    for k, a in enumerate(actions):
        vobs, _, _, vtrunc, infos = venv.step(a)
        obs, _, _, trunc, info = env.step(a[1])
        if k < 4:
            assert not vtrunc.any() and "final_obs" not in infos
            np.testing.assert_array_equal(vobs[1], obs)
    assert trunc and vtrunc.all()
    assert infos["_final_obs"].all()
    np.testing.assert_array_equal(infos["final_obs"][1], obs)
    assert infos["final_info"]["success"][1] == info["success"]
    # The returned observation is the next episode's first, from the same seeded stream.
    fresh, _ = env.reset()
    np.testing.assert_array_equal(vobs[1], fresh)


def test_a_settle_that_diverges_is_retried_as_a_single_environment_retries_it(monkeypatch):
    # The vector environment settles new episodes together in the batch; one that diverges
    # while settling starts again from its generator's next draw, as a single one does.
    import mujoco

    from wirecraft.envs.env import MAX_LINEAR_SPEED, WireCraftEnv

    start = WireCraftEnv.start_episode
    sick = {"episodes": 0}

    def target_starts_flying(self):
        start(self)
        if getattr(self, "target", False) and sick["episodes"] > 0:
            sick["episodes"] -= 1
            free = list(self.model.jnt_type).index(mujoco.mjtJoint.mjJNT_FREE)
            adr = self.model.jnt_dofadr[free]
            self.data.qvel[adr : adr + 3] = (0.0, 0.0, 3 * MAX_LINEAR_SPEED)

    monkeypatch.setattr(WireCraftEnv, "start_episode", target_starts_flying)
    venv = wirecraft.make_vec("insertion", 3, threads=2)
    venv.envs[1].target = True
    sick["episodes"] = 1
    obs, infos = venv.reset(seed=SEED)
    assert infos["reset_attempts"].tolist() == [1, 2, 1]
    env = wirecraft.make("insertion").unwrapped
    env.target = True
    sick["episodes"] = 1
    single, info = env.reset(seed=env_seed(SEED, 1))
    assert info["reset_attempts"] == 2
    np.testing.assert_array_equal(obs[1], single)
    # Three diverged settles in a row are an error, as for a single environment.
    sick["episodes"] = 10
    with pytest.raises(RuntimeError, match="diverged while settling"):
        venv.reset(seed=SEED)


def test_partial_reset_touches_only_the_masked_environments():
    venv = wirecraft.make_vec("insertion", 3, threads=1)
    obs, _ = venv.reset(seed=SEED)
    obs, *_ = venv.step(actions_for(venv, 1)[0])
    again, infos = venv.reset(seed=SEED, options={"reset_mask": np.array([False, True, False])})
    first, _ = wirecraft.make_vec("insertion", 3, threads=1).reset(seed=SEED)
    np.testing.assert_array_equal(again[1], first[1])
    np.testing.assert_array_equal(again[[0, 2]], obs[[0, 2]])
    assert infos["_success"].tolist() == [False, True, False]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"num_envs": 0}, "num_envs"),
        ({"threads": -1}, "threads"),
        ({"backend": "gpu"}, "backend"),
        ({"num_envs": 2.5}, "num_envs"),
        ({"arrays": "jax"}, "unknown arrays"),
        ({"sync_envs": "false"}, "sync_envs must be True or False"),
        ({"sync_envs": False, "obs_mode": "rgb", "image_size": 32}, "sync_envs=False needs"),
        ({"diagnostics": "no"}, "diagnostics must be True or False"),
    ],
)
def test_bad_arguments(kwargs, match):
    args = {"num_envs": 2, **kwargs}
    with pytest.raises(ValueError, match=match):
        wirecraft.make_vec("insertion", **args)


def test_nan_action_in_one_environment_is_refused_before_anything_moves():
    venv = wirecraft.make_vec("insertion", 3, threads=1)
    venv.reset(seed=SEED)
    time_before = [env.data.time for env in venv.envs]
    actions = np.zeros(venv.action_space.shape)
    actions[1, 0] = np.nan
    with pytest.raises(ValueError, match=r"\[1\]"):
        venv.step(actions)
    assert [env.data.time for env in venv.envs] == time_before


def test_image_observations_batch():
    """One shared renderer draws every row, and each row is what a single environment with
    that row's seed renders, after reset and after steps."""
    venv = wirecraft.make_vec("seating", 2, threads=1, obs_mode="rgb", image_size=32)
    obs, _ = venv.reset(seed=SEED)
    assert obs["rgb_side"].shape == (2, 32, 32, 3)
    assert venv.observation_space.contains(obs)
    single = wirecraft.make("seating", obs_mode="rgb", image_size=32)
    single_obs, _ = single.reset(seed=env_seed(SEED, 1))
    actions = actions_for(venv, 3)
    for a in actions:
        for key in ("rgb_side", "rgb_wrist", "proprio"):
            np.testing.assert_array_equal(obs[key][1], single_obs[key], err_msg=key)
        obs, *_ = venv.step(a)
        single_obs, *_ = single.step(a[1])
    assert obs["rgb_wrist"][1].any()  # something was drawn
    venv.close()
    single.close()


def test_torch_arrays_match_numpy_and_share_memory():
    torch = pytest.importorskip("torch")
    plain = wirecraft.make_vec("insertion", 2, threads=1)
    tensors = wirecraft.make_vec("insertion", 2, threads=1, arrays="torch")
    actions = actions_for(plain, 3)
    obs_np, _ = plain.reset(seed=5)
    obs_t, _ = tensors.reset(seed=5)
    assert isinstance(obs_t, torch.Tensor)
    np.testing.assert_array_equal(obs_t.numpy(), obs_np)
    for a in actions:
        obs_np, rew_np, term_np, trunc_np, _ = plain.step(a)
        obs_t, rew_t, term_t, trunc_t, info_t = tensors.step(torch.from_numpy(a))
        np.testing.assert_array_equal(obs_t.numpy(), obs_np)
        np.testing.assert_array_equal(rew_t.numpy(), rew_np)
        assert term_t.dtype == torch.bool and trunc_t.dtype == torch.bool
        assert isinstance(info_t["success"], np.ndarray)
    # On the CPU the tensor is a view of the array the environment returned, not a copy.
    raw = tensors.env._obs_copy()
    assert np.shares_memory(tensors._tensor(raw).numpy(), raw)
    plain.close()
    tensors.close()


def test_an_environment_reset_mid_run_continues_exactly_like_a_fresh_single_environment():
    # The batch keeps each simulation's MjData between calls (persistent): a reset written into
    # the state rows must not be stepped from stale derived quantities.
    rng = np.random.default_rng(1)
    venv = wirecraft.make_vec("insertion", 2, threads=1)
    venv.reset(seed=3)
    actions = rng.uniform(-1, 1, (12, *venv.action_space.shape))
    for a in actions[:4]:
        venv.step(a)
    obs, _ = venv.reset(seed=[None, 77], options={"reset_mask": [False, True]})
    batched = [obs[1].copy()]
    for a in actions[4:]:
        obs, *_ = venv.step(a)
        batched.append(obs[1].copy())
    env = wirecraft.make("insertion")
    obs, _ = env.reset(seed=77)
    single = [obs]
    for a in actions[4:]:
        obs, *_ = env.step(a[1])
        single.append(obs)
    np.testing.assert_array_equal(np.array(batched), np.array(single))


def test_batched_infos_match_gymnasiums_own_per_environment_merge():
    from gymnasium.vector import VectorEnv

    def per_environment(venv):
        def merge(infos, step_infos):
            for i, info in enumerate(step_infos):
                infos = VectorEnv._add_info(venv, infos, info, i)
            return infos

        venv._merge_infos = merge
        return venv

    fast = wirecraft.make_vec("insertion", 3, threads=1)
    slow = per_environment(wirecraft.make_vec("insertion", 3, threads=1))
    for venv in (fast, slow):
        venv.reset(seed=0)
    action = np.zeros(fast.action_space.shape)
    for _ in range(2):
        *_, info_fast = fast.step(action)
        *_, info_slow = slow.step(action)
        assert info_fast.keys() == info_slow.keys()
        for key in info_fast:
            assert info_fast[key].dtype == info_slow[key].dtype, key
            np.testing.assert_array_equal(info_fast[key], info_slow[key])
