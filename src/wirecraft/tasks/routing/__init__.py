"""Clip routing: the task (``task``), its options (``options``) and what the evaluation
measures (``metrics``)."""

from wirecraft.tasks.routing.metrics import RoutingMetrics
from wirecraft.tasks.routing.options import RoutingOptions
from wirecraft.tasks.routing.task import RoutingTask

__all__ = ["RoutingMetrics", "RoutingOptions", "RoutingTask"]
