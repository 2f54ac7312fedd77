"""The co-design studies of ``biped-jax codesign``: designs in batches of 16 (one compiled program of the
batched interior point for every batch; study (d) one batch of all its starts), every solve
warm-started from the paper design's gait.

(a) peak joint power and Joule energy per metre against total mass (8-24 kg) at 0.417 and 0.555 m/s,
    with fitted power-law exponents; (b) the highest feasible speed against the gear ratio for the 42 V
    winding; (c) Joule energy per metre against robot mass over catalogue ratios x windings and its
    Pareto front; (d) gear ratios and windings per joint, the structure's mass split and the knee
    drives' place co-optimised with the gait for M2 and M4 from 64 starts each, snapped to the catalogue
    and re-verified, with CMA-ES over the same variables and the same number of solves beside it.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Callable

import jax
import numpy as np

from biped_jax import codesign
from biped_jax.drives import model as drive_model
from biped_jax.drives import selection
from biped_jax.gait import problem as gait_problem
from biped_jax.gait.solver import GaitSolver
from biped_jax.optim import interior_point
from biped_jax.optim import nlp
from biped_jax.report import outputs

BATCH = 16
SPEEDS = (0.417, 0.555)  # M1/M3 and M2/M4, m/s
MASSES = tuple(np.linspace(8.0, 24.0, 8))  # kg
POWER_LIMIT = 20.0  # W, the RE 25's rating and the paper's M_W for the 12 kg robot
#: The study's windings: the paper's three (estimates) and the datasheet 24 V winding; the paper's
#: 42 V first, so that its gait (first batch, heuristic starts) warm-starts the second batch.
WINDINGS = ("RE25-42V", "RE25-118752", "RE25-30V", "RE25-48V")
#: The batched interior point's settings for the co-design batches (every design of a batch in one
#: compiled program).
IP_OPTIONS = interior_point.InteriorPointOptions()
#: Its settings for batches warm-started from a solved gait (every batch but the reference's): from a
#: smaller barrier parameter, as the paper study's warm stages (the same compiled iterations).
IP_WARM_OPTIONS = codesign.SOLVER_OPTIONS
#: Catalogue ratios of the Pareto study (2- and 3-stage GP 32 A).
PARETO_GEARHEADS = ("GP32A-18", "GP32A-23", "GP32A-33", "GP32A-51", "GP32A-66.22", "GP32A-86",
                    "GP32A-111", "GP32A-159")
#: The 16 ratios of study (b): every 2- and 3-stage GP 32 A.
SPEED_GEARHEADS = ("GP32A-14", "GP32A-18", "GP32A-21", "GP32A-23", "GP32A-28", "GP32A-33", "GP32A-51",
                   "GP32A-66.22", "GP32A-79", "GP32A-86", "GP32A-103", "GP32A-111", "GP32A-123",
                   "GP32A-132", "GP32A-159", "GP32A-190")


def _cold(solver: GaitSolver) -> GaitSolver:
    """The solver for a solve from the heuristic start: the interior point from its cold barrier
    parameter (:data:`IP_OPTIONS`)."""
    return solver.using(IP_OPTIONS)


def _converged(solution) -> bool:
    return solution.status == nlp.CONVERGED


def power_law_exponent(mass, value) -> float:
    """Least-squares slope of log(value) over log(mass): value ~ mass^exponent."""
    mass, value = np.asarray(mass, float), np.asarray(value, float)
    if mass.size < 2:
        return math.nan
    return float(np.polyfit(np.log(mass), np.log(value), 1)[0])


def mass_scaling(solver: GaitSolver, say) -> dict:
    """Study (a): the paper's drive (42 V, 66:1) on robots of 8-24 kg (structure scaled), no power and
    no voltage limit, so that the requirement itself is measured. Per speed, the 12 kg robot is solved
    from the heuristic start first and warm-starts every mass (a gait of the other speed is a worse
    start: from 0.555 m/s's, SLSQP did not find the 0.417 m/s gaits in 300 iterations)."""
    designs, speeds, starts = [], [], []
    for speed in SPEEDS:
        say(f"(a) the paper's 12 kg robot at {speed} m/s from the heuristic start")
        reference, = codesign.solve_designs(
            _cold(solver), [codesign.catalogue_design(supply_voltage=drive_model.NO_VOLTAGE_LIMIT)], speed,
            gait_problem.NO_POWER_LIMIT, summary=say)
        for mass in MASSES:
            designs.append(codesign.catalogue_design(total_mass=float(mass),
                                                     supply_voltage=drive_model.NO_VOLTAGE_LIMIT))
            speeds.append(speed)
            starts.append(reference.x)
    say("(a) 8 masses x 2 speeds")
    solutions = codesign.solve_designs(solver, designs, speeds, gait_problem.NO_POWER_LIMIT, x0=np.stack(starts),
                                       summary=say)
    records = [codesign.design_record(d, s) for d, s in zip(designs, solutions)]
    fits = {}
    for speed in SPEEDS:
        rows = [r for r in records if r["speed_mps"] == speed and r["status"] == nlp.CONVERGED]
        mass = [r["total_mass_kg"] for r in rows]
        fits[f"{speed}"] = {
            "converged": len(rows),
            "peak_power_exponent": power_law_exponent(mass, [r["peak_joint_power_W"] for r in rows]),
            "joule_per_metre_exponent": power_law_exponent(
                mass, [r["joule_energy_per_metre_J_per_m"] for r in rows]),
            "int_u2_exponent": power_law_exponent(mass, [r["int_u2_N2m2s"] for r in rows]),
        }
    return {"designs": records, "fits": fits}


def speed_limits(solver: GaitSolver, x_start, say, bisections: int = 5, low: float = 0.3,
                 high: float = 1.2) -> dict:
    """Study (b): per ratio, the highest speed (bisection between ``low`` and ``high`` m/s, step length
    0.2 m) with a converged gait under the voltage limit (42 V winding at 38 V) and M_W = 20 W."""
    catalogue = drive_model.load_catalogue()
    designs = [codesign.catalogue_design("RE25-42V", g, catalogue=catalogue) for g in SPEED_GEARHEADS]
    feasible = np.full(BATCH, math.nan)
    lower, upper = np.full(BATCH, low), np.full(BATCH, high)
    warm = np.tile(x_start, (BATCH, 1))
    trial = np.full(BATCH, SPEEDS[1])
    for k in range(bisections + 1):
        say(f"(b) speed limit per ratio, trial {k + 1}/{bisections + 1}")
        solutions = codesign.solve_designs(solver, designs, trial, POWER_LIMIT, x0=warm, summary=say)
        for b, solution in enumerate(solutions):
            if _converged(solution):
                feasible[b] = trial[b]  # trials only rise above a feasible speed
                lower[b], warm[b] = trial[b], solution.x
            else:
                upper[b] = trial[b]
        trial = 0.5 * (lower + upper)
    return {"gearheads": list(SPEED_GEARHEADS), "ratios": [float(d.ratio[0]) for d in designs],
            "max_speed_mps": feasible.tolist(), "bracket_mps": np.stack([lower, upper], 1).tolist(),
            "winding": "RE25-42V", "supply_voltage_V": catalogue.supply_voltage, "power_limit_W": POWER_LIMIT}


def pareto_front(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the points (mass, energy) that no other point beats in both (lower is better)."""
    return [i for i, (m, e) in enumerate(points)
            if not any((m2 <= m and e2 <= e) and (m2 < m or e2 < e) for m2, e2 in points)]


def reference_gait(solver: GaitSolver, say) -> np.ndarray:
    """The paper's design (42 V, 66:1) at 0.555 m/s, M_W = 20 W, 38 V from the heuristic start: the warm
    start of every study. RuntimeError with its status and violations if it finds no gait."""
    say("the paper's design (42 V, 66:1) from the heuristic start")
    reference, = codesign.solve_designs(_cold(solver), [codesign.catalogue_design()], SPEEDS[1], POWER_LIMIT,
                                        summary=say)
    if not _converged(reference):
        raise RuntimeError(f"the paper's design found no gait ({reference.status}; {reference.violations})")
    return reference.x


def pareto(solver: GaitSolver, x_start, say) -> dict:
    """Study (c): every winding x ratio of the lists above at 0.555 m/s, M_W = 20 W, 38 V, warm-started
    from ``x_start``: Joule energy per metre against robot mass, and the Pareto front of the converged
    designs."""
    catalogue = drive_model.load_catalogue()
    pairs = [(w, g) for w in WINDINGS for g in PARETO_GEARHEADS]
    records = []
    for start in range(0, len(pairs), BATCH):
        chunk = pairs[start:start + BATCH]
        say(f"(c) windings x ratios, designs {start + 1}-{start + len(chunk)} of {len(pairs)}")
        designs = [codesign.catalogue_design(w, g, catalogue=catalogue) for w, g in chunk]
        solutions = codesign.solve_designs(solver, designs, SPEEDS[1], POWER_LIMIT,
                                           x0=np.tile(x_start, (len(chunk), 1)), summary=say)
        records += [{"winding": w, "gearhead": g, **codesign.design_record(d, s)}
                    for (w, g), d, s in zip(chunk, designs, solutions)]
    ok = [i for i, r in enumerate(records) if r["status"] == nlp.CONVERGED]
    front = pareto_front([(records[i]["total_mass_kg"], records[i]["joule_energy_per_metre_J_per_m"]) for i in ok])
    return {"designs": records, "pareto": [ok[i] for i in front]}


@dataclasses.dataclass(frozen=True)
class DesignProblem:
    """One problem of study (d): a mass class walking at ``speed`` (m/s) under the power limit
    ``power_limit`` (W) on the catalogue's 38 V supply."""

    name: str
    mass_class: str
    speed: float
    power_limit: float


#: Study (d)'s problems: the paper's M2 and M4 (12 and 18 kg at 0.555 m/s) at the RE 25's 20 W, the
#: power limit the paper asks about (it found no 20 W gait for the 18 kg robot).
DESIGN_PROBLEMS = (DesignProblem("M2", "12kg", 0.555, POWER_LIMIT), DesignProblem("M4", "18kg", 0.555, POWER_LIMIT))
#: Starting designs per problem in study (d) (one batch of all problems' starts).
STARTS = 64
#: Study (d)'s solver settings: the warm ones, and a batch of many starts stops 60 iterations after 90 %
#: of its designs have finished (``InteriorPointOptions.quorum``): a start far from any gait otherwise
#: runs to the iteration cap and, on a batched loop, costs every design its iterations (a first batch of
#: 64 starts on 2 CPU cores ran over 20 minutes). A design cut off is masked like one that fails.
DESIGN_OPTIONS = dataclasses.replace(IP_WARM_OPTIONS, quorum=0.9, patience=60)
#: Lanes of study (d)'s batch on a CPU (``InteriorPointOptions.lanes``): a design that finishes hands
#: its lane to the next one. Measured on 2 cores, 32 warm-started designs: 49.0 s in 8 lanes, 51.0 s in
#: 4, 54.3 s in 16, 59.8 s all at once (benchmarks/RESULTS.md). On an accelerator the whole batch.
CPU_LANES = 8
#: Study (d)'s bounds of the knee drives' place: anywhere from the knee (0) up the thigh to the hip (1).
DRIVE_OFFSET_BOUNDS = (0.0, 1.0)
#: CMA-ES's initial step in study (d), in the variables scaled to [0, 1] within their bounds.
CMAES_SIGMA = 0.2


#: One design at many variables (V,) -> (B, V): the designs of study (d)'s starts and CMA-ES's
#: generations, one compiled program.
_designs_at = jax.jit(jax.vmap(codesign.with_variables, in_axes=(None, 0)))


def study_settings(settings: gait_problem.GaitSettings) -> gait_problem.GaitSettings:
    """The co-design's gait space from ``settings``: single-shot settings shot in a segment per knot span,
    the drives' gear limits held (a catalogue drive cannot do more)."""
    if settings.segments == 1:
        settings = dataclasses.replace(settings, segments=settings.spans)
    return dataclasses.replace(settings, drive_limits=True)


def study_bounds(catalogue: drive_model.Catalogue) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) of study (d)'s design variables: :func:`~biped_jax.codesign.design_bounds` with the
    catalogue's windings and the knee drives anywhere from the knee to the hip."""
    return codesign.design_bounds(torque_constant_bounds=codesign.winding_range(catalogue),
                                  drive_offset_bounds=DRIVE_OFFSET_BOUNDS)


def design_lanes(lanes: int | None = None) -> int | None:
    """Study (d)'s lanes: ``lanes`` where given, else :data:`CPU_LANES` on a CPU and the whole batch
    (None) on an accelerator."""
    if lanes is not None:
        return lanes
    return CPU_LANES if jax.default_backend() == "cpu" else None


def design_starts(paper: codesign.DriveDesign, count: int, low, high, seed: int = 0) -> np.ndarray:
    """``count`` starting variables (count, V): the paper's design first, then a scrambled Sobol
    sequence over the bounds (``scipy.stats.qmc``; the same points for every problem with one seed)."""
    from scipy.stats import qmc
    unit = qmc.Sobol(d=len(low), scramble=True, seed=seed).random(count)[:count - 1]  # 2^m points: balanced
    return np.concatenate([np.clip(codesign.design_variables(paper), low, high)[None], low + unit * (high - low)])


def snapped_design(continuous: codesign.DriveDesign, mass_class: str,
                   catalogue: drive_model.Catalogue) -> tuple[tuple[str, ...], tuple[str, ...], codesign.DriveDesign]:
    """The catalogue design nearest to a continuous one: per joint the nearest gearhead
    (:func:`~biped_jax.codesign.nearest_gearhead`) and the winding at or below its torque
    constant (:func:`~biped_jax.codesign.nearest_winding`), its structure split and knee drives'
    place as the continuous design's. Returns (motors, gearheads, design)."""
    heads = tuple(codesign.nearest_gearhead(float(n), catalogue) for n in np.asarray(continuous.ratio))
    motors = tuple(codesign.nearest_winding(float(k), catalogue) for k in np.asarray(continuous.torque_constant))
    design = codesign.with_mass_split(codesign.catalogue_design(motors, heads, mass_class=mass_class,
                                                                catalogue=catalogue), codesign.mass_split(continuous))
    return motors, heads, codesign.with_knee_drive_offset(design, codesign.knee_drive_offset(continuous))


def _per_problem(problems, count: int, values) -> np.ndarray:
    return np.repeat(np.asarray([values(p) for p in problems], dtype=float), count)


def cmaes_baseline(solver, papers, problems, low, high, x_warm, penalties, generations: int, population: int,
                   say, seed: int = 1) -> dict:
    """CMA-ES (the ``cma`` package) per problem over the same variables and bounds (scaled to [0, 1]),
    from the paper's design with step :data:`CMAES_SIGMA`, ``population`` designs a generation, every
    generation's populations of all problems solved as one batch warm-started from the paper designs'
    gaits (``x_warm``, one per problem); a design whose gait does not converge scores its problem's
    ``penalties`` (J). Returns per problem the best converged energy after each generation and the
    solves."""
    import cma
    strategies = [cma.CMAEvolutionStrategy((codesign.design_variables(paper) - low) / (high - low), CMAES_SIGMA,
                                           {"bounds": [0.0, 1.0], "seed": seed, "popsize": population,
                                            "verbose": -9})
                  for paper in papers]
    best = [[] for _ in problems]
    best_variables = [None] * len(problems)
    for generation in range(generations):
        units = [np.asarray(strategy.ask()) for strategy in strategies]
        designs = [d for paper, unit in zip(papers, units)
                   for d in codesign.unstack(_designs_at(paper, low + unit * (high - low)))]
        solutions = codesign.solve_designs(solver, designs, _per_problem(problems, population, lambda p: p.speed),
                                           _per_problem(problems, population, lambda p: p.power_limit),
                                           x0=np.repeat(x_warm, population, axis=0), summary=say)
        for i, (strategy, unit) in enumerate(zip(strategies, units)):
            mine = solutions[i * population:(i + 1) * population]
            scores = [s.cost if _converged(s) else penalties[i] for s in mine]
            strategy.tell(list(unit), scores)
            current, k = (best[i][-1] if best[i] else math.inf), int(np.argmin(scores))
            if _converged(mine[k]) and scores[k] < current:
                current, best_variables[i] = scores[k], (low + unit[k] * (high - low)).tolist()
            best[i].append(current)
        say(f"(d) CMA-ES generation {generation + 1}/{generations}: best "
            + ", ".join(f"{p.name} {b[-1]:.4g} J" for p, b in zip(problems, best)))
    return {"method": "CMA-ES (cma), the same variables and bounds", "population": population,
            "sigma_unit": CMAES_SIGMA,
            "per_problem": {p.name: {"solves": [population * (g + 1) for g in range(generations)],
                                     "best_energy_J": [None if not math.isfinite(e) else e for e in b],
                                     "best_variables": v}
                            for p, b, v in zip(problems, best, best_variables)}}


def lowest_energy(records: list[dict], indices) -> int | None:
    """The index among ``indices`` of the record with the lowest ``joule_energy_J``; None for none."""
    indices = list(indices)
    return min(indices, key=lambda b: records[b]["joule_energy_J"]) if indices else None


def energy_reduction(paper: dict, best: dict | None) -> dict | None:
    """The best catalogue design's Joule energy per step (J) against the paper design's (both
    :func:`~biped_jax.codesign.design_record`s of one problem) and the reduction, 1 - best /
    paper; None without a best design, the reason where the paper's design has no converged gait."""
    if best is None:
        return None
    if paper["status"] != nlp.CONVERGED:
        return {"paper_joule_energy_J": None, "best_joule_energy_J": best["joule_energy_J"], "reduction": None,
                "reason": f"the paper's design has no converged gait ({paper['status']})"}
    return {"paper_joule_energy_J": paper["joule_energy_J"], "best_joule_energy_J": best["joule_energy_J"],
            "reduction": 1.0 - best["joule_energy_J"] / paper["joule_energy_J"]}


def co_optimisation(solver: GaitSolver, x_start, say, iterations: int, starts: int = STARTS,
                    problems=DESIGN_PROBLEMS, baseline: bool = True, lanes: int | None = None) -> dict:
    """Study (d): per problem (:data:`DESIGN_PROBLEMS`) the gear ratio and the winding per joint, the
    structure's mass split and the knee drives' place co-optimised with the gait
    (:func:`~biped_jax.codesign.co_optimise`, the variables within
    :func:`~biped_jax.codesign.design_bounds`: ratios 14-190:1, the catalogue's windings, the
    split within ``MASS_SPLIT_BOUNDS``, the drives anywhere from the knee to the hip,
    :data:`DRIVE_OFFSET_BOUNDS`) from ``starts`` designs per problem
    (:func:`design_starts`: the paper's design and a Sobol sequence), all problems' designs in one
    batch warm-started from the paper design's gait (``x_start``, M2's; the paper design of every
    problem is solved first, in the batch size of the other studies). Then each design snapped to the
    catalogue (:func:`snapped_design`) and re-solved; per problem the best snapped design with its
    drive verdicts, its reduction against the paper design, and at its continuous design the gradient
    against central differences of re-solved optima; with ``baseline`` CMA-ES over the same variables
    (:func:`cmaes_baseline`), as many generations of ``starts`` designs as the gradient method had
    batch solves. Every batch with :data:`DESIGN_OPTIONS` in :func:`design_lanes` (``lanes``)."""
    catalogue = drive_model.load_catalogue()
    solver = solver.using(dataclasses.replace(DESIGN_OPTIONS, lanes=design_lanes(lanes)))
    low, high = study_bounds(catalogue)
    papers = [codesign.catalogue_design(mass_class=p.mass_class, catalogue=catalogue) for p in problems]
    say(f"(d) the paper's design of {', '.join(p.name for p in problems)}")
    padded = papers + [papers[0]] * (BATCH - len(papers))
    paper_solutions = codesign.solve_designs(
        solver, padded, [p.speed for p in problems] + [problems[0].speed] * (BATCH - len(problems)),
        [p.power_limit for p in problems] + [problems[0].power_limit] * (BATCH - len(problems)),
        x0=np.tile(x_start, (BATCH, 1)), summary=say)[:len(problems)]
    x_warm = np.stack([s.x if _converged(s) else x_start for s in paper_solutions])
    theta0 = [design_starts(paper, starts, low, high) for paper in papers]
    designs = [d for paper, theta in zip(papers, theta0) for d in codesign.unstack(_designs_at(paper, theta))]
    speeds = _per_problem(problems, starts, lambda p: p.speed)
    limits = _per_problem(problems, starts, lambda p: p.power_limit)
    say(f"(d) {starts} starts x {len(problems)} problems in one batch")
    path = codesign.co_optimise(solver, designs, speeds, limits, x0=np.repeat(x_warm, starts, axis=0),
                                iterations=iterations, progress=say, mass_split_bounds=codesign.MASS_SPLIT_BOUNDS,
                                torque_constant_bounds=codesign.winding_range(catalogue),
                                drive_offset_bounds=DRIVE_OFFSET_BOUNDS)
    snapped = [snapped_design(d, problems[b // starts].mass_class, catalogue) for b, d in enumerate(path.designs)]
    say("(d) re-solving the snapped catalogue designs")
    verified = codesign.solve_designs(solver, [d for _, _, d in snapped], speeds, limits,
                                      x0=np.stack([s.x for s in path.solutions]), summary=say)
    records = []
    for b, ((motors, heads, design), solution) in enumerate(zip(snapped, verified)):
        split = dict(zip(codesign.MASS_SPLIT_NAMES, np.asarray(codesign.mass_split(design)).tolist()))
        verdicts = (selection.joint_verdicts(motors, heads, solution, catalogue.supply_voltage, catalogue)
                    if _converged(solution) else [])
        records.append({"problem": problems[b // starts].name, "motors": list(motors), "gearheads": list(heads),
                        "mass_split": split, **codesign.design_record(design, solution), "drive_verdicts": verdicts,
                        "passes_catalogue_check": bool(verdicts) and all(v["feasible"] for v in verdicts),
                        "passes_without_thermal": bool(verdicts) and all(v["feasible_without_thermal"]
                                                                         for v in verdicts)})
    gradient_solves = starts * len(path.joule)  # the first solve and one per iteration run
    per_problem = {}
    checks_at = []
    for i, problem in enumerate(problems):
        mine = range(i * starts, (i + 1) * starts)
        ok = [b for b in mine if records[b]["status"] == nlp.CONVERGED]
        best = lowest_energy(records, ok)
        paper = codesign.design_record(papers[i], paper_solutions[i])
        entry = {"problem": dataclasses.asdict(problem), "best": best, "converged_snapped": len(ok),
                 "paper_design": {"motor": codesign.REFERENCE_MOTOR, "gearhead": codesign.REFERENCE_GEARHEAD, **paper}}
        if best is not None:
            entry["best_design"] = {**records[best], "variables": dict(zip(
                codesign.DESIGN_VARIABLES, codesign.design_variables(path.designs[best]).tolist()))}
            checks_at.append((i, best))
        entry["energy_reduction_vs_paper"] = energy_reduction(paper, None if best is None else records[best])
        # a buildable design: every joint's motor and gearhead within the catalogue's limits on the gait
        # (the co-design's gait problem holds the voltage and power limits, not the gear's torque and
        # speed limits, nor the thermal one), and by the paper's criterion (all but the thermal check)
        for label, flag in (("best_passing_catalogue_check", "passes_catalogue_check"),
                            ("best_passing_without_thermal", "passes_without_thermal")):
            chosen = lowest_energy(records, [b for b in ok if records[b][flag]])
            entry[label] = None if chosen is None else {
                "index": chosen, "motors": records[chosen]["motors"], "gearheads": records[chosen]["gearheads"],
                "joule_energy_J": records[chosen]["joule_energy_J"],
                "energy_reduction_vs_paper": energy_reduction(paper, records[chosen])}
        per_problem[problem.name] = entry
    say("(d) the gradient at each problem's best design against re-solved optima")
    checks_made = codesign.gradient_check(
        solver, [path.designs[b] for _, b in checks_at], [path.solutions[b] for _, b in checks_at],
        [problems[i].speed for i, _ in checks_at], [problems[i].power_limit for i, _ in checks_at],
        batch=BATCH, bounds=(low, high)) if checks_at else []
    for (i, _), check in zip(checks_at, checks_made):
        per_problem[problems[i].name]["gradient_check"] = check
    errors = [c["max_relative_error"] for c in checks_made if c["max_relative_error"] is not None]
    smooth_errors = [c["max_relative_error_where_smooth"] for c in checks_made
                     if c["max_relative_error_where_smooth"] is not None]
    result = {
        "variables": {"names": list(codesign.DESIGN_VARIABLES), "units": list(codesign.DESIGN_UNITS),
                      "low": low.tolist(), "high": high.tolist(),
                      "bounds": {"ratio": np.exp([low[codesign.RATIOS][0], high[codesign.RATIOS][0]]).tolist(),
                                 "torque_constant_Nm_per_A": list(codesign.winding_range(catalogue)),
                                 "mass_split": [list(b) for b in codesign.MASS_SPLIT_BOUNDS],
                                 "knee_drive_offset": list(DRIVE_OFFSET_BOUNDS)}},
        "problems": [dataclasses.asdict(p) for p in problems], "starts_per_problem": starts,
        "designs": [{"problem": records[b]["problem"], "start": theta.tolist(),
                     "final": codesign.design_variables(d).tolist(), "status": s.status,
                     "joule_energy_J": s.cost, "stationary": path.stationary[b] if path.stationary else False}
                    for b, (theta, d, s) in enumerate(zip(np.concatenate(theta0), path.designs, path.solutions))],
        "path": {"ratios": path.ratios, "torque_constants_Nm_per_A": path.torque_constants,
                 "mass_splits": path.mass_splits, "knee_drive_offsets": path.knee_drive_offsets,
                 "joule_J": path.joule, "status": path.status},
        "snapped": records, "per_problem": per_problem,
        "best": {name: entry["best"] for name, entry in per_problem.items()},
        "energy_reduction_vs_paper": {name: entry["energy_reduction_vs_paper"] for name, entry in per_problem.items()},
        "gradient_solves": gradient_solves,
        "gradient_check_max_rel_error": max(errors) if errors else None,
        # where J* has no kink within the check's steps (codesign.gradient_check's one-sided differences)
        "gradient_check_max_rel_error_where_smooth": max(smooth_errors) if smooth_errors else None,
        "gradient_check_kinks": {problems[i].name: [v for v, k in zip(check["variables"], check["kink"]) if k]
                                 for (i, _), check in zip(checks_at, checks_made)},
    }
    if baseline:
        say("(d) CMA-ES over the same variables, the same number of solves")
        result["baseline"] = cmaes_baseline(solver, papers, problems, low, high, x_warm,
                                            [10.0 * s.cost for s in paper_solutions], len(path.joule), starts, say)
    return result


#: ``biped-jax codesign --quick``: study (d) alone, 8 starts per problem, 2 iterations, every file stamped.
QUICK_STARTS, QUICK_ITERATIONS = 8, 2
QUICK_STAMP = ("QUICK LOOK (biped-jax codesign --quick): study (d) alone, 8 starts per problem, 2 iterations; "
               "not the study's result")


def run_codesign(out: Path, settings: gait_problem.GaitSettings = gait_problem.GaitSettings(dynamics="chain"),
                 iterations: int = 5, progress: Callable[[str], None] | None = None, resume: bool = False,
                 starts: int = STARTS, optimisation_only: bool = False, lanes: int | None = None) -> dict:
    """The four studies (``optimisation_only``: study (d) alone); writes codesign.json and
    codesign_{pareto,mass_scaling,speed,optimisation}.png. The batched interior point solves every
    batch: :data:`IP_OPTIONS` for the reference gait, :data:`IP_WARM_OPTIONS` otherwise; single-shot
    settings are shot in a segment per knot span. Every gait holds its drives' gear limits (intermittent
    output torque, input speed: ``GaitSettings.drive_limits``). Study (d) runs ``starts`` designs per
    problem for ``iterations`` iterations in ``lanes`` lanes (:func:`design_lanes`: 8 on a CPU, the
    whole batch on an accelerator). Each finished study is kept in ``out/stages``
    (:func:`biped_jax.report.outputs.stage`); ``resume`` takes those written with the same settings
    instead of solving them again."""
    from biped_jax.codesign import plots as codesign_plots

    say = progress or (lambda message: None)
    out.mkdir(parents=True, exist_ok=True)
    options = IP_WARM_OPTIONS
    settings = study_settings(settings)
    solver = GaitSolver(settings, options)
    results = {"settings": {"spans": settings.spans, "substeps": settings.substeps, "steps": settings.steps,
                            "degree": settings.degree, "batch": BATCH, "torque_bound_Nm": settings.torque_bound,
                            "drive_limits": settings.drive_limits,
                            "dynamics": settings.dynamics, "solver": "interior point", "starts_per_problem": starts,
                            "iterations": iterations, "co_optimisation_lanes": design_lanes(lanes)}}
    save = lambda: outputs.write_json(out / "codesign.json", results)  # noqa: E731
    key = {"settings": dataclasses.asdict(settings), "options": dataclasses.asdict(options)}
    kept = lambda name, compute, **more: outputs.stage(out, f"codesign_{name}", {**key, **more}, compute,  # noqa: E731
                                                       resume, say)
    say("compiling the gait problem; the paper's design from the heuristic start")
    x_start = kept("reference", lambda: reference_gait(solver, say))
    if not optimisation_only:
        results["pareto"] = kept("pareto", lambda: pareto(solver, x_start, say))
        save()
        codesign_plots.plot_pareto(results["pareto"], out / "codesign_pareto.png")
        results["mass_scaling"] = kept("mass_scaling", lambda: mass_scaling(solver, say))
        save()
        codesign_plots.plot_mass_scaling(results["mass_scaling"], out / "codesign_mass_scaling.png")
        results["speed_limits"] = kept("speed_limits", lambda: speed_limits(solver, x_start, say))
        save()
        codesign_plots.plot_speed_limits(results["speed_limits"], out / "codesign_speed.png")
    results["co_optimisation"] = kept("co_optimisation", lambda: co_optimisation(solver, x_start, say, iterations,
                                                                             starts, lanes=lanes),
                                      iterations=iterations, starts=starts)
    save()
    codesign_plots.plot_optimisation(results["co_optimisation"], out / "codesign_optimisation.png")
    return results
