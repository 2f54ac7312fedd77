"""The optimal sagittal step as the humanoid's reference: sampled on a fixed phase grid (one compiled
replay serves every gait), the swing foot lifted to a clearance profile."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax.dynamics import interface, mjx_biped
from biped_jax.gait import problem as gait_problem

#: Samples of the reference over the step's phase: fixed, so every gait shares one program.
PHASE_SAMPLES = 201
#: Extra height of the swing foot's path, m, largest mid-step and fading linearly to zero over the first
#: and the last :data:`CLEARANCE_RAMP` of the step. The optimal step sweeps the foot forward at about
#: 2 mm over the ground just before touchdown (its clearance constraint is active there); under contact,
#: millimetres of tracking error would scuff it and land it early.
SWING_CLEARANCE = 0.01
CLEARANCE_RAMP = 0.1
CLEARANCE_DAMPING = 0.03  # m/rad


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class GaitReference:
    """The optimal step sampled on a fixed phase grid (arrays; shapes independent of the gait's settings).

    Attributes:
      phase: s in [0, 1], shape (S,).
      stance_angle: theta(s) of the optimal step, strictly increasing, shape (S,), rad.
      stance_angle_slope: d theta / d s, shape (S,), rad.
      joints: (H1, K1, H2, K2)(s), leg 1 standing, shape (S, 4), rad.
      joint_slope: d joints / d s, shape (S, 4), rad.
      torque: the optimiser's torques (H1, K1, H2, K2), shape (S, 4), N m.
      step_time: t_f, s. speed: the gait's average speed, m/s.
    """

    phase: jax.Array
    stance_angle: jax.Array
    stance_angle_slope: jax.Array
    joints: jax.Array
    joint_slope: jax.Array
    torque: jax.Array
    step_time: jax.Array
    speed: jax.Array


#: Largest backward travel of the stance angle (a fraction of its range over the step) that the
#: replay's phase clock absorbs, and only at the step's end (see :func:`gait_reference`).
PHASE_REVERSAL = 0.01


def _reversal_at_end(theta: np.ndarray) -> bool:
    """Whether theta increases strictly up to its maximum and only falls after it."""
    top = int(np.argmax(theta))
    return bool(np.all(np.diff(theta[:top + 1]) > 0) and np.all(np.diff(theta[top:]) <= 0))


def gait_reference(x, model: gait_problem.GaitModel, settings: gait_problem.GaitSettings,
                   trajectory: gait_problem.GaitTrajectory, mass_class: str = "12kg") -> GaitReference:
    """The reference of a solved step (decision vector ``x``, its ``trajectory``, solved for the planar
    biped of ``mass_class``); raises ValueError if the stance angle does not advance monotonically
    (then it cannot phase the gait), except for a backward travel of at most :data:`PHASE_REVERSAL` of
    its range after its maximum (the phase clock is then flat there)."""
    x = np.asarray(x)
    phase = np.linspace(0.0, 1.0, PHASE_SAMPLES)
    joints = np.asarray(gait_problem.reference(jnp.asarray(x), settings, phase)[0])
    step_time = float(model.step_length / model.speed)
    grid = np.asarray(trajectory.t) / step_time
    theta = np.asarray(trajectory.q)[:, 0]
    # The optimal gaits of 48 knot spans let the stance leg swing back by about 1e-4 rad in the last
    # grid points before touchdown (rate down to -0.7 rad/s over 0.5 % of the step): the phase clock
    # is the running maximum there, flat over that sliver. A larger reversal cannot phase the replay.
    envelope = np.maximum.accumulate(theta)
    small_reversal_at_end = _reversal_at_end(theta) and \
        envelope[-1] - theta[-1] <= PHASE_REVERSAL * (envelope[-1] - theta[0])
    if np.any(np.diff(theta) <= 0) and not small_reversal_at_end:
        raise ValueError(f"the stance angle of this gait does not increase monotonically "
                         f"(from {theta[0]:.3f} to {theta[-1]:.3f} rad): it cannot phase the replay")
    theta = envelope
    rate = np.asarray(trajectory.qd)[:, 0] * step_time
    joints = joints + clearance_offset(model, np.asarray(trajectory.q), grid, phase, mass_class)
    joint_slope = np.gradient(joints, phase, axis=0)
    # the gait's torques are samples of a continuous trajectory at its grid points: interpolate them
    u = np.asarray(trajectory.u)
    torque = np.column_stack([np.interp(phase, grid, u[:, k]) for k in range(u.shape[1])])
    return GaitReference(phase=jnp.asarray(phase), stance_angle=jnp.asarray(np.interp(phase, grid, theta)),
                         stance_angle_slope=jnp.asarray(np.interp(phase, grid, rate)),
                         joints=jnp.asarray(joints), joint_slope=jnp.asarray(joint_slope),
                         torque=jnp.asarray(torque), step_time=jnp.asarray(step_time),
                         speed=jnp.asarray(float(model.speed)))


@jax.jit
def _swing_foot(dynamics, states):
    """The swing foot's (x, z), (S, 2) m, and their Jacobian with respect to the pinned coordinates,
    (S, 2, 5), at ``states`` (S, 5), by the planar chain's closed forms (``dynamics``, equal to MJX's
    kinematics: tests/test_planar_chain.py), one program for every design: MJX's kinematics under
    ``jacfwd`` took some 20 s a call on a 2-core CPU, op by op or compiled."""
    def foot(q):
        at = dynamics.swing_foot(q, jnp.zeros_like(q))[0]
        return at, at
    return jax.vmap(jax.jacfwd(foot, has_aux=True))(states)  # (the Jacobian, the position) in one pass


def clearance_offset(model: gait_problem.GaitModel, q: np.ndarray, grid: np.ndarray, phase: np.ndarray,
                     mass_class: str = "12kg", clearance: float = SWING_CLEARANCE) -> np.ndarray:
    """Offsets of (H1, K1, H2, K2), shape (S, 4), rad, that lift the swing foot to at least the clearance
    profile (``clearance`` m mid-step, ramps of :data:`CLEARANCE_RAMP`) where the optimal step (its states
    ``q`` (T + 1, 5) at phases ``grid``) runs lower, without moving it forward: a damped least-squares step
    (:data:`CLEARANCE_DAMPING`) on the swing foot's (x, z) Jacobian with respect to (hip2, knee2), which is
    singular with a straight swing leg. The geometry is that of ``mass_class``'s planar biped; the masses are
    the gait's design."""
    biped = mjx_biped.with_design(mjx_biped.load_planar_biped(mass_class), model.design)
    states = jnp.asarray(np.column_stack([np.interp(phase, grid, q[:, k]) for k in range(q.shape[1])]))
    jacobians, at = (np.asarray(a) for a in _swing_foot(interface.stance_dynamics(biped, "chain"), states))
    jacobians, height = jacobians[:, :, 3:5], at[:, 1]
    profile = clearance * np.minimum(1.0, np.minimum(phase, 1.0 - phase) / CLEARANCE_RAMP)
    lift = np.column_stack([np.zeros_like(phase), np.maximum(profile - height, 0.0)])
    normal = jacobians @ np.swapaxes(jacobians, 1, 2) + CLEARANCE_DAMPING**2 * np.eye(2)
    swing = np.einsum("sji,sj->si", jacobians, np.linalg.solve(normal, lift[..., None])[..., 0])
    return np.column_stack([np.zeros((len(phase), 2)), swing])
