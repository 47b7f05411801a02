"""Input devices for teleoperation: each one gives a ``Command`` per control step.

A ``Command`` is what a person asked for during one control step (1/60 s): a 6-DoF Cartesian
motion in [-1, 1] (TCP translation x, y, z then rotation about x, y, z, in the robot base
frame: x forward, y left, z up), whether the gripper toggles, and events (``EVENTS``).
The session turns it into the environment's ``cartesian`` action (``session.py``).

Devices (``make_device``):

- ``keyboard``: keys of MuJoCo's viewer window (``KEY_MAP``; its ``key_callback`` goes to
  ``mujoco.viewer.launch_passive``).  The viewer reports key presses only, not releases, so a
  motion key counts as held while GLFW says it is down (``glfw.get_key`` on the viewer's
  window, found on the first key press) and, in any case, for ``tap_seconds`` after each
  press or auto-repeat;
- ``spacemouse``: a 3Dconnexion SpaceMouse through ``pyspacemouse`` (hidapi);
- ``gamepad``: a game pad through ``pygame``'s joystick module (``GAMEPAD_MAP``);
- ``replay``: a command stream written by ``CommandLog`` (``--save-commands``), JSON lines,
  read back one command per control step, so that a recorded session runs again without a
  person (and without a display).

The third-party packages are imported only when their device is made; a missing package or
device is a RuntimeError naming both and the fix.
"""

from __future__ import annotations

import json
import math
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

EVENTS = ("save", "discard", "restart", "pause", "speed_up", "speed_down", "quit")
DEVICES = ("keyboard", "spacemouse", "gamepad", "replay")
AXES = ("x", "y", "z", "rx", "ry", "rz")
STREAM_FORMAT = "wirecraft-teleop-commands"
STREAM_VERSION = 1


@dataclass(frozen=True)
class Command:
    """One control step's input: ``motion`` (6 values in [-1, 1]: translation x, y, z, then
    rotation about x, y, z, base frame), ``gripper`` (True: toggle open / closed) and
    ``events`` (names from ``EVENTS``, in the order they happened)."""

    motion: tuple[float, ...] = (0.0,) * 6
    gripper: bool = False
    events: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        try:
            motion = tuple(float(v) for v in self.motion)
        except (TypeError, ValueError):
            raise ValueError(f"Command.motion must be 6 numbers, got {self.motion!r}") from None
        if len(motion) != 6 or not all(math.isfinite(v) for v in motion):
            raise ValueError(f"Command.motion must be 6 finite numbers, got {self.motion!r}")
        object.__setattr__(self, "motion", tuple(min(1.0, max(-1.0, v)) for v in motion))
        if not isinstance(self.gripper, bool):
            raise ValueError(f"Command.gripper must be True or False, got {self.gripper!r}")
        events = (self.events,) if isinstance(self.events, str) else tuple(self.events)
        unknown = [e for e in events if e not in EVENTS]
        if unknown:
            raise ValueError(f"unknown command event(s) {unknown}; valid: {', '.join(EVENTS)}")
        object.__setattr__(self, "events", events)

    @property
    def moves(self) -> bool:
        return any(self.motion)

    @property
    def acts(self) -> bool:
        """True if the command does anything besides moving (a toggle or an event)."""
        return self.gripper or bool(self.events)

    def to_json(self) -> dict:
        line: dict = {"motion": list(self.motion)}
        if self.gripper:
            line["gripper"] = True
        if self.events:
            line["events"] = list(self.events)
        return line

    @classmethod
    def from_json(cls, line: dict) -> Command:
        if not isinstance(line, dict):
            raise ValueError(f"a command must be a JSON object, got {line!r}")
        unknown = sorted(set(line) - {"motion", "gripper", "events"})
        if unknown:
            raise ValueError(f"unknown command field(s) {unknown}")
        return cls(
            motion=tuple(line.get("motion", (0.0,) * 6)),
            gripper=line.get("gripper", False),
            events=tuple(line.get("events", ())),
        )


IDLE = Command()


@runtime_checkable
class Device(Protocol):
    """A source of commands: ``poll`` once per control step (None: the stream has ended, the
    session quits), ``close`` at the end.  A device may also have ``key_callback`` (MuJoCo
    viewer keys) and ``needs_viewer`` (True: it cannot run without the viewer window)."""

    name: str

    def poll(self) -> Command | None: ...

    def close(self) -> None: ...


def _motion(values) -> tuple[float, ...]:
    return tuple(min(1.0, max(-1.0, float(v))) for v in values)


