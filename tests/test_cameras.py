"""A cell's cameras from a file (poses, fields of view, far clip, exposure) and sensor-style
noise on rendered RGB, in observations, dataset frames and as a dataset transform."""

import math

import numpy as np
import pytest

import wirecraft
from wirecraft.cameras import CameraConfig, ImageNoise, SensorNoiseTransform
from wirecraft.datasets.recorder import frame_images, frame_renderer

CELL = """
[side]
pos = [0.5, -0.55, 0.6]
target = [0.0, 0.0, 0.05]
fovy = 42.0
[wrist]
fovy = 75.0
[image]
far_clip = 2.5
exposure_gain = 1.25
[noise]
read = 0.02
shot = 0.01
colour_shift = 0.05
blur = 0.5
jpeg_quality = 85
"""


def test_a_cell_file_sets_the_camera_poses_fields_of_view_and_far_clip(tmp_path):
    path = tmp_path / "cell.toml"
    path.write_text(CELL)
    config = CameraConfig.load(path)
    assert config.side_pos == (0.5, -0.55, 0.6) and config.noise.jpeg_quality == 85
    assert CameraConfig.of(config.as_dict()) == config  # the record a dataset keeps
    env = wirecraft.make("insertion", camera_config=str(path)).unwrapped
    model, data = env.model, env.data
    side = model.camera(env.robot.side_camera)
    assert side.fovy[0] == pytest.approx(42.0)
    assert model.camera(env.robot.wrist_camera).fovy[0] == pytest.approx(75.0)
    assert data.cam_xpos[side.id] == pytest.approx([0.5, -0.55, 0.6])
    # the camera looks at the target: its -z axis points from the eye to it
    view = -data.cam_xmat[side.id].reshape(3, 3)[:, 2]
    towards = np.array([0.0, 0.0, 0.05]) - np.array([0.5, -0.55, 0.6])
    assert view == pytest.approx(towards / math.sqrt(float(np.sum(towards**2))), abs=1e-9)
    assert model.vis.map.zfar * model.stat.extent == pytest.approx(2.5)
    env.close()


@pytest.mark.parametrize(
    "text, names",
    [
        ("[side]\npos = [0, 0, 1]\n", "pos and target"),
        ("[side]\npos = [0, 0]\ntarget = [0, 0, 0]\n", "side_pos"),
        ("[side]\nfovy = 0.0\n", "side_fovy"),
        ("[image]\nexposure_gain = -1.0\n", "exposure_gain"),
        ("[image]\nfar_clip = 0.0\n", "far_clip"),
        ("[noise]\nread = -0.1\n", "read"),
        ("[noise]\njpeg_quality = 101\n", "jpeg_quality"),
        ("[noise]\ncolour_shift = 1.5\n", "colour_shift"),
        ("[lens]\nk1 = 0.1\n", "lens"),
        ("[side]\nroll = 3.0\n", "roll"),
        ("[side\n", "not valid TOML"),
    ],
)
def test_a_bad_cell_file_is_refused_naming_the_setting(tmp_path, text, names):
    path = tmp_path / "cell.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=names):
        CameraConfig.load(path)


def test_exposure_gain_scales_the_rendered_image():
    config = {"image": {"exposure_gain": 1.5}}
    plain = wirecraft.make("insertion", obs_mode="rgb", image_size=32)
    bright = wirecraft.make("insertion", obs_mode="rgb", image_size=32, camera_config=config)
    a, _ = plain.reset(seed=1)
    b, _ = bright.reset(seed=1)
    for key in ("rgb_side", "rgb_wrist"):
        expected = np.clip(np.rint(a[key].astype(float) * 1.5), 0, 255)
        assert np.abs(b[key].astype(float) - expected).max() <= 1.0
    plain.close()
    bright.close()


def test_read_and_shot_noise_have_their_configured_spread():
    rng = np.random.default_rng(0)
    flat = np.full((200, 200, 3), 128, np.uint8)
    read = ImageNoise(read=0.02).apply(flat, rng, np.ones(3))
    assert read.astype(float).mean() == pytest.approx(128.0, abs=0.5)
    assert read.astype(float).std() == pytest.approx(0.02 * 255, rel=0.05)
    for level in (64, 192):
        image = np.full((200, 200, 3), level, np.uint8)
        shot = ImageNoise(shot=0.01).apply(image, rng, np.ones(3)).astype(float)
        assert shot.std() == pytest.approx(math.sqrt(0.01 * level / 255) * 255, rel=0.05)
    gains = CameraConfig(noise=ImageNoise(colour_shift=0.05)).episode_colour(7)
    assert np.all(np.abs(gains - 1.0) <= 0.05) and len(set(gains.tolist())) == 3


def test_noise_depends_only_on_the_episode_seed_the_step_and_the_camera():
    config = CameraConfig(noise=ImageNoise(read=0.03, colour_shift=0.05))
    env = wirecraft.make("insertion", obs_mode="rgb", image_size=32, camera_config=config)
    first, _ = env.reset(seed=4)
    again, _ = env.reset(seed=4)
    other, _ = env.reset(seed=5)
    assert np.array_equal(first["rgb_side"], again["rgb_side"])
    assert not np.array_equal(first["rgb_side"], other["rgb_side"])
    # the dataset recorder renders the same images as the observation
    u = env.unwrapped
    env.reset(seed=4)
    renderer = frame_renderer(u)
    images = frame_images(u, renderer)
    assert np.array_equal(images["side"], first["rgb_side"])
    assert np.array_equal(images["wrist"], first["rgb_wrist"])
    renderer.close()
    # a later step draws other noise for the same scene
    step0 = u.postprocess_image(first["rgb_side"], u.robot.side_camera)
    u.elapsed_steps = 1
    assert not np.array_equal(u.postprocess_image(first["rgb_side"], u.robot.side_camera), step0)
    env.close()


def test_the_noise_works_as_a_dataset_transform(quick_dataset):
    torch = pytest.importorskip("torch")
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    plain = LeRobotDataset("wirecraft/quick", root=quick_dataset)
    noisy = LeRobotDataset(
        "wirecraft/quick",
        root=quick_dataset,
        image_transforms=SensorNoiseTransform(ImageNoise(read=0.05, blur=0.5), seed=0),
    )
    key = "observation.images.cam_side"
    a, b = plain[0][key], noisy[0][key]
    assert a.shape == b.shape and b.dtype == torch.float32
    assert 0.0 <= float(b.min()) and float(b.max()) <= 1.0
    assert float((a - b).abs().mean()) > 0.005


def test_the_command_line_previews_a_cell_and_records_with_it(tmp_path, capsys):
    import json

    from PIL import Image

    from wirecraft.cli import main

    path = tmp_path / "cell.toml"
    path.write_text(CELL)
    png = tmp_path / "preview.png"
    assert main(["view", "--camera-config", str(path), "--width", "48", "--out", str(png)]) == 0
    assert Image.open(png).size == (96, 96)  # default | configured, side over wrist
    (tmp_path / "bad.toml").write_text("[noise]\nread = -1\n")
    assert main(["view", "--camera-config", str(tmp_path / "bad.toml")]) == 2
    assert "read" in capsys.readouterr().err
    out = tmp_path / "ds"
    argv = ["collect", "--episodes", "1", "--image-size", "32", "--fps", "10", "--workers", "0"]
    assert main([*argv, "--camera-config", str(path), "--out", str(out)]) == 0
    settings = json.loads((out / "meta" / "wirecraft_collect.json").read_text())["settings"]
    assert CameraConfig.of(settings["env_kwargs"]["camera_config"]) == CameraConfig.load(path)
