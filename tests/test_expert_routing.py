"""The routing expert routes the cable through one clip (UR5, articulated wire)."""

from __future__ import annotations

import pytest

import wirecraft
from wirecraft.experts.routing import RoutingExpert


@pytest.fixture(scope="module")
def env():
    env = wirecraft.make("routing", num_clips=1)
    yield env
    env.close()


@pytest.mark.parametrize("seed", [0, 7])
def test_routes_one_clip(env, seed):
    expert = RoutingExpert(env)
    env.reset(seed=seed)
    expert.reset()
    for _ in range(480):
        _, _, terminated, truncated, info = env.step(expert.act()[0])
        if terminated or truncated:
            break
    assert info["success"], (seed, expert.phase_names, info["clips_routed"])
    assert expert.phase_names == ["done"]


def test_needs_the_routing_task_and_cartesian_control():
    with pytest.raises(ValueError, match="cartesian"):
        RoutingExpert(wirecraft.make("routing", control="joint"))
    with pytest.raises(ValueError, match="routing task"):
        RoutingExpert(wirecraft.make("insertion"))
