"""Making DONALD faster: its gait parameters optimised for speed by single shooting through the MJX
contact simulation, with the augmented-Lagrangian solver of the gait optimiser.

Decision vector (7 numbers, scaled so each is of order one): step angle, lift angle and pendulum
angle (rad), and the shift, lift, swing and lower durations (s), as multiples of the default gait's.
The objective is minus the walking speed over steps 2 and 3 of a three-step walk (step 1 starts from
standing). Constraints, at the physics samples of the planned phases:

- static stability, measured as ``donald.support_phases`` does: whenever one foot is in the air (every
  sole corner above the contact height) the other sole lies flat on the ground and the centre of mass
  projects inside it with at least :data:`STABILITY_MARGIN` (distance to the sole's edges);
- the swing foot clears the ground by :data:`FOOT_CLEARANCE` during the swing (no scuffing, so the
  planned single support is real);
- the pelvis stays above :data:`PELVIS_HEIGHT` (no fall);
- durations at least :data:`MIN_DURATION` and at most the default gait's (the aim is a faster gait,
  and the bound lets the simulated time end soon after the third step), angles within
  :data:`ANGLE_BOUNDS`.

Derivatives are central differences of width :data:`DIFFERENCE_STEP` (``nlp.central_differences``),
not reverse mode: through 5 700 contact steps the exact gradient of the speed is no guide (measured
at a feasible fast gait: with 2 ms steps its shift-time entry has the opposite sign to every
difference's, with 4 ms steps its entries reach 1e32); it is that of single contact events, while
differences over a few per cent of each parameter show the trend (they agree in sign between widths of
1 % and 3 %, and not at 0.3 %). Seven parameters make a difference gradient
14 rollouts, one vmapped call, and no reverse pass to compile.

The motor limits need no constraint: every joint's torque is clipped to its drive's speed-torque line
inside the simulation, so a gait that asks for more than the motors give fails the other constraints.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax.donald import model as donald
from biped_jax.drives import model as drives
from biped_jax.optim import augmented_lagrangian as al
from biped_jax.optim import nlp

STEPS = 3
STABILITY_MARGIN = 0.01  # m
FOOT_CLEARANCE = 0.003  # m
PELVIS_HEIGHT = 0.30  # m
MIN_DURATION = 0.2  # s
ANGLE_BOUNDS = {"step_angle": (0.05, 0.35), "lift_angle": (0.05, 0.3), "pendulum_angle": (0.3, 1.57)}
PARAMETERS = ("step_angle", "lift_angle", "pendulum_angle", "shift_time", "lift_time", "swing_time",
              "lower_time")
#: Simulated time, s: three steps of the slowest gait the bounds allow (the default), plus the
#: difference step and the bounds' tolerance.
DURATION = donald.SETTLE_TIME + STEPS * 1.1 * float(donald.DEFAULT_GAIT.step_time)
#: Half-width of the central differences, in the decision vector's units (fractions of the default
#: gait's parameters): 3 %, e.g. 36 ms of the shift and 5 mrad of the step angle.
DIFFERENCE_STEP = 0.03


def differentiable_donald(drive: drives.JointDrives):
    """DONALD with one constraint-solver iteration per step: MJX's solver loop is a while_loop, which
    reverse mode cannot differentiate; a single Newton iteration (warm-started) is a scan
    (mjx-notes.md). The walk is re-checked with the full solver after optimising."""
    mj_model, _ = donald.load_donald(drive)
    mj_model.opt.iterations = 1
    from biped_jax.robots import registry as robots
    return mj_model, robots.put_mjx_model(mj_model)


def gait_from_vector(z: jax.Array, base: donald.DonaldGait = donald.DEFAULT_GAIT) -> donald.DonaldGait:
    """The gait whose parameters are ``z`` (7,) times the default gait's."""
    return dataclasses.replace(base, **{name: z[k] * getattr(base, name) for k, name in enumerate(PARAMETERS)})


def _value_at(t: jax.Array, samples_t: jax.Array, values: jax.Array) -> jax.Array:
    """Linear interpolation of ``values`` (S,) at time t (differentiable in t and values)."""
    return jnp.interp(t, samples_t, values)


