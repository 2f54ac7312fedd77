"""The rollout of one step: the stance angle's zero dynamics by Runge-Kutta under the prescribed
joints (a backend of :mod:`biped_jax.dynamics.interface`), torques, forces, the touchdown."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax.dynamics import mjx_biped
from biped_jax.dynamics.interface import stance_dynamics, touchdown
from biped_jax.gait.settings import GaitModel, GaitSettings, GaitTrajectory
from biped_jax.gait.splines import grid, reference, simpson_weights, stance_nodes
from biped_jax.robots.planar_biped import ACTUATED_INDEX, pinned_coordinates



# ----------------------------------------------------------------------------- dynamics

def zero_dynamics_acceleration(mass, bias, actuated_acceleration):
    """The zero dynamics: theta_dd from the unactuated row of M qdd + bias = B u. mass (5, 5), bias =
    qfrc_bias - qfrc_passive (5,), actuated_acceleration (4,) in (H1, K1, H2, K2) order."""
    a = ACTUATED_INDEX
    return -(mass[0, a] @ actuated_acceleration + bias[0]) / mass[0, 0]


def actuated_torque(mass, bias, qdd):
    """Torques (H1, K1, H2, K2) from the actuated rows of M qdd + bias = B u, (4,), N m."""
    a = ACTUATED_INDEX
    return mass[a] @ qdd + bias[a]




def rk4(dynamics, state, inputs):
    """One Runge-Kutta step of the stance angle's zero dynamics: state (theta, rate), inputs (reference
    (3, 4) at the step's start, middle and end, and the step dt in s); returns the next state twice
    (carry and output (2,) of a scan)."""
    start, middle, end, dt = inputs

    def acceleration(theta, theta_dot, ref):
        q, qd = pinned_coordinates(theta, ref[0], jnp), pinned_coordinates(theta_dot, ref[1], jnp)
        mass, bias, _ = dynamics.terms(q, qd)
        return zero_dynamics_acceleration(mass, bias, ref[2])

    theta, rate = state
    k1 = (rate, acceleration(theta, rate, start))
    k2 = (rate + 0.5 * dt * k1[1], acceleration(theta + 0.5 * dt * k1[0], rate + 0.5 * dt * k1[1], middle))
    k3 = (rate + 0.5 * dt * k2[1], acceleration(theta + 0.5 * dt * k2[0], rate + 0.5 * dt * k2[1], middle))
    k4 = (rate + dt * k3[1], acceleration(theta + dt * k3[0], rate + dt * k3[1], end))
    theta_next = theta + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
    rate_next = rate + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    return (theta_next, rate_next), jnp.stack([theta_next, rate_next])


def shoot(dynamics, node, starts, middles, ends, dt):
    """The stance state after every step of one shooting segment, (steps, 2), from ``node`` (2,) with
    the reference (steps, 3, 4) at the steps' starts, middles and ends and the steps dt (steps,), s."""
    return jax.lax.scan(lambda state, inputs: rk4(dynamics, state, inputs), (node[0], node[1]),
                        (starts, middles, ends, dt))[1]


def sample_outputs(dynamics, theta, rate, ref):
    """The pinned state, accelerations, torques, ground force and points of interest at one sample from
    the stance state and the reference (3, 4)."""
    q, qd = pinned_coordinates(theta, ref[0], jnp), pinned_coordinates(rate, ref[1], jnp)
    mass, bias, state = dynamics.terms(q, qd)
    qdd = pinned_coordinates(zero_dynamics_acceleration(mass, bias, ref[2]), ref[2], jnp)
    force, positions = dynamics.outputs(q, qd, qdd, state)
    return q, qd, qdd, actuated_torque(mass, bias, qdd), force, positions


def time_scale(step_time):
    """Factors from derivatives in normalised time to time derivatives, shaped to scale (3, ..., 4)."""
    return jnp.stack([1.0, 1.0 / step_time, 1.0 / step_time**2])[:, None, None]


def simulate(x: jax.Array, model: GaitModel, biped: mjx_biped.PlanarBiped, settings: GaitSettings) -> GaitTrajectory:
    """One rollout of the step (pure; vmap over x and model): the prescribed joints, the stance
    angle's zero dynamics by RK4 from every shooting node over its segment (all segments at once),
    the outputs at every grid point (a segment's first point takes its node's state)."""
    biped = mjx_biped.with_design(biped, model.design)
    dynamics = stance_dynamics(biped, settings.dynamics)
    step_time = model.step_length / model.speed
    segments, per_segment = settings.segments, settings.steps // settings.segments
    s = grid(settings)
    midpoints = 0.5 * (s[1:] + s[:-1])
    scale = time_scale(step_time)
    at_grid = jnp.stack(reference(x, settings, s)) * scale          # (3, T + 1, 4): q_a, qd_a, qdd_a
    at_mid = jnp.stack(reference(x, settings, midpoints)) * scale   # (3, T, 4)
    h = jnp.asarray(np.diff(s)) * step_time

    def by_segment(a):  # (3, T, 4) -> (segments, T / segments, 3, 4)
        return jnp.swapaxes(a, 0, 1).reshape(segments, per_segment, 3, 4)

    nodes = stance_nodes(x, settings)
    after = jax.vmap(lambda *a: shoot(dynamics, *a))(
        nodes, by_segment(at_grid[:, :-1]), by_segment(at_mid), by_segment(at_grid[:, 1:]),
        h.reshape(segments, per_segment))                                 # (segments, T / segments, 2)
    stance = jnp.concatenate([jnp.concatenate([nodes[:, None], after[:, :-1]], axis=1).reshape(-1, 2),
                              after[-1, -1:]])                            # (T + 1, 2)
    q, qd, qdd, u, force, positions = jax.vmap(lambda *a: sample_outputs(dynamics, *a))(
        stance[:, 0], stance[:, 1], jnp.swapaxes(at_grid, 0, 1))
    _, foot_velocity = dynamics.swing_foot(q[-1], qd[-1])
    return GaitTrajectory(
        t=jnp.asarray(s) * step_time, weights=jnp.asarray(simpson_weights(settings)) * step_time,
        q=q, qd=qd, qdd=qdd, u=u, ground_force=force, swing_foot=positions[:, 0], heights=positions[:, 1:, 1],
        touchdown=touchdown(dynamics, q[-1], qd[-1]), swing_foot_velocity=foot_velocity,
        continuity=after[:-1, -1] - nodes[1:])