# -- keyboard --------------------------------------------------------------------------------------
# GLFW key codes (what MuJoCo's viewer passes to key_callback), so that this module needs no
# glfw import.
GLFW_KEYS = {
    "W": 87, "S": 83, "A": 65, "D": 68, "R": 82, "F": 70, "Q": 81, "E": 69, "P": 80,
    "Up": 265, "Down": 264, "Left": 263, "Right": 262, "Space": 32, "Enter": 257,
    "Keypad Enter": 335, "Backspace": 259, "Home": 268, "=": 61, "-": 45, "Keypad +": 334,
    "Keypad -": 333, "Esc": 256,
}  # fmt: skip
# Motion keys: key -> (axis index into Command.motion, sign).
MOTION_KEYS = {
    "W": (0, 1.0), "S": (0, -1.0),  # x: forward / back
    "A": (1, 1.0), "D": (1, -1.0),  # y: left / right
    "R": (2, 1.0), "F": (2, -1.0),  # z: up / down
    "Right": (3, 1.0), "Left": (3, -1.0),  # rotation about x (roll)
    "Up": (4, 1.0), "Down": (4, -1.0),  # rotation about y (pitch)
    "Q": (5, 1.0), "E": (5, -1.0),  # rotation about z (yaw)
}  # fmt: skip
EVENT_KEYS = {
    "Enter": "save", "Keypad Enter": "save", "Backspace": "discard", "Home": "restart",
    "P": "pause", "=": "speed_up", "Keypad +": "speed_up", "-": "speed_down",
    "Keypad -": "speed_down", "Esc": "quit",
}  # fmt: skip
GRIPPER_KEY = "Space"
# The key map as documented (docs/datasets.md) and shown in the viewer's overlay.
KEY_MAP = (
    ("W / S", "TCP forward / back (+x / -x)"),
    ("A / D", "TCP left / right (+y / -y)"),
    ("R / F", "TCP up / down (+z / -z)"),
    ("Right / Left", "rotate about x (roll) + / -"),
    ("Up / Down", "rotate about y (pitch) + / -"),
    ("Q / E", "rotate about z (yaw) + / -"),
    ("Space", "gripper: close / open"),
    ("+ / -", "speed up / down"),
    ("P", "pause / resume"),
    ("Enter", "save the episode, next scene"),
    ("Backspace", "discard the episode, same scene again"),
    ("Home", "discard the episode, next scene"),
    ("Esc", "quit (the unsaved episode is dropped)"),
)
TAP_SECONDS = 0.1  # a key press moves for at least this long (6 control steps)


class KeyboardDevice:
    """Keys of MuJoCo's viewer window (``KEY_MAP``).  ``key_callback`` runs on the viewer's
    thread; ``poll`` on the session's.  ``key_down(code)``: whether a key is held now (None:
    ask GLFW about the viewer's window)."""

    name = "keyboard"
    needs_viewer = True

    def __init__(self, tap_seconds: float = TAP_SECONDS, key_down=None, clock=time.monotonic):
        self.tap_seconds = float(tap_seconds)
        self._clock = clock
        self._key_down = key_down
        self._window = None
        self._lock = threading.Lock()
        self._pressed: dict[int, float] = {}  # key code -> time of its last press / repeat
        self._events: list[str] = []
        self._toggles = 0
        self._motion_codes = {GLFW_KEYS[k]: v for k, v in MOTION_KEYS.items()}
        self._event_codes = {GLFW_KEYS[k]: v for k, v in EVENT_KEYS.items()}
        self.active = True

    @property
    def bound_letters(self) -> str:
        """The letter keys this device uses (the viewer's own shortcuts on them are undone)."""
        return "".join(k for k in (*MOTION_KEYS, *EVENT_KEYS) if len(k) == 1 and k.isalpha())

    def key_callback(self, keycode: int) -> None:
        now = self._clock()
        with self._lock:
            if self._window is None and self._key_down is None:
                self._window = _current_glfw_window()
            if keycode in self._motion_codes:
                self._pressed[keycode] = now
            elif keycode in self._event_codes:
                self._events.append(self._event_codes[keycode])
            elif keycode == GLFW_KEYS[GRIPPER_KEY]:
                self._toggles += 1

    def _held(self, code: int, now: float) -> bool:
        if now - self._pressed.get(code, -math.inf) < self.tap_seconds:
            return True
        if self._key_down is not None:
            return bool(self._key_down(code))
        if self._window is not None and self.active:
            return _glfw_key_down(self._window, code)
        return False

    def poll(self) -> Command:
        now = self._clock()
        motion = [0.0] * 6
        with self._lock:
            for code, (axis, sign) in self._motion_codes.items():
                if self._held(code, now):
                    motion[axis] += sign
            events, self._events = tuple(self._events), []
            toggle, self._toggles = self._toggles % 2 == 1, 0
        return Command(_motion(motion), toggle, events)

    def close(self) -> None:
        # The viewer's window goes away with the viewer: stop asking GLFW about it.
        self.active = False
        self._window = None


