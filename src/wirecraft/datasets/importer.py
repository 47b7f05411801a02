"""``wirecraft import``: a LeRobot v3 dataset recorded elsewhere (a real robot cell,
teleoperation in another tool) converted into the shared schema (``schema.features_for``),
source ``real`` or ``teleop``.

A map (a TOML file, ``load_map``; keys in ``MAP_KEYS`` and docs/datasets.md) says where the
foreign dataset keeps what the schema needs and in which units:

- ``state`` / ``action``: the foreign features of the joint angles and the joint targets;
  ``joint_order`` picks the robot's joints 1..dof from them (indices or names of the foreign
  vector), ``joint_units`` (``rad`` | ``deg``), then ``q = joint_sign * q_foreign +
  joint_offset`` (offsets in rad, after the unit conversion);
- the gripper: ``gripper_state`` / ``gripper_action`` (default: the ``state`` / ``action``
  feature) at ``gripper_index`` (``gripper_action_index``, default the same), in
  ``gripper_units``: ``fraction`` (0 closed ... 1 open, times the robot gripper's
  ``max_opening``; ``gripper_closed_is_one`` flips it), ``m`` or ``mm`` of pad gap;
- ``cameras``: foreign image feature -> ``side`` / ``wrist`` (``schema.CAMERAS``, both needed),
  resized to ``image_size`` (default: the foreign size, if square) after a centred square crop;
- ``fps`` of the output (a divisor of 60, at most the foreign fps; default: the foreign fps);
- ``task`` (family: which success flags the features carry), ``success`` and ``flags`` (foreign
  boolean features for the family's flags; the others are written false and listed as not
  recorded in ``meta/wirecraft_import.json``), ``instruction`` (the language instruction;
  default: the foreign frame's task string), ``control`` (the control mode whose action size
  ``action.env`` has; default ``cartesian``, what ``wirecraft collect`` records, so that the
  output has the features of a collected dataset and ``wirecraft mix`` takes both).

Resampling (zero-order hold, nearest earlier frame): foreign frames are ``1 / F`` s apart,
output frames ``1 / f`` s apart (``f <= F``; upsampling is refused: it would repeat foreign
frames and add no information).  Output frame ``j`` covers ``[j / f, (j + 1) / f)``; as in
``recorder`` its observation (state, images, flags) is the foreign frame at or just before
``j / f`` (index ``floor(j F / f)``) and its action the foreign action in effect at the end of
the period, i.e. that of the last foreign frame before ``(j + 1) / f`` (index
``ceil((j + 1) F / f) - 1``): the target that drives the robot to the next output frame.  An
episode of ``n`` foreign frames gives ``floor(n f / F)`` frames (a period cut short is not
written); at ``f = F`` every frame is kept as it is.

What a foreign dataset cannot provide:

- ``action.env`` (the actions passed to ``env.step``) is written as NaN: no simulated
  environment was stepped, so there is nothing to replay exactly (replaying it fails loudly:
  ``env.step`` refuses non-finite actions).  ``action`` (absolute joint targets) replays
  under ``joint`` control like any dataset's (``evaluation.policies.joint_action``);
- ``observation.cartesian_state`` is computed from the converted joint angles by the robot
  model's forward kinematics in MuJoCo (``schema.cartesian_state``, the recorder's function,
  on a model holding only the robot);
- ``seed`` is ``schema.NO_SEED``.

Every mismatch between the map and the dataset (a missing feature, a joint count other than
the robot's dof, an index out of range, an unknown unit, a missing camera, an fps that does
not divide 60, joints outside the robot's limits or a gripper gap outside its range after
conversion, ...) is collected, and one ValueError lists them, one per line.  The dataset is
written into a temporary folder beside ``out`` and renamed into place when complete; any
failure removes it.
"""

from __future__ import annotations

import json
import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wirecraft.datasets import schema

