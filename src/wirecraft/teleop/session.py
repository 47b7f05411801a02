"""A teleoperation session: a device drives the robot, episodes are saved into the shared
LeRobot dataset schema with ``source = "teleop"``.

Per control step (60 Hz, paced to the wall clock when a person watches) the session polls the
device for a ``Command``, handles its events in order, then, unless paused or the episode is
over, steps the environment with the ``cartesian`` action

    action = (speed * motion[0:6], +1 if the gripper is closed else -1)

where ``speed`` is one of ``speeds`` (+ / - change it; the controller moves the TCP by
``translation_scale`` m and ``rotation_scale`` rad per step at 1: 0.6 m/s and 0.6 rad/s),
and records it with ``EpisodeRecorder`` (both cameras, off-screen, at ``fps``).

Events: ``save`` writes the episode (its whole frames; none yet: ignored) and starts the next
scene; ``discard`` drops it and starts the same scene again; ``restart`` drops it and starts
the next scene; ``pause`` stops and resumes the clock; ``speed_up`` / ``speed_down``;
``quit`` ends the session (an unsaved episode is dropped).  At the episode's time limit (or a
divergence) the robot stops and the session waits for save, discard or restart.

Scenes: scene ``k`` resets with ``env_seed(seed, k)``, as ``wirecraft collect``'s attempt
``k``; the dataset's commit record keeps the next scene, so ``resume`` continues there.

Crash safety: the dataset is committed after every saved episode (``EpisodeWriter`` with
``commit_every=1``: finalized, recorded in ``meta/wirecraft_commit.json``, reopened), so a
session killed at any point leaves a dataset that loads with every saved episode, except
during the second that an episode is being written (then ``resume`` rolls back to the commit
before it).  SIGINT / SIGTERM end the session cleanly (a second one stops at once).
``meta/wirecraft_collect.json`` holds the settings (as ``wirecraft collect`` writes them,
``source`` teleop, so that ``wirecraft train`` and ``mix`` read the dataset) and one provenance
record per session.

Command streams: ``save_commands`` writes every command the session acted on (the steps it
took, and each command with a toggle or an event) after a header of the settings; the
``replay`` device plays it back through this same loop, so a replay writes the same episodes
(the viewer never changes the simulation: ``viewer.py``).  A replay may use another image
size or fps (it re-renders the same episodes); the settings that decide the motion (task and
environment, seed, episode length, speeds, first scene) must match the stream's header.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from wirecraft.datasets import schema
from wirecraft.datasets.recorder import EpisodeRecorder
from wirecraft.workers import StopOnSignal

DEFAULT_EPISODE_SECONDS = 60.0  # people need longer than the 8 s scripted episodes
SPEEDS = (0.05, 0.1, 0.15, 0.25, 0.4, 0.6, 1.0)
DEFAULT_SPEED = 3  # index into SPEEDS: 0.25 (15 cm/s, 0.15 rad/s)
DISPLAY_HZ = 30.0
MAX_LAG_S = 0.25  # further behind the wall clock than this: stop catching up
RESET_TRIES = 10
# The header fields of a command stream that decide what the commands do.
REPLAY_KEYS = ("task", "env_kwargs", "seed", "episode_seconds", "speeds", "speed", "first_scene")


def _plain(value):
    """``value`` as JSON would give it back (tuples become lists, ...)."""
    return json.loads(json.dumps(value, default=str))


def env_settings(env) -> tuple[str, dict]:
    """(task family, environment keywords) of a built environment, completed with defaults as
    ``wirecraft collect`` stores them (``collect._with_defaults``)."""
    from wirecraft.datasets.collect import _with_defaults

    u = env.unwrapped
    family = u.task.name
    kwargs = {"robot": u.robot_name, "wire": u.wire_name, "control": u.control_name}
    if u.camera_config is not None:  # a cell's cameras, as collect records --camera-config
        kwargs["camera_config"] = u.camera_config.as_dict()
    defaults = type(u.task).Options.defaults()
    for key, value in u.task.options.as_dict().items():
        if key in defaults and value != defaults[key]:
            kwargs[key] = value
    return family, _plain(_with_defaults(family, kwargs))


@dataclass
class TeleopReport:
    out: str
    saved: int = 0  # episodes this session saved
    successes: int = 0
    discarded: int = 0  # episodes dropped by discard or restart
    frames: int = 0
    episodes_in_dataset: int = 0
    commands: int = 0  # commands written to the command stream
    steps: int = 0  # control steps taken
    ended: str = ""  # why the session ended
    dropped_unsaved: int = 0  # frames of the episode under way at the end (not saved)
    seconds: float = 0.0
    viewer_restores: int = 0  # syncs after which the viewer's own changes were undone
    episodes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)

    def lines(self) -> list[str]:
        lines = [
            f"teleop: saved {self.saved} episodes ({self.successes} successful, {self.frames} "
            f"frames), discarded {self.discarded}; {self.out} holds {self.episodes_in_dataset} "
            f"episodes ({self.seconds:.0f} s; ended: {self.ended})"
        ]
        if self.dropped_unsaved:
            lines.append(f"the episode under way ({self.dropped_unsaved} frames) was not saved")
        return lines


class TeleopSession:
    """Teleoperation of ``env`` (a WireCraft environment under ``cartesian`` control) by
    ``device`` (``devices.Device``) into the dataset at ``out_dir`` (see the module docstring).

    ``fps``: frames per second of the dataset (a divisor of 60); ``seed``: scene ``k`` resets
    with ``env_seed(seed, k)``; ``episodes``: stop once this session saved that many;
    ``viewer``: True opens MuJoCo's viewer (``TeleopViewer``; or pass an object with its
    methods), False runs headless (the ``replay`` device); ``save_commands``: write the
    command stream there; ``resume``: add to the teleoperation dataset at ``out_dir`` (else it
    must be new or empty); ``realtime``: pace the steps to the wall clock (default: with a
    viewer); ``speeds`` / ``speed``: the speed levels and the index of the first one."""

    def __init__(
        self,
        env,
        device,
        out_dir: str | os.PathLike,
        fps: int = 30,
        *,
        seed: int = 0,
        episodes: int | None = None,
        viewer=False,
        save_commands: str | os.PathLike | None = None,
        resume: bool = False,
        realtime: bool | None = None,
        speeds: tuple[float, ...] = SPEEDS,
        speed: int = DEFAULT_SPEED,
        vcodec: str = "h264",
        log=None,
    ):
        from wirecraft.envs.env import CONTROL_HZ, steps_per_frame

        self.env = env
        u = env.unwrapped
        if u.control_name != "cartesian":
            raise ValueError(
                f"teleoperation drives control='cartesian' (6-DoF TCP deltas and the gripper); "
                f"the environment has control={u.control_name!r}"
            )
        steps_per_frame(fps)
        for name, value, low in (("seed", seed, 0), ("episodes", episodes, 1)):
            if value is None and name == "episodes":
                continue
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
        speeds = tuple(float(s) for s in speeds)
        if not speeds or not all(0.0 < s <= 1.0 for s in speeds):
            raise ValueError(f"speeds must be numbers in (0, 1], got {speeds!r}")
        if isinstance(speed, bool) or not isinstance(speed, int) or not 0 <= speed < len(speeds):
            raise ValueError(f"speed must be an index into speeds (0..{len(speeds) - 1})")
        self.device = device
        self.out = Path(out_dir)
        self.fps = int(fps)
        self.seed = int(seed)
        self.target = episodes
        self.viewer_option = viewer
        self.save_commands = save_commands
        self.resume = bool(resume)
        self.realtime = bool(viewer) if realtime is None else bool(realtime)
        self.speeds, self.speed = speeds, speed
        self.vcodec = vcodec
        self.log = log if log is not None else (lambda text: print(text, flush=True))
        self.control_hz = CONTROL_HZ
        self.family, self.env_kwargs = env_settings(env)
        self.episode_seconds = u.max_steps / CONTROL_HZ
        self.recorder = EpisodeRecorder(env, self.fps, source="teleop")
        self.flag_names = self.recorder.flag_names
        # the state of the loop
        self.scene = 0
        self.scene_seed = schema.NO_SEED
        self.paused = False
        self.gripper_closed = False
        self.ended: str | None = None  # "time limit" or "diverged" once the episode is over
        self.info: dict = {}
        self.message = ""
        self.writer = None
        self.viewer = None
        self.command_log = None
        self.report = TeleopReport(out=str(self.out))
        self._records: list[dict] = []
        self._new = self._created = False

    # -- settings ------------------------------------------------------------------------------
    def settings(self) -> dict:
        """The dataset's settings, in ``wirecraft collect``'s layout."""
        return {
            "task": self.family,
            "env_kwargs": self.env_kwargs,
            "image_size": int(self.env.unwrapped.image_size),
            "fps": self.fps,
            "seed": self.seed,
            "keep_failures": True,  # a person decides what to keep
            "success_hold_s": None,  # episodes end when a person saves them
            "vcodec": self.vcodec,
        }

    def teleop_settings(self) -> dict:
        config = self.env.unwrapped.controller.config
        return {
            "episode_seconds": self.episode_seconds,
            "control_hz": self.control_hz,
            "speeds": list(self.speeds),
            "translation_scale": config.translation_scale,
            "rotation_scale": config.rotation_scale,
        }

    def stream_header(self) -> dict:
        return _plain(
            {
                "task": self.family,
                "env_kwargs": self.env_kwargs,
                "seed": self.seed,
                "episode_seconds": self.episode_seconds,
                "speeds": list(self.speeds),
                "speed": self.speed,
                "first_scene": self.scene,
                "image_size": int(self.env.unwrapped.image_size),
                "fps": self.fps,
                "device": self.device.name,
            }
        )

    def check_stream(self, header: dict) -> None:
        """Refuse to replay a command stream recorded with other settings."""
        mine = self.stream_header()
        diff = [
            f"{key}: stream {header.get(key)!r}, this session {mine[key]!r}"
            for key in REPLAY_KEYS
            if _plain(header.get(key)) != mine[key]
        ]
        if diff:
            raise ValueError(
                "--commands: the command stream was recorded with other settings (pass the "
                "same task flags, --seed and --episode-seconds, and a dataset at the same "
                "scene): " + "; ".join(diff)
            )

    # -- the dataset -----------------------------------------------------------------------------
    def _open_dataset(self) -> None:
        from wirecraft.datasets.collect import SETTINGS_FILE, _differences
        from wirecraft.datasets.writer import EpisodeWriter, read_commit, write_json_atomic
        from wirecraft.tasks import STATE_REVISION, check_state_revision

        out = self.out
        existing = out.exists() and (not out.is_dir() or any(out.iterdir()))
        settings_path = out / SETTINGS_FILE
        if existing:
            if not self.resume:
                raise ValueError(
                    f"--record {out} exists and is not empty: --resume adds episodes to it, "
                    "or choose another folder"
                )
            if not settings_path.is_file() or read_commit(out) is None:
                raise ValueError(f"--record {out} is not a dataset written by wirecraft teleop")
            stored = json.loads(settings_path.read_text())
            if stored.get("source") != "teleop":
                raise ValueError(
                    f"--record {out} holds {stored.get('source')!r} episodes, not teleop ones "
                    "(wirecraft mix combines datasets of several sources)"
                )
            check_state_revision(stored, f"{out} was recorded", "refusing to mix them")
            diff = _differences(stored["settings"], _plain(self.settings()))
            diff += _differences(stored.get("teleop", {}), _plain(self.teleop_settings()))
            if diff:
                raise ValueError(
                    f"--record {out} was recorded with other settings; refusing to mix them ("
                    + "; ".join(diff)
                    + ")"
                )
            self.writer = EpisodeWriter.open(out, commit_every=1)
            progress = self.writer.progress
            self.scene = int(progress.get("next_scene", 0))
            self._records = list(progress.get("episodes", []))
        else:
            self._new, self._created = True, not out.exists()
            progress = {"next_scene": 0, "episodes": []}
            self.writer = EpisodeWriter.create(
                out,
                self.recorder.features(),
                self.fps,
                robot_type=self.env.unwrapped.robot_name,
                commit_every=1,
                vcodec=self.vcodec,
                progress=progress,
            )
            stored = {
                "schema_version": schema.SCHEMA_VERSION,
                "state_revision": STATE_REVISION,
                "sources": list(schema.SOURCES),
                "source": "teleop",
                "settings": _plain(self.settings()),
                "teleop": _plain(self.teleop_settings()),
                "expert": None,
            }
        from wirecraft.provenance import provenance

        stored.setdefault("provenance", []).append(
            provenance(
                threads=1,
                command="teleop",
                device=self.device.name,
                first_scene=self.scene,
                started=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            )
        )
        write_json_atomic(settings_path, stored)

    def _progress(self) -> dict:
        return {"next_scene": self.scene, "episodes": list(self._records)}

    # -- episodes ------------------------------------------------------------------------------
    def _start_scene(self) -> None:
        from wirecraft.envs.vector import env_seed

        for _ in range(RESET_TRIES):
            seed = env_seed(self.seed, self.scene)
            try:
                _, info = self.env.reset(seed=seed)
                break
            except RuntimeError as err:  # the scene diverged while settling: the next one
                self.log(f"scene {self.scene} (seed {seed}) could not start ({err}); next scene")
                self.scene += 1
        else:
            raise RuntimeError(f"{RESET_TRIES} scenes in a row diverged while settling")
        self.scene_seed = seed
        self.recorder.start(info, seed)
        self.info = info
        self.ended = None
        self.gripper_closed = False

    def _save(self) -> bool:
        episode = self.recorder.finish({"scene": self.scene, "device": self.device.name})
        if len(episode) == 0:
            self.message = "nothing to save yet (less than one frame recorded)"
            return False
        diverged = self.ended == "diverged"
        episode.success = bool(episode.success and not diverged)
        if self.viewer is not None:
            self.viewer.show(self.status(), f"saving episode ({len(episode)} frames)...")
            self.viewer.sync()
        record = {
            "index": self.writer.num_episodes,
            "scene": self.scene,
            "seed": episode.seed,
            "success": episode.success,
            "frames": len(episode),
            "control_steps": episode.control_steps,
            "end": self.ended or "saved",
            "device": self.device.name,
        }
        self._records.append(record)
        self.recorder.clear()
        self.scene += 1
        self.writer.add_episode(episode, progress=self._progress())
        self.report.saved += 1
        self.report.successes += int(episode.success)
        self.report.frames += len(episode)
        self.report.episodes.append(record)
        self.message = (
            f"saved episode {record['index']} ({len(episode)} frames, "
            f"{'success' if episode.success else 'no success'})"
        )
        self.log(self.message)
        return True

    def _drop(self, next_scene: bool) -> None:
        frames = len(self.recorder.finish())
        self.recorder.clear()
        self.report.discarded += 1
        if next_scene:
            self.scene += 1
            self.writer.progress = self._progress()
        self.message = f"discarded ({frames} frames); " + (
            "next scene" if next_scene else "the same scene again"
        )
        self.log(self.message)

    # -- one control step ------------------------------------------------------------------------
    def action(self, motion) -> np.ndarray:
        speed = self.speeds[self.speed]
        action = np.empty(7)
        for i in range(6):
            action[i] = speed * motion[i]
        action[6] = 1.0 if self.gripper_closed else -1.0
        return action

    def tick(self, command) -> str | None:
        """Handle one command; returns why the session ends, or None."""
        stop = None
        new_scene = False
        for event in command.events:
            if event == "quit":
                stop = "quit"
                break
            if event == "speed_up":
                self.speed = min(self.speed + 1, len(self.speeds) - 1)
            elif event == "speed_down":
                self.speed = max(self.speed - 1, 0)
            elif event == "pause":
                self.paused = not self.paused
            elif event == "save":
                if self._save():
                    new_scene = True
                    if self.target is not None and self.report.saved >= self.target:
                        stop = f"{self.target} episodes saved"
                        break
                    self._start_scene()
            elif event in ("discard", "restart"):
                self._drop(next_scene=event == "restart")
                new_scene = True
                self._start_scene()
        if command.gripper:
            self.gripper_closed = not self.gripper_closed
        step = stop is None and not new_scene and not self.paused and self.ended is None
        if self.command_log is not None and (step or command.acts):
            self.command_log.write(command)
            self.report.commands += 1
        if not step:
            return stop
        action = self.action(command.motion)
        _, _, terminated, truncated, info = self.env.step(action)
        self.recorder.record(action, info)
        self.info = info
        self.report.steps += 1
        if terminated or truncated:
            self.ended = "diverged" if info.get("diverged") else "time limit"
            self.message = f"episode over ({self.ended}): Enter saves, Backspace retries"
        return None

    # -- the overlay ---------------------------------------------------------------------------
    def status(self) -> list[tuple[str, str]]:
        u = self.env.unwrapped
        config = u.controller.config
        speed = self.speeds[self.speed]
        if self.ended:
            state = f"over ({self.ended})"
        elif self.paused:
            state = "PAUSED"
        else:
            state = "recording"
        total = self.writer.num_episodes if self.writer else 0
        rows = [
            ("Saved", f"{self.report.saved} (dataset {total})"),
            ("Scene", f"{self.scene} (seed {self.scene_seed})"),
            ("Time", f"{u.elapsed_steps / self.control_hz:5.1f} / {self.episode_seconds:g} s"),
            (
                "Speed",
                f"{speed:g} ({100 * speed * config.translation_scale * self.control_hz:.0f} cm/s)",
            ),
            ("Gripper", "closed" if self.gripper_closed else "open"),
            ("State", state),
        ]
        for flag in self.flag_names:
            rows.append((flag, "YES" if self.info.get(flag) else "no"))
        return rows

    def _open_viewer(self) -> None:
        from wirecraft.teleop.devices import KEY_MAP
        from wirecraft.teleop.viewer import TeleopViewer

        if self.viewer_option is True:
            u = self.env.unwrapped
            self.viewer = TeleopViewer(
                u.model,
                u.data,
                key_callback=getattr(self.device, "key_callback", None),
                pinned_letters=getattr(self.device, "bound_letters", ""),
                title_lines=KEY_MAP,
            )
        else:
            self.viewer = self.viewer_option

    # -- the session ---------------------------------------------------------------------------
    def run(self) -> TeleopReport:
        """Run until quit, the command stream's end, ``episodes`` saved, the viewer closed or
        a signal; returns the report.  The dataset is closed (loadable) at the end."""
        from wirecraft.teleop.devices import CommandLog

        start = time.perf_counter()
        header = getattr(self.device, "header", None)
        if self.viewer_option is False and getattr(self.device, "needs_viewer", False):
            raise ValueError(f"the {self.device.name} device needs the viewer's window")
        on_stop = "ending the session, without the episode under way"
        with StopOnSignal(on_stop) as stopper:
            try:
                self._open_dataset()
                if header:
                    self.check_stream(header)
                if self.save_commands is not None:
                    self.command_log = CommandLog(self.save_commands, self.stream_header())
                self._start_scene()
                if self.viewer_option:
                    self._open_viewer()
                self.report.ended = self._loop(stopper)
            finally:
                self._close()
        self.report.seconds = time.perf_counter() - start
        return self.report

    def _loop(self, stopper) -> str:
        period = 1.0 / self.control_hz
        next_tick = time.perf_counter()
        shown = -1.0
        viewer = self.viewer
        while True:
            if stopper.stop:
                return stopper.stop
            if viewer is not None and not viewer.is_running():
                return "viewer closed"
            command = self.device.poll()
            if command is None:
                return "end of the command stream"
            stop = self.tick(command)
            if stop:
                return stop
            now = time.perf_counter()
            if viewer is not None and (now - shown >= 1.0 / DISPLAY_HZ or command.acts):
                viewer.show(self.status(), self.message)
                viewer.sync()
                shown = now
            if self.realtime:
                next_tick += period
                delay = next_tick - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                elif delay < -MAX_LAG_S:
                    next_tick = time.perf_counter()

    def _close(self) -> None:
        import shutil

        self.report.dropped_unsaved = len(self.recorder.finish()) if self.writer else 0
        close = getattr(self.device, "close", None)
        if callable(close):
            close()
        if self.viewer is not None:
            self.report.viewer_restores = getattr(self.viewer, "restored", 0)
            self.viewer.close()
            self.viewer = None
        if self.command_log is not None:
            self.command_log.close()
        self.recorder.close()
        if self.writer is not None:
            self.writer.close(self._progress())
            self.report.episodes_in_dataset = self.writer.num_episodes
            if self._new and self.writer.num_episodes == 0:
                # Nothing was saved in a dataset this session made: leave no empty dataset.
                if self._created:
                    shutil.rmtree(self.out, ignore_errors=True)
                else:
                    for child in self.out.iterdir():
                        if child.is_dir():
                            shutil.rmtree(child, ignore_errors=True)
                        else:
                            child.unlink(missing_ok=True)
                self.report.out = f"{self.out} (removed: no episode saved)"
