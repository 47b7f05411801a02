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
from wirecraft.assets.robots.kinematics import chain_jacobian, dls_batch, dls_limited_batch
from wirecraft.geometry import axis_angle_to_mats, rotation_error, rotation_errors
from wirecraft.numerics import matmul, matvec, norm
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


@dataclass
class ControlState:
    """The targets of N controllers, one row each (a single environment: N = 1).  Every field
    is a numpy array with a leading axis of N."""

    joint_targets: np.ndarray  # (N, dof) last arm servo targets, rad
    gripper_target: np.ndarray  # (N,) commanded pad gap, m
    target_pos: np.ndarray  # (N, 3) Cartesian target, world
    target_rot: np.ndarray  # (N, 3, 3)
    base_pos_world: np.ndarray  # (N, 3) robot base frame, world
    base_rot_world: np.ndarray  # (N, 3, 3)

    FIELDS = ("joint_targets", "gripper_target", "target_pos", "target_rot")
    FIELDS += ("base_pos_world", "base_rot_world")

    @classmethod
    def gather(cls, controllers) -> ControlState:
        """Stack the targets of these controllers (one row each)."""
        return cls(
            **{
                f: np.stack([np.asarray(_target(c, f), float) for c in controllers])
                for f in cls.FIELDS
            }
        )

    def load(self, i: int, controller: Controller) -> None:
        """Row ``i`` := the targets of ``controller``."""
        for f in self.FIELDS:
            getattr(self, f)[i] = _target(controller, f)

    def store(self, i: int, controller: Controller) -> None:
        """``controller``'s targets := row ``i`` (copies: the controller owns its arrays)."""
        controller.joint_targets = self.joint_targets[i].copy()
        controller.gripper_target = float(self.gripper_target[i])
        if hasattr(controller, "target_pos"):
            for f in self.FIELDS[2:]:
                setattr(controller, f, getattr(self, f)[i].copy())

    def rows(self, mask) -> ControlState:
        """A copy of the rows ``mask`` selects."""
        return ControlState(**{f: getattr(self, f)[mask].copy() for f in self.FIELDS})

    def set_rows(self, mask, other: ControlState) -> None:
        """Rows ``mask`` selects := ``other``'s rows, in order."""
        for f in self.FIELDS:
            getattr(self, f)[mask] = getattr(other, f)

    def copy(self) -> ControlState:
        return ControlState(**{f: getattr(self, f).copy() for f in self.FIELDS})

    def restore(self, rows, other: ControlState) -> None:
        """Rows ``rows`` := those of ``other``."""
        for f in self.FIELDS:
            getattr(self, f)[rows] = getattr(other, f)[rows]


def _target(controller, field: str):
    """A controller's target ``field``; the Cartesian ones default for joint control."""
    return getattr(controller, field) if hasattr(controller, field) else _DEFAULTS[field]


_DEFAULTS = {
    "gripper_target": 0.0,
    "target_pos": np.zeros(3),
    "target_rot": np.eye(3),
    "base_pos_world": np.zeros(3),
    "base_rot_world": np.eye(3),
}


def commanded_gap(command, max_opening: float):
    """Pad gap (m) that a gripper command asks for: -1 fully open ... +1 closed."""
    return 0.5 * (1.0 - command) * max_opening


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
        state = ControlState.gather([self])
        if self.needs_kinematics:
            self.sync(data)
            pos, rot, jac = self.tcp_kinematics(q)
            kinematics = (pos[None], rot[None], jac[None])
        else:
            kinematics = None
        ctrl = self.compute(state, q[None], kinematics, action[None])
        state.store(0, self)
        data.ctrl[self.index.arm_act] = ctrl[0]
        data.ctrl[self.index.gripper_act] = self.gripper_target

    needs_kinematics = False  # whether ``compute`` needs the TCP pose and Jacobian

    def compute(self, state: ControlState, q: np.ndarray, kinematics, actions) -> np.ndarray:
        """Servo targets of N controllers at once (the vector environment's step; a single
        environment is N = 1): ``q`` (N, dof) measured arm joints, ``kinematics`` the TCP's
        world position (N, 3), rotation (N, 3, 3) and Jacobian (N, 6, dof) over the arm joints
        (or None for joint control), ``actions`` (N, action_dim) already clipped.  Updates
        ``state`` and returns the arm controls (N, dof); the gripper's are
        ``state.gripper_target``."""
        target, velocity = self._arm_targets(state, q, kinematics, actions[:, :-1])
        # Servo targets lead the measured joints by at most a few periods at rated speed, and
        # by at most half the room left to a (soft) limit: joints brake before their limits.
        up = np.minimum(self.max_lead, LIMIT_BRAKE * (self.upper - q))
        down = np.minimum(self.max_lead, LIMIT_BRAKE * (q - self.lower))
        state.joint_targets = np.clip(np.clip(target, q - down, q + up), self.lower, self.upper)
        # Velocity feed-forward: MuJoCo's servo force is kp (ctrl - q) - kv qdot, so shifting
        # the target by kv / kp * v makes its damping act on (v - qdot) and the servo follows a
        # moving target without the ramp lag kv v / kp (which differs per joint and would bend
        # the tool's path).
        ctrl = state.joint_targets + self.kv_over_kp * velocity
        state.gripper_target = commanded_gap(actions[:, -1], self.robot.max_opening)
        return np.clip(np.clip(ctrl, q - down, q + up), self.lower, self.upper)

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
        jac = self.tcp_jacobian(kin.cdof[None], kin.subtree_com[None], pos[None])[0]
        return pos, rot, jac

    def tcp_jacobian(self, cdof, subtree_com, tcp_pos) -> np.ndarray:
        """(N, 6, dof) TCP Jacobians over the arm joints from N simulations' ``cdof`` and
        ``subtree_com`` (bit-identical to ``mj_jacSite``)."""
        body = self.model.site_bodyid[self.index.tcp_site]
        root = self.model.body_rootid[body]
        return chain_jacobian(cdof, subtree_com, tcp_pos, root, self.index.arm_dof)

    def sync(self, data: mujoco.MjData) -> None:
        self._kin.qpos[:] = data.qpos

    def _arm_targets(self, state: ControlState, q, kinematics, arm_actions):
        """Servo targets (N, dof) and commanded joint velocities (N, dof) for the
        feed-forward."""
        raise NotImplementedError


