"""Where the time of a 200-step rollout gradient goes, and whether rematerialisation or scan
unrolling changes it: forward and gradient timed separately per variant, compile time apart, the
variants interleaved over three rounds (this machine's speed drifts by up to 2x between minutes).

    python benchmarks/profile_rollout.py [--float32]
"""

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp
from _results import median_seconds, save_results

HORIZON, TIMESTEP = 200, 1.8e-3
VARIANTS = ((True, 1), (False, 1), (True, 2))  # (checkpoint each step, scan unroll)


def make_rollout_cost(biped, remat: bool, unroll: int):
    """A scalar cost of a 200-step single-support rollout (stance force included), for timing."""
    from biped_jax.dynamics import mjx_biped
    mjx = mjx_biped.mjx
    pinned = mjx_biped.with_timestep(biped.pinned, TIMESTEP)

    def rollout_cost(design, q0, qd0, controls):
        model = mjx_biped.with_design(mjx_biped.PlanarBiped(pinned, biped.floating), design).pinned
        template = mjx.make_data(model)

        def step(state, u):
            q, qd = state
            data = mjx.forward(model, template.replace(qpos=q, qvel=qd, ctrl=u))
            force = mjx_biped.stance_force(model, data)
            data = mjx.euler(model, data)
            return (data.qpos, data.qvel), (data.qpos, force)
        if remat:
            step = jax.checkpoint(step)
        (q, qd), (qs, force) = jax.lax.scan(step, (q0, qd0), controls, unroll=unroll)
        return (jnp.sum(q**2) + 0.1 * jnp.sum(qd**2) + 1e-3 * jnp.sum(controls**2)
                + 1e-6 * jnp.sum(force[:, 1] ** 2) + 1e-3 * jnp.sum(qs**2))
    return rollout_cost


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--float32", action="store_true", help="float32 instead of float64")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    options = parser.parse_args()
    jax.config.update("jax_enable_x64", not options.float32)
    from biped_jax.dynamics import mjx_biped
    biped = mjx_biped.load_planar_biped("12kg")
    args = (mjx_biped.planar_design("12kg"), jnp.array([-0.35, 0.0, -0.35, 0.35, 0.0]),
            jnp.array([2.5, 0.0, 2.5, -4.0, 0.0]), jnp.full((HORIZON, 4), 0.5))
    if options.float32:
        args = jax.tree.map(lambda a: a.astype(jnp.float32), args)
    compiled = {}
    for remat, unroll in VARIANTS:
        cost = make_rollout_cost(biped, remat, unroll)
        forward = jax.jit(cost).lower(*args).compile()
        started = time.perf_counter()
        gradient = jax.jit(jax.grad(cost, argnums=(1, 2, 3))).lower(*args).compile()
        compiled[(remat, unroll)] = (time.perf_counter() - started, forward, gradient)
    rows = []
    for round_ in range(3):
        for (remat, unroll), (compile_s, forward, gradient) in compiled.items():
            row = dict(round=round_, remat=remat, unroll=unroll, float32=options.float32, compile_grad_s=compile_s,
                       forward_ms=1e3 * median_seconds(forward, args, 25),
                       grad_ms=1e3 * median_seconds(gradient, args, 25))
            rows.append(row)
            print(row, flush=True)
    save_results("profile_rollout", {"horizon": HORIZON, "dtype": "float32" if options.float32 else "float64"},
                 rows, options.out)


if __name__ == "__main__":
    main()
