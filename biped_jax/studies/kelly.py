"""External validation: Kelly's five-link biped walking benchmark, solved by the library's optimiser.

M. Kelly, "An Introduction to Trajectory Optimization: How to Do Your Own Direct Collocation", SIAM
Review 59(4), 2017, Section 7 (model data: ``robot_specs.KELLY_BIPED``). Kelly's problem: minimise the
integral of the sum of squared joint torques over one step of length 0.5 m in 0.7 s; stance ankle
unactuated; inelastic heel-strike with leg swap; periodic; knees do not hyperextend; the swing foot
leaves the ground upwards and lands downwards at the step length; |u| <= 100 N m.

We solve it with the same single-shooting problem as the paper's models (``biped_jax.gait.problem``), so it
keeps the constraints Kelly's formulation leaves out but a physical walker needs: the swing foot above
the ground, a stance foot that pushes (F_z >= 0) and a non-pulling impact. Kelly imposes no friction
limit and no power limit; both are set far out of reach here (:data:`NO_FRICTION_LIMIT`,
:data:`NO_POWER_LIMIT`) and :func:`active_constraints` reports which constraints bind at the optimum.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import jax.numpy as jnp
import numpy as np

from biped_jax.gait import problem as gait_problem
from biped_jax.gait import report as gait_report
from biped_jax.gait.solver import GaitSolution, GaitSolver
from biped_jax.optim import interior_point
from biped_jax.optim import nlp
from biped_jax.report import outputs
from biped_jax.robots.specs import KELLY_BIPED

STEP_LENGTH = 0.5  # m
STEP_TIME = 0.7  # s
TORQUE_BOUND = 100.0  # N m, Kelly's uMax
#: Friction coefficient standing for "no limit": the cone then only keeps F_z >= 0.
NO_FRICTION_LIMIT = gait_problem.NO_FRICTION_LIMIT
#: Power limit standing for "none", W.
NO_POWER_LIMIT = gait_problem.NO_POWER_LIMIT
#: Settings of the benchmark: 16 cubic knot spans, a shooting segment per span, with Kelly's bounds.
KELLY_SETTINGS = gait_problem.GaitSettings(spans=16, degree=3, substeps=4, torque_bound=TORQUE_BOUND,
                                   friction=NO_FRICTION_LIMIT, knee_max=3.0, segments=16)
#: The batched interior point solves every start in one batch.
KELLY_OPTIONS = interior_point.InteriorPointOptions()
#: Swing-knee lifts of the heuristic starts solved together (one batch, the best converged one wins).
START_LIFTS = (0.3, 0.5, 0.8, 1.1)
#: A constraint whose residual is within this of its bound (own units) counts as active.
ACTIVE_MARGIN = 1e-3


def kelly_model() -> gait_problem.GaitModel:
    """The benchmark as a gait problem (speed L / T, no power limit)."""
    return gait_problem.gait_model("kelly", STEP_LENGTH / STEP_TIME, NO_POWER_LIMIT, STEP_LENGTH)


def starts(model: gait_problem.GaitModel, settings: gait_problem.GaitSettings) -> jnp.ndarray:
    """Heuristic starting points, one per swing lift of :data:`START_LIFTS`, shape (len, n)."""
    return jnp.stack([gait_problem.initial_guess(model, settings, KELLY_BIPED.leg_length, swing_lift=lift)
                      for lift in START_LIFTS])


def active_constraints(solution: GaitSolution, settings: gait_problem.GaitSettings,
                       margin: float = ACTIVE_MARGIN) -> list[str]:
    """Inequality groups with some residual within ``margin`` of its bound at the solution."""
    groups = gait_problem.constraint_groups(solution.trajectory, kelly_model(), settings)
    return [name for name, (kind, _) in gait_problem.CONSTRAINT_GROUPS.items()
            if kind == "inequality" and np.size(groups[name]) and float(np.max(groups[name])) > -margin]


def solve_kelly(settings: gait_problem.GaitSettings = KELLY_SETTINGS,
                progress: Callable[[int, dict], None] | None = None) -> list[GaitSolution]:
    """Solves the benchmark from every start of :func:`starts` in one batch; best (converged, then
    cheapest) first."""
    solver = GaitSolver(settings, KELLY_OPTIONS, mass_class_template="kelly")
    model = kelly_model()
    names = [f"kelly (swing lift {lift})" for lift in START_LIFTS]
    solutions = solver.solve(names, [model] * len(START_LIFTS), x0=starts(model, settings), progress=progress)
    return sorted(solutions, key=lambda s: (s.status != nlp.CONVERGED, s.cost))


def refine(solution: GaitSolution, settings: gait_problem.GaitSettings,
           progress: Callable[[int, dict], None] | None = None) -> GaitSolution:
    """Re-solves on a grid twice as fine, warm-started from ``solution`` (the decision vector does not
    depend on the grid)."""
    solver = GaitSolver(gait_problem.refined(settings, 2), KELLY_OPTIONS, mass_class_template="kelly")
    fine, = solver.solve(["kelly"], [kelly_model()], x0=jnp.asarray(solution.x)[None], progress=progress)
    return fine


def kelly_record(solutions: list[GaitSolution], fine: GaitSolution, settings: gait_problem.GaitSettings) -> dict:
    """kelly.json: the fine-grid solution's cost, status and violations, its refinement check (J on a
    grid four times finer again), the coarse grid's cost and every start's outcome. The quadrature and
    the integrator are 4th order, so the coarse, fine and refined costs agree to the digits shown
    rather than needing an extrapolation."""
    coarse = solutions[0]
    record = gait_report.results_record(fine)
    record.update({
        "benchmark": "Kelly 2017, five-link biped, SIAM Review 59(4) Section 7",
        "cost_unit": "N^2 m^2 s",
        "steps": gait_problem.refined(settings, 2).steps,
        "cost_coarse": coarse.cost,
        "steps_coarse": settings.steps,
        "cost_refined": fine.refinement["cost"],
        "steps_refined": fine.refinement["steps"],
        "active_constraints": active_constraints(fine, gait_problem.refined(settings, 2)),
        "settings": dataclasses.asdict(settings),
        "starts": [{"name": s.name, "status": s.status, "cost": s.cost, "max_violation": s.max_violation}
                   for s in solutions],
    })
    return record


def run_kelly(out: Path, settings: gait_problem.GaitSettings = KELLY_SETTINGS,
              progress: Callable[[str], None] | None = None) -> dict:
    """Solves the benchmark on ``settings``' grid and one twice as fine; writes kelly.json and
    kelly_step.png (angles, rates, torques, power of the fine-grid step)."""
    say = progress or (lambda message: None)
    out.mkdir(parents=True, exist_ok=True)

    def report(i, row):
        say(f"interior-point iteration {i}: best J {np.min(row['cost']):.2f}, largest scaled violation "
            f"{np.max(row['violation']):.1e}, {int(np.sum(row['done']))} of {row['done'].size} starts finished")

    say(f"compiling and solving Kelly's five-link biped on {settings.steps} Runge-Kutta steps from "
        f"{len(START_LIFTS)} starts in one batch")
    solutions = solve_kelly(settings, progress=report)
    steps = gait_problem.refined(settings, 2).steps
    say(f"{solutions[0].status}, J = {solutions[0].cost:.2f}; refining on {steps} steps")
    fine = refine(solutions[0], settings, progress=report)
    record = kelly_record(solutions, fine, settings)
    outputs.write_json(out / "kelly.json", record)
    gait_report.plot_figure_2([fine], out / "kelly_step.png",
                              title=f"Kelly's five-link biped: optimal step, J = {fine.cost:.2f} N^2 m^2 s")
    return record
