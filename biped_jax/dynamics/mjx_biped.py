"""The sagittal five-link biped in MJX: its two models (pinned single-support chain, floating base),
designs as arrays, kinematics, and the MJX backend of the walking step (:class:`MjxDynamics`, behind
:mod:`biped_jax.dynamics.interface`).

Single support is a forward simulation of the pinned-stance chain with MJX's pipeline (the stance foot is
the world-fixed ``stance`` hinge, so it neither slips nor penetrates); touchdown is the perfectly
inelastic impact of the floating-base model (:mod:`biped_jax.dynamics.impact`). Both models are
generated from one parameter set (``biped_jax.robots.mjcf``). Every function is pure, differentiable with
``jax.grad`` and batchable with ``jax.vmap``; no constraint solver is involved.

Coordinates (see ``biped_jax.robots.mjcf``):
  pinned q = (stance, knee1, hip1, hip2, knee2), rad; stance is the stance shank's absolute pitch
  (0 upright, positive leaning forward), the others are relative joint angles.
  floating q = (x, z, pitch, hip1, knee1, hip2, knee2): hip position (m) and torso pitch (rad).
  torques u = (H1, K1, H2, K2), N m; leg 1 stands, leg 2 swings.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax import checks
from biped_jax.dynamics import impact
from biped_jax.robots import registry
from biped_jax.robots.design import (
    Design,
    DesignLayout,
    apply_design,
    check_design,
    design_layout,
    nominal_design,
)
from biped_jax.robots.planar_biped import GAIT_SITES, PLANAR_ACTUATED, PLANAR_LINKS, STANCE_BODY

mjx = registry.import_mjx()


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class PlanarBiped:
    """The two MJX models of one sagittal biped design (a pytree: batchable over designs).

    Attributes:
      pinned: ``mjx.Model`` of the single-support chain (5 DoF).
      floating: ``mjx.Model`` of the floating-base planar biped (7 DoF).
    """

    pinned: object
    floating: object


# ----------------------------------------------------------------------------- models and designs

def _check_mass_class(mass_class: str) -> None:
    if mass_class not in registry.PLANAR_MASS_CLASSES:
        raise ValueError(f"unknown mass class {mass_class!r}; known: {registry.PLANAR_MASS_CLASSES}")


def load_planar_biped(mass_class: str = "12kg") -> PlanarBiped:
    """Loads the pinned and floating MJX models of the 12 kg or 18 kg biped (paper Table 2)."""
    _check_mass_class(mass_class)
    return PlanarBiped(pinned=registry.load_mjx_model(f"biped5_pinned_{mass_class}"),
                       floating=registry.load_mjx_model(f"biped5_floating_{mass_class}"))


@functools.lru_cache(maxsize=None)
def planar_layouts() -> tuple[DesignLayout, DesignLayout]:
    """Design layouts (links torso, thigh1, shank1, thigh2, shank2; joints hip1, knee1, hip2, knee2) in
    the pinned and the floating model. Identical for both mass classes."""
    return tuple(design_layout(registry.load_mj_model(f"biped5_{variant}_12kg"), PLANAR_LINKS,
                               PLANAR_ACTUATED) for variant in ("pinned", "floating"))


def planar_design(mass_class: str = "12kg") -> Design:
    """The design stored in the MJCF file of a mass class."""
    _check_mass_class(mass_class)
    return nominal_design(registry.load_mj_model(f"biped5_pinned_{mass_class}"), planar_layouts()[0])


def with_design(biped: PlanarBiped, design: Design) -> PlanarBiped:
    """Both models of ``biped`` carrying ``design`` (traceable; vmap over designs). A concrete design
    is checked first (:func:`~biped_jax.robots.design.check_design`: ValueError naming a non-positive or
    non-finite mass, a negative armature or damping, a wrong shape)."""
    if not isinstance(biped, PlanarBiped):
        raise TypeError(f"biped must be a PlanarBiped (load_planar_biped(mass_class)), got {type(biped).__name__}")
    pinned_layout, floating_layout = planar_layouts()
    if checks.concrete(design):
        check_design(design, pinned_layout)
    return PlanarBiped(pinned=apply_design(biped.pinned, pinned_layout, design),
                       floating=apply_design(biped.floating, floating_layout, design))


def with_timestep(model, timestep):
    """``model`` (an ``mjx.Model``) integrating with ``timestep`` s; traceable. A concrete timestep
    must be a finite number > 0 (ValueError naming it)."""
    if checks.concrete(timestep):
        value = np.asarray(timestep)
        if value.shape or not np.isfinite(value) or not value > 0:
            raise ValueError(f"timestep must be a finite number > 0 s, got {timestep!r}")
    return model.replace(opt=model.opt.replace(timestep=jnp.asarray(timestep, model.opt.timestep.dtype)))


# ----------------------------------------------------------------------------- kinematics

def check_shape(name: str, value, shape: tuple, xp=jnp) -> jax.Array:
    """``value`` as an array of ``xp`` (``jax.numpy`` or ``numpy``), or a ValueError naming it and both
    shapes."""
    value = xp.asarray(value)
    if value.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {value.shape}")
    return value


#: MJX's forward pass, compiled (the model an argument: one program per model shape). Op by op, MJX
#: compiles every operation alone.
forward = jax.jit(mjx.forward)


# MJX's kinematics and single-support terms as jitted functions: a gait rollout and the touchdown call
# them at many points (four per Runge-Kutta step, a site at a time), and JAX then traces and transforms
# each one's program once per signature instead of at every call (as the planar chain's, planar_chain.py).
@jax.jit
def _positions(model, q):
    q = check_shape("q", q, (model.nq,))
    data = mjx.make_data(model).replace(qpos=q)
    return mjx.kinematics(model, data)


def site_position(model, q: jax.Array, site: str) -> jax.Array:
    """World position of a named site, shape (3,), m, at configuration ``q``, shape (nq,)."""
    site_id = mjx.name2id(model, registry.mujoco.mjtObj.mjOBJ_SITE, site)
    if site_id < 0:
        raise ValueError(f"model has no site {site!r}")
    return _positions(model, q).site_xpos[site_id]


def site_velocity(model, q: jax.Array, qd: jax.Array, site: str) -> tuple[jax.Array, jax.Array]:
    """(position (3,) m, velocity (3,) m/s) of a named site."""
    # qd is the tangent of q here (the same shape: equal to the rates where nq == nv, as in the planar chain)
    q, qd = check_shape("q", q, (model.nq,)), check_shape("qd", qd, (model.nq,))
    return jax.jvp(lambda q_: site_position(model, q_, site), (q,), (qd,))


def center_of_mass(model, q: jax.Array) -> jax.Array:
    """Whole-body centre of mass, shape (3,), m."""
    data = _positions(model, q)
    return model.body_mass @ data.xipos / jnp.sum(model.body_mass)


def mass_matrix(model, q: jax.Array) -> jax.Array:
    """Joint-space mass matrix M(q), shape (nv, nv)."""
    data = mjx.com_pos(model, _positions(model, q))
    return mjx.full_m(model, mjx.crb(model, data))


def mechanical_energy(model, q: jax.Array, qd: jax.Array) -> jax.Array:
    """Kinetic plus gravitational potential energy, J (scalar)."""
    data = _positions(model, q)
    potential = -jnp.sum(model.body_mass * (data.xipos @ model.opt.gravity))
    return 0.5 * qd @ mass_matrix(model, q) @ qd + potential


@jax.jit  # traced once per signature (see _positions)
def _velocity_pass(model, q, qd):
    """MJX's data after its position and velocity stages at (q, qd): the bias force, the bodies'
    velocities."""
    data = mjx.make_data(model).replace(qpos=q, qvel=qd)
    return mjx.fwd_velocity(model, mjx.fwd_position(model, data))


def generalized_gravity(model, q: jax.Array) -> jax.Array:
    """Generalised gravity forces G(q) (the bias force at rest), shape (nv,), N m or N."""
    return _velocity_pass(model, q, jnp.zeros(model.nv, q.dtype)).qfrc_bias


# ----------------------------------------------------------------------------- single support

# mjx.step's integrator dispatch, split so the ground force comes from the same forward pass.
_INTEGRATORS = {int(mjx.IntegratorType.EULER): mjx.euler,
                int(mjx.IntegratorType.RK4): mjx.rungekutta4,
                int(mjx.IntegratorType.IMPLICITFAST): mjx.implicit}


def stance_force(pinned, data) -> jax.Array:
    """(F_x, F_z) the world exerts on the stance shank through the pin, N, from MJX's
    Newton-Euler pass (``rne_postconstraint``: body accelerations with gravity, interaction forces)."""
    data = mjx.rne_postconstraint(pinned, data)
    return registry.jax_fields(data).cfrc_int[STANCE_BODY, jnp.array([3, 5])]


def stance_acceleration(pinned, q: jax.Array, qd: jax.Array, u: jax.Array) -> jax.Array:
    """Single-support accelerations qdd(q, qd, u), shape (5,), rad/s^2 (MJX forward dynamics)."""
    data = mjx.make_data(pinned).replace(qpos=q, qvel=qd, ctrl=u)
    return mjx.forward(pinned, data).qacc


def swing_foot(pinned, q: jax.Array, qd: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Swing-foot (x, z) position and velocity relative to the stance foot, each shape (2,), m, m/s."""
    position, velocity = site_velocity(pinned, q, qd, "foot2")
    return position[jnp.array([0, 2])], velocity[jnp.array([0, 2])]


