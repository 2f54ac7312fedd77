"""Co-design of the sagittal biped: gear ratios, windings and link masses with the gait, motor in the loop.

The hardware is a :class:`~biped_jax.codesign.drive_design.DriveDesign` (arrays, batchable; its names are
re-exported here, so ``from biped_jax.codesign import problem as codesign`` is the whole co-design), mapped
to the gait problem by :func:`~biped_jax.codesign.drive_design.design_gait_model`. So one compiled gait program
(``GaitSolver``) solves any batch of designs (:func:`solve_designs`), and the paper's problem is the
special case of ideal drives. Gradients of the optimal Joule energy with respect to the design come
from the envelope theorem (:func:`biped_jax.optim.nlp.optimal_value_gradient`): at a
converged gait, one gradient of the Lagrangian with the interior point's multipliers (see
:data:`SOLVER_OPTIONS`), no differentiation through the solver. Chosen over implicit differentiation
of the KKT system (needs the Lagrangian's Hessian through the rollout: a second-order program that
compiles for minutes on a small CPU) and over design variables as extra decision variables (couples
every design into one larger, worse conditioned gait problem and loses the warm-started independent
solves).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax

from biped_jax import checks
from biped_jax.codesign.drive_design import (  # the hardware, re-exported: one co-design namespace
    DriveDesign,
    REFERENCE_GEARHEAD,
    REFERENCE_MOTOR,
    catalogue_design,
    design_gait_model,
    joint_drives,
    nearest_gearhead,
    reflected_inertia,
    robot_design,
    stack,
    unstack,
    with_ratio,
)
from biped_jax.drives import model as drive_model
from biped_jax.gait import problem as gait_problem
from biped_jax.optim import interior_point as ip
from biped_jax.optim import nlp

__all__ = [
    "CoOptimisation",
    "DriveDesign",
    "REFERENCE_GEARHEAD",
    "REFERENCE_MOTOR",
    "SOLVER_OPTIONS",
    "catalogue_design",
    "co_optimise",
    "design_record",
    "design_gait_model",
    "joint_drives",
    "nearest_gearhead",
    "ratio_gradient",
    "reflected_inertia",
    "robot_design",
    "solve_designs",
    "stack",
    "unstack",
    "with_ratio",
]

#: The co-design's gait solver: the batched interior point warm-started from a solved gait (a
#: neighbouring design's), from a small barrier parameter, as the study's warm stages. The envelope
#: gradient needs a KKT point and its multipliers, not a point that merely stops improving: a solver
#: that stopped at a loose stationarity left neighbouring designs on different local optima, whose
#: envelope gradient and difference of optima disagreed (measured on the tests' 4-span grid at
#: 66:1 * exp(+-0.03); ``tests/test_codesign.py`` compares the two). The iteration cap bounds a design
#: without a gait (a too-high speed in a bisection).
SOLVER_OPTIONS = ip.InteriorPointOptions(mu_initial=1e-3, max_iterations=300)


# ----------------------------------------------------------------------------- batch evaluation

def per_design(name: str, value, size: int) -> np.ndarray:
    """``value`` (a number or one per design) as (size,) floats; ValueError naming a mismatch."""
    array = np.asarray(value, dtype=float)
    if array.ndim > 1 or (array.ndim == 1 and array.shape[0] != size):
        raise ValueError(f"{name} must be a number or one value per design ({size}), got shape {array.shape}")
    return np.broadcast_to(array, (size,))


def solve_designs(solver, designs: list[DriveDesign], speed, power_limit, step_length=0.2, x0=None,
                  names: list[str] | None = None, progress=None,
                  summary: Callable[[str], None] | None = None) -> list:
    """Solves the gait of every design in one batch (one compiled program per batch size).

    ``speed`` (m/s), ``power_limit`` (W) and ``step_length`` (m) are scalars or one value per design;
    x0 (B, n) warm-starts (e.g. a solved reference gait repeated). Returns ``GaitSolution``s whose cost
    is the Joule energy (J), with status and per-group violations (the voltage limit among them);
    ``summary`` receives one line on the batch (statuses, gradients, time).
    """
    designs = checks.sequence("designs", designs, DriveDesign, "DriveDesign")
    size = len(designs)
    speeds, limits, lengths = (per_design(label, value, size) for label, value in
                               (("speed", speed), ("power_limit", power_limit), ("step_length", step_length)))
    gait_problem.check_problem(speeds, limits, lengths)
    if names is not None:
        checks.same_length(designs=designs, names=checks.sequence("names", names, str, "label (str)"))
    models = [design_gait_model(d, v, p, length) for d, v, p, length in zip(designs, speeds, limits, lengths)]
    names = names or [f"design {b}" for b in range(size)]
    solutions = solver.solve(names, models, x0=x0, progress=progress)
    if summary:
        statuses = [s.status for s in solutions]
        summary(f"{statuses.count(nlp.CONVERGED)} of {size} converged "
                f"({', '.join(sorted(set(statuses) - {nlp.CONVERGED})) or 'all'}), "
                f"gradients per design up to {max(s.gradients for s in solutions)}, "
                f"{solutions[0].wall_time_s:.0f} s")
    return solutions


def design_record(design: DriveDesign, solution) -> dict:
    """A JSON-ready summary of one solved design: hardware, status, Joule energy (J and J/m; the
    objective, with the smooth efficiency switch, and with the exact one), the integral of u^T u, peak
    joint power, the largest voltage needed (exact efficiency law) and the violations."""
    trajectory = solution.trajectory
    drives = joint_drives(design)
    torque_at_motor = drive_model.motor_torque(trajectory.u, trajectory.joint_speed, drives.ratio,
                                               drives.efficiency)
    needed = np.abs(np.asarray(drive_model.voltage(
        torque_at_motor, drive_model.motor_speed(trajectory.joint_speed, drives.ratio), drives)))
    weights = np.asarray(trajectory.weights)[:, None]  # the trajectory's quadrature, s
    exact_joule = float(np.sum(weights * np.asarray(drive_model.joule_loss(torque_at_motor, drives))))
    return {
        "ratio": np.asarray(design.ratio).tolist(),
        "torque_constant_Nm_per_A": float(design.torque_constant[0]),
        "resistance_ohm": float(design.resistance[0]),
        "supply_voltage_V": float(design.supply_voltage),
        "total_mass_kg": float(design.total_mass),
        "armature_kgm2": np.asarray(reflected_inertia(design)).tolist(),
        "speed_mps": solution.speed_mps, "power_limit_W": solution.power_limit_W,
        "status": solution.status, "max_violation": solution.max_violation,
        "violations": solution.violations,
        "joule_energy_J": solution.cost,
        "joule_energy_exact_switch_J": exact_joule,
        "joule_energy_per_metre_J_per_m": solution.cost / solution.step_length_m,
        "int_u2_N2m2s": float(gait_problem.cost(trajectory)),
        "peak_joint_power_W": float(np.max(np.abs(np.asarray(trajectory.joint_power)))),
        "max_voltage_needed_V": float(np.max(needed)),
    }


# ----------------------------------------------------------------------------- gradients and co-optimisation

def ratio_gradient(solver) -> Callable:
    """d J*/d log N per joint for a batch of converged solutions, by the envelope theorem.

    Returns ``gradient(designs, log_ratio, speed, power_limit, step_length, solutions) -> (B, 4)``
    (designs stacked with :func:`stack`; gear data follow the ratio as in :func:`with_ratio`).
    """
    catalogue = drive_model.load_catalogue()

    def parameters_to_model(theta):
        design, log_ratio, speed, power_limit, step_length = theta
        return design_gait_model(with_ratio(design, log_ratio, catalogue), speed, power_limit, step_length)

    envelope = nlp.optimal_value_gradient(solver.problem, parameters_to_model)

    def gradient(designs, log_ratio, speed, power_limit, step_length, solutions):
        size = log_ratio.shape[0]
        per = lambda value: jnp.broadcast_to(jnp.asarray(value, float), (size,))  # noqa: E731
        theta = (designs, jnp.asarray(log_ratio), per(speed), per(power_limit), per(step_length))
        x = jnp.stack([jnp.asarray(s.x) for s in solutions])
        lam_eq = jnp.stack([jnp.asarray(s.multipliers_eq) for s in solutions])
        lam_in = jnp.stack([jnp.asarray(s.multipliers_in) for s in solutions])
        return np.asarray(envelope(theta, x, lam_eq, lam_in)[1])
    return gradient


@dataclasses.dataclass
class CoOptimisation:
    """The path of :func:`co_optimise`: per iteration the ratios (B, 4), Joule energies (B,), statuses,
    and the final designs and gaits."""

    ratios: list
    joule: list
    status: list
    designs: list
    solutions: list


def co_optimise(solver, designs: list[DriveDesign], speed, power_limit, step_length=0.2, x0=None,
                iterations: int = 6, max_step: float = 0.25, ratio_bounds=(14.0, 190.0),
                min_step: float = 0.02, solutions: list | None = None,
                progress: Callable[[str], None] | None = None) -> CoOptimisation:
    """Gear ratios per joint co-optimised with the gait, all designs of the batch at once.

    optax's Adam on log N, one optimiser state per design (vmapped), its learning rate the design's
    step (at first ``max_step``: Adam's first step moves each joint by about the step, later ones by
    less where the gradient's sign wavers), the update projected onto ``ratio_bounds``
    (``optax.projections.projection_box``); the gradient from the envelope theorem at each re-solved
    (warm-started) optimum. A step that raises the Joule energy or loses feasibility is undone (the
    design keeps its point and optimiser state) and the design's step halved. A design is frozen once
    its step falls below ``min_step`` (log N) or its gait does not converge; the loop ends early when
    every design is frozen (the batch keeps its shape, so a frozen design is still solved while others
    move, but its result is not taken).
    Gear data follow the ratio smoothly (:func:`with_ratio`); snap the result to the catalogue with
    :func:`nearest_gearhead` and re-solve to verify. ``solutions``: the designs' gaits if already solved
    (e.g. by :func:`solve_designs`), else they are solved first.
    """
    designs = checks.sequence("designs", designs, DriveDesign, "DriveDesign")
    checks.integer_in("iterations", iterations, 0, 10_000)
    checks.number_in("max_step", max_step, 0.0, 10.0, "(log N)")
    checks.number_in("min_step", min_step, 0.0, 10.0, "(log N)")
    if not (len(ratio_bounds) == 2 and 0 < ratio_bounds[0] < ratio_bounds[1]):
        raise ValueError(f"ratio_bounds must be (low, high) with 0 < low < high, got {ratio_bounds!r}")
    gait_problem.check_problem(*(per_design(label, value, len(designs)) for label, value in
                         (("speed", speed), ("power_limit", power_limit), ("step_length", step_length))))
    say = progress or (lambda message: None)
    gradient = ratio_gradient(solver)
    catalogue = drive_model.load_catalogue()
    base = stack(designs)
    theta = np.log(np.asarray(base.ratio, dtype=float))
    low, high = np.log(ratio_bounds[0]), np.log(ratio_bounds[1])
    step = np.full(len(designs), max_step)
    apply = jax.jit(jax.vmap(lambda d, t: with_ratio(d, t, catalogue)))
    adam = optax.inject_hyperparams(optax.adam)(learning_rate=max_step)
    state = jax.vmap(adam.init)(jnp.asarray(theta))
    if solutions is None:
        solutions = solve_designs(solver, unstack(apply(base, jnp.asarray(theta))), speed, power_limit,
                                  step_length, x0=x0, summary=progress)
    elif len(solutions) != len(designs):
        raise ValueError(f"give one solution per design: {len(solutions)} for {len(designs)} designs")
    path = CoOptimisation([], [], [], [], [])

    def record(theta_, solutions_):
        path.ratios.append(np.exp(theta_).tolist())
        path.joule.append([s.cost for s in solutions_])
        path.status.append([s.status for s in solutions_])

    record(theta, solutions)
    for k in range(iterations):
        moving = np.array([s.status == nlp.CONVERGED for s in solutions]) & (step >= min_step)
        if not moving.any():
            say(f"co-design stopped after {k} iterations: every design converged to its step floor or failed")
            break
        grad = gradient(base, theta, speed, power_limit, step_length, solutions)
        state.hyperparams["learning_rate"] = jnp.asarray(step)
        trial, trial_state = _projected_step(adam, jnp.asarray(grad), state, jnp.asarray(theta), low, high)
        trial = np.where(moving[:, None], np.asarray(trial), theta)
        x_warm = jnp.stack([jnp.asarray(s.x) for s in solutions])
        trial_solutions = solve_designs(solver, unstack(apply(base, jnp.asarray(trial))), speed, power_limit,
                                        step_length, x0=x_warm, summary=progress)
        better = moving & np.array([t.status == nlp.CONVERGED and t.cost < s.cost
                                    for s, t in zip(solutions, trial_solutions)])
        theta = np.where(better[:, None], trial, theta)
        state = _rows_where(better, trial_state, state)
        solutions = [t if b else s for s, t, b in zip(solutions, trial_solutions, better)]
        step = np.where(better | ~moving, step, 0.5 * step)
        record(theta, solutions)
        best = min((s.cost for s in solutions if s.status == nlp.CONVERGED), default=math.nan)
        say(f"co-design iteration {k + 1}/{iterations}: {int(better.sum())} of {len(designs)} designs "
            f"improved, best Joule energy {best:.4g} J")
    path.designs = unstack(apply(base, jnp.asarray(theta)))
    path.solutions = solutions
    return path


def _rows_where(mask, new, old):
    """Per design (leading axis), ``new``'s leaves where ``mask`` (B,) holds, ``old``'s elsewhere."""
    def pick(a, b):
        return jnp.where(jnp.reshape(jnp.asarray(mask), (-1,) + (1,) * (jnp.ndim(a) - 1)), a, b)
    return jax.tree.map(pick, new, old)


def _projected_step(optimiser, grad, state, theta, low, high):
    """Every design's optax update of ``theta`` (B, 4) with its own state, projected onto [low, high]."""
    updates, state = jax.vmap(optimiser.update)(grad, state, theta)
    return optax.projections.projection_box(optax.apply_updates(theta, updates), low, high), state
