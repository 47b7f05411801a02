"""SAC from demonstrations on skrl (2.1): skrl's SAC agent, plus

- a demonstration replay buffer filled from the task's scripted expert (successful episodes);
  every SAC batch draws ``demo_ratio`` of its samples from it (``DemoMixingMemory``);
- a behaviour-cloning term: after each SAC gradient step, one step of
  ``bc_weight * MSE(policy mean, demo action)`` on a demo batch, the weight annealed linearly
  from ``bc_weight_start`` to ``bc_weight_end`` between ``bc_anneal_start`` and
  ``bc_anneal_end`` env steps;
- SAME_STEP autoreset handled: a finished episode's transition stores its *final*
  observation as the next observation (skrl's gymnasium wrapper hands over the first
  observation of the next episode), time-outs bootstrap, diverged episodes do not;
- the entropy coefficient saved in checkpoints (skrl 2.1 saves only its optimizer).

Options beyond the reference (``SACfDConfig``; docs/baselines.md, "SACfD"): demonstrations
from the task's memoryless expert (``demo_expert="reactive"``), goal-relative inputs
(``inputs="relative"``, for actor and critics alike), a BC term on the agent's own replay
states labelled by that expert (``bc_states="replay"``: DAgger inside SAC), a fit of the
actor to the demonstrations before the first step (``bc_init_steps``), and a DAgger warm
start of the actor (``dagger_init_iterations``).

Import this module only when training or loading a SACfD policy (it imports torch and skrl).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from gymnasium.vector import VectorWrapper
from skrl.agents.torch.sac import SAC, SAC_CFG
from skrl.memories.torch import RandomMemory
from skrl.models.torch import DeterministicMixin, GaussianMixin, Model
from torch import nn

from wirecraft.rl.common import (
    CHECKPOINT_DIR,
    EpisodeTracker,
    ProgressTable,
    WallClock,
    expert_vec_env,
    final_observations,
    state_batch,
    summarize,
)
from wirecraft.rl.config import MAX_LOG_STD, MIN_LOG_STD, SACfDConfig

TRANSITION_NAMES = ("observations", "actions", "rewards", "next_observations", "terminated")


def _mlp(inputs: int, hidden: tuple[int, ...], activation: str) -> nn.Sequential:
    from rsl_rl.utils import resolve_nn_activation

    layers, width = [], inputs
    for n in hidden:
        layers += [nn.Linear(width, n), resolve_nn_activation(activation)]
        width = n
    return nn.Sequential(*layers)


class GaussianActor(GaussianMixin, Model):
    """Tanh-bounded mean and a state-dependent log std (skrl samples the Gaussian; the
    controller clips actions to [-1, 1])."""

    def __init__(
        self,
        observation_space,
        action_space,
        hidden,
        activation,
        max_log_std=MAX_LOG_STD,
        device="cpu",
    ):
        Model.__init__(
            self, observation_space=observation_space, action_space=action_space, device=device
        )
        GaussianMixin.__init__(
            self,
            clip_actions=False,
            clip_log_std=True,
            min_log_std=MIN_LOG_STD,
            max_log_std=max_log_std,
            reduction="sum",
        )
        self.net = _mlp(self.num_observations, hidden, activation)
        self.mean_head = nn.Linear(hidden[-1], self.num_actions)
        self.log_std_head = nn.Linear(hidden[-1], self.num_actions)

    def compute(self, inputs, role=""):
        features = self.net(inputs["observations"])
        return torch.tanh(self.mean_head(features)), {"log_std": self.log_std_head(features)}


class QCritic(DeterministicMixin, Model):
    def __init__(self, observation_space, action_space, hidden, activation, device="cpu"):
        Model.__init__(
            self, observation_space=observation_space, action_space=action_space, device=device
        )
        DeterministicMixin.__init__(self, clip_actions=False)
        self.net = nn.Sequential(
            _mlp(self.num_observations + self.num_actions, hidden, activation),
            nn.Linear(hidden[-1], 1),
        )

    def compute(self, inputs, role=""):
        return self.net(torch.cat([inputs["observations"], inputs["taken_actions"]], dim=-1)), {}


def make_models(observation_space, action_space, cfg: SACfDConfig) -> dict[str, Model]:
    def critic():
        return QCritic(observation_space, action_space, cfg.hidden_dims, cfg.activation)

    return {
        "policy": GaussianActor(
            observation_space, action_space, cfg.hidden_dims, cfg.activation, cfg.max_log_std
        ),
        "critic_1": critic(),
        "critic_2": critic(),
        "target_critic_1": critic(),
        "target_critic_2": critic(),
    }


class DemoMixingMemory(RandomMemory):
    """The agent's replay buffer; each sample takes ``demo_ratio`` of the batch from
    ``demos`` (another skrl memory with the same tensors)."""

    def __init__(self, *, demos: RandomMemory, demo_ratio: float, **kwargs) -> None:
        super().__init__(**kwargs, replacement=True)
        self.demos = demos
        self.demo_ratio = demo_ratio

    def sample(self, names, *, batch_size, mini_batches=1, sequence_length=1):
        n_demo = int(round(batch_size * self.demo_ratio)) if len(self.demos) else 0
        n_agent = batch_size - n_demo
        parts = []
        if n_agent:
            parts.append(super().sample(names, batch_size=n_agent)[0])
        if n_demo:
            parts.append(self.demos.sample(names, batch_size=n_demo)[0])
        batch = [
            None if tensors[0] is None else torch.cat(tensors, dim=0)
            for tensors in zip(*parts, strict=True)
        ]
        return [batch]

    def sample_own(self, names, *, batch_size: int):
        """A batch of the agent's own transitions only."""
        return super().sample(names, batch_size=batch_size)[0]


