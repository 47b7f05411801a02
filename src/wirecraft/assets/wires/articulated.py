"""Articulated wire: a chain of rigid capsules joined by ball joints with springs.

Bending stiffness comes from the config's Young's modulus: each of the N - 1 ball joints between
N capsules is a rotational spring k = E I / l_joint (N m/rad), the stiffness of the beam length
l_joint = L / (N - 1) it stands for, so the chain bends like an Euler-Bernoulli beam
(``joint_stiffness``).  The ball joint's spring is
isotropic, so twist gets the same k (instead of G J / l_seg: a documented simplification).  Each
joint is limited to a cone of 0.5 rad.  The first capsule's body carries a free joint; attached
ends use weld equalities between site frames.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from wirecraft import physics
from wirecraft.assets.wires import shape
from wirecraft.assets.wires.base import ATTACH_SOLIMP, ATTACH_SOLREF, WIRE_MODELS, WireHandle
from wirecraft.numerics import norm

JOINT_LIMIT = 0.5  # rad, cone half-angle of each ball joint
ARMATURE = 1e-6  # kg m^2: keeps the capsules' tiny roll inertia stable at 2 ms


@WIRE_MODELS.register("articulated")
class ArticulatedWire(WireHandle):
    model = "articulated"
    DEFAULTS = {
        "radius": 0.004,
        "segments": 12,
        "density": 2000.0,
        # E chosen so that E I / (rho A) equals the rod's and the FEM's: same hanging sag.
        "young": 5e7 * (2000.0 * 0.004**2) / (800.0 * 0.003**2) / (0.004 / 0.003) ** 4,
        "poisson": 0.49,
        "damping": 0.002,
        "friction": 1.0,
        "rgba": (0.8, 0.35, 0.15, 1.0),
    }

    @property
    def num_points(self) -> int:
        return self.config.segments + 1

    def body_name(self, index: int) -> str:
        return f"{self.name}_seg{index}"

    @property
    def joint_stiffness(self) -> float:
        """N m/rad: k = E I / l_joint, l_joint = L / (segments - 1) the spacing of the joints.

        The chain has one joint fewer than capsules, so each joint carries the compliance of
        L / (N - 1) of beam (k = E I / l_seg * (N - 1) / N): a uniform moment M then turns the
        end by exactly M L / (E I).
        """
        c = self.config
        return c.bending_stiffness * (c.segments - 1) / c.length

    def _build(self, spec: mujoco.MjSpec) -> None:
        c = self.config
        seg = c.segment_length
        # joint ranges are read in the spec's angle unit (MjSpec's default is degrees)
        limit = math.degrees(JOINT_LIMIT) if spec.compiler.degree else JOINT_LIMIT
        parent = spec.worldbody
        for i in range(c.segments):
            body = parent.add_body(
                name=self.body_name(i),
                pos=self.pos.tolist() if i == 0 else [seg, 0.0, 0.0],
                quat=self.quat.tolist() if i == 0 else [1.0, 0.0, 0.0, 0.0],
            )
            if i == 0:
                body.add_freejoint(name=f"{self.name}_root")
            else:
                body.add_joint(
                    name=f"{self.name}_j{i}",
                    type=mujoco.mjtJoint.mjJNT_BALL,
                    stiffness=self.joint_stiffness,
                    damping=c.damping,
                    armature=ARMATURE,
                    limited=mujoco.mjtLimited.mjLIMITED_TRUE,
                    range=[0.0, limit],
                )
            geom = body.add_geom(
                name=f"{self.name}_cap{i}",
                type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                fromto=[0.0, 0.0, 0.0, seg, 0.0, 0.0],
                size=[c.radius, 0.0, 0.0],
                density=c.density,
                rgba=list(c.rgba),
            )
            physics.stiff_contact(geom, friction=c.friction)
            geom.solmix = 1.0
            parent = body
        # Capsule density over a capsule's full volume (with caps) would overstate the mass:
        # use the cylinder's mass pi r^2 l_seg rho, as the other models do.
        for i in range(c.segments):
            geom = spec.geom(f"{self.name}_cap{i}")
            cyl = math.pi * c.radius**2 * seg
            caps = 4.0 / 3.0 * math.pi * c.radius**3
            geom.density = c.density * cyl / (cyl + caps)

    def _attach(self, spec: mujoco.MjSpec, end: str, body_name: str) -> None:
        c = self.config
        index = 0 if end == "start" else c.segments - 1
        wire_body = spec.body(self.body_name(index))
        # Site on the capsule at the wire's end, oriented like the attached body.
        _, lquat = self.end_pose_local(end)
        local_x = 0.0 if end == "start" else c.segment_length
        tag = f"{self.name}_{end}"
        wire_body.add_site(name=f"{tag}_w", pos=[local_x, 0.0, 0.0], quat=lquat.tolist())
        spec.body(body_name).add_site(name=f"{tag}_b", pos=[0.0, 0.0, 0.0])
        eq = spec.add_equality(
            name=tag,
            type=mujoco.mjtEq.mjEQ_WELD,
            objtype=mujoco.mjtObj.mjOBJ_SITE,
            name1=f"{tag}_b",
            name2=f"{tag}_w",
        )
        eq.solref = ATTACH_SOLREF
        eq.solimp = ATTACH_SOLIMP
        spec.add_exclude(bodyname1=body_name, bodyname2=self.body_name(index))

    def _resolve(self, model: mujoco.MjModel) -> object:
        ids = []
        for i in range(self.config.segments):
            bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, self.body_name(i))
            if bid < 0:
                raise ValueError(f"no body named {self.body_name(i)!r} in the model")
            ids.append(bid)
        return np.array(ids)

    def _points(self, xpos, xmat, flexvert_xpos, ids: object) -> np.ndarray:
        ids = np.asarray(ids)
        last = ids[-1]
        tip = xpos[:, last] + xmat[:, last, 0::3] * self.config.segment_length  # along body x
        return np.concatenate([xpos[:, ids], tip[:, None]], axis=1)

    def _touch_criteria(self, spec, geom: str) -> list[tuple[float, mujoco.mjtObj, str]]:
        # The capsules are a chain of bodies under the first: its subtree (no plug, no clamp).
        return [(1.0, mujoco.mjtObj.mjOBJ_XBODY, self.body_name(0))]

    # -- set_centerline ------------------------------------------------------------------------
    def _shape_nodes(self) -> tuple[int, float]:
        return self.config.segments, self.config.segment_length

    def _shape_ids(self, model: mujoco.MjModel) -> dict[str, np.ndarray]:
        bodies = np.asarray(self._resolve(model))
        joints = []
        for i, body in enumerate(bodies):
            name = f"{self.name}_root" if i == 0 else f"{self.name}_j{i}"
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if jid < 0 or model.jnt_bodyid[jid] != body:
                raise ValueError(f"no joint named {name!r} on {self.body_name(i)!r}")
            joints.append(jid)
        return {"bodies": bodies, "joints": np.asarray(joints)}

    def _set_shape(self, model, data, ids, nodes, frames, roll) -> None:
        # Capsule i runs from node i to node i + 1 along its body's +x (nodes are one segment
        # apart), so its body frame is chord frame i.  Ball joint i holds the rotation of body i
        # relative to body i - 1 (whose child frame is offset by (seg, 0, 0), identity quat).
        balls = [
            shape.quat_mul(shape.quat_conj(frames[i - 1]), frames[i]) for i in range(1, len(frames))
        ]
        for i, quat in enumerate(balls, start=1):
            angle = shape.quat_angle(quat)
            if angle > JOINT_LIMIT + 1e-9:
                raise ValueError(
                    f"wire {self.name!r}: the shape bends joint {i} by {angle:.3f} rad, over the "
                    f"joint limit {JOINT_LIMIT} rad"
                )
        joints = ids["joints"]
        root = model.jnt_qposadr[joints[0]]
        data.qpos[root : root + 3] = nodes[0]
        data.qpos[root + 3 : root + 7] = frames[0] / norm(frames[0])
        for jid, quat in zip(joints[1:], balls, strict=True):
            adr = model.jnt_qposadr[jid]
            data.qpos[adr : adr + 4] = quat / norm(quat)
