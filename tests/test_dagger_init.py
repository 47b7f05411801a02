"""State PPO's goal-relative actor inputs and DAgger warm start (rl/features.py, rl/dagger.py):
the features against MuJoCo's own frames, returns against their closed form, a wave executing
the actor's actions (not the labels), a real warm start whose expert wave seats the plug and
whose saved actor is the loaded policy, and bad settings refused before anything is written."""

from __future__ import annotations

import json

import numpy as np
import pytest

import wirecraft
from wirecraft.experts.reactive import FINE_SCALES, ReactiveInsertionExpert
from wirecraft.rl import RUN_FILE, load_policy, train
from wirecraft.rl.config import PPOConfig, VisionPPOConfig
from wirecraft.rl.dagger import actor_means, discounted_returns, run_wave
from wirecraft.rl.features import actor_input_dim, actor_transform

relative_features = ReactiveInsertionExpert.relative_features


# A warm start small enough for a test: 2 environments, tiny networks, one DAgger wave.
TINY_WARM_START = {
    "num_envs": 2,
    "num_steps_per_env": 8,
    "actor_hidden_dims": (32, 16),
    "critic_hidden_dims": (16,),
    "num_mini_batches": 2,
    "num_learning_epochs": 1,
    "threads": 1,
    "actor_inputs": "relative",
    "dagger_init_iterations": 1,
    "dagger_init_epochs": 2,
}


def _world(env):
    """(TCP position, TCP rotation, plug position, plug rotation, tip) in the world."""
    env = env.unwrapped
    data, task = env.data, env.task
    tcp = env.controller.index.tcp_site
    plug = task.assembly.plug_id
    return (
        data.site_xpos[tcp].copy(),
        data.site_xmat[tcp].reshape(3, 3).copy(),
        data.xpos[plug].copy(),
        data.xmat[plug].reshape(3, 3).copy(),
        data.site_xpos[task.assembly.tip_site].copy(),
    )


@pytest.mark.parametrize("robot", ["ur5", "panda"])
def test_relative_features_are_the_plug_and_tip_seen_from_the_tcp(robot):
    env = wirecraft.make("insertion", robot=robot, control="cartesian")
    obs, _ = env.reset(seed=3)
    for _ in range(20):  # off the home pose, turned a little
        obs, *_ = env.step(np.array([0.5, -0.3, -0.4, 0.0, 0.0, 0.6, 0.0]))
    state = obs[None]
    features = relative_features(state)
    width = state.shape[1]
    assert features.shape == (1, actor_input_dim("relative", width))
    np.testing.assert_array_equal(features[:, :width], state)
    tcp, tcp_rot, plug, plug_rot, tip = _world(env)
    # Relative quantities in the TCP's own frame do not depend on the frame the state uses.
    plug_in_tcp = tcp_rot.T @ (plug - tcp)
    np.testing.assert_allclose(features[0, width : width + 3], plug_in_tcp, atol=1e-6)
    np.testing.assert_allclose(
        features[0, width + 3 : width + 12], (tcp_rot.T @ plug_rot).ravel(), atol=1e-6
    )
    tip_from_tcp = features[0, width + 12 : width + 15]  # in the base frame: compare lengths
    assert abs(np.linalg.norm(tip_from_tcp) - np.linalg.norm(tip - tcp)) < 1e-6
    fine = features[0, width + 15 :]
    for k, scale in enumerate(FINE_SCALES):
        np.testing.assert_allclose(fine[9 * k : 9 * k + 3], np.tanh(plug_in_tcp / scale), atol=1e-4)
    env.close()


def test_relative_features_refuse_a_state_that_is_not_an_insertion_state():
    with pytest.raises(ValueError, match="width of the insertion task"):
        relative_features(np.zeros((2, 43)))


def test_a_family_gets_relative_inputs_from_its_memoryless_experts_hook():
    from wirecraft.experts.reactive import REACTIVE_EXPERTS, ReactiveGraspExpert

    assert actor_transform("relative", "insertion") is relative_features
    assert actor_transform("state", "insertion") is None

    @REACTIVE_EXPERTS.register("toy_family")
    class ToyExpert(ReactiveGraspExpert):
        TASK = "toy_family"

    try:  # an expert without the hook: no relative inputs, and the error names who has them
        with pytest.raises(
            ValueError, match="insertion, routing, seating tasks' states, not toy_family"
        ):
            actor_transform("relative", "toy_family")
        ToyExpert.relative_features = staticmethod(lambda states: states)
        assert actor_transform("relative", "toy_family") is ToyExpert.relative_features
    finally:
        REACTIVE_EXPERTS.unregister("toy_family")


