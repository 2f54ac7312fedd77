"""M1-M4 by continuation in the power limit (opt-in, the second generation's pipeline; measured in
``benchmarks/vs_collocation.py``, see README "Continuation in the power limit"): every start family
solved without a power limit, the cheapest gait per model carried to the model's limit."""

from __future__ import annotations

import dataclasses
from typing import Callable

import jax.numpy as jnp
import numpy as np

from biped_jax.gait import problem as gait
from biped_jax.gait import solver as gait_solver
from biped_jax.gait import verdict
from biped_jax.gait.solver import GaitSolution, GaitSolver
from biped_jax.optim import augmented_lagrangian as al
from biped_jax.optim import nlp
from biped_jax.studies.paper import PAPER_MODELS, paper_gait_models


#: The continuation pipeline's space (:func:`solve_paper_models`; opt-in, not yet the study's default,
#: see README "Continuation in the power limit"): 16 cubic knot spans, the stance angle shot in every
#: span (multiple shooting).
CONTINUATION_SETTINGS = gait.GaitSettings(segments=16)

#: Its solver settings at the model's limit: the Gauss-Newton preconditioner refreshed every 10 L-BFGS
#: iterations with the full Gauss-Newton step after each refresh, 80 iterations per inner problem, the
#: penalty from 1e3 growing 3x at most per update, and IPOPT-like acceptable termination (feasible and J
#: settled to 1e-4 over three multiplier updates).
CONTINUATION_OPTIONS = dataclasses.replace(gait_solver.GAIT_SOLVER_OPTIONS, precondition_every=10, max_inner=80,
                                           cap_first_step=False, max_outer=30, penalty_initial=1e3,
                                           penalty_growth=3.0, acceptable_change=1e-4)

#: Its start families: those landing on a flexed knee and the plain straight-stance one.
CONTINUATION_FAMILIES = gait.IMPACT_FAMILIES + gait.START_FAMILIES[:1]

#: The first stage's "no power limit", W (the power constraint is scaled by it: far out of reach).
FREE_POWER_LIMIT = 1e4


def solve_paper_models(solver: GaitSolver, families=CONTINUATION_FAMILIES, rows=PAPER_MODELS,
                       progress: Callable[[str], None] | None = None) -> tuple[list[GaitSolution], list]:
    """M1-M4 by continuation in the power limit (opt-in; measured in ``benchmarks/vs_collocation.py``):
    every family without a power limit (one batch of all models per family, so one compiled program
    serves every stage), the cheapest converged gait per model (else the least violated) then solved at
    the model's limit with ``solver``'s options (:data:`CONTINUATION_OPTIONS` intended, in
    :data:`CONTINUATION_SETTINGS`' space).

    Returns the solutions at the paper's limits (each with ``starts``: every family's outcome without
    the limit and the one carried on) and the free-stage solutions per family."""
    say = progress or (lambda message: None)
    names = [r.name for r in rows]
    free_models = paper_gait_models(rows, [FREE_POWER_LIMIT] * len(rows))
    free_solver = solver.with_options(penalty_initial=100.0, penalty_growth=10.0, max_inner=40, max_outer=20)
    by_family = []
    for k, family in enumerate(families):
        x0 = jnp.stack([gait.initial_guess(m, solver.settings, solver.leg_length, family=family)
                        for m in free_models])
        by_family.append(free_solver.solve(names, free_models, x0=x0, progress=_iterations(
            say, f"no power limit, start {k + 1}/{len(families)} ({family.name})", free_solver.options)))
    chosen, spreads = [], []
    for b in range(len(rows)):
        group = [solutions[b] for solutions in by_family]
        feasible = [s for s in group if s.status in (nlp.CONVERGED, verdict.GRID_DEPENDENT)]
        best = min(feasible, key=lambda s: s.cost) if feasible else min(group, key=lambda s: s.max_violation)
        chosen.append(best.x)
        spreads.append([{"family": f.name, "status": s.status, "cost": s.cost, "max_violation": s.max_violation,
                         "power_limit_W": FREE_POWER_LIMIT, "carried_on": s is best}
                        for f, s in zip(families, group)])
    solutions = solver.solve(names, paper_gait_models(rows), x0=jnp.asarray(np.stack(chosen)),
                             progress=_iterations(say, "at the paper's power limits", solver.options))
    for solution, spread in zip(solutions, spreads):
        solution.starts = spread
    return solutions, by_family


def _iterations(say, label: str, options: al.SolverOptions):
    return lambda i, row: say(f"{label}: outer iteration {i + 1}/{options.max_outer}, largest scaled violation "
                              f"{np.max(row['violation']):.1e}, J = " + ", ".join(f"{c:.3f}" for c in row["cost"]))