def _memory(size: int, num_envs: int, observation_space, action_space, cls=RandomMemory, **kw):
    memory = cls(memory_size=size, num_envs=num_envs, device="cpu", **kw)
    for name in ("observations", "next_observations"):
        memory.create_tensor(name=name, size=observation_space, dtype=torch.float32)
    memory.create_tensor(name="actions", size=action_space, dtype=torch.float32)
    memory.create_tensor(name="rewards", size=1, dtype=torch.float32)
    memory.create_tensor(name="terminated", size=1, dtype=torch.bool)
    return memory


class _EntropyState(nn.Module):
    """Holds SAC's log entropy coefficient so that skrl checkpoints carry it."""

    def __init__(self, log_alpha: torch.Tensor) -> None:
        super().__init__()
        self.register_buffer("log_alpha", log_alpha)


class _NoStep:
    """An optimizer that changes nothing (SACfDConfig.critic_warmup_steps)."""

    def zero_grad(self) -> None:
        pass

    def step(self) -> None:
        pass


class SACfD(SAC):
    """skrl SAC with a demonstration buffer and an annealed BC term (see the module doc)."""

    def __init__(
        self,
        *,
        demo_memory,
        sacfd: SACfDConfig,
        num_envs: int,
        on_checkpoint=None,
        labeller: Callable[[torch.Tensor], torch.Tensor] | None = None,
        **kw,
    ):
        super().__init__(**kw)
        if sacfd.bc_states == "replay" and labeller is None:
            raise ValueError("bc_states='replay' needs a labeller (the task's reactive expert)")
        self.demo_memory = demo_memory
        self.labeller = labeller
        self.sacfd = sacfd
        self.num_envs = num_envs
        self.on_checkpoint = on_checkpoint
        self.last_bc_loss = float("nan")
        if self.cfg.learn_entropy:
            self.checkpoint_modules["entropy"] = _EntropyState(self.log_entropy_coefficient)

    def record_transition(self, *, next_observations, terminated, truncated, infos, **kw):
        done = (terminated | truncated).view(-1).cpu().numpy()
        if done.any():
            # skrl's wrapper tensorized the next episode's first observation for these rows.
            fixed = final_observations(next_observations.cpu().numpy(), infos, done)
            next_observations = torch.as_tensor(fixed, dtype=torch.float32)
        diverged = np.asarray(infos.get("diverged", np.zeros(len(done), bool)), bool)
        terminated = terminated | torch.as_tensor(diverged).view(-1, 1)
        super().record_transition(
            next_observations=next_observations,
            terminated=terminated,
            truncated=truncated,
            infos=infos,
            **kw,
        )

    def update(self, *, timestep: int, timesteps: int) -> None:
        held = (
            timestep - self.cfg.learning_starts
        ) * self.num_envs < self.sacfd.critic_warmup_steps
        optimizer = self.policy_optimizer
        if held:  # skrl's update computes the actor's SAC step; nothing applies it
            self.policy_optimizer = _NoStep()
        try:
            super().update(timestep=timestep, timesteps=timesteps)
        finally:
            self.policy_optimizer = optimizer
        if self.cfg.learn_entropy:
            self.log_entropy_coefficient.data.clamp_(max=math.log(10.0))
        weight = self.sacfd.bc_weight(timestep * self.num_envs)
        n_demo = max(1, int(round(self.cfg.batch_size * self.sacfd.demo_ratio)))
        if weight <= 0 or not len(self.demo_memory):
            return
        for _ in range(self.cfg.gradient_steps):
            obs, actions = self.bc_batch(n_demo)
            inputs = {"observations": self._observation_preprocessor(obs), "states": None}
            _, outputs = self.policy.act(inputs, role="policy")
            bc_loss = weight * F.mse_loss(outputs["mean_actions"], actions)
            self.policy_optimizer.zero_grad()
            bc_loss.backward()
            if self.cfg.grad_norm_clip > 0:
                nn.utils.clip_grad_norm_(self.policy.parameters(), self.cfg.grad_norm_clip)
            self.policy_optimizer.step()
        self.last_bc_loss = float(bc_loss.item())
        if self.write_interval > 0:
            self.track_data("Loss / BC loss", self.last_bc_loss)
            self.track_data("Coefficient / BC weight", weight)

    def bc_batch(self, size: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The behaviour-cloning term's (observations, target actions)."""
        if self.sacfd.bc_states == "demos":
            return self.demo_memory.sample(["observations", "actions"], batch_size=size)[0]
        (obs,) = self.memory.sample_own(["observations"], batch_size=size)
        obs = obs[torch.isfinite(obs).all(dim=1)]
        return obs, self.labeller(obs)

    def write_checkpoint(self, *, timestep: int, timesteps: int) -> None:
        super().write_checkpoint(timestep=timestep, timesteps=timesteps)
        if self.on_checkpoint is not None:
            path = Path(self.experiment_dir) / CHECKPOINT_DIR / f"agent_{timestep}.pt"
            self.on_checkpoint(path, timestep)

    def load(self, path: str) -> None:
        super().load(path)
        if self.cfg.learn_entropy:
            self._entropy_coefficient = torch.exp(self.log_entropy_coefficient.detach())


def agent_config(cfg: SACfDConfig, observation_space, run_dir: Path) -> SAC_CFG:
    from skrl.resources.preprocessors.torch import RunningStandardScaler

    scale = cfg.reward_scale
    per_vector_step = cfg.num_envs
    sac = SAC_CFG(
        gradient_steps=cfg.gradient_steps_per_vector_step,
        batch_size=cfg.batch_size,
        discount_factor=cfg.gamma,
        polyak=cfg.tau,
        learning_rate=(
            cfg.actor_learning_rate or cfg.learning_rate,
            cfg.learning_rate,
            cfg.learning_rate,
        ),
        random_timesteps=0,
        learning_starts=math.ceil(cfg.warmup_steps / per_vector_step),
        grad_norm_clip=0,
        learn_entropy=cfg.learn_entropy,
        initial_entropy_value=cfg.initial_alpha,
        target_entropy=cfg.target_entropy,
        rewards_shaper=lambda rewards, *_: rewards * scale,
    )
    if cfg.obs_normalization:
        sac.observation_preprocessor = RunningStandardScaler
        sac.observation_preprocessor_kwargs = {"size": observation_space, "device": "cpu"}
    sac.experiment.directory = str(Path(run_dir).parent)
    sac.experiment.experiment_name = Path(run_dir).name
    sac.experiment.write_interval = max(1, math.ceil(cfg.log_every_steps / per_vector_step))
    sac.experiment.checkpoint_interval = max(
        1, math.ceil(cfg.checkpoint_every_steps / per_vector_step)
    )
    return sac


# -- inputs --------------------------------------------------------------------------------------
class TransformedInputs(VectorWrapper):
    """A vector env whose observations, final ones included, pass through ``transform``
    ((N, state) -> (N, width) arrays; rl/features.py)."""

    def __init__(self, env, transform: Callable[[np.ndarray], np.ndarray], width: int) -> None:
        import gymnasium as gym

        super().__init__(env)
        self.transform = transform
        self.single_observation_space = gym.spaces.Box(-np.inf, np.inf, (width,), np.float64)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (env.num_envs, width), np.float64)

    def reset(self, **kwargs):
        obs, infos = self.env.reset(**kwargs)
        return self.transform(obs), infos

    def step(self, actions):
        obs, rewards, terminated, truncated, infos = self.env.step(actions)
        if "final_obs" in infos:
            final = infos["final_obs"].copy()
            for i in np.flatnonzero(infos["_final_obs"]):
                final[i] = self.transform(np.asarray(final[i])[None])[0]
            infos = {**infos, "final_obs": final}
        return self.transform(obs), rewards, terminated, truncated, infos


