"""Parallel-jaw grippers built from boxes: one design, three sets of facts.

Gripper frame (the ``{prefix}hand`` body): origin on the arm's flange, +z the approach
direction (out of the flange), the fingers close along y.  Each finger is a slide joint
(0 = closed, ``stroke`` = fully open) whose pad's inner face sits at y = +/- q, so the gap
between the pads equals the sum of the two finger positions: ``gripper_opening``.

Actuation mirrors the real coupled mechanisms: one position servo acts on a fixed tendon that
sums both finger positions (tendon length = pad gap, control = commanded gap in metres), and an
equality constraint keeps the fingers symmetric.  The servo is force-limited to ``grip_force``
(newtons of squeeze per finger); joint damping ``grip_force / finger_speed`` caps the free
closing speed at ``finger_speed``.  The TCP site sits between the pads, ``tip_margin`` above the
fingertips (the ends of the pads), ``tcp_offset`` beyond the flange.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from wirecraft import physics, validation
from wirecraft.geometry import mat_to_quat, rot_z
from wirecraft.numerics import norm
from wirecraft.registry import Registry

GRIPPERS: Registry[GripperSpec] = Registry("gripper")

ROBOT_CONTYPE = 2  # robot geoms collide with the world (contype 1) but not with each other
ROBOT_CONAFFINITY = 1
PAD_CONDIM = 4
PAD_PRIORITY = 1
PAD_RGBA = (0.9, 0.55, 0.15, 1.0)
GRIPPER_RGBA = (0.25, 0.25, 0.28, 1.0)
SERVO_SATURATION_GAP = 0.002  # m of gap error at which the gripper servo reaches its force limit


@dataclass(frozen=True)
class GripperSpec:
    """Facts of one parallel-jaw gripper (metres, kilograms, newtons, seconds)."""

    name: str
    description: str
    stroke: float  # travel of each finger; max pad gap = 2 * stroke
    tcp_offset: float  # flange -> TCP along the approach axis
    mount_yaw: float  # rad, rotation of the gripper about the flange z axis
    pad_width: float  # pad contact face extent along x
    pad_length: float  # pad contact face extent along the approach axis
    pad_thickness: float
    palm_half: tuple[float, float, float]  # half extents of the palm box (starts at the flange)
    palm_mass: float
    finger_mass: float
    grip_force: float  # N per finger (servo force limit)
    finger_speed: float  # m/s per finger at full force (sets the finger damping)
    tip_margin: float = 0.008  # TCP distance above the fingertip ends

    def __post_init__(self) -> None:
        owner = f"GripperSpec({self.name})"
        for field in (
            "stroke",
            "tcp_offset",
            "pad_width",
            "pad_length",
            "pad_thickness",
            "palm_mass",
            "finger_mass",
            "grip_force",
            "finger_speed",
        ):
            validation.positive(owner, field, getattr(self, field))
        validation.non_negative(owner, "tip_margin", self.tip_margin)
        for i, half in enumerate(self.palm_half):
            validation.positive(owner, f"palm_half[{i}]", half)
        if self.pad_top <= 2.0 * self.palm_half[2]:
            raise ValueError(
                f"{owner}: pads (from z={self.pad_top:.4f} m) must start below the palm "
                f"(ends at z={2 * self.palm_half[2]:.4f} m)"
            )

    @property
    def max_opening(self) -> float:
        return 2.0 * self.stroke

    @property
    def tip(self) -> float:
        """Fingertip distance from the flange along the approach axis."""
        return self.tcp_offset + self.tip_margin

    @property
    def pad_top(self) -> float:
        return self.tip - self.pad_length

    @property
    def finger_damping(self) -> float:
        return self.grip_force / self.finger_speed

    @property
    def servo_kp(self) -> float:
        return self.grip_force / SERVO_SATURATION_GAP


@dataclass(frozen=True)
class GripperParts:
    """Names of the gripper's elements in the compiled model."""

    hand_body: str
    finger_joints: tuple[str, str]
    pad_geoms: tuple[str, str]
    actuator: str
    tendon: str
    tcp_site: str
    camera: str


def _robot_geom(geom: mujoco.MjsGeom) -> mujoco.MjsGeom:
    geom.contype = ROBOT_CONTYPE
    geom.conaffinity = ROBOT_CONAFFINITY
    return physics.stiff_contact(geom)


