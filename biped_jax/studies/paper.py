"""The paper's study (Section 2.2): models M1-M4, their optimal steps, the 20 W question and the
smallest power limit at which each model still walks."""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Callable

import jax.numpy as jnp
import numpy as np

from biped_jax.drives import selection as drive_selection
from biped_jax.gait import problem as gait_problem
from biped_jax.gait import report as gait_report
from biped_jax.gait import multistart
from biped_jax.gait import verdict
from biped_jax.gait.solver import LIMIT_ENERGY_WEIGHTS, GaitSolution, GaitSolver
from biped_jax.optim import interior_point
from biped_jax.optim import nlp
from biped_jax.report import outputs
from biped_jax.studies import drive_train


@dataclasses.dataclass(frozen=True)
class PaperModel:
    """A row of the paper's Table 3 with the power limit of Section 2.2."""

    name: str
    mass_class: str
    speed: float
    power_limit: float


#: Table 3 of the paper, power limits of Section 2.2 (docs/gait-problem.md).
PAPER_MODELS = (PaperModel("M1", "12kg", 0.417, 20.0), PaperModel("M2", "12kg", 0.555, 20.0),
                PaperModel("M3", "18kg", 0.417, 25.0), PaperModel("M4", "18kg", 0.555, 40.0))


def paper_gait_models(rows, power_limits=None, step_length: float = 0.2) -> list[gait_problem.GaitModel]:
    """The gait problems of ``rows`` (:data:`PAPER_MODELS` or some of them), at their own power limits
    or at ``power_limits`` (W, one per row); step length in m."""
    limits = power_limits if power_limits is not None else [r.power_limit for r in rows]
    return [gait_problem.gait_model(r.mass_class, r.speed, float(p), step_length) for r, p in zip(rows, limits)]


def minimal_power_limits(solver: GaitSolver, solutions: list[GaitSolution], models: list[gait_problem.GaitModel],
                         progress: Callable[[int, dict], None] | None = None,
                         coarse: GaitSolver | None = None) -> list[dict]:
    """The smallest power limit M_W per model (all models in one call): the limit itself minimised over
    the gait (:meth:`GaitSolver.minimise_power_limit`, the interior point's continuation),
    started from each model's converged gait at its own limit (``solutions[b]`` solved for
    ``models[b]``); with ``coarse``, first in its space (the gaits carried there by least squares, the
    continuation of :data:`COARSE_LIMIT_WEIGHTS`), then from there in
    ``solver``'s (its last stages, :data:`STUDY_LIMIT_WEIGHTS`: an iteration in the 4x coarser space
    costs a tenth).

    A gait whose solver stopped at its iteration limit still gives a limit (an upper bound, feasible on
    both grids, with that status); a gait infeasible on either grid gives none.

    Returns per model {"min_power_limit_W": the smallest limit whose gait keeps it on the solve grid
    and on the 4x finer one (None when the gait found is not converged there, or the model had no
    converged gait to start from), "min_power_solve_grid_W": the limit reached on the solve grid,
    "min_power_status": the gait's status at that limit, "min_power_cost": its J (not minimised),
    "min_power_gait": the :class:`GaitSolution`}.
    """
    usable = [b for b, s in enumerate(solutions) if s.status == nlp.CONVERGED]
    found = {}
    if usable:
        rows = [solutions[b] for b in usable]
        models = [models[b] for b in usable]
        names = [s.name for s in rows]
        x0 = np.stack([s.x for s in rows])

        def tagged(stage):
            return (lambda i, row: progress(i, {**row, "space": stage})) if progress else None
        if coarse is not None:
            carried = np.stack([gait_problem.project(s.x, solver.settings, coarse.settings,
                                                     s.trajectory) for s in rows])
            first = coarse.minimise_power_limit(names, models, carried, progress=tagged("coarse space"),
                                                energy_weights=COARSE_LIMIT_WEIGHTS)
            # from the coarse space's gait and limit (2 % above it: the carried gait is close, not equal)
            carried_on = [c.max_violation <= verdict.VIOLATION_TOLERANCE for c in first]
            x0 = np.stack([gait_problem.project(c.x, coarse.settings, solver.settings, c.trajectory) if ok else s.x
                           for c, s, ok in zip(first, rows, carried_on)])
            models = [dataclasses.replace(m, power_limit=jnp.asarray(1.02 * c.power_limit_W)) if ok else m
                      for m, c, ok in zip(models, first, carried_on)]
        minima = solver.minimise_power_limit(names, models, x0, progress=tagged("study space"),
                                             energy_weights=STUDY_LIMIT_WEIGHTS if coarse is not None
                                             else LIMIT_ENERGY_WEIGHTS)
        found = dict(zip(usable, minima))
    records = []
    for b, solution in enumerate(solutions):
        if b not in found:
            records.append({"min_power_limit_W": None, "min_power_solve_grid_W": None,
                            "min_power_status": f"no converged gait at the model's own limit ({solution.status})",
                            "min_power_cost": None, "min_power_gait": None})
            continue
        minimum = found[b]
        feasible = minimum.status in (nlp.CONVERGED, nlp.ITERATION_LIMIT) and minimum.refinement["passed"] \
            and minimum.max_violation <= verdict.VIOLATION_TOLERANCE
        records.append({"min_power_limit_W": minimum.power_limit_W if feasible else None,
                        "min_power_solve_grid_W": minimum.refinement["solve_grid_limit_W"],
                        "min_power_status": minimum.status, "min_power_cost": minimum.cost,
                        "min_power_gait": minimum})
    return records


