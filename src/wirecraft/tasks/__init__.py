"""Task families.  Add one: a module with a ``Task`` subclass registered in ``TASKS``."""

from wirecraft.tasks import insertion, routing, seating  # noqa: F401  (registration)
from wirecraft.tasks.base import STATE_REVISION, TASKS, Task, check_state_revision

__all__ = ["STATE_REVISION", "TASKS", "Task", "check_state_revision"]
