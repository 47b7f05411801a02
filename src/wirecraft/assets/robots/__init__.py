"""Robot arms with grippers, built from published kinematic facts (see docs/robots.md).

Add a robot: write its fact table in a new module (a ``RobotSpec`` registered in ``ROBOTS``)
and import the module here.
"""

from wirecraft.assets.robots import panda, ur5, wxai  # noqa: F401  (registers the robots)
from wirecraft.assets.robots.base import (
    HOME_HEIGHT,
    HOME_TCP_ROT,
    ROBOTS,
    SIDE_CAMERA,
    ArmJoint,
    LinkOffsets,
    ModifiedDH,
    RobotHandle,
    RobotSpec,
    StandardDH,
    add_robot,
    add_side_camera,
    home_qpos,
)
from wirecraft.assets.robots.grippers import GRIPPERS, GripperSpec

__all__ = [
    "GRIPPERS",
    "HOME_HEIGHT",
    "HOME_TCP_ROT",
    "ROBOTS",
    "SIDE_CAMERA",
    "ArmJoint",
    "GripperSpec",
    "LinkOffsets",
    "ModifiedDH",
    "RobotHandle",
    "RobotSpec",
    "StandardDH",
    "add_robot",
    "add_side_camera",
    "home_qpos",
]
