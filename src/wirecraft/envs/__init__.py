"""Gymnasium environments over the task families."""

from wirecraft.envs.env import CONTROL_HZ, OBS_MODES, WireCraftEnv
from wirecraft.envs.vector import WireCraftVectorEnv, env_seed

__all__ = ["CONTROL_HZ", "OBS_MODES", "WireCraftEnv", "WireCraftVectorEnv", "env_seed"]