def _number(value, spec: str) -> str:
    return "-" if value is None else format(value, spec)


#: The study's reference space and grid: 48 cubic knot spans graded 0.5 towards the impacts, the stance
#: angle shot in every span, 4 Runge-Kutta steps per span (192 in all). Against the collocation peer
#: (README, "Gait optimiser"): 16 spans left J 1.3-1.7 % above it (M2 at 20 W: 2.8506, grid converged),
#: 32 spans 0.3-1.0 % (M4 at 20 W: 7.0165, the same from five starts: the space's limit, not a local
#: optimum), 48 spans 0.1-0.5 %. The grid: 8 steps per span of 16 (128 in all) left M2's power 0.216 W
#: (1.08 % of M_W) over the limit between grid points (a 4x finer grid), 192 steps keep that within the
#: refinement check's 1 %, and a Jacobian's cost grows with the steps, not the spans.
STUDY_SETTINGS = gait_problem.GaitSettings(spans=48, segments=48, substeps=4)

#: The study's start families: every heuristic family, the flexed-impact ones included.
STUDY_FAMILIES = gait_problem.START_FAMILIES + gait_problem.IMPACT_FAMILIES

#: ``biped-jax reproduce --quick``: a first look in a few minutes, not the study: 8 knot spans (the
#: starts in 2), three start families; every file it writes says so (:data:`QUICK_STAMP`).
QUICK_SETTINGS = gait_problem.GaitSettings(spans=8, segments=8, substeps=6)
QUICK_FAMILIES = (gait_problem.START_FAMILIES[1], gait_problem.IMPACT_FAMILIES[0], gait_problem.IMPACT_FAMILIES[1])
QUICK_STAMP = ("QUICK LOOK (biped-jax reproduce --quick): 8 knot spans, 3 start families; coarse, not the "
               "study's result")

