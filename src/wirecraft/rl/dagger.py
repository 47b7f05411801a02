"""A DAgger warm start of state PPO from a task's reactive expert (``--set
dagger_init_iterations=K``; ``experts.reactive.REACTIVE_EXPERTS``).

Behaviour cloning of an expert's own episodes fails closed loop: the clone drifts into states the
expert never visited (docs/baselines.md).  DAgger (Ross et al., 2011) labels the learner's own
states instead.  Before PPO's first iteration, wave ``k`` (k = 0 ... K-1) runs one episode in
every training environment, each step executing the expert's action with probability 0.5 ** k,
else the actor's mean; the task's reactive expert, whose action is a function of the state
alone, labels every state; the actor is then fitted to all labels so far (warm start).  A last
wave runs the actor alone (its success rates are the warm start's own figures), is labelled too,
and the final fit also fits the critic to the discounted returns of all the waves, so that PPO's
first updates meet a value function that knows the actor's behaviour.

PPO from such a start keeps the expert's success for a few dozen iterations and then loses it
(docs/baselines.md).  ``auxiliary_dagger`` (``--set dagger_aux_lr=...``) keeps labelling during
PPO: after every update, the expert labels that iteration's rollout states and the actor takes
one pass of regression steps toward the labels, with its own optimiser, at a learning rate that
decays by ``dagger_aux_decay`` per iteration (an annealed imitation term, as SACfD's
behaviour-cloning loss).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from wirecraft.experts.reactive import REACTIVE_EXPERTS
from wirecraft.rl.common import EPISODE_FLAGS


def check_dagger_task(
    task: str, control: str, options: str = "dagger_init_iterations and dagger_aux_lr"
) -> None:
    """A ValueError (naming the ``options`` that need it) unless a reactive expert can label
    ``task`` under ``control``."""
    expert = REACTIVE_EXPERTS.get(task) if task in REACTIVE_EXPERTS else None
    if expert is None or control != expert.CONTROL:
        needs = " or ".join(
            f"the {name} task with control={REACTIVE_EXPERTS.get(name).CONTROL!r}"
            for name in REACTIVE_EXPERTS
        )
        raise ValueError(
            f"{options} need {needs} (a reactive expert's), got task={task!r}, control={control!r}"
        )


def discounted_returns(rewards: np.ndarray, dones: np.ndarray, gamma: float) -> np.ndarray:
    """(T, N) returns of (T, N) rewards; an episode ends where ``dones`` (nothing bootstrapped
    past the end of the wave)."""
    returns = np.zeros_like(rewards, dtype=float)
    running = np.zeros(rewards.shape[1])
    for t in range(len(rewards) - 1, -1, -1):
        running = rewards[t] + gamma * running * (1.0 - dones[t])
        returns[t] = running
    return returns


def actor_means(actor, obs_groups: Callable, obs: np.ndarray) -> np.ndarray:
    """The actor's deterministic (mean) actions on numpy states."""
    import torch
    from tensordict import TensorDict

    from wirecraft.rl.ppo import tensor_groups

    with torch.no_grad():
        td = TensorDict(tensor_groups(obs_groups(obs)), batch_size=[len(obs)])
        return np.clip(actor(td).numpy().astype(np.float64), -1.0, 1.0)


def run_wave(
    venv, expert, act: Callable[[np.ndarray], np.ndarray], beta: float, seed: int, rng
) -> dict:
    """One episode in every environment of ``venv``: the expert's action with probability
    ``beta``, else the learner's (``act``: numpy states to its deterministic actions);
    returns the states, labels, (T, N) rewards and dones, and the wave's rate of each success
    flag the task raises (at some step; ``success``, and for insertion ``reach`` and
    ``insert``)."""
    obs, _ = venv.reset(seed=seed)
    n, steps = venv.num_envs, int(venv.unwrapped.envs[0].max_steps)
    states, labels, rewards, dones = [], [], [], []
    raised: dict[str, np.ndarray] = {}
    for _ in range(steps):
        label = expert.act(obs)
        action = label.copy()
        if beta < 1.0:
            learner = rng.random(n) >= beta
            action[learner] = act(obs[learner])
        states.append(obs.copy())
        labels.append(label)
        obs, reward, terminated, truncated, info = venv.step(action)
        rewards.append(np.asarray(reward, float))
        dones.append(np.asarray(terminated | truncated, float))
        for flag in EPISODE_FLAGS:
            if flag in info:
                seen = raised.setdefault(flag, np.zeros(n, bool))
                seen |= np.asarray(info[flag], bool)
    return {
        "states": np.stack(states),
        "labels": np.stack(labels),
        "rewards": np.stack(rewards),
        "dones": np.stack(dones),
        "rates": {
            flag.removesuffix("_success"): float(seen.mean()) for flag, seen in raised.items()
        },
    }


