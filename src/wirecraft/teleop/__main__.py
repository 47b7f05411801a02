"""``python -m wirecraft.teleop ...``: the teleoperation command (``command.configure`` /
``command.run``) on its own, with the ``wirecraft`` program's error handling."""

from __future__ import annotations

import argparse
import sys


def build_parser() -> argparse.ArgumentParser:
    from wirecraft.cli import add_task_args
    from wirecraft.teleop.command import DESCRIPTION, configure

    parser = argparse.ArgumentParser(prog="python -m wirecraft.teleop", description=DESCRIPTION)
    configure(parser, add_task_args)
    return parser


def main(argv: list[str] | None = None) -> int:
    from wirecraft.teleop.command import run

    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exit_:
        return exit_.code if isinstance(exit_.code, int) else 2
    try:
        return run(args)
    except (ValueError, RuntimeError, OSError) as err:
        print(f"wirecraft teleop: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("wirecraft teleop: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
