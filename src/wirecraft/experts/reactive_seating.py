"""A reactive seating expert: its action is a function of the seating task's state vector alone.

Why it exists: DAgger (``wirecraft train ppo ... --set dagger_init_iterations=K``) asks an
expert to label the learner's own states, so the expert's action must depend on nothing but
the state the learner sees; the scripted ``SeatingExpert`` carries phases, timers and poses
frozen at phase changes (docs/baselines.md, "DAgger").  ``ReactiveSeatingExpert`` reads one row
of ``observation["state"]`` (the seating task's privileged state, docs/tasks.md: the TCP, the
pads' contacts, the plug's pose, the channel's joint points at floor height) and constants of
the scene (the wire's radius and end gap, the plug lead, the gripper), and lays the wire into the
channel by its end:

- grasping: the insertion expert's funnel onto the plug's tail (``ReactiveGraspExpert._grasp``),
  pointing straight down, pads across the tail;
- both pads on the plug: rise to ``lift`` while low, turn the plug onto the heading of the
  channel's last segment, carry the wire's end to ``lay_height`` above the floor ``lay_from``
  of path before its goal (the channel's end plus the task's plug lead); once the end is
  within ``lay_corridor`` of the path past that point, lay: the goal runs ``lay_ahead`` along
  the path from the end's own place and comes down with it to a wire resting on the floor at
  the goal, so the wire behind drops between the walls;
- the end at its goal (``placed_across``, ``placed_height``): open the pads wide; released
  there, rise to ``retreat`` above the table.

It does not press a wire that stays up on the walls, as the scripted expert's pressing pass
does (bends of the curved channel).  Only ``control="cartesian"``; deterministic.
"""

from __future__ import annotations

import math

import numpy as np

from wirecraft.experts.insertion import gripper_for_gap
from wirecraft.experts.reactive import (
    REACTIVE_EXPERTS,
    ReactiveGraspExpert,
    RobotStateLayout,
    _capped,
    plug_in_tcp_frame,
    squashed,
)
from wirecraft.geometry import quat_to_mat
from wirecraft.numerics import cross, dot, norm

PHASES = (
    "approach",
    "descend",
    "close",
    "reopen",
    "settle",
    "lift",
    "carry",
    "lay",
    "place",
    "release",
    "retreat",
)


class SeatingStateLayout(RobotStateLayout):
    """Column slices of the seating state for an arm of ``dof`` joints (docs/tasks.md)."""

    def __init__(self, dof: int) -> None:
        super().__init__(dof)
        start = self.task_start
        self.plug_pos = slice(start, start + 3)
        self.plug_quat = slice(start + 3, start + 7)
        self.clamp = slice(start + 7, start + 10)
        self.wire = slice(start + 10, start + 40)
        self.joints = slice(start + 40, start + 58)
        self.fraction = start + 58
        self.size = start + 59


