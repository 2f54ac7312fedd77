"""Compile time and run time of the gradient of a single-support rollout cost (forward + backward).

Five-link biped, pinned stance, 200 steps of 1.8 ms by default; gradient with respect to the initial
state and every torque. Reports a single gradient and a vmapped batch of designs (one compiled
program per batch size), prints a table and saves JSON.

    python benchmarks/rollout_gradient.py --horizon 200 --batch 1 16 64
"""

import argparse
import dataclasses
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _results import save_results


def rollout_cost(biped, design, q0, qd0, controls, dynamics="mjx"):
    from biped_jax.dynamics import interface, mjx_biped, planar_chain
    designed = mjx_biped.with_design(biped, design)
    if dynamics == "chain":  # the structure read from the concrete model: the designed one is traced
        backend = planar_chain.ChainDynamics.of(designed.pinned, planar_chain.PlanarChain.from_model(biped.pinned))
    else:
        backend = interface.stance_dynamics(designed, "mjx")
    trajectory = interface.stance_rollout(backend, q0, qd0, controls)
    q, qd, force = trajectory.q, trajectory.qd, trajectory.ground_force
    foot, _ = backend.swing_foot(q[-1], qd[-1])
    return (jnp.sum(q[-1] ** 2) + 0.1 * jnp.sum(qd[-1] ** 2) + foot[1] ** 2
            + 1e-3 * jnp.sum(controls ** 2) + 1e-6 * jnp.sum(force[:, 1] ** 2))


def measure(function, args, repeats):
    started = time.perf_counter()
    compiled = jax.jit(function).lower(*args).compile()
    compile_s = time.perf_counter() - started
    jax.block_until_ready(compiled(*args))  # warm-up
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - started)
    return compile_s, float(np.median(times))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--horizon", type=int, default=200)
    parser.add_argument("--batch", type=int, nargs="+", default=[1, 16, 64])
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--float32", action="store_true", help="float32 instead of float64")
    parser.add_argument("--dynamics", choices=("mjx", "chain"), default="mjx",
                        help="the backend of biped_jax.dynamics.interface: MJX's pipeline or the closed-form chain")
    parser.add_argument("--name", default="rollout_gradient", help="results file stem")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", not args.float32)

    from biped_jax.dynamics import mjx_biped
    biped = mjx_biped.load_planar_biped("12kg")
    biped = mjx_biped.PlanarBiped(pinned=mjx_biped.with_timestep(biped.pinned, 1.8e-3), floating=biped.floating)
    design = mjx_biped.planar_design("12kg")
    q0 = jnp.array([-0.35, 0.0, -0.35, 0.35, 0.0])
    qd0 = jnp.array([2.5, 0.0, 2.5, -4.0, 0.0])
    controls = jnp.full((args.horizon, 4), 0.5)
    gradient = jax.grad(lambda d, q, qd, u: rollout_cost(biped, d, q, qd, u, args.dynamics), argnums=(1, 2, 3))

    rows = []
    for batch in args.batch:
        if batch == 1:
            function, call_args = gradient, (design, q0, qd0, controls)
        else:
            function = jax.vmap(gradient)
            scales = jnp.linspace(0.8, 1.2, batch)
            designs = jax.tree.map(lambda a: jnp.tile(a, (batch, 1)), design)
            designs = dataclasses.replace(designs, link_mass=scales[:, None] * design.link_mass)  # light to heavy
            call_args = (designs, jnp.tile(q0, (batch, 1)), jnp.tile(qd0, (batch, 1)),
                         jnp.tile(controls, (batch, 1, 1)))
        compile_s, run_s = measure(function, call_args, args.repeats)
        rows.append({"batch": batch, "compile_s": compile_s, "run_s": run_s,
                     "gradients_per_s": batch / run_s, "ms_per_gradient": 1e3 * run_s / batch})
        print(f"batch {batch:6d}: compile {compile_s:7.1f} s   run {1e3 * run_s:9.2f} ms   "
              f"{batch / run_s:10.1f} gradients/s   {1e3 * run_s / batch:8.2f} ms/gradient", flush=True)

    save_results(args.name, {"dtype": "float32" if args.float32 else "float64", "dynamics": args.dynamics,
                                      "horizon": args.horizon, "timestep_s": 1.8e-3}, rows, args.out)


if __name__ == "__main__":
    main()
