"""Teleoperation with recording (wirecraft.teleop): a recorded command stream replays into the
same dataset, saved episodes survive a killed session, missing device packages give a clear
error, and the keyboard drives the robot in a real MuJoCo window under Xvfb."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np
import pytest

import wirecraft
from wirecraft.datasets import schema
from wirecraft.envs.vector import env_seed
from wirecraft.teleop import Command, TeleopSession, make_device
from wirecraft.teleop.devices import (
    GLFW_KEYS,
    CommandLog,
    KeyboardDevice,
    ReplayDevice,
    read_stream,
)

SIZE, FPS = 32, 10  # small images, 6 control steps per frame: fast
ROOT = Path(__file__).resolve().parents[1]
SCREENSHOT = ROOT / "out" / "teleop_overlay.png"
OFFLINE = {"HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1"}


class ScriptedDevice:
    """A person's session as a script: the ``Device`` protocol without a person."""

    name = "scripted"

    def __init__(self, commands):
        self._commands = iter(commands)

    def poll(self):
        return next(self._commands, None)

    def close(self):
        pass


def move(n, *motion, **kw):
    return [Command(tuple(motion) + (0.0,) * (6 - len(motion)), **kw)] + [
        Command(tuple(motion) + (0.0,) * (6 - len(motion)))
    ] * (n - 1)


def event(*names, gripper=False):
    return [Command(events=names, gripper=gripper)]


def person() -> list[Command]:
    """Two short episodes saved (scenes 0 and 1), one discarded between them (scene 1, tried
    again): motion on every axis, the gripper, speed changes, a pause (with motion that must
    not move anything), and an episode that runs into its 1 s limit before it is saved."""
    rng = np.random.default_rng(0)
    wobble = [Command(tuple(rng.uniform(-1, 1, 6))) for _ in range(12)]
    return (
        move(18, 1.0, 0.0, -0.5)  # forward and down
        + event(gripper=True)  # close
        + move(12, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)  # yaw
        + event("speed_up", "speed_up")
        + wobble
        + event("save")  # scene 0 saved (~7 frames)
        + move(20, 0.0, 1.0)
        + event("discard")  # scene 1 dropped, tried again
        + event("pause")
        + move(30, 1.0)  # paused: no effect, not in the stream
        + event("pause", "speed_down")
        + move(45, 0.0, -1.0, 0.3, 0.2, -0.2)
        + event(gripper=True)
        + move(30, 0.0, 0.0, 1.0)  # runs into the 1 s limit (60 steps)
        + event("save")  # scene 1 saved (10 frames)
        + move(5, 1.0)
        + event("quit")
    )


def make_env(seconds: float = 1.0):
    return wirecraft.make(
        "insertion", control="cartesian", image_size=SIZE, episode_seconds=seconds
    )


def dataset_frames(root: Path) -> dict[str, np.ndarray]:
    """Every column of the dataset, frame by frame, and the decoded images of both cameras."""
    from wirecraft.datasets.writer import load_dataset

    ds = load_dataset(root)
    table = ds.hf_dataset.with_format("arrow")[:]
    frames = {k: np.asarray(table[k].to_pylist()) for k in table.column_names}
    for key in schema.CAMERAS.values():
        frames[key] = np.stack([ds[i][key].numpy() for i in range(len(ds))])
    return frames


def teleop(*argv: str) -> int:
    from wirecraft.teleop.__main__ import main

    return main(list(argv))


def stream_commands(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()[1:]]