def inputs_transform(cfg: SACfDConfig, task: str):
    """(N, state) -> what actor and critics read (``cfg.inputs``); the identity for "state"."""
    from wirecraft.rl.features import actor_transform

    transform = actor_transform(cfg.inputs, task)
    return transform if transform is not None else (lambda states: np.asarray(states, float))


def expert_labeller(task: str, venv, state_dim: int) -> Callable[[torch.Tensor], torch.Tensor]:
    """Labels (N, inputs) observations with the task's reactive expert's actions on their
    first ``state_dim`` columns (the state every input option starts with)."""
    from wirecraft.experts.reactive import REACTIVE_EXPERTS

    expert = REACTIVE_EXPERTS.get(task)(venv)

    def label(obs: torch.Tensor) -> torch.Tensor:
        states = obs[:, :state_dim].numpy().astype(np.float64)
        return torch.as_tensor(expert.act(states), dtype=torch.float32)

    return label


# -- demonstrations ------------------------------------------------------------------------------
def collect_demonstrations(
    task: str,
    env_kwargs: dict,
    transitions: int,
    *,
    num_envs: int,
    seed: int,
    reward_scale: float,
    threads: int = 0,
    success_only: bool = True,
    progress: bool = True,
    max_factor: float = 4.0,
    kind: str = "scripted",
    transform: Callable[[np.ndarray], np.ndarray] | None = None,
) -> dict[str, torch.Tensor]:
    """``transitions`` transitions of the task's ``kind`` of expert (scripted or reactive), as
    float32 tensors (rewards already scaled; observations through ``transform`` when given).
    ``success_only``: keep only whole episodes in which ``success`` was reached (giving up
    after ``max_factor * transitions`` steps)."""
    expert, venv = expert_vec_env(
        task, env_kwargs, "demonstrations", num_envs, seed, kind, threads=threads
    )
    obs, _ = venv.reset(seed=seed)
    expert.reset()
    pending = [[] for _ in range(num_envs)]
    ever = np.zeros(num_envs, bool)
    kept: list[tuple] = []
    count, steps = 0, 0
    from tqdm import tqdm

    bar = tqdm(total=transitions, desc="expert demonstrations", unit="step", disable=not progress)
    try:
        while count < transitions:
            if success_only and steps > max_factor * transitions:
                raise RuntimeError(
                    f"the {task} expert succeeded too rarely: {count} demonstration transitions "
                    f"after {steps} steps"
                )
            actions = expert.act(obs)
            next_obs, rewards, terminated, truncated, infos = venv.step(actions)
            steps += num_envs
            done = terminated | truncated
            real_next = final_observations(next_obs, infos, done)
            ever |= np.asarray(infos["success"], bool)
            diverged = np.asarray(infos.get("diverged", np.zeros(num_envs, bool)), bool)
            for i in range(num_envs):
                pending[i].append(
                    (obs[i], actions[i], rewards[i] * reward_scale, real_next[i], diverged[i])
                )
                if done[i]:
                    if (ever[i] or not success_only) and not diverged[i]:
                        kept.extend(pending[i])
                        count += len(pending[i])
                        bar.update(len(pending[i]))
                    pending[i], ever[i] = [], False
            obs = next_obs
    finally:
        bar.close()
        venv.close()
    kept = kept[:transitions]
    columns = list(zip(*kept, strict=True))
    transform = transform or (lambda states: states)
    return {
        "observations": torch.as_tensor(transform(np.stack(columns[0])), dtype=torch.float32),
        "actions": torch.as_tensor(np.stack(columns[1]), dtype=torch.float32),
        "rewards": torch.as_tensor(np.array(columns[2])[:, None], dtype=torch.float32),
        "next_observations": torch.as_tensor(transform(np.stack(columns[3])), dtype=torch.float32),
        "terminated": torch.as_tensor(np.array(columns[4])[:, None], dtype=torch.bool),
    }


