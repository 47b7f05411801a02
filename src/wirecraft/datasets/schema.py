"""The one dataset schema that every data source (scripted, rl, teleop, real) writes.

LeRobot v3 features (``features_for``); every feature is documented in docs/datasets.md:

- ``observation.state`` (dof + 1) float32: joint angles (rad) then the gripper pad gap (m)
  (``RobotHandle.dataset_state``);
- ``action`` (dof + 1) float32: the arm servo targets the controller resolved (IK for the
  Cartesian modes; rad) then the commanded pad gap (m) (``Controller.dataset_action``); in a
  dataset of ``action="env"`` it is instead ``action.env`` as float32 (what a policy that
  commands the environment directly learns), the joint targets moving to ``action.joint``;
- ``observation.cartesian_state`` (7,) float32: TCP position (m) and orientation quaternion
  ``(qw, qx, qy, qz)`` (MuJoCo's order, scalar first) in the robot base frame;
- ``observation.images.cam_side`` / ``observation.images.cam_wrist``: RGB videos (H, W, 3);
- ``action.env`` (steps_per_frame * env action dim,) float64: the actions passed to
  ``env.step`` during the frame's control steps, in order (exact replay); NaN where no
  environment was stepped (datasets converted by ``importer``);
- the task's success flags (bool, one per frame): its family's ``metrics.success_flags``
  (``success`` first; insertion adds ``reach_success`` and ``insert_success``);
- ``source`` int64: index into ``SOURCES``; ``seed`` int64: the episode's reset seed (-1: none).
"""

from __future__ import annotations

import numpy as np

from wirecraft.geometry import quat_near

SCHEMA_VERSION = 1
SOURCES = ("scripted", "rl", "teleop", "real")
CAMERAS = {"side": "observation.images.cam_side", "wrist": "observation.images.cam_wrist"}
STATE_KEY = "observation.state"
ACTION_KEY = "action"
CARTESIAN_KEY = "observation.cartesian_state"
ENV_ACTION_KEY = "action.env"
JOINT_ACTION_KEY = "action.joint"
# What a dataset's ``action`` holds: the joint servo targets + pad gap, or the frame's
# environment actions (``action.env``) in the control mode it was collected with.
ACTION_KINDS = ("joint", "env")
SOURCE_KEY = "source"
SEED_KEY = "seed"
NO_SEED = -1
# Arm part of the environment's action per control mode (None: one per joint); + 1 gripper.
ARM_ACTION_DIMS = {"joint": None, "cartesian": 6, "cartesian_fixed": 3}
CARTESIAN_NAMES = ["x", "y", "z", "qw", "qx", "qy", "qz"]


def source_code(source: str) -> int:
    """The integer stored in ``source`` for a data source name."""
    if source not in SOURCES:
        raise ValueError(f"unknown data source {source!r}; valid: {', '.join(SOURCES)}")
    return SOURCES.index(source)


def source_name(code: int) -> str:
    """The data source name of a stored ``source`` integer."""
    code = int(code)
    if not 0 <= code < len(SOURCES):
        raise ValueError(f"unknown data source code {code}; valid: 0..{len(SOURCES) - 1}")
    return SOURCES[code]


def success_flags(task: str) -> tuple[str, ...]:
    """The per-frame success flags of a task family (ValueError for an unknown one)."""
    from wirecraft.tasks import TASKS

    return TASKS.get(task).metrics.success_flags


def check_action_kind(action: str) -> str:
    if action not in ACTION_KINDS:
        raise ValueError(f"unknown action {action!r}; valid: {', '.join(ACTION_KINDS)}")
    return action


def env_action_dim(robot: str, control: str) -> int:
    """Size of the environment's action for ``robot`` under ``control`` (gripper included)."""
    from wirecraft.assets.robots import ROBOTS

    if control not in ARM_ACTION_DIMS:
        raise ValueError(f"unknown control {control!r}; valid: {', '.join(ARM_ACTION_DIMS)}")
    arm = ARM_ACTION_DIMS[control]
    return (ROBOTS.get(robot).dof if arm is None else arm) + 1


def features_for(
    robot: str,
    image_size: int,
    *,
    task: str,
    control: str = "cartesian",
    steps_per_frame: int = 2,
    action: str = "joint",
) -> dict[str, dict]:
    """LeRobot ``features`` of the WireCraft schema for one robot, task family and control mode.

    ``steps_per_frame``: control steps (60 Hz) per recorded frame (2 at 30 fps); ``action``:
    what ``action`` holds (``ACTION_KINDS``)."""
    from wirecraft.assets.robots import ROBOTS

    dof = ROBOTS.get(robot).dof
    if isinstance(image_size, bool) or not isinstance(image_size, int) or image_size < 16:
        raise ValueError(f"image_size must be an integer >= 16, got {image_size!r}")
    if isinstance(steps_per_frame, bool) or not isinstance(steps_per_frame, int):
        raise ValueError(f"steps_per_frame must be an integer, got {steps_per_frame!r}")
    if steps_per_frame < 1:
        raise ValueError(f"steps_per_frame must be >= 1, got {steps_per_frame}")
    check_action_kind(action)
    joints = [f"joint{i + 1}" for i in range(dof)]
    env_dim = env_action_dim(robot, control)
    joint_action = {"dtype": "float32", "shape": (dof + 1,), "names": [*joints, "gripper_gap"]}
    env_names = [f"step{s}_{i}" for s in range(steps_per_frame) for i in range(env_dim)]
    env_shape = (steps_per_frame * env_dim,)
    env_action = {"dtype": "float32", "shape": env_shape, "names": list(env_names)}
    features: dict[str, dict] = {
        STATE_KEY: {"dtype": "float32", "shape": (dof + 1,), "names": [*joints, "gripper_opening"]},
        ACTION_KEY: joint_action if action == "joint" else env_action,
        CARTESIAN_KEY: {"dtype": "float32", "shape": (7,), "names": list(CARTESIAN_NAMES)},
        ENV_ACTION_KEY: {"dtype": "float64", "shape": env_shape, "names": env_names},
    }
    if action == "env":
        features[JOINT_ACTION_KEY] = joint_action
    for camera_key in CAMERAS.values():
        features[camera_key] = {
            "dtype": "video",
            "shape": (image_size, image_size, 3),
            "names": ["height", "width", "channels"],
        }
    for flag in success_flags(task):
        features[flag] = {"dtype": "bool", "shape": (1,), "names": None}
    features[SOURCE_KEY] = {
        "dtype": "int64",
        "shape": (1,),
        "names": None,
        "info": {"codes": {str(i): name for i, name in enumerate(SOURCES)}},
    }
    features[SEED_KEY] = {"dtype": "int64", "shape": (1,), "names": None}
    return features


def cartesian_state(robot, model, data) -> np.ndarray:
    """(7,) TCP position (m) and quaternion (w, x, y, z) in the robot base frame; of q and -q,
    the one nearer the home orientation's (``geometry.quats_near``: w >= 0 would flip the
    sign right at the pointing-down home, where w = 0)."""
    pos, rot = robot.tcp_pose_base(model, data)
    return np.concatenate([pos, quat_near(rot, robot.home_tcp_rot)])
