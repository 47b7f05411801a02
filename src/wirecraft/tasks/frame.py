"""The simulation fields a task reads, for N simulations at once.

A ``Frame`` holds arrays with a leading axis of N: the vector environment's are live views of
its ``mujoco.batch.Batch`` (``Frame.of_batch``), a single environment's are its ``MjData``
fields with an axis of 1 added (``Frame.of_data``, no copy).  Tasks that compute their
observation, reward and success on frames (every ``Task``) run the same code, with the same
floating-point operations, in both, so a vector environment's episodes are bit-identical to a
single environment's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

FIELDS = (
    "qpos",
    "qvel",
    "xpos",
    "xmat",
    "site_xpos",
    "site_xmat",
    "sensordata",
    "eq_active",
    "cdof",
    "subtree_com",
    "flexvert_xpos",
)


@dataclass
class Frame:
    qpos: np.ndarray  # (N, nq)
    qvel: np.ndarray  # (N, nv)
    xpos: np.ndarray  # (N, nbody, 3)
    xmat: np.ndarray  # (N, nbody, 9)
    site_xpos: np.ndarray  # (N, nsite, 3)
    site_xmat: np.ndarray  # (N, nsite, 9)
    sensordata: np.ndarray  # (N, nsensordata)
    eq_active: np.ndarray  # (N, neq); writable: the task's latches change it
    cdof: np.ndarray  # (N, nv, 6) for Jacobians
    subtree_com: np.ndarray  # (N, nbody, 3)
    flexvert_xpos: np.ndarray  # (N, nflexvert, 3): rod and FEM wires' vertices
    # Quantities derived from the positions, computed once per state (``cached``); whoever
    # changes the state clears it (``Frame.of_batch`` frames live across steps).
    cache: dict = field(default_factory=dict, repr=False)

    def cached(self, name: str, compute):
        if name not in self.cache:
            self.cache[name] = compute()
        return self.cache[name]

    @property
    def size(self) -> int:
        return self.qpos.shape[0]

    @classmethod
    def of_data(cls, data: mujoco.MjData) -> Frame:
        """One simulation (N = 1): views of ``data``'s fields."""
        return cls(**{name: getattr(data, name)[None] for name in FIELDS})

    @classmethod
    def of_batch(cls, batch) -> Frame:
        """All simulations of a ``mujoco.batch.Batch``: its bound fields (live views; the
        derived ones are current after a call with ``stage=mjSTAGE_ACC``)."""
        return cls(**{name: batch.bind(name) for name in FIELDS})

    def rot(self, field: str, index: int) -> np.ndarray:
        """(N, 3, 3) rotation matrices of object ``index`` of ``xmat`` or ``site_xmat``."""
        return getattr(self, field)[:, index].reshape(-1, 3, 3)


def norms(vectors: np.ndarray) -> np.ndarray:
    """(N,) Euclidean norms of (N, 3) vectors."""
    return np.sqrt(np.sum(vectors * vectors, axis=1))


def dots(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) row-wise dot products of (N, 3) vectors."""
    return np.sum(a * b, axis=1)
