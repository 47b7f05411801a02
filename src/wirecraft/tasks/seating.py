"""Channel seating: lay the cable into a five-segment channel.

Task description
    A cable runs from a clamp block at the channel's entry to a plug lying beside the
    channel.  The robot grasps the plug, lifts it and lays the wire into the channel along its
    path (straight, or with bends), then releases it.

Randomizations (each reset, from the reset seed)
    Channel: fixed position (entry at x = 0.10 m, y = -0.20 m, running along +y).  Curved:
    each of the 4 joints bends by a uniform +/-20 deg, resampled until the heading stays within
    +/-45 deg of the lane (so the channel stays on the table in front of the robot); straight:
    no bends.  The shape is state (mocap segments): no rebuild per episode.
    Cable: the clamp 2 cm before the entry; the wire leaves it 20-35 deg off the channel
    towards the robot, the plug end at 6-11 cm height, rolled +/-18 deg; the assembly falls and
    settles for 1 s.

Success conditions
    success: at least 80% of the wire's length lies inside the channel (over the floor, between
    the walls, below their tops).

Privileged state (82-d for a 6-joint arm; positions in the robot base frame)
    proprioception (2 dof + 2), TCP position (3) and quaternion (4), left/right pad touching the
    plug (2), plug position (3) and quaternion (4), clamp position (3), 10 points along the wire
    (30), the channel's 6 joint points at floor height (18), fraction of the wire inside (1).
"""

from __future__ import annotations

import math

import numpy as np

from wirecraft import validation
from wirecraft.assets.connectors import make_connector
from wirecraft.assets.fixtures import ChannelConfig, add_segmented_channel
from wirecraft.assets.fixtures.channels import MAX_BEND, NUM_SEGMENTS
from wirecraft.sensors import body_geom_ids, mat_to_quat
from wirecraft.tasks.assembly import WireAssembly
from wirecraft.tasks.base import TASKS, Task, shaped

CHANNEL_ENTRY = (0.10, -0.20, 0.0)
CHANNEL_YAW = math.pi / 2  # runs along +y
MAX_HEADING = math.radians(45.0)
CLAMP_BACK = 0.02  # m before the entry
WIRE_ANGLE = (math.radians(20.0), math.radians(35.0))
PLUG_HEIGHT = (0.06, 0.11)
PLUG_ROLL = math.radians(18.0)
SUCCESS_FRACTION = 0.8
WIRE_SAMPLES = 10
CHANNELS = ("straight", "curved")


