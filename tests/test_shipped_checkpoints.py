"""Every policy shipped in ``checkpoints/`` loads and still does what its record says.

Each folder's record names the variant it was evaluated on and its success there (4 x 16
episodes).  Eight of the public episodes must succeed (the task's headline flag) at least
``ceil(8 x recorded rate) - 3`` times, and at least once: a rate with a margin, not one chaotic
episode's outcome (a 97 % policy must succeed 5 times, a 58 % one twice).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from wirecraft.rl import RUN_FILE

CHECKPOINTS = Path(__file__).resolve().parents[1] / "checkpoints"
SHIPPED = sorted(p.parent for p in CHECKPOINTS.glob(f"*/{RUN_FILE}"))
EPISODES = 8


def test_checkpoints_are_shipped():
    assert SHIPPED, f"no shipped policy under {CHECKPOINTS}"


@pytest.mark.parametrize("folder", SHIPPED, ids=[p.name for p in SHIPPED])
def test_a_shipped_policy_succeeds_as_recorded(folder):
    from wirecraft.evaluation.protocol import run_evaluation

    record = json.loads((folder / RUN_FILE).read_text())
    shipped = record["shipped"]
    assert shipped["train_command"].startswith(("wirecraft train ppo", "wirecraft train sacfd"))
    public = [e for e in shipped["evaluations"] if e["held_out_seed"] is None]
    assert public
    # the task's headline flag: insertion's insert_success, the others' success
    flag = "insert_success" if "insert_success" in public[0] else "success"
    recorded = public[0][flag]["mean"]
    size = (folder / record["latest_checkpoint"]).stat().st_size
    assert size < 400_000  # the actor alone
    env_kwargs = {k: v for k, v in record["env_kwargs"].items() if k != "obs_mode"}
    run = run_evaluation(
        record["task"], str(folder), seeds=1, episodes=EPISODES, progress=False, **env_kwargs
    )
    succeeded = [r.summary[flag] for r in run.results]
    assert sum(succeeded) >= max(1, math.ceil(EPISODES * recorded) - 3), (recorded, succeeded)
