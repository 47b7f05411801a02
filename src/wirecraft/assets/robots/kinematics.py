"""Damped-least-squares differential IK shared by robots and control (rotations and transforms:
``wirecraft.geometry``)."""

from __future__ import annotations

import mujoco
import numpy as np

from wirecraft.geometry import cross3, rotation_error
from wirecraft.numerics import matmul, matvec, norm, solve_spd

# -- elementary transforms -------------------------------------------------------------------


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
