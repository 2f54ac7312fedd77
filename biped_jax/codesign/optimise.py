"""Co-design of the sagittal biped: gear ratios, windings and link masses with the gait, motor in the loop.

The hardware is a :class:`~biped_jax.codesign.drive_design.DriveDesign` (arrays, batchable; its names are
re-exported here and the package re-exports this module's, so ``from biped_jax import codesign`` is the
whole co-design), mapped
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
import functools
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
    knee_drive_offset,
    mass_split,
    nearest_gearhead,
    nearest_winding,
    reflected_inertia,
    robot_design,
    stack,
    unstack,
    winding_range,
    with_knee_drive_offset,
    with_mass_split,
    with_ratio,
    with_torque_constant,
)
from biped_jax.drives import model as drive_model
from biped_jax.gait import problem as gait_problem
from biped_jax.optim import interior_point
from biped_jax.optim import nlp

__all__ = [
    "CoOptimisation",
    "DESIGN_UNITS",
    "DESIGN_VARIABLES",
    "JOINTS",
    "PLACEMENT",
    "RATIOS",
    "SPLIT",
    "SPLIT_STEP_SCALE",
    "WINDINGS",
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
    "gradient_check",
    "projected_gradient",
    "design_gait_model",
    "joint_drives",
    "knee_drive_offset",
    "mass_split",
    "nearest_gearhead",
    "nearest_winding",
    "ratio_gradient",
    "reflected_inertia",
    "robot_design",
    "solve_designs",
    "stack",
    "unstack",
    "winding_range",
    "with_knee_drive_offset",
    "with_mass_split",
    "with_ratio",
    "with_torque_constant",
    "with_variables",
]

#: The co-design's gait solver: the batched interior point warm-started from a solved gait (a
#: neighbouring design's), from a small barrier parameter, as the study's warm stages. The envelope
#: gradient needs a KKT point and its multipliers, not a point that merely stops improving: a solver
#: that stopped at a loose stationarity left neighbouring designs on different local optima, whose
#: envelope gradient and difference of optima disagreed (measured on the tests' 4-span grid at
#: 66:1 * exp(+-0.03); ``tests/test_codesign.py`` compares the two). The iteration cap bounds a design
#: without a gait (a too-high speed in a bisection).
SOLVER_OPTIONS = interior_point.InteriorPointOptions(mu_initial=1e-3, max_iterations=300)


# ----------------------------------------------------------------------------- batch evaluation

def per_design(name: str, value, size: int) -> np.ndarray:
    """``value`` (a number or one per design) as (size,) floats; ValueError naming a mismatch."""
    array = np.asarray(value, dtype=float)
    if array.ndim > 1 or (array.ndim == 1 and array.shape[0] != size):
        raise ValueError(f"{name} must be a number or one value per design ({size}), got shape {array.shape}")
    return np.broadcast_to(array, (size,))


def solve_designs(solver, designs: list[DriveDesign], speed, power_limit, step_length=0.2, x0=None,
                  names: list[str] | None = None, progress=None,
                  summary: Callable[[str], None] | None = None, multipliers=None) -> list:
    """Solves the gait of every design in one batch (one compiled program per batch size).

    ``speed`` (m/s), ``power_limit`` (W) and ``step_length`` (m) are scalars or one value per design;
    x0 (B, n) warm-starts (e.g. a solved reference gait repeated), and so do ``multipliers``
    (equalities (B, m_h), inequalities (B, m_g), e.g. those of solved gaits). Returns ``GaitSolution``s whose cost
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
    solutions = solver.solve(names, models, x0=x0, progress=progress, multipliers=multipliers)
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
    joint power, the largest voltage needed (exact efficiency law), the peak winding current per joint
    (A: what a lower winding costs) and the violations."""
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
        "torque_constant_Nm_per_A": np.asarray(design.torque_constant).tolist(),
        "resistance_ohm": np.asarray(design.resistance).tolist(),
        "peak_current_A": np.max(np.abs(np.asarray(drive_model.current(torque_at_motor, drives))), axis=0).tolist(),
        "supply_voltage_V": float(design.supply_voltage),
        "total_mass_kg": float(design.total_mass),
        "knee_drive_offset": float(knee_drive_offset(design)),
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

JOINTS = ("H1", "K1", "H2", "K2")
#: The co-design's variables per design, in order: log N per joint (H1, K1, H2, K2), log k_t per joint
#: (the winding, N m/A: :func:`with_torque_constant`), the mass split (:data:`MASS_SPLIT_NAMES`:
#: fractions), and how far up their thighs the knee drives sit (:func:`with_knee_drive_offset`).
DESIGN_VARIABLES = (tuple(f"log_ratio_{j}" for j in JOINTS) + tuple(f"log_torque_constant_{j}" for j in JOINTS)
                    + MASS_SPLIT_NAMES + ("knee_drive_offset",))
#: Their units, in the same order.
DESIGN_UNITS = (("log of the gear ratio",) * 4 + ("log of k_t in N m/A",) * 4 + ("fraction",) * 2
                + ("fraction of the thigh from the knee to the hip",))
#: Where each kind sits in the variables.
RATIOS, WINDINGS, SPLIT, PLACEMENT = slice(0, 4), slice(4, 8), slice(8, 10), slice(10, 11)
#: A step of the mass split per unit step of log N (Adam moves every variable by about its learning
#: rate): a step of 0.25 in log N (28 % in N) goes with 0.05 of the structure's mass moved.
SPLIT_STEP_SCALE = 0.2


def design_variables(design: DriveDesign) -> np.ndarray:
    """The variables (:data:`DESIGN_VARIABLES`) of one design, (11,)."""
    return np.concatenate([np.log(np.asarray(design.ratio, dtype=float)),
                           np.log(np.asarray(design.torque_constant, dtype=float)),
                           np.asarray(mass_split(design), dtype=float),
                           np.asarray(knee_drive_offset(design), dtype=float)[None]])


def with_variables(design: DriveDesign, theta, catalogue: drive_model.Catalogue | None = None) -> DriveDesign:
    """``design`` at the variables ``theta`` (11,) (traceable): the gear ratios with their gear data
    (:func:`with_ratio`), the windings (:func:`with_torque_constant`), the structure mass split
    (:func:`with_mass_split`) and the knee drives' place (:func:`with_knee_drive_offset`)."""
    design = with_torque_constant(with_ratio(design, theta[RATIOS], catalogue), theta[WINDINGS])
    return with_knee_drive_offset(with_mass_split(design, theta[SPLIT]), theta[PLACEMENT][0])


