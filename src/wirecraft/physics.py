"""Simulation settings shared by every WireCraft model.

Why these values (measured, see docs/physics.md):
- ``discrete`` integrator: the only one MuJoCo 4.0 accepts for flex-rod elasticity.
- Newton solver with elliptic cones: PGS and noslip are rejected with any flex; elliptic cones
  hold a pinched plug, and an impedance ratio of 10 (frictional over normal constraint
  stiffness) stops the slow creep of a held plug under the cable's pull (at 1 it turned ~25 deg
  in the pads during a carry; at 10 about 2 deg).
- Stiff contacts (time constant 2 x timestep, impedance close to 1): MuJoCo's default soft
  contacts let a finger push a light wire through a 5 mm floor.  Geoms and flexes use the same
  values, since mixed values are averaged and soften the contact again.
"""

from __future__ import annotations

import mujoco

TIMESTEP = 0.002  # s
SOLVER_TOLERANCE = 1e-6
SOLVER_ITERATIONS = 100
IMPEDANCE_RATIO = 10.0

CONTACT_SOLREF = (2 * TIMESTEP, 1.0)
CONTACT_SOLIMP = (0.99, 0.999, 0.0005, 0.5, 2.0)

TABLE_FRICTION = 1.0
PLUG_FRICTION = 2.0
PAD_FRICTION = 5.0
PLUG_MASS = 0.01  # kg


def configure_options(spec: mujoco.MjSpec, *, timestep: float = TIMESTEP) -> None:
    """Apply the WireCraft solver settings to a spec."""
    opt = spec.option
    opt.timestep = timestep
    opt.integrator = mujoco.mjtIntegrator.mjINT_DISCRETE
    opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
    opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    opt.tolerance = SOLVER_TOLERANCE
    opt.iterations = SOLVER_ITERATIONS
    opt.impratio = IMPEDANCE_RATIO


def stiff_contact(geom: mujoco.MjsGeom, *, friction: float | None = None) -> mujoco.MjsGeom:
    """Give a geom the shared stiff-contact parameters (and a sliding friction if given)."""
    geom.solref = CONTACT_SOLREF
    geom.solimp = CONTACT_SOLIMP
    if friction is not None:
        geom.friction = (friction, 0.005, 0.0001)
    return geom
