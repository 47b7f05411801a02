"""Scripted expert for connector insertion (``WireCraft/ConnectorInsertion-v0``, ``cartesian``).

What it reads (privileged; per environment ``env = env_or_envs.unwrapped``, never the task's
success flags):

- ``env.model`` / ``env.data``: the MuJoCo state of that environment;
- ``env.task.assembly``: ``plug_pose(data)`` (plug frame: origin at the wire end of the tail,
  +x along the insertion direction, +z the top / latch face), the ``grasp_site`` (middle of the
  tail) and ``tip_site`` ids;
- ``env.task``: ``port_id`` (port body; its frame is the socket frame: +x into the socket, +z
  the top), ``entry_site`` and ``seated_site`` ids, ``connector`` (``symmetry``,
  ``tail_half``, ``plug_length``), ``held(model, data)`` (both pads touching the plug) and
  ``seating_errors(data)`` (axial / lateral errors of the tip, to stop pushing once seated);
- ``env.robot``: ``tcp_pose_base(model, data)``, ``gripper_opening(model, data)``,
  ``max_opening``;
- ``env.controller``: its own target pose and base frame, through
  ``wirecraft.control.servo_action``.

Every goal is an end-effector (TCP) pose in the robot base frame; ``servo_action`` turns it into
a clipped Cartesian delta measured from the controller's target, and phases that must be slow
cap the distance the goal may lie ahead of that target (``Speeds``).

Phases (``PHASES``; see the banner comments in ``InsertionExpert._goals``): approach -> descend
-> close -> lift -> pre_insert -> insert -> release -> retreat -> done.  A grasp that does not
hold after the lift sends the environment back to ``approach``; an insertion that does not seat
within its timeout backs off to ``pre_insert`` (``max_insert_retries`` times) before releasing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from wirecraft.assets.robots.kinematics import axis_angle_to_mat
from wirecraft.experts.base import ScriptedExpert, rotation_angle
from wirecraft.experts.fsm import Phase

UP = np.array([0.0, 0.0, 1.0])  # world
TABLE_Z = 0.0  # m, table top (world)


@dataclass(frozen=True)
class InsertionExpertConfig:
    """Geometry and speeds of the insertion expert (SI units; per control step where stated)."""

    approach_pitch: float = 0.2  # rad the pads lean back (toward the wire) when grasping
    hover: float = 0.05  # m above the grasp point where the approach ends
    min_tcp_height: float = 0.013  # m: TCP above the table when grasping (pads clear it)
    grasp_back: float = 0.007  # m behind the tail's middle (pads stay clear of the port face)
    pre_open_margin: float = 0.02  # m: pads open to the tail width + this before closing
    lift: float = 0.06  # m lifted straight up after the grasp
    pre_insert: float = 0.02  # m: tip this far before the socket mouth, aligned
    push: float = 0.001  # m: the insert goal puts the tip this far past the seated target
    descend_speed: float = 0.004  # m per step
    align_speed: float = 0.006  # m per step (approach to the pre-insertion pose)
    insert_speed: float = 0.0015  # m per step (drive-in along the socket axis)
    retreat: float = 0.05  # m straight up after releasing
    seated_axial: float = 0.001  # m: axial error under which the plug counts as home
    seated_lateral: float = 0.0005  # m beyond the clearance: lateral error counted as home
    max_insert_retries: int = 2
    max_grasp_retries: int = 2
    track_plug: bool = True  # re-measure the plug in the pads while aligning and inserting
    release: bool = True  # open the pads once seated (False: hold the plug in the socket)


PHASES = (
    Phase("approach", pos_tol=0.006, rot_tol=0.05, dwell=1, timeout=260),
    Phase("descend", pos_tol=0.002, rot_tol=0.03, dwell=3, timeout=80),
    Phase("close", pos_tol=np.inf, rot_tol=np.inf, dwell=6, timeout=45),
    Phase("lift", pos_tol=0.008, rot_tol=0.05, dwell=1, timeout=60),
    Phase("pre_insert", pos_tol=0.0015, rot_tol=0.015, dwell=6, timeout=200),
    Phase("insert", pos_tol=np.inf, rot_tol=np.inf, dwell=4, timeout=90),
    Phase("release", pos_tol=np.inf, rot_tol=np.inf, dwell=3, timeout=30),
    Phase("retreat", pos_tol=0.01, rot_tol=0.1, dwell=1, timeout=40),
    Phase("done"),
)


def _rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


class InsertionExpert(ScriptedExpert):
    """Vectorized scripted expert for the insertion task (N environments, N = 1 for one env).

    ``reset(env_ids)`` after the environments are reset (a vector env's autoreset included);
    ``act()`` returns the (N, 7) ``cartesian`` actions for the current states.
    """

    PHASES = PHASES
    SNAPSHOTS = (
        ("grasp_rot", (3, 3)),
        ("grasp_pos", (3,)),
        ("plug_in_tcp", (4, 4)),
        ("lift_from", (3,)),
        ("plug_goal_rot", (3, 3)),
        ("hold_pos", (3,)),
        ("hold_rot", (3, 3)),
    )
    CONTROL = "cartesian"
    TASK = "insertion"
    config_class = InsertionExpertConfig

    def _init_state(self) -> None:
        self.insert_retries = np.zeros(self.num_envs, int)
        self.grasp_retries = np.zeros(self.num_envs, int)

    def _reset_state(self, mask) -> None:
        self.insert_retries[mask] = 0
        self.grasp_retries[mask] = 0

    # -- frames ------------------------------------------------------------------------------
    def _plug_base(self, i):
        """The plug's position and rotation in the base frame."""
        env = self.envs[i]
        pos, rot = env.task.assembly.plug_pose(env.data)
        return self._to_base(i, pos), self._base(i)[1].T @ rot

    # -- snapshots ---------------------------------------------------------------------------
    def _take_grasp_goal(self, i) -> None:
        """Grasp pose (base frame) from the plug as it lies: TCP pointing down, pads closing
        across the tail; of the two equivalent yaws of the parallel gripper, the nearer one."""
        cfg, env = self.config, self.envs[i]
        task = env.task
        plug_pos, plug_rot = self._plug_base(i)
        up = self._base(i)[1].T @ UP
        axis = plug_rot[:, 0] - np.dot(plug_rot[:, 0], up) * up
        axis /= np.linalg.norm(axis)
        grasp = env.data.site_xpos[task.assembly.grasp_site]
        grasp = self._to_base(i, grasp)
        grasp = grasp - cfg.grasp_back * axis
        table = self._to_base(i, np.array([0.0, 0.0, TABLE_Z]))
        grasp_height = max(np.dot(grasp - table, up), cfg.min_tcp_height)
        grasp = grasp + (grasp_height - np.dot(grasp - table, up)) * up
        z = -up
        _, current = self._ctl_target(i)
        best = None
        for sign in (1.0, -1.0):
            y = sign * np.cross(up, axis)
            rot = np.column_stack([np.cross(y, z), y, z])
            if best is None or rotation_angle(rot, current) < rotation_angle(best, current):
                best = rot
        # Approach pitch: the pads' tops lean back toward the wire, so the gripper may later
        # pitch forward (to keep a plug that turns in the pads aligned) without its pads
        # reaching the port's face.
        lean = axis_angle_to_mat(np.cross(up, axis) * cfg.approach_pitch)
        if np.dot(-(lean @ best)[:, 2], axis) > 0:
            lean = lean.T
        self.fsm.snapshots["grasp_pos"][i] = grasp
        self.fsm.snapshots["grasp_rot"][i] = lean @ best

    def _take_grasp_transform(self, i, lift: bool = True) -> None:
        """The plug's pose in the TCP frame, measured now (at grasp time)."""
        env = self.envs[i]
        tcp_pos, tcp_rot = env.robot.tcp_pose_base(env.model, env.data)
        plug_pos, plug_rot = self._plug_base(i)
        rel = np.eye(4)
        rel[:3, :3] = tcp_rot.T @ plug_rot
        rel[:3, 3] = tcp_rot.T @ (plug_pos - tcp_pos)
        self.fsm.snapshot("plug_in_tcp", self._row(i, rel), self._one(i))
        if lift:
            self.fsm.snapshot("lift_from", self._row(i, tcp_pos), self._one(i))

    def _row(self, i, value):
        out = np.zeros((self.num_envs, *np.shape(value)))
        out[i] = value
        return out

    def _one(self, i):
        mask = np.zeros(self.num_envs, bool)
        mask[i] = True
        return mask

    # -- geometry of the insertion -------------------------------------------------------------
    def _plug_goal_rot(self, i) -> np.ndarray:
        """Plug rotation (base frame) aligned with the socket, its roll the equivalent (under
        the connector's symmetry) nearest to the plug's current roll."""
        env = self.envs[i]
        task = env.task
        port_rot = self._base(i)[1].T @ env.data.xmat[task.port_id].reshape(3, 3)
        _, plug_rot = self._plug_base(i)
        axis = port_rot[:, 0]
        up = plug_rot[:, 2] - np.dot(plug_rot[:, 2], axis) * axis
        roll = math.atan2(
            float(np.dot(np.cross(port_rot[:, 2], up), axis)), float(port_rot[:, 2] @ up)
        )
        n = task.connector.symmetry
        if n > 0:
            step = 2 * math.pi / n
            roll = step * round(roll / step)
        return port_rot @ _rot_x(roll)

    def _tcp_for_plug(self, i, plug_pos, plug_rot):
        """TCP pose (base frame) that puts the held plug at ``plug_pos``/``plug_rot`` through
        the grasp transform: snapshotted at grasp time, or (``track_plug``) re-measured now,
        which compensates the plug turning in the pads under the wire's pull."""
        if self.config.track_plug:
            self._take_grasp_transform(i, lift=False)
        rel = self.fsm.get("plug_in_tcp")[i]
        tcp_rot = plug_rot @ rel[:3, :3].T
        return plug_pos - tcp_rot @ rel[:3, 3], tcp_rot

    def _plug_origin_for_tip(self, i, tip, plug_rot):
        return tip - self.envs[i].task.connector.plug_length * plug_rot[:, 0]

    # -- control -------------------------------------------------------------------------------
    def _gripper_pre_open(self, i) -> float:
        """Gripper command opening the pads to the tail width + a margin."""
        env = self.envs[i]
        width = 2.0 * max(env.task.connector.tail_half[1:])
        gap = min(width + self.config.pre_open_margin, env.robot.max_opening)
        return 1.0 - 2.0 * gap / env.robot.max_opening

    def _goals(self, i):
        """(goal position, goal rotation, max step (m), gripper command, own reached flag or
        None) of environment ``i`` in its current phase; base frame."""
        cfg, env, fsm = self.config, self.envs[i], self.fsm
        name = fsm.phases[fsm.phase[i]].name
        up = self._base(i)[1].T @ UP
        grasp_pos = fsm.get("grasp_pos")[i]
        grasp_rot = fsm.get("grasp_rot")[i]
        pre_open = self._gripper_pre_open(i)
        fast = 1.0  # m: no cap beyond the controller's own 1 cm per step

        # ---- Approach: above the tail, gripper yawed to the plug, pads pre-opened -------------
        if name == "approach":
            if np.isnan(grasp_pos).any():  # first step of the episode: plan the grasp
                self._take_grasp_goal(i)
                grasp_pos, grasp_rot = fsm.get("grasp_pos")[i], fsm.get("grasp_rot")[i]
            return grasp_pos + cfg.hover * up, grasp_rot, fast, pre_open, None

        # ---- Descend: straight down onto the tail ---------------------------------------------
        if name == "descend":
            return grasp_pos, grasp_rot, cfg.descend_speed, pre_open, None

        # ---- Close: hold still, close the pads; done when both touch and the pads stopped ----
        if name == "close":
            still = abs(env.robot.gripper_velocity(env.model, env.data)) < 0.005
            return (
                grasp_pos,
                grasp_rot,
                fast,
                1.0,
                bool(env.task.held(env.model, env.data) and still),
            )

        # ---- Lift: straight up, the plug in hand ------------------------------------------------
        if name == "lift":
            start = fsm.get("lift_from")[i]
            return start + cfg.lift * up, grasp_rot, fast, 1.0, None

        # ---- Pre-insert: plug on the socket axis, pre_insert before the mouth, aligned --------
        plug_rot = self._plug_goal_rot_cached(i)
        entry = self._to_base(i, env.data.site_xpos[env.task.entry_site])
        seated = self._to_base(i, env.data.site_xpos[env.task.seated_site])
        axis = plug_rot[:, 0]
        if name == "pre_insert":
            tip = entry - cfg.pre_insert * axis
            pos, rot = self._tcp_for_plug(i, self._plug_origin_for_tip(i, tip, plug_rot), plug_rot)
            return pos, rot, cfg.align_speed, 1.0, None

        # ---- Insert: drive in along the socket axis, slowly, until the tip is home ------------
        if name == "insert":
            tip = seated + cfg.push * axis
            pos, rot = self._tcp_for_plug(i, self._plug_origin_for_tip(i, tip, plug_rot), plug_rot)
            err = env.task.seating_errors(env.data)
            lateral = env.task.connector.clearance + cfg.seated_lateral
            home = err["axial"] < cfg.seated_axial and err["lateral"] < lateral
            return pos, rot, cfg.insert_speed, 1.0, bool(home)

        # ---- Release: open the pads where the plug sits -----------------------------------------
        hold_pos, hold_rot = fsm.get("hold_pos")[i], fsm.get("hold_rot")[i]
        if not cfg.release:  # keep holding the seated plug to the end of the episode
            return hold_pos, hold_rot, fast, 1.0, True
        if name == "release":
            opened = env.robot.gripper_opening(env.model, env.data) > (
                2.0 * max(env.task.connector.tail_half[1:]) + 0.5 * cfg.pre_open_margin
            )
            return hold_pos, hold_rot, fast, pre_open, bool(opened)

        # ---- Retreat (and done): straight up, away from the seated plug ----------------------
        return hold_pos + cfg.retreat * up, hold_rot, cfg.descend_speed, pre_open, None

    def _plug_goal_rot_cached(self, i) -> np.ndarray:
        rot = self.fsm.get("plug_goal_rot")[i]
        if np.isnan(rot).any():
            rot = self._plug_goal_rot(i)
            self.fsm.snapshot("plug_goal_rot", self._row(i, rot), self._one(i))
        return rot

    def _on_advance(self, advanced: np.ndarray, before: np.ndarray) -> None:
        """Snapshots and branches when environments leave a phase."""
        fsm, cfg = self.fsm, self.config
        idx = fsm.index
        for i in np.flatnonzero(advanced):
            env = self.envs[i]
            left = before[i]
            if left == idx("close"):
                # Grasp time: freeze the plug-in-TCP transform and the lift start.
                self._take_grasp_transform(i)
            elif left == idx("lift"):
                if not env.task.held(env.model, env.data) and self.grasp_retries[i] < (
                    cfg.max_grasp_retries
                ):
                    self.grasp_retries[i] += 1
                    self._take_grasp_goal(i)
                    fsm.goto("approach", self._one(i))
                    continue
                # The roll to insert with, chosen once from the lifted plug.
                fsm.snapshot("plug_goal_rot", self._row(i, self._plug_goal_rot(i)), self._one(i))
            elif left == idx("insert"):
                if fsm.timed_out[i] and self.insert_retries[i] < cfg.max_insert_retries:
                    self.insert_retries[i] += 1
                    # Re-measure the grasp (the plug may have turned in the pads while jammed).
                    self._take_grasp_transform(i)
                    fsm.goto("pre_insert", self._one(i))
                    continue
                tcp_pos, tcp_rot = env.robot.tcp_pose_base(env.model, env.data)
                fsm.snapshot("hold_pos", self._row(i, tcp_pos), self._one(i))
                fsm.snapshot("hold_rot", self._row(i, tcp_rot), self._one(i))
