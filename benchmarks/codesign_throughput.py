"""Co-design throughput: gait problems of different designs solved per second, the batched interior point
against the same solver one design after another, in the same run, and against SLSQP's recorded figure.

Each batch holds B different designs (the paper's RE 25 42 V drive with gear ratios spread log-uniformly
over 30-110:1 and total masses over 10-14 kg, paired at random) at M2's speed and power limit, each solved
from the paper design's gait and its multipliers (the co-design loop's warm start; the paper design solved
first from the heuristic start). The interior point solves each batch in one compiled program
(``biped_jax.optim.interior_point``) of ``--lanes`` lanes (default: the whole batch), each lane taking the
next design as soon as its own finishes; its compile time is measured apart (a first call of one
iteration), then the solve. The serial peer solves
a sample of ``--sample`` designs of the largest batch one after another (batches of one, their own
compiled program); its designs/s is its converged designs over its time, and each of the sample is
compared with the batch's optimum of the same design. The batch is also compared with SLSQP one design
after another, the solver the interior point replaced: :data:`SLSQP_DESIGNS_PER_SECOND`, recorded in
``benchmarks/RESULTS.md`` (not re-measured: SLSQP is no longer in the package). Results are saved after
every batch.

    python benchmarks/codesign_throughput.py --batch 16 64 256 --sample 16 [--lanes 16]
"""

import argparse
import dataclasses
import time
from pathlib import Path

import jax
import numpy as np
from _results import save_results


def designs_for(batch: int):
    from biped_jax import codesign
    ratios = np.exp(np.linspace(np.log(30.0), np.log(110.0), batch)) if batch > 1 else np.array([66.22])
    masses = np.linspace(10.0, 14.0, batch) if batch > 1 else np.array([12.0])
    rng = np.random.default_rng(0)
    rng.shuffle(masses)  # pair ratios and masses at random
    return [codesign.with_ratio(codesign.catalogue_design(total_mass=float(m)), np.full(4, np.log(n)))
            for n, m in zip(ratios, masses)]


#: SLSQP one design after another (the co-design's solver before the interior point), converged designs
#: per second: 8 designs of the batch of 16 in 45.3 s, 2-core CPU, 2026-12-03 (``benchmarks/RESULTS.md``,
#: "Co-design throughput against SLSQP in the same run").
SLSQP_DESIGNS_PER_SECOND = 0.18


def converged(solutions) -> int:
    return sum(s.status == "converged" for s in solutions)


def warm_start(reference, batch: int) -> tuple:
    """x0 (batch, n) and multipliers ((batch, m_h), (batch, m_g)): the reference gait's, repeated."""
    return (np.tile(reference.x, (batch, 1)),
            (np.tile(reference.multipliers_eq, (batch, 1)), np.tile(reference.multipliers_in, (batch, 1))))


def interior_point_batch(solver, batch: int, reference, lanes: int | None) -> tuple[dict, list]:
    from biped_jax import codesign
    from biped_jax.studies import codesign as codesign_study
    solver = solver.using(dataclasses.replace(codesign_study.IP_WARM_OPTIONS, lanes=lanes))
    designs = designs_for(batch)
    x0, multipliers = warm_start(reference, batch)
    started = time.perf_counter()  # one iteration compiles every program
    codesign.solve_designs(solver.with_options(max_iterations=1, block=1), designs, 0.555, 20.0, x0=x0,
                           multipliers=multipliers)
    compile_s = time.perf_counter() - started
    started = time.perf_counter()
    solutions = codesign.solve_designs(solver, designs, 0.555, 20.0, x0=x0, multipliers=multipliers,
                                       progress=lambda i, row: i % 10 == 0 and print(
        f"  batch {batch}, iteration {i}: {time.perf_counter() - started:.0f} s, {int(np.sum(row['done']))} "
        f"finished", flush=True))  # lanes report after every iteration while designs wait
    seconds = time.perf_counter() - started
    count = converged(solutions)
    iterations = [s.outer_iterations for s in solutions]
    return ({"solver": "interior point", "batch": batch, "lanes": lanes or batch, "compile_s": compile_s,
             "solve_s": seconds, "converged": count, "converged_fraction": count / batch,
             "converged_designs_per_second": count / seconds,
             "iterations_max": int(max(iterations)), "iterations_mean": float(np.mean(iterations)),
             "statuses": sorted({s.status for s in solutions})}, solutions)