IMPORT_FILE = "meta/wirecraft_import.json"
IMPORT_FORMAT = 1
INFO_FILE = "meta/info.json"
REPO_ID = "wirecraft/local"
IMPORT_SOURCES = ("real", "teleop")
JOINT_UNITS = {"rad": 1.0, "deg": math.pi / 180.0}  # rad per unit
GRIPPER_UNITS = {"fraction": None, "m": 1.0, "mm": 1e-3}  # m per unit (fraction: max_opening)
NUMERIC = ("float16", "float32", "float64", "int8", "int16", "int32", "int64", "uint8", "uint16")
IMAGES = ("video", "image")
# Beyond a joint limit (rad) or the gripper's range (m): float rounding of the foreign values.
RANGE_TOLERANCE = 1e-6
DEFAULT_CONTROL = "cartesian"
RESAMPLING = (
    "zero-order hold (nearest earlier foreign frame): output frame j's observation is foreign "
    "frame floor(j F / f), its action that of foreign frame ceil((j + 1) F / f) - 1 (the last "
    "before the next output frame); an episode of n foreign frames gives floor(n f / F) frames"
)
ENV_ACTION_NOTE = (
    "NaN: no simulated environment was stepped, so there are no environment actions to replay; "
    "`action` holds the joint targets"
)
CARTESIAN_NOTE = (
    "forward kinematics of the converted joint angles on the robot's MuJoCo model "
    "(schema.cartesian_state, as the recorder computes it)"
)
# The map's keys: key -> what it takes (the docs' table says the same).
MAP_KEYS = {
    "state": "foreign feature of the joint angles (required)",
    "action": "foreign feature of the joint targets (required)",
    "joint_order": "dof indices or names into the foreign vectors, our joint1 first "
    "(default: the first dof entries)",
    "joint_units": "rad | deg (required)",
    "joint_sign": "dof values, +1 or -1 (default all +1)",
    "joint_offset": "dof values in rad, added after units and sign (default 0)",
    "gripper_state": "foreign feature of the gripper reading (default: state)",
    "gripper_action": "foreign feature of the gripper command (default: action)",
    "gripper_index": "index or name in gripper_state (default 0 for a 1-value feature)",
    "gripper_action_index": "index or name in gripper_action (default: gripper_index)",
    "gripper_units": "fraction | m | mm (required)",
    "gripper_closed_is_one": "true: fraction 1 is closed (default false: 1 is open)",
    "cameras": "table: foreign image feature -> side | wrist (both required)",
    "image_size": "output image size in pixels (default: the foreign size, if square)",
    "fps": "output frame rate, a divisor of 60, <= the foreign fps (default: the foreign fps)",
    "task": "task family for the success flags (default: --task, else the first family)",
    "success": "foreign boolean feature written as success (default: false throughout)",
    "flags": "table: the family's other flag -> foreign boolean feature",
    "instruction": "language instruction of every episode (default: the foreign task string)",
    "control": "control mode that sizes action.env (default cartesian)",
}


def usage(flag: str, message: str) -> ValueError:
    return ValueError(f"{flag}: {message}")


def load_map(path: str | os.PathLike) -> dict:
    """The map in the TOML file at ``path`` (ValueError ``--map: ...`` where it cannot be read)."""
    path = Path(path)
    if not path.is_file():
        raise usage("--map", f"{path} is not a file (a TOML map)")
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except OSError as err:
        raise usage("--map", f"{path}: unreadable ({err})") from None
    except tomllib.TOMLDecodeError as err:
        raise usage("--map", f"{path} is not valid TOML: {err}") from None


# -- the foreign dataset's description -------------------------------------------------------
def read_info(source_dir: str | os.PathLike) -> dict:
    """``meta/info.json`` of the foreign dataset (ValueError ``--from: ...`` where it is not a
    complete LeRobot v3.0 dataset on disk)."""
    root = Path(source_dir)
    if not root.is_dir():
        raise usage("--from", f"{source_dir} is not a folder (a LeRobot dataset)")
    path = root / INFO_FILE
    if not path.is_file():
        raise usage("--from", f"{source_dir} is not a LeRobot dataset (no {INFO_FILE})")
    try:
        info = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise usage("--from", f"{path}: unreadable ({err})") from None
    if info.get("codebase_version") != "v3.0":
        raise usage(
            "--from",
            f"{source_dir} is a LeRobot {info.get('codebase_version')} dataset; import reads "
            "v3.0 (convert it with LeRobot's conversion script first)",
        )
    if not isinstance(info.get("features"), dict) or not info.get("fps"):
        raise usage("--from", f"{path} has no features or no fps")
    if not info.get("total_episodes"):
        raise usage("--from", f"{source_dir} holds no episodes")
    for folder in ("data", "meta/episodes"):
        if not any((root / folder).rglob("*.parquet")):
            raise usage("--from", f"{source_dir} has no {folder}/**/*.parquet (incomplete copy?)")
    return info


def _names(feature: dict) -> list[str] | None:
    """A feature's entry names: a list, or a dict holding one list (older datasets)."""
    names = feature.get("names")
    if isinstance(names, dict) and len(names) == 1:
        names = next(iter(names.values()))
    if isinstance(names, list) and all(isinstance(n, str) for n in names):
        return names
    return None


def _width(feature: dict) -> int | None:
    """Entries of a 1-D numeric feature (None for anything else)."""
    shape = list(feature.get("shape") or [])
    if feature.get("dtype") not in (*NUMERIC, "bool") or len(shape) > 1:
        return None
    return int(shape[0]) if shape else 1


