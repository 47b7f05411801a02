"""Whether PPO kept its DAgger warm start: per run directory, from its TensorBoard log.

    python research/ppo_drift.py RUN [RUN ...]

Prints one Markdown row per run: the DAgger pass's loss (``Loss/dagger``: the actor against the
memoryless expert's labels of the states PPO visits), median and largest, and the iterations
above 0.06; the share of iterations whose learning rate sits at rsl-rl's adaptive floor (1e-5);
the lowest training success (``Episode/insert_success_any``, else ``Episode/success_any``:
episodes with the action noise) and its iteration; the run's ``public.json`` headline rate
when it has one (``wirecraft eval ... --json RUN/public.json``).  docs/baselines.md reads these
for the runs that lost their warm start's success and those that kept it.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

TAGS = ("Loss/dagger", "Loss/learning_rate", "Episode/insert_success_any", "Episode/success_any")
LOSS_LIMIT = 0.06
LR_FLOOR = 1e-5  # rsl-rl's adaptive schedule never goes below it


def scalars(run: Path) -> dict[str, dict[int, float]]:
    """Tag -> {iteration: value}; a resumed run's later log wins for an iteration logged twice."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    values: dict[str, dict[int, float]] = {}
    for path in sorted(run.glob("events.out.tfevents*"), key=lambda p: p.stat().st_mtime):
        log = EventAccumulator(str(path))
        log.Reload()
        for tag in TAGS:
            if tag in log.Tags()["scalars"]:
                for event in log.Scalars(tag):
                    values.setdefault(tag, {})[event.step] = event.value
    return values


def public_rate(run: Path) -> str:
    try:
        metrics = json.loads((run / "public.json").read_text())["metrics"]
    except (OSError, KeyError, json.JSONDecodeError):
        return "-"
    key = "insert_success" if "insert_success" in metrics else "success"
    return f"{100 * metrics[key]['mean']:.1f} %"


def row(run: Path) -> str:
    values = scalars(run)
    loss = values.get("Loss/dagger")
    if not loss:
        return f"| {run.name} | no DAgger pass logged | | | | {public_rate(run)} |"
    rates = values.get("Loss/learning_rate", {})
    success = values.get("Episode/insert_success_any") or values.get("Episode/success_any") or {}
    worst = min(success, key=success.get) if success else None
    floor = np.mean([v <= LR_FLOOR * 1.0001 for v in rates.values()]) if rates else float("nan")
    peak = max(loss, key=loss.get)
    cells = [
        run.name,
        f"{np.median(list(loss.values())):.3f} / {loss[peak]:.3f} ({peak})",
        f"{sum(v > LOSS_LIMIT for v in loss.values())} of {len(loss)}",
        f"{100 * floor:.0f} %",
        f"{100 * success[worst]:.0f} % ({worst})" if worst is not None else "-",
        public_rate(run),
    ]
    return "| " + " | ".join(cells) + " |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run directories (wirecraft train ppo)")
    args = parser.parse_args()
    missing = [str(r) for r in args.runs if not r.is_dir()]
    if missing:
        parser.error(f"not a folder: {', '.join(missing)}")
    print(
        "| run | DAgger-pass loss: median / max (iteration) | iterations with loss > "
        f"{LOSS_LIMIT} | iterations at the learning-rate floor | lowest training success "
        "(iteration) | SR, public |"
    )
    print("|---|---|---|---|---|---|")
    for run in args.runs:
        print(row(run))


if __name__ == "__main__":
    main()
