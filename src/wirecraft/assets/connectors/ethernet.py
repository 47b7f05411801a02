"""RJ45-like plug: an 11.7 mm wide body with a latch tab on its top face (one-fold).

The socket has a slot for the latch.  Upside down, the latch meets the socket floor: it blocks
only if it stands out further than the 2c the plug can rattle in the socket, so the latch
height is max(2 mm, 2c + KEY_MARGIN).
"""

from __future__ import annotations

from wirecraft.assets.connectors.base import CONNECTORS, KEY_MARGIN, TAIL_HALF_LENGTH, Connector


@CONNECTORS.register("ethernet")
class EthernetConnector(Connector):
    name = "ethernet"
    symmetry = 1
    description = "RJ45-like, 11.7 x 6 mm body with a latch tab on top (about 8 mm high)"
    retention_mechanism = "latch"
    retention_force = 50.0  # N, see docs/assets.md (Retention)
    shell_length = 0.018
    tail_half = (TAIL_HALF_LENGTH, 0.0070, 0.0055)
    width, height = 0.0117, 0.006
    latch_width, latch_nominal_height = 0.004, 0.002

    @property
    def latch_height(self) -> float:
        return max(self.latch_nominal_height, 2 * self.clearance + KEY_MARGIN)

    def shell_rects(self):
        w, h, lw = self.width / 2, self.height / 2, self.latch_width / 2
        return [(-w, w, -h, h), (-lw, lw, h, h + self.latch_height)]
