"""Rectangular peg: two-fold symmetric, so roll must be right to within 180 degrees."""

from __future__ import annotations

from wirecraft.assets.connectors.base import CONNECTORS, TAIL_HALF_LENGTH, Connector


@CONNECTORS.register("cuboid")
class CuboidConnector(Connector):
    name = "cuboid"
    symmetry = 2
    description = "rectangular peg, 12 x 8 mm"
    shell_length = 0.020
    tail_half = (TAIL_HALF_LENGTH, 0.0075, 0.0055)
    width, height = 0.012, 0.008

    def shell_rects(self):
        return [(-self.width / 2, self.width / 2, -self.height / 2, self.height / 2)]
