"""``wirecraft collect``: scripted-expert demonstrations written as a LeRobot v3 dataset.

- Episode attempt ``k`` resets the environment with ``env_seed(seed, k)`` and seeds the
  expert's own random choices (diversity) with the same number: it depends only on
  (``seed``, ``k``), so the dataset is the same whatever the number of workers, with Ray or
  without, and after any interruption and ``--resume``.  Results are written in attempt order.
- An episode ends at the environment's end (8 s, or a divergence) or, earlier, at the first
  frame boundary once the task's ``success`` flag has held for ``success_hold_s`` (0.5 s =
  30 control steps; 0 disables the early end).  It succeeded when ``success`` holds at its
  last state (and it did not diverge).  Failed episodes are dropped unless ``keep_failures``;
  attempts continue until ``episodes`` are saved or ``max_attempts`` were made.
- Frames and actions follow ``EpisodeRecorder`` (fps a divisor of 60; the action of a frame is
  the joint targets after the last control step of its period, or with ``action="env"`` the
  period's environment actions).
- Workers: ``workers = 0`` runs in this process; ``N >= 1`` starts N processes (spawn); with
  ``ray_address`` (``"local"``: a local Ray instance with ``workers`` CPUs) Ray tasks generate
  the episodes.  This process is the only writer (``EpisodeWriter``).  Each task is a run of
  up to ``batch`` consecutive attempts that the worker steps side by side in one vector
  environment (``run_episodes``: a finished attempt's slot takes the next); a vector
  environment's row is a single environment, so the episodes do not depend on ``batch``.
- SIGINT / SIGTERM: the episode being written is finished, the dataset is committed and
  finalized (loadable), and ``collect`` returns with ``interrupted`` set; a second signal
  stops at once (``--resume`` then rolls back to the last commit).  A hard kill loses at most
  the episodes since the last commit (``commit_every``); ``--resume`` regenerates them.
- The collection settings are stored in ``meta/wirecraft_collect.json``; ``resume`` refuses a
  dataset collected with different settings (only ``episodes`` and the workers may change) or
  on another state revision (``wirecraft.tasks.STATE_REVISION``: what ``observation.state``
  means).
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wirecraft.datasets import schema
from wirecraft.datasets.recorder import Episode, EpisodeRecorder
from wirecraft.torch_threads import DEFAULT_TORCH_THREADS, set_torch_threads
from wirecraft.workers import StopOnSignal, open_workers

SETTINGS_FILE = "meta/wirecraft_collect.json"
DEFAULT_IMAGE_SIZE = 224
POLL_SECONDS = 0.2
# An attempt without a result after this long means a worker died (a crashed process's task
# is lost: multiprocessing would wait for it forever).
ATTEMPT_TIMEOUT_S = 900.0
# Episodes a worker steps side by side in one vector environment (``run_episodes``).
DEFAULT_BATCH = 4


def _default_family() -> str:
    from wirecraft.tasks import default_family

    return default_family()


@dataclass(frozen=True)
class CollectSettings:
    """What determines the episodes' content (stored with the dataset, checked on resume)."""

    task: str = field(default_factory=lambda: _default_family())  # task family
    env_kwargs: dict = field(default_factory=dict)  # environment keywords (image size apart)
    image_size: int = DEFAULT_IMAGE_SIZE
    fps: int = 30
    seed: int = 0
    keep_failures: bool = False
    success_hold_s: float = 0.5
    vcodec: str = "h264"  # a key of writer.VIDEO_CODECS
    expert: str = "scripted"  # a name of wirecraft.experts.DEMONSTRATORS
    action: str = "joint"  # what a frame's ``action`` holds (schema.ACTION_KINDS)

    def __post_init__(self) -> None:
        import wirecraft
        from wirecraft.envs.env import steps_per_frame

        family = wirecraft.family_of(self.task)
        object.__setattr__(self, "task", family)
        expert = self.expert_class
        kwargs = dict(self.env_kwargs)
        for key in ("obs_mode", "render_mode", "image_size", "task"):
            if key in kwargs:
                raise ValueError(f"collect sets {key!r} itself; do not pass it in env_kwargs")
        control = kwargs.setdefault("control", expert.CONTROL)
        if control != expert.CONTROL:
            raise ValueError(
                f"the {self.expert} {family} expert drives control={expert.CONTROL!r}, "
                f"got control={control!r}"
            )
        object.__setattr__(self, "env_kwargs", _with_defaults(family, kwargs))
        for name, low in (("image_size", 16), ("fps", 1), ("seed", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
        steps_per_frame(self.fps)
        schema.check_action_kind(self.action)
        from wirecraft.datasets.writer import VIDEO_CODECS

        if self.vcodec not in VIDEO_CODECS:
            raise ValueError(f"unknown vcodec {self.vcodec!r}; valid: {', '.join(VIDEO_CODECS)}")
        hold = self.success_hold_s
        if isinstance(hold, bool) or not isinstance(hold, (int, float)) or not hold >= 0:
            raise ValueError(f"success_hold_s must be a number >= 0, got {hold!r}")

    @property
    def steps_per_frame(self) -> int:
        from wirecraft.envs.env import steps_per_frame

        return steps_per_frame(self.fps)

    @property
    def expert_class(self) -> type:
        """The class of the expert that demonstrates (``wirecraft.experts.demonstrator_class``)."""
        from wirecraft.experts import demonstrator_class

        return demonstrator_class(self.task, self.expert)

    def episode_seed(self, attempt: int) -> int:
        """The reset seed of episode attempt ``attempt`` (independent of workers and order)."""
        from wirecraft.envs.vector import env_seed

        return env_seed(self.seed, attempt)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> CollectSettings:
        return cls(**data)


def _with_defaults(family: str, kwargs: dict) -> dict:
    """``kwargs`` completed with the environment's and task's defaults (scalars only), so that
    a flag given explicitly at its default value reads as the same settings on resume."""
    import inspect

    from wirecraft.envs.env import WireCraftEnv
    from wirecraft.tasks import TASKS

    defaults = {
        name: param.default
        for name, param in inspect.signature(WireCraftEnv.__init__).parameters.items()
        if name not in ("self", "task", "obs_mode", "image_size", "render_mode")
    }
    defaults.update(TASKS.get(family).Options.defaults())
    full = {
        name: default
        for name, default in defaults.items()
        if isinstance(default, (str, int, float)) and not isinstance(default, bool)
    }
    full.update(kwargs)
    return dict(sorted(full.items()))


# -- one episode (runs in a worker) ----------------------------------------------------------
_CACHE: dict[str, tuple] = {}  # settings -> (env, recorder, expert class); one per process


def _episode_tools(settings: CollectSettings):
    key = json.dumps(settings.to_dict(), sort_keys=True)
    if key not in _CACHE:
        import wirecraft

        env = wirecraft.make(
            settings.task, obs_mode="state", image_size=settings.image_size, **settings.env_kwargs
        )
        recorder = EpisodeRecorder(env, settings.fps, source="scripted", action=settings.action)
        _CACHE[key] = (env, recorder, settings.expert_class)
    return _CACHE[key]


def _expert_config(expert_cls, seed: int | None = None):
    """The expert's default configuration (a ``seed`` field, if it has one, set to ``seed``)."""
    config = expert_cls.config_class()
    if seed is not None and "seed" in {f.name for f in dataclasses.fields(config)}:
        config = dataclasses.replace(config, seed=int(seed))
    return config


def expert_description(settings: CollectSettings) -> dict:
    """The expert that demonstrates and its configuration (stored with the dataset: a changed
    expert would make different episodes, so ``--resume`` refuses it)."""
    expert_cls = settings.expert_class
    config = dataclasses.asdict(_expert_config(expert_cls))
    config.pop("seed", None)
    return {"class": expert_cls.__name__, "config": json.loads(json.dumps(config, default=str))}


def run_episode(settings: CollectSettings | dict, attempt: int) -> Episode:
    """Generate episode attempt ``attempt`` with the scripted expert; its ``info`` holds
    ``attempt``, ``end`` (success_held, time_limit, diverged or terminated), ``diverged``, and
    the wall / CPU seconds of physics + expert and of rendering."""
    from wirecraft.envs.env import CONTROL_HZ

    if isinstance(settings, dict):
        settings = CollectSettings.from_dict(settings)
    env, recorder, expert_cls = _episode_tools(settings)
    seed = settings.episode_seed(attempt)
    hold_steps = int(round(settings.success_hold_s * CONTROL_HZ))
    tic, cpu = time.perf_counter(), time.process_time()
    render0, render_cpu0 = recorder.render_seconds, recorder.render_cpu_seconds
    try:
        obs, info = env.reset(seed=seed)
    except RuntimeError as err:  # the scene diverged while settling: a failed attempt
        recorder.clear(seed)
        zero = dict.fromkeys(("physics_s", "render_s", "physics_cpu_s", "render_cpu_s"), 0.0)
        info = {"attempt": int(attempt), "end": f"reset failed: {err}", "diverged": True}
        return recorder.finish({**info, **zero})
    # The expert's own random choices (diversity) are seeded by the episode's seed too.
    expert = expert_cls(env, _expert_config(expert_cls, seed), seed=seed)
    recorder.start(info, seed)
    held, end = 0, "time_limit"
    while True:
        action = expert.act(obs)[0]
        obs, _, terminated, truncated, info = env.step(action)
        recorder.record(action, info)
        held = held + 1 if info["success"] else 0
        if info["diverged"]:
            end = "diverged"
            break
        if terminated or truncated:
            end = "terminated" if terminated else "time_limit"
            break
        if hold_steps and held >= hold_steps and recorder.at_frame_boundary:
            end = "success_held"
            break
    wall, cpu = time.perf_counter() - tic, time.process_time() - cpu
    render = recorder.render_seconds - render0
    render_cpu = recorder.render_cpu_seconds - render_cpu0
    episode = recorder.finish(
        {
            "attempt": int(attempt),
            "end": end,
            "diverged": bool(info["diverged"]),
            "physics_s": wall - render,
            "render_s": render,
            "physics_cpu_s": cpu - render_cpu,
            "render_cpu_s": render_cpu,
        }
    )
    episode.success = bool(episode.success and not info["diverged"])
    return episode


# -- several episodes side by side (runs in a worker) --------------------------------------------
_BATCH_CACHE: dict[str, tuple] = {}  # (settings, slots) -> (vector env, renderer, recorders)


def _batch_tools(settings: CollectSettings, slots: int):
    key = json.dumps([settings.to_dict(), slots], sort_keys=True)
    if key not in _BATCH_CACHE:
        import wirecraft
        from wirecraft.render import FastRenderer

        while _BATCH_CACHE:  # one configuration at a time
            venv, renderer, _ = _BATCH_CACHE.pop(next(iter(_BATCH_CACHE)))
            venv.close()
            renderer.close()
        # The recorder reads the success flags only: no per-environment force diagnostics.
        venv = wirecraft.make_vec(
            settings.task,
            slots,
            threads=1,
            obs_mode="state",
            image_size=settings.image_size,
            diagnostics=False,
            **settings.env_kwargs,
        )
        renderer = FastRenderer(venv.model, settings.image_size, settings.image_size)
        recorders = [
            EpisodeRecorder(
                env, settings.fps, source="scripted", renderer=renderer, action=settings.action
            )
            for env in venv.envs
        ]
        _BATCH_CACHE[key] = (venv, renderer, recorders)
    return _BATCH_CACHE[key]


def run_episodes(settings: CollectSettings | dict, attempts: list[int], slots: int) -> list:
    """Episode attempts ``attempts`` (in this order), up to ``slots`` at a time in one vector
    environment: each attempt takes a free slot (its reset seed, its own expert and recorder),
    the slots step together, and a finished attempt's slot takes the next one.  A vector
    environment's row is a single environment, so each episode is the one ``run_episode``
    gives for its attempt; physics + expert time is shared out among the running slots."""
    from wirecraft.envs.env import CONTROL_HZ
    from wirecraft.envs.vector import info_row

    if isinstance(settings, dict):
        settings = CollectSettings.from_dict(settings)
    slots = max(1, min(int(slots), len(attempts)))
    venv, _, recorders = _batch_tools(settings, slots)
    expert_cls = settings.expert_class
    hold_steps = int(round(settings.success_hold_s * CONTROL_HZ))
    queue = deque(int(a) for a in attempts)
    episodes: dict[int, Episode] = {}
    running: list[dict | None] = [None] * slots
    ready = np.zeros(slots, bool)  # the slot holds a valid state (it can be stepped)
    obs = None

    def failed_reset(i: int, attempt: int, seed: int, err: Exception) -> None:
        recorders[i].clear(seed)
        zero = dict.fromkeys(("physics_s", "render_s", "physics_cpu_s", "render_cpu_s"), 0.0)
        info = {"attempt": attempt, "end": f"reset failed: {err}", "diverged": True}
        episodes[attempt] = recorders[i].finish({**info, **zero})

    def begin(i: int, attempt: int, seed: int, info: dict) -> None:
        recorder = recorders[i]
        running[i] = {
            "attempt": attempt,
            "expert": expert_cls(venv.envs[i], _expert_config(expert_cls, seed), seed=seed),
            "held": 0,
            "physics_s": 0.0,
            "physics_cpu_s": 0.0,
            "render0": (recorder.render_seconds, recorder.render_cpu_seconds),
        }
        recorder.start(info, seed)

    def start(i: int) -> None:
        """Give slot ``i`` the next attempt whose reset succeeds (none left: it idles)."""
        nonlocal obs
        while queue:
            attempt = queue.popleft()
            seed = settings.episode_seed(attempt)
            seeds = [seed] * slots
            mask = np.zeros(slots, bool)
            mask[i] = True
            snapshot = venv.envs[i].get_state() if ready[i] else None
            try:
                obs, infos = venv.reset(seed=seeds, options={"reset_mask": mask})
            except RuntimeError as err:  # the scene diverged while settling
                failed_reset(i, attempt, seed, err)
                if snapshot is not None:
                    venv.set_states([i], [snapshot])
                continue
            ready[i] = True
            begin(i, attempt, seed, info_row(infos, i))
            return
        if not ready[i] and ready.any():  # never started: idle in another slot's state
            state = venv.envs[int(np.flatnonzero(ready)[0])].get_state()
            venv.set_states([i], [state])
            ready[i] = True

    # The first attempts start together (their settles run in one batch).
    first = [queue.popleft() for _ in range(slots)]
    seeds = [settings.episode_seed(a) for a in first]
    try:
        obs, infos = venv.reset(seed=seeds)
    except RuntimeError:  # one of them diverged while settling: start them one by one
        queue.extendleft(reversed(first))
        for i in range(slots):
            start(i)
    else:
        ready[:] = True
        for i, (attempt, seed) in enumerate(zip(first, seeds, strict=True)):
            begin(i, attempt, seed, info_row(infos, i))
    idle = venv.envs[0].settle_action
    while any(r is not None for r in running):
        active = [i for i, r in enumerate(running) if r is not None]
        render_before = sum(r.render_seconds for r in recorders)
        render_cpu_before = sum(r.render_cpu_seconds for r in recorders)
        tic, cpu = time.perf_counter(), time.process_time()
        actions = np.tile(idle, (slots, 1))
        for i in active:
            actions[i] = running[i]["expert"].act(obs[i])[0]
        obs, _, terminated, truncated, infos = venv.step(actions)
        ended = []
        for i in active:
            info = info_row(infos, i)
            recorder, slot = recorders[i], running[i]
            recorder.record(actions[i], info)
            slot["held"] = slot["held"] + 1 if info["success"] else 0
            if info["diverged"]:
                ended.append((i, "diverged", info))
            elif terminated[i] or truncated[i]:
                ended.append((i, "terminated" if terminated[i] else "time_limit", info))
            elif hold_steps and slot["held"] >= hold_steps and recorder.at_frame_boundary:
                ended.append((i, "success_held", info))
        rendered = sum(r.render_seconds for r in recorders) - render_before
        rendered_cpu = sum(r.render_cpu_seconds for r in recorders) - render_cpu_before
        wall = time.perf_counter() - tic - rendered
        cpu = time.process_time() - cpu - rendered_cpu
        for i in active:
            running[i]["physics_s"] += wall / len(active)
            running[i]["physics_cpu_s"] += cpu / len(active)
        for i, end, info in ended:
            slot, recorder = running[i], recorders[i]
            render0, render_cpu0 = slot["render0"]
            episode = recorder.finish(
                {
                    "attempt": slot["attempt"],
                    "end": end,
                    "diverged": bool(info["diverged"]),
                    "physics_s": slot["physics_s"],
                    "render_s": recorder.render_seconds - render0,
                    "physics_cpu_s": slot["physics_cpu_s"],
                    "render_cpu_s": recorder.render_cpu_seconds - render_cpu0,
                }
            )
            episode.success = bool(episode.success and not info["diverged"])
            episodes[slot["attempt"]] = episode
            running[i] = None
            start(i)
    return [episodes[int(a)] for a in attempts]


# -- the collection ------------------------------------------------------------------------
@dataclass
class CollectReport:
    out: str
    target: int
    saved: int = 0  # episodes in the dataset
    saved_successes: int = 0
    saved_failures: int = 0  # kept with keep_failures
    dropped_failures: int = 0
    attempts: int = 0  # attempts made so far (all runs of this dataset)
    new_episodes: int = 0  # saved by this run
    new_attempts: int = 0
    new_frames: int = 0
    seconds: float = 0.0
    first_save_s: float | None = None  # when this run saved its first episode (start-up)
    interrupted: str | None = None  # the signal that stopped this run
    gave_up: bool = False  # max_attempts reached before the target
    timing: dict = field(default_factory=dict)

    @property
    def success_rate(self) -> float:
        successes = self.saved_successes
        failures = self.saved_failures + self.dropped_failures
        return successes / (successes + failures) if successes + failures else 0.0

    def to_dict(self) -> dict:
        data = dataclasses.asdict(self)
        data["success_rate"] = round(self.success_rate, 4)
        hours = self.seconds / 3600.0
        data["episodes_per_hour"] = round(self.new_episodes / hours, 1) if hours > 0 else None
        return data


def _settings_path(out: Path) -> Path:
    return out / SETTINGS_FILE


def _differences(stored: dict, wanted: dict) -> list[str]:
    keys = sorted(set(stored) | set(wanted))
    return [
        f"{k}: {stored.get(k)!r} -> {wanted.get(k)!r}"
        for k in keys
        if stored.get(k) != wanted.get(k)
    ]


def _check_out(settings: CollectSettings, out: Path, resume: bool) -> dict | None:
    """Refuse an ``out`` that cannot take these settings; the commit record of the dataset to
    continue (None for a new dataset).  Cheap (no lerobot): runs before the workers start."""
    from wirecraft.datasets.writer import COMMIT_FILE, read_commit
    from wirecraft.tasks import check_state_revision

    existing = out.exists() and (not out.is_dir() or any(out.iterdir()))
    if existing and not resume:
        raise ValueError(
            f"--out {out} exists and is not empty: use --resume to continue that dataset, "
            "or choose another folder"
        )
    if existing:
        path = _settings_path(out)
        if not path.is_file():
            raise ValueError(
                f"{out} is not a dataset written by wirecraft collect (no {SETTINGS_FILE})"
            )
        stored = json.loads(path.read_text())
        check_state_revision(stored, f"{out} was collected", "refusing to mix them in one dataset")
        # Datasets from before the expert and the action were settings: scripted, joint targets.
        before = {"expert": "scripted", "action": "joint"}
        diff = _differences({**before, **stored["settings"]}, settings.to_dict())
        diff += _differences(stored.get("expert", {}), expert_description(settings))
        if diff:
            raise ValueError(
                f"{out} was collected with other settings; refusing to mix them ("
                + "; ".join(diff)
                + ")"
            )
        record = read_commit(out)
        if record is None:
            raise ValueError(f"{out}: no {COMMIT_FILE}; not a dataset written by EpisodeWriter")
        return record
    return None


def _open_writer(
    settings: CollectSettings, out: Path, existing: bool, features, robot_type, commit_every
):
    from wirecraft.datasets.writer import EpisodeWriter

    if existing:
        return EpisodeWriter.open(out, commit_every=commit_every)
    progress = {"next_attempt": 0, "attempts": 0, "dropped_failures": 0, "episodes": []}
    writer = EpisodeWriter.create(
        out,
        features,
        settings.fps,
        robot_type=robot_type,
        commit_every=commit_every,
        vcodec=settings.vcodec,
        progress=progress,
    )
    from wirecraft.datasets.writer import write_json_atomic
    from wirecraft.tasks import STATE_REVISION

    write_json_atomic(
        _settings_path(out),
        {
            "schema_version": schema.SCHEMA_VERSION,
            "state_revision": STATE_REVISION,
            "sources": list(schema.SOURCES),
            "source": "scripted",
            "settings": settings.to_dict(),
            "expert": expert_description(settings),
        },
    )
    return writer


def _record_provenance(out: Path, workers: int, ray_address: str | None) -> None:
    """Append this run's provenance to the settings file: a resumed dataset may be continued on
    another machine, and every run that added episodes is named."""
    from wirecraft.datasets.writer import write_json_atomic
    from wirecraft.provenance import provenance

    path = _settings_path(out)
    stored = json.loads(path.read_text())
    stored.setdefault("provenance", []).append(
        provenance(
            threads=workers or 1,
            ray_address=ray_address,
            started=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        )
    )
    write_json_atomic(path, stored)


def _remove_failed_start(out: Path, created: bool) -> None:
    """A new dataset that failed before its first episode: remove what was written, so that
    the same command can run again."""
    import shutil

    if created:
        shutil.rmtree(out, ignore_errors=True)
        return
    for child in out.iterdir():
        if child.is_dir():
            shutil.rmtree(child, ignore_errors=True)
        else:
            child.unlink(missing_ok=True)


def collect(
    settings: CollectSettings,
    out: str | os.PathLike,
    episodes: int,
    *,
    workers: int = 2,
    ray_address: str | None = None,
    resume: bool = False,
    commit_every: int = 10,
    max_attempts: int | None = None,
    progress_bar: bool = True,
    batch: int = DEFAULT_BATCH,
) -> CollectReport:
    """Collect until ``episodes`` episodes are in the dataset at ``out`` (see the module
    docstring); returns the report.  ``max_attempts`` (total, over every run of this dataset;
    default ``2 * episodes + 10``) bounds the attempts when the expert keeps failing.
    ``batch``: episodes a worker steps side by side (``run_episodes``); the dataset does not
    depend on it."""
    from tqdm import tqdm

    for name, value, low in (
        ("episodes", episodes, 1),
        ("workers", workers, 0),
        ("batch", batch, 1),
    ):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    if max_attempts is None:
        max_attempts = 2 * episodes + 10
    if isinstance(max_attempts, bool) or not isinstance(max_attempts, int) or max_attempts < 1:
        raise ValueError(f"max_attempts must be an integer >= 1, got {max_attempts!r}")
    out = Path(out)
    start = time.perf_counter()
    # Build the environment here first: bad task keywords fail now, with a clear message,
    # and the features come from the environment itself.
    env, recorder, _ = _episode_tools(settings)
    features = recorder.features()
    # What the dataset holds comes from its last commit (opening the writer rolls it back to
    # that commit), so the workers can start before the writer: opening it imports lerobot
    # (torch, torchvision: ~4 s of CPU), time the workers spend on their first episodes.
    created = not out.exists()
    committed = _check_out(settings, out, resume)
    progress = dict(committed["progress"] or {}) if committed else {}
    records: list[dict] = list(progress.get("episodes", []))
    report = CollectReport(
        out=str(out), target=episodes, saved=committed["episodes"] if committed else 0
    )
    report.saved_successes = sum(1 for r in records if r["success"])
    report.saved_failures = len(records) - report.saved_successes
    report.dropped_failures = int(progress.get("dropped_failures", 0))
    next_attempt = int(progress.get("next_attempt", 0))
    report.attempts = next_attempt
    timing = {k: 0.0 for k in ("physics_s", "render_s", "physics_cpu_s", "render_cpu_s")}
    timing.update(write_s=0.0, write_cpu_s=0.0)

    def current_progress() -> dict:
        return {
            "next_attempt": next_attempt,
            "attempts": report.attempts,
            "dropped_failures": report.dropped_failures,
            "episodes": list(records),
        }

    executor = None
    settings_dict = settings.to_dict()
    torch_before = None
    bar = tqdm(
        total=episodes,
        initial=min(report.saved, episodes),
        desc="collect",
        unit="episode",
        disable=not progress_bar,
        dynamic_ncols=True,
    )
    pending: deque = deque()
    submitted = next_attempt

    def submit_window() -> None:
        # No more attempts in flight than episodes still needed: when the target is reached
        # the pool is terminated, and attempts running then would be wasted work (with the
        # expert's ~100% success, half an episode per worker); a failure frees a place.
        # Each task is a run of up to ``batch`` consecutive attempts.
        nonlocal submitted
        while len(pending) < executor.window and submitted < max_attempts:
            in_flight = sum(len(run) for run, _, _ in pending)
            size = min(batch, episodes - report.saved - in_flight, max_attempts - submitted)
            if size < 1:
                break
            run = list(range(submitted, submitted + size))
            handle = executor.submit(run_episodes, settings_dict, run, batch)
            pending.append((run, handle, time.monotonic()))
            submitted += size

    try:
        with StopOnSignal(
            "finishing the episode being written, then saving the dataset"
        ) as stopper:
            if report.saved < episodes and next_attempt < max_attempts:
                executor = open_workers(workers, ray_address or None)
                submit_window()
            robot_type = env.unwrapped.robot_name
            writer = _open_writer(
                settings, out, committed is not None, features, robot_type, commit_every
            )
            # lerobot brought torch into this process: one thread next to the workers (they
            # step the expert and render; none of them loads torch).
            torch_before = set_torch_threads(DEFAULT_TORCH_THREADS)
            _record_provenance(out, workers, ray_address)
            report.saved = writer.num_episodes
            if pending:  # the head attempt's clock starts now that results can be taken
                pending[0] = (*pending[0][:2], time.monotonic())
            while executor is not None and report.saved < episodes and not stopper.stop:
                submit_window()
                if not pending:
                    report.gave_up = True
                    break
                run, handle, since = pending[0]
                try:
                    done_episodes = executor.result(handle, POLL_SECONDS)
                    timeout = ATTEMPT_TIMEOUT_S * len(run)
                    if done_episodes is None and time.monotonic() - since > timeout:
                        raise RuntimeError(
                            f"episode attempts {run[0]}-{run[-1]} gave no result in "
                            f"{timeout:.0f} s (did a worker die?)"
                        )
                except Exception:
                    # The writer is consistent: keep what was saved, then report the failure.
                    executor.close()
                    executor = None
                    writer.close(current_progress())
                    raise
                if done_episodes is None or stopper.stop:
                    continue
                pending.popleft()
                if pending:  # the next run's clock starts when it reaches the head
                    pending[0] = (*pending[0][:2], time.monotonic())
                for attempt, episode in zip(run, done_episodes, strict=True):
                    if report.saved >= episodes or stopper.stop:
                        break  # the rest of the run is made again by a later run
                    next_attempt = attempt + 1
                    report.attempts = next_attempt
                    report.new_attempts += 1
                    for key in ("physics_s", "render_s", "physics_cpu_s", "render_cpu_s"):
                        timing[key] += episode.info[key]
                    keep = episode.success or settings.keep_failures
                    if keep and len(episode):
                        tic, cpu = time.perf_counter(), time.process_time()
                        records.append(
                            {
                                "index": report.saved,
                                "attempt": attempt,
                                "seed": episode.seed,
                                "success": episode.success,
                                "frames": len(episode),
                                "control_steps": episode.control_steps,
                                "end": episode.info["end"],
                            }
                        )
                        writer.add_episode(episode, progress=current_progress())
                        timing["write_s"] += time.perf_counter() - tic
                        timing["write_cpu_s"] += time.process_time() - cpu
                        report.saved += 1
                        report.new_episodes += 1
                        report.new_frames += len(episode)
                        if report.first_save_s is None:
                            report.first_save_s = time.perf_counter() - start
                        if episode.success:
                            report.saved_successes += 1
                        else:
                            report.saved_failures += 1
                        bar.update(1)
                    else:
                        report.dropped_failures += 1
                        writer.progress = current_progress()
                    bar.set_postfix(
                        attempts=report.attempts,
                        success=f"{report.success_rate:.0%}",
                        refresh=False,
                    )
            if report.saved < episodes and not stopper.stop and next_attempt >= max_attempts:
                report.gave_up = True
            report.interrupted = stopper.stop
            if executor is not None:
                executor.close()
                executor = None
            tic, cpu = time.perf_counter(), time.process_time()
            writer.close(current_progress())
            timing["write_s"] += time.perf_counter() - tic
            timing["write_cpu_s"] += time.process_time() - cpu
    except BaseException:
        if executor is not None:
            executor.close()
        if committed is None and report.saved == 0 and out.is_dir():
            _remove_failed_start(out, created)
        raise
    finally:
        bar.close()
        set_torch_threads(torch_before)
    report.seconds = time.perf_counter() - start
    report.timing = {k: round(v, 3) for k, v in timing.items()}
    return report


def summary_lines(report: CollectReport) -> list[str]:
    d = report.to_dict()
    lines = [
        f"dataset {report.out}: {report.saved} episodes ({report.saved_successes} successful, "
        f"{report.saved_failures} failed kept); {report.dropped_failures} failed dropped; "
        f"{report.attempts} attempts, success rate {report.success_rate:.1%}",
        f"this run: {report.new_episodes} episodes in {report.seconds:.1f} s"
        + (f" ({d['episodes_per_hour']:.0f} episodes/hour)" if d["episodes_per_hour"] else ""),
    ]
    n = max(report.new_attempts, 1)
    t = report.timing
    if t:
        lines.append(
            "per attempt, summed over workers (wall / CPU s): physics+expert "
            f"{t['physics_s'] / n:.2f} / {t['physics_cpu_s'] / n:.2f}, rendering "
            f"{t['render_s'] / n:.2f} / {t['render_cpu_s'] / n:.2f}; per saved episode, "
            f"writing+encoding {t['write_s'] / max(report.new_episodes, 1):.2f} / "
            f"{t['write_cpu_s'] / max(report.new_episodes, 1):.2f}"
        )
    if report.interrupted:
        lines.append(f"interrupted by {report.interrupted}: continue with --resume")
    if report.gave_up:
        lines.append(
            f"gave up after {report.attempts} attempts with {report.saved} of {report.target} "
            "episodes: the expert fails too often (see --keep-failures, --max-attempts)"
        )
    return lines


def episode_sources(dataset) -> list[str]:
    """The data source of each episode of a loaded LeRobotDataset (from ``source``)."""
    codes = np.asarray(dataset.hf_dataset["source"]).reshape(-1)
    episode = np.asarray(dataset.hf_dataset["episode_index"]).reshape(-1)
    result = {}
    for e, c in zip(episode.tolist(), codes.tolist(), strict=True):
        result.setdefault(e, schema.source_name(c))
    return [result[e] for e in sorted(result)]
