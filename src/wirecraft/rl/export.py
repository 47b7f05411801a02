"""A state policy (PPO or SACfD) to ship: the actor of one checkpoint and the run's record,
small enough for the repository (``checkpoints/`` holds the reference cells; checkpoints/README.md).

    python -m wirecraft.rl.export RUN --checkpoint model_39.pt --out checkpoints/NAME \\
        --command "wirecraft train ppo ..." --evaluation public.json --evaluation heldout.json
    python -m wirecraft.rl.export RUN --selection sweep.json --out checkpoints/NAME ...

``--selection``: a ``wirecraft eval --select validation --json`` document (a sweep of this run,
or of several runs including it); the checkpoint it chose is shipped and the record keeps the
choice (``shipped.selection``: validation seed, criterion, each candidate's figure).

The folder is a run directory that ``wirecraft eval --policy`` and ``load_policy`` read as any
other: ``wirecraft_rl.json`` (the run's record, with the shipped checkpoint as its only and
latest one, and ``shipped``: where it came from, the training command and the evaluations'
metrics), the checkpoint holding the actor alone (``ACTOR_KEYS``; a PPO ``model_<iteration>.pt``
is about 250 KB against 1.4 MB with the critic and the optimizer), so it cannot be resumed,
and the run's
``progress.csv`` (its learning curve; ``benchmarks/rl_table.py --curves`` plots it).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from wirecraft.cli_args import folder_built_beside
from wirecraft.rl.common import (
    CHECKPOINT_DIR,
    PROGRESS_FILE,
    RUN_FILE,
    checkpoint_path,
    read_run,
)

SHIPPED_METRICS = ("success", "reach_success", "insert_success")
# What a shipped checkpoint keeps of each algorithm's: the actor (and SACfD's observation
# scaler, which skrl keeps beside it).
ACTOR_KEYS = {
    "ppo": ("actor_state_dict", "iter", "infos"),
    "sacfd": ("policy", "observation_preprocessor"),
}


def run_selection(document: dict, run_dir: Path, where: str = "the selection") -> tuple[dict, str]:
    """The validation choice that a ``wirecraft eval --select validation --json`` document
    (one run's sweep, or several runs' under ``runs``) made for ``run_dir``, as the record
    keeps it, and the chosen checkpoint's file name."""
    sweeps = document.get("runs", [document])
    for sweep in sweeps:
        if "policy" in sweep and Path(sweep["policy"]).resolve() == run_dir.resolve():
            chosen = sweep.get("selection")
            if not chosen or chosen.get("method") != "validation":
                raise ValueError(f"{where}: {run_dir} was not selected with --select validation")
            try:
                record = {
                    "method": "validation",
                    "validation_seed": chosen["validation_seed"],
                    "ranked_by": chosen["ranked_by"],
                    "chosen": chosen["chosen_step"],
                    "candidates": {
                        str(r["step"]): r["metrics"][chosen["ranked_by"]]["mean"]
                        for r in sweep["checkpoints"]
                    },
                }
                return record, Path(chosen["score"]["path"]).name
            except (KeyError, TypeError) as err:
                raise ValueError(f"{where}: not a sweep document ({err!r} missing)") from None
    raise ValueError(f"{where}: no sweep of {run_dir}")


def export_policy(
    run_dir: str | Path,
    out: str | Path,
    checkpoint: str | None = None,
    command: str | None = None,
    evaluations: tuple[str | Path, ...] = (),
    selection: str | Path | None = None,
) -> Path:
    """Write the shipped policy of ``run_dir``'s ``checkpoint`` (default: the one
    ``selection`` chose, else its latest) to ``out`` (which must not exist); returns ``out``.
    ``evaluations``: JSON documents of ``wirecraft eval --json`` on this checkpoint, whose
    metrics the record keeps; ``selection``: a ``--select validation`` sweep document."""
    import torch

    run_dir, out = Path(run_dir), Path(out)
    run = read_run(run_dir)
    if run["algorithm"] not in ACTOR_KEYS:
        raise ValueError(
            f"{run_dir}: only {' and '.join(ACTOR_KEYS)} runs are exported, not {run['algorithm']}"
        )
    if out.exists():
        raise ValueError(f"{out} exists: give a new folder")
    chosen = None
    if selection is not None:
        document = json.loads(Path(selection).read_text())
        chosen, picked = run_selection(document, run_dir, str(selection))
        if checkpoint not in (None, picked):
            raise ValueError(f"{selection} chose {picked}, not --checkpoint {checkpoint}")
        checkpoint = picked
    if checkpoint is None:
        source = checkpoint_path(run_dir, run)
    else:
        source = run_dir / CHECKPOINT_DIR / checkpoint
    if not source.is_file():
        raise ValueError(f"no checkpoint {source}")
    results = []
    for path in evaluations:
        document = json.loads(Path(path).read_text())
        metrics, protocol = document.get("metrics", {}), document.get("protocol", {})
        results.append(
            {
                "variant": document.get("variant"),
                "held_out_seed": protocol.get("held_out_seed"),
                "seeds": protocol.get("seeds"),
                "episodes_per_seed": protocol.get("episodes_per_seed"),
                **{name: metrics[name] for name in SHIPPED_METRICS if name in metrics},
            }
        )
    saved = torch.load(source, map_location="cpu", weights_only=False)
    name = f"{CHECKPOINT_DIR}/{source.name}"
    record = dict(run)
    record.update(checkpoints=[name], latest_checkpoint=name)
    record["shipped"] = {
        "from_run": str(run_dir),
        "checkpoint": source.name,
        "train_command": command,
        "evaluations": results,
    }
    if chosen is not None:
        record["shipped"]["selection"] = chosen
    actor = {key: saved[key] for key in ACTOR_KEYS[run["algorithm"]] if key in saved}
    with folder_built_beside(out, "export") as staging:
        (staging / CHECKPOINT_DIR).mkdir(parents=True)
        torch.save(actor, staging / name)
        (staging / RUN_FILE).write_text(json.dumps(record, indent=2, sort_keys=True) + "\n")
        if (run_dir / PROGRESS_FILE).is_file():
            shutil.copyfile(run_dir / PROGRESS_FILE, staging / PROGRESS_FILE)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m wirecraft.rl.export", description=__doc__)
    parser.add_argument("run", help="a state PPO or SACfD run directory")
    parser.add_argument("--out", required=True, help="the new folder")
    parser.add_argument(
        "--checkpoint", default=None, help="model_N.pt or agent_N.pt (default: the latest)"
    )
    parser.add_argument("--command", default=None, help="the command that trained the run")
    parser.add_argument(
        "--evaluation", action="append", default=[], help="a wirecraft eval --json document"
    )
    parser.add_argument(
        "--selection",
        default=None,
        help="a wirecraft eval --select validation --json document: ship the checkpoint it chose",
    )
    args = parser.parse_args(argv)
    try:
        out = export_policy(
            args.run, args.out, args.checkpoint, args.command, args.evaluation, args.selection
        )
    except (ValueError, OSError) as err:
        print(f"export: error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
