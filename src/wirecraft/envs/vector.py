"""Many environments of one task on one compiled model, their physics stepped on C threads.

``WireCraftVectorEnv`` keeps one ``WireCraftEnv`` per environment (clones sharing the model:
each its own MjData, controller targets, task state and random generator).  Per-environment
randomization (poses, port and clip placement, channel shape, wire state) is state, so nothing
is rebuilt.

Seeds: ``reset(seed=s)`` gives environment i the seed derived from (s, i) alone, so
environment i sees the same episodes whatever ``num_envs`` and ``threads`` are.

A step runs once on (num_envs, ...) arrays: the controllers (``ControlState``), the physics
(``mujoco.batch.Batch``, bit-identical to a loop of ``mj_step`` at any thread count), then the
task's latch logic, reward, success and state observation on a ``Frame`` of the batch's bound
fields, with the same code a single environment runs for N = 1, so episodes stay
bit-identical.  The batch's state rows are the environments' state.  With ``sync_envs=True``
(the default) each environment's ``MjData``, controller targets and task trackers are brought
up to date after every step (``Batch.get_data``), and what is written into them between steps
(an external force, a placed plug) is taken into the batch before the next, so ``envs[i]``
behaves as a single environment; ``sync_envs=False`` skips both per-environment copies, for
consumers that only call ``step`` and read what it returns (RL training).  Image observations
are rendered from each synced environment's ``MjData``.

Autoreset: gymnasium's SAME_STEP mode.  An environment whose episode ends (time limit or
divergence) is reset within the same ``step``; its last observation and info are in
``infos["final_obs"]`` / ``infos["final_info"]``, masked by ``infos["_final_obs"]``.  A
diverged environment is rolled back, flagged (``diverged``) and reset while the others go on.
``step`` before every environment was reset raises ``gymnasium.error.ResetNeeded``.
"""

from __future__ import annotations

import os

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv, VectorWrapper
from gymnasium.vector.utils import batch_space, create_empty_array
from mujoco.batch import Batch, SimulationError

from wirecraft import BACKENDS, validation
from wirecraft.control import ControlState
from wirecraft.envs.env import (
    STATE_SPEC,
    SUBSTEPS,
    WireCraftEnv,
    as_actions,
    check_options,
    check_seed,
    spec_with_length,
    within_limits,
)
from wirecraft.tasks.base import weighted_reward
from wirecraft.tasks.frame import Frame

ACC = mujoco.mjtStage.mjSTAGE_ACC.value
VEL = mujoco.mjtStage.mjSTAGE_VEL.value
MAX_NUM_ENVS = 65536
# Resident memory of one environment (its MjData, the batch's, Python objects), an upper
# bound of what was measured: 1.7 MiB (articulated wire), 3.6 MiB (fem).
ENV_BYTES = 2**20
ENV_BYTES_PER_DATA_BYTE = 8


