"""Every policy shipped in ``checkpoints/`` loads and still does what its record says.

Each folder's record names the variant it was evaluated on and its success there (4 x 16
episodes).  Four of the public episodes must insert at least three times: a rate with a margin
(the recorded rates are 92 % and more), not one chaotic episode's outcome.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from wirecraft.rl import RUN_FILE

CHECKPOINTS = Path(__file__).resolve().parents[1] / "checkpoints"
SHIPPED = sorted(p.parent for p in CHECKPOINTS.glob(f"*/{RUN_FILE}"))


def test_checkpoints_are_shipped():
    assert SHIPPED, f"no shipped policy under {CHECKPOINTS}"


@pytest.mark.parametrize("folder", SHIPPED, ids=[p.name for p in SHIPPED])
def test_a_shipped_policy_succeeds_as_recorded(folder):
    from wirecraft.evaluation.protocol import run_evaluation

    record = json.loads((folder / RUN_FILE).read_text())
    shipped = record["shipped"]
    assert shipped["train_command"].startswith("wirecraft train ppo")
    public = [e for e in shipped["evaluations"] if e["held_out_seed"] is None]
    # the task's headline flag: insertion's insert_success, the others' success
    flag = "insert_success" if "insert_success" in public[0] else "success"
    assert public and public[0][flag]["mean"] >= 0.9
    size = (folder / record["latest_checkpoint"]).stat().st_size
    assert size < 400_000  # the actor alone
    env_kwargs = {k: v for k, v in record["env_kwargs"].items() if k != "obs_mode"}
    run = run_evaluation(
        record["task"], str(folder), seeds=1, episodes=4, progress=False, **env_kwargs
    )
    succeeded = [r.summary[flag] for r in run.results]
    assert sum(succeeded) >= 3, succeeded
