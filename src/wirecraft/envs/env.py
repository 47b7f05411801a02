"""The gymnasium environment: one task, one robot, one wire model, one control mode.

Timing: physics at 1/480 s, 8 substeps per control step: exactly 60 Hz; an 8 s episode is 480
control steps (the default; routing gets 8 s per clip, see ``Task.episode_seconds``).
(1/480 s is within 5% of the 2 ms at which the wire physics was validated.)
``episode_seconds=`` or ``max_episode_steps=`` (also ``gymnasium.make``'s) sets the length:
``max_steps``, which ``env.spec.max_episode_steps`` reports.

Cameras: ``camera_config=`` (a ``wirecraft.cameras.CameraConfig``, its dict, or a TOML path)
sets the cell's camera poses, fields of view and far clip, and post-processes every rendered
RGB image with its exposure gain and sensor noise (``postprocess_image``).

Divergence: after every control step the state is checked (finite; linear and angular speeds
below ``MAX_LINEAR_SPEED`` and ``MAX_ANGULAR_SPEED``); a diverged step is rolled back to the
state before it, the episode ends with ``truncated=True`` and ``info["diverged"] = True``, and
observations never contain NaN.

Call order: ``step`` raises ``gymnasium.error.ResetNeeded`` before the first ``reset`` and after
an episode ended (terminated or truncated), ``step`` and ``reset`` raise
``gymnasium.error.ClosedEnvironmentError`` after ``close``.  Bad arguments raise ValueError
naming the field.
"""

from __future__ import annotations

import copy
import os
import sys
import warnings
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from wirecraft import validation
from wirecraft.assets.robots import ROBOTS, add_robot
from wirecraft.assets.wires import WIRE_MODELS, WireConfig
from wirecraft.control import CONTROLLERS, ControlConfig, make_controller
from wirecraft.scene import OFFSCREEN_HEIGHT, OFFSCREEN_WIDTH, add_table, compile_spec, new_spec
from wirecraft.tasks import TASKS
from wirecraft.tasks.base import weighted_reward
from wirecraft.tasks.options import split_options

CONTROL_HZ = 60
SUBSTEPS = 8
TIMESTEP = 1.0 / (CONTROL_HZ * SUBSTEPS)
OBS_MODES = ("state", "rgb", "rgbd", "state_rgb")
RENDER_MODES = (None, "rgb_array", "human")
# Anything faster is a numerical explosion in these scenes (a robot TCP moves < 2 m/s; a rod's
# twist joints, with tiny inertia, legitimately spin at a few hundred rad/s).
MAX_LINEAR_SPEED = 20.0  # m/s
MAX_ANGULAR_SPEED = 2000.0  # rad/s
STATE_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION
RESET_ATTEMPTS = 3
MAX_IMAGE_SIZE = min(OFFSCREEN_WIDTH, OFFSCREEN_HEIGHT)  # square images in the framebuffer


def check_seed(owner: str, seed) -> int | None:
    if seed is None:
        return None
    seed = validation.integer(owner, "seed", seed)
    if seed < 0:
        raise ValueError(f"{owner}.seed must be None or an integer >= 0, got {seed!r}")
    return seed


def check_options(owner: str, options, allowed: tuple[str, ...] = ()) -> dict:
    if options is None:
        return {}
    options = validation.mapping(owner, "options", options)
    unknown = [key for key in options if key not in allowed]
    if unknown:
        valid = ", ".join(allowed) if allowed else "none"
        raise ValueError(f"{owner}: unknown reset option(s) {unknown}; valid: {valid}")
    return options


def _add_wrist_sensor(spec: mujoco.MjSpec, hand_body: str) -> None:
    """A force/torque sensor where the gripper meets the arm (what the hand carries, in the
    hand frame: its own weight included, as on a real wrist sensor)."""
    spec.body(hand_body).add_site(name="wrist_ft", size=(0.005, 0, 0))
    for name, kind in (
        ("wrist_force", mujoco.mjtSensor.mjSENS_FORCE),
        ("wrist_torque", mujoco.mjtSensor.mjSENS_TORQUE),
    ):
        spec.add_sensor(name=name, type=kind, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="wrist_ft")


NO_DISPLAY = (
    "render_mode='human' opens MuJoCo's viewer, which needs a display: {reason}. Run with a "
    "display (set DISPLAY, or run under a virtual one: xvfb-run -a python ...), or render "
    "off-screen with render_mode='rgb_array' and MUJOCO_GL=egl"
)


