"""A reactive insertion expert: its action is a function of the task's state vector alone.

The scripted ``InsertionExpert`` carries memory the state does not show: its phase, dwell
timers, poses frozen at phase changes, and the Cartesian controller's own target (its actions
are measured from that target, which leads the TCP).  An imitation learner given only the state
cannot tell those apart, and its fit stays poor wherever they decide the action
(docs/baselines.md, "DAgger").  ``ReactiveInsertionExpert`` decides everything from one row of
``observation["state"]`` (the insertion task's privileged state, docs/tasks.md) and constants of
the scene (the socket's orientation, the plug's geometry, the gripper's width, the table), and,
for a learner's sake, mostly through ramps rather than switches, so that nearby states get
nearby actions:

- grasping: a funnel onto the grasp pose (TCP down across the tail, yawed like the robot's
  home): the goal hovers 5 cm above it while the TCP is off by more than 1.5 tolerances
  (across or in rotation), sits on it within half a tolerance, and ramps in between; the pads
  close on the same ramp, in height too; pads closed on nothing reopen while rising;
- both pads on the plug: turn the plug onto the socket's rotation (the roll nearest under the
  connector's symmetry), bring its tip onto the socket axis ``pre_insert`` before the mouth, and
  drive it along the axis at ``insert_speed`` times (2 x alignment - 1): in while aligned, out
  while not, still half-way; low over the table and far from the socket, rise first;
- seated, or the tip within 4 mm of home with the pads off it: open the pads, then rise 5 cm.

Commands are moves of the TCP per step (``gain`` of its error, capped), measured from the TCP,
not from the controller's target: the target integrates them, so the TCP still settles where it
should (the servos' sag is taken up), and the label stays a function of what the state shows.
The switches left are on inputs the state gives exactly: the pads' contact flags, the seated
test and a gripper closed past the tail.  ``phase_names()`` says which rule chose each action.
Only ``control="cartesian"`` and the insertion task; deterministic, no diversity.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from wirecraft.experts.fsm import unwrap_envs
from wirecraft.experts.insertion import grasp_pose, gripper_for_gap, plug_goal_rot
from wirecraft.geometry import quat_to_mat, quats_to_mats, rotation_error
from wirecraft.numerics import cross, dot, matmul, matvec, norm, tanh
from wirecraft.registry import Registry

PHASES = (
    "approach",
    "descend",
    "close",
    "reopen",
    "settle",
    "lift",
    "pre_insert",
    "insert",
    "back_out",
    "release",
    "retreat",
)


class RobotStateLayout:
    """Column slices every task's state starts with, for an arm of ``dof`` joints
    (docs/tasks.md): proprioception (gripper opening at ``dof``, its rate at 2 dof + 1), the
    TCP's position and quaternion, the pads' contact flags; the task's own columns start at
    ``task_start``."""

    def __init__(self, dof: int) -> None:
        self.opening = dof
        self.opening_rate = 2 * dof + 1
        start = 2 * dof + 2
        self.tcp_pos = slice(start, start + 3)
        self.tcp_quat = slice(start + 3, start + 7)
        self.pads = slice(start + 7, start + 9)
        self.task_start = start + 9

    @classmethod
    def for_width(cls, width: int, task: str):
        """The layout of ``task``'s states ``width`` columns wide (a ValueError for a width
        no arm gives); a subclass's ``size`` is 2 dof + a constant."""
        dof, odd = divmod(width - (cls(1).size - 2), 2)
        if odd or dof < 1:
            raise ValueError(f"not the width of the {task} task's state: {width}")
        return cls(dof)


class StateLayout(RobotStateLayout):
    """Column slices of the insertion state for an arm of ``dof`` joints (docs/tasks.md)."""

    def __init__(self, dof: int) -> None:
        super().__init__(dof)
        start = self.task_start
        self.tip_to_target = slice(start, start + 3)
        self.plug_pos = slice(start + 3, start + 6)
        self.plug_quat = slice(start + 6, start + 10)
        self.entry = slice(start + 10, start + 13)
        self.seated = slice(start + 13, start + 16)
        self.axial = start + 17
        self.lateral = start + 18
        self.size = start + 19


# Task family -> its memoryless expert (a function of the state: DAgger's labeller).
REACTIVE_EXPERTS: Registry[type] = Registry("reactive expert")

