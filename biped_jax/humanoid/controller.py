"""The replay's controller: feed-forward torques of the optimal step plus PD on its joint paths,
phased by the stance leg's angle (hybrid-zero-dynamics phasing); traceable, run inside the replay's scan."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax.humanoid.model import Layout
from biped_jax.humanoid.reference import GaitReference

#: Share of the step over which the reference blends from the robot's joints at touchdown into the
#: optimal path (the contact model's touchdown never lands exactly on the optimal posture).
OFFSET_FADE = 0.2


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Gains:
    """PD gains: sagittal hips and knees (N m/rad, N m s/rad) and the held joints."""

    sagittal_stiffness: float = 300.0
    sagittal_damping: float = 6.0
    held_stiffness: float = 200.0
    held_damping: float = 4.0


DEFAULT_GAINS = Gains()


def _interp(x, xp, fp):
    """np.interp along the first axis of fp (S,) or (S, k)."""
    if fp.ndim == 1:
        return jnp.interp(x, xp, fp)
    return jax.vmap(lambda column: jnp.interp(x, xp, column), in_axes=1, out_axes=-1)(fp)


def sagittal_state(layout: Layout, qpos, qvel, stance):
    """(theta, theta_dot, joints (H1, K1, H2, K2), their rates) with leg ``stance`` (0 = l, 1 = r) as
    leg 1."""
    hip, knee = jnp.array(layout.hip), jnp.array(layout.knee)
    order = jnp.stack([hip[stance], knee[stance], hip[1 - stance], knee[1 - stance]])
    theta = qpos[2] + qpos[order[0]] + qpos[order[1]]
    theta_dot = qvel[2] + qvel[order[0]] + qvel[order[1]]
    return theta, theta_dot, qpos[order], qvel[order], order


def with_gains(model, layout: Layout, gains: Gains):
    """The MJX ``model`` with the PD loops' damping as joint damping (MJX's Euler step integrates it
    implicitly, which keeps stiff loops on light links stable at 1 ms) and the held joints' stiffness as
    joint springs about zero. :func:`control` adds the rest of the law; traceable."""
    sagittal = np.array(layout.hip + layout.knee)
    held = np.setdiff1d(np.array(layout.held_q), sagittal)
    damping = jnp.zeros_like(model.dof_damping).at[sagittal].set(gains.sagittal_damping).at[held].set(
        gains.held_damping)
    joints = np.array([i for i in range(model.njnt) if int(model.jnt_qposadr[i]) in set(held.tolist())])
    stiffness = jnp.zeros_like(model.jnt_stiffness).at[joints].set(gains.held_stiffness)
    return model.replace(dof_damping=damping, jnt_stiffness=stiffness)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Support:
    """What the controller keeps from the last touchdown.

    Attributes:
      stance: the supporting leg, 0 (l) or 1 (r).
      stance_angle: theta at that touchdown (the step's start), rad.
      offset: joints (H1, K1, H2, K2) minus the reference at the touchdown, shape (4,), rad; it fades out
        over the first :data:`OFFSET_FADE` of the step, so the reference starts where the robot is.
    """

    stance: jax.Array
    stance_angle: jax.Array
    offset: jax.Array


def phase_of(reference: GaitReference, support: Support, theta):
    """s: theta mapped linearly from [theta at touchdown, theta at the optimal step's end] onto the
    optimal step's [theta_0, theta_end], then through theta(s) (hybrid-zero-dynamics phasing that
    re-normalises every step, so a short or long step starts at s = 0)."""
    start, end = reference.stance_angle[0], reference.stance_angle[-1]
    stretch = (end - start) / (end - support.stance_angle)
    equivalent = start + (theta - support.stance_angle) * stretch
    return jnp.clip(jnp.interp(equivalent, reference.stance_angle, reference.phase), 0.0, 1.0)


def after_touchdown(layout: Layout, reference: GaitReference, qpos, qvel, stance) -> Support:
    """The support state when leg ``stance`` has just landed."""
    theta, _, joints, _, _ = sagittal_state(layout, qpos, qvel, stance)
    # keep a usable phase range if the robot lands far off the optimal posture
    theta = jnp.minimum(theta, reference.stance_angle[-1] - 0.1)
    return Support(stance=stance, stance_angle=theta, offset=joints - reference.joints[0])


def control(layout: Layout, reference: GaitReference, gains: Gains, qpos, qvel, support: Support):
    """Torques of the hips and knees (the other actuators are idle: their joints are held by springs and
    dampers, see :func:`with_gains`), shape (16,), N m; the phase s; the reference (H1, K1, H2, K2), rad.

    Law: u = u_ff(s) + K_p (q_ref(s) - q) + K_d (qdot_ref - qdot), the - K_d qdot part acting as joint
    damping; q_ref = b(s) + (1 - s / OFFSET_FADE)^3 offset for s < OFFSET_FADE, else b(s); qdot_ref =
    d q_ref / d s at the nominal pace ds/dt = 1 / t_f.
    """
    theta, _, joints, _, _ = sagittal_state(layout, qpos, qvel, support.stance)
    phase = phase_of(reference, support, theta)
    # the reference's rate at the nominal pace: a rate from the measured theta_dot would feed the stance
    # leg's joint rates back explicitly through the gains (unstable at 1 ms late in the step, measured)
    phase_rate = 1.0 / reference.step_time
    fade = jnp.maximum(1.0 - phase / OFFSET_FADE, 0.0)
    target = _interp(phase, reference.phase, reference.joints) + fade**3 * support.offset
    target_rate = (_interp(phase, reference.phase, reference.joint_slope)
                   - 3 * fade**2 / OFFSET_FADE * support.offset) * phase_rate
    sagittal = (_interp(phase, reference.phase, reference.torque)
                + gains.sagittal_stiffness * (target - joints) + gains.sagittal_damping * target_rate)
    hip, knee = jnp.array(layout.actuator_hip), jnp.array(layout.actuator_knee)
    stance = support.stance
    actuators = jnp.stack([hip[stance], knee[stance], hip[1 - stance], knee[1 - stance]])
    return jnp.zeros(len(layout.held_q)).at[actuators].set(sagittal), phase, target
