"""Universal Robots UR5 (CB3): standard DH facts, published link masses, 2F-85 style gripper.

Sources of the facts: SPEC.md section 4 (UR's published DH table and link masses, joint
speed 180 deg/s, torques 150/150/150/28/28/28 N m).  The elbow is limited to +/- pi as in
practice; the other joints to +/- 2 pi.  Gains, armature and damping are our choices
(docs/robots.md).
"""

from __future__ import annotations

import math

from wirecraft.assets.robots.base import ROBOTS, ArmJoint, RobotSpec, StandardDH

PI = math.pi
SPEED = PI  # rad/s, 180 deg/s on every joint

# (d, a, alpha) per joint, metres and radians.
UR5_DH = (
    (0.089159, 0.0, PI / 2),
    (0.0, -0.425, 0.0),
    (0.0, -0.39225, 0.0),
    (0.10915, 0.0, PI / 2),
    (0.09465, 0.0, -PI / 2),
    (0.0823, 0.0, 0.0),
)

#         lower    upper   speed  torque  mass    kp      armature damping radius
UR5_JOINTS = tuple(
    ArmJoint(*row)
    for row in (
        (-2 * PI, 2 * PI, SPEED, 150.0, 3.7, 3000.0, 0.5, 1.0, 0.060),
        (-2 * PI, 2 * PI, SPEED, 150.0, 8.393, 3000.0, 0.5, 1.0, 0.054),
        (-PI, PI, SPEED, 150.0, 2.33, 2000.0, 0.5, 1.0, 0.045),
        (-2 * PI, 2 * PI, SPEED, 28.0, 1.219, 500.0, 0.1, 0.5, 0.040),
        (-2 * PI, 2 * PI, SPEED, 28.0, 1.219, 500.0, 0.1, 0.5, 0.040),
        (-2 * PI, 2 * PI, SPEED, 28.0, 0.1879, 500.0, 0.1, 0.5, 0.035),
    )
)

UR5 = ROBOTS.register("ur5")(
    RobotSpec(
        name="ur5",
        description="UR5 (CB3), standard DH, with a 2F-85 style parallel-jaw gripper",
        chain=StandardDH(UR5_DH),
        joints=UR5_JOINTS,
        gripper="2f85",
        # UR's DH frame 0 has the arm stretched along -x at q = 0; turn it so q = 0 points forward.
        chain_yaw=PI,
        base_radius=0.075,
        base_height=0.03,
        base_mass=4.0,
        home_reach=0.5,
        home_seed=(-0.2, -1.2, 1.3, -1.6, -PI / 2, 1.4),  # elbow up, wrist down
        dataset_note="6 joint angles + gripper opening = 7-d, the reference schema",
    )
)