# Goal-relative actor inputs (each expert's ``relative_features``, wirecraft.rl.features): the
# millimetres that decide the expert's action, squashed at these scales, because standardised
# over the whole workspace, as the raw state is for a network, they are a thousandth of the
# inputs' spread (docs/baselines.md, "Goal-relative inputs").
FINE_SCALES = (0.01, 0.002)  # m
RELATIVE_WIDTH = 33  # columns each family's ``relative_features`` adds to its state


def plug_in_tcp_frame(states, lay) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) the plug's position and (N, 9) its rotation matrix in the TCP frame, from states
    with ``lay``'s ``tcp_pos``, ``tcp_quat``, ``plug_pos`` and ``plug_quat`` columns."""
    tcp_rot = quats_to_mats(states[:, lay.tcp_quat])
    plug_rot = quats_to_mats(states[:, lay.plug_quat])
    offset = states[:, lay.plug_pos] - states[:, lay.tcp_pos]
    into_tcp = np.swapaxes(tcp_rot, -1, -2)
    position = matvec(into_tcp, offset)
    rotation = matmul(into_tcp, plug_rot).reshape(len(states), 9)
    return position, rotation


def squashed(near) -> list[np.ndarray]:
    """``near`` (N, k) metres as tanh(near / scale) at each of ``FINE_SCALES``."""
    return [tanh(near / scale) for scale in FINE_SCALES]


