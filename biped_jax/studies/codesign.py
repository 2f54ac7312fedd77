"""The co-design studies of ``biped-jax codesign``: designs in batches of 16 (one compiled program of the
batched interior point for every batch), every solve warm-started from the paper design's gait.

(a) peak joint power and Joule energy per metre against total mass (8-24 kg) at 0.417 and 0.555 m/s,
    with fitted power-law exponents; (b) the highest feasible speed against the gear ratio for the 42 V
    winding; (c) Joule energy per metre against robot mass over catalogue ratios x windings and its
    Pareto front; (d) gear ratios per joint and the structure's mass split co-optimised with the gait
    from 16 starts, snapped to the catalogue and re-verified.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Callable

import numpy as np

from biped_jax.codesign import problem as codesign
from biped_jax.drives import model as drive_model
from biped_jax.gait import problem as gait_problem
from biped_jax.gait.solver import GaitSolver
from biped_jax.optim import interior_point as ip
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
IP_OPTIONS = ip.InteriorPointOptions()
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


def co_optimisation(solver: GaitSolver, x_start, say, iterations: int) -> dict:
    """Study (d): gear ratios per joint and the structure's mass split (legs' share, thighs' share of
    the legs, within :data:`~biped_jax.codesign.drive_design.MASS_SPLIT_BOUNDS`; the total kept) for the
    42 V winding at M2 (0.555 m/s, 20 W, 38 V) from 16 uniform ratio starts (14:1 to 190:1, the paper's
    split), co-optimised with the gait, then snapped to the nearest catalogue gearhead per joint (the
    split kept) and re-solved."""
    catalogue = drive_model.load_catalogue()
    starts = [codesign.with_ratio(codesign.catalogue_design(), np.full(4, t), catalogue)
              for t in np.linspace(np.log(14.0), np.log(190.0), BATCH)]
    path = codesign.co_optimise(solver, starts, SPEEDS[1], POWER_LIMIT, x0=np.tile(x_start, (BATCH, 1)),
                                iterations=iterations, progress=say, mass_split_bounds=codesign.MASS_SPLIT_BOUNDS)
    snapped_names = [tuple(codesign.nearest_gearhead(float(n), catalogue) for n in np.asarray(d.ratio))
                     for d in path.designs]
    snapped = [codesign.with_mass_split(codesign.catalogue_design("RE25-42V", names, catalogue=catalogue),
                                        codesign.mass_split(d))
               for names, d in zip(snapped_names, path.designs)]
    say("(d) re-solving the snapped catalogue designs")
    verified = codesign.solve_designs(solver, snapped, SPEEDS[1], POWER_LIMIT,
                                      x0=np.stack([s.x for s in path.solutions]), summary=say)
    split_record = lambda d: dict(zip(codesign.MASS_SPLIT_NAMES, np.asarray(codesign.mass_split(d)).tolist()))  # noqa: E731
    records = [{"gearheads": list(n), "mass_split": split_record(d), **codesign.design_record(d, s)}
               for n, d, s in zip(snapped_names, snapped, verified)]
    ok = [i for i, r in enumerate(records) if r["status"] == nlp.CONVERGED]
    best = min(ok, key=lambda i: records[i]["joule_energy_J"]) if ok else None
    return {"variables": {"names": list(codesign.DESIGN_VARIABLES),
                          "units": ["log of the gear ratio"] * 4 + ["fraction"] * 2,
                          "mass_split_bounds": [list(b) for b in codesign.MASS_SPLIT_BOUNDS]},
            "path": {"ratios": path.ratios, "mass_splits": path.mass_splits, "joule_J": path.joule,
                     "status": path.status},
            "continuous": [{"ratio": np.asarray(d.ratio).tolist(), "mass_split": split_record(d),
                            "status": s.status, "joule_energy_J": s.cost}
                           for d, s in zip(path.designs, path.solutions)],
            "snapped": records, "best": best}


def reduction_vs_paper(pareto_study: dict, optimisation: dict) -> dict | None:
    """The best catalogue design of study (d) against the paper's design (RE 25 42 V, GP 32 A 66:1,
    Table 2's mass split) as study (c) solved it (the same problem: 0.555 m/s, 20 W, 38 V): both Joule
    energies per step (J) and the reduction, 1 - best / paper; None where either has no converged gait."""
    paper = [r for r in pareto_study["designs"] if r.get("winding") == "RE25-42V"
             and r.get("gearhead") == codesign.REFERENCE_GEARHEAD and r["status"] == nlp.CONVERGED]
    best = optimisation.get("best")
    if not paper or best is None:
        return None
    paper_energy, best_energy = paper[0]["joule_energy_J"], optimisation["snapped"][best]["joule_energy_J"]
    return {"paper_joule_energy_J": paper_energy, "best_joule_energy_J": best_energy,
            "reduction": 1.0 - best_energy / paper_energy}


def run_codesign(out: Path, settings: gait_problem.GaitSettings = gait_problem.GaitSettings(dynamics="chain"),
                 iterations: int = 5,
                 progress: Callable[[str], None] | None = None, resume: bool = False) -> dict:
    """All four studies; writes codesign.json and codesign_{mass_scaling,speed,pareto,optimisation}.png.
    The batched interior point solves every batch: :data:`IP_OPTIONS` for the reference gait,
    :data:`IP_WARM_OPTIONS` otherwise; single-shot settings are shot in a segment per knot span.
    Each finished study is kept in ``out/stages`` (:func:`biped_jax.report.outputs.stage`); ``resume``
    takes those written with the same settings instead of solving them again."""
    from biped_jax.codesign import plots as codesign_plots

    say = progress or (lambda message: None)
    out.mkdir(parents=True, exist_ok=True)
    options = IP_WARM_OPTIONS
    if settings.segments == 1:
        settings = dataclasses.replace(settings, segments=settings.spans)
    solver = GaitSolver(settings, options)
    results = {"settings": {"spans": settings.spans, "substeps": settings.substeps, "steps": settings.steps,
                            "degree": settings.degree, "batch": BATCH, "torque_bound_Nm": settings.torque_bound,
                            "dynamics": settings.dynamics, "solver": "interior point"}}
    save = lambda: outputs.write_json(out / "codesign.json", results)  # noqa: E731
    key = {"settings": dataclasses.asdict(settings), "iterations": iterations, "options": dataclasses.asdict(options)}
    kept = lambda name, compute: outputs.stage(out, f"codesign_{name}", key, compute, resume, say)  # noqa: E731
    say("compiling the gait problem; the paper's design from the heuristic start")
    x_start = kept("reference", lambda: reference_gait(solver, say))
    results["pareto"] = kept("pareto", lambda: pareto(solver, x_start, say))
    save()
    codesign_plots.plot_pareto(results["pareto"], out / "codesign_pareto.png")
    results["mass_scaling"] = kept("mass_scaling", lambda: mass_scaling(solver, say))
    save()
    codesign_plots.plot_mass_scaling(results["mass_scaling"], out / "codesign_mass_scaling.png")
    results["speed_limits"] = kept("speed_limits", lambda: speed_limits(solver, x_start, say))
    save()
    codesign_plots.plot_speed_limits(results["speed_limits"], out / "codesign_speed.png")
    results["co_optimisation"] = kept("co_optimisation", lambda: co_optimisation(solver, x_start, say, iterations))
    results["co_optimisation"]["energy_reduction_vs_paper"] = reduction_vs_paper(results["pareto"],
                                                                                 results["co_optimisation"])
    save()
    codesign_plots.plot_optimisation(results["co_optimisation"], out / "codesign_optimisation.png")
    return results
