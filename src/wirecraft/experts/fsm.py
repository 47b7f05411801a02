"""A vectorized finite-state machine for scripted experts: one phase index per environment.

Phases are data (``Phase``: a name, position / orientation tolerances, a dwell and an optional
timeout).  Every array carries one row per environment:

- ``phase``: (N,) int, index into ``phases``
- ``steps``: (N,) int, control steps spent in the current phase
- ``dwell``: (N,) int, consecutive steps the current phase's goal has been within tolerance
- ``snapshots[name]``: (N, ...) float arrays the expert writes once (e.g. the grasp transform at
  grasp time) and reads in later phases, so that those servo toward a reference the wire's
  deformation does not move.

- ``retries[counter]``: (N,) int, how often each environment was sent back by ``retry``.

A single environment is N = 1.  Each control step the expert computes, per environment, the
distance of the end effector to its phase goal and calls ``advance_if(reached)``: an
environment moves on once its goal has been reached (within the phase's tolerances) for
``dwell`` consecutive steps, or once it has spent ``timeout`` steps in the phase.  It moves to
the phase's ``next`` (default: the following phase in the list), so branches that are only
taken sometimes (a retry, a drop) can sit in the list without being entered by default.  The
last phase is terminal (it never advances).  ``retry(counter, target, mask, limit)`` sends
environments back to an earlier phase at most ``limit`` times per episode.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wirecraft.numerics import norm


@dataclass(frozen=True)
class Phase:
    """One phase of a scripted expert.

    pos_tol: m, rot_tol: rad: how close the end effector must be to the phase goal.
    dwell: consecutive control steps within tolerance before the phase advances (>= 1).
    timeout: control steps after which the phase advances anyway (None: never).
    next: name of the phase it advances to (None: the following one in the list).
    """

    name: str
    pos_tol: float = 0.005
    rot_tol: float = 0.05
    dwell: int = 1
    timeout: int | None = None
    next: str | None = None

    def __post_init__(self) -> None:
        if self.pos_tol < 0 or self.rot_tol < 0:
            raise ValueError(f"Phase {self.name!r}: tolerances must be >= 0")
        if self.dwell < 1:
            raise ValueError(f"Phase {self.name!r}: dwell must be >= 1, got {self.dwell}")
        if self.timeout is not None and self.timeout < 1:
            raise ValueError(f"Phase {self.name!r}: timeout must be >= 1, got {self.timeout}")


class VectorFSM:
    """Per-environment phase index, step counter, dwell counter and snapshots for N envs."""

    def __init__(self, phases: list[Phase] | tuple[Phase, ...], num_envs: int) -> None:
        if not phases:
            raise ValueError("VectorFSM needs at least one phase")
        names = [p.name for p in phases]
        if len(set(names)) != len(names):
            raise ValueError(f"VectorFSM: phase names must be unique, got {names}")
        if num_envs < 1:
            raise ValueError(f"VectorFSM: num_envs must be >= 1, got {num_envs}")
        self.phases = tuple(phases)
        self.num_envs = num_envs
        self._index = {name: i for i, name in enumerate(names)}
        self.pos_tol = np.array([p.pos_tol for p in phases])
        self.rot_tol = np.array([p.rot_tol for p in phases])
        self.dwell_needed = np.array([p.dwell for p in phases])
        big = np.iinfo(np.int64).max
        self.timeout = np.array([big if p.timeout is None else p.timeout for p in phases])
        last = len(phases) - 1
        self.next_index = np.array(
            [
                last if i == last else (i + 1 if p.next is None else self.index(p.next))
                for i, p in enumerate(phases)
            ]
        )
        self.phase = np.zeros(num_envs, dtype=np.int64)
        self.steps = np.zeros(num_envs, dtype=np.int64)
        self.dwell = np.zeros(num_envs, dtype=np.int64)
        self.timed_out = np.zeros(num_envs, dtype=bool)  # the last advance came from a timeout
        self.snapshots: dict[str, np.ndarray] = {}
        self.retries: dict[str, np.ndarray] = {}

    # -- lookup ------------------------------------------------------------------------------
    def index(self, name: str) -> int:
        try:
            return self._index[name]
        except KeyError:
            raise ValueError(f"unknown phase {name!r}; valid: {', '.join(self._index)}") from None

    @property
    def names(self) -> list[str]:
        """(N,) the current phase name of every environment."""
        return [self.phases[i].name for i in self.phase]

    def in_phase(self, *names: str) -> np.ndarray:
        """(N,) bool: environments currently in any of ``names``."""
        return np.isin(self.phase, [self.index(n) for n in names])

    @property
    def done(self) -> np.ndarray:
        """(N,) bool: environments in the terminal (last) phase."""
        return self.phase == len(self.phases) - 1

    # -- lifecycle ---------------------------------------------------------------------------
    def _mask(self, env_ids) -> np.ndarray:
        mask = np.zeros(self.num_envs, bool)
        if env_ids is None:
            mask[:] = True
        else:
            ids = np.asarray(env_ids)
            if ids.dtype == bool:
                if ids.shape != (self.num_envs,):
                    raise ValueError(f"env mask must have shape ({self.num_envs},)")
                mask = ids.copy()
            else:
                mask[ids.astype(int)] = True
        return mask

    def reset(self, env_ids=None) -> None:
        """Back to the first phase for ``env_ids`` (indices or an (N,) mask; None: all)."""
        mask = self._mask(env_ids)
        self.phase[mask] = 0
        self.steps[mask] = 0
        self.dwell[mask] = 0
        self.timed_out[mask] = False
        for value in self.snapshots.values():
            value[mask] = np.nan
        for count in self.retries.values():
            count[mask] = 0

    def within(self, pos_err, rot_err) -> np.ndarray:
        """(N,) bool: errors (N,) (m, rad) within the tolerances of each env's current phase."""
        return (np.asarray(pos_err) <= self.pos_tol[self.phase]) & (
            np.asarray(rot_err) <= self.rot_tol[self.phase]
        )

    def advance_if(self, reached) -> np.ndarray:
        """Count one control step; advance the environments whose goal has been ``reached``
        ((N,) bool) for the current phase's dwell in a row, or whose phase timed out.

        A step outside tolerance restarts the dwell count.  Returns the (N,) mask of the
        environments that advanced (their step and dwell counters restart at 0).
        """
        reached = np.asarray(reached, bool)
        if reached.shape != (self.num_envs,):
            raise ValueError(f"reached must have shape ({self.num_envs},), got {reached.shape}")
        self.steps += 1
        self.dwell = np.where(reached, self.dwell + 1, 0)
        settled = self.dwell >= self.dwell_needed[self.phase]
        expired = self.steps >= self.timeout[self.phase]
        advance = (settled | expired) & ~self.done
        self.timed_out[advance] = expired[advance] & ~settled[advance]
        self.phase[advance] = self.next_index[self.phase[advance]]
        self.steps[advance] = 0
        self.dwell[advance] = 0
        return advance

    def goto(self, name: str, mask) -> None:
        """Jump the environments in ``mask`` to phase ``name`` (e.g. a retry)."""
        mask = self._mask(mask)
        self.phase[mask] = self.index(name)
        self.steps[mask] = 0
        self.dwell[mask] = 0

    def retry(self, counter: str, target: str, mask, limit: int) -> np.ndarray:
        """Send the environments in ``mask`` back to phase ``target`` unless ``counter`` has
        already sent them back ``limit`` times this episode; count it.  Returns the (N,) mask of
        the environments sent back (the others stay where they are: the caller lets them go
        on)."""
        if limit < 0:
            raise ValueError(f"retry {counter!r}: limit must be >= 0, got {limit}")
        mask = self._mask(mask)
        count = self.retries.setdefault(counter, np.zeros(self.num_envs, dtype=np.int64))
        allowed = mask & (count < limit)
        count[allowed] += 1
        self.goto(target, allowed)
        return allowed

    def retry_count(self, counter: str) -> np.ndarray:
        """(N,) how often ``counter`` sent each environment back since its last reset."""
        return self.retries.get(counter, np.zeros(self.num_envs, dtype=np.int64)).copy()

    # -- snapshots ---------------------------------------------------------------------------
    def snapshot(self, name: str, values, mask) -> None:
        """Store ``values`` ((N, ...) array) for the environments in ``mask``."""
        values = np.asarray(values, float)
        if values.shape[0] != self.num_envs:
            raise ValueError(f"snapshot {name!r} needs {self.num_envs} rows, got {values.shape}")
        if name not in self.snapshots:
            self.snapshots[name] = np.full(values.shape, np.nan)
        mask = self._mask(mask)
        self.snapshots[name][mask] = values[mask]

    def get(self, name: str) -> np.ndarray:
        """(N, ...) snapshot ``name`` (NaN rows where never taken since the last reset)."""
        return self.snapshots[name]


def unwrap_envs(env_or_envs) -> list:
    """The ``WireCraftEnv`` instances behind a gymnasium env, a WireCraft vector env or a list."""
    if hasattr(env_or_envs, "envs"):
        return [e.unwrapped for e in env_or_envs.envs]
    if isinstance(env_or_envs, (list, tuple)):
        return [e.unwrapped for e in env_or_envs]
    return [env_or_envs.unwrapped]


def step_toward(start: np.ndarray, goal: np.ndarray, max_step: float) -> np.ndarray:
    """``goal``, or the point ``max_step`` from ``start`` on the way to it."""
    delta = goal - start
    dist = norm(delta)
    return goal if dist <= max_step else start + delta * (max_step / dist)
