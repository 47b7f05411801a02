"""Argument checks shared by the ``wirecraft`` sub-commands (argparse ``type=`` validators,
output paths checked before any work starts) and atomic writing of their results."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import shutil
from pathlib import Path

RAY_CONNECT_TIMEOUT_S = 5.0


def number(
    low: float | None = None,
    high: float | None = None,
    *,
    integer: bool = False,
    low_open: bool = False,
):
    """An argparse ``type=``: a finite number (an integer with ``integer``) in
    [``low``, ``high``] (``(low, high]`` with ``low_open``)."""
    kind = "an integer" if integer else "a finite number"
    lo = "" if low is None else f"{'>' if low_open else '>='} {low:g}"
    hi = "" if high is None else f"<= {high:g}"
    allowed = (
        kind + (f" {lo}" if lo else "") + (" and" if lo and hi else "") + (f" {hi}" if hi else "")
    )

    def parse(text: str):
        try:
            value = int(text) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}")
        if low is not None and (value < low or (low_open and value == low)):
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}")
        if high is not None and value > high:
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}")
        return value

    parse.__name__ = "integer" if integer else "number"
    return parse


def int_list(low: int, high: int):
    """An argparse ``type=``: comma-separated integers in [``low``, ``high``]."""
    item = number(low, high, integer=True)

    def parse(text: str) -> list[int]:
        parts = [p.strip() for p in text.split(",")]
        if not all(parts):
            raise argparse.ArgumentTypeError(
                f"must be comma-separated integers in [{low}, {high}], got {text!r}"
            )
        try:
            return [item(p) for p in parts]
        except argparse.ArgumentTypeError:
            raise argparse.ArgumentTypeError(
                f"must be comma-separated integers in [{low}, {high}], got {text!r}"
            ) from None

    parse.__name__ = "list"
    return parse


def ray_address(text: str) -> str:
    """An argparse ``type=``: ``local``, ``auto`` or a Ray cluster's HOST:PORT that answers
    (checked now: ``ray.init`` would retry an unreachable address for minutes)."""
    import socket

    if text in ("local", "auto"):
        return text
    host, _, port = text.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, auto or local, got {text!r}")
    try:
        socket.create_connection(
            (host.strip("[]"), int(port)), timeout=RAY_CONNECT_TIMEOUT_S
        ).close()
    except OSError as err:
        raise argparse.ArgumentTypeError(f"cannot reach a Ray cluster at {text}: {err}") from None
    return text


def _writable_parent(path: Path) -> str | None:
    """Why files cannot be created at ``path`` (None if they can): its nearest existing
    ancestor must be a writable folder."""
    parent = path.parent if str(path.parent) else Path(".")
    while not parent.exists():
        if parent.is_symlink():
            return f"{parent} is a broken link"
        parent = parent.parent
    if not parent.is_dir():
        return f"{parent} is a file, not a folder"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"{parent} is not writable"
    return None


def output_file(text: str) -> str:
    """An argparse ``type=``: a file that can be written (not a folder, not under a file)."""
    if not text:
        raise argparse.ArgumentTypeError("must be a file path, got ''")
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a folder; expected a file path")
    if path.exists() and not os.access(path, os.W_OK):
        raise argparse.ArgumentTypeError(f"{text} is not writable")
    why = _writable_parent(path)
    if why:
        raise argparse.ArgumentTypeError(f"cannot write {text}: {why}")
    return text


def output_dir(text: str) -> str:
    """An argparse ``type=``: a folder that exists and is writable, or can be created."""
    if not text:
        raise argparse.ArgumentTypeError("must be a folder path, got ''")
    path = Path(text)
    if path.exists():
        if not path.is_dir():
            raise argparse.ArgumentTypeError(f"{text} is a file; expected a folder")
        if not os.access(path, os.W_OK | os.X_OK):
            raise argparse.ArgumentTypeError(f"{text} is not writable")
        return text
    why = _writable_parent(path / "x")
    if why:
        raise argparse.ArgumentTypeError(f"cannot create {text}: {why}")
    return text


def suffixed(*suffixes: str):
    """``output_file`` that must end in one of ``suffixes``."""

    def parse(text: str) -> str:
        if Path(text).suffix.lower() not in suffixes:
            raise argparse.ArgumentTypeError(f"must end in {' or '.join(suffixes)}, got {text!r}")
        return output_file(text)

    parse.__name__ = "path"
    return parse


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """A temporary path beside ``path`` (same suffix) for a writer; it replaces ``path`` when
    the block succeeds and is removed when it fails, so ``path`` is never half-written."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_block(path: str | os.PathLike, markers: tuple[str, str], text: str) -> None:
    """Replace what lies between the two ``markers`` in the file ``path`` (a table a script
    generates inside README.md) with ``text``, atomically; a ValueError if they are missing."""
    path = Path(path)
    body = path.read_text()
    start, end = (body.find(m) for m in markers)
    if start < 0 or end < start:
        raise ValueError(f"{path}: no {markers[0]} ... {markers[1]} block to replace")
    body = body[: start + len(markers[0])] + "\n" + text + "\n" + body[end:]
    with atomic_path(path) as tmp:
        tmp.write_text(body)


def write_json(path: str | os.PathLike | None, payload) -> None:
    """Write results atomically (a crash never leaves half a file)."""
    if not path:
        return
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(payload, indent=2, sort_keys=True) + "\n")


def write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


@contextlib.contextmanager
def folder_built_beside(out: str | os.PathLike, job: str, *, replace_empty: bool = False):
    """A fresh temporary folder beside ``out`` to build it in: renamed to ``out`` when the block
    succeeds, removed when it fails, so ``out`` is never half-written.  ``out`` must still be
    absent at the end (with ``replace_empty``: absent or an empty folder); otherwise a
    ValueError naming ``--out`` says it appeared while ``job`` ran."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{job}-{os.getpid()}.tmp")
    if tmp.exists():
        shutil.rmtree(tmp)
    try:
        yield tmp
        taken = out.exists() or out.is_symlink()
        if taken and replace_empty and out.is_dir() and not any(out.iterdir()):
            taken = False
        if taken:
            raise ValueError(f"--out: {out} appeared while {job} ran; name a new folder")
        os.rename(tmp, out)  # replaces an empty folder
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def new_folder(path: str | os.PathLike):
    """Remove ``path`` again if this block created it and then failed (a failed start leaves
    nothing that blocks the rerun)."""
    path = Path(path)
    created = not path.exists()
    try:
        yield path
    except BaseException:
        if created and path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        raise


def add_backend_args(parser, device_flag: str = "--warp-device", where: str = "") -> None:
    """``--backend cpu|warp`` and the Warp device flag, for commands that step environments;
    ``where`` prefixes the help (``"RL: "``)."""
    from wirecraft import BACKENDS

    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default=None,
        help=f"{where}where the physics steps: cpu (default) or warp (MuJoCo Warp, make gpu)",
    )
    parser.add_argument(
        device_flag,
        metavar="DEV",
        default=None,
        help=f"{where}with --backend warp: the Warp device, e.g. cuda:0 (default: Warp's)",
    )
