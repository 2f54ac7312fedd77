"""The co-design's gradient method against a gradient-free baseline, CMA-ES, over the same design variables
and bounds, counted in gait solves, in the same run.

The problem: M2 (0.555 m/s, 20 W, 38 V) on the paper's RE 25 42 V drive; the variables
(``codesign.DESIGN_VARIABLES``): log N per joint within 14-190:1, log k_t per joint within the
catalogue's windings (``codesign.winding_range()``), the structure's mass split within
``codesign.MASS_SPLIT_BOUNDS`` and the knee drives' place from the knee (0) to the hip (1); the
objective the converged gait's Joule energy per step (the step length is fixed, so per metre is the
same ranking).

- **gradient**: ``codesign.co_optimise`` from the paper's design (66:1, Table 2's split): optax's Adam on
  the envelope-theorem gradient, one warm-started solve per iteration;
- **CMA-ES** (the ``cma`` package): the variables scaled to [0, 1] within their
  bounds, started at the paper's design with step 0.2, every generation's population solved as one
  batch warm-started from the paper design's gait; a design whose gait does not converge scores ten
  times the paper's energy.

Reported: each method's best energy against the solves spent, the solves each needed to come within
0.5 % of the better best, and at the gradient method's final design its gradient against central
differences of re-solved optima (every variable +- its step, one batch).

    python benchmarks/codesign_vs_cmaes.py                       # the co-design studies' 16 knot spans
    python benchmarks/codesign_vs_cmaes.py --generations 30
"""

import argparse
import time
from pathlib import Path

import jax
import numpy as np
from _results import save_results

SPEED, POWER_LIMIT = 0.555, 20.0
RATIO_BOUNDS = (14.0, 190.0)


def best_so_far(costs):
    return np.minimum.accumulate(np.asarray(costs, dtype=float)).tolist()


def gradient_method(solver, paper, reference, iterations: int) -> dict:
    from biped_jax import codesign
    started = time.perf_counter()
    path = codesign.co_optimise(solver, [paper], SPEED, POWER_LIMIT, x0=reference.x[None], iterations=iterations,
                                ratio_bounds=RATIO_BOUNDS, solutions=[reference],
                                mass_split_bounds=codesign.MASS_SPLIT_BOUNDS,
                                torque_constant_bounds=codesign.winding_range(), drive_offset_bounds=(0.0, 1.0),
                                progress=lambda message: print("  gradient:", message, flush=True))
    seconds = time.perf_counter() - started
    energies = [row[0] for row in path.joule]   # after 0, 1, ... solves beyond the paper design's
    return {"method": "gradient (optax Adam, envelope theorem)", "solves": list(range(1, len(energies) + 1)),
            "best_energy_J": best_so_far(energies), "seconds": seconds, "final_design": path.designs[0],
            "final_solution": path.solutions[0], "ratios": path.ratios[-1][0],
            "torque_constants_Nm_per_A": path.torque_constants[-1][0], "mass_split": path.mass_splits[-1][0],
            "knee_drive_offset": path.knee_drive_offsets[-1][0]}


def cmaes(solver, paper, reference, generations: int, seed: int) -> dict:
    import cma

    from biped_jax import codesign
    low, high = codesign.design_bounds(RATIO_BOUNDS)
    start = (codesign.design_variables(paper) - low) / (high - low)
    strategy = cma.CMAEvolutionStrategy(start, 0.2, {"bounds": [0.0, 1.0], "seed": seed, "verbose": -9})
    apply = jax.jit(jax.vmap(codesign.with_variables, in_axes=(None, 0)))
    solves, energies, best_theta = [], [], None
    started = time.perf_counter()
    for generation in range(generations):
        unit = np.asarray(strategy.ask())
        theta = low + unit * (high - low)
        designs = codesign.unstack(apply(paper, theta))
        solutions = codesign.solve_designs(solver, designs, SPEED, POWER_LIMIT,
                                           x0=np.tile(reference.x, (len(designs), 1)))
        scores = [s.cost if s.status == "converged" else 10.0 * reference.cost for s in solutions]
        strategy.tell(list(unit), scores)
        for t, score in zip(theta, scores):
            solves.append(len(solves) + 1)
            if not energies or score < min(energies):
                best_theta = t
            energies.append(score)
        print(f"  CMA-ES generation {generation + 1}/{generations}: {len(solves)} solves, best "
              f"{min(energies):.5g} J, {time.perf_counter() - started:.0f} s", flush=True)
    return {"method": "CMA-ES (cma)", "solves": solves, "best_energy_J": best_so_far(energies),
            "seconds": time.perf_counter() - started, "population": int(strategy.popsize),
            "best_variables": best_theta.tolist()}