#: The batched interior point (:mod:`biped_jax.optim.interior_point`) in every stage: from the heuristic
#: starts a cold start (mu = 0.1); warm from a nearby optimum (the coarse space's carried into the study's,
#: the paper's limit's at 20 W, a gait at its own limit for the smallest limit) from mu = 1e-5. From 1e-3
#: the barrier of the few thousand inequality rows first pushed the gait far inside (M1's J from 1.81 to
#: 2.87 in 19 iterations) and the next barrier problems brought it back: measured on the six cases (2-core
#: CPU, 2026-12-05), the study's space took 48 iterations from the coarse gaits and 52 for 20 W from 1e-3,
#: 45 and 40 from 1e-4, 26 and 29 from 1e-5 (25 and 25 from 1e-6), every J equal to 7 digits (the six
#: cases warm 44.8, 43.3, 35.3 s). In the smallest power limit's study space from 1e-3 the limit first rose
#: to twice the start's (the barrier's centring moves t by about mu times the 1,544 power rows, measured
#: 2026-12-04); its coarse stage starts from gaits carried into the coarse space, not from its optima,
#: from 1e-3 (:data:`COARSE_POWER_OPTIONS`). A batch runs until its slowest problem stops, so the coarse
#: starts' stage is capped at 80 iterations and the others at 150 per stage of a continuation. All share
#: the compiled iterations.
IP_OPTIONS = interior_point.InteriorPointOptions(max_iterations=80)
IP_WARM_OPTIONS = interior_point.InteriorPointOptions(mu_initial=1e-5, max_iterations=150)
COARSE_POWER_OPTIONS = dataclasses.replace(IP_WARM_OPTIONS, mu_initial=1e-3)
#: The starts' stage in the coarse space: once 95 % of its starts have finished the batch stops, the rest
#: ending "iteration limit" (a batched loop costs every start an iteration until the last one stops).
#: Measured on the study's 36 starts on the coarse space's grid of 4 steps per span (2-core CPU, warm
#: cache, 2026-12-05): none finished before iteration 41, 35 by 60, the last ran to 80 and ended
#: infeasible; with this quorum the six cases (M1-M4, M3 and M4 at 20 W) took 75.9 s instead of 91.1 s,
#: every model's J and kept family unchanged (with 10 iterations of patience 84.7 s). On the grid of 2
#: steps per span (:func:`coarse_substeps`) all 36 converge by iteration 56.
STARTS_OPTIONS = dataclasses.replace(IP_OPTIONS, quorum=0.95, patience=0)
#: The smallest limit's continuation in the 4x coarser space: the weights of
#: :data:`~biped_jax.gait.solver.LIMIT_ENERGY_WEIGHTS` less 0.001, after whose stage the stage at 0 reached
#: the same gaits (the study space's start equal to 8 digits; 2-core CPU, 2026-12-05); from (0.1, 0.01)
#: alone the study's space stopped at its iteration limit for M1.
COARSE_LIMIT_WEIGHTS = (0.1, 0.01, 0.0)
#: The continuation's last stages in the study's space (the coarse space runs
#: :data:`COARSE_LIMIT_WEIGHTS`). Measured on M1-M4 from the coarse space's gaits (2-core CPU, 2026-12-05):
#: (0.01, 0) reaches the same four limits as (0.01, 0.001, 0) to 5 digits (1.48284 / 2.28427 / 2.23274 /
#: 3.42658 W) in 226 iterations of the batch instead of 325 (89 s against 126 s); (0.001, 0) the same but
#: M4 3.42998 W in 246; the plain epigraph form alone (w = 0) converges in 122 but to worse local minima
#: (M1 and M3 +0.8 %). The first stage starts from :data:`IP_WARM_OPTIONS`' mu = 1e-5 (from 1e-4 or 1e-6
#: M3 or all four stopped at the iteration limit), every later one from
#: :data:`~biped_jax.gait.solver.LIMIT_WARM_MU` = 1e-4, whose barrier pushes the gait inside before the
#: limit falls again: from 1e-6 the limits were 1-6 % worse, and an adaptive barrier (Mehrotra's probing)
#: found M1 and M3 0.8 and 3.7 % worse or stopped at the iteration limit (benchmarks/RESULTS.md).
STUDY_LIMIT_WEIGHTS = (0.01, 0.0)


@dataclasses.dataclass(frozen=True)
class StudySolvers:
    """The study's solvers, sharing compiled programs where they share a space.

    Attributes:
      fine: in the study's space (every reported gait), warm-started.
      coarse: in the 4x coarser space on a grid of :func:`coarse_substeps`, choosing each model's start
        (no refinement check).
      coarse_power: the smallest power limit's first stages in the 4x coarser space (on the study's steps
        per span, :data:`COARSE_POWER_OPTIONS`); its last stages run in ``fine``.
      families: the heuristic start families solved in the coarse space.
    """

    fine: GaitSolver
    coarse: GaitSolver
    coarse_power: GaitSolver
    families: tuple


def coarse_substeps(settings: gait_problem.GaitSettings) -> int:
    """Runge-Kutta steps per knot span of the coarse space's grid: half of ``settings``' where that stays
    even (Simpson's rule pairs the steps), else as many. The coarse stage only chooses each model's start
    and the continuation's first gait, and an iteration's cost grows with the steps: measured on the
    study's six cases (2-core CPU, warm cache, 2026-12-05), its 36 starts on 12 spans x 2 steps instead
    of x 4 all converged (one M4 start had ended infeasible), each model's starts to one optimum, the
    six cases in 44.8 s instead of 63.3 s with every J equal to 7 digits."""
    half = settings.substeps // 2
    return half if half % 2 == 0 and half > 0 else settings.substeps


def study_solvers(settings: gait_problem.GaitSettings = STUDY_SETTINGS) -> StudySolvers:
    """The solvers of :func:`run_study` (and of ``benchmarks/vs_collocation.py``) in ``settings``' space
    and its 4x coarser one (on a grid of :func:`coarse_substeps`)."""
    fine = GaitSolver(settings, IP_WARM_OPTIONS)
    # the coarse stage only chooses starts: no refinement check, so its refined rollout is never compiled
    coarse = GaitSolver(multistart.coarse_settings(settings, substeps=coarse_substeps(settings)), STARTS_OPTIONS,
                        check_refinement=False)
    # the smallest power limit's first stages on the study's steps per span: on half of them the coarse
    # gaits used the power between the samples, and from them the study's space ended infeasible or at the
    # iteration limit for M3 and M4 (measured 2026-12-05)
    coarse_power = GaitSolver(multistart.coarse_settings(settings), COARSE_POWER_OPTIONS, check_refinement=False)
    return StudySolvers(fine, coarse, coarse_power, STUDY_FAMILIES)


