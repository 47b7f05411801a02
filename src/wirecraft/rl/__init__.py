"""Reinforcement-learning baselines: state PPO (rsl-rl), SACfD (skrl) and vision PPO.

``train(...)`` starts or resumes a run in a run directory; ``load_policy(path, env)`` loads a
trained policy (``control``, ``reset(env_ids=None)``, ``act(obs) -> (N, action_dim)``).
Nothing heavy is imported until one of them is called.
"""

from __future__ import annotations

from wirecraft.rl.common import RUN_FILE

ALGORITHMS = ("ppo", "sacfd", "vision-ppo")


def train(*args, **kwargs):
    from wirecraft.rl.training import train as _train

    return _train(*args, **kwargs)


train.__doc__ = "See ``wirecraft.rl.training.train``."


def load_policy(path, env=None):
    """The policy of an RL run directory (or of a checkpoint inside one); see
    ``wirecraft.rl.training.load_policy``."""
    from wirecraft.rl.training import load_policy as _load

    return _load(path, env)


def policy_env_kwargs(path) -> dict:
    """The environment keywords a policy of the run at ``path`` needs: ``control``,
    ``obs_mode`` (``state``, or ``state_rgb`` for vision) and, for vision, ``image_size``."""
    from wirecraft.rl.common import find_run_dir, read_run

    run = read_run(find_run_dir(path))
    kwargs = {"control": run["control"], "obs_mode": run["obs"]["kind"]}
    if "image_size" in run["obs"]:
        kwargs["image_size"] = run["obs"]["image_size"]
    return kwargs


__all__ = ["ALGORITHMS", "RUN_FILE", "load_policy", "policy_env_kwargs", "train"]