def speed_and_constraints(z: jax.Array, walk, model, gains: donald.Gains, drive: drives.JointDrives,
                          spec: donald.DonaldSpec = donald.DonaldSpec()):
    """(minus the speed in units of 0.01 m/s, no equalities, inequalities <= 0), each inequality group
    divided by its scale (margin 10 mm, contact height 2 mm, clearance 3 mm, pelvis 10 mm; bounds as
    fractions of the default gait's values) so that all are of order one."""
    gait = gait_from_vector(z)
    run = walk(model, gait, gains, drive)
    _, times = donald.keyframes(gait, STEPS)
    t = run.t
    com = run.com
    # keyframes per step: shift, lift, swing, lower; the step k ends at times[1 + 4 (k + 1)]
    step_end = lambda k: times[1 + 4 * (k + 1)]  # noqa: E731
    speed = (_value_at(step_end(2), t, com[:, 0]) - _value_at(step_end(0), t, com[:, 0])) / (
        step_end(2) - step_end(0))

    half = np.asarray(spec.foot_size) / 2
    rotation = run.foot_rotation.reshape(t.shape[0], 2, 3, 3)
    corner_height = donald.sole_corners(run, spec)[..., 2]
    # Measured phases, as donald.support_phases: a foot with every sole corner above the contact
    # height is in the air (the mask selects constraints; gradients flow through the values).
    airborne = jax.lax.stop_gradient(jnp.all(corner_height > donald.CONTACT_HEIGHT, axis=2))
    stability, flat, clearance = [], [], []
    for support, swing in ((0, 1), (1, 0)):
        single = airborne[:, swing] & ~airborne[:, support]
        offset = jnp.einsum("sji,sj->si", rotation[:, support], com - run.foot_position[:, support])
        margin = jnp.min(half[None, :2] - jnp.abs(offset[:, :2]), axis=1)
        stability.append(jnp.where(single, STABILITY_MARGIN - margin, -1.0))
        # the supporting sole lies flat (all four corners on the ground), so the sole is the polygon
        flat.append(jnp.where(single, jnp.max(corner_height[:, support], axis=1) - donald.CONTACT_HEIGHT, -1.0))
    for k in range(STEPS):
        swing = 1 if k % 2 == 0 else 0
        lifted, lowered = times[1 + 4 * k + 2], times[1 + 4 * k + 3]  # end of lift, end of swing
        in_air = (t > lifted) & (t < lowered)
        clearance.append(jnp.where(in_air, FOOT_CLEARANCE - jnp.min(corner_height[:, swing], axis=1), -1.0))
    values = dict(zip(PARAMETERS, z))
    bounds = [MIN_DURATION / getattr(donald.DEFAULT_GAIT, name) - values[name] for name in PARAMETERS[3:]]
    bounds += [values[name] - 1.0 for name in PARAMETERS[3:]]  # no phase slower than the default's
    for name, (low, high) in ANGLE_BOUNDS.items():
        default = getattr(donald.DEFAULT_GAIT, name)
        bounds += [low / default - values[name], values[name] - high / default]
    inequalities = jnp.concatenate([
        jnp.concatenate(stability) / STABILITY_MARGIN, jnp.concatenate(flat) / donald.CONTACT_HEIGHT,
        jnp.concatenate(clearance) / FOOT_CLEARANCE,
        (PELVIS_HEIGHT - run.qpos[:, 2]) / 0.01, jnp.stack(bounds)])
    return -speed / 0.01, jnp.zeros(0), inequalities


#: Solver settings: one gradient is 15 rollouts of 5 700 contact steps (about 12 s on one CPU core),
#: so the budget is a few hundred gradients; on a rough objective a line search that needs more than
#: eight halvings has found noise, not descent.
SPEED_SOLVER_OPTIONS = al.SolverOptions(tolerance=1e-3, stationarity=1e-2, max_outer=4, max_inner=15,
                                        penalty_initial=100.0, max_backtracks=8)


def optimise(options: al.SolverOptions = SPEED_SOLVER_OPTIONS,
             progress=None) -> dict:
    """Optimises the gait from the default; returns the default's and the optimum's speed, the
    optimal parameters, the solver status and its largest violation."""
    drive = donald.donald_drive()
    mj_model, model = differentiable_donald(drive)
    walk = donald.walker(mj_model, STEPS, DURATION)
    gains = donald.DEFAULT_GAINS

    def evaluate(z, _params):
        return speed_and_constraints(z, walk, model, gains, drive)

    problem = nlp.ConstrainedProblem(evaluate).with_central_differences(DIFFERENCE_STEP)
    z0 = jnp.ones((1, len(PARAMETERS)))
    result = al.solve(problem, z0, jnp.zeros(1), options, progress=progress)
    start_speed = -float(jax.jit(evaluate)(z0[0], None)[0]) * 0.01
    z = jnp.asarray(result.x[0])
    as_gait = lambda z_: {name: float(getattr(gait_from_vector(jnp.asarray(z_)), name))  # noqa: E731
                          for name in PARAMETERS}
    return {"status": result.status[0], "speed_mps": -float(result.cost[0]) * 0.01,
            "default_speed_mps": start_speed, "max_scaled_violation": float(result.violation[0]),
            "gait": as_gait(z),
            # every outer iterate, so a caller can walk them all and keep the best verified one
            "iterates": [{"outer_iteration": k + 1, "speed_mps": -0.01 * float(row["cost"][0]),
                          "max_scaled_violation": float(row["violation"][0]), "gait": as_gait(row["x"][0])}
                         for k, row in enumerate(result.history)],
            "gradients": int(result.gradients[0]), "wall_time_s": result.wall_time_s}
