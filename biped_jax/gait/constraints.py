"""The gait's constraints in groups with their units and scales, the objective (Simpson's integral of
u^T u, or the drives' Joule energy) and the violations."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from biped_jax.drives import model as drive_model
from biped_jax.gait.settings import GaitModel, GaitSettings, GaitTrajectory

# stays below 1e-4 in the group's own unit.
LENGTH_SCALE = 0.1  # m
RATE_SCALE = 1.0  # rad/s
FORCE_SCALE = 10.0  # N
IMPULSE_SCALE = 1.0  # N s
POWER_SCALE = 10.0  # W
TORQUE_SCALE = 10.0  # N m
VOLTAGE_SCALE = 10.0  # V


# ----------------------------------------------------------------------------- constraints

#: Constraint groups: name -> (kind, unit). Each group's violation is reported in its own unit.
CONSTRAINT_GROUPS = {
    "continuity_angle": ("equality", "rad"),
    "continuity_rate": ("equality", "rad/s"),
    "touchdown_position": ("equality", "m"),
    "periodicity_angle": ("equality", "rad"),
    "periodicity_rate": ("equality", "rad/s"),
    "swing_foot_height": ("inequality", "m"),
    "touchdown_descending": ("inequality", "m/s"),
    "heights": ("inequality", "m"),
    "knee_range": ("inequality", "rad"),
    "vertical_force": ("inequality", "N"),
    "friction_cone": ("inequality", "N"),
    "torque_bound": ("inequality", "N m"),
    "power_limit": ("inequality", "W"),
    "impact_impulse": ("inequality", "N s"),
    "liftoff": ("inequality", "m/s"),
    "voltage": ("inequality", "V"),
}


def constraint_groups(trajectory: GaitTrajectory, model: GaitModel, settings: GaitSettings) -> dict:
    """Each group's residuals in its own unit: equalities (= 0) and inequalities (<= 0)."""
    tr, impact = trajectory, trajectory.touchdown
    knees = tr.q[:, jnp.array([1, 4])]
    fx, fz = tr.ground_force[:, 0], tr.ground_force[:, 1]
    lx, lz = impact.impulse
    power = tr.joint_power
    return {
        "continuity_angle": tr.continuity[:, 0],
        "continuity_rate": tr.continuity[:, 1],
        "touchdown_position": jnp.array([tr.swing_foot[-1, 0] - model.step_length, tr.swing_foot[-1, 1]]),
        "periodicity_angle": impact.q[:1] - tr.q[0, :1],
        "periodicity_rate": impact.qd - tr.qd[0],
        "swing_foot_height": -tr.swing_foot[1:-1, 1],
        "touchdown_descending": tr.swing_foot_velocity[1:],
        "heights": -tr.heights.ravel(),
        "knee_range": jnp.concatenate([-knees.ravel(), (knees - settings.knee_max).ravel()]),
        "vertical_force": -fz,
        "friction_cone": jnp.concatenate([fx - settings.friction * fz, -fx - settings.friction * fz]),
        "torque_bound": _two_sided(tr.u, settings.torque_bound),
        "power_limit": _two_sided(power, model.power_limit),
        "impact_impulse": jnp.array([-lz, lx - settings.friction * lz, -lx - settings.friction * lz]),
        "liftoff": -impact.old_stance_foot_velocity[1:],
        "voltage": _two_sided(drive_model.required_voltage(tr.u, tr.joint_speed, model.drives),
                              model.drives.supply_voltage),
    }


def _two_sided(value, bound):
    """|value| <= bound as the two smooth rows value - bound and -value - bound (flattened): |value|
    has a kink at 0, where a row far from active would still make a Newton model's dual residual jump
    by its multiplier times its gradient."""
    return jnp.concatenate([(value - bound).ravel(), (-value - bound).ravel()])


_SCALES = {"m": LENGTH_SCALE, "rad": 1.0, "rad/s": RATE_SCALE, "m/s": LENGTH_SCALE, "N": FORCE_SCALE,
           "N m": TORQUE_SCALE, "W": POWER_SCALE, "N s": IMPULSE_SCALE, "V": VOLTAGE_SCALE}


def scaled_constraints(groups: dict) -> tuple[jax.Array, jax.Array]:
    """(equalities, inequalities), each concatenated and scaled to order one."""
    equalities, inequalities = [], []
    for name, (kind, unit) in CONSTRAINT_GROUPS.items():
        value = groups[name] / _SCALES[unit]
        (equalities if kind == "equality" else inequalities).append(value)
    return jnp.concatenate(equalities), jnp.concatenate(inequalities)


def cost(trajectory: GaitTrajectory) -> jax.Array:
    """J = integral of u^T u dt over the step (composite Simpson), N^2 m^2 s."""
    return trajectory.weights @ jnp.sum(trajectory.u**2, axis=-1)


def cost_residuals(trajectory: GaitTrajectory, drives: drive_model.JointDrives) -> jax.Array:
    """r with r . r = the objective, the drives' Joule energy (J = integral of u^T u for ideal
    drives), flattened, shape (4 (T + 1),): Simpson's weights are positive, so the quadrature stays a
    sum of squares."""
    return drive_model.joule_residuals(trajectory.u, trajectory.joint_speed, drives,
                                       trajectory.weights[:, None]).ravel()


def joule_energy(trajectory: GaitTrajectory, drives: drive_model.JointDrives) -> jax.Array:
    """Integral of R i^2 over the step summed over the joints, J (= J for ideal drives)."""
    residuals = cost_residuals(trajectory, drives)
    return residuals @ residuals


def violations(groups: dict) -> dict:
    """Largest violation of each group in its own unit (0 when satisfied)."""
    out = {}
    for name, (kind, _) in CONSTRAINT_GROUPS.items():
        value = jnp.abs(groups[name]) if kind == "equality" else jnp.maximum(groups[name], 0.0)
        out[name] = jnp.max(value) if value.size else jnp.zeros(())
    return out