def _current_glfw_window():
    """The GLFW window whose context is current on this thread (the viewer's, when called
    from its key callback); None where GLFW is unavailable."""
    try:
        import glfw

        return glfw.get_current_context() or None
    except Exception:
        return None


def _glfw_key_down(window, code: int) -> bool:
    # glfwGetKey only reads the window's key state, which GLFW keeps for every key (MuJoCo's
    # key_callback reports presses, never releases).
    try:
        import glfw

        return glfw.get_key(window, code) == glfw.PRESS
    except Exception:
        return False


# -- optional packages -------------------------------------------------------------------------
SPACEMOUSE_HELP = (
    "the spacemouse device needs the pyspacemouse package (pip install pyspacemouse), which "
    "reads the SpaceMouse over hidapi: install the hidapi library too (Debian/Ubuntu: "
    "apt-get install libhidapi-dev); on Linux the user needs read access to /dev/hidraw*: "
    'add a udev rule such as KERNEL=="hidraw*", SUBSYSTEM=="hidraw", MODE="0664", '
    'GROUP="plugdev" in /etc/udev/rules.d/99-hidraw-permissions.rules, put the user in '
    "plugdev, then unplug and replug the device"
)
GAMEPAD_HELP = (
    "the gamepad device needs the pygame package (pip install pygame), whose joystick module "
    "(SDL) reads the pad"
)


def import_optional(module: str, device: str, help_text: str):
    """``module`` imported, or a RuntimeError naming ``device``, the package and the fix."""
    import importlib

    try:
        return importlib.import_module(module)
    except Exception as err:  # ImportError, or a package whose native library fails to load
        raise RuntimeError(
            f"--device {device}: cannot import {module} ({type(err).__name__}: {err}); {help_text}"
        ) from None


def _deadzone(value: float, zone: float) -> float:
    """0 inside ``zone``, then rescaled linearly to reach +-1 at +-1."""
    value = min(1.0, max(-1.0, float(value)))
    if abs(value) <= zone:
        return 0.0
    return math.copysign((abs(value) - zone) / (1.0 - zone), value)


# -- SpaceMouse ----------------------------------------------------------------------------------
# The cap's axes (pyspacemouse: x right, y away from the user, z up; roll, pitch, yaw about
# y, x, z) -> the command's motion (base frame: x forward, y left, z up).  (state field, sign)
SPACEMOUSE_AXES = (
    ("y", 1.0),  # push the cap away: +x
    ("x", -1.0),  # push it left: +y
    ("z", 1.0),  # lift it: +z
    ("roll", 1.0),  # tilt it right / left: rotation about x
    ("pitch", 1.0),  # tilt it forward / back: rotation about y
    ("yaw", -1.0),  # twist it anticlockwise (seen from above): +rotation about z
)
SPACEMOUSE_BUTTONS = ("gripper", "save")  # left button, right button
SPACEMOUSE_DEADZONE = 0.05


class SpaceMouseDevice:
    """A 3Dconnexion SpaceMouse (``pyspacemouse``): the cap gives the 6-DoF motion
    (``SPACEMOUSE_AXES``), the left button toggles the gripper and the right one saves."""

    name = "spacemouse"
    needs_viewer = False

    def __init__(self, deadzone: float = SPACEMOUSE_DEADZONE):
        self._lib = import_optional("pyspacemouse", "spacemouse", SPACEMOUSE_HELP)
        try:
            handle = self._lib.open()
        except Exception as err:  # hidapi missing, no permission, ...
            raise RuntimeError(
                f"--device spacemouse: pyspacemouse could not open a SpaceMouse "
                f"({type(err).__name__}: {err}); {SPACEMOUSE_HELP}"
            ) from None
        if not handle:
            raise RuntimeError(
                "--device spacemouse: no SpaceMouse found (pyspacemouse.open() found none): "
                f"plug one in; {SPACEMOUSE_HELP}"
            )
        self._handle = handle
        self.deadzone = float(deadzone)
        self._buttons: tuple[int, ...] = ()

    def _read(self):
        read = getattr(self._handle, "read", None)
        return read() if callable(read) else self._lib.read()

    def poll(self) -> Command:
        state = self._read()
        motion = [
            sign * _deadzone(getattr(state, key, 0.0), self.deadzone)
            for key, sign in SPACEMOUSE_AXES
        ]
        buttons = tuple(
            int(b)
            for b in (getattr(state, "buttons", None) or getattr(state, "button", None) or ())
        )
        pressed = [
            i
            for i, b in enumerate(buttons)
            if b and (i >= len(self._buttons) or not self._buttons[i])
        ]
        self._buttons = buttons
        gripper = False
        events = []
        for i in pressed:
            if i < len(SPACEMOUSE_BUTTONS):
                if SPACEMOUSE_BUTTONS[i] == "gripper":
                    gripper = not gripper
                else:
                    events.append(SPACEMOUSE_BUTTONS[i])
        return Command(_motion(motion), gripper, tuple(events))

    def close(self) -> None:
        close = getattr(self._handle, "close", None)
        try:
            close() if callable(close) else self._lib.close()
        except Exception:
            pass


