"""The hybrid walking step of the sagittal five-link biped in MJX.

Single support is a forward simulation of the pinned-stance chain with ``mjx.step`` (the stance foot is
the world-fixed ``stance`` hinge, so it neither slips nor penetrates); touchdown is the perfectly
inelastic impact map of the floating-base model, followed by relabelling legs 1 and 2. Both models are
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
from biped_jax.dynamics import planar_chain
from biped_jax.robots import registry as robots
from biped_jax.robots.design import (
    PLANAR_ACTUATED,
    PLANAR_LINKS,
    Design,
    DesignLayout,
    apply_design,
    check_design,
    design_layout,
    nominal_design,
)

from biped_jax.robots.planar_biped import (  # noqa: F401 (the index maps, also read as hybrid_step's)
    ACTUATED,
    FLOATING_TO_PINNED,
    N_ACTUATED,
    N_FLOATING,
    N_PINNED,
    PINNED_COORDINATES,
    RELABEL,
    STANCE_BODY,
)

mjx = robots.import_mjx()



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


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class StanceTrajectory:
    """A single-support rollout of T steps.

    Attributes:
      q: pinned coordinates, shape (T + 1, 5), rad.
      qd: their rates, shape (T + 1, 5), rad/s.
      qdd: accelerations at steps 0..T-1, shape (T, 5), rad/s^2.
      u: joint torques applied at steps 0..T-1, shape (T, 4), N m.
      ground_force: stance-foot ground reaction (F_x, F_z) at steps 0..T-1, shape (T, 2), N.
    """

    q: jax.Array
    qd: jax.Array
    qdd: jax.Array
    u: jax.Array
    ground_force: jax.Array


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Touchdown:
    """The impact at touchdown and the relabelled start of the next step.

    Attributes:
      q: pinned coordinates after impact and relabelling, shape (5,), rad.
      qd: their rates, shape (5,), rad/s.
      impulse: ground impulse on the landing foot (x, z), shape (2,), N s.
      old_stance_foot_velocity: (x, z) velocity of the foot that leaves the ground, shape (2,), m/s.
      floating_qd_before, floating_qd_after: floating-base velocities across the impact, shape (7,).
      floating_q: floating-base configuration at impact (before relabelling), shape (7,).
    """

    q: jax.Array
    qd: jax.Array
    impulse: jax.Array
    old_stance_foot_velocity: jax.Array
    floating_qd_before: jax.Array
    floating_qd_after: jax.Array
    floating_q: jax.Array


# ----------------------------------------------------------------------------- models and designs

def _check_mass_class(mass_class: str) -> None:
    if mass_class not in robots.PLANAR_MASS_CLASSES:
        raise ValueError(f"unknown mass class {mass_class!r}; known: {robots.PLANAR_MASS_CLASSES}")


def load_planar_biped(mass_class: str = "12kg") -> PlanarBiped:
    """Loads the pinned and floating MJX models of the 12 kg or 18 kg biped (paper Table 2)."""
    _check_mass_class(mass_class)
    return PlanarBiped(pinned=robots.load_mjx_model(f"biped5_pinned_{mass_class}"),
                       floating=robots.load_mjx_model(f"biped5_floating_{mass_class}"))


@functools.lru_cache(maxsize=None)
def planar_layouts() -> tuple[DesignLayout, DesignLayout]:
    """Design layouts (links torso, thigh1, shank1, thigh2, shank2; joints hip1, knee1, hip2, knee2) in
    the pinned and the floating model. Identical for both mass classes."""
    return tuple(design_layout(robots.load_mj_model(f"biped5_{variant}_12kg"), PLANAR_LINKS,
                               PLANAR_ACTUATED) for variant in ("pinned", "floating"))


def planar_design(mass_class: str = "12kg") -> Design:
    """The design stored in the MJCF file of a mass class."""
    _check_mass_class(mass_class)
    return nominal_design(robots.load_mj_model(f"biped5_pinned_{mass_class}"), planar_layouts()[0])


def with_design(biped: PlanarBiped, design: Design) -> PlanarBiped:
    """Both models of ``biped`` carrying ``design`` (traceable; vmap over designs). A concrete design
    is checked first (:func:`~biped_jax.robots.design.check_design`: ValueError naming a non-positive or
    non-finite mass, a negative armature or damping, a wrong shape)."""
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

def _check_shape(name: str, value, shape: tuple) -> jax.Array:
    value = jnp.asarray(value)
    if value.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {value.shape}")
    return value


def _positions(model, q):
    q = _check_shape("q", q, (model.nq,))
    data = mjx.make_data(model).replace(qpos=q)
    return mjx.kinematics(model, data)


def site_position(model, q: jax.Array, site: str) -> jax.Array:
    """World position of a named site, shape (3,), m, at configuration ``q``, shape (nq,)."""
    site_id = mjx.name2id(model, robots.mujoco.mjtObj.mjOBJ_SITE, site)
    if site_id < 0:
        raise ValueError(f"model has no site {site!r}")
    return _positions(model, q).site_xpos[site_id]


def site_velocity(model, q: jax.Array, qd: jax.Array, site: str) -> tuple[jax.Array, jax.Array]:
    """(position (3,) m, velocity (3,) m/s) of a named site."""
    # qd is the tangent of q here (the same shape: equal to the rates where nq == nv, as in the planar chain)
    q, qd = _check_shape("q", q, (model.nq,)), _check_shape("qd", qd, (model.nq,))
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


def generalized_gravity(model, q: jax.Array) -> jax.Array:
    """Generalised gravity forces G(q) (the bias force at rest), shape (nv,), N m or N."""
    data = mjx.make_data(model).replace(qpos=q)
    return mjx.fwd_velocity(model, mjx.fwd_position(model, data)).qfrc_bias


# ----------------------------------------------------------------------------- single support

def stance_rollout(pinned, q0: jax.Array, qd0: jax.Array, controls: jax.Array) -> StanceTrajectory:
    """Simulates single support with ``mjx.step`` under zero-order-hold torques.

    Args:
      pinned: ``mjx.Model`` of the pinned chain; its ``opt.timestep`` is the step (s).
      q0: initial pinned coordinates, shape (5,), rad.
      qd0: initial rates, shape (5,), rad/s.
      controls: torques (H1, K1, H2, K2) for each step, shape (T, 4), N m.

    Returns:
      The trajectory; step k applies ``controls[k]`` from state k.
    """
    q0 = _check_shape("q0", q0, (N_PINNED,))
    qd0 = _check_shape("qd0", qd0, (N_PINNED,))
    controls = jnp.asarray(controls)
    if controls.ndim != 2 or controls.shape[1] != N_ACTUATED:
        raise ValueError(f"controls must have shape (T, {N_ACTUATED}), got {controls.shape}")

    @jax.checkpoint  # store (q, qd) per step for the backward pass, not the whole mjx.Data
    def step(state, u):
        state, (qdd, force) = stance_step(pinned, state, u)
        return state, (*state, qdd, force)

    _, (q, qd, qdd, force) = jax.lax.scan(step, (q0, qd0), controls)
    return StanceTrajectory(q=jnp.concatenate([q0[None], q]), qd=jnp.concatenate([qd0[None], qd]),
                            qdd=qdd, u=controls, ground_force=force)


def stance_step(pinned, state: tuple[jax.Array, jax.Array], u: jax.Array):
    """One step of single support in MJX under torques u (H1, K1, H2, K2) (N m), with the model's own
    integrator and ``opt.timestep``: ``state`` = (q, qd), shapes (5,), rad and rad/s. Returns (the next
    state, (qdd (5,) rad/s^2, the ground force (F_x, F_z) N)), both from the step's one forward pass, as
    ``mjx.step`` would; traceable, for ``lax.scan`` (:func:`stance_rollout`, the heuristic step's
    controller in the loop; :class:`biped_jax.dynamics.stance.MjxDynamics`)."""
    q, qd = state
    data = mjx.forward(pinned, mjx.make_data(pinned).replace(qpos=q, qvel=qd, ctrl=u))
    force = stance_force(pinned, data)
    data = _INTEGRATORS[int(pinned.opt.integrator)](pinned, data)
    return (data.qpos, data.qvel), (data.qacc, force)


# mjx.step's integrator dispatch, split so the ground force comes from the same forward pass.
_INTEGRATORS = {int(mjx.IntegratorType.EULER): mjx.euler,
                int(mjx.IntegratorType.RK4): mjx.rungekutta4,
                int(mjx.IntegratorType.IMPLICITFAST): mjx.implicit}


def stance_force(pinned, data) -> jax.Array:
    """(F_x, F_z) the world exerts on the stance shank through the pin, N, from MJX's
    Newton-Euler pass (``rne_postconstraint``: body accelerations with gravity, interaction forces)."""
    data = mjx.rne_postconstraint(pinned, data)
    return data._impl.cfrc_int[STANCE_BODY, jnp.array([3, 5])]


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
    data = mjx.make_data(pinned).replace(qpos=q, qvel=qd)
    data = mjx.fwd_velocity(pinned, mjx.fwd_position(pinned, data))
    return stance_force(pinned, data.replace(qacc=qdd))


# ----------------------------------------------------------------------------- touchdown

def pinned_to_floating(pinned, q: jax.Array, qd: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Floating-base state (shape (7,) each) of a single-support state, stance foot at the origin."""
    return jax.jvp(lambda q_: _floating_coordinates(site_position(pinned, q_, "hip")[jnp.array([0, 2])], q_),
                   (q,), (qd,))


