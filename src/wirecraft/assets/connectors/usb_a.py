"""USB-A-like shell, 12 x 4.5 mm: two-fold symmetric outside.

The real connector's asymmetric inner tongue is not modelled as a collision body: at the
benchmark's clearances a thin tongue would not survive the rattle slack (see base.py, Keying).
"""

from __future__ import annotations

from wirecraft.assets.connectors.base import CONNECTORS, TAIL_HALF_LENGTH, Connector


@CONNECTORS.register("usb_a")
class UsbAConnector(Connector):
    name = "usb_a"
    symmetry = 2
    description = "USB-A-like shell, 12 x 4.5 mm"
    retention_mechanism = "friction"
    retention_force = 10.0  # N, see docs/assets.md (Retention)
    shell_length = 0.014
    tail_half = (TAIL_HALF_LENGTH, 0.0080, 0.0040)
    width, height = 0.012, 0.0045

    def shell_rects(self):
        return [(-self.width / 2, self.width / 2, -self.height / 2, self.height / 2)]
