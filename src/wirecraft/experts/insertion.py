"""Scripted expert for connector insertion (``WireCraft/ConnectorInsertion-v0``, ``cartesian``).

What it reads (privileged; never ``info`` nor the task's success flags) is exactly one
``InsertionView`` per environment and control step, made by ``read_insertion(env)``: the
robot's ``RobotView`` (base frame, TCP, gripper, the controller's target) plus the plug's pose
and speed, the tail's middle and the tip, the socket frame, mouth and seated target, whether
both pads touch the plug, the tip's seating errors and the connector's dimensions (see the
class docstring).  All poses are in the robot base frame.

Every goal is an end-effector (TCP) pose in the robot base frame; ``servo_action`` turns it into
a clipped Cartesian delta measured from the controller's target, and phases that must be slow
cap the distance the goal may lie ahead of that target (the ``*_speed`` settings).

Phases (``PHASES``; see the banner comments in ``InsertionExpert._goals``): approach -> descend
-> close -> lift -> pre_insert -> insert -> release -> retreat -> done, with three branches:

- a grasp that does not hold after the lift goes back to ``approach`` (``max_grasp_retries``);
- pick-and-drop (diversity): after the lift the pads open mid-air (``drop``), the plug falls,
  and the expert plans a new grasp and starts over from ``approach`` (once per episode);
- an insertion that stalls (no axial progress for ``stall_steps``) or times out backs out
  along the socket axis (``back_out``), re-measures the grasp, re-solves the roll and drives
  in again (``max_insert_retries`` times) before releasing;
- a plug whose latch (or friction hold) engaged when it seated is released where it is, at
  once (``insert`` -> ``release``); only a plug that nothing holds (cylinder, cuboid, or a
  latch that did not engage) is first tipped into the pose it will rest in (``tilt``).

Gentle insertion: the plug is pushed by the lead of the Cartesian controller's target over the
TCP (the arm's servo turns that lead into force).  While the plug touches the port (the
insertion force, ``InsertionView.insertion_force``, is what a wrist force sensor or the
``fixture_force`` observation measures) the expert stops advancing the target once the force
nears ``force_hold`` x ``max_insertion_force`` (slowing down as the force builds), holds it
up to ``max_insertion_force`` and backs it off toward the TCP above: the push stays within a
few tens of newtons, like a hand's.

Diversity (``InsertionExpertConfig.diversity``, on by default), drawn per episode from the
expert's per-environment generator (``ScriptedExpert.rngs``; seed it with ``seed=`` or
``reset(seed=...)``): pick-and-drop with probability ``pick_and_drop_prob``, the approach
pitch and the grasp offset along the tail uniform in their ranges, slower descents and
drive-ins (speed factors) and pauses before closing the pads and before driving in.  With
``diversity=False`` the expert is deterministic and uses the fixed ``approach_pitch``,
``grasp_back`` and speeds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from wirecraft.experts.base import (
    EXPERTS,
    TABLE_Z,
    RobotView,
    ScriptedExpert,
    robot_fields,
    rotation_angle,
)
from wirecraft.experts.fsm import Phase
from wirecraft.geometry import axis_angle_to_mat, rotation_error
from wirecraft.numerics import cross, dot, matmul, norm


# -- the privileged state it reads ------------------------------------------------------------
@dataclass(frozen=True)
class InsertionView(RobotView):
    """What the insertion expert reads of one environment in one control step (base frame).

    plug_pos / plug_rot: plug frame (origin at the wire end of the tail, +x the insertion
    direction, +z the top face).  plug_speed: m/s of the plug body.  grasp_point: middle of the
    tail; tip: front of the shell.  port_rot: socket frame (+x into the socket, +z its top);
    entry: socket mouth; seated: where the tip sits when home.  held: both pads touch the plug.
    insertion_force: N between plug and port, contacts plus an engaged latch's load (the task's
    insertion force).  latched: the connector's latch or friction hold is engaged (its
    "click").
    depth / axial / lateral: the tip's depth past the mouth, distance still to go and distance
    off the socket axis (m).  symmetry: n-fold symmetry of the connector about its axis (0:
    continuous); tail_width: the tail's larger cross dimension; plug_length; cavity_depth (mouth
    to seated target); clearance (m, per side).
    table_height: the table top's height above the base frame origin (along ``up``).
    """

    plug_pos: np.ndarray
    plug_rot: np.ndarray
    plug_speed: float
    grasp_point: np.ndarray
    tip: np.ndarray
    port_rot: np.ndarray
    entry: np.ndarray
    seated: np.ndarray
    held: bool
    insertion_force: float
    latched: bool
    depth: float
    axial: float
    lateral: float
    symmetry: int
    tail_width: float
    plug_length: float
    cavity_depth: float
    clearance: float
    table_height: float


def read_insertion(env) -> InsertionView:
    """``InsertionView`` of a ``WireCraftEnv`` running the insertion task: the only place the
    insertion expert reads privileged state (``task.assembly``, ``task`` sites and
    ``seating_errors``, ``task.held``, the robot and the controller's target)."""
    model, data, task = env.model, env.data, env.task
    fields = robot_fields(env)
    base_pos, base_rot = fields["base_pos"], fields["base_rot"]

    def to_base(points):
        return matmul(np.asarray(points, float) - base_pos, base_rot)

    assembly, connector = task.assembly, task.connector
    plug_pos, plug_rot = assembly.plug_pose(data)
    velocity = np.zeros(6)
    mujoco.mj_objectVelocity(
        model, data, mujoco.mjtObj.mjOBJ_BODY, model.body(assembly.plug).id, velocity, 0
    )
    err = task.seating_errors(data)
    return InsertionView(
        **fields,
        plug_pos=to_base(plug_pos),
        plug_rot=matmul(base_rot.T, plug_rot),
        plug_speed=norm(velocity[3:]),
        grasp_point=to_base(data.site_xpos[assembly.grasp_site]),
        tip=to_base(data.site_xpos[assembly.tip_site]),
        port_rot=matmul(base_rot.T, data.xmat[task.port_id].reshape(3, 3)),
        entry=to_base(data.site_xpos[task.entry_site]),
        seated=to_base(data.site_xpos[task.seated_site]),
        held=bool(task.held(model, data)),
        insertion_force=float(task.plug_port_force(model, data)),
        latched=task.engaged_retention(data) is not None,
        depth=float(err["depth"]),
        axial=float(err["axial"]),
        lateral=float(err["lateral"]),
        symmetry=int(connector.symmetry),
        tail_width=2.0 * float(max(connector.tail_half[1:])),
        plug_length=float(connector.plug_length),
        cavity_depth=float(connector.cavity_depth),
        clearance=float(connector.clearance),
        table_height=TABLE_Z - float(base_pos[2]),
    )


# -- configuration ------------------------------------------------------------------------------
def _check_range(name: str, value, low: float, high: float) -> None:
    if len(value) != 2 or not low <= value[0] <= value[1] <= high:
        raise ValueError(
            f"InsertionExpertConfig.{name} must be (lo, hi) with {low} <= lo <= hi <= {high}, "
            f"got {value!r}"
        )


@dataclass(frozen=True)
class InsertionExpertConfig:
    """Geometry, speeds and diversity of the insertion expert (SI units; per control step
    where stated)."""

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
    back_out_speed: float = 0.003  # m per step (a failed insertion backs out along the axis)
    stall_steps: int = 25  # steps without stall_progress of axial progress: the insertion failed
    stall_progress: float = 0.0005  # m
    seated_axial: float = 0.001  # m: axial error under which the plug counts as home
    seated_lateral: float = 0.0005  # m beyond the clearance: lateral error counted as home
    max_insert_retries: int = 2
    max_grasp_retries: int = 2
    track_plug: bool = True  # re-measure the plug in the pads while aligning and inserting
    release: bool = True  # open the pads once seated (False: hold the plug in the socket)
    release_tilt: float = 1.0  # fraction of the socket's tilt limit to rest the plug at first
    release_rise: float = 0.8  # fraction of the clearance the tipped plug's tip rises
    tilt_speed: float = 0.006  # rad per step the plug is tipped at
    open_steps: int = 12  # steps over which the pads open when releasing (slowly: no kick)
    withdraw: float = 0.0  # m the open pads back off along the socket axis before rising
    # Gentle insertion (see the module docstring): N of plug-port contact force above which
    # the target backs off, and the fraction of it above which the target stops advancing.
    max_insertion_force: float = 25.0
    force_hold: float = 0.6
    force_backoff: float = 0.25
    # Integral action in pre_insert: the arm's position servos sag under the held plug and
    # wire (2.3 mm on the WidowX AI, more than the 1.5 mm tolerance), so the expert aims past
    # the goal by the accumulated error, within sag_window of the goal, up to sag_limit; the
    # offset is kept while inserting and dropped in every other phase.
    sag_gain: float = 0.05
    sag_window: float = 0.01  # m
    sag_limit: float = 0.005  # m
    retreat: float = 0.05  # m straight up after releasing
    retreat_speed: float = 0.004  # m per step
    # Diversity (drawn per episode from the expert's generator; off: the values above).
    diversity: bool = True
    pick_and_drop_prob: float = 0.3  # lift, open the pads mid-air, re-approach, re-grasp
    drop_height: tuple[float, float] = (0.04, 0.06)  # m lifted before the drop
    approach_pitch_range: tuple[float, float] = (0.12, 0.28)  # rad
    grasp_back_range: tuple[float, float] = (0.004, 0.009)  # m
    descend_slowdown: tuple[float, float] = (0.4, 1.0)  # factor on descend_speed
    insert_slowdown: tuple[float, float] = (0.5, 1.0)  # factor on insert_speed
    close_pause: tuple[int, int] = (0, 10)  # steps holding still, pads open, before closing
    insert_pause: tuple[int, int] = (0, 10)  # steps holding at the pre-insertion pose

    def __post_init__(self) -> None:
        for name in ("max_insert_retries", "max_grasp_retries", "open_steps"):
            if getattr(self, name) < 0:
                raise ValueError(f"InsertionExpertConfig.{name} must be >= 0")
        if self.stall_steps < 1:
            raise ValueError("InsertionExpertConfig.stall_steps must be >= 1")
        for name in (
            "descend_speed",
            "align_speed",
            "insert_speed",
            "back_out_speed",
            "retreat_speed",
            "max_insertion_force",
            "tilt_speed",
        ):
            if getattr(self, name) <= 0:
                raise ValueError(f"InsertionExpertConfig.{name} must be > 0")
        if not 0.0 <= self.sag_gain <= 1.0:
            raise ValueError(
                f"InsertionExpertConfig.sag_gain must be in [0, 1], got {self.sag_gain}"
            )
        for name in ("sag_window", "sag_limit"):
            if not getattr(self, name) >= 0:  # NaN fails too
                raise ValueError(
                    f"InsertionExpertConfig.{name} must be >= 0, got {getattr(self, name)}"
                )
        for name in ("force_hold", "force_backoff"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ValueError(
                    f"InsertionExpertConfig.{name} must be in (0, 1], got {getattr(self, name)}"
                )
        if not 0.0 <= self.pick_and_drop_prob <= 1.0:
            raise ValueError(
                f"InsertionExpertConfig.pick_and_drop_prob must be in [0, 1], "
                f"got {self.pick_and_drop_prob}"
            )
        _check_range("drop_height", self.drop_height, 0.0, 0.2)
        _check_range("approach_pitch_range", self.approach_pitch_range, -0.6, 0.6)
        _check_range("grasp_back_range", self.grasp_back_range, -0.02, 0.02)
        _check_range("descend_slowdown", self.descend_slowdown, 0.05, 1.0)
        _check_range("insert_slowdown", self.insert_slowdown, 0.05, 1.0)
        _check_range("close_pause", self.close_pause, 0, 100)
        _check_range("insert_pause", self.insert_pause, 0, 100)


PAUSE_MAX = 100  # steps, the largest pause the config allows (phase timeouts make room)
PHASES = (
    Phase("approach", pos_tol=0.006, rot_tol=0.05, dwell=1, timeout=260),
    Phase("descend", pos_tol=0.002, rot_tol=0.03, dwell=3, timeout=80),
    Phase("close", pos_tol=np.inf, rot_tol=np.inf, dwell=6, timeout=45 + PAUSE_MAX),
    Phase("lift", pos_tol=0.008, rot_tol=0.05, dwell=1, timeout=60, next="pre_insert"),
    Phase("drop", pos_tol=np.inf, rot_tol=np.inf, dwell=1, timeout=60, next="approach"),
    Phase("pre_insert", pos_tol=0.0015, rot_tol=0.015, dwell=6, timeout=200),
    Phase("insert", pos_tol=np.inf, rot_tol=np.inf, dwell=4, timeout=90 + PAUSE_MAX, next="tilt"),
    Phase("back_out", pos_tol=0.003, rot_tol=0.05, dwell=1, timeout=40, next="pre_insert"),
    Phase("tilt", pos_tol=np.inf, rot_tol=np.inf, dwell=3, timeout=100, next="release"),
    Phase("release", pos_tol=np.inf, rot_tol=np.inf, dwell=3, timeout=60),
    Phase("withdraw", pos_tol=0.003, rot_tol=0.1, dwell=1, timeout=40),
    Phase("retreat", pos_tol=0.01, rot_tol=0.1, dwell=1, timeout=60),
    Phase("done"),
)
TILT_STEPS = 80  # steps after which the tilt gives up on the rest pose and releases
DROP_MIN_STEPS = 8  # steps with the pads open before the fallen plug may count as at rest
DROP_REST_SPEED = 0.02  # m/s: the dropped plug is at rest


def _rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


# -- geometry shared with the reactive expert (experts/reactive.py) ----------------------------
def grasp_pose(grasp_point, plug_rot, up, table_height, *, back, min_height, pitch, reference):
    """Grasp pose (base frame) from the plug as it lies: TCP pointing down, pads closing across
    the tail ``back`` m behind ``grasp_point``, at least ``min_height`` above the table, the
    pads' tops leaning ``pitch`` rad back toward the wire; of the parallel gripper's two
    equivalent yaws, the one nearer the rotation ``reference``."""
    axis = plug_rot[:, 0] - dot(plug_rot[:, 0], up) * up
    axis /= norm(axis)
    grasp = grasp_point - back * axis
    height = dot(grasp, up) - table_height
    grasp = grasp + (max(height, min_height) - height) * up
    z = -up
    best = None
    for sign in (1.0, -1.0):
        y = sign * cross(up, axis)
        rot = np.column_stack([cross(y, z), y, z])
        if best is None or rotation_angle(rot, reference) < rotation_angle(best, reference):
            best = rot
    # The lean lets the gripper later pitch forward (to keep a plug that turns in the pads
    # aligned) without its pads reaching the port's face.
    lean = axis_angle_to_mat(cross(up, axis) * pitch)
    if dot(-matmul(lean, best)[:, 2], axis) > 0:
        lean = lean.T
    return grasp, matmul(lean, best)


def plug_goal_rot(port_rot, plug_rot, symmetry: int) -> np.ndarray:
    """Plug rotation (base frame) aligned with the socket, its roll the equivalent (under the
    connector's ``symmetry``, 0: continuous) nearest to the plug's current roll."""
    axis = port_rot[:, 0]
    up = plug_rot[:, 2] - dot(plug_rot[:, 2], axis) * axis
    roll = math.atan2(dot(cross(port_rot[:, 2], up), axis), dot(port_rot[:, 2], up))
    if symmetry > 0:
        step = 2 * math.pi / symmetry
        roll = step * round(roll / step)
    return matmul(port_rot, _rot_x(roll))


def gripper_for_gap(gap: float, max_opening: float) -> float:
    """Gripper command for a pad gap of ``gap`` m."""
    return 1.0 - 2.0 * min(gap, max_opening) / max_opening


@EXPERTS.register("insertion")
class InsertionExpert(ScriptedExpert):
    """Vectorized scripted expert for the insertion task (N environments, N = 1 for one env).

    ``InsertionExpert(env_or_envs, config=None, seed=None)``; ``reset(env_ids=None,
    seed=None)`` after the environments are reset (a vector env's autoreset is noticed by
    ``act`` itself); ``act()`` returns the (N, 7) ``cartesian`` actions for the current states.
    Per-episode draws are in ``episode_plan`` (pick-and-drop, pitch, grasp offset, speed
    factors, pauses).
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
        ("back_pos", (3,)),
        ("back_rot", (3, 3)),
    )
    CONTROL = "cartesian"
    TASK = "insertion"
    config_class = InsertionExpertConfig
    PLAN_FIELDS = (
        "pick_and_drop",
        "drop_height",
        "approach_pitch",
        "grasp_back",
        "descend_factor",
        "insert_factor",
        "close_pause",
        "insert_pause",
    )

    def _init_state(self) -> None:
        n = self.num_envs
        self.pick_and_drop = np.zeros(n, bool)  # this episode drops the plug once
        self.dropped = np.zeros(n, bool)
        self.drop_height = np.zeros(n)
        self.approach_pitch = np.zeros(n)
        self.grasp_back = np.zeros(n)
        self.descend_factor = np.ones(n)
        self.insert_factor = np.ones(n)
        self.close_pause = np.zeros(n, int)
        self.insert_pause = np.zeros(n, int)
        self.best_axial = np.full(n, np.inf)  # insertion progress, for the stall test
        self.last_progress = np.zeros(n, int)  # insert step of the last progress
        self.stalled = np.zeros(n, bool)
        self.sag = np.zeros((n, 3))  # m: integral offset against servo sag (pre_insert)

    def _reset_state(self, mask) -> None:
        """Draw the episode's plan; every draw is made whatever the flags, so a seed gives the
        same stream of episodes with diversity on or off."""
        cfg = self.config
        for i in np.flatnonzero(mask):
            rng = self.rngs[i]
            draws = rng.random(8)
            drop = bool(draws[0] < cfg.pick_and_drop_prob)

            def lerp(bounds, u):
                return bounds[0] + (bounds[1] - bounds[0]) * u

            def pause(bounds, u):
                return int(min(bounds[1], math.floor(lerp((bounds[0], bounds[1] + 1), u))))

            if cfg.diversity:
                self.pick_and_drop[i] = drop
                self.drop_height[i] = lerp(cfg.drop_height, draws[1])
                self.approach_pitch[i] = lerp(cfg.approach_pitch_range, draws[2])
                self.grasp_back[i] = lerp(cfg.grasp_back_range, draws[3])
                self.descend_factor[i] = lerp(cfg.descend_slowdown, draws[4])
                self.insert_factor[i] = lerp(cfg.insert_slowdown, draws[5])
                self.close_pause[i] = pause(cfg.close_pause, draws[6])
                self.insert_pause[i] = pause(cfg.insert_pause, draws[7])
            else:
                self.pick_and_drop[i] = False
                self.drop_height[i] = cfg.lift
                self.approach_pitch[i] = cfg.approach_pitch
                self.grasp_back[i] = cfg.grasp_back
                self.descend_factor[i] = self.insert_factor[i] = 1.0
                self.close_pause[i] = self.insert_pause[i] = 0
        self.dropped[mask] = False
        self.best_axial[mask] = np.inf
        self.last_progress[mask] = 0
        self.stalled[mask] = False
        self.sag[mask] = 0.0

    @property
    def episode_plan(self) -> list[dict]:
        """Per environment, this episode's diversity draws."""
        return [
            {name: getattr(self, name)[i].item() for name in self.PLAN_FIELDS}
            for i in range(self.num_envs)
        ]

    @property
    def insert_retries(self) -> np.ndarray:
        """(N,) insertions retried this episode."""
        return self.fsm.retry_count("insert")

    @property
    def grasp_retries(self) -> np.ndarray:
        """(N,) grasps retried this episode."""
        return self.fsm.retry_count("grasp")

    def read_state(self, i) -> InsertionView:
        return read_insertion(self.envs[i])

    # -- snapshots ---------------------------------------------------------------------------
    def _take_grasp_goal(self, i) -> None:
        """Grasp pose (``grasp_pose``) from the plug as it lies; of the two equivalent yaws,
        the one nearer the controller's target."""
        cfg, view = self.config, self.views[i]
        grasp, rot = grasp_pose(
            view.grasp_point,
            view.plug_rot,
            view.up,
            view.table_height,
            back=self.grasp_back[i],
            min_height=cfg.min_tcp_height,
            pitch=self.approach_pitch[i],
            reference=view.target_rot,
        )
        self.fsm.snapshots["grasp_pos"][i] = grasp
        self.fsm.snapshots["grasp_rot"][i] = rot

    def _grasp_transform(self, i) -> np.ndarray:
        """(4, 4) the plug's pose in the TCP frame now."""
        view = self.views[i]
        rel = np.eye(4)
        rel[:3, :3] = matmul(view.tcp_rot.T, view.plug_rot)
        rel[:3, 3] = matmul(view.tcp_rot.T, view.plug_pos - view.tcp_pos)
        return rel

    # -- geometry of the insertion -------------------------------------------------------------
    def _plug_goal_rot(self, i) -> np.ndarray:
        """``plug_goal_rot`` of the plug now."""
        view = self.views[i]
        return plug_goal_rot(view.port_rot, view.plug_rot, view.symmetry)

    def _tcp_for_tip(self, i, tip, plug_rot):
        """TCP pose (base frame) that puts the held plug's tip at ``tip`` with rotation
        ``plug_rot``, through the grasp transform: snapshotted at grasp time, or
        (``track_plug``) re-measured now, which compensates the plug turning in the pads under
        the wire's pull."""
        fsm = self.fsm
        if self.config.track_plug:
            fsm.snapshots["plug_in_tcp"][i] = self._grasp_transform(i)
        rel = fsm.get("plug_in_tcp")[i]
        plug_pos = tip - self.views[i].plug_length * plug_rot[:, 0]
        tcp_rot = matmul(plug_rot, rel[:3, :3].T)
        return plug_pos - matmul(tcp_rot, rel[:3, 3]), tcp_rot

    # -- control -------------------------------------------------------------------------------
    def _pre_open(self, i) -> float:
        """Gripper command opening the pads to the tail width + a margin."""
        view = self.views[i]
        return gripper_for_gap(view.tail_width + self.config.pre_open_margin, view.max_opening)

    def _opened(self, i) -> bool:
        view = self.views[i]
        return view.gripper_opening > view.tail_width + 0.5 * self.config.pre_open_margin

    def _command_offset(self, i, goal_pos, view):
        cfg = self.config
        name = self.PHASES[self.fsm.phase[i]].name
        if name == "pre_insert":
            error = goal_pos - view.tcp_pos
            if norm(error) < cfg.sag_window:
                offset = self.sag[i] + cfg.sag_gain * error
                size = norm(offset)
                self.sag[i] = offset if size <= cfg.sag_limit else offset * (cfg.sag_limit / size)
        elif name != "insert":
            self.sag[i] = 0.0
        return self.sag[i]

    def _goals(self, i):
        """(goal position, goal rotation, max step (m), gripper command, own reached flag or
        None) of environment ``i`` in its current phase; base frame."""
        cfg, fsm, view = self.config, self.fsm, self.views[i]
        name = fsm.phases[fsm.phase[i]].name
        steps = int(fsm.steps[i])
        up = view.up
        grasp_pos = fsm.get("grasp_pos")[i]
        grasp_rot = fsm.get("grasp_rot")[i]
        pre_open = self._pre_open(i)
        fast = 1.0  # m: no cap beyond the controller's own 1 cm per step

        # ---- Approach: above the tail, gripper yawed to the plug, pads pre-opened -------------
        if name == "approach":
            if np.isnan(grasp_pos).any():  # first step, or after a drop: plan the grasp
                self._take_grasp_goal(i)
                grasp_pos, grasp_rot = fsm.get("grasp_pos")[i], fsm.get("grasp_rot")[i]
            return grasp_pos + cfg.hover * up, grasp_rot, fast, pre_open, None

        # ---- Descend: straight down onto the tail (slower on some episodes) -----------------
        if name == "descend":
            return grasp_pos, grasp_rot, cfg.descend_speed * self.descend_factor[i], pre_open, None

        # ---- Close: (pause,) close the pads; done when both touch and the pads stopped -------
        if name == "close":
            if steps < self.close_pause[i]:
                return grasp_pos, grasp_rot, fast, pre_open, False
            still = abs(view.gripper_velocity) < 0.005
            return grasp_pos, grasp_rot, fast, 1.0, bool(view.held and still)

        # ---- Lift: straight up, the plug in hand ------------------------------------------------
        if name == "lift":
            height = self.drop_height[i] if self._drop_pending(i) else cfg.lift
            return fsm.get("lift_from")[i] + height * up, grasp_rot, fast, 1.0, None

        # ---- Drop (pick-and-drop): open the pads mid-air, wait for the plug to come to rest --
        if name == "drop":
            hold = fsm.get("lift_from")[i] + self.drop_height[i] * up
            rest = steps >= DROP_MIN_STEPS and view.plug_speed < DROP_REST_SPEED
            return hold, grasp_rot, fast, pre_open, bool(self._opened(i) and rest)

        # ---- Pre-insert: plug on the socket axis, pre_insert before the mouth, aligned --------
        plug_rot = self._plug_goal_rot_cached(i)
        axis = plug_rot[:, 0]
        if name == "pre_insert":
            pos, rot = self._tcp_for_tip(i, view.entry - cfg.pre_insert * axis, plug_rot)
            return pos, rot, cfg.align_speed, 1.0, None

        # ---- Insert: (pause,) drive in along the socket axis until the tip is home ------------
        if name == "insert":
            if steps < self.insert_pause[i]:  # hesitate at the pre-insertion pose
                pos, rot = self._tcp_for_tip(i, view.entry - cfg.pre_insert * axis, plug_rot)
                return pos, rot, cfg.align_speed, 1.0, False
            pos, rot = self._tcp_for_tip(i, view.seated + cfg.push * axis, plug_rot)
            home = view.axial < cfg.seated_axial and view.lateral < (
                view.clearance + cfg.seated_lateral
            )
            if view.axial < self.best_axial[i] - cfg.stall_progress:
                self.best_axial[i], self.last_progress[i] = view.axial, steps
            self.stalled[i] = not home and steps - self.last_progress[i] >= max(
                cfg.stall_steps, self.insert_pause[i] + cfg.stall_steps
            )
            speed = cfg.insert_speed * self.insert_factor[i]
            pos, rot, speed = self._gentle(i, pos, rot, speed)
            return pos, rot, speed, 1.0, bool(home or self.stalled[i])

        # ---- Back out (a failed insertion): along the socket axis to the pre-insertion pose --
        if name == "back_out":
            return fsm.get("back_pos")[i], fsm.get("back_rot")[i], cfg.back_out_speed, 1.0, None

        hold_pos, hold_rot = fsm.get("hold_pos")[i], fsm.get("hold_rot")[i]
        if not cfg.release:  # keep holding the seated plug to the end of the episode
            return hold_pos, hold_rot, fast, 1.0, True

        # ---- Tilt: lay the plug, tip pressed home, in the pose it will rest in when released --
        if name == "tilt":
            # Tipped progressively (tilt_speed rad per step, the rise along with it): a plug
            # swung onto the socket walls at the controller's full turn rate hits them hard.
            rest = self._rest_rot(i, plug_rot)
            full = rotation_angle(rest, plug_rot)
            frac = 1.0 if full < 1e-9 else min(1.0, (steps + 1) * cfg.tilt_speed / full)
            rest_now = matmul(axis_angle_to_mat(frac * rotation_error(rest, plug_rot)), plug_rot)
            rise = view.up - dot(view.up, axis) * axis
            rise *= frac * cfg.release_rise * view.clearance / max(norm(rise), 1e-9)
            pos, rot = self._tcp_for_tip(i, view.seated + cfg.push * axis + rise, rest_now)
            done = (frac >= 1.0 and rotation_angle(view.plug_rot, rest) < 0.03) or (
                steps >= TILT_STEPS
            )
            pos, rot, speed = self._gentle(i, pos, rot, cfg.insert_speed)
            return pos, rot, speed, 1.0, bool(done)

        # ---- Release: open the pads slowly where the plug sits ----------------------------------
        if name == "release":
            ramp = min(1.0, (steps + 1) / max(cfg.open_steps, 1))
            gripper = 1.0 + ramp * (pre_open - 1.0)
            pos, rot, speed = self._gentle(i, hold_pos, hold_rot, fast)
            return pos, rot, speed, gripper, bool(ramp >= 1.0 and self._opened(i))

        # ---- Withdraw: the open pads back off along the socket axis (not dragging the plug) --
        back = hold_pos - cfg.withdraw * axis
        if name == "withdraw":
            return back, hold_rot, cfg.retreat_speed, pre_open, None

        # ---- Retreat (and done): straight up, away from the seated plug ----------------------
        return back + cfg.retreat * up, hold_rot, cfg.retreat_speed, pre_open, None

    def _gentle(self, i, pos, rot, speed):
        """The goal (position, rotation, speed) limited by the insertion force ``f``, with
        ``hold = force_hold x max_insertion_force``: below ``hold`` the goal is unchanged and
        the speed scaled by ``1 - f / hold`` (the push builds up gently); up to
        ``max_insertion_force`` the controller's target is held where it is; above it, the
        target is backed off by ``force_backoff`` of its lead over the TCP (position and
        rotation), since that lead over the blocked TCP is what pushes."""
        cfg, view = self.config, self.views[i]
        force, hold = view.insertion_force, cfg.force_hold * cfg.max_insertion_force
        if force <= hold:
            return pos, rot, speed * (1.0 - force / hold)
        if force <= cfg.max_insertion_force:
            return view.target_pos, view.target_rot, speed
        keep = 1.0 - cfg.force_backoff
        turn = axis_angle_to_mat(keep * rotation_error(view.target_rot, view.tcp_rot))
        pos = view.tcp_pos + keep * (view.target_pos - view.tcp_pos)
        return pos, matmul(turn, view.tcp_rot), 1.0

    def _rest_rot(self, i, plug_rot) -> np.ndarray:
        """The seated plug's rotation tipped (tail down, tip up) by ``release_tilt`` of the
        angle the socket's clearance allows (about atan(2 clearance / cavity depth)): a
        released plug sags there under the cable's weight, pivoting on the mouth's lower lip
        and sliding out; tipped first with the tip pressed home, it rests in that pose."""
        view = self.views[i]
        axis = plug_rot[:, 0]
        across = cross(view.up, axis)
        length = norm(across)
        if length < 1e-6:  # a vertical socket: no sag direction
            return plug_rot
        angle = self.config.release_tilt * math.atan2(2.0 * view.clearance, view.cavity_depth)
        return matmul(axis_angle_to_mat(-across / length * angle), plug_rot)

    def _drop_pending(self, i) -> bool:
        return bool(self.pick_and_drop[i] and not self.dropped[i])

    def _plug_goal_rot_cached(self, i) -> np.ndarray:
        rot = self.fsm.get("plug_goal_rot")[i]
        if np.isnan(rot).any():
            rot = self.fsm.snapshots["plug_goal_rot"][i] = self._plug_goal_rot(i)
        return rot

    def _on_advance(self, advanced: np.ndarray, before: np.ndarray) -> None:
        """Snapshots and branches when environments leave a phase."""
        fsm, cfg = self.fsm, self.config
        idx = fsm.index
        snap = fsm.snapshots
        for i in np.flatnonzero(advanced):
            view = self.views[i]
            one = np.arange(self.num_envs) == i
            left = before[i]
            if left == idx("close"):
                # Grasp time: freeze the plug-in-TCP transform and the lift start.
                snap["plug_in_tcp"][i] = self._grasp_transform(i)
                snap["lift_from"][i] = view.tcp_pos
            elif left == idx("lift"):
                if not view.held:
                    if fsm.retry("grasp", "approach", one, cfg.max_grasp_retries).any():
                        snap["grasp_pos"][i] = np.nan  # re-planned on the next approach step
                        continue
                elif self._drop_pending(i):
                    self.dropped[i] = True
                    fsm.goto("drop", one)
                    continue
                # The roll to insert with, chosen once from the lifted plug.
                snap["plug_goal_rot"][i] = self._plug_goal_rot(i)
            elif left == idx("drop"):
                snap["grasp_pos"][i] = np.nan  # plan a new grasp where the plug came to rest
            elif left == idx("insert"):
                self.best_axial[i], self.last_progress[i] = np.inf, 0
                failed = bool(fsm.timed_out[i] or self.stalled[i])
                self.stalled[i] = False
                if failed and fsm.retry("insert", "back_out", one, cfg.max_insert_retries).any():
                    axis = view.port_rot[:, 0]
                    back = max(view.depth, 0.0) + cfg.pre_insert
                    snap["back_pos"][i] = view.tcp_pos - back * axis
                    snap["back_rot"][i] = view.tcp_rot
                    continue
                snap["hold_pos"][i] = view.tcp_pos
                snap["hold_rot"][i] = view.tcp_rot
                if view.latched:
                    # Held by its latch: nothing to tip; open the pads with the controller's
                    # target where it is (still pressing gently home: backing it off to the TCP
                    # would pull on the plug, enough to unseat a 10 N friction hold).
                    snap["hold_pos"][i] = view.target_pos
                    snap["hold_rot"][i] = view.target_rot
                    fsm.goto("release", one)
            elif left == idx("tilt"):
                # Release where the controller's target is (it leads the blocked TCP): the
                # pads keep pressing the plug home while they open.
                snap["hold_pos"][i] = view.target_pos
                snap["hold_rot"][i] = view.target_rot
            elif left == idx("back_out"):
                # Re-solve: the plug may have turned in the pads while jammed.
                snap["plug_in_tcp"][i] = self._grasp_transform(i)
                snap["plug_goal_rot"][i] = self._plug_goal_rot(i)
