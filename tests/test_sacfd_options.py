"""SACfD's options beyond the reference (rl/sacfd.py): demonstrations from the memoryless
expert, goal-relative inputs for actor and critics, the behaviour-cloning term on the agent's
own replay states labelled by that expert, the behaviour-cloned start and the DAgger warm
start."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

import wirecraft
from wirecraft.experts.reactive import REACTIVE_EXPERTS
from wirecraft.rl import load_policy, train
from wirecraft.rl.config import SACfDConfig
from wirecraft.rl.sacfd import (
    SACfD,
    TransformedInputs,
    _memory,
    agent_config,
    behaviour_clone_start,
    make_models,
)

SHORT = {"episode_seconds": 0.1}  # 6 control steps per episode


def test_options_reject_unknown_values():
    for bad in (
        {"demo_expert": "human"},
        {"inputs": "pixels"},
        {"bc_states": "expert"},
        {"bc_init_steps": -1},
        {"max_log_std": -6.0},
        {"max_log_std": float("nan")},
        {"actor_learning_rate": -1.0},
    ):
        with pytest.raises(ValueError, match=next(iter(bad))):
            SACfDConfig(**bad)


def test_transformed_inputs_pass_observations_and_final_observations_through():
    def doubled(states):
        return np.concatenate([states, 2.0 * states], axis=1)

    plain = wirecraft.make_vec("insertion", 2, threads=1, **SHORT)
    wrapped = TransformedInputs(wirecraft.make_vec("insertion", 2, threads=1, **SHORT), doubled, 84)
    assert wrapped.single_observation_space.shape == (84,)
    obs, _ = plain.reset(seed=3)
    got, _ = wrapped.reset(seed=3)
    np.testing.assert_array_equal(got, doubled(obs))
    actions = np.zeros((2, 7))
    finished = False
    for _ in range(6):  # the sixth step truncates both episodes
        obs, *_, infos = plain.step(actions)
        got, *_, got_infos = wrapped.step(actions)
        np.testing.assert_array_equal(got, doubled(obs))
        if "final_obs" in infos:
            finished = True
            for i in np.flatnonzero(infos["_final_obs"]):
                np.testing.assert_array_equal(
                    got_infos["final_obs"][i], doubled(infos["final_obs"][i][None])[0]
                )
    assert finished
    plain.close()
    wrapped.close()


def _agent(cfg: SACfDConfig, obs_dim: int, action_dim: int, tmp_path, labeller=None):
    torch.manual_seed(0)  # the networks' initial weights
    obs_space = gym.spaces.Box(-np.inf, np.inf, (obs_dim,))
    act_space = gym.spaces.Box(-1.0, 1.0, (action_dim,))
    demos = _memory(64, 1, obs_space, act_space, replacement=True)
    demos.add_samples(
        observations=torch.ones(64, obs_dim),
        next_observations=torch.ones(64, obs_dim),
        actions=torch.full((64, action_dim), 0.5),
        rewards=torch.zeros(64, 1),
        terminated=torch.zeros(64, 1, dtype=torch.bool),
    )
    from wirecraft.rl.sacfd import DemoMixingMemory

    memory = _memory(
        16, 2, obs_space, act_space, DemoMixingMemory, demos=demos, demo_ratio=cfg.demo_ratio
    )
    agent = SACfD(
        models=make_models(obs_space, act_space, cfg),
        memory=memory,
        observation_space=obs_space,
        action_space=act_space,
        device="cpu",
        cfg=agent_config(cfg, obs_space, tmp_path / "run"),
        demo_memory=demos,
        sacfd=cfg,
        num_envs=2,
        labeller=labeller,
    )
    return agent, memory


def test_bc_term_draws_demo_pairs_or_own_states_labelled_by_the_labeller(tmp_path):
    def labeller(obs):  # any function of the state: here minus its first column
        return -obs[:, :1]

    cfg = SACfDConfig(bc_states="replay", hidden_dims=(8,), batch_size=8)
    with pytest.raises(ValueError, match="labeller"):
        _agent(cfg, 3, 1, tmp_path)
    agent, memory = _agent(cfg, 3, 1, tmp_path, labeller)
    for k in range(8):  # the agent's own states: -0.0, -0.1, ... in every column
        own = torch.full((2, 3), -0.1 * k)
        memory.add_samples(
            observations=own,
            next_observations=own,
            actions=torch.zeros(2, 1),
            rewards=torch.zeros(2, 1),
            terminated=torch.zeros(2, 1, dtype=torch.bool),
        )
    obs, labels = agent.bc_batch(32)
    assert obs.shape == (32, 3) and (obs <= 0).all()  # none of the demonstrations' (ones)
    torch.testing.assert_close(labels, -obs[:, :1])

    demos_agent, _ = _agent(SACfDConfig(hidden_dims=(8,), batch_size=8), 3, 1, tmp_path)
    obs, labels = demos_agent.bc_batch(16)
    assert (obs == 1).all() and (labels == 0.5).all()


def _agent_with_replay(cfg: SACfDConfig, tmp_path) -> SACfD:
    """An initialised agent (3-d states, 1-d actions) whose replay holds 16 random
    transitions, enough for updates."""
    agent, memory = _agent(cfg, 3, 1, tmp_path)
    agent.init()
    generator = torch.Generator().manual_seed(1)
    for _ in range(8):
        memory.add_samples(
            observations=torch.randn(2, 3, generator=generator),
            next_observations=torch.randn(2, 3, generator=generator),
            actions=torch.rand(2, 1, generator=generator) * 2 - 1,
            rewards=torch.randn(2, 1, generator=generator),
            terminated=torch.zeros(2, 1, dtype=torch.bool),
        )
    return agent


def test_behaviour_cloned_start_recovers_a_known_policy_and_its_residual_spread(tmp_path):
    """Demonstrations of a known deterministic policy: the fit's mean approaches it, and its
    spread is the fit's residual, per action dimension, in every state."""
    generator = torch.Generator().manual_seed(0)
    obs = torch.randn(2000, 4, generator=generator) * torch.tensor([1.0, 10.0, 0.1, 3.0])
    weights = torch.tensor([[0.8, 0.0], [0.0, -0.05], [2.0, 1.0], [0.0, 0.2]])
    actions = torch.tanh(obs @ weights)
    cfg = SACfDConfig(hidden_dims=(64, 64), batch_size=128)
    agent, _ = _agent(cfg, 4, 2, tmp_path)
    inputs = {"observations": agent._observation_preprocessor(obs), "states": None}
    before = agent.policy.act(inputs, role="policy")[1]["mean_actions"].detach()
    start_error = float(((before - actions) ** 2).mean())
    mse = behaviour_clone_start(agent, {"observations": obs, "actions": actions}, 1500, seed=1)
    inputs = {"observations": agent._observation_preprocessor(obs), "states": None}
    _, outputs = agent.policy.act(inputs, role="policy")
    residual = outputs["mean_actions"].detach() - actions
    error = float((residual**2).mean())
    assert error < 0.05 * start_error and error < 0.01 and mse == pytest.approx(error, rel=1e-4)
    spread = outputs["log_std"].detach().exp()
    torch.testing.assert_close(spread, (residual**2).mean(0).sqrt().expand_as(spread))
    scaler = agent._observation_preprocessor  # fitted to the demonstrations' statistics
    np.testing.assert_allclose(
        scaler.running_mean.numpy(), obs.mean(0).numpy(), rtol=0.05, atol=0.02
    )


