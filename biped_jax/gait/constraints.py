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
    "gear_input_speed": ("inequality", "rad/s"),
}


#: The groups of one row block per grid sample (or two: a two-sided bound), laid out as
#: (blocks, samples, components) and flattened in that order; the others are the boundary groups (the
#: shooting defects, the touchdown and the periodicity). ``swing_foot_height`` leaves out the first and the
#: last sample (the feet are on the ground there).
SAMPLE_GROUPS = ("swing_foot_height", "heights", "knee_range", "vertical_force", "friction_cone",
                 "torque_bound", "power_limit", "voltage", "gear_input_speed")

#: The joint speed, rad/s, standing for "no input speed limit" where a drive has none (ideal drives in
#: a problem with ``GaitSettings.drive_limits``): far beyond any gait's, and finite, so that its rows
#: keep finite slacks.
NO_SPEED_LIMIT = 1e3


def clearance_profile(phase, settings: GaitSettings):
    """The swing foot's least height at the step's phases ``phase`` (t / t_f, any shape), m:
    ``settings.swing_clearance`` between the ramps, a smoothstep from 0 over the first and to 0 over the
    last ``settings.clearance_ramp`` of the step."""
    ramp = jnp.clip(jnp.minimum(phase, 1.0 - phase) / settings.clearance_ramp, 0.0, 1.0)
    return settings.swing_clearance * ramp**2 * (3.0 - 2.0 * ramp)


def sample_groups(q, u, ground_force, swing_foot, heights, joint_speed, phase, model: GaitModel,
                  settings: GaitSettings) -> dict:
    """The per-sample groups at N samples (arrays (N, ...) of :class:`GaitTrajectory`'s fields; ``phase``
    the samples' t / t_f, (N,)), each of shape (blocks, N, components) in its own unit
    (``swing_foot_height`` at every sample: the foot's height under :func:`clearance_profile`). With
    ``settings.drive_limits`` the torque bound is also the gear's intermittent torque and
    ``gear_input_speed`` bounds the joint speeds by the gear's input speed over N; without, that group
    has no components."""
    knees = q[:, jnp.array([1, 4])]
    fx, fz = ground_force[:, 0], ground_force[:, 1]
    drives = model.drives
    if settings.drive_limits:
        torque_bound = jnp.minimum(settings.torque_bound, drives.gear_torque_limit)
        speed_bound = jnp.minimum(drives.input_speed_limit / drives.ratio, NO_SPEED_LIMIT)
        gear_speed = _two_sided_blocks(joint_speed, speed_bound)
    else:
        torque_bound, gear_speed = settings.torque_bound, jnp.zeros((2, joint_speed.shape[0], 0), joint_speed.dtype)
    clearance = -swing_foot[None, :, 1:2]
    if settings.swing_clearance:  # the paper's problem (none) keeps its programs
        clearance = clearance + clearance_profile(phase, settings)[None, :, None]
    return {
        "swing_foot_height": clearance,
        "heights": -heights[None],
        "knee_range": jnp.stack([-knees, knees - settings.knee_max]),
        "vertical_force": -fz[None, :, None],
        "friction_cone": jnp.stack([fx - settings.friction * fz, -fx - settings.friction * fz])[..., None],
        "torque_bound": _two_sided_blocks(u, torque_bound),
        "power_limit": _two_sided_blocks(joint_speed * u, model.power_limit),
        "voltage": _two_sided_blocks(drive_model.required_voltage(u, joint_speed, drives), drives.supply_voltage),
        "gear_input_speed": gear_speed,
    }


def boundary_groups(trajectory_ends: dict, model: GaitModel, settings: GaitSettings) -> dict:
    """The touchdown's and the periodicity's groups from the step's first sample (q0, qd0) and its
    last (swing_foot_end (2,), swing_foot_velocity (2,), touchdown)."""
    e = trajectory_ends
    impact = e["touchdown"]
    lx, lz = impact.impulse
    return {
        "touchdown_position": jnp.array([e["swing_foot_end"][0] - model.step_length, e["swing_foot_end"][1]]),
        "periodicity_angle": impact.q[:1] - e["q0"][:1],
        "periodicity_rate": impact.qd - e["qd0"],
        "touchdown_descending": touchdown_rows(e["swing_foot_velocity"], settings),
        "impact_impulse": jnp.array([-lz, lx - settings.friction * lz, -lx - settings.friction * lz]),
        "liftoff": -impact.old_stance_foot_velocity[1:],
    }


def touchdown_rows(swing_foot_velocity, settings: GaitSettings):
    """``touchdown_descending``'s rows from the swing foot's (x, z) velocity at touchdown (2,), m/s: moving
    down, and with ``settings.touchdown_forward_speed`` forward at most that fast."""
    rows = swing_foot_velocity[1:]
    if settings.touchdown_forward_speed is not None:
        rows = jnp.concatenate([rows, swing_foot_velocity[:1] - settings.touchdown_forward_speed])
    return rows


def constraint_groups(trajectory: GaitTrajectory, model: GaitModel, settings: GaitSettings) -> dict:
    """Each group's residuals in its own unit: equalities (= 0) and inequalities (<= 0)."""
    tr = trajectory
    samples = sample_groups(tr.q, tr.u, tr.ground_force, tr.swing_foot, tr.heights, tr.joint_speed, tr.t / tr.t[-1],
                            model, settings)
    samples["swing_foot_height"] = samples["swing_foot_height"][:, 1:-1]
    ends = {"q0": tr.q[0], "qd0": tr.qd[0], "swing_foot_end": tr.swing_foot[-1],
            "swing_foot_velocity": tr.swing_foot_velocity, "touchdown": tr.touchdown}
    return {"continuity_angle": tr.continuity[:, 0], "continuity_rate": tr.continuity[:, 1],
            **{name: value.ravel() for name, value in samples.items()},
            **boundary_groups(ends, model, settings)}


def _two_sided_blocks(value, bound):
    """|value| <= bound as the two smooth blocks value - bound and -value - bound, (2, *value.shape):
    |value| has a kink at 0, where a row far from active would still make a Newton model's dual
    residual jump by its multiplier times its gradient."""
    return jnp.stack([value - bound, -value - bound])


_SCALES = {"m": LENGTH_SCALE, "rad": 1.0, "rad/s": RATE_SCALE, "m/s": LENGTH_SCALE, "N": FORCE_SCALE,
           "N m": TORQUE_SCALE, "W": POWER_SCALE, "N s": IMPULSE_SCALE, "V": VOLTAGE_SCALE}


def group_scale(name: str) -> float:
    """The own units per scaled unit of constraint group ``name`` (what :func:`scaled_constraints` divides by)."""
    return _SCALES[CONSTRAINT_GROUPS[name][1]]


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
