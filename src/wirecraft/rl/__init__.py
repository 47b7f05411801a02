"""Reinforcement-learning baselines: state PPO (rsl-rl), SACfD (skrl) and vision PPO.

``train(...)`` starts or resumes a run in a run directory; ``load_policy(path, env)`` loads a
trained policy (``control``, ``reset(env_ids=None)``, ``act(obs) -> (N, action_dim)``).
Nothing heavy is imported until one of them is called.
"""

from __future__ import annotations

from pathlib import Path

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


# What a checkpoint's number counts, by algorithm (rsl-rl names files model_<iteration>.pt,
# skrl agent_<step>.pt, a step of all its environments at once).
CHECKPOINT_UNITS = {"ppo": "PPO iterations", "vision-ppo": "PPO iterations", "sacfd": "SAC steps"}


def run_checkpoints(path) -> tuple[list[tuple[int, Path]], str]:
    """(number, file) of each checkpoint the RL run directory ``path`` recorded and still
    holds, by number, and what the number counts (``CHECKPOINT_UNITS``).  ([], "") when
    ``path`` is not an RL run directory (a checkpoint file inside one is not)."""
    from wirecraft.rl.common import read_run

    path = Path(path)
    if not (path / RUN_FILE).is_file():
        return [], ""
    run = read_run(path)
    found = []
    for rel in run.get("checkpoints", []):
        stem = Path(rel).stem
        number = stem.rpartition("_")[2]
        if number.isdigit() and (path / rel).is_file():
            found.append((int(number), path / rel))
    return sorted(found), CHECKPOINT_UNITS.get(run["algorithm"], "checkpoints")


def policy_env_kwargs(path) -> dict:
    """The environment keywords a policy of the run at ``path`` needs: ``control``,
    ``obs_mode`` (``state``, or ``state_rgb`` for vision) and, for vision, ``image_size``."""
    from wirecraft.rl.common import find_run_dir, read_run

    run = read_run(find_run_dir(path))
    kwargs = {"control": run["control"], "obs_mode": run["obs"]["kind"]}
    if "image_size" in run["obs"]:
        kwargs["image_size"] = run["obs"]["image_size"]
    return kwargs


__all__ = [
    "ALGORITHMS",
    "CHECKPOINT_UNITS",
    "RUN_FILE",
    "load_policy",
    "policy_env_kwargs",
    "run_checkpoints",
    "train",
]
