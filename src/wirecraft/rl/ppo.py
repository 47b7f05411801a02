"""State PPO through rsl-rl (5.5): an ``rsl_rl.env.VecEnv`` adapter over ``wirecraft.make_vec``,
the runner configuration, a runner that keeps the run directory up to date, and the policy
loaded back for evaluation.

Adapter conventions (what rsl-rl expects):
- observations: a ``TensorDict`` of float32 groups, batch size (num_envs,); state PPO uses one
  group ``policy`` (the 42-d privileged state) for actor and critic;
- ``dones = terminated | truncated`` (the vector env already reset those environments: SAME_STEP);
- ``extras["time_outs"]``: episodes cut by the time limit, so that PPO bootstraps them; a
  diverged episode (rolled back by the environment) is not a time-out and is not bootstrapped;
- ``extras["log"]``: per finished episode, its final success flags, whether they were ever
  reached and its return, logged by rsl-rl as ``Episode/...``;
- rewards are the environment's weighted sum times ``reward_scale``.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from wirecraft.rl.common import (
    CHECKPOINT_DIR,
    PROGRESS_FIELDS,
    EpisodeTracker,
    ProgressTable,
    WallClock,
    state_batch,
)
from wirecraft.rl.config import PPOConfig


def _torch():
    import torch

    return torch


# Logged again over the episodes that started from a fresh reset, when some started from an
# expert's state (``Episode/fresh/...``).
FRESH_KEYS = ("return", "reach_success_any", "insert_success_any", "insert_success")


def state_observations(obs) -> dict:
    """The observation groups of state PPO: the privileged state for actor and critic."""
    return {"policy": obs}


def observation_groups(actor_inputs: str = "state", task: str | None = None) -> Callable:
    """The observation groups of state PPO on ``task`` whose actor sees ``actor_inputs``
    (rl/features.py): ``policy``, the state (the critic's, and the actor's for "state"), and
    ``actor``, the actor's inputs computed from it otherwise."""
    from wirecraft.rl.features import actor_transform

    transform = actor_transform(actor_inputs, task)
    if transform is None:
        return state_observations

    def groups(obs) -> dict:
        state = obs.numpy() if hasattr(obs, "numpy") else np.asarray(obs)
        return {"policy": obs, "actor": transform(state)}

    return groups


def actor_groups(actor_inputs: str = "state") -> tuple[str, ...]:
    """The observation group the actor reads (``observation_groups``)."""
    return ("policy",) if actor_inputs == "state" else ("actor",)


def tensor_groups(groups: dict) -> dict:
    """``observation_groups``' output as float32 tensors."""
    torch = _torch()
    return {
        k: v.float() if torch.is_tensor(v) else torch.as_tensor(np.asarray(v)).float()
        for k, v in groups.items()
    }


