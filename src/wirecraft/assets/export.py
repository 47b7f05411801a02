"""STL export of every printable part, as watertight solids in millimetres.

Parts are the same primitive lists the simulation uses (see shapes.py); each is unioned into
one solid by the manifold boolean engine and written by trimesh.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import trimesh

from wirecraft.assets.connectors import CONNECTORS, make_connector
from wirecraft.assets.fixtures import BoardConfig, ChannelConfig, ClipConfig, PortStandConfig
from wirecraft.assets.shapes import Shape, to_mesh

MM_PER_M = 1000.0

# name -> builder(clearance) -> shapes in the part's frame (metres)
PartBuilder = Callable[[float], list[Shape]]


def _parts() -> dict[str, PartBuilder]:
    parts: dict[str, PartBuilder] = {}
    for name in CONNECTORS:
        parts[f"{name}_plug"] = lambda c, n=name: make_connector(n, c).plug_shapes()
        parts[f"{name}_port"] = lambda c, n=name: make_connector(n, c).port_shapes()
    parts["clip"] = lambda c: ClipConfig().shapes()
    parts["clip_open"] = lambda c: ClipConfig(opening=ClipConfig().slot_width).shapes()
    parts["channel_straight"] = lambda c: ChannelConfig().shapes()
    parts["channel_curved"] = lambda c: ChannelConfig.curved().shapes()
    parts["board"] = lambda c: BoardConfig().shapes()
    parts["port_stand"] = lambda c: PortStandConfig().shapes()
    return parts


PARTS = _parts()


def part_names() -> list[str]:
    return list(PARTS)


def part_mesh(part: str, clearance: float = 0.003) -> trimesh.Trimesh:
    """The watertight solid of ``part`` in millimetres."""
    if part not in PARTS:
        raise ValueError(f"unknown part {part!r}; valid: {', '.join(PARTS)}")
    return to_mesh(PARTS[part](clearance), scale=MM_PER_M)


def export_stl(part: str, out: str | os.PathLike, clearance: float = 0.003) -> Path:
    """Write ``part`` as a binary STL in millimetres; the file appears whole or not at all."""
    mesh = part_mesh(part, clearance)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=".stl", dir=out.parent)
    try:
        with os.fdopen(fd, "wb") as handle:
            mesh.export(handle, file_type="stl")
        os.replace(tmp, out)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return out