@dataclass
class Plan:
    """The map resolved against one foreign dataset: where each value comes from."""

    robot: str
    dof: int
    fps_in: int
    fps: int
    task: str
    control: str
    image_size: int
    state_key: str = ""
    action_key: str = ""
    state_idx: list[int] = field(default_factory=list)
    action_idx: list[int] = field(default_factory=list)
    joint_scale: float = 1.0
    joint_sign: np.ndarray | None = None
    joint_offset: np.ndarray | None = None
    gripper_state_key: str = ""
    gripper_action_key: str = ""
    gripper_state_idx: int = 0
    gripper_action_idx: int = 0
    gripper_units: str = "m"
    gripper_closed_is_one: bool = False
    max_opening: float = 0.0
    cameras: dict[str, str] = field(default_factory=dict)  # our camera -> foreign key
    camera_sizes: dict[str, tuple[int, int]] = field(default_factory=dict)  # (height, width)
    flags: dict[str, str | None] = field(default_factory=dict)  # our flag -> foreign key
    instruction: str | None = None

    def numeric_keys(self) -> list[str]:
        keys = [self.state_key, self.action_key, self.gripper_state_key, self.gripper_action_key]
        keys += [k for k in self.flags.values() if k]
        return list(dict.fromkeys(keys))

    def resolved(self) -> dict:
        """What the map resolved to (for ``meta/wirecraft_import.json``)."""
        return {
            "state": {"feature": self.state_key, "indices": self.state_idx},
            "action": {"feature": self.action_key, "indices": self.action_idx},
            "joint_scale_rad_per_unit": self.joint_scale,
            "joint_sign": [float(v) for v in self.joint_sign],
            "joint_offset_rad": [float(v) for v in self.joint_offset],
            "gripper_state": {"feature": self.gripper_state_key, "index": self.gripper_state_idx},
            "gripper_action": {
                "feature": self.gripper_action_key,
                "index": self.gripper_action_idx,
            },
            "gripper_units": self.gripper_units,
            "gripper_closed_is_one": self.gripper_closed_is_one,
            "max_opening_m": self.max_opening,
            "cameras": {schema.CAMERAS[c]: k for c, k in self.cameras.items()},
            "flags": dict(self.flags),
        }

    # -- conversion ----------------------------------------------------------------------------
    def joints(self, raw: np.ndarray, indices: list[int]) -> np.ndarray:
        """(T, dof) joint angles in rad from the foreign (T, width) vectors."""
        picked = raw[:, indices].astype(np.float64) * self.joint_scale
        return picked * self.joint_sign + self.joint_offset

    def gripper(self, raw: np.ndarray, index: int) -> np.ndarray:
        """(T,) pad gap in m from the foreign (T, width) vectors."""
        value = raw[:, index].astype(np.float64)
        if self.gripper_units == "fraction":
            fraction = 1.0 - value if self.gripper_closed_is_one else value
            return fraction * self.max_opening
        return value * GRIPPER_UNITS[self.gripper_units]


def _one_of(value, options) -> bool:
    """``value in options`` for any TOML value (a list or table is never one)."""
    return isinstance(value, str) and value in options


class _Problems(list):
    def add(self, key: str, message: str) -> None:
        self.append(f"{key}: {message}")


def _feature(problems, features, key, what, kinds, mapping_key) -> dict | None:
    """The foreign feature ``features[key]`` if it exists and has a dtype in ``kinds``."""
    if not isinstance(key, str) or not key:
        problems.add(mapping_key, f"must name a foreign feature ({what}), got {key!r}")
        return None
    if key not in features:
        problems.add(
            mapping_key,
            f"the foreign dataset has no feature {key!r} ({what}); it has "
            f"{', '.join(sorted(features))}",
        )
        return None
    feature = features[key]
    if feature.get("dtype") not in kinds:
        problems.add(
            mapping_key,
            f"foreign feature {key!r} is {feature.get('dtype')}, expected {' or '.join(kinds)} "
            f"({what})",
        )
        return None
    return feature


def _index(problems, entry, key, feature, mapping_key) -> int | None:
    """One entry (an index or a name) of the 1-D foreign feature ``key``."""
    width = _width(feature)
    if width is None:
        problems.add(
            mapping_key, f"foreign feature {key!r} is not a vector (shape {feature.get('shape')})"
        )
        return None
    if isinstance(entry, bool) or not isinstance(entry, int | str):
        problems.add(mapping_key, f"entries are indices or names, got {entry!r}")
        return None
    if isinstance(entry, str):
        names = _names(feature)
        if names is None:
            problems.add(mapping_key, f"{entry!r}: foreign feature {key!r} has no entry names")
            return None
        if entry not in names:
            problems.add(
                mapping_key,
                f"{entry!r} is not an entry of foreign feature {key!r} (names: {', '.join(names)})",
            )
            return None
        return names.index(entry)
    if not 0 <= entry < width:
        problems.add(
            mapping_key,
            f"index {entry} out of range for foreign feature {key!r} "
            f"({width} entries: 0..{width - 1})",
        )
        return None
    return entry


def _numbers(problems, mapping, key, dof, default, check) -> np.ndarray:
    values = mapping.get(key, default)
    ok = isinstance(values, list) and all(
        not isinstance(v, bool) and isinstance(v, int | float) and math.isfinite(v) for v in values
    )
    if not ok:
        problems.add(key, f"must be a list of {dof} numbers, got {values!r}")
        return np.asarray(default, float)
    if len(values) != dof:
        problems.add(key, f"has {len(values)} values, the robot has {dof} joints")
        return np.asarray(default, float)
    bad = [v for v in values if not check(v)]
    if bad:
        problems.add(key, f"values must be +1 or -1, got {bad}")
    return np.asarray(values, float)


