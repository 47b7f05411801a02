"""The evaluation protocol: seeded episodes, success metrics over seeds, failure labels.

Reference protocol: 4 seeds x 16 episodes, 8 s (480 control steps) each, success reported as
mean +/- std over the seeds (population std, numpy's default ``ddof=0``).  Episode (s, e)
resets its environment with the frozen public seed of the task variant (``seeds.py``), so an
episode's outcome depends neither on how many workers run nor on how episodes are batched:
each environment of a batch is seeded explicitly, stepped by MuJoCo's batch engine
(bit-identical to stepping it alone) and driven by a policy whose per-environment state is
reset with it.

Per episode: ``success`` and, for insertion, ``reach_success`` / ``insert_success`` are true
if the task reported them at any control step (the reference counts a rollout once the plug
reached / seated); ``success_at_end`` is the flag at the last step; ``retain_success`` adds
the retention check (retention.py) after the last step.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from wirecraft.envs.env import CONTROL_HZ, default_episode_seconds
from wirecraft.envs.vector import info_row
from wirecraft.evaluation import diagnostics, retention
from wirecraft.evaluation.policies import (
    load_policy,
    policy_env_kwargs,
    policy_label,
    policy_name,
    policy_phase_names,
)
from wirecraft.evaluation.seeds import (
    PROTOCOL_VERSION,
    REFERENCE_EPISODES,
    REFERENCE_SEEDS,
    episode_seeds,
    variant_key,
)
from wirecraft.provenance import provenance
from wirecraft.tasks import TASKS
from wirecraft.tasks.options import split_options
from wirecraft.torch_threads import DEFAULT_TORCH_THREADS, check_torch_threads
from wirecraft.torch_threads import torch_threads as limit_torch_threads
from wirecraft.workers import open_workers

# Episode flags every family's summary adds to its success flags.
EPISODE_FLAGS = ("retain_success", "success_at_end")


def summary_metrics(task: str) -> tuple[str, ...]:
    """The rates a run reports for ``task``: the family's success flags, retention, success at
    the end."""
    return TASKS.get(task).metrics.success_flags + EPISODE_FLAGS


DEFAULT_BATCH = 8


@dataclass(frozen=True)
class EpisodeSpec:
    seed_index: int
    episode: int
    reset_seed: int


@dataclass(frozen=True)
class EvalConfig:
    """Everything a worker needs to run episodes (picklable, no live objects)."""

    task: str
    policy: Any  # a spec string, or a picklable factory
    env_kwargs: dict[str, Any]
    horizon: int  # control steps per episode
    retain_force: float = retention.DEFAULT_FORCE
    batch: int = DEFAULT_BATCH
    threads: int = 1
    policy_kwargs: dict[str, Any] = field(default_factory=dict)
    # Torch's intra-op threads while this process steps the policy (None or 0: torch's own).
    torch_threads: int | None = DEFAULT_TORCH_THREADS

    def key(self) -> str:
        return json.dumps(
            [
                self.task,
                policy_name(self.policy),
                self.env_kwargs,
                self.horizon,
                self.batch,
                self.threads,
                self.policy_kwargs,
            ],
            sort_keys=True,
            default=str,
        )


@dataclass
class EpisodeResult:
    spec: EpisodeSpec
    summary: dict[str, Any]
    trace: dict[str, np.ndarray]  # episode steps, then the retention steps (if any)


@dataclass
class EvaluationRun:
    payload: dict[str, Any]  # the JSON document
    results: list[EpisodeResult]  # in (seed, episode) order, with traces
    config: EvalConfig


# -- environments and policies per process -----------------------------------------------------
_CACHE: dict[str, tuple[Any, Any]] = {}


def environment_and_policy(config: EvalConfig):
    """The vector environment and policy of ``config``, built once per process."""
    key = config.key()
    if key not in _CACHE:
        import wirecraft

        while _CACHE:  # one configuration at a time: free the previous environments
            venv, _ = _CACHE.pop(next(iter(_CACHE)))
            venv.close()
        kwargs = dict(config.env_kwargs)
        # The environments never end an episode by time themselves: the protocol counts
        # steps, then may run the retention check from the final state.
        kwargs["episode_seconds"] = (config.horizon + retention.STEPS) / CONTROL_HZ + 1.0
        venv = wirecraft.make_vec(config.task, config.batch, threads=config.threads, **kwargs)
        policy = load_policy(config.policy, venv, **config.policy_kwargs)
        wanted = getattr(policy, "control", None)
        if wanted is not None and wanted != venv.envs[0].control_name:
            raise ValueError(
                f"policy {policy_name(config.policy)!r} needs control={wanted!r}, the "
                f"environments use {venv.envs[0].control_name!r}"
            )
        _CACHE[key] = (venv, policy)
    return _CACHE[key]


def run_chunk(config: EvalConfig, specs: list[EpisodeSpec], progress=None) -> list[EpisodeResult]:
    """Run up to ``config.batch`` episodes side by side (padding a short chunk with repeats
    of its first episode, whose results are dropped)."""
    if not 1 <= len(specs) <= config.batch:
        raise ValueError(f"a chunk holds 1 to {config.batch} episodes, got {len(specs)}")
    venv, policy = environment_and_policy(config)
    with limit_torch_threads(config.torch_threads):
        return _run_chunk(config, specs, venv, policy, progress)


def _run_chunk(config, specs, venv, policy, progress) -> list[EpisodeResult]:
    envs = venv.envs
    n = config.batch
    seeds = [s.reset_seed for s in specs] + [specs[0].reset_seed] * (n - len(specs))
    obs, _ = venv.reset(seed=seeds)
    policy.reset(None)
    recorders = [diagnostics.TraceRecorder(config.task) for _ in range(n)]
    active = np.zeros(n, bool)
    active[: len(specs)] = True
    diverged = np.zeros(n, bool)
    for _ in range(config.horizon):
        actions = np.asarray(policy.act(obs), dtype=float)
        phases = policy_phase_names(policy)
        obs, _, _, _, infos = venv.step(actions)
        for i in np.flatnonzero(active):
            info = info_row(infos, i)
            phase = phases[i] if phases else None
            if info["diverged"]:
                recorders[i].add(diagnostics.info_only(config.task, info), phase)
                diverged[i] = True
                active[i] = False
            else:
                recorders[i].add(diagnostics.measure(envs[i], info), phase)
        if progress is not None:
            progress(len(specs) / config.horizon)
    horizon_rows = [len(r.rows) for r in recorders]
    final_success = np.array(
        [bool(r.rows) and r.rows[-1][r.columns.index("success")] > 0.5 for r in recorders]
    )
    check = active & final_success
    retain_failure: list[str | None] = [None] * n
    if check.any():
        retain_failure = _run_retention(config, venv, check, recorders)
    results = []
    for i, spec in enumerate(specs):
        trace = recorders[i].arrays()
        summary = _summarize(
            config, trace, horizon_rows[i], bool(diverged[i]), bool(check[i]), retain_failure[i]
        )
        results.append(EpisodeResult(spec, summary, trace))
    return results


def _run_retention(config, venv, check, recorders) -> list[str | None]:
    envs = venv.envs
    n = len(envs)
    failure: list[str | None] = [None] * n
    live = check.copy()
    for k in range(retention.STEPS):
        actions = np.stack([retention.retention_action(env, k) for env in envs])
        for i in np.flatnonzero(live):
            if failure[i] is None:
                retention.apply_pull(envs[i], k, config.retain_force)
            else:
                retention.clear_pull(envs[i])
        _, _, _, _, infos = venv.step(actions)
        for i in np.flatnonzero(live):
            info = info_row(infos, i)
            if info["diverged"]:
                recorders[i].add(diagnostics.info_only(config.task, info), retention.stage(k))
                failure[i], live[i] = "diverged", False
                continue
            recorders[i].add(diagnostics.measure(envs[i], info), retention.stage(k))
            if failure[i] is None:
                failure[i] = retention.failure_at(k, info["success"])
    for env in envs:
        retention.clear_pull(env)
    return failure


def _clean(value):
    """JSON-friendly: floats rounded to 6 decimals, non-finite as None."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return round(value, 6) if math.isfinite(value) else None
    return value


