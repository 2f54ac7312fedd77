"""Diagnostic: our smallest power limit started from the collocation peer's gait at its smallest limit.

Our study reports a local minimum of the epigraph problem min M_W over feasible gaits from its own
optima; the collocation peer's bisection (``peer_smallest_limit.py``) finds much smaller limits. This
script asks whether the gap is the start or the transcription: per model the peer's bisection (IPOPT
converges = feasible) on ``--segments``, its gait at the smallest feasible limit fitted into our study
space (``peer_basin.fitted_start``), our energy problem solved from each fit at a few limits above the
peer's (``--factors``), then our interior point's continuation of the limit problem
(:meth:`biped_jax.gait.solver.GaitSolver.minimise_power_limit`, all models in one batch) from the gait at
the lowest of those limits that converged, with our refinement check on the 4x grid. Reported per
model: the peer's limit, ours from the peer's gait (on the solve grid and kept on the 4x grid) and
their ratio. A diagnostic, never a product start (the study solves from its own heuristics only).

    python benchmarks/limit_from_peer.py --models M2 M4

Needs the ``bench`` extra (casadi).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
from _results import save_results


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["M1", "M2", "M3", "M4"])
    parser.add_argument("--segments", type=int, default=40, help="the peer's Hermite-Simpson segments")
    parser.add_argument("--tolerance", type=float, default=0.02, help="the peer's bisection bracket, relative")
    parser.add_argument("--spans", type=int, default=48, help="our knot spans (and shooting segments)")
    parser.add_argument("--factors", type=float, nargs="+", default=[1.25, 2.5],
                        help="the limits, over the peer's, at which our energy problem is first solved")
    parser.add_argument("--power-points", type=int, default=0,
                        help="the peer's limit held also at this many points between every two of its nodes "
                             "(collocation_peer.solve's power_points; 0: at its nodes only)")
    parser.add_argument("--peer-gaits", type=Path, default=None,
                        help="a folder keeping the peer's bisections (read where present, else written)")
    parser.add_argument("--name", default="limit_from_peer")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args()

    from biped_jax.commands import configure_jax
    configure_jax()
    import jax.numpy as jnp
    from collocation_peer import PeerProblem
    from peer_basin import fitted_start
    from peer_smallest_limit import kept_bisection

    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait.solver import GaitSolver
    from biped_jax.robots.specs import PLANAR_SPECS
    from biped_jax.studies import paper as study

    chosen = [m for m in study.PAPER_MODELS if m.name in args.models]
    if not chosen:
        raise SystemExit(f"--models: none of {args.models} is one of {[m.name for m in study.PAPER_MODELS]}")
    settings = gait_problem.GaitSettings(spans=args.spans, segments=args.spans, substeps=4)
    rows, starts, models = [], [], []
    for model, gait_model in zip(chosen, study.paper_gait_models(chosen)):
        problem = PeerProblem(PLANAR_SPECS[model.mass_class], model.speed, model.power_limit)
        peer = kept_bisection(problem, model.name, args.segments, args.tolerance, args.power_points,
                              args.peer_gaits, say=lambda m: print(m, flush=True))
        print(f"{model.name}: the peer's smallest feasible limit {peer['limit_W']} W", flush=True)
        rows.append({"model": model.name, "peer": {k: v for k, v in peer.items() if k != "gait"}})
        starts.append(fitted_start(peer["gait"], settings))
        # posed at the peer's limit: the continuation's t starts at 1 (the fit is close to feasible there)
        models.append(dataclasses.replace(gait_model, power_limit=jnp.asarray(peer["limit_W"])))

    solver = GaitSolver(settings, study.IP_WARM_OPTIONS)
    started = time.perf_counter()
    # the fits are not feasible in our transcription (the peer holds its limit at its nodes only, and the
    # least-squares fit moves the joints): first our energy problem at a few limits above the peer's from
    # each fit, one batch; the limit's continuation then starts from the lowest limit that converged
    factors = args.factors
    lanes = [(b, f) for b in range(len(rows)) for f in factors]
    posed = [dataclasses.replace(models[b], power_limit=jnp.asarray(f * float(models[b].power_limit)))
             for b, f in lanes]
    def progress(i, row):
        print(f"  iteration {i}: {int(np.sum(row['done']))} of {len(row['done'])} done, "
              f"{time.perf_counter() - started:.0f} s", flush=True)

    # from a start off the optimum: the study's cold options, and no rounds holding the power between samples
    energy = solver.using(study.IP_OPTIONS).solve([f"{rows[b]['model']} at {f} x" for b, f in lanes], posed,
                                                  x0=np.stack([starts[b] for b, _ in lanes]), progress=progress,
                                                  tightening=0)
    kept, kept_models = [], []
    for b, row in enumerate(rows):
        mine = [(f, s, m) for (c, f), s, m in zip(lanes, energy, posed) if c == b]
        row["energy_at"] = [{"factor": f, "status": s.status, "cost": s.cost, "max_violation": s.max_violation}
                            for f, s, _ in mine]
        usable = [(f, s, m) for f, s, m in mine if s.status == "converged"]
        f, s, m = usable[0] if usable else min(mine, key=lambda t: t[1].max_violation)
        row["started_at_factor"] = f
        kept.append(s.x)
        kept_models.append(m)
        print(f"{row['model']}: our energy problem from the peer's gait: "
              + ", ".join(f"{e['factor']} x {e['status']} J {e['cost']:.3f}" for e in row["energy_at"]), flush=True)
    minima = solver.minimise_power_limit([r["model"] for r in rows], kept_models, np.stack(kept), progress=progress)
    wall = time.perf_counter() - started
    for row, minimum in zip(rows, minima):
        peer_limit = row["peer"]["limit_W"]
        row.update(ours_status=minimum.status, ours_solve_grid_W=minimum.refinement["solve_grid_limit_W"],
                   ours_kept_W=minimum.power_limit_W, refinement_passed=minimum.refinement["passed"],
                   refinement_failed=minimum.refinement["failed"], max_violation=minimum.max_violation,
                   cost=minimum.cost, ours_over_peer=minimum.power_limit_W / peer_limit)
        print(f"{row['model']}: peer {peer_limit:.4f} W; ours from the peer's gait {minimum.status}, "
              f"{row['ours_solve_grid_W']:.4f} W on the solve grid, {minimum.power_limit_W:.4f} W kept on the 4x "
              f"grid (refinement {'passed' if row['refinement_passed'] else 'failed: ' + str(row['refinement_failed'])}"
              f"), {row['ours_over_peer']:.3f} x the peer's", flush=True)
    save_results(args.name, {"segments": args.segments, "tolerance": args.tolerance, "spans": args.spans,
                             "power_points": args.power_points,
                             "factors": factors,
                             "our_wall_time_s": wall}, rows, args.out)


if __name__ == "__main__":
    main()
