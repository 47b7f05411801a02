"""Contact and force readings, and camera images, for task observations.

Contact forces come from MuJoCo's solved contact impulses (``mj_contactForce``): normal force
in newtons, summed over the contacts between two sets of geoms.  Images come from
``render.FastRenderer``: RGB (uint8) and depth (float32 metres).
"""

from __future__ import annotations

from collections.abc import Iterable

import mujoco
import numpy as np


def geom_ids(model: mujoco.MjModel, names: Iterable[str]) -> np.ndarray:
    return np.array([model.geom(n).id for n in names], dtype=int)


def body_geom_ids(model: mujoco.MjModel, body_names: Iterable[str]) -> np.ndarray:
    bodies = {model.body(n).id for n in body_names}
    return np.array([g for g in range(model.ngeom) if model.geom_bodyid[g] in bodies], dtype=int)


def contact_normal_force(
    model: mujoco.MjModel, data: mujoco.MjData, geoms_a: np.ndarray, geoms_b: np.ndarray | None
) -> float:
    """Sum of contact normal forces (N) between a geom of ``geoms_a`` and one of ``geoms_b``
    (``None``: any other geom)."""
    total = 0.0
    wrench = np.zeros(6)
    set_a = set(int(g) for g in geoms_a)
    set_b = None if geoms_b is None else set(int(g) for g in geoms_b)
    for i in range(data.ncon):
        g1, g2 = int(data.contact.geom1[i]), int(data.contact.geom2[i])
        if g1 in set_a:
            other = g2
        elif g2 in set_a:
            other = g1
        else:
            continue
        if set_b is not None and other not in set_b:
            continue
        mujoco.mj_contactForce(model, data, i, wrench)
        total += abs(wrench[0])
    return total


def touching(model, data, geoms_a: np.ndarray, geoms_b: np.ndarray | None) -> bool:
    set_a = set(int(g) for g in geoms_a)
    set_b = None if geoms_b is None else set(int(g) for g in geoms_b)
    for i in range(data.ncon):
        g1, g2 = int(data.contact.geom1[i]), int(data.contact.geom2[i])
        for a, b in ((g1, g2), (g2, g1)):
            if a in set_a and (set_b is None or b in set_b):
                return True
    return False


def quat_to_mat(quat: np.ndarray) -> np.ndarray:
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, dtype=float))
    return mat.reshape(3, 3)


def mat_to_quat(mat: np.ndarray) -> np.ndarray:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.asarray(mat, dtype=float).reshape(9))
    return quat