@CONTROLLERS.register("joint")
class JointController(Controller):
    """Per-step joint target deltas: action * rated speed * control period."""

    name = "joint"

    @property
    def arm_action_dim(self) -> int:
        return self.robot.dof

    def _arm_targets(self, state, q, kinematics, arm_actions):
        step = arm_actions * self.config.joint_speed_fraction * self.max_step
        return state.joint_targets + step, step / self.period


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

    needs_kinematics = True

    def _rotation_delta(self, arm_actions: np.ndarray) -> np.ndarray:
        return arm_actions[:, 3:6] * self.config.rotation_scale

    def _arm_targets(self, state, q, kinematics, arm_actions):
        cfg = self.config
        pos, rot, jac = kinematics
        base = state.base_rot_world
        # Accumulate the delta in the target pose (base-frame deltas -> world).
        move = matvec(base, arm_actions[:, :3] * cfg.translation_scale)
        rotvec = matvec(base, self._rotation_delta(arm_actions))
        state.target_pos = state.target_pos + move
        state.target_rot = matmul(axis_angle_to_mats(rotvec), state.target_rot)
        # Keep the target within reach of the measured TCP (no wind-up when blocked).
        lead = state.target_pos - pos
        dist = norm(lead, axis=1)
        far = dist > cfg.max_lead_pos
        if far.any():
            state.target_pos[far] = pos[far] + lead[far] * (cfg.max_lead_pos / dist[far])[:, None]
        rot_err = rotation_errors(state.target_rot, rot)
        angle = norm(rot_err, axis=1)
        wide = angle > cfg.max_lead_rot
        if wide.any():
            rot_err[wide] *= (cfg.max_lead_rot / angle[wide])[:, None]
            state.target_rot[wide] = matmul(axis_angle_to_mats(rot_err[wide]), rot[wide])
        err = np.concatenate([state.target_pos - pos, rot_err], axis=1)
        dq = dls_limited_batch(jac, err, cfg.ik_damping, q, self.lower, self.upper)
        if self.robot.dof > 6 and cfg.nullspace_gain > 0.0:
            dq += self._nullspace(jac, q, dq)
        # Scale the whole step (keeping its direction) so no joint leads by more than allowed.
        ratio = np.max(np.abs(dq) / self.max_lead, axis=1)
        velocity = dls_batch(
            jac, np.concatenate([move, rotvec], axis=1) / self.period, cfg.ik_damping
        )
        scaled = np.where(ratio[:, None] > 1.0, dq / np.maximum(ratio, 1.0)[:, None], dq)
        return q + scaled, velocity

    def _nullspace(self, jac: np.ndarray, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Pull toward home inside the Jacobian's null space (redundant arms), (N, dof)."""
        pull = self.config.nullspace_gain * (self.robot.home_qpos - q)
        projected = pull - dls_batch(jac, matvec(jac, pull), 1e-4)
        moved = q + dq + projected
        inside = (moved >= self.lower) & (moved <= self.upper)
        return np.where(inside, projected, 0.0)


@CONTROLLERS.register("cartesian_fixed")
class CartesianFixedController(CartesianController):
    """3-DoF TCP translation; the orientation is held at the one captured by ``reset``."""

    name = "cartesian_fixed"

    @property
    def arm_action_dim(self) -> int:
        return 3

    def _rotation_delta(self, arm_actions: np.ndarray) -> np.ndarray:
        return np.zeros((arm_actions.shape[0], 3))


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
    pos = matvec(base.T, controller.target_pos - controller.base_pos_world)
    rot = matmul(base.T, controller.target_rot)
    delta_pos = (np.asarray(target_pos, float) - pos) / cfg.translation_scale
    delta_rot = rotation_error(np.asarray(target_rot, float), rot) / cfg.rotation_scale
    parts = [delta_pos, delta_rot][: 1 + (controller.arm_action_dim == 6)]
    return np.clip(np.concatenate([*parts, [gripper]]), -1.0, 1.0)
