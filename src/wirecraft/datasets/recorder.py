"""Recording one episode of a live environment into the dataset schema (``Episode``).

Timing: the environment steps at 60 Hz; a frame is recorded every ``steps_per_frame`` control
steps (2 at 30 fps).  Frame ``j`` covers control steps ``[j * k, (j + 1) * k)``:

- its observation (``observation.*``, images, success flags) is the state at the start of
  that period (after ``reset`` for frame 0), with the flags ``info`` reported for that state;
- ``action`` is the controller's joint servo targets and gripper command after the last
  control step of the period (what the robot is being driven to at the next frame);
- ``action.env`` holds the ``k`` environment actions of the period, in order.

With ``action="env"`` the frame's ``action`` is its ``action.env`` (float32) and the joint
targets are written as ``action.joint`` (``schema.features_for``).

A period cut short (only a divergence ends an episode between frames) is not recorded.  Any
policy can drive the environment (scripted expert, RL policy, teleoperation): call ``start``
after ``reset`` and ``record`` after every ``step``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wirecraft.datasets import schema


@dataclass
class Episode:
    """One episode in the dataset schema; arrays have one row per frame."""

    task: str  # the language instruction
    source: str  # one of schema.SOURCES
    seed: int  # the reset seed (schema.NO_SEED when there is none)
    state: np.ndarray  # (T, dof + 1)
    action: np.ndarray  # (T, dof + 1)
    cartesian_state: np.ndarray  # (T, 7)
    env_action: np.ndarray  # (T, steps_per_frame * env action dim)
    images: dict[str, np.ndarray]  # camera name (schema.CAMERAS) -> (T, H, W, 3) uint8
    flags: dict[str, np.ndarray]  # success flag -> (T,) bool
    action_kind: str = "joint"  # what the frames' ``action`` holds (schema.ACTION_KINDS)
    success: bool = False  # the task's success flag at the episode's last state
    control_steps: int = 0  # environment steps taken (recorded or not)
    info: dict = field(default_factory=dict)  # free-form extras (not written per frame)

    def __len__(self) -> int:
        return int(self.state.shape[0])

    def frames(self):
        """The frames as ``LeRobotDataset.add_frame`` dictionaries."""
        source = np.array([schema.source_code(self.source)], dtype=np.int64)
        seed = np.array([self.seed], dtype=np.int64)
        env_action = self.action_kind == "env"
        for t in range(len(self)):
            joint_action = self.action[t].astype(np.float32)
            frame = {
                schema.STATE_KEY: self.state[t].astype(np.float32),
                schema.ACTION_KEY: self.env_action[t].astype(np.float32)
                if env_action
                else joint_action,
                schema.CARTESIAN_KEY: self.cartesian_state[t].astype(np.float32),
                schema.ENV_ACTION_KEY: self.env_action[t].astype(np.float64),
                schema.SOURCE_KEY: source,
                schema.SEED_KEY: seed,
                "task": self.task,
            }
            if env_action:
                frame[schema.JOINT_ACTION_KEY] = joint_action
            for camera, key in schema.CAMERAS.items():
                frame[key] = self.images[camera][t]
            for flag, values in self.flags.items():
                frame[flag] = np.array([bool(values[t])])
            yield frame


class EpisodeRecorder:
    """Samples a running environment into an ``Episode`` (see the module docstring).

    ``env``: a WireCraft environment (wrapped or not); ``fps``: a divisor of 60; ``renderer``:
    a ``FastRenderer`` of the environment's model and image size to draw with (shared by the
    recorders of one vector env; its owner closes it), else the recorder makes its own;
    ``action``: what the frames' ``action`` holds (``schema.ACTION_KINDS``)."""

    def __init__(
        self, env, fps: int = 30, *, source: str = "scripted", renderer=None, action="joint"
    ):
        from wirecraft.envs.env import CONTROL_HZ

        self.env = getattr(env, "unwrapped", env)
        if isinstance(fps, bool) or not isinstance(fps, int) or fps < 1 or CONTROL_HZ % fps:
            raise ValueError(f"fps must be a divisor of {CONTROL_HZ}, got {fps!r}")
        schema.source_code(source)
        self.action_kind = schema.check_action_kind(action)
        self.fps = fps
        self.steps_per_frame = CONTROL_HZ // fps
        self.source = source
        self.flag_names = schema.success_flags(self.env.task.name)
        self._renderer = renderer
        self._owns_renderer = renderer is None
        self.render_seconds = 0.0  # wall time spent rendering
        self.render_cpu_seconds = 0.0  # CPU time of this process (Mesa's threads included)
        self.clear(schema.NO_SEED)

    def features(self) -> dict[str, dict]:
        """The LeRobot features of the episodes this recorder produces."""
        env = self.env
        return schema.features_for(
            env.robot_name,
            env.image_size,
            task=env.task.name,
            control=env.control_name,
            steps_per_frame=self.steps_per_frame,
            action=self.action_kind,
        )

    # -- recording -----------------------------------------------------------------------------
    def start(self, info: dict, seed: int | None = None) -> None:
        """Begin an episode right after ``env.reset``; ``info`` is what reset returned."""
        self.clear(schema.NO_SEED if seed is None else int(seed))
        self._observe(info)

    def record(self, env_action, info: dict) -> None:
        """After each ``env.step(env_action)``; ``info`` is what the step returned."""
        self._period.append(np.asarray(env_action, dtype=np.float64).reshape(-1))
        self._steps += 1
        self._last_success = bool(info["success"])
        if len(self._period) < self.steps_per_frame:
            return
        self._actions.append(self.env.controller.dataset_action())
        self._env_actions.append(np.concatenate(self._period))
        self._period = []
        self._observe(info)

    @property
    def at_frame_boundary(self) -> bool:
        """True when the steps so far fill whole frames (a good place to end the episode)."""
        return not self._period

    @property
    def control_steps(self) -> int:
        return self._steps

    def finish(self, info: dict | None = None) -> Episode:
        """The recorded episode (frames with a complete period); ``info`` extras kept."""
        n = len(self._actions)
        dof = self.env.robot.dof
        env_dim = self.steps_per_frame * self.env.action_space.shape[0]
        images = {
            camera: np.stack(frames[:n])
            if n
            else np.zeros((0, self.env.image_size, self.env.image_size, 3), np.uint8)
            for camera, frames in self._images.items()
        }
        return Episode(
            task=self.env.task.instruction,
            source=self.source,
            seed=self._seed,
            state=np.asarray(self._states[:n], dtype=np.float32).reshape(n, dof + 1),
            action=np.asarray(self._actions, dtype=np.float32).reshape(n, dof + 1),
            cartesian_state=np.asarray(self._cartesian[:n], dtype=np.float32).reshape(n, 7),
            env_action=np.asarray(self._env_actions, dtype=np.float64).reshape(n, env_dim),
            images=images,
            flags={k: np.asarray(v[:n], dtype=bool) for k, v in self._flags.items()},
            action_kind=self.action_kind,
            success=self._last_success,
            control_steps=self._steps,
            info=dict(info or {}),
        )

    def close(self) -> None:
        if self._renderer is not None and self._owns_renderer:
            self._renderer.close()
        self._renderer = None

    def clear(self, seed: int = schema.NO_SEED) -> None:
        """Forget the frames recorded so far (``finish`` then gives an empty episode)."""
        self._seed = int(seed)
        self._steps = 0
        self._period: list[np.ndarray] = []
        self._states: list[np.ndarray] = []
        self._actions: list[np.ndarray] = []
        self._cartesian: list[np.ndarray] = []
        self._env_actions: list[np.ndarray] = []
        self._images: dict[str, list[np.ndarray]] = {camera: [] for camera in schema.CAMERAS}
        self._flags: dict[str, list[bool]] = {flag: [] for flag in self.flag_names}
        self._last_success = False

    # -- internals ---------------------------------------------------------------------------
    def _observe(self, info: dict) -> None:
        import time

        env = self.env
        self._states.append(frame_state(env))
        self._cartesian.append(schema.cartesian_state(env.robot, env.model, env.data))
        for flag in self.flag_names:
            self._flags[flag].append(bool(info[flag]))
        self._last_success = bool(info["success"])
        tic, cpu = time.perf_counter(), time.process_time()
        if self._renderer is None:
            self._renderer = frame_renderer(env)
        for camera, image in frame_images(env, self._renderer).items():
            self._images[camera].append(image)
        self.render_seconds += time.perf_counter() - tic
        self.render_cpu_seconds += time.process_time() - cpu


# A frame's observation, shared with whatever must observe a running environment the way a
# dataset frame does (the LeRobot environment plug-in, plugins/lerobot_env_wirecraft).
def frame_state(env) -> np.ndarray:
    """``observation.state`` of the (unwrapped) environment's current state, (dof + 1,)."""
    return env.robot.dataset_state(env.model, env.data)


def frame_renderer(env):
    """The renderer the environment's own image observations use, at its image size."""
    from wirecraft.render import FastRenderer

    return FastRenderer(env.model, env.image_size, env.image_size)


def frame_images(env, renderer) -> dict[str, np.ndarray]:
    """Camera name (``schema.CAMERAS``) -> the (H, W, 3) uint8 image of the current state."""
    robot = env.robot
    names = {"side": robot.side_camera, "wrist": robot.wrist_camera}
    return {
        camera: env.postprocess_image(renderer.render(env.data, names[camera]), names[camera])
        for camera in schema.CAMERAS
    }
