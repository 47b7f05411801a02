"""The vector environment's physics on MuJoCo Warp (``make_vec(..., backend="warp")``).

``WarpBatch`` offers the part of ``mujoco.batch.Batch``'s interface that
``WireCraftVectorEnv`` uses (state rows, ``bind``, ``step``, ``forward``, ``get_data``), so
the controller, the tasks, autoreset and divergence handling are the CPU backend's own code.
The physics of all worlds steps on the Warp device; what crosses to the host is the minimal
set the step needs: the state rows (``mjSTATE_INTEGRATION``: the controls go up, the new state
comes back, so that divergence roll-backs and resets work on rows as on the CPU) and the
derived fields the task and controller read (``Frame``'s), each call.  ``bytes_per_step``
says how many.

Warp is not bitwise deterministic and runs in float32 where MuJoCo's C code runs in float64:
parity with the CPU backend is statistical (tests/test_warp_backend.py names the tolerances).
``njmax`` / ``nconmax`` (constraint rows / contacts per world) are fixed at construction; an
overflow raises ``WarpOverflow`` instead of dropping constraints silently.  (An ``njmax``
below what a world needs, 20 and once even 30 for 31 rows, crashed MuJoCo Warp 4.0.0's CPU
device with a segmentation fault before any flag could be read: leave the defaults' margin.)

Models: MuJoCo Warp refuses ``mjDSBL_AUTORESET`` (it never resets a world itself, which is
what the flag asks of MuJoCo's C code), so it is cleared on the device's copy.

Solver: Newton, as on the CPU, with a fallback.  Newton factorizes ``M + J' D J`` by Cholesky,
and on our scenes that matrix can be too ill-conditioned for float32: a light plug (smallest
inertia eigenvalue 1.6e-7) striking the table with stiff contacts gave a condition number of
2e9, the float32 Cholesky failed and the step returned NaN where MuJoCo's C code (float64)
steps the same state.  A world whose state is not finite after a Newton step is stepped again
from the same state with the conjugate-gradient solver, which needs no factorization;
``cg_fallbacks`` counts those world-steps.  A world that is still not finite is left so, for
the vector environment's divergence handling.  ``solver="cg"`` runs CG throughout, and MuJoCo
Warp refuses Newton with general flex attachments (the rod's clamped ends), so that model runs
CG.  CG runs with up to ``CG_ITERATIONS`` iterations, not the model's 100: at 100 it stopped
short of convergence and the episodes drifted from the CPU backend's (the rod's observation by
0.65 after the reset; 1.4e-3 at 1,000).
"""

from __future__ import annotations

import mujoco
import numpy as np

from wirecraft.envs.env import STATE_SPEC

# Where each component of an mjSTATE_INTEGRATION row lives in MjData (and in Warp's Data).
STATE_FIELDS = (
    (mujoco.mjtState.mjSTATE_TIME, "time"),
    (mujoco.mjtState.mjSTATE_QPOS, "qpos"),
    (mujoco.mjtState.mjSTATE_QVEL, "qvel"),
    (mujoco.mjtState.mjSTATE_ACT, "act"),
    (mujoco.mjtState.mjSTATE_HISTORY, "history"),
    (mujoco.mjtState.mjSTATE_WARMSTART, "qacc_warmstart"),
    (mujoco.mjtState.mjSTATE_CTRL, "ctrl"),
    (mujoco.mjtState.mjSTATE_QFRC_APPLIED, "qfrc_applied"),
    (mujoco.mjtState.mjSTATE_XFRC_APPLIED, "xfrc_applied"),
    (mujoco.mjtState.mjSTATE_EQ_ACTIVE, "eq_active"),
    (mujoco.mjtState.mjSTATE_MOCAP_POS, "mocap_pos"),
    (mujoco.mjtState.mjSTATE_MOCAP_QUAT, "mocap_quat"),
    (mujoco.mjtState.mjSTATE_USERDATA, "userdata"),
    (mujoco.mjtState.mjSTATE_PLUGIN, "plugin_state"),
    (mujoco.mjtState.mjSTATE_PLASTIC, "plastic"),
)
DEFAULT_NCONMAX = 256  # contacts per world
DEFAULT_NJMAX = 1024  # constraint rows per world
CG_ITERATIONS = 1000  # the cap on CG's iterations (it stops earlier once converged)
SOLVERS = {"cg": mujoco.mjtSolver.mjSOL_CG, "newton": mujoco.mjtSolver.mjSOL_NEWTON}


