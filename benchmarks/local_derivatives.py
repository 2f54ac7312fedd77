"""The interior point's exact derivatives of the gait problem: split by shooting segment
(``biped_jax.optim.local_derivatives``, a segment's columns per pass) against the column colouring of the
whole problem (``biped_jax.optim.exact_derivatives``, a direction per colour), in the same run. Checks
that both give the same values (the dense derivatives as the reference in a small space, the two against
each other in the benchmark's), then times a batch of each.

    python benchmarks/local_derivatives.py --spans 16 --substeps 8 --batch 16
    python benchmarks/local_derivatives.py --spans 48 --substeps 4 --batch 9
"""

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _results import median_seconds, save_results

PARTS = ("f", "h", "g", "grad", "jac_h", "jac_g", "hessian")


def largest_difference(a_parts, b_parts) -> dict:
    """Per part, max |a - b| over max |b|."""
    return {name: float(jnp.max(jnp.abs(a - b)) / max(float(jnp.max(jnp.abs(b))), 1e-300))
            for name, a, b in zip(PARTS, a_parts, b_parts)}


def space_problem(settings, kind: str):
    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait import segmented
    from biped_jax.gait.solver import GaitSolver
    solver = GaitSolver(settings, check_refinement=False)
    model = gait_problem.gait_model("12kg", 0.555, 20.0)
    x = np.asarray(solver._initial_guess(jax.tree.map(lambda a: a[None], model))[0])
    x = x + 0.01 * np.random.default_rng(0).normal(size=x.shape)
    problem = solver.problem if kind == "energy" else solver.limit_problem
    point = x if kind == "energy" else np.concatenate([x, [0.9]])
    params = model if kind == "energy" else gait_problem.LimitParams(model, np.asarray(0.01))
    return solver, params, point, problem, segmented.local_problem(solver.biped, settings, kind)


def exactness(settings) -> list[dict]:
    """The split's derivatives against the dense ones (every column its own direction), both problems."""
    from biped_jax.optim import exact_derivatives as ed
    from biped_jax.optim import local_derivatives as ld
    rows = []
    for kind in ("energy", "limit"):
        _, model, point, problem, local = space_problem(settings, kind)
        f, h, g = problem.evaluate(point, model)
        rng = np.random.default_rng(1)
        y, z = rng.normal(size=h.shape), rng.uniform(size=g.shape)
        dense = ed.dense_structure(point.shape[0], h.shape[0] + g.shape[0])
        reference = jax.jit(ed.derivatives, static_argnums=0)(problem, point, model, 0.7, y, z, dense)
        split = jax.jit(ld.derivatives, static_argnums=0)(local, point, model, 0.7, y, z)
        rows.append({"check": "split against dense", "problem": kind, "spans": settings.spans,
                     "segments": settings.segments,
                     "largest_relative_difference": largest_difference(split, reference)})
        print(rows[-1], flush=True)
    return rows


def timing(settings, batch: int, repeats: int) -> dict:
    from biped_jax.gait.solver import stack_tree
    from biped_jax.optim import exact_derivatives as ed
    from biped_jax.optim import local_derivatives as ld
    solver, model, point, problem, local = space_problem(settings, "energy")
    structure = ed.probe_structure(problem, point, model)
    models = stack_tree([model] * batch)
    xs = jnp.asarray(np.tile(point, (batch, 1)) + 1e-3 * np.random.default_rng(2).normal(size=(batch, point.size)))
    f, h, g = problem.evaluate(point, model)
    y, z = jnp.zeros((batch,) + h.shape), jnp.full((batch,) + g.shape, 0.1)
    w = jnp.ones(batch)
    coloured = jax.jit(jax.vmap(lambda x, p, w, y, z: ed.derivatives(problem, x, p, w, y, z, structure)))
    split = jax.jit(jax.vmap(lambda x, p, w, y, z: ld.derivatives(local, x, p, w, y, z)))
    row = {"spans": settings.spans, "segments": settings.segments, "substeps": settings.substeps, "batch": batch,
           "columns": int(point.size), "colours": structure.colours, "split_directions": local.directions}
    for name, function in (("coloured", coloured), ("split", split)):
        started = time.perf_counter()
        parts = jax.block_until_ready(function(xs, models, w, y, z))
        row[f"{name}_compile_and_first_s"] = time.perf_counter() - started
        row[f"{name}_s"] = median_seconds(function, (xs, models, w, y, z), repeats)
        row[f"{name}_parts"] = parts
    row["largest_relative_difference"] = largest_difference(row.pop("split_parts"), row.pop("coloured_parts"))
    row["speedup_split_over_coloured"] = row["coloured_s"] / row["split_s"]
    print({k: v for k, v in row.items()}, flush=True)
    return row


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spans", type=int, default=16)
    parser.add_argument("--substeps", type=int, default=8)
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    from biped_jax.gait import problem as gait_problem
    rows = exactness(gait_problem.GaitSettings(spans=4, segments=4, substeps=2))
    rows += exactness(gait_problem.GaitSettings(spans=8, segments=4, substeps=2))
    rows.append(timing(gait_problem.GaitSettings(spans=args.spans, segments=args.spans, substeps=args.substeps),
                       args.batch, args.repeats))
    save_results(f"local_derivatives_{args.spans}spans", {"float": "float64"}, rows, args.out)


if __name__ == "__main__":
    main()