def make_vec_env_adapter(venv, *, reward_scale: float, seed: int, obs_groups: Callable = None):
    """An ``rsl_rl.env.VecEnv`` over a WireCraft vector env (built lazily: rsl-rl imports
    torch)."""
    from rsl_rl.env import VecEnv
    from tensordict import TensorDict

    torch = _torch()
    group_fn = obs_groups or state_observations

    class WireCraftRslEnv(VecEnv):
        def __init__(self) -> None:
            self.venv = venv
            self.num_envs = venv.num_envs
            self.num_actions = int(venv.single_action_space.shape[0])
            self.max_episode_length = int(venv.unwrapped.envs[0].max_steps)
            self.episode_length_buf = torch.zeros(self.num_envs, dtype=torch.long)
            self.device = "cpu"
            self.cfg = {"reward_scale": reward_scale}
            self.reward_scale = reward_scale
            self.tracker = EpisodeTracker(self.num_envs)
            self.env_steps = 0
            obs, infos = venv.reset(seed=seed)
            self.tracker.started(infos)
            self._obs = self._tensordict(obs)

        def _tensordict(self, obs):
            return TensorDict(tensor_groups(group_fn(obs)), batch_size=[self.num_envs])

        def get_observations(self):
            return self._obs

        def step(self, actions):
            act = actions.detach().cpu().numpy().astype(np.float64)
            # rsl-rl samples an unbounded Gaussian; the controller clips to [-1, 1] anyway.
            obs, rewards, terminated, truncated, infos = venv.step(np.clip(act, -1.0, 1.0))
            self.env_steps += self.num_envs
            diverged = np.asarray(infos.get("diverged", np.zeros(self.num_envs, bool)), bool)
            dones = terminated | truncated
            time_outs = truncated & ~terminated & ~diverged
            self.episode_length_buf += 1
            self.episode_length_buf[torch.as_tensor(dones)] = 0
            self._obs = self._tensordict(obs)
            extras = {"time_outs": torch.as_tensor(time_outs, dtype=torch.float32)}
            records = self.tracker.step(rewards, terminated, truncated, infos)
            if records:
                extras["log"] = {
                    f"Episode/{key}": torch.tensor([r[key] for r in records], dtype=torch.float32)
                    for key in records[0]
                }
                # With expert starts, the honest training curve is that of fresh episodes.
                fresh = [r for r in records if r.get("expert_start") == 0.0]
                for key in FRESH_KEYS if fresh else ():
                    values = torch.tensor([r[key] for r in fresh], dtype=torch.float32)
                    extras["log"][f"Episode/fresh/{key}"] = values
            return (
                self._obs,
                torch.as_tensor(rewards * self.reward_scale, dtype=torch.float32),
                torch.as_tensor(dones, dtype=torch.long),
                extras,
            )

        def close(self) -> None:
            venv.close()

    return WireCraftRslEnv()


def runner_config(
    cfg: PPOConfig,
    *,
    actor_groups=("policy",),
    critic_groups=("policy",),
    actor_normalization: bool | None = None,
) -> dict:
    """The rsl-rl 5.5 training configuration for ``cfg`` (``actor_normalization``: None
    follows ``cfg.obs_normalization``)."""
    if actor_normalization is None:
        actor_normalization = cfg.obs_normalization
    return {
        "num_steps_per_env": cfg.num_steps_per_env,
        "save_interval": cfg.save_interval,
        "obs_groups": {"actor": list(actor_groups), "critic": list(critic_groups)},
        "actor": {
            "class_name": "rsl_rl.models.MLPModel",
            "hidden_dims": list(cfg.actor_hidden_dims),
            "activation": cfg.activation,
            "obs_normalization": actor_normalization,
            "distribution_cfg": {
                "class_name": "rsl_rl.modules.distribution.GaussianDistribution",
                "init_std": cfg.init_std,
            },
        },
        "critic": {
            "class_name": "rsl_rl.models.MLPModel",
            "hidden_dims": list(cfg.critic_hidden_dims),
            "activation": cfg.activation,
            "obs_normalization": cfg.obs_normalization,
        },
        "algorithm": {
            "class_name": "rsl_rl.algorithms.PPO",
            "num_learning_epochs": cfg.num_learning_epochs,
            "num_mini_batches": cfg.num_mini_batches,
            "clip_param": cfg.clip_param,
            "gamma": cfg.gamma,
            "lam": cfg.lam,
            "value_loss_coef": cfg.value_loss_coef,
            "entropy_coef": cfg.entropy_coef,
            "learning_rate": cfg.learning_rate,
            "max_grad_norm": cfg.max_grad_norm,
            "schedule": cfg.schedule,
            "desired_kl": cfg.desired_kl,
        },
        "check_for_nan": True,
    }