class WarpOverflow(RuntimeError):
    """More contacts or constraint rows than ``nconmax`` / ``njmax`` in some world."""


def warp_modules():
    """(warp, mujoco_warp), or an error naming the extra that installs them."""
    try:
        import mujoco_warp
        import warp
    except ImportError as err:
        raise RuntimeError(
            f"backend='warp' needs MuJoCo Warp ({err}); install it with: pip install "
            "'wirecraft[gpu]' (or make gpu)"
        ) from None
    warp.config.quiet = True
    return warp, mujoco_warp


class WarpBatch:
    """``nsim`` worlds of ``model`` on the Warp ``device`` (see the module docstring)."""

    def __init__(
        self,
        model: mujoco.MjModel,
        nsim: int,
        device: str | None = None,
        nconmax: int = DEFAULT_NCONMAX,
        njmax: int = DEFAULT_NJMAX,
        solver: str = "newton",
    ) -> None:
        if solver not in SOLVERS:
            raise ValueError(f"unknown Warp solver {solver!r}; valid: {', '.join(SOLVERS)}")
        wp, mjw = warp_modules()
        self._wp, self._mjw = wp, mjw
        try:
            self.device = str(wp.get_device(device))
        except ValueError as err:
            raise ValueError(
                f"backend='warp': device {device!r}: {err} (e.g. cuda:0, cpu)"
            ) from None
        self.model, self.nsim = model, int(nsim)
        self.nconmax, self.njmax = int(nconmax), int(njmax)
        # Not forwarded: put_data sizes nothing after its contacts (all bodies at the origin
        # would overlap); the first call uploads the real states.
        template = mujoco.MjData(model)
        self._template = template
        flags, model_solver = model.opt.disableflags, model.opt.solver
        model.opt.disableflags = flags & ~int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
        model.opt.solver = SOLVERS[solver]
        try:
            with wp.ScopedDevice(self.device):
                try:
                    self._wm = mjw.put_model(model)
                except ValueError as err:
                    if "requires solver='CG'" not in str(err):
                        raise
                    model.opt.solver = mujoco.mjtSolver.mjSOL_CG
                    self._wm = mjw.put_model(model)
                try:
                    self._wd = mjw.put_data(
                        model, template, nworld=self.nsim, nconmax=self.nconmax, njmax=self.njmax
                    )
                except RuntimeError as err:
                    if "Failed to allocate" not in str(err):
                        raise
                    raise MemoryError(
                        f"{self.nsim} worlds do not fit on {self.device}: {err}"
                    ) from None
                pristine = mjw.put_data(
                    model, template, nworld=1, nconmax=self.nconmax, njmax=self.njmax
                )
        finally:
            model.opt.disableflags, model.opt.solver = flags, model_solver
        self.solver = next(k for k, v in SOLVERS.items() if int(v) == int(self._wm.opt.solver))
        if self.solver == "cg":
            self._wm.opt.iterations = max(int(self._wm.opt.iterations), CG_ITERATIONS)
        self.cg_fallbacks = 0
        # The solver's iteration limit is counted (solver_limit_hits), not printed per step.
        iterations = int(mjw.OverflowType.ITERATIONS)
        self._wm.opt.warn_overflow = int(self._wm.opt.warn_overflow) & ~iterations
        self.solver_limit_hits = 0
        self._per_world = [  # (device array, its one-world pristine copy), for _scrub
            (array, getattr(group_of(pristine), name))
            for group_of in (lambda data: data, lambda data: data.efc)
            for name, array in vars(group_of(self._wd)).items()
            if isinstance(array, wp.array) and array.ndim and array.shape[0] == self.nsim
        ]
        self._tainted = np.zeros(self.nsim, bool)  # worlds whose device fields may hold NaN
        self._non_finite = np.zeros(self.nsim, bool)  # rows the last download found so
        # State rows and where each component sits in them.
        self._components = []
        offset = 0
        for bit, name in STATE_FIELDS:
            if not int(STATE_SPEC) & int(bit):
                continue
            size = mujoco.mj_stateSize(model, bit)
            if size:
                if getattr(self._wd, name, None) is None:
                    raise NotImplementedError(
                        f"backend='warp': MuJoCo Warp keeps no {name!r}, which this model's "
                        "state holds"
                    )
                self._components.append((name, offset, size))
            offset += size
        self.state = np.empty((self.nsim, offset))
        row = np.empty(offset)
        mujoco.mj_getState(model, template, row, STATE_SPEC)
        self.state[:] = row
        self._before = np.empty_like(self.state)
        self._outputs: dict[str, np.ndarray] = {}
        self.bytes_up = self.state.nbytes
        self.bytes_down = self.state.nbytes

    # -- the Batch interface the vector environment uses ----------------------------------------
    def bind(self, name: str) -> np.ndarray:
        """A live (nsim, ...) array of ``name``: a view of the state rows for a state field,
        else the host copy of a derived field, refreshed after every call."""
        for field, offset, size in self._components:
            if field == name:
                view = self.state[:, offset : offset + size]
                return view[:, 0] if name == "time" else view.reshape(self.nsim, *self._shape(name))
        if name not in self._outputs:
            shape = getattr(self._template, name).shape
            out = np.zeros((self.nsim, *shape))
            self._outputs[name] = out
            self.bytes_down += out.nbytes
            self._download_outputs([name])
        return self._outputs[name]

    def step(self, ids=None, nstep: int = 1, stage=None) -> None:
        """``nstep`` steps of the worlds ``ids`` (default all), then the position stage at the
        new state (``_positions``, whatever ``stage``); a world that Newton left non-finite is
        stepped again with CG (module docstring).  The other worlds keep their state and
        fields."""
        keep = self._others(ids)
        before = self._before
        np.copyto(before, self.state)  # for the retry and the worlds kept (no allocation)
        saved = {k: v[keep].copy() for k, v in self._outputs.items()}
        self._run(nstep)
        failed = np.setdiff1d(np.flatnonzero(self._non_finite), keep)
        if failed.size and self.solver == "newton":
            self._retry_with_cg(failed, before, nstep)
        if keep.size:
            self.state[keep] = before[keep]
            for name, values in saved.items():
                self._outputs[name][keep] = values

    def forward(self, ids=None, stage=None) -> None:
        """The position-stage fields of the current states of the worlds ``ids`` (default
        all)."""
        keep = self._others(ids)
        saved = {k: v[keep].copy() for k, v in self._outputs.items()}
        self._upload()
        with self._wp.ScopedDevice(self.device):
            self._positions()
        self._download_outputs(self._outputs)
        for name, values in saved.items():
            self._outputs[name][keep] = values

    def get_data(self, sim: int, data: mujoco.MjData) -> None:
        """World ``sim`` as an MjData: its state, and MuJoCo's own forward pass at it (what
        experts and renderers read)."""
        mujoco.mj_setState(self.model, data, self.state[sim], STATE_SPEC)
        mujoco.mj_forward(self.model, data)

    def physics_only(self, nstep: int) -> None:
        """``nstep`` steps of every world on the device from whatever it holds, nothing
        crossing to the host, and wait for them: raw MuJoCo Warp physics, for benchmarks.
        The host's state rows are left as they were (the next call uploads them)."""
        with self._wp.ScopedDevice(self.device):
            self._substeps(nstep)
            self._wp.synchronize_device(self.device)

    @property
    def device_name(self) -> str:
        """The device's own name (the GPU's model, or "CPU")."""
        return self._wp.get_device(self.device).name

    @property
    def bytes_per_step(self) -> int:
        """Bytes crossing between host and device in one step: state rows up, state rows and
        the bound derived fields down."""
        return self.bytes_up + self.bytes_down

    # -- internals --------------------------------------------------------------------------
    def _run(self, nstep: int) -> None:
        """Upload the state rows, ``nstep`` steps and the position stage in every world,
        download the state rows and the bound fields."""
        self._upload()
        with self._wp.ScopedDevice(self.device):
            self._substeps(nstep)
            self._positions()
        self._check_overflow()
        self._download_state()
        self._download_outputs(self._outputs)

    def _substeps(self, nstep: int) -> None:
        for _ in range(nstep):
            self._mjw.step(self._wm, self._wd)

    def _retry_with_cg(self, worlds: np.ndarray, before: np.ndarray, nstep: int) -> None:
        """Step ``worlds`` again from ``before`` with CG; the other worlds keep Newton's
        result."""
        newton_state = self.state.copy()
        newton_outputs = {k: v.copy() for k, v in self._outputs.items()}
        options = self._wm.opt
        solver, iterations = options.solver, options.iterations
        options.solver, options.iterations = self._mjw.SolverType.CG, CG_ITERATIONS
        try:
            self.state[:] = before
            self._run(nstep)
        finally:
            options.solver, options.iterations = solver, iterations
        others = np.setdiff1d(np.arange(self.nsim), worlds)
        self.state[others] = newton_state[others]
        for name, values in newton_outputs.items():
            self._outputs[name][others] = values[others]
        self.cg_fallbacks += worlds.size

    def _positions(self) -> None:
        """Kinematics, contacts and position sensors (contact flags) at the current state:
        what the controller and the task read.  Not the velocity stage: run between steps,
        MuJoCo Warp 4.0.0's ``fwd_velocity`` (and ``forward``, which calls it) left the next
        step finding no contacts, and the worlds went to NaN within a few steps."""
        self._mjw.fwd_position(self._wm, self._wd)
        self._mjw.sensor_pos(self._wm, self._wd)

    def _others(self, ids) -> np.ndarray:
        if ids is None or (isinstance(ids, slice) and ids == slice(None)):
            return np.zeros(0, int)
        chosen = np.zeros(self.nsim, bool)
        chosen[np.asarray(ids, dtype=int)] = True
        return np.flatnonzero(~chosen)

    def _scrub(self, worlds: np.ndarray) -> None:
        """Give ``worlds`` the derived fields of a fresh world.  A world that went non-finite
        leaves NaN in fields the next step reads before writing (MuJoCo Warp 4.0.0 keeps the
        world body's ``xpos``, ``cvel`` and ``cdof_dot`` from step to step), so a new state
        alone would still step to NaN."""
        for array, pristine in self._per_world:
            size = pristine.size
            for world in worlds:
                self._wp.copy(array, pristine, dest_offset=int(world) * size, count=size)

    def _upload(self) -> None:
        wp = self._wp
        if self._tainted.any():
            renewed = self._tainted & np.isfinite(self.state).all(axis=1)
            self._scrub(np.flatnonzero(renewed))
            self._tainted &= ~renewed
        for name, offset, size in self._components:
            target = getattr(self._wd, name)
            values = self.state[:, offset : offset + size]
            shape = (self.nsim,) if name == "time" else (self.nsim, *self._shape(name))
            scalar = wp.dtype_to_numpy(getattr(target.dtype, "_wp_scalar_type_", target.dtype))
            target.assign(values.reshape(shape).astype(scalar))

    def _download_state(self) -> None:
        for name, offset, size in self._components:
            values = getattr(self._wd, name).numpy()
            self.state[:, offset : offset + size] = values.reshape(self.nsim, size)
        self._non_finite = ~np.isfinite(self.state).all(axis=1)
        self._tainted |= self._non_finite

    def _download_outputs(self, names) -> None:
        for name in names:
            out = self._outputs[name]
            out[:] = getattr(self._wd, name).numpy().reshape(out.shape)

    def _shape(self, name: str) -> tuple[int, ...]:
        return getattr(self._template, name).shape

    def _check_overflow(self) -> None:
        """Raise where a world ran out of contact or constraint room; Warp would otherwise
        drop them and print a warning.  Worlds whose solver stopped at its iteration limit
        are counted in ``solver_limit_hits`` (one per world and call)."""
        overflow = self._wd.overflow.numpy()
        iterations = int(self._mjw.OverflowType.ITERATIONS)
        limited = overflow & iterations != 0
        if limited.any():
            self.solver_limit_hits += int(limited.sum())
            self._wd.overflow.assign(overflow & ~iterations)
        worlds = np.flatnonzero(overflow & ~iterations)
        if worlds.size:
            kinds = self._mjw.OverflowType(int(np.bitwise_or.reduce(overflow[worlds])))
            self._wd.overflow.zero_()
            raise WarpOverflow(
                f"MuJoCo Warp ran out of room in worlds {worlds.tolist()} ({kinds!r}) with "
                f"nconmax={self.nconmax} contacts and njmax={self.njmax} constraint rows per "
                "world; make the vector env with larger warp_nconmax / warp_njmax"
            )
