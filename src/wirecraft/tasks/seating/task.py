"""Channel seating: lay the cable into a five-segment channel.

Task description
    A cable runs from a clamp bolted to the board at the channel's entry to a plug lying beside
    the channel.  The robot grasps the plug, lifts it and lays the wire into the channel along
    its path (straight, or with bends), then releases it.

Scene
    The channel's entry is at x = 0.20 m, y = 0 and it runs along -x, towards the robot; its
    five segments are together as long as the wire minus ``CLAMP_BACK`` + ``PLUG_LEAD`` (0.37 m
    for the 0.4 m wire), so a seated wire ends ``PLUG_LEAD`` past the channel's end and the
    plug (wider than the channel) lies beyond it on the table.  (A flex wire starts and ends
    ``end_gap`` away from the bodies on its ends, wires/base.py: seated, it ends that much
    farther past the channel's end; the task's ``plug_lead`` includes it.)  The clamp is
    static (no joint): its wire exit is on the channel's axis ``CLAMP_BACK`` before the entry,
    at the height of a wire resting on the channel floor, and the wire leaves it along the
    channel.

Randomizations (each reset, from the reset seed)
    Channel: fixed position.  Curved: each of the 4 joints bends by a uniform +/-20 deg,
    resampled until the heading stays within +/-45 deg of the lane (so the channel stays on
    the table in front of the robot); straight: no bends.  The shape is state (mocap
    segments): no rebuild per episode.
    Cable: laid ``LEAD`` along the channel out of the clamp, then over the left or right wall
    (random side), turning 20-35 deg off the channel, its plug end 6-11 cm up; the cable falls
    and settles for 1 s (its stiffness keeps its first ~10 cm in the channel: the fraction
    inside starts at ~0.17-0.25).

Success conditions
    success: at least 80% of the wire's whole length lies inside the channel (centre line over
    the floor, between the walls, below their tops).  A fully seated wire scores 0.925 (the
    1 cm out of the clamp and the 2 cm before the plug are outside by construction); a wire
    on the table beside the channel scores 0.

Privileged state (82-d for a 6-joint arm; positions in the robot base frame)
    proprioception (2 dof + 2), TCP position (3) and quaternion (4), left/right pad touching the
    plug (2), plug position (3) and quaternion (4), clamp position (3), 10 points along the wire
    (30), the channel's 6 joint points at floor height (18), fraction of the wire inside (1).
    Quaternion signs are fixed (``quats_near``): the TCP's by the robot's home orientation, the
    plug's by the channel's heading, so that neither jumps between q and -q along an episode.
"""

from __future__ import annotations

import math

import numpy as np

from wirecraft.assets.assembly import WireAssembly
from wirecraft.assets.connectors import make_connector
from wirecraft.assets.fixtures import ChannelConfig, add_segmented_channel
from wirecraft.assets.fixtures.channels import MAX_BEND, NUM_SEGMENTS
from wirecraft.geometry import quats_near, rot_z
from wirecraft.numerics import norm, sum_in_order
from wirecraft.sensors import body_geom_ids
from wirecraft.tasks.base import TASKS, Task, shaped
from wirecraft.tasks.frame import Frame, norms
from wirecraft.tasks.seating.options import SeatingOptions