def test_replay_writes_the_same_dataset_as_the_live_session(tmp_path):
    live, replayed = tmp_path / "live", tmp_path / "replayed"
    stream, again = tmp_path / "commands.jsonl", tmp_path / "again.jsonl"
    env = make_env()
    try:
        session = TeleopSession(
            env, ScriptedDevice(person()), live, FPS, seed=11, save_commands=stream
        )
        report = session.run()
    finally:
        env.close()
    assert (report.saved, report.discarded, report.ended) == (2, 1, "quit")
    assert report.episodes_in_dataset == 2 and report.dropped_unsaved == 0
    header, commands = read_stream(stream)
    assert header["task"] == "insertion" and header["seed"] == 11
    # Commands that change nothing are not in the stream: the 30 motions while paused and the
    # 17 after the second episode ran into its limit (1 + 45 + 1 + 30 steps, 60 taken).
    assert report.commands == len(commands) == len(person()) - 30 - 17

    assert teleop(
        "--task", "insertion", "--device", "replay", "--commands", str(stream),
        "--record", str(replayed), "--image-size", str(SIZE), "--fps", str(FPS),
        "--save-commands", str(again),
    ) == 0  # fmt: skip
    a, b = dataset_frames(live), dataset_frames(replayed)
    assert sorted(a) == sorted(b)
    for key in a:
        assert np.array_equal(a[key], b[key]), key  # state, action, images, flags, ...
    assert len(a["index"]) == 7 + 10
    assert set(a["source"].reshape(-1).tolist()) == {schema.source_code("teleop")}
    seeds = sorted(set(a["seed"].reshape(-1).tolist()))
    assert seeds == sorted({env_seed(11, 0), env_seed(11, 1)})
    for flag in schema.success_flags("insertion"):
        assert a[flag].dtype == bool
    assert stream_commands(again) == stream_commands(stream)  # the same commands acted on
    stored = json.loads((live / "meta/wirecraft_collect.json").read_text())
    assert stored["source"] == "teleop" and stored["settings"]["task"] == "insertion"
    assert stored["settings"]["image_size"] == SIZE and stored["teleop"]["episode_seconds"] == 1
    assert stored["provenance"][0]["device"] == "scripted"


def test_replay_refuses_a_stream_of_other_settings(tmp_path, capsys):
    env = make_env()
    try:
        header = TeleopSession(env, ScriptedDevice([]), tmp_path / "x", FPS).stream_header()
    finally:
        env.close()
    stream = tmp_path / "s.jsonl"
    log = CommandLog(stream, header)
    log.write(Command(events=("save",)))
    log.close()
    out = tmp_path / "out"
    assert teleop("--device", "replay", "--commands", str(stream), "--record", str(out),
                  "--seed", "9") == 2  # fmt: skip
    err = capsys.readouterr().err
    assert "other settings" in err and "seed: stream 0, this session 9" in err
    assert not out.exists()  # nothing left behind
    assert teleop("--device", "replay", "--record", str(out)) == 2
    assert "--commands" in capsys.readouterr().err
    bad = tmp_path / "bad.jsonl"
    bad.write_text(stream.read_text().splitlines()[0] + '\n{"motion": [0, 0, 0]}\n')
    with pytest.raises(ValueError, match="line 2"):
        read_stream(bad)


def test_a_cell_camera_config_is_kept_for_the_dataset_and_the_replay(tmp_path):
    from wirecraft.cameras import CameraConfig

    cell = tmp_path / "cell.toml"
    cell.write_text("[side]\nfovy = 42.0\n[noise]\nread = 0.02\n")
    config = CameraConfig.load(cell).as_dict()
    env = wirecraft.make(
        "insertion", control="cartesian", image_size=SIZE, episode_seconds=1.0,
        camera_config=config,
    )  # fmt: skip
    try:
        session = TeleopSession(env, ScriptedDevice([]), tmp_path / "x", FPS)
        header = session.stream_header()
    finally:
        env.close()
    assert session.settings()["env_kwargs"]["camera_config"] == json.loads(json.dumps(config))
    again = wirecraft.make("insertion", image_size=SIZE, **header["env_kwargs"]).unwrapped
    assert again.camera_config == CameraConfig.of(config)
    again.close()


