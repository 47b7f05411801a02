"""Policies the evaluation runs: one protocol, adapters for every kind of controller.

A policy drives a batch of N environments (a ``wirecraft.make_vec`` vector environment, or a
single environment as N = 1):

- ``control``: the environment control mode it needs (``joint``, ``cartesian``,
  ``cartesian_fixed``), or None when any mode will do;
- ``reset(env_ids=None)``: called after the environments ``env_ids`` (None: all) started a new
  episode;
- ``act(obs) -> (N, action_dim)`` actions for the current observations;
- optionally ``phase_names() -> list[str] | None``: one phase name per environment for the
  video overlays (the scripted experts' state-machine phase).

``load_policy(spec, env)`` builds one from a spec: ``scripted`` (the task's expert), ``random``,
``zero``, or a path to a checkpoint (an RL run directory holding ``wirecraft_rl.json``, or a
LeRobot pretrained-policy directory).  ``policy_env_kwargs(spec, task)`` says, before the
environments exist, which environment keyword arguments the policy needs (control mode,
observation mode, image size).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from wirecraft.datasets import schema
from wirecraft.experts.fsm import unwrap_envs
from wirecraft.lerobot_compat import quiet_torchcodec

quiet_torchcodec()  # lerobot's torchcodec traceback where FFmpeg is missing
BUILTIN_POLICIES = ("scripted", "reactive", "random", "zero")
RL_MARKER = "wirecraft_rl.json"
# What an RL policy fixes about its environments (its observation and action spaces).
# LeRobot camera feature -> our observation key (the dataset schema's camera names).
LEROBOT_CAMERAS = {"cam_side": "rgb_side", "cam_wrist": "rgb_wrist"}
# Written by lerobot-train next to a checkpoint's config.json (the training run's settings).
TRAIN_CONFIG = "train_config.json"


@runtime_checkable
class Policy(Protocol):
    control: str | None

    def reset(self, env_ids=None) -> None: ...

    def act(self, obs) -> np.ndarray: ...


def _mask(num_envs: int, env_ids) -> np.ndarray:
    mask = np.zeros(num_envs, bool)
    if env_ids is None:
        mask[:] = True
    else:
        ids = np.asarray(env_ids)
        if ids.dtype == bool:
            mask = ids.copy()
        else:
            mask[ids.astype(int)] = True
    return mask


EXPERT_STREAM = 0xE4BE47  # tags the expert's generator apart from the environment's own


class ScriptedPolicy:
    """The task family's scripted expert (``wirecraft.experts``), default configuration.

    The expert draws per-episode diversity (pauses, pick-and-drop...) from one generator per
    environment; ``reset`` seeds it from the seed the environment was reset with, so an
    episode plays out the same whatever slot of a batch it runs in."""

    def __init__(self, env, config=None) -> None:
        from wirecraft.experts import expert_class

        envs = unwrap_envs(env)
        cls = expert_class(envs[0].task.name)
        self.control = cls.CONTROL
        self.expert = cls(env, config)

    def reset(self, env_ids=None) -> None:
        expert = self.expert
        mask = _mask(expert.num_envs, env_ids)
        if hasattr(expert, "rngs"):
            for i in np.flatnonzero(mask):
                seed = max(int(expert.envs[i].np_random_seed), 0)
                expert.rngs[i] = np.random.default_rng([seed, EXPERT_STREAM])
        expert.reset(mask)

    def act(self, obs) -> np.ndarray:
        return self.expert.act(obs)

    def phase_names(self) -> list[str]:
        return list(self.expert.phase_names)


class ReactivePolicy:
    """The task family's memoryless expert (``wirecraft.experts.reactive.REACTIVE_EXPERTS``):
    its action is a function of the state observation alone, so ``reset`` has nothing to do."""

    def __init__(self, env) -> None:
        from wirecraft.experts.reactive import REACTIVE_EXPERTS

        cls = REACTIVE_EXPERTS.get(unwrap_envs(env)[0].task.name)
        self.control = cls.CONTROL
        self.expert = cls(env)

    def reset(self, env_ids=None) -> None:
        del env_ids

    def act(self, obs) -> np.ndarray:
        return self.expert.act(np.atleast_2d(obs))

    def phase_names(self) -> list[str]:
        return self.expert.phase_names()


class ZeroPolicy:
    """All-zero actions: the arm holds still, the gripper stays half open (a do-nothing
    baseline; under ``joint`` and ``cartesian`` control zero means "hold")."""

    control = None

    def __init__(self, env) -> None:
        envs = unwrap_envs(env)
        self.shape = (len(envs), envs[0].action_space.shape[0])

    def reset(self, env_ids=None) -> None:
        del env_ids

    def act(self, obs) -> np.ndarray:
        del obs
        return np.zeros(self.shape)


class RandomPolicy:
    """Uniform random actions in [-1, 1].  Each environment's generator is seeded, at
    ``reset``, from the seed its environment was last reset with, so an episode's actions do
    not depend on how episodes are batched."""

    control = None

    def __init__(self, env) -> None:
        self.envs = unwrap_envs(env)
        self.action_dim = self.envs[0].action_space.shape[0]
        self.generators: list[np.random.Generator | None] = [None] * len(self.envs)
        self.reset()

    def reset(self, env_ids=None) -> None:
        for i in np.flatnonzero(_mask(len(self.envs), env_ids)):
            seed = self.envs[i].np_random_seed
            # A fixed tag keeps the action stream apart from the environment's own stream.
            self.generators[i] = np.random.default_rng([max(int(seed), 0), 0x7A11D])

    def act(self, obs) -> np.ndarray:
        del obs
        return np.stack([g.uniform(-1.0, 1.0, self.action_dim) for g in self.generators])


class DatasetActionPolicy:
    """Drives environments with dataset actions at the dataset's frame rate (the base of
    ``LeRobotPolicy``).

    A dataset records one frame every ``k = CONTROL_HZ / fps`` control steps
    (``wirecraft.datasets.recorder``): frame ``j``'s observation is the state after control
    step ``j k`` (after ``reset`` for frame 0); its action covers control steps
    ``[j k, (j + 1) k)``.  ``act`` is called at every control step; at a frame boundary (every
    ``k``-th call since ``reset``) it asks ``frame_actions(obs)`` for the next frame's actions.
    The observations between frame boundaries are not read.  ``action`` says what a frame's
    action is (``schema.ACTION_KINDS``):

    - ``joint``: the absolute servo targets (rad) + pad gap (m) the robot is driven to during
      the frame; the environments run ``joint`` control, and on each of the ``k`` steps the
      targets become ``joint`` actions through ``joint_action`` (a target further than a
      step's rated motion is approached over the frame's steps);
    - ``env``: the frame's ``k`` environment actions (``k * a`` values, ``a`` the environments'
      action size), step ``s`` of the frame playing values ``[s a, (s + 1) a)`` clipped to
      [-1, 1], in whatever control mode the environments run."""

    def __init__(self, env, fps: float, action: str = "joint") -> None:
        self.envs = unwrap_envs(env)
        self.fps = fps
        from wirecraft.envs.env import steps_per_frame

        self.action_kind = schema.check_action_kind(action)
        self.control = "joint" if action == "joint" else self.envs[0].controller.name
        self.steps_per_frame = steps_per_frame(fps)
        self.env_action_dim = self.envs[0].action_space.shape[0]
        # The number of values in one frame's action.
        self.frame_width = (
            self.envs[0].robot.dof + 1
            if action == "joint"
            else self.steps_per_frame * self.env_action_dim
        )
        self._step = 0
        self._targets: np.ndarray | None = None

    def frame_actions(self, obs) -> np.ndarray:
        """(N, dof + 1) joint targets, or (N, k * a) environment actions, for the frame
        starting at observation ``obs``."""
        raise NotImplementedError

    def reset(self, env_ids=None) -> None:
        # One frame clock for the whole batch: the protocol resets every environment together.
        del env_ids
        self._step = 0
        self._targets = None

    def act(self, obs) -> np.ndarray:
        step_in_frame = self._step % self.steps_per_frame
        if self._targets is None or step_in_frame == 0:
            targets = np.asarray(self.frame_actions(obs), dtype=float)
            width = self.frame_width
            if targets.size != len(self.envs) * width:
                raise ValueError(
                    f"a frame's {self.action_kind} action has {width} values per environment "
                    f"here; the policy gave shape {targets.shape} for {len(self.envs)}"
                )
            self._targets = targets.reshape(len(self.envs), width)
        self._step += 1
        if self.action_kind == "env":
            a = self.env_action_dim
            part = self._targets[:, step_in_frame * a : (step_in_frame + 1) * a]
            return np.clip(part, -1.0, 1.0)
        rows = zip(self.envs, self._targets, strict=True)
        return np.stack([joint_action(env, row) for env, row in rows])


class LeRobotPolicy(DatasetActionPolicy):
    """A LeRobot pretrained policy (``PreTrainedPolicy.from_pretrained``) on our environments.

    Observations (``obs_mode="state_rgb"``) map onto the WireCraft dataset schema:
    ``observation.state`` = arm joint positions + gripper opening (the first dof + 1 entries of
    ``proprio``), ``observation.images.cam_side`` / ``cam_wrist`` = ``rgb_side`` /
    ``rgb_wrist`` (channels first, floats in [0, 1]), ``task`` = the instruction.  The policy's
    action is the dataset action (``checkpoint_action``): absolute arm joint targets (rad) +
    gripper opening (m), which the adapter turns into ``joint``-control actions (per-step
    target deltas over the joints' rated step, clipped to [-1, 1]; gripper command = 1 - 2
    opening / max opening); or, for a policy trained on a dataset collected with ``--action
    env``, the frame's environment actions in the control mode the checkpoint names.

    The policy runs at the frame rate of the dataset it was trained on (``DatasetActionPolicy``):
    queried once per frame, on the observation the dataset recorder would have sampled, each
    action held for ``CONTROL_HZ / fps`` control steps, so action chunks play at recorded speed.
    ``fps``: that frame rate; None reads it from the checkpoint (``checkpoint_fps``) and fails
    when the checkpoint does not say.
    """

    def __init__(
        self, path: str | Path, env, device: str = "cpu", fps: float | None = None
    ) -> None:
        if fps is None:
            fps = checkpoint_fps(path)
            if fps is None:
                raise ValueError(
                    f"{path}: the frame rate of the policy's training data is not recorded in "
                    f"the checkpoint (no {TRAIN_CONFIG} naming a dataset whose meta/info.json "
                    "is on this machine, nor an env with an fps): pass it explicitly, "
                    "fps=... (wirecraft eval --fps N; the dataset's meta/info.json has it)"
                )
        action, control = checkpoint_action(path)
        super().__init__(env, fps, action)
        import torch
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors

        self.torch = torch
        for e in self.envs:
            if e.controller.name != control:
                raise ValueError(
                    f"this LeRobot policy's actions are {action} actions under control="
                    f"{control!r}: it needs environments with control={control!r}, got "
                    f"{e.controller.name!r}"
                )
            if e.obs_mode != "state_rgb":
                raise ValueError("a LeRobot policy needs environments with obs_mode='state_rgb'")
        path = str(path)
        config = PreTrainedConfig.from_pretrained(path)
        output = (config.output_features or {}).get("action")
        if output is not None and tuple(output.shape) != (self.frame_width,):
            raise ValueError(
                f"{path}: the policy's action has shape {tuple(output.shape)}; {action} "
                f"actions at {fps} frames/s in these environments have {self.frame_width} "
                "values (was it trained on a dataset of another robot, control or frame rate?)"
            )
        config.device = device
        self.policy = get_policy_class(config.type).from_pretrained(path, config=config)
        self.policy.eval()
        overrides = {"device_processor": {"device": device}}
        self.pre, self.post = make_pre_post_processors(
            config, pretrained_path=path, preprocessor_overrides=overrides
        )
        self.image_keys = [k for k in config.input_features if k.startswith("observation.images.")]
        for key in self.image_keys:
            camera = key.split(".")[-1]
            if camera not in LEROBOT_CAMERAS:
                raise ValueError(
                    f"LeRobot policy input {key!r}: no WireCraft camera of that name "
                    f"(known: {', '.join(LEROBOT_CAMERAS)})"
                )
        self.uses_state = "observation.state" in config.input_features
        self.uses_cartesian = schema.CARTESIAN_KEY in config.input_features
        known = {"observation.state", schema.CARTESIAN_KEY, *self.image_keys}
        unknown = sorted(set(config.input_features) - known)
        if unknown:
            raise ValueError(
                f"LeRobot policy inputs {unknown}: WireCraft supplies observation.state, "
                f"{schema.CARTESIAN_KEY} and observation.images.* "
                f"({', '.join(LEROBOT_CAMERAS)})"
            )

    def reset(self, env_ids=None) -> None:
        # LeRobot policies keep one action queue for the whole batch: any reset restarts it.
        super().reset(env_ids)
        self.policy.reset()

    def _batch(self, obs) -> dict[str, Any]:
        torch = self.torch
        batch: dict[str, Any] = {}
        dof = self.envs[0].robot.dof
        if self.uses_state:
            state = np.asarray(obs["proprio"])[:, : dof + 1]
            batch["observation.state"] = torch.as_tensor(state, dtype=torch.float32)
        if self.uses_cartesian:
            cartesian = [schema.cartesian_state(e.robot, e.model, e.data) for e in self.envs]
            batch[schema.CARTESIAN_KEY] = torch.as_tensor(np.stack(cartesian), dtype=torch.float32)
        for key in self.image_keys:
            images = np.asarray(obs[LEROBOT_CAMERAS[key.split(".")[-1]]])
            tensor = torch.as_tensor(images).permute(0, 3, 1, 2).float() / 255.0
            batch[key] = tensor
        batch["task"] = [env.task_description for env in self.envs]
        return batch

    def frame_actions(self, obs) -> np.ndarray:
        with self.torch.inference_mode():
            action = self.post(self.policy.select_action(self.pre(self._batch(obs))))
        return np.asarray(action.detach().cpu().numpy(), dtype=float)


def _train_config(path: str | Path) -> dict | None:
    """The ``train_config.json`` that ``lerobot-train`` writes beside a checkpoint, if readable."""
    try:
        config = json.loads((Path(path) / TRAIN_CONFIG).read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return config if isinstance(config, dict) else None


def checkpoint_action(path: str | Path) -> tuple[str, str]:
    """(what the LeRobot checkpoint's action is, the control mode it needs): ("joint",
    "joint"), or ("env", control) for a policy trained on environment actions.
    ``wirecraft train`` records that in the training config's environment (the LeRobot
    plug-in's ``action_type`` and ``control``), saved next to each checkpoint."""
    env = (_train_config(path) or {}).get("env")
    if not isinstance(env, dict) or env.get("action_type") != "env":
        return "joint", "joint"
    if not env.get("control"):
        raise ValueError(
            f"{path}: {TRAIN_CONFIG} says the policy outputs environment actions but names "
            "no control mode (env.control)"
        )
    return "env", str(env["control"])


