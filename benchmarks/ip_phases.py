"""Where an iteration of the batched interior point spends its time, phase by phase, on the study's gait
problem (M1-M4 repeated to a batch of B): the exact derivatives (one forward-over-reverse pass split by
shooting segment, the inequality Jacobian in its segments' blocks), the Newton system (condensed
Hessian, null-space QR, reduced Hessian and its Cholesky factorisation, one solve), one trial point
of the line search (a rollout), and the whole iteration as the solver runs it (its line search
included); with ``--segment-pass``, inside the derivatives, the shooting segments' rows alone and their
forward-over-reverse pass alone (one direction per curved column: what a direction costs against the
rows). Each phase is its own jit-compiled, vmapped program timed at the same iterate (the state after
``--warm-iterations`` iterations from the heuristic start), so the sum of the phases need not equal the
iteration: XLA fuses across them in the solver (the segments' pass alone can take longer than the
derivatives that hold it).

    python benchmarks/ip_phases.py --batch 4 16
    python benchmarks/ip_phases.py --batch 4 16 --spans 16 --segment-pass
    python benchmarks/ip_phases.py --batch 256 1024 --repeats 5     # on a GPU
"""

import argparse
import functools
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _results import median_seconds, save_results


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, nargs="+", default=[4, 16], help="batch sizes B")
    parser.add_argument("--spans", type=int, default=48, help="knot spans (the study's 48)")
    parser.add_argument("--substeps", type=int, default=4)
    parser.add_argument("--warm-iterations", type=int, default=15,
                        help="iterations from the heuristic start before timing (a representative iterate)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--segment-pass", action="store_true",
                        help="also time, inside the derivatives, the segments' rows and their second-order pass alone")
    parser.add_argument("--float32", action="store_true", help="single precision (default float64)")
    parser.add_argument("--name", default="ip_phases", help="results file stem")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", not args.float32)

    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait.solver import GaitSolver, stack_tree
    from biped_jax.optim import exact_derivatives, jacobian, local_derivatives
    from biped_jax.optim import interior_point
    from biped_jax.studies import paper as study

    settings = gait_problem.GaitSettings(spans=args.spans, substeps=args.substeps)
    solver = GaitSolver(settings)
    models = study.paper_gait_models(study.PAPER_MODELS)
    rows = []
    for batch_size in args.batch:
        picked = [models[b % len(models)] for b in range(batch_size)]
        params = stack_tree(picked)
        x0 = solver._initial_guess(params)
        problem, structure = solver.prepared("energy", x0, params)
        options = interior_point.InteriorPointOptions()
        compiled = interior_point.compile_problem(problem, options)
        _, h0, g0 = jax.eval_shape(problem.evaluate, x0[0], jax.tree.map(lambda a: a[0], params))
        zeros = (jnp.zeros((batch_size,) + h0.shape), jnp.zeros((batch_size,) + g0.shape))
        state = compiled.initial(x0, params, *zeros, options.mu_initial)
        started = time.perf_counter()
        state = jax.block_until_ready(compiled.block(structure, params, state,
                                                     jnp.asarray(args.warm_iterations, jnp.int32)))
        warm_seconds = time.perf_counter() - started
        weight, y, z = state.scale_f, state.scale_h * state.y, state.scale_g * state.z

        derivatives = jax.jit(jax.vmap(functools.partial(exact_derivatives.derivatives, problem, blocks=True),
                                       in_axes=(0, 0, 0, 0, 0, None)))
        evaluate = jax.jit(jax.vmap(problem.evaluate))

        def newton_step(hessian, jac_h, jac_g, grad, h, g, s, z, mu):
            sigma = z / s
            solve, _ = interior_point.condensed_newton_solver(hessian, jac_h, jac_g, sigma, jnp.zeros(()),
                                                              jnp.zeros(()), options.equality_regularisation)
            return solve(-(grad + jacobian.rmatvec(jac_g, sigma * (g + s) + mu / s - z)), h)

        newton = jax.jit(jax.vmap(newton_step))

        # inside the derivatives: every shooting segment's rows once (the primal), and the segments'
        # forward-over-reverse pass alone (one direction per curved column, its Lagrangian weighted by
        # the iterate's multipliers in the split's order), the boundary and the assembly left out
        local = problem.local
        if args.segment_pass and local is None:
            raise SystemExit("--segment-pass needs shooting segments (the split derivatives): this space has one")
        columns = jnp.asarray(local.segment_columns) if local is not None else None

        def segment_rows(x, model):
            padded = jnp.concatenate([x, jnp.zeros(1, x.dtype)])
            return jax.vmap(lambda c, d: local.segment(padded[c], d, model))(columns, local.segment_data)

        def segment_pass(x, model, y, z):
            segments, width = columns.shape
            # the row counts (shapes only, not timed), then the multipliers in the split's order as the
            # derivatives place them: the segments' part
            rows = jax.eval_shape(segment_rows, x, model)
            ends = jax.eval_shape(local.boundary, jnp.zeros(local.boundary_columns.shape[0], x.dtype),
                                  jax.ShapeDtypeStruct(rows[3].shape[1:], x.dtype), model)
            y_k, z_k = (local_derivatives._lifted(order, values, segments * part.shape[1] + end.shape[0])
                        [:segments * part.shape[1]]
                        for order, values, part, end in ((local.order_h, y, rows[1], ends[1]),
                                                         (local.order_g, z, rows[2], ends[2])))
            padded = jnp.concatenate([x, jnp.zeros(1, x.dtype)])
            unit = jnp.eye(width, dtype=x.dtype)[local.curved_segment_columns]

            def one(c, d, y_s, z_s):
                def lagrangian(point):
                    r, h, g, _ = local.segment(point, d, model)
                    return r @ r + y_s @ h + z_s @ g, (r, h, g)
                return local_derivatives._second_order(lagrangian, padded[c], unit)
            return jax.vmap(one)(columns, local.segment_data, y_k.reshape(segments, -1), z_k.reshape(segments, -1))
        primal_rows = jax.jit(jax.vmap(segment_rows))
        second_order = jax.jit(jax.vmap(segment_pass))
        one_iteration = jax.jit(jax.vmap(functools.partial(interior_point._iterate, problem, options),
                                         in_axes=(None, 0, 0)))
        f, h, g, grad, jac_h, jac_g, hessian = derivatives(state.x, params, weight, y, z, structure)
        newton_args = (hessian, state.scale_h[:, :, None] * jac_h,
                       jax.vmap(jacobian.row_scaled)(jac_g, state.scale_g), grad,
                       state.scale_h * h, state.scale_g * g, state.s, state.z, state.mu)
        phases = {}
        inside = ((("  segments' rows", primal_rows, (state.x, params)),
                   ("  segments' pass", second_order, (state.x, params, y, z))) if args.segment_pass else ())
        for label, function, call in (
                ("derivatives", derivatives, (state.x, params, weight, y, z, structure)), *inside,
                ("newton system", newton, newton_args),
                ("one trial point", evaluate, (state.x, params)),
                ("whole iteration", one_iteration, (structure, params, state))):
            started = time.perf_counter()
            jax.block_until_ready(function(*call))
            compile_seconds = time.perf_counter() - started
            seconds = median_seconds(function, call, args.repeats)
            phases[label] = seconds
            rows.append({"batch": batch_size, "phase": label, "seconds": seconds,
                         "per_problem_ms": 1e3 * seconds / batch_size, "first_call_s": compile_seconds})
        after = one_iteration(structure, params, state)
        trials = float(np.mean(np.asarray(after.evaluations - state.evaluations)
                               - exact_derivatives.directions(problem, structure) - 2))
        # XLA's own figure for the iteration program (arguments, outputs, temporaries), per problem
        memory = (interior_point.program_memory(compiled, structure, x0, params, zeros)
                  / interior_point.padded_batch(batch_size))
        rows.append({"batch": batch_size, "phase": "trial points per iteration (mean)", "count": trials,
                     "warm_iterations_s": warm_seconds, "program_memory_per_problem_MiB": memory / 2**20})
        print(f"B = {batch_size}: n = {x0.shape[1]}, m_h = {h.shape[1]}, m_g = {g.shape[1]}, "
              f"{args.warm_iterations} iterations to the timed iterate in {warm_seconds:.2f} s; "
              f"{trials:.1f} trial points per iteration; the iteration program needs "
              f"{memory / 2**20:.1f} MiB a problem")
        for label, seconds in phases.items():
            share = seconds / phases["whole iteration"]
            print(f"  {label:18s} {1e3 * seconds:10.2f} ms  ({1e3 * seconds / batch_size:8.3f} ms a problem, "
                  f"{100 * share:5.1f} % of the iteration)")
    save_results(args.name, {"spans": args.spans, "substeps": args.substeps,
                             "warm_iterations": args.warm_iterations,
                             "dtype": "float32" if args.float32 else "float64"}, rows, args.out)


if __name__ == "__main__":
    main()