def test_a_killed_session_keeps_its_saved_episodes(tmp_path):
    """SIGKILL in the middle of an episode: the episodes saved before it load (LeRobot's own
    class and load_dataset), the discarded ones are absent, every one is teleop."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from wirecraft.datasets.collect import episode_sources
    from wirecraft.datasets.writer import load_dataset, read_commit

    env = make_env(seconds=100.0)
    try:
        header = TeleopSession(env, ScriptedDevice([]), tmp_path / "x", FPS, seed=5)
        header = header.stream_header()
    finally:
        env.close()
    stream = tmp_path / "s.jsonl"
    log = CommandLog(stream, header)
    script = (
        move(12, 1.0) + event("save")  # scene 0: 2 frames
        + move(30, 0.0, 1.0) + event("restart")  # scene 1: dropped
        + move(24, 0.0, 0.0, 1.0) + event("discard")  # scene 2: dropped, tried again
        + move(18, 0.0, 0.0, 1.0) + event("save")  # scene 2: 3 frames
        + move(20_000, 0.5)  # scene 3 under way when the session is killed
    )  # fmt: skip
    for command in script:
        log.write(command)
    log.close()
    out = tmp_path / "ds"
    proc = subprocess.Popen(
        [sys.executable, "-m", "wirecraft.teleop", "--device", "replay", "--commands",
         str(stream), "--record", str(out)],
        env={**os.environ, **OFFLINE}, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            if (out / "meta/wirecraft_commit.json").is_file():
                record = read_commit(out)
                if record["episodes"] == 2:
                    break
            time.sleep(0.05)
        assert proc.poll() is None, proc.stdout.read().decode()[-3000:]
        time.sleep(0.5)  # into scene 3
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    record = read_commit(out)
    assert record["episodes"] == 2 and record["progress"]["next_scene"] == 3
    for ds in (load_dataset(out), LeRobotDataset("wirecraft/local", root=out,
                                                 video_backend="pyav")):  # fmt: skip
        assert ds.num_episodes == 2 and ds.num_frames == 2 + 3
        assert episode_sources(ds) == ["teleop", "teleop"]
        seeds = np.asarray(ds.hf_dataset["seed"]).reshape(-1).tolist()
        assert seeds == [env_seed(5, 0)] * 2 + [env_seed(5, 2)] * 3  # not scene 1
    assert [e["scene"] for e in record["progress"]["episodes"]] == [0, 2]

    # --resume adds to it, from the scene after the last saved one.
    env = make_env(seconds=100.0)
    try:
        script = move(6, 0.0, 0.0, 1.0) + event("save")
        with pytest.raises(ValueError, match="--resume adds episodes"):
            TeleopSession(env, ScriptedDevice(script), out, FPS, seed=5).run()
        with pytest.raises(ValueError, match="seed: 5 -> 6"):
            TeleopSession(env, ScriptedDevice(script), out, FPS, seed=6, resume=True).run()
        report = TeleopSession(env, ScriptedDevice(script), out, FPS, seed=5, resume=True).run()
    finally:
        env.close()
    assert report.saved == 1 and report.episodes_in_dataset == 3
    seeds = np.asarray(load_dataset(out).hf_dataset["seed"]).reshape(-1).tolist()
    assert seeds[-1] == env_seed(5, 3) and len(seeds) == 2 + 3 + 1
    provenance = json.loads((out / "meta/wirecraft_collect.json").read_text())["provenance"]
    assert [p["first_scene"] for p in provenance] == [0, 3]


def test_missing_device_packages_name_the_package_and_the_fix(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyspacemouse", None)  # import fails
    with pytest.raises(RuntimeError) as err:
        make_device("spacemouse")
    text = str(err.value)
    for part in ("--device spacemouse", "pip install pyspacemouse", "hidapi", "udev", "hidraw"):
        assert part in text
    monkeypatch.setitem(sys.modules, "pygame", None)
    with pytest.raises(RuntimeError, match=r"--device gamepad.*pip install pygame"):
        make_device("gamepad")
    with pytest.raises(ValueError, match="valid: keyboard, spacemouse, gamepad, replay"):
        make_device("joystick")
    with pytest.raises(ValueError, match="--commands"):
        make_device("replay")


def test_spacemouse_and_gamepad_commands_from_stand_in_packages(monkeypatch):
    state = types.SimpleNamespace(x=0.0, y=0.8, z=0.0, roll=0.0, pitch=0.0, yaw=0.5, buttons=[0, 0])
    mouse = types.SimpleNamespace(open=lambda: types.SimpleNamespace(read=lambda: state))
    monkeypatch.setitem(sys.modules, "pyspacemouse", mouse)
    device = make_device("spacemouse")
    command = device.poll()
    assert command.motion[0] > 0.7 and command.motion[5] < -0.4 and not command.acts
    state.buttons = [1, 1]
    assert device.poll().gripper and device.poll().events == ()  # held: one toggle, one save
    assert not device.poll().gripper
    state.buttons = [0, 0]
    device.poll()
    state.buttons = [0, 1]
    assert device.poll().events == ("save",)
    monkeypatch.setitem(sys.modules, "pyspacemouse", types.SimpleNamespace(open=lambda: None))
    with pytest.raises(RuntimeError, match="no SpaceMouse found"):
        make_device("spacemouse")

    pad = {"axes": [0.0] * 6, "buttons": [0] * 11, "hat": (0, 0)}

    class Joystick:
        def __init__(self, index):
            pass

        def init(self):
            pass

        def get_numaxes(self):
            return 6

        def get_axis(self, i):
            return pad["axes"][i]

        def get_numbuttons(self):
            return 11

        def get_button(self, i):
            return pad["buttons"][i]

        def get_numhats(self):
            return 1

        def get_hat(self, i):
            return pad["hat"]

    pads = {"count": 1}
    pygame = types.SimpleNamespace(
        display=types.SimpleNamespace(init=lambda: None),
        event=types.SimpleNamespace(pump=lambda: None),
        joystick=types.SimpleNamespace(
            init=lambda: None, get_count=lambda: pads["count"], Joystick=Joystick
        ),
    )
    monkeypatch.setitem(sys.modules, "pygame", pygame)
    device = make_device("gamepad")
    pad["axes"][1] = -1.0  # left stick up: forward
    pad["buttons"][0] = 1  # A: gripper
    pad["hat"] = (0, 1)  # d-pad up: faster
    command = device.poll()
    assert command.motion[0] == 1.0 and command.gripper and command.events == ("speed_up",)
    pad["buttons"][7] = 1  # Start: save (A still held: no second toggle)
    command = device.poll()
    assert command.events == ("save",) and not command.gripper
    pads["count"] = 0
    with pytest.raises(RuntimeError, match="no game pad connected"):
        make_device("gamepad")


def test_keyboard_device_maps_keys_to_commands():
    held: set[int] = set()
    clock = {"t": 0.0}
    keyboard = KeyboardDevice(key_down=held.__contains__, clock=lambda: clock["t"])
    held.add(GLFW_KEYS["W"])
    keyboard.key_callback(GLFW_KEYS["W"])
    for key in ("Space", "Enter", "=", "P", "Backspace", "Home", "-", "Esc"):
        keyboard.key_callback(GLFW_KEYS[key])
    command = keyboard.poll()
    assert command.motion == (1.0, 0.0, 0.0, 0.0, 0.0, 0.0) and command.gripper
    assert command.events == (
        "save", "speed_up", "pause", "discard", "restart", "speed_down", "quit"
    )  # fmt: skip
    held.clear()
    clock["t"] = 1.0
    keyboard.key_callback(GLFW_KEYS["Q"])  # a tap: moves for tap_seconds
    keyboard.key_callback(GLFW_KEYS["Space"])
    keyboard.key_callback(GLFW_KEYS["Space"])  # twice in one step: no change
    command = keyboard.poll()
    assert command.motion[5] == 1.0 and not command.acts
    clock["t"] = 1.0 + keyboard.tap_seconds
    assert keyboard.poll() == Command()
    assert set("WSADRFQEP") <= set(keyboard.bound_letters)


def test_commands_check_their_values_and_round_trip():
    command = Command((2.0, -3.0, 0.5, 0, 0, 0), True, ("save", "quit"))
    assert command.motion[:3] == (1.0, -1.0, 0.5)
    assert Command.from_json(json.loads(json.dumps(command.to_json()))) == command
    with pytest.raises(ValueError, match="unknown command event"):
        Command(events=("jump",))
    with pytest.raises(ValueError, match="6 finite numbers"):
        Command((float("nan"),) * 6)
    assert ReplayDevice(header={}, commands=[command]).poll() == command


def test_a_viewer_device_without_a_display_is_a_clear_error(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    out = tmp_path / "ds"
    assert teleop("--device", "keyboard", "--record", str(out)) == 2
    err = capsys.readouterr().err
    assert "--device keyboard" in err and "DISPLAY is not set" in err and "replay" in err
    assert not out.exists()


def test_a_display_that_does_not_answer_is_a_clear_error_with_glfws_reason(monkeypatch):
    from wirecraft.envs.env import check_display

    pytest.importorskip("glfw")
    monkeypatch.setenv("DISPLAY", ":4093")  # no X server listens there (none was started)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    if os.path.exists("/tmp/.X11-unix/X4093"):
        pytest.skip("an X server runs on :4093 here")
    with pytest.raises(RuntimeError) as raised:
        check_display()
    assert "':4093'" in str(raised.value) and "X11: Failed to open display" in str(raised.value)


# -- a real window ------------------------------------------------------------------------------
def _x_tools() -> list[str]:
    return [tool for tool in ("Xvfb", "xdotool") if shutil.which(tool) is None]


@pytest.fixture
def xvfb(tmp_path):
    """A fresh Xvfb display (its number chosen by Xvfb), answering clients before the test
    starts; skipped where Xvfb or xdotool is missing (Debian: apt-get install xvfb xdotool)."""
    missing = _x_tools()
    if missing:
        pytest.skip(f"{' and '.join(missing)} not installed (apt-get install xvfb xdotool)")
    log = tmp_path / "xvfb.log"
    read, write = os.pipe()
    with open(log, "wb") as log_file:
        proc = subprocess.Popen(
            ["Xvfb", "-displayfd", str(write), "-screen", "0", "1280x1024x24", "-nolisten", "tcp"],
            pass_fds=(write,), stdout=log_file, stderr=subprocess.STDOUT,
        )  # fmt: skip
    os.close(write)
    number = b""
    with os.fdopen(read, "rb") as pipe:
        while not number.endswith(b"\n"):
            chunk = pipe.read(1)
            if not chunk:
                break
            number += chunk
    if not number.strip():
        proc.kill()
        pytest.skip(f"Xvfb did not start: {log.read_text(errors='replace')}")
    display = f":{int(number)}"
    deadline = time.monotonic() + 30
    while _xdotool(display, "getdisplaygeometry").strip() == "":
        assert proc.poll() is None and time.monotonic() < deadline, (
            f"Xvfb on {display} answers no client (running: {proc.poll() is None}): "
            f"{log.read_text(errors='replace')}"
        )
        time.sleep(0.2)
    # GLFW (the viewer's window library) on this display, in a process of its own: where it
    # cannot start on a display that answers, the machine lacks what a window needs; skip with
    # GLFW's reason, as where Xvfb is missing
    probe = subprocess.run(
        [sys.executable, "-c", "from wirecraft.envs.env import check_display; check_display()"],
        env={**os.environ, "DISPLAY": display}, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    if probe.returncode != 0:
        proc.terminate()
        pytest.skip(f"GLFW cannot open a window on Xvfb {display}: {probe.stderr[-600:]}")
    yield display
    proc.terminate()
    proc.wait(timeout=10)


def _xdotool(display: str, *args: str, timeout: float = 30) -> str:
    done = subprocess.run(
        ["xdotool", *args], env={**os.environ, "DISPLAY": display}, capture_output=True,
        text=True, timeout=timeout,
    )  # fmt: skip
    return done.stdout


def _text_pixels(image: np.ndarray) -> float:
    """Fraction of bright, colourless pixels (the overlay's white text; the scene's table and
    robot are tinted or darker)."""
    pixels = image.reshape(-1, 3).astype(int)
    bright = pixels.min(axis=1) > 180
    neutral = pixels.max(axis=1) - pixels.min(axis=1) < 12
    return float(np.mean(bright & neutral))


@pytest.mark.slow
def test_keyboard_drives_the_robot_in_a_real_window(tmp_path, xvfb):
    """``python -m wirecraft.teleop --device keyboard`` in MuJoCo's viewer under Xvfb: keys
    sent with xdotool move the TCP forward and up, close the gripper and save; the overlay is
    on screen (out/teleop_overlay.png); the stream replays into the same dataset."""
    from PIL import ImageGrab

    out, stream = tmp_path / "ds", tmp_path / "keys.jsonl"
    env = {**os.environ, **OFFLINE, "DISPLAY": xvfb, "MUJOCO_GL": "glfw"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "wirecraft.teleop", "--task", "insertion", "--device",
         "keyboard", "--record", str(out), "--episodes", "1", "--image-size", str(SIZE),
         "--fps", str(FPS), "--episode-seconds", "30", "--save-commands", str(stream)],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        window = ""
        deadline = time.monotonic() + 180
        while not window and proc.poll() is None and time.monotonic() < deadline:
            window = _xdotool(xvfb, "search", "--name", "MuJoCo").split("\n")[0].strip()
            time.sleep(0.5)
        assert window, (
            f"no viewer window: {proc.stdout.read() if proc.poll() is not None else ''}; "
            f"the display still answers: {_xdotool(xvfb, 'getdisplaygeometry')!r}"
        )
        time.sleep(2.0)  # the first frames
        x = lambda *args: _xdotool(xvfb, *args)  # noqa: E731
        x("mousemove", "--window", window, "300", "300")  # keys go to the window under it
        x("keydown", "w")
        time.sleep(0.8)
        x("keyup", "w")
        x("key", "space")  # close the gripper
        x("keydown", "r")
        time.sleep(0.5)
        x("keyup", "r")
        time.sleep(0.5)
        geometry = x("getwindowgeometry", "--shell", window)
        g = dict(line.split("=") for line in geometry.split() if "=" in line)
        left, top, width, height = (int(g[k]) for k in ("X", "Y", "WIDTH", "HEIGHT"))
        shot = ImageGrab.grab(bbox=(left, top, left + width, top + height), xdisplay=xvfb)
        SCREENSHOT.parent.mkdir(exist_ok=True)
        shot.save(SCREENSHOT)
        x("key", "Return")  # save: --episodes 1 ends the session
        try:
            proc.wait(timeout=120)
        except subprocess.TimeoutExpired:
            x("key", "Escape")
            proc.wait(timeout=60)
        log = proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, log[-3000:]
    assert "saved episode 0" in log

    frames = dataset_frames(out)
    assert set(frames["episode_index"].tolist()) == {0}
    assert set(frames["source"].reshape(-1).tolist()) == {schema.source_code("teleop")}
    tcp = frames["observation.cartesian_state"]
    # W held 0.8 s at 15 cm/s is 12 cm forward, R 0.5 s up, when the session keeps real time;
    # on a machine busy with other jobs its ticks fall behind (3 cm forward beside four
    # training runs on two cores), so the test asks for the direction, at least 1 cm each.
    assert tcp[-1, 0] - tcp[0, 0] > 0.01  # W: forward
    assert tcp[-1, 2] - tcp[0, 2] > 0.01  # R: up
    gap = frames["action"][:, -1]
    assert gap[-1] < 0.5 * gap[0]  # Space: the gripper closed
    commands = stream_commands(stream)
    assert commands[-1].get("events") == ["save"]
    assert sum(1 for c in commands if c.get("gripper")) == 1

    # The overlay: the key map (top left) and the status (top right) are white text.
    image = np.asarray(shot.convert("RGB"))
    h, w = image.shape[:2]
    assert image.std() > 20  # not blank
    keys, status = image[: h // 3, : w // 3], image[: h // 4, 2 * w // 3 :]
    scene = image[h // 2 :, w // 4 : 3 * w // 4]
    assert _text_pixels(keys) > 0.01 and _text_pixels(status) > 0.005
    assert _text_pixels(scene) < 0.002

    # The viewer never changed the simulation: the stream replays into the same dataset, every
    # state, action and flag bit for bit.
    replayed = tmp_path / "replayed"
    assert teleop("--device", "replay", "--commands", str(stream), "--record", str(replayed),
                  "--episodes", "1") == 0  # fmt: skip
    again = dataset_frames(replayed)
    assert frames.keys() == again.keys()
    for key in frames.keys() - set(schema.CAMERAS.values()):
        assert np.array_equal(frames[key], again[key]), key
    # The images of those same states were drawn by two OpenGL stacks: GLX on the X server, beside
    # the viewer's own context, then EGL in this process.  Mesa does not promise them the same
    # bits (a wrist frame can differ while every state matches), so each frame is held to within
    # 1 % of full brightness on average; a viewer setting that leaked into the recording would
    # not pass (transparency changes a frame of these 32-pixel cameras by 1.8 % at the wrist and
    # 36 % at the side).
    for key in schema.CAMERAS.values():
        per_frame = np.abs(frames[key] - again[key]).reshape(len(frames[key]), -1).mean(axis=1)
        assert per_frame.max() <= 0.01, (key, np.flatnonzero(per_frame), per_frame.max())


VIEWER_PROBE = """
import json, subprocess, time
import mujoco
from wirecraft.teleop.viewer import TeleopViewer

