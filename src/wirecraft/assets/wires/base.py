"""One wire configuration, three physics models, one builder API.

``WireConfig`` names the model and its parameters; ``None`` means "the model's default" (each
model class lists its ``DEFAULTS``).  ``add_wire`` builds the chosen model into an ``MjSpec`` and
returns a ``WireHandle`` that reads the centre line and attaches the wire's ends to bodies.

Wire frame: the centre line starts at ``pos`` and runs along the frame's +x axis for ``length``
metres (``quat`` is (w, x, y, z)).  Units are SI throughout.

End-attachment convention (same for both ends): the attached body's origin sits on the wire's
axis ``end_gap`` beyond the wire's end point, and the body's +x axis points *away* from the
wire, so the wire leaves the body along the body's -x axis.  For the ``"end"`` end the body's
frame equals the wire frame shifted to ``(length + end_gap, 0, 0)``; for ``"start"`` it is the
wire frame turned 180 degrees about z, at ``(-end_gap, 0, 0)``.  A connector's plug therefore
extends along its own +x, beyond the wire.

Why the gap: a body attached to a flex wire must not touch the flex's end element.  Contact
excludes act on bodies, and a flex element is not a body's geom, so nothing filters that
contact: a plug face at the end point lay 2.6 mm deep inside the rod's end capsule, and the
contact and the attachment fought on every step (it ended 3 in 100 rod routing episodes in a
divergence).  The capsule chain excludes its end capsule instead and has no gap.
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
from wirecraft.assets.wires import shape
from wirecraft.numerics import dot, norm
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

# m of clearance between a flex wire's collision surface and the body attached to its end: the
# attachment holds the end within ~0.1 mm, so a contact there would need a real push.
END_CLEARANCE = 0.001


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
        self.quat = q / norm(q)
        self.attached: dict[str, str] = {}
        self._ids: object | None = None
        self._shape_cache: tuple[mujoco.MjModel, dict[str, np.ndarray]] | None = None
        self._build(spec)

    # -- geometry of the straight, as-built wire -------------------------------------------------
    def to_world(self, local: np.ndarray) -> np.ndarray:
        """Points given in the wire frame, (..., 3) -> world (..., 3), as built."""
        local = np.asarray(local, float)
        flat = local.reshape(-1, 3)
        out = np.array([self.pos + _rotate(self.quat, p) for p in flat])
        return out.reshape(local.shape)

    @classmethod
    def gap_for(cls, config: WireConfig) -> float:
        """m from the wire's end point to the origin of a body attached there (module docstring),
        for a resolved ``config``: 0 unless the model's collision surface reaches past its end
        point.  A class method, so that a task can place a body before the wire is built."""
        return 0.0

    @property
    def end_gap(self) -> float:
        return self.gap_for(self.config)

    def end_pose_local(self, end: str) -> tuple[np.ndarray, np.ndarray]:
        """Pose of an attached body in the wire frame (see the module's convention)."""
        validation.one_of("WireHandle", "end", end, ENDS)
        gap = self.end_gap
        if end == "end":
            return np.array([self.config.length + gap, 0.0, 0.0]), np.array([1.0, 0.0, 0.0, 0.0])
        return np.array([-gap, 0.0, 0.0]), _TURN_Z.copy()

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

    def resolve(self, model: mujoco.MjModel) -> None:
        """Look the wire's ids up in ``model`` (once; ``points_batch`` needs them)."""
        if self._ids is None:
            self._ids = self._resolve(model)

    def points(self, model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
        """World centre-line points, (num_points, 3), from the start end to the other end."""
        self.resolve(model)
        return self.points_batch(data.xpos[None], data.xmat[None], data.flexvert_xpos[None])[0]

    def points_batch(
        self, xpos: np.ndarray, xmat: np.ndarray, flexvert_xpos: np.ndarray
    ) -> np.ndarray:
        """``points`` of N simulations, (N, num_points, 3), from their (N, ...) ``xpos``,
        ``xmat`` and ``flexvert_xpos`` (one code for one simulation and for a batch, so both
        give the same bits); after ``resolve``."""
        if self._ids is None:
            raise RuntimeError(f"wire {self.name!r}: call resolve(model) before points_batch")
        return self._points(xpos, xmat, flexvert_xpos, self._ids)

    def touch_criteria(
        self, spec: mujoco.MjSpec, geom: str
    ) -> list[tuple[float, mujoco.mjtObj, str]]:
        """How contact sensors on the geom ``geom`` count its contacts with this wire:
        (sign, reftype, refname) criteria whose signed ``found`` counts add up to them."""
        return self._touch_criteria(spec, geom)

    @property
    @abstractmethod
    def num_points(self) -> int:
        """Number of rows returned by ``points``."""

    def set_centerline(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        points: np.ndarray,
        *,
        roll: float = 0.0,
    ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Put the wire into the shape of the polyline ``points`` (K, 3), world frame, at rest.

        The polyline runs from the wire's "start" end to its "end" end; it is extended straight
        along its last segment if shorter than the wire and truncated if longer.  The wire's
        nodes are placed *on* the polyline, consecutive nodes exactly one segment (capsule, rod
        edge or FEM cell) apart (``shape.chord_walk``), so the state satisfies the model's
        length constraints; after a kink the nodes lag their arc-length position by
        ~l (1 - cos(kink / 2)) per kink (l: the segment length), see docs/physics.md.

        The cross-section / material frame follows the polyline by parallel transport from the
        as-built wire frame turned by the smallest rotation onto the polyline's start tangent,
        then is rolled by ``roll`` (rad) about the tangent everywhere.  (For a polyline lying on
        the table and a wire built with its z axis up, z stays up at ``roll`` = 0.)

        Sets the wire's generalized positions (and rod reference frames in ``data.plastic``),
        zeroes its velocities and calls ``mj_forward``.  Bodies attached to the wire are not
        moved: the returned dict gives, for "start" and "end", the world pose (pos (3,), quat
        (4,) w-x-y-z) where the attached body must be placed (module docstring's convention;
        for the as-built straight polyline and ``roll`` = 0 this is ``end_pose(end)``).
        Raises ValueError if the shape would violate a model limit (the capsule chain's joint
        cone).
        """
        roll = float(roll)
        if not math.isfinite(roll):
            raise ValueError(f"set_centerline: roll must be finite, got {roll!r}")
        poly = shape.clean_polyline(points)
        count, step = self._shape_nodes()
        nodes = shape.chord_walk(poly, step, count)
        axis = _rotate(self.quat, np.array([1.0, 0.0, 0.0]))
        frames = shape.transport_frames(nodes, self.quat, axis, roll)
        ids = self._shape_resolve(model)
        self._set_shape(model, data, ids, nodes, frames, roll)
        dofs = _joint_dofs(model, ids["joints"])
        data.qvel[dofs] = 0.0
        data.qacc_warmstart[dofs] = 0.0
        mujoco.mj_forward(model, data)
        poses = {}
        for end, node, frame in (("start", nodes[0], frames[0]), ("end", nodes[-1], frames[-1])):
            _, lquat = self.end_pose_local(end)
            quat = _quat_mul(frame, lquat)
            quat /= norm(quat)
            # the body's +x points away from the wire: the gap lies along it
            poses[end] = (node + self.end_gap * _rotate(quat, np.array([1.0, 0.0, 0.0])), quat)
        return poses

    # -- model-specific hooks --------------------------------------------------------------------
    @abstractmethod
    def _build(self, spec: mujoco.MjSpec) -> None: ...

    @abstractmethod
    def _attach(self, spec: mujoco.MjSpec, end: str, body_name: str) -> None: ...

    @abstractmethod
    def _resolve(self, model: mujoco.MjModel) -> object: ...

    @abstractmethod
    def _points(self, xpos, xmat, flexvert_xpos, ids: object) -> np.ndarray:
        """(N, num_points, 3) centre lines from N simulations' fields."""

    @abstractmethod
    def _touch_criteria(self, spec, geom: str) -> list[tuple[float, mujoco.mjtObj, str]]: ...

    @abstractmethod
    def _shape_nodes(self) -> tuple[int, float]:
        """(number of segments, segment length) of the chain the shape is laid out on."""

    @abstractmethod
    def _shape_ids(self, model: mujoco.MjModel) -> dict[str, np.ndarray]:
        """Ids ``set_centerline`` needs; key "joints": every joint of the wire."""

    @abstractmethod
    def _set_shape(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        ids: dict[str, np.ndarray],
        nodes: np.ndarray,
        frames: np.ndarray,
        roll: float,
    ) -> None:
        """Write qpos (and any other state) for nodes (count + 1, 3) and chord frames (count, 4)."""

    def _shape_resolve(self, model: mujoco.MjModel) -> dict[str, np.ndarray]:
        cached = self._shape_cache
        if cached is None or cached[0] is not model:
            cached = (model, self._shape_ids(model))
            self._shape_cache = cached
        return cached[1]

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


def _joint_dofs(model: mujoco.MjModel, joints: np.ndarray) -> np.ndarray:
    """Dof indices of the given joints."""
    sizes = {
        mujoco.mjtJoint.mjJNT_FREE: 6,
        mujoco.mjtJoint.mjJNT_BALL: 3,
        mujoco.mjtJoint.mjJNT_SLIDE: 1,
        mujoco.mjtJoint.mjJNT_HINGE: 1,
    }
    out = [
        model.jnt_dofadr[j] + k
        for j in joints
        for k in range(sizes[mujoco.mjtJoint(model.jnt_type[j])])
    ]
    return np.asarray(out, dtype=int)


def _static_pose(model: mujoco.MjModel, body: int) -> tuple[np.ndarray, np.ndarray]:
    """World pose (pos, quat) of a body whose ancestors (and itself) have no joints."""
    pos, quat = np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])
    chain = []
    while body != 0:
        if model.body_jntnum[body] != 0:
            raise ValueError(f"body {model.body(body).name!r} is not static")
        chain.append(body)
        body = model.body_parentid[body]
    for b in reversed(chain):
        pos = pos + _rotate(quat, model.body_pos[b])
        quat = _quat_mul(quat, model.body_quat[b])
    return pos, quat


def set_slide_bodies(
    model: mujoco.MjModel, data: mujoco.MjData, bodies: np.ndarray, targets: np.ndarray
) -> None:
    """Move bodies that each carry three orthogonal slide joints (flex vertices / nodes, whose
    parents are static) so that their origins land on the world points ``targets``."""
    for body, target in zip(bodies, np.asarray(targets, float), strict=True):
        parent_pos, parent_quat = _static_pose(model, model.body_parentid[body])
        origin = parent_pos + _rotate(parent_quat, model.body_pos[body])
        quat = _quat_mul(parent_quat, model.body_quat[body])
        adr, num = model.body_jntadr[body], model.body_jntnum[body]
        for j in range(adr, adr + num):
            if (
                model.jnt_type[j] != mujoco.mjtJoint.mjJNT_SLIDE
                or model.qpos0[model.jnt_qposadr[j]] != 0.0
            ):
                raise ValueError(f"body {model.body(body).name!r}: expected slide joints at 0")
            axis = _rotate(quat, model.jnt_axis[j])
            data.qpos[model.jnt_qposadr[j]] = dot(axis, target - origin)


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


def flex_touch_criteria(spec: mujoco.MjSpec, geom: str) -> list[tuple[float, mujoco.mjtObj, str]]:
    """Contact sensor criteria for ``geom`` against a flex wire.  A flex contact has no geom on
    the flex's side, so no body criterion matches it there; the geom's contacts with the flex
    are all its contacts (no criterion) less those with each other body's geoms (a body
    criterion matches either side, so the geom's own body, whose geoms never collide with it,
    is left out).  Exact while the wire is the scene's only flex."""
    own = spec.geom(geom).parent.name
    others = [b.name for b in spec.bodies if b.geoms and b.name != own]
    return [(1.0, mujoco.mjtObj.mjOBJ_UNKNOWN, "")] + [
        (-1.0, mujoco.mjtObj.mjOBJ_BODY, name) for name in others
    ]


def end_gap(config: WireConfig | None = None) -> float:
    """The ``end_gap`` a wire built from ``config`` (as ``add_wire`` takes it) will have, without
    building it."""
    config = config if config is not None else WireConfig()
    return WIRE_MODELS.get(config.model).gap_for(config.resolved())
