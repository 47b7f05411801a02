"""A reactive routing expert: its action is a function of the routing task's state vector alone.

Why it exists: DAgger (``wirecraft train ppo ... --set dagger_init_iterations=K``) asks an
expert to label the learner's own states, so the expert's action must depend on nothing but the
state the learner sees; the scripted ``RoutingExpert`` carries phases, frozen anchors, measured
depths and force histories (docs/baselines.md, "DAgger").  ``ReactiveRoutingExpert`` reads one
row of ``observation["state"]`` (the routing task's privileged state, docs/tasks.md: the TCP,
the pads' contacts, each clip's slot centre, yaw and seated flag, 10 points along the wire, the
clamp) and constants of the scene (the clip's size, the wire's radius, the gripper), and routes
the first clip whose flag reads empty:

- grasping: the funnel of ``ReactiveGraspExpert._grasp`` onto the point of the wire (the
  polyline through the state's 10 points) that lies ``taut + slack`` along it from the anchor
  (the clamp, or the previous clip's slot), where ``taut`` is the straight length from the
  anchor to the pads' place over the clip at the carry height; TCP pointing down, pads across
  the wire there (of the two yaws, the one nearer the robot's home);
- both pads on the wire: rise to ``carry_height`` while low and far from the clip, turn the pads
  across the slot axis, carry the wire to ``front`` past the slot centre along the slot axis
  (away from the anchor), corrected sideways against the offset at which the wire crosses the
  clip's mid-plane, and there push down to ``push_height``: the wire between anchor and pads
  goes down into the slot;
- every clip seated: open the pads where they are; released, rise to ``retreat`` above the
  table.

It has no press (the scripted expert's pass with one open pad over a wire resting on the lips)
and no force stop.  Only ``control="cartesian"``; deterministic.
"""

from __future__ import annotations

import numpy as np

from wirecraft.experts.base import rotation_angle
from wirecraft.experts.insertion import gripper_for_gap
from wirecraft.experts.reactive import (
    REACTIVE_EXPERTS,
    ReactiveGraspExpert,
    RobotStateLayout,
    _capped,
    squashed,
)
from wirecraft.geometry import quat_to_mat, quats_to_mats, rotation_error
from wirecraft.numerics import cross, dot, matvec, norm
from wirecraft.tasks.routing.options import MAX_CLIPS

PHASES = (
    "approach",
    "descend",
    "close",
    "reopen",
    "settle",
    "lift",
    "carry",
    "push",
    "release",
    "retreat",
)
WIRE_POINTS = 10  # points along the wire in the routing state
# The route's geometry, shared by the expert's rules and its relative features (m).
CARRY_HEIGHT = 0.038  # TCP above the table while the wire is carried
WIRE_BELOW_TCP = 0.005  # the held wire's centre below the TCP
FRONT = 0.022  # past the slot centre along the slot axis, where the pads push
SLACK = 0.003  # of wire beyond the taut length at the grasp
PLUG_CLEARANCE = 0.02  # of wire kept between the grasp point and the plug
CROSSING_REACH = 0.03  # a crossing of the clip's mid-plane farther from the slot is ignored


class RoutingStateLayout(RobotStateLayout):
    """Column slices of the routing state for an arm of ``dof`` joints (docs/tasks.md)."""

    def __init__(self, dof: int) -> None:
        super().__init__(dof)
        start = self.task_start
        self.clips = slice(start, start + 7 * MAX_CLIPS)  # present, slot (3), cos, sin, seated
        start += 7 * MAX_CLIPS
        self.wire = slice(start, start + 3 * WIRE_POINTS)
        self.clamp = slice(start + 3 * WIRE_POINTS, start + 3 * WIRE_POINTS + 3)
        self.plug_pos = slice(start + 3 * WIRE_POINTS + 3, start + 3 * WIRE_POINTS + 6)
        self.size = start + 3 * WIRE_POINTS + 6