def run_study(out: Path, settings: gait_problem.GaitSettings = STUDY_SETTINGS,
              progress: Callable[..., None] | None = None, resume: bool = False,
              families: tuple | None = None) -> dict:
    """Solves M1-M4 (many starts in a coarse reference space, then the best per model in ``settings``'
    space: :func:`biped_jax.gait.multistart.solve_multistart`), M1-M4 at 20 W (warm-started)
    and the minimal power limits; writes
    results.json, tables.md, fig2_trajectories.png, fig3_torque_rpm.png, convergence.png,
    trajectories.npz, and the drive-train part (drives.json, drives.md, fig4/fig5). Each finished
    stage is kept in ``out/stages`` (:func:`biped_jax.report.outputs.stage`); ``resume`` takes the
    stages found there for these settings instead of solving them again. ``families`` replaces the
    study's start families (:data:`STUDY_FAMILIES`). ``progress(message, task=None)`` hears every iteration;
    ``task`` = (stage, problems done, problems in the stage) counts the work
    (:func:`biped_jax.report.progress.live_progress`)."""
    solvers = study_solvers(settings)
    solver, coarse, families = solvers.fine, solvers.coarse, families or solvers.families
    say = progress or (lambda message, task=None: None)
    out.mkdir(parents=True, exist_ok=True)
    key = {"settings": dataclasses.asdict(settings), "method": "ip", "families": [f.name for f in families]}
    names = [r.name for r in PAPER_MODELS]

    report = functools.partial(_stage_report, say, solver.options)
    done = functools.partial(_done, say)
    say(f"compiling the gait problems; M1-M4 from {len(families)} starts each ({coarse.settings.spans} knot "
        f"spans), then the best in {settings.spans} spans")
    solutions = outputs.stage(out, "paper_models", key, lambda: multistart.solve_multistart(
        solver, names, paper_gait_models(PAPER_MODELS), families=families, coarse=coarse,
        progress=lambda part, i, row: report(f"M1-M4 {part}")(i, row),
        finished=lambda part, count: say(f"M1-M4 {part}: done", task=(f"M1-M4 {part}", count, count))),
        resume, say)
    say("the four models at M_W = 20 W")
    at_20 = outputs.stage(out, "at_20W", key, lambda: done("20 W", solver.solve(
        names, paper_gait_models(PAPER_MODELS, [20.0] * 4), x0=jnp.stack([jnp.asarray(s.x) for s in solutions]),
        progress=report("20 W"))), resume, say)
    # A gait feasible at 20 W is feasible at every looser limit: where it costs less than the solution
    # found at the paper's limit, that solution was a worse local optimum; restart from it. (Cheaper by
    # more than 1e-4 relative: a solve ended on acceptable termination is settled to about 1e-6-1e-5.)
    better = [b for b, (s, t) in enumerate(zip(solutions, at_20)) if t.status == nlp.CONVERGED
              and s.power_limit_W >= 20.0 and t.cost < s.cost * (1 - 1e-4)]
    if better:
        say("restarting " + ", ".join(names[b] for b in better) + " from their cheaper 20 W gaits")
        starts = jnp.stack([jnp.asarray(at_20[b].x if b in better else s.x) for b, s in enumerate(solutions)])
        restarted = outputs.stage(out, "restart", key, lambda: done("restart", solver.solve(
            names, paper_gait_models(PAPER_MODELS), x0=starts, progress=report("restart"))), resume, say)
        solutions = [r if (b in better and r.status == nlp.CONVERGED and r.cost < s.cost) else s
                     for b, (s, r) in enumerate(zip(solutions, restarted))]
    say("smallest feasible power limit per model")
    minimal = outputs.stage(out, "minimal_power_limits", key, lambda: done(
        "smallest power limit (study space)", minimal_power_limits(
            solvers.fine, solutions, paper_gait_models(PAPER_MODELS), coarse=solvers.coarse_power,
            progress=power_report(say)),
        lambda records: sum(r["min_power_gait"] is not None for r in records)), resume, say)

    return _write_results(out, solutions, at_20, minimal, settings, solver, say)


