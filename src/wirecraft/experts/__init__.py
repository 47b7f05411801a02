"""Scripted experts: a vectorized finite-state-machine framework and one expert per task."""

# The memoryless experts register themselves in ``reactive.REACTIVE_EXPERTS`` (insertion's is in
# ``reactive`` itself).
from wirecraft.experts import reactive_routing, reactive_seating  # noqa: F401
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


# What ``wirecraft collect --expert`` runs: the scripted expert (seeded diversity) or the
# memoryless one, whose action is a function of the state (docs/experts.md).
DEMONSTRATORS = ("scripted", "reactive")


def demonstrator_class(task: str, kind: str = "scripted") -> type:
    """The expert class ``wirecraft collect`` runs for ``task``: ``scripted`` or ``reactive``
    (``DEMONSTRATORS``); both take ``(env, config, seed=...)`` and have ``config_class`` and
    ``CONTROL``."""
    if kind == "scripted":
        return expert_class(task)
    if kind == "reactive":
        from wirecraft.experts.reactive import REACTIVE_EXPERTS, reactive_demonstrator

        if task not in REACTIVE_EXPERTS:
            raise ValueError(
                f"no reactive expert for task {task!r}; tasks with one: "
                + ", ".join(REACTIVE_EXPERTS)
            )
        return reactive_demonstrator(task)
    raise ValueError(f"unknown expert {kind!r}; valid: {', '.join(DEMONSTRATORS)}")


__all__ = [
    "DEMONSTRATORS",
    "EXPERTS",
    "demonstrator_class",
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
