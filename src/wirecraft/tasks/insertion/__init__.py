"""Connector insertion: the task (``task``), its options (``options``) and what the evaluation
measures (``metrics``)."""

from wirecraft.tasks.insertion.metrics import InsertionMetrics
from wirecraft.tasks.insertion.options import InsertionOptions
from wirecraft.tasks.insertion.task import InsertionTask

__all__ = ["InsertionMetrics", "InsertionOptions", "InsertionTask"]