def check_display() -> None:
    """Raise RuntimeError, naming the fix, where MuJoCo's viewer could not open a window
    (it would print "could not initialize GLFW" and end the process)."""
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        raise RuntimeError(NO_DISPLAY.format(reason="DISPLAY is not set"))
    try:
        import glfw
    except ImportError as err:
        raise RuntimeError(NO_DISPLAY.format(reason=f"GLFW is not available ({err})")) from None
    with warnings.catch_warnings(record=True) as glfw_warnings:
        warnings.simplefilter("always")  # glfw reports its reason as a warning: the error says it
        ok = glfw.init()
    if not ok:
        display = os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
        said = "; ".join(str(w.message) for w in glfw_warnings) or "no reason given"
        raise RuntimeError(
            NO_DISPLAY.format(reason=f"GLFW could not initialize on display {display!r} ({said})")
        )


def _gym_make_max_episode_steps(frame) -> int | None:
    """The ``max_episode_steps`` argument of the ``gymnasium.make`` call running in ``frame``
    (None if ``frame`` is not ``gymnasium.make``, or it was not given or was -1)."""
    from gymnasium.envs import registration

    if frame is None or frame.f_code is not registration.make.__code__:
        return None
    steps = frame.f_locals.get("max_episode_steps")
    return None if steps is None or steps == -1 else steps


def default_episode_seconds(task: str, **env_kwargs: Any) -> float:
    """The episode length ``WireCraftEnv(task, **env_kwargs)`` gets when ``episode_seconds``
    is not given, without building the environment."""
    task_cls = TASKS.get(task)
    options, _ = split_options(task_cls.Options, env_kwargs)
    return task_cls(task_cls.Options.build(options)).episode_seconds


