"""Vector-environment throughput against the raw batched physics of the same model.

For each (task, wire, num_envs, threads): reset, warm up, then time ``step`` over a measured
window.  The raw figure steps the same model and substeps with ``mujoco.batch`` alone (no
Python environment code, controls held), from the same states: each control step is timed
twice, the batch alone first, then (states put back) the environment, so both see the same
contacts; ``overhead_ratio`` is the environment's step time over the raw one.  Rows as SPEC
section 1; CSV, JSON and a PNG plot.

``backend="warp"`` runs the physics on MuJoCo Warp on ``device``: the raw figure is then Warp
stepping every world on the device with nothing crossing to the host (``physics_only``), the
environment's step includes the transfers and the task code on the host.  A count that does not
fit on the device ends that (task, wire) sweep (``run``'s second result lists it); a case whose
reset keeps diverging is reported and skipped (the third).

Two configurations (the ``info`` column): ``training`` (the default, as ``wirecraft train`` runs
it: ``diagnostics=False, sync_envs=False``, success flags and reward terms in ``info``) and
``full`` (``--full-info``: per-environment force and cable diagnostics, and every environment's
own ``MjData`` kept up to date, as evaluation and the experts use it).
"""

from __future__ import annotations

import csv
import time
from pathlib import Path

import numpy as np

from wirecraft.envs.env import CONTROL_HZ, SUBSTEPS, ResetDiverged

NUM_ENVS = (1, 4, 16, 64, 256, 1024)
THREADS = (1, 2)
FIELDS = (
    "task",
    "options",
    "info",
    "wire",
    "backend",
    "device",
    "num_envs",
    "threads",
    "control_steps_per_s",
    "physics_steps_per_s",
    "realtime_factor",
    "raw_physics_steps_per_s",
    "overhead_ratio",
    "bytes_per_step",
)


INFO_CONFIGS = {
    "training": {"diagnostics": False, "sync_envs": False},
    "full": {"diagnostics": True, "sync_envs": True},
}


def measure(
    task: str,
    wire: str,
    num_envs: int,
    threads: int,
    seconds: float,
    warmup: float,
    info: str = "training",
    options: dict | None = None,
    backend: str = "cpu",
    device: str | None = None,
) -> dict:
    import mujoco

    import wirecraft

    options = dict(options or {})
    placement = {"backend": "warp", "device": device} if backend == "warp" else {}
    venv = wirecraft.make_vec(
        task, num_envs, threads=threads, wire=wire, **INFO_CONFIGS[info], **options, **placement
    )
    venv.reset(seed=0)
    rng = np.random.default_rng(0)
    batch = venv.batch
    acc = mujoco.mjtStage.mjSTAGE_ACC.value
    raw_step = getattr(batch, "physics_only", None) or (lambda n: batch.step(nstep=n))

    def paired_step() -> tuple[float, float]:
        """(raw, env) seconds of one control step from the same states: the batch alone
        steps them (controls held), the states are put back, then the environment steps."""
        saved = batch.state.copy()
        start = time.perf_counter()
        raw_step(SUBSTEPS)
        raw = time.perf_counter() - start
        batch.state[:] = saved
        batch.forward(stage=acc)  # the next step reads the derived fields of those states
        actions = rng.uniform(-0.3, 0.3, venv.action_space.shape)
        start = time.perf_counter()
        venv.step(actions)
        return raw, time.perf_counter() - start

    end = time.perf_counter() + warmup
    while time.perf_counter() < end:
        paired_step()
    raw_total = env_total = 0.0
    calls = 0
    while env_total < seconds or calls < 3:
        raw, env = paired_step()
        raw_total, env_total, calls = raw_total + raw, env_total + env, calls + 1
    venv.close()
    raw_time, env_time = raw_total / calls, env_total / calls
    control = num_envs / env_time
    return {
        "task": task,
        "options": " ".join(f"{k}={v}" for k, v in sorted(options.items())),
        "info": info,
        "wire": wire,
        "backend": backend,
        "device": getattr(batch, "device_name", "cpu"),
        "num_envs": num_envs,
        "threads": threads if backend == "cpu" else 0,
        "control_steps_per_s": round(control, 1),
        "physics_steps_per_s": round(control * SUBSTEPS, 1),
        "realtime_factor": round(control / CONTROL_HZ, 2),
        "raw_physics_steps_per_s": round(num_envs * SUBSTEPS / raw_time, 1),
        "overhead_ratio": round(env_time / raw_time, 3),
        "bytes_per_step": getattr(batch, "bytes_per_step", 0),
    }


