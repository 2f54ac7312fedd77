"""Touchdown of the sagittal five-link biped: the perfectly inelastic impact of the swing foot, solved
on the floating-base model (MJX) or in the pinned chain's coordinates extended by the root's translation
(closed form), followed by relabelling legs 1 and 2: the next step's start state.

Coordinates as :mod:`biped_jax.dynamics.hybrid_step`: pinned q (5,), floating q = (x, z, pitch, hip1,
knee1, hip2, knee2) (7,). Every function is pure, differentiable and batchable.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from biped_jax.dynamics import planar_chain
from biped_jax.dynamics.hybrid_step import PlanarBiped, check_shape, mass_matrix, site_position
from biped_jax.robots.planar_biped import FLOATING_TO_PINNED, N_PINNED, RELABEL


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
    q = check_shape("q", q, (N_PINNED,))
    qd = check_shape("qd", qd, (N_PINNED,))

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
    q = check_shape("q", q, (N_PINNED,))
    qd = check_shape("qd", qd, (N_PINNED,))
    qf, qfd_before = pinned_to_floating(biped.pinned, q, qd)
    qfd_after, impulse = impact_map(biped.floating, qf, qfd_before)
    old_foot_velocity = foot_jacobian(biped.floating, qf, "foot1") @ qfd_after
    q_next, qd_next = floating_to_pinned(*relabel(qf, qfd_after))
    return Touchdown(q=q_next, qd=qd_next, impulse=impulse,
                     old_stance_foot_velocity=old_foot_velocity, floating_qd_before=qfd_before,
                     floating_qd_after=qfd_after, floating_q=qf)
