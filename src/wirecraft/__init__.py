"""WireCraft: a simulation benchmark for wire and cable manipulation on MuJoCo."""

from __future__ import annotations

import os

# MuJoCo picks its OpenGL platform when it is first imported; without a display, GLFW would
# fail, so default to EGL (Mesa's software renderer on a CPU-only machine).
if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
    os.environ["MUJOCO_GL"] = "egl"

__version__ = "0.1.0"
