"""Datasets whose ``action`` is the environment's own command (``wirecraft collect --action
env``), and the imitation policies trained on them.

The truth: the scripted expert's episodes themselves.  Each frame's ``action`` must be the
frame's recorded environment actions (``action.env``), and its ``action.joint`` what a
default dataset of the same seeds stores as ``action``; replaying the ``action`` column
through the adapter LeRobot policies use, in the dataset's control mode, must seat the plug
wherever the expert seated it.  A tiny ACT trained on such a dataset by ``wirecraft train``
must then run in that control mode, and refuse environments of another.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

import wirecraft
from wirecraft.datasets import schema
from wirecraft.datasets.collect import CollectSettings, collect
from wirecraft.datasets.mix import check_compatible, read_input
from wirecraft.datasets.writer import load_dataset
from wirecraft.envs.env import CONTROL_HZ
from wirecraft.evaluation import protocol
from wirecraft.evaluation.policies import DatasetActionPolicy, load_policy, policy_env_kwargs
from wirecraft.evaluation.protocol import EpisodeSpec, EvalConfig, run_chunk

FPS = 10
K = CONTROL_HZ // FPS
SETTINGS = CollectSettings(
    task="insertion",
    env_kwargs={"connector": "ethernet"},
    image_size=32,
    fps=FPS,
    seed=3,
    action="env",
)


def test_the_action_feature_follows_the_action_kind():
    joint = schema.features_for("panda", 32, task="insertion", control="cartesian")
    env = schema.features_for(
        "panda", 32, task="insertion", control="cartesian", steps_per_frame=K, action="env"
    )
    assert joint[schema.ACTION_KEY]["shape"] == (8,) and schema.JOINT_ACTION_KEY not in joint
    assert env[schema.ACTION_KEY]["shape"] == (K * 7,)
    assert env[schema.ACTION_KEY]["dtype"] == "float32"
    assert env[schema.ACTION_KEY]["names"] == env[schema.ENV_ACTION_KEY]["names"]
    assert env[schema.JOINT_ACTION_KEY] == joint[schema.ACTION_KEY]
    with pytest.raises(ValueError, match="unknown action 'cartesian'"):
        schema.features_for("ur5", 32, task="insertion", action="cartesian")
    with pytest.raises(ValueError, match="unknown action"):
        dataclasses.replace(SETTINGS, action="delta")


def _columns(root, keys):
    table = load_dataset(root).hf_dataset.with_format("arrow")[:]
    index = table.column("episode_index").to_numpy()
    columns = {
        key: np.stack(table.column(key).to_numpy(zero_copy_only=False)).reshape(len(index), -1)
        for key in keys
    }
    return index, columns


@pytest.fixture(scope="module")
def env_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("env_actions") / "ds"
    assert collect(SETTINGS, root, 3, workers=0, progress_bar=False).saved == 3
    return root


def test_the_action_is_the_frames_environment_actions_and_the_joint_targets_stay(
    env_dataset, tmp_path
):
    keys = ("action", "action.env", "action.joint", "seed")
    index, env_cols = _columns(env_dataset, keys)
    assert np.array_equal(env_cols["action"], env_cols["action.env"].astype(np.float32))
    joint_root = tmp_path / "joint"
    joint_settings = dataclasses.replace(SETTINGS, action="joint")
    assert collect(joint_settings, joint_root, 1, workers=0, progress_bar=False).saved == 1
    joint_index, joint_cols = _columns(joint_root, ("action", "action.env", "seed"))
    first = index == 0
    assert joint_cols["seed"][0, 0] == env_cols["seed"][first][0, 0]
    # The same episode: the same environment actions, and the joint targets moved aside.
    assert np.array_equal(joint_cols["action.env"], env_cols["action.env"][first])
    assert np.array_equal(joint_cols["action"], env_cols["action.joint"][first])
    settings = json.loads((env_dataset / "meta" / "wirecraft_collect.json").read_text())
    assert settings["settings"]["action"] == "env"
    with pytest.raises(ValueError, match="action.joint only in"):
        check_compatible([read_input(env_dataset), read_input(joint_root)])


def test_resuming_with_the_other_action_kind_is_refused(env_dataset, tmp_path):
    copy = tmp_path / "ds"
    shutil.copytree(env_dataset, copy)
    joint_settings = dataclasses.replace(SETTINGS, action="joint")
    with pytest.raises(ValueError, match="action: 'env' -> 'joint'"):
        collect(joint_settings, copy, 4, workers=0, resume=True, progress_bar=False)


class EnvActionReplay(DatasetActionPolicy):
    """The dataset's ``action`` rows in order, one per frame, through the LeRobot adapter."""

    def __init__(self, env, actions, fps):
        super().__init__(env, fps, action="env")
        self.actions = np.asarray(actions, dtype=float)
        self.queries: list[tuple[int, np.ndarray]] = []

    def reset(self, env_ids=None) -> None:
        super().reset(env_ids)
        self.queries = []

    def frame_actions(self, obs) -> np.ndarray:
        env = self.envs[0]
        self.queries.append((self._step, env.robot.dataset_state(env.model, env.data)))
        return self.actions[min(len(self.queries), len(self.actions)) - 1][None]


