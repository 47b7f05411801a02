"""The LeRobot adapter: our observations in, the dataset's joint-target action out."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

import wirecraft
from wirecraft.datasets import schema
from wirecraft.evaluation import protocol
from wirecraft.evaluation.policies import (
    checkpoint_fps,
    joint_action,
    load_policy,
    policy_env_kwargs,
)

IMAGE = 32
FPS = 30


def test_joint_action_moves_the_servo_targets_toward_absolute_targets():
    env = wirecraft.make("insertion", control="joint").unwrapped
    env.reset(seed=0)
    ctl = env.controller
    step = ctl.max_step * ctl.config.joint_speed_fraction
    offsets = np.array([0.5, -0.25, 0.0, 3.0, -3.0, 0.1])  # in rated steps; +-3 saturate
    gap = 0.3 * env.robot.max_opening
    action = joint_action(env, np.concatenate([ctl.joint_targets + offsets * step, [gap]]))
    assert np.allclose(action[:6], np.clip(offsets, -1, 1))
    before = ctl.joint_targets.copy()
    env.step(action)
    moved = (ctl.joint_targets - before) / step
    assert np.allclose(moved[:3], offsets[:3], atol=1e-9)  # unsaturated joints land on target
    assert ctl.gripper_target == pytest.approx(gap)
    with pytest.raises(ValueError, match="7 entries"):
        joint_action(env, np.zeros(6))


@pytest.fixture(scope="module")
def tiny_act(tmp_path_factory):
    """A randomly initialised, tiny ACT policy saved as LeRobot saves a trained one."""
    return save_tiny_act(tmp_path_factory)


def save_tiny_act(tmp_path_factory, extra_inputs=()):
    torch = pytest.importorskip("torch")
    pytest.importorskip("lerobot")
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors

    visual = PolicyFeature(type=FeatureType.VISUAL, shape=(3, IMAGE, IMAGE))
    config = ACTConfig(
        input_features={
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(7,)),
            "observation.images.cam_side": visual,
            "observation.images.cam_wrist": visual,
            **{key: PolicyFeature(type=FeatureType.STATE, shape=(7,)) for key in extra_inputs},
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(7,))},
        device="cpu",
        chunk_size=4,
        n_action_steps=4,
        dim_model=32,
        n_heads=2,
        dim_feedforward=64,
        n_encoder_layers=1,
        n_decoder_layers=1,
        use_vae=False,
        pretrained_backbone_weights=None,
    )
    torch.manual_seed(0)
    policy = ACTPolicy(config)
    image_stats = {"mean": torch.full((3, 1, 1), 0.5), "std": torch.full((3, 1, 1), 0.25)}
    stats = {
        "observation.state": {"mean": torch.zeros(7), "std": torch.ones(7)},
        "action": {"mean": torch.zeros(7), "std": torch.full((7,), 0.1)},
        "observation.images.cam_side": image_stats,
        "observation.images.cam_wrist": image_stats,
        **{key: {"mean": torch.zeros(7), "std": torch.ones(7)} for key in extra_inputs},
    }
    pre, post = make_pre_post_processors(config, dataset_stats=stats)
    folder = tmp_path_factory.mktemp("act")
    for part in (policy, pre, post):
        part.save_pretrained(folder)
    # What lerobot-train writes beside them: the training run's settings, naming the dataset
    # (here a stand-in holding only the metadata the adapter reads: its frame rate).
    dataset = tmp_path_factory.mktemp("dataset")
    (dataset / "meta").mkdir()
    (dataset / "meta" / "info.json").write_text(json.dumps({"fps": FPS}))
    train = {"dataset": {"repo_id": "wirecraft/local", "root": str(dataset)}, "env": None}
    (folder / "train_config.json").write_text(json.dumps(train))
    return folder


@pytest.mark.slow
def test_a_saved_lerobot_policy_drives_joint_controlled_environments(tiny_act):
    kwargs = policy_env_kwargs(str(tiny_act), "insertion")
    assert kwargs == {"control": "joint", "obs_mode": "state_rgb", "image_size": IMAGE}
    venv = wirecraft.make_vec("insertion", 2, threads=1, **kwargs)
    obs, _ = venv.reset(seed=[1, 2])
    policy = load_policy(str(tiny_act), venv)
    assert policy.control == "joint"
    batch = policy._batch(obs)
    for i, env in enumerate(venv.envs):
        expected = env.robot.dataset_state(env.model, env.data)  # the dataset's state
        assert np.allclose(batch["observation.state"][i].numpy(), expected, atol=1e-6)
    assert tuple(batch["observation.images.cam_side"].shape) == (2, 3, IMAGE, IMAGE)
    assert float(batch["observation.images.cam_wrist"].max()) <= 1.0
    policy.reset()
    for _ in range(2):
        actions = policy.act(obs)
        assert actions.shape == (2, 7) and np.all(np.abs(actions) <= 1.0)
        obs, *_ = venv.step(actions)
    venv.close()
    payload = protocol.evaluate(
        "insertion", str(tiny_act), seeds=1, episodes=1, episode_seconds=0.1, progress=False
    )
    assert payload["env_kwargs"]["control"] == "joint"
    assert payload["episodes"][0]["failure"] == "no_grasp"


def test_the_frame_rate_comes_from_the_checkpoints_training_dataset(tiny_act, tmp_path):
    assert checkpoint_fps(tiny_act) == FPS
    bare = tmp_path / "bare"
    shutil.copytree(tiny_act, bare)
    (bare / "train_config.json").unlink()
    assert checkpoint_fps(bare) is None
    # A dataset no longer on this machine: the training environment's rate, if it had one.
    train = {"dataset": {"repo_id": "someone/gone", "root": str(tmp_path / "gone")}}
    (bare / "train_config.json").write_text(json.dumps({**train, "env": {"fps": 15}}))
    assert checkpoint_fps(bare) == 15
    (bare / "train_config.json").write_text(json.dumps({**train, "env": None}))
    assert checkpoint_fps(bare) is None
    venv = wirecraft.make_vec(
        "insertion", 1, threads=1, control="joint", obs_mode="state_rgb", image_size=IMAGE
    )
    with pytest.raises(ValueError, match=r"frame rate .* fps=\.\.\. \(wirecraft eval --fps N"):
        load_policy(str(bare), venv)
    assert load_policy(str(bare), venv, fps=20).steps_per_frame == 3
    with pytest.raises(ValueError, match="must divide the 60 Hz"):
        load_policy(str(bare), venv, fps=7)
    venv.close()


@pytest.mark.slow
def test_the_policy_is_queried_once_per_frame_and_its_actions_held(tiny_act):
    venv = wirecraft.make_vec(
        "insertion", 2, threads=1, control="joint", obs_mode="state_rgb", image_size=IMAGE
    )
    obs, _ = venv.reset(seed=[1, 2])
    policy = load_policy(str(tiny_act), venv)
    assert policy.fps == FPS and policy.steps_per_frame == 2
    calls = []
    select = policy.policy.select_action
    policy.policy.select_action = lambda batch: calls.append(1) or select(batch)
    policy.reset()
    for step in range(8):
        if step % 2:  # between frames the observation is not read
            obs = {key: None for key in obs}
        actions = policy.act(obs)
        assert actions.shape == (2, 7) and np.all(np.abs(actions) <= 1.0)
        obs, *_ = venv.step(actions)
        # the targets approached during a frame are the frame's action
        assert policy._targets.shape == (2, 7)
    assert len(calls) == 4  # one query per frame: an action chunk plays at recorded speed
    venv.close()


def test_importing_the_modules_that_load_lerobot_prints_no_traceback(tmp_path):
    """lerobot looks for torchcodec whenever it picks a default video backend; without the
    system's FFmpeg libraries it used to log ~100 lines of loading traceback."""
    pytest.importorskip("lerobot")
    code = (
        "import wirecraft.datasets.writer, wirecraft.datasets.encoding\n"
        "import wirecraft.evaluation.policies\n"
        "from lerobot.configs.default import DatasetConfig\n"
        "from lerobot.utils.import_utils import get_safe_default_video_backend\n"
        "print(get_safe_default_video_backend(), DatasetConfig(repo_id='x').video_backend)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "Traceback" not in out.stderr and "torchcodec" not in out.stderr, out.stderr[:2000]
    assert out.stdout.split()[0] in ("pyav", "torchcodec")


def test_the_cartesian_state_is_supplied_when_a_policy_takes_it(tmp_path_factory):
    folder = save_tiny_act(tmp_path_factory, extra_inputs=(schema.CARTESIAN_KEY,))
    venv = wirecraft.make_vec(
        "insertion", 2, threads=1, **policy_env_kwargs(str(folder), "insertion")
    )
    obs, _ = venv.reset(seed=[1, 2])
    policy = load_policy(str(folder), venv)
    batch = policy._batch(obs)
    for i, env in enumerate(venv.envs):
        expected = schema.cartesian_state(env.robot, env.model, env.data)  # the dataset's
        assert np.allclose(batch[schema.CARTESIAN_KEY][i].numpy(), expected, atol=1e-6)
    assert policy.act(obs).shape == (2, 7)
    venv.close()


def test_an_input_wirecraft_does_not_supply_is_a_clear_error(tmp_path_factory):
    folder = save_tiny_act(tmp_path_factory, extra_inputs=("observation.environment_state",))
    venv = wirecraft.make_vec(
        "insertion", 1, threads=1, **policy_env_kwargs(str(folder), "insertion")
    )
    with pytest.raises(ValueError, match="observation.environment_state"):
        load_policy(str(folder), venv)
    venv.close()