def plan_import(
    mapping: dict, info: dict, *, robot: str, task: str | None = None
) -> tuple[Plan | None, list[str]]:
    """Resolve ``mapping`` against the foreign dataset's ``info.json``: (the plan, []) or
    (None, one line per mismatch).  Checks the map's structure only; ``import_dataset`` then
    checks the values."""
    from wirecraft.assets.robots import ROBOTS
    from wirecraft.envs.env import steps_per_frame
    from wirecraft.tasks import TASKS, default_family

    problems = _Problems()
    spec = ROBOTS.get(robot)
    dof = spec.dof
    features = info["features"]
    fps_in = info["fps"]
    if not isinstance(mapping, dict):
        return None, [f"the map must be a table of keys, got {type(mapping).__name__}"]
    for key in mapping:
        if key not in MAP_KEYS:
            problems.add(key, f"unknown map key (valid: {', '.join(MAP_KEYS)})")

    # task family, control mode, frame rate
    family = task if task is not None else mapping.get("task", default_family())
    if not _one_of(family, TASKS.names()):
        problems.add("task", f"unknown task family {family!r} (valid: {', '.join(TASKS.names())})")
        family = default_family()
    control = mapping.get("control", DEFAULT_CONTROL)
    if not _one_of(control, schema.ARM_ACTION_DIMS):
        problems.add(
            "control",
            f"unknown control mode {control!r} (valid: {', '.join(schema.ARM_ACTION_DIMS)})",
        )
        control = DEFAULT_CONTROL
    fps = mapping.get("fps", fps_in)
    try:
        steps_per_frame(fps)
        if fps > fps_in:
            problems.add(
                "fps",
                f"{fps} is above the foreign dataset's {fps_in} fps: upsampling would repeat "
                f"foreign frames (no new information) and is refused; use {fps_in} or less",
            )
    except ValueError as err:
        where = "fps" if "fps" in mapping else f"fps (the foreign dataset's {fps_in})"
        problems.add(where, str(err))
        fps = fps_in

    plan = Plan(
        robot=robot,
        dof=dof,
        fps_in=int(fps_in),
        fps=int(fps) if isinstance(fps, int | float) and not isinstance(fps, bool) else 0,
        task=family,
        control=control,
        image_size=0,
        max_opening=float(spec.gripper_spec.max_opening),
    )

    # joints
    found_ft = {}
    for side, what in (("state", "joint angles"), ("action", "joint targets")):
        if side not in mapping:
            problems.add(side, f"required: the foreign feature of the {what}")
            found_ft[side] = None
            continue
        ft = _feature(problems, features, mapping[side], what, NUMERIC, side)
        width = None if ft is None else _width(ft)
        if ft is not None and "joint_order" not in mapping and (width or 0) < dof:
            problems.add(
                side,
                f"foreign feature {mapping[side]!r} has "
                + (f"{width} entries" if width else f"shape {ft.get('shape')}")
                + f", the robot {robot} has {dof} joints (or give joint_order)",
            )
            ft = None
        found_ft[side] = ft
    state, action = mapping.get("state"), mapping.get("action")
    state_ft, action_ft = found_ft["state"], found_ft["action"]
    order = mapping.get("joint_order", list(range(dof)))
    if not isinstance(order, list):
        problems.add("joint_order", f"must be a list of {dof} indices or names, got {order!r}")
        order = None
    elif len(order) != dof:
        problems.add(
            "joint_order", f"names {len(order)} joints, the robot {robot} has {dof} ({order!r})"
        )
        order = None
    elif len({json.dumps(e) for e in order}) != len(order):
        problems.add("joint_order", f"names a joint twice: {order!r}")
        order = None
    for key, ft, target in ((state, state_ft, "state_idx"), (action, action_ft, "action_idx")):
        if ft is None or order is None:
            continue
        found = _Problems()
        indices = [_index(found, e, key, ft, "joint_order") for e in order]
        if found:  # one line per feature, naming every bad entry
            problems.append(found[0] if len(found) == 1 else "; ".join(found))
        else:
            setattr(plan, target, indices)
    plan.state_key = state if state_ft is not None else ""
    plan.action_key = action if action_ft is not None else ""
    units = mapping.get("joint_units")
    if not _one_of(units, JOINT_UNITS):
        problems.add(
            "joint_units",
            f"{'required' if units is None else f'unknown unit {units!r}'} "
            f"(valid: {', '.join(JOINT_UNITS)})",
        )
    else:
        plan.joint_scale = JOINT_UNITS[units]
    plan.joint_sign = _numbers(
        problems, mapping, "joint_sign", dof, [1.0] * dof, lambda v: v in (1, -1)
    )
    plan.joint_offset = _numbers(
        problems, mapping, "joint_offset", dof, [0.0] * dof, lambda v: True
    )

    # gripper
    g_units = mapping.get("gripper_units")
    if not _one_of(g_units, GRIPPER_UNITS):
        problems.add(
            "gripper_units",
            f"{'required' if g_units is None else f'unknown unit {g_units!r}'} "
            f"(valid: {', '.join(GRIPPER_UNITS)})",
        )
    else:
        plan.gripper_units = g_units
    closed_is_one = mapping.get("gripper_closed_is_one", False)
    if not isinstance(closed_is_one, bool):
        problems.add("gripper_closed_is_one", f"must be true or false, got {closed_is_one!r}")
    elif closed_is_one and g_units in ("m", "mm"):
        problems.add(
            "gripper_closed_is_one", f"applies to gripper_units = 'fraction' only, not {g_units!r}"
        )
    else:
        plan.gripper_closed_is_one = closed_is_one
    unnamed = []  # gripper features of several entries without an index
    for side, joints_key, joints_ft, joints_idx in (
        ("state", state, state_ft, plan.state_idx),
        ("action", action, action_ft, plan.action_idx),
    ):
        map_key = f"gripper_{side}"
        if map_key not in mapping and joints_ft is None:
            continue  # the state / action feature's mismatch is reported already
        key = mapping.get(map_key, joints_key)
        ft = _feature(problems, features, key, f"gripper {side}", NUMERIC, map_key)
        if ft is None:
            continue
        index_key = "gripper_index" if side == "state" else "gripper_action_index"
        entry = mapping.get(index_key, mapping.get("gripper_index"))
        if entry is None:
            if _width(ft) != 1:
                unnamed.append(f"{key!r} has {_width(ft)} entries")
                continue
            entry = 0
        index = _index(problems, entry, key, ft, index_key)
        if index is None:
            continue
        if key == joints_key and index in joints_idx:
            problems.add(
                index_key,
                f"entry {index} of foreign feature {key!r} is joint{joints_idx.index(index) + 1} "
                "in joint_order",
            )
            continue
        if side == "state":
            plan.gripper_state_key, plan.gripper_state_idx = key, index
        else:
            plan.gripper_action_key, plan.gripper_action_idx = key, index

    if unnamed:  # one line: a single gripper_index names both
        problems.add(
            "gripper_index",
            f"required: foreign feature {' and '.join(unnamed)}; which entry is the gripper?",
        )

    # cameras
    cameras = mapping.get("cameras")
    if not isinstance(cameras, dict):
        problems.add(
            "cameras",
            f"required: a table of foreign image feature -> {' / '.join(schema.CAMERAS)}"
            + ("" if cameras is None else f", got {cameras!r}"),
        )
        cameras = {}
    for key, camera in cameras.items():
        if not _one_of(camera, schema.CAMERAS):
            problems.add(
                "cameras",
                f"{key!r} = {camera!r}: not one of our cameras ({', '.join(schema.CAMERAS)})",
            )
            continue
        if camera in plan.cameras:
            problems.add(
                "cameras", f"{camera!r} is mapped twice ({plan.cameras[camera]!r}, {key!r})"
            )
            continue
        ft = _feature(problems, features, key, f"the {camera} camera", IMAGES, "cameras")
        if ft is None:
            continue
        shape, names = list(ft.get("shape") or []), ft.get("names") or []
        if len(shape) != 3 or 3 not in (shape[0], shape[-1]):
            problems.add("cameras", f"foreign feature {key!r} has shape {shape}, not an RGB image")
            continue
        channels_first = shape[0] == 3 and not (names and str(names[-1]).startswith("channel"))
        height, width = (shape[1], shape[2]) if channels_first else (shape[0], shape[1])
        plan.cameras[camera] = key
        plan.camera_sizes[camera] = (int(height), int(width))
    images = [k for k, v in features.items() if v.get("dtype") in IMAGES]
    for camera in schema.CAMERAS:
        if camera not in plan.cameras and not any(v == camera for v in cameras.values()):
            problems.add(
                "cameras",
                f"camera {camera!r} ({schema.CAMERAS[camera]}) is not mapped; foreign image "
                f"features: {', '.join(images) or 'none'}",
            )
    size = mapping.get("image_size")
    if size is None:
        sizes = set(plan.camera_sizes.values())
        if len(sizes) == 1 and next(iter(sizes))[0] == next(iter(sizes))[1]:
            size = next(iter(sizes))[0]
        elif sizes:
            problems.add(
                "image_size",
                f"required: the foreign cameras are {sorted(sizes)} (height, width), not one "
                "square size",
            )
    if size is not None:
        if isinstance(size, bool) or not isinstance(size, int) or size < 16:
            problems.add("image_size", f"must be an integer >= 16, got {size!r}")
        else:
            plan.image_size = size

    # success flags
    flag_names = schema.success_flags(family)
    plan.flags = dict.fromkeys(flag_names)
    flags = mapping.get("flags", {})
    if not isinstance(flags, dict):
        problems.add("flags", f"must be a table of flag -> foreign feature, got {flags!r}")
        flags = {}
    if "success" in mapping:
        if "success" in flags:
            problems.add("success", "given twice (also in flags)")
        flags = {"success": mapping["success"], **flags}
    for flag, key in flags.items():
        where = "success" if flag == "success" and "success" in mapping else f"flags.{flag}"
        if flag not in flag_names:
            problems.add(
                where,
                f"{flag!r} is not a success flag of task family {family} ({', '.join(flag_names)})",
            )
            continue
        ft = _feature(problems, features, key, f"the {flag} flag", (*NUMERIC, "bool"), where)
        if ft is not None and _width(ft) != 1:
            problems.add(
                where, f"foreign feature {key!r} has shape {ft.get('shape')}, not one value"
            )
        elif ft is not None:
            plan.flags[flag] = key
    instruction = mapping.get("instruction")
    if instruction is not None and (not isinstance(instruction, str) or not instruction.strip()):
        problems.add("instruction", f"must be a non-empty string, got {instruction!r}")
    else:
        plan.instruction = instruction
    return (None if problems else plan), list(problems)