def checkpoint_fps(path: str | Path) -> float | None:
    """The frame rate (frames/s) of the dataset a LeRobot checkpoint was trained on, or None.

    LeRobot's policy config does not store it; ``lerobot-train`` writes ``train_config.json``
    next to it, whose ``dataset`` names the dataset (``root``, else ``repo_id`` under
    ``$HF_LEROBOT_HOME``): the ``fps`` of that dataset's ``meta/info.json``, when it is on this
    machine; else the training config's ``env.fps``."""
    config = _train_config(path)
    if config is None:
        return None
    dataset = config.get("dataset") or {}
    roots = []
    if isinstance(dataset, dict):
        if dataset.get("root"):
            roots.append(Path(str(dataset["root"])).expanduser())
        if isinstance(dataset.get("repo_id"), str):
            roots.append(_lerobot_home() / dataset["repo_id"])
    for root in roots:
        try:
            fps = json.loads((root / "meta" / "info.json").read_text()).get("fps")
        except (OSError, json.JSONDecodeError, AttributeError):
            continue
        if fps:
            return fps
    env = config.get("env")
    if isinstance(env, dict) and env.get("fps"):
        return env["fps"]
    return None


def _lerobot_home() -> Path:
    """Where LeRobot keeps local datasets (``HF_LEROBOT_HOME``; lerobot.utils.constants)."""
    import os

    try:
        from lerobot.utils.constants import HF_LEROBOT_HOME
    except ImportError:
        pass
    else:
        return Path(HF_LEROBOT_HOME)
    if os.environ.get("HF_LEROBOT_HOME"):
        return Path(os.environ["HF_LEROBOT_HOME"]).expanduser()
    hf_home = os.environ.get("HF_HOME", os.path.join("~", ".cache", "huggingface"))
    return Path(hf_home).expanduser() / "lerobot"


