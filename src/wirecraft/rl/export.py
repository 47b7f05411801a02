"""A state-PPO policy to ship: the actor of one checkpoint and the run's record, small enough
for the repository (``checkpoints/`` holds the reference cells; checkpoints/README.md).

    python -m wirecraft.rl.export RUN --checkpoint model_39.pt --out checkpoints/NAME \\
        --command "wirecraft train ppo ..." --evaluation public.json --evaluation heldout.json

The folder is a run directory that ``wirecraft eval --policy`` and ``load_policy`` read as any
other: ``wirecraft_rl.json`` (the run's record, with the shipped checkpoint as its only and
latest one, and ``shipped``: where it came from, the training command and the evaluations'
metrics), ``checkpoints/model_<iteration>.pt`` holding the actor alone (about 250 KB against
1.4 MB with the critic and the optimizer), so it cannot be resumed, and the run's
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


def export_policy(
    run_dir: str | Path,
    out: str | Path,
    checkpoint: str | None = None,
    command: str | None = None,
    evaluations: tuple[str | Path, ...] = (),
) -> Path:
    """Write the shipped policy of ``run_dir``'s ``checkpoint`` (default: its latest) to
    ``out`` (which must not exist); returns ``out``.  ``evaluations``: JSON documents of
    ``wirecraft eval --json`` on this checkpoint, whose metrics the record keeps."""
    import torch

    run_dir, out = Path(run_dir), Path(out)
    run = read_run(run_dir)
    if run["algorithm"] != "ppo":
        raise ValueError(f"{run_dir}: only state PPO runs are exported, not {run['algorithm']}")
    if out.exists():
        raise ValueError(f"{out} exists: give a new folder")
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
    actor = {key: saved[key] for key in ("actor_state_dict", "iter", "infos") if key in saved}
    with folder_built_beside(out, "export") as staging:
        (staging / CHECKPOINT_DIR).mkdir(parents=True)
        torch.save(actor, staging / name)
        (staging / RUN_FILE).write_text(json.dumps(record, indent=2, sort_keys=True) + "\n")
        if (run_dir / PROGRESS_FILE).is_file():
            shutil.copyfile(run_dir / PROGRESS_FILE, staging / PROGRESS_FILE)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m wirecraft.rl.export", description=__doc__)
    parser.add_argument("run", help="a state PPO run directory")
    parser.add_argument("--out", required=True, help="the new folder")
    parser.add_argument("--checkpoint", default=None, help="model_N.pt (default: the latest)")
    parser.add_argument("--command", default=None, help="the command that trained the run")
    parser.add_argument(
        "--evaluation", action="append", default=[], help="a wirecraft eval --json document"
    )
    args = parser.parse_args(argv)
    try:
        out = export_policy(args.run, args.out, args.checkpoint, args.command, args.evaluation)
    except (ValueError, OSError) as err:
        print(f"export: error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
