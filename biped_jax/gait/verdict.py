"""The verdict on a solved gait: every constraint group's violation in its own unit on a fresh
re-simulation, the refinement check (the same decision vector re-simulated on a grid
:data:`biped_jax.gait.problem.REFINEMENT` times finer: J changes by less than
:data:`REFINED_COST_CHANGE`, every group within :func:`refined_tolerance`), and the reported status
(:func:`classify`; :data:`GRID_DEPENDENT` for a gait that converged on its grid only)."""

from __future__ import annotations

import functools

import jax

from biped_jax.gait import problem as gait
from biped_jax.optim import nlp

#: Largest violation accepted, in each constraint group's own unit.
VIOLATION_TOLERANCE = 1e-4

#: Status of a solution that converged on its grid but fails the refinement check.
GRID_DEPENDENT = "grid dependent"

#: Largest relative change of J between the solution's grid and the refined one.
REFINED_COST_CHANGE = 5e-3

#: Largest violation on the refined grid per unit (power: a fraction of M_W, see refined_tolerance).
_REFINED_TOLERANCE = {"m": 1e-4, "rad": 1e-3, "rad/s": 1e-3, "m/s": 1e-3, "N": 1.0, "N m": 0.05,
                      "N s": 1e-3, "V": 0.1}
#: The refinement check's power tolerance, a fraction of M_W.
REFINED_POWER_FRACTION = 0.01


def refined_tolerance(group: str, power_limit: float) -> float:
    """The refinement check's tolerance for a constraint group, in the group's own unit: 1 % of M_W for
    the power limit, 1 N for forces, 1e-3 rad/s for rates, 0.1 mm for lengths, 1e-3 rad for angles."""
    if group == "power_limit":
        return REFINED_POWER_FRACTION * power_limit
    return _REFINED_TOLERANCE[gait.CONSTRAINT_GROUPS[group][1]]


@functools.partial(jax.jit, static_argnames="settings")
def grid_check(trajectory: gait.GaitTrajectory, model: gait.GaitModel, settings: gait.GaitSettings):
    """Each constraint group's largest violation (its own unit) and the objective (the Joule energy of
    ``model.drives``; the integral of u^T u for ideal drives) of one rollout on the grid ``settings``.
    Compiled: one program per grid instead of an eager XLA program per operation and shape."""
    groups = gait.constraint_groups(trajectory, model, settings)
    return gait.violations(groups), gait.joule_energy(trajectory, model.drives)


def refinement_record(coarse_cost: float, fine: gait.GaitTrajectory, model: gait.GaitModel,
                      settings: gait.GaitSettings) -> dict:
    """The refinement check of one solution: J and each group's violation on the finer grid
    ``settings`` (the same decision vector), and whether it passes. J is the problem's own objective,
    the Joule energy of ``model.drives`` (the integral of u^T u for the paper's ideal drives)."""
    groups, cost = grid_check(fine, model, settings)
    violations = {k: float(v) for k, v in groups.items()}
    cost = float(cost)
    change = abs(cost - coarse_cost) / max(abs(coarse_cost), 1e-12)
    limit = float(model.power_limit)
    failed = sorted(k for k, v in violations.items() if not v <= refined_tolerance(k, limit))
    if not change <= REFINED_COST_CHANGE:
        failed.insert(0, "cost")
    return {"steps": settings.steps, "cost": cost, "cost_change": change, "violations": violations,
            "power_margin_fraction": violations["power_limit"] / limit, "failed": failed,
            "passed": not failed}


def classify(solver_status: str, finite: bool, violations: dict, refinement: dict,
             require_refinement: bool = True) -> str:
    """The reported status of one solve: ``diverged`` for a NaN anywhere, ``iteration limit`` when the
    solver's scaled feasibility is not met in every group's own unit, :data:`GRID_DEPENDENT` when it
    converged on its grid but fails the refinement check (unless ``require_refinement`` is off), else
    the solver's own status."""
    if not finite:
        return nlp.DIVERGED
    if solver_status == nlp.CONVERGED and max(violations.values()) > VIOLATION_TOLERANCE:
        return nlp.ITERATION_LIMIT  # feasible only in the scaled sense: keep iterating
    if solver_status == nlp.CONVERGED and require_refinement and not refinement["passed"]:
        return GRID_DEPENDENT
    return solver_status
