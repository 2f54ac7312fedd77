"""Tunes the 3D walking controller's parameters by CMA-ES over batched MJX walks.

Each generation is one vmapped program: ``--population`` walks of ``--seconds`` s on the free-base humanoid
with the drives in the loop (:mod:`biped_jax.humanoid.walk3d`), each with its own parameters. The cost of
a walk, measured inside the compiled loop:

    10 (seconds - time upright) + 4 [fell] + 10 |v / v_gait - 1| + 5 |n T / 2 s - 1|
    + 20 (share of stance samples with the stance foot's sole above 2 mm, after its first 30 ms)
    + w_sat (share of samples with a torque beyond the drive's line; --saturation-weight, default 2)
    + 100 (stance foot slip per step, m)
    + 0.5 |yaw at the end| + 0.5 |lateral drift|

with v the pelvis's speed and n the touchdowns over the last 2 s, T the gait's step time. With
``--disturbed K`` each candidate also walks from K disturbed starts (new errors each generation, the same
for every candidate; the walks run in calls of ``--population``) and its cost is the mean over its starts:
tuned on the nominal start alone, the best numbers can sit on a knife edge. The best
parameters and the figures of their walk are written to JSON; the controller's defaults
(:class:`biped_jax.humanoid.walker.WalkerParams`) are copied from such a run.

    python benchmarks/humanoid_tune.py [--model M2] [--generations 40] [--population 48]
        [--seconds 5] [--disturbed 0] [--start FILE.json] [--name humanoid_tune_12kg]
"""

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from _results import save_results

