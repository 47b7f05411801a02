"""Robot arms from published kinematic facts: one chain builder for three conventions.

A robot is data (a ``RobotSpec``): a kinematic chain in one of three conventions (standard DH,
modified DH, link offsets), one ``ArmJoint`` row per joint (limits, speed, torque, link mass,
servo gain, armature, damping, link radius), a gripper name and its base placement.
``add_robot`` turns it into nested MjSpec bodies:

- ``{prefix}base`` (fixed, on the table at ``base_pos`` with ``base_yaw``) carries the
  ``{prefix}base`` site: the robot base frame (x forward, z up) in which Cartesian actions are
  expressed.  The chain's own frame 0 (``{prefix}chain_base`` site) is that frame turned by the
  robot's ``chain_yaw``.
- ``{prefix}link1`` ... ``{prefix}linkN``, each with its hinge ``{prefix}joint{i}`` at the
  body origin, a capsule from the joint to the next joint and a cylinder housing on the axis;
  geoms collide with the world but not with each other.  Link masses are the published ones;
  every robot body has ``gravcomp = 1`` (the real controllers compensate gravity).
- ``{prefix}flange`` body and site: the tool flange, +z pointing out of it; the gripper hangs
  below it (grippers.py) with the ``{prefix}tcp`` site between its pads.
- position servos ``{prefix}joint{i}`` (control = joint angle, force-limited to the published
  torques; kv for a damping ratio of 1 against each joint's inertia at home).
- a keyframe ``{prefix}home``: TCP ``home_height`` (0.2 m; 0.12 m for the WidowX AI) above
  the point ``home_reach`` in front of the base, pointing down, fingers closing along the base
  y axis, gripper open, the wrist's last joint near the middle of its range.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Protocol

import mujoco
import numpy as np

from wirecraft import physics, validation
from wirecraft.assets.robots.grippers import (
    GRIPPER_RGBA,
    GRIPPERS,
    ROBOT_CONAFFINITY,
    ROBOT_CONTYPE,
    GripperParts,
    GripperSpec,
    build_gripper,
)
from wirecraft.assets.robots.kinematics import solve_ik
from wirecraft.geometry import mat_to_quat, rot_x, rot_y, rot_z, transform
from wirecraft.numerics import dot, matmul, matvec, norm
from wirecraft.registry import Registry

ROBOTS: Registry[RobotSpec] = Registry("robot")

LINK_RGBA = (0.78, 0.8, 0.84, 1.0)
HOUSING_RGBA = (0.3, 0.45, 0.65, 1.0)
SIDE_CAMERA = "cam_side"
SIDE_CAMERA_POS = (0.6, -0.65, 0.76)  # m, world: front right, sees cable, port, clips, channel
SIDE_CAMERA_TARGET = (0.0, -0.05, 0.05)
HOME_HEIGHT = 0.2  # m, TCP height above the table at home
# TCP orientation at home in the base frame: approach axis (z) down, fingers closing along the
# base y axis, TCP x pointing back at the robot: diag(-1, 1, -1).
HOME_TCP_ROT = np.diag([-1.0, 1.0, -1.0])
MIN_BONE = 1e-3  # m; shorter link segments get no capsule
MAX_JOINT_ANGLE = 4 * np.pi  # rad, sanity bound on joint limits
MAX_BASE_OFFSET = 100.0  # m, sanity bound on base positions


# -- kinematic conventions ------------------------------------------------------------------
@dataclass(frozen=True)
class ChainFrames:
    """Body frames of a serial chain, each relative to its parent.

    link_poses: (4, 4) transform of link i's body frame (joint i at its origin) relative to link
    i-1 (the chain base for i = 1), with every joint at 0.  axes: joint axis in the link frame.
    flange: (4, 4) transform of the flange relative to the last link.
    """

    link_poses: tuple[np.ndarray, ...]
    axes: tuple[tuple[float, float, float], ...]
    flange: np.ndarray


class Chain(Protocol):
    @property
    def dof(self) -> int: ...

    def frames(self) -> ChainFrames: ...


@dataclass(frozen=True)
class StandardDH:
    """Classic DH, one row (d, a, alpha) per joint: T_i = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i).

    The flange is frame N.  Link i's body is frame i-1 turned by q_i, so the joint axis is z.
    """

    rows: tuple[tuple[float, float, float], ...]

    @property
    def dof(self) -> int:
        return len(self.rows)

    @staticmethod
    def _row(d: float, a: float, alpha: float) -> np.ndarray:
        shift = matmul(transform(pos=(0, 0, d)), transform(pos=(a, 0, 0)))
        return matmul(shift, transform(rot_x(alpha)))

    def frames(self) -> ChainFrames:
        poses = [np.eye(4)] + [self._row(*row) for row in self.rows[:-1]]
        return ChainFrames(tuple(poses), ((0.0, 0.0, 1.0),) * self.dof, self._row(*self.rows[-1]))


@dataclass(frozen=True)
class ModifiedDH:
    """Craig's modified DH, one row (a_{i-1}, d_i, alpha_{i-1}) per joint:
    T_i = Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(q_i) Tz(d_i); ``flange`` is one more row without a joint.
    """

    rows: tuple[tuple[float, float, float], ...]
    flange: tuple[float, float, float]

    @property
    def dof(self) -> int:
        return len(self.rows)

    @staticmethod
    def _row(a: float, d: float, alpha: float) -> np.ndarray:
        turn = matmul(transform(rot_x(alpha)), transform(pos=(a, 0, 0)))
        return matmul(turn, transform(pos=(0, 0, d)))

    def frames(self) -> ChainFrames:
        poses = tuple(self._row(*row) for row in self.rows)
        return ChainFrames(poses, ((0.0, 0.0, 1.0),) * self.dof, self._row(*self.flange))


@dataclass(frozen=True)
class LinkOffsets:
    """Joint origins as translations from the previous joint (frames not rotated at q = 0),
    one (offset, axis) row per joint; ``flange`` = (offset, rotation about y in rad)."""

    rows: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...]
    flange_offset: tuple[float, float, float]
    flange_pitch: float  # rad about the last link's y axis, so that the flange z is the tool axis

    @property
    def dof(self) -> int:
        return len(self.rows)

    def frames(self) -> ChainFrames:
        poses = tuple(transform(pos=offset) for offset, _ in self.rows)
        axes = tuple(tuple(float(v) for v in axis) for _, axis in self.rows)
        flange = transform(rot_y(self.flange_pitch), self.flange_offset)
        return ChainFrames(poses, axes, flange)  # type: ignore[arg-type]


# -- per-joint facts ------------------------------------------------------------------------
@dataclass(frozen=True)
class ArmJoint:
    """One row of a robot's joint table (SI units: rad, rad/s, N m, kg, m)."""

    lower: float
    upper: float
    velocity: float  # rad/s, enforced by the controllers (a per-step joint change limit)
    torque: float  # N m, the servo's force limit
    mass: float  # kg of the link this joint moves
    kp: float  # N m / rad, position servo stiffness
    armature: float  # kg m^2, reflected rotor inertia
    damping: float  # N m s / rad, joint viscous friction
    radius: float  # m, link capsule radius (geometry only)

    def __post_init__(self) -> None:
        owner = "ArmJoint"
        validation.in_range(owner, "lower", self.lower, -MAX_JOINT_ANGLE, MAX_JOINT_ANGLE)
        validation.in_range(owner, "upper", self.upper, -MAX_JOINT_ANGLE, MAX_JOINT_ANGLE)
        if not self.lower < self.upper:
            raise ValueError(f"{owner}: lower ({self.lower}) must be < upper ({self.upper})")
        for name in ("velocity", "torque", "mass", "kp", "radius"):
            validation.positive(owner, name, getattr(self, name))
        validation.non_negative(owner, "armature", self.armature)
        validation.non_negative(owner, "damping", self.damping)


