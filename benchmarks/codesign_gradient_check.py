"""The co-design's gradient check again at a finished study's best designs (`biped-jax codesign --out OUT`).

Rebuilds each problem's best continuous design from ``OUT/codesign.json`` (its eleven variables on the
paper design of its mass class), solves its gait warm from the paper design's (itself solved from the
heuristic start, as the study does), and runs :func:`biped_jax.codesign.gradient_check` with the study's
bounds (a variable on its bound judged from inside). Prints per variable the envelope gradient and its
relative error at the finer and the given steps.

    python benchmarks/codesign_gradient_check.py OUT [--scale 0.25] [--name NAME]
"""

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
from _results import save_results


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("study", type=Path, help="the folder with codesign.json")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    parser.add_argument("--name", default="codesign_gradient_check")
    parser.add_argument("--scale", type=float, default=1.0,
                        help="the check's steps times this (default 1: the study's)")
    args = parser.parse_args()
    from biped_jax.commands import configure_jax
    configure_jax()
    import jax.numpy as jnp
    from biped_jax import codesign
    from biped_jax.codesign import optimise
    from biped_jax.drives import model as drive_model
    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait.solver import GaitSolver
    from biped_jax.studies import codesign as study

    result = json.loads((args.study / "codesign.json").read_text())["co_optimisation"]
    settings = study.study_settings(gait_problem.GaitSettings(dynamics="chain"))  # the command's default
    solver = GaitSolver(settings, study.IP_WARM_OPTIONS).using(
        dataclasses.replace(study.DESIGN_OPTIONS, lanes=study.design_lanes()))
    catalogue = drive_model.load_catalogue()
    low, high = study.study_bounds(catalogue)
    problems = [p for p in study.DESIGN_PROBLEMS if result["per_problem"].get(p.name, {}).get("best") is not None]
    x_start = study.reference_gait(solver, print)
    papers = [codesign.catalogue_design(mass_class=p.mass_class, catalogue=catalogue) for p in problems]
    speeds, limits = [p.speed for p in problems], [p.power_limit for p in problems]
    warm = codesign.solve_designs(solver, papers, speeds, limits, x0=np.tile(x_start, (len(problems), 1)))
    theta = [np.array(result["designs"][result["per_problem"][p.name]["best"]]["final"]) for p in problems]
    designs = [codesign.with_variables(paper, jnp.asarray(t)) for paper, t in zip(papers, theta)]
    solutions = codesign.solve_designs(solver, designs, speeds, limits, x0=np.stack([s.x for s in warm]))
    steps = args.scale * np.asarray(optimise.GRADIENT_CHECK_STEPS)
    checks = codesign.gradient_check(solver, designs, solutions, speeds, limits, steps=steps, batch=study.BATCH,
                                     bounds=(low, high))
    rows = []
    for problem, design_index, solution, check in zip(problems, [result["per_problem"][p.name]["best"]
                                                                  for p in problems], solutions, checks):
        recorded = result["designs"][design_index]["joule_energy_J"]
        print(f"{problem.name}: J re-solved {solution.cost:.6f} J (the study's {recorded:.6f}), largest relative "
              f"error {check['max_relative_error']:.2e} at the finer steps")
        for v, name in enumerate(check["variables"]):
            print(f"  {name:24s} {check['envelope'][v]: .4e} J per unit, error {check['relative_error'][v]:.1e} "
                  f"(given steps {check['coarse']['relative_error'][v]:.1e})"
                  + {1: ", at its upper bound", -1: ", at its lower bound", 0: ""}[check["at_bound"][v]])
        rows.append({"problem": problem.name, "design": design_index, "joule_energy_J": solution.cost,
                     "study_joule_energy_J": recorded, "status": solution.status, **check})
    save_results(args.name, {"study": str(args.study), "steps": steps.tolist(),
                             "refinement": optimise.GRADIENT_CHECK_REFINEMENT}, rows, args.out)


if __name__ == "__main__":
    main()