def _mismatches(problems: list[str], source_dir) -> ValueError:
    n = len(problems)
    lines = "\n".join(f"  {p}" for p in problems)
    return usage(
        "--map",
        f"{n} mismatch{'es' if n > 1 else ''} between the map and {source_dir} "
        f"(one per line, map key first):\n{lines}",
    )


# -- reading and checking the values ---------------------------------------------------------
@dataclass
class ForeignEpisode:
    """One foreign episode's rows (positions in the foreign dataset) and the chosen frames."""

    index: int  # foreign episode_index
    rows: np.ndarray  # (n,) dataset rows, in frame order
    obs: np.ndarray  # (m,) positions in ``rows`` of the output frames' observations
    act: np.ndarray  # (m,) positions in ``rows`` of their actions


def resample(n: int, fps_in: int, fps: int) -> tuple[np.ndarray, np.ndarray]:
    """Foreign frame indices (observation, action) of each output frame (module docstring)."""
    m = (n * fps) // fps_in
    j = np.arange(m, dtype=np.int64)
    obs = (j * fps_in) // fps
    act = ((j + 1) * fps_in + fps - 1) // fps - 1
    return obs, act


def _columns(dataset, keys: list[str]) -> dict[str, np.ndarray]:
    table = dataset.hf_dataset.select_columns([*keys, "episode_index", "frame_index"])
    table = table.with_format("numpy")
    n = len(table)
    out = {}
    for key in [*keys, "episode_index", "frame_index"]:
        out[key] = np.asarray(table[key]).reshape(n, -1)
    return out


