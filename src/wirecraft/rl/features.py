"""Inputs a state policy can compute from the insertion task's state: ``ACTOR_INPUTS`` by name.

``relative``: the state plus goal-relative vectors computed from it: the plug in the TCP frame
(position and rotation), the tip from the TCP, and the vectors whose millimetres decide an
expert's action (plug from TCP, tip from the socket's mouth, tip from the seated target)
squashed at two fine scales, tanh(v / 1 cm) and tanh(v / 2 mm).  Standardised over the whole
workspace, as the raw state is for a network, those millimetres are a thousandth of the
inputs' spread; a learner imitating the reactive expert from the raw state hovered above the
plug, from these it seats it (docs/baselines.md, "Goal-relative inputs").
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


def relative_features(states) -> np.ndarray:
    """(N, width + 33): the insertion states and their goal-relative features (module doc)."""
    states = np.asarray(states, dtype=float)
    lay = insertion_layout(states.shape[-1])
    tcp = states[:, lay.tcp_pos]
    tcp_rot = quats_to_mats(states[:, lay.tcp_quat])
    plug_rot = quats_to_mats(states[:, lay.plug_quat])
    plug_in_tcp = np.einsum("nji,nj->ni", tcp_rot, states[:, lay.plug_pos] - tcp)
    plug_rot_in_tcp = np.einsum("nji,njk->nik", tcp_rot, plug_rot).reshape(len(states), 9)
    tip = states[:, lay.seated] - states[:, lay.tip_to_target]
    near = np.concatenate(
        [plug_in_tcp, tip - states[:, lay.entry], states[:, lay.tip_to_target]], axis=1
    )
    fine = [np.tanh(near / scale) for scale in FINE_SCALES]
    return np.concatenate([states, plug_in_tcp, plug_rot_in_tcp, tip - tcp, *fine], axis=1)


ACTOR_INPUTS = {"state": None, "relative": relative_features}
# The task family whose state layout each computed input set reads.
ACTOR_INPUT_TASKS = {"relative": "insertion"}


def actor_input_dim(name: str, state_dim: int) -> int:
    """The width of actor inputs ``name`` for states ``state_dim`` wide."""
    if name == "state":
        return state_dim
    return state_dim + 33
