"""Connector families: a plug (held part, on the wire) and its port (fixed part, on the board).

Frames (metres):
- Plug frame: origin at the wire attachment point at the back of the tail; +x points along
  the insertion direction.  The tail (grasped by the gripper) spans x in [0, tail_length],
  the insertable shell x in [tail_length, tail_length + shell_length].  Sites:
  ``{name}_wire`` (origin), ``{name}_grasp`` (middle of the tail), ``{name}_tip`` (shell front).
- Port frame: origin at the centre of the socket mouth; the cavity runs along +x to the back
  stop at ``cavity_depth``.  Sites: ``{name}_entry`` (origin), ``{name}_seated`` (where the
  plug tip is when fully seated).  A plug is aligned with its port when the frames coincide
  up to a shift along x.

Cross-sections live in the (y, z) plane; +z is the "top" face (the Ethernet latch side).
``clearance`` is the gap per side between plug and socket: the socket cavity is the plug's
cross-section offset outwards by the clearance (Minkowski offset by a square).

Keying.  In a socket with clearance c the plug can rattle 2c across; a key feature can only
block a wrong orientation if it stands out further than that slack.  Keyed families therefore
size their key as ``max(nominal, 2 c + KEY_MARGIN)`` (see ethernet.py, displayport.py).

Retention.  Each family says what holds a seated plug (``retention_mechanism``: ``latch``,
``friction`` or ``none``) and the axial pull that overcomes it (``retention_force``, N).  The
rigid plug has no springy latch tab nor contact springs, so ``add_retention`` models the hold
as weld equalities between the plug's tip frame and the socket's seated frame (one per
orientation the plug seats in), inactive until a task engages one (``wirecraft.tasks.insertion``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import mujoco
import numpy as np

from wirecraft import physics, validation
from wirecraft.assets.shapes import Box, Prism, Quat, Shape, Vec3, add_to_body, quat_about
from wirecraft.numerics import dot
from wirecraft.registry import Registry

CONNECTORS: Registry[type[Connector]] = Registry("connector")

KEY_MARGIN = 0.001  # m by which a key exceeds the socket's rattle slack 2c
# The gripped tail is 26 mm long: a 2F-85's 22 mm pads centred on it clear the shell, which
# stands 2 mm out of a seated socket, with 2 mm to spare (a 16 mm tail put the pads in the port).
TAIL_HALF_LENGTH = 0.013
WALL = 0.004  # m, socket wall and back-stop thickness
PLUG_RGBA = (0.15, 0.15, 0.18, 1.0)
SHELL_RGBA = (0.75, 0.75, 0.78, 1.0)
PORT_RGBA = (0.2, 0.35, 0.7, 1.0)
MAX_CLEARANCE = 0.01  # m; a wider gap is no longer a socket

Rect = tuple[float, float, float, float]  # (y_min, y_max, z_min, z_max)


@dataclass(frozen=True)
class Connector:
    """One connector family at one clearance.  Subclasses set the class constants and shapes."""

    clearance: float = 0.003
    allow_interference: bool = False  # physics checks only: a negative clearance is a press fit

    name: ClassVar[str]
    symmetry: ClassVar[int]  # n-fold rotational symmetry about the insertion axis
    description: ClassVar[str]
    shell_length: ClassVar[float]
    tail_half: ClassVar[Vec3]  # half extents of the grasp tail (x, y, z)
    # Length of shell left outside the socket when seated, so the tail never touches the port.
    seat_standoff: ClassVar[float] = 0.002
    # What holds a seated plug in its socket, and the axial pull (N) that overcomes it.
    retention_mechanism: ClassVar[str] = "none"
    retention_force: ClassVar[float] = 0.0

    @property
    def retains(self) -> bool:
        """True when a seated plug is held by a latch or by friction (not a plain peg)."""
        return self.retention_mechanism != "none" and self.retention_force > 0.0

    def seated_rolls(self) -> list[float]:
        """Rolls (rad about the insertion axis) in which the plug seats: one per symmetric
        orientation (a continuous symmetry has no distinct orientation to latch in)."""
        if self.symmetry == 0:
            return []
        return [2.0 * np.pi * k / self.symmetry for k in range(self.symmetry)]

    def __post_init__(self) -> None:
        owner = type(self).__name__
        if self.allow_interference:
            validation.in_range(owner, "clearance", self.clearance, -0.002, MAX_CLEARANCE)
        else:
            validation.in_range(owner, "clearance", self.clearance, 0.0, MAX_CLEARANCE)

    # -- geometry every family provides ------------------------------------------------------
    def shell_rects(self) -> list[Rect]:
        """Cross-section of the insertable shell as a union of rectangles (y/z extents)."""
        raise NotImplementedError

    def shell_shapes(self, x0: float, x1: float) -> list[Shape]:
        """The insertable shell between x0 and x1; default: the rectangles as boxes."""
        return [_rect_box(r, x0, x1) for r in self.shell_rects()]

    def port_extra_shapes(self) -> list[Shape]:
        """Key features added inside the socket (port frame); default none."""
        return []

    # -- derived geometry -----------------------------------------------------------------------
    @property
    def tail_length(self) -> float:
        return 2.0 * self.tail_half[0]

    @property
    def plug_length(self) -> float:
        return self.tail_length + self.shell_length

    @property
    def cavity_depth(self) -> float:
        return self.shell_length - self.seat_standoff

    def plug_tail_shapes(self) -> list[Shape]:
        hx, hy, hz = self.tail_half
        return [Box((hx, hy, hz), (hx, 0.0, 0.0))]

    def plug_shell_shapes(self) -> list[Shape]:
        return self.shell_shapes(self.tail_length, self.plug_length)

    def plug_shapes(self) -> list[Shape]:
        return self.plug_tail_shapes() + self.plug_shell_shapes()

    def cavity_rects(self) -> list[Rect]:
        c = self.clearance
        return [(y0 - c, y1 + c, z0 - c, z1 + c) for (y0, y1, z0, z1) in self.shell_rects()]

    def port_outer_rect(self) -> Rect:
        rects = np.asarray(self.cavity_rects())
        return (
            float(rects[:, 0].min()) - WALL,
            float(rects[:, 1].max()) + WALL,
            float(rects[:, 2].min()) - WALL,
            float(rects[:, 3].max()) + WALL,
        )

    def port_shapes(self) -> list[Shape]:
        """Socket walls around the cavity, a back stop, then any key features."""
        depth = self.cavity_depth
        walls = [
            _rect_box(r, 0.0, depth)
            for r in _rect_difference(self.port_outer_rect(), self.cavity_rects())
        ]
        back = _rect_box(self.port_outer_rect(), depth, depth + WALL)
        return walls + [back] + self.port_extra_shapes()


def _rect_box(rect: Rect, x0: float, x1: float) -> Box:
    y0, y1, z0, z1 = rect
    return Box(
        ((x1 - x0) / 2, (y1 - y0) / 2, (z1 - z0) / 2),
        ((x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2),
    )


def _rect_difference(outer: Rect, holes: list[Rect]) -> list[Rect]:
    """``outer`` minus the union of ``holes``, as few non-overlapping rectangles.

    Grid decomposition: the rectangles' edges cut the outer rectangle into cells; cells not
    inside any hole are solid, and runs of solid cells along y within one z-band are merged.
    """
    ys = sorted({outer[0], outer[1], *(v for h in holes for v in h[:2])})
    zs = sorted({outer[2], outer[3], *(v for h in holes for v in h[2:])})
    ys = [y for y in ys if outer[0] <= y <= outer[1]]
    zs = [z for z in zs if outer[2] <= z <= outer[3]]

    def solid(yc: float, zc: float) -> bool:
        return not any(h[0] < yc < h[1] and h[2] < zc < h[3] for h in holes)

    rects: list[Rect] = []
    for z0, z1 in zip(zs, zs[1:], strict=False):
        run_start = None
        for i, (y0, y1) in enumerate(zip(ys, ys[1:], strict=False)):
            if solid((y0 + y1) / 2, (z0 + z1) / 2):
                run_start = y0 if run_start is None else run_start
                if i == len(ys) - 2:
                    rects.append((run_start, y1, z0, z1))
            elif run_start is not None:
                rects.append((run_start, y0, z0, z1))
                run_start = None
    return rects


def shape_volume(shape: Shape) -> float:
    if isinstance(shape, Box):
        return 8.0 * float(np.prod(shape.half))
    if isinstance(shape, Prism):
        yz = np.asarray(shape.profile)
        area = 0.5 * abs(
            dot(yz[:, 0], np.roll(yz[:, 1], -1)) - dot(yz[:, 1], np.roll(yz[:, 0], -1))
        )
        return area * abs(shape.x1 - shape.x0)
    return float(np.pi * shape.radius**2 * 2.0 * shape.half_length)


def make_connector(name: str, clearance: float = 0.003, **kwargs) -> Connector:
    """The connector family ``name`` at ``clearance`` (metres of gap per side)."""
    return CONNECTORS.get(name)(clearance=clearance, **kwargs)


def add_plug(
    spec: mujoco.MjSpec,
    connector: Connector,
    *,
    name: str = "plug",
    pos: Vec3 = (0.0, 0.0, 0.0),
    quat: Quat = (1.0, 0.0, 0.0, 0.0),
    parent: mujoco.MjsBody | None = None,
    free: bool = True,
    mass: float = physics.PLUG_MASS,
) -> mujoco.MjsBody:
    """Add the plug as a body (with a free joint unless ``free`` is False)."""
    body = (parent or spec.worldbody).add_body(name=name, pos=pos, quat=quat)
    if free:
        body.add_freejoint(name=f"{name}_free")
    shapes = connector.plug_shapes()
    density = mass / sum(shape_volume(s) for s in shapes)
    add_to_body(
        spec,
        body,
        connector.plug_tail_shapes(),
        f"{name}_tail",
        rgba=PLUG_RGBA,
        friction=physics.PLUG_FRICTION,
        density=density,
    )
    add_to_body(
        spec,
        body,
        connector.plug_shell_shapes(),
        f"{name}_shell",
        rgba=SHELL_RGBA,
        friction=physics.PLUG_FRICTION,
        density=density,
    )
    body.add_site(name=f"{name}_wire", pos=(0.0, 0.0, 0.0), size=(0.002, 0, 0))
    body.add_site(name=f"{name}_grasp", pos=(connector.tail_half[0], 0.0, 0.0), size=(0.002, 0, 0))
    body.add_site(name=f"{name}_tip", pos=(connector.plug_length, 0.0, 0.0), size=(0.002, 0, 0))
    return body


def add_port(
    spec: mujoco.MjSpec,
    connector: Connector,
    *,
    name: str = "port",
    pos: Vec3 = (0.0, 0.0, 0.0),
    quat: Quat = (1.0, 0.0, 0.0, 0.0),
    parent: mujoco.MjsBody | None = None,
) -> mujoco.MjsBody:
    """Add the socket as a fixed body (a child of ``parent``, the world by default)."""
    body = (parent or spec.worldbody).add_body(name=name, pos=pos, quat=quat)
    add_to_body(
        spec,
        body,
        connector.port_shapes(),
        f"{name}_wall",
        rgba=PORT_RGBA,
        friction=physics.PLUG_FRICTION,
    )
    body.add_site(name=f"{name}_entry", pos=(0.0, 0.0, 0.0), size=(0.002, 0, 0))
    body.add_site(name=f"{name}_seated", pos=(connector.cavity_depth, 0.0, 0.0), size=(0.002, 0, 0))
    return body


# Retention welds: stiff enough that a latch holds its rated pull within a fraction of a
# millimetre (a 10 g plug's weld is only as stiff as its impedance and time constant make it:
# see docs/assets.md), soft enough (10 ms, critically damped) that engaging it settles the
# plug into place over a few control steps instead of in one substep.
RETENTION_SOLREF = (0.01, 1.0)
RETENTION_SOLIMP = (0.99, 0.999, 0.001, 0.5, 2.0)
RETENTION_MECHANISMS = ("none", "latch", "friction")
# The weld holds the tip this far short of the back stop: a latch has axial play, and a weld
# target on the stop face would press the plug into it forever (a standing contact force).
RETENTION_PLAY = 0.0005  # m


def add_retention(
    spec: mujoco.MjSpec, connector: Connector, *, plug: str = "plug", port: str = "port"
) -> list[str]:
    """Weld equalities (inactive) holding the plug ``plug`` seated in the port ``port``: the
    plug's tip frame on the socket's seated frame (``RETENTION_PLAY`` short of the back stop,
    site ``{port}_retention{k}``), one weld per roll of ``seated_rolls`` (names
    ``{plug}_retention{k}``).  None for a connector that does not retain.  Returns the
    names."""
    validation.one_of(
        type(connector).__name__,
        "retention_mechanism",
        connector.retention_mechanism,
        RETENTION_MECHANISMS,
    )
    if not connector.retains:
        return []
    if connector.symmetry == 0:
        raise ValueError(
            f"{type(connector).__name__}: a rotation-invariant connector has no orientation to "
            f"latch in; give it retention_mechanism 'none'"
        )
    names = []
    port_body = spec.body(port)
    for k, roll in enumerate(connector.seated_rolls()):
        target = f"{port}_retention{k}"
        port_body.add_site(
            name=target,
            pos=(connector.cavity_depth - RETENTION_PLAY, 0.0, 0.0),
            quat=quat_about((1.0, 0.0, 0.0), roll),
            size=(0.002, 0, 0),
        )
        name = f"{plug}_retention{k}"
        spec.add_equality(
            name=name,
            type=mujoco.mjtEq.mjEQ_WELD,
            objtype=mujoco.mjtObj.mjOBJ_SITE,
            name1=f"{plug}_tip",
            name2=target,
            active=False,
            solref=RETENTION_SOLREF,
            solimp=RETENTION_SOLIMP,
        )
        names.append(name)
    return names


FLIP_ABOUT_AXIS = quat_about((1.0, 0.0, 0.0), np.pi)  # 180 degrees about the insertion axis