def ground_reaction(pinned, q: jax.Array, qd: jax.Array, qdd: jax.Array) -> jax.Array:
    """Stance-foot ground reaction force (F_x, F_z), shape (2,), N, at a state and acceleration.

    The pin is the only contact, so this is the force the world exerts on the stance shank; MJX's
    Newton-Euler pass gives it from (q, qd, qdd).
    """
    return stance_force(pinned, _velocity_pass(pinned, q, qd).replace(qacc=qdd))


# ----------------------------------------------------------------------------- touchdown

def pinned_to_floating(pinned, q: jax.Array, qd: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Floating-base state (shape (7,) each) of a single-support state, stance foot at the origin."""
    return jax.jvp(lambda q_: impact.floating_coordinates(site_position(pinned, q_, "hip")[jnp.array([0, 2])], q_),
                   (q,), (qd,))


def foot_jacobian(floating, qf: jax.Array, foot: str) -> jax.Array:
    """d(foot x, z)/dq of the floating model, shape (2, 7)."""
    return jax.jacfwd(lambda q_: site_position(floating, q_, foot)[jnp.array([0, 2])])(qf)


def impact_map(floating, qf: jax.Array, qfd_before: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Perfectly inelastic impact of foot 2 with the ground on the floating model: (qd+ (7,), the
    ground impulse on foot 2 (x, z) (2,), N s), from M (qd+ - qd-) = J2^T Lambda, J2 qd+ = 0."""
    return impact.inelastic_impact(mass_matrix(floating, qf), foot_jacobian(floating, qf, "foot2"), qfd_before)


# ----------------------------------------------------------------------------- the MJX backend

@jax.jit  # traced once per signature (see _positions)
def _terms(pinned, q, qd):
    """(M (nv, nv), qfrc_bias - qfrc_passive (nv,), the forward pass's data) at (q, qd)."""
    data = _velocity_pass(pinned, q, qd)
    return mjx.full_m(pinned, data), data.qfrc_bias - data.qfrc_passive, data


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class MjxDynamics:
    """The MJX backend of :class:`biped_jax.dynamics.interface.StanceDynamics` (a pytree of one
    design's models: batchable over designs): MJX's forward pipeline for single support, the
    floating-base model's mass matrix and site Jacobians for the touchdown.

    Attributes:
      biped: the design's two models.
      sites: the model's ids of :data:`~biped_jax.robots.planar_biped.GAIT_SITES`, shape (4,).
    """

    biped: PlanarBiped
    sites: jax.Array

    @classmethod
    def of(cls, biped: PlanarBiped) -> "MjxDynamics":
        sites = [mjx.name2id(biped.pinned, registry.mujoco.mjtObj.mjOBJ_SITE, name) for name in GAIT_SITES]
        return cls(biped=biped, sites=jnp.array(sites))

    @property
    def pinned(self):
        return self.biped.pinned

    def terms(self, q, qd):
        return _terms(self.pinned, q, qd)

    def outputs(self, q, qd, qdd, data):
        force = stance_force(self.pinned, data.replace(qacc=qdd))
        return force, data.site_xpos[self.sites][:, jnp.array([0, 2])]

    def swing_foot(self, q, qd):
        return swing_foot(self.pinned, q, qd)

    def step(self, state, u):
        """One step in MJX under torques u (4,), N m, with the model's own integrator and
        ``opt.timestep``: (q, qd) -> ((q, qd) next, (qdd (5,), ground force (F_x, F_z) N)), both from the
        step's one forward pass, as ``mjx.step`` would."""
        q, qd = state
        data = mjx.forward(self.pinned, mjx.make_data(self.pinned).replace(qpos=q, qvel=qd, ctrl=u))
        force = stance_force(self.pinned, data)
        data = _INTEGRATORS[int(self.pinned.opt.integrator)](self.pinned, data)
        return (data.qpos, data.qvel), (data.qacc, force)

    def impact_system(self, q, qd) -> impact.ImpactSystem:
        qf, qfd = pinned_to_floating(self.pinned, q, qd)
        floating = self.biped.floating
        return impact.ImpactSystem(mass=mass_matrix(floating, qf), landing=foot_jacobian(floating, qf, "foot2"),
                                   leaving=foot_jacobian(floating, qf, "foot1"), velocity=qfd, floating_q=qf)
