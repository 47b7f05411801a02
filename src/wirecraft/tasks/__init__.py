"""Task families.  Add one: a package ``tasks/<family>/`` with a ``Task`` subclass registered in
``TASKS`` (``task.py``), its ``TaskOptions`` (``options.py``) and its ``TaskMetrics``
(``metrics.py``), imported here; docs/adding.md walks through it."""

from wirecraft.tasks import insertion, routing, seating  # noqa: F401  (registration)
from wirecraft.tasks.base import STATE_REVISION, TASKS, Task, check_state_revision
from wirecraft.tasks.metrics import TaskMetrics, metrics_of
from wirecraft.tasks.options import TaskOptions, option


def default_family() -> str:
    """The family commands use when ``--task`` is not given: the first registered."""
    return TASKS.names()[0]


__all__ = [
    "STATE_REVISION",
    "TASKS",
    "Task",
    "TaskMetrics",
    "TaskOptions",
    "check_state_revision",
    "default_family",
    "metrics_of",
    "option",
]
