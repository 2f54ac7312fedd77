"""The product's gait optimiser against an independent direct-collocation solve, in the same run.

For each case (M1-M4 at the paper's power limits, and M3, M4 at 20 W; M1 and M2's own limits are
20 W) this solves the planar-step problem twice:

- **ours**: ``biped_jax`` as the study runs it (``multistart.solve_multistart`` with the batched
  interior point: every start family of ``study.STUDY_FAMILIES`` in the coarse space, the cheapest per
  model carried into the study's space, 20 W warm-started from it), from its own starts only;
- **peer**: ``collocation_peer.solve`` (CasADi + IPOPT, Hermite-Simpson, written from the spec), on
  ``--segments`` segments and again on twice as many (its own mesh check).

Reported per case: J of each, the gap (ours / peer - 1) in %, ours' largest violation per group on the
grid 4x finer (the refinement check) and the peer's J change on its finer mesh, and wall times (ours:
compile included; with ``--warm`` solved again, warm). Needs the ``bench`` extra (casadi).

    python benchmarks/vs_collocation.py                 # all six cases
    python benchmarks/vs_collocation.py --cases M2      # one
    python benchmarks/vs_collocation.py --smallest-limit 7   # and the smallest power limits

With ``--smallest-limit K`` it also compares the smallest power limits of the paper's models: ours (the
study's continuation, kept on the 4x grid) against the peer's own minimisation of the limit with the
limit held at K points between every two of its nodes as well (held at its nodes alone, the peer's gaits
ask tens of W between them; see ``peer_smallest_limit.py``).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import jax
from _results import save_results


def peer_row(case, segments: int) -> dict:
    from collocation_peer import PeerProblem, solve

    from biped_jax.robots.specs import PLANAR_SPECS
    problem = PeerProblem(PLANAR_SPECS[case.mass_class], case.speed, case.power_limit)
    coarse = solve(problem, segments)
    fine = solve(problem, 2 * segments)
    return {"cost": coarse["cost"], "status": coarse["status"], "segments": segments,
            "cost_finer_mesh": fine["cost"], "status_finer_mesh": fine["status"],
            "mesh_change": abs(fine["cost"] - coarse["cost"]) / abs(coarse["cost"]),
            "wall_time_s": coarse["wall_time_s"], "wall_time_finer_s": fine["wall_time_s"]}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="*", default=None,
                        help="subset, e.g. M2 M4@20W (default: M1-M4 at the paper's limits and at 20 W)")
    parser.add_argument("--segments", type=int, default=40, help="the peer's Hermite-Simpson segments")
    parser.add_argument("--spans", type=int, default=None, help="ours (default: the study's)")
    parser.add_argument("--substeps", type=int, default=None, help="ours (default: the study's)")
    parser.add_argument("--shooting-segments", type=int, default=None,
                        help="our shooting segments (default: the study's)")
    parser.add_argument("--warm", action="store_true", help="solve ours a second time for the warm wall time")
    parser.add_argument("--smallest-limit", type=int, default=None, metavar="K",
                        help="also the smallest power limits of the paper's models: ours (the study's continuation "
                             "from ours' optima, kept on the 4x grid) against the peer's own minimisation with its "
                             "limit held at K points between every two nodes (peer_smallest_limit.minimised_limit)")
    parser.add_argument("--name", default="vs_collocation")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)

    import jax.numpy as jnp
    import numpy as np

    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait import multistart
    from biped_jax.studies import paper as study

    cases = [(m, m.power_limit) for m in study.PAPER_MODELS] + [(m, 20.0) for m in study.PAPER_MODELS]
    label = lambda m, p: m.name if p == m.power_limit else f"{m.name}@{p:g}W"  # noqa: E731
    cases = list({label(*c): c for c in cases}.values())  # M1 and M2's own limits are 20 W
    if args.cases:
        cases = [c for c in cases if label(*c) in args.cases]
        if not cases:
            parser.error(f"--cases {args.cases}: none of M1..M4 or M3@20W, M4@20W")

    given = {"spans": args.spans, "substeps": args.substeps, "segments": args.shooting_segments}
    settings = dataclasses.replace(study.STUDY_SETTINGS, **{k: v for k, v in given.items() if v is not None})
    rows = list({m.name: m for m, _ in cases}.values())
    at_20 = [c for c in cases if c[1] != c[0].power_limit]

    # compiled on first use, reused when warm
    solvers = study.study_solvers(settings)
    solver, coarse = solvers.fine, solvers.coarse

    def paper_models():
        models = [gait_problem.gait_model(m.mass_class, m.speed, m.power_limit) for m in rows]
        return multistart.solve_multistart(solver, [m.name for m in rows], models, families=study.STUDY_FAMILIES,
                                            coarse=coarse)

    def ours_once():
        """The study's way: the paper's models from every family, 20 W warm-started from them."""
        solutions = paper_models()
        found = {s.name: s for s in solutions}
        if at_20:
            models = [gait_problem.gait_model(m.mass_class, m.speed, p) for m, p in at_20]
            x0 = jnp.asarray(np.stack([found[m.name].x for m, _ in at_20]))
            for solution in solver.solve([label(*c) for c in at_20], models, x0=x0):
                solution.starts = found[solution.name.split("@")[0]].starts
                found[solution.name] = solution
        return [found[label(*c)] for c in cases]

    started = time.perf_counter()
    ours = ours_once()
    ours_time = time.perf_counter() - started
    ours_warm = None  # measured only with --warm
    if args.warm:
        started = time.perf_counter()
        ours_once()
        ours_warm = time.perf_counter() - started

    rows = []
    for (model, limit), solution in zip(cases, ours):
        peer = peer_row(dataclasses.replace(model, power_limit=limit), args.segments)
        gap = 100 * (solution.cost / peer["cost"] - 1)
        row = {"case": solution.name, "ours": {
            "cost": solution.cost, "status": solution.status, "cost_refined": solution.refinement["cost"],
            "refined_violations": solution.refinement["violations"],
            "refinement_passed": solution.refinement["passed"],
            "starts": solution.starts}, "peer": peer, "gap_percent": gap,
            "ours_batch_cold_s": ours_time, "ours_batch_warm_s": ours_warm}
        rows.append(row)
        worst = max(solution.refinement["violations"].items(), key=lambda kv: kv[1])
        print(f"{solution.name:8s} ours J = {solution.cost:8.4f} ({solution.status}; 4x grid J "
              f"{solution.refinement['cost']:.4f}, worst {worst[0]} {worst[1]:.1e})  peer J = {peer['cost']:8.4f} "
              f"({peer['status']}; {2 * args.segments} segments {peer['cost_finer_mesh']:.4f})  gap {gap:+6.2f} %",
              flush=True)
    warm = "not measured (--warm)" if ours_warm is None else f"{ours_warm:.0f} s warm"
    print(f"ours: {len(cases)} cases, {ours_time:.0f} s cold (compile included), {warm}")
    if args.smallest_limit is not None:
        rows += smallest_limits(solvers, [s for (m, p), s in zip(cases, ours) if p == m.power_limit],
                                args.segments, args.smallest_limit)
    save_results(args.name, {"segments": args.segments, "spans": settings.spans, "substeps": settings.substeps,
                             "shooting_segments": settings.segments, "solver": "interior point",
                             "smallest_limit_power_points": args.smallest_limit},
                 rows, args.out)


def smallest_limits(solvers, solutions, segments: int, power_points: int) -> list[dict]:
    """Per paper model: our smallest power limit (``paper.minimal_power_limits`` from ``solutions``, the
    models' optima, as the study runs it) against the peer's own minimisation with its limit held at
    ``power_points`` points between every two of its nodes, and the largest power each gait asks anywhere
    (the peer's on its interpolants; ours is kept on the 4x grid)."""
    from collocation_peer import PeerProblem
    from peer_smallest_limit import minimised_limit

    from biped_jax.robots.specs import PLANAR_SPECS
    from biped_jax.studies import paper as study
    models = {m.name: m for m in study.PAPER_MODELS}
    chosen = [models[s.name] for s in solutions]
    started = time.perf_counter()
    minima = study.minimal_power_limits(solvers.fine, solutions, study.paper_gait_models(chosen),
                                        coarse=solvers.coarse_power)
    ours_time = time.perf_counter() - started
    rows = []
    for model, mine in zip(chosen, minima):
        problem = PeerProblem(PLANAR_SPECS[model.mass_class], model.speed, model.power_limit)
        peer = minimised_limit(problem, segments, power_points)
        peer.pop("gait")
        ours_w = mine["min_power_limit_W"]
        ratio = None if ours_w is None or peer["limit_W"] is None else ours_w / peer["limit_W"]
        rows.append({"case": f"{model.name} smallest limit", "ours_W": ours_w, "ours_status": mine["min_power_status"],
                     "ours_solve_grid_W": mine["min_power_solve_grid_W"], "ours_s": ours_time,
                     "peer": peer, "peer_power_points": power_points, "ours_over_peer": ratio})
        print(f"{model.name} smallest limit: ours {ours_w} W ({mine['min_power_status']}, kept on the 4x grid); "
              f"peer {peer['limit_W']} W ({peer['status']}, its limit held at {power_points} points between its "
              f"nodes; {peer['between_nodes_W']:.4f} W anywhere)"
              + ("" if ratio is None else f"; ours / peer {ratio:.4f}"), flush=True)
    return rows


if __name__ == "__main__":
    main()