@TASKS.register("seating")
class SeatingTask(Task):
    name = "seating"
    gym_id = "WireCraft/ChannelSeating-v0"
    default_control = "cartesian_fixed"
    default_weights = {
        "reach": 10.0,
        "grasp": 20.0,
        "lift": 10.0,
        "inside": 50.0,
        "seated": 500.0,
        "action": -0.1,
        "collision": -10.0,
    }

    def __init__(self, channel: str = "straight", connector: str = "ethernet", weights=None):
        super().__init__(weights)
        validation.one_of("seating", "channel", channel, CHANNELS)
        self.channel_kind = channel
        self.connector = make_connector(connector)
        self.bends = (0.0,) * (NUM_SEGMENTS - 1)

    @property
    def instruction(self) -> str:
        return f"Lay the cable into the {self.channel_kind} channel."

    def build_scene(self, spec, wire_config) -> None:
        self.assembly = WireAssembly.build(spec, wire_config, self.connector)
        self.channel = add_segmented_channel(
            spec, ChannelConfig(), name="channel", pos=CHANNEL_ENTRY, yaw=CHANNEL_YAW
        )

    def bind(self, model, robot) -> None:
        super().bind(model, robot)
        self.channel.bind(model)
        self.channel_contacts = body_geom_ids(
            model, [f"channel_seg{i}" for i in range(NUM_SEGMENTS)]
        )
        self.placed = self.channel.placed(self.bends)
        self.fixture_contacts = self.channel_contacts
        self.held_contacts = self.assembly.plug_contacts

    # -- episode ----------------------------------------------------------------------------
    def sample_bends(self, rng) -> tuple[float, ...]:
        if self.channel_kind == "straight":
            return (0.0,) * (NUM_SEGMENTS - 1)
        while True:
            bends = rng.uniform(-MAX_BEND, MAX_BEND, NUM_SEGMENTS - 1)
            if np.all(np.abs(np.cumsum(bends)) <= MAX_HEADING):
                return tuple(float(b) for b in bends)

    def initialize_episode(self, model, data, rng) -> None:
        self.bends = self.sample_bends(rng)
        self.placed = self.channel.set_bends(data, self.bends)
        angle = rng.uniform(*WIRE_ANGLE)
        roll = rng.uniform(-PLUG_ROLL, PLUG_ROLL)
        length = self.assembly.wire.config.length
        entry = np.asarray(CHANNEL_ENTRY, float)
        start = entry + [0.0, -CLAMP_BACK, 0.022]
        rise = rng.uniform(*PLUG_HEIGHT) - start[2]
        pitch = math.asin(rise / length)
        direction = np.array(
            [-math.sin(angle) * math.cos(pitch), math.cos(angle) * math.cos(pitch), math.sin(pitch)]
        )
        self.sampled = {"bends": self.bends, "angle": angle, "roll": roll, "pitch": pitch}
        self.assembly.place(model, data, start + length * direction, direction, roll)

    def fraction_inside(self, model, data) -> float:
        return self.placed.fraction_inside(self.wire_points(model, data))

    # -- observation ------------------------------------------------------------------------
    def privileged_state(self, model, data) -> np.ndarray:
        robot = self.robot
        tcp = self.to_base(data, data.site_xpos[self.tcp_site])
        tcp_rot = self.rot_to_base(data, data.site_xmat[self.tcp_site].reshape(3, 3))
        plug_pos, plug_rot = self.assembly.plug_pose(data)
        points = self.wire_points(model, data)
        samples = points[np.linspace(0, len(points) - 1, WIRE_SAMPLES).round().astype(int)]
        joints = self._channel_joints()
        return np.concatenate(
            [
                robot.proprioception(model, data),
                tcp,
                mat_to_quat(tcp_rot),
                np.array(self.pad_contacts(model, data, self.assembly.plug_contacts), float),
                self.to_base(data, plug_pos),
                mat_to_quat(self.rot_to_base(data, plug_rot)),
                self.to_base(data, data.xpos[model.body(self.assembly.clamp).id]),
                self.to_base(data, samples).ravel(),
                self.to_base(data, joints).ravel(),
                [self.placed.fraction_inside(points)],
            ]
        )

    def _channel_joints(self) -> np.ndarray:
        """(6, 3) world points where the segments meet (and the two ends), at floor height."""
        cfg = self.placed.config
        local = cfg.centerline(samples_per_segment=1)
        c, s = math.cos(self.placed.yaw), math.sin(self.placed.yaw)
        world = local.copy()
        world[:, 0] = c * local[:, 0] - s * local[:, 1] + self.placed.pos[0]
        world[:, 1] = s * local[:, 0] + c * local[:, 1] + self.placed.pos[1]
        world[:, 2] += self.placed.pos[2]
        return world

    # -- reward -----------------------------------------------------------------------------
    def reward_terms(self, model, data, action) -> dict[str, float]:
        held = all(self.pad_contacts(model, data, self.assembly.plug_contacts))
        tcp = data.site_xpos[self.tcp_site]
        grasp_point = data.site_xpos[self.assembly.grasp_site]
        fraction = self.fraction_inside(model, data)
        wall_top = self.placed.config.floor + self.placed.config.wall_height
        plug_z = data.xpos[self.assembly.plug_id][2]
        return {
            "reach": shaped(float(np.linalg.norm(tcp - grasp_point)), 0.1),
            "grasp": float(held),
            "lift": float(held) * float(np.clip((plug_z - wall_top) / 0.03, 0.0, 1.0)),
            "inside": fraction,
            "seated": float(fraction >= SUCCESS_FRACTION),
            "action": float(np.sum(np.square(action))),
            "collision": float(self.gripper_collision(model, data)),
        }

    def evaluate(self, model, data) -> dict[str, float | bool]:
        fraction = self.fraction_inside(model, data)
        return {
            "success": fraction >= SUCCESS_FRACTION,
            "fraction_inside": fraction,
            "grasp_force": self.grasp_force(model, data, self.assembly.plug_contacts),
            **self.cable_diagnostics(model, data),
        }

    def get_state(self) -> dict:
        return {"bends": self.bends}

    def set_state(self, state: dict) -> None:
        self.bends = tuple(state["bends"])
        self.placed = self.channel.placed(self.bends)
