"""Training episodes that start from the scripted expert's states (PPO ``expert_starts``).

Exploration is what the insertion PPO runs lacked: in 10.7M env steps from fresh resets the
policy never carried the plug to the port (docs/baselines.md), so the reward for inserting it
was never seen.  Starting a fraction of the training episodes part-way through a successful
expert episode (a uniformly chosen recorded step: plug on the table, in the gripper, lifted,
at the port) puts the policy where those rewards are.  Evaluation always starts fresh.

- ``record_expert_states`` runs the task's expert in a vector env and keeps
  ``WireCraftEnv.get_state`` snapshots (physics, controller targets, task trackers, step
  count) every ``stride`` steps of the episodes in which it succeeded, up to the first success;
- ``ExpertStarts`` wraps the training vector env: each episode that ends is followed, with
  probability ``fraction``, by one that starts from a random snapshot (with that snapshot's step
  count, so its time limit is the expert's remaining time).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from gymnasium.vector import VectorWrapper

STATES_FILE = "expert_starts.pt"


def record_expert_states(
    task: str,
    env_kwargs: dict,
    episodes: int,
    *,
    num_envs: int,
    seed: int,
    stride: int,
    threads: int = 0,
    progress: bool = True,
) -> list[dict]:
    """Snapshots of ``episodes`` successful expert episodes, every ``stride`` control steps
    from the first up to (not including) the first successful step.  Raises if the expert
    cannot drive this control mode or succeeds in fewer than half of its episodes."""
    from tqdm import tqdm

    from wirecraft.rl.common import expert_vec_env

    expert, venv = expert_vec_env(
        task, env_kwargs, "expert starts", num_envs, seed, threads=threads, diagnostics=False
    )
    obs, _ = venv.reset(seed=seed)
    expert.reset()
    pending: list[list[dict]] = [[] for _ in range(num_envs)]
    succeeded = np.zeros(num_envs, bool)
    kept: list[dict] = []
    kept_episodes = attempts = 0
    bar = tqdm(total=episodes, desc="expert starts", unit="episode", disable=not progress)
    try:
        while kept_episodes < episodes:
            for i, env in enumerate(venv.envs):
                if not succeeded[i] and env.elapsed_steps % stride == 0:
                    pending[i].append(env.get_state())
            obs, _, terminated, truncated, infos = venv.step(expert.act(obs))
            final = infos.get("final_info", {})
            done = terminated | truncated
            success = np.where(done, final.get("success", False), infos["success"])
            succeeded |= np.asarray(success, bool)
            for i in np.flatnonzero(done):
                attempts += 1
                if succeeded[i] and not final["diverged"][i] and kept_episodes < episodes:
                    kept.extend(pending[i])
                    kept_episodes += 1
                    bar.update(1)
                pending[i], succeeded[i] = [], False
            if attempts >= 2 * episodes + num_envs and kept_episodes < attempts / 2:
                raise RuntimeError(
                    f"the {task} expert succeeded in {kept_episodes} of {attempts} episodes: "
                    "too few for expert starts"
                )
    finally:
        bar.close()
        venv.close()
    return kept


def load_or_record(run_dir: Path, record) -> list[dict]:
    """The run's snapshots from ``run_dir/expert_starts.pt``, recorded (``record()``) and
    saved there the first time, so that a resumed run starts from the same states."""
    import torch

    path = Path(run_dir) / STATES_FILE
    if path.is_file():
        return torch.load(path, weights_only=False)
    states = record()
    tmp = path.with_name(path.name + ".tmp")
    torch.save(states, tmp)
    tmp.replace(path)
    return states


class ExpertStarts(VectorWrapper):
    """A WireCraft vector env whose finished episodes restart, with probability ``fraction``,
    from one of ``states`` instead of a fresh reset.  ``infos["expert_start"]`` marks the
    environments that did in this step (reset: on ``reset``)."""

    def __init__(self, env, states: list[dict], fraction: float, seed: int) -> None:
        super().__init__(env)
        if not 0.0 <= fraction <= 1.0:
            raise ValueError(f"ExpertStarts: fraction must be in [0, 1], got {fraction!r}")
        if fraction > 0 and not states:
            raise ValueError("ExpertStarts: no states to start from")
        self.states = states
        self.fraction = float(fraction)
        self.rng = np.random.default_rng(seed)

    def _restart(self, obs, ended: np.ndarray, infos: dict):
        chosen = ended[self.rng.random(ended.size) < self.fraction]
        flags = np.zeros(self.num_envs, bool)
        flags[chosen] = True
        infos["expert_start"] = flags
        if chosen.size:
            picks = self.rng.integers(len(self.states), size=chosen.size)
            obs[chosen] = self.env.set_states(chosen, [self.states[k] for k in picks])
        return obs, infos

    def reset(self, *, seed=None, options=None):
        obs, infos = self.env.reset(seed=seed, options=options)
        mask = np.ones(self.num_envs, bool)
        if options and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"], bool)
        return self._restart(obs, np.flatnonzero(mask), dict(infos))

    def step(self, actions):
        obs, rewards, terminated, truncated, infos = self.env.step(actions)
        obs, infos = self._restart(obs, np.flatnonzero(terminated | truncated), infos)
        return obs, rewards, terminated, truncated, infos