def joint_action(env, dataset_action: np.ndarray) -> np.ndarray:
    """The ``joint``-control action that moves ``env``'s servo targets toward the absolute
    ``dataset_action`` (dof joint targets, rad, + gripper opening, m) as far as one step allows."""
    ctl = env.controller
    dof = env.robot.dof
    dataset_action = np.asarray(dataset_action, float)
    if dataset_action.shape != (dof + 1,):
        raise ValueError(f"dataset action must have {dof + 1} entries, got {dataset_action.shape}")
    step = ctl.max_step * ctl.config.joint_speed_fraction
    arm = np.clip((dataset_action[:dof] - ctl.joint_targets) / step, -1.0, 1.0)
    gripper = 1.0 - 2.0 * dataset_action[dof] / env.robot.max_opening
    return np.concatenate([arm, [np.clip(gripper, -1.0, 1.0)]])


# -- loading ----------------------------------------------------------------------------------
def _rl_dir(path: Path) -> Path | None:
    """The directory holding ``wirecraft_rl.json`` that ``path`` is or lies in, if any."""
    start = path if path.is_dir() else path.parent
    for folder in (start, *start.parents):
        if (folder / RL_MARKER).is_file():
            return folder
    return None


def _lerobot_config(path: Path) -> dict | None:
    config = path / "config.json" if path.is_dir() else None
    if config is None or not config.is_file():
        return None
    try:
        data = json.loads(config.read_text())
    except json.JSONDecodeError:
        return None
    return data if isinstance(data, dict) and "type" in data else None


