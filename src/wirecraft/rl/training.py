"""``wirecraft train``: start or resume a PPO, SACfD or vision-PPO run in a run directory, and
load a trained policy back (``load_policy``).

A run directory is self-describing (``wirecraft_rl.json``, see ``wirecraft/rl/common.py``): a
resumed run takes its algorithm, task, environment keywords and settings from it; only the
length of training (``steps``) may change.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import io
import os
import time
from pathlib import Path
from typing import Any

from wirecraft.cli_args import write_json
from wirecraft.provenance import provenance, source_commit
from wirecraft.rl import ALGORITHMS  # noqa: E402
from wirecraft.rl.common import (
    RUN_FILE,
    RUN_FORMAT,
    ProgressTable,
    WallClock,
    check_run_state_revision,
    checkpoint_path,
    env_control,
    find_run_dir,
    read_run,
)
from wirecraft.rl.config import config_class, config_from_dict, config_to_dict, replace


def _task_family(task: str) -> str:
    import wirecraft

    for family, gym_id in wirecraft.TASK_IDS.items():
        if task in (family, gym_id):
            return family
    raise ValueError(f"unknown task {task!r}; valid: {', '.join(wirecraft.TASK_IDS)}")


def _probe_spaces(task: str, env_kwargs: dict) -> dict[str, Any]:
    """Observation and action sizes of the environment (one env, built and closed)."""
    import wirecraft

    env = wirecraft.make(task, **env_kwargs)
    try:
        space = env.observation_space
        if hasattr(space, "spaces"):
            obs = {
                "kind": env_kwargs["obs_mode"],
                "dim": int(space["state"].shape[0]),
                "proprio_dim": int(space["proprio"].shape[0]),
                "image_size": int(space["rgb_side"].shape[0]),
            }
        else:
            obs = {"kind": "state", "dim": int(space.shape[0])}
        return {"obs": obs, "action_dim": int(env.action_space.shape[0])}
    finally:
        env.close()


def _normalizer_note(algorithm: str, cfg) -> str:
    if not cfg.obs_normalization:
        return "none"
    if algorithm == "ppo":
        return "rsl-rl EmpiricalNormalization of the state (actor and critic), in the checkpoint"
    if algorithm == "sacfd":
        return "skrl RunningStandardScaler of the state, in the checkpoint"
    return (
        "actor: proprioception standardised with the behaviour-cloning data's statistics "
        "(encoder.pt); critic: rsl-rl EmpiricalNormalization of the state, in the checkpoint"
    )


def _versions(algorithm: str) -> dict[str, str]:
    from importlib.metadata import version

    import wirecraft

    names = ["torch", "skrl"] if algorithm == "sacfd" else ["torch", "rsl-rl-lib"]
    versions = {name: version(name) for name in names}
    versions["wirecraft"] = wirecraft.__version__
    commit = source_commit(Path(wirecraft.__file__).parent)
    if commit:
        versions["wirecraft_commit"] = commit
    return versions


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


class Run:
    """The run directory's JSON, updated atomically as checkpoints appear."""

    def __init__(self, run_dir: Path, data: dict) -> None:
        self.dir = Path(run_dir)
        self.data = data

    def save(self) -> None:
        write_json(self.dir / RUN_FILE, self.data)

    def checkpoint_written(self, path: Path, step: int, infos: dict) -> None:
        del step
        rel = os.path.relpath(path, self.dir)
        self.data["checkpoints"] = [c for c in self.data["checkpoints"] if c != rel] + [rel]
        self.data["latest_checkpoint"] = rel
        for key in ("env_steps", "wall_time_s", "iterations_done"):
            if key in infos:
                self.data[key] = infos[key]
        self.save()


def training_vec_options(env_kwargs: dict) -> dict:
    """make_vec options for training, which reads observations, rewards and success flags
    only: no per-environment force diagnostics, and no per-environment copies of the batch
    unless images are rendered from them (envs/vector.py)."""
    images = env_kwargs.get("obs_mode", "state") != "state"
    return {"diagnostics": False, "sync_envs": images}


