"""``wirecraft teleop`` (also ``python -m wirecraft.teleop``): the command's flags and what it
does with them."""

from __future__ import annotations

import argparse

DEFAULT_FPS = 30
DEFAULT_SEED = 0


def configure(p: argparse.ArgumentParser, add_task_args) -> None:
    from wirecraft.cli import MAX_SECONDS, MAX_SEED
    from wirecraft.cli_args import number, output_dir, output_file
    from wirecraft.datasets.writer import VIDEO_CODECS
    from wirecraft.teleop.devices import DEVICES
    from wirecraft.teleop.session import DEFAULT_EPISODE_SECONDS

    add_task_args(p)
    p.set_defaults(task=None)  # None: the first family (replay: the stream's)
    p.add_argument(
        "--device",
        choices=DEVICES,
        default="keyboard",
        help="keyboard (keys in the viewer), spacemouse (pyspacemouse), gamepad (pygame) or "
        "replay (a --save-commands stream; no display needed)",
    )
    p.add_argument(
        "--commands", metavar="FILE", default=None, help="--device replay: the command stream"
    )
    p.add_argument(
        "--save-commands",
        metavar="FILE",
        type=output_file,
        default=None,
        help="write the command stream this session acts on (JSON lines; --device replay "
        "plays it back)",
    )
    p.add_argument(
        "--record",
        metavar="DIR",
        type=output_dir,
        required=True,
        help="the dataset to write (new or empty; with --resume a teleop dataset to add to)",
    )
    p.add_argument("--resume", action="store_true", help="add episodes to the --record dataset")
    p.add_argument(
        "--episodes",
        type=number(1, 100_000, integer=True),
        default=None,
        help="end the session once it saved this many episodes (default: when you quit)",
    )
    p.add_argument(
        "--fps",
        type=number(1, 60, integer=True),
        default=None,
        help=f"dataset frames per second, a divisor of 60 (default {DEFAULT_FPS}; replay: the "
        "stream's)",
    )
    p.add_argument(
        "--seed",
        type=number(0, MAX_SEED, integer=True),
        default=None,
        help=f"scene k resets with a seed derived from this one and k (default {DEFAULT_SEED}; "
        "replay: the stream's)",
    )
    p.add_argument(
        "--episode-seconds",
        type=number(0, MAX_SECONDS, low_open=True),
        default=None,
        help=f"time limit of an episode in simulated seconds (default {DEFAULT_EPISODE_SECONDS:g}; "
        "replay: the stream's)",
    )
    p.add_argument(
        "--show",
        action="store_true",
        help="--device replay: show the replay in the viewer, in real time (needs a display)",
    )
    p.add_argument(
        "--vcodec", choices=tuple(VIDEO_CODECS), default="h264", help="video codec (h264)"
    )
    p.add_argument("--json", metavar="PATH", type=output_file, help="write the session's report")


def run(args) -> int:
    import signal

    import wirecraft
    from wirecraft.cli import only_with, task_kwargs, usage_error
    from wirecraft.cli_args import write_json
    from wirecraft.datasets.collect import DEFAULT_IMAGE_SIZE
    from wirecraft.envs.env import steps_per_frame
    from wirecraft.teleop.devices import (
        CombinedDevice,
        KeyboardDevice,
        ReplayDevice,
        make_device,
        read_stream,
    )
    from wirecraft.teleop.session import DEFAULT_EPISODE_SECONDS, TeleopSession

    header: dict = {}
    if args.device == "replay":
        if args.commands is None:
            raise usage_error("--commands", "--device replay plays a command stream: pass FILE")
        header, commands = read_stream(args.commands)
    else:
        only_with(args, "--device replay", "--commands", "--show")
    if args.task is None:
        args.task = header.get("task") or _default_family()
    family, given = task_kwargs(args)
    image_size = given.pop("image_size", header.get("image_size", DEFAULT_IMAGE_SIZE))
    if given.get("control", "cartesian") != "cartesian":
        raise usage_error(
            "--control", "teleoperation drives control=cartesian (6-DoF TCP deltas, gripper)"
        )
    env_kwargs = dict(header.get("env_kwargs") or {}) if family == header.get("task") else {}
    env_kwargs.update(given)
    env_kwargs["control"] = "cartesian"
    fps = args.fps if args.fps is not None else header.get("fps", DEFAULT_FPS)
    try:
        steps_per_frame(fps)
    except ValueError as err:
        raise usage_error("--fps", str(err)) from None
    seed = args.seed if args.seed is not None else header.get("seed", DEFAULT_SEED)
    seconds = args.episode_seconds
    if seconds is None:
        seconds = header.get("episode_seconds", DEFAULT_EPISODE_SECONDS)
    speeds = {}
    if header:
        speeds = {"speeds": tuple(header.get("speeds", ())), "speed": header.get("speed")}
        speeds = {k: v for k, v in speeds.items() if v not in ((), None)}
    show = args.device != "replay" or args.show
    if show:
        from wirecraft.envs.env import check_display

        try:
            check_display()  # before anything is built or written
        except RuntimeError as err:
            raise RuntimeError(
                f"--device {args.device} shows the robot in MuJoCo's viewer: {err} (only "
                "--device replay runs without a display)"
            ) from None
    env = wirecraft.make(
        family, obs_mode="state", image_size=image_size, episode_seconds=seconds, **env_kwargs
    )
    device = None
    try:
        if args.device == "replay":
            device = ReplayDevice(header=header, commands=commands)
        else:
            device = make_device(args.device)
            if not isinstance(device, KeyboardDevice):
                # The viewer's keys give the events (save, discard, ...) and move as well.
                device = CombinedDevice(device, KeyboardDevice())
        session = TeleopSession(
            env,
            device,
            args.record,
            fps,
            seed=seed,
            episodes=args.episodes,
            viewer=show,
            save_commands=args.save_commands,
            resume=args.resume,
            vcodec=args.vcodec,
            **speeds,
        )
        device = None  # the session closes it
        report = session.run()
    finally:
        if device is not None:
            device.close()
        env.close()
    for line in report.lines():
        print(line)
    if args.save_commands:
        print(f"wrote {report.commands} commands to {args.save_commands}")
    write_json(args.json, report.to_dict())
    if report.ended in ("SIGINT", "SIGTERM"):
        return 128 + int(getattr(signal, report.ended))
    return 0


def _default_family() -> str:
    from wirecraft.tasks import default_family

    return default_family()
