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

from wirecraft.experts.fsm import unwrap_envs

BUILTIN_POLICIES = ("scripted", "random", "zero")
RL_MARKER = "wirecraft_rl.json"
# What an RL policy fixes about its environments (its observation and action spaces).
# LeRobot camera feature -> our observation key (the dataset schema's camera names).
LEROBOT_CAMERAS = {"cam_side": "rgb_side", "cam_wrist": "rgb_wrist"}


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


class LeRobotPolicy:
    """A LeRobot pretrained policy (``PreTrainedPolicy.from_pretrained``) on our environments.

    Observations (``obs_mode="state_rgb"``) map onto the WireCraft dataset schema:
    ``observation.state`` = arm joint positions + gripper opening (the first dof + 1 entries of
    ``proprio``), ``observation.images.cam_side`` / ``cam_wrist`` = ``rgb_side`` /
    ``rgb_wrist`` (channels first, floats in [0, 1]), ``task`` = the instruction.  The policy's
    action is the dataset action: absolute arm joint targets (rad) + gripper opening (m), which
    the adapter turns into ``joint``-control actions (per-step target deltas over the joints'
    rated step, clipped to [-1, 1]; gripper command = 1 - 2 opening / max opening).
    """

    control = "joint"

    def __init__(self, path: str | Path, env, device: str = "cpu") -> None:
        import torch
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors

        self.torch = torch
        self.envs = unwrap_envs(env)
        for e in self.envs:
            if e.controller.name != "joint":
                raise ValueError("a LeRobot policy needs environments with control='joint'")
            if e.obs_mode != "state_rgb":
                raise ValueError("a LeRobot policy needs environments with obs_mode='state_rgb'")
        path = str(path)
        config = PreTrainedConfig.from_pretrained(path)
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

    def reset(self, env_ids=None) -> None:
        # LeRobot policies keep one action queue for the whole batch: any reset restarts it.
        del env_ids
        self.policy.reset()

    def _batch(self, obs) -> dict[str, Any]:
        torch = self.torch
        batch: dict[str, Any] = {}
        dof = self.envs[0].robot.dof
        if self.uses_state:
            state = np.asarray(obs["proprio"])[:, : dof + 1]
            batch["observation.state"] = torch.as_tensor(state, dtype=torch.float32)
        for key in self.image_keys:
            images = np.asarray(obs[LEROBOT_CAMERAS[key.split(".")[-1]]])
            tensor = torch.as_tensor(images).permute(0, 3, 1, 2).float() / 255.0
            batch[key] = tensor
        batch["task"] = [env.task_description for env in self.envs]
        return batch

    def act(self, obs) -> np.ndarray:
        with self.torch.inference_mode():
            action = self.post(self.policy.select_action(self.pre(self._batch(obs))))
        targets = np.asarray(action.detach().cpu().numpy(), dtype=float)
        targets = targets.reshape(len(self.envs), -1)
        rows = zip(self.envs, targets, strict=True)
        return np.stack([joint_action(env, row) for env, row in rows])


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
        kwargs: dict[str, Any] = {"control": "joint", "obs_mode": "state_rgb"}
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

    ``scripted``: the task's expert; ``random``; ``zero``; or a path: an RL run (a directory
    containing, or a file inside a directory containing, ``wirecraft_rl.json``: loaded by
    ``wirecraft.rl.load_policy(path, env)``) or a LeRobot pretrained-policy directory.
    Extra keywords go to the loader (e.g. ``device`` for LeRobot).  ``spec`` may also be a
    factory called as ``spec(env, **kw)`` (a module-level class, so that worker processes
    can import it)."""
    if callable(spec):
        return spec(env, **kw)
    spec = str(spec)
    if spec == "scripted":
        return ScriptedPolicy(env)
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
    "LeRobotPolicy",
    "Policy",
    "RandomPolicy",
    "ScriptedPolicy",
    "ZeroPolicy",
    "joint_action",
    "load_policy",
    "policy_env_kwargs",
    "policy_name",
    "policy_phase_names",
]