def _episodes(columns: dict, plan: Plan, problems: _Problems) -> list[ForeignEpisode]:
    episode_index = columns["episode_index"][:, 0]
    frame_index = columns["frame_index"][:, 0]
    episodes = []
    for e in np.unique(episode_index).tolist():
        rows = np.flatnonzero(episode_index == e)
        rows = rows[np.argsort(frame_index[rows], kind="stable")]
        if not np.array_equal(frame_index[rows], np.arange(len(rows))):
            problems.add(
                "--from", f"foreign episode {e}: frame_index is not 0..{len(rows) - 1} in order"
            )
            continue
        obs, act = resample(len(rows), plan.fps_in, plan.fps)
        episodes.append(ForeignEpisode(int(e), rows, obs, act))
    return episodes


def _first_outside(values: np.ndarray, low, high, episodes, positions: str):
    """(episode, foreign frame, column, value, count) of the first value outside [low, high]
    (or not finite) over the chosen frames of ``episodes``; None if all are inside."""
    count, first = 0, None
    for ep in episodes:
        frames = getattr(ep, positions)
        chosen = values[ep.rows[frames]]
        bad = (
            ~np.isfinite(chosen)
            | (chosen < low - RANGE_TOLERANCE)
            | (chosen > high + RANGE_TOLERANCE)
        )
        count += int(bad.any(axis=-1).sum()) if bad.ndim > 1 else int(bad.sum())
        if first is None and bad.any():
            flat = np.argwhere(bad.reshape(len(chosen), -1))[0]
            t, col = int(flat[0]), int(flat[1])
            first = (ep.index, int(frames[t]), col, float(chosen.reshape(len(chosen), -1)[t, col]))
    return None if first is None else (*first, count)


def check_values(
    plan: Plan, columns: dict, episodes: list[ForeignEpisode]
) -> tuple[dict, list[str]]:
    """The converted joints and gaps of every foreign row, and one line per kind of value
    outside the robot's range (the first offending episode and frame named)."""
    from wirecraft.assets.robots import ROBOTS

    spec = ROBOTS.get(plan.robot)
    lower, upper = spec.lower, spec.upper
    problems = _Problems()
    converted = {
        "state": plan.joints(columns[plan.state_key], plan.state_idx),
        "action": plan.joints(columns[plan.action_key], plan.action_idx),
        "gripper_state": plan.gripper(columns[plan.gripper_state_key], plan.gripper_state_idx),
        "gripper_action": plan.gripper(columns[plan.gripper_action_key], plan.gripper_action_idx),
    }
    joint_keys = "joint_units / joint_sign / joint_offset / joint_order"
    for side, positions in (("state", "obs"), ("action", "act")):
        found = _first_outside(converted[side], lower, upper, episodes, positions)
        if found:
            e, frame, col, value, count = found
            key = plan.state_key if side == "state" else plan.action_key
            problems.add(
                side,
                f"foreign feature {key!r} gives joint{col + 1} = {value:.6g} rad after "
                f"conversion ({joint_keys}), outside the {plan.robot}'s limits "
                f"[{lower[col]:.6g}, {upper[col]:.6g}] (first at foreign episode {e}, frame "
                f"{frame}; {count} frame{'s' if count > 1 else ''} in all)",
            )
    for side, positions in (("state", "obs"), ("action", "act")):
        name = f"gripper_{side}"
        found = _first_outside(converted[name], 0.0, plan.max_opening, episodes, positions)
        if found:
            e, frame, _, value, count = found
            key = plan.gripper_state_key if side == "state" else plan.gripper_action_key
            problems.add(
                name,
                f"foreign feature {key!r} gives a pad gap of {value:.6g} m (gripper_units = "
                f"{plan.gripper_units!r}), outside [0, {plan.max_opening:g}] (first at foreign "
                f"episode {e}, frame {frame}; {count} frame{'s' if count > 1 else ''} in all)",
            )
    return converted, list(problems)


