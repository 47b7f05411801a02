"""The environments follow gymnasium's conventions, so that third-party tools work on them:
SB3's env checker and PPO on every observation mode, ``gymnasium.make_vec``, the spec's
``max_episode_steps``, FlattenObservation, RecordVideo, and a Python error (not a dead process)
for ``render_mode="human"`` without a display."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest

import wirecraft
from wirecraft.envs import OBS_MODES
from wirecraft.envs.vector import WireCraftVectorEnv

IMAGE = 48  # SB3's default image encoder (NatureCNN) takes 36 px and more
INSERTION = wirecraft.TASK_IDS["insertion"]


def _check_env(env) -> list[str]:
    """SB3's env checker (raises on a violation); returns its warnings."""
    from stable_baselines3.common.env_checker import check_env

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env, warn=True)
    return [str(w.message) for w in caught]


@pytest.mark.parametrize(
    ("task", "obs_mode"),
    [*(("insertion", mode) for mode in OBS_MODES), ("routing", "rgbd"), ("seating", "state_rgb")],
)
def test_sb3_check_env_passes_on_every_observation_mode(task, obs_mode):
    env = wirecraft.make(task, obs_mode=obs_mode, image_size=IMAGE)
    try:
        messages = _check_env(env)
    finally:
        env.close()
    # Depth images are float metres, which SB3 does not take for pictures; nothing else warns.
    assert all("depth_" in m for m in messages), messages


@pytest.mark.parametrize("obs_mode", OBS_MODES)
def test_sb3_ppo_trains_on_every_observation_mode(obs_mode):
    import torch
    from stable_baselines3 import PPO

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    env = wirecraft.make("insertion", obs_mode=obs_mode, image_size=IMAGE)
    try:
        policy = "MlpPolicy" if obs_mode == "state" else "MultiInputPolicy"
        model = PPO(policy, env, n_steps=512, batch_size=128, n_epochs=1, seed=0, device="cpu")
        model.learn(2048)
        assert model.num_timesteps >= 2048
        obs, _ = env.reset(seed=1)
        action, _ = model.predict(obs, deterministic=True)
        assert env.action_space.contains(action.astype(np.float32))
    finally:
        env.close()
        torch.set_num_threads(threads)


def test_the_instruction_is_task_description_and_info_not_observation():
    env = wirecraft.make("routing", obs_mode="state_rgb", image_size=16, num_clips=2)
    try:
        assert "instruction" not in env.observation_space.spaces
        expected = "Route the cable through all 2 clips."
        assert env.unwrapped.task_description == expected
        obs, info = env.reset(seed=0)
        assert "instruction" not in obs and info["instruction"] == expected
        *_, info = env.step(np.zeros(env.action_space.shape))
        assert info["instruction"] == expected
    finally:
        env.close()


def test_flatten_observation_gives_numbers_only():
    env = gym.wrappers.FlattenObservation(
        wirecraft.make("insertion", obs_mode="rgb", image_size=16)
    )
    try:
        obs, _ = env.reset(seed=0)
        size = 2 * 16 * 16 * 3 + 14 + 2 + 1 + 1 + 6  # two pictures, proprio, sensors, wrench
        assert obs.shape == env.observation_space.shape == (size,)
        assert np.issubdtype(obs.dtype, np.floating) and np.all(np.isfinite(obs))
        assert env.observation_space.contains(obs)
    finally:
        env.close()


@pytest.mark.parametrize("mode", [None, "vector_entry_point"])
def test_gymnasium_make_vec_builds_the_batched_vector_env(mode):
    kwargs = {} if mode is None else {"vectorization_mode": mode}
    venv = gym.make_vec(INSERTION, num_envs=2, threads=1, connector="usb_a", **kwargs)
    try:
        assert isinstance(venv, WireCraftVectorEnv)
        assert venv.num_envs == 2 and venv.envs[0].task.connector.name == "usb_a"
        assert venv.spec.id == INSERTION and venv.spec.max_episode_steps == 480
        expected = "Pick up the usb_a plug and insert it into the port."
        assert venv.task_description == (expected, expected)
        assert venv.call("task_description") == (expected, expected)
        obs, infos = venv.reset(seed=0)
        assert obs.shape == (2, 42) and list(infos["instruction"]) == [expected] * 2
        *_, infos = venv.step(np.zeros((2, 7)))
        assert list(infos["instruction"]) == [expected] * 2
    finally:
        venv.close()