#: Tuned parameters: (scale of a CMA-ES unit step, lowest, highest); the start is the defaults or --start.
SPACE = {
    "clearance": (0.01, 0.01, 0.08), "forward_gain": (0.04, 0.0, 0.4), "speed_gain": (0.05, -0.1, 0.4),
    "forward_offset": (0.02, -0.08, 0.08), "lateral_gain": (0.05, 0.0, 0.5), "width": (0.01, 0.05, 0.14),
    "swing_end": (0.05, 0.5, 1.0), "stance_knee": (0.05, 0.05, 0.8), "lean": (0.03, -0.1, 0.3),
    "push": (0.5, -3.0, 3.0), "roll_lean": (0.03, -0.1, 0.2), "roll_push": (0.5, -3.0, 3.0),
    "kp_swing": (10.0, 10.0, 150.0), "kd_swing": (0.3, 0.3, 4.0), "kp_torso": (10.0, 10.0, 150.0),
    "kd_torso": (1.0, 0.5, 10.0), "kp_knee": (15.0, 20.0, 200.0), "kd_knee": (0.3, 0.3, 4.0),
    "kp_ankle": (4.0, 2.0, 60.0), "kd_ankle": (0.1, 0.05, 2.0), "kp_yaw": (4.0, 2.0, 60.0),
    "side_speed": (0.05, 0.0, 0.6), "settle": (0.03, 0.02, 0.3), "transfer": (0.02, 0.001, 0.12),
    "push_off": (1.0, -8.0, 8.0),
}
WINDOW = 2.0  # s: speed and cadence are measured over the walk's last WINDOW seconds


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="M2", choices=("M1", "M2", "M3", "M4"),
                        help="the paper's model whose gait speed and step time the walk is tuned for")
    parser.add_argument("--generations", type=int, default=40)
    parser.add_argument("--population", type=int, default=48)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--sigma", type=float, default=1.0, help="CMA-ES's initial step, in SPACE's units")
    parser.add_argument("--start", type=Path, default=None, help="JSON with 'params' to start from")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    parser.add_argument("--name", default=None)
    parser.add_argument("--disturbed", type=int, default=0,
                        help="disturbed starts per candidate beside the nominal one (walk3d.disturbed_starts; "
                             "new errors each generation); the cost is the mean over the starts")
    parser.add_argument("--saturation-weight", type=float, default=2.0,
                        help="cost per unit share of samples with a torque beyond the drive's line")
    args = parser.parse_args()
    from biped_jax.commands import configure_jax
    configure_jax()
    import cma
    import jax
    import jax.numpy as jnp
    from biped_jax.humanoid import walk3d, walker
    from biped_jax.studies.humanoid import paper_model, walk_params

    args.mass_class = paper_model(args.model)[0]
    base = walk_params(args.model)
    if args.start is not None:
        base = dataclasses.replace(base, **{k: v for k, v in json.loads(args.start.read_text())["params"].items()
                                            if k in SPACE})
    names = list(SPACE)
    prog = walk3d.program(args.mass_class)
    timestep = float(prog.mj_model.opt.timestep)
    physics_steps = int(round(args.seconds / timestep))
    legs, layout = prog.legs, prog.layout
    feet = jnp.asarray(layout.feet)
    step = walk3d.stepper(prog)

    def walk_cost_terms(params, data, memory):
        def body(carry, _):
            (data, memory), acc = carry
            stance, time_in_step = memory.stance, memory.time
            (data, memory), (command, applied) = step(params, walk3d.NO_PUSH, (data, memory))
            yaw = walk3d.attitude(data.qpos)[2]
            up = acc["up"] & walk3d.upright(data.qpos)
            soles = walker.sole_heights(legs, data)
            in_stance = time_in_step > 0.03
            late = data.time > args.seconds - WINDOW
            # the stance foot's velocity at its body origin (cvel is taken at the tree's centre of mass)
            spin, shift = data.cvel[feet[stance], :3], data.xpos[feet[stance]] - data.subtree_com[layout.torso]
            foot_speed = jnp.linalg.norm((data.cvel[feet[stance], 3:] + jnp.cross(spin, shift))[:2])
            acc = {"up": up, "upright": acc["upright"] + timestep * up,
                   "x_window": jnp.where(late & ~acc["started"], data.qpos[0], acc["x_window"]),
                   "started": acc["started"] | late,
                   "steps_window": acc["steps_window"] + (late & (memory.steps > acc["last_steps"])),
                   "last_steps": memory.steps,
                   "lifted": acc["lifted"] + up * in_stance * (soles[stance] > 0.002),
                   "stance_samples": acc["stance_samples"] + up * in_stance,
                   "saturated": acc["saturated"] + up * jnp.mean(jnp.abs(command - applied) > 1e-9),
                   "slip": acc["slip"] + up * in_stance * foot_speed * timestep,
                   "x": jnp.where(up, data.qpos[0], acc["x"]), "y": jnp.where(up, data.qpos[1], acc["y"]),
                   "yaw": jnp.where(up, yaw, acc["yaw"])}
            return ((data, memory), acc), None

        zero = jnp.asarray(0.0)
        acc = {"up": jnp.asarray(True), "upright": zero, "x_window": zero, "started": jnp.asarray(False),
               "steps_window": jnp.asarray(0), "last_steps": memory.steps, "lifted": zero, "stance_samples": zero,
               "saturated": zero, "slip": zero, "x": zero, "y": zero, "yaw": zero}
        ((data, memory), acc), _ = jax.lax.scan(body, ((data, memory), acc), None, length=physics_steps)
        acc["steps"] = memory.steps
        return acc

    batched = jax.jit(jax.vmap(walk_cost_terms))

    def run(params, starts):
        """The walks' accumulated terms, in calls of --population walks (one program for any number)."""
        parts = []
        for first in range(0, len(params), args.population):
            chunk = list(range(first, min(first + args.population, len(params))))
            chunk += [chunk[0]] * (args.population - len(chunk))  # padded: one program shape
            data, memory = jax.tree.map(lambda *a: jnp.stack(a), *[starts[i] for i in chunk])
            stacked = jax.tree.map(lambda *a: jnp.asarray(np.array(a, dtype=float)), *[params[i] for i in chunk])
            parts.append(jax.tree.map(np.asarray, batched(stacked, data, memory)))
        return jax.tree.map(lambda *a: np.concatenate(a)[:len(params)], *parts)

    def evaluate(candidates, seed):
        params = [dataclasses.replace(base, **dict(zip(names, map(float, c)))) for c in candidates]
        starts, rows = [], []
        for p in params:  # the nominal start, then --disturbed starts (the same errors for every candidate)
            qpos, qvel = walk3d.disturbed_starts(prog, p, args.disturbed, seed) if args.disturbed else ([], [])
            starts += [walk3d.initial(prog, p)] + [walk3d.initial(prog, p, q, v) for q, v in zip(qpos, qvel)]
            rows += [p] * (1 + args.disturbed)
        acc = run(rows, starts)
        speed = (acc["x"] - acc["x_window"]) / WINDOW
        cadence = acc["steps_window"] * float(base.step_time) / WINDOW
        terms = {"fall": 10.0 * (args.seconds - acc["upright"]) + 4.0 * ~acc["up"],
                 "speed": 10.0 * np.abs(speed / float(base.speed) - 1.0),
                 "cadence": 5.0 * np.abs(cadence - 1.0),
                 "lifted": 20.0 * acc["lifted"] / np.maximum(acc["stance_samples"], 1.0),
                 "saturated": args.saturation_weight * acc["saturated"] / physics_steps,
                 "slip": 100.0 * acc["slip"] / np.maximum(acc["steps"], 1),
                 "heading": 0.5 * np.abs(acc["yaw"]) + 0.5 * np.abs(acc["y"])}
        walking = {k: v * acc["up"] for k, v in terms.items() if k != "fall"}
        cost = terms["fall"] + sum(walking.values())
        figures = {"speed_mps": speed, "cadence": cadence, "upright_s": acc["upright"], **{
            f"cost_{k}": v for k, v in {**walking, "fall": terms["fall"]}.items()}}
        # a candidate's cost and figures: the mean over its starts
        per_candidate = lambda a: np.asarray(a, dtype=float).reshape(len(params), -1).mean(axis=1)  # noqa: E731
        return per_candidate(cost), {k: per_candidate(v) for k, v in figures.items()}

    scale = np.array([SPACE[n][0] for n in names])
    low, high = np.array([SPACE[n][1] for n in names]), np.array([SPACE[n][2] for n in names])
    origin = np.array([float(getattr(base, n)) for n in names])

    def candidate(z):
        return np.clip(origin + scale * np.asarray(z), low, high)

    es = cma.CMAEvolutionStrategy(np.zeros(len(names)), args.sigma,
                                  {"popsize": args.population, "seed": args.seed, "verbose": -9})
    best, history, started = None, [], time.perf_counter()
    for generation in range(args.generations):
        tick = time.perf_counter()
        zs = es.ask()
        cost, figures = evaluate([candidate(z) for z in zs], seed=args.seed * 1000 + generation)
        es.tell(zs, cost.tolist())
        i = int(np.argmin(cost))
        row = {"generation": generation, "best_cost": float(cost[i]), "median_cost": float(np.median(cost)),
               "upright_share": float(np.mean(figures["upright_s"] >= args.seconds - 1e-9)),
               "seconds": time.perf_counter() - tick, **{k: float(v[i]) for k, v in figures.items()}}
        history.append(row)
        if best is None or cost[i] < best["cost"]:
            best = {"cost": float(cost[i]), "generation": generation,
                    "params": dict(zip(names, map(float, candidate(zs[i])))), "figures": row}
        print(f"generation {generation}: best {cost[i]:.3f} (speed {row['speed_mps']:.3f} m/s, cadence "
              f"{row['cadence']:.2f}, upright {row['upright_s']:.2f} s), median {row['median_cost']:.2f}, "
              f"{row['upright_share']:.0%} upright, {row['seconds']:.0f} s; best so far {best['cost']:.3f}", flush=True)
        save_results(args.name or f"humanoid_tune_{args.mass_class}",
                     {"model": args.model, "mass_class": args.mass_class, "population": args.population,
                      "seconds": args.seconds, "sigma": args.sigma, "seed": args.seed,
                      "saturation_weight": args.saturation_weight, "disturbed": args.disturbed,
                      "space": SPACE,
                      "start": {n: float(v) for n, v in zip(names, origin)},
                      "fixed": {k: float(getattr(base, k)) for k in ("step_time", "speed", "ramp")},
                      "wall_s": time.perf_counter() - started},
                     [{"best": best, "history": history}], args.out)


if __name__ == "__main__":
    main()
