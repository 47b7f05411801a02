"""Trossen WidowX AI: link offsets and joint axes, published masses, two-carriage gripper.

Sources: SPEC.md section 4 (link offsets, limits, speeds); joint axes, the sign of the
shoulder-to-elbow offset and link masses from Trossen's public description
(trossen_arm_description); torques 27 N m (j0-2) and 7 N m (j3-5) from Trossen's
specification page.  The last link's 0.555 kg is split: 0.455 kg wrist + 0.1 kg gripper palm.
The tool axis is the last link's +x: the flange turns z onto it (pitch +90 deg).

Servo gains are our choice, set as stiff relative to each joint's torque as the UR5's and the
Panda's: a joint reaches its torque limit ~0.03 rad from its target (UR5 0.05, Panda 0.02-0.04
rad).  The first gains (300 and 60 N m / rad, 0.09-0.12 rad) let the arm yield: pressing the
wire into the seating channel, the pad rode up to the wall tops, and carrying the plug, the TCP
stopped ~5 mm short against the wire's pull (docs/experts.md, "The WidowX AI's servos").
"""

from __future__ import annotations

import math

from wirecraft.assets.robots.base import ROBOTS, ArmJoint, LinkOffsets, RobotSpec, Workspace

PI = math.pi

# (offset from the previous joint, joint axis), metres; joint 0 first.
WXAI_OFFSETS = (
    ((0.0, 0.0, 0.05725), (0.0, 0.0, 1.0)),
    ((0.02, 0.0, 0.04625), (0.0, 1.0, 0.0)),
    ((-0.264, 0.0, 0.0), (0.0, -1.0, 0.0)),
    ((0.245, 0.0, 0.06), (0.0, -1.0, 0.0)),
    ((0.06775, 0.0, 0.0455), (0.0, 0.0, -1.0)),
    ((0.02895, 0.0, -0.0455), (1.0, 0.0, 0.0)),
)

#         lower    upper   speed  torque mass    kp     armature damping radius
WXAI_JOINTS = tuple(
    ArmJoint(*row)
    for row in (
        (-3.054, 3.054, 3.375, 27.0, 0.153, 1000.0, 0.05, 0.3, 0.040),
        (0.0, 3.14, 3.375, 27.0, 1.153, 1000.0, 0.05, 0.3, 0.035),
        (0.0, 2.356, 3.375, 27.0, 0.687, 1000.0, 0.05, 0.3, 0.030),
        (-1.57, 1.57, 7.0, 7.0, 0.458, 200.0, 0.01, 0.1, 0.028),
        (-1.57, 1.57, 7.0, 7.0, 0.367, 200.0, 0.01, 0.1, 0.025),
        (-3.14, 3.14, 7.0, 7.0, 0.455, 200.0, 0.01, 0.1, 0.025),
    )
)

WXAI = ROBOTS.register("wxai")(
    RobotSpec(
        name="wxai",
        description="Trossen WidowX AI (6 joints) with its two-carriage parallel gripper",
        chain=LinkOffsets(WXAI_OFFSETS, flange_offset=(0.0, 0.0, 0.0), flange_pitch=PI / 2),
        joints=WXAI_JOINTS,
        gripper="wxai_gripper",
        chain_yaw=0.0,
        base_radius=0.045,
        base_height=0.05,
        base_mass=0.46,
        # The arm cannot point the tool straight down 0.2 m above the table (the wrist pitch
        # limit of 90 deg would be exceeded): home hovers 0.12 m up, 0.3 m in front.
        home_reach=0.3,
        home_height=0.12,
        home_seed=(0.0, 1.7, 1.5, -1.35, 0.0, 0.0),
        dataset_note="6 joint angles + gripper opening = 7-d, like the UR5",
        # With the tool pointing down it cannot hold a pose above a part beyond x = 0.10 m
        # (0.40 m in front of its base; its elbow reaches its limit near 0.46 m), nor hold a
        # horizontal plug at a mouth higher than ~0.13 m (measured with the insertion expert;
        # docs/experts.md, "The WidowX AI's reach").
        workspace=Workspace(max_x=0.10, max_height=0.13),
    )
)
