"""Round peg: rotation-invariant about its axis, the easiest insertion."""

from __future__ import annotations

import math

import numpy as np

from wirecraft.assets.connectors.base import CONNECTORS, TAIL_HALF_LENGTH, WALL, Connector
from wirecraft.assets.shapes import Box, Cylinder, Shape, quat_about

ALONG_X = quat_about((0.0, 1.0, 0.0), np.pi / 2)  # turns a cylinder's z axis onto x
RING_SIDES = 24  # the socket bore is a 24-sided polygon whose inscribed circle is the bore


@CONNECTORS.register("cylinder")
class CylinderConnector(Connector):
    name = "cylinder"
    symmetry = 0  # continuous
    description = "round peg, 10 mm diameter"
    shell_length = 0.020
    tail_half = (TAIL_HALF_LENGTH, 0.0065, 0.0065)
    radius = 0.005

    def shell_rects(self):
        return [(-self.radius, self.radius, -self.radius, self.radius)]

    def shell_shapes(self, x0: float, x1: float) -> list[Shape]:
        half = (x1 - x0) / 2
        return [Cylinder(self.radius, half, (x0 + half, 0.0, 0.0), ALONG_X)]

    def plug_tail_shapes(self) -> list[Shape]:
        hx, r, _ = self.tail_half
        return [Cylinder(r, hx, (hx, 0.0, 0.0), ALONG_X)]

    def port_shapes(self) -> list[Shape]:
        bore = self.radius + self.clearance  # inscribed radius of the polygonal bore
        depth = self.cavity_depth
        half_width = (bore + WALL) * math.tan(np.pi / RING_SIDES) + 1e-4  # faces overlap slightly
        shapes: list[Shape] = []
        for k in range(RING_SIDES):
            theta = 2 * np.pi * k / RING_SIDES
            centre = bore + WALL / 2
            shapes.append(
                Box(
                    (depth / 2, half_width, WALL / 2),
                    (depth / 2, centre * np.cos(theta), centre * np.sin(theta)),
                    quat_about((1.0, 0.0, 0.0), theta - np.pi / 2),
                )
            )
        outer = (bore + WALL) / np.cos(np.pi / RING_SIDES)
        shapes.append(Cylinder(outer, WALL / 2, (depth + WALL / 2, 0.0, 0.0), ALONG_X))
        return shapes