def _summarize(config, trace, steps, diverged, checked, retain_failure) -> dict[str, Any]:
    ep = {k: v[:steps] for k, v in trace.items()}
    success = ep["success"] > 0.5
    summary: dict[str, Any] = {
        "success": bool(success.any()),
        "success_at_end": bool(steps and success[-1] and not diverged),
        "first_success_step": int(np.argmax(success)) + 1 if success.any() else None,
        "steps": steps,
        "diverged": diverged,
    }
    metrics = TASKS.get(config.task).metrics
    with np.errstate(all="ignore"):
        family = metrics.summarize(ep, steps)
    summary.update({k: v for k, v in family.items() if k in metrics.success_flags})
    summary["retain_success"] = bool(checked and retain_failure is None)
    if checked:
        summary["retain_failure"] = retain_failure
    elif summary["success"]:  # succeeded at some step, lost it before the end
        summary["retain_failure"] = "lost_before_end"
    else:
        summary["retain_failure"] = None
    options, _ = split_options(TASKS.get(config.task).Options, dict(config.env_kwargs))
    context = diagnostics.LabelContext(
        config.task, diverged, TASKS.get(config.task).Options.build(options)
    )
    primary, events = diagnostics.diagnose(ep, context)
    summary["failure"] = None if summary["success"] else primary
    # Everything observed (also in successful episodes, e.g. a collision on the way).
    summary["events"] = (
        events
        if not summary["success"]
        else [e for e in events if e in ("fixture_collision", "dropped")]
    )
    with np.errstate(all="ignore"):
        stats = {
            "max_grasp_force": np.nanmax(ep["grasp_force"], initial=0.0),
            "max_fixture_force": np.nanmax(ep["fixture_force"], initial=0.0),
            "max_robot_fixture_force": np.nanmax(ep["robot_fixture_force"], initial=0.0),
            "max_wire_tension": np.nanmax(ep["wire_tension"], initial=0.0),
            "min_bend_radius": np.nanmin(ep["min_bend_radius"], initial=np.inf),
            "max_contact_force": np.nanmax(ep["peak_contact_force"], initial=0.0),
        }
        stats.update({k: v for k, v in family.items() if k not in metrics.success_flags})
    summary.update(stats)
    phases = [p for p in ep["phase"] if p]
    summary["final_phase"] = phases[-1] if phases else None
    return {k: v if isinstance(v, list) else _clean(v) for k, v in summary.items()}


