"""One walking step of the five-link biped under a heuristic PD controller, with touchdown.

A simple reference gait (`biped-jax step`): the actuated joints track a straight-line blend from
the start pose to its mirror image (swing knee lifted mid-step) with PD torques. The blend is indexed
by the stance angle, not by time (a phase variable, as in hybrid-zero-dynamics control), so the swing
foot reaches the ground when the stance leg has rotated through the step, whatever the timing; the
stance angle itself is left to the dynamics. The step ends at the first downward crossing of the
ground by the swing foot after mid-step, where the impact map is applied.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax.dynamics import mjx_biped
from biped_jax.dynamics import planar_chain
from biped_jax.dynamics import interface
from biped_jax.robots.planar_biped import ACTUATED_INDEX


@dataclasses.dataclass(frozen=True)
class HeuristicGait:
    """Settings of the heuristic step (SI units).

    Attributes:
      step_length: m, distance between the feet at start and touchdown.
      speed: m/s, sets the nominal step time step_length / speed and the initial stance rate.
      knee_bend: rad, stance knee flexion held throughout.
      swing_knee_lift: rad, extra swing knee flexion at mid-step.
      stiffness, damping: PD gains, N m/rad and N m s/rad; explicit (Euler) damping of a shank's
        ~0.01 kg m^2 about the knee stays stable for damping * dt / inertia < 2.
      steps: integration steps over 1.5 nominal step times.
    """

    step_length: float = 0.2
    speed: float = 0.555
    knee_bend: float = 0.0
    swing_knee_lift: float = 0.7
    stiffness: float = 100.0
    damping: float = 2.0
    steps: int = 600

    def __post_init__(self):
        for name in ("step_length", "speed", "stiffness", "damping"):
            value = getattr(self, name)
            if not value > 0:
                raise ValueError(f"{name} must be positive, got {value!r}")

    @property
    def step_time(self) -> float:
        return self.step_length / self.speed


def start_state(gait: HeuristicGait, leg_length: float = 0.29):
    """Start pose (shape (5,)), rates (5,) and the mirrored end pose of the actuated joints (4,).

    Args:
      leg_length: hip to foot with the knee straight, m.
    """
    stance = -float(np.arcsin(0.5 * gait.step_length / leg_length))
    hip1, knee1 = stance - gait.knee_bend, gait.knee_bend  # torso upright: pitch = stance - k1 - h1 = 0
    hip2, knee2 = -stance, 0.0
    q0 = jnp.array([stance, knee1, hip1, hip2, knee2])
    # Faster than the mean rate speed / leg_length: the stance leg must vault over the top.
    rate = 1.3 * gait.speed / leg_length
    start = jnp.array([hip1, knee1, hip2, knee2])
    end = jnp.array([hip2 - gait.knee_bend, knee1, hip1 + gait.knee_bend, knee2])
    qd0 = jnp.concatenate([jnp.array([rate]), reference(gait, start, end, q0[0], rate, q0[0])[1]
                           [jnp.array([1, 0, 2, 3])]])
    return q0, qd0, end


def reference(gait: HeuristicGait, start, end, stance, stance_rate, stance_start):
    """Joint reference (H1, K1, H2, K2) and its rate at a stance angle and rate, shape (4,) each."""
    span = -2.0 * stance_start
    phase = jnp.clip((stance - stance_start) / span, 0.0, 1.0)
    moving = ((phase > 0) & (phase < 1)) | (stance == stance_start)
    swing_knee = jnp.array([0, 0, -0.6, 1.0])  # flex the swing hip with the knee: foot clears the ground
    angle = start + phase * (end - start) + gait.swing_knee_lift * jnp.sin(jnp.pi * phase) ** 2 * swing_knee
    d_phase = moving * stance_rate / span
    rate = d_phase * ((end - start) + gait.swing_knee_lift * jnp.pi * jnp.sin(2 * jnp.pi * phase) * swing_knee)
    return angle, rate


def simulate_step(biped: mjx_biped.PlanarBiped, gait: HeuristicGait, chain: planar_chain.PlanarChain | None = None):
    """Runs the step; returns (trajectory, dt, touchdown index or -1, Touchdown at that index, swing
    foot positions and velocities).

    The trajectory covers 1.5 nominal step times so that a late touchdown is still found. With
    ``chain`` (the structure of ``biped.pinned``, :class:`~biped_jax.dynamics.planar_chain.PlanarChain`)
    the closed-form chain steps and lands the robot, else MJX's pipeline: equal to rounding
    (``tests/test_planar_chain.py``), and the chain's program compiles in a fraction of MJX's time.
    """
    q0, qd0, end = start_state(gait)
    dt = 1.5 * gait.step_time / gait.steps
    timed = dataclasses.replace(biped, pinned=mjx_biped.with_timestep(biped.pinned, dt))
    dynamics = mjx_biped.MjxDynamics.of(timed) if chain is None else planar_chain.ChainDynamics.of(timed.pinned, chain)
    actuated = jnp.asarray(ACTUATED_INDEX)  # (H1, K1, H2, K2) in pinned coordinates
    start = q0[actuated]

    def step(state, _):
        q, qd = state
        angle, rate = reference(gait, start, end, q[0], qd[0], q0[0])
        u = gait.stiffness * (angle - q[actuated]) + gait.damping * (rate - qd[actuated])
        state, (qdd, force) = interface.stance_step(dynamics, state, u)
        return state, (*state, qdd, u, force)

    _, (q, qd, qdd, u, force) = jax.lax.scan(step, (q0, qd0), None, length=gait.steps)
    trajectory = interface.StanceTrajectory(q=jnp.concatenate([q0[None], q]),
                                     qd=jnp.concatenate([qd0[None], qd]), qdd=qdd, u=u,
                                     ground_force=force)
    foot, foot_velocity = jax.vmap(dynamics.swing_foot)(trajectory.q, trajectory.qd)
    after_mid_step = jnp.arange(gait.steps + 1) * dt > 0.5 * gait.step_time
    crossing = after_mid_step & (foot[:, 1] <= 0.0) & (foot_velocity[:, 1] < 0.0)
    index = jnp.where(jnp.any(crossing), jnp.argmax(crossing), -1)
    safe = jnp.maximum(index, 0)
    impact = interface.touchdown(dynamics, trajectory.q[safe], trajectory.qd[safe])
    return trajectory, dt, index, impact, foot, foot_velocity