def behaviour_clone_start(agent: SACfD, demos: dict, steps: int, seed: int) -> float:
    """Fit ``agent``'s actor to the demonstrations: the observation scaler to their statistics,
    the mean to their actions (``steps`` Adam steps of mean squared error, batch
    ``batch_size``), then its spread to what the mean leaves, per action dimension, for every
    state (the log-std head's weights zeroed, its bias the log of the residual's RMS), so that
    SAC's first samples explore around the demonstrations rather than at a random width.
    Returns the mean squared error over the demonstrations.  (A joint maximum-likelihood fit of
    mean and spread fits the mean worse: it widens the spread where the actions are hard to
    fit, and a DAgger warm start fitted that way failed closed loop.)"""
    generator = torch.Generator().manual_seed(seed)
    obs, actions = demos["observations"], demos["actions"]
    agent._observation_preprocessor(obs, train=True)  # the scaler's statistics
    optimizer = torch.optim.Adam(agent.policy.parameters(), lr=agent.sacfd.learning_rate)

    def means(rows) -> torch.Tensor:
        inputs = {"observations": agent._observation_preprocessor(obs[rows]), "states": None}
        return agent.policy.act(inputs, role="policy")[1]["mean_actions"]

    for _ in range(steps):
        rows = torch.randint(len(obs), (agent.cfg.batch_size,), generator=generator)
        loss = F.mse_loss(means(rows), actions[rows])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    with torch.no_grad():
        squared = torch.cat(
            [(means(rows) - actions[rows]) ** 2 for rows in torch.arange(len(obs)).split(4096)]
        )
        head = agent.policy.log_std_head
        head.weight.zero_()
        head.bias.copy_(squared.mean(0).sqrt().clamp(min=math.exp(MIN_LOG_STD)).log())
    return float(squared.mean())


