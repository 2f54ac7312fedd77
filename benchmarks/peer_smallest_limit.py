"""The smallest feasible power limit of M1-M4 by the collocation peer, found by bisection, against ours.

For each model the peer (``collocation_peer.solve``, CasADi + IPOPT, Hermite-Simpson) solves the energy
problem at a power limit M_W: a limit is feasible when IPOPT converges. Bisection between an infeasible
limit and the model's own (feasible) limit, warm-started from the last feasible gait, until the bracket
is within ``--tolerance`` of its upper end; reported: that upper end (the smallest feasible limit found,
to the tolerance), on ``--segments`` and on twice as many segments, and what the gait found asks of a
motor between the peer's nodes (``collocation_peer.power_between_nodes``). Held at its nodes alone the
peer's limit is not a motor's: its gaits at the smallest limits chatter between the nodes (measured:
37-100 W between nodes of 40 segments at limits of 0.7-2.6 W); ``--power-points K`` holds it also at K
points between every two nodes, as our refinement grid holds ours. ``--methods minimise``: the peer's own
epigraph form (min M_W over gait and limit) from its energy optimum, as our continuation starts from
ours. Ours: the smallest limits of a ``biped-jax reproduce`` results file (``--ours OUT/results.json``:
the interior point's continuation, kept on the 4x finer grid), and the ratio ours / peer. Needs the
``bench`` extra (casadi).

    python benchmarks/peer_smallest_limit.py --ours out/results.json --one-mesh --power-points 1 \
        --methods bisection minimise
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pickle
import time
from pathlib import Path

from _results import save_results


def smallest_feasible_limit(problem, segments: int, tolerance: float, say=print, power_points: int = 0) -> dict:
    """Bisection on the peer's power limit between 0 and ``problem.power_limit`` (feasible); "gait": the
    peer's solution at the smallest feasible limit found, "between_nodes_W": the largest power it asks
    anywhere (``collocation_peer.power_between_nodes``)."""
    from collocation_peer import power_between_nodes, solve
    started = time.perf_counter()
    best = solve(problem, segments, power_points=power_points)
    if best["status"] != "converged":
        return {"limit_W": None, "status": f"infeasible at its own limit ({best['status']})", "solves": 1}
    low, high, solves = 0.0, problem.power_limit, 1
    while high - low > tolerance * high:
        middle = 0.5 * (low + high)
        trial = solve(dataclasses.replace(problem, power_limit=middle), segments, guess=best, power_points=power_points)
        solves += 1
        if trial["status"] == "converged":
            high, best = middle, trial
        else:
            low = middle
        say(f"  {segments} segments, M_W = {middle:.4f} W: {trial['status']} ({trial['wall_time_s']:.0f} s)")
    return {"limit_W": high, "infeasible_below_W": low, "cost_at_limit": best["cost"], "solves": solves,
            "status": "bracketed", "wall_time_s": time.perf_counter() - started, "gait": best,
            "between_nodes_W": power_between_nodes(problem, best)}


def minimised_limit(problem, segments: int, power_points: int = 0) -> dict:
    """The peer's own epigraph form: its energy optimum at the model's limit, then min M_W over gait and
    limit from there (``collocation_peer.solve(minimise_power_limit=True)``), as our continuation starts
    from our optimum; "limit_W" None where IPOPT did not converge; "between_nodes_W" as in
    :func:`smallest_feasible_limit`."""
    from collocation_peer import power_between_nodes, solve
    started = time.perf_counter()
    start = solve(problem, segments, power_points=power_points)
    found = solve(problem, segments, guess=start, minimise_power_limit=True, power_points=power_points)
    return {"limit_W": found["power_limit"] if found["status"] == "converged" else None, "status": found["status"],
            "cost_at_limit": found["cost"], "iterations": found["iterations"],
            "wall_time_s": time.perf_counter() - started, "gait": found,
            "between_nodes_W": power_between_nodes(problem, found)}


def kept_bisection(problem, name: str, segments: int, tolerance: float, power_points: int = 0,
                   folder: Path | None = None, say=print) -> dict:
    """:func:`smallest_feasible_limit`, read from ``folder`` where an earlier run kept it (a pickle per
    model, mesh and ``power_points``), else run and kept there (``folder`` None: run, not kept)."""
    saved = folder and folder / f"{name}_{segments}{f'_p{power_points}' if power_points else ''}.pickle"
    if saved and saved.is_file():
        found = pickle.loads(saved.read_bytes())
        if "gait" in found and "between_nodes_W" not in found:  # kept before bisections reported it
            from collocation_peer import power_between_nodes
            found["between_nodes_W"] = power_between_nodes(problem, found["gait"])
        return found
    found = smallest_feasible_limit(problem, segments, tolerance, say=say, power_points=power_points)
    if saved:
        saved.parent.mkdir(parents=True, exist_ok=True)
        saved.write_bytes(pickle.dumps(found))
    return found


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ours", type=Path, required=True, help="results.json of `biped-jax reproduce`")
    parser.add_argument("--segments", type=int, default=40, help="the peer's Hermite-Simpson segments")
    parser.add_argument("--tolerance", type=float, default=0.01, help="the bracket's relative width")
    parser.add_argument("--one-mesh", action="store_true", help="only --segments (not also twice as many)")
    parser.add_argument("--power-points", type=int, default=0,
                        help="the limit held also at this many points between every two of the peer's nodes "
                             "(collocation_peer.solve's power_points; 0: at its nodes only)")
    parser.add_argument("--models", nargs="+", default=None, help="some of M1-M4 (default: all four)")
    parser.add_argument("--peer-gaits", type=Path, default=None,
                        help="a folder keeping the peer's bisections (read where present, else written)")
    parser.add_argument("--methods", nargs="+", default=["bisection"], choices=("bisection", "minimise"),
                        help="the peer's bisection on the limit (smallest_feasible_limit) and/or its own "
                             "minimisation of the limit from its energy optimum (minimised_limit)")
    parser.add_argument("--name", default="peer_smallest_limit")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args()

    from collocation_peer import PeerProblem

    from biped_jax.robots.specs import PLANAR_SPECS
    from biped_jax.studies import paper as study

    ours = {m["model"]: m for m in json.loads(args.ours.read_text())["models"]}
    rows = []
    for model in study.PAPER_MODELS:
        if args.models and model.name not in args.models:
            continue
        problem = PeerProblem(PLANAR_SPECS[model.mass_class], model.speed, model.power_limit)
        meshes = (args.segments,) if args.one_mesh else (args.segments, 2 * args.segments)
        peer = {n: kept_bisection(problem, model.name, n, args.tolerance, args.power_points, args.peer_gaits,
                                  say=lambda m: print(m, flush=True)) for n in meshes} \
            if "bisection" in args.methods else {}
        minimised = {n: minimised_limit(problem, n, args.power_points) for n in meshes} \
            if "minimise" in args.methods else {}
        mine = ours[model.name]["min_power_limit_W"]
        row = {"model": model.name, "ours_W": mine, "ours_status": ours[model.name]["min_power_status"],
               "peer": {str(n): {k: v for k, v in p.items() if k != "gait"} for n, p in peer.items()},
               "peer_minimised": {str(n): {k: v for k, v in p.items() if k != "gait"} for n, p in minimised.items()}}
        for label, found in (("peer", peer), ("peer_minimised", minimised)):
            for n, p in found.items():
                row[f"ours_over_{label}_{n}"] = None if mine is None or p["limit_W"] is None else mine / p["limit_W"]
        rows.append(row)
        print(f"{model.name}: ours {mine} W; peer " + ", ".join(
            f"{n} segments {p['limit_W']} W ({p['solves']} solves; {p.get('between_nodes_W', float('nan')):.4f} W "
            f"between its nodes)" for n, p in peer.items()) + "".join(
            f"; minimised on {n} segments: {p['limit_W']} W ({p['status']}, {p['between_nodes_W']:.4f} W between "
            f"its nodes)" for n, p in minimised.items()), flush=True)
        save_results(args.name, {"segments": args.segments, "tolerance": args.tolerance, "ours": str(args.ours),
                                 "power_points": args.power_points},
                     rows, args.out)  # after every model: a long run keeps what it found


if __name__ == "__main__":
    main()
