"""What every scripted expert shares: the environments it drives, its state machine, noticing
environment resets, frames, and the control loop.

An expert subclass declares ``PHASES`` (its states), ``SNAPSHOTS`` (per-environment arrays
frozen at phase changes), ``CONTROL`` and ``TASK`` (what it drives), ``config_class``, and
implements ``_goals(i)``: for environment ``i`` in its current phase, the TCP goal position
and rotation in the robot base frame (rotation ``None``: hold the controller's), the speed
(m per control step), the gripper command, and its own "phase done" verdict (``None``: the
phase's position/orientation tolerances and dwell decide).  ``_init_state`` and
``_reset_state(mask)`` add and restart counters of its own; ``_on_advance(advanced, before)``
acts on phase changes.

Privileged state is read in one place: each control step ``act`` calls ``read_state(i)`` once
per environment and keeps the result in ``self.views[i]`` for ``_goals`` and ``_on_advance``.
The default reads the robot (``RobotView``: base frame, TCP, gripper, the controller's target);
an expert that needs the task's state (the insertion expert's ``InsertionView``) extends it.

Randomness (diversity) comes from ``self.rngs[i]``, one generator per environment: seeded from
``seed`` (constructor) or ``reset(seed=...)`` as ``numpy.random.default_rng([seed, i])``, from
fresh entropy when no seed was given.  The same seed and the same environment states give the
same actions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from wirecraft.control import servo_action
from wirecraft.experts.fsm import Phase, VectorFSM, step_toward, unwrap_envs
from wirecraft.geometry import rotation_error
from wirecraft.numerics import dot, matmul, norm
from wirecraft.registry import Registry

UP = np.array([0.0, 0.0, 1.0])  # world
TABLE_Z = 0.0  # m, table top (world; wirecraft.scene puts it at z = 0)


def rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (rad) of the rotation between rotation matrices ``a`` and ``b``."""
    return norm(rotation_error(a, b))


