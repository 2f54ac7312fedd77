"""Touchdown of the sagittal five-link biped, written once for every backend: the perfectly inelastic
impact of the swing foot, then relabelling legs 1 and 2 (the next step's start state).

A backend (:mod:`biped_jax.dynamics.interface`) poses the impact as an :class:`ImpactSystem` in
coordinates of its choice (MJX and MuJoCo C: the floating-base model's; the closed-form chain: the
pinned chain's angles extended by its root's translation): the inertia, the two feet's Jacobians, the
velocity before, and the map of those coordinates' velocities to the floating base's. :func:`resolve`
solves it and relabels. Coordinates: pinned q (5,) as :mod:`biped_jax.dynamics.mjx_biped`, floating
q = (x, z, pitch, hip1, knee1, hip2, knee2) (7,). Every function is pure; with ``xp = jax.numpy``
differentiable and batchable.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from biped_jax.robots.planar_biped import FLOATING_TO_PINNED, RELABEL


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


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ImpactSystem:
    """The impact of the swing foot as a backend poses it, in n impact coordinates of its choice.

    Attributes:
      mass: the inertia in those coordinates, shape (n, n) (armature included).
      landing: d(swing foot x, z)/d(coordinates), shape (2, n).
      leaving: d(stance foot x, z)/d(coordinates), shape (2, n).
      velocity: the coordinates' velocity just before the impact, shape (n,).
      floating_q: the floating-base configuration at impact, shape (7,).
      to_floating: the floating base's rates per coordinate velocity, shape (7, n); None where the
        coordinates are the floating base's (n = 7).
    """

    mass: jax.Array
    landing: jax.Array
    leaving: jax.Array
    velocity: jax.Array
    floating_q: jax.Array
    to_floating: jax.Array | None = None


def floating_coordinates(hip, q, xp=jnp):
    """Floating-base coordinates (7,) from the hip's world (x, z) and the pinned angles q (5,); ``xp``:
    ``jax.numpy`` or ``numpy``. Linear in (hip, q): given the hip's velocity and the rates it gives the
    floating base's rates."""
    stance, knee1, hip1, hip2, knee2 = q
    return xp.stack([hip[0], hip[1], stance - knee1 - hip1, hip1, knee1, hip2, knee2])


def floating_to_pinned(qf, qfd, xp=jnp):
    """Pinned coordinates (shape (5,) each) of a floating state whose leg 1 is on the ground."""
    transform = xp.asarray(FLOATING_TO_PINNED, qf.dtype)
    return transform @ qf, transform @ qfd


def relabel(qf, qfd):
    """Swaps legs 1 and 2 of a floating-base state."""
    return qf[RELABEL], qfd[RELABEL]


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


def resolve(system: ImpactSystem, xp=jnp) -> Touchdown:
    """The touchdown of an impact ``system``: the velocity after and the impulse
    (:func:`inelastic_impact`), the floating base's velocities across the impact, the old stance
    foot's velocity, and the relabelled pinned start of the next step. ``xp``: ``jax.numpy`` or
    ``numpy`` (the MuJoCo C backend)."""
    after, impulse = inelastic_impact(system.mass, system.landing, system.velocity, xp)
    if system.to_floating is None:
        before_floating, after_floating = system.velocity, after
    else:
        before_floating, after_floating = system.to_floating @ system.velocity, system.to_floating @ after
    q_next, qd_next = floating_to_pinned(*relabel(system.floating_q, after_floating), xp=xp)
    return Touchdown(q=q_next, qd=qd_next, impulse=impulse, old_stance_foot_velocity=system.leaving @ after,
                     floating_qd_before=before_floating, floating_qd_after=after_floating,
                     floating_q=system.floating_q)
