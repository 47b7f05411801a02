"""The LeRobot environment plug-in (plugins/lerobot_env_wirecraft): ``--env.type=wirecraft_*``.

- LeRobot's plug-in discovery finds the three task families;
- LeRobot's ``make_env`` builds and steps each, with the dataset schema's observation keys;
- one plug-in step is one dataset frame: replaying a ``wirecraft collect`` episode's
  ``action.env`` reproduces its ``observation.state`` / ``observation.cartesian_state`` exactly
  and ends successful;
- end to end, offline: ``wirecraft collect`` -> ``lerobot-train`` (a tiny ACT without a
  pretrained backbone, evaluating in the environment during training) -> ``lerobot-eval``.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("lerobot", reason="LeRobot is not installed (pip install 'wirecraft[data]')")

PLUGIN = "lerobot_env_wirecraft"
FAMILIES = {
    "wirecraft_insertion": "insertion",
    "wirecraft_routing": "routing",
    "wirecraft_seating": "seating",
}
SIZE, FPS, SEED = 32, 10, 7  # small images, 6 control steps per frame
BIN = Path(sys.executable).parent


def _plugin_installed() -> bool:
    try:
        importlib.metadata.distribution(PLUGIN)
    except importlib.metadata.PackageNotFoundError:
        return False
    return True


pytestmark = pytest.mark.skipif(
    not _plugin_installed(),
    reason=f"the {PLUGIN} distribution is not installed (make install, or "
    f"pip install -e plugins/{PLUGIN}): LeRobot discovers plug-ins by installed distribution",
)


@pytest.fixture(scope="module", autouse=True)
def plugins():
    """What LeRobot's scripts do at start-up: import every installed plug-in."""
    from lerobot.utils.import_utils import register_third_party_plugins

    register_third_party_plugins()


def _offline_env() -> dict:
    env = dict(os.environ)
    env.update(HF_HUB_OFFLINE="1", HF_DATASETS_OFFLINE="1", WANDB_MODE="disabled")
    return env


