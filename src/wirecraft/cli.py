"""The ``wirecraft`` program: one entry point, one sub-command per job."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from pathlib import Path

from wirecraft.cli_args import (
    add_backend_args,
    atomic_path,
    int_list,
    number,
    output_dir,
    output_file,
    ray_address,
    suffixed,
    write_json,
    write_text,
)

# Upper bounds of the command-line values (larger ones are refused, not run for days).
MAX_SECONDS = 3600.0  # simulated seconds: episodes, benchmarks, settling
MAX_ENVS = 4096
MAX_WORKERS = 1024
MAX_SEED = 2**32 - 1
FRAMEBUFFER = (1280, 960)  # off-screen width x height of every scene (scene.new_spec)

COMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None], Callable]] = {}


def command(name: str, help_text: str, configure: Callable[[argparse.ArgumentParser], None]):
    def decorator(func):
        COMMANDS[name] = (help_text, configure, func)
        return func

    return decorator


def usage_error(flag: str, message: str) -> ValueError:
    return ValueError(f"{flag}: {message}")


def check_path(flag: str, text: str, kind=output_file) -> str:
    """``kind`` (an argparse path check) as a ValueError naming ``flag``."""
    try:
        return kind(text)
    except argparse.ArgumentTypeError as err:
        raise usage_error(flag, str(err)) from None


def only_with(args, where: str, *flags: str) -> None:
    """Refuse ``flags`` given on the command line (not None / False) outside ``where``."""
    for flag in flags:
        value = getattr(args, flag.lstrip("-").replace("-", "_"))
        if value is not None and value is not False and value != []:
            raise usage_error(flag, f"applies only with {where}")


# -- task flags shared by collect, eval and train -------------------------------------------------
# Environment flags every task takes: flag -> (keyword, type, the valid names or None).
ENV_FLAGS: dict[str, tuple[str, Callable, Callable[[], list[str]] | None]] = {
    "--robot": ("robot", str, lambda: _registry_names("wirecraft.assets.robots", "ROBOTS")),
    "--wire": ("wire", str, lambda: _registry_names("wirecraft.assets.wires", "WIRE_MODELS")),
    "--control": ("control", str, lambda: _registry_names("wirecraft.control", "CONTROLLERS")),
    "--image-size": ("image_size", number(16, min(FRAMEBUFFER), integer=True), None),
    # a cell's cameras and sensor noise: a TOML file (wirecraft.cameras), recorded as its dict
    "--camera-config": ("camera_config", lambda text: camera_config_file(text), None),
}


def _registry_names(module: str, registry: str) -> list[str]:
    import importlib

    return getattr(importlib.import_module(module), registry).names()


def task_flags() -> dict[str, tuple[str, Callable, Callable[[], list[str]] | None, tuple]]:
    """Flag -> (keyword, type, valid names or None, families that take it; () = every task):
    the environment flags, then one per option field of every registered family."""
    import dataclasses

    from wirecraft.tasks import TASKS

    flags = {flag: (*spec, ()) for flag, spec in ENV_FLAGS.items()}
    for family in TASKS:
        for f in dataclasses.fields(TASKS.get(family).Options):
            flag = "--" + f.name.replace("_", "-")
            if flag in ENV_FLAGS:
                raise ValueError(f"{family}: option {f.name!r} shadows the environment's {flag}")
            _, kind, names, families = flags.get(
                flag, (f.name, f.metadata.get("parse", str), f.metadata.get("names"), ())
            )
            flags[flag] = (f.name, kind, names, (*families, family))
    return flags


def add_task_args(p: argparse.ArgumentParser, *, default_task: str | None = None) -> None:
    """``--task`` and one flag per environment keyword and task option (same names in every
    command); ``default_task`` None: the first registered family."""
    from wirecraft.tasks import TASKS, default_family

    p.add_argument(
        "--task",
        default=default_task or default_family(),
        help=f"{', '.join(TASKS)} (or a full gymnasium id)",
    )
    for flag, (key, kind, _, families) in task_flags().items():
        where = ", ".join(families) if families else "every task"
        p.add_argument(flag, dest=key, type=kind, default=None, help=f"{key} ({where})")


def task_kwargs(args: argparse.Namespace) -> tuple[str, dict]:
    """(task family, environment keyword arguments) from ``add_task_args`` flags; a flag the
    task does not take is an error, not silently ignored."""
    import wirecraft

    try:
        family = wirecraft.family_of(args.task)
    except ValueError as err:
        raise usage_error("--task", str(err)) from None
    kwargs = {}
    flags = task_flags()
    for flag, (key, _, names, families) in flags.items():
        value = getattr(args, key, None)
        if value is None:
            continue
        if families and family not in families:
            where = " and ".join(families)
            raise ValueError(f"{flag} does not apply to the {family} task (only {where})")
        if names is not None and value not in (valid := names()):
            raise usage_error(flag, f"unknown {key} {value!r}; valid: {', '.join(valid)}")
        kwargs[key] = value
    return family, kwargs


# -- list ---------------------------------------------------------------------------------------
def _list_args(p):
    p.add_argument(
        "--json", metavar="PATH", type=output_file, help="also write the listing as JSON"
    )


@command(
    "list", "list tasks, robots, control modes, connectors, wire models, parts, scenes", _list_args
)
def cmd_list(args) -> int:
    from wirecraft import register_gym_ids
    from wirecraft.assets.connectors import CONNECTORS
    from wirecraft.assets.export import part_names
    from wirecraft.assets.robots import ROBOTS
    from wirecraft.assets.wires import WIRE_MODELS
    from wirecraft.control import CONTROLLERS
    from wirecraft.showcase import SCENES

    listing = {
        "tasks": register_gym_ids(),
        "robots": ROBOTS.names(),
        "controls": CONTROLLERS.names(),
        "connectors": {
            name: {"symmetry": cls.symmetry, "description": cls.description}
            for name, cls in ((n, CONNECTORS.get(n)) for n in CONNECTORS)
        },
        "wire_models": WIRE_MODELS.names(),
        "parts": part_names(),
        "scenes": SCENES.names(),
    }
    print("tasks:")
    for name, gym_id in listing["tasks"].items():
        print(f"  {name:12s} {gym_id}")
    print("robots: " + ", ".join(listing["robots"]))
    print("control modes: " + ", ".join(listing["controls"]))
    print("connectors:")
    for name, info in listing["connectors"].items():
        fold = "continuous" if info["symmetry"] == 0 else f"{info['symmetry']}-fold"
        print(f"  {name:12s} {fold:11s} {info['description']}")
    print("wire models: " + ", ".join(listing["wire_models"]))
    print("printable parts: " + ", ".join(listing["parts"]))
    print("scenes: " + ", ".join(listing["scenes"]))
    write_json(args.json, listing)
    return 0


# -- view ---------------------------------------------------------------------------------------
def _view_args(p):
    p.add_argument(
        "--scene", default=None, help="scene to show (see `wirecraft list`; default: wires)"
    )
    p.add_argument(
        "--camera-config",
        metavar="CELL.toml",
        type=camera_config_file,
        default=None,
        help="preview a cell's cameras: the default and the configured side and wrist images "
        "of a reset task scene, side by side, written to --out (docs/tasks.md, Rendering)",
    )
    p.add_argument("--task", default=None, help="with --camera-config: the task scene")
    p.add_argument("--headless", action="store_true", help="render an image instead of a window")
    p.add_argument(
        "--out",
        type=suffixed(".png", ".jpg", ".jpeg"),
        help="image path for --headless (default: wirecraft_view.png)",
    )
    p.add_argument(
        "--settle",
        type=number(0, 60),
        help="--headless: seconds simulated before the shot, 0 to 60 (default: 1)",
    )
    w, h = FRAMEBUFFER
    p.add_argument("--width", type=number(16, w, integer=True), help=f"--headless: 16 to {w} (960)")
    p.add_argument(
        "--height", type=number(16, h, integer=True), help=f"--headless: 16 to {h} (720)"
    )


@command("view", "show a scene in MuJoCo's viewer, or render it (--headless)", _view_args)
def cmd_view(args) -> int:
    import mujoco

    from wirecraft.render import FastRenderer, save_png
    from wirecraft.scene import compile_spec
    from wirecraft.showcase import SCENES

    if args.camera_config is not None:
        return camera_preview(args)
    only_with(args, "--camera-config", "--task")
    build = SCENES.get(args.scene or "wires")
    if not args.headless:
        only_with(args, "--headless", "--out", "--settle", "--width", "--height")
        if not os.environ.get("DISPLAY") and sys.platform.startswith("linux"):
            raise RuntimeError("no display: use --headless --out FILE.png")
    out = args.out or check_path("--out", "wirecraft_view.png")
    settle = 1.0 if args.settle is None else args.settle
    spec, viewpoint = build()
    model = compile_spec(spec)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    if not args.headless:
        import mujoco.viewer

        mujoco.viewer.launch(model, data)
        return 0
    for _ in range(int(settle / model.opt.timestep)):
        mujoco.mj_step(model, data)
    with FastRenderer(model, height=args.height or 720, width=args.width or 960) as renderer:
        image = renderer.render(data, viewpoint.camera())
    with atomic_path(out) as tmp:
        save_png(image, tmp)
    print(f"wrote {out}")
    return 0


def camera_preview(args) -> int:
    """``wirecraft view --camera-config F``: default | configured, side row over wrist row."""
    import numpy as np

    import wirecraft
    from wirecraft.render import save_png

    only_with(args, "the scene viewer (without --camera-config)", "--scene")
    only_with(args, "a scene (--settle)", "--settle")
    task = args.task
    if task is None:
        from wirecraft.tasks import default_family

        task = default_family()
    try:
        task = wirecraft.family_of(task)
    except ValueError as err:
        raise usage_error("--task", str(err)) from None
    size = min(args.width or 320, args.height or 320)
    images = []
    for config in (None, args.camera_config):
        env = wirecraft.make(task, obs_mode="rgb", image_size=size, camera_config=config)
        obs, _ = env.reset(seed=0)
        images.append((obs["rgb_side"], obs["rgb_wrist"]))
        env.close()
    grid = np.concatenate(
        [np.concatenate([images[0][k], images[1][k]], axis=1) for k in (0, 1)], axis=0
    )
    out = args.out or check_path("--out", "wirecraft_cameras.png")
    with atomic_path(out) as tmp:
        save_png(grid, tmp)
    print(f"wrote {out}: default | configured; side (top), wrist (bottom); {size} px each")
    return 0


def camera_config_file(text: str) -> dict:
    """An argparse ``type=``: a camera config TOML file, as the dict environments take."""
    from wirecraft.cameras import CameraConfig

    try:
        return CameraConfig.load(text).as_dict()
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


# -- export-stl ---------------------------------------------------------------------------------
def _export_args(p):
    target = p.add_mutually_exclusive_group(required=True)
    target.add_argument("--part", help="part name (see `wirecraft list`), e.g. displayport_port")
    target.add_argument(
        "--all", action="store_true", help="export every part into --out (a folder)"
    )
    p.add_argument(
        "--clearance", type=number(0, 0.01), default=0.003, help="socket gap per side, 0 to 0.01 m"
    )
    p.add_argument("--out", required=True, help="STL file (or folder with --all)")


@command(
    "export-stl",
    "write 3D-printable STL files (millimetres) of plugs, ports, fixtures",
    _export_args,
)
def cmd_export_stl(args) -> int:
    from tqdm import tqdm

    from wirecraft.assets.export import export_stl, part_mesh, part_names

    if args.all:
        check_path("--out", args.out, output_dir)
    else:
        check_path("--out", args.out, suffixed(".stl"))
        if args.part not in part_names():
            raise usage_error(
                "--part", f"unknown part {args.part!r}; valid: {', '.join(part_names())}"
            )
    if not args.all:
        path = export_stl(args.part, args.out, clearance=args.clearance)
        mesh = part_mesh(args.part, args.clearance)
        print(f"wrote {path}: {mesh.extents.round(2).tolist()} mm, {mesh.volume:.0f} mm^3")
        return 0
    for part in tqdm(part_names(), desc="export-stl", unit="part"):
        export_stl(part, Path(args.out) / f"{part}.stl", clearance=args.clearance)
    print(f"wrote {len(part_names())} parts to {args.out}")
    return 0


# -- bench --------------------------------------------------------------------------------------
BENCH_SUITES = ("wires", "robots", "envs")


def _bench_args(p):
    p.add_argument("--suite", default="wires", choices=BENCH_SUITES, help="(default: wires)")
    p.add_argument(
        "--seconds",
        type=number(0, 600, low_open=True),
        default=None,
        help="seconds timed per row, up to 600 (default: 5; 60 with --backend warp)",
    )
    p.add_argument(
        "--wire",
        nargs="+",
        default=None,
        help="wires and envs suites: wire models (default: all; envs: articulated)",
    )
    p.add_argument(
        "--task", nargs="+", default=None, help="envs suite: tasks (default: the first family)"
    )
    p.add_argument(
        "--num-envs",
        type=int_list(1, MAX_ENVS),
        default=None,
        help=f"envs suite: comma-separated counts, 1 to {MAX_ENVS} (default: 1,4,16,64,256; "
        "with --backend warp 1024,4096,8192,16384,32768)",
    )
    p.add_argument(
        "--threads",
        type=int_list(1, 1024),
        default=None,
        help="envs suite: comma-separated thread counts (default: 1,2)",
    )
    p.add_argument(
        "--warmup",
        type=number(0, 600),
        default=None,
        help="envs suite: warm-up seconds, up to 600 (default: 1; 5 with --backend warp)",
    )
    add_backend_args(p, "--device", "envs suite: ")
    p.add_argument(
        "--full-info",
        action="store_true",
        help="envs suite: with per-environment diagnostics and synced environments "
        "(as evaluation runs); default: as training runs",
    )
    p.add_argument(
        "--out", type=output_dir, help="envs suite: folder for CSV and PNG (default: out/bench)"
    )
    p.add_argument("--json", metavar="PATH", type=output_file, help="write the rows as JSON")
    for flag, (key, kind, _, families) in task_flags().items():
        if families:  # the families' own options (--num-clips, --channel, ...)
            help_text = f"envs suite: {key} of the {', '.join(families)} rows"
            p.add_argument(flag, dest=f"option_{key}", type=kind, default=None, help=help_text)


def _bench_options(args, tasks) -> dict[str, dict]:
    """task -> the task options given as flags; a flag that no benchmarked task takes is an
    error."""
    options: dict[str, dict] = {task: {} for task in tasks}
    for flag, (key, _, names, families) in task_flags().items():
        value = getattr(args, f"option_{key}", None)
        if not families or value is None:
            continue
        takers = [task for task in tasks if task in families]
        if not takers:
            raise usage_error(
                flag, f"taken by {', '.join(families)} only; benchmarked: {', '.join(tasks)}"
            )
        if names is not None and value not in names():
            raise usage_error(flag, f"unknown {key} {value!r}; valid: {', '.join(names())}")
        for task in takers:
            options[task][key] = value
    return options


@command("bench", "print throughput figures (physics steps/s, real-time factor)", _bench_args)
def cmd_bench(args) -> int:
    if args.suite != "envs":
        envs_flags = ("--task", "--num-envs", "--threads", "--warmup", "--backend", "--device")
        envs_flags += ("--full-info", "--out")
        only_with(args, "--suite envs", *envs_flags)
        given = [
            flag
            for flag, (key, *_) in task_flags().items()
            if getattr(args, f"option_{key}", None) is not None
        ]
        if given:
            raise usage_error(given[0], "only with --suite envs")
    if args.suite == "robots":
        only_with(args, "--suite wires or --suite envs", "--wire")
    from wirecraft.assets.wires import WIRE_MODELS
    from wirecraft.bench import robots, wires

    for wire in args.wire or []:
        if wire not in WIRE_MODELS.names():
            raise usage_error(
                "--wire", f"unknown wire model {wire!r}; valid: {', '.join(WIRE_MODELS.names())}"
            )

    if args.suite == "wires":
        rows = wires.run(args.seconds or 5.0, args.wire)
        wires.print_table(rows)
    elif args.suite == "robots":
        rows = robots.run(args.seconds or 5.0)
        robots.print_table(rows)
    else:
        from wirecraft import register_gym_ids
        from wirecraft.bench import envs
        from wirecraft.tasks import default_family

        tasks = args.task or [default_family()]
        for task in tasks:
            if task not in (ids := register_gym_ids()):
                raise usage_error("--task", f"unknown task {task!r}; valid: {', '.join(ids)}")
        out = Path(args.out or check_path("--out", "out/bench", output_dir))
        wire_models = args.wire or ["articulated"]
        backend = args.backend or "cpu"
        if backend == "warp":
            only_with(args, "--backend cpu", "--threads")
        else:
            only_with(args, "--backend warp", "--device")
        warp = backend == "warp"
        counts = args.num_envs or (
            [1024, 4096, 8192, 16384, 32768] if warp else [1, 4, 16, 64, 256]
        )
        threads = args.threads or [1, 2]
        warmup = args.warmup if args.warmup is not None else 5.0 if warp else 1.0
        seconds = args.seconds or (60.0 if warp else 5.0)
        info = "full" if args.full_info else "training"
        options = _bench_options(args, tasks)
        rows, too_big, failed = envs.run(
            tasks,
            wire_models,
            counts,
            threads,
            seconds,
            warmup,
            info,
            options,
            backend,
            args.device,
        )
        envs.print_table(rows)
        with atomic_path(out / "bench_envs.csv") as tmp:
            envs.write_csv(rows, tmp)
        with atomic_path(out / "bench_envs.png") as tmp:
            envs.plot(rows, tmp)
        print(f"wrote {out}/bench_envs.csv and {out}/bench_envs.png")
    from wirecraft.provenance import provenance

    document = {"suite": args.suite, "rows": rows, "provenance": provenance()}
    if args.suite == "envs":
        document.update(did_not_fit=too_big, not_measured=failed)
    write_json(args.json, document)
    return 0


# -- demo ---------------------------------------------------------------------------------------
def _demo_args(p):
    p.add_argument(
        "--out", type=output_dir, default="out/demo", help="folder for the images and summary"
    )
    p.add_argument(
        "--seconds",
        type=number(0, 60, low_open=True),
        default=2.0,
        help="simulated seconds per wire drop, up to 60 (default: 2)",
    )
    p.add_argument(
        "--json",
        metavar="PATH",
        type=output_file,
        help="summary as JSON (default: OUT/summary.json)",
    )


@command(
    "demo",
    "run the main job on the CPU: every task's scripted expert (videos) and every wire model",
    _demo_args,
)
def cmd_demo(args) -> int:
    from wirecraft.demo import run_demo, run_task_demo, summary_markdown

    tasks = run_task_demo(args.out)
    print(
        f"{'task':10s} {'expert':16s} {'success':>8s} {'first (s)':>9s} {'steps/s':>8s} "
        f"{'return':>8s}  video"
    )
    for r in tasks:
        first = "-" if r["first_success_s"] is None else r["first_success_s"]
        print(
            f"{r['task']:10s} {r['policy']:16s} {str(r['success']):>8s} {first:>9} "
            f"{r['control_steps_per_s']:>8} {r['return']:>8.1f}  {r['video']}"
        )
    rows = run_demo(args.out, seconds=args.seconds)
    header = (
        f"{'wire':12s} {'steps/s':>9s} {'x real time':>11s} {'in channel':>10s} {'diverged':>8s}"
    )
    print(header)
    for r in rows:
        print(
            f"{r['wire']:12s} {r['physics_steps_per_s']:>9} {r['realtime_factor']:>11} "
            f"{r['fraction_in_channel']:>10.0%} {str(r['diverged']):>8s}"
        )
    write_json(args.json or str(Path(args.out) / "summary.json"), {"tasks": tasks, "rows": rows})
    write_text(Path(args.out) / "summary.md", summary_markdown(tasks, rows))
    videos = ", ".join(r["video"] for r in tasks)
    print(f"wrote {args.out}: {videos}, tasks.png, wires.png, summary.md, summary.json")
    return 1 if any(r["diverged"] for r in rows + tasks) else 0


# -- collect ------------------------------------------------------------------------------------
def _collect_args(p):
    add_task_args(p)
    p.set_defaults(task=None)  # None: the first family (--policy: the run's own)
    p.add_argument(
        "--episodes",
        type=number(1, 10**6, integer=True),
        default=10,
        help="episodes the dataset should hold",
    )
    p.add_argument("--out", type=output_dir, required=True, help="dataset folder (LeRobot v3)")
    p.add_argument(
        "--workers",
        type=number(0, MAX_WORKERS, integer=True),
        default=None,
        help="worker processes (0: this process; default 2); with --ray local: its CPUs",
    )
    p.add_argument(
        "--ray",
        metavar="ADDRESS",
        type=ray_address,
        help="generate with Ray: HOST:PORT, auto, or local (start one here)",
    )
    p.add_argument(
        "--expert",
        choices=("scripted", "reactive"),
        default=None,
        help="who demonstrates: the task's scripted expert (default) or its reactive expert "
        "(no memory: the action is a function of the state)",
    )
    p.add_argument(
        "--action",
        choices=("joint", "env"),
        default="joint",
        help="what a frame's `action` holds: joint, the arm's joint targets and the gripper "
        "gap (default); env, the frame's 60 / fps environment actions in the control mode "
        "(action.env as float32; the joint targets then go to action.joint)",
    )
    p.add_argument("--keep-failures", action="store_true", help="also save failed episodes")
    p.add_argument("--resume", action="store_true", help="continue the dataset in --out")
    p.add_argument(
        "--fps",
        type=number(1, 60, integer=True),
        default=30,
        help="frames per second (a divisor of 60)",
    )
    p.add_argument(
        "--seed",
        type=number(0, MAX_SEED, integer=True),
        default=0,
        help="episode k is reset with seed (SEED, k)",
    )
    p.add_argument(
        "--success-hold",
        type=number(0, 60),
        default=None,
        help="end once success held this long, 0 to 60 s (0: never early; default 0.5)",
    )
    p.add_argument(
        "--vcodec", default="h264", choices=("h264", "libsvtav1"), help="video codec (AV1: svt)"
    )
    p.add_argument(
        "--commit-every",
        type=number(1, 10**6, integer=True),
        default=None,
        help="episodes per durable commit (default 10)",
    )
    p.add_argument(
        "--max-attempts",
        type=number(1, 10**7, integer=True),
        default=None,
        help="default: 2 * episodes + 10",
    )
    p.add_argument(
        "--batch",
        type=number(1, 256, integer=True),
        default=None,
        help="episodes each worker steps side by side (default 4; the dataset does not depend "
        "on it)",
    )
    p.add_argument("--json", metavar="PATH", type=output_file, help="write the report as JSON")
    p.add_argument(
        "--policy",
        metavar="RUN",
        default=None,
        help="record a trained RL policy's episodes instead (an RL run directory or checkpoint; "
        "source rl; its own task and environment; episode k reset with seed SEED + k; every "
        "episode kept)",
    )


# collect flags that apply to scripted demonstrations only (not to --policy rollouts).
SCRIPTED_ONLY = (
    "--expert",
    "--workers",
    "--ray",
    "--keep-failures",
    "--resume",
    "--success-hold",
    "--commit-every",
    "--max-attempts",
    "--batch",
)


@command(
    "collect",
    "write scripted demonstrations (or a trained RL policy's rollouts) as a LeRobot v3 dataset",
    _collect_args,
)
def cmd_collect(args) -> int:
    if args.policy is not None:
        return collect_rollouts(args)
    if args.task is None:
        from wirecraft.tasks import default_family

        args.task = default_family()
    from wirecraft.datasets.collect import (
        DEFAULT_BATCH,
        DEFAULT_IMAGE_SIZE,
        CollectSettings,
        collect,
        summary_lines,
    )

    family, kwargs = task_kwargs(args)
    out = Path(args.out)
    if args.resume:
        check_resume(
            args.out, "meta/wirecraft_collect.json", "dataset written by wirecraft collect"
        )
    elif out.is_dir() and any(out.iterdir()):
        raise usage_error(
            "--out", f"{out} exists and is not empty: --resume continues that dataset"
        )
    if args.ray and args.ray != "local":
        only_with(args, "--ray local or without --ray", "--workers")
    image_size = kwargs.pop("image_size", DEFAULT_IMAGE_SIZE)
    settings = CollectSettings(
        task=family,
        env_kwargs=kwargs,
        image_size=image_size,
        fps=args.fps,
        seed=args.seed,
        keep_failures=args.keep_failures,
        success_hold_s=0.5 if args.success_hold is None else args.success_hold,
        vcodec=args.vcodec,
        expert=args.expert or "scripted",
        action=args.action,
    )
    report = collect(
        settings,
        args.out,
        args.episodes,
        workers=2 if args.workers is None else args.workers,
        ray_address=args.ray,
        resume=args.resume,
        commit_every=args.commit_every or 10,
        max_attempts=args.max_attempts,
        batch=DEFAULT_BATCH if args.batch is None else args.batch,
    )
    for line in summary_lines(report):
        print(line)
    write_json(args.json, report.to_dict())
    if report.interrupted:
        return 128 + int(getattr(__import__("signal"), report.interrupted))
    return 1 if report.gave_up else 0


def collect_rollouts(args) -> int:
    """``wirecraft collect --policy RUN``: the policy's episodes in the shared schema."""
    from wirecraft.rl.record import record_rollouts

    only_with(args, "scripted demonstrations (without --policy)", *SCRIPTED_ONLY)
    only_with(args, "scripted demonstrations (the run keeps its own task)", "--task")
    flags = {flag: spec for flag, spec in task_flags().items() if flag != "--image-size"}
    only_with(args, "scripted demonstrations (the run keeps its environment)", *flags)
    if args.vcodec != "h264":
        raise usage_error("--vcodec", "applies only to scripted demonstrations")
    out = Path(args.out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise usage_error("--out", f"{out} exists and is not empty")
    try:
        written = record_rollouts(
            args.policy,
            out,
            args.episodes,
            seed=args.seed,
            fps=args.fps,
            image_size=args.image_size,
            action=args.action,
        )
    except ValueError as err:
        raise usage_error("--policy", str(err)) from None
    print(
        f"dataset {out}: {written['episodes']} episodes of {args.policy} ({written['frames']} "
        f"frames, {written['successes']} successful), source rl"
    )
    write_json(args.json, written)
    return 0


def check_resume(out: str, marker: str, kind: str) -> None:
    """``--resume`` needs something to continue: refuse a missing or foreign ``out``."""
    if not Path(out).exists():
        raise usage_error("--resume", f"{out} does not exist: nothing to resume")
    if not (Path(out) / marker).is_file():
        raise usage_error("--resume", f"{out} is not a {kind} (no {marker}): nothing to resume")


# -- mix ----------------------------------------------------------------------------------------
def _mix_args(p):
    p.add_argument(
        "--input",
        action="append",
        required=True,
        metavar="DIR[:WEIGHT]",
        help="a dataset (any source) and its weight (default 1): it makes up "
        "WEIGHT / sum of the weights of the frames training samples; two or more",
    )
    p.add_argument("--out", required=True, help="the new dataset (must not exist)")
    p.add_argument(
        "--max-copies",
        type=number(1, 10**4, integer=True),
        default=100,
        help="the most copies of one input's episodes the weights may need (default 100)",
    )
    p.add_argument("--json", metavar="PATH", type=output_file, help="write the record as JSON")


@command("mix", "merge datasets into one, weighting each by repeating its episodes", _mix_args)
def cmd_mix(args) -> int:
    from wirecraft.datasets.mix import mix, parse_input, summary_lines

    inputs = [parse_input(text) for text in args.input]
    record = mix(inputs, args.out, max_copies=args.max_copies)
    for line in summary_lines(record, args.out):
        print(line)
    write_json(args.json, record)
    return 0


# -- import -------------------------------------------------------------------------------------
def _import_args(p):
    p.add_argument(
        "--from", dest="source_dir", required=True, metavar="DIR", help="the LeRobot v3 dataset"
    )
    p.add_argument(
        "--source", required=True, choices=("real", "teleop"), help="where its data came from"
    )
    p.add_argument("--robot", required=True, help="the robot it was recorded on (e.g. ur5)")
    p.add_argument(
        "--map",
        required=True,
        metavar="MAP.toml",
        help="which foreign features hold the joints, gripper, cameras, in which units "
        "(docs/datasets.md)",
    )
    p.add_argument("--out", required=True, help="the new dataset (must not exist, or be empty)")
    p.add_argument(
        "--task", metavar="FAMILY", help="task family for the success flags (default: the map's)"
    )
    p.add_argument("--json", metavar="PATH", type=output_file, help="write the record as JSON")


@command(
    "import",
    "convert a LeRobot dataset recorded elsewhere (real robot, teleoperation) to this schema",
    _import_args,
)
def cmd_import(args) -> int:
    from wirecraft.datasets.importer import import_dataset, load_map, summary_lines

    record = import_dataset(
        args.source_dir,
        args.out,
        source=args.source,
        robot=args.robot,
        mapping=load_map(args.map),
        task=args.task,
        map_file=args.map,
    )
    for line in summary_lines(record, args.out):
        print(line)
    write_json(args.json, record)
    return 0


# -- train --------------------------------------------------------------------------------------
RL_ALGORITHMS = ("ppo", "sacfd", "vision-ppo")
IL_ALGORITHMS = ("act", "diffusion", "smolvla", "pi05")  # wirecraft.il.train.ALGORITHMS
IL_FLAGS = (
    "--dataset",
    "--batch-size",
    "--device",
    "--preset",
    "--pretrained",
    "--policy-arg",
    "--train-arg",
    "--torch-threads",
)
# Imitation flags a resumed run takes again (the others are the run's settings).
IL_SESSION_FLAGS = ("--train-arg", "--torch-threads")
RL_FLAGS = (
    "--num-envs",
    "--threads",
    "--backend",
    "--warp-device",
    "--episode-seconds",
    "--set",
    "--task",
)  # + task flags


def torch_device(text: str) -> str:
    """An argparse ``type=``: cpu, cuda, cuda:N or mps."""
    head, _, index = text.partition(":")
    if head in ("cpu", "mps") and not index or head == "cuda" and (not index or index.isdigit()):
        return text
    raise argparse.ArgumentTypeError(f"expected cpu, cuda, cuda:N or mps, got {text!r}")


def _train_args(p):
    p.add_argument(
        "algorithm",
        choices=RL_ALGORITHMS + IL_ALGORITHMS,
        help="RL baseline (ppo, sacfd, vision-ppo) or imitation policy trained by LeRobot "
        "(act, diffusion; smolvla and pi05 only from a local checkpoint, --pretrained)",
    )
    add_task_args(p)
    p.set_defaults(task=None)
    p.add_argument(
        "--out", type=output_dir, required=True, help="run directory (checkpoints, logs, settings)"
    )
    p.add_argument(
        "--num-envs",
        type=number(1, MAX_ENVS, integer=True),
        default=None,
        help=f"parallel environments, 1 to {MAX_ENVS}",
    )
    p.add_argument(
        "--steps",
        type=number(1, 1e12),
        default=None,
        help="total env steps, e.g. 2e6 (default: config's)",
    )
    p.add_argument("--seed", type=number(0, MAX_SEED, integer=True), default=None)
    p.add_argument(
        "--threads",
        type=number(0, 1024, integer=True),
        default=None,
        help="physics threads (0: all CPUs)",
    )
    add_backend_args(p, where="RL: ")
    p.add_argument(
        "--episode-seconds",
        type=number(0, MAX_SECONDS, low_open=True),
        default=None,
        help=f"episode length, up to {MAX_SECONDS:g} s",
    )
    p.add_argument("--resume", action="store_true", help="continue the run in --out")
    p.add_argument(
        "--set", action="append", default=[], metavar="NAME=VALUE", help="any config setting"
    )
    p.add_argument("--json", metavar="PATH", type=output_file, help="write the run summary as JSON")
    il = p.add_argument_group("imitation (act, diffusion, smolvla, pi05)")
    il.add_argument("--dataset", metavar="DIR", help="a dataset written by wirecraft collect")
    il.add_argument(
        "--batch-size",
        type=number(1, 1_000_000, integer=True),
        default=None,
        help="default: the reference's (ACT 64; Diffusion: LeRobot's 8)",
    )
    il.add_argument(
        "--device", type=torch_device, default=None, help="cpu, cuda (default: LeRobot's choice)"
    )
    il.add_argument(
        "--preset",
        choices=("cpu",),
        default=None,
        help="cpu: a reduced model and batch for CPU training (a starting point)",
    )
    il.add_argument(
        "--pretrained",
        metavar="PATH",
        default=None,
        help="act/diffusion: torchvision's ImageNet ResNet-18 file (resnet18-f37072fd.pth) or a "
        "folder holding it; smolvla/pi05: a LeRobot checkpoint folder (required)",
    )
    il.add_argument(
        "--policy-arg",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="any LeRobot policy option (--policy.KEY=VALUE), e.g. dim_model=256",
    )
    il.add_argument(
        "--train-arg",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="any other lerobot-train option, e.g. save_freq=5000, num_workers=2, "
        "eval.n_episodes=16, env_eval_freq=0",
    )
    il.add_argument(
        "--torch-threads",
        type=number(1, 1024, integer=True),
        default=None,
        help="torch's CPU threads in the training process (OMP_NUM_THREADS; default: torch's, "
        "one per core); 1 beside other busy jobs",
    )


def cmd_train_il(args) -> int:
    """``wirecraft train act|diffusion|smolvla|pi05``: LeRobot's training (wirecraft.il)."""
    from wirecraft.il.train import parse_pairs, train

    only_with(args, "RL algorithms (ppo, sacfd, vision-ppo)", *RL_FLAGS, *task_flags())
    train_args = parse_pairs("--train-arg", args.train_arg)
    if args.seed is not None:
        train_args["seed"] = str(args.seed)
    if args.resume:
        new_run_flags = [f for f in IL_FLAGS if f not in IL_SESSION_FLAGS]
        only_with(args, "a new run (a resumed run keeps its settings)", *new_run_flags)
        options = {"steps": args.steps, "train_args": train_args}
    else:
        if args.dataset is None:
            raise usage_error("--dataset", f"{args.algorithm} trains on a dataset: --dataset DIR")
        options = {
            "steps": args.steps,
            "batch_size": args.batch_size,
            "device": args.device,
            "preset": args.preset,
            "policy_args": parse_pairs("--policy-arg", args.policy_arg),
            "train_args": train_args,
            "pretrained": args.pretrained,
        }
    options["torch_threads"] = args.torch_threads
    command = ["wirecraft", *getattr(args, "argv", sys.argv[1:])]
    record = train(
        args.algorithm, args.dataset, args.out, resume=args.resume, command=command, **options
    )
    session = record["sessions"][-1]
    print(
        f"{args.algorithm}: step {session['last_step']} in {session['wall_time_s']:.0f} s; "
        f"checkpoints in {args.out}/checkpoints, record {args.out}/wirecraft_il.json"
    )
    write_json(args.json, record)
    return 0


def check_resumed_run(args) -> None:
    """A resumed run keeps its task and environment: a task flag must repeat what it holds."""
    from wirecraft.rl.common import read_run

    run = read_run(Path(args.out))
    if args.task is not None:
        family, _ = task_kwargs(args)
        if family != run["task"]:
            raise usage_error("--task", f"{args.out} holds a {run['task']} run, not {family}")
    given = {flag: getattr(args, spec[0]) for flag, spec in task_flags().items()}
    given["--episode-seconds"] = args.episode_seconds
    stored = run["env_kwargs"]
    for flag, value in given.items():
        key = flag[2:].replace("-", "_")
        if value is not None and stored.get(key) != value:
            raise usage_error(
                flag,
                f"a resumed run keeps its environment ({key}={stored.get(key)!r} in {args.out})",
            )


@command(
    "train",
    "train an RL baseline (PPO, SACfD, vision PPO) or, through LeRobot, an imitation policy "
    "(ACT, Diffusion Policy); resumable",
    _train_args,
)
def cmd_train(args) -> int:
    if args.algorithm in IL_ALGORITHMS:
        return cmd_train_il(args)
    only_with(args, "imitation algorithms (act, diffusion, smolvla, pi05)", *IL_FLAGS)
    from wirecraft.rl.common import RUN_FILE
    from wirecraft.rl.training import parse_cli_settings, train

    if args.resume:
        check_resume(args.out, RUN_FILE, "RL run directory")
        check_resumed_run(args)
    if args.task is None:
        from wirecraft.tasks import default_family

        args.task = default_family()
    task, env_kwargs = task_kwargs(args)
    if args.episode_seconds is not None:
        env_kwargs["episode_seconds"] = args.episode_seconds
    steps, overrides = parse_cli_settings(args)
    summary = train(
        args.algorithm,
        task,
        env_kwargs,
        args.out,
        steps=steps,
        overrides=overrides,
        resume=args.resume,
    )
    print(
        f"{args.algorithm}: {summary['env_steps']} env steps in {summary['wall_time_s']:.0f} s; "
        f"latest checkpoint {args.out}/{summary['latest_checkpoint']}"
    )
    write_json(args.json, summary)
    return 0


# -- eval ---------------------------------------------------------------------------------------
def _eval_args(p):
    from wirecraft.evaluation.command import configure

    configure(p, add_task_args)


@command("eval", "evaluate a policy on the seeded protocol (metrics, failures, report)", _eval_args)
def cmd_eval(args) -> int:
    from wirecraft.evaluation.command import run

    return run(args, task_kwargs, write_json)


def _teleop_args(p):
    from wirecraft.teleop.command import configure

    configure(p, add_task_args)


@command(
    "teleop",
    "drive the robot by hand in MuJoCo's viewer (keyboard, SpaceMouse, game pad) or replay a "
    "command stream, and record the saved episodes as a LeRobot dataset (source teleop)",
    _teleop_args,
)
def cmd_teleop(args) -> int:
    from wirecraft.teleop.command import run

    return run(args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="wirecraft",
        description="WireCraft: simulation benchmark for wire and cable manipulation.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (help_text, configure, _) in COMMANDS.items():
        configure(sub.add_parser(name, help=help_text, description=help_text))
    return parser


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exit_:
        return exit_.code if isinstance(exit_.code, int) else 2
    args.argv = list(sys.argv[1:] if argv is None else argv)
    try:
        return COMMANDS[args.command][2](args)
    except (ValueError, RuntimeError, OSError, MemoryError) as err:
        print(f"wirecraft {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"wirecraft {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
