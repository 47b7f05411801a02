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

Task state kept across steps (e.g. a high-water mark) goes through ``get_state``/``set_state``
so that environment snapshots reproduce episodes exactly.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

import mujoco
import numpy as np

from wirecraft.assets.robots import RobotHandle
from wirecraft.assets.wires import WireConfig
from wirecraft.registry import Registry
from wirecraft.sensors import (
    Contacts,
    body_geom_ids,
    contact_normal_force,
    geom_ids,
    peak_contact_force,
    touching,
)

TASKS: Registry[type[Task]] = Registry("task")


class Task(ABC):
    name: ClassVar[str]
    gym_id: ClassVar[str]
    default_control: ClassVar[str]
    default_weights: ClassVar[dict[str, float]]
    settle_seconds: ClassVar[float] = 1.0

    def __init__(self, weights: dict[str, float] | None = None) -> None:
        self.weights = dict(self.default_weights)
        for key, value in (weights or {}).items():
            if key not in self.weights:
                raise ValueError(
                    f"{self.name}: unknown reward term {key!r}; valid: {', '.join(self.weights)}"
                )
            self.weights[key] = float(value)
        self.robot: RobotHandle | None = None

    @property
    @abstractmethod
    def instruction(self) -> str:
        """The language instruction of the episode."""

    @abstractmethod
    def build_scene(self, spec: mujoco.MjSpec, wire_config: WireConfig) -> None: ...

    def bind(self, model: mujoco.MjModel, robot: RobotHandle) -> None:
        """Look up, once, what every task reads: the robot's base, TCP and pads, the cable."""
        self.robot = robot
        index = robot.index(model)
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

    @abstractmethod
    def initialize_episode(self, model, data, rng: np.random.Generator) -> None: ...

    def after_settle(self, model, data) -> None:
        """Called once the scene has settled at reset (e.g. to zero trackers)."""
        del model, data

    def after_step(self, model, data) -> None:
        """Called after each control step's physics (state up to date, constraint forces of
        that state included); may change state flags such as ``data.eq_active``."""
        del model, data

    @abstractmethod
    def privileged_state(self, model, data) -> np.ndarray: ...

    @abstractmethod
    def reward_terms(self, model, data, action: np.ndarray) -> dict[str, float]: ...

    @abstractmethod
    def evaluate(self, model, data) -> dict[str, float | bool]: ...

    def get_state(self) -> dict:
        return {}

    def set_state(self, state: dict) -> None:
        del state

    def wire_points(self, model, data) -> np.ndarray:
        return self.assembly.wire.points(model, data)

    # -- helpers shared by task families ----------------------------------------------------
    def memo(self, data, name: str, compute):
        """``compute()`` once per simulation state: observation, reward and success all ask for
        the same geometry within a step.  Keyed on time, positions and mocap poses, so a state
        written by hand is never served a stale answer."""
        key = (
            name,
            data.time,
            data.qpos.tobytes(),
            data.mocap_pos.tobytes(),
            data.mocap_quat.tobytes(),
        )
        cache = self.__dict__.setdefault("_memo", {})
        if key not in cache:
            if len(cache) > 64:
                cache.clear()
            cache[key] = compute()
        return cache[key]

    def to_base(self, data, points: np.ndarray) -> np.ndarray:
        """World points (..., 3) in the robot base frame."""
        origin = data.site_xpos[self.base_site]
        rot = data.site_xmat[self.base_site].reshape(3, 3)
        return (np.asarray(points) - origin) @ rot

    def rot_to_base(self, data, rot: np.ndarray) -> np.ndarray:
        return data.site_xmat[self.base_site].reshape(3, 3).T @ rot

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


def shaped(distance: float, scale: float) -> float:
    """1 at distance 0, falling smoothly to 0 over a few ``scale``s."""
    return float(1.0 - np.tanh(distance / scale))