def physical_memory() -> int:
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def env_seed(seed: int, index: int) -> int:
    """The seed of environment ``index`` under vector seed ``seed``: independent of the number
    of environments."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1)[0])


class WireCraftVectorEnv(VectorEnv):
    def __init__(
        self,
        task: str,
        num_envs: int,
        *,
        threads: int = 0,
        sync_envs: bool = True,
        backend: str = "cpu",
        device: str | None = None,
        warp_nconmax: int | None = None,
        warp_njmax: int | None = None,
        warp_solver: str | None = None,
        **kwargs,
    ) -> None:
        validation.int_in_range("make_vec", "num_envs", num_envs, 1, MAX_NUM_ENVS)
        cpus = os.cpu_count() or 1
        validation.int_in_range("make_vec", "threads", threads, 0, cpus, f"0: all {cpus} CPUs")
        validation.boolean("make_vec", "sync_envs", sync_envs)
        if kwargs.get("render_mode") == "human":
            raise ValueError("make_vec: render_mode='human' is for single environments")
        first = WireCraftEnv(task, **kwargs)
        needed = num_envs * (ENV_BYTES + ENV_BYTES_PER_DATA_BYTE * first.data.nbuffer)
        if needed > physical_memory():
            raise MemoryError(
                f"make_vec: num_envs={num_envs} needs about {needed / 2**30:.1f} GiB, more than "
                f"this machine's {physical_memory() / 2**30:.1f} GiB of memory"
            )
        self.envs = [first] + [first.clone() for _ in range(num_envs - 1)]
        self.model = first.model
        self.num_envs = num_envs
        self.threads = threads
        validation.one_of("make_vec", "backend", backend, BACKENDS)
        warp_sizes = {"nconmax": warp_nconmax, "njmax": warp_njmax}
        warp_sizes = {k: v for k, v in warp_sizes.items() if v is not None}
        for name, value in warp_sizes.items():
            validation.int_in_range("make_vec", f"warp_{name}", value, 1, 10**7)
        if warp_solver is not None:  # WarpBatch checks the name
            warp_sizes["solver"] = warp_solver
        if backend == "warp":
            from wirecraft.envs.warp_batch import WarpBatch

            self.batch = WarpBatch(self.model, num_envs, device, **warp_sizes)
        else:
            if device is not None or warp_sizes:
                given = ["device"] * (device is not None) + [f"warp_{k}" for k in warp_sizes]
                raise ValueError(f"make_vec: {', '.join(given)} is for backend='warp' only")
            # Persistent: each simulation keeps its MjData, so the forward pass that brings
            # derived quantities up to date after a step runs on the batch's threads and
            # get_data hands the whole result back (cheaper than mj_setState + mj_forward per
            # environment in Python).
            self.batch = Batch(self.model, num_envs, nthread=threads, persistent=True)
        self.backend = backend
        self._ctrl = self.batch.bind("ctrl")
        self.frame = Frame.of_batch(self.batch)  # the batched step's and the settle's view
        self.single_observation_space = first.observation_space
        self.single_action_space = first.action_space
        self.observation_space = batch_space(first.observation_space, num_envs)
        self.action_space = batch_space(first.action_space, num_envs)
        self.metadata = {**first.metadata, "autoreset_mode": AutoresetMode.SAME_STEP}
        self.render_mode = first.render_mode
        self._obs = create_empty_array(self.single_observation_space, num_envs)
        self._needs_reset = np.ones(num_envs, bool)
        self._spec = None
        # Images are rendered from each environment's own MjData.
        self.images = first.obs_mode != "state"
        if self.images and not sync_envs:
            raise ValueError(
                f"make_vec: sync_envs=False needs obs_mode='state' (got {first.obs_mode!r}): "
                "image observations are rendered from each environment's synced MjData"
            )
        self.sync_envs = bool(sync_envs)
        self._renderer = None
        if self.images or self.render_mode == "rgb_array":
            from wirecraft.render import FastRenderer

            # One renderer draws every environment: they share the model, so one OpenGL
            # context holds its meshes once, and no context switches between images.
            self._renderer = FastRenderer(self.model, first.image_size, first.image_size)
            for env in self.envs:
                env.use_renderer(self._renderer)
        self.controls = ControlState.gather([env.controller for env in self.envs])
        self.trackers = {
            name: np.full(num_envs, value) for name, value in first.task.trackers.items()
        }
        self.steps = np.zeros(num_envs, int)
        self._incoming = np.empty_like(self.batch.state)
        # After the substeps the batch computes the new state's positions, contacts and
        # contact flags (position stage; velocities too, which its next step reuses, so this
        # costs nothing).  Constraint forces and acceleration-stage sensors need a full forward
        # pass: for the diagnostics and for synced environments (experts read the wrist
        # force), in the batch; otherwise only for the environments that need them (an
        # engaged latch's force), on their own MjData.
        full = first.diagnostics or self.sync_envs
        self._end_stage = ACC if full else VEL

    # -- gymnasium vector API ---------------------------------------------------------------
    def reset(self, *, seed=None, options: dict | None = None):
        self._check_open("reset")
        options = check_options("WireCraftVectorEnv.reset", options, ("reset_mask",))
        mask = np.ones(self.num_envs, bool)
        if "reset_mask" in options:
            mask = np.asarray(options["reset_mask"])
            if mask.dtype != bool or mask.shape != (self.num_envs,):
                raise ValueError(
                    f"WireCraftVectorEnv.reset: options['reset_mask'] must be {self.num_envs} "
                    f"booleans, got {options['reset_mask']!r}"
                )
        seeds = self._seeds(seed)
        ids = np.flatnonzero(mask)
        infos = {}
        for i, (obs, info) in self._reset_envs(ids, [seeds[i] for i in ids]).items():
            self._write_obs(i, obs)
            infos = self._add_info(infos, info, i)
        self._load_rows(ids)
        self._needs_reset[ids] = False
        return self._obs_copy(), infos

    def step(self, actions):
        self._check_open("step")
        if self._needs_reset.any():
            raise gym.error.ResetNeeded(
                "WireCraftVectorEnv.step: call reset() first; environments "
                f"{np.flatnonzero(self._needs_reset).tolist()} were never reset"
            )
        actions = as_actions("actions", actions, self.action_space.shape)
        bad = np.flatnonzero(~np.all(np.isfinite(actions), axis=1))
        if bad.size:
            raise ValueError(f"actions of environments {bad.tolist()} contain NaN or inf")
        return self._step(actions)

    def set_states(self, ids, states: list[dict]):
        """Put environments ``ids`` into ``states`` (``WireCraftEnv.get_state`` snapshots, e.g.
        of another run of the same task and model) between steps; returns the observations of
        those environments, (len(ids), ...), also written into the next step's batch."""
        ids = [int(i) for i in ids]
        if len(ids) != len(states):
            raise ValueError(f"set_states: {len(ids)} ids for {len(states)} states")
        for i, state in zip(ids, states, strict=True):
            if not 0 <= i < self.num_envs:
                raise ValueError(f"set_states: no environment {i} of {self.num_envs}")
            self.envs[i].set_state(state)
            self._needs_reset[i] = False
            self._write_obs(i, self.envs[i].observe())
        self._load_rows(ids)
        obs = self._obs_copy()
        if isinstance(obs, dict):
            return {k: v[ids] for k, v in obs.items()}
        return obs[ids]

    # -- attributes of the environments -----------------------------------------------------
    @property
    def spec(self):
        """gymnasium's ``EnvSpec`` (set by ``gymnasium.make_vec``), its ``max_episode_steps``
        the environments' episode length."""
        return spec_with_length(self._spec, self.envs[0].max_steps)

    @spec.setter
    def spec(self, spec) -> None:
        self._spec = spec

    @property
    def task_description(self) -> tuple[str, ...]:
        """Each environment's language instruction (also ``infos["instruction"]``)."""
        return tuple(env.task_description for env in self.envs)

    def call(self, name: str, *args, **kwargs) -> tuple:
        """Each environment's attribute ``name``, called with ``args`` where it is a method (as
        gymnasium's SyncVectorEnv.call; e.g. ``call("task_description")``)."""
        if not self.sync_envs:
            for i in range(self.num_envs):
                self._sync_env(i)
        results = []
        for env in self.envs:
            value = getattr(env, name)
            results.append(value(*args, **kwargs) if callable(value) else value)
        return tuple(results)

    def get_attr(self, name: str) -> tuple:
        """Each environment's attribute ``name``."""
        return tuple(getattr(env, name) for env in self.envs)

    def _check_open(self, call: str) -> None:
        if self.closed:
            raise gym.error.ClosedEnvironmentError(
                f"WireCraftVectorEnv.{call}: the environment is closed; make a new one"
            )

    def close_extras(self, **kwargs) -> None:
        for env in self.envs:
            env.close()
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def render(self):
        if not self.sync_envs:
            for i in range(self.num_envs):
                self._sync_env(i)
        return tuple(env.render() for env in self.envs)

    # -- the step ---------------------------------------------------------------------------
    def _load_rows(self, ids, *, only_changed: bool = False) -> None:
        """Make the batch rows ``ids`` the state of those environments: their MjData,
        controller targets, task trackers and step counts (after a reset, or anything written
        into them between steps).  ``only_changed``: recompute derived fields only for rows
        whose physics state differs from the batch's."""
        ids = np.asarray(ids, dtype=int)
        if not ids.size:
            return
        incoming = self._incoming[: ids.size]
        for k, i in enumerate(ids):
            env = self.envs[i]
            mujoco.mj_getState(self.model, env.data, incoming[k], STATE_SPEC)
            self.controls.load(i, env.controller)
            for name, values in self.trackers.items():
                values[i] = getattr(env.task, name)
            self.steps[i] = env.elapsed_steps
        if only_changed:
            differs = np.any(incoming != self.batch.state[ids], axis=1)
            ids, incoming = ids[differs], incoming[differs]
            if not ids.size:
                return
        self.batch.state[ids] = incoming
        self.batch.forward(ids, stage=ACC)  # derived fields of the new states

    def _step(self, actions):
        first, frame, n = self.envs[0], self.frame, self.num_envs
        task = first.task
        clipped = np.clip(actions, -1.0, 1.0)
        if self.sync_envs:  # environments mirror the batch: adopt what was written into them
            self._load_rows(np.arange(n), only_changed=True)
        before = self.batch.state.copy()
        controls_before = self.controls.copy()
        trackers_before = {name: values.copy() for name, values in self.trackers.items()}

        self._write_controls(slice(None), self.controls, clipped)

        bad = np.zeros(n, bool)
        try:
            self.batch.step(nstep=SUBSTEPS, stage=self._end_stage)
        except SimulationError as err:
            bad[np.asarray(err.ids, dtype=int)] = True
        self.steps += 1
        bad |= ~within_limits(frame.qpos, frame.qvel, first.speed_limits)
        diverged = np.flatnonzero(bad)
        if diverged.size:  # roll those back; the others go on untouched
            self.batch.state[diverged] = before[diverged]
            self.controls.restore(diverged, controls_before)
            self.batch.forward(diverged, stage=ACC)

        frame.cache.clear()  # new positions
        synced = np.zeros(n, bool)
        eq_stepped = frame.eq_active.copy()  # before the task engages or releases latches
        forwarded = self._end_stage == ACC

        def data_of(i):
            """Environment i's MjData, brought up to this step (once), its forward pass run
            with the flags the physics stepped with, as a single environment's is."""
            data = self.envs[i].data
            if not synced[i]:
                self.batch.get_data(i, data)
                data.eq_active[:] = eq_stepped[i]
                if not forwarded and not bad[i]:
                    mujoco.mj_forward(self.model, data)
                synced[i] = True
            data.eq_active[:] = frame.eq_active[i]  # the task may have just changed it
            return data

        task.after_step_batch(frame, self.trackers, ~bad, data_of)
        terms = task.reward_batch(frame, self.trackers, clipped)
        weighted, rewards = weighted_reward(terms, task.weights)
        core = task.evaluate_batch(frame, data_of)
        state_obs = None if self.images else task.observe_batch(frame)
        for name, values in self.trackers.items():
            values[diverged] = trackers_before[name][diverged]

        # Environments' own MjData, controller and task follow the batch: all of them (experts,
        # renderers and snapshots read them), or those the step reports per environment.
        for i in range(n) if self.sync_envs else diverged:
            self._sync_env(i, data_of)
        if self.images:
            for i, env in enumerate(self.envs):
                self._write_obs(i, env.observe())
        else:
            self._obs[:] = state_obs

        infos: dict = {name: np.array(values) for name, values in core.items()}
        infos["instruction"] = np.array([env.task.instruction for env in self.envs], object)
        if first.diagnostics:
            rows = [env.task.diagnostics(self.model, data_of(i)) for i, env in enumerate(self.envs)]
            for name in rows[0]:
                infos[name] = np.array([row[name] for row in rows], dtype=float)
        infos["diverged"] = bad.copy()
        for name, values in weighted.items():
            infos[f"reward/{name}"] = np.array(values)
        rewards = np.where(bad, 0.0, rewards)
        for i in diverged:  # as a single environment reports a rolled-back step
            env = self.envs[i]
            if not self.images:
                self._write_obs(i, env.observe())
            for name, value in {**env.info_without_reward(), "diverged": True}.items():
                infos[name][i] = value
        step_keys = list(infos)
        for name in step_keys:
            infos[f"_{name}"] = np.ones(n, bool)

        truncations = (self.steps >= first.max_steps) | bad
        done = np.flatnonzero(truncations)
        for i in done:  # SAME_STEP autoreset: report the final step, start the next episode
            final_info = {name: _item(infos[name][i]) for name in step_keys}
            infos = self._add_info(
                infos, {"final_obs": self._obs_row(i), "final_info": final_info}, i
            )
        for i, (new_obs, reset_info) in self._reset_envs(done).items():
            self._write_obs(i, new_obs)
            infos = self._add_info(infos, {f"reset/{k}": v for k, v in reset_info.items()}, i)
        self._load_rows(done)
        terminations = np.zeros(n, bool)
        return self._obs_copy(), rewards, terminations, truncations, infos

    def _sync_env(self, i: int, data_of=None) -> None:
        env = self.envs[i]
        if data_of is None:
            self.batch.get_data(i, env.data)
        else:
            data_of(i)
        self.controls.store(i, env.controller)
        env.task.store_trackers(self.trackers, i)
        env.elapsed_steps = int(self.steps[i])

    # -- internals --------------------------------------------------------------------------
    def _reset_envs(self, ids, seeds=None) -> dict[int, tuple]:
        """Reset environments ``ids`` (with ``seeds``, or continuing their generators): bit for
        bit what each one's own ``reset`` gives, but their settle steps run together in the
        batch, on its threads.  Returns {id: (obs, info)}."""
        ids = [int(i) for i in ids]
        for k, i in enumerate(ids):
            self.envs[i].seed_episode(None if seeds is None else seeds[k])
        attempts = dict.fromkeys(ids, 1)
        pending = ids
        while pending:
            for i in pending:
                self.envs[i].start_episode()
            pending = self._settle_together(pending)
            for i in pending:
                self.envs[i].check_reset_attempt(attempts[i])
                attempts[i] += 1
        return {i: self.envs[i].finish_reset(attempts[i]) for i in ids}

    def _settle_together(self, ids: list[int]) -> list[int]:
        """The settle steps of the new episodes of ``ids``, all in the batch: the controllers
        hold still through the batched ``compute`` (the batched step's code, bit-identical to
        each controller's own ``apply``), the physics steps on the batch's threads.  Returns
        the ids that diverged."""
        if not ids:
            return []
        model, state = self.model, self.batch.state
        first, frame = self.envs[ids[0]], self.frame
        rows = np.array(ids)
        for i in ids:
            mujoco.mj_getState(model, self.envs[i].data, state[i], STATE_SPEC)
        self.batch.forward(rows, stage=VEL)  # positions for the first step's kinematics
        controls = ControlState.gather([self.envs[i].controller for i in ids])
        hold = np.tile(first.settle_action, (len(ids), 1))
        alive = np.ones(len(ids), bool)
        for _ in range(first.settle_steps):
            live = rows[alive]
            held = controls if alive.all() else controls.rows(alive)
            self._write_controls(live, held, hold[alive])
            if held is not controls:
                controls.set_rows(alive, held)
            failed = np.zeros(len(ids), bool)
            try:
                self.batch.step(live, nstep=SUBSTEPS, stage=VEL)
            except SimulationError as err:
                failed = np.isin(rows, np.asarray(err.ids, dtype=int))
            healthy = within_limits(frame.qpos[rows], frame.qvel[rows], first.speed_limits)
            alive &= healthy & ~failed
            if not alive.any():
                break
        frame.cache.clear()
        for k, i in enumerate(ids):
            env = self.envs[i]
            # The state alone: finish_reset runs the forward pass for the rest.
            mujoco.mj_setState(model, env.data, state[i], STATE_SPEC)
            controls.store(k, env.controller)
        return [i for i, ok in zip(ids, alive, strict=True) if not ok]

    def _write_controls(self, rows, controls: ControlState, actions) -> None:
        """Servo targets of the environments ``rows`` (an index array, or ``slice(None)`` for
        all) from their ``controls`` and clipped ``actions``, computed at once from the batch's
        current positions and written to its ``ctrl`` (bit-identical to each controller's own
        ``apply``)."""
        controller = self.envs[0].controller
        index, frame = controller.index, self.frame
        kinematics = None
        if controller.needs_kinematics:
            tcp = frame.site_xpos[rows, index.tcp_site]
            jac = controller.tcp_jacobian(frame.cdof[rows], frame.subtree_com[rows], tcp)
            kinematics = (tcp, frame.rot("site_xmat", index.tcp_site)[rows], jac)
        q = frame.qpos[rows][:, index.arm_qpos]
        arm = controller.compute(controls, q, kinematics, actions)
        self._ctrl[rows if isinstance(rows, slice) else rows[:, None], index.arm_act] = arm
        self._ctrl[rows, index.gripper_act] = controls.gripper_target

    def _seeds(self, seed) -> list[int | None]:
        owner = "WireCraftVectorEnv.reset"
        if seed is None:
            return [None] * self.num_envs
        if not isinstance(seed, (list, tuple, np.ndarray)):
            seed = check_seed(owner, seed)
            return [env_seed(seed, i) for i in range(self.num_envs)]
        seeds = [check_seed(owner, s) for s in seed]
        if len(seeds) != self.num_envs:
            raise ValueError(f"{owner}: {len(seeds)} seeds for {self.num_envs} environments")
        return seeds

    def _write_obs(self, index: int, obs) -> None:
        if isinstance(self._obs, dict):
            for key, value in obs.items():
                self._obs[key][index] = value
        else:
            self._obs[index] = obs

    def _obs_row(self, index: int):
        """A copy of environment ``index``'s observation."""
        if isinstance(self._obs, dict):
            return {k: v[index].copy() for k, v in self._obs.items()}
        return self._obs[index].copy()

    def _obs_copy(self):
        if isinstance(self._obs, dict):
            return {k: v.copy() for k, v in self._obs.items()}
        return self._obs.copy()


