"""Globalisation of the gait solve by many starts: every model from every heuristic start family, the
best kept per model, optionally solved first in a coarser reference space and carried into the fine
one (continuation)."""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import jax.numpy as jnp
import numpy as np

from biped_jax import checks
from biped_jax.gait import problem as gait_problem
from biped_jax.gait import verdict
from biped_jax.gait.solver import GaitSolution, GaitSolver
from biped_jax.optim import nlp


def coarse_settings(settings: gait_problem.GaitSettings, factor: int = 4,
                    substeps: int | None = None) -> gait_problem.GaitSettings:
    """The reference space ``factor`` times coarser (fewer knot spans, the same grading, so the fine
    space contains it when ``spans`` is a multiple of ``factor``), on a grid with ``substeps`` steps per
    span (None: as many as ``settings``), shot in as many segments as divide both (multiple shooting
    kept where it fits): the continuation's first stage."""
    spans = max(1, settings.spans // factor)
    return dataclasses.replace(settings, spans=spans, segments=math.gcd(spans, settings.segments),
                               substeps=settings.substeps if substeps is None else substeps)


def solve_multistart(fine: GaitSolver, names: list[str], models: list[gait_problem.GaitModel],
                     families=gait_problem.START_FAMILIES, coarse: GaitSolver | None = None,
                     progress: Callable[[str, int, dict], None] | None = None,
                     finished: Callable[[str, int], None] | None = None) -> list[GaitSolution]:
    """Globalisation by many starts (and optionally continuation in the reference space).

    Every model from every heuristic family in ``families`` (:data:`gait_problem.START_FAMILIES`) in one
    batch; per model the best converged start (else the least violated) is kept. With ``coarse``, that
    batch runs in the coarse space and the kept starts are carried into the fine space
    (:func:`gait_problem.project`) and solved there, all models in one batch (the study's way: the coarse
    stage is cheap). Without it the starts are solved in the fine space directly (measured on M2:
    every family solved in the 4-span space reaches the same J = 4.62 family, which the fine space
    then keeps, so the coarse stage narrows the search). Each returned solution lists every start's
    outcome in ``starts`` ("kept": the one carried on). No start comes from anywhere but the product's
    own heuristics. ``progress(stage, iteration, row)`` follows the solver of each stage ("starts", then
    "refined space"); ``finished(stage, problems)`` is called when a stage has solved all its problems.
    """
    fine.check_batch(names, models)
    families = checks.sequence("families", families, gait_problem.StartFamily,
                               "start family (gait_problem.START_FAMILIES)")
    count = len(families)
    first_solver = coarse or fine
    x0 = jnp.stack([gait_problem.initial_guess(m, first_solver.settings, fine.leg_length, family=f)
                    for m in models for f in families])
    tagged = (lambda stage: (lambda i, row: progress(stage, i, row))) if progress else (lambda stage: None)
    first = first_solver.solve([f"{n} / {f.name}" for n in names for f in families],
                               [m for m in models for _ in families], x0=x0, progress=tagged("starts"))
    if finished:
        finished("starts", len(first))
    chosen, spreads, best_solutions = [], [], []
    for b in range(len(models)):
        group = first[b * count:(b + 1) * count]
        feasible = [s for s in group if s.status in (nlp.CONVERGED, verdict.GRID_DEPENDENT)]
        best = min(feasible, key=lambda s: s.cost) if feasible else min(group, key=lambda s: s.max_violation)
        spreads.append([{"family": f.name, "status": s.status, "cost": s.cost, "max_violation": s.max_violation,
                         "kept": s is best} for f, s in zip(families, group)])
        best_solutions.append(best)
        if coarse is not None:
            chosen.append(gait_problem.project(best.x, coarse.settings, fine.settings, best.trajectory))
    if coarse is None:
        solutions = [dataclasses.replace(s, name=n) for s, n in zip(best_solutions, names)]
    else:
        solutions = fine.solve(names, models, x0=jnp.asarray(np.stack(chosen)), progress=tagged("refined space"))
        if finished:
            finished("refined space", len(solutions))
    for solution, spread in zip(solutions, spreads):
        solution.starts = spread
    return solutions
