"""Clip routing: press the cable into every U-slot clip along a lane.

Task description
    A cable (clamp block on its start, plug on its end) lies on the table beside a lane of
    1-3 U-slot clips.  The plug is wider than the clip mouth, so the robot grasps the wire
    itself, lifts it over each clip in turn and pushes it down past the compliant lip.

Randomizations (each reset, from the reset seed)
    Clips: fixed along the lane (world +y) at places that depend on the number of clips
    (``LAYOUTS``); each clip +/-6 cm across the lane, yaw +/-15 deg.  With several clips,
    neighbouring clips are at most
    ``max_across`` apart across the lane (rejection sampling): a 0.4 m cable cannot follow a
    zigzag of 12 cm steps through three clips 8.5 cm apart, and its 33 mm segments cannot bend
    sharply enough between slots.  Every clip still lies within +/-6 cm of the lane.  The
    lane is the line x = 0.10 m, nearer the robot where its ``workspace`` ends within 6 cm of
    it (the WidowX AI: x = 0.04 m, ``lane_x``); the clamp and cable move with it.
    Cable: clamp block on the table at the lane's start; the wire leaves it at
    ``wire_angle`` off the lane towards the robot (steep enough that the fallen cable clears
    the first clip), its plug end at 6-11 cm height, rolled +/-18 deg; the assembly then falls
    and settles for 1 s.  (The connector's own offset and yaw ranges of the insertion task are
    not applied: they would drop the cable onto the clips.)

Success conditions
    success: for every clip, some point of the wire's centre line (the polyline through its
    nodes) lies inside its slot, below the lips.

Privileged state (80-d for a 6-joint arm; positions in the robot base frame)
    proprioception (2 dof + 2), TCP position (3) and quaternion (4), left/right pad touching the
    wire (2); for 3 clip places: present flag, slot centre (3), cos and sin of the slot's yaw
    in the base frame (2), wire seated in it (1) (7 each, zeros where no clip); 10 points along
    the wire (30); clamp position (3); plug position (3).  The TCP quaternion's sign is fixed by
    the robot's home orientation (``quats_near``): it does not jump between q and -q.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from wirecraft.assets.assembly import WireAssembly
from wirecraft.assets.connectors import make_connector
from wirecraft.assets.fixtures import ClipConfig, PlacedClip, add_clip
from wirecraft.geometry import segments_meet_box
from wirecraft.sensors import body_geom_ids
from wirecraft.tasks.base import EPISODE_SECONDS, TASKS, Task, shaped
from wirecraft.tasks.frame import Frame, norms
from wirecraft.tasks.routing.options import MAX_CLIPS, RoutingOptions

LANE_X = 0.10  # m (world): the lane's line, 0.40 m in front of the WidowX AI's base
# A robot whose workspace ends before LANE_X + LANE_JITTER gets its lane that much nearer
# (``lane_x``), so that no clip lies beyond its reach; the clips, clamp and cable move with it,
# from the same draws.  With the shared lane the WidowX AI's approach stalled short of grasp
# points past the far clips until the phase timed out (docs/experts.md, "The WidowX AI's
# reach").
LANE_JITTER = 0.06  # m across the lane
CLIP_YAW_JITTER = math.radians(15.0)
PLUG_HEIGHT = (0.06, 0.11)
PLUG_ROLL = math.radians(18.0)


@dataclass(frozen=True)
class RouteLayout:
    """Where the clips and the clamp sit along the lane, and how the cable is laid out."""

    clip_y: tuple[float, ...]  # m along the lane
    clamp_y: float  # m along the lane
    wire_angle: tuple[float, float]  # rad off the lane, towards the robot
    max_across: float  # m: largest offset across the lane between neighbouring clips

    def route_length(self, clip_offsets) -> float:
        """m of centre line from the clamp through every slot centre (straight hops), for clips
        at ``clip_offsets`` (m) across the lane from the clamp: the same on every robot's lane."""
        xs = np.concatenate([[0.0], np.asarray(clip_offsets, float)])
        ys = np.concatenate([[self.clamp_y], self.clip_y])
        return float(np.hypot(np.diff(xs), np.diff(ys)).sum())