def info_row(infos: dict, i: int) -> dict:
    """Environment ``i``'s info from a vector step's or reset's batched ``infos`` (for an
    environment whose episode ended in that step, its final step's, without the keys of the
    reset that followed)."""
    return {
        key: value[i]
        for key, value in infos.items()
        if not key.startswith(("_", "reset/"))
        and key not in ("final_obs", "final_info")
        and (f"_{key}" not in infos or infos[f"_{key}"][i])
    }


def _item(value):
    """A plain Python value of one environment's entry of a batched info array."""
    return value.item() if isinstance(value, np.generic) else value


class TorchArrays(VectorWrapper):
    """Observations, rewards, terminations and truncations as torch tensors; actions may be
    tensors.  On the CPU the tensors share memory with the arrays the environment returned
    (``torch.from_numpy``), so nothing is copied.  Infos stay numpy: they hold flags and
    strings (the instruction) that tensors cannot (gymnasium's own NumpyToTorch fails on
    them)."""

    def __init__(self, env: VectorEnv, device=None) -> None:
        try:
            import torch
        except ImportError as err:
            raise RuntimeError(
                f"arrays='torch' needs torch ({err}); install it with: pip install 'wirecraft[rl]'"
            ) from None
        super().__init__(env)
        self._torch = torch
        self.device = torch.device(device) if device is not None else torch.device("cpu")

    @property
    def task_description(self) -> tuple[str, ...]:
        return self.env.task_description

    def call(self, name: str, *args, **kwargs) -> tuple:
        return self.env.call(name, *args, **kwargs)

    def get_attr(self, name: str) -> tuple:
        return self.env.get_attr(name)

    def _tensor(self, value):
        if isinstance(value, dict):
            return {k: self._tensor(v) for k, v in value.items()}
        if isinstance(value, np.ndarray):
            return self._torch.from_numpy(value).to(self.device)
        return value

    def reset(self, *, seed=None, options=None):
        obs, infos = self.env.reset(seed=seed, options=options)
        return self._tensor(obs), infos

    def step(self, actions):
        if isinstance(actions, self._torch.Tensor):
            actions = actions.detach().cpu().numpy()
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        return (
            self._tensor(obs),
            self._tensor(rewards),
            self._tensor(terminations),
            self._tensor(truncations),
            infos,
        )


__all__ = ["TorchArrays", "WireCraftVectorEnv", "env_seed", "info_row"]
