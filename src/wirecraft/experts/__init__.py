"""Scripted experts: a vectorized finite-state-machine framework and one expert per task."""

from wirecraft.experts.base import ScriptedExpert
from wirecraft.experts.fsm import Phase, VectorFSM
from wirecraft.experts.insertion import InsertionExpert, InsertionExpertConfig
from wirecraft.experts.routing import RoutingExpert, RoutingExpertConfig
from wirecraft.experts.seating import SeatingExpert, SeatingExpertConfig

__all__ = [
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
