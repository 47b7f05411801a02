"""Golden rollouts: fingerprints of frozen scripted episodes that define the benchmark's version.

Each cell (a task family with a wire model and a robot) is one seeded episode driven by the
family's scripted expert for ``STEPS`` control steps. Its fingerprint is a SHA-256 over every
step's action, ``qpos``, observation and reward, and a checkpoint hash every second, so that a
changed episode says when it started to differ.

``golden_rollouts.json`` beside this module holds the fingerprints. A test compares today's
episodes with it and names the cells that changed: a MuJoCo or numpy upgrade, or an edit to an
asset, a task or an expert, that changes what an episode does fails there. When the change is
meant, write the file anew:

    python -m wirecraft.golden --write

Writing changed fingerprints raises ``benchmark_version`` in the file: results obtained under two
benchmark versions are not comparable. ``python -m wirecraft.golden`` (no flag) checks and prints
the cells that differ; ``--json`` prints today's fingerprints.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

from wirecraft.cli_args import write_text

GOLDEN_FILE = Path(__file__).with_name("golden_rollouts.json")
STEPS = 480  # one default episode (8 s at 60 Hz)
CHECKPOINT_EVERY = 60
SEED = 7


def cells(path: Path = GOLDEN_FILE) -> dict[str, tuple[str, dict]]:
    """name -> (task family, environment keywords) of the golden cells, as the golden file
    defines them: every family with every wire model, each robot in every family once, and the
    task options spread over the cells.  Add a cell to the file (its ``task`` and
    ``env_kwargs``), then ``--write``."""
    return {name: (c["task"], c["env_kwargs"]) for name, c in load_golden(path)["cells"].items()}


def _feed(digest, value) -> None:
    if isinstance(value, dict):
        for key in sorted(value):
            digest.update(key.encode())
            _feed(digest, value[key])
    else:
        digest.update(np.ascontiguousarray(value, dtype=np.float64).tobytes())


def rollout_fingerprint(task: str, kwargs: dict, seed: int = SEED, steps: int = STEPS) -> dict:
    """Fingerprint of one scripted episode: ``{"sha256", "checkpoints", "steps"}``."""
    import wirecraft
    from wirecraft.experts import expert_class

    expert_cls = expert_class(task)
    env = wirecraft.make(task, control=expert_cls.CONTROL, **kwargs)
    try:
        obs, _ = env.reset(seed=seed)
        expert = expert_cls(env, seed=seed)
        data = env.unwrapped.data
        digest = hashlib.sha256()
        _feed(digest, data.qpos)
        _feed(digest, obs)
        checkpoints = []
        done = 0
        for step in range(steps):
            action = expert.act(obs)[0]
            obs, reward, terminated, truncated, _ = env.step(action)
            for value in (action, data.qpos, data.qvel, obs, reward):
                _feed(digest, value)
            done = step + 1
            if done % CHECKPOINT_EVERY == 0:
                checkpoints.append(digest.hexdigest()[:16])
            if terminated or truncated:
                break
        return {"sha256": digest.hexdigest(), "checkpoints": checkpoints, "steps": done}
    finally:
        env.close()


def fingerprints(names=None) -> dict[str, dict]:
    """Today's fingerprints of the named cells (default: all)."""
    defined = cells()
    names = list(defined) if names is None else list(names)
    unknown = sorted(set(names) - set(defined))
    if unknown:
        raise ValueError(f"unknown golden cells {unknown}; valid: {', '.join(defined)}")
    out = {}
    for name in names:
        task, kwargs = defined[name]
        out[name] = rollout_fingerprint(task, kwargs)
    return out


def load_golden(path: Path = GOLDEN_FILE) -> dict:
    return json.loads(Path(path).read_text())


def golden_file_sha256(path: Path = GOLDEN_FILE) -> str | None:
    path = Path(path)
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.exists() else None


def differences(today: dict[str, dict], golden: dict[str, dict]) -> list[str]:
    """One line per cell whose fingerprint differs, with the second in which it first differs."""
    lines = []
    for name in sorted(set(today) | set(golden)):
        if name not in golden:
            lines.append(f"{name}: not in the golden file")
            continue
        if name not in today:
            continue
        now, then = today[name], golden[name]
        if now["sha256"] == then["sha256"]:
            continue
        pairs = zip(now["checkpoints"], then["checkpoints"], strict=False)
        first = next((i for i, (a, b) in enumerate(pairs) if a != b), None)
        when = (
            f"differs within second {first + 1}"
            if first is not None
            else f"differs after the last checkpoint ({now['steps']} vs {then['steps']} steps)"
        )
        lines.append(f"{name}: {when}")
    return lines


def write_golden(today: dict[str, dict], path: Path = GOLDEN_FILE) -> tuple[int, list[str]]:
    """Write ``today`` as the golden file; the benchmark version goes up when a cell changed."""
    path = Path(path)
    old = load_golden(path) if path.exists() else {"benchmark_version": 0, "cells": {}}
    defined = {
        name: {"task": c["task"], "env_kwargs": c["env_kwargs"]} for name, c in old["cells"].items()
    }
    changed = differences(today, old["cells"]) + [
        f"{name}: dropped" for name in sorted(set(old["cells"]) - set(today))
    ]
    version = old["benchmark_version"] + (1 if changed else 0)
    body = {
        "benchmark_version": version,
        "steps": STEPS,
        "seed": SEED,
        "regenerate": "python -m wirecraft.golden --write",
        "cells": {name: {**defined.get(name, {}), **today[name]} for name in sorted(today)},
    }
    write_text(path, json.dumps(body, indent=1) + "\n")
    return version, changed


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m wirecraft.golden",
        description="Check today's scripted episodes against the golden rollouts, or write them.",
    )
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true", help="write today's fingerprints")
    mode.add_argument("--json", action="store_true", help="print today's fingerprints as JSON")
    parser.add_argument("--cells", nargs="+", metavar="NAME", choices=list(cells()))
    args = parser.parse_args(argv)
    if args.write and args.cells:
        parser.error("--write regenerates every cell; leave out --cells")
    today = fingerprints(args.cells)
    if args.json:
        print(json.dumps(today, indent=1))
        return 0
    if args.write:
        version, changed = write_golden(today)
        for line in changed:
            print(line)
        print(f"wrote {GOLDEN_FILE} (benchmark version {version})")
        return 0
    changed = differences(today, load_golden()["cells"])
    for line in changed:
        print(line)
    print(f"{len(today) - len(changed)} of {len(today)} golden rollouts unchanged")
    return 1 if changed else 0


if __name__ == "__main__":
    sys.exit(main())