def dagger_init(
    runner,
    venv,
    *,
    iterations: int,
    epochs: int,
    gamma: float,
    reward_scale: float,
    seed: int,
    obs_groups: Callable,
    progress: bool = True,
    save_dir: Path | None = None,
) -> list[dict]:
    """Warm-start ``runner``'s actor (and, at the end, its critic) by DAgger on ``venv`` (module
    docstring); returns one record per wave: beta, the wave's success rates (``run_wave``), the
    labels so far and the fit's last actor loss.  With ``save_dir``, each finished wave is saved
    there (``WarmStartProgress``) and a warm start that finds saved waves continues after them,
    as if it had not stopped."""
    import torch

    from wirecraft.rl.ppo import behaviour_clone_init

    expert = REACTIVE_EXPERTS.get(venv.unwrapped.envs[0].task.name)(venv)
    actor = runner.alg.actor
    rng = np.random.default_rng(seed)
    waves = [0.5**k for k in range(iterations)] + [0.0]  # the last: the actor alone
    saved = WarmStartProgress(save_dir, waves, seed) if save_dir is not None else None
    states, labels, returns, history = saved.load(runner, rng) if saved else ([], [], [], [])
    bar = tqdm(
        total=len(waves), desc="DAgger warm start", disable=not progress, initial=len(history)
    )
    for k in range(len(history), len(waves)):
        beta = waves[k]
        actor.eval()
        wave = run_wave(
            venv, expert, lambda obs: actor_means(actor, obs_groups, obs), beta, seed + k, rng
        )
        # float32: what the fits see (and what a resumed warm start must see too)
        states.append(wave["states"].reshape(-1, wave["states"].shape[-1]).astype(np.float32))
        labels.append(wave["labels"].reshape(-1, wave["labels"].shape[-1]).astype(np.float32))
        scaled = wave["rewards"] * reward_scale
        returns.append(
            discounted_returns(scaled, wave["dones"], gamma).reshape(-1).astype(np.float32)
        )
        last = k == len(waves) - 1
        demos = {
            "observations": torch.as_tensor(np.concatenate(states)),
            "actions": torch.as_tensor(np.concatenate(labels)),
            "returns": torch.as_tensor(np.concatenate(returns))[:, None],
        }
        losses = behaviour_clone_init(
            runner,
            demos,
            episode_steps=1,
            gamma=gamma,
            epochs=epochs,
            seed=seed + k,
            batch_size=1024,
            progress=False,
            obs_groups=obs_groups,
            fit_critic=last,
        )
        record = {
            "wave": k,
            "beta": beta,
            **wave["rates"],
            "labels": len(demos["actions"]),
            "actor_loss": losses["actor"],
        }
        if last:
            record["critic_loss"] = losses["critic"]
        history.append(record)
        if saved:
            saved.save(runner, rng, history, states[-1], labels[-1], returns[-1])
        bar.update()
        if progress:
            tqdm.write(f"DAgger wave {k}: {record}")
    bar.close()
    return history