def _check_expert_control(algorithm: str, task: str, env_kwargs: dict, cfg) -> None:
    """Before anything is written: a run that drives an expert for its data (SACfD's
    demonstrations, PPO's cloned start or expert starts) or labels states with the reactive
    expert needs that expert's control mode, and ``relative`` inputs need a task that defines
    them."""
    from wirecraft.rl.common import expert_for
    from wirecraft.rl.dagger import check_dagger_task
    from wirecraft.rl.features import actor_transform
    from wirecraft.tasks import TASKS

    control = env_kwargs.get("control") or TASKS.get(task).default_control
    if algorithm == "sacfd":
        expert_for(task, control, "sacfd runs' demonstrations", cfg.demo_expert)
        if cfg.bc_states == "replay" or cfg.dagger_init_iterations:
            check_dagger_task(task, control, "bc_states='replay' and dagger_init_iterations")
        actor_transform(cfg.inputs, task)  # a ValueError for a task without them
    if algorithm == "ppo" and (cfg.bc_init_transitions or cfg.expert_starts):
        expert_for(task, control, "ppo runs' expert data")
    if algorithm == "ppo" and (cfg.dagger_init_iterations or cfg.dagger_aux_lr):
        check_dagger_task(task, control)
    if algorithm == "ppo":
        actor_transform(cfg.actor_inputs, task)  # a ValueError for a task without them


def physics_backend(cfg) -> dict:
    """make_vec's backend keywords of ``cfg`` (``backend``, ``warp_device``)."""
    if cfg.backend == "cpu":
        return {}
    return {"backend": cfg.backend, "device": cfg.warp_device or None}


def _new_run(algorithm: str, task: str, env_kwargs: dict, cfg, run_dir: Path) -> Run:
    from wirecraft.tasks import STATE_REVISION, TASKS

    env_kwargs = dict(env_kwargs)
    env_kwargs.setdefault("control", TASKS.get(task).default_control)
    if algorithm == "vision-ppo":
        if env_kwargs.get("obs_mode", "state_rgb") != "state_rgb":
            raise ValueError("vision-ppo trains on obs_mode='state_rgb' (images + state)")
        env_kwargs["obs_mode"] = "state_rgb"
    elif env_kwargs.get("obs_mode", "state") != "state":
        raise ValueError(f"{algorithm} trains on obs_mode='state'")
    spaces = _probe_spaces(task, env_kwargs)
    data = {
        "format": RUN_FORMAT,
        "algorithm": algorithm,
        "task": task,
        "env_kwargs": env_kwargs,
        "control": env_kwargs["control"],
        **spaces,
        "obs_normalization": _normalizer_note(algorithm, cfg),
        "config": config_to_dict(cfg),
        "checkpoints": [],
        "latest_checkpoint": None,
        "env_steps": 0,
        "wall_time_s": 0.0,
        "created": _now(),
        "versions": _versions(algorithm),
        "state_revision": STATE_REVISION,
    }
    run = Run(run_dir, data)
    run.save()
    return run


def train(
    algorithm: str,
    task: str,
    env_kwargs: dict | None,
    out: str | os.PathLike,
    steps: int | None = None,
    *,
    overrides: dict | None = None,
    resume: bool = False,
    progress: bool = True,
) -> dict:
    """Train ``algorithm`` on ``task`` into the run directory ``out`` (resume it when
    ``resume`` and it holds a run).  ``steps``: total env steps (default: the config's);
    ``overrides``: config fields (e.g. ``num_envs``).  Returns a summary."""
    if algorithm not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {algorithm!r}; valid: {', '.join(ALGORITHMS)}")
    if steps is not None and (isinstance(steps, bool) or int(steps) != steps or steps < 1):
        raise ValueError(f"steps must be a positive integer, got {steps!r}")
    run_dir = Path(out)
    overrides = dict(overrides or {})
    fresh = None  # a new run: whether run_dir had to be created
    if (run_dir / RUN_FILE).exists():
        if not resume:
            raise ValueError(
                f"{run_dir} already holds a run: pass --resume to continue it, or another --out"
            )
        data = read_run(run_dir)
        if "shipped" in data:
            raise ValueError(
                f"{run_dir} is a shipped policy (the actor alone): resume its source run, "
                f"{data['shipped']['from_run']}"
            )
        if data["algorithm"] != algorithm:
            raise ValueError(f"{run_dir} holds a {data['algorithm']} run, not {algorithm}")
        check_run_state_revision(run_dir, data)
        cfg = config_from_dict(algorithm, data["config"])
        changed = {k: v for k, v in overrides.items() if getattr(cfg, k, object()) != v}
        if changed:
            raise ValueError(
                f"a resumed run keeps its settings; cannot change {', '.join(sorted(changed))}"
            )
        run = Run(run_dir, data)
    else:
        if run_dir.exists() and any(run_dir.iterdir()):
            raise ValueError(
                f"{run_dir} exists and is not an RL run directory; choose another --out"
            )
        cfg = replace(config_class(algorithm)(), **overrides)
        _check_expert_control(algorithm, _task_family(task), env_kwargs or {}, cfg)
        fresh = not run_dir.exists()
        run = _new_run(algorithm, _task_family(task), dict(env_kwargs or {}), cfg, run_dir)
    # One record per training session: a resumed run may continue on another machine.
    run.data.setdefault("provenance", []).append(
        provenance(threads=cfg.threads or os.cpu_count(), started=_now())
    )
    run.save()
    try:
        with _terminate_as_interrupt():
            if algorithm == "sacfd":
                _train_sacfd(cfg, run, steps, progress)
            else:
                _train_ppo_family(cfg, run, steps, progress)
    except Exception:
        if fresh is not None and not any(run_dir.rglob("*.pt")):
            _remove_failed_start(run_dir, fresh)
        raise
    rows = ProgressTable(run_dir / "progress.csv").rows()
    return {
        "run_dir": str(run_dir),
        "algorithm": algorithm,
        "env_steps": run.data["env_steps"],
        "wall_time_s": run.data["wall_time_s"],
        "latest_checkpoint": run.data["latest_checkpoint"],
        "last_progress": rows[-1] if rows else None,
    }


