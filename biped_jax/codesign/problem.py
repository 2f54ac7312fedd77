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
    MASS_SPLIT_BOUNDS,
    MASS_SPLIT_NAMES,
    DriveDesign,
    REFERENCE_GEARHEAD,
    REFERENCE_MOTOR,
    catalogue_design,
    design_gait_model,
    joint_drives,
    mass_split,
    nearest_gearhead,
    reflected_inertia,
    robot_design,
    stack,
    unstack,
    with_mass_split,
    with_ratio,
)
from biped_jax.drives import model as drive_model
from biped_jax.gait import problem as gait_problem
from biped_jax.optim import interior_point as ip
from biped_jax.optim import nlp

__all__ = [
    "CoOptimisation",
    "DESIGN_VARIABLES",
    "MASS_SPLIT_BOUNDS",
    "MASS_SPLIT_NAMES",
    "DriveDesign",
    "REFERENCE_GEARHEAD",
    "REFERENCE_MOTOR",
    "SOLVER_OPTIONS",
    "catalogue_design",
    "co_optimise",
    "design_bounds",
    "design_gradient",
    "design_record",
    "design_variables",
    "design_gait_model",
    "joint_drives",
    "mass_split",
    "nearest_gearhead",
    "ratio_gradient",
    "reflected_inertia",
    "robot_design",
    "solve_designs",
    "stack",
    "unstack",
    "with_mass_split",
    "with_ratio",
    "with_variables",
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

#: The co-design's variables per design, in order: log N per joint (H1, K1, H2, K2), then the mass
#: split (:data:`MASS_SPLIT_NAMES`: fractions).
DESIGN_VARIABLES = ("log_ratio_H1", "log_ratio_K1", "log_ratio_H2", "log_ratio_K2") + MASS_SPLIT_NAMES
#: A step of the mass split per unit step of log N (Adam moves every variable by about its learning
#: rate): a step of 0.25 in log N (28 % in N) goes with 0.05 of the structure's mass moved.
SPLIT_STEP_SCALE = 0.2


def design_variables(design: DriveDesign) -> np.ndarray:
    """The variables (:data:`DESIGN_VARIABLES`) of one design, (6,)."""
    return np.concatenate([np.log(np.asarray(design.ratio, dtype=float)), np.asarray(mass_split(design), dtype=float)])


def with_variables(design: DriveDesign, theta, catalogue: drive_model.Catalogue | None = None) -> DriveDesign:
    """``design`` at the variables ``theta`` (6,) (traceable): the gear ratios with their gear data
    (:func:`with_ratio`) and the structure mass split (:func:`with_mass_split`)."""
    return with_mass_split(with_ratio(design, theta[:4], catalogue), theta[4:])


def design_gradient(solver) -> Callable:
    """d J*/d theta for a batch of converged solutions, by the envelope theorem, theta the variables
    of :data:`DESIGN_VARIABLES` (log N per joint, the mass split).

    Returns ``gradient(designs, theta, speed, power_limit, step_length, solutions) -> (B, 6)`` (designs
    stacked with :func:`stack`, theta (B, 6); one compiled program for every batch of one size).
    """
    catalogue = drive_model.load_catalogue()

    def parameters_to_model(parameters):
        design, theta, speed, power_limit, step_length = parameters
        return design_gait_model(with_variables(design, theta, catalogue), speed, power_limit, step_length)

    envelope = nlp.optimal_value_gradient(solver.problem, parameters_to_model)

    def gradient(designs, theta, speed, power_limit, step_length, solutions):
        size = theta.shape[0]
        per = lambda value: jnp.broadcast_to(jnp.asarray(value, float), (size,))  # noqa: E731
        parameters = (designs, jnp.asarray(theta, float), per(speed), per(power_limit), per(step_length))
        x = jnp.stack([jnp.asarray(s.x) for s in solutions])
        lam_eq = jnp.stack([jnp.asarray(s.multipliers_eq) for s in solutions])
        lam_in = jnp.stack([jnp.asarray(s.multipliers_in) for s in solutions])
        return np.asarray(envelope(parameters, x, lam_eq, lam_in)[1])
    return gradient


def ratio_gradient(solver) -> Callable:
    """d J*/d log N per joint for a batch of converged solutions, by the envelope theorem (the first
    four columns of :func:`design_gradient`, at each design's own mass split).

    Returns ``gradient(designs, log_ratio, speed, power_limit, step_length, solutions) -> (B, 4)``.
    """
    full = design_gradient(solver)

    def gradient(designs, log_ratio, speed, power_limit, step_length, solutions):
        split = np.asarray(mass_split(designs))  # each design's own
        return full(designs, np.concatenate([np.asarray(log_ratio, float), split], axis=1), speed, power_limit,
                    step_length, solutions)[:, :4]
    return gradient


@dataclasses.dataclass
class CoOptimisation:
    """The path of :func:`co_optimise`: per iteration the ratios (B, 4), the mass splits (B, 2:
    leg_fraction, thigh_share), Joule energies (B,), statuses, and the final designs and gaits."""

    ratios: list
    joule: list
    status: list
    designs: list
    solutions: list
    mass_splits: list = dataclasses.field(default_factory=list)


def _check_bounds(name: str, bounds, unit: str, within=(0.0, np.inf)) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) as arrays; ValueError naming ``bounds`` unless low < high, inside ``within``."""
    try:
        low, high = (np.asarray(b, dtype=float) for b in bounds)
    except (TypeError, ValueError):
        low = high = np.asarray(np.nan)
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and np.all(within[0] < low)
            and np.all(low < high) and np.all(high < within[1])):
        raise ValueError(f"{name} must be (low, high) with {within[0]:g} < low < high < {within[1]:g} ({unit}), "
                         f"got {bounds!r}")
    return low, high


def design_bounds(ratio_bounds=(14.0, 190.0), mass_split_bounds=MASS_SPLIT_BOUNDS) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) of :data:`DESIGN_VARIABLES`, (6,) each: log N within ``ratio_bounds`` (gear ratios),
    the split within ``mass_split_bounds`` ((low, high) per split variable, fractions). ValueError
    naming bounds that are not low < high inside (0, inf) and (0, 1)."""
    ratio_low, ratio_high = _check_bounds("ratio_bounds", ratio_bounds, "gear ratio")
    split_low, split_high = _check_bounds("mass_split_bounds", mass_split_bounds, "fractions", (0.0, 1.0))
    if ratio_low.shape != () or split_low.shape != (2,):
        raise ValueError(f"give ratio_bounds as (low, high) and mass_split_bounds as two values each (leg_fraction, "
                         f"thigh_share), got {ratio_bounds!r} and {mass_split_bounds!r}")
    return (np.concatenate([np.full(4, np.log(ratio_low)), split_low]),
            np.concatenate([np.full(4, np.log(ratio_high)), split_high]))


