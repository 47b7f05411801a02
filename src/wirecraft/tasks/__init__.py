"""Task families.  Add one: a module with a ``Task`` subclass registered in ``TASKS``."""

from wirecraft.tasks import insertion, routing, seating  # noqa: F401  (registration)
from wirecraft.tasks.base import TASKS, Task

__all__ = ["TASKS", "Task"]