def route_geometry(states, lay, table: float = 0.0) -> dict[str, np.ndarray]:
    """The route of the first clip each (N, width) routing state shows empty (the last clip's
    where all are seated), base frame, heights above the table at base-frame z = ``table``
    (the state gives the slots' yaw about the base's z, which is up):

    ``pending`` (N,) whether some clip is empty; ``slot`` (N, 3) its centre; ``axis`` (N, 3)
    its slot axis, pointing away from the ``anchor`` (N, 3: the clamp for the first clip, the
    previous slot after it); ``push`` (N, 3) ``FRONT`` past the slot along that axis;
    ``grasp`` (N, 3) the wire's point (on the polyline through the state's points) ``taut +
    SLACK`` along it from the anchor, ``taut`` the straight length from the anchor to the push
    point with the wire ``WIRE_BELOW_TCP`` under a TCP at ``CARRY_HEIGHT``, at most
    ``PLUG_CLEARANCE`` before the wire's end; ``tangent`` (N, 3) the unit wire direction
    there; ``crossing`` (N, 3) where the wire crosses the clip's mid-plane nearest the slot,
    from the slot (zeros where it crosses nowhere within ``CROSSING_REACH``) and ``crosses``
    (N,) whether it does."""
    n = len(states)
    rows = np.arange(n)
    clips = states[:, lay.clips].reshape(n, MAX_CLIPS, 7)
    present = clips[:, :, 0] > 0.5
    empty = present & (clips[:, :, 6] < 0.5)
    pending = empty.any(axis=1)
    last = present.sum(axis=1) - 1
    k = np.where(pending, np.argmax(empty, axis=1), last)
    slot = clips[rows, k, 1:4]
    anchor = np.where(
        (k == 0)[:, None], states[:, lay.clamp], clips[rows, np.maximum(k - 1, 0), 1:4]
    )
    axis = np.stack([clips[rows, k, 4], clips[rows, k, 5], np.zeros(n)], axis=1)
    axis *= np.where(((slot - anchor) * axis).sum(axis=1) < 0.0, -1.0, 1.0)[:, None]
    push = slot + FRONT * axis
    points = states[:, lay.wire].reshape(n, WIRE_POINTS, 3)
    arc = np.concatenate(
        [np.zeros((n, 1)), np.cumsum(np.sqrt((np.diff(points, axis=1) ** 2).sum(axis=2)), axis=1)],
        axis=1,
    )
    nearest = np.argmin(((points - anchor[:, None]) ** 2).sum(axis=2), axis=1)
    anchor_arc = np.where(k == 0, 0.0, arc[rows, nearest])
    reach = np.hypot(*(push - anchor)[:, :2].T)
    rise = CARRY_HEIGHT - WIRE_BELOW_TCP - (anchor[:, 2] - table)
    want = np.clip(anchor_arc + np.hypot(reach, rise) + SLACK, 0.0, arc[:, -1] - PLUG_CLEARANCE)
    j = np.clip((arc < want[:, None]).sum(axis=1), 1, WIRE_POINTS - 1)
    step = points[rows, j] - points[rows, j - 1]
    length = np.maximum(arc[rows, j] - arc[rows, j - 1], 1e-9)
    t = np.clip((want - arc[rows, j - 1]) / length, 0.0, 1.0)
    grasp = points[rows, j - 1] + t[:, None] * step
    tangent = step / length[:, None]
    # the crossing of the mid-plane (through the slot centre, across the axis) nearest the slot
    along = ((points - slot[:, None]) * axis[:, None]).sum(axis=2)  # (N, 10)
    changes = np.signbit(along[:, :-1]) != np.signbit(along[:, 1:])  # (N, 9)
    denominator = along[:, :-1] - along[:, 1:]
    fraction = np.where(changes, along[:, :-1] / np.where(changes, denominator, 1.0), 0.0)
    at = points[:, :-1] + fraction[..., None] * np.diff(points, axis=1) - slot[:, None]
    distance = np.where(changes, np.sqrt((at**2).sum(axis=2)), np.inf)
    best = np.argmin(distance, axis=1)
    crosses = distance[rows, best] <= CROSSING_REACH
    crossing = np.where(crosses[:, None], at[rows, best], 0.0)
    return {
        "pending": pending,
        "slot": slot,
        "axis": axis,
        "anchor": anchor,
        "push": push,
        "grasp": grasp,
        "tangent": tangent,
        "crossing": crossing,
        "crosses": crosses,
    }


