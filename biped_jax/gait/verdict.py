"""The verdict on a solved gait: every constraint group's violation in its own unit on a fresh
re-simulation, the refinement check (the same decision vector re-simulated on a grid
:data:`biped_jax.gait.problem.REFINEMENT` times finer: J changes by less than
:data:`REFINED_COST_CHANGE`, every group within :func:`refined_tolerance`), and the reported status
(:func:`classify`; :data:`GRID_DEPENDENT` for a gait that converged on its grid only)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax.gait import problem as gait_problem
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
#: The refinement check's tolerance of the gears' input speed as a joint speed, rad/s: a bound held at
#: the samples is passed between them by the curvature of the speed, as the power limit is; 0.05 rad/s
#: is 0.5-1.5 % of the GP 32 A's 6000 rpm over 66-190:1 (the gear torque's 0.05 N m is about 1 % of
#: its 6.5 N m; the 1e-3 rad/s of the other rates, the shooting defects, would fail every gait that
#: uses its gear's full speed).
REFINED_GEAR_SPEED = 0.05


def refined_tolerance(group: str, power_limit):
    """The refinement check's tolerance for a constraint group, in the group's own unit: 1 % of M_W for
    the power limit (an array of limits, W, gives an array), :data:`REFINED_GEAR_SPEED` for the gears'
    input speed, 1 N for forces, 1e-3 rad/s for other rates, 0.1 mm for lengths, 1e-3 rad for angles."""
    if group == "power_limit":
        return REFINED_POWER_FRACTION * power_limit
    if group == "gear_input_speed":
        return REFINED_GEAR_SPEED
    return _REFINED_TOLERANCE[gait_problem.CONSTRAINT_GROUPS[group][1]]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class GridCheck:
    """What the verdict reads of one rollout (or a batch: every leaf with a leading dimension B).

    Attributes:
      trajectory: the simulated step (:class:`~biped_jax.gait.problem.GaitTrajectory`).
      violations: each constraint group's largest violation in its own unit.
      energy: the objective on this grid, the Joule energy of ``model.drives`` (J = integral of u^T u,
        N^2 m^2 s, for ideal drives).
      finite: whether the decision vector and the torques are finite (bool).
    """

    trajectory: gait_problem.GaitTrajectory
    violations: dict
    energy: jax.Array
    finite: jax.Array


def rollout_check(x, model: gait_problem.GaitModel, biped, settings: gait_problem.GaitSettings) -> GridCheck:
    """One decision vector ``x`` (n,) re-simulated on the grid ``settings`` with what the verdict reads
    of it. Pure and traceable: the solver vmaps it over a batch, one program per grid."""
    trajectory = gait_problem.simulate(x, model, biped, settings)
    groups = gait_problem.constraint_groups(trajectory, model, settings)
    finite = jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(trajectory.u))
    return GridCheck(trajectory, gait_problem.violations(groups), gait_problem.joule_energy(trajectory, model.drives),
                     finite)


def power_alone(record: dict) -> bool:
    """Whether a refinement record (:func:`refinement_records`) failed on the power limit and nothing
    else: a gait that holds the limit on its grid and exceeds it between the samples."""
    return record.get("failed") == ["power_limit"]


def refinement_records(coarse_cost, fine: GridCheck, power_limit, steps: int) -> list[dict]:
    """The refinement check of a batch of B solutions: ``coarse_cost`` (B,) J on the solve grid,
    ``fine`` their :class:`GridCheck` on the grid ``steps`` samples long (numpy, leading dimension B),
    ``power_limit`` (B,) W. Per solution J and each group's violation on the finer grid, and whether
    it passes (J moves by at most :data:`REFINED_COST_CHANGE`, every group within
    :func:`refined_tolerance`); the failed checks named, "cost" first."""
    coarse = np.asarray(coarse_cost, dtype=float)
    cost = np.asarray(fine.energy, dtype=float)
    limit = np.asarray(power_limit, dtype=float)
    violations = {k: np.asarray(v, dtype=float) for k, v in fine.violations.items()}
    change = np.abs(cost - coarse) / np.maximum(np.abs(coarse), 1e-12)
    over = {k: ~(v <= refined_tolerance(k, limit)) for k, v in violations.items()}
    records = []
    for b in range(cost.shape[0]):
        failed = sorted(k for k in violations if over[k][b])
        if not change[b] <= REFINED_COST_CHANGE:
            failed.insert(0, "cost")
        records.append({"steps": steps, "cost": float(cost[b]), "cost_change": float(change[b]),
                        "violations": {k: float(v[b]) for k, v in violations.items()},
                        "power_margin_fraction": float(violations["power_limit"][b] / limit[b]),
                        "failed": failed, "passed": not failed})
    return records


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
