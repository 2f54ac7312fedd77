"""Co-design throughput: gait problems of different designs solved per second, by batch size.

Each batch holds B different designs (the paper's RE 25 42 V drive with gear ratios spread
log-uniformly over 30-110:1 and total masses over 10-14 kg) at M2's speed and power limit, each solved
from the heuristic start to convergence (or its status) by the library's batched augmented-Lagrangian
solver: one compiled program per batch size. Compilation is timed apart (a first call of one outer
iteration compiles every program), then the full solve (the throughput). The solver's options are the
co-design studies' (``codesign_study.STUDY_OPTIONS``). Results are saved after every batch.

    python benchmarks/codesign_throughput.py --batch 1 16 64
"""

import argparse
import time
from pathlib import Path

import jax
import numpy as np
from _results import save_results


def designs_for(batch: int):
    from biped_jax.codesign import problem as codesign
    ratios = np.exp(np.linspace(np.log(30.0), np.log(110.0), batch)) if batch > 1 else np.array([66.22])
    masses = np.linspace(10.0, 14.0, batch) if batch > 1 else np.array([12.0])
    rng = np.random.default_rng(0)
    rng.shuffle(masses)  # pair ratios and masses at random
    return [codesign.with_ratio(codesign.catalogue_design(total_mass=float(m)), np.full(4, np.log(n)))
            for n, m in zip(ratios, masses)]


def measure(solver, batch: int) -> dict:
    from biped_jax.codesign import problem as codesign
    designs = designs_for(batch)
    started = time.perf_counter()  # one outer iteration of two inner steps compiles every program
    codesign.solve_designs(solver.with_options(max_outer=1, max_inner=2), designs, 0.555, 20.0)
    compile_s = time.perf_counter() - started
    started = time.perf_counter()
    solutions = codesign.solve_designs(solver, designs, 0.555, 20.0, progress=lambda i, row: print(
        f"  batch {batch}, outer iteration {i + 1}: {time.perf_counter() - started:.0f} s, largest scaled "
        f"violation {np.max(row['violation']):.1e}, gradients per design up to {int(np.max(row['gradients']))}",
        flush=True))
    seconds = time.perf_counter() - started
    converged = sum(s.status == "converged" for s in solutions)
    return {"batch": batch, "compile_s": compile_s, "solve_s": seconds,
            "designs_per_second": batch / seconds, "converged": converged,
            "mean_gradients": float(np.mean([s.gradients for s in solutions])),
            "statuses": sorted({s.status for s in solutions})}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, nargs="+", default=[1, 16, 64])
    parser.add_argument("--spans", type=int, default=16, help="knot spans of the joint B-splines (default 16)")
    parser.add_argument("--degree", type=int, default=3, help="B-spline degree (default 3)")
    parser.add_argument("--substeps", type=int, default=8, help="Runge-Kutta steps per span (default 8)")
    parser.add_argument("--dynamics", choices=("mjx", "chain"), default="chain",
                        help="single-support dynamics (default chain, the co-design study's)")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    parser.add_argument("--name", default="codesign_throughput",
                        help="results file stem, so runs of other batch sizes keep their own file")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    from biped_jax.gait import problem as gait
    from biped_jax.gait.solver import GaitSolver
    from biped_jax.studies.codesign import STUDY_OPTIONS
    settings = gait.GaitSettings(spans=args.spans, degree=args.degree, substeps=args.substeps,
                                dynamics=args.dynamics)
    solver = GaitSolver(settings).with_options(**STUDY_OPTIONS)
    rows = []
    print(f"{'batch':>6s} {'compile s':>16s} {'solve s':>9s} {'designs/s':>10s} {'converged':>10s} "
          f"{'gradients':>10s}", flush=True)
    for batch in args.batch:
        row = measure(solver, batch)
        rows.append(row)
        print(f"{batch:6d} {row['compile_s']:16.1f} {row['solve_s']:9.1f} {row['designs_per_second']:10.3f} "
              f"{row['converged']:6d}/{batch:<3d} {row['mean_gradients']:10.0f}", flush=True)
        save_results(args.name, {"spans": args.spans, "degree": args.degree, "substeps": args.substeps,
                                 "dynamics": args.dynamics, "speed": 0.555,
                                             "power_limit": 20.0, "float": "float64"}, rows, args.out)


if __name__ == "__main__":
    main()
