"""Inputs a state policy can compute from its task's state: ``actor_transform(name, task)``.

``relative``: the state plus goal-relative vectors computed from it, one function per task
family (``RELATIVE_FEATURES``), 33 columns each.  Insertion: the plug in the TCP frame
(position and rotation), the tip from the TCP, and the vectors whose millimetres decide an
expert's action (plug from TCP, tip from the socket's mouth, tip from the seated target)
squashed at two fine scales, tanh(v / 1 cm) and tanh(v / 2 mm).  Seating: the plug in the TCP
frame (position and rotation), the plug from the TCP, and, at the two fine scales, the plug
from the TCP, from the channel's end extended by the plug lead and from ``LAY_BACK`` before
that point.  Standardised over the whole workspace, as the raw state is for a network, those
millimetres are a thousandth of the inputs' spread; a learner imitating the reactive expert
from the raw insertion state hovered above the plug, from these it seats it (docs/baselines.md,
"Goal-relative inputs").
"""

from __future__ import annotations

import numpy as np

from wirecraft.experts.reactive import StateLayout
from wirecraft.geometry import quats_to_mats

FINE_SCALES = (0.01, 0.002)  # m


def insertion_layout(width: int) -> StateLayout:
    """The ``StateLayout`` of an insertion state ``width`` columns wide (2 x dof + 30)."""
    dof, odd = divmod(width - 30, 2)
    if odd or dof < 1:
        raise ValueError(f"not an insertion state width: {width}")
    return StateLayout(dof)


def _in_frame(rot, vectors) -> np.ndarray:
    """(N, 3) ``vectors`` in the frames ``rot`` (N, 3, 3)."""
    return np.einsum("nji,nj->ni", rot, vectors)


def relative_features(states) -> np.ndarray:
    """(N, width + 33): the insertion states and their goal-relative features (module doc)."""
    states = np.asarray(states, dtype=float)
    lay = insertion_layout(states.shape[-1])
    tcp = states[:, lay.tcp_pos]
    tcp_rot = quats_to_mats(states[:, lay.tcp_quat])
    plug_rot = quats_to_mats(states[:, lay.plug_quat])
    plug_in_tcp = _in_frame(tcp_rot, states[:, lay.plug_pos] - tcp)
    plug_rot_in_tcp = np.einsum("nji,njk->nik", tcp_rot, plug_rot).reshape(len(states), 9)
    tip = states[:, lay.seated] - states[:, lay.tip_to_target]
    near = np.concatenate(
        [plug_in_tcp, tip - states[:, lay.entry], states[:, lay.tip_to_target]], axis=1
    )
    fine = [np.tanh(near / scale) for scale in FINE_SCALES]
    return np.concatenate([states, plug_in_tcp, plug_rot_in_tcp, tip - tcp, *fine], axis=1)


LAY_BACK = 0.04  # m: the seating features' second reference, before the channel's end


def seating_relative_features(states) -> np.ndarray:
    """(N, width + 33): the seating states and their goal-relative features (module doc)."""
    from wirecraft.experts.reactive_seating import SeatingStateLayout
    from wirecraft.tasks.seating.task import PLUG_LEAD

    states = np.asarray(states, dtype=float)
    dof, odd = divmod(states.shape[-1] - 70, 2)
    if odd or dof < 1:
        raise ValueError(f"not a seating state width: {states.shape[-1]}")
    lay = SeatingStateLayout(dof)
    tcp, plug = states[:, lay.tcp_pos], states[:, lay.plug_pos]
    tcp_rot = quats_to_mats(states[:, lay.tcp_quat])
    plug_rot = quats_to_mats(states[:, lay.plug_quat])
    plug_in_tcp = _in_frame(tcp_rot, plug - tcp)
    plug_rot_in_tcp = np.einsum("nji,njk->nik", tcp_rot, plug_rot).reshape(len(states), 9)
    joints = states[:, lay.joints].reshape(len(states), -1, 3)
    heading = joints[:, -1] - joints[:, -2]
    heading /= np.sqrt((heading**2).sum(axis=1, keepdims=True))
    end = joints[:, -1] + PLUG_LEAD * heading
    near = np.concatenate([plug_in_tcp, plug - end, plug - (end - LAY_BACK * heading)], axis=1)
    fine = [np.tanh(near / scale) for scale in FINE_SCALES]
    return np.concatenate([states, plug_in_tcp, plug_rot_in_tcp, plug - tcp, *fine], axis=1)


ACTOR_INPUTS = ("state", "relative")
# Task family -> its ``relative`` inputs.
RELATIVE_FEATURES = {"insertion": relative_features, "seating": seating_relative_features}


def actor_transform(name: str, task: str):
    """The function computing actor inputs ``name`` from ``task``'s states (None: the state
    itself); a ValueError for a task without them."""
    if name not in ACTOR_INPUTS:
        raise ValueError(f"unknown actor inputs {name!r}; valid: {', '.join(ACTOR_INPUTS)}")
    if name == "state":
        return None
    if task not in RELATIVE_FEATURES:
        raise ValueError(
            f"actor_inputs={name!r} is defined for the {' and '.join(RELATIVE_FEATURES)} tasks' "
            f"states, not {task}'s"
        )
    return RELATIVE_FEATURES[task]


def actor_input_dim(name: str, state_dim: int) -> int:
    """The width of actor inputs ``name`` for states ``state_dim`` wide."""
    if name == "state":
        return state_dim
    return state_dim + 33