class WarmStartProgress:
    """A DAgger warm start's finished waves in ``folder``: each wave's states, labels and
    returns (``wave_K.npz``, written once), and after each wave the actor, the critic, the
    random generators and the records (``state.pt``, replaced whole), so that a run stopped
    mid-warm-start continues where it was.  The waves' data (about 25 MB a wave for 256
    insertion environments) is deleted once the last wave is fitted; ``state.pt`` (the size of
    a checkpoint) stays, so that a run stopped before PPO's first checkpoint starts PPO from the
    finished warm start."""

    def __init__(self, folder: Path, waves: list[float], seed: int) -> None:
        self.folder, self.settings = Path(folder), {"waves": list(waves), "seed": seed}

    def load(self, runner, rng) -> tuple[list, list, list, list]:
        import torch

        path = self.folder / "state.pt"
        if not path.exists():
            return [], [], [], []
        saved = torch.load(path, weights_only=False)
        if saved["settings"] != self.settings:
            raise ValueError(
                f"{path} holds a warm start with {saved['settings']}, not {self.settings}"
            )
        runner.alg.actor.load_state_dict(saved["actor"])
        runner.alg.critic.load_state_dict(saved["critic"])
        rng.bit_generator.state = saved["numpy_rng"]
        torch.set_rng_state(saved["torch_rng"])
        history = saved["history"]
        if len(history) == len(self.settings["waves"]):
            return [], [], [], history  # finished: the fits need no data
        data: dict[str, list] = {"states": [], "labels": [], "returns": []}
        for k in range(len(history)):
            with np.load(self.folder / f"wave_{k}.npz") as wave:
                for name, arrays in data.items():
                    arrays.append(wave[name])
        return data["states"], data["labels"], data["returns"], history

    def save(self, runner, rng, history, states, labels, returns) -> None:
        """Save the wave that ``history``'s last record describes (its data, unless it is the
        last wave) and the state after it."""
        import torch

        from wirecraft.cli_args import atomic_path

        k = len(history) - 1
        done = len(history) == len(self.settings["waves"])
        if not done:
            with atomic_path(self.folder / f"wave_{k}.npz") as tmp:
                np.savez(tmp, states=states, labels=labels, returns=returns)
        state = {
            "settings": self.settings,
            "history": history,
            "actor": runner.alg.actor.state_dict(),
            "critic": runner.alg.critic.state_dict(),
            "numpy_rng": rng.bit_generator.state,
            "torch_rng": torch.get_rng_state(),
        }
        with atomic_path(self.folder / "state.pt") as tmp:
            torch.save(state, tmp)
        if done:
            for wave in self.folder.glob("wave_*.npz"):
                wave.unlink()


@contextlib.contextmanager
def auxiliary_dagger(
    runner, venv, *, learning_rate: float, decay: float, seed: int, batch_size: int = 4096
):
    """Within: each PPO update of ``runner`` is followed by one DAgger pass of the actor over
    the update's rollout (module docstring); the pass's mean squared error to the labels is
    logged with the update's losses as ``Loss/dagger`` (and its learning rate as
    ``Loss/dagger_lr``)."""
    import torch

    expert = REACTIVE_EXPERTS.get(venv.unwrapped.envs[0].task.name)(venv)
    alg = runner.alg
    optimizer = torch.optim.Adam(alg.actor.parameters(), lr=learning_rate)
    generator = torch.Generator().manual_seed(seed)
    update = alg.update

    def update_then_imitate(*args, **kwargs):
        # the update clears the storage: take the rollout first
        observations = alg.storage.observations.flatten(0, 1).clone()
        losses = update(*args, **kwargs)
        states = observations["policy"].numpy().astype(np.float64)
        labels = torch.as_tensor(expert.act(states), dtype=torch.float32)
        lr = learning_rate * decay ** max(runner.current_learning_iteration, 0)
        for group in optimizer.param_groups:
            group["lr"] = lr
        alg.actor.train()
        order = torch.randperm(len(labels), generator=generator)
        total, batches = 0.0, 0
        for start in range(0, len(labels), batch_size):
            idx = order[start : start + batch_size]
            loss = torch.nn.functional.mse_loss(alg.actor(observations[idx]), labels[idx])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total, batches = total + float(loss.detach()), batches + 1
        return {**losses, "dagger": total / batches, "dagger_lr": lr}

    alg.update = update_then_imitate
    try:
        yield
    finally:
        alg.update = update
