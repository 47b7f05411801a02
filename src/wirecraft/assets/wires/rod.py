"""Discrete elastic rod: a MuJoCo ``flexcomp dim="1"`` with bending and twist elasticity.

The flex lives at world level (no pins): each vertex is a point mass with three slide joints,
each edge a capsule of the wire's radius, edge lengths are held by a flex equality, and the
``elasticity`` element gives bending (from E I) and twist (from G J).  An attached end is
clamped: its two vertices become points of the attached body, which MuJoCo then treats like a
``<pin>`` of that edge (XMLreference, flex elasticity): the body fixes the end's position,
tangent and material frame, so the rod's twist reaches it, and the edge's own twist joint goes.
(Two ``connect`` equalities, used before, clamped position and tangent but left the roll about
the wire's axis free: a plug turned against no torsional stiffness at all, docs/physics.md.)
The flex stays at world level rather than inside a jointed body, which is ~5x faster.
"""

from __future__ import annotations

import mujoco
import numpy as np

from wirecraft.assets.wires.base import (
    ATTACH_SOLIMP,
    ATTACH_SOLREF,
    END_CLEARANCE,
    FLEX,
    WIRE_MODELS,
    WireConfig,
    WireHandle,
    flex_touch_criteria,
    set_slide_bodies,
)

TWIST_DAMPING = 1e-7  # N m s / rad


