"""Connector insertion: pick the plug off the table and seat it in the port.

Task description
    A cable lies on the table: a clamp block on one end, a plug (one of the connector
    families) on the other.  The robot must grasp the plug by its tail, carry it to the port
    held by a stand, align it with the socket (position, axis and roll) and push it home.

Randomizations (each reset, from the reset seed)
    Plug: 6-11 cm above the table, roll and pitch uniform +/-18 deg, yaw +/-36 deg about the
    insertion axis (world +y), offset +/-5 cm along it and +/-15 cm across it; the cable is laid
    out straight behind the plug and the whole assembly falls and settles for 1 s.  If the
    pitched cable would reach into the table, the assembly is lifted until it clears.
    Port: fixed along the insertion axis (mouth at y = 0.22 m); across it (x) within 28 cm,
    height within 15 cm.

Success conditions
    reach_success: the plug tip within 2 cm of the socket entry while held (or inserted).
    insert_success: the tip within ``AXIAL_TOLERANCE`` of the seated target along the socket
    axis and within the clearance + ``LATERAL_TOLERANCE`` of the axis.  success = insert.

Privileged state (42-d for a 6-joint arm; positions and orientations in the robot base frame):
    arm joint positions (dof), gripper opening (1), arm joint velocities (dof), gripper opening
    rate (1), TCP position (3) and quaternion (4), left/right pad touching the plug (2), plug
    tip to seated target (3), plug position (3) and quaternion (4), port entry (3), seated
    target (3), insertion gate, axial and lateral seating errors (3).
"""

from __future__ import annotations

import math

import numpy as np

from wirecraft import physics
from wirecraft.assets.connectors import CONNECTORS, add_port, make_connector
from wirecraft.assets.fixtures import PortStandConfig
from wirecraft.assets.shapes import add_to_body, quat_about
from wirecraft.sensors import body_geom_ids, contact_normal_force, mat_to_quat
from wirecraft.tasks.assembly import WireAssembly
from wirecraft.tasks.base import TASKS, Task, shaped

INSERTION_AXIS = np.array([0.0, 1.0, 0.0])  # world direction the plug moves to seat
PORT_Y = 0.22  # m, socket mouth along the insertion axis
PORT_X_RANGE = (-0.14, 0.14)  # m across the axis: 28 cm
PORT_Z_RANGE = (0.04, 0.19)  # m mouth centre height: 15 cm
PLUG_CENTRE = np.array([0.0, -0.02])  # m (x, y) of the plug spawn region
PLUG_OFFSET = (0.15, 0.05)  # m, +/- across (x) and along (y) the insertion axis
PLUG_HEIGHT = (0.06, 0.11)  # m
PLUG_ROLL_PITCH = math.radians(18.0)
PLUG_YAW = math.radians(36.0)

AXIAL_TOLERANCE = 0.002  # m
LATERAL_TOLERANCE = 0.001  # m beyond the clearance
REACH_DISTANCE = 0.02  # m
ROLL_GATE = math.radians(10.0)  # insertion depth only counts with the roll this well aligned
PRE_INSERT = 0.03  # m before the mouth: where "bring" aims


