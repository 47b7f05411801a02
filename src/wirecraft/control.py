"""Control modes shared by every robot: ``joint``, ``cartesian``, ``cartesian_fixed``.

Timing: one control step = ``CONTROL_SUBSTEPS`` = 8 physics steps, whatever the model's
timestep: 16 ms (62.5 Hz) at 2 ms; the environments use 1/480 s, hence exactly 60 Hz and 480
control steps per 8 s episode.

Actions are in [-1, 1] (clipped); the last element is the gripper command (-1 fully open,
+1 closed, linear in between: commanded pad gap = (1 - g) / 2 * max_opening).  NaN or infinite
actions raise ValueError.

- ``joint``: action[:dof] moves each joint target by action * velocity_limit * control_period
  (a joint can be driven at its rated speed); targets are clipped to the joint limits.
- ``cartesian``: action[:3] * 0.01 m translation and action[3:6] * 0.01 rad rotation (an axis *
  angle vector) of the TCP per control step, both expressed in the robot base frame.  The
  deltas accumulate in a target pose; each control step one damped-least-squares IK step from
  the measured joint angles toward the target (``mj_jacSite`` on the TCP) gives the joint
  servo targets; joints that would cross a limit are stopped at it and the others re-solved.
  Redundant arms (Panda) add a null-space pull toward the home posture.
- ``cartesian_fixed``: action[:3] as in ``cartesian``; the orientation target stays at the TCP
  orientation captured by ``reset``.

Servo targets never lead the measured joints by more than ``joint_lead_periods`` (3) control
periods at rated speed (the joints' speed limits) nor by more than half the room left to a
joint's soft limit (``limit_margin`` inside the hard one), so joints brake before their stops;
Cartesian targets never lead the measured TCP by more than ``max_lead_*`` (no wind-up when a
motion is blocked).  ``joint_targets`` holds the last arm servo targets: the dataset's action.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from wirecraft import validation
from wirecraft.assets.robots import RobotHandle
from wirecraft.assets.robots.kinematics import (
    axis_angle_to_mat,
    dls,
    dls_limited,
    rotation_error,
    site_jacobian,
)
from wirecraft.registry import Registry

CONTROL_SUBSTEPS = 8
LIMIT_BRAKE = 0.5  # servo lead toward a joint limit <= this fraction of the room left
CONTROLLERS: Registry[type[Controller]] = Registry("control")


@dataclass(frozen=True)
class ControlConfig:
    """Scales and limits of the control modes (SI units; per control step where stated)."""

    substeps: int = CONTROL_SUBSTEPS
    translation_scale: float = 0.01  # m per control step at |action| = 1
    rotation_scale: float = 0.01  # rad per control step at |action| = 1
    joint_speed_fraction: float = 1.0  # joint mode: fraction of the rated speed at |action| = 1
    ik_damping: float = 0.02  # DLS damping (m and rad mixed, as in the Jacobian rows)
    max_lead_pos: float = 0.04  # m the Cartesian target may lead the measured TCP
    max_lead_rot: float = 0.3  # rad
    limit_margin: float = 0.02  # rad kept between servo targets and the joint limits (soft limits)
    nullspace_gain: float = 0.05  # redundant arms: pull toward home per control step
    joint_lead_periods: float = 3.0  # servo targets lead the joints by <= this many periods

    def __post_init__(self) -> None:
        owner = "ControlConfig"
        validation.at_least_int(owner, "substeps", self.substeps, 1)
        for name in (
            "translation_scale",
            "rotation_scale",
            "joint_speed_fraction",
            "ik_damping",
            "max_lead_pos",
            "max_lead_rot",
            "joint_lead_periods",
        ):
            validation.positive(owner, name, getattr(self, name))
        validation.non_negative(owner, "limit_margin", self.limit_margin)
        validation.in_range(owner, "nullspace_gain", self.nullspace_gain, 0.0, 1.0)


def control_period(model: mujoco.MjModel, config: ControlConfig | None = None) -> float:
    """Seconds per control step."""
    return (config or ControlConfig()).substeps * model.opt.timestep


class Controller:
    """Base class: turns an action into servo targets for one robot in one model."""

    name: str = ""

    def __init__(
        self, robot: RobotHandle, model: mujoco.MjModel, config: ControlConfig | None = None
    ) -> None:
        self.robot = robot
        self.model = model
        self.config = config or ControlConfig()
        self.index = robot.index(model)
        self.period = control_period(model, self.config)
        margin = self.config.limit_margin
        self.lower = robot.joint_lower + margin
        self.upper = robot.joint_upper - margin
        self.max_step = robot.joint_velocity * self.period  # rad per control step at rated speed
        self.max_lead = self.max_step * self.config.joint_lead_periods
        self.joint_targets = robot.home_qpos.copy()
        self.gripper_target = robot.max_opening
        self._kin = mujoco.MjData(model)
        act = self.index.arm_act
        self.kv_over_kp = -model.actuator_biasprm[act, 2] / model.actuator_gainprm[act, 0]

    # -- sizes -----------------------------------------------------------------------------
    @property
    def arm_action_dim(self) -> int:
        raise NotImplementedError

    @property
    def action_dim(self) -> int:
        return self.arm_action_dim + 1

    # -- lifecycle -------------------------------------------------------------------------
    def reset(self, data: mujoco.MjData) -> None:
        """Hold the current configuration: targets = measured joints, gripper as commanded."""
        self.joint_targets = data.qpos[self.index.arm_qpos].copy()
        self.gripper_target = float(data.ctrl[self.index.gripper_act])

    def apply(self, data: mujoco.MjData, action) -> None:
        """Validate and clip ``action``, compute servo targets, write them to ``data.ctrl``."""
        action = self.check_action(action)
        q = data.qpos[self.index.arm_qpos].copy()
        target, velocity = self._arm_targets(data, q, action[:-1])
        # Servo targets lead the measured joints by at most a few periods at rated speed, and
        # by at most half the room left to a (soft) limit: joints brake before their limits.
        up = np.minimum(self.max_lead, LIMIT_BRAKE * (self.upper - q))
        down = np.minimum(self.max_lead, LIMIT_BRAKE * (q - self.lower))
        self.joint_targets = np.clip(np.clip(target, q - down, q + up), self.lower, self.upper)
        # Velocity feed-forward: MuJoCo's servo force is kp (ctrl - q) - kv qdot, so shifting
        # the target by kv / kp * v makes its damping act on (v - qdot) and the servo follows a
        # moving target without the ramp lag kv v / kp (which differs per joint and would bend
        # the tool's path).
        ctrl = self.joint_targets + self.kv_over_kp * velocity
        ctrl = np.clip(np.clip(ctrl, q - down, q + up), self.lower, self.upper)
        data.ctrl[self.index.arm_act] = ctrl
        self.gripper_target = 0.5 * (1.0 - float(action[-1])) * self.robot.max_opening
        data.ctrl[self.index.gripper_act] = self.gripper_target

    def step(self, data: mujoco.MjData, action) -> None:
        """``apply`` then advance the physics by one control period."""
        self.apply(data, action)
        mujoco.mj_step(self.model, data, nstep=self.config.substeps)

    def set_joint_targets(self, data: mujoco.MjData, joints, gripper_opening: float) -> None:
        """Absolute servo targets (e.g. replaying a dataset's action); clipped to the limits."""
        joints = self.check_values(joints, self.robot.dof, "joint targets")
        opening = self.check_values([gripper_opening], 1, "gripper opening")[0]
        self.joint_targets = np.clip(joints, self.lower, self.upper)
        self.gripper_target = float(np.clip(opening, 0.0, self.robot.max_opening))
        data.ctrl[self.index.arm_act] = self.joint_targets
        data.ctrl[self.index.gripper_act] = self.gripper_target
        self.reset_targets(data)

    def reset_targets(self, data: mujoco.MjData) -> None:
        """Re-anchor any internal target to the current state (no-op for joint control)."""

    def dataset_action(self) -> np.ndarray:
        """(dof + 1,): the last arm servo targets (rad) and commanded pad gap (m)."""
        return np.concatenate([self.joint_targets, [self.gripper_target]])

    # -- helpers ---------------------------------------------------------------------------
    def check_action(self, action) -> np.ndarray:
        return np.clip(self.check_values(action, self.action_dim, "action"), -1.0, 1.0)

    def check_values(self, values, size: int, what: str) -> np.ndarray:
        try:
            arr = np.asarray(values, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise ValueError(f"{self.name} {what} must be numbers, got {values!r}") from None
        if arr.size != size:
            raise ValueError(f"{self.name} {what} must have {size} values, got {arr.size}")
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            raise ValueError(
                f"{self.name} {what} has non-finite values (NaN or inf) at indices "
                f"{bad.tolist()}: {arr[bad].tolist()}"
            )
        return arr

    def tcp_kinematics(self, q: np.ndarray):
        """TCP world position, rotation and (6, dof) Jacobian at arm joints ``q`` (other joints
        as in the last ``sync``).  Uses a private MjData, so the simulation is untouched."""
        kin = self._kin
        kin.qpos[self.index.arm_qpos] = q
        mujoco.mj_kinematics(self.model, kin)
        mujoco.mj_comPos(self.model, kin)
        site = self.index.tcp_site
        pos = kin.site_xpos[site].copy()
        rot = kin.site_xmat[site].reshape(3, 3).copy()
        return pos, rot, site_jacobian(self.model, kin, site, self.index.arm_dof)

    def sync(self, data: mujoco.MjData) -> None:
        self._kin.qpos[:] = data.qpos

    def _arm_targets(self, data: mujoco.MjData, q: np.ndarray, arm_action: np.ndarray):
        """Servo targets (dof,) and the commanded joint velocity (dof,) for the feed-forward."""
        raise NotImplementedError


@CONTROLLERS.register("joint")
class JointController(Controller):
    """Per-step joint target deltas: action * rated speed * control period."""

    name = "joint"

    @property
    def arm_action_dim(self) -> int:
        return self.robot.dof

    def _arm_targets(self, data, q, arm_action):
        step = arm_action * self.config.joint_speed_fraction * self.max_step
        return self.joint_targets + step, step / self.period


@CONTROLLERS.register("cartesian")
class CartesianController(Controller):
    """6-DoF TCP deltas in the base frame resolved by damped-least-squares differential IK."""

    name = "cartesian"

    def __init__(self, robot, model, config=None) -> None:
        super().__init__(robot, model, config)
        self.target_pos = np.zeros(3)  # world frame
        self.target_rot = np.eye(3)
        self.base_pos_world = np.zeros(3)
        self.base_rot_world = np.eye(3)

    @property
    def arm_action_dim(self) -> int:
        return 6

    def reset(self, data: mujoco.MjData) -> None:
        super().reset(data)
        self.reset_targets(data)

    def reset_targets(self, data: mujoco.MjData) -> None:
        self.sync(data)
        self.target_pos, self.target_rot, _ = self.tcp_kinematics(
            data.qpos[self.index.arm_qpos].copy()
        )
        site = self.index.base_site
        self.base_pos_world = self._kin.site_xpos[site].copy()
        self.base_rot_world = self._kin.site_xmat[site].reshape(3, 3).copy()

    def _rotation_delta(self, arm_action: np.ndarray) -> np.ndarray:
        return arm_action[3:6] * self.config.rotation_scale

    def _arm_targets(self, data, q, arm_action):
        cfg = self.config
        self.sync(data)
        pos, rot, jac = self.tcp_kinematics(q)
        base = self.base_rot_world
        # Accumulate the delta in the target pose (base-frame deltas -> world).
        move = base @ (arm_action[:3] * cfg.translation_scale)
        rotvec = base @ self._rotation_delta(arm_action)
        self.target_pos = self.target_pos + move
        self.target_rot = axis_angle_to_mat(rotvec) @ self.target_rot
        # Keep the target within reach of the measured TCP (no wind-up when blocked).
        lead = self.target_pos - pos
        dist = float(np.linalg.norm(lead))
        if dist > cfg.max_lead_pos:
            self.target_pos = pos + lead * (cfg.max_lead_pos / dist)
        rot_err = rotation_error(self.target_rot, rot)
        angle = float(np.linalg.norm(rot_err))
        if angle > cfg.max_lead_rot:
            rot_err *= cfg.max_lead_rot / angle
            self.target_rot = axis_angle_to_mat(rot_err) @ rot
        err = np.concatenate([self.target_pos - pos, rot_err])
        dq = dls_limited(jac, err, cfg.ik_damping, q, self.lower, self.upper)
        if self.robot.dof > 6 and cfg.nullspace_gain > 0.0:
            dq += self._nullspace(jac, q, dq)
        # Scale the whole step (keeping its direction) so no joint leads by more than allowed.
        ratio = float(np.max(np.abs(dq) / self.max_lead))
        velocity = dls(jac, np.concatenate([move, rotvec]) / self.period, cfg.ik_damping)
        return q + (dq / ratio if ratio > 1.0 else dq), velocity

    def _nullspace(self, jac: np.ndarray, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Pull toward home inside the Jacobian's null space (redundant arms)."""
        pull = self.config.nullspace_gain * (self.robot.home_qpos - q)
        projected = pull - dls(jac, jac @ pull, 1e-4)
        inside = (q + dq + projected >= self.lower) & (q + dq + projected <= self.upper)
        return np.where(inside, projected, 0.0)


@CONTROLLERS.register("cartesian_fixed")
class CartesianFixedController(CartesianController):
    """3-DoF TCP translation; the orientation is held at the one captured by ``reset``."""

    name = "cartesian_fixed"

    @property
    def arm_action_dim(self) -> int:
        return 3

    def _rotation_delta(self, arm_action: np.ndarray) -> np.ndarray:
        return np.zeros(3)


def make_controller(
    name: str,
    robot: RobotHandle,
    model: mujoco.MjModel,
    config: ControlConfig | None = None,
) -> Controller:
    """Controller ``name`` (one of ``CONTROLLERS``) for ``robot`` in ``model``."""
    return CONTROLLERS.get(name)(robot, model, config)


def servo_action(
    controller: CartesianController,
    target_pos,
    target_rot,
    gripper: float,
) -> np.ndarray:
    """A Cartesian action stepping the controller's target toward a pose in the base frame.

    The delta is the remaining distance between the controller's own target and the goal,
    divided by the action scales and clipped to [-1, 1]; it is measured from the target, not
    from the lagging TCP, so the target moves at most 1 cm / 0.01 rad per step and stops on
    the goal without overshoot.  Returns a 7-d (``cartesian``) or 4-d (``cartesian_fixed``)
    action whose last element is ``gripper``.
    """
    cfg = controller.config
    base = controller.base_rot_world
    pos = base.T @ (controller.target_pos - controller.base_pos_world)
    rot = base.T @ controller.target_rot
    delta_pos = (np.asarray(target_pos, float) - pos) / cfg.translation_scale
    delta_rot = rotation_error(np.asarray(target_rot, float), rot) / cfg.rotation_scale
    parts = [delta_pos, delta_rot][: 1 + (controller.arm_action_dim == 6)]
    return np.clip(np.concatenate([*parts, [gripper]]), -1.0, 1.0)
