"""The seating expert: action layout, grasp and the full phase sequence.

Success (>= 80% of the wire inside the channel) is NOT reached yet by this expert (0/20 seeds,
see docs/experts.md); that test is an expected failure until the expert (or the task) is fixed.
"""

from __future__ import annotations

import numpy as np
import pytest

import wirecraft
from wirecraft.experts.seating import SeatingExpert


def run(channel: str, seed: int):
    env = wirecraft.make("seating", channel=channel)
    expert = SeatingExpert(env)
    obs, info = env.reset(seed=seed)
    expert.reset()
    carried, phases = False, set()
    for _ in range(480):
        action = expert.act(obs)
        assert action.shape == (1, 4)
        assert np.all(np.abs(action) <= 1.0)
        obs, _, terminated, truncated, info = env.step(action[0])
        phases.add(expert.phase_names[0])
        carried |= expert.phase_names[0] == "lay" and expert._held(0)
        if terminated or truncated:
            break
    return info, carried, phases, expert


def test_needs_cartesian_fixed():
    with pytest.raises(ValueError, match="cartesian_fixed"):
        SeatingExpert(wirecraft.make("seating", control="cartesian"))


@pytest.mark.parametrize(("channel", "seed"), [("straight", 0), ("curved", 1)])
def test_grasps_carries_and_finishes(channel, seed):
    info, carried, phases, expert = run(channel, seed)
    assert carried, "the plug must be held while laying"
    assert {"settle", "close", "carry", "lay", "place", "release"} <= phases
    assert expert.phase_names[0] == "done"
    assert not info["diverged"]


@pytest.mark.xfail(reason="the expert does not yet lay the wire into the channel", strict=False)
@pytest.mark.parametrize("channel", ["straight", "curved"])
def test_seats_the_wire(channel):
    info, *_ = run(channel, 0)
    assert info["success"]
