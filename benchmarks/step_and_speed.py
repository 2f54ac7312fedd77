"""The paper's four models with the step length free and at their fastest, on the study's grid.

For M1-M4 (their speeds and power limits, Table 3) this solves, as the study does, the optimal step at
the paper's 0.2 m (every start family in the coarse space, the best carried into the study's), then
from it in one batch each:

- the step length free within ``--bounds`` (``GaitSolver.solve_step_length``: least energy per metre
  J / L at the model's speed);
- the fastest gait at the model's power limit, the step length free within the same bounds
  (``GaitSolver.fastest_gait``: a KKT point of max v).

Reported per model: J and J / L at 0.2 m, the step length found and its J / L, the fastest speed and its
step length, each with its status and the refinement check (J and the verdict on the 4x finer grid),
and the wall time of each stage (compilation included).

    python benchmarks/step_and_speed.py                  # study grid (48 spans), M1-M4
    python benchmarks/step_and_speed.py --spans 8 --substeps 4    # a quick look
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
from _results import save_results


def _record(solution) -> dict:
    return {"status": solution.status, "cost": solution.cost, "cost_per_metre": solution.energy_per_metre,
            "step_length_m": solution.step_length_m, "speed_mps": solution.speed_mps,
            "step_time_s": solution.step_time_s, "max_violation": solution.max_violation,
            "refined_cost": solution.refinement.get("cost"), "refinement_passed": solution.refinement.get("passed"),
            "refinement_failed": solution.refinement.get("failed"),
            "power_margin_fraction": solution.refinement.get("power_margin_fraction"),
            "solve_grid_power_limit_W": solution.refinement.get("solve_grid_power_limit_W"),
            "iterations": int(solution.outer_iterations)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bounds", type=float, nargs=2, default=(0.1, 0.35), metavar=("LOW", "HIGH"),
                        help="the step length's bounds, m (default 0.1 0.35)")
    parser.add_argument("--spans", type=int, default=None, help="knot spans (default the study's)")
    parser.add_argument("--substeps", type=int, default=None, help="Runge-Kutta steps per span (default the study's)")
    parser.add_argument("--name", default="step_and_speed")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args()

    from biped_jax.commands import configure_jax
    configure_jax()
    from biped_jax.gait import multistart
    from biped_jax.studies import paper

    settings = paper.STUDY_SETTINGS
    if args.spans is not None or args.substeps is not None:
        spans = args.spans or settings.spans
        settings = dataclasses.replace(settings, spans=spans, segments=spans,
                                       substeps=args.substeps or settings.substeps)
    solvers = paper.study_solvers(settings)
    rows = paper.PAPER_MODELS
    names, models = [r.name for r in rows], paper.paper_gait_models(rows)
    bounds = tuple(args.bounds)
    times = {}

    started = time.perf_counter()
    fixed = multistart.solve_multistart(solvers.fine, names, models, families=solvers.families,
                                        coarse=solvers.coarse)
    times["fixed_step_s"] = time.perf_counter() - started
    print(f"at 0.2 m ({times['fixed_step_s']:.0f} s): " + ", ".join(
        f"{s.name} {s.status} J {s.cost:.4f} J/L {s.energy_per_metre:.3f}" for s in fixed), flush=True)
    x0 = np.stack([s.x for s in fixed])

    started = time.perf_counter()
    free = solvers.fine.solve_step_length(names, models, bounds, x0=x0)
    times["free_step_s"] = time.perf_counter() - started
    print(f"step length free ({times['free_step_s']:.0f} s): " + ", ".join(
        f"{s.name} {s.status} L {s.step_length_m:.4f} J/L {s.energy_per_metre:.3f}" for s in free), flush=True)

    started = time.perf_counter()
    fastest = solvers.fine.fastest_gait(names, models, x0, bounds)
    times["fastest_s"] = time.perf_counter() - started
    print(f"fastest ({times['fastest_s']:.0f} s): " + ", ".join(
        f"{s.name} {s.status} v {s.speed_mps:.4f} L {s.step_length_m:.4f}" for s in fastest), flush=True)

    table = []
    for row, a, b, c in zip(rows, fixed, free, fastest):
        table.append({"model": row.name, "mass_class": row.mass_class, "speed_mps": row.speed,
                      "power_limit_W": row.power_limit, "at_0.2_m": _record(a), "step_free": _record(b),
                      "energy_per_metre_saved_percent": 100 * (1 - b.energy_per_metre / a.energy_per_metre),
                      "fastest": _record(c)})
        print(f"{row.name}: J/L {a.energy_per_metre:.3f} at 0.2 m -> {b.energy_per_metre:.3f} at "
              f"{b.step_length_m:.3f} m ({table[-1]['energy_per_metre_saved_percent']:.1f} % less; {b.status}, "
              f"4x grid {b.refinement.get('passed')}); fastest {c.speed_mps:.3f} m/s at {c.step_length_m:.3f} m "
              f"({c.status}, 4x grid {c.refinement.get('passed')})")
    save_results(args.name, {"bounds_m": list(bounds), "spans": settings.spans, "substeps": settings.substeps,
                             "segments": settings.segments, **times}, table, args.out)


if __name__ == "__main__":
    main()