class ReactiveGraspExpert:
    """What the reactive experts share: the scene constants of the gripper and the plug,
    ``act`` over a batch of states, and the grasp funnel (``_grasp``) onto the pose
    ``_grasp_target(state)`` gives (by default the plug's tail, ``_grasp_pose``; ``grasp_width``
    is what the pads close on).  A subclass sets ``TASK``, ``PHASES``, ``layout_class`` (column
    slices of its task's state: ``opening``, ``opening_rate``, ``tcp_pos``, ``tcp_quat``,
    ``pads``, ``size``, and ``plug_pos``, ``plug_quat`` for the default target), the grasp
    geometry (``min_tcp_height``, ``grasp_back``, ``approach_pitch``) and ``_command``, and
    may set ``relative_features`` (a static method: (N, width) states to (N, width +
    ``RELATIVE_WIDTH``), the states and goal-relative inputs for a learner's actor)."""

    TASK: str
    PHASES: tuple[str, ...]
    layout_class: type
    relative_features = None
    hover = 0.05  # m above the grasp pose where the approach ends
    pre_open_margin = 0.02  # m: pads open to the tail width + this
    at_grasp = 0.004  # m: tolerance of the grasp pose across and in height (funnel ramps)
    grasp_rot_tol = 0.05  # rad
    gain = 0.5  # fraction of the TCP's error commanded per step
    descend_speed = 0.004  # m per step
    settle_rate = 0.005  # m/s of pad gap change under which closed pads count as settled
    CONTROL = "cartesian"

    def __init__(self, env_or_envs, gain: float | None = None) -> None:
        name = type(self).__name__
        if gain is not None:
            if not 0.0 < gain <= 1.0:  # NaN fails too
                raise ValueError(f"{name} gain must be in (0, 1], got {gain}")
            self.gain = float(gain)
        envs = unwrap_envs(env_or_envs)
        env = envs[0]
        if env.controller.name != self.CONTROL or env.task.name != self.TASK:
            raise ValueError(f"{name} needs the {self.TASK} task with control={self.CONTROL!r}")
        task, robot, controller = env.task, env.robot, env.controller
        base = controller.index.base_site
        base_pos = env.data.site_xpos[base]
        self.base_rot = env.data.site_xmat[base].reshape(3, 3).copy()
        self.up = self.base_rot[2].copy()  # world +z in the base frame
        self.table = -float(base_pos[2])  # the table top (world z = 0) in the base frame
        self.grasp_local = env.model.site_pos[task.assembly.grasp_site].copy()
        connector = task.connector
        self.plug_length = float(connector.plug_length)
        self.tail_width = 2.0 * float(max(connector.tail_half[1:]))
        self.grasp_width = self.tail_width  # of what the pads close on
        self.open_command = gripper_for_gap(  # pads open to the tail width + the margin
            self.tail_width + self.pre_open_margin, float(robot.max_opening)
        )
        self.max_opening = float(robot.max_opening)
        self.translation_scale = controller.config.translation_scale
        self.rotation_scale = controller.config.rotation_scale
        self.home_rot = np.asarray(robot.home_tcp_rot, float)
        self.layout = self.layout_class(robot.dof)
        self.phase = np.zeros(len(envs), int)
        self._scene(env)

    def _scene(self, env) -> None:
        """The task's own scene constants (from the first environment)."""

    def phase_names(self) -> list[str]:
        """The rule that chose each environment's last action."""
        return [self.PHASES[k] for k in self.phase]

    def act(self, states) -> np.ndarray:
        states = np.asarray(states, float)
        if states.ndim != 2 or states.shape[1] != self.layout.size:
            raise ValueError(
                f"expected (N, {self.layout.size}) {self.TASK} states, got {states.shape}"
            )
        if not np.isfinite(states).all():
            raise ValueError(f"non-finite {self.TASK} state (diverged simulation?)")
        actions = np.zeros((len(states), 7))
        self.phase = np.zeros(len(states), int)
        for i, state in enumerate(states):
            move, turn, gripper, phase = self._command(state)
            actions[i, :3] = move / self.translation_scale
            actions[i, 3:6] = turn / self.rotation_scale
            actions[i, 6] = gripper
            self.phase[i] = self.PHASES.index(phase)
        return np.clip(actions, -1.0, 1.0)

    # -- geometry (shared with the scripted expert) ---------------------------------------------
    def _grasp_pose(self, plug_pos, plug_rot):
        """``grasp_pose`` of the plug; of the gripper's two equivalent yaws, the one nearer the
        robot's home orientation (a choice by the TCP's own yaw, as the scripted expert makes
        by its target's, would flip the goal, and the label, as the wrist turns)."""
        return grasp_pose(
            plug_pos + matmul(plug_rot, self.grasp_local),
            plug_rot,
            self.up,
            self.table,
            back=self.grasp_back,
            min_height=self.min_tcp_height,
            pitch=self.approach_pitch,
            reference=self.home_rot,
        )

    def _flat(self, vector) -> np.ndarray:
        """``vector`` (base frame) less its vertical part."""
        return vector - dot(vector, self.up) * self.up

    def _grasp_target(self, state):
        """(TCP position, rotation) that grasps: the plug's tail (``_grasp_pose``)."""
        lay = self.layout
        return self._grasp_pose(state[lay.plug_pos], quat_to_mat(state[lay.plug_quat]))

    # -- the rules ------------------------------------------------------------------------------
    def _grasp(self, state, tcp, tcp_rot):
        """Pads open, down a funnel onto the grasp pose: the goal sits ``hover`` above it while
        the TCP is more than 1.5 tolerances off (across or in rotation), on it within half a
        tolerance, in between on a ramp; the pads close on the same ramp as the TCP nears it
        in height too."""
        lay, up, open_cmd = self.layout, self.up, self.open_command
        if state[lay.opening] < self.grasp_width - 0.004:  # closed on nothing: open, rise
            return 0.01 * up, np.zeros(3), open_cmd, "reopen"
        grasp, grasp_rot = self._grasp_target(state)
        turning = rotation_error(grasp_rot, tcp_rot)
        turn = self.gain * turning
        offset = tcp - grasp
        above = dot(offset, up)
        across = norm(offset - above * up)
        off = max(across / self.at_grasp, norm(turning) / self.grasp_rot_tol)
        lift = float(np.clip(off - 0.5, 0.0, 1.0))
        move = self.gain * (grasp + lift * self.hover * up - tcp)
        down = dot(move, up)
        if down < -self.descend_speed:  # the last centimetres slowly
            move -= (down + self.descend_speed) * up
        move = _capped(move, self.translation_scale)
        closing = float(np.clip(2.0 - 2.0 * max(off, abs(above) / self.at_grasp), 0.0, 1.0))
        gripper = open_cmd + closing * (1.0 - open_cmd)
        if closing > 0.0:
            phase = "close"
        else:
            phase = "approach" if lift > 0.5 else "descend"
        return move, turn, gripper, phase