@REACTIVE_EXPERTS.register("routing")
class ReactiveRoutingExpert(ReactiveGraspExpert):
    """``ReactiveRoutingExpert(env_or_envs, gain=None)``; ``act(states)`` maps (N, state_dim)
    routing states to (N, 7) ``cartesian`` actions (module docstring)."""

    TASK = "routing"
    PHASES = PHASES
    layout_class = RoutingStateLayout
    pre_open_margin = 0.022  # m: pads open to the wire's diameter + this
    grasp_height = 0.009  # m: TCP above the table when closing on a wire lying there
    max_lateral = 0.012  # m: largest sideways correction of the push point
    push_height = 0.008  # m: TCP above the table at the end of the push
    push_speed = 0.002  # m per step down
    carry_speed = 0.008  # m per step
    over_slot = 0.003  # m: the push starts within this of the push point (horizontally) ...
    push_ramp = 0.004  # m: ... and is fully off this much farther
    push_rot_tol = 0.1  # rad: the push starts with the pads turned within half of this
    retreat = 0.05  # m: TCP above the table after releasing
    retreat_speed = 0.004  # m per step

    @staticmethod
    def relative_features(states) -> np.ndarray:
        """(N, width + 33): the routing states, then (``route_geometry``, heights from the base
        frame's z = 0, where every robot's base stands on the table) the slot axis and the
        wire's direction at the grasp point in the TCP frame, the push point and the grasp
        point from the TCP, the wire's crossing of the clip's mid-plane from the slot, and
        those three vectors ``squashed``."""
        states = np.asarray(states, dtype=float)
        lay = RoutingStateLayout.for_width(states.shape[-1], "routing")
        route = route_geometry(states, lay)
        tcp = states[:, lay.tcp_pos]
        tcp_rot = quats_to_mats(states[:, lay.tcp_quat])
        into_tcp = np.swapaxes(tcp_rot, -1, -2)
        axis_in_tcp = matvec(into_tcp, route["axis"])
        tangent_in_tcp = matvec(into_tcp, route["tangent"])
        near = np.concatenate([route["push"] - tcp, route["grasp"] - tcp, route["crossing"]], 1)
        return np.concatenate([states, axis_in_tcp, tangent_in_tcp, near, *squashed(near)], 1)

    def _scene(self, env) -> None:
        self.grasp_width = 2.0 * float(env.task.assembly.wire.config.radius)
        self.open_command = gripper_for_gap(
            self.grasp_width + self.pre_open_margin, self.max_opening
        )

    # -- geometry (base frame) ------------------------------------------------------------------
    def _height(self, point) -> float:
        return dot(point, self.up) - self.table

    def _down_rot(self, axis, near):
        """TCP rotation pointing down with the pads closing across the horizontal ``axis``; of
        the two yaws (the gripper is symmetric), the one nearer the rotation ``near``."""
        axis = self._flat(axis)
        axis = axis / max(norm(axis), 1e-9)
        down = -self.up
        rots = []
        for sign in (1.0, -1.0):
            across = sign * cross(self.up, axis)
            rots.append(np.column_stack([cross(across, down), across, down]))
        return min(rots, key=lambda rot: rotation_angle(rot, near))

    def _grasp_target(self, state):
        """The grasp point of ``_command``'s route (the state being commanded)."""
        point, tangent = self._route["grasp"], self._route["tangent"]
        height = max(self.grasp_height, self._height(point) + WIRE_BELOW_TCP)
        grasp_rot = self._down_rot(tangent, self.home_rot)  # the label: a function of the wire
        return point + (height - self._height(point)) * self.up, grasp_rot

    # -- the rules ------------------------------------------------------------------------------
    def _command(self, state):
        lay, up = self.layout, self.up
        tcp, tcp_rot = state[lay.tcp_pos], quat_to_mat(state[lay.tcp_quat])
        route = {k: v[0] for k, v in route_geometry(state[None], lay, self.table).items()}
        self._route = route  # the grasp rules read it too (``_grasp_target``)
        if not route["pending"]:
            if state[lay.pads].max() > 0.5 or state[lay.opening] < self.grasp_width + 0.01:
                return np.zeros(3), np.zeros(3), self.open_command, "release"
            rise = min(self.retreat_speed, max(0.0, self.gain * (self.retreat - self._height(tcp))))
            return rise * up, np.zeros(3), self.open_command, "retreat"
        if state[lay.pads].min() > 0.5:
            return self._carry(state, tcp, tcp_rot, route)
        return self._grasp(state, tcp, tcp_rot)

    def _carry(self, state, tcp, tcp_rot, route):
        """The wire in the pads: rise while low and far, carry it over the push point with the
        pads across the slot axis, moved sideways against the wire's offset at the slot; push
        down there."""
        lay, up = self.layout, self.up
        height = self._height(tcp)
        axis = route["axis"]
        side = cross(up, axis)
        goal = route["push"]
        if route["crosses"]:  # move the pads against the wire's offset at the slot
            shift = dot(tcp - goal, side) - dot(route["crossing"], side)
            goal = goal + float(np.clip(shift, -self.max_lateral, self.max_lateral)) * side
        # the pads across the slot axis: of the two yaws, the one the wrist is nearer
        twist = rotation_error(self._down_rot(axis, tcp_rot), tcp_rot)
        turned = float(np.clip(1.5 - norm(twist) / self.push_rot_tol, 0.0, 1.0))
        far = norm(self._flat(goal - tcp))
        near = float(np.clip(1.0 - (far - self.over_slot) / self.push_ramp, 0.0, 1.0))
        pushing = min(near, turned)
        closing = abs(state[lay.opening_rate]) > self.settle_rate
        if closing and height < 0.02 and pushing == 0.0:
            return np.zeros(3), np.zeros(3), 1.0, "settle"  # the pads still closing
        goal_height = CARRY_HEIGHT + pushing * (self.push_height - CARRY_HEIGHT)
        goal = goal + (goal_height - self._height(goal)) * up
        turn = self.gain * twist
        move = self.gain * (goal - tcp)
        down = dot(move, up)
        if down < -self.push_speed:
            move -= (down + self.push_speed) * up
        # low and far from the clip: rise first (a wire dragged low catches on the clip)
        free = max(float(np.clip((height - 0.02) / (CARRY_HEIGHT - 0.025), 0.0, 1.0)), pushing)
        rise = min(0.01, self.gain * max(0.0, CARRY_HEIGHT - height))
        move = free * _capped(move, self.carry_speed) + (1.0 - free) * rise * up
        phase = "push" if pushing > 0.5 else ("carry" if free > 0.5 else "lift")
        return _capped(move, self.translation_scale), turn, 1.0, phase