xml = '<mujoco model="probe"><worldbody><light pos="0 0 1"/><geom size=".1"/></worldbody></mujoco>'
model = mujoco.MjModel.from_xml_string(xml)
data = mujoco.MjData(model)
viewer = TeleopViewer(model, data)
deadline = time.monotonic() + 120
while not subprocess.run(["xdotool", "search", "--name", "MuJoCo : probe"],
                         capture_output=True).stdout.strip():  # the viewer has loaded the model
    assert time.monotonic() < deadline, "no viewer window"
    time.sleep(0.2)
model.opt.timestep = 0.0005
model.vis.quality.offsamples = 0
model.vis.map.zfar = 7.0
model.stat.extent = 3.0
for _ in range(2):
    viewer.sync()
    time.sleep(0.2)
print(json.dumps([model.opt.timestep, model.vis.quality.offsamples, model.vis.map.zfar,
                  model.stat.extent, viewer.restored]))
viewer.close()
"""


@pytest.mark.slow
def test_the_viewer_keeps_the_settings_written_after_it_opened(xvfb):
    """MuJoCo's passive viewer writes mjModel.vis and .stat back, at its first sync, as they
    were when it loaded the model; TeleopViewer puts back what the program set since."""
    env = {**os.environ, "DISPLAY": xvfb, "MUJOCO_GL": "glfw"}
    done = subprocess.run([sys.executable, "-c", VIEWER_PROBE], env=env, capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    timestep, offsamples, zfar, extent, restored = json.loads(done.stdout.splitlines()[-1])
    assert (timestep, offsamples, zfar, extent) == (0.0005, 0, 7.0, 3.0)
    assert restored == 1  # the first sync only


def test_the_wirecraft_program_runs_teleop(capsys):
    from wirecraft.cli import main

    assert main(["teleop", "--device", "replay", "--record", "unused"]) == 2
    assert "--commands" in capsys.readouterr().err
