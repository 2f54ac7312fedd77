"""Diagnostic: where does our solver land when started inside the collocation peer's basin?

Solves M2 (or another model) with the independent peer (``collocation_peer.solve``), fits its joint
paths into our B-spline space (least squares on the peer's node positions; control point 0 mirrored)
with the shooting nodes on the peer's stance angle and rate, reports J and the violations of that fit
in our transcription, then solves our problem from it. This is a diagnostic of the transcription and
the solver, never a product start (the study solves from its own heuristics only).

    python benchmarks/peer_basin.py --segments 16

Needs the ``bench`` extra (casadi).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _results import save_results

# peer coordinates (absolute pitches) -> the peer's relative joints, the matrix it uses for its power limit
from collocation_peer import JOINT_SIGNS as _JOINT_SIGNS  # noqa: E402
from collocation_peer import RELATIVE_JOINTS as _PEER_TO_JOINTS  # noqa: E402


def fitted_start(peer: dict, settings) -> np.ndarray:
    """Our decision vector closest to the peer's solution, shape (settings.size,)."""
    from scipy.interpolate import CubicHermiteSpline

    from biped_jax.gait import problem as gait_problem
    from biped_jax.robots import planar_biped
    phi, phid, t = peer["phi"], peer["phid"], peer["t"]
    joints = (_PEER_TO_JOINTS @ phi) * _JOINT_SIGNS[:, None]
    points = np.linalg.lstsq(gait_problem.basis(settings, t / t[-1])[0], joints.T, rcond=None)[0]
    points[-1] = 0.5 * (points[-1] + points[0][planar_biped.SWAP])
    starts = gait_problem.segment_starts(settings) * t[-1]
    stance = CubicHermiteSpline(t, phi[0], phid[0])  # our stance angle is the peer's shank pitch
    nodes = np.stack([stance(starts), np.interp(starts, t, phid[0])], axis=-1)
    return np.asarray(gait_problem.pack(nodes, points[1:]))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mass-class", default="12kg", choices=("12kg", "18kg"))
    parser.add_argument("--speed", type=float, default=0.555, help="m/s")
    parser.add_argument("--power-limit", type=float, default=20.0, help="W")
    parser.add_argument("--peer-segments", type=int, default=30)
    parser.add_argument("--spans", type=int, default=16)
    parser.add_argument("--segments", type=int, default=16, help="our shooting segments (1: single shooting)")
    parser.add_argument("--mu-initial", type=float, default=1e-3,
                        help="the interior point's first barrier parameter (default 1e-3, a warm start)")
    parser.add_argument("--max-iterations", type=int, default=300)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)

    from collocation_peer import PeerProblem, solve

    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait.solver import GaitSolver
    from biped_jax.robots.specs import PLANAR_SPECS

    peer = solve(PeerProblem(PLANAR_SPECS[args.mass_class], args.speed, args.power_limit), args.peer_segments)
    print(f"peer: J = {peer['cost']:.4f} ({peer['status']}, {args.peer_segments} segments)", flush=True)
    settings = gait_problem.GaitSettings(spans=args.spans, segments=args.segments)
    solver = GaitSolver(settings, mass_class_template=args.mass_class).with_options(
        mu_initial=args.mu_initial, max_iterations=args.max_iterations)
    model = gait_problem.gait_model(args.mass_class, args.speed, args.power_limit)
    x0 = fitted_start(peer, settings)
    fit = jax.tree.map(lambda a: np.asarray(a[0]), solver.simulate(
        jnp.asarray(x0)[None], jax.tree.map(lambda a: jnp.asarray(a, float)[None], model)))
    groups = gait_problem.constraint_groups(fit, model, settings)
    fit_violations = {k: float(v) for k, v in gait_problem.violations(groups).items()}
    print(f"fit: J = {float(gait_problem.cost(fit)):.4f}, violations "
          + ", ".join(f"{k} {v:.1e}" for k, v in fit_violations.items() if v > 1e-4), flush=True)
    started = time.perf_counter()
    def progress(i, row):
        print(f"  iteration {i}: J {float(row['cost'][0]):.4f}, scaled violation "
              f"{float(row['violation'][0]):.1e}, KKT error {float(row['error'][0]):.0e}, "
              f"{time.perf_counter() - started:.0f} s", flush=True)

    solution, = solver.solve(["from the peer's basin"], [model], x0=jnp.asarray(x0)[None], progress=progress)
    gap = 100 * (solution.cost / peer["cost"] - 1)
    print(f"ours from there: {solution.status}, J = {solution.cost:.4f} ({gap:+.1f} % on the peer)"
          f", largest violation {solution.max_violation:.1e}, 4x grid J {solution.refinement['cost']:.4f}")
    save_results("peer_basin", {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
                 [{"peer_cost": peer["cost"], "fit_cost": float(gait_problem.cost(fit)),
                   "fit_violations": fit_violations,
                   "status": solution.status, "cost": solution.cost, "max_violation": solution.max_violation,
                   "refinement": solution.refinement, "history": solution.history}], args.out)


if __name__ == "__main__":
    main()
