"""Scripted experts: a vectorized finite-state-machine framework and one expert per task."""

from wirecraft.experts.base import EXPERTS, ScriptedExpert
from wirecraft.experts.fsm import Phase, VectorFSM
from wirecraft.experts.insertion import InsertionExpert, InsertionExpertConfig
from wirecraft.experts.routing import RoutingExpert, RoutingExpertConfig
from wirecraft.experts.seating import SeatingExpert, SeatingExpertConfig


def expert_class(task: str) -> type[ScriptedExpert]:
    """The scripted expert of a task family; build its environments with
    ``control=expert_class(task).CONTROL``."""
    if task not in EXPERTS:
        raise ValueError(f"no scripted expert for task {task!r}; valid: {', '.join(EXPERTS)}")
    return EXPERTS.get(task)


__all__ = [
    "EXPERTS",
    "expert_class",
    "InsertionExpert",
    "InsertionExpertConfig",
    "Phase",
    "RoutingExpert",
    "RoutingExpertConfig",
    "ScriptedExpert",
    "SeatingExpert",
    "SeatingExpertConfig",
    "VectorFSM",
]