@pytest.mark.slow
def test_sacfd_with_memoryless_demonstrations_relative_inputs_and_replay_labels(tmp_path, sac_tiny):
    run_dir = tmp_path / "sac"
    settings = {
        **sac_tiny,
        "demo_expert": "reactive",
        "inputs": "relative",
        "bc_states": "replay",
        "bc_init_steps": 20,
    }
    summary = train("sacfd", "insertion", SHORT, run_dir, 20, overrides=settings, progress=False)
    assert summary["latest_checkpoint"] == "checkpoints/agent_10.pt"
    demos = torch.load(run_dir / "demos.pt", weights_only=True)
    relative = REACTIVE_EXPERTS.get("insertion").relative_features
    states = demos["observations"][:, :42].double().numpy()
    assert demos["observations"].shape[1] == relative(states).shape[1] > 42
    np.testing.assert_allclose(demos["observations"][:, 42:], relative(states)[:, 42:], atol=1e-4)
    # The memoryless expert's action is a function of the state: relabel the stored states.
    venv = wirecraft.make_vec("insertion", 2, threads=1, **SHORT)
    expert = REACTIVE_EXPERTS.get("insertion")(venv)
    np.testing.assert_allclose(demos["actions"], expert.act(states), atol=1e-4)

    obs, _ = venv.reset(seed=5)
    policy = load_policy(run_dir, venv)
    saved = torch.load(run_dir / "checkpoints/agent_10.pt", weights_only=False)
    scaler = saved["observation_preprocessor"]
    x = relative(obs)
    x = (x - scaler["running_mean"].numpy()) / (np.sqrt(scaler["running_variance"].numpy()) + 1e-8)
    features = torch.as_tensor(np.clip(x, -5, 5), dtype=torch.float32)
    from wirecraft.rl.sacfd import GaussianActor

    actor = GaussianActor(
        gym.spaces.Box(-np.inf, np.inf, (x.shape[1],)), venv.single_action_space, (16, 16), "elu"
    )
    actor.load_state_dict(saved["policy"])
    with torch.no_grad():
        expected = torch.tanh(actor.mean_head(actor.net(features))).double().numpy()
    np.testing.assert_allclose(policy.act(obs), expected, atol=1e-5)

    # Shipped: the actor and its observation scaler alone, acting as the run does.
    from wirecraft.rl.export import main as export_main

    out = tmp_path / "shipped"
    assert export_main([str(run_dir), "--out", str(out), "--command", "wirecraft train"]) == 0
    full = (run_dir / "checkpoints/agent_10.pt").stat().st_size
    assert (out / "checkpoints/agent_10.pt").stat().st_size < full / 3
    np.testing.assert_array_equal(load_policy(out, venv).act(obs), policy.act(obs))
    with pytest.raises(ValueError, match="shipped policy"):
        train("sacfd", "insertion", SHORT, out, 40, progress=False, resume=True)
    venv.close()


