"""Per-step traces of an episode and the failure label of a failed one.

Every control step of an evaluated episode is recorded (``TraceRecorder``): what ``info``
reports (insertion depth, lateral / yaw / roll errors, insertion force, wire tension, minimum
bend radius...) plus what only the simulation state tells (which part the pads hold, contact
between the robot and the task's fixture, distance to the goal).  A failed episode then gets
exactly one label (``label_failure``): the first that applies in the order of ``TAXONOMY``,
from the earliest failure in the task's story (the simulation broke, the robot hit the
fixture, nothing was grasped) to the latest (misaligned or jammed at the goal, out of time).

Thresholds are module constants, documented in docs/evaluation.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from wirecraft.numerics import norm
from wirecraft.sensors import contact_normal_force
from wirecraft.tasks.insertion import LATERAL_TOLERANCE, ROLL_GATE

HOLD_STEPS = 3  # consecutive control steps (50 ms) of both pads on a part: a grasp
COLLISION_FORCE = 5.0  # N, robot against the fixture
ORIENTATION_TOLERANCE = ROLL_GATE  # rad (10 deg), for roll and axis tilt alike
JAM_FORCE = 2.0  # N, plug against the port
JAM_STEPS = 30  # control steps (0.5 s)
JAM_PROGRESS = 0.0005  # m of depth over those steps
CLIP_NEAR = 0.03  # m (horizontal), TCP to a clip: "brought to the clip"
LAID_FRACTION = 0.2  # of the wire inside the channel: "laid"

ALL = ("insertion", "routing", "seating")
# label -> (families it applies to, what it means), in order of precedence (see diagnose).
TAXONOMY: dict[str, tuple[tuple[str, ...], str]] = {
    "diverged": (ALL, "the simulation diverged (the step was rolled back, the episode ended)"),
    "fixture_collision": (
        ALL,
        f"the robot pressed on the fixture (port and stand, clip, channel) with >= "
        f"{COLLISION_FORCE:g} N; primary label when it happened before the part reached the "
        "goal, otherwise after the goal labels",
    ),
    "wrong_part": (
        ALL,
        "the pads held the other part (the wire instead of the plug; for routing the plug "
        f"instead of the wire) for >= {HOLD_STEPS} steps, and never the right one",
    ),
    "no_grasp": (ALL, f"the pads never held the part for {HOLD_STEPS} steps in a row"),
    "yaw_misaligned": (
        ("insertion",),
        "at the port (deepest point), the plug's roll about the socket axis or the tilt of its "
        f"axis was off by more than {math.degrees(ORIENTATION_TOLERANCE):.0f} deg",
    ),
    "lateral_misaligned": (
        ("insertion",),
        "at the port (deepest point), the tip was off the socket axis by more than the "
        f"clearance + {1000 * LATERAL_TOLERANCE:g} mm",
    ),
    "jammed": (
        ("insertion",),
        f"at the port and aligned, but stalled: insertion force >= {JAM_FORCE:g} N for "
        f"{JAM_STEPS} steps while the depth moved less than {1000 * JAM_PROGRESS:g} mm",
    ),
    "clip_missed": (
        ("routing",),
        f"the held wire was brought within {100 * CLIP_NEAR:g} cm of a clip, which is not "
        "routed at the end",
    ),
    "not_seated": (
        ("seating",),
        f"the wire was laid (>= {100 * LAID_FRACTION:g}% inside the channel at some step) but "
        "is < 80% inside at the end",
    ),
    "dropped": (
        ALL,
        "the part was held, then let go before it reached the goal, and was not held at the end",
    ),
    "timeout": (ALL, "none of the above: the part was still held, short of the goal"),
}


def labels_for(task: str) -> list[str]:
    return [label for label, (families, _) in TAXONOMY.items() if task in families]


# -- recording -----------------------------------------------------------------------------------
# Columns of every trace (float unless noted), in recording order.
COMMON_COLUMNS = (
    "held",  # 0/1: both pads on the task's part (plug; wire for routing)
    "wrong_held",  # 0/1: both pads on the other part
    "grasp_force",  # N, pads on the part
    "fixture_force",  # N, cable against the fixture (insertion force for insertion)
    "robot_fixture_force",  # N, robot against the fixture
    "table_collision",  # 0/1: robot touching the table
    "wire_tension",  # N
    "min_bend_radius",  # m (inf when straight)
    "peak_contact_force",  # N, largest single contact on the cable
    "gripper_opening",  # m
    "success",  # 0/1
)
FAMILY_COLUMNS = {
    "insertion": (
        "insertion_depth",  # m past the socket mouth
        "lateral_error",  # m off the socket axis
        "yaw_error",  # rad, plug axis vs socket axis
        "roll_error",  # rad about the axis, modulo symmetry
        "insertion_force",  # N, plug against the port
        "tip_distance",  # m, plug tip to the socket entry
        "reach",  # 0/1: info["reach_success"]
    ),
    "routing": (
        "clips_routed",  # count
        "clip_distance",  # m (horizontal), TCP to the nearest clip not routed (nan: none left)
    ),
    "seating": ("fraction_inside",),
}


def columns(task: str) -> tuple[str, ...]:
    return COMMON_COLUMNS + FAMILY_COLUMNS[task]


def _other_part(task):
    assembly = task.assembly
    if task.held_contacts == assembly.plug_contacts:
        return assembly.wire_contacts
    return assembly.plug_contacts


def measure(env, info: dict) -> dict[str, float]:
    """One row of the trace for ``env`` (a ``WireCraftEnv``) after a step with ``info``."""
    model, data, task = env.model, env.data, env.task
    row = {
        "held": float(all(task.pad_contacts(model, data, task.held_contacts))),
        "wrong_held": float(all(task.pad_contacts(model, data, _other_part(task)))),
        "grasp_force": float(info["grasp_force"]),
        "fixture_force": task.fixture_force(model, data),
        "robot_fixture_force": contact_normal_force(
            model, data, task.robot_geoms, task.fixture_contacts
        ),
        "table_collision": float(task.gripper_collision(model, data)),
        "wire_tension": float(info["wire_tension"]),
        "min_bend_radius": float(info["min_bend_radius"]),
        "peak_contact_force": float(info["peak_contact_force"]),
        "gripper_opening": env.robot.gripper_opening(model, data),
        "success": float(info["success"]),
    }
    name = task.name
    if name == "insertion":
        tip = data.site_xpos[task.assembly.tip_site]
        row.update(
            insertion_depth=float(info["insertion_depth"]),
            lateral_error=float(info["lateral_error"]),
            yaw_error=float(info["yaw_error"]),
            roll_error=float(info["roll_error"]),
            insertion_force=float(info["insertion_force"]),
            tip_distance=norm(tip - data.site_xpos[task.entry_site]),
            reach=float(info["reach_success"]),
        )
    elif name == "routing":
        routed = task.routed(model, data)
        tcp = data.site_xpos[task.tcp_site]
        pending = [
            norm((np.asarray(clip.pos) - tcp)[:2])
            for clip, done in zip(task.placed_clips(data), routed, strict=True)
            if not done
        ]
        row.update(clips_routed=float(sum(routed)), clip_distance=min(pending, default=math.nan))
    elif name == "seating":
        row.update(fraction_inside=float(info["fraction_inside"]))
    return row


def info_only(task_name: str, info: dict) -> dict[str, float]:
    """A row from ``info`` alone (the step that diverged: its state was rolled back and the
    environment reset, so only the reported values remain); the rest is NaN."""
    row = {c: math.nan for c in columns(task_name)}
    for key in row:
        if key in info:
            row[key] = float(info[key])
    if task_name == "insertion" and "reach_success" in info:
        row["reach"] = float(info["reach_success"])
    return row


class TraceRecorder:
    """Rows of one episode: ``add(row, phase)``, then ``arrays()`` (column -> (T,) array)."""

    def __init__(self, task: str) -> None:
        self.task = task
        self.columns = columns(task)
        self.rows: list[list[float]] = []
        self.phases: list[str] = []

    def add(self, row: dict[str, float], phase: str | None = None) -> None:
        self.rows.append([row[c] for c in self.columns])
        self.phases.append(phase or "")

    def arrays(self) -> dict[str, np.ndarray]:
        table = np.asarray(self.rows, float).reshape(len(self.rows), len(self.columns))
        out = {c: table[:, k] for k, c in enumerate(self.columns)}
        out["phase"] = np.asarray(self.phases, dtype=object)
        return out


# -- labelling ------------------------------------------------------------------------------------
def longest_run(flags: np.ndarray) -> int:
    """Length of the longest run of True in ``flags``."""
    best = run = 0
    for flag in np.asarray(flags, bool):
        run = run + 1 if flag else 0
        best = max(best, run)
    return best


def _gripped(flags: np.ndarray) -> np.ndarray:
    """Steps inside runs of at least ``HOLD_STEPS`` True (a grasp, not a brush)."""
    flags = np.nan_to_num(np.asarray(flags, float)) > 0.5
    out = np.zeros_like(flags)
    start = None
    for k, flag in enumerate([*flags, False]):
        if flag and start is None:
            start = k
        elif not flag and start is not None:
            if k - start >= HOLD_STEPS:
                out[start:k] = True
            start = None
    return out


def stalled_under_force(depth: np.ndarray, force: np.ndarray, window: np.ndarray) -> bool:
    """``JAM_STEPS`` consecutive steps inside ``window`` with the force >= ``JAM_FORCE`` and
    the depth moving less than ``JAM_PROGRESS``."""
    pressed = window & (np.nan_to_num(force) >= JAM_FORCE)
    start = None
    for k, flag in enumerate([*pressed, False]):
        if flag and start is None:
            start = k
        elif not flag and start is not None:
            for a in range(start, k - JAM_STEPS + 1):
                segment = depth[a : a + JAM_STEPS]
                if np.nanmax(segment) - np.nanmin(segment) < JAM_PROGRESS:
                    return True
            start = None
    return False


@dataclass(frozen=True)
class LabelContext:
    task: str
    diverged: bool
    clearance: float = 0.0  # m (insertion)


def _first(flags: np.ndarray) -> int | None:
    hits = np.flatnonzero(flags)
    return int(hits[0]) if hits.size else None


def _at_goal(trace: dict[str, np.ndarray], held: np.ndarray, task: str) -> np.ndarray:
    """(T,) steps at which the part was at the task's goal: the plug within reach of the
    socket (insertion), the held wire at a clip (routing), the wire laid (seating)."""
    if task == "insertion":
        return np.nan_to_num(trace["reach"]) > 0.5
    if task == "routing":
        return held & (np.nan_to_num(trace["clip_distance"], nan=np.inf) <= CLIP_NEAR)
    if task == "seating":
        return np.nan_to_num(trace["fraction_inside"]) >= LAID_FRACTION
    raise ValueError(f"no failure taxonomy for task {task!r}")


def _at_goal_labels(trace, at_goal, context: LabelContext) -> list[str]:
    """Labels explaining why a part that reached the goal did not succeed."""
    if context.task == "routing":
        return ["clip_missed"]
    if context.task == "seating":
        return ["not_seated"]
    depth = trace["insertion_depth"]
    # The decisive moment: the deepest the plug got while at the port.
    k = int(np.nanargmax(np.where(at_goal, depth, -np.inf)))
    labels = []
    if max(trace["roll_error"][k], trace["yaw_error"][k]) > ORIENTATION_TOLERANCE:
        labels.append("yaw_misaligned")
    if trace["lateral_error"][k] > context.clearance + LATERAL_TOLERANCE:
        labels.append("lateral_misaligned")
    if stalled_under_force(depth, trace["insertion_force"], at_goal):
        labels.append("jammed")
    return labels


def diagnose(trace: dict[str, np.ndarray], context: LabelContext) -> tuple[str, list[str]]:
    """(primary failure label, every label whose condition holds) of a failed episode.

    The primary label is the first thing that went wrong: divergence; a collision with the
    fixture before the part ever reached the goal; the grasp (wrong part, none); at the goal,
    orientation, then lateral offset, then a jam (or the family's own: clip missed, not
    seated); a collision after the goal was reached; the part dropped on the way; timeout.
    """
    events: list[str] = []
    if context.diverged:
        events.append("diverged")
    collision = _first(np.nan_to_num(trace["robot_fixture_force"]) >= COLLISION_FORCE)
    if collision is not None:
        events.append("fixture_collision")
    held = _gripped(trace["held"])
    grasped = bool(held.any())
    if not grasped:
        events.append("wrong_part" if _gripped(trace["wrong_held"]).any() else "no_grasp")
    at_goal = _at_goal(trace, held, context.task)
    reached = _first(at_goal)
    if grasped and reached is not None:
        events += _at_goal_labels(trace, at_goal, context)
    held_at_end = grasped and bool(held[-1])
    if grasped and reached is None and not held_at_end:
        events.append("dropped")
    if context.diverged:
        return "diverged", events
    if collision is not None and (reached is None or collision < reached):
        return "fixture_collision", events
    order = [label for label in TAXONOMY if label not in ("diverged", "fixture_collision")]
    order.insert(order.index("dropped"), "fixture_collision")
    for label in order:
        if label in events:
            return label, events
    return "timeout", events + ["timeout"]


def label_failure(trace: dict[str, np.ndarray], context: LabelContext) -> str:
    """The primary failure label of a failed episode from its trace (see ``diagnose``)."""
    return diagnose(trace, context)[0]