# -- game pad ------------------------------------------------------------------------------------
# SDL joystick indices of an Xbox-style pad (Linux xpad / xinput layout).
GAMEPAD_MAP = {
    # motion axis -> (joystick axis, sign): stick up is -1 in SDL
    "axes": {0: (1, -1.0), 1: (0, -1.0), 2: (4, -1.0), 5: (3, -1.0)},
    # motion axis -> (button for -, button for +)
    "buttons_axes": {3: (4, 5)},  # LB / RB: roll - / +
    "hat_axes": {4: 0},  # d-pad left / right: pitch - / + (hat 0's x)
    "buttons": {0: "gripper", 1: "discard", 2: "pause", 3: "restart", 7: "save"},
    "hat_speed": True,  # d-pad up / down: speed up / down
}
GAMEPAD_LAYOUT = (
    ("left stick", "TCP forward / back / left / right (x, y)"),
    ("right stick up / down", "TCP up / down (z)"),
    ("right stick left / right", "rotate about z (yaw)"),
    ("LB / RB", "rotate about x (roll) - / +"),
    ("d-pad left / right", "rotate about y (pitch) - / +"),
    ("d-pad up / down", "speed up / down"),
    ("A", "gripper: close / open"),
    ("B", "discard the episode, same scene again"),
    ("X", "pause / resume"),
    ("Y", "discard the episode, next scene"),
    ("Start", "save the episode, next scene"),
)
GAMEPAD_DEADZONE = 0.15


class GamepadDevice:
    """The first game pad ``pygame`` sees (``GAMEPAD_LAYOUT``); its events are read even
    while MuJoCo's window has the focus."""

    name = "gamepad"
    needs_viewer = False

    def __init__(self, index: int = 0, deadzone: float = GAMEPAD_DEADZONE):
        # Read the pad while another window (MuJoCo's) has the focus; no window of pygame's.
        os.environ.setdefault("SDL_JOYSTICK_ALLOW_BACKGROUND_EVENTS", "1")
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        pygame = import_optional("pygame", "gamepad", GAMEPAD_HELP)
        try:
            if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
                os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
            pygame.display.init()  # SDL's event pump, which updates the joystick state
            pygame.joystick.init()
            count = pygame.joystick.get_count()
        except Exception as err:
            raise RuntimeError(
                f"--device gamepad: pygame could not start its joystick module "
                f"({type(err).__name__}: {err}); {GAMEPAD_HELP}"
            ) from None
        if count <= index:
            raise RuntimeError(
                f"--device gamepad: no game pad connected (pygame sees {count}): plug one in "
                "(on Linux the user needs read access to /dev/input/event*: the input group)"
            )
        self._pygame = pygame
        self._pad = pygame.joystick.Joystick(index)
        self._pad.init()
        self.deadzone = float(deadzone)
        self._buttons: tuple[int, ...] = ()
        self._hat = (0, 0)

    def poll(self) -> Command:
        pg, pad = self._pygame, self._pad
        pg.event.pump()
        axes = [pad.get_axis(i) for i in range(pad.get_numaxes())]
        buttons = tuple(int(pad.get_button(i)) for i in range(pad.get_numbuttons()))
        hat = tuple(pad.get_hat(0)) if pad.get_numhats() else (0, 0)
        motion = [0.0] * 6
        for axis, (index, sign) in GAMEPAD_MAP["axes"].items():
            if index < len(axes):
                motion[axis] += sign * _deadzone(axes[index], self.deadzone)
        for axis, (minus, plus) in GAMEPAD_MAP["buttons_axes"].items():
            for button, sign in ((minus, -1.0), (plus, 1.0)):
                if button < len(buttons) and buttons[button]:
                    motion[axis] += sign
        for axis, hat_index in GAMEPAD_MAP["hat_axes"].items():
            motion[axis] += float(hat[hat_index])
        gripper, events = False, []
        for button, what in GAMEPAD_MAP["buttons"].items():
            was = button < len(self._buttons) and self._buttons[button]
            if button < len(buttons) and buttons[button] and not was:
                if what == "gripper":
                    gripper = not gripper
                else:
                    events.append(what)
        if GAMEPAD_MAP["hat_speed"] and hat[1] != self._hat[1]:
            if hat[1] > 0:
                events.append("speed_up")
            elif hat[1] < 0:
                events.append("speed_down")
        self._buttons, self._hat = buttons, hat
        return Command(_motion(motion), gripper, tuple(events))

    def close(self) -> None:
        try:
            self._pad.quit()
        except Exception:
            pass


