"""Per-step traces of an episode and the failure label of a failed one.

Every control step of an evaluated episode is recorded (``TraceRecorder``): the columns every
family shares (which part the pads hold, contact between the robot and the task's fixture,
forces, wire tension, minimum bend radius, success) and then the family's own
(``TaskMetrics.columns``, e.g. insertion depth and alignment).  A failed episode then gets
exactly one label (``label_failure``): the first that applies in the order of
``taxonomy(task)``, from the earliest failure in the task's story (the simulation broke, the
robot hit the fixture, nothing was grasped) to the latest (the family's goal labels, dropped,
out of time).

Thresholds are module constants (the family's in its metrics module), documented in
docs/evaluation.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from wirecraft.sensors import contact_normal_force

HOLD_STEPS = 3  # consecutive control steps (50 ms) of both pads on a part: a grasp
COLLISION_FORCE = 5.0  # N, robot against the fixture

# Labels every family shares -> what each means; the family's own labels
# (``TaskMetrics.failure_labels``) rank between ``LATE_LABELS``'s and these (see diagnose).
EARLY_LABELS = {
    "diverged": "the simulation diverged (the step was rolled back, the episode ended)",
    "fixture_collision": (
        f"the robot pressed on the fixture (port and stand, clip, channel) with >= "
        f"{COLLISION_FORCE:g} N; primary label when it happened before the part reached the "
        "goal, otherwise after the goal labels"
    ),
    "wrong_part": (
        "the pads held the other part (the wire instead of the plug; for routing the plug "
        f"instead of the wire) for >= {HOLD_STEPS} steps, and never the right one"
    ),
    "no_grasp": f"the pads never held the part for {HOLD_STEPS} steps in a row",
}
LATE_LABELS = {
    "dropped": (
        "the part was held, then let go before it reached the goal, and was not held at the end"
    ),
    "timeout": "none of the above: the part was still held, short of the goal",
}


def _metrics(task: str):
    from wirecraft.tasks import TASKS

    return TASKS.get(task).metrics


def taxonomy(task: str) -> dict[str, str]:
    """Failure label -> meaning for one family, in order of precedence."""
    return {**EARLY_LABELS, **_metrics(task).failure_labels, **LATE_LABELS}


def labels_for(task: str) -> list[str]:
    return list(taxonomy(task))


def all_labels() -> dict[str, tuple[tuple[str, ...], str]]:
    """Every family's labels: label -> (families it applies to, meaning), shared labels first
    and last, family labels in registry order between."""
    from wirecraft.tasks import TASKS

    families = tuple(TASKS)
    out: dict[str, tuple[tuple[str, ...], str]] = {
        k: (families, v) for k, v in EARLY_LABELS.items()
    }
    for family in families:
        for label, text in _metrics(family).failure_labels.items():
            owners = out.get(label, ((), text))[0]
            out[label] = ((*owners, family), text)
    out.update({k: (families, v) for k, v in LATE_LABELS.items()})
    return out


# -- recording -----------------------------------------------------------------------------------
# Columns of every trace (float unless noted), in recording order; the family's
# (``TaskMetrics.columns``) follow.
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


def columns(task: str) -> tuple[str, ...]:
    return COMMON_COLUMNS + _metrics(task).columns


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
    row.update(task.metrics.measure(env, info))
    return row


def info_only(task_name: str, info: dict) -> dict[str, float]:
    """A row from ``info`` alone (the step that diverged: its state was rolled back and the
    environment reset, so only the reported values remain); the rest is NaN."""
    row = {c: math.nan for c in COMMON_COLUMNS}
    for key in row:
        if key in info:
            row[key] = float(info[key])
    row.update(_metrics(task_name).from_info(info))
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


@dataclass(frozen=True)
class LabelContext:
    task: str
    diverged: bool
    options: Any = None  # the task's options (None: its defaults)

    def task_options(self):
        from wirecraft.tasks import TASKS

        return self.options if self.options is not None else TASKS.get(self.task).Options()


def _first(flags: np.ndarray) -> int | None:
    hits = np.flatnonzero(flags)
    return int(hits[0]) if hits.size else None


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
    metrics = _metrics(context.task)
    at_goal = metrics.at_goal(trace, held)
    reached = _first(at_goal)
    if grasped and reached is not None:
        events += metrics.at_goal_labels(trace, at_goal, context.task_options())
    held_at_end = grasped and bool(held[-1])
    if grasped and reached is None and not held_at_end:
        events.append("dropped")
    if context.diverged:
        return "diverged", events
    if collision is not None and (reached is None or collision < reached):
        return "fixture_collision", events
    order = [label for label in taxonomy(context.task) if label not in EARLY_LABELS]
    order = ["wrong_part", "no_grasp", *order]
    order.insert(order.index("dropped"), "fixture_collision")
    for label in order:
        if label in events:
            return label, events
    return "timeout", events + ["timeout"]


def label_failure(trace: dict[str, np.ndarray], context: LabelContext) -> str:
    """The primary failure label of a failed episode from its trace (see ``diagnose``)."""
    return diagnose(trace, context)[0]
