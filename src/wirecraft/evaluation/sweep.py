"""Checkpoint sweeps of a training run (``wirecraft eval --policy RUN --checkpoints ...``).

Two kinds of run folder are swept:

- an imitation run written by ``lerobot-train`` (``wirecraft train act|diffusion``):
  ``checkpoints/NNNNNN/pretrained_model``, numbered by training step; always swept;
- an RL run directory (``wirecraft train ppo|sacfd|vision-ppo``): the checkpoints its
  ``wirecraft_rl.json`` lists, numbered as the RL library names them (PPO iterations, SAC
  steps); swept only when ``--checkpoints``, ``--select`` or ``--curve`` is given, since
  ``--policy RUN`` alone is the run's latest checkpoint.

Each chosen checkpoint is evaluated under the protocol (``run_evaluation``) and gives one row:
SR reach / insert / success, mean +/- std over seeds.  Two ways to pick a checkpoint
(``--select``):

- ``reference`` (the reference's method): the 3 best of the last ``REFERENCE_LAST``
  checkpoints (or those ``--checkpoints`` names) on the evaluation seeds, and the mean of
  their metrics.  Selection and score use the same seeds, so the figure is optimistic.
- ``validation``: the best checkpoint on the validation list derived from ``--seed N``
  (seeds.py's held-out stream, disjoint from the public list), then scored on the frozen public
  list, which the selection never saw (and so comparable with any other policy's public
  figures).

"Best" is by SR reach for imitation runs (the reference's criterion: its policies reach far
more often than they seat) and by the task's success for RL runs; ties go to the higher
success, then to the later checkpoint.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from wirecraft.evaluation.policies import LEROBOT_CHECKPOINTS, LEROBOT_MODEL_DIR

REFERENCE_LAST = 5  # checkpoints the reference method chooses among, by default
REFERENCE_TOP = 3
ROW_METRICS = ("reach_success", "insert_success", "success")


def imitation_checkpoints(run: str | Path) -> list[tuple[int, Path]]:
    """(step, pretrained_model folder) of every numbered checkpoint in the LeRobot run
    ``run``, by step."""
    folder = Path(run) / LEROBOT_CHECKPOINTS
    found = []
    if folder.is_dir():
        for child in folder.iterdir():
            model = child / LEROBOT_MODEL_DIR
            if (
                child.name.isdigit()
                and not child.is_symlink()
                and (model / "config.json").is_file()
            ):
                found.append((int(child.name), model))
    return sorted(found)


def is_imitation_run(path: str | Path) -> bool:
    return bool(imitation_checkpoints(path))


@dataclass(frozen=True)
class SweptRun:
    checkpoints: list[tuple[int, Path]]
    unit: str  # what a checkpoint's number counts
    rank_by: str  # the metric that "best" means


def swept_run(path: str | Path, sweep_flags: bool) -> SweptRun | None:
    """What a sweep of ``--policy path`` covers, or None when ``path`` is evaluated as one
    policy: an imitation run is always swept, an RL run directory only when ``sweep_flags``
    (``--checkpoints``, ``--select`` or ``--curve``) were given."""
    found = imitation_checkpoints(path)
    if found:
        return SweptRun(found, "training steps", "reach_success")
    if sweep_flags:
        from wirecraft.rl import run_checkpoints as rl_checkpoints

        found, unit = rl_checkpoints(path)
        if found:
            return SweptRun(found, unit, "success")
    return None


def choose(checkpoints: list[tuple[int, Path]], spec: str | None, select: str | None):
    """The checkpoints ``--checkpoints`` names: all, last, or steps N,M,... (default: all; with
    ``--select reference`` the last ``REFERENCE_LAST``)."""
    if spec is None:
        return checkpoints[-REFERENCE_LAST:] if select == "reference" else checkpoints
    if spec == "all":
        return checkpoints
    if spec == "last":
        return checkpoints[-1:]
    by_step = dict(checkpoints)
    try:
        steps = [int(s) for s in spec.split(",")]
    except ValueError:
        raise ValueError(
            f"--checkpoints: expected all, last or steps N,M,..., got {spec!r}"
        ) from None
    missing = [s for s in steps if s not in by_step]
    if missing:
        raise ValueError(
            f"--checkpoints: no checkpoint at step {', '.join(map(str, missing))} "
            f"(steps: {', '.join(str(s) for s, _ in checkpoints)})"
        )
    return [(s, by_step[s]) for s in sorted(set(steps))]


def row(step: int, path: Path, payload: dict, seeds: str) -> dict:
    metrics = payload["metrics"]
    return {
        "step": step,
        "path": str(path),
        "seeds": seeds,
        "metrics": {
            name: {"mean": metrics[name]["mean"], "std": metrics[name]["std"]}
            for name in ROW_METRICS
            if name in metrics
        },
        "failures": payload.get("failures", {}),
    }


def _rank_key(rank_by: str):
    def key(r: dict):
        m = r["metrics"]
        first = m.get(rank_by, m["success"])["mean"]
        return (first if first is not None else -1.0, m["success"]["mean"] or 0.0, r["step"])

    return key


def mean_of(rows: list[dict]) -> dict:
    import numpy as np

    names = rows[0]["metrics"]
    return {n: {"mean": float(np.mean([r["metrics"][n]["mean"] for r in rows]))} for n in names}


def sweep(
    evaluate, checkpoints, select: str | None, seed: int | None, rank_by: str = "reach_success"
) -> dict:
    """Rows of the chosen checkpoints and the selection (the best by ``rank_by``).
    ``evaluate(path, held_out)`` runs the protocol on one checkpoint (``held_out``: the
    ``--seed`` list, or None: the public list)."""
    if select == "validation":
        rows = [row(s, p, evaluate(p, seed), f"validation --seed {seed}") for s, p in checkpoints]
        best = max(rows, key=_rank_key(rank_by))
        final = row(best["step"], Path(best["path"]), evaluate(Path(best["path"]), None), "public")
        selection = {
            "method": "validation",
            "validation_seed": seed,
            "ranked_by": rank_by,
            "chosen_step": best["step"],
            "score": final,
        }
        return {"checkpoints": rows, "selection": selection}
    which = "public" if seed is None else f"held-out --seed {seed}"
    rows = [row(s, p, evaluate(p, seed), which) for s, p in checkpoints]
    if select != "reference":
        return {"checkpoints": rows, "selection": None}
    top = sorted(rows, key=_rank_key(rank_by), reverse=True)[:REFERENCE_TOP]
    selection = {
        "method": "reference",
        "ranked_by": rank_by,
        "candidates": [r["step"] for r in rows],
        "top_steps": [r["step"] for r in top],
        "mean_of_top": mean_of(top),
    }
    return {"checkpoints": rows, "selection": selection}


CURVE_TITLES = {"reach_success": "SR reach", "insert_success": "SR insert", "success": "success"}


def plot_curve(result: dict, path: str | Path, title: str = "") -> Path:
    """Learning curve of a sweep: each metric (mean +/- std over seeds) against training
    steps, one point per checkpoint (the seeds it was scored on in the legend)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = sorted(result["checkpoints"], key=lambda r: r["step"])
    steps = [r["step"] for r in rows]
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    names = [n for n in CURVE_TITLES if n in rows[0]["metrics"]]
    if "insert_success" in names:
        names.remove("success")  # the same as SR insert for insertion
    for name in names:
        means = [100 * (r["metrics"][name]["mean"] or 0.0) for r in rows]
        stds = [100 * (r["metrics"][name]["std"] or 0.0) for r in rows]
        ax.errorbar(steps, means, yerr=stds, marker="o", capsize=3, label=CURVE_TITLES[name])
    ax.set_xlabel(result.get("step_unit", "training steps"))
    ax.set_ylabel("% of episodes (mean +/- std over seeds)")
    ax.set_ylim(-2, 102)
    ax.grid(alpha=0.3)
    ax.legend(title=rows[0]["seeds"], fontsize=8, title_fontsize=8)
    ax.set_title(title or str(result.get("policy", "")), fontsize=9)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _pct(value) -> str:
    return "    -" if value is None else f"{100 * value:5.1f}"


