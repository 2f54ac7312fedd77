"""How a library point's optimum moves with the joint paths' knot spans (the space, not the rollout grid).

Solves the same gait problems (ideal drives) from the heuristic start in spaces of ``--spans`` knot
spans (a shooting segment each, 4 Runge-Kutta steps per span, the library's interior point) and prints
J on the solve grid and on the 4x finer one per space: the refinement check refines the rollout grid
only, so a J that still falls from one space to the next is the space's error, which that check cannot
see. Defaults: the library's long-step points where it sits furthest above the collocation peer
(``benchmarks/library_vs_collocation.py``).

    python benchmarks/library_spans.py                        # 0.45 and 0.6 m/s at 0.25 m, 16 / 32 / 48 spans
    python benchmarks/library_spans.py --speeds 0.3 --step-length 0.175
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from _results import save_results


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mass-class", default="12kg")
    parser.add_argument("--speeds", type=float, nargs="+", default=[0.45, 0.6], help="m/s")
    parser.add_argument("--step-length", type=float, default=0.25, help="m")
    parser.add_argument("--power-limit", type=float, default=20.0, help="W")
    parser.add_argument("--spans", type=int, nargs="+", default=[16, 32, 48])
    parser.add_argument("--name", default="library_spans")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args()
    from biped_jax.commands import configure_jax
    configure_jax()
    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait.solver import GaitSolver
    from biped_jax.studies.library import LIBRARY_OPTIONS

    models = [gait_problem.gait_model(args.mass_class, v, args.power_limit, args.step_length) for v in args.speeds]
    names = [f"{v:g} m/s, {args.step_length:g} m" for v in args.speeds]
    rows = []
    for spans in args.spans:
        solver = GaitSolver(gait_problem.GaitSettings(spans=spans, substeps=4, segments=spans), LIBRARY_OPTIONS,
                            mass_class_template=args.mass_class)
        started = time.perf_counter()
        solutions = solver.solve(names, models)
        seconds = time.perf_counter() - started
        for solution in solutions:
            rows.append({"spans": spans, "point": solution.name, "status": solution.status, "cost": solution.cost,
                         "cost_refined": solution.refinement["cost"], "seconds_with_compile": seconds})
            print(f"{spans:3d} spans  {solution.name}: J {solution.cost:.4f} "
                  f"(4x grid {solution.refinement['cost']:.4f}, {solution.status})  {seconds:.0f} s", flush=True)
    save_results(args.name, {"mass_class": args.mass_class, "power_limit_W": args.power_limit,
                             "step_length_m": args.step_length, "substeps": 4}, rows, args.out)


if __name__ == "__main__":
    main()
