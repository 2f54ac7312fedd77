"""Making DONALD faster: its gait parameters optimised for speed by single shooting through the MJX
contact simulation, by a short augmented-Lagrangian loop of its own around optax's L-BFGS
(:func:`optimise`).

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

Why not the gait optimiser's interior point: it needs the Lagrangian's exact Hessian, and through 5 700
contact steps second derivatives are noise, as the first ones are; with seven parameters and
difference gradients, a first-order method over a smoothed objective is the right tool.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax

from biped_jax.donald import model as donald
from biped_jax.drives import model as drive_model
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


def differentiable_donald(drive: drive_model.JointDrives):
    """DONALD with one constraint-solver iteration per step: MJX's solver loop is a while_loop, which
    reverse mode cannot differentiate; a single Newton iteration (warm-started) is a scan
    (docs/dynamics.md, "Through contact"). The walk is re-checked with the full solver after optimising."""
    mj_model, _ = donald.load_donald(drive)
    mj_model.opt.iterations = 1
    from biped_jax.robots import registry
    return mj_model, registry.put_mjx_model(mj_model)


def gait_from_vector(z: jax.Array, base: donald.DonaldGait = donald.DEFAULT_GAIT) -> donald.DonaldGait:
    """The gait whose parameters are ``z`` (7,) times the default gait's."""
    return dataclasses.replace(base, **{name: z[k] * getattr(base, name) for k, name in enumerate(PARAMETERS)})


def _value_at(t: jax.Array, samples_t: jax.Array, values: jax.Array) -> jax.Array:
    """Linear interpolation of ``values`` (S,) at time t (differentiable in t and values)."""
    return jnp.interp(t, samples_t, values)


