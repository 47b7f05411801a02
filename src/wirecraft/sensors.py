"""Contact and force readings, and camera images, for task observations.

Contact forces come from MuJoCo's solved contact impulses (``mj_contactForce``): normal force
in newtons, summed over the contacts between two sets of geoms.  Images come from
``render.FastRenderer``: RGB (uint8) and depth (float32 metres).
"""

from __future__ import annotations

import functools
from collections.abc import Iterable
from dataclasses import dataclass

import mujoco
import numpy as np

from wirecraft.numerics import matmul


@dataclass(frozen=True)
class Contacts:
    """A set of collision elements: geoms (by id) and flexes (by id, for rod and FEM wires)."""

    geoms: frozenset[int] = frozenset()
    flexes: frozenset[int] = frozenset()

    def __or__(self, other: Contacts) -> Contacts:
        return Contacts(self.geoms | other.geoms, self.flexes | other.flexes)

    def mask(self, data: mujoco.MjData, side: int) -> np.ndarray:
        """(ncon,) which contacts have this set on ``side`` (0 or 1)."""
        n = data.ncon
        ngeom = int(data.contact.geom[:n].max(initial=0)) + 1
        nflex = int(data.contact.flex[:n].max(initial=0)) + 1
        geom_lut, flex_lut = _lookup(self, ngeom, nflex)
        # -1 (no geom / no flex) indexes the tables' last entry, which is False.
        return geom_lut[data.contact.geom[:n, side]] | flex_lut[data.contact.flex[:n, side]]


@functools.lru_cache(maxsize=4096)
def _lookup(contacts: Contacts, ngeom: int, nflex: int) -> tuple[np.ndarray, np.ndarray]:
    """Boolean tables over geom and flex ids (one spare False entry for id -1)."""
    geoms = np.zeros(max(ngeom, max(contacts.geoms, default=-1) + 1) + 1, dtype=bool)
    geoms[list(contacts.geoms)] = True
    flexes = np.zeros(max(nflex, max(contacts.flexes, default=-1) + 1) + 1, dtype=bool)
    flexes[list(contacts.flexes)] = True
    return geoms, flexes


EVERYTHING = None  # as the second set: contacts with anything


def geom_ids(model: mujoco.MjModel, names: Iterable[str]) -> Contacts:
    return Contacts(geoms=frozenset(model.geom(n).id for n in names))


def body_geom_ids(model: mujoco.MjModel, body_names: Iterable[str]) -> Contacts:
    bodies = {model.body(n).id for n in body_names}
    geoms = frozenset(g for g in range(model.ngeom) if model.geom_bodyid[g] in bodies)
    return Contacts(geoms=geoms)


def flex_ids(model: mujoco.MjModel, names: Iterable[str]) -> Contacts:
    return Contacts(
        flexes=frozenset(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_FLEX, n) for n in names)
    )


_BETWEEN_CACHE: dict = {}
_BETWEEN_CACHE_SIZE = 4096


def _between(data: mujoco.MjData, a: Contacts, b: Contacts | None) -> np.ndarray:
    """Indices of contacts between set ``a`` and set ``b`` (None: anything).

    The answer depends only on the contacts' geom and flex ids, so it is memoized on them: one
    step asks the same question many times (observation, reward, success).
    """
    n = data.ncon
    geom, flex = data.contact.geom[:n], data.contact.flex[:n]
    key = (a, b, geom.tobytes(), flex.tobytes())
    hit = _BETWEEN_CACHE.get(key)
    if hit is not None:
        return hit
    if b is None:
        mask = a.mask(data, 0) | a.mask(data, 1)
    else:
        mask = (a.mask(data, 0) & b.mask(data, 1)) | (a.mask(data, 1) & b.mask(data, 0))
    hit = np.flatnonzero(mask)
    if len(_BETWEEN_CACHE) >= _BETWEEN_CACHE_SIZE:
        _BETWEEN_CACHE.clear()
    _BETWEEN_CACHE[key] = hit
    return hit


def contact_normal_force(model, data, a: Contacts, b: Contacts | None) -> float:
    """Sum of contact normal forces (N) between set ``a`` and set ``b`` (None: anything)."""
    wrench = np.zeros(6)
    total = 0.0
    for i in _between(data, a, b):
        mujoco.mj_contactForce(model, data, int(i), wrench)
        total += abs(wrench[0])
    return total


def peak_contact_force(model, data, a: Contacts, b: Contacts | None = None) -> float:
    """Largest single contact normal force (N) between set ``a`` and set ``b`` (None: anything)."""
    wrench = np.zeros(6)
    peak = 0.0
    for i in _between(data, a, b):
        mujoco.mj_contactForce(model, data, int(i), wrench)
        peak = max(peak, abs(wrench[0]))
    return peak


def deepest_penetration(data, a: Contacts, b: Contacts | None = None) -> float:
    """Largest overlap (m, >= 0) of the contacts between set ``a`` and set ``b`` (None:
    anything); 0 without contacts."""
    hits = _between(data, a, b)
    return float(max(0.0, -data.contact.dist[hits].min())) if hits.size else 0.0


def contact_push(data, a: Contacts, b: Contacts | None) -> np.ndarray:
    """Sum (3,) of the unit normals of the contacts between set ``a`` and set ``b`` (None:
    anything), each turned to point from ``b`` into ``a``: the way ``b`` pushes ``a``."""
    hits = _between(data, a, b)
    # MuJoCo's contact normal points from the contact's side 0 to its side 1.
    sign = np.where(a.mask(data, 1)[hits], 1.0, -1.0)
    return matmul(sign, data.contact.frame[hits, :3]) if hits.size else np.zeros(3)


def touching(model, data, a: Contacts, b: Contacts | None) -> bool:
    del model
    return bool(_between(data, a, b).size)