#: Each design of a batch at its own variables (B, ...) x (B, V): one compiled program per batch size
#: for every co-optimisation (a jitted map built inside a call would be traced again each call).
_designs_with_variables = jax.jit(jax.vmap(with_variables))


@functools.lru_cache(maxsize=8)
def _envelope(problem: nlp.ConstrainedProblem) -> Callable:
    """The jitted envelope gradient of ``problem`` (a gait solver's) in the design variables: one per
    problem, so that every caller (the co-design loop, the gradient check, a solver's ``using``
    variants) shares its traced and compiled programs."""
    catalogue = drive_model.load_catalogue()

    def parameters_to_model(parameters):
        design, theta, speed, power_limit, step_length = parameters
        return design_gait_model(with_variables(design, theta, catalogue), speed, power_limit, step_length)

    return nlp.optimal_value_gradient(problem, parameters_to_model)


def design_gradient(solver) -> Callable:
    """d J*/d theta for a batch of converged solutions, by the envelope theorem, theta the variables
    of :data:`DESIGN_VARIABLES` (log N and log k_t per joint, the mass split, the knee drives' place).

    Returns ``gradient(designs, theta, speed, power_limit, step_length, solutions) -> (B, 11)`` (designs
    stacked with :func:`stack`, theta (B, 11); one compiled program for every batch of one size).
    """
    envelope = _envelope(solver.problem)

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
    four columns of :func:`design_gradient`, at each design's own windings, mass split and drive
    places).

    Returns ``gradient(designs, log_ratio, speed, power_limit, step_length, solutions) -> (B, 4)``.
    """
    full = design_gradient(solver)

    def gradient(designs, log_ratio, speed, power_limit, step_length, solutions):
        own = np.concatenate([np.log(np.asarray(designs.torque_constant, float)), np.asarray(mass_split(designs)),
                              np.asarray(knee_drive_offset(designs))[:, None]], axis=1)
        return full(designs, np.concatenate([np.asarray(log_ratio, float), own], axis=1), speed, power_limit,
                    step_length, solutions)[:, RATIOS]
    return gradient


#: Steps of :func:`gradient_check`'s differences per variable: 0.0025 in log N and in log k_t, 0.00125
#: in the split's fractions and of the thigh in the knee drives' place. J* is smooth (C1) but its
#: curvature jumps wherever an inequality of the gait starts or stops binding, and the co-design's optima
#: sit near such places: there a difference is off by about the step times the jump, first order.
#: Measured at the full study's best designs (2026-12-06, ``benchmarks/codesign_gradient_check.py``,
#: variables on a bound judged from inside): with four times these steps M2 within 0.009 %, M4 within
#: 0.11 % but K1's ratio 2.0 %; with these M2 0.003 %, M4 0.12 % (K1); the tests' design at 66:1 within
#: 0.5 % at both.
GRADIENT_CHECK_STEPS = (0.0025,) * 8 + (0.00125,) * 3
#: :func:`gradient_check` differences again at this fraction of its steps and judges the gradient there;
#: the given steps' differences are kept to show the convergence.
GRADIENT_CHECK_REFINEMENT = 0.25
#: The barrier parameter :func:`gradient_check`'s re-solves start from: near the converged one, so that
#: a re-solve stays on its design's branch. From the co-design's 1e-3 the barrier first pushes the gait
#: off its active constraints, and on M4 in 16 knot spans the re-solve of a converged design from its
#: own optimum then ended on a neighbouring local optimum 0.05 % dearer (measured 2026-12-04), which
#: spoils differences of 1e-4 J; from 1e-7 it came back to the same optimum to 1e-11.
GRADIENT_CHECK_MU = 1e-7
#: Components of the gradient under this fraction of its largest are judged against that fraction of
#: it (a relative error of a component that is zero, such as a flat winding, means nothing).
GRADIENT_CHECK_FLOOR = 0.01
#: A variable's one-sided differences further apart than this fraction of the larger of them (floored
#: as the relative error) mark a kink of J* within its steps (an active set that changes there, such as
#: a gear limit that starts to bind): there J* has no derivative for central differences to approximate,
#: the envelope gradient is that of the design's own active set, and the variable is left out of
#: ``max_relative_error_where_smooth``. A smooth J* within 1 % steps differs by J'' h, a few per cent.
GRADIENT_CHECK_KINK = 0.25


def gradient_check(solver, designs: list[DriveDesign], solutions: list, speed, power_limit, step_length=0.2,
                   steps=GRADIENT_CHECK_STEPS, batch: int | None = None,
                   refinement: float = GRADIENT_CHECK_REFINEMENT, bounds=None) -> list[dict]:
    """The envelope gradient of J* at each design (its converged solution) against central differences
    of optima re-solved at each variable +- its step (``steps``, one per :data:`DESIGN_VARIABLES`; the
    knee drives' place kept within [0, 1], so one-sided at its ends) and again at +- ``refinement``
    times its step (:data:`GRADIENT_CHECK_REFINEMENT`: the gradient is judged at the finer steps, the
    coarser show the differences converging), warm-started from the design's gait and multipliers from
    the barrier parameter :data:`GRADIENT_CHECK_MU` (the same compiled program): all 4 V re-solves of all
    designs in batches of ``batch`` (default 2 V; the last padded with copies of a design) so that a
    caller's compiled batch size serves. ``speed``, ``power_limit``, ``step_length``: numbers or one per
    design.

    Returns per design a JSON-ready dict: ``envelope`` and ``central_differences`` at the finer steps
    (J per unit of each variable), ``one_sided_differences`` ((backward, forward) per variable at the
    finer steps, from the design's own J*), ``kink`` per variable (:data:`GRADIENT_CHECK_KINK`),
    ``re_solves_converged`` per variable (all four), ``relative_error`` per variable (|envelope -
    central| over |central|, floored at :data:`GRADIENT_CHECK_FLOOR` of the largest |central|: a flat
    variable, such as a winding whose voltage limit is inactive, is judged against the gradient's scale),
    ``max_relative_error`` over the variables whose re-solves converged (None if none did) and
    ``max_relative_error_where_smooth`` over those of them without a kink (None if none); ``steps``
    (the finer) and under ``coarse`` the ``steps``, ``central_differences`` and ``relative_error`` at
    the given steps.

    With ``bounds`` = (low, high) ((V,) each, :func:`design_bounds`) a variable sitting on a bound
    (``at_bound``: +1 upper, -1 lower) is judged from inside only, where the co-design can move it: its
    ``central_differences`` entry is then the second-order one-sided difference through the design's J*
    and the re-solves one finer and one given step inward (J* beyond a bound is no design's: past 190:1
    the gear steps toward the 4-stage data, and a central difference across the bound measures that
    step), its ``coarse`` entry the first-order one over the given step.
    """
    steps = np.asarray(steps, dtype=float)
    size = len(DESIGN_VARIABLES)
    if steps.shape != (size,) or not np.all(steps > 0):
        raise ValueError(f"steps must be {size} positive numbers, got {steps!r}")
    if bounds is not None and (len(bounds) != 2 or any(np.shape(b) != (size,) for b in bounds)):
        raise ValueError(f"bounds must be (low, high) with {size} values each, got {bounds!r}")
    checks.number_in("refinement", refinement, 0.0, 1.0, "(a fraction of the steps)")
    count = len(designs)
    speeds, limits, lengths = (np.repeat(per_design(label, value, count), 4 * size) for label, value in
                               (("speed", speed), ("power_limit", power_limit), ("step_length", step_length)))
    theta = np.stack([design_variables(d) for d in designs])
    fine = refinement * steps
    offsets = np.concatenate([np.diag(fine), -np.diag(fine), np.diag(steps), -np.diag(steps)])
    # the drives' place is a fraction of the thigh: one-sided at its ends (the others extend smoothly)
    points = theta[:, None, :] + offsets[None]  # (count, 4 V, V): the finer steps +, -, then the given +, -
    points[..., PLACEMENT] = np.clip(points[..., PLACEMENT], 0.0, 1.0)
    trial = [with_variables(d, jnp.asarray(t)) for d, row in zip(designs, points) for t in row]
    warm = np.repeat(np.stack([s.x for s in solutions]), 4 * size, axis=0)
    warm_eq, warm_in = (np.repeat(np.stack([getattr(s, f"multipliers_{kind}") for s in solutions]), 4 * size, axis=0)
                        for kind in ("eq", "in"))
    batch = batch or 2 * size
    near = solver.using(dataclasses.replace(solver.options, mu_initial=GRADIENT_CHECK_MU))
    solved = []
    for first in range(0, len(trial), batch):
        chunk = slice(first, first + batch)
        pad = batch - len(trial[chunk])
        extend = lambda a: np.concatenate([a[chunk], np.repeat(a[chunk][:1], pad, axis=0)])  # noqa: E731
        solved += solve_designs(near, trial[chunk] + [trial[first]] * pad, extend(speeds), extend(limits),
                                extend(lengths), x0=extend(warm),
                                multipliers=(extend(warm_eq), extend(warm_in)))[:batch - pad]
    gradient = design_gradient(solver)(stack(designs), theta, speeds[::4 * size], limits[::4 * size],
                                       lengths[::4 * size], solutions)
    results = []
    for k in range(count):
        mine = solved[4 * size * k:4 * size * (k + 1)]
        ok = np.array([all(s.status == nlp.CONVERGED for s in mine[i::size]) for i in range(size)])
        costs = np.array([s.cost for s in mine])
        central, coarse = (_central(costs[half:half + 2 * size], points[k, half:half + 2 * size])
                           for half in (0, 2 * size))
        at_bound = _at_bound(theta[k], bounds)
        inward = _inward(solutions[k].cost, costs, fine, steps, at_bound)
        central, coarse = np.where(at_bound != 0, inward[0], central), np.where(at_bound != 0, inward[1], coarse)
        error, coarse_error = (_relative_error(gradient[k], c) for c in (central, coarse))
        floor = GRADIENT_CHECK_FLOOR * np.max(np.abs(central))
        one_sided = _one_sided(solutions[k].cost, list(costs[:2 * size]), theta[k], points[k, :2 * size])
        kink = kinks(one_sided, floor) & (at_bound == 0)  # at a bound J* is judged from inside only
        smooth = ok & ~kink
        results.append({"variables": list(DESIGN_VARIABLES), "envelope": gradient[k].tolist(),
                        "central_differences": central.tolist(), "one_sided_differences": one_sided.tolist(),
                        "at_bound": at_bound.tolist(), "kink": kink.tolist(), "steps": fine.tolist(),
                        "coarse": {"steps": steps.tolist(), "central_differences": coarse.tolist(),
                                   "relative_error": coarse_error.tolist()},
                        "floor_of_the_largest": GRADIENT_CHECK_FLOOR, "mu_initial": GRADIENT_CHECK_MU,
                        "re_solves_converged": ok.tolist(), "relative_error": error.tolist(),
                        "max_relative_error": float(np.max(error[ok])) if ok.any() else None,
                        "max_relative_error_where_smooth": float(np.max(error[smooth])) if smooth.any() else None})
    return results


def _central(costs: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Central differences per variable (V,) from J* at ``points`` (2 V, V: + steps, then - steps)."""
    size = points.shape[1]
    spans = points[np.arange(size), np.arange(size)] - points[size + np.arange(size), np.arange(size)]
    return (costs[:size] - costs[size:]) / spans


def _relative_error(gradient: np.ndarray, differences: np.ndarray) -> np.ndarray:
    """|gradient - differences| over |differences|, floored at :data:`GRADIENT_CHECK_FLOOR` of the largest."""
    floor = GRADIENT_CHECK_FLOOR * np.max(np.abs(differences))
    return np.abs(gradient - differences) / np.maximum(np.abs(differences), floor)


def _at_bound(theta: np.ndarray, bounds) -> np.ndarray:
    """Per variable +1 at its upper bound, -1 at its lower one, 0 inside (or without ``bounds``), (V,)."""
    if bounds is None:
        return np.zeros(len(theta), int)
    low, high = (np.asarray(b, dtype=float) for b in bounds)
    tight = 1e-9 * np.maximum(1.0, np.abs(theta))
    return np.where(theta >= high - tight, 1, np.where(theta <= low + tight, -1, 0)) * (high > low)


def _inward(cost: float, costs: np.ndarray, fine: np.ndarray, steps: np.ndarray, at_bound: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Derivatives from inside the bounds for the variables at a bound (``at_bound`` +1 upper, -1 lower):
    the second-order one-sided difference through J* at the design and at the finer and the given steps
    inward (Lagrange's three-point rule on 0, h, H with H = ``steps`` and h = ``fine``), and the
    first-order one over the given step; from ``costs`` (4 V: finer +, -, given +, -). (V,) each."""
    size = len(fine)
    v = np.arange(size)
    near = np.where(at_bound > 0, costs[size + v], costs[v])  # J* one finer step inside
    far = np.where(at_bound > 0, costs[3 * size + v], costs[2 * size + v])  # one given step inside
    h, big = fine, steps
    side = np.where(at_bound > 0, -1.0, 1.0)  # samples at 0, s h, s H: forward from a lower bound, else back
    second = side * (-(1 / h + 1 / big) * cost + big / (h * (big - h)) * near - h / (big * (big - h)) * far)
    first = side * (far - cost) / big
    return second, first


def _one_sided(cost: float, costs: list[float], theta: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(backward, forward) differences per variable, (V, 2), from J* at ``theta`` (V,) and at its 2 V
    ``points`` (+ steps, then - steps); a step clipped to nothing (the drives' place at an end of the
    thigh) gives the other side's difference on both."""
    size = len(theta)
    forward_span = points[np.arange(size), np.arange(size)] - theta
    backward_span = theta - points[size + np.arange(size), np.arange(size)]
    costs = np.asarray(costs)
    with np.errstate(divide="ignore", invalid="ignore"):
        forward = np.where(forward_span > 0, (costs[:size] - cost) / forward_span, np.nan)
        backward = np.where(backward_span > 0, (cost - costs[size:]) / backward_span, np.nan)
    forward, backward = np.where(np.isnan(forward), backward, forward), np.where(np.isnan(backward), forward, backward)
    return np.stack([backward, forward], axis=1)


def kinks(one_sided: np.ndarray, floor: float = 0.0) -> np.ndarray:
    """Per variable whether its (backward, forward) differences (V, 2) are further apart than
    :data:`GRADIENT_CHECK_KINK` of the larger of them (at least ``floor``): a kink of J* between the steps."""
    return np.abs(one_sided[:, 1] - one_sided[:, 0]) > GRADIENT_CHECK_KINK * np.maximum(np.abs(one_sided).max(axis=1),
                                                                                          floor)


@dataclasses.dataclass
class CoOptimisation:
    """The path of :func:`co_optimise`: per iteration the ratios (B, 4), the torque constants (B, 4,
    N m/A), the mass splits (B, 2: leg_fraction, thigh_share), the knee drives' places (B,), Joule
    energies (B,), statuses; the final
    designs and gaits, and per design whether it stopped on the projected-gradient rule (``stationary``,
    as judged at the last gradient taken)."""

    ratios: list
    joule: list
    status: list
    designs: list
    solutions: list
    mass_splits: list = dataclasses.field(default_factory=list)
    torque_constants: list = dataclasses.field(default_factory=list)
    knee_drive_offsets: list = dataclasses.field(default_factory=list)
    stationary: list = dataclasses.field(default_factory=list)


def _check_bounds(name: str, bounds, unit: str, within=(0.0, np.inf), closed: bool = False
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) as arrays; ValueError naming ``bounds`` unless low < high, inside ``within`` (open,
    or with ``closed`` the closed interval)."""
    try:
        low, high = (np.asarray(b, dtype=float) for b in bounds)
    except (TypeError, ValueError):
        low = high = np.asarray(np.nan)
    inside = (np.all(within[0] <= low) and np.all(high <= within[1]) if closed else
              np.all(within[0] < low) and np.all(high < within[1]))
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and inside and np.all(low < high)):
        sign = "<=" if closed else "<"
        raise ValueError(f"{name} must be (low, high) with {within[0]:g} {sign} low < high {sign} {within[1]:g} "
                         f"({unit}), got {bounds!r}")
    return low, high


def design_bounds(ratio_bounds=(14.0, 190.0), mass_split_bounds=MASS_SPLIT_BOUNDS,
                  torque_constant_bounds=None, drive_offset_bounds=(0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) of :data:`DESIGN_VARIABLES`, (11,) each: log N within ``ratio_bounds`` (gear ratios),
    log k_t within ``torque_constant_bounds`` (N m/A; default the catalogue's windings,
    :func:`winding_range`), the split within ``mass_split_bounds`` ((low, high) per split variable,
    fractions), the knee drives' place within ``drive_offset_bounds`` (fractions of the thigh, 0 at
    the knee). ValueError naming bounds that are not low < high inside (0, inf), (0, 1) and [0, 1]."""
    ratio_low, ratio_high = _check_bounds("ratio_bounds", ratio_bounds, "gear ratio")
    kt_low, kt_high = _check_bounds("torque_constant_bounds", torque_constant_bounds or winding_range(), "N m/A")
    split_low, split_high = _check_bounds("mass_split_bounds", mass_split_bounds, "fractions", (0.0, 1.0))
    place_low, place_high = _check_bounds("drive_offset_bounds", drive_offset_bounds, "fraction of the thigh",
                                          (0.0, 1.0), closed=True)
    if ratio_low.shape != () or kt_low.shape != () or split_low.shape != (2,) or place_low.shape != ():
        raise ValueError(f"give ratio_bounds, torque_constant_bounds and drive_offset_bounds as (low, high) and "
                         f"mass_split_bounds as two values each (leg_fraction, thigh_share), got {ratio_bounds!r}, "
                         f"{torque_constant_bounds!r}, {drive_offset_bounds!r} and {mass_split_bounds!r}")
    return (np.concatenate([np.full(4, np.log(ratio_low)), np.full(4, np.log(kt_low)), split_low, [place_low]]),
            np.concatenate([np.full(4, np.log(ratio_high)), np.full(4, np.log(kt_high)), split_high, [place_high]]))


def projected_gradient(grad, theta, low, high) -> np.ndarray:
    """The gradient (B, V) with the components that point out of the bounds at a bound, and those of
    held variables (low = high), set to zero: what a projected step can still use."""
    grad, theta = np.asarray(grad, float), np.asarray(theta, float)
    held = low >= high
    blocked = ((theta <= low) & (grad > 0)) | ((theta >= high) & (grad < 0)) | held
    return np.where(blocked, 0.0, grad)


def co_optimise(solver, designs: list[DriveDesign], speed, power_limit, step_length=0.2, x0=None,
                iterations: int = 6, max_step: float = 0.25, ratio_bounds=(14.0, 190.0),
                min_step: float = 0.02, solutions: list | None = None,
                progress: Callable[[str], None] | None = None, mass_split_bounds=None,
                torque_constant_bounds=None, drive_offset_bounds=None,
                gradient_tolerance: float = 1e-3) -> CoOptimisation:
    """Gear ratios per joint (with ``torque_constant_bounds`` the windings, with ``mass_split_bounds``
    the structure's mass split, with ``drive_offset_bounds`` the knee drives' place) co-optimised with
    the gait, all designs of the batch at once.

    The variables (:data:`DESIGN_VARIABLES`): log N per joint, log k_t per joint (the winding along the
    family, :func:`with_torque_constant`; only with ``torque_constant_bounds``, (low, high) in N m/A,
    e.g. :func:`winding_range`), the mass split (the legs' share of the structure mass, the thighs'
    share of the legs'; the total kept; only with ``mass_split_bounds``, (low, high) per split
    variable, e.g. :data:`MASS_SPLIT_BOUNDS`) and how far up their thighs the knee drives sit
    (:func:`with_knee_drive_offset`; only with ``drive_offset_bounds``, e.g. (0, 1)); a variable
    without bounds keeps each design's own value. optax's Adam, one optimiser state per design
    (vmapped), its learning rate the design's step (at first ``max_step`` in log N, log k_t and the
    drives' place, :data:`SPLIT_STEP_SCALE` times that in the split's fractions: Adam's first step
    moves each variable by about its rate, later ones by less where the gradient's sign wavers), the
    update projected onto the bounds (``optax.projections.projection_box``); the gradient from the
    envelope theorem at each re-solved (warm-started) optimum (:func:`design_gradient`). A step that
    raises the Joule energy or loses feasibility is undone (the design keeps its point and optimiser
    state) and the design's step halved.

    Stopping rule, per design: a gradient component (times its variable's rate, so per unit of the
    design's step) of at most ``gradient_tolerance`` times the design's Joule energy counts as zero (no
    full step of that variable could change the energy by more than that fraction to first order; Adam
    would otherwise make a full step of a gradient of 1e-9). A design is frozen once its gait does not
    converge, once its step falls below ``min_step`` (log N), or once its projected gradient
    (:func:`projected_gradient`) is zero: every component flat, or pointing out of the bounds at a bound.
    The loop ends early when every design is frozen (the batch keeps its shape, so a frozen design is
    still solved while others move, but its result is not taken). Gear data follow the ratio smoothly
    (:func:`with_ratio`); snap the result to the catalogue with :func:`nearest_gearhead` and
    :func:`nearest_winding` and re-solve to verify. ``solutions``: the designs' gaits if already solved
    (e.g. by :func:`solve_designs`), else they are solved first.
    """
    designs = checks.sequence("designs", designs, DriveDesign, "DriveDesign")
    checks.integer_in("iterations", iterations, 0, 10_000)
    checks.number_in("max_step", max_step, 0.0, 10.0, "(log N)")
    checks.number_in("min_step", min_step, 0.0, 10.0, "(log N)")
    checks.number_in("gradient_tolerance", gradient_tolerance, 0.0, math.inf, "(relative)")
    theta = np.stack([design_variables(d) for d in designs])
    low, high = (np.tile(b, (len(designs), 1)) for b in design_bounds(
        ratio_bounds, MASS_SPLIT_BOUNDS if mass_split_bounds is None else mass_split_bounds, torque_constant_bounds,
        (0.0, 1.0) if drive_offset_bounds is None else drive_offset_bounds))
    for kind, bounds in ((WINDINGS, torque_constant_bounds), (SPLIT, mass_split_bounds),
                         (PLACEMENT, drive_offset_bounds)):
        if bounds is None:  # each design keeps its own
            low[:, kind], high[:, kind] = theta[:, kind], theta[:, kind]
    gait_problem.check_problem(*(per_design(label, value, len(designs)) for label, value in
                         (("speed", speed), ("power_limit", power_limit), ("step_length", step_length))))
    say = progress or (lambda message: None)
    gradient = design_gradient(solver)
    base = stack(designs)
    designs_at = lambda t: unstack(_designs_with_variables(base, jnp.asarray(t)))  # noqa: E731
    theta = np.clip(theta, low, high)
    rates = np.ones(len(DESIGN_VARIABLES))
    rates[SPLIT] = SPLIT_STEP_SCALE  # each variable's step per unit of the design's
    step = np.full(len(designs), max_step)
    adam = optax.inject_hyperparams(optax.adam)(learning_rate=max_step)
    state = jax.vmap(adam.init)(jnp.asarray(theta))
    if solutions is None:
        solutions = solve_designs(solver, designs_at(theta), speed, power_limit,
                                  step_length, x0=x0, summary=progress)
    elif len(solutions) != len(designs):
        raise ValueError(f"give one solution per design: {len(solutions)} for {len(designs)} designs")
    path = CoOptimisation([], [], [], [], [])
    stationary = np.zeros(len(designs), bool)

    def record(theta_, solutions_):
        path.ratios.append(np.exp(theta_[:, RATIOS]).tolist())
        path.torque_constants.append(np.exp(theta_[:, WINDINGS]).tolist())
        path.mass_splits.append(theta_[:, SPLIT].tolist())
        path.knee_drive_offsets.append(theta_[:, PLACEMENT.start].tolist())
        path.joule.append([s.cost for s in solutions_])
        path.status.append([s.status for s in solutions_])

    record(theta, solutions)
    for k in range(iterations):
        converged = np.array([s.status == nlp.CONVERGED for s in solutions])
        if not (converged & (step >= min_step)).any():
            say(f"co-design stopped after {k} iterations: every design converged to its step floor or failed")
            break
        grad = gradient(base, theta, speed, power_limit, step_length, solutions)
        # components under the tolerance are flat (the winding with the voltage limit inactive): zeroed,
        # since Adam would turn a gradient of 1e-9 into a full step
        flat = np.abs(grad) * rates <= gradient_tolerance * np.array([abs(s.cost) for s in solutions])[:, None]
        grad = np.where(flat, 0.0, grad)
        stationary = converged & ~np.any(projected_gradient(grad, theta, low, high), axis=1)
        moving = converged & (step >= min_step) & ~stationary
        if not moving.any():
            say(f"co-design stopped after {k} iterations: every design stationary (projected gradient at most "
                f"{gradient_tolerance:g} of its energy), at its step floor or failed")
            break
        state.hyperparams["learning_rate"] = jnp.asarray(step)
        trial, trial_state = _projected_step(adam, jnp.asarray(grad), state, jnp.asarray(theta), jnp.asarray(rates),
                                             jnp.asarray(low), jnp.asarray(high))
        trial = np.where(moving[:, None], np.asarray(trial), theta)
        x_warm = jnp.stack([jnp.asarray(s.x) for s in solutions])
        trial_solutions = solve_designs(solver, designs_at(trial), speed, power_limit,
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
    path.designs = designs_at(theta)
    path.solutions = solutions
    path.stationary = stationary.tolist()
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