def make_progress_writer():
    """A rsl-rl ``LogWriter`` that forwards to TensorBoard and keeps ``progress.csv``: one row
    per iteration with env steps, wall time and the episode means rsl-rl computed."""
    from rsl_rl.utils.log_writer import LogWriter
    from torch.utils.tensorboard import SummaryWriter

    class ProgressWriter(LogWriter):
        def __init__(self, log_dir: str, steps_per_iteration: int, clock: WallClock) -> None:
            self.tensorboard = SummaryWriter(log_dir=log_dir, flush_secs=10)
            self.table = ProgressTable(Path(log_dir) / "progress.csv")
            self.steps_per_iteration = steps_per_iteration
            self.clock = clock
            self.row: dict | None = None
            self.last_time: float | None = None

        def add_scalar(self, tag: str, scalar_value: float, global_step: int) -> None:
            self.tensorboard.add_scalar(tag, scalar_value, global_step)
            if tag.endswith("/time"):  # indexed by seconds, not iterations
                return
            if self.row is None or self.row["iteration"] != global_step:
                self.flush()
                now = self.clock()
                env_steps = (global_step + 1) * self.steps_per_iteration
                self.row = {"iteration": global_step, "env_steps": env_steps, "wall_time_s": now}
            if tag.startswith("Episode/"):
                self.row[f"mean_{tag.split('/', 1)[1]}"] = float(scalar_value)
            if tag == "Perf/total_fps":
                self.row["env_steps_per_s"] = float(scalar_value)

        def flush(self) -> None:
            if self.row is not None:
                row = {k: self.row.get(k, float("nan")) for k in PROGRESS_FIELDS}
                row["episodes"] = ""
                self.table.append(row)
                self.row = None

        def stop(self) -> None:
            self.flush()
            self.tensorboard.flush()
            self.tensorboard.close()

    return ProgressWriter


def make_runner(env, train_cfg: dict, run_dir: Path, *, on_save: Callable, clock: WallClock):
    """An rsl-rl ``OnPolicyRunner`` whose checkpoints go to ``run_dir/checkpoints`` and carry the
    env steps and wall time; ``on_save(path, iteration)`` follows every save."""
    from rsl_rl.runners import OnPolicyRunner

    writer_cls = make_progress_writer()
    train_cfg = dict(train_cfg)
    steps = env.num_envs * train_cfg["num_steps_per_env"]
    train_cfg["logger"] = {"class_name": writer_cls, "steps_per_iteration": steps, "clock": clock}

    class WireCraftRunner(OnPolicyRunner):
        def save(self, path: str, infos: dict | None = None) -> None:
            iteration = self.current_learning_iteration
            target = Path(run_dir) / CHECKPOINT_DIR / Path(path).name
            target.parent.mkdir(parents=True, exist_ok=True)
            infos = {
                **(infos or {}),
                "iterations_done": iteration + 1,
                "env_steps": (iteration + 1) * steps,
                "wall_time_s": clock(),
            }
            super().save(str(target), infos)
            on_save(target, iteration, infos)

    runner = WireCraftRunner(env, train_cfg, log_dir=str(run_dir), device="cpu")
    # rsl-rl would run `git status`/`git diff` on the repository around its own install (our
    # working tree, where the venv lives) and store them in the run: not wanted.
    runner.logger._store_code_state = lambda: []
    return runner


@contextlib.contextmanager
def single_threaded_rollouts(runner):
    """Within: the rollouts' policy inference runs on one torch thread, the PPO update on as
    many as torch had.  A state policy's forward pass is tiny, and torch's OpenMP workers,
    spinning after each one, take cores from MuJoCo's physics threads: on a 16-core machine,
    one torch thread made collection 1.8x faster (docs/performance.md).  The update, a large
    batch of matrix products, keeps its threads."""
    torch = _torch()
    learning_threads = torch.get_num_threads()
    update = runner.alg.update

    def update_with_threads(*args, **kwargs):
        torch.set_num_threads(learning_threads)
        try:
            return update(*args, **kwargs)
        finally:
            torch.set_num_threads(1)

    runner.alg.update = update_with_threads
    torch.set_num_threads(1)
    try:
        yield
    finally:
        runner.alg.update = update
        torch.set_num_threads(learning_threads)


