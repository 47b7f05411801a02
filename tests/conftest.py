"""Test-session set-up that must happen before any test module imports MuJoCo."""

from __future__ import annotations

import os

# MuJoCo chooses its OpenGL platform at import; headless machines need EGL (see wirecraft/__init__).
if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
    os.environ["MUJOCO_GL"] = "egl"
