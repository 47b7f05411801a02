"""Training episodes started from the scripted expert's states (rl/expert_starts.py).

The truth: the expert's own run.  A snapshot put into another (batched, unsynced) vector env and
stepped with the action the expert took must give the expert run's next state bit for bit, so
the snapshot holds everything the step depends on."""

from __future__ import annotations

import json

import numpy as np
import pytest

import wirecraft
from wirecraft.experts import InsertionExpert
from wirecraft.rl import RUN_FILE, train
from wirecraft.rl.config import PPOConfig, VisionPPOConfig
from wirecraft.rl.expert_starts import STATES_FILE, ExpertStarts, record_expert_states

KW = {"connector": "ethernet"}
TRAINING = {"diagnostics": False, "sync_envs": False}  # as train() builds it


@pytest.fixture(scope="module")
def states():
    return record_expert_states("insertion", KW, 2, num_envs=2, seed=3, stride=40, threads=1)


def test_recorded_states_are_strided_steps_of_successful_episodes_before_success(states):
    steps = [s["steps"] for s in states]
    starts = [k for k, t in enumerate(steps) if t == 0]
    assert len(starts) == 2  # two episodes, each from its first step
    for a, b in zip(starts, starts[1:] + [len(steps)], strict=True):
        assert steps[a:b] == list(range(0, 40 * (b - a), 40))
    # the expert needs ~280 steps to seat the plug: every episode got past the grasp
    assert all(b - a >= 5 for a, b in zip(starts, starts[1:] + [len(steps)], strict=True))
    again = record_expert_states("insertion", KW, 2, num_envs=2, seed=3, stride=40, threads=1)
    assert len(again) == len(states)  # the same seed, the same states (expert choices included)
    assert all(
        np.array_equal(a["physics"], b["physics"]) for a, b in zip(again, states, strict=True)
    )
    env = wirecraft.make("insertion", **KW)
    for state in states:
        env.unwrapped.set_state(state)
        assert not env.unwrapped.task.evaluate(env.unwrapped.model, env.unwrapped.data)["success"]
    env.close()


def test_a_snapshot_steps_in_another_vector_env_as_in_the_expert_run():
    expert_run = wirecraft.make_vec("insertion", 2, threads=1, **KW)
    expert = InsertionExpert(expert_run)
    obs, _ = expert_run.reset(seed=11)
    expert.reset()
    for _ in range(150):  # into the carry
        obs, *_ = expert_run.step(expert.act(obs))
    snapshot = expert_run.envs[1].get_state()
    actions = expert.act(obs)
    after, rewards, *_ = expert_run.step(actions)
    expected = expert_run.envs[1].get_state()

    training = wirecraft.make_vec("insertion", 2, threads=1, **KW, **TRAINING)
    training.reset(seed=99)  # other episodes
    restored = training.set_states([0], [snapshot])
    np.testing.assert_array_equal(restored[0], obs[1])
    moved, moved_rewards, *_ = training.step(np.stack([actions[1], np.zeros(7)]))
    np.testing.assert_array_equal(training.batch.state[0], expected["physics"])
    np.testing.assert_array_equal(moved[0], after[1])
    assert moved_rewards[0] == rewards[1]
    assert training.steps[0] == expected["steps"] == 151
    with pytest.raises(ValueError, match="2 ids for 1 states"):
        training.set_states([0, 1], [snapshot])
    with pytest.raises(ValueError, match="no environment 5"):
        training.set_states([5], [snapshot])
    expert_run.close()
    training.close()


def test_expert_starts_replace_the_chosen_fraction_of_resets(states):
    plain = wirecraft.make_vec("insertion", 3, threads=1, **KW, **TRAINING)
    never = ExpertStarts(
        wirecraft.make_vec("insertion", 3, threads=1, **KW, **TRAINING), states, 0.0, 0
    )
    a, _ = plain.reset(seed=4)
    b, info = never.reset(seed=4)
    np.testing.assert_array_equal(a, b)
    assert not info["expert_start"].any()
    rng = np.random.default_rng(0)
    for _ in range(3):
        actions = rng.uniform(-1, 1, (3, 7))
        np.testing.assert_array_equal(plain.step(actions)[0], never.step(actions)[0])

    always = ExpertStarts(
        wirecraft.make_vec("insertion", 3, threads=1, **KW, **TRAINING), states, 1.0, 0
    )
    obs, info = always.reset(seed=4)
    assert info["expert_start"].all()
    recorded = {s["steps"] for s in states}
    assert set(always.unwrapped.steps) <= recorded
    for i, env in enumerate(always.unwrapped.envs):
        match = [s for s in states if np.array_equal(s["physics"], env.get_state()["physics"])]
        assert match, f"environment {i} is not in a recorded state"
    with pytest.raises(ValueError, match="fraction"):
        ExpertStarts(plain, states, 1.5, 0)
    with pytest.raises(ValueError, match="no states"):
        ExpertStarts(plain, [], 0.5, 0)
    with pytest.raises(ValueError, match="expert_starts"):
        PPOConfig(expert_starts=-0.1)
    for venv in (plain, never, always):
        venv.close()


