"""What the RL baselines share: the run directory and its ``wirecraft_rl.json``, episode
statistics from a vector environment's SAME_STEP autoreset, and the progress table.

A run directory holds:
    wirecraft_rl.json   algorithm, task, environment keywords, config, observation
                        normalisation, checkpoints (latest last), env steps and wall time so far
    checkpoints/        rsl-rl ``model_<iteration>.pt`` or skrl ``agent_<vector step>.pt``
    progress.csv        one row per iteration / logging period: env steps, wall time, success
    events.out.tfevents.*  TensorBoard logs
"""

from __future__ import annotations

import csv
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

RUN_FILE = "wirecraft_rl.json"
RUN_FORMAT = 1
CHECKPOINT_DIR = "checkpoints"
PROGRESS_FILE = "progress.csv"
EPISODE_FLAGS = ("success", "reach_success", "insert_success")


def find_run_dir(path: str | os.PathLike) -> Path:
    """The run directory of ``path``: the directory itself, or the one holding a checkpoint
    file (directly or in its ``checkpoints/``)."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"no such run directory or checkpoint: {path}")
    candidates = [path] if path.is_dir() else []
    candidates += [path.parent, path.parent.parent]
    for candidate in candidates:
        if (candidate / RUN_FILE).is_file():
            return candidate
    raise ValueError(f"{path} is not in an RL run directory (no {RUN_FILE} found)")


def read_run(run_dir: str | os.PathLike) -> dict:
    run_dir = Path(run_dir)
    try:
        run = json.loads((run_dir / RUN_FILE).read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise ValueError(f"cannot read {run_dir / RUN_FILE}: {err}") from None
    if run.get("format") != RUN_FORMAT:
        raise ValueError(f"{run_dir / RUN_FILE}: unknown format {run.get('format')!r}")
    return run


def check_run_state_revision(run_dir: Path, run: dict) -> None:
    """``tasks.check_state_revision`` of a run, naming the commit it was trained on."""
    from wirecraft.tasks import check_state_revision

    commit = run.get("versions", {}).get("wirecraft_commit")
    where = f" (commit {commit})" if commit else ""
    check_state_revision(
        run,
        f"{run_dir} was trained",
        "its policy would read inputs it never saw. Use the WireCraft it was trained "
        f"with{where}, or train it again.",
    )


def checkpoint_path(run_dir: Path, run: dict, path: str | os.PathLike | None = None) -> Path:
    """``path`` when it is a checkpoint file, else the run's latest checkpoint."""
    if path is not None and Path(path).is_file():
        return Path(path)
    latest = run.get("latest_checkpoint")
    if not latest:
        raise ValueError(f"{run_dir}: the run has no checkpoint yet")
    return run_dir / latest


def expert_for(task: str, control: str | None, purpose: str, kind: str = "scripted"):
    """The class of ``task``'s ``kind`` of expert (``experts.DEMONSTRATORS``: scripted or
    reactive); a ValueError naming ``purpose`` when ``control`` is given and is not the mode
    the expert drives."""
    from wirecraft.experts import demonstrator_class

    expert_cls = demonstrator_class(task, kind)
    if control is not None and control != expert_cls.CONTROL:
        raise ValueError(
            f"{purpose} come from the {task} {kind} expert, which needs "
            f"control={expert_cls.CONTROL!r}; got control={control!r}"
        )
    return expert_cls


def expert_vec_env(
    task: str,
    env_kwargs: dict,
    purpose: str,
    num_envs: int,
    seed: int,
    kind: str = "scripted",
    **options,
):
    """``task``'s ``kind`` of expert (seeded: the scripted one's random perturbations follow
    ``seed``) on a new vector env of ``env_kwargs`` in the expert's control mode
    (``expert_for`` checks it)."""
    import wirecraft

    expert_cls = expert_for(task, env_kwargs.get("control"), purpose, kind)
    env_kwargs = {**env_kwargs, "control": expert_cls.CONTROL}
    venv = wirecraft.make_vec(task, num_envs, **options, **env_kwargs)
    return expert_cls(venv, seed=seed), venv


def batch_obs(obs):
    """A numpy observation (batched or not) as float arrays with a leading batch axis."""
    if isinstance(obs, dict):
        return {k: v if isinstance(v, (tuple, list)) else np.asarray(v) for k, v in obs.items()}
    obs = np.asarray(obs, dtype=np.float64)
    return obs[None] if obs.ndim == 1 else obs


def state_batch(obs, obs_dim: int) -> np.ndarray:
    """``batch_obs`` for a state policy: (N, obs_dim) float64, or a ValueError naming the
    width it expected."""
    obs = batch_obs(obs)
    if obs.shape[-1] != obs_dim:
        raise ValueError(f"observations must have {obs_dim} columns, got {obs.shape}")
    return obs


def env_control(env) -> str:
    """The control mode of a single environment, a wrapped one or a WireCraft vector env."""
    if hasattr(env, "envs"):
        return env.envs[0].control_name
    return env.unwrapped.control_name


def final_observations(obs, infos: dict, done: np.ndarray):
    """Observations with the rows of finished environments replaced by their final
    observation (SAME_STEP autoreset puts the first observation of the next episode in
    ``obs``).  Works for array and dict observations."""
    if not done.any() or "final_obs" not in infos:
        return obs
    final = infos["final_obs"]
    ids = np.flatnonzero(done)
    if isinstance(obs, dict):
        out = {k: (list(v) if isinstance(v, (tuple, list)) else v.copy()) for k, v in obs.items()}
        for i in ids:
            for key in out:
                out[key][i] = final[i][key]
        return out
    out = obs.copy()
    for i in ids:
        out[i] = final[i]
    return out