def test_gymnasium_make_vec_image_modes_and_episode_length():
    venv = gym.make_vec(
        wirecraft.TASK_IDS["seating"],
        2,
        threads=1,
        obs_mode="rgb",
        image_size=16,
        max_episode_steps=2,
    )
    try:
        assert isinstance(venv, WireCraftVectorEnv) and venv.spec.max_episode_steps == 2
        assert "instruction" not in venv.observation_space.spaces
        venv.reset(seed=0)
        for step in (1, 2):
            _, _, _, truncated, infos = venv.step(np.zeros(venv.action_space.shape))
            assert truncated.tolist() == [step == 2] * 2
        assert list(infos["instruction"]) == ["Lay the cable into the straight channel."] * 2
        assert (
            list(infos["final_info"]["instruction"])
            == ["Lay the cable into the straight channel."] * 2
        )
    finally:
        venv.close()


def test_spec_max_episode_steps_is_the_episode_length():
    assert wirecraft.make("insertion").spec.max_episode_steps == 480
    assert wirecraft.make("seating", episode_seconds=0.5).spec.max_episode_steps == 30
    assert gym.make(wirecraft.TASK_IDS["routing"], num_clips=3).spec.max_episode_steps == 1440
    env = gym.make(INSERTION, max_episode_steps=-1)  # no TimeLimit: the environment's own
    assert env.spec.max_episode_steps == env.unwrapped.max_steps == 480


def test_gym_make_max_episode_steps_is_honoured():
    env = gym.make(INSERTION, max_episode_steps=1000)
    try:
        assert env.spec.max_episode_steps == env.unwrapped.max_steps == 1000
        env.reset(seed=0)
        action = np.zeros(env.action_space.shape)
        for step in range(1, 1001):
            *_, terminated, truncated, _ = env.step(action)
            assert not terminated and truncated == (step == 1000), step
    finally:
        env.close()
    short = wirecraft.make("routing", max_episode_steps=3, num_clips=2)
    short.reset(seed=0)
    assert [short.step(np.zeros(7))[3] for _ in range(3)] == [False, False, True]


def test_episode_seconds_and_max_episode_steps_must_agree():
    with pytest.raises(ValueError, match="episode_seconds=2.0 .*max_episode_steps=1000"):
        gym.make(INSERTION, episode_seconds=2.0, max_episode_steps=1000)
    with pytest.raises(ValueError, match="disagree"):
        wirecraft.make_vec("insertion", 1, episode_seconds=1.0, max_episode_steps=61)
    assert gym.make(INSERTION, episode_seconds=2.0, max_episode_steps=120).spec.max_episode_steps
    with pytest.raises(ValueError, match="max_episode_steps"):
        wirecraft.make("insertion", max_episode_steps=0)


def test_record_video_writes_an_mp4(tmp_path):
    env = wirecraft.make("insertion", render_mode="rgb_array", image_size=64, max_episode_steps=6)
    folder = tmp_path / "videos"
    env = gym.wrappers.RecordVideo(env, str(folder), episode_trigger=lambda _: True)
    try:
        env.reset(seed=0)
        truncated = False
        while not truncated:
            *_, truncated, _ = env.step(np.zeros(env.action_space.shape))
    finally:
        env.close()
    videos = list(folder.glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 0


HUMAN = """
import wirecraft
try:
    wirecraft.make("insertion", render_mode="human")
except RuntimeError as err:
    print("RuntimeError:", err)
"""


@pytest.mark.parametrize("display", [None, ":987"])
def test_human_rendering_without_a_display_raises_with_the_fix(display):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    if display is not None:  # set, but nothing listens there
        env["DISPLAY"] = display
    run = subprocess.run(
        [sys.executable, "-c", HUMAN], env=env, capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, run.stderr
    message = run.stdout
    assert message.startswith("RuntimeError:"), (message, run.stderr)
    for fix in ("DISPLAY", "xvfb-run", "render_mode='rgb_array'", "MUJOCO_GL=egl"):
        assert fix in message