def solves_to_reach(run: dict, target: float):
    reached = [n for n, e in zip(run["solves"], run["best_energy_J"]) if e <= target]
    return reached[0] if reached else None


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spans", type=int, default=16, help="knot spans (default 16, the co-design studies')")
    parser.add_argument("--substeps", type=int, default=8, help="Runge-Kutta steps per span (default 8)")
    parser.add_argument("--iterations", type=int, default=12, help="the gradient method's iterations")
    parser.add_argument("--generations", type=int, default=15, help="CMA-ES generations")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    parser.add_argument("--name", default="codesign_vs_cmaes", help="results file stem")
    parser.add_argument("--no-drive-limits", action="store_true",
                        help="leave the gears' torque and input speed limits out of the gait")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    from biped_jax import codesign
    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait.solver import GaitSolver
    from biped_jax.studies import codesign as codesign_study
    settings = gait_problem.GaitSettings(spans=args.spans, substeps=args.substeps,
                                         drive_limits=not args.no_drive_limits)
    cold = GaitSolver(settings, codesign_study.IP_OPTIONS)
    solver = cold.using(codesign.SOLVER_OPTIONS)
    paper = codesign.catalogue_design()
    started = time.perf_counter()
    reference, = codesign.solve_designs(cold, [paper], SPEED, POWER_LIMIT)
    print(f"the paper's design: {reference.status}, J = {reference.cost:.5f} J "
          f"({time.perf_counter() - started:.0f} s with compiling)", flush=True)
    if reference.status != "converged":
        raise SystemExit("the paper's design has no converged gait in this space: nothing to compare")
    # the paper's design solved from its own gait: the same warm start both methods then use
    reference, = codesign.solve_designs(solver, [paper], SPEED, POWER_LIMIT, x0=reference.x[None])
    gradient = gradient_method(solver, paper, reference, args.iterations)
    baseline = cmaes(solver, paper, reference, args.generations, args.seed)
    better = min(gradient["best_energy_J"][-1], baseline["best_energy_J"][-1])
    target = better * 1.005
    reach = {"gradient": solves_to_reach(gradient, target), "cmaes": solves_to_reach(baseline, target)}
    check, = codesign.gradient_check(solver, [gradient["final_design"]], [gradient["final_solution"]], SPEED,
                                     POWER_LIMIT)
    rows = [{k: v for k, v in gradient.items() if k not in ("final_design", "final_solution")}, baseline,
            {"better_best_energy_J": better, "target_J (within 0.5 %)": target,
             "solves_to_target": reach, "paper_energy_J": reference.cost,
             "solve_ratio_cmaes_over_gradient": (reach["cmaes"] / reach["gradient"]
                                                 if reach["cmaes"] and reach["gradient"] else None)},
            {"gradient_check_at_the_gradient_methods_design": check}]
    for run in rows[:2]:
        print(f"{run['method']:42s} best {run['best_energy_J'][-1]:.5g} J after {run['solves'][-1]} solves "
              f"({run['seconds']:.0f} s)")
    print(f"paper design {reference.cost:.5g} J; within 0.5 % of the better best ({better:.5g} J): gradient after "
          f"{reach['gradient']} solves, CMA-ES after {reach['cmaes']}; gradient check at the final design: "
          f"largest relative error {check['max_relative_error']}")
    save_results(args.name, {"spans": args.spans, "substeps": args.substeps, "speed": SPEED,
                             "drive_limits": settings.drive_limits,
                             "power_limit": POWER_LIMIT, "ratio_bounds": RATIO_BOUNDS,
                             "mass_split_bounds": codesign.MASS_SPLIT_BOUNDS,
                             "torque_constant_bounds_Nm_per_A": codesign.winding_range()}, rows, args.out)


if __name__ == "__main__":
    main()
