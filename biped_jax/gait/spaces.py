"""The space check: whether a gait's optimum still moves with the knot spans of its joint paths, and the
gait of a finer space where it does.

The refinement check (:mod:`biped_jax.gait.verdict`) re-simulates one decision vector on a rollout grid 4x
finer: it measures the integration's error, not the error of the space the joint paths are drawn from
(clamped B-splines on ``spans`` knot spans), which no re-simulation of that vector can see. At long steps
the space's error dominates: at 0.45 m/s and 0.25 m (12 kg, 20 W) J falls 5.1 % from 16 to 32 knot spans
and 6.6 % to 48, every gait passing the refinement check (``benchmarks/library_spans.py``).

:func:`space_check` solves each gait again, warm, in a space with ``factor`` times the knot spans (nested
when ``factor`` is an integer: the finer space holds the coarser curve exactly, so its solve starts at the
coarser optimum) and reports the finer optimum, with the estimated error of its J: for J converging as
spans^-p the finer space's error is |J_coarse - J_fine| / (factor^p - 1), at most |J_coarse - J_fine| /
(factor - 1) for any order p >= 1. :data:`SPACE_ORDER` takes p = 1, that bound, because the order is
not the same everywhere: against the collocation peer the library's errors at 0.25 m fell from 16 to 48
spans with orders 1.9-2.0 at 0.45-0.75 m/s, but at 0.3 m/s (a slow step of 0.83 s) with order 0.9: there
48 spans are 2.0 % above the optimum (J 5.2350 against 5.1592 in 96 spans and the peer's 5.1323 on 320
segments), which order 2 would have estimated at 0.4 % and order 1 estimates at 1.6 % (2026-12-05,
``benchmarks/library_vs_collocation.py``).
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import jax.numpy as jnp
import numpy as np

from biped_jax import checks
from biped_jax.gait import problem as gait_problem
from biped_jax.gait import verdict
from biped_jax.gait.solver import GaitSolution, GaitSolver
from biped_jax.optim import nlp

#: Status of a gait that converged in its space whose estimated space error exceeds the tolerance.
SPACE_DEPENDENT = "space dependent"
#: Largest estimated relative error of J accepted from the space.
SPACE_TOLERANCE = 0.01
#: The order p of J's convergence in the knot spans the estimate assumes: 1, the bound for every order
#: p >= 1 (measured orders range from 0.9 to 2; see the module's docstring).
SPACE_ORDER = 1.0
#: The first barrier parameter of a space check's solve: it starts at an optimum of the coarser space
#: (nested), and a barrier started at the default pushed one such start into a dearer optimum (at 0.3 m/s,
#: 0.25 m: J 5.4641 in 96 spans from 5.2350 in 48, where from 1e-4 the solve reaches 5.1592).
SPACE_WARM_MU = 1e-4
#: A finer space's optimum dearer than the coarser one's by more than this (relative) is another, worse
#: local optimum (the finer space holds the coarser gait): the coarser gait is kept.
DEARER = 1e-3
#: Statuses whose gaits are checked (a gait that failed its own solve has no optimum to compare).
CHECKED = (nlp.CONVERGED, verdict.GRID_DEPENDENT)


def finer_settings(settings: gait_problem.GaitSettings, factor: int) -> gait_problem.GaitSettings:
    """``settings``' space with ``factor`` times the knot spans and shooting segments (the same grading and
    steps per span: the finer space contains the coarser one)."""
    checks.integer_in("factor", factor, 2, 8)
    return dataclasses.replace(settings, spans=settings.spans * factor, segments=settings.segments * factor)


def finer_solver(solver: GaitSolver, factor: int) -> GaitSolver:
    """A solver like ``solver`` (options, mass class, refinement check) in :func:`finer_settings`' space,
    its barrier started at :data:`SPACE_WARM_MU` (its starts are optima)."""
    return GaitSolver(finer_settings(solver.settings, factor),
                      dataclasses.replace(solver.options, mu_initial=SPACE_WARM_MU),
                      mass_class_template=solver.mass_class, require_refinement=solver.require_refinement,
                      check_refinement=solver.check_refinement)


def space_record(coarse: GaitSolution, fine: GaitSolution, spans: tuple[int, int], tolerance: float) -> dict:
    """The space check of one gait, solved in ``spans`` (coarse, fine) knot spans: J in both spaces, the
    relative change (fine / coarse - 1), the estimated
    relative error of the fine space's J and whether it is within ``tolerance`` (None where the fine
    solve did not end in an optimum, or ended in one dearer than the coarse space's by more than
    :data:`DEARER`: then nothing is known of the space's error)."""
    ratio = spans[1] / spans[0]
    record = {"spans": list(spans), "cost": [coarse.cost, fine.cost], "status_finer": fine.status,
              "change": fine.cost / coarse.cost - 1.0, "error_estimate": None, "passed": None}
    if fine.status in CHECKED and record["change"] > DEARER:
        record["status_finer"] = f"{fine.status} at a dearer optimum"
    elif fine.status in CHECKED:
        record["error_estimate"] = abs(coarse.cost - fine.cost) / (ratio**SPACE_ORDER - 1.0) / abs(fine.cost)
        record["passed"] = record["error_estimate"] <= tolerance
    return record