# -- writing ---------------------------------------------------------------------------------
def _fk_model(robot: str):
    """The robot alone, for forward kinematics: (handle, model, data)."""
    import mujoco

    from wirecraft.assets.robots import add_robot
    from wirecraft.scene import compile_spec, new_spec

    spec = new_spec(f"import_{robot}")
    handle = add_robot(spec, robot, side_camera=False, keyframe=False)
    model = compile_spec(spec)
    return handle, model, mujoco.MjData(model)


def cartesian_states(fk, joints: np.ndarray) -> np.ndarray:
    """(T, 7) ``observation.cartesian_state`` of (T, dof) joint angles (``_fk_model``)."""
    import mujoco

    handle, model, data = fk
    arm = handle.index(model).arm_qpos
    out = np.empty((len(joints), 7))
    for t, q in enumerate(joints):
        data.qpos[arm] = q
        mujoco.mj_kinematics(model, data)
        out[t] = schema.cartesian_state(handle, model, data)
    return out


def _image(item, key: str, size: int) -> np.ndarray:
    """(size, size, 3) uint8 of a decoded foreign image (CHW or HWC, uint8 or float in
    [0, 1]), centre-cropped to a square and resized (bilinear) where it differs."""
    array = item[key]
    array = array.numpy() if hasattr(array, "numpy") else np.asarray(array)
    if array.ndim == 3 and array.shape[0] == 3 and array.shape[-1] != 3:
        array = np.moveaxis(array, 0, -1)
    if array.dtype != np.uint8:
        array = np.clip(np.rint(array.astype(np.float64) * 255.0), 0, 255).astype(np.uint8)
    height, width = array.shape[:2]
    if (height, width) == (size, size):
        return np.ascontiguousarray(array)
    from PIL import Image

    side = min(height, width)
    top, left = (height - side) // 2, (width - side) // 2
    crop = Image.fromarray(np.ascontiguousarray(array[top : top + side, left : left + side]))
    return np.asarray(crop.resize((size, size), Image.Resampling.BILINEAR))


def _read_frame(dataset, row: int, source_dir) -> dict:
    """Row ``row`` of the foreign dataset with its images decoded."""
    try:
        return dataset[row]
    except Exception as err:  # a damaged video or data file
        raise usage(
            "--from", f"{source_dir}: frame {row} cannot be read ({type(err).__name__}: {err})"
        ) from None


