"""Frozen public evaluation seeds: every lab running the same command sees the same episodes.

An evaluation runs ``num_seeds`` x ``episodes`` episodes; episode (s, e) resets its
environment with ``episode_seed(variant, s, e)``.  The seed depends on the protocol version,
the task variant and (s, e) only, never on worker counts or batching.

Variant key: the task family and every keyword argument of its task class except ``weights``,
defaults filled in, sorted, e.g. ``insertion/clearance=0.003/connector=ethernet``.  Robot,
wire model, control and observation modes are not part of it: they see the same sampled
layouts (plug, port, clips, channel), so they compare on equal footing.

Derivation (version ``v1``)::

    numpy.random.SeedSequence(PROTOCOL_ENTROPY["v1"],
                              spawn_key=(crc32(variant_key), stream, s, e)).generate_state(1)[0]

with ``stream = 0`` for the public lists.  ``seeds/v1.json`` holds the resulting 4 x 16 lists
of the standard variants (every connector at 3 mm, 1-3 clips, both channels), frozen: a test
checks the file against the derivation, so neither can drift.  Larger protocols and other
variants extend the same derivation.  ``--seed N`` (held-out checks) uses ``stream = 1`` and
puts N in front of (s, e): a fresh list that the public one never overlaps by construction.
"""

from __future__ import annotations

import json
import re
import zlib
from functools import cache
from pathlib import Path

import numpy as np

PROTOCOL_VERSION = "v1"
# Fixed, arbitrary entropy per protocol version (changing it changes every public episode).
PROTOCOL_ENTROPY = {"v1": 0x5EED_C0DE_2026_0001}
REFERENCE_SEEDS = 4
REFERENCE_EPISODES = 16
SEEDS_DIR = Path(__file__).parent / "seeds"
PUBLIC, HELD_OUT = 0, 1


def variant_key(task: str, env_kwargs: dict | None = None) -> str:
    """``family/key=value/...`` from the task options in ``env_kwargs`` (defaults filled in;
    environment-level keywords such as robot or wire ignored)."""
    from wirecraft.tasks import TASKS

    defaults = TASKS.get(task).Options.defaults()
    env_kwargs = env_kwargs or {}
    parts = [task]
    for name in sorted(defaults):
        value = env_kwargs.get(name, defaults[name])
        if isinstance(defaults[name], float) and isinstance(value, int):
            value = float(value)
        parts.append(f"{name}={value!r}" if isinstance(value, float) else f"{name}={value}")
    return "/".join(parts)


def derive_seed(key: str, seed_index: int, episode: int, *, stream: int = PUBLIC, base=()) -> int:
    """One episode's reset seed by the documented derivation (a uint32)."""
    spawn = (zlib.crc32(key.encode()), stream, *base, int(seed_index), int(episode))
    sequence = np.random.SeedSequence(PROTOCOL_ENTROPY[PROTOCOL_VERSION], spawn_key=spawn)
    return int(sequence.generate_state(1)[0])


@cache
def frozen_lists(version: str = PROTOCOL_VERSION) -> dict[str, list[list[int]]]:
    """The seed lists versioned in the package: variant key -> [seed][episode]."""
    path = SEEDS_DIR / f"{version}.json"
    return json.loads(path.read_text())["variants"]


def episode_seeds(
    task: str,
    env_kwargs: dict | None,
    num_seeds: int = REFERENCE_SEEDS,
    episodes: int = REFERENCE_EPISODES,
    held_out: int | None = None,
) -> list[list[int]]:
    """(num_seeds, episodes) reset seeds: the frozen public list of the variant, or with
    ``held_out=N`` a fresh list derived from N."""
    if num_seeds < 1 or episodes < 1:
        raise ValueError(f"seeds and episodes must be >= 1, got {num_seeds} and {episodes}")
    key = variant_key(task, env_kwargs)
    if held_out is not None:
        return [
            [
                derive_seed(key, s, e, stream=HELD_OUT, base=(int(held_out),))
                for e in range(episodes)
            ]
            for s in range(num_seeds)
        ]
    frozen = frozen_lists().get(key)
    return [
        [
            frozen[s][e]
            if frozen is not None and s < len(frozen) and e < len(frozen[s])
            else derive_seed(key, s, e)
            for e in range(episodes)
        ]
        for s in range(num_seeds)
    ]


def standard_variants() -> list[tuple[str, dict]]:
    """The variants whose lists are frozen in ``seeds/<version>.json``: each family's
    ``metrics.standard_variants()``."""
    from wirecraft.tasks import TASKS

    return [(name, dict(v)) for name in TASKS for v in TASKS.get(name).metrics.standard_variants()]


def write_frozen_lists(path: Path | None = None) -> Path:
    """(Re)generate the frozen file from the derivation (done once per protocol version)."""
    path = path or SEEDS_DIR / f"{PROTOCOL_VERSION}.json"
    variants = {}
    for task, kwargs in standard_variants():
        key = variant_key(task, kwargs)
        variants[key] = [
            [derive_seed(key, s, e) for e in range(REFERENCE_EPISODES)]
            for s in range(REFERENCE_SEEDS)
        ]
    payload = {
        "version": PROTOCOL_VERSION,
        "entropy": PROTOCOL_ENTROPY[PROTOCOL_VERSION],
        "derivation": "numpy SeedSequence(entropy, spawn_key=(crc32(key), 0, seed, episode))",
        "variants": variants,
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(payload, indent=2)
    # One line per seed's list of episode seeds (readable, diff-friendly).
    text = re.sub(
        r"\[\s+([\d,\s]+?)\s+\]", lambda m: "[" + " ".join(m.group(1).split()) + "]", text
    )
    path.write_text(text + "\n")
    return path
