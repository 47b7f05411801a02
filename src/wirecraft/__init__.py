"""WireCraft: a simulation benchmark for wire and cable manipulation on MuJoCo.

``import wirecraft`` registers the gymnasium ids; ``wirecraft.make(task, **kwargs)`` builds one.
"""

from __future__ import annotations

import os

# MuJoCo picks its OpenGL platform when it is first imported; without a display, GLFW would
# fail, so default to EGL (Mesa's software renderer on a CPU-only machine).
if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
    os.environ["MUJOCO_GL"] = "egl"

import logging  # noqa: E402

import gymnasium as gym  # noqa: E402
import mujoco  # noqa: E402

# MuJoCo's warnings go to logging, not to a MUJOCO_LOG.TXT in the working folder.
mujoco.set_mju_user_warning(logging.getLogger("wirecraft.mujoco").warning)

__version__ = "0.1.0"

EPISODE_STEPS = 480  # 8 s at 60 Hz


def register_gym_ids() -> dict[str, str]:
    """Register every task family of ``wirecraft.tasks.TASKS`` (one registered after import
    too) with gymnasium; returns family -> gymnasium id.

    The registered specs leave max_episode_steps None: the length depends on the task options
    (episode_seconds, max_episode_steps, a family's own length such as routing's per clip), and
    the environment keeps it itself, so that no TimeLimit wrapper with another length sits on
    top.  A made environment's env.spec.max_episode_steps is its length (480 by default);
    gymnasium.make(id, max_episode_steps=N) sets it.  gymnasium.make_vec(id, n, **kwargs) builds
    make_vec's batched vector environment (the vector entry point, gymnasium's default where
    there is one)."""
    from wirecraft.tasks import TASKS

    ids = {}
    for family in TASKS:
        gym_id = ids[family] = TASKS.get(family).gym_id
        if gym_id not in gym.registry:
            gym.register(
                id=gym_id,
                entry_point="wirecraft.envs:WireCraftEnv",
                vector_entry_point="wirecraft:vector_entry_point",
                kwargs={"task": family},
                disable_env_checker=True,
            )
    return ids


# Task family -> gymnasium id, as registered on import.
TASK_IDS = register_gym_ids()


def family_of(task: str) -> str:
    """The family name of ``task`` (a family or its gymnasium id); ValueError listing both."""
    ids = register_gym_ids()
    for family, gym_id in ids.items():
        if task in (family, gym_id):
            return family
    valid = ", ".join([*ids, *ids.values()])
    raise ValueError(f"unknown task {task!r}; valid: {valid}")


def make(task: str, **kwargs) -> gym.Env:
    """Build a WireCraft environment: ``task`` is a family (``wirecraft.tasks.TASKS``) or its
    gymnasium id."""
    from wirecraft import validation
    from wirecraft.envs.env import RENDER_MODES

    task_id = register_gym_ids()[family_of(task)]
    # gym.make reads render_mode before the environment can check it.
    validation.one_of("WireCraftEnv", "render_mode", kwargs.get("render_mode"), RENDER_MODES)
    return gym.make(task_id, **kwargs)


# cpu: MuJoCo's batch engine on C threads; warp: MuJoCo Warp (GPU, or its CPU device).
BACKENDS = ("cpu", "warp")
ARRAY_TYPES = ("numpy", "torch")


def make_vec(
    task: str,
    num_envs: int,
    backend: str = "cpu",
    threads: int = 0,
    arrays: str = "numpy",
    device=None,
    **kwargs,
):
    """``num_envs`` environments of ``task`` whose physics steps on ``threads`` C threads
    (0: all CPUs) with MuJoCo's batch engine; a gymnasium VectorEnv (SAME_STEP autoreset).

    ``backend="warp"``: the physics steps on MuJoCo Warp on ``device`` (a Warp device:
    ``"cuda:0"``, or ``"cpu"`` for tests; default Warp's preferred one), the task's code on the
    host (``wirecraft.envs.warp_batch``); ``warp_nconmax`` / ``warp_njmax`` size its contact
    and constraint buffers per world;
    ``warp_solver="cg"`` replaces Newton (whose float32 steps are retried with CG where they
    go non-finite) by CG throughout.  Needs ``pip install wirecraft[gpu]``.

    ``arrays="torch"`` returns observations, rewards and flags as torch tensors (on ``device``,
    default the CPU, where they share memory with the numpy arrays) and accepts tensor
    actions; infos stay numpy.  Needs torch (``pip install wirecraft[rl]``)."""
    from wirecraft.envs.vector import WireCraftVectorEnv

    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; valid: {', '.join(BACKENDS)}")
    if arrays not in ARRAY_TYPES:
        raise ValueError(f"unknown arrays {arrays!r}; valid: {', '.join(ARRAY_TYPES)}")
    if device is not None and arrays != "torch" and backend != "warp":
        raise ValueError(
            f"make_vec: device={device!r} is for arrays='torch' or backend='warp' only"
        )
    warp = {"device": device} if backend == "warp" else {}
    env = WireCraftVectorEnv(
        family_of(task), num_envs, threads=threads, backend=backend, **warp, **kwargs
    )
    if arrays == "torch":
        from wirecraft.envs.vector import TorchArrays

        env = TorchArrays(env, device=device)
    return env


def vector_entry_point(num_envs: int, task: str, **kwargs):
    """``gymnasium.make_vec(id, num_envs, **kwargs)``'s builder (``vectorization_mode``
    ``"vector_entry_point"``, the default for these ids): ``make_vec(task, num_envs, **kwargs)``."""
    return make_vec(task, num_envs, **kwargs)


__all__ = [
    "ARRAY_TYPES",
    "BACKENDS",
    "TASK_IDS",
    "family_of",
    "make",
    "make_vec",
    "register_gym_ids",
    "vector_entry_point",
]
