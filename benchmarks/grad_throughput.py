"""Gradients per second of the optimiser's own objective, and MuJoCo C finite differences as baseline.

The objective is the Lagrangian f + y . h + z . g of the M2 gait problem (cost, every constraint group,
fixed multipliers) through the solver's own problem (``GaitSolver.problem.evaluate``), its gradient the
reverse pass the interior point's exact derivatives start from; ``--segments 1`` for single shooting
(default: one segment per knot span, the solver's default). Batches are
B different decision vectors (vmap); compile time is measured apart, run time is the median of
``--repeats`` calls. The baseline evaluates the same function with MuJoCo C (``biped_jax.gait.mujoco_reference``)
and takes central differences over the same decision vector, spread over all CPU cores with a process
pool; its gradient is checked against the MJX one.

    python benchmarks/grad_throughput.py --batch 1 16 256 1024
"""

import argparse
import multiprocessing
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _results import median_seconds, save_results

SPEED, POWER_LIMIT, STEP_LENGTH = 0.555, 20.0, 0.2  # model M2


def _problem(settings):
    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait.solver import GaitSolver
    solver = GaitSolver(settings)
    model = gait_problem.gait_model("12kg", SPEED, POWER_LIMIT, STEP_LENGTH)
    x0 = jax.jit(lambda m: gait_problem.initial_guess(m, settings))(model)
    trajectory = jax.jit(lambda x, m: gait_problem.simulate(x, m, solver.biped, settings))(x0, model)
    h, g = gait_problem.scaled_constraints(gait_problem.constraint_groups(trajectory, model, settings))
    multipliers = (0.1 * jnp.ones(h.size), 0.1 * jnp.ones(g.size))
    return solver, model, np.asarray(x0), multipliers


def lagrangian_value(f, h, g, lam_eq, lam_in):
    """The Lagrangian f + y . h + z . g."""
    return f + h @ lam_eq + g @ lam_in


def _inputs(model, x0, multipliers, batch):
    offsets = 0.01 * np.sin(np.arange(batch)[:, None] + np.arange(x0.size)[None])
    lam_eq, lam_in = multipliers
    tile = lambda a: jnp.broadcast_to(a, (batch,) + jnp.shape(a))  # noqa: E731
    return jnp.asarray(x0 + offsets), jax.tree.map(tile, model), tile(lam_eq), tile(lam_in)


def measure_mjx(solver, model, x0, multipliers, batch, repeats):
    args = _inputs(model, x0, multipliers, batch)

    def lagrangian(x, model_, lam_eq, lam_in):
        return lagrangian_value(*solver.problem.evaluate(x, model_), lam_eq, lam_in)
    started = time.perf_counter()
    compiled = jax.jit(jax.vmap(jax.value_and_grad(lagrangian))).lower(*args).compile()
    compile_s = time.perf_counter() - started
    seconds = median_seconds(compiled, args, repeats)
    _, gradient = compiled(*args)
    return {"backend": "mjx", "batch": batch, "compile_s": compile_s, "seconds_per_call": seconds,
            "gradients_per_second": batch / seconds, "ms_per_gradient": 1e3 * seconds / batch}, \
        np.asarray(gradient[0])


# ----------------------------------------------------------------------------- MuJoCo C baseline

_WORKER = {}


def _worker_init(settings, multipliers):
    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait.mujoco_reference import CGaitRollout
    jax.config.update("jax_platforms", "cpu")
    _WORKER["rollout"] = CGaitRollout("12kg", settings)
    _WORKER["model"] = gait_problem.gait_model("12kg", SPEED, POWER_LIMIT, STEP_LENGTH)
    _WORKER["settings"] = settings
    _WORKER["multipliers"] = tuple(np.asarray(m) for m in multipliers)

    @jax.jit
    def merit(trajectory, model, lam_eq, lam_in):  # the cheap algebra after the C rollout
        h, g = gait_problem.scaled_constraints(gait_problem.constraint_groups(trajectory, model, settings))
        return lagrangian_value(gait_problem.cost(trajectory), h, g, lam_eq, lam_in)
    _WORKER["merit"] = merit


def _lagrangian_c(x):
    trajectory = _WORKER["rollout"].simulate(x, SPEED, STEP_LENGTH)
    return float(_WORKER["merit"](trajectory, _WORKER["model"], *_WORKER["multipliers"]))


def central_difference_gradient(pool, x, step=1e-6):
    points = [x + step * e for e in np.eye(x.size)] + [x - step * e for e in np.eye(x.size)]
    values = np.array(pool.map(_lagrangian_c, points))
    return (values[:x.size] - values[x.size:]) / (2 * step)