def test_discounted_returns_restart_where_an_episode_ends():
    rewards = np.ones((4, 2))
    dones = np.zeros((4, 2))
    dones[1, 1] = 1.0  # the second environment's first episode ends after step 1
    returns = discounted_returns(rewards, dones, 0.5)
    np.testing.assert_allclose(returns[:, 0], [1.875, 1.75, 1.5, 1.0])
    np.testing.assert_allclose(returns[:, 1], [1.5, 1.0, 1.5, 1.0])


def test_a_wave_without_the_expert_executes_the_actor_and_still_labels_every_state():
    import torch

    from wirecraft.experts.reactive import ReactiveInsertionExpert
    from wirecraft.rl.ppo import state_observations

    def still_actor(td):  # holds the arm where it is (zero Cartesian moves), pads open
        action = torch.zeros(len(td["policy"]), 7)
        action[:, 6] = -1.0
        return action

    def act(obs):
        return actor_means(still_actor, state_observations, obs)

    venv = wirecraft.make_vec("insertion", 2, threads=1, control="cartesian", episode_seconds=0.5)
    expert = ReactiveInsertionExpert(venv)
    wave = run_wave(venv, expert, act, 0.0, 5, np.random.default_rng())
    venv.close()
    steps = wave["states"].shape[0]
    assert wave["labels"].shape == (steps, 2, 7)
    tcp = wave["states"][:, :, expert.layout.tcp_pos]
    assert np.abs(tcp - tcp[0]).max() < 0.002  # the actor held still...
    assert np.abs(wave["labels"][:, :, :3]).max() > 0.5  # ...while the expert asked to move
    assert wave["rates"].keys() == {"success", "reach", "insert"}  # the task's own flags
    assert wave["rates"]["insert"] == 0.0


def test_dagger_warm_start_trains_the_actor_on_relative_inputs_and_loads_back(
    tmp_path, saved_actor_means
):
    import torch

    run_dir = tmp_path / "ppo"
    overrides = {**TINY_WARM_START, "init_std": 0.05}
    train("ppo", "insertion", {}, run_dir, 16, overrides=overrides, progress=False)
    run = json.loads((run_dir / RUN_FILE).read_text())
    first, alone = run["dagger_init"]
    assert (first["beta"], alone["beta"]) == (1.0, 0.0)
    assert first["insert"] == 1.0  # the expert's own wave: the task's insert_success, both envs
    assert (first["labels"], alone["labels"]) == (960, 1920)  # 480 steps x 2 envs per wave
    assert np.isfinite([first["actor_loss"], alone["actor_loss"], alone["critic_loss"]]).all()

    # the loaded policy computes the relative inputs itself: its action is the saved actor's
    venv = wirecraft.make_vec("insertion", 2, threads=1, control="cartesian")
    obs, _ = venv.reset(seed=4)
    policy = load_policy(run_dir, venv)
    venv.close()
    saved = torch.load(run_dir / run["latest_checkpoint"], weights_only=False)
    state = saved["actor_state_dict"]
    np.testing.assert_allclose(
        policy.act(obs), saved_actor_means(state, relative_features(obs)), atol=1e-5
    )


@pytest.mark.parametrize(
    "task, env_kwargs",
    [
        ("seating", {"channel": "straight", "control": "cartesian"}),
        ("routing", {"num_clips": 1, "control": "cartesian"}),
    ],
)
def test_dagger_warm_start_runs_on_each_family_and_its_policy_loads_back(
    task, env_kwargs, tmp_path, saved_actor_means
):
    """The recipe beyond insertion: the family's memoryless expert labels, its flags are
    recorded per wave, and the loaded policy computes the family's relative inputs itself."""
    import torch

    from wirecraft.experts.reactive import REACTIVE_EXPERTS

    overrides = TINY_WARM_START
    kwargs = {**env_kwargs, "episode_seconds": 2.0}
    train("ppo", task, kwargs, tmp_path, 16, overrides=overrides, progress=False)
    run = json.loads((tmp_path / RUN_FILE).read_text())
    first, alone = run["dagger_init"]
    assert (first["beta"], alone["beta"]) == (1.0, 0.0)
    # one success flag (no insert flag); 2 s of 60 Hz control steps per wave in 2 environments
    assert first.keys() >= {"success"} and "insert" not in first
    assert (first["labels"], alone["labels"]) == (240, 480)

    venv = wirecraft.make_vec(task, 2, threads=1, **env_kwargs)
    obs, _ = venv.reset(seed=4)
    policy = load_policy(tmp_path, venv)
    venv.close()
    saved = torch.load(tmp_path / run["latest_checkpoint"], weights_only=False)
    features = REACTIVE_EXPERTS.get(task).relative_features(obs)
    np.testing.assert_allclose(
        policy.act(obs), saved_actor_means(saved["actor_state_dict"], features), atol=1e-5
    )


