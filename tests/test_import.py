"""``wirecraft import``: a LeRobot dataset recorded elsewhere, converted into the shared schema.

The foreign dataset is written with LeRobot's own API (``LeRobotDataset.create``): 2 episodes of
12 frames at 30 fps, 32 x 32 px, a UR5 moving near its home pose, and five mismatches a map
resolves: the joints under another key, in another order, in degrees (one joint's sign
flipped, one offset); the gripper as a fraction with 1 = closed; the cameras under other keys;
30 fps resampled to 10.

- the converted dataset loads with LeRobot (and ``writer.load_dataset``), has the schema's
  features, source ``real``, the foreign values converted (exact up to float32) at the frames
  the resampling rule picks, ``observation.cartesian_state`` equal to the simulated UR5's
  forward kinematics, and ``meta/wirecraft_import.json``;
- replaying its ``action`` (joint targets) in the simulated UR5 cell under joint control, the
  robot follows the targets;
- a bad map gives one ValueError listing every mismatch, one per line, and leaves nothing
  behind; bad command-line input exits 2 naming the flag.
"""

from __future__ import annotations

import json
import math
import tomllib

import numpy as np
import pytest

pytest.importorskip("lerobot", reason="LeRobot is not installed (pip install 'wirecraft[data]')")

from wirecraft.cli import main  # noqa: E402
from wirecraft.datasets import importer, schema  # noqa: E402

SIZE, FOREIGN_FPS, FPS, FRAMES, EPISODES = 32, 30, 10, 12, 2
# Foreign joint names in the foreign order; JOINTS is the UR5's order (joint1..joint6).
JOINTS = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
FOREIGN_ORDER = ["wrist_3", "elbow", "shoulder_pan", "wrist_1", "shoulder_lift", "wrist_2"]
SIGN = [1, 1, 1, 1, 1, -1]
OFFSET = [0.0, 0.0, 0.0, 0.0, 0.1, 0.0]  # rad
INSTRUCTION = "Insert the cable into the port."
MAP = f"""
fps = {FPS}
task = "insertion"
state = "observation.joints"
action = "action.joints"
joint_order = {json.dumps(JOINTS)}
joint_units = "deg"
joint_sign = {SIGN}
joint_offset = {OFFSET}
gripper_state = "observation.gripper"
gripper_action = "action.gripper"
gripper_units = "fraction"
gripper_closed_is_one = true

[cameras]
"observation.images.top" = "side"
"observation.images.hand" = "wrist"
"""


