"""``python -m wirecraft.teleop ...``: the same as ``wirecraft teleop ...``."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    from wirecraft.cli import main as wirecraft_main

    return wirecraft_main(["teleop", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
