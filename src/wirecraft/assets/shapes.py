"""Primitive solids shared by simulation and 3D printing.

Every printable part (plugs, ports, clips, channels, board) is described once, as a list of
convex primitives in the part's own frame.  The same list becomes MuJoCo geoms (``add_to_body``)
and, unioned into one watertight solid, an STL mesh (``to_mesh``): what you print is what you
simulate.  Units are metres; quaternions are (w, x, y, z).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import manifold3d
import mujoco
import numpy as np
import trimesh

from wirecraft import physics
from wirecraft.numerics import norm

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
IDENTITY: Quat = (1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Box:
    half: Vec3  # half extents along the shape's local x, y, z
    pos: Vec3 = (0.0, 0.0, 0.0)
    quat: Quat = IDENTITY


@dataclass(frozen=True)
class Cylinder:
    radius: float
    half_length: float  # along the shape's local z, as in MuJoCo
    pos: Vec3 = (0.0, 0.0, 0.0)
    quat: Quat = IDENTITY


@dataclass(frozen=True)
class Prism:
    """A convex polygon in the part's (y, z) plane, extruded along x from ``x0`` to ``x1``.

    The profile's vertices go counter-clockwise seen from +x.  Used for chamfered shells.
    """

    profile: tuple[tuple[float, float], ...]
    x0: float
    x1: float
    pos: Vec3 = (0.0, 0.0, 0.0)
    quat: Quat = IDENTITY

    def vertices(self) -> np.ndarray:
        """(2 n, 3) corner points in the prism's own frame: the x0 cap, then the x1 cap."""
        yz = np.asarray(self.profile, dtype=float)
        n = len(yz)
        near = np.column_stack([np.full(n, self.x0), yz])
        far = np.column_stack([np.full(n, self.x1), yz])
        return np.vstack([near, far])


Shape = Box | Cylinder | Prism


def quat_about(axis: Sequence[float], angle: float) -> Quat:
    """Quaternion (w, x, y, z) for a rotation of ``angle`` radians about ``axis``."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / norm(axis)
    s = np.sin(angle / 2.0)
    return (float(np.cos(angle / 2.0)), *(float(a * s) for a in axis))


def to_yawed_frame(points: np.ndarray, pos: Sequence[float], yaw: float) -> np.ndarray:
    """World points (..., 3) in a frame at ``pos`` turned by ``yaw`` about z: (n, 3)."""
    c, s = np.cos(yaw), np.sin(yaw)
    d = np.asarray(points, dtype=float).reshape(-1, 3) - np.asarray(pos)
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]])


def add_yawed_body(
    spec: mujoco.MjSpec,
    name: str,
    pos: Sequence[float],
    yaw: float,
    parent: mujoco.MjsBody | None = None,
) -> mujoco.MjsBody:
    """A fixed body at ``pos`` turned by ``yaw`` about z (a fixture standing on the table)."""
    return (parent or spec.worldbody).add_body(
        name=name, pos=tuple(pos), quat=quat_about((0.0, 0.0, 1.0), yaw)
    )


def _transform(pos: Vec3, quat: Quat) -> np.ndarray:
    mat = np.eye(4)
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, np.asarray(quat, dtype=float))
    mat[:3, :3] = rot.reshape(3, 3)
    mat[:3, 3] = pos
    return mat


def add_to_body(
    spec: mujoco.MjSpec,
    body: mujoco.MjsBody,
    shapes: Sequence[Shape],
    prefix: str,
    *,
    rgba: Sequence[float] = (0.6, 0.6, 0.6, 1.0),
    friction: float | None = None,
    density: float | None = None,
) -> list[mujoco.MjsGeom]:
    """Add ``shapes`` as collision geoms named ``{prefix}_{i}`` to ``body``."""
    geoms = []
    for i, shape in enumerate(shapes):
        geom = body.add_geom(name=f"{prefix}_{i}", pos=shape.pos, quat=shape.quat, rgba=rgba)
        if isinstance(shape, Box):
            geom.type = mujoco.mjtGeom.mjGEOM_BOX
            geom.size = shape.half
        elif isinstance(shape, Cylinder):
            geom.type = mujoco.mjtGeom.mjGEOM_CYLINDER
            geom.size = (shape.radius, shape.half_length, 0.0)
        elif isinstance(shape, Prism):
            mesh_name = f"{prefix}_{i}_mesh"
            spec.add_mesh(name=mesh_name, uservert=shape.vertices().ravel().tolist())
            geom.type = mujoco.mjtGeom.mjGEOM_MESH
            geom.meshname = mesh_name
        else:  # pragma: no cover - the Shape union is closed
            raise TypeError(f"not a shape: {shape!r}")
        if density is not None:
            geom.density = density
        physics.stiff_contact(geom, friction=friction)
        geoms.append(geom)
    return geoms


def _shape_mesh(shape: Shape) -> trimesh.Trimesh:
    if isinstance(shape, Box):
        mesh = trimesh.creation.box(extents=2.0 * np.asarray(shape.half))
    elif isinstance(shape, Cylinder):
        mesh = trimesh.creation.cylinder(
            radius=shape.radius, height=2.0 * shape.half_length, sections=96
        )
    elif isinstance(shape, Prism):
        verts = shape.vertices()
        n = len(shape.profile)
        faces = []
        for k in range(1, n - 1):  # caps: fans; x0 cap faces -x, x1 cap faces +x
            faces.append([0, k + 1, k])
            faces.append([n, n + k, n + k + 1])
        for k in range(n):  # sides
            a, b = k, (k + 1) % n
            faces.append([a, b, n + b])
            faces.append([a, n + b, n + a])
        mesh = trimesh.Trimesh(vertices=verts, faces=np.asarray(faces), process=True)
        mesh.fix_normals()
    else:  # pragma: no cover
        raise TypeError(f"not a shape: {shape!r}")
    mesh.apply_transform(_transform(shape.pos, shape.quat))
    return mesh


def to_mesh(
    shapes: Sequence[Shape], *, scale: float = 1.0, tolerance: float = 1e-3
) -> trimesh.Trimesh:
    """One watertight solid: the boolean union of ``shapes``, scaled (1000 gives millimetres).

    Overlapping primitives leave sliver edges; simplifying the union to ``tolerance`` (in the
    scaled unit) removes them, so the solid stays watertight after a float32 STL round trip.
    """
    if not shapes:
        raise ValueError("to_mesh needs at least one shape")
    solids = []
    for shape in shapes:
        mesh = _shape_mesh(shape)
        mesh.apply_scale(scale)
        solids.append(
            manifold3d.Manifold(
                manifold3d.Mesh(
                    vert_properties=np.asarray(mesh.vertices, dtype=np.float32),
                    tri_verts=np.asarray(mesh.faces, dtype=np.uint32),
                )
            )
        )
    union = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add).simplify(tolerance)
    out = union.to_mesh()
    solid = trimesh.Trimesh(vertices=out.vert_properties[:, :3], faces=out.tri_verts, process=False)
    if not solid.is_watertight:
        raise RuntimeError("the union of the part's shapes is not watertight")
    return solid
