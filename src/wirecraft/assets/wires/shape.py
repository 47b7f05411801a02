"""Polyline geometry for ``WireHandle.set_centerline``: resampling, chord walks, material frames.

All functions are pure numpy (plus MuJoCo's quaternion helpers), deterministic, world frame.
Quaternions are (w, x, y, z).

* ``clean_polyline`` validates a (K, 3) polyline and drops repeated points.
* ``resample_polyline`` samples a polyline at equal arc-length steps (extended straight along its
  last tangent when it is too short, truncated when too long): the reference a wire's
  ``points`` are compared against.
* ``chord_walk`` places nodes *on* the polyline so that consecutive nodes are exactly one
  segment length apart (in a straight line): what a chain of rigid segments (capsules, rod edges
  held by equality constraints, FEM cells) can follow without stretching.  At a kink of angle
  theta falling inside a segment of length l, the chord is shorter than the arc by up to
  l (1 - cos(theta / 2)), so nodes after a kink lag their arc-length position slightly.
* ``transport_frames`` gives each chord a material frame (x = chord direction) by parallel
  transport from a start frame: the frames turn only by the bend between chords (no twist).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from wirecraft.numerics import dot, norm

_EPS = 1e-12


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, np.asarray(a, float), np.asarray(b, float))
    return out


def quat_conj(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, float)
    return np.array([q[0], -q[1], -q[2], -q[3]])


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    out = np.zeros(3)
    mujoco.mju_rotVecQuat(out, np.asarray(v, float), np.asarray(q, float))
    return out


def quat_matrix(q: np.ndarray) -> np.ndarray:
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, np.asarray(q, float))
    return out.reshape(3, 3)


def quat_angle(q: np.ndarray) -> float:
    """Rotation angle (rad, in [0, pi]) of a unit quaternion."""
    q = np.asarray(q, float)
    return 2.0 * math.atan2(norm(q[1:]), abs(float(q[0])))


def axis_angle_quat(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = np.asarray(axis, float)
    axis = axis / norm(axis)
    return np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * axis])


def min_rotation(a: np.ndarray, b: np.ndarray, fallback_axis: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``a`` to unit vector ``b``, as a quaternion.

    For opposite vectors (no unique smallest rotation) it turns by pi about ``fallback_axis``
    (which must be perpendicular to ``a``).
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    cross = np.cross(a, b)
    sin = norm(cross)
    cos = dot(a, b)
    if sin < _EPS:
        if cos > 0:
            return np.array([1.0, 0.0, 0.0, 0.0])
        return axis_angle_quat(fallback_axis, math.pi)
    return axis_angle_quat(cross / sin, math.atan2(sin, cos))


def clean_polyline(points: np.ndarray) -> np.ndarray:
    """Validate a (K, 3) polyline of finite points; drop points repeating their predecessor."""
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"polyline must have shape (K, 3), got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("polyline has non-finite points")
    keep = [0]
    for i in range(1, len(pts)):
        if norm(pts[i] - pts[keep[-1]]) > _EPS:
            keep.append(i)
    if len(keep) < 2:
        raise ValueError("polyline needs at least two distinct points")
    return pts[keep]


def extend_polyline(points: np.ndarray, extra: float) -> np.ndarray:
    """Append a point ``extra`` metres beyond the end, along the last segment's direction."""
    tangent = points[-1] - points[-2]
    tangent = tangent / norm(tangent)
    return np.vstack([points, points[-1] + extra * tangent])


def resample_polyline(points: np.ndarray, count: int, length: float) -> np.ndarray:
    """``count`` points at arc lengths 0, length / (count - 1), ..., length along the polyline.

    A polyline shorter than ``length`` is extended straight along its last segment.
    """
    pts = extend_polyline(clean_polyline(points), length)
    seg = norm(np.diff(pts, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    out = np.empty((count, 3))
    for j, s in enumerate(np.linspace(0.0, length, count)):
        i = min(int(np.searchsorted(cum, s, side="right")) - 1, len(seg) - 1)
        u = (s - cum[i]) / seg[i]
        out[j] = pts[i] + u * (pts[i + 1] - pts[i])
    return out


def distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance of each point to the nearest point of the polyline (its segments)."""
    poly = clean_polyline(polyline)
    a, b = poly[:-1], poly[1:]
    d = b - a
    out = []
    for p in np.asarray(points, float).reshape(-1, 3):
        u = np.clip(dot(p - a, d) / dot(d, d), 0.0, 1.0)
        out.append(np.min(norm(a + u[:, None] * d - p, axis=1)))
    return np.asarray(out)


def chord_walk(points: np.ndarray, step: float, count: int) -> np.ndarray:
    """``count + 1`` nodes on the polyline, node 0 at its start, consecutive nodes ``step`` apart.

    Each node is the first point further along the polyline at straight-line distance ``step``
    from the previous one.  The polyline is extended straight along its last segment as far as
    needed, and whatever lies beyond the last node is ignored.
    """
    pts = extend_polyline(clean_polyline(points), 2.0 * step * count + 1.0)
    nodes = np.empty((count + 1, 3))
    nodes[0] = pts[0]
    seg_index, u_now = 0, 0.0
    for k in range(1, count + 1):
        centre = nodes[k - 1]
        while True:
            a = pts[seg_index]
            d = pts[seg_index + 1] - a
            rel = a - centre
            qa = dot(d, d)
            qb = 2.0 * dot(d, rel)
            qc = dot(rel, rel) - step * step
            disc = max(qb * qb - 4.0 * qa * qc, 0.0)
            u = (-qb + math.sqrt(disc)) / (2.0 * qa)  # the exit from the sphere, going forward
            if u_now <= u <= 1.0 or seg_index == len(pts) - 2:
                break
            seg_index, u_now = seg_index + 1, 0.0
        # snap the node to exactly ``step`` from the previous one (removes rounding)
        node = a + u * d
        offset = node - centre
        nodes[k] = centre + offset * (step / norm(offset))
        u_now = u
    return nodes


def transport_frames(
    nodes: np.ndarray, start_quat: np.ndarray, start_axis: np.ndarray, roll: float
) -> np.ndarray:
    """One frame per chord (nodes[k] -> nodes[k + 1]), (count, 4), x = the chord's direction.

    The first frame is ``start_quat`` (the as-built wire frame, whose x axis is ``start_axis``)
    turned by the smallest rotation onto the first chord (by pi about its z axis if the chord
    points backwards); each next frame is the previous one turned by the smallest rotation onto
    the next chord (parallel transport: no twist).  Finally every frame is rolled by ``roll``
    about its own x axis.
    """
    chords = np.diff(nodes, axis=0)
    tangents = chords / norm(chords, axis=1, keepdims=True)
    frames = np.empty((len(tangents), 4))
    quat = np.asarray(start_quat, float)
    axis = np.asarray(start_axis, float)
    fallback = quat_rotate(quat, np.array([0.0, 0.0, 1.0]))
    for k, t in enumerate(tangents):
        quat = quat_mul(min_rotation(axis, t, fallback), quat)
        quat = quat / norm(quat)
        axis = quat_rotate(quat, np.array([1.0, 0.0, 0.0]))
        fallback = quat_rotate(quat, np.array([0.0, 0.0, 1.0]))
        frames[k] = quat
    if roll != 0.0:
        turn = axis_angle_quat(np.array([1.0, 0.0, 0.0]), roll)
        frames = np.array([quat_mul(f, turn) for f in frames])
    return frames
