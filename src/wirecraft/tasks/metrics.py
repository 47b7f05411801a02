"""What the evaluation measures and reports for a task family, beside the family's task.

Evaluation (``wirecraft.evaluation``) records, for every control step, the columns every task
shares (grasp, forces, cable health, success; ``diagnostics.COMMON_COLUMNS``) and then the
family's own ``columns`` (``measure``).  A failed episode gets one failure label: the shared
ones (divergence, collision, grasp) come first, then the family's ``failure_labels`` in their
order, then the shared late ones (dropped, timeout).  A family subclasses ``TaskMetrics``
next to its task and attaches it with ``@metrics_of(TaskClass)``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np


class TaskMetrics:
    # Per-step success flags of ``info`` (first: ``success``): recorded per dataset frame and
    # summarised per episode (any step).
    success_flags: ClassVar[tuple[str, ...]] = ("success",)
    # The family's trace columns (float), after the shared ones.
    columns: ClassVar[tuple[str, ...]] = ()
    # Column -> the ``info`` key it copies, where the names differ (default: the same name).
    info_keys: ClassVar[dict[str, str]] = {}
    # Failure labels of the family -> what each means, in order of precedence; they rank after
    # the grasp labels and before ``dropped`` (``diagnostics.diagnose``).
    failure_labels: ClassVar[dict[str, str]] = {}
    # Trace panels of the report: (column, axis title, scale, y limits or None).
    trace_plots: ClassVar[tuple[tuple[str, str, float, tuple | None], ...]] = ()
    # Episode summary fields the report's episode table shows, after the shared ones.
    episode_columns: ClassVar[tuple[str, ...]] = ()
    # Whether the retention check pulls the part after the release (``retention_pull``).
    pulls: ClassVar[bool] = False

    def measure(self, env, info: dict) -> dict[str, float]:
        """This step's family columns for ``env`` (a ``WireCraftEnv``), after ``info``."""
        del env
        return self.from_info(info)

    def from_info(self, info: dict) -> dict[str, float]:
        """The family columns ``info`` holds (NaN for the others): a diverged step's row."""
        row = {}
        for column in self.columns:
            key = self.info_keys.get(column, column)
            row[column] = float(info[key]) if key in info else float("nan")
        return row

    def at_goal(self, trace: dict[str, np.ndarray], held: np.ndarray) -> np.ndarray:
        """(T,) whether the part was at the family's goal at each step (``held``: (T,) the
        pads gripped the right part)."""
        raise NotImplementedError

    def at_goal_labels(self, trace: dict[str, np.ndarray], at_goal: np.ndarray, options) -> list:
        """The labels that explain why a part that reached the goal did not succeed
        (``options``: the task's options)."""
        del trace, at_goal, options
        return list(self.failure_labels)

    def summarize(self, episode: dict[str, np.ndarray], steps: int) -> dict[str, Any]:
        """Family fields of one episode's summary from its trace (``steps`` rows): the success
        flags beyond ``success`` and final or peak values."""
        del episode, steps
        return {}

    def standard_variants(self) -> list[dict[str, Any]]:
        """The task variants (option values) whose evaluation seed lists are frozen."""
        return [{}]

    def retention_pull(self, task, data) -> tuple[int, np.ndarray] | None:
        """(body id, unit world direction) the retention check pulls on after the release, or
        None where it only waits."""
        del task, data
        return None


def metrics_of(task_cls):
    """Class decorator: ``task_cls.metrics`` is an instance of the decorated ``TaskMetrics``."""

    def attach(metrics_cls: type[TaskMetrics]) -> type[TaskMetrics]:
        task_cls.metrics = metrics_cls()
        return metrics_cls

    return attach


def final(values: np.ndarray, steps: int) -> float:
    """The last of ``values`` (NaN for an empty episode)."""
    return values[-1] if steps else np.nan
