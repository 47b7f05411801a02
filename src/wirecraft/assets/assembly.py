"""The cable every task starts from: a wire with a plug on its end and a clamp on its start.

By default the clamp is a 0.2 kg block that rests on the table: the cable's far end is
dynamic, as on a real harness board, and drifts when the wire is pulled hard.  At each reset
the whole assembly is laid out straight behind a sampled plug pose (``place``), then the task
lets it fall and settle.

``build(..., fixed_clamp=(exit, yaw))`` instead bolts the clamp to the board: a static body
(no joint) whose wire exit is the world point ``exit`` and from which the wire leaves
horizontally at heading ``yaw``; its block stands on the table behind the exit.  A task then
lays the wire out from that exit itself (``lay_from_clamp``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from wirecraft import physics
from wirecraft.assets.connectors import Connector, add_plug
from wirecraft.assets.shapes import Box, add_to_body, quat_about
from wirecraft.assets.wires import WireConfig, WireHandle, add_wire, end_gap
from wirecraft.geometry import quat_to_mat, rotation_from_axis
from wirecraft.numerics import arccos, dot, norm
from wirecraft.sensors import Contacts, body_geom_ids, flex_ids

CLAMP_HALF = (0.02, 0.015, 0.012)  # m
CLAMP_EXIT_DROP = -0.008  # m: block centre below the wire's start
TABLE_CLEARANCE = 0.001  # m: a placed assembly starts at least this far above the table
CLAMP_MASS = 0.2  # kg
CLAMP_RGBA = (0.35, 0.35, 0.38, 1.0)


@dataclass
class WireAssembly:
    wire: WireHandle
    connector: Connector
    plug: str = "plug"
    clamp: str = "clamp"

    @classmethod
    def build(
        cls,
        spec: mujoco.MjSpec,
        wire_config: WireConfig,
        connector: Connector,
        *,
        fixed_clamp: tuple[tuple[float, float, float], float] | None = None,
    ):
        """The wire, its plug and its clamp.  ``fixed_clamp``: None for the free 0.2 kg clamp
        block; ``(exit, yaw)`` for a clamp bolted to the board with its wire exit at the world
        point ``exit`` and the wire leaving it horizontally at heading ``yaw`` (rad about z)."""
        if fixed_clamp is None:
            wire = add_wire(spec, wire_config, name="wire", pos=(0.0, 0.0, 0.05))
        else:
            exit_point, yaw = fixed_clamp
            if exit_point[2] <= 0.0:
                raise ValueError(f"fixed_clamp: the exit must be above the table, got {exit_point}")
            # Built leaving the clamp's exit: a wire end clamped inside its body (the rod)
            # takes the as-built pose as its rest shape, so the body must sit at end_pose.
            heading = np.array([math.cos(yaw), math.sin(yaw), 0.0])
            wire = add_wire(
                spec,
                wire_config,
                name="wire",
                pos=tuple(np.asarray(exit_point, float) + end_gap(wire_config) * heading),
                quat=quat_about((0, 0, 1), yaw),
            )
        pos, quat = wire.end_pose("end")
        add_plug(spec, connector, name="plug", pos=tuple(pos), quat=tuple(quat))
        wire.attach(spec, "end", "plug")
        if fixed_clamp is None:
            pos, quat = wire.end_pose("start")
            clamp = spec.worldbody.add_body(name="clamp", pos=tuple(pos), quat=tuple(quat))
            clamp.add_freejoint(name="clamp_free")
            # The clamp's origin holds the wire start near the top of its block, which sits
            # behind it (+x, away from the wire): the cable leaves above low fixtures.
            drop = CLAMP_EXIT_DROP
        else:
            # The body's +x points away from the wire (wires/base.py): turned by yaw + pi.
            # (This is the wire's end_pose("start"), written exactly.)
            clamp = spec.worldbody.add_body(
                name="clamp", pos=tuple(exit_point), quat=quat_about((0, 0, 1), yaw + math.pi)
            )
            # Bolted down: the block stands on the table whatever the exit height.
            drop = CLAMP_HALF[2] - exit_point[2]
        block = Box(CLAMP_HALF, (CLAMP_HALF[0], 0.0, drop))
        volume = 8 * np.prod(CLAMP_HALF)
        add_to_body(
            spec,
            clamp,
            [block],
            "clamp",
            rgba=CLAMP_RGBA,
            friction=physics.TABLE_FRICTION,
            density=CLAMP_MASS / volume,
        )
        wire.attach(spec, "start", "clamp")
        return cls(wire=wire, connector=connector)

    def bind(self, model: mujoco.MjModel) -> None:
        self.plug_id = model.body(self.plug).id
        self.plug_qpos = model.joint("plug_free").qposadr[0]
        self.plug_dof = model.joint("plug_free").dofadr[0]
        clamp_body = model.body(self.clamp)
        self.clamp_fixed = int(clamp_body.jntnum[0]) == 0
        self.clamp_qpos = None if self.clamp_fixed else model.joint("clamp_free").qposadr[0]
        self.clamp_dof = None if self.clamp_fixed else model.joint("clamp_free").dofadr[0]
        self.tip_site = model.site("plug_tip").id
        self.grasp_site = model.site("plug_grasp").id
        self.plug_contacts = body_geom_ids(model, [self.plug])
        self.wire_contacts = self._wire_contacts(model)
        self.wire.resolve(model)
        self.end_equalities = np.array(
            [e for e in range(model.neq) if model.equality(e).name.startswith("wire_end")],
            dtype=int,
        )

    def _wire_contacts(self, model) -> Contacts:
        """The wire's collision elements: its capsules, or its flex."""
        if getattr(self.wire, "flex_name", None) and model.nflex:
            return flex_ids(model, [self.wire.flex_name])
        prefix = f"{self.wire.name}_"
        return Contacts(
            geoms=frozenset(
                g
                for g in range(model.ngeom)
                if model.body(model.geom_bodyid[g]).name.startswith(prefix)
            )
        )

    def place(self, model, data, plug_pos, direction, roll: float) -> np.ndarray:
        """Lay the wire straight along ``direction`` (unit, the plug's insertion axis) ending at
        ``plug_pos``, rolled by ``roll`` about it; put the plug and clamp on its ends, at rest.

        If any part would reach into the table (a pitched cable, a tilted clamp block), the
        whole assembly is lifted until it clears it by ``TABLE_CLEARANCE``; returns the plug
        position used.
        """
        direction = np.asarray(direction, float) / norm(direction)
        plug_pos = np.asarray(plug_pos, float)
        self._lay(model, data, plug_pos, direction, roll)
        lift = TABLE_CLEARANCE - self.lowest_point(model, data)
        if lift > 0:
            plug_pos = plug_pos + [0.0, 0.0, lift]
            self._lay(model, data, plug_pos, direction, roll)
        return plug_pos

    def _lay(self, model, data, plug_pos, direction, roll) -> None:
        end = plug_pos - self.wire.end_gap * direction
        line = np.linspace(end - self.wire.config.length * direction, end, 9)
        # set_centerline rolls relative to its own minimal-rotation frame; the task's roll is
        # measured from the frame whose y axis is horizontal (rotation_from_axis).
        natural = quat_to_mat(self.wire.set_centerline(model, data, line)["end"][1])
        wanted = rotation_from_axis(direction, roll)
        offset = math.atan2(
            dot(np.cross(natural[:, 1], wanted[:, 1]), direction),
            dot(natural[:, 1], wanted[:, 1]),
        )
        ends = self.wire.set_centerline(model, data, line, roll=offset)
        self._put_ends(model, data, ends)

    def _put_ends(self, model, data, ends) -> None:
        """Plug (and a free clamp) on the wire's ends, at rest; then ``mj_forward``."""
        for body_qpos, body_dof, end in (
            (self.plug_qpos, self.plug_dof, "end"),
            (self.clamp_qpos, self.clamp_dof, "start"),
        ):
            if body_qpos is None:  # a clamp bolted to the board stays where it is
                continue
            pos, quat = ends[end]
            data.qpos[body_qpos : body_qpos + 3] = pos
            data.qpos[body_qpos + 3 : body_qpos + 7] = quat
            data.qvel[body_dof : body_dof + 6] = 0.0
        mujoco.mj_forward(model, data)

    def lay_from_clamp(self, model, data, points) -> None:
        """Lay the wire along the polyline ``points`` (K, 3, world), which must start at a fixed
        clamp's exit, untwisted from the clamp's frame, and put the plug on its end, at rest."""
        if not self.clamp_fixed:
            raise ValueError("lay_from_clamp needs an assembly built with fixed_clamp")
        points = np.asarray(points, float).copy()
        # the wire starts end_gap out of the clamp (wires/base.py), along the first segment
        lead = points[1] - points[0]
        if norm(lead) <= self.wire.end_gap:
            raise ValueError("lay_from_clamp: the first segment must be longer than the end gap")
        points[0] += self.wire.end_gap * lead / norm(lead)
        # set_centerline's roll is relative to its own transported frame; roll the wire so its
        # start frame is the clamp's (the weld holds it there).
        clamp = quat_to_mat(model.body_quat[model.body(self.clamp).id])
        natural = quat_to_mat(self.wire.set_centerline(model, data, points)["start"][1])
        offset = math.atan2(
            dot(np.cross(natural[:, 1], clamp[:, 1]), natural[:, 0]),
            dot(natural[:, 1], clamp[:, 1]),
        )
        for sign in (-1.0, 1.0):  # the start frame's x is minus the tangent the roll turns about
            ends = self.wire.set_centerline(model, data, points, roll=sign * offset)
            if sign > 0 or dot(quat_to_mat(ends["start"][1])[:, 1], clamp[:, 1]) > 0.999:
                break
        self._put_ends(model, data, ends)

    def lowest_point(self, model, data) -> float:
        """Lowest height (m) of the wire surface, the plug and the clamp (after mj_forward)."""
        radius = self.wire.config.radius
        lowest = float(self.wire.points(model, data)[:, 2].min()) - radius
        for body in (self.plug, self.clamp):
            bid = model.body(body).id
            for g in range(model.ngeom):
                if model.geom_bodyid[g] == bid:
                    lowest = min(lowest, float(data.geom_xpos[g, 2] - model.geom_rbound[g]))
        return lowest

    def plug_pose(self, data) -> tuple[np.ndarray, np.ndarray]:
        """Plug position (3,) and rotation matrix (3, 3) in the world."""
        return data.xpos[self.plug_id].copy(), data.xmat[self.plug_id].reshape(3, 3).copy()

    def tension(self, model, data) -> float:
        """Peak pull (N) along the wire.

        Rod: the largest force of the flex's edge-length constraints, leaving out the two end
        edges (their load is shared arbitrarily with the end attachments, which constrain the
        same lengths).  Capsule chain and FEM: the net force of the plug-end attachment.
        """
        rows = np.flatnonzero(data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY)
        ids = data.efc_id[rows]
        edges = rows[model.eq_type[ids] == mujoco.mjtEq.mjEQ_FLEX]
        if len(edges) > 2:
            return float(np.abs(data.efc_force[edges[1:-1]]).max())
        force = np.zeros(3)
        for eq in self.end_equalities:
            eq_rows = rows[ids == eq]
            force += data.efc_force[eq_rows[:3]]
        return norm(force)

    def min_bend_radius(self, model, data) -> float:
        """Smallest radius of curvature (m) along the wire's centre line (inf when straight)."""
        pts = self.wire.points(model, data)
        seg = np.diff(pts, axis=0)
        lengths = norm(seg, axis=1)
        unit = seg / lengths[:, None]
        cos = np.clip(dot(unit[:-1], unit[1:]), -1.0, 1.0)
        turn = arccos(cos)
        mean_len = (lengths[:-1] + lengths[1:]) / 2
        curvature = turn / mean_len
        peak = float(curvature.max()) if len(curvature) else 0.0
        return float("inf") if peak < 1e-9 else 1.0 / peak


__all__ = ["WireAssembly"]
