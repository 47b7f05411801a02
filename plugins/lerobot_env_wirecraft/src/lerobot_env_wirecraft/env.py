"""A WireCraft environment that steps one dataset frame at a time, seen as LeRobot sees it.

One ``step`` is one frame of a ``wirecraft collect`` dataset: ``60 / fps`` control steps of the
60 Hz environment.  The observation is what the dataset records for a frame
(``wirecraft.datasets.recorder``: the state at the start of the frame's period) under the key
names ``lerobot.envs.utils.preprocess_observation`` maps onto the dataset's features:

- ``agent_pos`` -> ``observation.state`` (dof + 1,) float32: joint angles, gripper opening (m);
- ``cartesian_state`` -> ``observation.cartesian_state`` (7,) float32: TCP pose, base frame;
- ``pixels/cam_side``, ``pixels/cam_wrist`` -> ``observation.images.cam_side`` / ``cam_wrist``
  (H, W, 3) uint8.

Actions (``action_type``):

- ``"dataset"`` (default): the dataset's ``action``, (dof + 1,): absolute arm joint targets
  (rad) and the gripper gap (m).  The environment runs ``joint`` control; each of the frame's
  control steps moves the servo targets toward the action as far as one step allows
  (``wirecraft.evaluation.policies.joint_action``), i.e. the action is held for the frame.
- ``"env"``: the dataset's ``action.env``, (k * a,): the frame's ``k = 60 / fps`` actions of
  the environment's own action space (``control``; by default the control mode the task's
  scripted expert drives, which ``wirecraft collect`` records), applied in order.  Replaying a
  dataset episode's ``action.env`` from its ``seed`` reproduces it exactly.

``info["is_success"]`` is the task's ``success`` flag at the end of the frame (LeRobot's
evaluation counts an episode as a success if it is set at some step); the other flags of the
last control step are passed on.  ``task_description`` is the task's language instruction (the
dataset's task string).  ``render()`` returns the side camera's current image.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

ACTION_TYPES = ("dataset", "env")


def pixel_keys() -> dict[str, str]:
    """Camera name (``schema.CAMERAS``) -> the key under ``pixels`` (the dataset feature's last
    part: ``observation.images.cam_side`` -> ``cam_side``)."""
    from wirecraft.datasets import schema

    return {camera: key.split(".")[-1] for camera, key in schema.CAMERAS.items()}


def env_control(task: str, action_type: str, control: str | None) -> str:
    """The WireCraft control mode the environment runs for ``action_type``."""
    if action_type not in ACTION_TYPES:
        raise ValueError(f"unknown action_type {action_type!r}; valid: {', '.join(ACTION_TYPES)}")
    if action_type == "dataset":
        if control not in (None, "joint"):
            raise ValueError(
                "action_type='dataset' (absolute joint targets) runs joint control; "
                f"got control={control!r} (use action_type='env' for another control mode)"
            )
        return "joint"
    if control is None:
        from wirecraft.experts import expert_class

        return expert_class(task).CONTROL
    return control


def steps_per_frame(fps: int) -> int:
    """``wirecraft.envs.env.steps_per_frame`` of an integer ``fps`` (LeRobot's env option)."""
    from wirecraft.envs import env

    if isinstance(fps, bool) or not isinstance(fps, int):
        raise ValueError(f"fps must be an integer dividing {env.CONTROL_HZ}; got {fps!r}")
    return env.steps_per_frame(fps)


class WireCraftLeRobotEnv(gym.Env):
    """A WireCraft task family stepped one dataset frame (``1 / fps`` s) at a time.

    ``task``: a WireCraft task family; other keywords go to ``wirecraft.make`` (robot, wire,
    image_size, episode_seconds and the family's task options)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(
        self,
        task: str,
        fps: int = 30,
        action_type: str = "dataset",
        control: str | None = None,
        render_mode: str | None = "rgb_array",
        **env_kwargs,
    ) -> None:
        import wirecraft
        from wirecraft.datasets.recorder import frame_renderer

        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be 'rgb_array' or None, got {render_mode!r}")
        for key in ("obs_mode",):
            if key in env_kwargs:
                raise ValueError(f"{type(self).__name__} sets {key!r} itself")
        self.k = steps_per_frame(fps)
        self.fps = fps
        self.action_type = action_type
        control = env_control(task, action_type, control)
        # State observations only: the frame's images are rendered here, once per frame.
        self.sim = wirecraft.make(task, control=control, obs_mode="state", **env_kwargs)
        self.core = self.sim.unwrapped
        self.task = self.core.task.name  # LeRobot's fallback task string; see task_description
        self.render_mode = render_mode
        self.metadata = {**type(self).metadata, "render_fps": fps}
        self._renderer = frame_renderer(self.core)
        self._pixel_keys = pixel_keys()
        self._last_pixels: dict[str, np.ndarray] | None = None

        dof = self.core.robot.dof
        size = self.core.image_size
        image = gym.spaces.Box(0, 255, (size, size, 3), np.uint8)
        self.observation_space = gym.spaces.Dict(
            {
                "agent_pos": gym.spaces.Box(-np.inf, np.inf, (dof + 1,), np.float32),
                "cartesian_state": gym.spaces.Box(-np.inf, np.inf, (7,), np.float32),
                "pixels": gym.spaces.Dict({key: image for key in self._pixel_keys.values()}),
            }
        )
        self.env_action_dim = self.core.action_space.shape[0]
        if action_type == "dataset":
            self.action_space = gym.spaces.Box(-np.inf, np.inf, (dof + 1,), np.float32)
        else:
            self.action_space = gym.spaces.Box(
                -1.0, 1.0, (self.k * self.env_action_dim,), np.float32
            )

    # -- what LeRobot reads ---------------------------------------------------------------------
    @property
    def task_description(self) -> str:
        """The task's language instruction (the dataset's task string)."""
        description = getattr(self.core, "task_description", None)
        return str(description if description is not None else self.core.task.instruction)

    def render(self):
        if self._last_pixels is None:
            return None
        return self._last_pixels[self._pixel_keys["side"]].copy()

    # -- gymnasium API --------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        # LeRobot marks a new rollout in ``options``; WireCraft's reset takes no options.
        del options
        super().reset(seed=seed)
        _, info = self.sim.reset(seed=seed)
        return self._observe(), self._info(info)

    def step(self, action):
        from wirecraft.evaluation.policies import joint_action

        action = np.asarray(action, dtype=float).reshape(-1)
        if action.shape != self.action_space.shape:
            raise ValueError(
                f"action must have shape {self.action_space.shape}, got {action.shape}"
            )
        reward, terminated, truncated, info = 0.0, False, False, {}
        a = self.env_action_dim
        for i in range(self.k):
            if self.action_type == "dataset":
                env_action = joint_action(self.core, action)
            else:
                env_action = action[i * a : (i + 1) * a]
            _, r, terminated, truncated, info = self.sim.step(env_action)
            reward += float(r)
            if terminated or truncated:
                break
        return self._observe(), reward, bool(terminated), bool(truncated), self._info(info)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self.sim.close()

    # -- internals ------------------------------------------------------------------------------
    def _observe(self) -> dict:
        from wirecraft.datasets import schema
        from wirecraft.datasets.recorder import frame_images, frame_state

        core = self.core
        images = frame_images(core, self._renderer)
        self._last_pixels = {self._pixel_keys[camera]: image for camera, image in images.items()}
        return {
            "agent_pos": frame_state(core).astype(np.float32),
            "cartesian_state": schema.cartesian_state(core.robot, core.model, core.data).astype(
                np.float32
            ),
            "pixels": dict(self._last_pixels),
        }

    def _info(self, info: dict) -> dict:
        # Numbers and flags only: the vector environment stacks them per key.
        out = {
            k: v for k, v in info.items() if isinstance(v, (bool, int, float, np.bool_, np.number))
        }
        out["is_success"] = bool(info.get("success", False))
        return out
