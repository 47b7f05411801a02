"""Test-session set-up that must happen before any test module imports MuJoCo."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest

# MuJoCo chooses its OpenGL platform at import; headless machines need EGL (see wirecraft/__init__).
if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
    os.environ["MUJOCO_GL"] = "egl"


@pytest.fixture
def load_benchmark():
    """Imports a script of benchmarks/ by name (they are scripts, not a package)."""

    def load(name: str):
        path = Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    return load
