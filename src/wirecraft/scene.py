"""The one place where parts are merged into a MuJoCo model.

``new_spec`` gives an empty world with WireCraft's solver settings, lighting and a cheap visual
setup; asset builders add to it; ``compile_spec`` turns it into an ``MjModel``.  World frame:
z up, the table top is the plane z = 0.
"""

from __future__ import annotations

import mujoco

from wirecraft import physics

TABLE_HALF = (0.6, 0.8, 0.02)  # m: a 1.2 x 1.6 m top, 4 cm thick, its top face at z = 0
# MuJoCo's off-screen framebuffer (pixels): no rendered image can be larger.
OFFSCREEN_WIDTH, OFFSCREEN_HEIGHT = 1280, 960


def new_spec(name: str = "wirecraft", *, timestep: float = physics.TIMESTEP) -> mujoco.MjSpec:
    spec = mujoco.MjSpec()
    spec.modelname = name
    spec.compiler.degree = False  # SI throughout: MjSpec would otherwise read angles in degrees
    physics.configure_options(spec, timestep=timestep)
    spec.visual.global_.offwidth = OFFSCREEN_WIDTH
    spec.visual.global_.offheight = OFFSCREEN_HEIGHT
    spec.visual.quality.shadowsize = 0
    spec.visual.quality.offsamples = 0
    spec.worldbody.add_light(name="key", pos=(0.3, -0.5, 1.5), dir=(-0.2, 0.4, -1.0))
    spec.worldbody.add_light(name="fill", pos=(-0.6, 0.6, 1.2), dir=(0.5, -0.5, -1.0))
    return spec


def add_table(spec: mujoco.MjSpec, *, half: tuple[float, float, float] = TABLE_HALF):
    """A table whose top face is z = 0 (a box, so that thin wires rest on a convex primitive)."""
    geom = spec.worldbody.add_geom(
        name="table",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=half,
        pos=(0.0, 0.0, -half[2]),
        rgba=(0.55, 0.5, 0.45, 1.0),
    )
    physics.stiff_contact(geom, friction=physics.TABLE_FRICTION)
    return geom


def compile_spec(spec: mujoco.MjSpec) -> mujoco.MjModel:
    """Compile, turning MuJoCo's compiler errors into ValueError with the model name."""
    try:
        return spec.compile()
    except Exception as err:  # mujoco raises a plain ValueError/Exception subclass
        raise ValueError(f"model {spec.modelname!r} failed to compile: {err}") from err
