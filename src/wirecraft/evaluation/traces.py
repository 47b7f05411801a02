"""Per-step episode traces as one columnar file (Parquet, written with pyarrow).

Long format, one row per control step of every episode (the retention check's steps
included): ``seed``, ``episode``, ``reset_seed``, ``step`` (0-based), ``time`` (s since the
episode's first step), ``stage`` (``episode`` or ``retention``), ``phase`` (the policy's phase
name, or the retention stage), then the trace columns of ``diagnostics.columns(task)``:
insertion depth, lateral / yaw / roll errors, insertion and contact forces, wire tension,
minimum bend radius, ... (units in diagnostics.py and docs/evaluation.md).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wirecraft.envs.env import CONTROL_HZ
from wirecraft.evaluation import diagnostics


def to_table(task: str, results):
    """A ``pyarrow.Table`` of the traces of ``results`` (``EpisodeResult`` list)."""
    import pyarrow as pa

    names = diagnostics.columns(task)
    columns: dict[str, list] = {
        k: [] for k in ("seed", "episode", "reset_seed", "step", "time", "stage", "phase")
    }
    columns.update({name: [] for name in names})
    for result in results:
        trace = result.trace
        steps = len(trace["phase"])
        horizon = result.summary["steps"]
        columns["seed"].append(np.full(steps, result.spec.seed_index, np.int32))
        columns["episode"].append(np.full(steps, result.spec.episode, np.int32))
        columns["reset_seed"].append(np.full(steps, result.spec.reset_seed, np.int64))
        columns["step"].append(np.arange(steps, dtype=np.int32))
        columns["time"].append((np.arange(steps) + 1) / CONTROL_HZ)
        columns["stage"].append(np.where(np.arange(steps) < horizon, "episode", "retention"))
        columns["phase"].append(np.asarray(trace["phase"], dtype=str))
        for name in names:
            columns[name].append(np.asarray(trace[name], float))
    arrays = {}
    for key, parts in columns.items():
        if not parts:
            arrays[key] = pa.array([], type=pa.string() if key in ("stage", "phase") else None)
            continue
        value = np.concatenate(parts)
        arrays[key] = pa.array(value.tolist() if value.dtype.kind in "UO" else value)
    return pa.table(arrays)


def write_traces(path: str | Path, task: str, results, metadata: dict | None = None) -> Path:
    """Write the traces of ``results`` to ``path`` (Parquet); returns the path."""
    import json

    import pyarrow.parquet as pq

    table = to_table(task, results)
    if metadata:
        table = table.replace_schema_metadata({"wirecraft": json.dumps(metadata, default=str)})
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, path)
    return path


def read_traces(path: str | Path):
    """The traces file as a ``pyarrow.Table``."""
    import pyarrow.parquet as pq

    return pq.read_table(path)
