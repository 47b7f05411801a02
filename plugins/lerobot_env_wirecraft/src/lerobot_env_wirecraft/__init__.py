"""WireCraft as a LeRobot environment plug-in.

LeRobot imports this package at start-up (its distribution name starts with ``lerobot_env_``);
importing it registers one ``EnvConfig`` per WireCraft task family (``wirecraft_insertion``,
``wirecraft_routing``, ``wirecraft_seating``) and their gymnasium ids
(``WireCraftLeRobot/ConnectorInsertion-v0``, ...).  Importing it is cheap: wirecraft itself is
imported only when a configuration is built.  See docs/lerobot.md.
"""

from __future__ import annotations

import gymnasium as gym

from lerobot_env_wirecraft.configs import (
    GYM_NAMESPACE,
    TASK_NAMES,
    WireCraftEnvConfig,
    WireCraftInsertionEnv,
    WireCraftRoutingEnv,
    WireCraftSeatingEnv,
)
from wirecraft.lerobot_compat import quiet_torchcodec

# lerobot-train and lerobot-eval import this plug-in before they build a dataset configuration,
# which would otherwise log torchcodec's loading traceback where FFmpeg is missing.
quiet_torchcodec()

for _family, _name in TASK_NAMES.items():
    _id = f"{GYM_NAMESPACE}/{_name}"
    if _id not in gym.registry:
        gym.register(
            id=_id,
            entry_point="lerobot_env_wirecraft.env:WireCraftLeRobotEnv",
            kwargs={"task": _family},
            disable_env_checker=True,
        )

__all__ = [
    "GYM_NAMESPACE",
    "TASK_NAMES",
    "WireCraftEnvConfig",
    "WireCraftInsertionEnv",
    "WireCraftRoutingEnv",
    "WireCraftSeatingEnv",
]