# -- command streams -----------------------------------------------------------------------------
class CommandLog:
    """Writes a command stream (``--save-commands``): a header line, then one JSON line per
    command the session acted on, flushed as it goes (a killed session keeps its stream)."""

    def __init__(self, path: str | os.PathLike, header: dict):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "w")
        self._write({"format": STREAM_FORMAT, "version": STREAM_VERSION, **header})
        self.count = 0

    def _write(self, payload: dict) -> None:
        self._file.write(json.dumps(payload, separators=(",", ":")) + "\n")
        self._file.flush()

    def write(self, command: Command) -> None:
        self._write(command.to_json())
        self.count += 1

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()


def read_stream(path: str | os.PathLike) -> tuple[dict, list[Command]]:
    """(header, commands) of a command stream; ValueError naming the file and line."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"--commands: {path} is not a file")
    header: dict | None = None
    commands: list[Command] = []
    with open(path) as f:
        for number, text in enumerate(f, start=1):
            text = text.strip()
            if not text:
                continue
            try:
                line = json.loads(text)
                if number == 1 and isinstance(line, dict) and "format" in line:
                    if line["format"] != STREAM_FORMAT or line.get("version") != STREAM_VERSION:
                        raise ValueError(
                            f"not a {STREAM_FORMAT} stream of version {STREAM_VERSION}: "
                            f"{line.get('format')!r} version {line.get('version')!r}"
                        )
                    header = line
                    continue
                commands.append(Command.from_json(line))
            except (json.JSONDecodeError, ValueError) as err:
                raise ValueError(f"--commands: {path} line {number}: {err}") from None
    if header is None:
        raise ValueError(
            f"--commands: {path} has no header line (a stream written by --save-commands "
            f'starts with {{"format": "{STREAM_FORMAT}", ...}})'
        )
    return header, commands


class ReplayDevice:
    """The commands of a stream (``read_stream``), one per ``poll``; None after the last."""

    name = "replay"
    needs_viewer = False

    def __init__(self, path: str | os.PathLike | None = None, *, header=None, commands=None):
        if path is not None:
            header, commands = read_stream(path)
        self.header = dict(header or {})
        self._commands = list(commands or [])
        self._next = 0

    def __len__(self) -> int:
        return len(self._commands)

    def poll(self) -> Command | None:
        if self._next >= len(self._commands):
            return None
        command = self._commands[self._next]
        self._next += 1
        return command

    def close(self) -> None:
        pass


class CombinedDevice:
    """A motion device together with the viewer's keyboard: motions add up (clipped), gripper
    toggles combine, events of both in order (the device's first)."""

    def __init__(self, device, keyboard: KeyboardDevice):
        self.device, self.keyboard = device, keyboard
        self.name = device.name
        self.needs_viewer = getattr(device, "needs_viewer", False)
        self.key_callback = keyboard.key_callback
        self.bound_letters = keyboard.bound_letters

    def poll(self) -> Command | None:
        a = self.device.poll()
        if a is None:
            return None
        b = self.keyboard.poll()
        motion = _motion(x + y for x, y in zip(a.motion, b.motion, strict=True))
        return Command(motion, a.gripper != b.gripper, a.events + b.events)

    def close(self) -> None:
        self.keyboard.close()
        self.device.close()


def make_device(name: str, *, commands: str | os.PathLike | None = None):
    """The device called ``name`` (``DEVICES``); ``commands``: the stream ``replay`` plays."""
    if name not in DEVICES:
        raise ValueError(f"unknown device {name!r}; valid: {', '.join(DEVICES)}")
    if name == "replay":
        if commands is None:
            raise ValueError("--device replay plays a command stream: pass --commands FILE")
        return ReplayDevice(commands)
    if commands is not None:
        raise ValueError("--commands applies only with --device replay")
    if name == "keyboard":
        return KeyboardDevice()
    if name == "spacemouse":
        return SpaceMouseDevice()
    return GamepadDevice()