@REACTIVE_EXPERTS.register("insertion")
class ReactiveInsertionExpert(ReactiveGraspExpert):
    """``ReactiveInsertionExpert(env_or_envs, gain=None)``; ``act(states)`` maps (N,
    state_dim) insertion states to (N, 7) ``cartesian`` actions (module docstring).  ``gain``
    overrides the class's (in (0, 1]).  The scene constants come from the first environment:
    the socket's orientation is fixed across episodes (only its position is randomized), the
    plug's geometry by the connector."""

    TASK = "insertion"
    PHASES = PHASES
    layout_class = StateLayout
    min_tcp_height = 0.013  # m: TCP above the table when grasping (pads clear it)
    grasp_back = 0.007  # m behind the tail's middle
    approach_pitch = 0.2  # rad the pads lean back toward the wire
    carry_height = 0.07  # m of TCP above the table before the plug is carried sideways
    pre_insert = 0.02  # m: the tip this far before the mouth, aligned, before driving in
    # Alignment tolerances of the drive-in: within half of them it drives in, at them it holds,
    # beyond 1.5 of them it backs out.  Past the mouth they widen to the clearance + 1 mm and
    # inside_rot (the socket guides the plug).
    align_lateral = 0.0015  # m of the tip off the socket axis
    align_rot = 0.02  # rad
    inside_rot = 0.06  # rad
    push = 0.001  # m: the insert goal puts the tip this far past the seated target
    seated_axial = 0.001  # m
    seated_lateral = 0.0005  # m beyond the clearance
    retreat = 0.05  # m above the seated target after releasing
    align_speed = 0.006
    insert_speed = 0.0015
    retreat_speed = 0.004

    def _scene(self, env) -> None:
        self.port_rot = matmul(self.base_rot.T, env.data.xmat[env.task.port_id].reshape(3, 3))
        self.clearance = float(env.task.connector.clearance)
        self.symmetry = int(env.task.connector.symmetry)

    def _command(self, state):
        """(TCP move (m), TCP turn (rotation vector, rad), gripper command, phase) for one
        state, in the base frame, per control step."""
        lay, up = self.layout, self.up
        tcp, tcp_rot = state[lay.tcp_pos], quat_to_mat(state[lay.tcp_quat])
        opening = state[lay.opening]
        held = bool(state[lay.pads].min() > 0.5)
        home = state[lay.axial] < self.seated_axial and state[lay.lateral] < (
            self.clearance + self.seated_lateral
        )
        if home or (not held and norm(state[lay.tip_to_target]) < 0.004):
            if opening < self.tail_width + 0.5 * self.pre_open_margin:
                return np.zeros(3), np.zeros(3), self.open_command, "release"
            top = dot(state[lay.seated], up) + self.retreat
            rise = min(self.retreat_speed, max(0.0, self.gain * (top - dot(tcp, up))))
            return rise * up, np.zeros(3), self.open_command, "retreat"
        if held:
            return self._carry(state, tcp, tcp_rot)
        return self._grasp(state, tcp, tcp_rot)

    def _carry(self, state, tcp, tcp_rot):
        """The plug in the pads: turn it onto the socket's rotation, bring its tip onto the
        socket axis ``pre_insert`` before the mouth, and drive it in at ``insert_speed`` while
        it is aligned (back it out as fast when it is not, stop half-way between); low over
        the table, rise before moving sideways.  The plug's pose in the TCP frame is measured
        from the state, so a plug that turned in the pads is followed."""
        lay, up = self.layout, self.up
        height = dot(tcp, up) - self.table
        if abs(state[lay.opening_rate]) > self.settle_rate and height < 0.03:
            return np.zeros(3), np.zeros(3), 1.0, "settle"  # the pads still closing
        plug_rot = quat_to_mat(state[lay.plug_quat])
        seated = state[lay.seated]
        tip = seated - state[lay.tip_to_target]
        goal_rot = plug_goal_rot(self.port_rot, plug_rot, self.symmetry)
        axis = goal_rot[:, 0]
        twist = rotation_error(goal_rot, plug_rot)  # turns the plug (and the TCP) onto goal_rot
        offset = tip - state[lay.entry]
        along = dot(offset, axis)
        lateral = offset - along * axis
        inside = float(np.clip(along / 0.003, 0.0, 1.0))  # 0 outside the mouth, 1 past 3 mm
        lateral_tol = self.align_lateral + inside * (self.clearance + 0.001 - self.align_lateral)
        rot_tol = self.align_rot + inside * (self.inside_rot - self.align_rot)
        misalignment = max(norm(lateral) / lateral_tol, norm(twist) / rot_tol)
        aligned = float(np.clip(1.5 - misalignment, 0.0, 1.0))
        drive = max(
            self.gain * (-self.pre_insert - along),
            self.insert_speed * (2.0 * aligned - 1.0),
        )
        drive = min(drive, self.gain * (dot(seated - state[lay.entry], axis) + self.push - along))
        tip_move = _capped(drive * axis - self.gain * lateral, self.align_speed)
        turn = self.gain * twist
        move = tip_move - cross(turn, tip - tcp)  # the turn about the TCP moves the tip too
        # Low over the table and far from the socket, rise first (the port hangs 5-18 cm up).
        far = norm(offset - dot(offset, up) * up)
        free = max(
            float(np.clip((height - 0.04) / (self.carry_height - 0.04), 0.0, 1.0)),
            float(np.clip((0.05 - far) / 0.02, 0.0, 1.0)),
        )
        rise = min(0.01, self.gain * max(0.0, self.carry_height - height))
        move = free * move + (1.0 - free) * rise * up
        turn = free * turn
        if free < 1.0:
            phase = "lift"
        elif along > -self.pre_insert - 0.003 and drive > 0.0:
            phase = "insert"
        elif along > -self.pre_insert and drive < 0.0:
            phase = "back_out"
        else:
            phase = "pre_insert"
        return _capped(move, self.translation_scale), turn, 1.0, phase

    @staticmethod
    def relative_features(states) -> np.ndarray:
        """(N, width + 33): the insertion states, the plug's position and rotation in the TCP
        frame, the tip from the TCP, and the vectors whose millimetres decide the action (plug
        from the TCP, tip from the socket's mouth, tip from the seated target) ``squashed``."""
        states = np.asarray(states, dtype=float)
        lay = StateLayout.for_width(states.shape[-1], "insertion")
        plug_in_tcp, plug_rot_in_tcp = plug_in_tcp_frame(states, lay)
        tip = states[:, lay.seated] - states[:, lay.tip_to_target]
        near = np.concatenate(
            [plug_in_tcp, tip - states[:, lay.entry], states[:, lay.tip_to_target]], axis=1
        )
        tip_from_tcp = tip - states[:, lay.tcp_pos]
        return np.concatenate(
            [states, plug_in_tcp, plug_rot_in_tcp, tip_from_tcp, *squashed(near)], axis=1
        )