@REACTIVE_EXPERTS.register("seating")
class ReactiveSeatingExpert(ReactiveGraspExpert):
    """``ReactiveSeatingExpert(env_or_envs, gain=None)``; ``act(states)`` maps (N, state_dim)
    seating states to (N, 7) ``cartesian`` actions (module docstring)."""

    TASK = "seating"
    PHASES = PHASES
    layout_class = SeatingStateLayout
    min_tcp_height = 0.010  # m: TCP above the table when grasping (pads 2 mm clear)
    grasp_back = 0.0  # m: the pads close on the tail's middle
    approach_pitch = 0.0  # rad: straight down
    lift = 0.06  # m: TCP above the table before the plug is carried sideways
    lay_from = 0.04  # m of path before the goal where the lay starts
    lay_height = 0.04  # m: wire end above the floor where the lay starts
    lay_corridor = 0.01  # m: wire end this near the path (horizontally) past that point: laying
    lay_ahead = 0.01  # m of path ahead of the wire end where the lay's goal is
    lay_speed = 0.0015  # m per step
    carry_speed = 0.006  # m per step
    place_above = 0.0005  # m: wire end above resting on the floor at the goal
    placed_across = 0.006  # m: wire end this near its goal horizontally ...
    placed_height = 0.002  # m: ... and in height: placed
    release_open = 0.08  # m: pad gap when releasing (capped at the robot's)
    retreat = 0.05  # m: TCP above the table after releasing
    retreat_speed = 0.004  # m per step
    lay_back = 0.04  # m: the relative features' second reference, before the wire end's goal

    @staticmethod
    def relative_features(states) -> np.ndarray:
        """(N, width + 33): the seating states, the plug's position and rotation in the TCP
        frame, the plug from the TCP, and ``squashed``: the plug from the TCP, from its goal
        (the channel's end extended by the task's plug lead) and from ``lay_back`` before it
        along the last segment."""
        from wirecraft.tasks.seating.task import PLUG_LEAD

        states = np.asarray(states, dtype=float)
        lay = SeatingStateLayout.for_width(states.shape[-1], "seating")
        plug = states[:, lay.plug_pos]
        plug_in_tcp, plug_rot_in_tcp = plug_in_tcp_frame(states, lay)
        joints = states[:, lay.joints].reshape(len(states), -1, 3)
        heading = joints[:, -1] - joints[:, -2]
        heading /= np.sqrt((heading**2).sum(axis=1, keepdims=True))
        goal = joints[:, -1] + PLUG_LEAD * heading
        lay_start = goal - ReactiveSeatingExpert.lay_back * heading
        near = np.concatenate([plug_in_tcp, plug - goal, plug - lay_start], axis=1)
        plug_from_tcp = plug - states[:, lay.tcp_pos]
        return np.concatenate(
            [states, plug_in_tcp, plug_rot_in_tcp, plug_from_tcp, *squashed(near)], axis=1
        )

    def _scene(self, env) -> None:
        task = env.task
        self.end_gap = float(task.assembly.wire.end_gap)
        self.plug_lead = float(task.plug_lead)
        self.seated_height = float(task.assembly.wire.config.radius) + self.place_above
        self.release_command = gripper_for_gap(self.release_open, self.max_opening)

    # -- the channel's path (base frame, floor height) ------------------------------------------
    def _path(self, state):
        """(7, 3) the channel's joint points and its end extended by the plug lead; (7,) arc."""
        joints = state[self.layout.joints].reshape(-1, 3)
        last = joints[-1] - joints[-2]
        path = np.vstack([joints, joints[-1] + self.plug_lead * last / norm(last)])
        steps = np.sqrt(((path[1:] - path[:-1]) ** 2).sum(axis=1))
        return path, np.concatenate([[0.0], np.cumsum(steps)])

    def _project(self, path, arc, point) -> tuple[float, float]:
        """(arc, horizontal distance) of ``point``'s nearest place on the path; past the last
        point the path runs on straight (the arc exceeds its length)."""
        best = (math.inf, 0.0)
        for k in range(len(path) - 1):
            seg = self._flat(path[k + 1] - path[k])
            length = norm(seg)
            t = dot(self._flat(point - path[k]), seg) / (length * length)
            t = min(max(t, 0.0), math.inf if k == len(path) - 2 else 1.0)
            distance = norm(self._flat(point - path[k] - t * (path[k + 1] - path[k])))
            if distance < best[0]:
                best = (distance, arc[k] + t * length)
        return best[1], best[0]

    @staticmethod
    def _point(path, arc, s: float) -> np.ndarray:
        s = min(max(s, 0.0), arc[-1])
        return np.array([np.interp(s, arc, path[:, k]) for k in range(3)])

    # -- the rules ------------------------------------------------------------------------------
    def _command(self, state):
        lay, up = self.layout, self.up
        tcp, tcp_rot = state[lay.tcp_pos], quat_to_mat(state[lay.tcp_quat])
        held = bool(state[lay.pads].min() > 0.5)
        plug_rot = quat_to_mat(state[lay.plug_quat])
        wire_end = state[lay.plug_pos] - self.end_gap * plug_rot[:, 0]
        path, arc = self._path(state)
        offset = wire_end - (path[-1] + self.seated_height * up)
        above = dot(offset, up)
        across = norm(offset - above * up)
        if held and across < self.placed_across and above < self.placed_height:
            return np.zeros(3), np.zeros(3), self.release_command, "release"
        if not held and across < 2 * self.placed_across and above < 2 * self.lay_corridor:
            height = dot(tcp, up) - self.table
            rise = min(self.retreat_speed, max(0.0, self.gain * (self.retreat - height)))
            return rise * up, np.zeros(3), self.release_command, "retreat"
        if held:
            return self._carry(state, tcp, wire_end, plug_rot, path, arc)
        return self._grasp(state, tcp, tcp_rot)

    def _carry(self, state, tcp, wire_end, plug_rot, path, arc):
        """The plug in the pads: lift, turn it onto the last segment's heading, carry the
        wire's end to the lay's start, lay it along the path down to the goal (module
        docstring)."""
        lay, up = self.layout, self.up
        height = dot(tcp, up) - self.table
        if abs(state[lay.opening_rate]) > self.settle_rate and height < 0.03:
            return np.zeros(3), np.zeros(3), 1.0, "settle"  # the pads still closing
        heading = self._flat(path[-1] - path[-2])
        heading /= norm(heading)
        axis = self._flat(plug_rot[:, 0])
        axis /= max(norm(axis), 1e-9)
        yaw = math.atan2(dot(cross(axis, heading), up), dot(axis, heading))
        turn = self.gain * yaw * up
        s, distance = self._project(path, arc, wire_end)
        start = arc[-1] - self.lay_from
        laying = distance < self.lay_corridor and s > start - 0.005
        if laying:
            goal_s = min(s + self.lay_ahead, arc[-1])
            progress = min(max((goal_s - start) / self.lay_from, 0.0), 1.0)
            rise = self.lay_height + progress * (self.seated_height - self.lay_height)
            goal, speed = self._point(path, arc, goal_s) + rise * up, self.lay_speed
            phase = "lay" if goal_s < arc[-1] else "place"
        else:
            goal = self._point(path, arc, start) + self.lay_height * up
            speed, phase = self.carry_speed, "carry"
        move = _capped(self.gain * (goal - wire_end), speed) - cross(turn, wire_end - tcp)
        # Low and not yet laying: rise first (the plug lies beside the channel's walls).
        free = 1.0 if laying else min(max((height - self.lift + 0.02) / 0.02, 0.0), 1.0)
        if free < 1.0:
            up_move = min(0.01, self.gain * max(0.0, self.lift - height)) * up
            move, turn, phase = free * move + (1.0 - free) * up_move, free * turn, "lift"
        return _capped(move, self.translation_scale), turn, 1.0, phase
