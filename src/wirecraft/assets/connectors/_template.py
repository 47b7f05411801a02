"""Template for a new connector family: copy to NAME.py, fill in, import it in __init__.py.

Only the cross-section of the insertable shell is needed: the port (socket walls offset by the
clearance, back stop, sites), STL export and the registry-parametrised tests follow from it.
Override ``shell_shapes`` for non-rectangular shells and ``port_extra_shapes`` for key
features inside the socket.
"""

from __future__ import annotations

from wirecraft.assets.connectors.base import TAIL_HALF_LENGTH, Connector

# @CONNECTORS.register("my_connector")   # uncomment in your copy


class TemplateConnector(Connector):
    symmetry = 2
    description = "what it looks like, main dimensions"
    shell_length = 0.015  # m, insertable length
    tail_half = (TAIL_HALF_LENGTH, 0.007, 0.005)  # m, half extents of the part the gripper holds
    width, height = 0.010, 0.005
    # What holds it seated ("latch", "friction" or "none") and the axial pull (N) it resists:
    # a weld engaged on seating, released above that force (base.py, add_retention).
    retention_mechanism = "none"
    retention_force = 0.0

    def shell_rects(self):
        return [(-self.width / 2, self.width / 2, -self.height / 2, self.height / 2)]