@WIRE_MODELS.register("rod")
class RodWire(WireHandle):
    model = "rod"
    DEFAULTS = {
        "radius": 0.003,
        "segments": 40,
        "density": 800.0,
        "young": 5e7,
        "poisson": 0.49,
        # s, stiffness-proportional damping; NOTES: >= 0.01 exploded at 2 ms with an
        # attached yawed free body, <= 0.003 was stable
        "damping": 0.002,
        "friction": 1.0,
        "rgba": (0.15, 0.35, 0.8, 1.0),
    }

    @property
    def num_points(self) -> int:
        return self.config.segments + 1

    @classmethod
    def gap_for(cls, config: WireConfig) -> float:
        # the end edge's capsule reaches one radius past the end vertex
        return config.radius + END_CLEARANCE

    def body_name(self, vertex: int) -> str:
        return f"{self.flex_name}_{vertex}"

    def _build(self, spec: mujoco.MjSpec) -> None:
        c = self.config
        n = c.segments + 1
        seg = c.segment_length
        rgba = " ".join(f"{v:g}" for v in c.rgba)
        # stiff edge-length equality: the default (solref 0.02) let the rod stretch 17% under
        # its own weight, since soft constraints yield in proportion to the vertex mass
        ref = " ".join(f"{v:g}" for v in ATTACH_SOLREF)
        imp = " ".join(f"{v:g}" for v in ATTACH_SOLIMP)
        xml = (
            f'<flexcomp name="{FLEX}" type="grid" dim="1" count="{n} 1 1" '
            f'spacing="{seg:.9g} {seg:.9g} {seg:.9g}" radius="{c.radius:g}" '
            f'mass="{c.mass * n / (n - 1):.9g}" POSE rgba="{rgba}">'
            f'<edge equality="true" solref="{ref}" solimp="{imp}"/>'
            f'<elasticity young="{c.young:g}" shear="{c.shear_modulus:g}" '
            f'damping="{c.damping:g}"/>'
            f"{self._contact_xml('none')}"
            "</flexcomp>"
        )
        # flexcomp gives every vertex mass/n; n/(n-1) makes the interior vertices carry one edge
        # of wire each, so the distributed weight per length is density * area.
        self._add_flexcomp(spec, xml)
        # Both end attachments leave the wire's roll about its own axis free, and nothing damps
        # that rigid spin: a knock at reset kept it spinning at ~30 rad/s forever.  A tiny
        # damping on the twist joints (time constant ~10 ms at their ~1e-9 kg m^2) stops it.
        for joint in spec.joints:
            if joint.name.startswith(f"{self.flex_name}_twist"):
                joint.damping = (TWIST_DAMPING, 0.0, 0.0)

    def _end_vertices(self, end: str) -> list[int]:
        last = self.config.segments
        return [0, 1] if end == "start" else [last, last - 1]

    def _end_twist(self, end: str) -> str:
        """The twist joint (and body) of the end edge, which clamping removes."""
        return f"{self.flex_name}_twist_0" if end == "start" else f"{self.flex_name}_twist"

    def _attach(self, spec: mujoco.MjSpec, end: str, body_name: str) -> None:
        # MuJoCo clamps the last edge only on a rod of >= 3 edges (XMLreference)
        if self.config.segments < 3:
            raise ValueError(f"wire {self.name!r}: attaching a rod end needs >= 3 segments")
        seg = self.config.segment_length
        flex = spec.flex(self.flex_name)
        bodies = list(flex.vertbody)
        # vertices at their own body's origin have no stored offsets
        offsets = list(flex.vert) or [0.0] * (3 * len(bodies))
        for v in self._end_vertices(end):
            bodies[v] = body_name
            point = self.attach_frame_point(end, np.array([v * seg, 0.0, 0.0]))
            offsets[3 * v : 3 * v + 3] = point.tolist()
        flex.vertbody = bodies
        flex.vert = offsets
        # only now: deleting a body the flex still names deletes the flex with it
        for v in self._end_vertices(end):
            spec.delete(spec.body(self.body_name(v)))
        spec.delete(spec.body(self._end_twist(end)))
        self._stabilize(spec, body_name)

    def _stabilize(self, spec: mujoco.MjSpec, body_name: str) -> None:
        """Armature on the clamping body's joints, so that its turn stays stable.

        MuJoCo integrates the rod's twist implicitly in the rod's own joints but feeds the
        clamped end's torque to the body explicitly: with the edge's torsional stiffness
        k = G J / l and its Rayleigh damping beta k, a body of inertia I diverges once
        k dt (dt + beta) / I passes ~1 (a 10 g plug, I ~ 2.5e-7 kg m^2 about its axis, blew up
        in free fall within 25 steps).  An armature of k dt (dt + beta) keeps the ratio below
        1 whatever the body; it adds ~1.8e-6 kg m^2 with the defaults (and as many kg to a
        free joint's translation: nothing next to grams).
        """
        c = self.config
        k = c.shear_modulus * 2.0 * c.second_moment / c.segment_length  # J = 2 I for a circle
        dt = spec.option.timestep
        armature = k * dt * (dt + c.damping)
        body = spec.body(body_name)
        for joint in body.joints:
            joint.armature = max(joint.armature, armature)

    def _resolve(self, model: mujoco.MjModel) -> object:
        flex = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_FLEX, self.flex_name)
        if flex < 0:
            raise ValueError(f"no flex named {self.flex_name!r} in the model")
        adr = model.flex_vertadr[flex]
        return np.arange(adr, adr + model.flex_vertnum[flex])

    def _points(self, xpos, xmat, flexvert_xpos, ids: object) -> np.ndarray:
        return flexvert_xpos[:, ids]

    def _touch_criteria(self, spec, geom: str) -> list[tuple[float, mujoco.mjtObj, str]]:
        return flex_touch_criteria(spec, geom)

    # -- set_centerline ------------------------------------------------------------------------
    def _shape_nodes(self) -> tuple[int, float]:
        return self.config.segments, self.config.segment_length

    def _twist_names(self) -> list[str]:
        n = self.config.segments
        names = [f"{self.flex_name}_twist_{e}" for e in range(n - 1)] + [f"{self.flex_name}_twist"]
        clamped = {self._end_twist(end) for end in self.attached}
        return [name for name in names if name not in clamped]

    def _free_vertices(self) -> np.ndarray:
        """Vertices with their own slide bodies (the clamped ends' belong to attached bodies)."""
        clamped = {v for end in self.attached for v in self._end_vertices(end)}
        return np.array([v for v in range(self.num_points) if v not in clamped], dtype=int)

    def _shape_ids(self, model: mujoco.MjModel) -> dict[str, np.ndarray]:
        free = self._free_vertices()
        verts = np.asarray(self._resolve(model))[free]
        flex = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_FLEX, self.flex_name)
        bodies = model.flex_vertbodyid[verts]
        twists = []
        for name in self._twist_names():
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if jid < 0:
                raise ValueError(f"no twist joint named {name!r} in the model")
            twists.append(jid)
        slides = [j for b in bodies for j in range(model.body_jntadr[b], model.body_jntadr[b] + 3)]
        # reference frames (t, u) per edge, then the reference twist per interior vertex
        n = self.config.segments
        plastic = np.arange(model.flex_plasticadr[flex], model.flex_plasticadr[flex] + 7 * n - 1)
        if plastic[-1] >= model.nplastic:
            raise ValueError(f"flex {self.flex_name!r}: unexpected plastic layout")
        return {
            "free": free,
            "bodies": bodies,
            "twists": np.asarray(twists),
            "joints": np.asarray(slides + twists),
            "plastic": plastic,
        }

    def _set_shape(self, model, data, ids, nodes, frames, roll) -> None:
        # the clamped ends go with their bodies, which the caller places (set_centerline)
        set_slide_bodies(model, data, ids["bodies"], nodes[ids["free"]])
        # Uniform material angle: no twist energy.  Zeroed reference frames make MuJoCo restart
        # them at the next step, transported from qpos0 onto the new tangents twist-free
        # (XMLreference, flex elasticity "State"), i.e. exactly the frames of this shape.
        # A clamped start restarts the reference frames from its body, which the caller puts
        # at the rolled pose: the material frames then need no twist of their own.
        data.qpos[model.jnt_qposadr[ids["twists"]]] = 0.0 if "start" in self.attached else roll
        data.plastic[ids["plastic"]] = 0.0
