"""``wirecraft mix``: several datasets of the shared schema (any sources: scripted, rl, teleop,
real) merged into one LeRobot v3 dataset whose frames are drawn in chosen proportions.

LeRobot 0.6.1 has no weighted sampling of its own: ``lerobot-train`` draws every frame of a
map-style dataset once per epoch in a shuffled order (``EpisodeAwareSampler``), and its
``sample_weighting`` option only scales the loss (``rabc`` progress weights or ``uniform``),
it cannot weight a frame by its data source.  The weights are therefore realised by repeating
episodes: input ``i`` (``F_i`` frames, weight ``w_i``) is copied ``c_i >= 1`` times, so it
makes up ``c_i F_i / sum_j c_j F_j`` of the frames training samples, which is ``w_i / sum(w)``
up to rounding.  The copies are the smallest integers (``c_i = max(1, round(m r_i))``,
``r_i = (w_i / F_i) / min_j (w_j / F_j)``, ``m = 1, 2, ...``) whose shares are all within
``SHARE_TOLERANCE`` of the targets, or the closest shares with at most ``max_copies`` copies
of any input.

The merge itself is LeRobot's own ``aggregate_datasets`` (an input named ``c_i`` times is
aggregated ``c_i`` times: data and videos are copied, not re-encoded, so every frame is the
input's frame), written into a temporary folder beside ``--out`` and renamed into place only
when complete.  ``meta/wirecraft_mix.json`` records the inputs, weights, copies and shares and
the provenance; ``meta/wirecraft_collect.json`` keeps the inputs' collection settings where
they agree (``wirecraft train act --dataset`` reads the task and its options from it).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

from wirecraft.datasets import schema
from wirecraft.datasets.collect import SETTINGS_FILE as COLLECT_FILE
from wirecraft.datasets.writer import INFO_FILE

MIX_FILE = "meta/wirecraft_mix.json"
MIX_FORMAT = 1
REPO_ID = "wirecraft/local"
SHARE_TOLERANCE = 0.01  # largest |achieved - target| frame share accepted without more copies
DEFAULT_MAX_COPIES = 100
# Collection settings that differ between datasets of the same task without changing what a
# policy trained on them sees (the seeds, whether failures were kept, the video codec).
FREE_SETTINGS = ("seed", "keep_failures", "vcodec", "success_hold_s")
SEMANTICS = (
    "weight w_i: input i makes up w_i / sum(w) of the frames lerobot-train samples, realised by "
    "copying its episodes c_i times: its achieved share is c_i * frames_i / sum_j(c_j * frames_j)"
)


def usage(flag: str, message: str) -> ValueError:
    return ValueError(f"{flag}: {message}")


def parse_input(text: str) -> tuple[str, float]:
    """``DIR[:WEIGHT]`` -> (DIR, WEIGHT); no weight: 1.  A folder whose name holds a colon is
    taken whole when it exists."""
    path, sep, tail = text.rpartition(":")
    if not sep or Path(text).exists() or "/" in tail:
        return text, 1.0
    try:
        weight = float(tail)
    except ValueError:
        raise usage(
            "--input", f"{text!r}: expected DIR or DIR:WEIGHT with a number WEIGHT > 0"
        ) from None
    if not math.isfinite(weight) or weight <= 0:
        raise usage("--input", f"{text!r}: the weight must be a finite number > 0, got {tail!r}")
    if not path:
        raise usage("--input", f"{text!r}: no folder before the weight")
    return path, weight


# -- reading and checking the inputs ----------------------------------------------------------
def _read_json(path: Path, flag: str = "--input") -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise usage(flag, f"{path}: unreadable ({err})") from None


def _episode_sources(root: Path) -> list[str]:
    """The data source of each episode (from the ``source`` column of the data files)."""
    import numpy as np
    import pyarrow.parquet as pq

    files = sorted((root / "data").rglob("*.parquet"))
    if not files:
        raise usage("--input", f"{root} has no data files (data/**/*.parquet)")
    first: dict[int, int] = {}
    for path in files:
        table = pq.read_table(path, columns=["episode_index", schema.SOURCE_KEY])
        episodes = np.asarray(table.column("episode_index")).reshape(-1)
        codes = np.asarray(table.column(schema.SOURCE_KEY).to_pylist(), dtype=np.int64)
        for e, c in zip(episodes.tolist(), codes.reshape(-1).tolist(), strict=True):
            first.setdefault(int(e), int(c))
    try:
        return [schema.source_name(first[e]) for e in sorted(first)]
    except ValueError as err:
        raise usage("--input", f"{root}: {err}") from None


def read_input(path: str | os.PathLike) -> dict:
    """What ``mix`` needs to know of one input dataset; ValueError (``--input: ...``) where it is
    not a complete LeRobot v3 dataset of the shared schema."""
    from wirecraft.datasets.writer import _episode_files, read_commit

    root = Path(path)
    if not root.is_dir():
        raise usage("--input", f"{path} is not a folder (a LeRobot dataset)")
    if not (root / INFO_FILE).is_file():
        raise usage("--input", f"{path} is not a LeRobot dataset (no {INFO_FILE})")
    info = _read_json(root / INFO_FILE)
    if info.get("codebase_version") != "v3.0":
        raise usage(
            "--input",
            f"{path} is a LeRobot {info.get('codebase_version')} dataset; mix reads v3.0",
        )
    features = info.get("features") or {}
    missing = [
        k for k in (schema.STATE_KEY, schema.ACTION_KEY, schema.SOURCE_KEY) if k not in features
    ]
    if missing:
        raise usage(
            "--input", f"{path} is not a WireCraft dataset (no feature {', '.join(missing)})"
        )
    if not info.get("total_episodes"):
        raise usage("--input", f"{path} holds no episodes")
    try:
        record = read_commit(root)
    except ValueError as err:
        raise usage("--input", str(err)) from None
    if record is not None and _episode_files(root) != record["files"]:
        raise usage(
            "--input",
            f"{path} is incomplete (written to after its last commit and not closed); "
            f"`wirecraft collect --resume --out {path}` rolls it back and continues it",
        )
    if not (root / "meta" / "episodes").is_dir():
        raise usage("--input", f"{path} has no episode index (meta/episodes)")
    sources = _episode_sources(root)
    if len(sources) != info["total_episodes"]:
        raise usage(
            "--input",
            f"{path}: info.json counts {info['total_episodes']} episodes, the data {len(sources)}",
        )
    collect = (root / COLLECT_FILE).is_file() and _read_json(root / COLLECT_FILE) or None
    return {
        "path": str(root.resolve()),
        "info": info,
        "collect": collect,
        "episode_sources": sources,
    }


def _feature_shape(feature: dict) -> tuple:
    return (feature.get("dtype"), list(feature.get("shape") or []), feature.get("names"))


def check_compatible(inputs: list[dict]) -> None:
    """Same frame rate, robot and features (dtype, shape, names; video encoder details aside)
    in every input; the ValueError names the first difference."""
    base = inputs[0]
    first = base["path"]
    for other in inputs[1:]:
        where = f"{first} and {other['path']}"
        for key in ("fps", "robot_type"):
            a, b = base["info"].get(key), other["info"].get(key)
            if a != b:
                raise usage(
                    "--input", f"different {key}: {a!r} in {first}, {b!r} in {other['path']}"
                )
        fa, fb = base["info"]["features"], other["info"]["features"]
        only_a, only_b = sorted(set(fa) - set(fb)), sorted(set(fb) - set(fa))
        if only_a or only_b:
            parts = [f"{', '.join(only_a)} only in {first}"] if only_a else []
            parts += [f"{', '.join(only_b)} only in {other['path']}"] if only_b else []
            raise usage("--input", f"different features: {'; '.join(parts)}")
        for key in fa:
            (da, sa, na), (db, sb, nb) = _feature_shape(fa[key]), _feature_shape(fb[key])
            for what, a, b in (("dtype", da, db), ("shape", sa, sb), ("names", na, nb)):
                if a != b:
                    raise usage(
                        "--input",
                        f"feature {key} has {what} {a} in {first} but {b} in {other['path']} "
                        f"(mix needs the same robot, control mode, image size and fps: {where})",
                    )


def common_collect(inputs: list[dict]) -> tuple[dict | None, str | None]:
    """(the output's ``wirecraft_collect.json``, None) when every input that has one agrees on
    the settings that matter (all but ``FREE_SETTINGS``); (None, why) otherwise; (None, None)
    when no input has one."""
    having = [x for x in inputs if x["collect"]]
    if not having:
        return None, None
    base = having[0]["collect"]

    def relevant(collect: dict) -> dict:
        settings = {k: v for k, v in (collect.get("settings") or {}).items()}
        for key in FREE_SETTINGS:
            settings.pop(key, None)
        return {
            "settings": settings,
            "schema_version": collect.get("schema_version"),
            "state_revision": collect.get("state_revision"),
        }

    want = relevant(base)
    for other in having[1:]:
        got = relevant(other["collect"])
        if got != want:
            keys = sorted(
                {*want["settings"], *got["settings"]}
                if want["settings"] != got["settings"]
                else {"schema_version", "state_revision"}
            )
            diff = [
                k
                for k in keys
                if (want["settings"].get(k), want.get(k)) != (got["settings"].get(k), got.get(k))
            ]
            return None, (
                f"collection settings differ ({', '.join(diff)}) between {having[0]['path']} "
                f"and {other['path']}"
            )
    settings = dict(base.get("settings") or {})
    for key in FREE_SETTINGS:
        values = {json.dumps((x["collect"].get("settings") or {}).get(key)) for x in having}
        if len(values) > 1:
            settings[key] = None  # differs between the inputs: see each input's own file
    experts = {json.dumps(x["collect"].get("expert"), sort_keys=True) for x in having}
    merged = {
        "schema_version": base.get("schema_version"),
        "state_revision": base.get("state_revision"),
        "sources": list(schema.SOURCES),
        "source": "mix",
        "settings": settings,
        "expert": base.get("expert") if len(experts) == 1 else None,
        "provenance": [p for x in having for p in x["collect"].get("provenance") or []],
        "mix": MIX_FILE,
    }
    return merged, None


# -- the weights ------------------------------------------------------------------------------
def shares(frames: list[int], copies: list[int]) -> list[float]:
    total = sum(c * f for c, f in zip(copies, frames, strict=True))
    return [c * f / total for c, f in zip(copies, frames, strict=True)]


def plan_copies(
    frames: list[int],
    weights: list[float],
    max_copies: int = DEFAULT_MAX_COPIES,
    tolerance: float = SHARE_TOLERANCE,
) -> list[int]:
    """Copies per input (see the module docstring): the first ``m`` whose shares are all within
    ``tolerance`` of ``w / sum(w)``, else the closest with at most ``max_copies`` copies."""
    if len(frames) != len(weights) or not frames:
        raise ValueError("one weight per input")
    total_w = sum(weights)
    target = [w / total_w for w in weights]
    density = [w / f for w, f in zip(weights, frames, strict=True)]
    ratio = [d / min(density) for d in density]
    best, best_error = None, math.inf
    m = 1
    while True:
        copies = [max(1, round(m * r)) for r in ratio]
        if max(copies) > max_copies:
            break
        error = max(abs(s - t) for s, t in zip(shares(frames, copies), target, strict=True))
        if error < best_error - 1e-12:
            best, best_error = copies, error
        if error <= tolerance:
            break
        m += 1
    if best is None:
        need = max(1, round(max(ratio)))
        raise usage(
            "--max-copies",
            f"these weights need {need} copies of one input (frames {frames}, weights "
            f"{[float(w) for w in weights]}); raise --max-copies (now {max_copies}) or change "
            "the weights",
        )
    return best


# -- the command ------------------------------------------------------------------------------
def mix(
    inputs: list[tuple[str, float]],
    out: str | os.PathLike,
    *,
    max_copies: int = DEFAULT_MAX_COPIES,
) -> dict:
    """Merge ``inputs`` ((folder, weight) pairs, at least two) into a new dataset at ``out``;
    returns the record written to ``meta/wirecraft_mix.json``.  Every check happens before
    anything is written; a failure leaves nothing at ``out``."""
    from wirecraft.cli_args import _writable_parent, folder_built_beside
    from wirecraft.provenance import provenance

    out = Path(out)
    if len(inputs) < 2:
        raise usage("--input", f"mix needs at least two inputs, got {len(inputs)}")
    if isinstance(max_copies, bool) or not isinstance(max_copies, int) or max_copies < 1:
        raise usage("--max-copies", f"must be an integer >= 1, got {max_copies!r}")
    for path, weight in inputs:
        if not (isinstance(weight, int | float) and math.isfinite(weight) and weight > 0):
            raise usage("--input", f"{path}: the weight must be a finite number > 0, got {weight}")
    if out.exists() or out.is_symlink():
        raise usage("--out", f"{out} exists; name a new folder")
    why = _writable_parent(out / "x")
    if why:
        raise usage("--out", f"cannot create {out}: {why}")
    read = [read_input(path) for path, _ in inputs]
    resolved = [x["path"] for x in read]
    if str(out.resolve()) in resolved or any(
        out.resolve().is_relative_to(Path(p)) for p in resolved
    ):
        raise usage("--out", f"{out} is inside an input")
    check_compatible(read)
    collect, collect_note = common_collect(read)
    frames = [int(x["info"]["total_frames"]) for x in read]
    weights = [float(w) for _, w in inputs]
    copies = plan_copies(frames, weights, max_copies)
    achieved = shares(frames, copies)

    records, sources_out, start = [], dict.fromkeys(schema.SOURCES, 0), 0
    for x, w, c, s in zip(read, weights, copies, achieved, strict=True):
        count = dict.fromkeys(schema.SOURCES, 0)
        for name in x["episode_sources"]:
            count[name] += 1
        episodes = len(x["episode_sources"])
        for name in schema.SOURCES:
            sources_out[name] += c * count[name]
        records.append(
            {
                "path": x["path"],
                "sources": {k: v for k, v in count.items() if v},
                "source": "+".join(k for k, v in count.items() if v),
                "episodes": episodes,
                "frames": int(x["info"]["total_frames"]),
                "weight": w,
                "target_share": w / sum(weights),
                "copies": c,
                "share": s,
                # output episodes [first, last] of this input's copies, copy after copy
                "output_episodes": [start, start + c * episodes - 1],
                "collect_settings": (x["collect"] or {}).get("settings"),
            }
        )
        start += c * episodes
    record = {
        "format": MIX_FORMAT,
        "semantics": SEMANTICS,
        "inputs": records,
        "episodes": start,
        "frames": sum(c * f for c, f in zip(copies, frames, strict=True)),
        "sources": {k: v for k, v in sources_out.items() if v},
        "max_copies": max_copies,
        "share_tolerance": SHARE_TOLERANCE,
        "collect_settings": "kept" if collect else collect_note or "no input has any",
        "provenance": provenance(
            None,
            command="mix",
            inputs=[f"{p}:{w:g}" for p, w in zip(resolved, weights, strict=True)],
        ),
    }

    from lerobot.datasets.aggregate import aggregate_datasets

    from wirecraft.datasets.writer import quiet_writing, write_json_atomic

    quiet_writing()
    with folder_built_beside(out, "mix") as tmp:
        roots = [Path(x["path"]) for x, c in zip(read, copies, strict=True) for _ in range(c)]
        aggregate_datasets([REPO_ID] * len(roots), REPO_ID, roots=roots, aggr_root=tmp)
        info = _read_json(tmp / INFO_FILE, "--out")
        if (info.get("total_episodes"), info.get("total_frames")) != (
            record["episodes"],
            record["frames"],
        ):
            raise RuntimeError(
                f"LeRobot's aggregate wrote {info.get('total_episodes')} episodes and "
                f"{info.get('total_frames')} frames, expected {record['episodes']} and "
                f"{record['frames']}"
            )
        if collect is not None:
            write_json_atomic(tmp / COLLECT_FILE, collect)
        write_json_atomic(tmp / MIX_FILE, record)
    return record


def summary_lines(record: dict, out: str | os.PathLike) -> list[str]:
    lines = [
        f"{out}: {record['episodes']} episodes, {record['frames']} frames "
        f"({', '.join(f'{k} {v}' for k, v in record['sources'].items())} episodes)"
    ]
    for x in record["inputs"]:
        lines.append(
            f"  {x['path']} ({x['source']}, {x['episodes']} episodes, {x['frames']} frames): "
            f"weight {x['weight']:g}, {x['copies']} cop{'y' if x['copies'] == 1 else 'ies'}, "
            f"{100 * x['share']:.1f}% of the frames (target {100 * x['target_share']:.1f}%)"
        )
    if record["collect_settings"] != "kept":
        lines.append(
            f"  no {COLLECT_FILE}: {record['collect_settings']} (lerobot-train reads the "
            "dataset; wirecraft train needs the settings)"
        )
    return lines
