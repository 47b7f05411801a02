"""Rigid transforms and damped-least-squares differential IK shared by robots and control.

Conventions: rotation matrices are (3, 3), quaternions (w, x, y, z), homogeneous transforms
(4, 4); rotation errors are axis * angle vectors (3,) in the world frame.
"""

from __future__ import annotations

import mujoco
import numpy as np

from wirecraft.numerics import arctan2, matmul, matvec, norm, solve_spd


# -- elementary transforms -------------------------------------------------------------------
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


# -- differential IK ------------------------------------------------------------------------
def dls(jac: np.ndarray, err: np.ndarray, damping: float) -> np.ndarray:
    """Damped least squares: argmin |J dq - e|^2 + damping^2 |dq|^2.  jac (6, n), err (6,)."""
    rows = jac.shape[0]
    return matvec(jac.T, solve_spd(matmul(jac, jac.T) + damping**2 * np.eye(rows), err))


def dls_limited(
    jac: np.ndarray,
    err: np.ndarray,
    damping: float,
    q: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
) -> np.ndarray:
    """DLS step that respects joint limits: joints the free step would push past a limit are
    stopped at the limit and the remaining error is re-solved with the other joints (one pass).
    """
    dq = dls(jac, err, damping)
    over = (q + dq < lower) | (q + dq > upper)
    if not over.any():
        return dq
    fixed = np.clip(q + dq, lower, upper) - q
    dq = np.zeros_like(dq)
    dq[over] = fixed[over]
    free = ~over
    if free.any():
        residual = err - matvec(jac[:, over], dq[over])
        dq[free] = dls(jac[:, free], residual, damping)
    return np.clip(q + dq, lower, upper) - q


def site_pose(model: mujoco.MjModel, data: mujoco.MjData, site_id: int):
    """World position (3,) and rotation (3, 3) of a site (kinematics must be current)."""
    return data.site_xpos[site_id].copy(), data.site_xmat[site_id].reshape(3, 3).copy()


def site_jacobian(
    model: mujoco.MjModel, data: mujoco.MjData, site_id: int, dofs: np.ndarray
) -> np.ndarray:
    """(6, len(dofs)) translational + rotational Jacobian of a site over the given DoF columns."""
    jacp = np.zeros((3, model.nv))
    jacr = np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jacp, jacr, site_id)
    return np.vstack([jacp[:, dofs], jacr[:, dofs]])


def solve_ik(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    site_id: int,
    qpos_adr: np.ndarray,
    dof_adr: np.ndarray,
    target_pos: np.ndarray,
    target_rot: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    iterations: int = 300,
    damping: float = 1e-3,
    tolerance: float = 1e-7,
) -> tuple[np.ndarray, float]:
    """Iterate DLS on ``data`` (its qpos is modified) until the site reaches the target pose.

    Returns the joint vector and the final error norm (metres + radians).
    """
    err_norm = np.inf
    for _ in range(iterations):
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        pos, rot = site_pose(model, data, site_id)
        err = np.concatenate([target_pos - pos, rotation_error(target_rot, rot)])
        err_norm = norm(err)
        if err_norm < tolerance:
            break
        q = data.qpos[qpos_adr]
        jac = site_jacobian(model, data, site_id, dof_adr)
        data.qpos[qpos_adr] = q + dls_limited(jac, err, damping, q, lower, upper)
    return data.qpos[qpos_adr].copy(), err_norm


# -- batched forms: a leading axis of N environments ------------------------------------------
# The vector environment runs these on (N, ...) arrays and a single environment on N = 1, so
# both compute every step with the same floating-point operations (bit-identical episodes).
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


def dls_batch(jac: np.ndarray, err: np.ndarray, damping: float) -> np.ndarray:
    """(N, n) damped least squares per environment: jac (N, 6, n), err (N, 6)."""
    rows = jac.shape[1]
    jac_t = np.swapaxes(jac, 1, 2)
    gram = matmul(jac, jac_t) + damping**2 * np.eye(rows)
    return matvec(jac_t, solve_spd(gram, err))


def dls_limited_batch(jac, err, damping: float, q, lower, upper) -> np.ndarray:
    """``dls_limited`` per environment (N, n): only environments where a joint would cross a
    limit take the second, per-environment solve."""
    dq = dls_batch(jac, err, damping)
    over = (q + dq < lower) | (q + dq > upper)
    for r in np.flatnonzero(over.any(axis=1)):
        fixed = np.clip(q[r] + dq[r], lower, upper) - q[r]
        row = np.zeros_like(dq[r])
        row[over[r]] = fixed[over[r]]
        free = ~over[r]
        if free.any():
            residual = err[r] - matvec(jac[r][:, over[r]], row[over[r]])
            row[free] = dls_batch(jac[r][None][:, :, free], residual[None], damping)[0]
        dq[r] = np.clip(q[r] + row, lower, upper) - q[r]
    return dq


def chain_jacobian(cdof, subtree_com, point, root: int, dofs) -> np.ndarray:
    """(N, 6, len(dofs)) translational + rotational Jacobian of world points (N, 3) over DoFs
    that are all ancestors of the point's body, from MuJoCo's ``cdof`` (N, nv, 6) and
    ``subtree_com`` (N, nbody, 3) (``mj_jac``'s formula; ``root`` is the body's root)."""
    offset = point - subtree_com[:, root]
    motion = cdof[:, dofs]
    angular = motion[:, :, :3]
    linear = motion[:, :, 3:] + cross3(angular, offset[:, None, :])
    return np.concatenate([linear, angular], axis=2).transpose(0, 2, 1)
