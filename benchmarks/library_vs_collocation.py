"""A gait library's points against the independent direct-collocation peer.

Reads a ``biped-jax library`` output folder (``library.json``) and solves the same problems (mass class,
speed, step length, power limit; ideal drives) with ``collocation_peer.solve`` (CasADi + IPOPT,
Hermite-Simpson) on ``--segments`` segments and on twice as many (its own mesh check). Reported per
point: our J on the library's grid and on the 4x finer one, our status, refinement check and space
check (J in the library's space and in the finer one it reports, the estimated error), the peer's J on
both meshes and the gap (ours on the 4x grid / the peer's on its finer mesh - 1, in %); where ours is
below the peer (``--from-ours all``: everywhere) the peer started from our gait (``library.npz``'s samples)
on its finer mesh, which must find our gait or a cheaper one; the peer's largest joint power between its
nodes (``collocation_peer.power_between_nodes``: it holds M_W at its nodes only, ours on the 4x grid);
and how many points are within 1 % of the peer (or below it), and of the peer from our gait too. Needs
the ``bench`` extra (casadi).

    biped-jax library --out OUT
    python benchmarks/library_vs_collocation.py OUT          # every converged point
    python benchmarks/library_vs_collocation.py OUT --points 6
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from _results import save_results


def chosen_points(points: list[dict], count: int | None) -> list[dict]:
    """The points to check: all, or ``count`` spread over the grid, the steepest corner (largest J / L)
    always among them."""
    if count is None or count >= len(points):
        return points
    steepest = max(points, key=lambda p: p["cost_per_metre"])
    step = len(points) / count
    picked = [points[int(k * step)] for k in range(count)]
    return picked if steepest in picked else picked[:-1] + [steepest]


def peer_guess(q: np.ndarray, qd: np.ndarray, u: np.ndarray, t_f: float, segments: int) -> dict:
    """Our gait (``library.npz``'s samples evenly in time: q, qd (S, 5), u (S, 4)) as a start of the peer
    on ``segments`` Hermite-Simpson segments: its link pitches phi from our stance angle (its shank
    pitch) and joints, interpolated at its knots and midpoints; the torques with the joints' signs."""
    from collocation_peer import JOINT_SIGNS

    from biped_jax.robots.planar_biped import ACTUATED_INDEX as ACTUATED
    s = np.linspace(0.0, 1.0, q.shape[0])
    nodes = np.linspace(0.0, 1.0, 2 * segments + 1)

    def pitches(stance, joints):
        hip1, knee1, hip2, knee2 = (joints * JOINT_SIGNS).T
        thigh1 = stance - knee1
        torso = hip1 + thigh1
        thigh2 = torso - hip2
        return np.stack([stance, thigh1, torso, thigh2, knee2 + thigh2])

    phi = pitches(q[:, 0], q[:, ACTUATED])
    phid = pitches(qd[:, 0], qd[:, ACTUATED])
    at = lambda a: np.stack([np.interp(nodes, s, row) for row in a])  # noqa: E731
    return {"phi": at(phi), "phid": at(phid), "u": at((u * JOINT_SIGNS).T)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("library", type=Path, help="a biped-jax library output folder")
    parser.add_argument("--points", type=int, default=None, help="how many points (default: all)")
    parser.add_argument("--segments", type=int, default=40, help="the peer's Hermite-Simpson segments")
    parser.add_argument("--from-ours", choices=("below", "all"), default="below",
                        help="start the peer from our gait too (on its finer mesh) where ours is below it "
                             "(default), or at every point")
    parser.add_argument("--name", default="library_vs_collocation")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args()
    from collocation_peer import PeerProblem, power_between_nodes, solve

    from biped_jax.robots.specs import PLANAR_SPECS
    record = json.loads((args.library / "library.json").read_text())
    if record.get("drive") is not None:
        parser.error("the peer has ideal drives only: give a library without --drive")
    spec = PLANAR_SPECS[record["mass_class"]]
    gaits = np.load(args.library / "library.npz")
    rows = []
    for point in chosen_points(record["points"], args.points):
        problem = PeerProblem(spec, point["speed_mps"], record["power_limit_W"], point["step_length_m"])
        coarse, fine = solve(problem, args.segments), solve(problem, 2 * args.segments)
        ours = point["refined_cost"]
        gap = 100 * (ours / fine["cost"] - 1)
        confirmed = None
        if gap < 0 or args.from_ours == "all":
            # below the peer: the peer started from our gait must find it (a cheaper optimum of its own problem)
            index = record["points"].index(point)
            at = np.unravel_index(index, gaits["cost"].shape)
            guess = peer_guess(gaits["gait_q"][at], gaits["gait_qd"][at], gaits["gait_u"][at], point["t_f"],
                               2 * args.segments)
            warm = solve(problem, 2 * args.segments, guess=guess)
            confirmed = {"cost": warm["cost"], "status": warm["status"], "gap_percent": 100 * (ours / warm["cost"] - 1),
                         "power_between_nodes_W": power_between_nodes(problem, warm)}
            print(f"  the peer from our gait: J {warm['cost']:.4f} ({warm['status']}, "
                  f"{confirmed['power_between_nodes_W']:.2f} W between its nodes), ours "
                  f"{confirmed['gap_percent']:+.2f} % from it", flush=True)
        rows.append({"speed_mps": point["speed_mps"], "step_length_m": point["step_length_m"],
                     "ours": {"cost": point["cost"], "cost_refined": ours, "status": point["status"],
                              "refinement_passed": point["refinement_passed"], "started": point["started"],
                              "space": point.get("space")},
                     "peer": {"cost": coarse["cost"], "status": coarse["status"], "segments": args.segments,
                              "cost_finer_mesh": fine["cost"], "status_finer_mesh": fine["status"],
                              "power_between_nodes_W": power_between_nodes(problem, fine)},
                     "gap_percent": gap, "peer_from_ours": confirmed})
        space = point.get("space") or {}
        spans = "" if space.get("error_estimate") is None else (
            f" in {space['spans'][-1]} spans (J " + " / ".join(f"{c:.4f}" for c in space["cost"][:-1])
            + f" in {' / '.join(map(str, space['spans'][:-1]))}, "
            f"est. error {100 * space['error_estimate']:.2f} %)")
        print(f"{point['speed_mps']:5.2f} m/s, L {point['step_length_m']:5.3f} m: ours J {point['cost']:8.4f}{spans} "
              f"(4x grid {ours:8.4f}, {point['status']})  peer J {coarse['cost']:8.4f} / {fine['cost']:8.4f} "
              f"({coarse['status']} / {fine['status']}, {args.segments} / {2 * args.segments} segments, "
              f"{rows[-1]['peer']['power_between_nodes_W']:.2f} W between its nodes)  "
              f"gap {gap:+6.2f} %", flush=True)
    within = sum(row["gap_percent"] <= 1.0 for row in rows)
    confirmed = sum(row["gap_percent"] <= 1.0 and (row["peer_from_ours"] is None
                                                   or row["peer_from_ours"]["gap_percent"] <= 1.0) for row in rows)
    print(f"{within} of {len(rows)} points within 1 % of the peer (or below it); {confirmed} also within 1 % of "
          "the peer started from our gait, where it was")
    save_results(args.name, {"library": str(args.library), "mass_class": record["mass_class"],
                             "power_limit_W": record["power_limit_W"], "settings": record["settings"],
                             "segments": args.segments, "space_check": record.get("space_check"),
                             "within_1_percent": within,
                             "within_1_percent_of_both": confirmed}, rows, args.out)


if __name__ == "__main__":
    main()
