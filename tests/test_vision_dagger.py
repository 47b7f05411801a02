"""Vision PPO's DAgger stage: the clone drives, a state-policy teacher labels every state."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import wirecraft
from wirecraft.envs.vector import env_seed
from wirecraft.rl import load_policy
from wirecraft.rl.config import VisionPPOConfig
from wirecraft.rl.vision import CAMERAS, dagger_wave

TEACHER = str(Path(__file__).parents[1] / "checkpoints" / "ppo_insertion_ethernet_seed1")
ENV = {"connector": "ethernet", "episode_seconds": 0.1, "obs_mode": "state_rgb", "image_size": 24}


def _wave(student, beta, seed=5, num_envs=2):
    return dagger_wave(
        "insertion",
        ENV,
        TEACHER,
        student,
        beta,
        num_envs=num_envs,
        seed=seed,
        threads=1,
        progress=False,
    )


def test_a_clone_driven_wave_holds_the_clone_states_with_the_teacher_labels():
    """beta 0: every environment runs the clone's actions; each stored observation must be the
    one an independent single environment reaches under those actions, labelled with the
    teacher's action on its state."""
    rng = np.random.default_rng(0)
    drift = rng.uniform(-0.6, 0.6, size=7)

    def student(obs):
        return np.tile(drift, (len(obs["proprio"]), 1))

    data, rates = _wave(student, beta=0.0)
    teacher = load_policy(TEACHER)
    num_envs = 2
    steps = len(data["actions"]) // num_envs
    assert steps == 6 and len(data["actions"]) == steps * num_envs
    for i in range(num_envs):
        env = wirecraft.make("insertion", **ENV)
        obs, _ = env.reset(seed=env_seed(5, i))
        for t in range(steps):
            row = t * num_envs + i
            for key in CAMERAS:
                np.testing.assert_array_equal(data[key][row].numpy(), obs[key])
            np.testing.assert_allclose(data["proprio"][row].numpy(), obs["proprio"], atol=1e-6)
            label = teacher.act(obs["state"][None])[0]
            np.testing.assert_allclose(data["actions"][row].numpy(), label, atol=1e-6)
            obs, *_ = env.step(drift)
        env.close()
    assert set(rates) == {"success", "reach", "insert"}


def test_a_teacher_driven_wave_never_asks_the_clone():
    def student(obs):
        raise AssertionError("beta 1: the clone must not act")

    data, _ = _wave(student, beta=1.0)
    assert len(data["actions"]) == 12


def test_dagger_waves_need_a_teacher_that_labels_any_state():
    with pytest.raises(ValueError, match="teacher"):
        VisionPPOConfig(bc_dagger_waves=2)
    with pytest.raises(ValueError, match="bc_dagger_waves"):
        VisionPPOConfig(bc_dagger_waves=-1, teacher=TEACHER)
    with pytest.raises(ValueError, match="bc_dagger_envs"):
        VisionPPOConfig(bc_dagger_waves=1, bc_dagger_envs=0, teacher=TEACHER)
    assert VisionPPOConfig(bc_dagger_waves=2, teacher=TEACHER).bc_dagger_waves == 2


def test_a_wave_on_a_task_without_reach_and_insert_flags(tmp_path):
    """Routing has only ``success``: the wave reports the flags the task raises."""
    from wirecraft.rl import train

    teacher = tmp_path / "routing_ppo"
    tiny = {"num_envs": 2, "num_steps_per_env": 4, "actor_hidden_dims": (8,), "threads": 1}
    train("ppo", "routing", {"episode_seconds": 0.1}, teacher, 8, overrides=tiny, progress=False)
    env = {"episode_seconds": 0.1, "obs_mode": "state_rgb", "image_size": 24}
    data, rates = dagger_wave(
        "routing",
        env,
        str(teacher),
        lambda obs: np.zeros((len(obs["proprio"]), 7)),
        0.5,
        num_envs=2,
        seed=3,
        threads=1,
        progress=False,
    )
    assert set(rates) == {"success"} and 0.0 <= rates["success"] <= 1.0
    assert len(data["actions"]) == 12
