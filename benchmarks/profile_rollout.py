"""Where the time of a 200-step rollout gradient goes, and whether rematerialisation or scan
unrolling changes it: forward and gradient timed separately per variant, compile time apart, the
variants interleaved over three rounds (this machine's speed drifts by up to 2x between minutes).

    python benchmarks/profile_rollout.py [f32]
"""
import sys, time, json
import jax, jax.numpy as jnp, numpy as np
f32 = "f32" in sys.argv
jax.config.update("jax_enable_x64", not f32)
from biped_jax import hybrid_step as hs
mjx = hs.mjx
biped = hs.load_planar_biped("12kg")
pinned = hs.with_timestep(biped.pinned, 1.8e-3)
design = hs.planar_design("12kg")
q0 = jnp.array([-0.35, 0.0, -0.35, 0.35, 0.0]); qd0 = jnp.array([2.5, 0.0, 2.5, -4.0, 0.0])
controls = jnp.full((200, 4), 0.5)

def make(remat, unroll):
    def rollout_cost(design, q0, qd0, controls):
        model = hs.with_design(hs.PlanarBiped(pinned, biped.floating), design).pinned
        template = mjx.make_data(model)
        def step(state, u):
            q, qd = state
            data = mjx.forward(model, template.replace(qpos=q, qvel=qd, ctrl=u))
            force = hs._stance_force(model, data)
            data = mjx.euler(model, data)
            return (data.qpos, data.qvel), (data.qpos, data.qvel, force)
        if remat:
            step = jax.checkpoint(step)
        (q, qd), (qs, qds, f) = jax.lax.scan(step, (q0, qd0), controls, unroll=unroll)
        return jnp.sum(q**2) + 0.1*jnp.sum(qd**2) + 1e-3*jnp.sum(controls**2) + 1e-6*jnp.sum(f[:, 1]**2) + 1e-3*jnp.sum(qs**2)
    return rollout_cost

rows = []
compiled = {}
for remat, unroll in [(True, 1), (False, 1), (True, 2)]:
    fn = make(remat, unroll)
    args = (design, q0, qd0, controls)
    if f32:
        args = jax.tree.map(lambda a: a.astype(jnp.float32), args)
    t = time.perf_counter(); fwd = jax.jit(fn).lower(*args).compile(); cf = time.perf_counter() - t
    t = time.perf_counter(); grad = jax.jit(jax.grad(fn, argnums=(1, 2, 3))).lower(*args).compile(); cg = time.perf_counter() - t
    def timeit(f):
        jax.block_until_ready(f(*args)); ts = []
        for _ in range(25):
            t = time.perf_counter(); jax.block_until_ready(f(*args)); ts.append(time.perf_counter() - t)
        return 1e3 * float(np.median(ts))
    compiled[(remat, unroll)] = (cf, cg, fwd, grad)
for round_ in range(3):
    for (remat, unroll), (cf, cg, fwd, grad) in compiled.items():
        row = dict(round=round_, remat=remat, unroll=unroll, float32=f32, compile_grad_s=cg, forward_ms=timeit(fwd), grad_ms=timeit(grad))
        rows.append(row); print(row, flush=True)
from pathlib import Path
from _results import save_results
save_results("profile_rollout", {"horizon": 200, "dtype": "float32" if f32 else "float64"}, rows,
             Path(__file__).parent / "results")
