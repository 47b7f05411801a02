"""The retention check: does a seated result stay put once the robot lets go (and, for a plug,
under a pull on the cable)?

After an episode whose task succeeded at its last step, the evaluation takes the robot over:

1. release (``RELEASE_STEPS``, 0.25 s): arm held, gripper commanded fully open;
2. retreat (``RETREAT_STEPS``, 1/3 s): under Cartesian control the TCP moves straight up at
   3 mm per step (6 cm), so the pads leave the part; under joint control the arm holds still;
3. pull (``PULL_STEPS``, 0.5 s): where the family defines one
   (``TaskMetrics.retention_pull``; insertion: the plug body, out of the socket along its
   axis), a force of ``force`` newtons ramped up linearly over ``RAMP_STEPS`` (0.1 s) so that
   the check measures holding, not an impact.  The other families only wait (no pull).

``retain_success``: the task's success (``success`` of its ``evaluate``) holds at the end of
the retreat and at every step after it.  A failed check says why: ``unseated_on_release``
(lost by the end of the retreat), ``pulled_out`` (lost during the pull, or the wait) or
``diverged``; an episode that succeeded at some step but not at its last is
``lost_before_end`` (no check is run).  The pull on a plug stops the step it comes out:
pulled on further, a free plug only flies off until the solver diverges, which would hide the
verdict.
"""

from __future__ import annotations

import numpy as np

from wirecraft.envs.env import CONTROL_HZ

RELEASE_STEPS = 15
RETREAT_STEPS = 20
PULL_STEPS = 30
RAMP_STEPS = 6
RETREAT_SPEED = 0.003  # m per control step
DEFAULT_FORCE = 2.0  # N
STEPS = RELEASE_STEPS + RETREAT_STEPS + PULL_STEPS
SECONDS = STEPS / CONTROL_HZ


def stage(k: int) -> str:
    """Name of retention step ``k``."""
    if k < RELEASE_STEPS:
        return "retention:release"
    if k < RELEASE_STEPS + RETREAT_STEPS:
        return "retention:retreat"
    return "retention:pull"


def retention_action(env, k: int) -> np.ndarray:
    """The evaluation's own action for retention step ``k`` in ``env`` (a ``WireCraftEnv``)."""
    action = np.zeros(env.action_space.shape)
    action[-1] = -1.0  # open
    retreating = RELEASE_STEPS <= k < RELEASE_STEPS + RETREAT_STEPS
    if retreating and env.controller.name in ("cartesian", "cartesian_fixed"):
        action[2] = RETREAT_SPEED / env.controller.config.translation_scale  # base z is up
    return action


def pull_force(env, k: int, force: float) -> np.ndarray:
    """(3,) world force on the pulled body at retention step ``k``: zero before the pull (and
    for a family without one), then along the family's pull direction, ramped to ``force``."""
    pull = env.task.metrics.retention_pull(env.task, env.data)
    if pull is None or k < RELEASE_STEPS + RETREAT_STEPS:
        return np.zeros(3)
    ramp = min(1.0, (k - RELEASE_STEPS - RETREAT_STEPS + 1) / RAMP_STEPS)
    return ramp * float(force) * pull[1]


def apply_pull(env, k: int, force: float) -> None:
    pull = env.task.metrics.retention_pull(env.task, env.data)
    if pull is not None:
        env.data.xfrc_applied[pull[0], :3] = pull_force(env, k, force)


def clear_pull(env) -> None:
    pull = env.task.metrics.retention_pull(env.task, env.data)
    if pull is not None:
        env.data.xfrc_applied[pull[0]] = 0.0


def failure_at(k: int, success: bool) -> str | None:
    """The check's verdict once retention step ``k`` is done: ``unseated_on_release`` when the
    task has failed by the end of the retreat, ``pulled_out`` when it fails during the pull
    (or the wait), else None (not failed yet)."""
    if success or k < RELEASE_STEPS + RETREAT_STEPS - 1:
        return None
    return "unseated_on_release" if k == RELEASE_STEPS + RETREAT_STEPS - 1 else "pulled_out"


def check_single(env, force: float = DEFAULT_FORCE) -> tuple[bool, str | None]:
    """Run the check on one ``WireCraftEnv`` from its current state (e.g. a constructed
    seated plug); returns (retained, failure reason or None)."""
    failure = None
    for k in range(STEPS):
        apply_pull(env, k, force)
        _, _, _, _, info = env.step(retention_action(env, k))
        failure = "diverged" if info["diverged"] else failure_at(k, info["success"])
        if failure:
            break
    clear_pull(env)
    return failure is None, failure