def _trajectory(episode: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Our joint angles (rad) and gripper gaps (m) of one foreign episode: states and targets
    (the state one foreign frame ahead) near the UR5's home pose."""
    from wirecraft.assets.robots import home_qpos

    home = np.array(home_qpos("ur5"))
    t = np.arange(FRAMES + 1) / FOREIGN_FPS
    phase = np.arange(6) + episode
    q = home + 0.15 * np.sin(2 * math.pi * 0.8 * t[:, None] + phase)
    gap = 0.085 * (0.3 + 0.2 * np.sin(2 * math.pi * 0.5 * t + episode))
    return q[:-1], q[1:], gap[:-1], gap[1:]


def _foreign_joints(q: np.ndarray) -> np.ndarray:
    """Our joint angles as the foreign dataset stores them: degrees, foreign order, sign flipped
    and offset removed."""
    raw = np.degrees((q - np.array(OFFSET)) / np.array(SIGN))
    return np.stack([raw[:, JOINTS.index(name)] for name in FOREIGN_ORDER], axis=1)


def _colour(episode: int, frame: int, camera: str) -> tuple[int, int, int]:
    """A flat colour naming the foreign frame (checked after the videos' round trips)."""
    value = 10 + 20 * frame if camera == "top" else 240 - 20 * frame
    return value, 60 + 120 * episode, 128


@pytest.fixture(scope="module")
def foreign(tmp_path_factory):
    """The foreign dataset's folder and the values it holds (float32, as stored)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from wirecraft.datasets.writer import quiet_writing

    quiet_writing()
    root = tmp_path_factory.mktemp("foreign") / "ur5_cell"
    vector = {"dtype": "float32", "shape": (6,), "names": FOREIGN_ORDER}
    image = {"dtype": "video", "shape": (SIZE, SIZE, 3), "names": ["height", "width", "channels"]}
    features = {
        "observation.joints": vector,
        "action.joints": vector,
        "observation.gripper": {"dtype": "float32", "shape": (1,), "names": ["gripper"]},
        "action.gripper": {"dtype": "float32", "shape": (1,), "names": ["gripper"]},
        "observation.images.top": image,
        "observation.images.hand": image,
    }
    dataset = LeRobotDataset.create(
        "lab/ur5_cell", fps=FOREIGN_FPS, root=root, features=features, robot_type="ur5e"
    )
    values = []
    for e in range(EPISODES):
        q, target, gap, gap_target = _trajectory(e)
        stored = {
            "observation.joints": _foreign_joints(q).astype(np.float32),
            "action.joints": _foreign_joints(target).astype(np.float32),
            "observation.gripper": (1.0 - gap / 0.085).astype(np.float32)[:, None],
            "action.gripper": (1.0 - gap_target / 0.085).astype(np.float32)[:, None],
        }
        for f in range(FRAMES):
            frame = {key: array[f] for key, array in stored.items()}
            for camera in ("top", "hand"):
                frame[f"observation.images.{camera}"] = np.full(
                    (SIZE, SIZE, 3), _colour(e, f, camera), np.uint8
                )
            dataset.add_frame({**frame, "task": INSTRUCTION})
        dataset.save_episode(parallel_encoding=False)  # no worker processes
        values.append(stored)
    dataset.finalize()
    return root, values


@pytest.fixture(scope="module")
def imported(foreign, tmp_path_factory):
    root, values = foreign
    work = tmp_path_factory.mktemp("imported")
    (work / "map.toml").write_text(MAP)
    out = work / "out"
    argv = ["import", "--from", str(root), "--source", "real", "--robot", "ur5"]
    argv += ["--map", str(work / "map.toml"), "--out", str(out), "--json", str(work / "r.json")]
    assert main(argv) == 0
    return out, values, json.loads((work / "r.json").read_text())


def _convert_joints(raw: np.ndarray) -> np.ndarray:
    picked = np.stack([raw[:, FOREIGN_ORDER.index(name)] for name in JOINTS], axis=1)
    return np.radians(picked.astype(np.float64)) * np.array(SIGN) + np.array(OFFSET)


def _columns(dataset, key: str) -> np.ndarray:
    column = dataset.hf_dataset.with_format("numpy")[key]
    return np.asarray(column).reshape(len(dataset), -1)


def test_resampling_rule():
    obs, act = importer.resample(12, 30, 10)
    assert obs.tolist() == [0, 3, 6, 9] and act.tolist() == [2, 5, 8, 11]
    obs, act = importer.resample(14, 30, 10)  # frames 12, 13: a period cut short
    assert obs.tolist() == [0, 3, 6, 9] and act.tolist() == [2, 5, 8, 11]
    obs, act = importer.resample(10, 25, 10)  # 2.5 foreign frames per frame
    assert obs.tolist() == [0, 2, 5, 7] and act.tolist() == [2, 4, 7, 9]
    obs, act = importer.resample(5, 30, 30)  # same rate: every frame as it is
    assert obs.tolist() == act.tolist() == [0, 1, 2, 3, 4]
    assert len(importer.resample(2, 30, 10)[0]) == 0  # shorter than one frame


def test_imported_dataset_has_the_schema_and_the_converted_values(imported):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from wirecraft.datasets.writer import load_dataset

    out, values, record = imported
    dataset = LeRobotDataset("wirecraft/local", root=out, video_backend="pyav")
    assert load_dataset(out).num_frames == dataset.num_frames
    expected = schema.features_for("ur5", SIZE, task="insertion", steps_per_frame=60 // FPS)
    for key, feature in expected.items():
        got = dataset.meta.features[key]
        assert (got["dtype"], tuple(got["shape"]), got["names"]) == (
            feature["dtype"],
            tuple(feature["shape"]),
            feature["names"],
        ), key
    assert dataset.meta.fps == FPS and dataset.meta.robot_type == "ur5"
    per_episode = FRAMES * FPS // FOREIGN_FPS  # floor(n f / F) = 4
    assert dataset.num_episodes == EPISODES and dataset.num_frames == EPISODES * per_episode
    assert record["frames"] == EPISODES * per_episode

    episode_index = _columns(dataset, "episode_index")[:, 0]
    state, action = _columns(dataset, "observation.state"), _columns(dataset, "action")
    obs, act = importer.resample(FRAMES, FOREIGN_FPS, FPS)
    for e, stored in enumerate(values):
        rows = episode_index == e
        want_state = _convert_joints(stored["observation.joints"][obs])
        want_action = _convert_joints(stored["action.joints"][act])
        np.testing.assert_array_equal(state[rows, :6], want_state.astype(np.float32))
        np.testing.assert_array_equal(action[rows, :6], want_action.astype(np.float32))
        q, target, gap, gap_target = _trajectory(e)  # the values before the foreign encoding
        np.testing.assert_allclose(state[rows, :6], q[obs], atol=1e-5)
        np.testing.assert_allclose(action[rows, :6], target[act], atol=1e-5)
        np.testing.assert_allclose(state[rows, 6], gap[obs], atol=1e-7)
        np.testing.assert_allclose(action[rows, 6], gap_target[act], atol=1e-7)

    assert set(_columns(dataset, schema.SOURCE_KEY)[:, 0]) == {schema.SOURCES.index("real")}
    assert set(_columns(dataset, schema.SEED_KEY)[:, 0]) == {schema.NO_SEED}
    for flag in ("success", "reach_success", "insert_success"):
        assert not _columns(dataset, flag).any()
    assert np.isnan(_columns(dataset, schema.ENV_ACTION_KEY)).all()
    for i in (0, per_episode + 2):  # images: the colour of the foreign frame resampling picks
        item = dataset[i]
        e, j = int(item["episode_index"]), int(item["frame_index"])
        assert item["task"] == INSTRUCTION
        for camera, foreign_camera in (("cam_side", "top"), ("cam_wrist", "hand")):
            image = item[f"observation.images.{camera}"].numpy() * 255.0
            colour = np.array(_colour(e, int(obs[j]), foreign_camera))
            assert np.abs(image.mean(axis=(1, 2)) - colour).max() < 6, (camera, i)

    meta = json.loads((out / importer.IMPORT_FILE).read_text())
    assert meta == record
    assert meta["source"] == "real" and meta["from"]["fps"] == FOREIGN_FPS
    assert meta["resampling"]["fps"] == FPS and "nearest earlier" in meta["resampling"]["method"]
    assert meta["flags_not_recorded"] == ["success", "reach_success", "insert_success"]
    assert meta["map"]["joint_units"] == "deg" and meta["provenance"]["command"] == "import"
    assert meta["resolved"]["state"]["indices"] == [FOREIGN_ORDER.index(n) for n in JOINTS]


def test_cartesian_state_is_the_simulated_ur5s_forward_kinematics(imported):
    import mujoco

    import wirecraft
    from wirecraft.datasets.writer import load_dataset
    from wirecraft.geometry import quat_near

    out, _, _ = imported
    dataset = load_dataset(out)
    state = _columns(dataset, "observation.state")
    cartesian = _columns(dataset, schema.CARTESIAN_KEY)
    env = wirecraft.make("insertion", robot="ur5").unwrapped
    env.reset(seed=0)
    arm = env.robot.index(env.model).arm_qpos
    for i in (0, 5):
        env.data.qpos[arm] = state[i, :6]
        mujoco.mj_forward(env.model, env.data)
        want = schema.cartesian_state(env.robot, env.model, env.data)
        np.testing.assert_allclose(cartesian[i], want, atol=2e-6)
    # a known configuration: at home the TCP is where the robot's facts put it
    fk = importer._fk_model("ur5")
    home = importer.cartesian_states(fk, env.robot.home_qpos[None])[0]
    np.testing.assert_allclose(home[:3], env.robot.home_tcp_pos, atol=1e-6)
    want_rot = quat_near(env.robot.home_tcp_rot, env.robot.home_tcp_rot)
    np.testing.assert_allclose(home[3:], want_rot, atol=1e-6)
    env.close()


def test_images_are_cropped_to_a_square_and_resized():
    import torch

    image = torch.zeros(3, 48, 64, dtype=torch.uint8)  # CHW, as LeRobot decodes
    image[0, :, :8] = 255  # a red band the centred square crop removes
    image[1] = 100
    out = importer._image({"cam": image}, "cam", 32)
    assert out.shape == (32, 32, 3) and out.dtype == np.uint8
    assert (out[..., 0] == 0).all() and (out[..., 1] == 100).all()
    levels = torch.randint(0, 256, (3, SIZE, SIZE), dtype=torch.uint8)
    floats = levels.float() / 255  # float images in [0, 1], as LeRobot gives: the same levels
    np.testing.assert_array_equal(
        importer._image({"cam": floats}, "cam", SIZE), levels.permute(1, 2, 0).numpy()
    )


def test_replayed_actions_drive_the_simulated_ur5_to_the_targets(imported):
    """Where the robot matches (a UR5 both sides): the imported joint targets, replayed in the
    simulated cell under joint control, move the robot toward each target in turn."""
    import wirecraft
    from wirecraft.datasets.writer import load_dataset
    from wirecraft.evaluation.policies import joint_action

    out, _, _ = imported
    dataset = load_dataset(out)
    rows = _columns(dataset, "episode_index")[:, 0] == 0
    actions = _columns(dataset, "action")[rows].astype(np.float64)
    env = wirecraft.make("insertion", robot="ur5", control="joint")
    env.reset(seed=0)
    core = env.unwrapped
    k = 60 // FPS
    for target in actions:
        before = np.abs(core.robot.arm_qpos(core.model, core.data) - target[:6]).max()
        for _ in range(k):
            env.step(joint_action(core, target))
        after = np.abs(core.robot.arm_qpos(core.model, core.data) - target[:6]).max()
        assert after < 0.5 * before + 1e-3, (before, after)
    assert after < 0.02
    env.close()


def _bad(map_text: str, foreign_root, tmp_path, **kwargs) -> str:
    out = tmp_path / "bad" / "out"
    out.parent.mkdir(parents=True)
    with pytest.raises(ValueError) as err:
        importer.import_dataset(
            foreign_root,
            out,
            source="real",
            robot="ur5",
            mapping=tomllib.loads(map_text),
            progress=False,
            **kwargs,
        )
    assert list(out.parent.iterdir()) == []  # nothing at --out, nor beside it
    return str(err.value)


def _mismatch_lines(message: str) -> list[str]:
    return [line.strip() for line in message.splitlines()[1:]]


def test_a_bad_map_gives_one_error_listing_each_mismatch(foreign, tmp_path):
    root, _ = foreign
    text = MAP.replace('state = "observation.joints"', 'state = "observation.joint"')
    text = text.replace('joint_units = "deg"', 'joint_units = "grad"')
    text = text.replace('"observation.images.hand" = "wrist"\n', "")
    message = _bad(text, root, tmp_path)
    assert message.startswith("--map: 3 mismatches")
    lines = _mismatch_lines(message)
    assert len(lines) == 3, message
    assert lines[0].startswith("state:") and "'observation.joint'" in lines[0]
    assert lines[1].startswith("joint_units:") and "'grad'" in lines[1]
    assert lines[2].startswith("cameras:") and "'wrist'" in lines[2]


def test_values_outside_the_robots_range_name_the_first_frame(foreign, tmp_path):
    root, _ = foreign
    text = MAP.replace('joint_units = "deg"', 'joint_units = "rad"')  # degrees read as rad
    text = text.replace('gripper_units = "fraction"', 'gripper_units = "mm"')
    text = text.replace("gripper_closed_is_one = true", "")
    message = _bad(text, root, tmp_path)
    lines = _mismatch_lines(message)
    assert [line.split(":")[0] for line in lines] == ["state", "action"], message
    assert (
        "outside the ur5's limits" in lines[0] and "first at foreign episode 0, frame" in lines[0]
    )

    text = MAP.replace('gripper_units = "fraction"', 'gripper_units = "m"')
    text = text.replace("gripper_closed_is_one = true", "")
    text = text.replace("fps = 10", "fps = 7")  # a map error: found before any value is read
    lines = _mismatch_lines(_bad(text, root, tmp_path / "x"))
    assert [line.split(":")[0] for line in lines] == ["fps"]


def test_gripper_out_of_range_and_unknown_keys(foreign, tmp_path):
    root, _ = foreign
    text = MAP.replace('gripper_units = "fraction"', 'gripper_units = "m"')  # 0..1 "m": too wide
    text = text.replace("gripper_closed_is_one = true", "joint_speed = 3")
    lines = _mismatch_lines(_bad(text, root, tmp_path))
    assert [line.split(":")[0] for line in lines] == ["joint_speed"]
    text = text.replace("joint_speed = 3", "")
    lines = _mismatch_lines(_bad(text, root, tmp_path / "y"))
    assert [line.split(":")[0] for line in lines] == ["gripper_state", "gripper_action"]
    assert "outside [0, 0.085]" in lines[0]


@pytest.mark.parametrize(
    ("change", "flag"),
    [
        ({"map": "missing.toml"}, "--map"),
        ({"robot": "r2d2"}, "--robot"),
        ({"out": "full"}, "--out"),
        ({"source": "sim"}, "--source"),
        ({"task": "knitting"}, "--task"),
        ({"from": "nowhere"}, "--from"),
    ],
)
def test_cli_bad_input_exits_2_naming_the_flag(foreign, tmp_path, capsys, change, flag):
    root, _ = foreign
    (tmp_path / "map.toml").write_text(MAP)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "a").write_text("x")
    args = {"from": str(root), "source": "real", "robot": "ur5", "map": "map.toml"}
    args |= {"out": "out", **change}
    argv = ["import"]
    for key, value in args.items():
        value = str(tmp_path / value) if key in ("from", "map", "out") else value
        argv += [f"--{key}", value]
    before = sorted(tmp_path.rglob("*"))
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert flag in err and "Traceback" not in err, err
    assert sorted(tmp_path.rglob("*")) == before