def _floating_coordinates(hip: jax.Array, q: jax.Array) -> jax.Array:
    """Floating-base coordinates (7,) from the hip's world (x, z) and the pinned angles q (5,)."""
    stance, knee1, hip1, hip2, knee2 = q
    return jnp.stack([hip[0], hip[1], stance - knee1 - hip1, hip1, knee1, hip2, knee2])


def floating_to_pinned(qf: jax.Array, qfd: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Pinned coordinates (shape (5,) each) of a floating state whose leg 1 is on the ground."""
    transform = jnp.asarray(FLOATING_TO_PINNED, qf.dtype)
    return transform @ qf, transform @ qfd


def relabel(qf: jax.Array, qfd: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Swaps legs 1 and 2 of a floating-base state."""
    return qf[RELABEL], qfd[RELABEL]


def foot_jacobian(floating, qf: jax.Array, foot: str) -> jax.Array:
    """d(foot x, z)/dq of the floating model, shape (2, 7)."""
    return jax.jacfwd(lambda q_: site_position(floating, q_, foot)[jnp.array([0, 2])])(qf)


def impact_map(floating, qf: jax.Array, qfd_before: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Perfectly inelastic impact of foot 2 with the ground.

    Solves M (qd+ - qd-) = J2^T Lambda with J2 qd+ = 0 (the landing foot at rest afterwards).

    Returns:
      (qd+ shape (7,), Lambda = ground impulse on foot 2 (x, z), shape (2,), N s).
    """
    return inelastic_impact(mass_matrix(floating, qf), foot_jacobian(floating, qf, "foot2"), qfd_before)


def chain_touchdown(chain: planar_chain.PlanarChain, pinned, q: jax.Array, qd: jax.Array) -> Touchdown:
    """:func:`touchdown` by the closed-form planar chain of the pinned model (no MJX).

    The floating model's impact in other coordinates: the pinned chain's angles extended by the
    translation (x, z) of its root, so every point moves as r = p + r_pinned(q) and the inertia is
    [[m I, sum_i m_i Jc_i], [sum_i m_i Jc_i^T, M_pinned]] (armature included); the same mechanics, so
    the same impulse and velocities to rounding (``tests/test_planar_chain.py``). Why: MJX's impact
    map on the floating model was two thirds of the gait rollout's compile time (measured 2026-12-02
    in 48 knot spans: 18.5 s of 27 s alone). ``chain`` is the structure of ``pinned``
    (:class:`~biped_jax.dynamics.planar_chain.PlanarChain`); q, qd as :func:`touchdown`."""
    q = _check_shape("q", q, (N_PINNED,))
    qd = _check_shape("qd", qd, (N_PINNED,))

    def to_floating(q_):  # as pinned_to_floating
        return _floating_coordinates(planar_chain.site_motion(chain, pinned, q_, jnp.zeros_like(q_), "hip")[0], q_)

    qf, qfd_before = jax.jvp(to_floating, (q,), (qd,))
    state = planar_chain.kinematics(chain, pinned, q, qd)
    mass = pinned.body_mass[1:]
    momentum = jnp.einsum("i,iaj->aj", mass, state.com_jacobian)  # (2, 5): linear momentum per rate
    inertia = jnp.block([[jnp.sum(mass) * jnp.eye(2, dtype=q.dtype), momentum],
                         [momentum.T, planar_chain.mass_matrix(chain, pinned, state)]])
    landing = jnp.concatenate([jnp.eye(2, dtype=q.dtype), planar_chain.site_jacobian(chain, pinned, q, "foot2")], 1)
    after, impulse = inelastic_impact(inertia, landing, jnp.concatenate([jnp.zeros(2, q.dtype), qd]))
    root_velocity, rates = after[:2], after[2:]
    qfd_after = jax.jvp(to_floating, (q,), (rates,))[1] + jnp.concatenate([root_velocity, jnp.zeros(5, q.dtype)])
    old_foot_velocity = root_velocity + planar_chain.site_jacobian(chain, pinned, q, "foot1") @ rates
    q_next, qd_next = floating_to_pinned(*relabel(qf, qfd_after))
    return Touchdown(q=q_next, qd=qd_next, impulse=impulse, old_stance_foot_velocity=old_foot_velocity,
                     floating_qd_before=qfd_before, floating_qd_after=qfd_after, floating_q=qf)


def inelastic_impact(mass, jac, qd_before, xp=jnp):
    """Velocity after, and impulse of, a perfectly inelastic impact that stops a point.

    Solves the KKT system M (qd+ - qd-) = J^T Lambda, J qd+ = 0. mass (n, n), jac (k, n) (the point's
    rows, e.g. (x, z)), qd_before (n,); ``xp`` is ``jax.numpy`` or ``numpy``. Returns (qd+ (n,),
    Lambda (k,)).
    """
    n, k = mass.shape[0], jac.shape[0]
    kkt = xp.block([[mass, -jac.T], [jac, xp.zeros((k, k), mass.dtype)]])
    solution = xp.linalg.solve(kkt, xp.concatenate([mass @ qd_before, xp.zeros(k, mass.dtype)]))
    return solution[:n], solution[n:]


def touchdown(biped: PlanarBiped, q: jax.Array, qd: jax.Array) -> Touchdown:
    """Impact of the swing foot and relabelling: the start state of the next step.

    Args:
      biped: the design's models.
      q, qd: single-support state just before impact, shape (5,) each.
    """
    q = _check_shape("q", q, (N_PINNED,))
    qd = _check_shape("qd", qd, (N_PINNED,))
    qf, qfd_before = pinned_to_floating(biped.pinned, q, qd)
    qfd_after, impulse = impact_map(biped.floating, qf, qfd_before)
    old_foot_velocity = foot_jacobian(biped.floating, qf, "foot1") @ qfd_after
    q_next, qd_next = floating_to_pinned(*relabel(qf, qfd_after))
    return Touchdown(q=q_next, qd=qd_next, impulse=impulse,
                     old_stance_foot_velocity=old_foot_velocity, floating_qd_before=qfd_before,
                     floating_qd_after=qfd_after, floating_q=qf)