CHANNEL_ENTRY = (0.20, 0.0, 0.0)
CHANNEL_YAW = math.pi  # runs along -x, towards the robot
MAX_HEADING = math.radians(45.0)
CLAMP_BACK = 0.01  # m: the clamp's wire exit, on the channel's axis before the entry
PLUG_LEAD = 0.02  # m of wire between the channel's end and the plug when the wire is seated
EXIT_GAP = 0.0005  # m: the exit holds the wire this far above resting on the channel floor
LEAD = 0.03  # m of wire laid along the channel out of the clamp at reset
TURN = 0.05  # m over which it then climbs over the wall and turns off the channel
WIRE_ANGLE = (math.radians(20.0), math.radians(35.0))
PLUG_HEIGHT = (0.06, 0.11)
SUCCESS_FRACTION = 0.8
WIRE_SAMPLES = 10


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

    held_body = "plug"

    Options = SeatingOptions
    demo_options = {"channel": "straight"}
    options: SeatingOptions

    def __init__(self, options: SeatingOptions | None = None, weights=None, **values):
        super().__init__(options, weights, **values)
        self.channel_kind = self.options.channel
        self.connector = make_connector(self.options.connector)
        self.bends = (0.0,) * (NUM_SEGMENTS - 1)
        self.plug_lead = PLUG_LEAD

    @property
    def instruction(self) -> str:
        return f"Lay the cable into the {self.channel_kind} channel."

    def build_scene(self, spec, wire_config) -> None:
        resolved = wire_config.resolved()
        radius = resolved.radius
        # The five segments take the wire from the clamp to PLUG_LEAD before the plug: the
        # plug (wider than the channel) stays outside, beyond the channel's end.
        channel = ChannelConfig(
            segment_length=(resolved.length - CLAMP_BACK - PLUG_LEAD) / NUM_SEGMENTS
        )
        # The clamp is bolted to the board in line with the channel: its exit on the channel's
        # axis just before the entry, at the height of a wire resting on the channel floor,
        # the wire leaving along the channel.
        self.clamp_exit = np.array(CHANNEL_ENTRY, float) + [
            -CLAMP_BACK * math.cos(CHANNEL_YAW),
            -CLAMP_BACK * math.sin(CHANNEL_YAW),
            channel.floor + radius + EXIT_GAP,
        ]
        self.assembly = WireAssembly.build(
            spec,
            wire_config,
            self.connector,
            fixed_clamp=(tuple(self.clamp_exit), CHANNEL_YAW),
        )
        self.channel = add_segmented_channel(
            spec, channel, name="channel", pos=CHANNEL_ENTRY, yaw=CHANNEL_YAW
        )
        # A flex wire starts end_gap out of the clamp's exit (wires/base.py): seated, it ends
        # that much farther past the channel's end.
        self.plug_lead = PLUG_LEAD + self.assembly.wire.end_gap

    def bind(self, model, robot) -> None:
        super().bind(model, robot)
        self.channel.bind(model)
        self.channel_contacts = body_geom_ids(
            model, [f"channel_seg{i}" for i in range(NUM_SEGMENTS)]
        )
        self.placed = self.channel.placed(self.bends)
        self.fixture_contacts = self.channel_contacts
        self.held_contacts = self.assembly.plug_contacts
        self.segment_bodies = [model.body(f"channel_seg{i}").id for i in range(NUM_SEGMENTS)]
        self.clamp_id = model.body(self.assembly.clamp).id
        count = self.assembly.wire.num_points
        self.wire_samples = np.linspace(0, count - 1, WIRE_SAMPLES).round().astype(int)

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
        angle = rng.choice([-1.0, 1.0]) * rng.uniform(*WIRE_ANGLE)
        height = rng.uniform(*PLUG_HEIGHT)
        self.sampled = {"bends": self.bends, "angle": angle, "height": height}
        self.assembly.lay_from_clamp(model, data, self.layout(angle, height))

    def layout(self, angle: float, height: float) -> np.ndarray:
        """(K, 3) world polyline of the cable at reset: out of the clamp along the channel for
        ``LEAD``, then climbing over a wall while turning by ``angle`` (signed, left positive)
        over ``TURN`` metres, then straight and rising to the plug end at ``height`` (the
        assembly then falls and settles: the wire drapes over the wall onto the table)."""
        length = self.assembly.wire.config.length
        radius = self.assembly.wire.config.radius
        cfg = self.placed.config
        over_wall = cfg.floor + cfg.wall_height + radius + 0.003
        start = self.clamp_exit
        pts = [start]
        heading = CHANNEL_YAW
        point = start + LEAD * np.array([math.cos(heading), math.sin(heading), 0.0])
        pts.append(point)
        steps = 8
        for k in range(1, steps + 1):
            t = k / steps
            a = heading + t * angle
            point = point + TURN / steps * np.array([math.cos(a), math.sin(a), 0.0])
            point[2] = start[2] + (over_wall - start[2]) * math.sin(t * math.pi / 2)
            pts.append(point.copy())
        rest = length - LEAD - TURN
        a = heading + angle
        end = point + rest * np.array([math.cos(a), math.sin(a), 0.0])
        end[2] = max(height, over_wall)
        pts.append(end)
        return np.asarray(pts)

    def fraction_inside(self, model, data) -> float:
        return float(self.fraction_inside_batch(self.frame_of(data))[0])

    def fraction_inside_batch(self, frame: Frame) -> np.ndarray:
        """(N,) fraction of the wire's length inside the channel: over the floor, between the
        walls of some segment, below their tops (edges judged by their midpoints, weighted by
        their length); the segments' poses are read from the simulation."""
        return frame.cached("fraction_inside", lambda: self._fraction_inside_batch(frame))

    def _fraction_inside_batch(self, frame: Frame) -> np.ndarray:
        cfg = self.channel.config
        points = self.wire_points_batch(frame)
        edges = points[:, 1:] - points[:, :-1]
        lengths = norm(edges)
        mids = points[:, :-1] + edges / 2
        height = mids[..., 2] - frame.xpos[:, self.segment_bodies[0], 2][:, None]
        inside = np.zeros(lengths.shape, bool)
        for body in self.segment_bodies:
            d = mids[..., :2] - frame.xpos[:, body, None, :2]
            cos = frame.xmat[:, body, 0][:, None]  # the segments turn about z only
            sin = frame.xmat[:, body, 3][:, None]
            u = d[..., 0] * cos + d[..., 1] * sin
            v = -d[..., 0] * sin + d[..., 1] * cos
            inside |= (u >= 0) & (u <= cfg.segment_length) & (np.abs(v) <= cfg.inner_width / 2)
        inside &= (height >= cfg.floor) & (height <= cfg.floor + cfg.wall_height)
        total = sum_in_order(lengths)
        within = sum_in_order(np.where(inside, lengths, 0.0))
        return np.where(total > 0, within / np.where(total > 0, total, 1.0), 0.0)

    # -- observation ------------------------------------------------------------------------
    def observe_batch(self, frame: Frame) -> np.ndarray:
        plug = self.assembly.plug_id
        plug_rot = self.rot_to_base_batch(frame, frame.rot("xmat", plug))
        # the plug lies along the channel: its heading fixes the quaternion's sign
        along = self.rot_to_base_batch(frame, np.broadcast_to(rot_z(CHANNEL_YAW), plug_rot.shape))
        samples = self.wire_points_batch(frame)[:, self.wire_samples]
        joints = self.channel_joints_batch(frame)
        return np.concatenate(
            [
                self.robot_state_batch(frame),
                self.pads_touching(frame).astype(float),
                self.to_base_batch(frame, frame.xpos[:, plug]),
                quats_near(plug_rot, along),
                self.to_base_batch(frame, frame.xpos[:, self.clamp_id]),
                self.to_base_batch(frame, samples).reshape(frame.size, -1),
                self.to_base_batch(frame, joints).reshape(frame.size, -1),
                self.fraction_inside_batch(frame)[:, None],
            ],
            axis=1,
        )

    def channel_joints_batch(self, frame: Frame) -> np.ndarray:
        """(N, 6, 3) world points where the segments meet (and the two ends), at floor
        height."""
        cfg = self.channel.config
        starts = frame.xpos[:, self.segment_bodies] + [0.0, 0.0, cfg.floor]
        last = self.segment_bodies[-1]
        direction = np.stack(
            [frame.xmat[:, last, 0], frame.xmat[:, last, 3], np.zeros(frame.size)], axis=1
        )
        end = starts[:, -1] + cfg.segment_length * direction
        return np.concatenate([starts, end[:, None]], axis=1)

    # -- reward -----------------------------------------------------------------------------
    def reward_batch(self, frame, trackers, actions) -> dict[str, np.ndarray]:
        held = self.pads_touching(frame).all(axis=1).astype(float)
        tcp = frame.site_xpos[:, self.tcp_site]
        grasp_point = frame.site_xpos[:, self.assembly.grasp_site]
        fraction = self.fraction_inside_batch(frame)
        cfg = self.channel.config
        wall_top = frame.xpos[:, self.segment_bodies[0], 2] + cfg.floor + cfg.wall_height
        plug_z = frame.xpos[:, self.assembly.plug_id, 2]
        return {
            "reach": shaped(norms(tcp - grasp_point), 0.1),
            "grasp": held,
            "lift": held * np.clip((plug_z - wall_top) / 0.03, 0.0, 1.0),
            "inside": fraction,
            "seated": (fraction >= SUCCESS_FRACTION).astype(float),
            "action": np.sum(np.square(actions), axis=1),
            "collision": self.table_collision(frame).astype(float),
        }

    def evaluate_batch(self, frame, data_of) -> dict[str, np.ndarray]:
        fraction = self.fraction_inside_batch(frame)
        return {"success": fraction >= SUCCESS_FRACTION, "fraction_inside": fraction}

    def get_state(self) -> dict:
        return {"bends": self.bends}

    def set_state(self, state: dict) -> None:
        self.bends = tuple(state["bends"])
        self.placed = self.channel.placed(self.bends)
