"""Gymnasium environments over the task families."""

from wirecraft.envs.env import CONTROL_HZ, OBS_MODES, WireCraftEnv

__all__ = ["CONTROL_HZ", "OBS_MODES", "WireCraftEnv"]