def import_dataset(
    source_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    source: str,
    robot: str,
    mapping: dict,
    task: str | None = None,
    progress: bool = True,
    map_file: str | os.PathLike | None = None,
) -> dict:
    """Convert the foreign LeRobot v3 dataset at ``source_dir`` into a new dataset of the shared
    schema at ``out_dir`` (module docstring); returns the record written to
    ``meta/wirecraft_import.json``.  ``task``: the task family (overrides the map's ``task``);
    ``map_file``: where the map came from (recorded only)."""
    from wirecraft.assets.robots import ROBOTS
    from wirecraft.cli_args import _writable_parent, folder_built_beside
    from wirecraft.provenance import provenance

    if source not in IMPORT_SOURCES:
        raise usage("--source", f"must be one of {', '.join(IMPORT_SOURCES)}, got {source!r}")
    if robot not in ROBOTS.names():
        raise usage("--robot", f"unknown robot {robot!r} (valid: {', '.join(ROBOTS.names())})")
    out = Path(out_dir)
    if out.is_symlink() or (out.exists() and (not out.is_dir() or any(out.iterdir()))):
        raise usage("--out", f"{out} exists and is not an empty folder; name a new folder")
    why = _writable_parent(out / "x")
    if why:
        raise usage("--out", f"cannot create {out}: {why}")
    info = read_info(source_dir)
    root = Path(source_dir).resolve()
    if out.resolve().is_relative_to(root):
        raise usage("--out", f"{out} is inside the foreign dataset {source_dir}")
    if task is not None:
        from wirecraft.tasks import TASKS

        if task not in TASKS.names():
            raise usage(
                "--task", f"unknown task family {task!r} (valid: {', '.join(TASKS.names())})"
            )
    plan, problems = plan_import(mapping, info, robot=robot, task=task)
    if problems:
        raise _mismatches(problems, source_dir)
    for key in plan.cameras.values():
        if info["features"][key]["dtype"] == "video" and not any(
            (root / "videos" / key).rglob("*.mp4")
        ):
            raise usage("--from", f"{source_dir} has no videos of {key} (videos/{key}/**/*.mp4)")

    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from wirecraft.datasets.writer import VIDEO_BACKEND

    try:
        foreign = LeRobotDataset(REPO_ID, root=root, video_backend=VIDEO_BACKEND, return_uint8=True)
        columns = _columns(foreign, plan.numeric_keys())
    except Exception as err:  # any reading failure: a damaged or incomplete dataset
        raise usage(
            "--from", f"{source_dir}: cannot be read by LeRobot ({type(err).__name__}: {err})"
        ) from None
    value_problems = _Problems()
    episodes = _episodes(columns, plan, value_problems)
    converted, found = check_values(plan, columns, episodes)
    value_problems += found
    if value_problems:
        raise _mismatches(list(value_problems), source_dir)
    kept = [ep for ep in episodes if len(ep.obs)]
    skipped = [ep.index for ep in episodes if not len(ep.obs)]
    if not kept:
        raise usage(
            "fps",
            f"every foreign episode is shorter than one output frame at {plan.fps} fps "
            f"({plan.fps_in / plan.fps:g} foreign frames)",
        )
    tasks = {int(i): str(t) for t, i in foreign.meta.tasks["task_index"].items()}
    task_index = np.asarray(foreign.hf_dataset.with_format("numpy")["task_index"]).reshape(-1)

    features = schema.features_for(
        robot,
        plan.image_size,
        task=plan.task,
        control=plan.control,
        steps_per_frame=60 // plan.fps,
    )
    env_width = features[schema.ENV_ACTION_KEY]["shape"][0]
    record: dict = {
        "format": IMPORT_FORMAT,
        "source": source,
        "robot": robot,
        "task": plan.task,
        "control": plan.control,
        "fps": plan.fps,
        "image_size": plan.image_size,
        "from": {
            "path": str(root),
            "fps": plan.fps_in,
            "robot_type": info.get("robot_type"),
            "episodes": int(info["total_episodes"]),
            "frames": int(info.get("total_frames") or len(columns["episode_index"])),
            "features": sorted(info["features"]),
        },
        "map": mapping,
        "map_file": str(Path(map_file).resolve()) if map_file else None,
        "resolved": plan.resolved(),
        "resampling": {
            "method": RESAMPLING,
            "foreign_fps": plan.fps_in,
            "fps": plan.fps,
            "foreign_frames_per_frame": plan.fps_in / plan.fps,
        },
        "episodes": len(kept),
        "frames": int(sum(len(ep.obs) for ep in kept)),
        "episode_map": [
            {"foreign_episode": ep.index, "foreign_frames": len(ep.rows), "frames": len(ep.obs)}
            for ep in kept
        ],
        "skipped_episodes": skipped,
        "success_flags": {
            flag: key if key else "not recorded: written false" for flag, key in plan.flags.items()
        },
        "flags_not_recorded": [flag for flag, key in plan.flags.items() if not key],
        "action_env": ENV_ACTION_NOTE,
        "cartesian_state": CARTESIAN_NOTE,
        "seed": schema.NO_SEED,
        "provenance": provenance(None, command="import", source_dir=str(root)),
    }
    record = json.loads(json.dumps(record, default=str))  # TOML dates in the map as text

    from tqdm import tqdm

    from wirecraft.datasets.recorder import Episode
    from wirecraft.datasets.writer import EpisodeWriter, write_json_atomic

    fk = _fk_model(robot)
    with folder_built_beside(out, "import", replace_empty=True) as tmp:
        writer = EpisodeWriter.create(
            tmp, features, plan.fps, robot_type=robot, commit_every=len(kept) + 1
        )
        bar = tqdm(total=record["frames"], desc="import", unit="frame", disable=not progress)
        try:
            for ep in kept:
                obs, act = ep.rows[ep.obs], ep.rows[ep.act]
                state_q = converted["state"][obs]
                images = {camera: [] for camera in schema.CAMERAS}
                for row in obs.tolist():
                    item = _read_frame(foreign, int(row), source_dir)
                    for camera, key in plan.cameras.items():
                        images[camera].append(_image(item, key, plan.image_size))
                    bar.update(1)
                flags = {
                    flag: (
                        columns[key][obs, 0].astype(bool) if key else np.zeros(len(obs), dtype=bool)
                    )
                    for flag, key in plan.flags.items()
                }
                episode = Episode(
                    task=plan.instruction or tasks[int(task_index[ep.rows[0]])],
                    source=source,
                    seed=schema.NO_SEED,
                    state=np.column_stack([state_q, converted["gripper_state"][obs]]),
                    action=np.column_stack(
                        [converted["action"][act], converted["gripper_action"][act]]
                    ),
                    cartesian_state=cartesian_states(fk, state_q),
                    env_action=np.full((len(obs), env_width), np.nan),
                    images={camera: np.stack(frames) for camera, frames in images.items()},
                    flags=flags,
                    success=bool(flags["success"][-1]),
                )
                writer.add_episode(episode)
        finally:
            bar.close()
        writer.close()
        write_json_atomic(tmp / IMPORT_FILE, record)
    return record


def summary_lines(record: dict, out: str | os.PathLike) -> list[str]:
    lines = [
        f"{out}: {record['episodes']} episodes, {record['frames']} frames at {record['fps']} fps "
        f"(from {record['from']['episodes']} episodes, {record['from']['frames']} frames at "
        f"{record['from']['fps']} fps), source {record['source']}, robot {record['robot']}"
    ]
    if record["skipped_episodes"]:
        lines.append(
            f"  skipped (shorter than one frame): foreign episodes {record['skipped_episodes']}"
        )
    if record["flags_not_recorded"]:
        lines.append(
            "  not in the foreign dataset, written false: "
            + ", ".join(record["flags_not_recorded"])
        )
    lines.append(f"  action.env: {ENV_ACTION_NOTE}")
    return lines