class EpisodeTracker:
    """Per-environment episode statistics from vector-env steps: return (unscaled), length,
    the final success flags, whether each flag was ever true, and divergence."""

    def __init__(self, num_envs: int) -> None:
        self.num_envs = num_envs
        self.returns = np.zeros(num_envs)
        self.lengths = np.zeros(num_envs, int)
        self.ever = {k: np.zeros(num_envs, bool) for k in EPISODE_FLAGS}
        # Per-term returns ("reward/bring", ...): which terms a policy collects shows what it
        # has learned long before any success flag moves.
        self.term_returns: dict[str, np.ndarray] = {}
        # Episodes started from an expert's state (rl/expert_starts.py), as the vector env's
        # ``infos["expert_start"]`` marked them at their reset; None: no such starts.
        self.expert_start: np.ndarray | None = None

    def started(self, infos: dict, ids=None) -> None:
        """Note how the episodes of ``ids`` (default: all) began, from their reset's infos."""
        if "expert_start" not in infos:
            return
        if self.expert_start is None:
            self.expert_start = np.zeros(self.num_envs, bool)
        ids = np.arange(self.num_envs) if ids is None else ids
        self.expert_start[ids] = np.asarray(infos["expert_start"], bool)[ids]

    def step(self, rewards, terminated, truncated, infos) -> list[dict[str, float]]:
        """Account for one step; returns one record per episode that ended in it."""
        self.returns += rewards
        self.lengths += 1
        for key, value in infos.items():
            if key.startswith("reward/"):
                sums = self.term_returns.setdefault(key, np.zeros(self.num_envs))
                sums += np.asarray(value, float)
        done = np.asarray(terminated) | np.asarray(truncated)
        final = infos.get("final_info", {})
        flags = {}
        for key in EPISODE_FLAGS:
            now = np.asarray(infos.get(key, np.zeros(self.num_envs, bool)), bool)
            if key in final:  # a finished env's own flags are in final_info, not the reset's
                now = np.where(done, np.asarray(final[key], bool), now)
            self.ever[key] |= now
            flags[key] = now
        diverged = np.asarray(final.get("diverged", np.zeros(self.num_envs, bool)), bool)
        records = []
        for i in np.flatnonzero(done):
            record = {"return": float(self.returns[i]), "length": int(self.lengths[i])}
            for key in EPISODE_FLAGS:
                record[key] = float(flags[key][i])
                record[f"{key}_any"] = float(self.ever[key][i])
            record["diverged"] = float(diverged[i])
            if self.expert_start is not None:
                record["expert_start"] = float(self.expert_start[i])
            for key, sums in self.term_returns.items():
                record[key] = float(sums[i])
                sums[i] = 0.0
            records.append(record)
            self.returns[i] = 0.0
            self.lengths[i] = 0
            for key in EPISODE_FLAGS:
                self.ever[key][i] = False
        self.started(infos, np.flatnonzero(done))
        return records


EPISODE_KEYS = (
    "return",
    "length",
    *EPISODE_FLAGS,
    *(f"{k}_any" for k in EPISODE_FLAGS),
    "diverged",
)
PROGRESS_FIELDS = ("iteration", "env_steps", "wall_time_s", "env_steps_per_s", "episodes") + tuple(
    f"mean_{k}" for k in EPISODE_KEYS
)


def summarize(records: list[dict[str, float]]) -> dict[str, float]:
    """Means of the episode records (NaN where there were none)."""
    out = {"episodes": len(records)}
    for key in EPISODE_KEYS:
        out[f"mean_{key}"] = float(np.mean([r[key] for r in records])) if records else float("nan")
    return out


class ProgressTable:
    """``progress.csv`` of a run: appended row by row, header written once."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)

    def append(self, row: dict[str, Any]) -> None:
        new = not self.path.exists()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self.path.open("a", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=PROGRESS_FIELDS, extrasaction="ignore")
            if new:
                writer.writeheader()
            writer.writerow({k: _fmt(row.get(k, "")) for k in PROGRESS_FIELDS})

    def drop_from(self, iteration: int) -> None:
        """Forget the rows of ``iteration`` and later: a run resumed from a checkpoint redoes
        them, and its curve must not hold both tries."""
        if not self.path.exists():
            return
        from wirecraft.cli_args import atomic_path

        with self.path.open(newline="") as f:
            rows = [r for r in csv.DictReader(f) if float(r["iteration"]) < iteration]
        with atomic_path(self.path) as tmp, tmp.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=PROGRESS_FIELDS, extrasaction="ignore")
            writer.writeheader()
            writer.writerows(rows)

    def rows(self) -> list[dict[str, float]]:
        if not self.path.exists():
            return []
        with self.path.open() as f:
            return [
                {k: float(v) if v != "" else float("nan") for k, v in r.items()}
                for r in csv.DictReader(f)
            ]


def _fmt(value):
    if isinstance(value, float):
        return f"{value:.6g}"
    return value


class WallClock:
    """Wall time of a run, continued across resumes."""

    def __init__(self, offset: float = 0.0) -> None:
        self.offset = float(offset)
        self.start = time.monotonic()

    def __call__(self) -> float:
        return self.offset + time.monotonic() - self.start
