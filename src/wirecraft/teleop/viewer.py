"""MuJoCo's interactive viewer as a display for teleoperation (``mujoco.viewer.launch_passive``).

The viewer only shows the simulation: the command stream alone decides an episode, so that a
replay reproduces it.  MuJoCo's viewer can change the simulation on its own, at ``sync``:
Backspace resets ``mjData``, a mouse perturbation writes forces, the history slider and the
control sliders write the state, the physics panel writes ``mjModel.opt``, and its first
``sync`` writes back ``mjModel.vis`` and ``mjModel.stat`` as they were when it loaded the model
(undoing, for one, the off-screen sample count a renderer created later sets).  ``TeleopViewer``
keeps the integration state (``mjSTATE_INTEGRATION``: time, positions, velocities, controls,
applied forces, ...) and the model's ``opt``, ``vis`` and ``stat`` from before each ``sync`` and
puts them back where the viewer changed them.  The viewer's letter shortcuts (every letter
toggles a visual flag, e.g. W wireframe, S shadows) are undone for the letters the keyboard
device uses.

The overlay (``handle.set_texts``): the key map (top left), the episode status (top right:
saved episodes, scene, seed, time, speed, gripper, pause, the task's success flags) and the
last message (bottom left).
"""

from __future__ import annotations

import copy
import threading

import mujoco
import numpy as np

STATE_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION
# mjModel's settings the viewer writes at sync: physics options, visualisation, statistics.
MODEL_SETTINGS = ("opt", "vis", "stat")
CLOSE_TIMEOUT_S = 10.0
# The viewer's first view: from behind the robot and to its right (it stands at x = -0.5 m
# facing +x), over the wire's side of the table: forward (+x) points into the screen and
# to the right, left (+y) into the screen and to the left; the mouse changes the view.
VIEW = {"lookat": (0.0, -0.05, 0.05), "distance": 1.7, "azimuth": 45.0, "elevation": -45.0}


def flags_for_letters(letters: str) -> tuple[list[int], list[int]]:
    """(visualisation flags, rendering flags) whose viewer shortcut is one of ``letters``."""
    letters = letters.upper()
    vis = [i for i, (_, _, key) in enumerate(mujoco.mjVISSTRING) if key and key in letters]
    rnd = [i for i, (_, _, key) in enumerate(mujoco.mjRNDSTRING) if key and key in letters]
    return vis, rnd


class TeleopViewer:
    """A passive MuJoCo viewer on ``model`` / ``data`` that shows and never changes them.

    ``key_callback``: called with each key press (GLFW key code) on the viewer's thread;
    ``pinned_letters``: letters whose viewer shortcuts are undone."""

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        *,
        key_callback=None,
        pinned_letters: str = "",
        title_lines: tuple[tuple[str, str], ...] = (),
    ):
        from wirecraft.envs.env import check_display

        check_display()
        import mujoco.viewer

        self.model, self.data = model, data
        self._state = np.empty(mujoco.mj_stateSize(model, STATE_SPEC))
        self._after = np.empty_like(self._state)
        self.restored = 0  # syncs after which the viewer's changes were undone
        before = set(threading.enumerate())
        self._handle = mujoco.viewer.launch_passive(
            model, data, key_callback=key_callback, show_left_ui=False, show_right_ui=False
        )
        # The viewer's thread: close() waits for it, else glfw.terminate (at exit) can run
        # while the thread still tears the window down, and the process crashes.
        self._threads = [t for t in threading.enumerate() if t not in before]
        self._vis, self._rnd = flags_for_letters(pinned_letters)
        with self._handle.lock():
            cam = self._handle.cam
            cam.type = mujoco.mjtCamera.mjCAMERA_FREE
            cam.lookat[:] = VIEW["lookat"]
            cam.distance, cam.azimuth = VIEW["distance"], VIEW["azimuth"]
            cam.elevation = VIEW["elevation"]
            self._vis_values = [int(self._handle.opt.flags[i]) for i in self._vis]
            self._rnd_values = [int(self._handle.user_scn.flags[i]) for i in self._rnd]
        self._texts = None
        self._keys = tuple(title_lines)

    def is_running(self) -> bool:
        return self._handle.is_running()

    def sync(self) -> None:
        """Show the current state; undo whatever the viewer changed in the simulation."""
        model, data = self.model, self.data
        mujoco.mj_getState(model, data, self._state, STATE_SPEC)
        settings = {name: copy.copy(getattr(model, name)) for name in MODEL_SETTINGS}
        self._handle.sync()
        mujoco.mj_getState(model, data, self._after, STATE_SPEC)
        state_changed = not np.array_equal(self._state, self._after)
        changed = [name for name, saved in settings.items() if saved != getattr(model, name)]
        for name in changed:
            _assign(getattr(model, name), settings[name])
            if settings[name] != getattr(model, name):
                raise RuntimeError(f"TeleopViewer: could not restore mjModel.{name}")
        if state_changed or "opt" in changed:
            mujoco.mj_setState(model, data, self._state, STATE_SPEC)
            mujoco.mj_forward(model, data)
        self.restored += bool(state_changed or changed)
        if self._vis or self._rnd:
            with self._handle.lock():
                for i, v in zip(self._vis, self._vis_values, strict=True):
                    self._handle.opt.flags[i] = v
                for i, v in zip(self._rnd, self._rnd_values, strict=True):
                    self._handle.user_scn.flags[i] = v

    def show(self, status: list[tuple[str, str]], message: str = "") -> None:
        """The overlay: the key map, ``status`` (label, value) rows and ``message``."""
        font = mujoco.mjtFontScale.mjFONTSCALE_150
        grid = mujoco.mjtGridPos
        texts = [
            (font, grid.mjGRID_TOPLEFT, "\n".join(k for k, _ in self._keys),
             "\n".join(v for _, v in self._keys)),
            (font, grid.mjGRID_TOPRIGHT, "\n".join(k for k, _ in status),
             "\n".join(v for _, v in status)),
        ]  # fmt: skip
        if message:
            texts.append((font, grid.mjGRID_BOTTOMLEFT, message, ""))
        if texts != self._texts:
            # set_texts takes the viewer's lock itself: never call it holding lock().
            self._handle.set_texts(texts)
            self._texts = texts

    def close(self, timeout: float = CLOSE_TIMEOUT_S) -> None:
        self._handle.close()
        for thread in self._threads:
            thread.join(timeout)


def _assign(current, saved) -> None:
    """Copy every field of the MuJoCo struct ``saved`` into ``current`` (same type), nested
    structs (``mjVisual``'s sections) included."""
    for name in dir(saved):
        if name.startswith("_"):
            continue
        value = getattr(saved, name)
        if callable(value):
            continue
        if isinstance(value, np.ndarray):
            getattr(current, name)[...] = value
        elif isinstance(value, (bool, int, float)):
            setattr(current, name, value)
        else:
            _assign(getattr(current, name), value)