# Why these places: the gripper holds the cable ~2.5 cm past the last clip (front of the clip)
# and keeps ~2 cm of wire before the plug, so the route from the clamp through every slot may
# use at most ~0.35 m of a 0.4 m cable (``MAX_ROUTE``); the widest zigzag allowed stays below
# it.  The wire angle keeps the fallen cable >= 1.5 cm off the first clip.  1 clip keeps the
# original, roomier layout.
LAYOUTS = {
    1: RouteLayout((0.0,), -0.24, (math.radians(25.0), math.radians(40.0)), 2 * LANE_JITTER),
    2: RouteLayout((-0.06, 0.06), -0.18, (math.radians(36.0), math.radians(50.0)), 0.05),
    3: RouteLayout((-0.085, 0.0, 0.085), -0.185, (math.radians(36.0), math.radians(50.0)), 0.04),
}
CLIP_Y = {n: layout.clip_y for n, layout in LAYOUTS.items()}
MAX_ROUTE = 0.35  # m of a 0.4 m cable the route from the clamp through every slot may use
# The lips narrow the mouth 2 mm below the wire's diameter: a 6 cm piece of seated wire then
# stays in under a slowly growing upward pull of 1 N (about twice the whole cable's weight; it
# comes out at 2 N), where 1 mm of interference let it out at 0.5 N, less than the stiff wire
# pries on a clip when the gripper bends it over the next one (tests/test_routing_layout.py).
LIP_INTERFERENCE = 0.002  # m
WIRE_SAMPLES = 10


