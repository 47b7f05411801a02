"""One wire configuration, three physics models, one builder API.

``WireConfig`` names the model and its parameters; ``None`` means "the model's default" (each
model class lists its ``DEFAULTS``).  ``add_wire`` builds the chosen model into an ``MjSpec`` and
returns a ``WireHandle`` that reads the centre line and attaches the wire's ends to bodies.

Wire frame: the centre line starts at ``pos`` and runs along the frame's +x axis for ``length``
metres (``quat`` is (w, x, y, z)).  Units are SI throughout.

End-attachment convention (same for both ends): the attached body's origin sits exactly on the
wire's end point, and the body's +x axis points *away* from the wire, so the wire leaves the body
along the body's -x axis.  For the ``"end"`` end the body's frame equals the wire frame shifted
to ``(length, 0, 0)``; for ``"start"`` it is the wire frame turned 180 degrees about z.  A
connector's plug therefore extends along its own +x, beyond the wire.
"""

from __future__ import annotations

import dataclasses
import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import mujoco
import numpy as np

from wirecraft import physics, validation
from wirecraft.registry import Registry

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
ENDS = ("start", "end")

WIRE_MODELS: Registry[type[WireHandle]] = Registry("wire model")

_OWNER = "WireConfig"
FLEX = "flex"  # name of the flexcomp inside a flex wire's sub-spec
_NUMERIC_FIELDS = ("radius", "density", "young", "damping", "friction")


@dataclass(frozen=True)
class WireConfig:
    """Parameters of a wire; ``None`` fields take the model's default (see ``resolved()``).

    model:    "articulated" (capsule chain), "rod" (flex elastic rod) or "fem" (3D trilinear FEM).
    length:   m, the centre-line length.
    radius:   m, the collision radius of the wire.
    segments: articulated: number of capsules; rod: number of flex edges; fem: number of vertex
              intervals along the axis (the FEM uses ``segments // 2`` trilinear cells).
    density:  kg/m^3 of the wire material (mass = density * pi r^2 * length).
    young:    Pa, Young's modulus that sets the bending stiffness E I, I = pi r^4 / 4.  For the
              capsule chain the joint stiffness is k = E I / l_seg (N m/rad).
    poisson:  Poisson's ratio in [0, 0.5): sets the twist stiffness G J, G = E / (2 (1 + nu)).
    damping:  model-specific (see docs/physics.md): articulated: joint damping, N m s/rad;
              rod and fem: the flex elasticity's stiffness-proportional (Rayleigh) damping, s.
    friction: sliding friction coefficient of the wire's contacts.
    rgba:     colour.
    """

    model: str = "articulated"
    length: float = 0.4
    radius: float | None = None
    segments: int | None = None
    density: float | None = None
    young: float | None = None
    poisson: float | None = None
    damping: float | None = None
    friction: float | None = None
    rgba: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        WIRE_MODELS.get(self.model)  # ValueError listing the valid models
        object.__setattr__(self, "length", validation.positive(_OWNER, "length", self.length))
        for field in _NUMERIC_FIELDS:
            value = getattr(self, field)
            if value is None:
                continue
            check = validation.non_negative if field == "damping" else validation.positive
            object.__setattr__(self, field, check(_OWNER, field, value))
        if self.poisson is not None:
            value = validation.in_range(_OWNER, "poisson", self.poisson, 0.0, 0.5, high_open=True)
            object.__setattr__(self, "poisson", value)
        if self.segments is not None:
            validation.at_least_int(_OWNER, "segments", self.segments, 2)
        if self.rgba is not None:
            object.__setattr__(self, "rgba", validation.rgba(_OWNER, "rgba", self.rgba))

    # -- defaults and derived quantities ------------------------------------------------------
    def resolved(self) -> WireConfig:
        """A copy with every ``None`` replaced by the model's default."""
        defaults = WIRE_MODELS.get(self.model).DEFAULTS
        filled = {
            f.name: defaults[f.name]
            for f in dataclasses.fields(self)
            if getattr(self, f.name) is None and f.name in defaults
        }
        return dataclasses.replace(self, **filled)

    def _need(self, field: str) -> float:
        value = getattr(self, field)
        if value is None:
            raise ValueError(f"WireConfig.{field} is unset: call resolved() first")
        return value

    @property
    def segment_length(self) -> float:
        """m, the length of one segment (capsule, rod edge or FEM vertex interval)."""
        return self.length / self._need("segments")

    @property
    def area(self) -> float:
        """m^2, cross-section area pi r^2."""
        return math.pi * self._need("radius") ** 2

    @property
    def second_moment(self) -> float:
        """m^4, area moment of inertia of the circular cross-section, pi r^4 / 4."""
        return math.pi * self._need("radius") ** 4 / 4.0

    @property
    def bending_stiffness(self) -> float:
        """N m^2, E I."""
        return self._need("young") * self.second_moment

    @property
    def shear_modulus(self) -> float:
        """Pa, G = E / (2 (1 + nu))."""
        return self._need("young") / (2.0 * (1.0 + self._need("poisson")))

    @property
    def linear_density(self) -> float:
        """kg/m, mass per unit length."""
        return self._need("density") * self.area

    @property
    def mass(self) -> float:
        """kg, total mass of the wire."""
        return self.linear_density * self.length


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, np.asarray(a, float), np.asarray(b, float))
    return out