def _run(args, cwd, timeout=300) -> subprocess.CompletedProcess:
    proc = subprocess.run(
        [str(a) for a in args],
        cwd=cwd,
        env=_offline_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert proc.returncode == 0, (
        f"{args[0]} exited {proc.returncode}:\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}"
    )
    return proc


def _env_config(env_type: str, **kwargs):
    from lerobot.envs.factory import make_env_config

    return make_env_config(env_type, **{"image_size": SIZE, "fps": FPS, **kwargs})


def _vector_env(cfg):
    from lerobot.envs.factory import make_env

    envs = make_env(cfg, n_envs=1, use_async_envs=False)
    return envs[cfg.type][0]


# -- discovery and the environments -----------------------------------------------------------
def test_lerobot_discovers_the_three_task_families():
    from lerobot.envs.configs import EnvConfig
    from lerobot.utils.import_utils import register_third_party_plugins

    register_third_party_plugins()
    assert set(FAMILIES) <= set(EnvConfig.get_known_choices())


@pytest.mark.parametrize("env_type", sorted(FAMILIES))
def test_make_env_builds_and_steps_each_family(env_type):
    import gymnasium as gym
    from lerobot.envs.utils import env_to_policy_features, preprocess_observation

    import wirecraft
    from wirecraft.datasets import schema

    cfg = _env_config(env_type, episode_length=3)
    family = FAMILIES[env_type]
    vec = _vector_env(cfg)
    try:
        assert isinstance(vec, gym.vector.SyncVectorEnv)
        obs, info = vec.reset(seed=[SEED], options={"lerobot_new_rollout": True})
        # LeRobot's key conventions give the dataset's feature names and shapes.
        batch = preprocess_observation(obs)
        features = schema.features_for("ur5", SIZE, task=family)
        policy_features = env_to_policy_features(cfg)
        for key, feature in policy_features.items():
            if key == "action":
                assert feature.shape == features["action"]["shape"]
                continue
            assert key in batch and key in features, key
            image = key.startswith("observation.images.")
            expected = (3, SIZE, SIZE) if image else features[key]["shape"]
            assert tuple(batch[key].shape[1:]) == tuple(expected) == tuple(feature.shape), key
        instruction = wirecraft.make(family).unwrapped.task.instruction
        assert list(vec.call("task_description")) == [instruction]
        assert vec.call("_max_episode_steps")[0] == 3
        assert vec.metadata["render_fps"] == FPS
        assert vec.envs[0].render().shape == (SIZE, SIZE, 3)
        for _ in range(3):
            # Hold the current joints and gripper gap: the dataset action of standing still.
            obs, reward, terminated, truncated, info = vec.step(obs["agent_pos"].astype(float))
            assert np.all(np.isfinite(reward)) and not terminated[0]
        assert truncated[0]
        assert "is_success" in info["final_info"]
        assert not info["final_info"]["is_success"][0]
    finally:
        vec.close()


def test_bad_options_are_clear_errors():
    with pytest.raises(ValueError, match="fps must divide"):
        _env_config("wirecraft_insertion", fps=7)
    with pytest.raises(ValueError, match="joint control"):
        _env_config("wirecraft_insertion", control="cartesian")
    with pytest.raises(ValueError, match="action_type"):
        _env_config("wirecraft_insertion", action_type="torque")


# -- a dataset, and the frames it holds --------------------------------------------------------
@pytest.fixture(scope="module")
def dataset(quick_dataset):
    """Two scripted insertion episodes written by ``wirecraft collect`` (conftest)."""
    return quick_dataset


def test_one_step_is_one_dataset_frame(dataset):
    """``action_type="env"`` replays the stored ``action.env`` of a frame in one step; the
    observations are the dataset's, frame by frame, bit for bit."""
    from wirecraft.datasets.writer import load_dataset

    ds = load_dataset(dataset)
    table = ds.hf_dataset.with_format("arrow")[:]
    episodes = table.column("episode_index").to_numpy()
    rows = np.flatnonzero(episodes == 0)

    def col(key):
        values = table.column(key).to_numpy(zero_copy_only=False)[rows]
        return np.stack(values).reshape(len(rows), -1)

    state, cartesian = col("observation.state"), col("observation.cartesian_state")
    env_actions, success = col("action.env"), col("success")[:, 0]
    seed = int(col("seed")[0, 0])
    assert len(rows) > 10
    cfg = _env_config("wirecraft_insertion", connector="ethernet", action_type="env")
    vec = _vector_env(cfg)
    try:
        obs, _ = vec.reset(seed=[seed])
        for t in range(len(rows)):
            np.testing.assert_array_equal(obs["agent_pos"][0], state[t])
            np.testing.assert_array_equal(obs["cartesian_state"][0], cartesian[t])
            obs, _, _, _, info = vec.step(env_actions[t][None])
        assert success[-1] and info["is_success"][0]
    finally:
        vec.close()


def test_dataset_actions_replay_the_demonstration(dataset):
    """The default ``action_type="dataset"``: the stored ``action`` (joint targets + gripper
    gap), held for its frame through ``joint_action``, replays the scripted demonstrations
    open loop: the joints stay near the recorded ones and the plug ends inserted."""
    from wirecraft.datasets.writer import load_dataset

    table = load_dataset(dataset).hf_dataset.with_format("arrow")[:]
    episodes = table.column("episode_index").to_numpy()
    cfg = _env_config("wirecraft_insertion", connector="ethernet")
    vec = _vector_env(cfg)
    try:
        for episode in (0, 1):
            rows = np.flatnonzero(episodes == episode)

            def col(key, rows=rows):
                values = table.column(key).to_numpy(zero_copy_only=False)[rows]
                return np.stack(values).reshape(len(rows), -1)

            state, action = col("observation.state"), col("action")
            obs, _ = vec.reset(seed=[int(col("seed")[0, 0])])
            error = 0.0
            for t in range(len(rows)):
                error = max(error, float(np.abs(obs["agent_pos"][0] - state[t]).max()))
                obs, _, _, _, info = vec.step(action[t][None].astype(float))
            assert error < 0.1, error  # rad (and m for the gripper)
            assert info["is_success"][0]
    finally:
        vec.close()


# -- lerobot-train and lerobot-eval, offline -----------------------------------------------------
TINY_ACT = [
    "--policy.type=act",
    "--policy.device=cpu",
    "--policy.push_to_hub=false",
    "--policy.pretrained_backbone_weights=null",  # no ImageNet download
    "--policy.dim_model=32",
    "--policy.n_heads=2",
    "--policy.dim_feedforward=64",
    "--policy.n_encoder_layers=1",
    "--policy.n_decoder_layers=1",
    "--policy.chunk_size=5",
    "--policy.n_action_steps=5",
    "--policy.use_vae=false",
]
# The policy reads the state and both cameras; observation.cartesian_state stays in the dataset.
INPUTS = {
    "observation.state": {"type": "STATE", "shape": [7]},
    "observation.images.cam_side": {"type": "VISUAL", "shape": [3, SIZE, SIZE]},
    "observation.images.cam_wrist": {"type": "VISUAL", "shape": [3, SIZE, SIZE]},
}
ENV_ARGS = [
    f"--env.image_size={SIZE}",
    f"--env.fps={FPS}",
    "--env.connector=ethernet",
    "--env.episode_length=6",
]


@pytest.fixture(scope="module")
def trained(dataset):
    """A tiny ACT trained for 2 steps, evaluated once in the environment at step 2."""
    if importlib.util.find_spec("accelerate") is None:
        pytest.skip("lerobot-train needs accelerate: pip install 'wirecraft[il]' (make install)")
    out = dataset.parent / "train"
    proc = _run(
        [
            BIN / "lerobot-train",
            "--dataset.repo_id=wirecraft/local",
            f"--dataset.root={dataset}",
            "--dataset.video_backend=pyav",
            *TINY_ACT,
            f"--policy.input_features={json.dumps(INPUTS)}",
            "--batch_size=4",
            "--steps=2",
            "--save_freq=2",
            "--log_freq=1",
            "--num_workers=0",
            "--wandb.enable=false",
            f"--output_dir={out}",
            "--env.type=wirecraft_insertion",
            *ENV_ARGS,
            "--env_eval_freq=2",
            "--eval.n_episodes=1",
            "--eval.batch_size=1",
        ],
        cwd=dataset.parent,
    )
    return out, proc.stdout + proc.stderr


def test_lerobot_train_evaluates_in_the_environment(trained):
    out, log = trained
    assert "Eval policy at step 2" in log
    assert "pc_success" in log
    videos = list((out / "eval").rglob("*.mp4"))
    assert videos, "no evaluation video"
    config = json.loads(
        (out / "checkpoints" / "last" / "pretrained_model" / "config.json").read_text()
    )
    assert set(config["input_features"]) == set(INPUTS)
    assert config["output_features"]["action"]["shape"] == [7]


def test_lerobot_eval_runs_a_trained_checkpoint(trained):
    out, _ = trained
    checkpoint = out / "checkpoints" / "last" / "pretrained_model"
    results = out.parent / "eval"
    _run(
        [
            BIN / "lerobot-eval",
            "--env.type=wirecraft_insertion",
            *ENV_ARGS,
            f"--policy.path={checkpoint}",
            "--policy.device=cpu",
            "--eval.n_episodes=1",
            "--eval.batch_size=1",
            f"--output_dir={results}",
        ],
        cwd=out.parent,
    )
    info = json.loads((results / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1
    assert 0.0 <= info["overall"]["pc_success"] <= 100.0
