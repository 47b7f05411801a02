"""Rigid transforms and damped-least-squares differential IK shared by robots and control.

Conventions: rotation matrices are (3, 3), quaternions (w, x, y, z), homogeneous transforms
(4, 4); rotation errors are axis * angle vectors (3,) in the world frame.
"""

from __future__ import annotations

import mujoco
import numpy as np


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
    angle = float(np.linalg.norm(rotvec))
    if angle < 1e-12:
        return np.eye(3)
    k = np.asarray(rotvec, dtype=float) / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * kx + (1.0 - np.cos(angle)) * (kx @ kx)


def rotation_error(target: np.ndarray, current: np.ndarray) -> np.ndarray:
    """Axis * angle (3,) of the rotation taking ``current`` to ``target`` (both (3, 3), world)."""
    quat = mat_to_quat(target @ current.T)
    if quat[0] < 0.0:
        quat = -quat
    vec = quat[1:]
    norm = float(np.linalg.norm(vec))
    if norm < 1e-12:
        return np.zeros(3)
    return 2.0 * np.arctan2(norm, quat[0]) * vec / norm


def angle_between(a: np.ndarray, b: np.ndarray) -> float:
    """Angle in radians between two rotation matrices."""
    return float(np.linalg.norm(rotation_error(a, b)))


# -- differential IK ------------------------------------------------------------------------
def dls(jac: np.ndarray, err: np.ndarray, damping: float) -> np.ndarray:
    """Damped least squares: argmin |J dq - e|^2 + damping^2 |dq|^2.  jac (6, n), err (6,)."""
    rows = jac.shape[0]
    return jac.T @ np.linalg.solve(jac @ jac.T + damping**2 * np.eye(rows), err)


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
        residual = err - jac[:, over] @ dq[over]
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
        err_norm = float(np.linalg.norm(err))
        if err_norm < tolerance:
            break
        q = data.qpos[qpos_adr]
        jac = site_jacobian(model, data, site_id, dof_adr)
        data.qpos[qpos_adr] = q + dls_limited(jac, err, damping, q, lower, upper)
    return data.qpos[qpos_adr].copy(), err_norm