def print_sweep(result: dict) -> None:
    rows = result["checkpoints"]
    names = list(rows[0]["metrics"])
    print(f"{'step':>8s}  " + "  ".join(f"{n:>20s}" for n in names) + "  seeds")
    for r in rows:
        cells = "  ".join(
            f"{_pct(r['metrics'][n]['mean'])} +/- {_pct(r['metrics'][n]['std'])} %" for n in names
        )
        print(f"{r['step']:>8d}  {cells}  {r['seeds']}")
    selection = result["selection"]
    if selection and selection["method"] == "reference":
        means = ", ".join(
            f"{n} {_pct(v['mean']).strip()} %" for n, v in selection["mean_of_top"].items()
        )
        print(
            f"reference selection: top {selection['top_steps']} by "
            f"{CURVE_TITLES[selection['ranked_by']]}; mean {means}"
        )
    elif selection:
        score = selection["score"]["metrics"]
        means = ", ".join(
            f"{n} {_pct(v['mean']).strip()} +/- {_pct(v['std']).strip()} %"
            for n, v in score.items()
        )
        print(
            f"validation selection: checkpoint {selection['chosen_step']} (best "
            f"{CURVE_TITLES[selection['ranked_by']]} on --seed {selection['validation_seed']}); "
            f"public seeds: {means}"
        )