def test_dagger_start_runs_expert_then_actor_waves_and_fits_the_labels(tmp_path):
    from wirecraft.rl.sacfd import dagger_start

    cfg = SACfDConfig(
        hidden_dims=(64, 64),
        batch_size=16,
        dagger_init_iterations=1,
        dagger_init_envs=2,
        dagger_init_epochs=400,
    )
    agent, _ = _agent(cfg, 42, 7, tmp_path)
    venv = wirecraft.make_vec("insertion", 2, threads=1, **SHORT)
    obs, _ = venv.reset(seed=cfg.seed + 20_000)  # the first wave's reset states
    labels = REACTIVE_EXPERTS.get("insertion")(venv).act(obs)
    venv.close()

    def actor_error() -> float:
        x = agent._observation_preprocessor(torch.as_tensor(obs, dtype=torch.float32))
        with torch.no_grad():
            _, outputs = agent.policy.act({"observations": x, "states": None}, role="policy")
        return float(((outputs["mean_actions"].numpy() - labels) ** 2).mean())

    before = actor_error()
    history = dagger_start(agent, "insertion", SHORT, cfg, lambda s: s, progress=False)
    assert [h["beta"] for h in history] == [1.0, 0.0]  # the expert's wave, then the actor's
    assert [h["labels"] for h in history] == [12, 24]  # 2 environments x 6 steps per wave
    assert {"success", "reach", "insert"} <= set(history[0])
    assert actor_error() < 0.25 * before


def test_critic_warmup_holds_the_actor_while_the_critics_learn(tmp_path):
    def params(model):
        return [p.detach().clone() for p in model.parameters()]

    def changed(before, model) -> bool:
        return any(not torch.equal(a, b) for a, b in zip(before, model.parameters(), strict=True))

    no_bc = {"bc_weight_start": 0.0, "bc_weight_end": 0.0, "hidden_dims": (8,), "batch_size": 8}
    for warmup, actor_moves in ((0, True), (160, False)):
        cfg = SACfDConfig(critic_warmup_steps=warmup, warmup_steps=0, **no_bc)
        agent = _agent_with_replay(cfg, tmp_path)
        actor, critic = params(agent.policy), params(agent.critic_1)
        agent.update(timestep=79, timesteps=100)  # 79 vector steps x 2 envs < 160
        assert changed(critic, agent.critic_1)
        assert changed(actor, agent.policy) == actor_moves
        agent.update(timestep=80, timesteps=100)  # 160 env steps after the first update
        assert changed(actor, agent.policy)


def test_max_log_std_bounds_the_spread_of_the_actors_samples(tmp_path):
    cfg = SACfDConfig(max_log_std=-3.0, hidden_dims=(8,))
    agent, _ = _agent(cfg, 3, 2, tmp_path)
    with torch.no_grad():
        agent.policy.log_std_head.bias.fill_(1.0)  # asks for a spread of e, 55 times the clip
    obs = torch.zeros(20000, 3)
    actions, outputs = agent.policy.act({"observations": obs, "states": None}, role="policy")
    spread = (actions - outputs["mean_actions"]).std(dim=0)
    assert torch.allclose(spread, torch.full((2,), np.exp(-3.0)), rtol=0.05)


def test_actor_learning_rate_sets_the_size_of_the_actors_steps_only(tmp_path):
    lr_actor, lr_critics = 1e-6, 1e-3
    cfg = SACfDConfig(
        actor_learning_rate=lr_actor,
        learning_rate=lr_critics,
        warmup_steps=0,
        hidden_dims=(8,),
        batch_size=8,
    )
    agent = _agent_with_replay(cfg, tmp_path)
    actor = [p.detach().clone() for p in agent.policy.parameters()]
    critic = [p.detach().clone() for p in agent.critic_1.parameters()]
    agent.update(timestep=1, timesteps=10)

    def largest_move(before, model) -> float:
        after = model.parameters()
        return max(float((a - b.detach()).abs().max()) for a, b in zip(before, after, strict=True))

    # Adam moves each weight by at most about its learning rate per step.
    steps = 2 * cfg.gradient_steps_per_vector_step  # SAC's and the BC term's
    assert 0 < largest_move(actor, agent.policy) <= 1.01 * lr_actor * steps
    assert largest_move(critic, agent.critic_1) > 10 * lr_actor * steps