def as_actions(name: str, actions, shape: tuple[int, ...]) -> np.ndarray:
    """``actions`` as a float array of ``shape``; ValueError naming ``name`` otherwise."""
    try:
        actions = np.asarray(actions, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be numbers of shape {shape}, got {actions!r}") from None
    if actions.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {actions.shape}")
    return actions


def spec_with_length(spec, steps: int):
    """gymnasium's ``spec`` with ``max_episode_steps`` = ``steps`` (a copy where it differs;
    None stays None)."""
    if spec is None or spec.max_episode_steps == steps:
        return spec
    spec = copy.copy(spec)
    spec.max_episode_steps = steps
    return spec


def steps_per_frame(fps) -> int:
    """Control steps per recorded frame at ``fps`` frames/s: ``CONTROL_HZ / fps``, which must be
    a whole number (a dataset frame holds whole control steps)."""
    ok = not isinstance(fps, bool) and isinstance(fps, (int, float)) and fps > 0
    if ok and float(CONTROL_HZ / fps).is_integer():
        return int(CONTROL_HZ // fps)
    divisors = [d for d in range(1, CONTROL_HZ + 1) if CONTROL_HZ % d == 0]
    raise ValueError(
        f"fps must divide the {CONTROL_HZ} Hz control rate (one of "
        f"{', '.join(map(str, divisors))}) so that each frame holds a whole number of "
        f"control steps; got {fps!r}"
    )


def within_limits(qpos, qvel, speed_limits) -> np.ndarray:
    """Whether each state (the last axis of ``qpos`` / ``qvel``; one state or N rows) is finite
    and below the speed limits: False means diverged."""
    return (
        np.all(np.isfinite(qpos), axis=-1)
        & np.all(np.isfinite(qvel), axis=-1)
        & np.all(np.abs(qvel) < speed_limits, axis=-1)
    )


def _speed_limits(model: mujoco.MjModel) -> np.ndarray:
    """(nv,) the speed above which each DOF counts as diverged: m/s or rad/s by DOF kind."""
    limits = np.full(model.nv, MAX_ANGULAR_SPEED)
    for j in range(model.njnt):
        adr, kind = model.jnt_dofadr[j], model.jnt_type[j]
        if kind == mujoco.mjtJoint.mjJNT_FREE:
            limits[adr : adr + 3] = MAX_LINEAR_SPEED
        elif kind == mujoco.mjtJoint.mjJNT_SLIDE:
            limits[adr] = MAX_LINEAR_SPEED
    return limits


class ResetDiverged(RuntimeError):
    """A new episode's settle diverged ``RESET_ATTEMPTS`` times in a row."""


class WireCraftEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": CONTROL_HZ}

    def __init__(
        self,
        task: str,
        robot: str = "ur5",
        wire: str = "articulated",
        control: str | None = None,
        obs_mode: str = "state",
        image_size: int = 224,
        render_mode: str | None = None,
        episode_seconds: float | None = None,
        max_episode_steps: int | None = None,
        wire_config: WireConfig | None = None,
        diagnostics: bool = True,
        camera_config=None,
        **task_kwargs: Any,
    ) -> None:
        task_cls = TASKS.get(task)
        ROBOTS.get(robot)
        WIRE_MODELS.get(wire)
        control = task_cls.default_control if control is None else control
        CONTROLLERS.get(control)
        validation.one_of("WireCraftEnv", "obs_mode", obs_mode, OBS_MODES)
        validation.one_of("WireCraftEnv", "render_mode", render_mode, RENDER_MODES)
        validation.int_in_range(
            "WireCraftEnv",
            "image_size",
            image_size,
            16,
            MAX_IMAGE_SIZE,
            f"MuJoCo's off-screen framebuffer is {OFFSCREEN_WIDTH} x {OFFSCREEN_HEIGHT}",
        )
        validation.boolean("WireCraftEnv", "diagnostics", diagnostics)
        if episode_seconds is not None:
            validation.finite("WireCraftEnv", "episode_seconds", episode_seconds)
            if round(episode_seconds * CONTROL_HZ) < 1:
                raise ValueError(
                    f"WireCraftEnv.episode_seconds must be at least one control step "
                    f"(1/{CONTROL_HZ} s), got {episode_seconds!r}"
                )
        if render_mode == "human":
            check_display()
        if wire_config is not None and not isinstance(wire_config, WireConfig):
            raise ValueError(
                f"WireCraftEnv.wire_config must be a WireConfig or None, got {wire_config!r}"
            )
        from wirecraft.cameras import CameraConfig

        self.camera_config = CameraConfig.of(camera_config)
        weights = task_kwargs.pop("weights", None)
        self.task = task_cls(task_cls.Options.build(task_kwargs), weights)
        self.robot_name, self.wire_name, self.control_name = robot, wire, control
        self.obs_mode, self.image_size, self.render_mode = obs_mode, image_size, render_mode
        self._episode_seconds = episode_seconds  # as given (None: the task's default)
        if episode_seconds is None:
            episode_seconds = self.task.episode_seconds
        self.max_steps = int(round(episode_seconds * CONTROL_HZ))
        self._spec = None
        if max_episode_steps is not None:
            self.set_max_episode_steps(max_episode_steps)
        # False: info leaves out the force and cable diagnostics (per-environment contact
        # walks that RL training never reads; the vector environment is faster without them).
        self.diagnostics = bool(diagnostics)

        spec = new_spec(f"{task}_{robot}_{wire}", timestep=TIMESTEP)
        add_table(spec)
        self.robot = add_robot(spec, robot)
        _add_wrist_sensor(spec, self.robot.hand_body)
        self.task.build_scene(spec, wire_config or WireConfig(model=wire))
        self.task.add_contact_sensors(spec, self.robot)
        if self.camera_config is not None:
            self.camera_config.apply_to_spec(spec, self.robot.side_camera, self.robot.wrist_camera)
        self.model = compile_spec(spec)
        if self.camera_config is not None:
            self.camera_config.apply_to_model(self.model)
        # MuJoCo would otherwise reset a diverged simulation silently; we detect and report it.
        self.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
        self.data = mujoco.MjData(self.model)
        self.robot.reset_home(self.model, self.data)  # a valid state before the first reset
        # (nv,) per-DOF speeds above which a state counts as diverged (``within_limits``).
        self.speed_limits = _speed_limits(self.model)
        self._wrench_adr = [self.model.sensor(n).adr[0] for n in ("wrist_force", "wrist_torque")]
        self.task.bind(self.model, self.robot)
        self.controller = make_controller(
            control, self.robot, self.model, ControlConfig(substeps=SUBSTEPS)
        )
        self._renderer = None
        self._owns_renderer = True
        self._viewer = None
        self.elapsed_steps = 0  # control steps of the current episode (truncated at max_steps)
        self._last_obs = None
        self._needs_reset = True
        self._closed = False

        self.action_space = gym.spaces.Box(-1.0, 1.0, (self.controller.action_dim,), np.float32)
        self.observation_space = self._make_observation_space()

    # -- episode length and gymnasium's spec -------------------------------------------------
    def set_max_episode_steps(self, steps: int) -> None:
        """End episodes after ``steps`` control steps (``truncated``), instead of the
        ``episode_seconds`` default; an ``episode_seconds`` given as well must agree."""
        steps = validation.at_least_int("WireCraftEnv", "max_episode_steps", steps, 1)
        if self._episode_seconds is not None and steps != self.max_steps:
            raise ValueError(
                f"WireCraftEnv: episode_seconds={self._episode_seconds!r} ({self.max_steps} "
                f"control steps at {CONTROL_HZ} Hz) and max_episode_steps={steps} disagree; "
                "give one of them"
            )
        self.max_steps = steps

    @property
    def spec(self):
        """gymnasium's ``EnvSpec`` of this environment (set by ``gymnasium.make``), its
        ``max_episode_steps`` this environment's episode length (``max_steps``)."""
        return spec_with_length(self.__dict__.get("_spec"), self.max_steps)

    @spec.setter
    def spec(self, spec) -> None:
        # gymnasium.make(id, max_episode_steps=N) keeps N for its TimeLimit wrapper and sets
        # the spec right after building the environment: the episode then lasts N steps here
        # too (else this environment's own limit would truncate first).
        steps = _gym_make_max_episode_steps(sys._getframe(1))
        if steps is not None:
            self.set_max_episode_steps(steps)
        self._spec = spec

    @property
    def task_description(self) -> str:
        """The episode's language instruction (also ``info["instruction"]`` at reset and at
        every step)."""
        return self.task.instruction

    @property
    def _max_episode_steps(self) -> int:
        """``max_steps``, under the name LeRobot's evaluation reads."""
        return self.max_steps

    # -- spaces -----------------------------------------------------------------------------
    def _make_observation_space(self) -> gym.Space:
        state_dim = self.task.privileged_state(self.model, self.data).size
        state = gym.spaces.Box(-np.inf, np.inf, (state_dim,), np.float64)
        if self.obs_mode == "state":
            return state
        size = self.image_size

        def vector(n):
            return gym.spaces.Box(-np.inf, np.inf, (n,), np.float64)

        spaces = {
            "rgb_side": gym.spaces.Box(0, 255, (size, size, 3), np.uint8),
            "rgb_wrist": gym.spaces.Box(0, 255, (size, size, 3), np.uint8),
            "proprio": vector(2 * self.robot.dof + 2),
            "fingertip_contact": gym.spaces.Box(0.0, 1.0, (2,), np.float64),
            "grasp_force": gym.spaces.Box(0.0, np.inf, (1,), np.float64),
            "fixture_force": gym.spaces.Box(0.0, np.inf, (1,), np.float64),
            "wrist_wrench": vector(6),
        }
        if self.obs_mode == "rgbd":
            spaces["depth_side"] = gym.spaces.Box(0, np.inf, (size, size, 1), np.float32)
            spaces["depth_wrist"] = gym.spaces.Box(0, np.inf, (size, size, 1), np.float32)
        if self.obs_mode == "state_rgb":
            spaces["state"] = state
        return gym.spaces.Dict(spaces)

    # -- gymnasium API ----------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self.check_open("reset")
        check_options("WireCraftEnv.reset", options)
        self.seed_episode(seed)
        # Later attempts continue the same seeded stream: still deterministic.
        attempt = 1
        while True:
            self.start_episode()
            if self._settle_alone():
                break
            self.check_reset_attempt(attempt)
            attempt += 1
        return self.finish_reset(attempt)

    # A reset in three parts, so that a vector environment can settle many environments'
    # new episodes in one batch (envs/vector.py): start_episode, the settle steps
    # (settle_action, settle_steps), finish_reset.
    def seed_episode(self, seed: int | None) -> None:
        """gymnasium's reset bookkeeping: reseed the generator where ``seed`` is given."""
        super().reset(seed=check_seed("WireCraftEnv.reset", seed))

    def start_episode(self) -> None:
        """Sample a new episode from this environment's generator: the scene before settling."""
        model, data = self.model, self.data
        mujoco.mj_resetData(model, data)
        self.robot.reset_home(model, data)
        self.task.initialize_episode(model, data, self.np_random)
        self.controller.reset(data)
        mujoco.mj_forward(model, data)

    @property
    def settle_steps(self) -> int:
        """Control steps the scene settles for, the robot holding still."""
        return int(round(self.task.settle_seconds * CONTROL_HZ))

    @property
    def settle_action(self) -> np.ndarray:
        hold = np.zeros(self.action_space.shape)
        hold[-1] = -1.0  # gripper open
        return hold

    def _settle_alone(self) -> bool:
        """Let the new episode settle; False if it diverged."""
        hold = self.settle_action
        for _ in range(self.settle_steps):
            self.controller.apply(self.data, hold)
            mujoco.mj_step(self.model, self.data, nstep=SUBSTEPS)
            if not self._healthy():
                return False
        return True

    @staticmethod
    def check_reset_attempt(attempt: int) -> None:
        """Raise once the settle diverged ``RESET_ATTEMPTS`` times in a row."""
        if attempt >= RESET_ATTEMPTS:
            raise ResetDiverged(
                f"the scene diverged while settling at reset, {attempt} times in a row"
            )

    def finish_reset(self, attempt: int):
        """The settled episode's first observation and info."""
        model, data = self.model, self.data
        self.controller.reset(data)
        self.controller.reset_targets(data)
        mujoco.mj_forward(model, data)
        self.task.after_settle(model, data)
        self.elapsed_steps = 0
        self._needs_reset = False
        obs = self.observe()
        info = {
            "instruction": self.task.instruction,
            **self.task.evaluate(model, data, self.diagnostics),
            "diverged": False,
            "reset_attempts": attempt,
        }
        return obs, info

    def step(self, action):
        self.check_open("step")
        if self._needs_reset:
            raise gym.error.ResetNeeded(
                "WireCraftEnv.step: call reset() first (before the first episode, and after "
                "an episode ended with terminated or truncated)"
            )
        action = as_actions("action", action, self.action_space.shape)
        if not np.all(np.isfinite(action)):
            raise ValueError(f"action contains NaN or inf: {action.tolist()}")
        before = self.get_state()  # for a roll-back if the physics diverges
        self.controller.apply(self.data, action)
        model, data = self.model, self.data
        mujoco.mj_step(model, data, nstep=SUBSTEPS)
        # mj_step leaves positions and contacts one substep behind qpos: bring them up to date,
        # so observations, rewards and success all describe the same instant.
        mujoco.mj_forward(model, data)
        self.elapsed_steps += 1
        if not self._healthy():
            self.set_state(before)
            self._needs_reset = True
            info = {**self.info_without_reward(), "diverged": True}
            return self.observe(), 0.0, False, True, info
        self.task.after_step(model, data)
        clipped = np.clip(action, -1.0, 1.0)
        terms = self.task.reward_terms(model, data, clipped)
        weighted, total = weighted_reward(terms, self.task.weights)
        reward = float(total)
        info = {
            "instruction": self.task.instruction,
            **self.task.evaluate(model, data, self.diagnostics),
            "diverged": False,
            **{f"reward/{k}": float(v) for k, v in weighted.items()},
        }
        truncated = self.elapsed_steps >= self.max_steps
        self._needs_reset = truncated
        obs = self.observe()
        if self.render_mode == "human":
            self.render()
        return obs, reward, False, truncated, info

    def clone(self) -> WireCraftEnv:
        """Another environment on the same compiled model: its own MjData, controller, task
        state and random generator; nothing is rebuilt."""
        other = copy.copy(self)
        other.data = mujoco.MjData(self.model)
        other.robot = copy.copy(self.robot)
        other.task = copy.copy(self.task)
        for cache in ("_frame", "_frame_key"):  # per-environment caches are not shared
            other.task.__dict__.pop(cache, None)
        other.controller = make_controller(
            self.control_name, other.robot, self.model, ControlConfig(substeps=SUBSTEPS)
        )
        other.robot.reset_home(self.model, other.data)
        other._renderer = None
        other._owns_renderer = True
        other._viewer = None
        other._np_random = None
        other._np_random_seed = None
        other.elapsed_steps = 0
        other._needs_reset = True
        return other

    def info_without_reward(self) -> dict:
        """``info`` of the current state with every reward term 0 (a reset, a diverged step)."""
        return {
            "instruction": self.task.instruction,
            **self.task.evaluate(self.model, self.data, self.diagnostics),
            **{f"reward/{k}": 0.0 for k in self.task.weights},
        }

    def _healthy(self) -> bool:
        return bool(within_limits(self.data.qpos, self.data.qvel, self.speed_limits))

    # -- observation ------------------------------------------------------------------------
    def observe(self):
        """The observation of the current state (the vector environment reads it per row)."""
        state = self.task.privileged_state(self.model, self.data)
        if self.obs_mode == "state":
            return state
        obs = {
            "proprio": self.robot.proprioception(self.model, self.data),
            **self.task.sensing(self.model, self.data),
            "wrist_wrench": self.wrist_wrench(),
        }
        depth = self.obs_mode == "rgbd"
        for camera, key in ((self.robot.side_camera, "side"), (self.robot.wrist_camera, "wrist")):
            rgb, dep = self._images(camera, depth)
            obs[f"rgb_{key}"] = rgb
            if depth:
                obs[f"depth_{key}"] = dep[..., None]
        if self.obs_mode == "state_rgb":
            obs["state"] = state
        return obs

    def use_renderer(self, renderer) -> None:
        """Draw this environment's images with ``renderer`` (a ``FastRenderer`` of this model
        and ``image_size``, shared with other environments of the model; its owner closes
        it)."""
        if self._renderer is not None and self._owns_renderer:
            self._renderer.close()
        self._renderer, self._owns_renderer = renderer, False

    def _images(self, camera: str, depth: bool):
        if self._renderer is None:
            from wirecraft.render import FastRenderer

            self._renderer = FastRenderer(self.model, self.image_size, self.image_size)
        rgb = self.postprocess_image(self._renderer.render(self.data, camera), camera)
        dep = self._renderer.render_depth(self.data, camera) if depth else None
        return rgb, dep

    def postprocess_image(self, rgb: np.ndarray, camera: str) -> np.ndarray:
        """A rendered RGB image of ``camera`` as the cell's sensor gives it (``camera_config``:
        exposure gain and noise; unchanged without one).  Its noise depends only on the
        episode's reset seed, the control step and the camera."""
        if self.camera_config is None or not self.camera_config.changes_images:
            return rgb
        index = 0 if camera == self.robot.side_camera else 1
        seed = max(int(self.np_random_seed), 0)
        return self.camera_config.postprocess(rgb, seed, self.elapsed_steps, index)

    def render(self):
        if self.render_mode == "rgb_array":
            return self._images(self.robot.side_camera, False)[0]
        if self.render_mode == "human":
            if self._viewer is None:
                import mujoco.viewer

                self._viewer = mujoco.viewer.launch_passive(self.model, self.data)
            self._viewer.sync()
        return None

    def check_open(self, call: str) -> None:
        if self._closed:
            raise gym.error.ClosedEnvironmentError(
                f"WireCraftEnv.{call}: the environment is closed; make a new one"
            )

    def close(self):
        self._closed = True
        if self._renderer is not None:
            if self._owns_renderer:
                self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None

    # -- state snapshots --------------------------------------------------------------------
    def get_state(self) -> dict:
        """Everything the next steps depend on: physics, controller targets, task trackers."""
        physics = np.empty(mujoco.mj_stateSize(self.model, STATE_SPEC))
        mujoco.mj_getState(self.model, self.data, physics, STATE_SPEC)
        # Arrays of numbers and scalars only: a copy is a deep copy (and far cheaper than
        # copy.deepcopy, which this runs for every environment on every step).
        controller = {
            k: v.copy() if isinstance(v, np.ndarray) else v
            for k, v in vars(self.controller).items()
            if isinstance(v, (np.ndarray, float, int, bool))
        }
        return {
            "physics": physics,
            "controller": controller,
            "task": self.task.get_state(),
            "steps": self.elapsed_steps,
        }

    def set_state(self, state: dict) -> None:
        mujoco.mj_setState(self.model, self.data, state["physics"], STATE_SPEC)
        for key, value in state["controller"].items():
            setattr(self.controller, key, value.copy() if isinstance(value, np.ndarray) else value)
        self.task.set_state(state["task"])
        self.elapsed_steps = state["steps"]
        self._needs_reset = False
        mujoco.mj_forward(self.model, self.data)

    def wrist_wrench(self) -> np.ndarray:
        """(6,) force (N) and torque (N m) through the wrist, in the hand frame."""
        force, torque = self._wrench_adr
        return np.concatenate(
            [self.data.sensordata[force : force + 3], self.data.sensordata[torque : torque + 3]]
        )

    def wire_points(self) -> np.ndarray:
        """(N, 3) the wire's centre line in world coordinates."""
        return self.task.wire_points(self.model, self.data)
