"""WireCraft as a LeRobot environment plug-in.

LeRobot imports this package at start-up (its distribution name starts with ``lerobot_env_``);
importing it registers one ``EnvConfig`` per registered WireCraft task family
(``wirecraft_insertion``, ``wirecraft_routing``, ``wirecraft_seating``, built from each
family's task options) and their gymnasium ids (``WireCraftLeRobot/ConnectorInsertion-v0``,
...).  See docs/lerobot.md.
"""

from __future__ import annotations

import gymnasium as gym

from lerobot_env_wirecraft.configs import (
    GYM_NAMESPACE,
    WireCraftEnvConfig,
    family_configs,
    gym_name,
)
from wirecraft.lerobot_compat import quiet_torchcodec

# lerobot-train and lerobot-eval import this plug-in before they build a dataset configuration,
# which would otherwise log torchcodec's loading traceback where FFmpeg is missing.
quiet_torchcodec()

CONFIGS = family_configs()
for _family in CONFIGS:
    _id = f"{GYM_NAMESPACE}/{gym_name(_family)}"
    if _id not in gym.registry:
        gym.register(
            id=_id,
            entry_point="lerobot_env_wirecraft.env:WireCraftLeRobotEnv",
            kwargs={"task": _family},
            disable_env_checker=True,
        )

__all__ = ["CONFIGS", "GYM_NAMESPACE", "WireCraftEnvConfig", "family_configs", "gym_name"]
