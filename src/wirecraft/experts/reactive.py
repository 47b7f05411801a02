"""A reactive insertion expert: its action is a function of the task's state vector alone.

The scripted ``InsertionExpert`` carries memory the state does not show: its phase, dwell
timers, poses frozen at phase changes, and the Cartesian controller's own target (its actions
are measured from that target, which leads the TCP).  An imitation learner given only the state
cannot tell those apart, and its fit stays poor wherever they decide the action
(docs/baselines.md, "DAgger").  ``ReactiveInsertionExpert`` decides everything from one row of
``observation["state"]`` (the insertion task's privileged state, docs/tasks.md) and constants of
the scene (the socket's orientation, the plug's geometry, the gripper's width, the table):

- released and seated, or the tip within 4 mm of home with the pads off it: open the pads, then
  rise 5 cm above the socket;
- both pads on the plug: wait for the pads to settle if it was just closed on the table, lift
  to carrying height, bring the tip ``pre_insert`` before the mouth on the socket axis, aligned
  (roll chosen under the connector's symmetry), then drive it home along the axis; misaligned
  inside the mouth, back straight out;
- otherwise grasp: above the tail, pads open, yawed to the plug (the nearer of the two yaws),
  descend, close; pads closed on nothing, or away from the grasp pose: reopen while rising.

Each step the goal pose is turned into a Cartesian delta measured from the TCP (``gain`` of the
error, capped at the phase's speed), not from the controller's target: the target integrates
those deltas, so the TCP still settles on the goal (and the servos' sag is taken up), and the
label stays a function of what the state shows.  ``phase_names()`` says which rule chose each
action.  Only ``control="cartesian"``, the insertion task; deterministic, no diversity.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from wirecraft.assets.robots.kinematics import axis_angle_to_mat, rotation_error
from wirecraft.experts.fsm import unwrap_envs

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


def _quat_to_mat(quat) -> np.ndarray:
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, float))
    return mat.reshape(3, 3)


def _rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


class StateLayout:
    """Column slices of the insertion state for an arm of ``dof`` joints (docs/tasks.md)."""

    def __init__(self, dof: int) -> None:
        self.opening = dof
        self.opening_rate = 2 * dof + 1
        start = 2 * dof + 2
        self.tcp_pos = slice(start, start + 3)
        self.tcp_quat = slice(start + 3, start + 7)
        self.pads = slice(start + 7, start + 9)
        self.tip_to_target = slice(start + 9, start + 12)
        self.plug_pos = slice(start + 12, start + 15)
        self.plug_quat = slice(start + 15, start + 19)
        self.entry = slice(start + 19, start + 22)
        self.seated = slice(start + 22, start + 25)
        self.axial = start + 26
        self.lateral = start + 27
        self.size = start + 28


class ReactiveInsertionExpert:
    """``ReactiveInsertionExpert(env_or_envs)``; ``act(states)`` maps (N, state_dim) insertion
    states to (N, 7) ``cartesian`` actions (module docstring).  The scene constants come from
    the first environment: the socket's orientation is fixed across episodes (only its position
    is randomized), the plug's geometry by the connector."""

    hover = 0.05  # m above the grasp pose where the approach ends
    min_tcp_height = 0.013  # m: TCP above the table when grasping (pads clear it)
    grasp_back = 0.007  # m behind the tail's middle
    approach_pitch = 0.2  # rad the pads lean back toward the wire
    pre_open_margin = 0.02  # m: pads open to the tail width + this
    at_grasp = 0.004  # m: position tolerance of the grasp pose (across and along up)
    grasp_rot_tol = 0.05  # rad
    carry_height = 0.07  # m of TCP above the table before the plug is carried sideways
    pre_insert = 0.02  # m: the tip this far before the mouth, aligned, before driving in
    align_lateral = 0.0015  # m off the socket axis allowed to start driving in
    align_rot = 0.02  # rad
    inside_rot = 0.06  # rad: once in the mouth, the looser alignment that keeps driving in
    push = 0.001  # m: the insert goal puts the tip this far past the seated target
    seated_axial = 0.001  # m
    seated_lateral = 0.0005  # m beyond the clearance
    retreat = 0.05  # m above the seated target after releasing
    gain = 0.5  # fraction of the TCP's error commanded per step
    descend_speed = 0.004  # m per step
    align_speed = 0.006
    insert_speed = 0.0015
    back_out_speed = 0.003
    retreat_speed = 0.004
    settle_rate = 0.005  # m/s of pad gap change under which closed pads count as settled

    def __init__(self, env_or_envs) -> None:
        envs = unwrap_envs(env_or_envs)
        env = envs[0]
        if env.controller.name != "cartesian" or env.task.name != "insertion":
            raise ValueError(
                "ReactiveInsertionExpert needs the insertion task with control='cartesian'"
            )
        task, robot, controller = env.task, env.robot, env.controller
        model, data = env.model, env.data
        base = controller.index.base_site
        base_pos = data.site_xpos[base]
        base_rot = data.site_xmat[base].reshape(3, 3)
        self.up = base_rot[2].copy()  # world +z in the base frame
        self.table = -float(base_pos[2])  # the table top (world z = 0) in the base frame
        self.port_rot = base_rot.T @ data.xmat[task.port_id].reshape(3, 3)
        self.grasp_local = model.site_pos[task.assembly.grasp_site].copy()
        connector = task.connector
        self.plug_length = float(connector.plug_length)
        self.tail_width = 2.0 * float(max(connector.tail_half[1:]))
        self.clearance = float(connector.clearance)
        self.symmetry = int(connector.symmetry)
        self.max_opening = float(robot.max_opening)
        self.translation_scale = controller.config.translation_scale
        self.rotation_scale = controller.config.rotation_scale
        self.layout = StateLayout(robot.dof)
        self.phase = np.zeros(len(envs), int)

    def phase_names(self) -> list[str]:
        """The rule that chose each environment's last action."""
        return [PHASES[k] for k in self.phase]

    def act(self, states) -> np.ndarray:
        states = np.asarray(states, float)
        if states.ndim != 2 or states.shape[1] != self.layout.size:
            raise ValueError(
                f"expected (N, {self.layout.size}) insertion states, got {states.shape}"
            )
        if not np.isfinite(states).all():
            raise ValueError("non-finite insertion state (diverged simulation?)")
        actions = np.zeros((len(states), 7))
        self.phase = np.zeros(len(states), int)
        lay = self.layout
        for i, state in enumerate(states):
            pos, rot, speed, gripper, phase = self._goal(state)
            tcp, tcp_rot = state[lay.tcp_pos], _quat_to_mat(state[lay.tcp_quat])
            move = self.gain * (pos - tcp)
            dist = float(np.linalg.norm(move))
            if dist > speed:
                move *= speed / dist
            actions[i, :3] = move / self.translation_scale
            actions[i, 3:6] = self.gain * rotation_error(rot, tcp_rot) / self.rotation_scale
            actions[i, 6] = gripper
            self.phase[i] = PHASES.index(phase)
        return np.clip(actions, -1.0, 1.0)

    # -- geometry -------------------------------------------------------------------------------
    def _gripper_for_gap(self, gap: float) -> float:
        return 1.0 - 2.0 * min(gap, self.max_opening) / self.max_opening

    def _plug_goal_rot(self, plug_rot) -> np.ndarray:
        """The socket's rotation with the roll (under the connector's symmetry) nearest the
        plug's."""
        axis = self.port_rot[:, 0]
        top = plug_rot[:, 2] - np.dot(plug_rot[:, 2], axis) * axis
        port_top = self.port_rot[:, 2]
        roll = math.atan2(float(np.dot(np.cross(port_top, top), axis)), float(port_top @ top))
        if self.symmetry > 0:
            step = 2 * math.pi / self.symmetry
            roll = step * round(roll / step)
        return self.port_rot @ _rot_x(roll)

    def _grasp_pose(self, plug_pos, plug_rot, tcp_rot):
        """TCP pointing down across the tail, ``grasp_back`` behind its middle, at least
        ``min_tcp_height`` above the table, leaning ``approach_pitch`` toward the wire; of the
        gripper's two equivalent yaws, the one nearer the TCP's."""
        up = self.up
        axis = plug_rot[:, 0] - np.dot(plug_rot[:, 0], up) * up
        axis /= np.linalg.norm(axis)
        grasp = plug_pos + plug_rot @ self.grasp_local - self.grasp_back * axis
        height = float(np.dot(grasp, up)) - self.table
        grasp = grasp + (max(height, self.min_tcp_height) - height) * up
        down = -up
        candidates = []
        for sign in (1.0, -1.0):
            across = sign * np.cross(up, axis)
            candidates.append(np.column_stack([np.cross(across, down), across, down]))
        best = min(candidates, key=lambda r: np.linalg.norm(rotation_error(r, tcp_rot)))
        lean = axis_angle_to_mat(np.cross(up, axis) * self.approach_pitch)
        if np.dot(-(lean @ best)[:, 2], axis) > 0:
            lean = lean.T
        return grasp, lean @ best

    # -- the rules ------------------------------------------------------------------------------
    def _goal(self, state):
        """(goal position, goal rotation, speed (m per step), gripper command, phase)."""
        lay, up = self.layout, self.up
        tcp, tcp_rot = state[lay.tcp_pos], _quat_to_mat(state[lay.tcp_quat])
        plug_pos, plug_rot = state[lay.plug_pos], _quat_to_mat(state[lay.plug_quat])
        entry, seated = state[lay.entry], state[lay.seated]
        tip = seated - state[lay.tip_to_target]
        opening = state[lay.opening]
        held = bool(state[lay.pads].min() > 0.5)
        open_cmd = self._gripper_for_gap(self.tail_width + self.pre_open_margin)
        opened = opening > self.tail_width + 0.5 * self.pre_open_margin
        home = state[lay.axial] < self.seated_axial and state[lay.lateral] < (
            self.clearance + self.seated_lateral
        )
        height = float(np.dot(tcp, up)) - self.table

        if home or (not held and np.linalg.norm(state[lay.tip_to_target]) < 0.004):
            if not opened:
                return tcp, tcp_rot, 0.0, open_cmd, "release"
            rise = max(0.0, float(np.dot(seated, up)) + self.retreat - float(np.dot(tcp, up)))
            return tcp + rise * up, tcp_rot, self.retreat_speed, open_cmd, "retreat"

        if held:
            if abs(state[lay.opening_rate]) > self.settle_rate and height < 0.03:
                return tcp, tcp_rot, 0.0, 1.0, "settle"
            return self._carry(tcp, tcp_rot, plug_pos, plug_rot, tip, entry, seated, height)

        grasp, grasp_rot = self._grasp_pose(plug_pos, plug_rot, tcp_rot)
        above = float(np.dot(tcp - grasp, up))
        across = float(np.linalg.norm(tcp - grasp - above * up))
        if not opened:
            at_grasp = across < self.at_grasp and abs(above) < self.at_grasp
            if at_grasp and opening > self.tail_width - 0.004:
                return grasp, grasp_rot, 1.0, 1.0, "close"
            return tcp + 0.01 * up, tcp_rot, 1.0, open_cmd, "reopen"
        if across > self.at_grasp or np.linalg.norm(rotation_error(grasp_rot, tcp_rot)) > (
            self.grasp_rot_tol
        ):
            return grasp + self.hover * up, grasp_rot, 1.0, open_cmd, "approach"
        if above > 0.002:
            return grasp, grasp_rot, self.descend_speed, open_cmd, "descend"
        return grasp, grasp_rot, 1.0, 1.0, "close"

    def _carry(self, tcp, tcp_rot, plug_pos, plug_rot, tip, entry, seated, height):
        """Goals with the plug in the pads, through its pose in the TCP frame measured now."""
        rel_rot = tcp_rot.T @ plug_rot
        rel_pos = tcp_rot.T @ (plug_pos - tcp)
        goal_rot = self._plug_goal_rot(plug_rot)
        axis = goal_rot[:, 0]

        def tcp_for_tip(tip_goal):
            rot = goal_rot @ rel_rot.T
            return tip_goal - self.plug_length * axis - rot @ rel_pos, rot

        offset = tip - entry
        along = float(offset @ axis)
        lateral = float(np.linalg.norm(offset - along * axis))
        misaligned = float(np.linalg.norm(rotation_error(goal_rot, plug_rot)))
        inside = along > -0.003
        aligned = (lateral < self.align_lateral and misaligned < self.align_rot) or (
            inside and lateral < self.clearance + 0.001 and misaligned < self.inside_rot
        )
        if aligned and along > -self.pre_insert - 0.003:
            pos, rot = tcp_for_tip(seated + self.push * axis)
            return pos, rot, self.insert_speed, 1.0, "insert"
        if inside:
            pos, _ = tcp_for_tip(tip - (along + self.pre_insert) * axis)
            return pos, tcp_rot, self.back_out_speed, 1.0, "back_out"
        pos, rot = tcp_for_tip(entry - self.pre_insert * axis)
        sideways = pos - tcp - np.dot(pos - tcp, self.up) * self.up
        if height < self.carry_height and np.linalg.norm(sideways) > 0.03:
            return tcp + 0.02 * self.up, tcp_rot, 1.0, 1.0, "lift"
        return pos, rot, self.align_speed, 1.0, "pre_insert"