def _unknown(spec: str) -> ValueError:
    return ValueError(
        f"unknown policy {spec!r}: use one of {', '.join(BUILTIN_POLICIES)}, a directory with "
        f"{RL_MARKER} (an RL run), or a LeRobot pretrained-policy directory (config.json with "
        "a 'type')"
    )


def policy_name(spec) -> str:
    """How a policy spec appears in results: the string, or a factory's qualified name."""
    if isinstance(spec, (str, Path)):
        return str(spec)
    return f"{spec.__module__}.{spec.__qualname__}"


# LeRobot's checkpoint layout: RUN/checkpoints/STEP/pretrained_model (STEP: 020000, or last).
LEROBOT_CHECKPOINTS = "checkpoints"
LEROBOT_MODEL_DIR = "pretrained_model"


def policy_label(spec) -> str:
    """A short name of a policy for reports: a built-in's name; for a path, its folder, with
    LeRobot's layout read as the run and the step (``RUN/checkpoints/020000/pretrained_model``
    -> ``RUN/020000``) and a file named with its folder (``RUN/model_500.pt``)."""
    if not isinstance(spec, (str, Path)):
        return policy_name(spec)
    text = str(spec)
    if text in BUILTIN_POLICIES:
        return text
    import os

    parts = [p for p in Path(os.path.abspath(text)).parts if p not in ("/", "")]
    if parts and parts[-1] == LEROBOT_MODEL_DIR and len(parts) > 1:
        parts = parts[:-1]
        if len(parts) > 2 and parts[-2] == LEROBOT_CHECKPOINTS:
            return f"{parts[-3]}/{parts[-1]}"
        return parts[-1]
    if Path(text).is_file() and len(parts) > 1:
        return f"{parts[-2]}/{parts[-1]}"
    return parts[-1] if parts else text


