"""Scripted experts: a vectorized finite-state-machine framework and one expert per task."""

from wirecraft.experts.fsm import Phase, VectorFSM
from wirecraft.experts.insertion import InsertionExpert, InsertionExpertConfig

__all__ = ["InsertionExpert", "InsertionExpertConfig", "Phase", "VectorFSM"]