def _remove_failed_start(run_dir: Path, created: bool) -> None:
    """A new run that failed before saving anything learned: remove what it wrote, so that
    the same command can run again."""
    import shutil

    for child in run_dir.iterdir():
        if child.is_dir():
            shutil.rmtree(child, ignore_errors=True)
        else:
            child.unlink(missing_ok=True)
    if created:
        run_dir.rmdir()


@contextlib.contextmanager
def _terminate_as_interrupt():
    """SIGTERM (``timeout``, a scheduler) stops training like Ctrl-C: the trainers then save a
    checkpoint of the last complete iteration before leaving."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _train_ppo_family(cfg, run: Run, steps: int | None, progress: bool) -> None:
    import torch

    import wirecraft
    from wirecraft.rl import ppo

    data = run.data
    task, env_kwargs = data["task"], data["env_kwargs"]
    checkpoint = run.dir / data["latest_checkpoint"] if data["latest_checkpoint"] else None
    iterations_done = int(data.get("iterations_done", 0))
    torch.manual_seed(cfg.seed + iterations_done)
    vision = data["algorithm"] == "vision-ppo"
    obs_groups, bc_actor = ppo.observation_groups(cfg.actor_inputs, task), None
    train_cfg = ppo.runner_config(cfg, actor_groups=ppo.actor_groups(cfg.actor_inputs))
    if vision:
        encoder, bc_actor = _vision_encoder(cfg, run, progress)
        from wirecraft.rl.vision import vision_observations

        obs_groups = vision_observations(encoder)
        train_cfg = ppo.runner_config(
            cfg, actor_groups=("features",), critic_groups=("state",), actor_normalization=False
        )
    venv = wirecraft.make_vec(
        task,
        cfg.num_envs,
        threads=cfg.threads,
        **env_kwargs,
        **training_vec_options(env_kwargs),
        **physics_backend(cfg),
    )
    if cfg.expert_starts > 0:
        venv = _with_expert_starts(venv, cfg, run, iterations_done, progress)
    # a resumed run starts new episodes rather than replaying the first ones
    env = ppo.make_vec_env_adapter(
        venv,
        reward_scale=cfg.reward_scale,
        seed=cfg.seed + 7919 * iterations_done,
        obs_groups=obs_groups,
    )
    clock = WallClock(data.get("wall_time_s", 0.0))
    try:
        runner = ppo.make_runner(
            env, train_cfg, run.dir, on_save=run.checkpoint_written, clock=clock
        )
        if checkpoint is not None:
            ppo.resume(runner, checkpoint)
        elif cfg.bc_init_transitions:
            _behaviour_clone_init(runner, cfg, run, venv, progress, obs_groups)
        elif cfg.dagger_init_iterations:
            _dagger_init(runner, cfg, run, venv, progress, obs_groups)
        elif bc_actor is not None:
            runner.alg.get_policy().load_state_dict(bc_actor.state_dict())
        total = ppo.iterations_for(cfg, steps)
        # an image encoder's forward pass does want its threads
        threads = contextlib.nullcontext() if vision else ppo.single_threaded_rollouts(runner)
        quiet = contextlib.nullcontext() if progress else contextlib.redirect_stdout(io.StringIO())
        imitation = contextlib.nullcontext()
        if cfg.dagger_aux_lr:
            from wirecraft.rl.dagger import auxiliary_dagger

            imitation = auxiliary_dagger(
                runner,
                venv,
                learning_rate=cfg.dagger_aux_lr,
                decay=cfg.dagger_aux_decay,
                seed=cfg.seed + iterations_done,
            )
        # the imitation pass inside the thread switch: it runs with the update's threads
        with imitation, threads, quiet:
            ppo.learn(runner, total)
    finally:
        venv.close()


def _expert_collection(cfg, progress: bool) -> dict:
    """How a PPO run drives the scripted expert for its own data: in up to 32 environments."""
    return {"num_envs": min(cfg.num_envs, 32), "threads": cfg.threads, "progress": progress}


def _dagger_init(runner, cfg, run: Run, venv, progress: bool, obs_groups) -> None:
    from wirecraft.rl.dagger import dagger_init

    history = dagger_init(
        runner,
        venv,
        iterations=cfg.dagger_init_iterations,
        epochs=cfg.dagger_init_epochs,
        gamma=cfg.gamma,
        reward_scale=cfg.reward_scale,
        seed=cfg.seed + 15_485_863,  # not the training episodes' seeds
        obs_groups=obs_groups,
        progress=progress,
        save_dir=run.dir / "dagger_init",
    )
    run.data["dagger_init"] = history
    run.save()


def _behaviour_clone_init(runner, cfg, run: Run, venv, progress: bool, obs_groups) -> None:
    from wirecraft.rl import ppo
    from wirecraft.rl.sacfd import collect_demonstrations

    data = run.data
    demos = collect_demonstrations(
        data["task"],
        data["env_kwargs"],
        cfg.bc_init_transitions,
        seed=cfg.seed + 15_485_863,  # not the training episodes' seeds
        reward_scale=cfg.reward_scale,
        **_expert_collection(cfg, progress),
    )
    losses = ppo.behaviour_clone_init(
        runner,
        demos,
        episode_steps=int(venv.unwrapped.envs[0].max_steps),
        gamma=cfg.gamma,
        epochs=cfg.bc_init_epochs,
        seed=cfg.seed,
        progress=progress,
        obs_groups=obs_groups,
    )
    run.data["bc_init"] = {"transitions": len(demos["actions"]), "final_losses": losses}
    run.save()


def _with_expert_starts(venv, cfg, run: Run, iterations_done: int, progress: bool):
    from wirecraft.rl import expert_starts

    data = run.data

    def record():
        return expert_starts.record_expert_states(
            data["task"],
            data["env_kwargs"],
            cfg.expert_start_episodes,
            seed=cfg.seed + 104729,  # not the training episodes' seeds
            stride=cfg.expert_start_stride,
            **_expert_collection(cfg, progress),
        )

    states = expert_starts.load_or_record(run.dir, record)
    return expert_starts.ExpertStarts(
        venv, states, cfg.expert_starts, seed=cfg.seed + 7919 * iterations_done + 1
    )


def _vision_encoder(cfg, run: Run, progress: bool):
    """The frozen encoder of a vision run (behaviour-cloned on first use) and, for a run
    without PPO checkpoints yet, the behaviour-cloned actor head."""
    import torch
    from torch.utils.tensorboard import SummaryWriter

    from wirecraft.rl import ppo, vision

    data = run.data
    encoder_file = run.dir / vision.ENCODER_FILE
    bc_file = run.dir / "bc_actor.pt"
    obs = data["obs"]
    if encoder_file.exists():
        encoder = vision.load_encoder(cfg, encoder_file)
        actor = None
        if data["latest_checkpoint"] is None and bc_file.exists():
            actor = ppo.build_actor(
                cfg, encoder.out_dim, data["action_dim"], groups=("features",), normalization=False
            )
            actor.load_state_dict(torch.load(bc_file, weights_only=True))
        return encoder, actor
    encoder = vision.VisualEncoder(cfg, obs["image_size"], obs["proprio_dim"])
    actor = ppo.build_actor(
        cfg, encoder.out_dim, data["action_dim"], groups=("features",), normalization=False
    )
    bc_seed = cfg.seed + 104_729  # episodes of their own, apart from PPO's
    teacher_data = vision.collect_teacher_data(
        data["task"],
        data["env_kwargs"],
        cfg.teacher,
        cfg.bc_transitions,
        num_envs=cfg.num_envs,
        seed=bc_seed,
        threads=cfg.threads,
        progress=progress,
    )
    writer = SummaryWriter(log_dir=str(run.dir))
    started = time.monotonic()
    waves = []
    try:
        losses = vision.behaviour_clone(
            encoder,
            actor,
            teacher_data,
            cfg,
            progress=progress,
            log=lambda epoch, loss: writer.add_scalar("BC/loss", loss, epoch),
        )
        for wave in range(1, cfg.bc_dagger_waves + 1):
            # the teacher's share halves each wave; the last wave is the clone's alone
            beta = 0.5**wave if wave < cfg.bc_dagger_waves else 0.0
            labelled, rates = vision.dagger_wave(
                data["task"],
                data["env_kwargs"],
                cfg.teacher,
                lambda obs: vision.student_actions(encoder, actor, obs),
                beta,
                num_envs=cfg.bc_dagger_envs,
                seed=bc_seed + wave,
                threads=cfg.threads,
                progress=progress,
            )
            teacher_data = vision.concatenate(teacher_data, labelled)
            for name, rate in rates.items():
                writer.add_scalar(f"BC/dagger_{name}", rate, wave)
            epochs_before = len(losses)
            losses += vision.behaviour_clone(
                encoder,
                actor,
                teacher_data,
                cfg,
                progress=progress,
                log=lambda epoch, loss, start=epochs_before: writer.add_scalar(
                    "BC/loss", loss, start + epoch
                ),
            )
            waves.append({"beta": beta, **rates, "transitions": int(len(teacher_data["actions"]))})
    finally:
        writer.close()
    vision.save_encoder(encoder, cfg, encoder_file)
    torch.save(actor.state_dict(), bc_file)
    data["behaviour_cloning"] = {
        "teacher": cfg.teacher or "scripted expert",
        "transitions": int(len(teacher_data["actions"])),
        "epoch_losses": losses,
        "dagger_waves": waves,
        "wall_time_s": time.monotonic() - started,
    }
    run.save()
    return encoder.freeze(), actor


def _train_sacfd(cfg, run: Run, steps: int | None, progress: bool) -> None:
    import torch

    from wirecraft.rl.sacfd import train_sacfd

    data = run.data
    checkpoint = run.dir / data["latest_checkpoint"] if data["latest_checkpoint"] else None
    torch.manual_seed(cfg.seed)
    train_sacfd(
        cfg,
        data["task"],
        data["env_kwargs"],
        run.dir,
        total_steps=int(steps) if steps is not None else cfg.total_steps,
        checkpoint=checkpoint,
        start_env_steps=int(data.get("env_steps", 0)),
        clock=WallClock(data.get("wall_time_s", 0.0)),
        on_checkpoint=run.checkpoint_written,
        progress=progress,
    )


def parse_cli_settings(args) -> tuple[int | None, dict]:
    """(total env steps, config overrides) from ``wirecraft train`` flags."""
    from wirecraft.rl.config import parse_override

    steps = None
    if args.steps is not None:
        try:
            value = float(args.steps)
        except ValueError:
            raise ValueError(f"--steps must be a number, got {args.steps!r}") from None
        if not value >= 1 or value != int(value):
            raise ValueError(f"--steps must be a positive whole number, got {args.steps!r}")
        steps = int(value)
    template = config_class(args.algorithm)()
    overrides = dict(parse_override(text, template) for text in args.set)
    fields = {field.name for field in dataclasses.fields(template)}
    for name in ("num_envs", "seed", "threads", "backend", "warp_device"):  # flag = field
        value = getattr(args, name, None)
        if value is None:
            continue
        if name not in fields:
            flag = "--" + name.replace("_", "-")
            raise ValueError(f"{flag} is for ppo and vision-ppo, not {args.algorithm}")
        overrides[name] = value
    return steps, overrides


# -- loading ------------------------------------------------------------------------------------
def load_policy(path: str | os.PathLike, env=None):
    """The policy of an RL run: ``path`` is the run directory (latest checkpoint) or a
    checkpoint inside it.  The policy has ``control`` (its control mode), ``reset(env_ids=None)``
    and ``act(obs) -> (N, action_dim)`` deterministic (mean) actions on numpy observations as
    the environments return them.  ``env`` (a single or vector env), when given, must use the
    policy's control mode."""
    run_dir = find_run_dir(path)
    run = read_run(run_dir)
    checkpoint = checkpoint_path(run_dir, run, path if Path(path).is_file() else None)
    check_run_state_revision(run_dir, run)
    if env is not None:
        control = env_control(env)
        if control != run["control"]:
            raise ValueError(
                f"the policy in {run_dir} was trained with control={run['control']!r}; the "
                f"environment uses control={control!r}"
            )
    algorithm = run["algorithm"]
    if algorithm == "ppo":
        from wirecraft.rl.ppo import load_state_policy

        return load_state_policy(run, checkpoint)
    if algorithm == "sacfd":
        from wirecraft.rl.sacfd import load_sac_policy

        return load_sac_policy(run, checkpoint)
    if algorithm == "vision-ppo":
        from wirecraft.rl.vision import load_vision_policy

        return load_vision_policy(run, run_dir, checkpoint)
    raise ValueError(f"{run_dir}: unknown algorithm {algorithm!r}")