def run(
    tasks,
    wires,
    num_envs,
    threads,
    seconds: float = 5.0,
    warmup: float = 1.0,
    info: str = "training",
    options: dict[str, dict] | None = None,
    backend: str = "cpu",
    device: str | None = None,
) -> tuple[list[dict], list[dict], list[dict]]:
    """(rows of ``measure`` for every (task, wire, num_envs, threads), the counts that did not
    fit, the cases whose reset kept diverging); ``options``: task -> the task options to build
    its environments with (``{family: {option: value}}``).  On Warp a count that fails to
    allocate ends its (task, wire) sweep: the larger ones are not tried."""
    from tqdm import tqdm

    options = options or {}
    threads = threads if backend == "cpu" else [0]
    cases = [(t, w, n, k) for t in tasks for w in wires for n in sorted(num_envs) for k in threads]
    rows, too_big, failed = [], [], []
    for case in tqdm(cases, desc="bench envs", unit="config"):
        task, wire, count, _ = case
        if any((r["task"], r["wire"]) == (task, wire) and r["num_envs"] <= count for r in too_big):
            continue
        try:
            rows.append(measure(*case, seconds, warmup, info, options.get(task), backend, device))
        except MemoryError as err:
            too_big.append({"task": task, "wire": wire, "num_envs": count, "error": str(err)})
            tqdm.write(f"{task}/{wire}: {count} environments do not fit ({err})")
        except ResetDiverged as err:  # report it, go on
            failed.append({"task": task, "wire": wire, "num_envs": count, "error": str(err)})
            tqdm.write(f"{task}/{wire}, {count} environments: not measured ({err})")
    return rows, too_big, failed


def variant(row: dict) -> str:
    """The row's task with its options: ``routing num_clips=3``."""
    return f"{row['task']} {row['options']}".strip()


def where(row: dict) -> str:
    """Where the row's physics ran: ``2 threads`` or the Warp device's name."""
    if row["backend"] == "cpu":
        return f"{row['threads']} thread{'s' * (row['threads'] > 1)}"
    return f"warp {row['device']}"


def print_table(rows: list[dict]) -> None:
    print(
        f"{'task':22} {'info':8} {'wire':12} {'envs':>5} {'physics on':18} {'control/s':>10}"
        f" {'physics/s':>11} {'x real':>8} {'raw phys/s':>11} {'env/raw':>8}"
    )
    for r in rows:
        print(
            f"{variant(r):22} {r['info']:8} {r['wire']:12} {r['num_envs']:>5} {where(r)[:18]:18} "
            f"{r['control_steps_per_s']:>10.0f} {r['physics_steps_per_s']:>11.0f} "
            f"{r['realtime_factor']:>8.1f} {r['raw_physics_steps_per_s']:>11.0f} "
            f"{r['overhead_ratio']:>8.2f}"
        )


def write_csv(rows: list[dict], path: str | Path) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=FIELDS)
        writer.writeheader()
        writer.writerows(rows)


def plot(rows: list[dict], path: str | Path) -> None:
    """Control steps/s against num_envs, one curve per (task, wire, threads), log-log."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax_ratio) = plt.subplots(1, 2, figsize=(11, 4.2))

    def key(r):
        return variant(r), r["wire"], where(r)

    for task, wire, place in sorted({key(r) for r in rows}):
        sel = sorted(
            (r for r in rows if key(r) == (task, wire, place)), key=lambda r: r["num_envs"]
        )
        n = [r["num_envs"] for r in sel]
        label = f"{task}/{wire}, {place}"
        ax.plot(n, [r["control_steps_per_s"] for r in sel], "o-", label=label)
        ax_ratio.plot(n, [r["overhead_ratio"] for r in sel], "o-", label=label)
    ax.set(
        xscale="log",
        yscale="log",
        xlabel="parallel environments",
        ylabel="control steps / s (all environments)",
        title="Throughput",
    )
    ax_ratio.axhline(1.1, color="grey", ls="--", lw=1, label="target 1.10")
    ax_ratio.set(
        xscale="log",
        xlabel="parallel environments",
        ylabel="env step time / raw physics time",
        title="Environment overhead",
    )
    ax.legend(fontsize=7)
    ax_ratio.legend(fontsize=7)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