def test_the_training_log_counts_fresh_episodes_apart(states):
    import torch

    from wirecraft.rl.ppo import make_vec_env_adapter

    # 6-step episodes; an expert state (step count >= 40, or 0) ends after 1-6 steps
    venv = wirecraft.make_vec("insertion", 4, threads=1, episode_seconds=0.1, **KW, **TRAINING)
    adapter = make_vec_env_adapter(ExpertStarts(venv, states, 0.5, 2), reward_scale=1.0, seed=0)
    fresh = started = 0
    for _ in range(12):
        _, _, dones, extras = adapter.step(torch.zeros(4, 7))
        if "log" not in extras:
            continue
        log = extras["log"]
        from_expert = log["Episode/expert_start"]
        assert len(from_expert) == int(dones.sum())
        started += int(from_expert.sum())
        count = int((from_expert == 0).sum())
        fresh += count
        if count:
            assert len(log["Episode/fresh/insert_success_any"]) == count
        else:
            assert "Episode/fresh/insert_success_any" not in log
    assert fresh and started
    venv.close()


def test_runs_that_need_the_expert_refuse_another_control_before_writing(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(ValueError, match="needs control='cartesian'; got control='joint'"):
        train("ppo", "insertion", {**KW, "control": "joint"}, out, overrides={"expert_starts": 0.5})
    # seating's default control is cartesian_fixed; its expert drives cartesian
    with pytest.raises(ValueError, match="got control='cartesian_fixed'"):
        train("sacfd", "seating", {}, out)
    with pytest.raises(ValueError, match="got control='joint'"):
        train("ppo", "insertion", {"control": "joint"}, out, overrides={"bc_init_transitions": 9})
    assert not out.exists()
    for name in ("expert_starts", "bc_init_transitions"):
        with pytest.raises(ValueError, match=f"{name} is for state PPO"):
            VisionPPOConfig(**{name: 1})


@pytest.mark.slow
def test_ppo_with_expert_starts_and_cloning_records_once_and_resumes_from_the_same_states(
    tmp_path, monkeypatch
):
    import torch

    from wirecraft.rl import expert_starts

    tiny = {
        "num_envs": 2,
        "num_steps_per_env": 8,
        "actor_hidden_dims": (8,),
        "critic_hidden_dims": (8,),
        "num_mini_batches": 2,
        "num_learning_epochs": 1,
        "threads": 1,
        "expert_starts": 1.0,
        "expert_start_episodes": 1,
        "expert_start_stride": 100,
        "bc_init_transitions": 480,  # one expert episode
        "bc_init_epochs": 1,
    }
    run_dir = tmp_path / "ppo"
    train("ppo", "insertion", KW, run_dir, 16, overrides=tiny, progress=False)
    bc_init = json.loads((run_dir / RUN_FILE).read_text())["bc_init"]
    assert (
        bc_init["transitions"] == 480 and np.isfinite(list(bc_init["final_losses"].values())).all()
    )
    saved = torch.load(run_dir / STATES_FILE, weights_only=False)
    assert [s["steps"] for s in saved] == [0, 100, 200]  # the expert seats the plug at ~280

    def no_recording(*args, **kwargs):
        raise AssertionError("a resumed run records the expert again")

    monkeypatch.setattr(expert_starts, "record_expert_states", no_recording)
    summary = train("ppo", "insertion", None, run_dir, 32, resume=True, progress=False)
    assert summary["env_steps"] == 32
    with pytest.raises(ValueError, match="needs control='cartesian'"):
        record_expert_states(
            "insertion", {**KW, "control": "joint"}, 1, num_envs=1, seed=0, stride=1
        )
