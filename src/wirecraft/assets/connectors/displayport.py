"""DisplayPort-like shell, 16 x 4.8 mm with one chamfered corner (one-fold).

The socket carries a wedge that fills the chamfer.  A 45-degree chamfer of leg k blocks the
upside-down plug only while k > (2 + sqrt 2) c (the plug rattles 2c in a socket of clearance
c); beyond that a key rail of height 2c + KEY_MARGIN on the top face, with its slot in the
socket, keeps the wrong orientation out.
"""

from __future__ import annotations

import math

from wirecraft.assets.connectors.base import (
    CONNECTORS,
    KEY_MARGIN,
    TAIL_HALF_LENGTH,
    WALL,
    Connector,
)
from wirecraft.assets.shapes import Box, Prism, Shape


@CONNECTORS.register("displayport")
class DisplayPortConnector(Connector):
    name = "displayport"
    symmetry = 1
    description = "DisplayPort-like shell, 16 x 4.8 mm, chamfered corner (most alignment-sensitive)"
    retention_mechanism = "latch"
    retention_force = 30.0  # N, see docs/assets.md (Retention)
    shell_length = 0.015
    tail_half = (TAIL_HALF_LENGTH, 0.0095, 0.0040)
    width, height, chamfer = 0.016, 0.0048, 0.0025
    rail_width = 0.003

    @property
    def rail_height(self) -> float:
        """0 while the chamfer alone keys the plug, else the rail that does."""
        if self.chamfer > (2 + math.sqrt(2)) * self.clearance + KEY_MARGIN / 2:
            return 0.0
        return 2 * self.clearance + KEY_MARGIN

    def _rail_rect(self):
        r = self.rail_width / 2
        return (-r, r, self.height / 2, self.height / 2 + self.rail_height)

    def shell_rects(self):
        w, h = self.width / 2, self.height / 2
        rects = [(-w, w, -h, h)]
        return rects + ([self._rail_rect()] if self.rail_height else [])

    def shell_shapes(self, x0: float, x1: float) -> list[Shape]:
        w, h, k = self.width / 2, self.height / 2, self.chamfer
        shell = Prism(((-w, -h), (w, -h), (w, h - k), (w - k, h), (-w, h)), x0, x1)
        if not self.rail_height:
            return [shell]
        y0, y1, z0, z1 = self._rail_rect()
        rail = Box(
            ((x1 - x0) / 2, (y1 - y0) / 2, (z1 - z0) / 2),
            ((x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2),
        )
        return [shell, rail]

    def port_extra_shapes(self) -> list[Shape]:
        """The wedge filling the cavity corner beyond the chamfer, offset by the clearance."""
        c, w, h = self.clearance, self.width / 2, self.height / 2
        line = w + h - self.chamfer + c * math.sqrt(2)  # y + z on the socket's chamfer face
        y_max, z_max = w + c + WALL / 2, h + c + WALL / 2  # reach into the walls
        wedge = ((y_max, line - y_max), (y_max, z_max), (line - z_max, z_max))
        return [Prism(wedge, 0.0, self.cavity_depth)]
