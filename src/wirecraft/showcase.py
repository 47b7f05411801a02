"""Showcase scenes for ``wirecraft view``: every asset family laid out on the table.

Each builder returns (spec, viewpoint).  Add a scene with ``@SCENES.register("name")``.
"""

from __future__ import annotations

import numpy as np

from wirecraft.assets.connectors import CONNECTORS, add_plug, add_port, make_connector
from wirecraft.assets.fixtures import ChannelConfig, ClipConfig, add_board, add_channel, add_clip
from wirecraft.assets.wires import WIRE_MODELS, WireConfig, add_wire
from wirecraft.registry import Registry
from wirecraft.render import ViewPoint
from wirecraft.scene import add_table, new_spec

SCENES: Registry = Registry("scene")


@SCENES.register("wires")
def wires_scene():
    """The three wire models side by side, each with an Ethernet plug on its far end."""
    spec = new_spec("wires")
    add_table(spec)
    connector = make_connector("ethernet")
    for i, model in enumerate(WIRE_MODELS):
        y = 0.1 * (i - 1)
        wire = add_wire(spec, WireConfig(model=model), name=f"wire_{model}", pos=(-0.2, y, 0.06))
        pos, quat = wire.end_pose("end")
        add_plug(spec, connector, name=f"plug_{model}", pos=tuple(pos), quat=tuple(quat))
        wire.attach(spec, "end", f"plug_{model}")
    return spec, ViewPoint(lookat=(0.0, 0.0, 0.0), distance=0.75, azimuth=120, elevation=-35)


@SCENES.register("connectors")
def connectors_scene():
    """Every connector family: plug in front of its port, at the default 3 mm clearance."""
    spec = new_spec("connectors")
    add_table(spec)
    for i, name in enumerate(CONNECTORS):
        connector = make_connector(name)
        y = 0.05 * (i - (len(CONNECTORS) - 1) / 2)
        add_port(spec, connector, name=f"{name}_port", pos=(0.02, y, 0.02))
        add_plug(
            spec,
            connector,
            name=f"{name}_plug",
            free=False,
            pos=(-0.01 - connector.plug_length, y, 0.02),
        )
    return spec, ViewPoint(lookat=(0.0, 0.0, 0.02), distance=0.32, azimuth=-30, elevation=-25)


@SCENES.register("fixtures")
def fixtures_scene():
    """Board with clips (with and without lip) and a straight and a curved channel."""
    spec = new_spec("fixtures")
    add_table(spec)
    board = 0.01
    add_board(spec)
    for i, opening in enumerate((0.007, 0.007, 0.012)):
        add_clip(
            spec,
            ClipConfig(opening=opening),
            name=f"clip_{i}",
            pos=(-0.1 + 0.1 * i, 0.1, board),
            yaw=float(np.radians(10 * (i - 1))),
        )
    add_channel(spec, name="channel_straight", pos=(-0.2, 0.0, board))
    add_channel(spec, ChannelConfig.curved(), name="channel_curved", pos=(-0.2, -0.1, board))
    return spec, ViewPoint(lookat=(0.0, 0.0, 0.0), distance=0.8, azimuth=150, elevation=-45)
