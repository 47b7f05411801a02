"""Geometry shared by assets, tasks, experts and control: rotations and polylines.

Conventions: rotation matrices are (3, 3), quaternions (w, x, y, z), homogeneous transforms
(4, 4); rotation errors are axis * angle vectors (3,) in the world frame.  The batched forms
take a leading axis of N environments: the vector environment runs them on (N, ...) arrays and
a single environment on N = 1, so both compute every step with the same floating-point
operations (bit-identical episodes).  Polylines are (N, 3) arrays of points.
"""

from __future__ import annotations

import mujoco
import numpy as np

from wirecraft.numerics import arctan2, matmul, norm


# -- rotations ---------------------------------------------------------------------------------
def rot_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def transform(rot: np.ndarray | None = None, pos=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(4, 4) homogeneous transform from a rotation matrix and a translation."""
    mat = np.eye(4)
    if rot is not None:
        mat[:3, :3] = rot
    mat[:3, 3] = pos
    return mat


def mat_to_quat(rot: np.ndarray) -> np.ndarray:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(rot, dtype=float).ravel())
    return quat


def quat_to_mat(quat) -> np.ndarray:
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, np.asarray(quat, dtype=float))
    return rot.reshape(3, 3)


def axis_angle_to_mat(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``rotvec`` (axis * angle, radians)."""
    angle = norm(rotvec)
    if angle < 1e-12:
        return np.eye(3)
    k = np.asarray(rotvec, dtype=float) / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * kx + (1.0 - np.cos(angle)) * matmul(kx, kx)


def rotation_error(target: np.ndarray, current: np.ndarray) -> np.ndarray:
    """Axis * angle (3,) of the rotation taking ``current`` to ``target`` (both (3, 3), world)."""
    quat = mat_to_quat(matmul(target, current.T))
    if quat[0] < 0.0:
        quat = -quat
    vec = quat[1:]
    length = norm(vec)
    if length < 1e-12:
        return np.zeros(3)
    return 2.0 * arctan2(length, quat[0]) * vec / length


def angle_between(a: np.ndarray, b: np.ndarray) -> float:
    """Angle in radians between two rotation matrices."""
    return norm(rotation_error(a, b))


def mats_to_quats(mats: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions (w, x, y, z) of (N, 3, 3) rotations: ``mju_mat2Quat`` per row
    (about a microsecond each; a numpy formulation costs more below a few hundred rows)."""
    flat = np.ascontiguousarray(mats, dtype=float).reshape(-1, 9)
    quats = np.empty((flat.shape[0], 4))
    for row, quat in zip(flat, quats, strict=True):
        mujoco.mju_mat2Quat(quat, row)
    return quats


def quats_to_mats(quats: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations of (N, 4) quaternions (w, x, y, z), normalised first: ``mju_quat2Mat``
    per row, in numpy (learners map whole batches of states)."""
    q = np.asarray(quats, dtype=float)
    w, x, y, z = (q / norm(q, axis=-1, keepdims=True)).T
    rows = (
        (1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)),
        (2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)),
        (2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)),
    )
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def quats_near(mats: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions (w, x, y, z) of (N, 3, 3) rotations, each with the sign that puts
    it in the hemisphere of ``reference``'s quaternion (one (3, 3) rotation, or (N, 3, 3): one
    per row).

    q and -q are the same rotation, and ``mju_mat2Quat`` picks the sign by whichever component
    is largest: for a tool pointing down (w ~ 0) it flips between q and -q as the tool turns
    about the vertical, a jump in an observation whose rotation did not change.  A sign fixed by
    a reference near the working orientations (the robot's home TCP orientation) keeps the
    feature continuous except ~180 deg away from the reference."""
    quats = mats_to_quats(mats)
    reference = np.asarray(reference, dtype=float)
    refs = mat_to_quat(reference) if reference.ndim == 2 else mats_to_quats(reference)
    flip = np.sum(quats * refs, axis=-1) < 0.0
    return np.where(flip[:, None], -quats, quats)


def quat_near(rot: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(4,) ``quats_near`` of one (3, 3) rotation."""
    return quats_near(np.asarray(rot, dtype=float)[None], reference)[0]


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products over the last axis (size 3) with broadcasting: ``numpy.cross``'s
    arithmetic without its axis handling, which costs more than the products for small
    arrays."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def axis_angle_to_mats(rotvecs: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices of (N, 3) rotation vectors (axis * angle, radians)."""
    rotvecs = np.asarray(rotvecs, dtype=float)
    angle = norm(rotvecs, axis=1)
    still = angle < 1e-12
    k = rotvecs / np.where(still, 1.0, angle)[:, None]
    zero = np.zeros_like(angle)
    kx = np.stack(
        [
            np.stack([zero, -k[:, 2], k[:, 1]], axis=1),
            np.stack([k[:, 2], zero, -k[:, 0]], axis=1),
            np.stack([-k[:, 1], k[:, 0], zero], axis=1),
        ],
        axis=1,
    )
    mats = (
        np.eye(3)
        + np.sin(angle)[:, None, None] * kx
        + (1.0 - np.cos(angle))[:, None, None] * matmul(kx, kx)
    )
    mats[still] = np.eye(3)
    return mats


def rotation_errors(targets: np.ndarray, currents: np.ndarray) -> np.ndarray:
    """(N, 3) axis * angle of the rotations taking ``currents`` to ``targets`` (N, 3, 3)."""
    quat = mats_to_quats(matmul(targets, np.swapaxes(currents, 1, 2)))
    quat = np.where(quat[:, :1] < 0.0, -quat, quat)
    vec = quat[:, 1:]
    length = norm(vec, axis=1)
    small = length < 1e-12
    scale = 2.0 * arctan2(length, quat[:, 0]) / np.where(small, 1.0, length)
    return np.where(small[:, None], 0.0, vec * scale[:, None])


# -- polylines -----------------------------------------------------------------------------------
def arc_lengths(polyline: np.ndarray) -> np.ndarray:
    """(N,) metres along a polyline from its first point to each of its points."""
    steps = norm(np.diff(np.asarray(polyline, float), axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def resample(polyline: np.ndarray, spacing: float) -> np.ndarray:
    """Points every ``spacing`` metres along a polyline (both ends kept)."""
    polyline = np.asarray(polyline, float)
    arc = arc_lengths(polyline)
    s = np.linspace(0.0, arc[-1], max(2, int(np.ceil(arc[-1] / spacing)) + 1))
    return np.column_stack([np.interp(s, arc, polyline[:, k]) for k in range(3)])


def rotation_from_axis(axis: np.ndarray, roll: float) -> np.ndarray:
    """Rotation whose x column is ``axis``, whose y column is horizontal, rolled by ``roll``."""
    x = np.asarray(axis, float) / norm(axis)
    y = np.cross([0.0, 0.0, 1.0], x)
    if norm(y) < 1e-9:
        y = np.array([0.0, 1.0, 0.0])
    y /= norm(y)
    z = np.cross(x, y)
    c, s = np.cos(roll), np.sin(roll)
    return np.column_stack([x, c * y + s * z, -s * y + c * z])


def segments_meet_box(starts: np.ndarray, ends: np.ndarray, low, high) -> np.ndarray:
    """Whether each segment from ``starts`` to ``ends`` (..., 3) has a point inside the
    axis-aligned box ``low`` <= p <= ``high`` (slab clipping: the segment's parameter range
    [0, 1] narrowed to each axis's slab must stay non-empty)."""
    step = ends - starts
    low, high = np.asarray(low, float), np.asarray(high, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_low = (low - starts) / step
        t_high = (high - starts) / step
    flat = step == 0  # parallel to the slab: inside it everywhere or nowhere
    within = (starts >= low) & (starts <= high)
    enter = np.where(flat, np.where(within, -np.inf, np.inf), np.minimum(t_low, t_high))
    leave = np.where(flat, np.where(within, np.inf, -np.inf), np.maximum(t_low, t_high))
    first = np.maximum(np.max(enter, axis=-1), 0.0)
    last = np.minimum(np.min(leave, axis=-1), 1.0)
    return first <= last
