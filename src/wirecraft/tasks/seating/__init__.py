"""Channel seating: the task (``task``), its options (``options``) and what the evaluation
measures (``metrics``)."""

from wirecraft.tasks.seating.metrics import SeatingMetrics
from wirecraft.tasks.seating.options import SeatingOptions
from wirecraft.tasks.seating.task import SeatingTask

__all__ = ["SeatingMetrics", "SeatingOptions", "SeatingTask"]