def serial_sample(solver, batch: int, sample: int, start, reference) -> dict:
    from biped_jax import codesign
    designs = designs_for(batch)
    picks = np.linspace(0, batch - 1, sample).round().astype(int)
    x0, multipliers = warm_start(start, 1)
    started = time.perf_counter()
    codesign.solve_designs(solver.with_options(max_iterations=1), designs[:1], 0.555, 20.0, x0=x0,
                           multipliers=multipliers)
    compile_s = time.perf_counter() - started
    started = time.perf_counter()
    solutions = [codesign.solve_designs(solver, [designs[b]], 0.555, 20.0, x0=x0, multipliers=multipliers)[0]
                 for b in picks]
    seconds = time.perf_counter() - started
    gaps = [(s.cost - reference[b].cost) / reference[b].cost for s, b in zip(solutions, picks)
            if s.status == "converged" and reference[b].status == "converged"]
    count = converged(solutions)
    return {"solver": "interior point, one design after another", "batch": sample, "of_batch": batch,
            "compile_s": compile_s, "solve_s": seconds, "converged": count,
            "converged_designs_per_second": count / seconds, "relative_gap_batch_minus_serial": [-g for g in gaps],
            "largest_relative_gap": float(np.max(np.abs(gaps))) if gaps else None}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, nargs="+", default=[16, 64, 256])
    parser.add_argument("--sample", type=int, default=16, help="designs solved one at a time for the comparison")
    parser.add_argument("--lanes", type=int, default=None,
                        help="designs iterated at once in a batch's program (default: the whole batch)")
    parser.add_argument("--spans", type=int, default=16, help="knot spans of the joint B-splines (default 16)")
    parser.add_argument("--segments", type=int, default=16, help="shooting segments (default: one per span)")
    parser.add_argument("--substeps", type=int, default=8, help="Runge-Kutta steps per span (default 8, the studies')")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    parser.add_argument("--name", default="codesign_throughput", help="results file stem")
    parser.add_argument("--no-drive-limits", action="store_true",
                        help="leave the gears' torque and input speed limits out of the gait")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    from biped_jax import codesign
    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait.solver import GaitSolver
    from biped_jax.studies import codesign as codesign_study
    settings = gait_problem.GaitSettings(spans=args.spans, segments=args.segments, substeps=args.substeps,
                                         drive_limits=not args.no_drive_limits)
    interior = GaitSolver(settings, codesign_study.IP_OPTIONS)
    started = time.perf_counter()
    reference, = codesign.solve_designs(interior, [codesign.catalogue_design()], 0.555, 20.0)
    print(f"the paper's design from the heuristic start: {reference.status}, J = {reference.cost:.5f} J, "
          f"{time.perf_counter() - started:.0f} s (compiling included)", flush=True)
    rows, last = [], None
    meta = {"spans": args.spans, "segments": args.segments, "substeps": args.substeps, "speed": 0.555,
            "drive_limits": settings.drive_limits, "warm_start": "the paper design's gait and multipliers",
            "power_limit": 20.0, "float": "float64", "options": dataclasses.asdict(interior.options)}
    for batch in args.batch:
        row, last = interior_point_batch(interior, batch, reference, args.lanes)
        rows.append(row)
        print(f"interior point, B = {batch}: {row['converged']}/{batch} converged in {row['solve_s']:.1f} s "
              f"({row['converged_designs_per_second']:.2f} designs/s; compile {row['compile_s']:.0f} s)", flush=True)
        save_results(args.name, meta, rows, args.out)
    peer = serial_sample(interior.using(codesign.SOLVER_OPTIONS), args.batch[-1], args.sample, reference, last)
    rows.append(peer)
    batched = rows[-2]["converged_designs_per_second"]
    ratio = batched / max(peer["converged_designs_per_second"], 1e-300)
    rows.append({"ratio_batch_over_serial": ratio,
                 "ratio_batch_over_recorded_slsqp": batched / SLSQP_DESIGNS_PER_SECOND,
                 "recorded_slsqp_designs_per_second": SLSQP_DESIGNS_PER_SECOND})
    print(f"one at a time: {peer['converged']}/{args.sample} in {peer['solve_s']:.1f} s "
          f"({peer['converged_designs_per_second']:.3f} designs/s); batch / serial = {ratio:.1f}x, batch / SLSQP "
          f"(recorded {SLSQP_DESIGNS_PER_SECOND} designs/s) = {batched / SLSQP_DESIGNS_PER_SECOND:.1f}x; "
          f"largest |J gap| over the sample {peer['largest_relative_gap']}", flush=True)
    save_results(args.name, meta, rows, args.out)


if __name__ == "__main__":
    main()