@dataclass(frozen=True)
class Workspace:
    """Where a robot can work with its tool pointing down, in the world frame (its base where
    ``home_reach`` puts it): tasks intersect their sampling ranges with it.  Infinite: no limit
    inside the table's task region."""

    max_x: float = math.inf  # m: farthest x at which it holds a pose above a part on the table
    max_height: float = math.inf  # m: highest point at which it holds a part horizontally

    def __post_init__(self) -> None:
        for name in ("max_x", "max_height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or math.isnan(value):
                raise ValueError(
                    f"Workspace.{name} must be a number (inf: no limit), got {value!r}"
                )


@dataclass(frozen=True)
class RobotSpec:
    """Everything needed to build one robot model (a row in the ROBOTS registry)."""

    name: str
    description: str
    chain: StandardDH | ModifiedDH | LinkOffsets
    joints: tuple[ArmJoint, ...]
    gripper: str  # name in GRIPPERS
    chain_yaw: float  # rad, chain frame 0 relative to the base frame (q = 0 points forward)
    base_radius: float  # m, pedestal cylinder
    base_height: float  # m
    home_reach: float  # m in front of the base where the home TCP hovers (the table centre)
    home_seed: tuple[float, ...]  # start of the IK that finds the home configuration
    home_height: float = HOME_HEIGHT  # m, TCP height above the table at home
    # rad about the vertical applied to HOME_TCP_ROT: chosen so that the last joint sits near
    # the middle of its range at home (then +/- 90 deg of tool yaw are always available).
    home_yaw: float = 0.0
    base_mass: float = 2.0
    dataset_note: str = ""
    workspace: Workspace = Workspace()

    def __post_init__(self) -> None:
        owner = f"RobotSpec({self.name})"
        if len(self.joints) != self.chain.dof:
            raise ValueError(
                f"{owner}: {len(self.joints)} joint rows for a {self.chain.dof}-joint chain"
            )
        if len(self.home_seed) != self.chain.dof:
            raise ValueError(f"{owner}.home_seed must have {self.chain.dof} values")
        validation.one_of(owner, "gripper", self.gripper, GRIPPERS.names())
        for name in ("base_radius", "base_height", "home_reach", "home_height", "base_mass"):
            validation.positive(owner, name, getattr(self, name))

    @property
    def dof(self) -> int:
        return self.chain.dof

    @property
    def gripper_spec(self) -> GripperSpec:
        return GRIPPERS.get(self.gripper)

    @property
    def lower(self) -> np.ndarray:
        return np.array([j.lower for j in self.joints])

    @property
    def upper(self) -> np.ndarray:
        return np.array([j.upper for j in self.joints])

    @property
    def velocity(self) -> np.ndarray:
        return np.array([j.velocity for j in self.joints])

    @property
    def home_tcp_rot(self) -> np.ndarray:
        """(3, 3) TCP orientation at home in the base frame (approach axis down)."""
        return matmul(rot_z(self.home_yaw), HOME_TCP_ROT)


# -- model building -------------------------------------------------------------------------
def _robot_geom(body: mujoco.MjsBody, **kwargs) -> mujoco.MjsGeom:
    geom = body.add_geom(**kwargs)
    geom.contype = ROBOT_CONTYPE
    geom.conaffinity = ROBOT_CONAFFINITY
    return physics.stiff_contact(geom)


def _add_link_geoms(
    body: mujoco.MjsBody, name: str, child: np.ndarray, axis: np.ndarray, joint: ArmJoint
):
    """A capsule from the joint to the next joint plus a housing cylinder on the joint axis,
    sharing the published link mass in proportion to their volumes."""
    r = joint.radius
    pieces = []
    length = norm(child)
    housing_half = 0.9 * r
    pieces.append(
        dict(
            name=f"{name}_housing",
            type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            size=(1.1 * r, housing_half, 0.0),
            quat=_z_to(axis),
            rgba=HOUSING_RGBA,
            volume=np.pi * (1.1 * r) ** 2 * 2 * housing_half,
        )
    )
    if length > MIN_BONE:
        pieces.append(
            dict(
                name=f"{name}_bone",
                type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                fromto=(0.0, 0.0, 0.0, *child),
                size=(r, 0.0, 0.0),
                rgba=LINK_RGBA,
                volume=np.pi * r**2 * length + 4.0 / 3.0 * np.pi * r**3,
            )
        )
    total = sum(p["volume"] for p in pieces)
    for piece in pieces:
        volume = piece.pop("volume")
        _robot_geom(body, mass=joint.mass * volume / total, **piece)


def _z_to(axis: np.ndarray) -> np.ndarray:
    """Quaternion turning +z onto ``axis``."""
    axis = np.asarray(axis, float) / norm(axis)
    z = np.array([0.0, 0.0, 1.0])
    cross = np.cross(z, axis)
    s, c = norm(cross), dot(z, axis)
    if s < 1e-9:
        return np.array([1.0, 0.0, 0.0, 0.0]) if c > 0 else np.array([0.0, 1.0, 0.0, 0.0])
    half = math.atan2(s, c) / 2
    return np.concatenate([[math.cos(half)], math.sin(half) * cross / s])


@dataclass(frozen=True)
class _Built:
    joint_names: tuple[str, ...]
    actuator_names: tuple[str, ...]
    gripper: GripperParts


def _build(
    spec: mujoco.MjSpec,
    robot: RobotSpec,
    prefix: str,
    base_pos: tuple[float, float, float],
    base_yaw: float,
    kv: np.ndarray | None = None,
) -> _Built:
    """Add the robot's bodies, joints, servos and gripper; ``kv``: servo damping per joint
    (None: a damping ratio of 1 at the reference configuration, MuJoCo's ``dampratio``)."""
    frames = robot.chain.frames()
    base = spec.worldbody.add_body(
        name=f"{prefix}base", pos=base_pos, quat=mat_to_quat(rot_z(base_yaw))
    )
    base.add_site(name=f"{prefix}base", size=(0.01, 0.0, 0.0))
    _robot_geom(
        base,
        name=f"{prefix}pedestal",
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=(robot.base_radius, robot.base_height / 2, 0.0),
        pos=(0.0, 0.0, robot.base_height / 2),
        mass=robot.base_mass,
        rgba=GRIPPER_RGBA,
    )
    chain_base = base.add_body(name=f"{prefix}chain_base", quat=mat_to_quat(rot_z(robot.chain_yaw)))
    chain_base.add_site(name=f"{prefix}chain_base", size=(0.005, 0.0, 0.0))

    parent = chain_base
    joint_names, actuator_names = [], []
    n = robot.dof
    for i, (pose, axis, row) in enumerate(
        zip(frames.link_poses, frames.axes, robot.joints, strict=True)
    ):
        link = parent.add_body(
            name=f"{prefix}link{i + 1}", pos=pose[:3, 3], quat=mat_to_quat(pose[:3, :3])
        )
        link.gravcomp = 1.0
        joint = link.add_joint(
            name=f"{prefix}joint{i + 1}",
            type=mujoco.mjtJoint.mjJNT_HINGE,
            axis=axis,
            range=(row.lower, row.upper),
            armature=row.armature,
            damping=row.damping,
        )
        joint.solref_limit = physics.CONTACT_SOLREF  # a hard stop, as stiff as the contacts
        child = frames.link_poses[i + 1] if i + 1 < n else frames.flange
        _add_link_geoms(link, f"{prefix}link{i + 1}", child[:3, 3], np.asarray(axis), row)
        actuator = spec.add_actuator(
            name=f"{prefix}joint{i + 1}", target=joint.name, trntype=mujoco.mjtTrn.mjTRN_JOINT
        )
        if kv is None:
            actuator.set_to_position(kp=row.kp, dampratio=1.0)
        else:
            actuator.set_to_position(kp=row.kp, kv=float(kv[i]))
        actuator.ctrllimited = True
        actuator.ctrlrange = (row.lower, row.upper)
        actuator.forcelimited = True
        actuator.forcerange = (-row.torque, row.torque)
        joint_names.append(joint.name)
        actuator_names.append(actuator.name)
        if i == 0:  # the first link turns inside the base, at table level
            spec.add_exclude(bodyname1="world", bodyname2=link.name)
        parent = link

    flange = parent.add_body(
        name=f"{prefix}flange",
        pos=frames.flange[:3, 3],
        quat=mat_to_quat(frames.flange[:3, :3]),
    )
    flange.gravcomp = 1.0
    flange.add_site(name=f"{prefix}flange", size=(0.006, 0.0, 0.0))
    parts = build_gripper(spec, flange, robot.gripper_spec, prefix)
    return _Built(tuple(joint_names), tuple(actuator_names), parts)


def add_side_camera(spec: mujoco.MjSpec, name: str = SIDE_CAMERA) -> None:
    """A fixed world camera looking at the table centre from the side (added once per spec)."""
    if spec.camera(name) is not None:
        return
    from wirecraft.assets.robots.grippers import _look_at_quat

    eye = np.asarray(SIDE_CAMERA_POS, float)
    quat = _look_at_quat(eye, np.asarray(SIDE_CAMERA_TARGET, float), np.array([0.0, 0.0, 1.0]))
    spec.worldbody.add_camera(name=name, pos=eye, quat=quat, fovy=50.0)


@functools.cache
def _home_solution(name: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Home joint angles and the joint-space inertia diagonal (kg m^2, armature included)
    there, from a model of the robot alone."""
    robot = ROBOTS.get(name)
    spec = mujoco.MjSpec()
    built = _build(spec, robot, "", (0.0, 0.0, 0.0), 0.0)
    model = spec.compile()
    data = mujoco.MjData(model)
    qadr = np.array([model.joint(j).qposadr[0] for j in built.joint_names])
    dadr = np.array([model.joint(j).dofadr[0] for j in built.joint_names])
    data.qpos[qadr] = robot.home_seed
    q, err = solve_ik(
        model,
        data,
        model.site(built.gripper.tcp_site).id,
        qadr,
        dadr,
        np.array([robot.home_reach, 0.0, robot.home_height]),
        robot.home_tcp_rot,
        robot.lower,
        robot.upper,
    )
    if err > 1e-6:
        raise RuntimeError(f"robot {name!r}: home pose not reachable from its seed (error {err})")
    data.qpos[:] = model.qpos0
    data.qpos[qadr] = q
    mujoco.mj_forward(model, data)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    inertia = np.diag(full)[dadr]
    return tuple(float(v) for v in q), tuple(float(v) for v in inertia)


def home_qpos(name: str) -> tuple[float, ...]:
    """Arm joint angles that put the TCP ``home_height`` above the point ``home_reach`` in
    front of the base, pointing down (``home_tcp_rot``); solved once by IK from the seed."""
    return _home_solution(name)[0]


def servo_damping(name: str) -> np.ndarray:
    """Servo kv per joint: critical damping of kp against the joint's inertia at home."""
    robot = ROBOTS.get(name)
    kp = np.array([j.kp for j in robot.joints])
    return 2.0 * np.sqrt(kp * np.array(_home_solution(name)[1]))


# -- handle ---------------------------------------------------------------------------------
@dataclass
class _Index:
    model: mujoco.MjModel
    arm_qpos: np.ndarray
    arm_dof: np.ndarray
    finger_qpos: np.ndarray
    finger_dof: np.ndarray
    arm_act: np.ndarray
    gripper_act: int
    tcp_site: int
    base_site: int


@dataclass
class RobotHandle:
    """Names of one robot's elements and readers of its state (any model that contains it)."""

    name: str
    prefix: str
    spec: RobotSpec
    base_pos: tuple[float, float, float]
    base_yaw: float
    arm_joint_names: tuple[str, ...]
    arm_actuator_names: tuple[str, ...]
    gripper_joint_names: tuple[str, str]
    gripper_actuator_name: str
    gripper_tendon_name: str
    pad_geom_names: tuple[str, str]
    hand_body: str
    tcp_site: str
    flange_site: str
    base_site: str
    chain_base_site: str
    wrist_camera: str
    side_camera: str | None
    home_keyframe: str | None
    home_qpos: np.ndarray
    _index: _Index | None = field(default=None, repr=False)

    # -- static facts ----------------------------------------------------------------------
    @property
    def dof(self) -> int:
        return self.spec.dof

    @property
    def gripper(self) -> GripperSpec:
        return self.spec.gripper_spec

    @property
    def max_opening(self) -> float:
        return self.gripper.max_opening

    @property
    def joint_lower(self) -> np.ndarray:
        return self.spec.lower

    @property
    def joint_upper(self) -> np.ndarray:
        return self.spec.upper

    @property
    def joint_velocity(self) -> np.ndarray:
        return self.spec.velocity

    @property
    def base_rot(self) -> np.ndarray:
        return rot_z(self.base_yaw)

    @property
    def home_tcp_pos(self) -> np.ndarray:
        """(3,) TCP position at home in the base frame."""
        return np.array([self.spec.home_reach, 0.0, self.spec.home_height])

    @property
    def home_tcp_rot(self) -> np.ndarray:
        """(3, 3) TCP orientation at home in the base frame."""
        return self.spec.home_tcp_rot

    # -- indices ---------------------------------------------------------------------------
    def index(self, model: mujoco.MjModel) -> _Index:
        """Addresses of this robot's joints, actuators and sites in ``model`` (cached)."""
        if self._index is None or self._index.model is not model:
            joints = [model.joint(n) for n in self.arm_joint_names]
            fingers = [model.joint(n) for n in self.gripper_joint_names]
            self._index = _Index(
                model=model,
                arm_qpos=np.array([j.qposadr[0] for j in joints]),
                arm_dof=np.array([j.dofadr[0] for j in joints]),
                finger_qpos=np.array([j.qposadr[0] for j in fingers]),
                finger_dof=np.array([j.dofadr[0] for j in fingers]),
                arm_act=np.array([model.actuator(n).id for n in self.arm_actuator_names]),
                gripper_act=model.actuator(self.gripper_actuator_name).id,
                tcp_site=model.site(self.tcp_site).id,
                base_site=model.site(self.base_site).id,
            )
        return self._index

    # -- state readers ---------------------------------------------------------------------
    def arm_qpos(self, model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
        """(dof,) arm joint angles, rad."""
        return data.qpos[self.index(model).arm_qpos].copy()

    def arm_qvel(self, model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
        """(dof,) arm joint velocities, rad/s."""
        return data.qvel[self.index(model).arm_dof].copy()

    def gripper_opening(self, model: mujoco.MjModel, data: mujoco.MjData) -> float:
        """Gap between the pads, m (0 closed ... ``max_opening``)."""
        return float(data.qpos[self.index(model).finger_qpos].sum())

    def gripper_velocity(self, model: mujoco.MjModel, data: mujoco.MjData) -> float:
        """Rate of change of the pad gap, m/s (positive = opening)."""
        return float(data.qvel[self.index(model).finger_dof].sum())

    def tcp_pose(self, model: mujoco.MjModel, data: mujoco.MjData):
        """World position (3,) and rotation matrix (3, 3) of the TCP (needs current kinematics)."""
        i = self.index(model).tcp_site
        return data.site_xpos[i].copy(), data.site_xmat[i].reshape(3, 3).copy()

    def tcp_pose_base(self, model: mujoco.MjModel, data: mujoco.MjData):
        """TCP position (3,) and rotation (3, 3) in the robot base frame."""
        idx = self.index(model)
        pos, rot = self.tcp_pose(model, data)
        base_pos = data.site_xpos[idx.base_site]
        base_rot = data.site_xmat[idx.base_site].reshape(3, 3)
        return matvec(base_rot.T, pos - base_pos), matmul(base_rot.T, rot)

    def proprioception(self, model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
        """(2 dof + 2,): joint angles, gripper opening, joint velocities, gripper opening rate."""
        return np.concatenate(
            [
                self.arm_qpos(model, data),
                [self.gripper_opening(model, data)],
                self.arm_qvel(model, data),
                [self.gripper_velocity(model, data)],
            ]
        )

    def dataset_state(self, model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
        """(dof + 1,) the dataset's ``observation.state``: joint angles then gripper opening (m).

        7-d for the UR5 and the WidowX AI, 8-d for the 7-joint Panda (see docs/robots.md).
        """
        return np.concatenate([self.arm_qpos(model, data), [self.gripper_opening(model, data)]])

    # -- state writers ---------------------------------------------------------------------
    def reset_home(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Put the arm at home, the gripper open, velocities zero, servos holding; forward."""
        idx = self.index(model)
        data.qpos[idx.arm_qpos] = self.home_qpos
        data.qpos[idx.finger_qpos] = self.gripper.stroke
        data.qvel[idx.arm_dof] = 0.0
        data.qvel[idx.finger_dof] = 0.0
        data.ctrl[idx.arm_act] = self.home_qpos
        data.ctrl[idx.gripper_act] = self.max_opening
        mujoco.mj_forward(model, data)


def _add_home_keyframe(spec: mujoco.MjSpec, handle: RobotHandle) -> str | None:
    """A keyframe with the robot at home and every other joint at its reference position.

    Keyframes are positional over the whole qpos, so the current spec is compiled to find the
    robot's addresses; joints added later take their defaults.  Returns None if the spec does
    not compile yet (use ``RobotHandle.reset_home`` then).
    """
    try:
        model = spec.compile()
    except ValueError:
        return None
    data = mujoco.MjData(model)
    handle.reset_home(model, data)
    handle._index = None
    name = f"{handle.prefix}home"
    spec.add_key(name=name, qpos=data.qpos.copy(), ctrl=data.ctrl.copy())
    return name


def add_robot(
    spec: mujoco.MjSpec,
    name: str = "ur5",
    *,
    prefix: str = "",
    base_pos: tuple[float, float, float] | None = None,
    base_yaw: float = 0.0,
    side_camera: bool = True,
    keyframe: bool = True,
) -> RobotHandle:
    """Add robot ``name`` (see ``ROBOTS``) with its gripper to ``spec``.

    base_pos: where the base sits on the table (z = 0 is the table top); default: ``home_reach``
    behind the table centre, so the TCP's home hovers over the table centre.  base_yaw: rad
    about z (0 = the robot faces +x).  prefix: prepended to every name (two arms need two).
    side_camera: also add the world camera ``cam_side`` (once per spec).
    """
    robot = ROBOTS.get(name)
    if base_pos is None:
        base_pos = (-robot.home_reach, 0.0, 0.0)
    if len(base_pos) != 3:
        raise ValueError(f"add_robot.base_pos must have 3 values, got {base_pos!r}")
    base_pos = tuple(
        validation.in_range("add_robot", "base_pos", v, -MAX_BASE_OFFSET, MAX_BASE_OFFSET)
        for v in base_pos
    )
    base_yaw = validation.in_range(
        "add_robot", "base_yaw", base_yaw, -MAX_JOINT_ANGLE, MAX_JOINT_ANGLE
    )
    built = _build(spec, robot, prefix, base_pos, base_yaw, kv=servo_damping(name))
    if side_camera:
        add_side_camera(spec)
    handle = RobotHandle(
        name=name,
        prefix=prefix,
        spec=robot,
        base_pos=base_pos,  # type: ignore[arg-type]
        base_yaw=base_yaw,
        arm_joint_names=built.joint_names,
        arm_actuator_names=built.actuator_names,
        gripper_joint_names=built.gripper.finger_joints,
        gripper_actuator_name=built.gripper.actuator,
        gripper_tendon_name=built.gripper.tendon,
        pad_geom_names=built.gripper.pad_geoms,
        hand_body=built.gripper.hand_body,
        tcp_site=built.gripper.tcp_site,
        flange_site=f"{prefix}flange",
        base_site=f"{prefix}base",
        chain_base_site=f"{prefix}chain_base",
        wrist_camera=built.gripper.camera,
        side_camera=SIDE_CAMERA if side_camera else None,
        home_keyframe=None,
        home_qpos=np.array(home_qpos(name)),
    )
    if keyframe:
        handle.home_keyframe = _add_home_keyframe(spec, handle)
    return handle
