"""Every bad input to the Python API is a clear error naming the field, raised before the model is
built where possible: wirecraft.make, gymnasium.make, wirecraft.make_vec, reset and step."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import wirecraft

NAN, INF = float("nan"), float("inf")

# (task, keyword arguments, the field the message names)
ENV_OPTIONS = [
    ("insertion", {"robot": "nope"}, "robot"),
    ("insertion", {"robot": 1}, "robot"),
    ("insertion", {"robot": None}, "robot"),
    ("insertion", {"wire": "nope"}, "wire"),
    ("insertion", {"wire": ["rod"]}, "wire"),
    ("insertion", {"control": ""}, "control"),
    ("insertion", {"control": "nope"}, "control"),
    ("insertion", {"control": 1}, "control"),
    ("insertion", {"obs_mode": "nope"}, "obs_mode"),
    ("insertion", {"obs_mode": None}, "obs_mode"),
    ("insertion", {"render_mode": "nope"}, "render_mode"),
    ("insertion", {"render_mode": 1}, "render_mode"),
    ("insertion", {"image_size": 961}, "image_size"),
    ("insertion", {"image_size": 2000}, "image_size"),
    ("insertion", {"image_size": 15}, "image_size"),
    ("insertion", {"image_size": 0}, "image_size"),
    ("insertion", {"image_size": -64}, "image_size"),
    ("insertion", {"image_size": 64.0}, "image_size"),
    ("insertion", {"image_size": "64"}, "image_size"),
    ("insertion", {"image_size": True}, "image_size"),
    ("insertion", {"image_size": None}, "image_size"),
    ("insertion", {"episode_seconds": 0}, "episode_seconds"),
    ("insertion", {"episode_seconds": -1.0}, "episode_seconds"),
    ("insertion", {"episode_seconds": 1e-6}, "episode_seconds"),
    ("insertion", {"episode_seconds": 1 / 200}, "episode_seconds"),
    ("insertion", {"episode_seconds": NAN}, "episode_seconds"),
    ("insertion", {"episode_seconds": INF}, "episode_seconds"),
    ("insertion", {"episode_seconds": "8"}, "episode_seconds"),
    ("insertion", {"episode_seconds": True}, "episode_seconds"),
    ("insertion", {"episode_seconds": [8.0]}, "episode_seconds"),
    ("insertion", {"diagnostics": "false"}, "diagnostics"),
    ("insertion", {"diagnostics": 0}, "diagnostics"),
    ("insertion", {"diagnostics": None}, "diagnostics"),
    ("insertion", {"wire_config": {"model": "rod"}}, "wire_config"),
    ("insertion", {"wire_config": "rod"}, "wire_config"),
    ("insertion", {"not_an_option": 1}, "not_an_option"),
    ("routing", {"not_an_option": 1}, "not_an_option"),
    ("seating", {"not_an_option": 1}, "not_an_option"),
]

WEIGHTS = [
    (task, {"weights": weights}, field)
    for task, term in (("insertion", "reach"), ("routing", "routed"), ("seating", "seated"))
    for weights, field in (
        ([1, 2], "weights"),
        ("reach", "weights"),
        (1.0, "weights"),
        ({"nope": 1.0}, "weights"),
        ({term: NAN}, term),
        ({term: INF}, term),
        ({term: -INF}, term),
        ({term: "1"}, term),
        ({term: True}, term),
        ({term: None}, term),
        ({term: [1.0]}, term),
    )
]

TASK_OPTIONS = [
    ("insertion", {"connector": "nope"}, "connector"),
    ("insertion", {"connector": 1}, "connector"),
    ("insertion", {"connector": None}, "connector"),
    ("insertion", {"clearance": "0.003"}, "clearance"),
    ("insertion", {"clearance": True}, "clearance"),
    ("insertion", {"clearance": None}, "clearance"),
    ("insertion", {"clearance": [0.003]}, "clearance"),
    ("insertion", {"clearance": NAN}, "clearance"),
    ("insertion", {"clearance": INF}, "clearance"),
    ("insertion", {"clearance": -0.001}, "clearance"),
    ("insertion", {"clearance": 1.0}, "clearance"),
    ("routing", {"num_clips": 0}, "num_clips"),
    ("routing", {"num_clips": 4}, "num_clips"),
    ("routing", {"num_clips": -1}, "num_clips"),
    ("routing", {"num_clips": 2.0}, "num_clips"),
    ("routing", {"num_clips": True}, "num_clips"),
    ("routing", {"num_clips": "2"}, "num_clips"),
    ("routing", {"num_clips": None}, "num_clips"),
    ("routing", {"clip_opening": 0.0}, "clip_opening"),
    ("routing", {"clip_opening": -0.001}, "clip_opening"),
    ("routing", {"clip_opening": NAN}, "clip_opening"),
    ("routing", {"clip_opening": INF}, "clip_opening"),
    ("routing", {"clip_opening": "0.005"}, "clip_opening"),
    ("routing", {"clip_opening": True}, "clip_opening"),
    ("routing", {"clip_opening": 1.0}, "clip_opening"),
    ("routing", {"connector": "nope"}, "connector"),
    ("seating", {"channel": "nope"}, "channel"),
    ("seating", {"channel": 1}, "channel"),
    ("seating", {"channel": None}, "channel"),
    ("seating", {"connector": "nope"}, "connector"),
]

TASKS = [1, None, ["insertion"], "nope", "WireCraft/Nope-v0"]


def case_id(case):
    task, kwargs, _ = case
    return f"{task}-{kwargs!r}"


@pytest.mark.parametrize("case", ENV_OPTIONS + WEIGHTS + TASK_OPTIONS, ids=case_id)
def test_make_rejects(case):
    task, kwargs, field = case
    with pytest.raises(ValueError, match=field):
        wirecraft.make(task, **kwargs)


@pytest.mark.parametrize("task", TASKS, ids=repr)
def test_make_rejects_task(task):
    with pytest.raises(ValueError, match="task"):
        wirecraft.make(task)


GYM_CASES = [
    ("insertion", {"image_size": 2000}, "image_size"),
    ("insertion", {"episode_seconds": 1e-6}, "episode_seconds"),
    ("insertion", {"clearance": "0.003"}, "clearance"),
    ("insertion", {"weights": {"reach": NAN}}, "reach"),
    ("insertion", {"weights": [1, 2]}, "weights"),
    ("insertion", {"diagnostics": "no"}, "diagnostics"),
    ("routing", {"num_clips": 2.0}, "num_clips"),
    ("routing", {"num_clips": True}, "num_clips"),
    ("routing", {"clip_opening": 1.0}, "clip_opening"),
    ("seating", {"channel": "round"}, "channel"),
    ("seating", {"not_an_option": 1}, "not_an_option"),
]


@pytest.mark.parametrize("case", GYM_CASES, ids=case_id)
def test_gym_make_rejects(case):
    task, kwargs, field = case
    with pytest.raises(ValueError, match=field):
        gym.make(wirecraft.TASK_IDS[task], **kwargs)


VEC_CASES = [
    ("nope", 2, {}, "task"),
    (1, 2, {}, "task"),
    ("insertion", 0, {}, "num_envs"),
    ("insertion", -1, {}, "num_envs"),
    ("insertion", 10**7, {}, "num_envs"),
    ("insertion", 65537, {}, "num_envs"),
    ("insertion", 2.0, {}, "num_envs"),
    ("insertion", True, {}, "num_envs"),
    ("insertion", "2", {}, "num_envs"),
    ("insertion", None, {}, "num_envs"),
    ("insertion", 2, {"threads": -1}, "threads"),
    ("insertion", 2, {"threads": 10**6}, "threads"),
    ("insertion", 2, {"threads": 1.5}, "threads"),
    ("insertion", 2, {"threads": True}, "threads"),
    ("insertion", 2, {"threads": "1"}, "threads"),
    ("insertion", 2, {"threads": None}, "threads"),
    ("insertion", 2, {"backend": "gpu"}, "backend"),
    ("insertion", 2, {"backend": None}, "backend"),
    ("insertion", 2, {"arrays": "jax"}, "arrays"),
    ("insertion", 2, {"arrays": None}, "arrays"),
    ("insertion", 2, {"device": "cpu"}, "device"),
    ("insertion", 2, {"sync_envs": "false"}, "sync_envs"),
    ("insertion", 2, {"sync_envs": 1}, "sync_envs"),
    ("insertion", 2, {"sync_envs": False, "obs_mode": "rgb"}, "sync_envs"),
    ("insertion", 2, {"render_mode": "human"}, "render_mode"),
    ("insertion", 2, {"image_size": 2000}, "image_size"),
    ("insertion", 2, {"weights": {"reach": INF}}, "reach"),
    ("routing", 2, {"num_clips": 2.0}, "num_clips"),
    ("routing", 2, {"clip_opening": "wide"}, "clip_opening"),
    ("seating", 2, {"channel": None}, "channel"),
]


@pytest.mark.parametrize("case", VEC_CASES, ids=lambda c: f"{c[0]}-{c[1]!r}-{c[2]!r}")
def test_make_vec_rejects(case):
    task, num_envs, kwargs, field = case
    with pytest.raises(ValueError, match=field):
        wirecraft.make_vec(task, num_envs, **kwargs)


def test_make_vec_checks_memory_before_allocating(monkeypatch):
    from wirecraft.envs import vector

    monkeypatch.setattr(vector, "physical_memory", lambda: 2**30)
    with pytest.raises(MemoryError, match="num_envs=4096 needs about .* GiB"):
        wirecraft.make_vec("insertion", 4096, threads=1)


# -- reset and step -------------------------------------------------------------------------
SEEDS = [1.5, np.float64(1.0), -1, True, "1", [1], {"seed": 1}]
OPTIONS = [
    ([1], "options"),
    ("x", "options"),
    ({"foo": 1}, "foo"),
    ({"reset_mask": 1}, "reset_mask"),
]


@pytest.fixture(scope="module")
def env():
    env = wirecraft.make("insertion", episode_seconds=2 / 60)
    yield env
    env.close()


@pytest.mark.parametrize("seed", SEEDS, ids=repr)
def test_reset_rejects_seed(env, seed):
    with pytest.raises(ValueError, match="seed"):
        env.reset(seed=seed)


@pytest.mark.parametrize(("options", "field"), OPTIONS, ids=repr)
def test_reset_rejects_options(env, options, field):
    with pytest.raises(ValueError, match=field):
        env.reset(options=options)


ACTIONS = [
    (np.zeros(3), "shape"),
    (np.zeros((1, 7)), "shape"),
    (np.full(7, np.nan), "NaN"),
    (np.full(7, np.inf), "NaN or inf"),
    (["a"] * 7, "action"),
    (None, "shape"),
]


@pytest.mark.parametrize(("action", "match"), ACTIONS, ids=repr)
def test_step_rejects_action(env, action, match):
    env.reset(seed=0)
    if isinstance(action, np.ndarray) and action.shape == (7,):
        action = np.resize(action, env.action_space.shape)
    with pytest.raises(ValueError, match=match):
        env.step(action)


def test_step_before_reset_is_refused():
    raw = wirecraft.make("insertion").unwrapped
    with pytest.raises(gym.error.ResetNeeded, match="reset"):
        raw.step(np.zeros(raw.action_space.shape))
    wrapped = wirecraft.make("insertion")
    with pytest.raises(gym.error.ResetNeeded, match="reset"):
        wrapped.step(np.zeros(wrapped.action_space.shape))


def test_step_after_the_episode_ended_needs_a_reset(env):
    action = np.zeros(env.action_space.shape)
    env.reset(seed=0)
    assert not env.step(action)[3]
    assert env.step(action)[3]
    with pytest.raises(gym.error.ResetNeeded, match="reset"):
        env.step(action)
    env.reset(seed=0)
    assert not env.step(action)[3]


def test_a_closed_environment_refuses_step_and_reset():
    env = wirecraft.make("insertion")
    env.reset(seed=0)
    env.close()
    with pytest.raises(gym.error.ClosedEnvironmentError, match="closed"):
        env.step(np.zeros(env.action_space.shape))
    with pytest.raises(gym.error.ClosedEnvironmentError, match="closed"):
        env.reset(seed=0)


@pytest.fixture(scope="module")
def venv():
    venv = wirecraft.make_vec("insertion", 2, threads=1, episode_seconds=2 / 60)
    yield venv
    venv.close()


VEC_SEEDS = [*SEEDS[:-2], [0], [0, 1, 2], [0, 1.5], [0, -1], [0, True]]
VEC_OPTIONS = [
    *OPTIONS,
    ({"reset_mask": [1, 0]}, "reset_mask"),
    ({"reset_mask": [True]}, "reset_mask"),
    ({"reset_mask": "ab"}, "reset_mask"),
    ({"reset_mask": np.ones((2, 1), bool)}, "reset_mask"),
]


@pytest.mark.parametrize("seed", VEC_SEEDS, ids=repr)
def test_vector_reset_rejects_seed(venv, seed):
    with pytest.raises(ValueError, match="seed"):
        venv.reset(seed=seed)


@pytest.mark.parametrize(("options", "field"), VEC_OPTIONS, ids=repr)
def test_vector_reset_rejects_options(venv, options, field):
    with pytest.raises(ValueError, match=field):
        venv.reset(options=options)


@pytest.mark.parametrize(("action", "match"), ACTIONS, ids=repr)
def test_vector_step_rejects_actions(venv, action, match):
    venv.reset(seed=0)
    if isinstance(action, np.ndarray) and action.shape == (7,):
        action = np.resize(action, venv.action_space.shape)
    with pytest.raises(ValueError, match=match.replace("action", "actions")):
        venv.step(action)


def test_vector_step_before_reset_is_refused():
    venv = wirecraft.make_vec("insertion", 2, threads=1)
    actions = np.zeros(venv.action_space.shape)
    with pytest.raises(gym.error.ResetNeeded, match="reset"):
        venv.step(actions)
    venv.reset(seed=0, options={"reset_mask": np.array([True, False])})
    with pytest.raises(gym.error.ResetNeeded, match=r"\[1\]"):
        venv.step(actions)
    venv.reset(seed=0)
    venv.step(actions)
    venv.close()
    with pytest.raises(gym.error.ClosedEnvironmentError, match="closed"):
        venv.step(actions)
    with pytest.raises(gym.error.ClosedEnvironmentError, match="closed"):
        venv.reset(seed=0)


def test_the_vector_env_steps_on_past_episode_ends_by_autoreset(venv):
    venv.reset(seed=0)
    actions = np.zeros(venv.action_space.shape)
    truncations = [venv.step(actions)[3].all() for _ in range(5)]
    assert truncations == [False, True, False, True, False]
