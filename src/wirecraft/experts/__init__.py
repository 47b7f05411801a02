"""Scripted experts: a vectorized finite-state-machine framework and one expert per task."""

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
    "SeatingExpert",
    "SeatingExpertConfig",
    "VectorFSM",
]
