"""Inputs a state policy can compute from its task's state: ``actor_transform(name, task)``.

``state``: the state itself.  ``relative``: the state plus goal-relative vectors computed from
it, defined by the task's memoryless expert (``relative_features`` of its class in
``wirecraft.experts.reactive.REACTIVE_EXPERTS``): the plug seen from the TCP and the
millimetres that decide the expert's action, squashed at fine scales.  Standardised over the
whole workspace, as the raw state is for a network, those millimetres are a thousandth of the
inputs' spread; a learner imitating the reactive insertion expert from the raw state hovered
above the plug, from these it seats it (docs/baselines.md, "Goal-relative inputs").
"""

from __future__ import annotations

from wirecraft.experts.reactive import REACTIVE_EXPERTS, RELATIVE_WIDTH

ACTOR_INPUTS = ("state", "relative")


def relative_tasks() -> list[str]:
    """The task families whose memoryless expert defines ``relative`` inputs."""
    return [task for task in REACTIVE_EXPERTS if REACTIVE_EXPERTS.get(task).relative_features]


def actor_transform(name: str, task: str):
    """The function computing actor inputs ``name`` from ``task``'s states (None: the state
    itself); a ValueError for a task without them."""
    if name not in ACTOR_INPUTS:
        raise ValueError(f"unknown actor inputs {name!r}; valid: {', '.join(ACTOR_INPUTS)}")
    if name == "state":
        return None
    tasks = relative_tasks()
    if task not in tasks:
        raise ValueError(
            f"actor_inputs={name!r} is defined for the {', '.join(tasks)} tasks' states, "
            f"not {task}'s"
        )
    return REACTIVE_EXPERTS.get(task).relative_features


def actor_input_dim(name: str, state_dim: int) -> int:
    """The width of actor inputs ``name`` for states ``state_dim`` wide."""
    if name == "state":
        return state_dim
    return state_dim + RELATIVE_WIDTH