def dagger_start(
    agent: SACfD, task: str, env_kwargs: dict, cfg: SACfDConfig, transform, progress: bool
) -> list[dict]:
    """A DAgger warm start of ``agent``'s actor: ``cfg.dagger_init_iterations`` waves of
    rl/dagger.py's ``run_wave`` on ``cfg.dagger_init_envs`` new environments (the expert's
    action with probability 0.5 ** k, else the actor's mean; the reactive expert labels every
    state), each followed by ``cfg.dagger_init_epochs`` passes of ``behaviour_clone_start``
    over all labels so far, then a last wave of the actor alone, fitted too.  Returns one
    record per wave: beta, its success rates, the labels so far, the fit's mean squared
    error."""
    import wirecraft
    from wirecraft.experts.reactive import REACTIVE_EXPERTS
    from wirecraft.rl.dagger import run_wave

    venv = wirecraft.make_vec(
        task,
        cfg.dagger_init_envs,
        threads=cfg.threads,
        **env_kwargs,
        diagnostics=False,
        sync_envs=False,
    )
    expert = REACTIVE_EXPERTS.get(task)(venv)
    state_dim = int(venv.single_observation_space.shape[0])
    learner = SACPolicy(
        agent.policy, agent._observation_preprocessor, expert.CONTROL, state_dim, transform
    )
    rng = np.random.default_rng(cfg.seed)
    waves = [0.5**k for k in range(cfg.dagger_init_iterations)] + [0.0]
    observations, labels, history = [], [], []
    try:
        for k, beta in enumerate(waves):
            wave = run_wave(venv, expert, learner.act, beta, cfg.seed + 20_000 + k, rng)
            states = wave["states"].reshape(-1, wave["states"].shape[-1])
            observations.append(torch.as_tensor(transform(states), dtype=torch.float32))
            labels.append(torch.as_tensor(wave["labels"].reshape(len(states), -1)).float())
            data = {"observations": torch.cat(observations), "actions": torch.cat(labels)}
            steps = math.ceil(cfg.dagger_init_epochs * len(data["actions"]) / cfg.batch_size)
            mse = behaviour_clone_start(agent, data, steps, cfg.seed + k)
            record = {"wave": k, "beta": beta, **wave["rates"], "labels": len(data["actions"])}
            history.append({**record, "mse": mse})
            if progress:
                from tqdm import tqdm

                tqdm.write(f"DAgger wave {k}: {history[-1]}")
    finally:
        venv.close()
    return history


