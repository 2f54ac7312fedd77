"""The walking step's dynamics behind one interface: single support and touchdown of the sagittal biped,
as three backends implement them (as Brax's pipelines share ``init``/``step``).

A backend (:class:`StanceDynamics`) gives, at a single-support state (q, qd) of the pinned chain, the
mass matrix and bias force, the ground force and site positions, the swing foot's motion, one
integration step under joint torques, and the touchdown's impact posed in coordinates of its choice
(:class:`~biped_jax.dynamics.impact.ImpactSystem`). Everything else is written once, here and in
:mod:`biped_jax.dynamics.impact`: :func:`stance_step`, :func:`stance_rollout`, :func:`touchdown`.

Backends, by name (:data:`DYNAMICS`, ``GaitSettings.dynamics``, the command line's ``--dynamics``):

- ``"chain"``: :class:`~biped_jax.dynamics.planar_chain.ChainDynamics`, closed forms of the planar
  chain (JAX; the gait optimiser's default: it compiles in a fraction of MJX's time);
- ``"mjx"``: :class:`~biped_jax.dynamics.mjx_biped.MjxDynamics`, MJX's pipeline (JAX);
- ``"mujoco"``: :class:`~biped_jax.dynamics.mujoco_c.MujocoDynamics`, MuJoCo's C library (numpy; not
  traceable: the independent reference the tests and the gradient benchmark compare with).

The three agree to rounding (``tests/test_dynamics.py`` runs the physics checks against each).
Coordinates as :mod:`biped_jax.dynamics.mjx_biped`: pinned q (5,), torques u = (H1, K1, H2, K2) (4,).
"""

from __future__ import annotations

import dataclasses
from typing import Protocol

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax.dynamics import impact, mjx_biped, planar_chain
from biped_jax.dynamics.mujoco_c import MujocoDynamics
from biped_jax.robots.planar_biped import N_ACTUATED, N_PINNED


class StanceDynamics(Protocol):
    """What a backend implements; (q, qd): the pinned chain's state, shapes (5,), rad and rad/s."""

    pinned: object  # the pinned model (its ``opt.timestep`` is the step of :meth:`step`)

    def terms(self, q, qd):
        """(mass matrix (5, 5), bias force (qfrc_bias - qfrc_passive) (5,), the backend's state of
        (q, qd) for :meth:`outputs`)."""

    def outputs(self, q, qd, qdd, state):
        """(ground force (F_x, F_z) (2,) N, positions (x, z) of the gait sites (4, 2) m) at an
        acceleration qdd (5,)."""

    def swing_foot(self, q, qd):
        """(position (x, z), velocity (x, z)) of the swing foot relative to the stance foot, (2,) each."""

    def step(self, state, u):
        """One step of the model's integrator: (q, qd) -> ((q, qd) next, (qdd (5,), ground force (2,)))."""

    def impact_system(self, q, qd) -> impact.ImpactSystem:
        """The touchdown's impact at (q, qd), in the backend's impact coordinates."""


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class StanceTrajectory:
    """A single-support rollout of T steps (:func:`stance_rollout`).

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


#: The backends by name: each builds the backend of a :class:`~biped_jax.dynamics.mjx_biped.PlanarBiped`.
DYNAMICS = {"chain": lambda biped: planar_chain.ChainDynamics.of(biped.pinned),
            "mjx": mjx_biped.MjxDynamics.of, "mujoco": MujocoDynamics.of}

#: The backends that trace under ``jax.jit`` (the gait optimiser's choices).
TRACEABLE = ("chain", "mjx")


def stance_dynamics(biped: mjx_biped.PlanarBiped, name: str = "chain") -> StanceDynamics:
    """The backend ``name`` (a key of :data:`DYNAMICS`) of ``biped``'s models; ValueError naming another."""
    if name not in DYNAMICS:
        raise ValueError(f"dynamics must be one of {tuple(DYNAMICS)}, got {name!r}")
    return DYNAMICS[name](biped)


def _is_numpy(dynamics) -> bool:
    return getattr(dynamics, "xp", jnp) is np


def stance_step(dynamics: StanceDynamics, state, u):
    """One step of single support under torques u (H1, K1, H2, K2) (N m) with the pinned model's
    ``opt.timestep``: ``state`` = (q, qd), (5,) each. Returns (the next state, (qdd, ground force
    (F_x, F_z) N)); the backend's integrator (MJX's and MuJoCo's own; semi-implicit Euler in the
    chain, equal without damping). Traceable with a JAX backend, e.g. inside a controller's scan."""
    return dynamics.step(state, u)


def stance_rollout(dynamics: StanceDynamics, q0, qd0, controls) -> StanceTrajectory:
    """Simulates single support under zero-order-hold torques.

    Args:
      dynamics: a backend (:func:`stance_dynamics`); its pinned model's ``opt.timestep`` is the step (s).
      q0: initial pinned coordinates, shape (5,), rad.
      qd0: initial rates, shape (5,), rad/s.
      controls: torques (H1, K1, H2, K2) for each step, shape (T, 4), N m.

    Returns:
      The trajectory; step k applies ``controls[k]`` from state k. A JAX backend's is one ``lax.scan``
      (differentiable, batchable; each step's (q, qd) kept for the backward pass, not the backend's
      whole state); MuJoCo C's a Python loop (numpy arrays).
    """
    xp = np if _is_numpy(dynamics) else jnp
    q0 = mjx_biped.check_shape("q0", q0, (N_PINNED,), xp)
    qd0 = mjx_biped.check_shape("qd0", qd0, (N_PINNED,), xp)
    controls = xp.asarray(controls)
    if controls.ndim != 2 or controls.shape[1] != N_ACTUATED:
        raise ValueError(f"controls must have shape (T, {N_ACTUATED}), got {controls.shape}")

    @jax.checkpoint
    def step(state, u):
        state, (qdd, force) = dynamics.step(state, u)
        return state, (*state, qdd, force)

    if xp is np:
        rows, state = [], (q0, qd0)
        for u in controls:
            state, row = dynamics.step(state, u)
            rows.append((*state, *row))
        q, qd, qdd, force = (np.stack(column) for column in zip(*rows))
    else:
        _, (q, qd, qdd, force) = jax.lax.scan(step, (q0, qd0), controls)
    return StanceTrajectory(q=xp.concatenate([q0[None], q]), qd=xp.concatenate([qd0[None], qd]), qdd=qdd,
                            u=controls, ground_force=force)


def touchdown(dynamics: StanceDynamics, q, qd) -> impact.Touchdown:
    """Impact of the swing foot and relabelling: the start state of the next step.

    Args:
      dynamics: a backend (:func:`stance_dynamics`).
      q, qd: single-support state just before impact, shape (5,) each.
    """
    xp = np if _is_numpy(dynamics) else jnp
    q = mjx_biped.check_shape("q", q, (N_PINNED,), xp)
    qd = mjx_biped.check_shape("qd", qd, (N_PINNED,), xp)
    return impact.resolve(dynamics.impact_system(q, qd), xp)