def _capped(vector, limit: float) -> np.ndarray:
    length = norm(vector)
    return vector if length <= limit else vector * (limit / length)


@dataclass(frozen=True)
class ReactiveDemoConfig:
    """The reactive experts have no options a demonstration changes (and no random choices)."""


class ReactiveDemonstrator:
    """A reactive expert behind the scripted experts' interface (``cls(env, config, seed=...)``;
    ``act(state)`` -> (1, action)), so that ``wirecraft collect --expert reactive`` records its
    episodes.  ``seed`` is accepted and unused: the expert is deterministic."""

    reactive: type  # set by ``reactive_demonstrator``
    config_class = ReactiveDemoConfig

    def __init__(self, env, config=None, seed: int | None = None) -> None:
        self.config = config or self.config_class()
        self.expert = self.reactive(env)

    def act(self, state) -> np.ndarray:
        return self.expert.act(np.atleast_2d(state))

    def reset(self, env_ids=None, seed: int | None = None) -> None:
        """Nothing to forget: the expert's action is a function of the state alone."""
        del env_ids, seed


@functools.cache  # one class per task: collect asks for it in every worker and episode run
def reactive_demonstrator(task: str) -> type[ReactiveDemonstrator]:
    """The demonstrator class of ``task``'s reactive expert (a ValueError naming the task
    families that have one)."""
    reactive = REACTIVE_EXPERTS.get(task)
    return type(
        f"{reactive.__name__}Demonstrator",
        (ReactiveDemonstrator,),
        {"reactive": reactive, "CONTROL": reactive.CONTROL, "__module__": __name__},
    )