# -- training ------------------------------------------------------------------------------------
def train_sacfd(
    cfg: SACfDConfig,
    task: str,
    env_kwargs: dict,
    run_dir: Path,
    *,
    total_steps: int,
    checkpoint: Path | None,
    start_env_steps: int,
    clock: WallClock,
    on_checkpoint: Callable[[Path, int, dict], None],
    progress: bool = True,
) -> dict:
    """Train (or resume) SACfD until ``total_steps`` env steps; returns a summary."""
    from skrl.envs.wrappers.torch import wrap_env
    from skrl.utils import set_seed
    from tqdm import tqdm

    import wirecraft

    run_dir = Path(run_dir)
    n = cfg.num_envs
    start = start_env_steps // n  # vector steps already done
    total = math.ceil(total_steps / n)
    set_seed(cfg.seed + start)  # a resumed run starts new episodes, not the first ones again

    transform = inputs_transform(cfg, task)
    demo_file = run_dir / "demos.pt"
    if demo_file.exists():
        demos = torch.load(demo_file, weights_only=True)
    else:
        demos = collect_demonstrations(
            task,
            env_kwargs,
            cfg.demo_transitions,
            num_envs=n,
            seed=cfg.seed + 10_000,
            reward_scale=cfg.reward_scale,
            threads=cfg.threads,
            success_only=cfg.demo_success_only,
            progress=progress,
            kind=cfg.demo_expert,
            transform=transform,
        )
        torch.save(demos, demo_file)

    venv = wirecraft.make_vec(
        task, n, threads=cfg.threads, **env_kwargs, diagnostics=False, sync_envs=False
    )
    state_dim = int(venv.single_observation_space.shape[0])
    labeller = expert_labeller(task, venv, state_dim) if cfg.bc_states == "replay" else None
    width = int(demos["observations"].shape[1])
    env = wrap_env(TransformedInputs(venv, transform, width), wrapper="gymnasium", verbose=False)
    obs_space, act_space = env.observation_space, env.action_space
    demo_memory = _memory(len(demos["observations"]), 1, obs_space, act_space, replacement=True)
    demo_memory.add_samples(**demos)
    memory = _memory(
        cfg.replay_per_env,
        n,
        obs_space,
        act_space,
        cls=DemoMixingMemory,
        demos=demo_memory,
        demo_ratio=cfg.demo_ratio,
    )
    steps_done = {"env": start_env_steps}

    def checkpoint_written(path: Path, timestep: int) -> None:
        on_checkpoint(path, timestep * n, {"env_steps": timestep * n, "wall_time_s": clock()})

    agent = SACfD(
        models=make_models(obs_space, act_space, cfg),
        memory=memory,
        observation_space=obs_space,
        action_space=act_space,
        device="cpu",
        cfg=agent_config(cfg, obs_space, run_dir),
        demo_memory=demo_memory,
        sacfd=cfg,
        num_envs=n,
        on_checkpoint=checkpoint_written,
        labeller=labeller,
    )
    if checkpoint is not None:
        agent.load(str(checkpoint))
        # the replay buffer is not saved: warm up again before updating
        agent.cfg.learning_starts = start + math.ceil(cfg.warmup_steps / n)
    else:
        if cfg.bc_init_steps:
            mse = behaviour_clone_start(agent, demos, cfg.bc_init_steps, cfg.seed)
            if progress:
                tqdm.write(f"behaviour-cloned start: {cfg.bc_init_steps} steps, MSE {mse:.4f}")
        if cfg.dagger_init_iterations:
            history = dagger_start(agent, task, env_kwargs, cfg, transform, progress)
            (run_dir / "dagger_start.json").write_text(json.dumps(history, indent=1) + "\n")
    agent.init()
    agent.enable_training_mode(True)

    table = ProgressTable(run_dir / "progress.csv")
    table.drop_from(start + 1)  # rows are numbered by vector steps done
    tracker = EpisodeTracker(n)
    records: list[dict] = []
    log_every = max(1, math.ceil(cfg.log_every_steps / n))
    period_start = (clock(), start_env_steps)
    obs, _ = env.reset()
    last_written = None
    bar = tqdm(
        total=total_steps, initial=start * n, desc="sacfd", unit="step", disable=not progress
    )
    try:
        for t in range(start, total):
            agent.pre_interaction(timestep=t, timesteps=total)
            with torch.no_grad():
                actions, _ = agent.act(obs, None, timestep=t, timesteps=total)
                next_obs, rewards, terminated, truncated, infos = env.step(actions)
                agent.record_transition(
                    observations=obs,
                    states=None,
                    actions=actions,
                    rewards=rewards,
                    next_observations=next_obs,
                    next_states=None,
                    terminated=terminated,
                    truncated=truncated,
                    infos=infos,
                    timestep=t,
                    timesteps=total,
                )
            records += tracker.step(
                rewards.view(-1).numpy(),
                terminated.view(-1).numpy(),
                truncated.view(-1).numpy(),
                infos,
            )
            agent.post_interaction(timestep=t, timesteps=total)
            if agent.checkpoint_interval > 0 and not (t + 1) % agent.checkpoint_interval:
                last_written = t + 1
            obs = next_obs
            steps_done["env"] = (t + 1) * n
            bar.update(n)
            if not (t + 1) % log_every or t + 1 == total:
                now = clock()
                rate = (steps_done["env"] - period_start[1]) / max(now - period_start[0], 1e-9)
                row = {
                    "iteration": t + 1,
                    "env_steps": steps_done["env"],
                    "wall_time_s": now,
                    "env_steps_per_s": rate,
                    **summarize(records),
                }
                table.append(row)
                bar.set_postfix(success=row["mean_success"], bc=agent.last_bc_loss)
                records, period_start = [], (now, steps_done["env"])
        if last_written != total:
            agent.write_checkpoint(timestep=total, timesteps=total)
    except KeyboardInterrupt:
        done = steps_done["env"] // n
        if done > start and last_written != done:
            agent.write_checkpoint(timestep=done, timesteps=total)
        raise
    finally:
        bar.close()
        venv.close()
        if getattr(agent, "writer", None) is not None:
            agent.writer.close()
    return {"env_steps": steps_done["env"], "vector_steps": total}