def learn(runner, total_iterations: int) -> None:
    """Run rsl-rl's learning loop until ``total_iterations`` iterations are done (counting
    those of a resumed run)."""
    done = runner.current_learning_iteration
    remaining = total_iterations - done
    if remaining <= 0:
        return
    completed = done - 1  # the last iteration whose update finished
    try:
        runner.learn(num_learning_iterations=remaining)
    except KeyboardInterrupt:
        # rsl-rl sets current_learning_iteration after each update: save what is complete.
        if runner.current_learning_iteration > completed:
            it = runner.current_learning_iteration
            runner.save(os.path.join(runner.logger.log_dir, f"model_{it}.pt"))
        runner.logger.stop_logging_writer()  # flushes the last progress row
        raise


def resume(runner, checkpoint: Path) -> dict:
    """Load a checkpoint into ``runner`` (models, optimizer, normalizers); the next iteration
    is the one after the saved one."""
    infos = runner.load(str(checkpoint), map_location="cpu") or {}
    runner.current_learning_iteration = int(infos.get("iterations_done", 0))
    ProgressTable(Path(runner.logger.log_dir) / "progress.csv").drop_from(
        runner.current_learning_iteration
    )
    return infos


def behaviour_clone_init(
    runner,
    demos: dict,
    *,
    episode_steps: int,
    gamma: float,
    epochs: int,
    seed: int,
    batch_size: int = 256,
    learning_rate: float = 1e-3,
    progress: bool = True,
    obs_groups: Callable = state_observations,
    fit_critic: bool = True,
) -> dict[str, float]:
    """Warm start of a fresh PPO run from scripted-expert ``demos`` (``sacfd.
    collect_demonstrations``: whole episodes of ``episode_steps`` transitions, in order, rewards
    already scaled; or, with ``returns``, each transition's discounted return): both
    observation normalisers take the demonstrations' statistics, the actor's mean is fitted to
    the demonstrated actions and the critic to their discounted returns (MSE, on standardised
    returns), so that PPO's first updates start from the expert's behaviour and a value
    function that knows it.  Returns the last epoch's mean
    losses (the critic's in the returns' units).  ``obs_groups`` maps the states to the
    observation groups (``observation_groups``); ``fit_critic`` False leaves the critic (and
    its normaliser) alone, as DAgger's intermediate fits do."""
    from tensordict import TensorDict
    from tqdm import tqdm

    torch = _torch()
    whole = len(demos["actions"]) // episode_steps * episode_steps
    if whole == 0:
        raise ValueError(f"behaviour cloning needs at least one whole {episode_steps}-step episode")
    obs = demos["observations"][:whole]
    actions = demos["actions"][:whole]
    if "returns" in demos:  # computed by the caller (DAgger's waves)
        returns = demos["returns"][:whole].reshape(-1, 1)
    else:
        rewards = demos["rewards"][:whole, 0].reshape(-1, episode_steps)
        returns = torch.zeros_like(rewards)
        running = torch.zeros(len(rewards))
        for t in range(episode_steps - 1, -1, -1):
            running = rewards[:, t] + gamma * running
            returns[:, t] = running
        returns = returns.reshape(-1, 1)
    # Returns run to ~1e3 (a seated plug pays 1000 x reward_scale per step), far beyond what a
    # few thousand Adam steps of size ~learning_rate move a freshly initialised output to.
    # The critic is fitted to standardised returns, and its output layer then scaled back.
    centre, spread = returns.mean(), returns.std().clamp_min(1e-6)
    targets = (returns - centre) / spread
    actor, critic = runner.alg.actor, runner.alg.critic
    output = [m for m in critic.mlp.modules() if isinstance(m, torch.nn.Linear)][-1]
    everything = TensorDict(tensor_groups(obs_groups(obs)), batch_size=[whole])
    models = [actor, critic] if fit_critic else [actor]
    for model in models:
        model.train()
        model.update_normalization(everything)
    parameters = [p for model in models for p in model.parameters()]
    optimizer = torch.optim.Adam(parameters, lr=learning_rate)
    generator = torch.Generator().manual_seed(seed)
    losses = {"actor": float("nan"), "critic": float("nan")}
    for _ in tqdm(range(epochs), desc="behaviour cloning", disable=not progress):
        order = torch.randperm(whole, generator=generator)
        sums, batches = {"actor": 0.0, "critic": 0.0}, 0
        for start in range(0, whole, batch_size):
            idx = order[start : start + batch_size]
            batch = everything[idx]
            loss = actor_loss = torch.nn.functional.mse_loss(actor(batch), actions[idx])
            if fit_critic:
                critic_loss = torch.nn.functional.mse_loss(critic(batch), targets[idx])
                loss = actor_loss + critic_loss
                sums["critic"] += float(critic_loss.detach())
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            sums["actor"] += float(actor_loss.detach())
            batches += 1
        losses = {k: v / batches for k, v in sums.items()}
    if not fit_critic:
        return {"actor": losses["actor"], "critic": float("nan")}
    with torch.no_grad():
        output.weight.mul_(spread)
        output.bias.mul_(spread).add_(centre)
    losses["critic"] *= float(spread) ** 2  # in the returns' own units
    return losses