def _rotate(quat: np.ndarray, vec: np.ndarray) -> np.ndarray:
    out = np.zeros(3)
    mujoco.mju_rotVecQuat(out, np.asarray(vec, float), np.asarray(quat, float))
    return out


# Attachment equalities: MuJoCo's soft constraints yield in proportion to the (tiny) mass of a
# wire vertex, so with the contact impedance 0.99 a clamp let a 0.4 m rod tip sag ~0.5 mm too
# far under 1% gravity.  Impedance 0.9999 (the maximum) makes the attachment ~100x stiffer.
ATTACH_SOLREF = physics.CONTACT_SOLREF
ATTACH_SOLIMP = (0.9999, 0.9999, 0.001, 0.5, 2.0)

_TURN_Z = np.array([0.0, 0.0, 0.0, 1.0])  # 180 degrees about z


class WireHandle(ABC):
    """A wire built into a spec.  Subclasses implement one physics model each.

    Attributes: ``name`` (prefix of every element the wire creates), ``model`` (registry name),
    ``config`` (resolved ``WireConfig``), ``pos`` / ``quat`` (the wire frame in the world).
    """

    model: ClassVar[str]
    DEFAULTS: ClassVar[Mapping[str, object]]

    def __init__(
        self, spec: mujoco.MjSpec, config: WireConfig, name: str, pos: Vec3, quat: Quat
    ) -> None:
        self.config = config.resolved()
        self.name = name
        self.pos = np.asarray(pos, dtype=float).reshape(3)
        q = np.asarray(quat, dtype=float).reshape(4)
        self.quat = q / np.linalg.norm(q)
        self.attached: dict[str, str] = {}
        self._ids: object | None = None
        self._build(spec)

    # -- geometry of the straight, as-built wire -------------------------------------------------
    def to_world(self, local: np.ndarray) -> np.ndarray:
        """Points given in the wire frame, (..., 3) -> world (..., 3), as built."""
        local = np.asarray(local, float)
        flat = local.reshape(-1, 3)
        out = np.array([self.pos + _rotate(self.quat, p) for p in flat])
        return out.reshape(local.shape)

    def end_pose_local(self, end: str) -> tuple[np.ndarray, np.ndarray]:
        """Pose of an attached body in the wire frame (see the module's convention)."""
        validation.one_of("WireHandle", "end", end, ENDS)
        if end == "end":
            return np.array([self.config.length, 0.0, 0.0]), np.array([1.0, 0.0, 0.0, 0.0])
        return np.zeros(3), _TURN_Z.copy()

    def end_pose(self, end: str) -> tuple[np.ndarray, np.ndarray]:
        """World pose (pos (3,), quat (4,) w-x-y-z) where a body attached at ``end`` belongs.

        Place the body there at build time; ``attach`` then holds it without a jump.
        """
        lpos, lquat = self.end_pose_local(end)
        return self.pos + _rotate(self.quat, lpos), _quat_mul(self.quat, lquat)

    def attach_frame_point(self, end: str, local_point: np.ndarray) -> np.ndarray:
        """A wire-frame point expressed in the frame of the body attached at ``end``."""
        lpos, lquat = self.end_pose_local(end)
        inv = np.array([lquat[0], -lquat[1], -lquat[2], -lquat[3]])
        return _rotate(inv, np.asarray(local_point, float) - lpos)

    # -- public API ---------------------------------------------------------------------------
    def attach(self, spec: mujoco.MjSpec, end: str, body_name: str) -> None:
        """Rigidly attach the wire's ``end`` ("start" or "end") to the existing body ``body_name``.

        The body's origin holds the wire's end point and the wire leaves along the body's -x
        axis (module docstring).  Place the body at ``end_pose(end)`` when building it.
        Contacts between the body and the wire's last segment are excluded.
        """
        validation.one_of("WireHandle", "end", end, ENDS)
        if end in self.attached:
            raise ValueError(f"wire {self.name!r}: end {end!r} is already attached")
        if spec.body(body_name) is None:
            raise ValueError(f"wire {self.name!r}: no body named {body_name!r} in the spec")
        self._attach(spec, end, body_name)
        self.attached[end] = body_name

    def points(self, model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
        """World centre-line points, (num_points, 3), from the start end to the other end."""
        if self._ids is None:
            self._ids = self._resolve(model)
        return self._points(model, data, self._ids)

    @property
    @abstractmethod
    def num_points(self) -> int:
        """Number of rows returned by ``points``."""

    # -- model-specific hooks --------------------------------------------------------------------
    @abstractmethod
    def _build(self, spec: mujoco.MjSpec) -> None: ...

    @abstractmethod
    def _attach(self, spec: mujoco.MjSpec, end: str, body_name: str) -> None: ...

    @abstractmethod
    def _resolve(self, model: mujoco.MjModel) -> object: ...

    @abstractmethod
    def _points(self, model: mujoco.MjModel, data: mujoco.MjData, ids: object) -> np.ndarray: ...

    # -- helpers shared by the flex models ---------------------------------------------------------
    def _contact_xml(self, selfcollide: str) -> str:
        ref = " ".join(f"{v:g}" for v in physics.CONTACT_SOLREF)
        imp = " ".join(f"{v:g}" for v in physics.CONTACT_SOLIMP)
        mu = self.config.friction
        return (
            f'<contact condim="3" friction="{mu:g} 0.005 0.0001" solref="{ref}" '
            f'solimp="{imp}" selfcollide="{selfcollide}"/>'
        )

    @property
    def flex_name(self) -> str:
        """Name of the flex in the compiled model (flex models only)."""
        return f"{self.name}/{FLEX}"

    def _add_flexcomp(self, spec: mujoco.MjSpec, xml: str, *, in_body: bool = False) -> None:
        """Parse a one-flexcomp MJCF (named ``FLEX``, with a ``POSE`` placeholder) and attach it.

        Every generated element is prefixed ``NAME/``: the flex is ``NAME/flex``, its bodies
        ``NAME/flex_<i>`` (vertices or trilinear nodes ``NAME/flex_<i>_<j>_<k>``).
        ``in_body`` places the flexcomp in a static (jointless) body ``NAME/frame`` carrying the
        wire's pose; trilinear flexes need it (see below).
        """
        # MuJoCo 4.0.0 quirks measured here: (1) a translated attachment frame breaks trilinear
        # flexes ("unpinned node 0 in empty cell with free DOFs"); (2) a rotated flexcomp
        # (its own quat) gets a trilinear grid aligned with the *parent's* axes, i.e. the
        # bounding box of the rotated wire.  A static parent body with the pose avoids both.
        centre = self.to_world(np.array([self.config.length / 2, 0.0, 0.0]))
        pos = " ".join(f"{v:.9g}" for v in centre)
        quat = " ".join(f"{v:.9g}" for v in self.quat)
        if in_body:
            body = f'<body name="frame" pos="{pos}" quat="{quat}">'
            inner = body + xml.replace("POSE", 'pos="0 0 0"') + "</body>"
        else:
            inner = xml.replace("POSE", f'pos="{pos}" quat="{quat}"')
        child = mujoco.MjSpec.from_string(
            f'<mujoco><compiler angle="radian"/><worldbody>{inner}</worldbody></mujoco>'
        )
        frame = spec.worldbody.add_frame()
        spec.attach(child, frame=frame, prefix=f"{self.name}/")

    def _connect_sites(
        self, spec: mujoco.MjSpec, body_name: str, end: str, anchors: list[tuple[str, np.ndarray]]
    ) -> None:
        """Connect equalities pinning wire-frame points (on bodies) to the attached body."""
        target = spec.body(body_name)
        for k, (wire_body, local_point) in enumerate(anchors):
            tag = f"{self.name}_{end}_{k}"
            spec.body(wire_body).add_site(name=f"{tag}_w", pos=[0.0, 0.0, 0.0])
            target.add_site(name=f"{tag}_b", pos=self.attach_frame_point(end, local_point).tolist())
            eq = spec.add_equality(
                name=tag,
                type=mujoco.mjtEq.mjEQ_CONNECT,
                objtype=mujoco.mjtObj.mjOBJ_SITE,
                name1=f"{tag}_b",
                name2=f"{tag}_w",
            )
            eq.solref = ATTACH_SOLREF
            eq.solimp = ATTACH_SOLIMP
            spec.add_exclude(bodyname1=body_name, bodyname2=wire_body)


def add_wire(
    spec: mujoco.MjSpec,
    config: WireConfig | None = None,
    *,
    name: str = "wire",
    pos: Vec3 = (0.0, 0.0, 0.0),
    quat: Quat = (1.0, 0.0, 0.0, 0.0),
) -> WireHandle:
    """Build a wire into ``spec``; its centre line starts at ``pos`` and runs along +x of ``quat``.

    Returns the model's ``WireHandle`` (``points``, ``attach``, ``end_pose``).
    """
    config = config if config is not None else WireConfig()
    return WIRE_MODELS.get(config.model)(spec, config, name, pos, quat)