# -- policy for evaluation -----------------------------------------------------------------------
class SACPolicy:
    """A trained SACfD actor: deterministic (mean) actions from numpy observations."""

    def __init__(
        self,
        actor: GaussianActor,
        scaler,
        control: str,
        obs_dim: int,
        transform: Callable[[np.ndarray], np.ndarray],
    ) -> None:
        self.actor = actor.eval()
        self.transform = transform
        self.scaler = scaler
        self.control = control
        self.obs_dim = obs_dim
        self.action_dim = actor.num_actions

    def reset(self, env_ids=None) -> None:
        del env_ids

    def act(self, obs) -> np.ndarray:
        obs = self.transform(state_batch(obs, self.obs_dim))
        with torch.no_grad():
            x = torch.as_tensor(obs, dtype=torch.float32)
            if self.scaler is not None:
                x = self.scaler(x)
            _, outputs = self.actor.act({"observations": x, "states": None}, role="policy")
            actions = outputs["mean_actions"].numpy().astype(np.float64)
        return np.clip(actions, -1.0, 1.0)


def load_sac_policy(run: dict, checkpoint: Path) -> SACPolicy:
    import gymnasium as gym
    from skrl.resources.preprocessors.torch import RunningStandardScaler

    from wirecraft.rl.config import config_from_dict
    from wirecraft.rl.features import actor_input_dim

    cfg = config_from_dict("sacfd", run["config"])
    obs_dim, action_dim = int(run["obs"]["dim"]), int(run["action_dim"])
    width = actor_input_dim(cfg.inputs, obs_dim)
    obs_space = gym.spaces.Box(-np.inf, np.inf, (width,), np.float64)
    act_space = gym.spaces.Box(-1.0, 1.0, (action_dim,), np.float32)
    actor = GaussianActor(obs_space, act_space, cfg.hidden_dims, cfg.activation, cfg.max_log_std)
    saved = torch.load(checkpoint, map_location="cpu", weights_only=False)
    actor.load_state_dict(saved["policy"])
    scaler = None
    if "observation_preprocessor" in saved:
        scaler = RunningStandardScaler(obs_space, device="cpu")
        scaler.load_state_dict(saved["observation_preprocessor"])
        scaler.eval()
    return SACPolicy(actor, scaler, run["control"], obs_dim, inputs_transform(cfg, run["task"]))