def iterations_for(cfg: PPOConfig, steps: int | None) -> int:
    """Total iterations: ``cfg.max_iterations``, or enough for ``steps`` env steps."""
    if steps is None:
        return cfg.max_iterations
    return max(1, math.ceil(steps / cfg.steps_per_iteration))


# -- policy for evaluation ---------------------------------------------------------------------
class StatePolicy:
    """A trained state PPO actor: deterministic (mean) actions from numpy state observations."""

    def __init__(
        self,
        actor,
        control: str,
        obs_dim: int,
        action_dim: int,
        actor_inputs: str = "state",
        task: str | None = None,
    ) -> None:
        self.actor = actor.eval()
        self.control = control
        self.obs_dim = obs_dim
        self.action_dim = action_dim
        self.groups = observation_groups(actor_inputs, task)

    def reset(self, env_ids=None) -> None:
        del env_ids  # a feed-forward policy has no memory

    def act(self, obs) -> np.ndarray:
        from tensordict import TensorDict

        torch = _torch()
        obs = state_batch(obs, self.obs_dim)
        with torch.no_grad():
            td = TensorDict(tensor_groups(self.groups(obs)), batch_size=[len(obs)])
            actions = self.actor(td).numpy().astype(np.float64)
        return np.clip(actions, -1.0, 1.0)


def build_actor(
    cfg: PPOConfig, obs_dim: int, action_dim: int, groups=("policy",), normalization=None
):
    """An rsl-rl actor with the architecture of ``cfg`` (weights untrained)."""
    from rsl_rl.utils import resolve_class
    from tensordict import TensorDict

    torch = _torch()
    example = TensorDict({g: torch.zeros(1, obs_dim) for g in groups}, batch_size=[1])
    train_cfg = runner_config(cfg, actor_groups=groups, actor_normalization=normalization)
    actor_cls, actor_kwargs = resolve_class(train_cfg["actor"])
    return actor_cls(example, {"actor": list(groups)}, "actor", action_dim, **actor_kwargs)


def load_state_policy(run: dict, checkpoint: Path) -> StatePolicy:
    from wirecraft.rl.config import config_from_dict

    torch = _torch()
    from wirecraft.rl.features import actor_input_dim

    cfg = config_from_dict("ppo", run["config"])
    obs_dim, action_dim = int(run["obs"]["dim"]), int(run["action_dim"])
    inputs = cfg.actor_inputs
    actor = build_actor(
        cfg, actor_input_dim(inputs, obs_dim), action_dim, groups=actor_groups(inputs)
    )
    saved = torch.load(checkpoint, map_location="cpu", weights_only=False)
    actor.load_state_dict(saved["actor_state_dict"])
    return StatePolicy(actor, run["control"], obs_dim, action_dim, inputs, run["task"])