# -- running many chunks ---------------------------------------------------------------------------
def _chunks(specs: list[EpisodeSpec], size: int) -> list[list[EpisodeSpec]]:
    return [specs[i : i + size] for i in range(0, len(specs), size)]


def _run_all(config: EvalConfig, specs, workers: int, ray_address: str | None, show: bool):
    from tqdm import tqdm

    chunks = _chunks(specs, config.batch)
    bar = tqdm(
        total=len(specs),
        desc="eval",
        unit="episode",
        disable=not show,
        mininterval=1.0,
        bar_format="{l_bar}{bar}| {n:.1f}/{total} episodes [{elapsed}<{remaining}]",
    )
    results: list[EpisodeResult] = []
    try:
        if ray_address is None and workers <= 1:
            for chunk in chunks:
                results += run_chunk(config, chunk, progress=bar.update)
        else:
            # Ray started here gets every CPU of this machine.
            count = (os.cpu_count() or 1) if ray_address is not None else workers
            with open_workers(count, ray_address) as pool:
                for done in pool.map(run_chunk, ((config, chunk) for chunk in chunks)):
                    results += done
                    bar.update(len(done))
    finally:
        bar.close()
    return sorted(results, key=lambda r: (r.spec.seed_index, r.spec.episode))


# -- metrics and the JSON document ---------------------------------------------------------------
def aggregate(task: str, episodes: list[dict], num_seeds: int) -> dict[str, dict]:
    """metric -> {"mean", "std", "per_seed"}: the rate per seed, then mean and population
    std over seeds."""
    metrics = {}
    for name in summary_metrics(task):
        per_seed = []
        for s in range(num_seeds):
            values = [bool(ep[name]) for ep in episodes if ep["seed"] == s]
            per_seed.append(float(np.mean(values)) if values else math.nan)
        metrics[name] = {
            "mean": _clean(float(np.mean(per_seed))),
            "std": _clean(float(np.std(per_seed))),
            "per_seed": [_clean(v) for v in per_seed],
        }
    return metrics


def aggregate_runs(payloads: list[dict]) -> dict[str, dict]:
    """metric -> {"mean", "std", "per_run"} across several runs evaluated on the same seeds
    (e.g. one policy trained with three seeds): each run's mean rate over its seeds, then the
    mean and population std over the runs."""
    metrics = {}
    for name in payloads[0]["metrics"]:
        per_run = [p["metrics"][name]["mean"] for p in payloads]
        known = [v for v in per_run if v is not None]
        metrics[name] = {
            "mean": _clean(float(np.mean(known))) if known else None,
            "std": _clean(float(np.std(known))) if known else None,
            "per_run": per_run,
        }
    return metrics


def resolve_env_kwargs(task: str, policy, env_kwargs: dict) -> dict:
    """The user's environment keywords merged with what the policy needs; a conflict (e.g.
    ``control='joint'`` for the scripted insertion expert) is an error."""
    needed = policy_env_kwargs(policy, task)
    merged = {k: v for k, v in env_kwargs.items() if v is not None}
    for key, value in needed.items():
        if key in merged and merged[key] != value:
            raise ValueError(
                f"policy {policy_name(policy)!r} needs {key}={value!r}, but "
                f"{key}={merged[key]!r} was given"
            )
        merged[key] = value
    return merged


