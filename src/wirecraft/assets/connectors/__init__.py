"""Connector families.  Add one: copy _template.py, register it, import it here."""

from wirecraft.assets.connectors import cuboid, cylinder, displayport, ethernet, usb_a  # noqa: F401
from wirecraft.assets.connectors.base import (
    CONNECTORS,
    FLIP_ABOUT_AXIS,
    Connector,
    add_plug,
    add_port,
    add_retention,
    make_connector,
)

__all__ = [
    "CONNECTORS",
    "FLIP_ABOUT_AXIS",
    "Connector",
    "add_plug",
    "add_port",
    "add_retention",
    "make_connector",
]
