"""Task families: what to build, how to randomize, what to observe, reward and judge.

A task never steps the simulation: the environment (envs/env.py) owns the model, the robot and
its controller, and calls the task's hooks, whose names say when they run:

- ``build_scene(spec, wire_config)``: once, adds fixtures and the cable to the spec.
- ``bind(model, robot)``: once after compiling, looks ids up by name.
- ``initialize_episode(model, data, rng)``: each reset, samples and writes poses; the
  environment then lets the scene settle for ``settle_seconds`` with the robot holding still.
- ``privileged_state(model, data)``: the full state vector (the ``state`` observation).
- ``reward_terms(model, data, action)``: named, unweighted terms; the environment multiplies
  them by ``weights`` and reports each in ``info``.
- ``evaluate(model, data)``: success flags and diagnostics for ``info``.
- ``after_step(model, data)``: after each control step's physics and forward pass (not on a
  diverged step), before rewards: discrete changes of the simulation the task owns, such as
  engaging or releasing a connector latch (an ``eq_active`` flag, so it is state).

A task computes its observation, reward, latch logic and success on a ``Frame`` of N
simulations (``observe_batch``, ``reward_batch``, ``after_step_batch``, ``evaluate_batch``),
with its step-to-step trackers as (N,) arrays named in ``trackers``.  The per-simulation hooks
above run the same code with N = 1, and the vector environment runs it once for all its
environments, so both give the same bits.  Contact flags come from MuJoCo contact sensors
(``add_contact_sensors``), which arrive in ``sensordata``.

Task state kept across steps (e.g. a high-water mark) goes through ``get_state``/``set_state``
so that environment snapshots reproduce episodes exactly.

``evaluate(model, data, diagnostics=True)``: ``diagnostics=False`` leaves out the force and
cable diagnostics (``diagnostics``), which walk the contact list of every simulation; RL
training does not read them.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

import mujoco
import numpy as np

from wirecraft import validation
from wirecraft.assets.robots import RobotHandle
from wirecraft.assets.robots.base import Workspace
from wirecraft.assets.wires import WireConfig
from wirecraft.geometry import quats_near
from wirecraft.numerics import matmul, tanh
from wirecraft.registry import Registry
from wirecraft.sensors import (
    Contacts,
    body_geom_ids,
    contact_normal_force,
    geom_ids,
    peak_contact_force,
    touching,
)
from wirecraft.tasks.frame import Frame
from wirecraft.tasks.metrics import TaskMetrics
from wirecraft.tasks.options import TaskOptions

# Episode length unless the task or the user says otherwise.
EPISODE_SECONDS = 8.0

# The meaning of every task's ``state`` vector (layout, frames, units, sign conventions).  Bump
# it with any such change: RL run directories record it, and loading a policy trained on
# another revision fails instead of feeding it inputs it never saw.
#   1: the first layout.
#   2: the TCP and plug quaternions keep the hemisphere of a fixed reference
#      (``geometry.quats_near``) instead of MuJoCo's largest-component sign, which flipped
#      q -> -q as the wrist turned.
STATE_REVISION = 2


def check_state_revision(record: dict, made: str, consequence: str) -> None:
    """A ValueError unless ``record`` (an RL run file, a dataset's settings) says it was made
    on ``STATE_REVISION``; records from before revisions were recorded count as revision 1.
    ``made``: what was made and how (``"RUN was trained"``); ``consequence``: why that stops
    the caller, and what to do instead."""
    revision = record.get("state_revision", 1)
    if revision != STATE_REVISION:
        raise ValueError(
            f"{made} on state revision {revision}; this WireCraft's state is revision "
            f"{STATE_REVISION} (wirecraft.tasks.STATE_REVISION says what changed): {consequence}"
        )


TASKS: Registry[type[Task]] = Registry("task")


def add_contact_found(spec: mujoco.MjSpec, name: str, obj: tuple, ref: tuple) -> None:
    """A contact sensor that counts the contacts (``found``) between ``obj`` and ``ref``, each
    an (mjtObj, name) pair; XBODY means the body's subtree, UNKNOWN (name "") anything."""
    spec.add_sensor(
        name=name,
        type=mujoco.mjtSensor.mjSENS_CONTACT,
        objtype=obj[0],
        objname=obj[1],
        reftype=ref[0],
        refname=ref[1],
        intprm=[1, 0, 1],  # data: found; reduce: none; one slot
    )


class Task(ABC):
    name: ClassVar[str]
    gym_id: ClassVar[str]
    default_control: ClassVar[str]
    default_weights: ClassVar[dict[str, float]]
    settle_seconds: ClassVar[float] = 1.0
    # Step-to-step trackers (attribute name -> initial value), kept per
    # environment as attributes and, in a vector environment, as (N,) arrays.
    trackers: ClassVar[dict[str, float | bool]] = {}
    held_body: ClassVar[str | None] = None  # the body the pads hold (its contact sensors)
    # The body whose subtree is the fixture the robot must not run into (its contact sensors).
    fixture_body: ClassVar[str | None] = None

    Options: ClassVar[type[TaskOptions]] = TaskOptions
    # The family's evaluation metrics (``wirecraft.tasks.metrics``), set by ``metrics_of``.
    metrics: ClassVar[TaskMetrics]
    # Keywords of the task variant ``wirecraft demo`` shows.
    demo_options: ClassVar[dict] = {}

    def __init__(
        self, options: TaskOptions | None = None, weights: dict[str, float] | None = None, **values
    ) -> None:
        if options is None:
            options = self.Options.build(values)
        elif values or not isinstance(options, self.Options):
            raise ValueError(
                f"{self.name}: pass {self.Options.__name__} or keyword values, not "
                f"{type(options).__name__} with {sorted(values)}"
            )
        self.options = options
        self.weights = dict(self.default_weights)
        weights = {} if weights is None else validation.mapping(self.name, "weights", weights)
        for key, value in weights.items():
            if key not in self.weights:
                raise ValueError(
                    f"{self.name}.weights: unknown reward term {key!r}; "
                    f"valid: {', '.join(self.weights)}"
                )
            self.weights[key] = validation.finite(self.name, f"weights[{key!r}]", value)
        self.robot: RobotHandle | None = None

    @property
    def robot_name(self) -> str | None:
        """The bound robot's name (None before ``bind``): per-robot layouts key on it."""
        return self.robot.name if self.robot is not None else None

    @property
    def workspace(self) -> Workspace:
        """The bound robot's workspace (no limits before ``bind``): sampling ranges of the
        task's parts intersect it."""
        return self.robot.spec.workspace if self.robot is not None else Workspace()

    @property
    def episode_seconds(self) -> float:
        """The default episode length of this task variant (``WireCraftEnv(episode_seconds=
        None)`` and the evaluation protocol use it)."""
        return EPISODE_SECONDS

    @property
    @abstractmethod
    def instruction(self) -> str:
        """The language instruction of the episode."""

    @abstractmethod
    def build_scene(self, spec: mujoco.MjSpec, wire_config: WireConfig) -> None: ...

    def add_contact_sensors(self, spec: mujoco.MjSpec, robot: RobotHandle) -> None:
        """Contact sensors (``found``: the number of contacts) for the flags tasks read: each
        pad against the held part (``held_criteria``), and each top moving part of the robot
        (its subtree) against the table and against ``fixture_body``'s subtree."""
        obj = mujoco.mjtObj
        self.pad_criteria = [self.held_criteria(spec, pad) for pad in robot.pad_geom_names]
        for k, pad in enumerate(robot.pad_geom_names):
            for j, (_, reftype, refname) in enumerate(self.pad_criteria[k]):
                add_contact_found(
                    spec, f"touch_pad{k}_{j}", (obj.mjOBJ_GEOM, pad), (reftype, refname)
                )
        fixed = {robot.base_site, f"{robot.prefix}chain_base"}
        tops = [
            b.name
            for b in spec.bodies
            if b.parent is not None and b.parent.name in fixed and b.name not in fixed
        ]
        for k, name in enumerate(tops):
            subtree = (obj.mjOBJ_XBODY, name)
            add_contact_found(spec, f"touch_table{k}", subtree, (obj.mjOBJ_GEOM, "table"))
            if self.fixture_body is not None:
                fixture = (obj.mjOBJ_XBODY, self.fixture_body)
                add_contact_found(spec, f"touch_fixture{k}", subtree, fixture)

    def held_criteria(
        self, spec: mujoco.MjSpec, pad: str
    ) -> list[tuple[float, mujoco.mjtObj, str]]:
        """What the contact sensors of the pad geom ``pad`` count as the held part: (sign,
        reftype, refname) criteria whose signed ``found`` counts add up to the pad's contacts
        with it (``held_body``'s geoms; none without one)."""
        del spec, pad
        if self.held_body is None:
            return []
        return [(1.0, mujoco.mjtObj.mjOBJ_BODY, self.held_body)]

    def bind(self, model: mujoco.MjModel, robot: RobotHandle) -> None:
        """Look up, once, what every task reads: the robot's base, TCP and pads, the cable."""
        self.robot = robot
        index = self.robot_index = robot.index(model)
        self.base_site = index.base_site
        self.tcp_site = index.tcp_site
        self.pads = [geom_ids(model, [name]) for name in robot.pad_geom_names]
        # Everything of the robot that moves (the base stands on the table by design).
        base = model.body(robot.base_site).id
        fixed = {base, model.body(f"{robot.prefix}chain_base").id}
        moving = [
            model.body(b).name
            for b in range(model.nbody)
            if model.body_rootid[b] == base and b not in fixed
        ]
        self.robot_geoms = body_geom_ids(model, moving)
        self.table_geom = geom_ids(model, ["table"])
        self.assembly.bind(model)
        sensors = {model.sensor(k).name: model.sensor_adr[k] for k in range(model.nsensor)}
        # (pads, criteria) sensor addresses and signs: every pad has as many criteria.
        self.pad_sensors = np.array(
            [
                [sensors[f"touch_pad{k}_{j}"] for j in range(len(criteria))]
                for k, criteria in enumerate(self.pad_criteria)
            ],
            dtype=int,
        ).reshape(len(self.pads), -1)
        self.pad_sensor_signs = np.array(
            [[sign for sign, _, _ in criteria] for criteria in self.pad_criteria]
        ).reshape(self.pad_sensors.shape)
        self.table_sensors = np.array(
            [adr for name, adr in sensors.items() if name.startswith("touch_table")], dtype=int
        )
        self.fixture_sensors = np.array(
            [adr for name, adr in sensors.items() if name.startswith("touch_fixture")], dtype=int
        )

    @abstractmethod
    def initialize_episode(self, model, data, rng: np.random.Generator) -> None: ...

    def after_settle(self, model, data) -> None:
        """Called once the scene has settled at reset (e.g. to zero trackers)."""
        del model, data

    def diagnostics(self, model, data) -> dict[str, float]:
        """Force and cable diagnostics for ``info`` (per simulation: they walk its contacts):
        the grasp force on ``held_contacts`` and the cable's health (what the evaluation's
        shared trace columns read)."""
        return {
            "grasp_force": self.grasp_force(model, data, self.held_contacts),
            **self.cable_diagnostics(model, data),
        }

    def get_state(self) -> dict:
        return {}

    def set_state(self, state: dict) -> None:
        del state

    # -- helpers shared by task families ----------------------------------------------------
    def to_base(self, data, points: np.ndarray) -> np.ndarray:
        """World points (..., 3) in the robot base frame."""
        origin = data.site_xpos[self.base_site]
        rot = data.site_xmat[self.base_site].reshape(3, 3)
        return matmul(np.asarray(points) - origin, rot)

    def rot_to_base(self, data, rot: np.ndarray) -> np.ndarray:
        return matmul(data.site_xmat[self.base_site].reshape(3, 3).T, rot)

    def pad_contacts(self, model, data, target: Contacts) -> tuple[bool, bool]:
        return tuple(touching(model, data, pads, target) for pads in self.pads)

    def grasp_force(self, model, data, target: Contacts) -> float:
        return sum(contact_normal_force(model, data, pads, target) for pads in self.pads)

    # -- per-step sensing and diagnostics every task reports -----------------------------------
    held_contacts: Contacts  # what the pads should hold: the plug, or the wire for routing
    fixture_contacts: Contacts  # the port, the clips or the channel

    def fixture_force(self, model, data) -> float:
        """Contact normal force (N) between the cable (wire and plug) and the task's fixture:
        the insertion force of the insertion task."""
        cable = self.assembly.plug_contacts | self.assembly.wire_contacts
        return contact_normal_force(model, data, cable, self.fixture_contacts)

    def sensing(self, model, data) -> dict[str, np.ndarray]:
        """Fingertip contacts (2), grasp force (1) and fixture force (1), as observed."""
        return {
            "fingertip_contact": np.array(
                self.pad_contacts(model, data, self.held_contacts), float
            ),
            "grasp_force": np.array([self.grasp_force(model, data, self.held_contacts)]),
            "fixture_force": np.array([self.fixture_force(model, data)]),
        }

    def cable_diagnostics(self, model, data) -> dict[str, float]:
        """Cable health and contact load: minimum bend radius (m), peak wire tension (N), peak
        single-contact normal force on the cable (N)."""
        cable = self.assembly.plug_contacts | self.assembly.wire_contacts
        return {
            "min_bend_radius": self.assembly.min_bend_radius(model, data),
            "wire_tension": self.assembly.tension(model, data),
            "peak_contact_force": peak_contact_force(model, data, cable),
        }

    def gripper_collision(self, model, data) -> bool:
        """Any moving part of the robot, pads included, touching the table."""
        return touching(model, data, self.robot_geoms, self.table_geom)

    # -- the batched hooks: N simulations at once --------------------------------------------
    @abstractmethod
    def observe_batch(self, frame: Frame) -> np.ndarray:
        """(N, state_dim) privileged states."""

    @abstractmethod
    def reward_batch(self, frame: Frame, trackers: dict, actions: np.ndarray) -> dict:
        """Named, unweighted reward terms, each (N,); may update ``trackers`` (N,) arrays."""

    @abstractmethod
    def evaluate_batch(self, frame: Frame, data_of) -> dict[str, np.ndarray]:
        """Success flags and cheap diagnostics, each (N,).  ``data_of(i)`` gives simulation
        i's ``MjData`` (current) where a quantity needs it."""

    def after_step_batch(self, frame: Frame, trackers: dict, rows: np.ndarray, data_of) -> None:
        """``after_step`` for the simulations where ``rows`` (N,) is True (not diverged)."""
        del frame, trackers, rows, data_of

    # -- the batch code as per-simulation hooks (N = 1) -------------------------------------
    def tracker_arrays(self) -> dict[str, np.ndarray]:
        return {name: np.array([getattr(self, name)]) for name in self.trackers}

    def store_trackers(self, arrays: dict[str, np.ndarray], row: int = 0) -> None:
        for name, values in arrays.items():
            setattr(self, name, values[row].item())

    def reset_trackers(self) -> None:
        for name, value in self.trackers.items():
            setattr(self, name, value)

    def frame_of(self, data) -> Frame:
        """``data`` as a frame of one; the same frame (and its cached geometry) while the
        positions are unchanged, so one step's hooks share their computations."""
        key = (
            id(data),
            data.time,
            data.qpos.tobytes(),
            data.mocap_pos.tobytes(),
            data.mocap_quat.tobytes(),
        )
        if self.__dict__.get("_frame_key") != key:
            self._frame = Frame.of_data(data)
            self._frame_key = key
        return self._frame

    def privileged_state(self, model, data) -> np.ndarray:
        return self.observe_batch(self.frame_of(data))[0]

    def after_step(self, model, data) -> None:
        trackers = self.tracker_arrays()
        self.after_step_batch(self.frame_of(data), trackers, np.ones(1, bool), lambda i: data)
        self.store_trackers(trackers)

    def reward_terms(self, model, data, action: np.ndarray) -> dict[str, float]:
        trackers = self.tracker_arrays()
        actions = np.asarray(action, dtype=float)[None]
        terms = self.reward_batch(self.frame_of(data), trackers, actions)
        self.store_trackers(trackers)
        return {name: float(values[0]) for name, values in terms.items()}

    def evaluate(self, model, data, diagnostics: bool = True) -> dict[str, float | bool]:
        core = self.evaluate_batch(self.frame_of(data), lambda i: data)
        info = {name: values[0].item() for name, values in core.items()}
        if diagnostics:
            info.update(self.diagnostics(model, data))
        return info

    # -- contact flags from the contact sensors ---------------------------------------------
    def pads_touching(self, frame: Frame) -> np.ndarray:
        """(N, 2) whether each pad touches the held part (``held_criteria``)."""
        counts = frame.sensordata[:, self.pad_sensors]  # (N, pads, criteria)
        return np.sum(counts * self.pad_sensor_signs, axis=2) > 0

    def robot_state_batch(self, frame: Frame) -> np.ndarray:
        """(N, 2 dof + 9) what every family's state starts with: joint angles, gripper
        opening, joint velocities, gripper opening rate, TCP position and quaternion (base
        frame; the sign kept near the robot's home orientation)."""
        index = self.robot_index
        tcp_rot = self.rot_to_base_batch(frame, frame.rot("site_xmat", self.tcp_site))
        return np.concatenate(
            [
                frame.qpos[:, index.arm_qpos],
                np.sum(frame.qpos[:, index.finger_qpos], axis=1, keepdims=True),
                frame.qvel[:, index.arm_dof],
                np.sum(frame.qvel[:, index.finger_dof], axis=1, keepdims=True),
                self.to_base_batch(frame, frame.site_xpos[:, self.tcp_site]),
                quats_near(tcp_rot, self.robot.home_tcp_rot),
            ],
            axis=1,
        )

    def wire_points_batch(self, frame: Frame) -> np.ndarray:
        """(N, points, 3) the wire's centre line in world coordinates (once per state)."""
        return frame.cached(
            "wire_points",
            lambda: self.assembly.wire.points_batch(frame.xpos, frame.xmat, frame.flexvert_xpos),
        )

    def wire_points(self, model, data) -> np.ndarray:
        return self.wire_points_batch(self.frame_of(data))[0]

    def table_collision(self, frame: Frame) -> np.ndarray:
        """(N,) whether any moving part of the robot touches the table."""
        return np.any(frame.sensordata[:, self.table_sensors] > 0, axis=1)

    def fixture_collision(self, frame: Frame) -> np.ndarray:
        """(N,) whether any moving part of the robot touches ``fixture_body`` (all False for a
        task without one)."""
        return np.any(frame.sensordata[:, self.fixture_sensors] > 0, axis=1)

    def to_base_batch(self, frame: Frame, points: np.ndarray) -> np.ndarray:
        """World points, (N, 3) or (N, P, 3), in the robot base frame (each point with the
        same arithmetic either way)."""
        origin = frame.site_xpos[:, self.base_site]
        rot = frame.rot("site_xmat", self.base_site)
        if points.ndim == 3:
            return matmul(points - origin[:, None, :], rot)
        return matmul((points - origin)[:, None, :], rot)[:, 0, :]

    def rot_to_base_batch(self, frame: Frame, rots: np.ndarray) -> np.ndarray:
        return matmul(np.swapaxes(frame.rot("site_xmat", self.base_site), 1, 2), rots)


def weighted_reward(terms: dict, weights: dict[str, float]) -> tuple[dict, np.ndarray]:
    """Each term times its weight, and their sum (N,), added in the terms' order (the same
    operations for one environment and for many)."""
    weighted = {name: weights[name] * np.asarray(value, float) for name, value in terms.items()}
    total = np.zeros(np.shape(next(iter(weighted.values()))))
    for value in weighted.values():
        total = total + value
    return weighted, total


def shaped(distance, scale: float):
    """1 at distance 0, falling smoothly to 0 over a few ``scale``s (scalar or array)."""
    return 1.0 - tanh(np.asarray(distance, float) / scale)