@TASKS.register("insertion")
class InsertionTask(Task):
    name = "insertion"
    gym_id = "WireCraft/ConnectorInsertion-v0"
    default_control = "cartesian"
    default_weights = {
        "reach": 15.0,
        "grasp": 25.0,
        "bring": 40.0,
        "align": 20.0,
        "insert_depth": 6000.0,
        "port_orientation": 10.0,
        "roll": 10.0,
        "ee_orientation": 10.0,
        "seated": 1000.0,
        "action": -0.1,
        "collision": -10.0,
    }

    def __init__(self, connector: str = "ethernet", clearance: float = 0.003, weights=None):
        super().__init__(weights)
        CONNECTORS.get(connector)  # ValueError listing the valid ones
        self.connector = make_connector(connector, clearance)
        self.depth_high_water = 0.0

    @property
    def instruction(self) -> str:
        return f"Pick up the {self.connector.name} plug and insert it into the port."

    # -- scene ------------------------------------------------------------------------------
    def build_scene(self, spec, wire_config) -> None:
        self.assembly = WireAssembly.build(spec, wire_config, self.connector)
        # The port hangs on a mocap stand: its pose is state, set per episode, no rebuild.
        mount = spec.worldbody.add_body(
            name="port_mount", mocap=True, quat=quat_about((0, 0, 1), math.pi / 2)
        )
        add_port(spec, self.connector, name="port", parent=mount)
        stand = PortStandConfig(height=0.3)  # reaches the table at every port height
        back = self.connector.cavity_depth + 0.004
        shapes = [
            s.__class__(s.half, (s.pos[0] + back, s.pos[1], s.pos[2] - stand.height + 0.03), s.quat)
            for s in stand.shapes()
        ]
        add_to_body(
            spec,
            mount,
            shapes,
            "port_stand",
            rgba=(0.7, 0.7, 0.72, 1.0),
            friction=physics.TABLE_FRICTION,
        )

    def bind(self, model, robot) -> None:
        super().bind(model, robot)
        self.mount_id = model.body("port_mount").mocapid[0]
        self.port_id = model.body("port").id
        self.entry_site = model.site("port_entry").id
        self.seated_site = model.site("port_seated").id
        self.port_contacts = body_geom_ids(model, ["port", "port_mount"])
        self.fixture_contacts = self.port_contacts
        self.held_contacts = self.assembly.plug_contacts

    # -- episode ----------------------------------------------------------------------------
    def initialize_episode(self, model, data, rng) -> None:
        port = np.array([rng.uniform(*PORT_X_RANGE), PORT_Y, rng.uniform(*PORT_Z_RANGE)])
        data.mocap_pos[self.mount_id] = port
        yaw = rng.uniform(-PLUG_YAW, PLUG_YAW)
        pitch = rng.uniform(-PLUG_ROLL_PITCH, PLUG_ROLL_PITCH)
        roll = rng.uniform(-PLUG_ROLL_PITCH, PLUG_ROLL_PITCH)
        axis = np.array(
            [-math.sin(yaw) * math.cos(pitch), math.cos(yaw) * math.cos(pitch), math.sin(pitch)]
        )
        plug = np.array(
            [
                PLUG_CENTRE[0] + rng.uniform(-PLUG_OFFSET[0], PLUG_OFFSET[0]),
                PLUG_CENTRE[1] + rng.uniform(-PLUG_OFFSET[1], PLUG_OFFSET[1]),
                rng.uniform(*PLUG_HEIGHT),
            ]
        )
        self.sampled = {"port": port, "plug": plug.copy(), "yaw": yaw, "pitch": pitch, "roll": roll}
        self.sampled["placed_plug"] = self.assembly.place(model, data, plug, axis, roll)
        self.depth_high_water = 0.0

    # -- geometry ---------------------------------------------------------------------------
    def _port_frame(self, data):
        rot = data.xmat[self.port_id].reshape(3, 3)
        return data.site_xpos[self.entry_site].copy(), rot

    def seating_errors(self, data) -> dict[str, float]:
        """Axial error (m to go along the socket axis), lateral error (m off the axis), depth
        (m past the mouth), roll error (rad, modulo the connector's symmetry) and axis error."""
        return self.memo(data, "seating_errors", lambda: self._seating_errors(data))

    def _seating_errors(self, data) -> dict[str, float]:
        entry, port_rot = self._port_frame(data)
        axis = port_rot[:, 0]
        tip = data.site_xpos[self.assembly.tip_site]
        depth = float(np.dot(tip - entry, axis))
        lateral = float(np.linalg.norm((tip - entry) - depth * axis))
        _, plug_rot = self.assembly.plug_pose(data)
        axis_error = float(np.arccos(np.clip(np.dot(plug_rot[:, 0], axis), -1.0, 1.0)))
        # Roll: angle of the plug's up (z) axis about the socket axis, against the socket's.
        up = plug_rot[:, 2] - np.dot(plug_rot[:, 2], axis) * axis
        roll = math.atan2(
            float(np.dot(np.cross(port_rot[:, 2], up), axis)), float(np.dot(port_rot[:, 2], up))
        )
        n = self.connector.symmetry
        roll_error = 0.0 if n == 0 else abs((roll + math.pi / n) % (2 * math.pi / n) - math.pi / n)
        return {
            "depth": depth,
            "axial": self.connector.cavity_depth - depth,
            "lateral": lateral,
            "roll_error": roll_error,
            "axis_error": axis_error,
        }

    def held(self, model, data) -> bool:
        return all(self.pad_contacts(model, data, self.assembly.plug_contacts))

    # -- observation ------------------------------------------------------------------------
    def privileged_state(self, model, data) -> np.ndarray:
        robot = self.robot
        tcp = self.to_base(data, data.site_xpos[self.tcp_site])
        tcp_quat = mat_to_quat(self.rot_to_base(data, data.site_xmat[self.tcp_site].reshape(3, 3)))
        plug_pos, plug_rot = self.assembly.plug_pose(data)
        entry = data.site_xpos[self.entry_site]
        seated = data.site_xpos[self.seated_site]
        tip = data.site_xpos[self.assembly.tip_site]
        err = self.seating_errors(data)
        gate = float(
            err["roll_error"] < ROLL_GATE
            and err["lateral"] < self.connector.clearance + LATERAL_TOLERANCE
            and err["depth"] > 0
        )
        return np.concatenate(
            [
                robot.arm_qpos(model, data),
                [robot.gripper_opening(model, data)],
                robot.arm_qvel(model, data),
                [robot.gripper_velocity(model, data)],
                tcp,
                tcp_quat,
                np.array(self.pad_contacts(model, data, self.assembly.plug_contacts), dtype=float),
                (seated - tip) @ data.site_xmat[self.base_site].reshape(3, 3),
                self.to_base(data, plug_pos),
                mat_to_quat(self.rot_to_base(data, plug_rot)),
                self.to_base(data, entry),
                self.to_base(data, seated),
                [gate, err["axial"], err["lateral"]],
            ]
        )

    # -- reward -----------------------------------------------------------------------------
    def reward_terms(self, model, data, action) -> dict[str, float]:
        tcp = data.site_xpos[self.tcp_site]
        grasp_point = data.site_xpos[self.assembly.grasp_site]
        held = self.held(model, data)
        entry, port_rot = self._port_frame(data)
        axis = port_rot[:, 0]
        tip = data.site_xpos[self.assembly.tip_site]
        tail = data.site_xpos[self.assembly.grasp_site]
        err = self.seating_errors(data)

        def off_axis(point):
            rel = point - entry
            return float(np.linalg.norm(rel - np.dot(rel, axis) * axis))

        pre_insert = entry - PRE_INSERT * axis
        depth_fraction = np.clip(err["depth"] / self.connector.cavity_depth, 0.0, 1.0)
        if err["roll_error"] > ROLL_GATE:
            depth_fraction = 0.0
        ratchet = max(0.0, depth_fraction - self.depth_high_water)
        self.depth_high_water = max(self.depth_high_water, depth_fraction)
        tcp_z = data.site_xmat[self.tcp_site].reshape(3, 3)[:, 2]
        return {
            "reach": shaped(float(np.linalg.norm(tcp - grasp_point)), 0.1),
            "grasp": float(held),
            "bring": float(held) * shaped(float(np.linalg.norm(tip - pre_insert)), 0.1),
            "align": float(held) * shaped(off_axis(tip) + off_axis(tail), 0.02),
            "insert_depth": ratchet,
            "port_orientation": float(held) * shaped(err["axis_error"], 0.2),
            "roll": float(held) * shaped(err["roll_error"], 0.2),
            "ee_orientation": shaped(float(np.arccos(np.clip(-tcp_z[2], -1, 1))), 0.5),
            "seated": float(self._inserted(err)),
            "action": float(np.sum(np.square(action))),
            "collision": float(self.gripper_collision(model, data)),
        }

    def _inserted(self, err) -> bool:
        return (
            err["axial"] < AXIAL_TOLERANCE
            and err["lateral"] < self.connector.clearance + LATERAL_TOLERANCE
        )

    # -- evaluation -------------------------------------------------------------------------
    def evaluate(self, model, data) -> dict[str, float | bool]:
        err = self.seating_errors(data)
        inserted = self._inserted(err)
        tip = data.site_xpos[self.assembly.tip_site]
        near = float(np.linalg.norm(tip - data.site_xpos[self.entry_site])) < REACH_DISTANCE
        return {
            "success": inserted,
            "reach_success": bool(near and (self.held(model, data) or inserted)),
            "insert_success": inserted,
            "insertion_depth": err["depth"],
            "lateral_error": err["lateral"],
            "yaw_error": err["axis_error"],
            "roll_error": err["roll_error"],
            "insertion_force": contact_normal_force(
                model, data, self.assembly.plug_contacts, self.port_contacts
            ),
            "grasp_force": self.grasp_force(model, data, self.assembly.plug_contacts),
            **self.cable_diagnostics(model, data),
        }

    def get_state(self) -> dict:
        return {"depth_high_water": self.depth_high_water}

    def set_state(self, state: dict) -> None:
        self.depth_high_water = state["depth_high_water"]