def co_optimise(solver, designs: list[DriveDesign], speed, power_limit, step_length=0.2, x0=None,
                iterations: int = 6, max_step: float = 0.25, ratio_bounds=(14.0, 190.0),
                min_step: float = 0.02, solutions: list | None = None,
                progress: Callable[[str], None] | None = None, mass_split_bounds=None) -> CoOptimisation:
    """Gear ratios per joint (and, with ``mass_split_bounds``, the structure's mass split) co-optimised
    with the gait, all designs of the batch at once.

    The variables (:data:`DESIGN_VARIABLES`): log N per joint and the mass split (the legs' share of
    the structure mass, the thighs' share of the legs'; the total kept), the latter only with
    ``mass_split_bounds`` ((low, high) per split variable, e.g. :data:`MASS_SPLIT_BOUNDS`; else each
    design keeps its own split). optax's Adam, one optimiser state per design (vmapped), its learning
    rate the design's step (at first ``max_step`` in log N, :data:`SPLIT_STEP_SCALE` times that in
    the split's fractions: Adam's first step moves each variable by about its rate, later ones by less
    where the gradient's sign wavers), the update projected onto the bounds
    (``optax.projections.projection_box``); the gradient from the envelope theorem at each re-solved
    (warm-started) optimum (:func:`design_gradient`). A step that raises the Joule energy or loses
    feasibility is undone (the design keeps its point and optimiser state) and the design's step
    halved. A design is frozen once its step falls below ``min_step`` (log N) or its gait does not
    converge; the loop ends early when every design is frozen (the batch keeps its shape, so a frozen
    design is still solved while others move, but its result is not taken).
    Gear data follow the ratio smoothly (:func:`with_ratio`); snap the result to the catalogue with
    :func:`nearest_gearhead` and re-solve to verify. ``solutions``: the designs' gaits if already solved
    (e.g. by :func:`solve_designs`), else they are solved first.
    """
    designs = checks.sequence("designs", designs, DriveDesign, "DriveDesign")
    checks.integer_in("iterations", iterations, 0, 10_000)
    checks.number_in("max_step", max_step, 0.0, 10.0, "(log N)")
    checks.number_in("min_step", min_step, 0.0, 10.0, "(log N)")
    theta = np.stack([design_variables(d) for d in designs])
    low, high = (np.tile(b, (len(designs), 1)) for b in
                 design_bounds(ratio_bounds, MASS_SPLIT_BOUNDS if mass_split_bounds is None else mass_split_bounds))
    if mass_split_bounds is None:  # each design keeps its own split
        low[:, 4:], high[:, 4:] = theta[:, 4:], theta[:, 4:]
    gait_problem.check_problem(*(per_design(label, value, len(designs)) for label, value in
                         (("speed", speed), ("power_limit", power_limit), ("step_length", step_length))))
    say = progress or (lambda message: None)
    gradient = design_gradient(solver)
    catalogue = drive_model.load_catalogue()
    base = stack(designs)
    theta = np.clip(theta, low, high)
    rates = np.array([1.0] * 4 + [SPLIT_STEP_SCALE] * 2)  # each variable's step per unit of the design's
    step = np.full(len(designs), max_step)
    apply = jax.jit(jax.vmap(lambda d, t: with_variables(d, t, catalogue)))
    adam = optax.inject_hyperparams(optax.adam)(learning_rate=max_step)
    state = jax.vmap(adam.init)(jnp.asarray(theta))
    if solutions is None:
        solutions = solve_designs(solver, unstack(apply(base, jnp.asarray(theta))), speed, power_limit,
                                  step_length, x0=x0, summary=progress)
    elif len(solutions) != len(designs):
        raise ValueError(f"give one solution per design: {len(solutions)} for {len(designs)} designs")
    path = CoOptimisation([], [], [], [], [])

    def record(theta_, solutions_):
        path.ratios.append(np.exp(theta_[:, :4]).tolist())
        path.mass_splits.append(theta_[:, 4:].tolist())
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
        trial, trial_state = _projected_step(adam, jnp.asarray(grad), state, jnp.asarray(theta), jnp.asarray(rates),
                                             jnp.asarray(low), jnp.asarray(high))
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


def _projected_step(optimiser, grad, state, theta, rates, low, high):
    """Every design's optax update of ``theta`` (B, V) with its own state, each variable's update times
    its ``rates`` (V,), projected onto [low, high] ((B, V) each; low = high holds a variable)."""
    updates, state = jax.vmap(optimiser.update)(grad, state, theta)
    return optax.projections.projection_box(optax.apply_updates(theta, rates * updates), low, high), state