def test_a_warm_start_stopped_mid_wave_resumes_to_the_same_run_as_one_never_stopped(
    tmp_path, monkeypatch
):
    """Killed in wave 2 of 3 (the first two saved), resumed: the waves' records, the saved
    checkpoint's actor and critic equal those of a run that was never stopped, bit for bit; the
    waves' data is gone once the last wave is fitted."""
    import torch

    from wirecraft.rl import dagger

    overrides = {**TINY_WARM_START, "dagger_init_iterations": 2}
    env_kwargs = {"episode_seconds": 1.0}
    whole, stopped = tmp_path / "whole", tmp_path / "stopped"
    train("ppo", "insertion", env_kwargs, whole, 16, overrides=overrides, progress=False)

    run_wave, calls = dagger.run_wave, []

    def killed_in_the_third_wave(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return run_wave(*args, **kwargs)

    monkeypatch.setattr(dagger, "run_wave", killed_in_the_third_wave)
    with pytest.raises(KeyboardInterrupt):
        train("ppo", "insertion", env_kwargs, stopped, 16, overrides=overrides, progress=False)
    assert sorted(p.name for p in (stopped / "dagger_init").iterdir()) == [
        "state.pt",
        "wave_0.npz",
        "wave_1.npz",
    ]
    assert len(torch.load(stopped / "dagger_init" / "state.pt", weights_only=False)["history"]) == 2
    monkeypatch.setattr(dagger, "run_wave", run_wave)
    calls.clear()
    train("ppo", "insertion", None, stopped, 16, resume=True, progress=False)

    runs = [json.loads((d / RUN_FILE).read_text()) for d in (whole, stopped)]
    assert runs[0]["dagger_init"] == runs[1]["dagger_init"]
    assert [w["beta"] for w in runs[1]["dagger_init"]] == [1.0, 0.5, 0.0]
    saved = [
        torch.load(d / r["latest_checkpoint"], weights_only=False)
        for d, r in zip((whole, stopped), runs, strict=True)
    ]
    for part in ("actor_state_dict", "critic_state_dict"):
        for name, value in saved[0][part].items():
            assert torch.equal(value, saved[1][part][name]), (part, name)
    assert [p.name for p in (stopped / "dagger_init").iterdir()] == ["state.pt"]


def test_a_saved_warm_start_with_other_settings_is_refused(tmp_path):
    import torch

    from wirecraft.rl.dagger import WarmStartProgress

    WarmStartProgress(tmp_path, [1.0, 0.0], 3).save(
        _FakeRunner(), np.random.default_rng(0), [{"wave": 0}], np.zeros((1, 2)), np.zeros((1, 1)),
        np.zeros(1),
    )  # fmt: skip
    assert torch.load(tmp_path / "state.pt", weights_only=False)["history"] == [{"wave": 0}]
    with pytest.raises(ValueError, match="holds a warm start with"):
        WarmStartProgress(tmp_path, [1.0, 0.5, 0.0], 3).load(
            _FakeRunner(), np.random.default_rng(0)
        )


class _FakeRunner:
    class alg:  # noqa: N801
        import torch

        actor = torch.nn.Linear(2, 1)
        critic = torch.nn.Linear(2, 1)


def test_bad_warm_start_settings_are_refused_before_anything_is_written(tmp_path):
    with pytest.raises(ValueError, match="actor_inputs"):
        PPOConfig(actor_inputs="pixels")
    with pytest.raises(ValueError, match="dagger_init_iterations"):
        PPOConfig(dagger_init_iterations=-1)
    with pytest.raises(ValueError, match="dagger_init_epochs"):
        PPOConfig(dagger_init_epochs=0)
    with pytest.raises(ValueError, match="choose"):
        PPOConfig(dagger_init_iterations=2, bc_init_transitions=100)
    with pytest.raises(ValueError, match="state PPO"):
        VisionPPOConfig(dagger_init_iterations=1)
    with pytest.raises(ValueError, match="state PPO"):
        VisionPPOConfig(actor_inputs="relative")
    run_dir = tmp_path / "run"
    cases = [
        ("routing", {"control": "joint"}, {"dagger_init_iterations": 1}, "insertion task"),
        ("insertion", {"control": "joint"}, {"dagger_init_iterations": 1}, "cartesian"),
        ("seating", {}, {"dagger_init_iterations": 1}, "seating task with control='cartesian'"),
    ]
    for task, env_kwargs, overrides, message in cases:
        with pytest.raises(ValueError, match=message):
            train("ppo", task, env_kwargs, run_dir, 16, overrides=overrides, progress=False)
        assert not run_dir.exists()


class _Storage:
    def __init__(self, observations):
        self.observations = observations


class _StateActor:
    """An MLP on the raw state (the ``policy`` group), as rsl-rl's actor is called."""

    def __init__(self, width: int):
        import torch

        torch.manual_seed(0)
        self.net = torch.nn.Sequential(
            torch.nn.Linear(width, 64), torch.nn.ELU(), torch.nn.Linear(64, 7)
        )

    def __call__(self, td):
        return self.net(td["policy"])

    def parameters(self):
        return self.net.parameters()

    def train(self):
        self.net.train()


def test_auxiliary_dagger_pulls_the_actor_toward_the_experts_labels_after_each_update():
    import types

    import torch
    from tensordict import TensorDict

    from wirecraft.experts.reactive import ReactiveInsertionExpert
    from wirecraft.rl.dagger import auxiliary_dagger

    venv = wirecraft.make_vec("insertion", 4, threads=1, control="cartesian")
    obs, _ = venv.reset(seed=5)
    expert = ReactiveInsertionExpert(venv)
    rollout = []
    for _ in range(40):  # the expert's own path: approach, descend, grasp
        rollout.append(obs.copy())
        obs, *_ = venv.step(expert.act(obs))
    states = np.stack(rollout)  # (T, N, width)
    labels = torch.as_tensor(ReactiveInsertionExpert(venv).act(states.reshape(-1, obs.shape[1])))
    td = TensorDict({"policy": torch.as_tensor(states, dtype=torch.float32)}, batch_size=[40, 4])
    actor = _StateActor(obs.shape[1])
    calls = []

    def ppo_update():
        calls.append(1)
        return {"surrogate": 0.0}

    alg = types.SimpleNamespace(actor=actor, storage=_Storage(td), update=ppo_update)
    runner = types.SimpleNamespace(alg=alg, current_learning_iteration=0)

    def error():
        with torch.no_grad():
            return float(torch.nn.functional.mse_loss(actor(td.flatten(0, 1)), labels.float()))

    before = error()
    with auxiliary_dagger(runner, venv, learning_rate=1e-2, decay=0.5, seed=0, batch_size=64):
        for it in range(30):
            runner.current_learning_iteration = it
            losses = alg.update()
            if it == 2:
                assert losses["dagger_lr"] == pytest.approx(1e-2 * 0.5**2)
        runner.current_learning_iteration = 0  # undecayed for the rest
        for _ in range(30):
            losses = alg.update()
    assert alg.update is ppo_update  # restored on leaving
    venv.close()
    assert len(calls) == 60 and losses["surrogate"] == 0.0  # PPO's update ran every time
    assert np.isfinite(losses["dagger"])
    assert error() < 0.2 * before, (before, error())


def test_bad_auxiliary_dagger_settings_are_refused(tmp_path):
    for bad in (-1e-4, float("nan")):
        with pytest.raises(ValueError, match="dagger_aux_lr"):
            PPOConfig(dagger_aux_lr=bad)
    for bad in (0.0, 1.5):
        with pytest.raises(ValueError, match="dagger_aux_decay"):
            PPOConfig(dagger_aux_decay=bad)
    with pytest.raises(ValueError, match="state PPO"):
        VisionPPOConfig(dagger_aux_lr=1e-4)
    run_dir = tmp_path / "run"
    with pytest.raises(ValueError, match="insertion task"):
        overrides = {"dagger_aux_lr": 1e-4}
        train(
            "ppo", "routing", {"control": "joint"}, run_dir, 16, overrides=overrides, progress=False
        )
    assert not run_dir.exists()
