"""The ``wirecraft`` program: one entry point, one sub-command per job."""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path

COMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None], Callable]] = {}


def command(name: str, help_text: str, configure: Callable[[argparse.ArgumentParser], None]):
    def decorator(func):
        COMMANDS[name] = (help_text, configure, func)
        return func

    return decorator


def write_json(path: str | None, payload) -> None:
    """Write results atomically (a crash never leaves half a file)."""
    if not path:
        return
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2, sort_keys=True) + "\n")
    os.replace(tmp, path)


# -- task flags shared by collect, eval and train -------------------------------------------------
# Flag -> (keyword, type, task families that accept it).  None as families: every task.
TASK_FLAGS: dict[str, tuple[str, type, tuple[str, ...] | None]] = {
    "--robot": ("robot", str, None),
    "--wire": ("wire", str, None),
    "--control": ("control", str, None),
    "--image-size": ("image_size", int, None),
    "--connector": ("connector", str, ("insertion", "routing")),
    "--clearance": ("clearance", float, ("insertion",)),
    "--num-clips": ("num_clips", int, ("routing",)),
    "--clip-opening": ("clip_opening", float, ("routing",)),
    "--channel": ("channel", str, ("seating",)),
}


def add_task_args(p: argparse.ArgumentParser, *, default_task: str | None = "insertion") -> None:
    """``--task`` and one flag per environment keyword (same names in every command)."""
    p.add_argument(
        "--task",
        default=default_task,
        required=default_task is None,
        help="insertion, routing or seating (or a full gymnasium id)",
    )
    for flag, (key, kind, families) in TASK_FLAGS.items():
        where = "every task" if families is None else ", ".join(families)
        p.add_argument(flag, dest=key, type=kind, default=None, help=f"{key} ({where})")


def task_kwargs(args: argparse.Namespace) -> tuple[str, dict]:
    """(task family, environment keyword arguments) from ``add_task_args`` flags; a flag the
    task does not take is an error, not silently ignored."""
    import wirecraft

    task = args.task
    family = next((k for k, v in wirecraft.TASK_IDS.items() if task in (k, v)), None)
    if family is None:
        raise ValueError(f"unknown task {task!r}; valid: {', '.join(wirecraft.TASK_IDS)}")
    kwargs = {}
    for flag, (key, _, families) in TASK_FLAGS.items():
        value = getattr(args, key, None)
        if value is None:
            continue
        if families is not None and family not in families:
            raise ValueError(f"{flag} does not apply to the {family} task")
        kwargs[key] = value
    return family, kwargs


# -- list ---------------------------------------------------------------------------------------
def _list_args(p):
    p.add_argument("--json", metavar="PATH", help="also write the listing as JSON")


