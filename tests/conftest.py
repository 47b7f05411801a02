"""Test-session set-up that must happen before any test module imports MuJoCo."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

# MuJoCo chooses its OpenGL platform at import; headless machines need EGL (see wirecraft/__init__).
if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
    os.environ["MUJOCO_GL"] = "egl"


@pytest.fixture
def load_benchmark():
    """Imports a script of benchmarks/ or research/ by name (they are scripts, not a package)."""

    def load(name: str):
        root = Path(__file__).resolve().parents[1]
        path = next(
            (p for d in ("benchmarks", "research") if (p := root / d / f"{name}.py").exists()),
            root / "benchmarks" / f"{name}.py",
        )
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    return load


# The quick dataset's settings; tests that build environments or policies to match it read them.
QUICK_SIZE, QUICK_FPS, QUICK_SEED = 32, 10, 7


@pytest.fixture(scope="session")
def quick_dataset(tmp_path_factory) -> Path:
    """Two scripted ethernet-insertion episodes written by ``wirecraft collect`` (32 x 32 px,
    10 fps, seed 7), shared read-only by the LeRobot tests; its parent folder is free for
    their run folders."""
    work = tmp_path_factory.mktemp("quick_dataset")
    root = work / "ds"
    command = [sys.executable, "-m", "wirecraft.cli", "collect", "--task", "insertion"]
    command += ["--connector", "ethernet", "--episodes", "2", "--out", str(root)]
    command += ["--image-size", str(QUICK_SIZE), "--fps", str(QUICK_FPS)]
    command += ["--seed", str(QUICK_SEED), "--workers", "0"]
    env = dict(os.environ, HF_HUB_OFFLINE="1", HF_DATASETS_OFFLINE="1")
    proc = subprocess.run(command, cwd=work, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"collect exited {proc.returncode}:\n{proc.stderr[-4000:]}"
    return root


@pytest.fixture
def saved_actor_means():
    """``(actor_state_dict, inputs) -> actions``: a saved rsl-rl MLP actor (empirical
    normalisation, two ELU hidden layers) evaluated in float64 numpy from its weights alone,
    the mean action clipped to [-1, 1]; an independent check of a loaded policy."""
    import numpy as np

    def forward(state, inputs):
        mean, std = state["obs_normalizer._mean"].double().numpy(), state["obs_normalizer._std"]
        x = (inputs - mean) / (std.double().numpy() + 1e-2)
        for i in (0, 2):
            w = state[f"mlp.{i}.weight"].double().numpy()
            x = x @ w.T + state[f"mlp.{i}.bias"].double().numpy()
            x = np.where(x > 0, x, np.expm1(np.minimum(x, 0)))
        w, b = state["mlp.4.weight"].double().numpy(), state["mlp.4.bias"].double().numpy()
        return np.clip(x @ w.T + b, -1, 1)

    return forward


@pytest.fixture
def sac_tiny() -> dict:
    """SACfD settings for a run of a few dozen env steps on 6-step insertion episodes: two
    environments, small networks, updates and checkpoints within the run."""
    return {
        "num_envs": 2,
        "hidden_dims": (16, 16),
        "batch_size": 16,
        "replay_per_env": 64,
        "warmup_steps": 8,
        "demo_transitions": 24,
        "demo_success_only": False,  # 6-step episodes: the expert cannot finish
        "checkpoint_every_steps": 20,
        "log_every_steps": 10,
        "updates_per_env_step": 0.5,
        "threads": 1,
    }
