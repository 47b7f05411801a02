"""LeRobot ``EnvConfig`` subclasses, one per registered WireCraft task family.

``--env.type=wirecraft_<family>`` (``wirecraft_insertion``, ``wirecraft_routing``,
``wirecraft_seating``); every field is a command-line option (``--env.connector=usb_a``,
``--env.fps=10``, ...).  The family's task options (``wirecraft.tasks.TaskOptions``) become
fields; left at None they take the task's own default (what ``wirecraft collect`` uses when the
flag is not given).
``features`` / ``features_map`` follow the dataset schema ``wirecraft collect`` writes
(``wirecraft.datasets.schema``): ``observation.state``, ``observation.cartesian_state``,
``observation.images.cam_side`` / ``cam_wrist`` and ``action``.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import dataclass, field
from typing import ClassVar

from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_IMAGES, OBS_STATE

GYM_NAMESPACE = "WireCraftLeRobot"
PACKAGE = "lerobot_env_wirecraft"
CARTESIAN_FEATURE = "observation.cartesian_state"


@dataclass
class WireCraftEnvConfig(EnvConfig):
    """Options shared by every family (not registered itself; ``family_configs`` builds one
    subclass per family)."""

    family: ClassVar[str] = ""
    # Task options each family passes to the environment (None: the task's default).
    task_options: ClassVar[tuple[str, ...]] = ()

    task: str | None = None  # the gymnasium name under GYM_NAMESPACE (set from the family)
    fps: int = 30  # frames per second: one env step = 60 / fps control steps (the dataset's fps)
    episode_length: int | None = None  # frames; None: the task's episode (8 s; routing 8 s/clip)
    robot: str = "ur5"
    wire: str = "articulated"
    image_size: int = 224  # the dataset's --image-size
    # "dataset": actions are the dataset's `action` (joint targets + gripper gap; joint control);
    # "env": the dataset's `action.env` (60 / fps actions of the environment in `control` mode).
    action_type: str = "dataset"
    control: str | None = None  # action_type "env" only; None: the scripted expert's mode
    render_mode: str = "rgb_array"
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        from lerobot_env_wirecraft.env import env_control, pixel_keys, steps_per_frame
        from wirecraft.assets.robots import ROBOTS
        from wirecraft.datasets import schema
        from wirecraft.envs.env import default_episode_seconds

        name = gym_name(self.family)
        if self.task is None:
            self.task = name
        if self.task != name:
            raise ValueError(
                f"{self.type}: task must be {name!r} (pick the family with --env.type), got "
                f"{self.task!r}"
            )
        k = steps_per_frame(self.fps)
        control = env_control(self.family, self.action_type, self.control)
        dof = ROBOTS.get(self.robot).dof
        if self.episode_length is None:
            seconds = default_episode_seconds(self.family, **self.task_kwargs())
            self.episode_length = max(1, int(round(seconds * self.fps)))
        if isinstance(self.episode_length, bool) or self.episode_length < 1:
            raise ValueError(f"episode_length must be >= 1 frame, got {self.episode_length!r}")
        if self.action_type == "dataset":
            action_shape = (dof + 1,)
        else:
            action_shape = (k * schema.env_action_dim(self.robot, control),)
        size = self.image_size
        features = {
            ACTION: PolicyFeature(type=FeatureType.ACTION, shape=action_shape),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(dof + 1,)),
            "cartesian_state": PolicyFeature(type=FeatureType.STATE, shape=(7,)),
        }
        features_map = {
            ACTION: ACTION,
            "agent_pos": OBS_STATE,
            "cartesian_state": CARTESIAN_FEATURE,
        }
        for key in pixel_keys().values():
            features[f"pixels/{key}"] = PolicyFeature(
                type=FeatureType.VISUAL, shape=(size, size, 3)
            )
            features_map[f"pixels/{key}"] = f"{OBS_IMAGES}.{key}"
        assert set(features_map.values()) - {ACTION} <= set(
            schema.features_for(self.robot, size, task=self.family)
        )
        self.features = features
        self.features_map = features_map

    # -- what LeRobot's factory reads -----------------------------------------------------------
    @property
    def package_name(self) -> str:
        return PACKAGE

    @property
    def gym_id(self) -> str:
        return f"{GYM_NAMESPACE}/{self.task}"

    def task_kwargs(self) -> dict:
        """The task options given (None: left to the task's default)."""
        return {n: getattr(self, n) for n in self.task_options if getattr(self, n) is not None}

    @property
    def gym_kwargs(self) -> dict:
        return {
            "fps": self.fps,
            "action_type": self.action_type,
            "control": self.control,
            "robot": self.robot,
            "wire": self.wire,
            "image_size": self.image_size,
            "render_mode": self.render_mode,
            # The episode's frames, twice: gymnasium's TimeLimit (LeRobot reads its
            # _max_episode_steps) and the environment's own end, at the same frame.
            "max_episode_steps": self.episode_length,
            "episode_seconds": self.episode_length / self.fps,
            **self.task_kwargs(),
        }


def gym_name(family: str) -> str:
    """The family's gymnasium name under ``GYM_NAMESPACE``: WireCraft's own id's name."""
    from wirecraft.tasks import TASKS

    return TASKS.get(family).gym_id.split("/", 1)[1]


def _optional(hint):
    return hint if types.NoneType in typing.get_args(hint) else hint | None


def family_configs() -> dict[str, type[WireCraftEnvConfig]]:
    """One registered ``EnvConfig`` subclass per WireCraft task family (``wirecraft_<family>``),
    whose extra fields are the family's task options, each None by default."""
    from wirecraft.tasks import TASKS

    configs = {}
    for family in TASKS:
        env_type = f"wirecraft_{family}"
        try:
            configs[family] = EnvConfig.get_choice_class(env_type)
            continue
        except KeyError:
            pass
        options = TASKS.get(family).Options
        hints = typing.get_type_hints(options)
        fields = [
            (f.name, _optional(hints[f.name]), field(default=None))
            for f in dataclasses.fields(options)
        ]
        title = "".join(part.capitalize() for part in family.split("_"))
        cls = dataclasses.make_dataclass(
            f"WireCraft{title}Env", fields, bases=(WireCraftEnvConfig,), module=__name__
        )
        cls.family = family
        cls.task_options = tuple(name for name, _, _ in fields)
        configs[family] = EnvConfig.register_subclass(env_type)(cls)
    return configs