def policy_env_kwargs(spec, task: str) -> dict[str, Any]:
    """Environment keyword arguments the policy ``spec`` needs on ``task`` (control mode,
    observation mode, image size), known before any environment is built.  A factory (a
    class or function taking the environment) declares them as ``env_kwargs`` and/or
    ``control`` attributes."""
    if callable(spec):
        kwargs = dict(getattr(spec, "env_kwargs", None) or {})
        if getattr(spec, "control", None) is not None:
            kwargs.setdefault("control", spec.control)
        return kwargs
    spec = str(spec)
    if spec == "scripted":
        from wirecraft.experts import expert_class

        return {"control": expert_class(task).CONTROL}
    if spec == "reactive":
        from wirecraft.experts.reactive import REACTIVE_EXPERTS

        return {"control": REACTIVE_EXPERTS.get(task).CONTROL, "obs_mode": "state"}
    if spec in ("random", "zero"):
        return {}
    path = Path(spec)
    if not path.exists():
        raise _unknown(spec)
    rl = _rl_dir(path)
    if rl is not None:
        return _rl_env_kwargs(rl)
    config = _lerobot_config(path)
    if config is not None:
        _, control = checkpoint_action(path)
        kwargs: dict[str, Any] = {"control": control, "obs_mode": "state_rgb"}
        for key, feature in (config.get("input_features") or {}).items():
            if key.startswith("observation.images.") and feature.get("shape"):
                kwargs["image_size"] = int(feature["shape"][-1])
        return kwargs
    raise _unknown(spec)