@command(
    "list", "list tasks, robots, control modes, connectors, wire models, parts, scenes", _list_args
)
def cmd_list(args) -> int:
    from wirecraft import TASK_IDS
    from wirecraft.assets.connectors import CONNECTORS
    from wirecraft.assets.export import part_names
    from wirecraft.assets.robots import ROBOTS
    from wirecraft.assets.wires import WIRE_MODELS
    from wirecraft.control import CONTROLLERS
    from wirecraft.scenes import SCENES

    listing = {
        "tasks": TASK_IDS,
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
    for name, gym_id in TASK_IDS.items():
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
    p.add_argument("--scene", default="wires", help="scene to show (see `wirecraft list`)")
    p.add_argument("--headless", action="store_true", help="render an image instead of a window")
    p.add_argument("--out", default="wirecraft_view.png", help="image path for --headless")
    p.add_argument("--settle", type=float, default=1.0, help="seconds simulated before the shot")
    p.add_argument("--width", type=int, default=960)
    p.add_argument("--height", type=int, default=720)


@command("view", "show a scene in MuJoCo's viewer, or render it (--headless)", _view_args)
def cmd_view(args) -> int:
    import mujoco

    from wirecraft.render import FastRenderer, save_png
    from wirecraft.scene import compile_spec
    from wirecraft.scenes import SCENES

    build = SCENES.get(args.scene)
    if args.settle < 0:
        raise ValueError(f"--settle must be >= 0, got {args.settle}")
    spec, viewpoint = build()
    model = compile_spec(spec)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    if not args.headless:
        if not os.environ.get("DISPLAY") and sys.platform.startswith("linux"):
            raise RuntimeError("no display: use --headless --out FILE.png")
        import mujoco.viewer

        mujoco.viewer.launch(model, data)
        return 0
    for _ in range(int(args.settle / model.opt.timestep)):
        mujoco.mj_step(model, data)
    with FastRenderer(model, height=args.height, width=args.width) as renderer:
        path = save_png(renderer.render(data, viewpoint.camera()), args.out)
    print(f"wrote {path}")
    return 0


# -- export-stl ---------------------------------------------------------------------------------
def _export_args(p):
    target = p.add_mutually_exclusive_group(required=True)
    target.add_argument("--part", help="part name (see `wirecraft list`), e.g. displayport_port")
    target.add_argument(
        "--all", action="store_true", help="export every part into --out (a folder)"
    )
    p.add_argument("--clearance", type=float, default=0.003, help="socket gap per side, metres")
    p.add_argument("--out", required=True, help="STL file (or folder with --all)")


@command(
    "export-stl",
    "write 3D-printable STL files (millimetres) of plugs, ports, fixtures",
    _export_args,
)
def cmd_export_stl(args) -> int:
    from tqdm import tqdm

    from wirecraft.assets.export import export_stl, part_mesh, part_names

    if not args.all:
        path = export_stl(args.part, args.out, clearance=args.clearance)
        mesh = part_mesh(args.part, args.clearance)
        print(f"wrote {path}: {mesh.extents.round(2).tolist()} mm, {mesh.volume:.0f} mm^3")
        return 0
    for part in tqdm(part_names(), desc="export-stl", unit="part"):
        export_stl(part, Path(args.out) / f"{part}.stl", clearance=args.clearance)
    print(f"wrote {len(part_names())} parts to {args.out}")
    return 0


def _int_list(flag: str, text: str) -> list[int]:
    try:
        values = [int(v) for v in str(text).split(",") if v.strip()]
    except ValueError:
        raise ValueError(f"{flag} must be comma-separated integers, got {text!r}") from None
    if not values or min(values) < 1:
        raise ValueError(f"{flag} must be integers >= 1, got {text!r}")
    return values


# -- bench --------------------------------------------------------------------------------------
BENCH_SUITES = ("wires", "robots", "envs")


def _bench_args(p):
    p.add_argument("--suite", default="wires", help=f"one of: {', '.join(BENCH_SUITES)}")
    p.add_argument("--seconds", type=float, default=5.0, help="simulated seconds timed per row")
    p.add_argument("--wire", nargs="*", default=None, help="wire models (default: all)")
    p.add_argument("--task", nargs="*", default=None, help="envs suite: tasks (default: insertion)")
    p.add_argument(
        "--num-envs",
        default=None,
        help="envs suite: comma-separated counts (default: 1,4,16,64,256)",
    )
    p.add_argument("--threads", default="1,2", help="envs suite: comma-separated thread counts")
    p.add_argument("--warmup", type=float, default=1.0, help="envs suite: warm-up seconds")
    p.add_argument(
        "--full-info",
        action="store_true",
        help="envs suite: with per-environment diagnostics and synced environments "
        "(as evaluation runs); default: as training runs",
    )
    p.add_argument("--out", default="out/bench", help="envs suite: folder for CSV and PNG")
    p.add_argument("--json", metavar="PATH", help="write the rows as JSON")


@command("bench", "print throughput figures (physics steps/s, real-time factor)", _bench_args)
def cmd_bench(args) -> int:
    if args.suite not in BENCH_SUITES:
        raise ValueError(f"unknown suite {args.suite!r}; valid: {', '.join(BENCH_SUITES)}")
    if not args.seconds > 0:
        raise ValueError(f"--seconds must be > 0, got {args.seconds}")
    from wirecraft.benchmarks import robots, wires

    if args.suite == "wires":
        rows = wires.run(args.seconds, args.wire)
        wires.print_table(rows)
    elif args.suite == "robots":
        rows = robots.run(args.seconds)
        robots.print_table(rows)
    else:
        from wirecraft import TASK_IDS
        from wirecraft.assets.wires import WIRE_MODELS
        from wirecraft.benchmarks import envs

        tasks = args.task or ["insertion"]
        for task in tasks:
            if task not in TASK_IDS:
                raise ValueError(f"unknown task {task!r}; valid: {', '.join(TASK_IDS)}")
        wire_models = args.wire or ["articulated"]
        for wire in wire_models:
            WIRE_MODELS.get(wire)
        counts = _int_list("--num-envs", args.num_envs or "1,4,16,64,256")
        threads = _int_list("--threads", args.threads)
        info = "full" if args.full_info else "training"
        rows = envs.run(tasks, wire_models, counts, threads, args.seconds, args.warmup, info)
        envs.print_table(rows)
        envs.write_csv(rows, Path(args.out) / "bench_envs.csv")
        envs.plot(rows, Path(args.out) / "bench_envs.png")
        print(f"wrote {args.out}/bench_envs.csv and {args.out}/bench_envs.png")
    write_json(args.json, rows)
    return 0


# -- demo ---------------------------------------------------------------------------------------
def _demo_args(p):
    p.add_argument("--out", default="out/demo", help="folder for the images and summary")
    p.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per wire drop")
    p.add_argument("--json", metavar="PATH", help="summary as JSON (default: OUT/summary.json)")


@command(
    "demo",
    "run the main job on the CPU: every task's scripted expert (videos) and every wire model",
    _demo_args,
)
def cmd_demo(args) -> int:
    from wirecraft.demo import run_demo, run_task_demo, summary_markdown

    if not args.seconds > 0:
        raise ValueError(f"--seconds must be > 0, got {args.seconds}")
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
    (Path(args.out) / "summary.md").write_text(summary_markdown(tasks, rows))
    videos = ", ".join(r["video"] for r in tasks)
    print(f"wrote {args.out}: {videos}, tasks.png, wires.png, summary.md, summary.json")
    return 1 if any(r["diverged"] for r in rows + tasks) else 0


# -- collect ------------------------------------------------------------------------------------
def _collect_args(p):
    add_task_args(p)
    p.add_argument("--episodes", type=int, default=10, help="episodes the dataset should hold")
    p.add_argument("--out", required=True, help="dataset folder (LeRobot v3)")
    p.add_argument("--workers", type=int, default=2, help="worker processes (0: this process)")
    p.add_argument("--ray", metavar="ADDRESS", help="generate with Ray ('local': start one here)")
    p.add_argument("--keep-failures", action="store_true", help="also save failed episodes")
    p.add_argument("--resume", action="store_true", help="continue the dataset in --out")
    p.add_argument("--fps", type=int, default=30, help="frames per second (a divisor of 60)")
    p.add_argument("--seed", type=int, default=0, help="episode k is reset with seed (SEED, k)")
    p.add_argument(
        "--success-hold", type=float, default=0.5, help="end once success held this long (s)"
    )
    p.add_argument("--vcodec", default="h264", help="video codec: h264 or libsvtav1 (AV1)")
    p.add_argument("--commit-every", type=int, default=10, help="episodes per durable commit")
    p.add_argument("--max-attempts", type=int, default=None, help="default: 2 * episodes + 10")
    p.add_argument("--json", metavar="PATH", help="write the report as JSON")


@command("collect", "write scripted demonstrations as a LeRobot v3 dataset", _collect_args)
def cmd_collect(args) -> int:
    from wirecraft.datasets.collect import (
        DEFAULT_IMAGE_SIZE,
        CollectSettings,
        collect,
        summary_lines,
    )

    family, kwargs = task_kwargs(args)
    image_size = kwargs.pop("image_size", DEFAULT_IMAGE_SIZE)
    settings = CollectSettings(
        task=family,
        env_kwargs=kwargs,
        image_size=image_size,
        fps=args.fps,
        seed=args.seed,
        keep_failures=args.keep_failures,
        success_hold_s=args.success_hold,
        vcodec=args.vcodec,
    )
    report = collect(
        settings,
        args.out,
        args.episodes,
        workers=args.workers,
        ray_address=args.ray,
        resume=args.resume,
        commit_every=args.commit_every,
        max_attempts=args.max_attempts,
    )
    for line in summary_lines(report):
        print(line)
    write_json(args.json, report.to_dict())
    if report.interrupted:
        return 128 + int(getattr(__import__("signal"), report.interrupted))
    return 1 if report.gave_up else 0


# -- train --------------------------------------------------------------------------------------
def _train_args(p):
    p.add_argument("algorithm", choices=("ppo", "sacfd", "vision-ppo"), help="RL baseline")
    add_task_args(p)
    p.add_argument("--out", required=True, help="run directory (checkpoints, logs, settings)")
    p.add_argument("--num-envs", type=int, default=None, help="parallel environments")
    p.add_argument("--steps", default=None, help="total env steps, e.g. 2e6 (default: config's)")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--threads", type=int, default=None, help="physics threads (0: all CPUs)")
    p.add_argument("--episode-seconds", type=float, default=None, help="episode length, s")
    p.add_argument("--resume", action="store_true", help="continue the run in --out")
    p.add_argument(
        "--set", action="append", default=[], metavar="NAME=VALUE", help="any config setting"
    )
    p.add_argument("--json", metavar="PATH", help="write the run summary as JSON")


@command("train", "train an RL baseline (PPO, SACfD, vision PPO); resumable", _train_args)
def cmd_train(args) -> int:
    from wirecraft.rl.train import parse_cli_settings, train

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
    args = build_parser().parse_args(argv)
    try:
        return COMMANDS[args.command][2](args)
    except (ValueError, RuntimeError) as err:
        print(f"wirecraft {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"wirecraft {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
