"""The routing expert routes the cable through 1, 2 and 3 clips (UR5, articulated wire)."""

from __future__ import annotations

import pytest

import wirecraft
from wirecraft.experts.routing import RoutingExpert


def run_episode(num_clips: int, seed: int):
    env = wirecraft.make("routing", num_clips=num_clips)
    expert = RoutingExpert(env)
    env.reset(seed=seed)
    expert.reset()
    for _ in range(env.unwrapped.max_steps):
        _, _, terminated, truncated, info = env.step(expert.act()[0])
        if terminated or truncated:
            break
    env.close()
    return info, expert


@pytest.mark.parametrize("seed", [0, 7])
def test_routes_one_clip(seed):
    info, expert = run_episode(1, seed)
    assert info["success"], (seed, expert.phase_names, info["clips_routed"])
    assert expert.phase_names == ["done"]


# Measured with benchmarks/eval_routing_expert.py (seeds 0-19): 2 clips 16/20, 3 clips 5/20.
# Seeds chosen without looking at their outcome would fail at those rates, so these stay
# non-strict xfails until the expert reaches the >= 98 % target.
@pytest.mark.slow
@pytest.mark.xfail(reason="routing expert: 2 clips 80 % (16/20 seeds), target 98 %", strict=False)
@pytest.mark.parametrize("seed", [4])
def test_routes_two_clips(seed):
    info, expert = run_episode(2, seed)
    assert info["success"], (seed, expert.phase_names, info["clips_routed"])


@pytest.mark.slow
@pytest.mark.xfail(reason="routing expert: 3 clips 25 % (5/20 seeds), target 98 %", strict=False)
@pytest.mark.parametrize("seed", [1])
def test_routes_three_clips(seed):
    info, expert = run_episode(3, seed)
    assert info["success"], (seed, expert.phase_names, info["clips_routed"])


def test_needs_the_routing_task_and_cartesian_control():
    with pytest.raises(ValueError, match="cartesian"):
        RoutingExpert(wirecraft.make("routing", control="joint"))
    with pytest.raises(ValueError, match="routing task"):
        RoutingExpert(wirecraft.make("insertion"))