def _look_at_quat(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Quaternion of a MuJoCo camera at ``eye`` looking at ``target`` (camera -z = view)."""
    back = eye - target
    back /= norm(back)
    right = np.cross(up, back)
    right /= norm(right)
    cam_up = np.cross(back, right)
    return mat_to_quat(np.column_stack([right, cam_up, back]))


def build_gripper(
    spec: mujoco.MjSpec, flange: mujoco.MjsBody, gripper: GripperSpec, prefix: str
) -> GripperParts:
    """Add ``gripper`` under the ``flange`` body; returns the names of its parts."""
    hand = flange.add_body(name=f"{prefix}hand", quat=mat_to_quat(rot_z(gripper.mount_yaw)))
    hand.gravcomp = 1.0
    px, py, pz = gripper.palm_half
    _robot_geom(
        hand.add_geom(
            name=f"{prefix}palm",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=gripper.palm_half,
            pos=(0.0, 0.0, pz),
            mass=gripper.palm_mass,
            rgba=GRIPPER_RGBA,
        )
    )
    tcp = f"{prefix}tcp"
    hand.add_site(name=tcp, pos=(0.0, 0.0, gripper.tcp_offset), size=(0.004, 0.0, 0.0))

    # Wrist camera: beside the palm on its -x side, level with the finger roots (higher up, the
    # palm filled half the image), looking just past the fingertips.
    eye = np.array([-px - 0.04, 0.0, 2.0 * pz + 0.01])
    camera = f"{prefix}cam_wrist"
    hand.add_camera(
        name=camera,
        pos=eye,
        quat=_look_at_quat(
            eye, np.array([0.0, 0.0, gripper.tip + 0.05]), np.array([1.0, 0.0, 0.0])
        ),
        fovy=75.0,
    )

    link_thickness = 0.006
    link_length = gripper.pad_top - 2.0 * pz
    joints, pads = [], []
    for side, sign in (("left", 1.0), ("right", -1.0)):
        finger = hand.add_body(name=f"{prefix}finger_{side}")
        finger.gravcomp = 1.0
        joint = finger.add_joint(
            name=f"{prefix}finger_{side}",
            type=mujoco.mjtJoint.mjJNT_SLIDE,
            axis=(0.0, sign, 0.0),
            range=(0.0, gripper.stroke),
            damping=gripper.finger_damping,
            armature=0.01,
        )
        joint.solref_limit = physics.CONTACT_SOLREF
        pad = _robot_geom(
            finger.add_geom(
                name=f"{prefix}pad_{side}",
                type=mujoco.mjtGeom.mjGEOM_BOX,
                size=(gripper.pad_width / 2, gripper.pad_thickness / 2, gripper.pad_length / 2),
                pos=(0.0, sign * gripper.pad_thickness / 2, gripper.tip - gripper.pad_length / 2),
                mass=0.3 * gripper.finger_mass,
                rgba=PAD_RGBA,
            )
        )
        pad.condim = PAD_CONDIM
        pad.priority = PAD_PRIORITY
        pad.friction = (physics.PAD_FRICTION, 0.005, 0.0001)
        _robot_geom(
            finger.add_geom(
                name=f"{prefix}finger_link_{side}",
                type=mujoco.mjtGeom.mjGEOM_BOX,
                size=(gripper.pad_width / 2, link_thickness / 2, link_length / 2),
                pos=(
                    0.0,
                    sign * (gripper.pad_thickness + link_thickness / 2),
                    2.0 * pz + link_length / 2,
                ),
                mass=0.7 * gripper.finger_mass,
                rgba=GRIPPER_RGBA,
            )
        )
        joints.append(joint.name)
        pads.append(pad.name)

    tendon = spec.add_tendon(name=f"{prefix}gripper_gap")
    for name in joints:
        tendon.wrap_joint(name, 1.0)
    spec.add_equality(
        type=mujoco.mjtEq.mjEQ_JOINT,
        name1=joints[1],
        name2=joints[0],
        data=[0.0, 1.0, 0.0, 0.0, 0.0] + [0.0] * 7,
        solref=physics.CONTACT_SOLREF,
    )
    actuator = spec.add_actuator(
        name=f"{prefix}gripper",
        target=tendon.name,
        trntype=mujoco.mjtTrn.mjTRN_TENDON,
    )
    actuator.set_to_position(kp=gripper.servo_kp)
    actuator.ctrllimited = True
    actuator.ctrlrange = (0.0, gripper.max_opening)
    actuator.forcelimited = True
    actuator.forcerange = (-gripper.grip_force, gripper.grip_force)
    return GripperParts(
        hand_body=hand.name,
        finger_joints=(joints[0], joints[1]),
        pad_geoms=(pads[0], pads[1]),
        actuator=actuator.name,
        tendon=tendon.name,
        tcp_site=tcp,
        camera=camera,
    )


# -- the three grippers ---------------------------------------------------------------------
GRIPPERS.register("2f85")(
    GripperSpec(
        name="2f85",
        description="Robotiq 2F-85 style: 85 mm stroke, 22 x 37.5 mm pads, TCP 0.174 m",
        stroke=0.0425,
        tcp_offset=0.174,
        mount_yaw=0.0,
        pad_width=0.022,
        pad_length=0.0375,
        pad_thickness=0.006,
        palm_half=(0.035, 0.06, 0.055),
        palm_mass=0.8,
        finger_mass=0.05,
        grip_force=20.0,  # the 2F-85's minimum grip force
        finger_speed=0.075,  # 150 mm/s opening speed
    )
)

GRIPPERS.register("panda_hand")(
    GripperSpec(
        name="panda_hand",
        description="Franka Hand: -45 deg on the flange, fingers 0-0.04 m, TCP 0.1034 m",
        stroke=0.04,
        tcp_offset=0.1034,
        mount_yaw=-np.pi / 4,
        pad_width=0.018,
        pad_length=0.02,
        pad_thickness=0.005,
        palm_half=(0.025, 0.1, 0.029),
        palm_mass=0.70,
        finger_mass=0.015,
        grip_force=20.0,
        finger_speed=0.05,
    )
)

GRIPPERS.register("wxai_gripper")(
    GripperSpec(
        name="wxai_gripper",
        description="WidowX AI two-carriage gripper: 0-0.044 m per carriage, TCP 0.156 m",
        stroke=0.044,
        tcp_offset=0.156062,
        mount_yaw=0.0,
        pad_width=0.02,
        pad_length=0.035,
        pad_thickness=0.005,
        palm_half=(0.03, 0.07, 0.043),
        palm_mass=0.10,
        finger_mass=0.081,
        grip_force=20.0,
        finger_speed=0.0875,
    )
)