@TASKS.register("routing")
class RoutingTask(Task):
    name = "routing"
    gym_id = "WireCraft/ClipRouting-v0"
    default_control = "cartesian"
    default_weights = {
        "reach": 10.0,
        "grasp": 20.0,
        "lift": 10.0,
        "over_slot": 20.0,
        "routed": 50.0,
        "all_routed": 500.0,
        "action": -0.1,
        "collision": -10.0,
    }

    Options = RoutingOptions
    demo_options = {"num_clips": 1}
    options: RoutingOptions

    def __init__(self, options: RoutingOptions | None = None, weights=None, **values):
        super().__init__(options, weights, **values)
        self.num_clips = self.options.num_clips
        self.layout = LAYOUTS[self.num_clips]
        self.clip_opening = self.options.clip_opening
        self.connector = make_connector(self.options.connector)

    @property
    def episode_seconds(self) -> float:
        # Each clip is its own grasp-route-release cycle (the route re-grasps between clips),
        # so every clip gets the time of a one-clip episode.
        return EPISODE_SECONDS * self.num_clips

    @property
    def instruction(self) -> str:
        clips = "the clip" if self.num_clips == 1 else f"all {self.num_clips} clips"
        return f"Route the cable through {clips}."

    def build_scene(self, spec, wire_config) -> None:
        self.assembly = WireAssembly.build(spec, wire_config, self.connector)
        diameter = 2 * self.assembly.wire.config.radius
        default = diameter - LIP_INTERFERENCE
        opening = self.clip_opening if self.clip_opening is not None else default
        slot = max(ClipConfig().slot_width, diameter + 0.002)
        if opening > slot:
            raise ValueError(
                f"routing.clip_opening must be in (0, {slot}] m (at the clip's slot width, "
                f"{slot} m for this wire, the clip has no lips), got {opening!r}"
            )
        self.clip_config = ClipConfig(slot_width=slot, opening=opening)
        self.clip_names = []
        for i in range(self.num_clips):
            mount = spec.worldbody.add_body(name=f"clip{i}_mount", mocap=True)
            add_clip(spec, self.clip_config, name=f"clip{i}", parent=mount)
            self.clip_names.append(f"clip{i}")

    def bind(self, model, robot) -> None:
        super().bind(model, robot)
        self.clip_mocap = [model.body(f"{n}_mount").mocapid[0] for n in self.clip_names]
        self.clip_bodies = [model.body(n).id for n in self.clip_names]
        self.clip_contacts = body_geom_ids(model, self.clip_names)
        self.fixture_contacts = self.clip_contacts
        self.held_contacts = self.assembly.wire_contacts
        self.clamp_id = model.body(self.assembly.clamp).id
        count = self.assembly.wire.num_points
        self.wire_samples = np.linspace(0, count - 1, WIRE_SAMPLES).round().astype(int)
        if model.nflex > len(self.assembly.wire_contacts.flexes):
            raise ValueError("routing: the pads' wire sensors need the wire as the only flex")

    def held_criteria(self, spec, pad):
        return self.assembly.wire.touch_criteria(spec, pad)  # the pads hold the wire itself

    # -- episode ----------------------------------------------------------------------------
    def lane_x(self) -> float:
        """x of the lane's line for this task's robot (m, world): ``LANE_X``, or nearer where
        the robot's workspace ends within ``LANE_JITTER`` of it (to the micrometre)."""
        return min(LANE_X, round(self.workspace.max_x - LANE_JITTER, 6))

    def initialize_episode(self, model, data, rng) -> None:
        layout = self.layout
        self.sampled = {"clips": []}
        xs = self._sample_clip_x(rng)
        for mocap, x, y in zip(self.clip_mocap, xs, layout.clip_y, strict=True):
            yaw = math.pi / 2 + rng.uniform(-CLIP_YAW_JITTER, CLIP_YAW_JITTER)
            data.mocap_pos[mocap] = (x, y, 0.0)
            data.mocap_quat[mocap] = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
            self.sampled["clips"].append((x, y, yaw))
        angle = rng.uniform(*layout.wire_angle)
        roll = rng.uniform(-PLUG_ROLL, PLUG_ROLL)
        length = self.assembly.wire.config.length
        start = np.array([self.lane_x(), layout.clamp_y, 0.02])
        rise = rng.uniform(*PLUG_HEIGHT) - start[2]
        pitch = math.asin(rise / length)
        direction = np.array(
            [-math.sin(angle) * math.cos(pitch), math.cos(angle) * math.cos(pitch), math.sin(pitch)]
        )
        self.sampled.update(angle=angle, roll=roll, pitch=pitch)
        self.assembly.place(model, data, start + length * direction, direction, roll)

    def _sample_clip_x(self, rng) -> np.ndarray:
        """Clip offsets across the lane: uniform +/-``LANE_JITTER`` each, resampled until
        neighbours are at most ``max_across`` apart (the first clip is free)."""
        while True:
            xs = self.lane_x() + rng.uniform(-LANE_JITTER, LANE_JITTER, self.num_clips)
            if np.all(np.abs(np.diff(xs)) <= self.layout.max_across):
                return xs

    # -- geometry ---------------------------------------------------------------------------
    def placed_clips(self, data) -> list[PlacedClip]:
        clips = []
        for body in self.clip_bodies:
            rot = data.xmat[body].reshape(3, 3)
            clips.append(
                PlacedClip(
                    self.clip_config, tuple(data.xpos[body]), math.atan2(rot[1, 0], rot[0, 0])
                )
            )
        return clips

    def routed(self, model, data) -> list[bool]:
        return [bool(r) for r in self.routed_batch(self.frame_of(data))[0]]

    def routed_batch(self, frame: Frame) -> np.ndarray:
        """(N, clips) whether some point of the wire's centre line lies inside each clip's slot
        (between the uprights, below the lips): a segment of the polyline meets the slot's box."""
        return frame.cached("routed", lambda: self._routed_batch(frame))

    def _routed_batch(self, frame: Frame) -> np.ndarray:
        cfg = self.clip_config
        pos = frame.xpos[:, self.clip_bodies]  # (N, C, 3)
        cos = frame.xmat[:, self.clip_bodies, 0][:, :, None]  # the clips turn about z only
        sin = frame.xmat[:, self.clip_bodies, 3][:, :, None]
        d = self.wire_points_batch(frame)[:, None] - pos[:, :, None]  # (N, C, K, 3)
        local = np.stack(
            [cos * d[..., 0] + sin * d[..., 1], -sin * d[..., 0] + cos * d[..., 1], d[..., 2]],
            axis=-1,
        )
        low = np.array([-cfg.length / 2, -cfg.slot_width / 2, cfg.base_height])
        high = np.array(
            [
                cfg.length / 2,
                cfg.slot_width / 2,
                cfg.base_height + cfg.slot_depth - cfg.lip_thickness,
            ]
        )
        return np.any(segments_meet_box(local[..., :-1, :], local[..., 1:, :], low, high), axis=-1)

    def _target_batch(self, frame: Frame):
        """Per simulation, for the first clip not yet routed (the last when all are): its slot
        centre (N, 3) and the wire point nearest to it (N, 3)."""
        routed = self.routed_batch(frame)
        pending = ~routed
        index = np.where(pending.any(axis=1), np.argmax(pending, axis=1), routed.shape[1] - 1)
        rows = np.arange(frame.size)
        clip = frame.xpos[rows, np.asarray(self.clip_bodies)[index]]
        slot = clip + [0.0, 0.0, self.clip_config.base_height]
        points = self.wire_points_batch(frame)
        gaps = points - slot[:, None]
        nearest = points[rows, np.argmin(np.sum(gaps * gaps, axis=2), axis=1)]
        return slot, nearest

    # -- observation ------------------------------------------------------------------------
    def observe_batch(self, frame: Frame) -> np.ndarray:
        n = frame.size
        base_rot = frame.rot("site_xmat", self.base_site)
        base_cos, base_sin = base_rot[:, 0, 0, None], base_rot[:, 1, 0, None]
        count = len(self.clip_bodies)
        slots = frame.xpos[:, self.clip_bodies] + [0.0, 0.0, self.clip_config.base_height]
        cos, sin = frame.xmat[:, self.clip_bodies, 0], frame.xmat[:, self.clip_bodies, 3]
        clips = np.zeros((n, MAX_CLIPS, 7))
        clips[:, :count, 0] = 1.0
        clips[:, :count, 1:4] = self.to_base_batch(frame, slots)
        clips[:, :count, 4] = cos * base_cos + sin * base_sin  # the slot's yaw less the base's
        clips[:, :count, 5] = sin * base_cos - cos * base_sin
        clips[:, :count, 6] = self.routed_batch(frame)
        samples = self.wire_points_batch(frame)[:, self.wire_samples]  # (N, WIRE_SAMPLES, 3)
        return np.concatenate(
            [
                self.robot_state_batch(frame),
                self.pads_touching(frame).astype(float),
                clips.reshape(n, -1),
                self.to_base_batch(frame, samples).reshape(n, -1),
                self.to_base_batch(frame, frame.xpos[:, self.clamp_id]),
                self.to_base_batch(frame, frame.xpos[:, self.assembly.plug_id]),
            ],
            axis=1,
        )

    # -- reward -----------------------------------------------------------------------------
    def reward_batch(self, frame, trackers, actions) -> dict[str, np.ndarray]:
        routed = self.routed_batch(frame)
        slot, nearest = self._target_batch(frame)
        held = self.pads_touching(frame).all(axis=1).astype(float)
        tcp = frame.site_xpos[:, self.tcp_site]
        cfg = self.clip_config
        clip_top = slot[:, 2] + cfg.slot_depth
        horizontal = norms((nearest - slot)[:, :2])
        return {
            "reach": shaped(norms(tcp - nearest), 0.1),
            "grasp": held,
            "lift": held * np.clip((nearest[:, 2] - clip_top) / 0.02 + 1.0, 0, 1),
            "over_slot": held * shaped(horizontal, 0.02),
            "routed": np.mean(routed, axis=1),
            "all_routed": routed.all(axis=1).astype(float),
            "action": np.sum(np.square(actions), axis=1),
            "collision": self.table_collision(frame).astype(float),
        }

    def evaluate_batch(self, frame, data_of) -> dict[str, np.ndarray]:
        routed = self.routed_batch(frame)
        return {"success": routed.all(axis=1), "clips_routed": np.sum(routed, axis=1)}