def space_check(finer: GaitSolver, source: GaitSolver, names: list[str], models: list[gait_problem.GaitModel],
                solutions: list[GaitSolution], tolerance: float = SPACE_TOLERANCE,
                progress: Callable[[int, dict], None] | None = None, statuses: tuple = CHECKED,
                tightening: int | None = None) -> list[GaitSolution]:
    """Every gait of ``solutions`` (solved in ``source``'s space for ``models``) that converged, on its grid
    or beyond it, carried into ``finer``'s space (:func:`biped_jax.gait.problem.project`) and solved
    there warm, all in one batch. Returns per gait the finer space's solution where that solve ended in
    an optimum (converged or grid dependent; :data:`SPACE_DEPENDENT` where it converged but its estimated
    error exceeds ``tolerance``), else a copy of the given one; each with ``space`` (:func:`space_record`,
    with "spans": [coarse, fine]; ``{"skipped": status}`` for a gait not checked) and the given
    ``starts``. ``statuses``: the statuses of the gaits checked (the others are returned as copies); ``tightening``:
    the finer solve's rounds holding the power limit between samples (:meth:`GaitSolver.solve`)."""
    checks.number_in("tolerance", tolerance, 0.0, 1.0, "(a fraction of J)")
    if finer.settings.spans <= source.settings.spans:
        raise ValueError(f"the finer space has {finer.settings.spans} knot spans, the gaits' {source.settings.spans}: "
                         "the space check needs more")
    if len(names) != len(models) or len(models) != len(solutions):
        raise ValueError(f"names ({len(names)}), models ({len(models)}) and solutions ({len(solutions)}) must "
                         "be as many")
    picked = [b for b, s in enumerate(solutions) if s.status in statuses]
    # copies: the caller's solutions keep their own records
    out = [s if s.status in statuses else dataclasses.replace(s, space={"skipped": s.status}) for s in solutions]
    if not picked:
        return out
    x0 = np.stack([gait_problem.project(solutions[b].x, source.settings, finer.settings, solutions[b].trajectory)
                   for b in picked])
    again = finer.solve([names[b] for b in picked], [models[b] for b in picked], x0=jnp.asarray(x0),
                        progress=progress, tightening=tightening)
    spans = (source.settings.spans, finer.settings.spans)
    for b, fine in zip(picked, again):
        record = space_record(solutions[b], fine, spans, tolerance)
        if record["passed"] is None:  # the finer solve found no (cheaper) optimum: the given gait stays
            out[b] = dataclasses.replace(solutions[b], space=record)
            continue
        space_dependent = fine.status == nlp.CONVERGED and not record["passed"]
        out[b] = dataclasses.replace(fine, starts=solutions[b].starts, space=record,
                                     status=SPACE_DEPENDENT if space_dependent else fine.status)
    return out


def goes_on(solution: GaitSolution) -> bool:
    """Whether a gait of a space check's stage goes on to the next, finer stage: its space's estimated
    error exceeds the tolerance (:data:`SPACE_DEPENDENT`), or its power rises above the limit between
    the samples and nothing else fails (a stage before the last holds the power limit by no extra
    solve: the next one, with twice the samples, does)."""
    return solution.status == SPACE_DEPENDENT or (
        solution.status == verdict.GRID_DEPENDENT and verdict.power_alone(solution.refinement))


def refine_spaces(stages: list[GaitSolver], source: GaitSolver, names: list[str],
                  models: list[gait_problem.GaitModel], solutions: list[GaitSolution],
                  tolerance: float = SPACE_TOLERANCE, progress: Callable[[int, dict], None] | None = None
                  ) -> list[GaitSolution]:
    """More knots where a gait needs them: :func:`space_check` into ``stages[0]``'s space, then the gaits
    that :func:`goes_on` into ``stages[1]``'s (each stage's spans more than the last's), and so on. Only
    the last stage holds the power limit between samples by solving again
    (:meth:`GaitSolver.solve`'s tightening): in the library's default grid that round re-solved the
    first stage's whole batch for one gait that went on to the second stage anyway (64 s of 2 cores).
    Each gait's ``space`` lists every space it was solved in ("spans", "cost"), the last pair's change
    and estimated error."""
    out = list(solutions)
    previous = source
    for k, stage in enumerate(stages):
        last = k == len(stages) - 1
        # after the first stage, the gaits of the last stage's space that go on
        picked = list(range(len(out))) if k == 0 else [
            b for b, s in enumerate(out) if goes_on(s) and np.size(s.x) == previous.settings.size]
        if not picked:
            break
        before = [out[b].space for b in picked]
        checked = space_check(stage, previous, [names[b] for b in picked], [models[b] for b in picked],
                              [out[b] for b in picked], tolerance, progress,
                              CHECKED if k == 0 else (SPACE_DEPENDENT, verdict.GRID_DEPENDENT),
                              tightening=None if last else 0)
        for b, solution, earlier in zip(picked, checked, before):
            if k and "spans" in earlier and solution.space is not earlier:
                solution.space = {**solution.space, "spans": earlier["spans"] + solution.space["spans"][1:],
                                  "cost": earlier["cost"] + solution.space["cost"][1:]}
            out[b] = solution
        previous = stage
    return out
