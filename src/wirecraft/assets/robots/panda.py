"""Franka Emika Panda: modified DH facts, Franka's published link masses, Franka Hand.

Sources: SPEC.md section 4 (modified DH, limits, speeds 2.175 / 2.61 rad/s), torques
87 N m (j1-4) and 12 N m (j5-7), link masses from Franka's published inertial parameters.
The hand sits on the flange turned -45 deg about z; its TCP is 0.1034 m beyond it.
"""

from __future__ import annotations

import math

from wirecraft.assets.robots.base import ROBOTS, ArmJoint, ModifiedDH, RobotSpec

PI = math.pi

# (a_{i-1}, d_i, alpha_{i-1}) per joint, metres and radians; the flange is one more row.
PANDA_MDH = (
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -PI / 2),
    (0.0, 0.316, PI / 2),
    (0.0825, 0.0, PI / 2),
    (-0.0825, 0.384, -PI / 2),
    (0.0, 0.0, PI / 2),
    (0.088, 0.0, PI / 2),
)
PANDA_FLANGE = (0.0, 0.107, 0.0)

#         lower     upper    speed  torque mass      kp      armature damping radius
PANDA_JOINTS = tuple(
    ArmJoint(*row)
    for row in (
        (-2.8973, 2.8973, 2.175, 87.0, 4.970684, 2000.0, 0.1, 1.0, 0.060),
        (-1.7628, 1.7628, 2.175, 87.0, 0.646926, 2000.0, 0.1, 1.0, 0.060),
        (-2.8973, 2.8973, 2.175, 87.0, 3.228604, 2000.0, 0.1, 1.0, 0.058),
        (-3.0718, -0.0698, 2.175, 87.0, 3.587895, 2000.0, 0.1, 1.0, 0.055),
        (-2.8973, 2.8973, 2.61, 12.0, 1.225946, 500.0, 0.1, 0.5, 0.055),
        (-0.0175, 3.7525, 2.61, 12.0, 1.666555, 500.0, 0.1, 0.5, 0.050),
        (-2.8973, 2.8973, 2.61, 12.0, 0.735522, 300.0, 0.1, 0.5, 0.045),
    )
)

PANDA = ROBOTS.register("panda")(
    RobotSpec(
        name="panda",
        description="Franka Emika Panda, modified DH, with the Franka Hand",
        chain=ModifiedDH(PANDA_MDH, PANDA_FLANGE),
        joints=PANDA_JOINTS,
        gripper="panda_hand",
        chain_yaw=0.0,
        base_radius=0.065,
        base_height=0.2,
        base_mass=4.0,
        home_reach=0.5,
        home_seed=(0.0, 0.2, 0.0, -2.0, 0.0, 2.2, PI / 4),
        home_yaw=PI,  # the hand's x forward: joint 7 at pi/4, mid-range
        dataset_note="7 joint angles + gripper opening = 8-d (the redundant joint is kept)",
    )
)