def _stage_report(say: Callable[..., None], options: interior_point.InteriorPointOptions,
                  label: str) -> Callable[[int, dict], None]:
    """A stage's progress line after every block of interior-point iterations, counting the batch's
    problems finished."""
    return lambda i, row: say(
        f"{label}: interior-point iteration {i} of at most {options.max_iterations}, "
        f"{int(np.sum(row['done']))} of {row['done'].size} problems finished, largest KKT error "
        f"{np.max(row['error']):.1e}, cheapest J {np.min(row['cost']):.4f}",
        task=(label, int(np.sum(row["done"])), row["done"].size))


def _done(say: Callable[..., None], label: str, result, solved: Callable = len):
    """Reports a stage finished (``solved(result)``: how many problems it solved) and passes its result on."""
    count = solved(result)
    say(f"{label}: done", task=(label, count, count))
    return result


def power_report(say: Callable[..., None]) -> Callable[[int, dict], None]:
    """The smallest power limit's progress line (one batch per stage of the continuation), counted per
    model of the stage's space."""
    def report(i, row):
        stage = f", J's weight {row['energy_weight']:g}" if "energy_weight" in row else ""
        label = f"smallest power limit ({row.get('space', 'study space')}{stage})"
        objective = "t + w J / J0" if row.get("energy_weight", 0.0) > 0 else "M_W / start"
        say(f"{label}: interior-point iteration {i}, {int(np.sum(row['done']))} of "
            f"{row['done'].size} finished, {objective} {np.array2string(row['cost'], precision=3)}",
            task=(label, int(np.sum(row["done"])), row["done"].size))
    return report


def _write_results(out: Path, solutions: list[GaitSolution], at_20: list[GaitSolution], minimal: list[dict],
                   settings: gait_problem.GaitSettings, solver: GaitSolver, say: Callable[..., None]) -> dict:
    """The study's files from its three stages: results.json, tables.md, Figs. 2-3, convergence.png,
    trajectories.npz and the drive-train part; returns the results record."""
    names = [s.name for s in solutions]
    records = []
    for solution, minimum in zip(solutions, minimal):
        record = gait_report.results_record(solution)
        gait_at_minimum = minimum["min_power_gait"]
        record.update(minimum, min_power_gait=None if gait_at_minimum is None
                      else gait_report.results_record(gait_at_minimum))
        records.append(record)
    results = {
        "models": records,
        "at_20W": [gait_report.results_record(s) for s in at_20],
        "settings": dataclasses.asdict(settings),
        "solver": {"method": "interior point", **dataclasses.asdict(solver.options)},
        "violation_tolerance_own_units": 1e-4,
    }
    outputs.write_json(out / "results.json", results)
    tables = ["# The paper's four models (layout of Tables 4 and 5)", ""]
    tables += [gait_report.markdown_table(s) for s in solutions]
    tables += ["## At M_W = 20 W (the paper: M3 and M4 not solvable)", "",
               f"| model | status | J | largest violation | J on {solver.refined_settings.steps} steps "
               "| largest power there [% of M_W over] |", "|---|---|---|---|---|---|"]
    tables += [f"| {s.name} | {s.status} | {s.cost:.4g} | {s.max_violation:.1e} | {s.refinement['cost']:.4g} "
               f"| {100 * s.refinement['power_margin_fraction']:.2f} |" for s in at_20]
    tables += ["", "## Smallest power limit with a feasible gait (the interior point minimising M_W)", "",
               f"| model | smallest M_W [W] (kept on {solver.refined_settings.steps} steps) | on the solve grid [W] "
               "| status | J of that gait |", "|---|---|---|---|---|"]
    tables += [f"| {n} | {_number(m['min_power_limit_W'], '.3f')} | {_number(m['min_power_solve_grid_W'], '.3f')} "
               f"| {m['min_power_status']} | {_number(m['min_power_cost'], '.4g')} |" for n, m in zip(names, minimal)]
    outputs.write_text(out / "tables.md", "\n".join(tables) + "\n")
    gait_report.plot_figure_2(solutions, out / "fig2_trajectories.png")
    gait_report.plot_figure_3(solutions, out / "fig3_torque_rpm.png")
    gait_report.plot_convergence(solutions, out / "convergence.png")
    say("drive train: Table 6, selection, Figs. 4-5")
    drive_selection.save_workspaces(out / "trajectories.npz", solutions)
    results.update(drive_train.run_drive_study(out, drive_selection.load_workspaces(out / "trajectories.npz")))
    return results
