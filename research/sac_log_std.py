"""The spread a SACfD actor asks for, per checkpoint of a run directory.

    python research/sac_log_std.py RUN

For each ``RUN/checkpoints/agent_N.pt``: the log-std head's output (before the actor's clip to
``[-5, max_log_std]``) on up to 20,000 of the run's demonstration states (``RUN/demos.pt``,
stored as the actor reads them), the median per action dimension, and the share of
state-dimension pairs above the clip.  docs/baselines.md ("SACfD with the memoryless expert")
reads it: the BC term fits the actor's mean only, so the spread is SAC's alone.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from wirecraft.rl import run_checkpoints
from wirecraft.rl.common import read_run
from wirecraft.rl.config import config_from_dict
from wirecraft.rl.sacfd import load_sac_policy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a wirecraft train sacfd run directory")
    args = parser.parse_args()
    run = read_run(args.run)
    cfg = config_from_dict("sacfd", run["config"])
    demos = torch.load(args.run / "demos.pt", map_location="cpu", weights_only=False)
    states = demos["observations"][:20000].float()
    clip = cfg.max_log_std
    print(f"| checkpoint | env steps | log std asked, median per dimension | share above {clip} |")
    print("|---|---:|---|---:|")
    for number, path in run_checkpoints(args.run)[0]:
        policy = load_sac_policy(run, path)
        with torch.no_grad():
            x = policy.scaler(states) if policy.scaler is not None else states
            log_std = policy.actor.log_std_head(policy.actor.net(x))
        medians = ", ".join(f"{v:.2f}" for v in log_std.median(dim=0).values.tolist())
        steps = number * cfg.num_envs
        above = float((log_std > clip).float().mean())
        print(f"| {path.stem} | {steps:,} | {medians} | {above:.0%} |")


if __name__ == "__main__":
    main()
