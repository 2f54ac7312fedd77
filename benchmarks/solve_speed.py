"""Time to solve the gait problem with the batched interior point: M2 cold (compilation included) and
warm, and the four-model batch.

Cold means a fresh process with JAX's persistent compilation cache off (unless --cache is given), so
the figure is what a first-time user waits. Prints a table and saves JSON.

    python benchmarks/solve_speed.py
"""

import argparse
import time
from pathlib import Path

import jax
from _results import save_results


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spans", type=int, default=16)
    parser.add_argument("--degree", type=int, default=3)
    parser.add_argument("--substeps", type=int, default=8)
    parser.add_argument("--cache", type=Path, default=None, help="use this persistent cache folder")
    parser.add_argument("--dynamics", choices=("mjx", "chain"), default="chain",
                        help="single-support dynamics of the rollout (default chain)")
    parser.add_argument("--name", default="solve_speed", help="results file stem")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    if args.cache:
        jax.config.update("jax_compilation_cache_dir", str(args.cache))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)

    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait.solver import GaitSolver
    from biped_jax.studies import paper as study

    settings = gait_problem.GaitSettings(spans=args.spans, degree=args.degree, substeps=args.substeps,
                                dynamics=args.dynamics)
    rows = []

    def record(label, started, solutions):
        seconds = time.perf_counter() - started
        row = {"case": label, "seconds": seconds, "designs_per_second": len(solutions) / seconds,
               "status": [s.status for s in solutions], "cost": [s.cost for s in solutions],
               "iterations": [s.outer_iterations for s in solutions]}
        rows.append(row)
        print(f"{label:38s} {seconds:8.1f} s  {row['status']}  J = "
              + ", ".join(f"{c:.4g}" for c in row["cost"]), flush=True)

    m2 = [gait_problem.gait_model("12kg", 0.555, 20.0)]
    started = time.perf_counter()
    solver = GaitSolver(settings)
    record("M2 cold (compile + solve)", started, solver.solve(["M2"], m2))
    started = time.perf_counter()
    record("M2 warm (compiled, heuristic start)", started, solver.solve(["M2"], m2))
    names = [r.name for r in study.PAPER_MODELS]
    models = study.paper_gait_models(study.PAPER_MODELS)
    started = time.perf_counter()
    first = solver.solve(names, models)
    record("M1-M4 batch cold (compile + solve)", started, first)
    started = time.perf_counter()
    record("M1-M4 batch warm (compiled)", started, solver.solve(names, models))

    save_results(args.name, {"spans": args.spans, "degree": args.degree,
                                 "substeps": args.substeps, "dynamics": args.dynamics, "solver": "interior point",
                                 "persistent_cache": bool(args.cache)}, rows, args.out)


if __name__ == "__main__":
    main()