def _rl_env_kwargs(folder: Path) -> dict[str, Any]:
    """What an RL run recorded about its environments (control, observation mode, image
    size), read by the RL package that wrote it."""
    try:
        from wirecraft.rl import policy_env_kwargs as rl_env_kwargs
    except ImportError as err:
        raise RuntimeError(
            f"{folder} is an RL run, but wirecraft.rl cannot be imported ({err}); "
            "install the rl extra: pip install 'wirecraft[rl]'"
        ) from err
    return dict(rl_env_kwargs(folder))


def load_policy(spec, env, **kw) -> Policy:
    """The policy ``spec`` driving ``env`` (a vector environment or a single environment).

    ``scripted``: the task's expert; ``reactive``: its memoryless expert; ``random``;
    ``zero``; or a path: an RL run (a directory containing, or a file inside a directory
    containing, ``wirecraft_rl.json``: loaded by
    ``wirecraft.rl.load_policy(path, env)``) or a LeRobot pretrained-policy directory.
    Extra keywords go to the loader (``device`` and ``fps`` for LeRobot).  ``spec`` may also be a
    factory called as ``spec(env, **kw)`` (a module-level class, so that worker processes
    can import it)."""
    if callable(spec):
        return spec(env, **kw)
    spec = str(spec)
    if spec == "scripted":
        return ScriptedPolicy(env)
    if spec == "reactive":
        return ReactivePolicy(env)
    if spec == "random":
        return RandomPolicy(env)
    if spec == "zero":
        return ZeroPolicy(env)
    path = Path(spec)
    if not path.exists():
        raise _unknown(spec)
    if _rl_dir(path) is not None:
        try:
            from wirecraft.rl import load_policy as load_rl_policy
        except ImportError as err:
            raise RuntimeError(
                f"{spec} is an RL checkpoint, but wirecraft.rl cannot be imported ({err}); "
                "install the rl extra: pip install 'wirecraft[rl]'"
            ) from err
        if kw:
            raise ValueError(f"RL policies take no loader options, got {sorted(kw)}")
        return load_rl_policy(path, env)
    if _lerobot_config(path) is not None:
        try:
            return LeRobotPolicy(path, env, **kw)
        except ImportError as err:
            raise RuntimeError(
                f"{spec} is a LeRobot policy, but lerobot cannot be imported ({err}); "
                "install the data extra: pip install 'wirecraft[data]'"
            ) from err
    raise _unknown(spec)


def policy_phase_names(policy) -> list[str] | None:
    """The policy's per-environment phase names, if it exposes them."""
    getter = getattr(policy, "phase_names", None)
    if getter is None:
        return None
    names = getter() if callable(getter) else getter
    return None if names is None else [str(n) for n in names]


__all__ = [
    "BUILTIN_POLICIES",
    "DatasetActionPolicy",
    "LeRobotPolicy",
    "Policy",
    "RandomPolicy",
    "ReactivePolicy",
    "ScriptedPolicy",
    "ZeroPolicy",
    "checkpoint_action",
    "checkpoint_fps",
    "joint_action",
    "load_policy",
    "policy_env_kwargs",
    "policy_label",
    "policy_name",
    "policy_phase_names",
]