def run_evaluation(
    task: str,
    policy_spec="scripted",
    *,
    seeds: int = REFERENCE_SEEDS,
    episodes: int = REFERENCE_EPISODES,
    workers: int = 1,
    seed: int | None = None,
    episode_seconds: float | None = None,
    retain_force: float = retention.DEFAULT_FORCE,
    batch: int | None = None,
    ray_address: str | None = None,
    progress: bool = True,
    policy_kwargs: dict | None = None,
    torch_threads: int | None = DEFAULT_TORCH_THREADS,
    label: str | None = None,
    **env_kwargs,
) -> EvaluationRun:
    """Evaluate ``policy_spec`` on ``task``: the payload (JSON document) and every episode's
    trace.  ``env_kwargs`` are ``wirecraft.make`` keywords (robot, wire, connector, ...).
    ``torch_threads``: torch's intra-op threads in each process stepping the policy, this
    one included while it does (None or 0: torch's default); ``label``: the run's name in
    reports (default: derived from the policy, ``policy_label``)."""
    import wirecraft

    family = wirecraft.family_of(task)
    for name, value in (("seeds", seeds), ("episodes", episodes), ("workers", workers)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    if episode_seconds is not None and not (
        isinstance(episode_seconds, (int, float)) and episode_seconds > 0
    ):
        raise ValueError(f"episode_seconds must be > 0, got {episode_seconds!r}")
    if not (math.isfinite(retain_force) and retain_force >= 0):
        raise ValueError(f"retain_force must be >= 0 newtons, got {retain_force!r}")
    torch_threads = check_torch_threads(torch_threads)
    if label is not None and not (isinstance(label, str) and label.strip()):
        raise ValueError(f"label must be a non-empty string, got {label!r}")
    if "render_mode" in env_kwargs and env_kwargs["render_mode"] is not None:
        raise ValueError("evaluation renders its own videos: do not pass render_mode")
    policy_spec = policy_spec if callable(policy_spec) else str(policy_spec)
    merged = resolve_env_kwargs(family, policy_spec, env_kwargs)
    if episode_seconds is None:  # the task variant's own length (routing: 8 s per clip)
        episode_seconds = default_episode_seconds(family, **merged)
    lists = episode_seeds(family, merged, seeds, episodes, held_out=seed)
    specs = [EpisodeSpec(s, e, lists[s][e]) for s in range(seeds) for e in range(episodes)]
    total = len(specs)
    if batch is None:
        batch = min(DEFAULT_BATCH, math.ceil(total / workers))
    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise ValueError(f"batch must be an integer >= 1, got {batch!r}")
    config = EvalConfig(
        task=family,
        policy=policy_spec,
        env_kwargs=merged,
        horizon=int(round(episode_seconds * CONTROL_HZ)),
        retain_force=float(retain_force),
        batch=batch,
        threads=1 if workers > 1 or ray_address else 0,
        policy_kwargs=dict(policy_kwargs or {}),
        torch_threads=torch_threads,
    )
    results = _run_all(config, specs, workers, ray_address, progress)
    episodes_json = [
        {
            "seed": r.spec.seed_index,
            "episode": r.spec.episode,
            "reset_seed": r.spec.reset_seed,
            **r.summary,
        }
        for r in results
    ]
    failures: dict[str, int] = {}
    for ep in episodes_json:
        if ep["failure"] is not None:
            failures[ep["failure"]] = failures.get(ep["failure"], 0) + 1
    payload = {
        "task": family,
        "variant": variant_key(family, merged),
        "policy": policy_name(policy_spec),
        "label": label.strip() if label is not None else policy_label(policy_spec),
        "env_kwargs": {k: _clean(v) for k, v in sorted(merged.items())},
        "protocol": {
            "version": PROTOCOL_VERSION,
            "seeds": seeds,
            "episodes_per_seed": episodes,
            "episode_steps": config.horizon,
            "control_hz": CONTROL_HZ,
            "held_out_seed": seed,
            "reset_seeds": lists,
            "retain_force": config.retain_force,
            "retention_steps": retention.STEPS,
            "success": "any step (reach/insert/success); success_at_end: last step",
            "std": "population std over seeds (ddof=0)",
        },
        "metrics": aggregate(family, episodes_json, seeds),
        "failures": dict(sorted(failures.items())),
        "failure_labels": diagnostics.labels_for(family),
        "episodes": episodes_json,
        "provenance": provenance(threads=workers, ray_address=ray_address, batch=batch),
    }
    return EvaluationRun(payload=payload, results=results, config=config)


def evaluate(
    task: str,
    policy_spec="scripted",
    *,
    seeds: int = REFERENCE_SEEDS,
    episodes: int = REFERENCE_EPISODES,
    workers: int = 1,
    **env_kwargs,
) -> dict:
    """The evaluation's JSON payload (see ``run_evaluation`` for every keyword)."""
    return run_evaluation(
        task, policy_spec, seeds=seeds, episodes=episodes, workers=workers, **env_kwargs
    ).payload
