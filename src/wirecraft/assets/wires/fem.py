"""Volumetric FEM wire: a MuJoCo ``flexcomp dim="3"`` grid with trilinear dofs.

Geometry: a grid of ``segments + 1`` x 2 x 2 vertices (tetrahedralised by flexcomp) whose square
cross-section of side ``s = r (3 pi)^(1/4)`` has the same second moment (s^4 / 12) as the wire's
circle (pi r^4 / 4); the flex radius ``r - s/2`` pads the collision surface out to the wire's
radius.  Dofs: a trilinear interpolation grid of ``segments // 2`` cells along the axis and one
across (nodes ``NAME_i_j_k``), so each cell spans two vertex intervals.

Shear locking: trilinear hexahedra with one cell across the thickness are far too stiff in
bending (measured 6.5x at E = 5e7 with 20 cells).  Their bending stiffness is that of the beam
times F = 1 + (a / s)^2 / (2 (1 + nu)) (a = cell length, the classical result for bilinear
elements in pure bending, which matched our cantilever to within a few percent), so the flex is
given E / F: the wire then bends with the config's E.  Stretch is F times softer than E would
give; at wire-scale loads that is still < 1% strain.

Damping: MuJoCo 4.0 refuses joint damping on flex vertex/node bodies, so the reference's
"vertex damping 3.0" has no direct counterpart; ``damping`` is the elasticity's
stiffness-proportional damping (s).  It damps a mode in proportion to its frequency (damping
ratio ~ omega * damping / 2), so the default is set by the slow bending swings: at 0.0005 s the
first one (1.3 Hz) kept 92% of its amplitude per swing (damping ratio 0.014) and the wire
pressed into a curved channel swung out of it again; 0.02 s gives 0.10 (docs/physics.md,
"FEM choices").  Ends attach with four ``connect`` equalities
on the end face's nodes, which clamps position, tangent and roll.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from wirecraft.assets.wires import shape
from wirecraft.assets.wires.base import (
    END_CLEARANCE,
    FLEX,
    WIRE_MODELS,
    WireConfig,
    WireHandle,
    flex_touch_criteria,
    set_slide_bodies,
)
from wirecraft.numerics import matvec, norm


def _square_side(radius: float) -> float:
    return radius * (3.0 * math.pi) ** 0.25


def _flex_radius(radius: float) -> float:
    return radius - _square_side(radius) / 2


@WIRE_MODELS.register("fem")
class FemWire(WireHandle):
    model = "fem"
    DEFAULTS = {
        "radius": 0.003,
        "segments": 40,
        "density": 800.0,
        "young": 5e7,
        "poisson": 0.49,
        "damping": 0.02,
        "friction": 1.0,
        "rgba": (0.2, 0.65, 0.3, 1.0),
    }

    @property
    def num_points(self) -> int:
        return self.config.segments + 1

    @property
    def cells(self) -> int:
        return max(1, self.config.segments // 2)

    @property
    def side(self) -> float:
        """m, side of the square elastic cross-section (same second moment as the circle)."""
        return _square_side(self.config.radius)

    @property
    def flex_radius(self) -> float:
        """m the collision surface reaches beyond the nodes: pads the square out to the radius."""
        return _flex_radius(self.config.radius)

    @classmethod
    def gap_for(cls, config: WireConfig) -> float:
        return _flex_radius(config.radius) + END_CLEARANCE

    @property
    def locking_factor(self) -> float:
        c = self.config
        aspect = (c.length / self.cells) / self.side
        return 1.0 + aspect**2 / (2.0 * (1.0 + c.poisson))

    @property
    def flex_young(self) -> float:
        """Pa, the Young's modulus given to MuJoCo (config E / locking factor)."""
        return self.config.young / self.locking_factor

    def node_name(self, i: int, j: int, k: int) -> str:
        return f"{self.flex_name}_{i}_{j}_{k}"

    def _build(self, spec: mujoco.MjSpec) -> None:
        c = self.config
        n = c.segments + 1
        s = self.side
        seg = c.segment_length
        rgba = " ".join(f"{v:g}" for v in c.rgba)
        xml = (
            f'<flexcomp name="{FLEX}" type="grid" dim="3" dof="trilinear" '
            f'cellcount="{self.cells} 1 1" count="{n} 2 2" '
            f'spacing="{seg:.9g} {s:.9g} {s:.9g}" radius="{self.flex_radius:.9g}" '
            f'mass="{c.mass:.9g}" POSE rgba="{rgba}">'
            '<edge equality="false"/>'
            f'<elasticity young="{self.flex_young:.9g}" poisson="{c.poisson:g}" '
            f'damping="{c.damping:g}"/>'
            f"{self._contact_xml('none')}"
            "</flexcomp>"
        )
        self._add_flexcomp(spec, xml, in_body=True)

    def _attach(self, spec: mujoco.MjSpec, end: str, body_name: str) -> None:
        i = 0 if end == "start" else self.cells
        x = 0.0 if end == "start" else self.config.length
        h = self.side / 2
        anchors = [
            (self.node_name(i, j, k), np.array([x, (2 * j - 1) * h, (2 * k - 1) * h]))
            for j in range(2)
            for k in range(2)
        ]
        self._connect_sites(spec, body_name, end, anchors)

    def _resolve(self, model: mujoco.MjModel) -> object:
        flex = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_FLEX, self.flex_name)
        if flex < 0:
            raise ValueError(f"no flex named {self.flex_name!r} in the model")
        adr = model.flex_vertadr[flex]
        return np.arange(adr, adr + model.flex_vertnum[flex])

    def _points(self, xpos, xmat, flexvert_xpos, ids: object) -> np.ndarray:
        verts = flexvert_xpos[:, ids]  # (N, n * 4, 3), x slowest
        return verts.reshape(len(verts), -1, 4, 3).mean(axis=2)

    def _touch_criteria(self, spec, geom: str) -> list[tuple[float, mujoco.mjtObj, str]]:
        return flex_touch_criteria(spec, geom)

    # -- set_centerline ------------------------------------------------------------------------
    def _shape_nodes(self) -> tuple[int, float]:
        return self.cells, self.config.length / self.cells

    def _shape_ids(self, model: mujoco.MjModel) -> dict[str, np.ndarray]:
        bodies = np.zeros((self.cells + 1, 2, 2), dtype=int)
        for i in range(self.cells + 1):
            for j in range(2):
                for k in range(2):
                    name = self.node_name(i, j, k)
                    bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
                    if bid < 0:
                        raise ValueError(f"no node body named {name!r} in the model")
                    bodies[i, j, k] = bid
        flat = bodies.reshape(-1)
        joints = [j for b in flat for j in range(model.body_jntadr[b], model.body_jntadr[b] + 3)]
        return {"bodies": flat, "joints": np.asarray(joints)}

    def _set_shape(self, model, data, ids, nodes, frames, roll) -> None:
        # ``nodes`` are the centres of the node cross-sections (cell boundaries), ``frames`` the
        # cells' frames.  Each cross-section is square to the mean of its two cells' tangents
        # (the end ones to their cell), its corners at (0, +-h, +-h) in that frame.
        h = self.side / 2
        x_axis = np.array([1.0, 0.0, 0.0])
        section = [frames[0]]
        for i in range(1, len(frames)):
            prev = shape.quat_rotate(frames[i - 1], x_axis)
            mean = prev + shape.quat_rotate(frames[i], x_axis)
            turn = shape.min_rotation(prev, mean / norm(mean), x_axis)
            section.append(shape.quat_mul(turn, frames[i - 1]))
        section.append(frames[-1])
        targets = np.empty((len(nodes), 2, 2, 3))
        for i, (centre, quat) in enumerate(zip(nodes, section, strict=True)):
            rot = shape.quat_matrix(quat)
            for j in range(2):
                for k in range(2):
                    targets[i, j, k] = centre + matvec(
                        rot, np.array([0.0, (2 * j - 1) * h, (2 * k - 1) * h])
                    )
        set_slide_bodies(model, data, ids["bodies"], targets.reshape(-1, 3))