def flat(v: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``v`` (..., 3) without its component along ``up``."""
    return v - np.multiply.outer(dot(v, up), up)


def horizontal(v: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Unit vector along ``v`` (3,) without its component along ``up`` (near zero, not unit,
    where that component is all of ``v``: a zero ``v`` gives zeros)."""
    v = flat(v, up)
    return v / max(norm(v), 1e-9)


@dataclass(frozen=True)
class RobotView:
    """What every expert reads of its robot, once per control step; poses in the robot base
    frame (m, rad), except ``base_pos`` / ``base_rot`` (the base frame in the world).

    up: world +z in the base frame.  target_pos / target_rot: the Cartesian controller's own
    target (it may lead the TCP).  gripper_opening: m between the pads; gripper_velocity: m/s.
    """

    base_pos: np.ndarray
    base_rot: np.ndarray
    up: np.ndarray
    tcp_pos: np.ndarray
    tcp_rot: np.ndarray
    target_pos: np.ndarray
    target_rot: np.ndarray
    gripper_opening: float
    gripper_velocity: float
    max_opening: float

    def to_base(self, points) -> np.ndarray:
        """World points (..., 3) in the robot base frame."""
        return matmul(np.asarray(points, float) - self.base_pos, self.base_rot)

    def rot_to_base(self, rot) -> np.ndarray:
        """A world rotation matrix in the robot base frame."""
        return matmul(self.base_rot.T, np.asarray(rot, float))


def robot_fields(env) -> dict:
    """The ``RobotView`` fields of environment ``env`` (a ``WireCraftEnv``), as a dict, so that
    views of task state can extend them."""
    model, data, robot, ctl = env.model, env.data, env.robot, env.controller
    site = ctl.index.base_site
    base_pos = data.site_xpos[site].copy()
    base_rot = data.site_xmat[site].reshape(3, 3).copy()
    tcp_pos, tcp_rot = robot.tcp_pose_base(model, data)
    world = ctl.base_rot_world
    return {
        "base_pos": base_pos,
        "base_rot": base_rot,
        "up": base_rot[2].copy(),  # base_rot.T @ (0, 0, 1)
        "tcp_pos": tcp_pos,
        "tcp_rot": tcp_rot,
        "target_pos": matmul(world.T, ctl.target_pos - ctl.base_pos_world),
        "target_rot": matmul(world.T, ctl.target_rot),
        "gripper_opening": float(robot.gripper_opening(model, data)),
        "gripper_velocity": float(robot.gripper_velocity(model, data)),
        "max_opening": float(robot.max_opening),
    }


def read_robot(env) -> RobotView:
    """``RobotView`` of environment ``env`` (a ``WireCraftEnv``) now."""
    return RobotView(**robot_fields(env))


# Task family -> its scripted expert class; each expert registers itself beside its class.
EXPERTS: Registry[type[ScriptedExpert]] = Registry("scripted expert")


class ScriptedExpert:
    """Vectorized scripted expert over N environments (N = 1 for one environment).

    ``reset(env_ids)`` after the environments are reset (a vector env's autoreset included: an
    environment whose simulation time went back is restarted by ``act`` itself); ``act()``
    returns the (N, action_dim) actions for the current states.
    """

    PHASES: ClassVar[tuple[Phase, ...]]
    SNAPSHOTS: ClassVar[tuple[tuple[str, tuple[int, ...]], ...]]  # name, per-environment shape
    CONTROL: ClassVar[str]
    TASK: ClassVar[str]
    config_class: ClassVar[type]

    def __init__(self, env_or_envs, config=None, seed: int | None = None) -> None:
        self.envs = unwrap_envs(env_or_envs)
        name = type(self).__name__
        for env in self.envs:
            if env.controller.name != self.CONTROL:
                raise ValueError(f"{name} needs control='{self.CONTROL}'")
            if env.task.name != self.TASK:
                raise ValueError(f"{name} needs the {self.TASK} task")
        self.config = config or self.config_class()
        self.num_envs = len(self.envs)
        self.rngs = [self._new_rng(seed, i) for i in range(self.num_envs)]
        self.views: list = [None] * self.num_envs  # read_state(i) of the current control step
        self.fsm = VectorFSM(self.PHASES, self.num_envs)
        self._last_time = np.full(self.num_envs, -np.inf)  # s, to notice environment resets
        self._still_from = np.zeros((self.num_envs, 3))  # TCP where it last moved (base frame)
        self._still_count = np.zeros(self.num_envs, int)  # steps since it moved from there
        self._init_state()
        self.reset()

    def _init_state(self) -> None:
        """Create the expert's own per-environment counters."""

    def _reset_state(self, mask: np.ndarray) -> None:
        """Restart the expert's own counters for the environments in ``mask``."""
        del mask

    # -- lifecycle ---------------------------------------------------------------------------
    @staticmethod
    def _new_rng(seed: int | None, i: int) -> np.random.Generator:
        if seed is None:
            return np.random.default_rng()
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"expert seed must be a non-negative int or None, got {seed!r}")
        return np.random.default_rng([int(seed), i])

    def reset(self, env_ids=None, seed: int | None = None) -> None:
        """Start over (first phase, snapshots cleared) for ``env_ids`` (None: all).  ``seed``
        re-seeds their generators (``default_rng([seed, i])``); without it they go on with
        their streams (still deterministic if the expert was seeded)."""
        mask = self.fsm._mask(env_ids)
        if seed is not None:
            for i in np.flatnonzero(mask):
                self.rngs[i] = self._new_rng(seed, int(i))
        self.fsm.reset(mask)
        for name, shape in self.SNAPSHOTS:
            if name not in self.fsm.snapshots:
                self.fsm.snapshots[name] = np.full((self.num_envs, *shape), np.nan)
        self._reset_state(mask)
        self._last_time[mask] = -np.inf

    @property
    def phase_names(self) -> list[str]:
        return self.fsm.names

    # -- frames ------------------------------------------------------------------------------
    def _base(self, i):
        """Robot base position (3,) and rotation (3, 3) in the world, environment ``i``."""
        env = self.envs[i]
        site = env.controller.index.base_site
        return env.data.site_xpos[site].copy(), env.data.site_xmat[site].reshape(3, 3).copy()

    def _up(self, i):
        """The world's up (unit, (3,)) in environment ``i``'s robot base frame."""
        return matmul(self._base(i)[1].T, UP)

    def _to_base(self, i, points):
        """World points (..., 3) in environment ``i``'s robot base frame."""
        origin, base = self._base(i)
        return matmul(np.asarray(points, float) - origin, base)

    def _height(self, i, point) -> float:
        """Height (m) of a base-frame point above the table (z = 0 in the world)."""
        return dot(point - self._to_base(i, np.zeros(3)), self._up(i))

    def _ctl_target(self, i):
        """The controller's own target pose (it may lead the TCP), in the base frame."""
        ctl = self.envs[i].controller
        base = ctl.base_rot_world
        return matmul(base.T, ctl.target_pos - ctl.base_pos_world), matmul(base.T, ctl.target_rot)

    def _steps_still(self, i, tcp_pos, distance: float) -> int:
        """Control steps the TCP (``tcp_pos``, base frame) has stayed within ``distance`` (m)
        of where it last moved, in the current phase: 0 on the phase's first step and whenever
        it moves farther.  Call it once per control step while the count matters."""
        if self.fsm.steps[i] == 0 or norm(tcp_pos - self._still_from[i]) > distance:
            self._still_from[i] = tcp_pos
            self._still_count[i] = 0
        else:
            self._still_count[i] += 1
        return int(self._still_count[i])

    # -- control loop ------------------------------------------------------------------------
    def read_state(self, i):
        """Everything the expert reads of environment ``i`` this control step (privileged
        state); kept in ``self.views[i]``.  Subclasses extend ``RobotView``."""
        return read_robot(self.envs[i])

    def _goals(self, i):
        raise NotImplementedError

    def _on_advance(self, advanced: np.ndarray, before: np.ndarray) -> None:
        del advanced, before

    def _command_offset(self, i, goal_pos, view):
        """Where to aim the controller relative to the phase goal (m, base frame); the
        phase's tolerance is still judged on the goal itself."""
        del i, goal_pos, view
        return 0.0

    def act(self, observations=None) -> np.ndarray:
        """(N, action_dim) actions for the current states (privileged state; ``observations``
        unused)."""
        del observations
        n = self.num_envs
        actions = np.zeros((n, self.envs[0].action_space.shape[0]))
        pos_err, rot_err = np.zeros(n), np.zeros(n)
        own_mask, own_value = np.zeros(n, bool), np.zeros(n, bool)  # phases judging themselves
        for i, env in enumerate(self.envs):
            if env.data.time < self._last_time[i]:  # the environment was reset: start over
                self.reset([i])
            self._last_time[i] = env.data.time
            view = self.views[i] = self.read_state(i)
            goal_pos, goal_rot, speed, gripper, own = self._goals(i)
            tcp_rot, target_pos, target_rot = view.tcp_rot, view.target_pos, view.target_rot
            pos_err[i] = norm(goal_pos - view.tcp_pos)
            if goal_rot is None:  # fixed orientation: hold the controller's
                goal_rot = target_rot
            else:
                rot_err[i] = rotation_angle(goal_rot, tcp_rot)
            if own is not None:
                own_mask[i], own_value[i] = True, own
            command = goal_pos + self._command_offset(i, goal_pos, view)
            step_goal = step_toward(target_pos, command, speed)
            actions[i] = servo_action(env.controller, step_goal, goal_rot, gripper)
        before = self.fsm.phase.copy()
        reached = np.where(own_mask, own_value, self.fsm.within(pos_err, rot_err))
        advanced = self.fsm.advance_if(reached)
        self._on_advance(advanced, before)
        return actions