def measure_c(settings, x, multipliers, repeats):
    workers = os.cpu_count()
    context = multiprocessing.get_context("spawn")
    with context.Pool(workers, _worker_init, (settings, tuple(np.asarray(m) for m in multipliers))) as pool:
        central_difference_gradient(pool, x)  # warm-up (workers jit their small merit function)
        times, gradient = [], None
        for _ in range(repeats):
            started = time.perf_counter()
            gradient = central_difference_gradient(pool, x)
            times.append(time.perf_counter() - started)
        single = time.perf_counter()
        pool.map(_lagrangian_c, [x] * workers)  # one objective per process, in parallel
        rollout_s = time.perf_counter() - single
    seconds = float(np.median(times))
    return {"backend": "mujoco-c central differences", "batch": 1, "workers": workers,
            "evaluations_per_gradient": 2 * x.size, "seconds_per_call": seconds,
            "gradients_per_second": 1 / seconds, "ms_per_gradient": 1e3 * seconds,
            "ms_per_objective": 1e3 * rollout_s}, gradient


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spans", type=int, default=16, help="knot spans of the joint B-splines (default 16)")
    parser.add_argument("--degree", type=int, default=3, help="B-spline degree (default 3)")
    parser.add_argument("--substeps", type=int, default=8, help="Runge-Kutta steps per span (default 8)")
    parser.add_argument("--segments", type=int, default=None, help="shooting segments (default: one per span)")
    parser.add_argument("--batch", type=int, nargs="+", default=[1, 16, 256, 1024])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-baseline", action="store_true", help="skip the MuJoCo C baseline")
    parser.add_argument("--dynamics", choices=("mjx", "chain"), default="chain",
                        help="single-support dynamics of the rollout (default chain)")
    parser.add_argument("--name", default="grad_throughput", help="results file stem")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    from biped_jax.gait import problem as gait_problem
    settings = gait_problem.GaitSettings(spans=args.spans, degree=args.degree, substeps=args.substeps,
                                dynamics=args.dynamics, segments=args.segments)
    solver, model, x0, multipliers = _problem(settings)
    rows, mjx_gradient = [], None
    print(f"{'backend':32s} {'batch':>6s} {'compile s':>10s} {'ms/call':>10s} {'grad/s':>10s} {'ms/grad':>8s}")
    for batch in args.batch:
        try:
            row, gradient = measure_mjx(solver, model, x0, multipliers, batch, args.repeats)
        except Exception as error:  # out of memory at large batches: record and stop growing
            print(f"batch {batch}: {type(error).__name__}: {str(error)[:200]}")
            rows.append({"backend": args.dynamics, "batch": batch, "error": str(error)[:500]})
            break
        mjx_gradient = gradient if mjx_gradient is None else mjx_gradient
        row["backend"] = args.dynamics
        rows.append(row)
        print(f"{args.dynamics + ' (jax.value_and_grad)':32s} {batch:6d} {row['compile_s']:10.1f} "
              f"{1e3 * row['seconds_per_call']:10.1f} {row['gradients_per_second']:10.1f} "
              f"{row['ms_per_gradient']:8.2f}", flush=True)
    if not args.no_baseline:
        x = x0 + 0.01 * np.sin(np.arange(x0.size))  # the batch's first point
        row, gradient = measure_c(settings, x, multipliers, args.repeats)
        row["max_relative_difference_to_mjx"] = float(
            np.max(np.abs(gradient - mjx_gradient)) / np.max(np.abs(mjx_gradient)))
        rows.append(row)
        best = max(r["gradients_per_second"] for r in rows if r["backend"] == args.dynamics and "error" not in r)
        single = next(r for r in rows if r["backend"] == args.dynamics and r["batch"] == args.batch[0])
        row["mjx_single_speedup"] = single["gradients_per_second"] / row["gradients_per_second"]
        row["mjx_best_batch_speedup"] = best / row["gradients_per_second"]
        print(f"{'mujoco C, central differences':32s} {1:6d} {'':10s} {1e3 * row['seconds_per_call']:10.1f} "
              f"{row['gradients_per_second']:10.1f} {row['ms_per_gradient']:8.2f}  ({row['workers']} processes, "
              f"{row['evaluations_per_gradient']} rollouts; gradient differs from MJX by "
              f"{row['max_relative_difference_to_mjx']:.1e} relative)")
        print(f"MJX over MuJoCo C finite differences: {row['mjx_single_speedup']:.1f}x at batch "
              f"{args.batch[0]}, {row['mjx_best_batch_speedup']:.1f}x at the best batch")
    save_results(args.name, {"spans": args.spans, "degree": args.degree,
                                 "substeps": args.substeps, "model": "M2", "dynamics": args.dynamics,
                                     "decision_variables": int(x0.size), "float": "float64"},
                 rows, args.out)


if __name__ == "__main__":
    main()