def test_replaying_the_action_column_in_the_datasets_control_mode_seats_every_plug(
    env_dataset,
):
    index, cols = _columns(env_dataset, ("action", "observation.state", "seed", "insert_success"))
    for episode in np.unique(index):
        rows = np.flatnonzero(index == episode)
        assert cols["insert_success"][rows].any()  # the expert seated it
        config = EvalConfig(
            task="insertion",
            policy=EnvActionReplay,
            env_kwargs={"connector": "ethernet", "control": "cartesian"},
            horizon=len(rows) * K,
            batch=1,
            policy_kwargs={"actions": cols["action"][rows].tolist(), "fps": FPS},
        )
        seed = int(cols["seed"][rows[0], 0])
        [result] = run_chunk(config, [EpisodeSpec(0, 0, seed)])
        assert result.summary["insert_success"]
        _, policy = protocol.environment_and_policy(config)
        assert policy.control == "cartesian"
        assert [step for step, _ in policy.queries] == list(range(0, K * len(rows), K))
        assert np.allclose(policy.queries[0][1], cols["observation.state"][rows[0]], atol=1e-6)


needs_training = pytest.mark.skipif(
    importlib.util.find_spec("lerobot") is None or importlib.util.find_spec("accelerate") is None,
    reason="lerobot-train needs the il extra: pip install 'wirecraft[il]'",
)
TINY_ACT = [
    "dim_model=32", "n_heads=2", "dim_feedforward=64", "n_encoder_layers=1",
    "n_decoder_layers=1", "chunk_size=5", "n_action_steps=5", "use_vae=false",
]  # fmt: skip


@needs_training
@pytest.mark.slow
def test_a_policy_trained_on_environment_actions_commands_the_environment(env_dataset):
    run = env_dataset.parent / "act"
    command = [sys.executable, "-m", "wirecraft.cli", "train", "act", "--dataset", env_dataset]
    command += ["--out", run, "--device", "cpu", "--steps", "2", "--batch-size", "4"]
    for arg in TINY_ACT:
        command += ["--policy-arg", arg]
    for arg in ("save_freq=2", "num_workers=0", "env_eval_freq=0"):
        command += ["--train-arg", arg]
    proc = subprocess.run(
        [str(c) for c in command], capture_output=True, text=True, timeout=600,
        env={**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"},
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-4000:]
    model = run / "checkpoints" / "last" / "pretrained_model"
    config = json.loads((model / "config.json").read_text())
    assert config["output_features"]["action"]["shape"] == [K * 7]
    assert json.loads((run / "wirecraft_il.json").read_text())["action"] == "env"

    kwargs = policy_env_kwargs(str(model), "insertion")
    assert kwargs["control"] == "cartesian"
    payload = protocol.evaluate(
        "insertion",
        str(model),
        seeds=1,
        episodes=1,
        episode_seconds=3 * K / CONTROL_HZ,
        progress=False,
    )
    assert payload["env_kwargs"]["control"] == "cartesian"
    assert payload["episodes"][0]["steps"] == 3 * K

    joint_env = wirecraft.make_vec(
        "insertion", 1, threads=1, control="joint", obs_mode="state_rgb", image_size=32
    )
    with pytest.raises(ValueError, match="control='cartesian'"):
        load_policy(str(model), joint_env)
    # The same weights said to output joint targets: 42 values cannot be 7 joint targets.
    relabelled = run / "relabelled"
    shutil.copytree(model, relabelled)
    train = json.loads((relabelled / "train_config.json").read_text())
    train["env"]["action_type"] = "dataset"
    (relabelled / "train_config.json").write_text(json.dumps(train))
    with pytest.raises(ValueError, match=r"action has shape \(42,\)"):
        load_policy(str(relabelled), joint_env)
    joint_env.close()