def speed_and_constraints(z: jax.Array, walk, model, gains: donald.Gains, drive: drive_model.JointDrives,
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


@dataclasses.dataclass(frozen=True)
class SpeedOptions:
    """Settings of :func:`optimise`: one gradient is 15 rollouts of 5 700 contact steps (about 12 s on
    one CPU core), so the budget is a few dozen gradients; on a rough objective a line search that needs
    more than eight halvings has found noise, not descent.

    Attributes:
      max_outer: multiplier updates. max_inner: L-BFGS iterations per multiplier update.
      penalty: rho of the augmented Lagrangian (the constraints are scaled to order one).
      tolerance: largest scaled violation of a feasible gait.
      stationarity: an inner loop ends when |gradient|_inf falls below this.
      memory: L-BFGS memory. armijo: sufficient decrease. max_backtracks: halvings of a step at most.
    """

    max_outer: int = 4
    max_inner: int = 15
    penalty: float = 100.0
    tolerance: float = 1e-3
    stationarity: float = 1e-2
    memory: int = 10
    armijo: float = 1e-4
    max_backtracks: int = 8


SPEED_OPTIONS = SpeedOptions()


def augmented_lagrangian(objective, inequalities, multipliers, penalty):
    """f + sum(max(0, z + rho g)^2 - z^2) / (2 rho) for inequalities g <= 0 with multipliers z >= 0
    (Nocedal and Wright, Numerical Optimization, 2006, eq. 17.65)."""
    shifted = jnp.maximum(0.0, multipliers + penalty * inequalities)
    return objective + jnp.sum(shifted ** 2 - multipliers ** 2) / (2 * penalty)


def _inner(value, value_and_grad, z, multipliers, options: SpeedOptions):
    """L-BFGS (optax's direction) with a backtracking Armijo search on the augmented Lagrangian at fixed
    multipliers (``value`` and ``value_and_grad`` return it with (f, g) beside); returns the last
    accepted point, (f, g) there, the gradient evaluations spent, whether it ended stationary
    (|gradient|_inf <= ``options.stationarity``) and whether it took a step at all."""
    lbfgs = optax.scale_by_lbfgs(memory_size=options.memory)
    state = lbfgs.init(z)
    (current, parts), grad = value_and_grad(z, multipliers)
    spent, moved = 1, False
    for _ in range(options.max_inner):
        if float(jnp.max(jnp.abs(grad))) <= options.stationarity:
            break
        direction, state = lbfgs.update(grad, state, z)  # the inverse-Hessian estimate times the gradient
        slope = -float(grad @ direction)
        if slope >= 0:  # not a descent direction: the gradient's own
            direction, slope = grad, -float(grad @ grad)
        step = 1.0
        for _ in range(options.max_backtracks):
            trial = z - step * direction
            if float(value(trial, multipliers)[0]) <= float(current) + options.armijo * step * slope:
                break
            step *= 0.5
        else:
            break  # no decrease along the direction: noise, not descent
        z, moved = trial, True
        (current, parts), grad = value_and_grad(z, multipliers)
        spent += 1
    return z, parts, spent, float(jnp.max(jnp.abs(grad))) <= options.stationarity, moved


def minimise(evaluate, z0, options: SpeedOptions = SPEED_OPTIONS, progress=None) -> dict:
    """min f(z) subject to g(z) <= 0 for ``evaluate(z, None) -> (f, h (empty), g)``, derivatives by
    central differences of width :data:`DIFFERENCE_STEP`: ``options.max_outer`` rounds of an inner
    L-BFGS solve of the augmented Lagrangian and the multiplier update z <- max(0, z + rho g).

    Returns {"z", "cost", "start_cost" (f at z0), "violation" (largest scaled), "status" (converged:
    feasible within ``options.tolerance``, the multipliers settled and the inner solve stationary;
    stalled: an inner solve found no descent at all, the smoothed objective's noise, not an optimum;
    else iteration limit), "iterates" (z after every outer iteration), "gradients"}.
    ``progress(outer, row)`` hears each outer iteration (row: "cost", "violation", "gradients", each of
    shape (1,))."""
    differenced = nlp.central_differences(evaluate, DIFFERENCE_STEP)

    def merit(z, multipliers):
        objective, _, inequalities = differenced(z, None)
        # (f, g) beside the merit: the loop reads them from the evaluations it makes anyway
        return augmented_lagrangian(objective, inequalities, multipliers, options.penalty), (objective, inequalities)

    value, value_and_grad = jax.jit(merit), jax.jit(jax.value_and_grad(merit, has_aux=True))
    z = jnp.asarray(z0, dtype=jnp.result_type(float))
    multipliers = jnp.zeros(jax.eval_shape(evaluate, z, None)[2].shape, z.dtype)  # the shape, nothing compiled
    _, (objective, inequalities) = value(z, multipliers)
    start_cost = float(objective)
    gradients, status, iterates = 0, nlp.ITERATION_LIMIT, []
    violation = float(nlp.violation(jnp.zeros(0), inequalities))
    for outer in range(options.max_outer):
        z, (objective, inequalities), spent, stationary, moved = _inner(value, value_and_grad, z, multipliers,
                                                                        options)
        gradients += spent
        violation = float(nlp.violation(jnp.zeros(0), inequalities))
        updated = jnp.maximum(0.0, multipliers + options.penalty * inequalities)
        settled = float(jnp.max(jnp.abs(updated - multipliers))) <= options.tolerance * options.penalty
        multipliers = updated
        iterates.append(np.asarray(z))
        if progress:
            progress(outer, {"cost": np.array([float(objective)]), "violation": np.array([violation]),
                             "gradients": np.array([gradients])})
        if violation <= options.tolerance and settled and stationary:
            status = nlp.CONVERGED
            break
        if not moved:
            status = nlp.STALLED
            break
    return {"z": np.asarray(z), "cost": float(objective), "start_cost": start_cost, "violation": violation,
            "status": status, "iterates": iterates, "gradients": gradients}


def optimise(options: SpeedOptions = SPEED_OPTIONS, progress=None) -> dict:
    """Optimises the gait from the default (:func:`minimise`); returns the default's and the optimum's
    speed, the optimal parameters, the status, its largest scaled violation, every outer iterate (so a
    caller can walk them all and keep the best verified one), the gradient count and the time."""
    started = time.perf_counter()
    drive = donald.donald_drive()
    mj_model, model = differentiable_donald(drive)
    walk = donald.walker(mj_model, STEPS, DURATION)
    gains = donald.DEFAULT_GAINS

    def evaluate(z, _params):
        return speed_and_constraints(z, walk, model, gains, drive)

    result = minimise(evaluate, jnp.ones(len(PARAMETERS)), options, progress)
    as_gait = lambda z_: {name: float(getattr(gait_from_vector(jnp.asarray(z_)), name))  # noqa: E731
                          for name in PARAMETERS}
    return {"status": result["status"], "speed_mps": -result["cost"] * 0.01,
            "default_speed_mps": -result["start_cost"] * 0.01,
            "max_scaled_violation": result["violation"], "gait": as_gait(result["z"]),
            "iterates": [{"outer_iteration": k + 1, "gait": as_gait(z)} for k, z in enumerate(result["iterates"])],
            "gradients": result["gradients"], "wall_time_s": time.perf_counter() - started}
