"""The 3D walk that tracks the optimal step (:mod:`biped_jax.humanoid.tracker`, the law of
``biped-jax humanoid``): tune its gains by CMA-ES over batched MJX walks, then walk and push it as the
command does.

``--tune G`` runs G generations of CMA-ES over the law's eleven gains (``--population`` walks of
``--tune-seconds`` s per start in one vmapped program per generation; ``--tune-starts K``: the nominal start
and K - 1 disturbed ones, the score their mean; ``--tune-push I``: those pushed I N s), from ``--gains
FILE`` (a result of this script) or the model's tuned gains (:data:`biped_jax.humanoid.tracker.TUNED`);
``--tune-lateral G`` first runs G generations over the lateral law's numbers (:func:`tune_lateral`, from the model's
:data:`biped_jax.humanoid.tracker.LATERAL`). Then the walk of ``--steps`` steps after the start's
transient and, with ``--push-batch B``, the command's two push trials
(:func:`biped_jax.studies.humanoid.walk_3d`). ``--one-hip-roll-drive`` puts one drive on each hip roll
instead of the tracker's two, ``--two-drives JOINT ...`` two on each of those leg joints; ``--clearance`` sets
the swing foot's lift over the optimal step's path; ``--gait-clearance`` walks the step solved again with
that clearance (``--touchdown-speed``: and landing's bound; ``--drive-limits``: and within the walk's drives).
``--carry-command TAU`` walks (after any tuning) with each leg's sagittal commands (``--carry-all``: every
actuator's) carried across a touchdown over TAU s (:func:`carried_across_touchdown`).

    python benchmarks/humanoid_feedforward.py --gaits OUT [--model M2] [--tune 0] [--steps 56]
        [--tune-lateral 0] [--push-batch 0] [--gains FILE.json] [--name humanoid_feedforward_M2]
"""

import argparse
import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _results import save_results

from biped_jax.commands import configure_jax

configure_jax()

from biped_jax.gait import problem as gait_problem  # noqa: E402
from biped_jax.humanoid import free_base, reference, tracker, walk3d, walker  # noqa: E402
from biped_jax.studies import humanoid as study  # noqa: E402


def optimal_step(name: str, gaits: Path):
    """(decision vector, settings, trajectory) of the study's model ``name`` from ``gaits``."""
    x, settings, status = study.solved_gait(name, gait_problem.GaitSettings(), gaits, print)
    if status != "converged":
        print(f"warning: the {name} gait did not converge ({status})")
    return x, settings, study.simulated_step(name, x, settings)


#: CMA-ES: each gain's unit step.
TUNE_SCALE = {"kp": 60.0, "kd": 1.5, "kp_sw": 60.0, "kd_sw": 1.5, "kp_t": 60.0, "kd_t": 3.0, "kp_a": 10.0,
              "kd_a": 0.3, "ankle_w": 5.0, "place": 0.3, "fade": 0.1}
#: CMA-ES over the lateral law: each number's unit step (the fields of WalkerParams it varies; not the
#: start's sideways speed, which the tuner's fixed starts would not see).
LATERAL_SCALE = {"lateral_gain": 0.03, "width": 0.015, "kp_torso": 30.0, "kd_torso": 3.0, "roll_push": 0.4,
                 "kp_swing": 15.0, "kd_swing": 0.4, "roll_lean": 0.03}
#: Numbers that may take either sign (the others are kept positive).
SIGNED = ("ankle_w", "place", "roll_lean")


def evolve(base: dict, scale: dict, scores, carries: list, generations: int, population: int, sigma: float,
           seed: int = 1, clip=lambda values: values) -> dict:
    """CMA-ES from the numbers ``base`` (steps of ``scale``), maximising the mean over ``carries`` (the
    starts) of ``scores(batch, carry)`` -> (population,), where batch maps each name to a (population,)
    array; ``clip`` bounds a candidate's numbers (a dict). Returns the best numbers seen."""
    import cma
    names = list(scale)
    es = cma.CMAEvolutionStrategy(np.zeros(len(names)), sigma, {"popsize": population, "seed": seed, "verbose": -9})
    best = (-np.inf, dict(base))
    for generation in range(generations):
        started = time.perf_counter()
        candidates = es.ask()
        chosen = [clip({k: base[k] + scale[k] * z[i] if k in SIGNED else abs(base[k] + scale[k] * z[i])
                        for i, k in enumerate(names)}) for z in candidates]
        batch = {k: jnp.asarray([c[k] for c in chosen]) for k in names}
        values = np.mean([np.asarray(scores(batch, carry)) for carry in carries], axis=0)
        es.tell(candidates, list(-values))
        if values.max() > best[0]:
            best = (float(values.max()), {**base, **chosen[int(values.argmax())]})
        print(f"generation {generation}: best {values.max():.2f}, overall {best[0]:.2f} "
              f"({time.perf_counter() - started:.0f} s)", flush=True)
    return best[1]


def walk_score(walking: study.Walking, seconds: float, step_length: float, lift_weight: float = 0.0,
               drift_weight: float = 0.0, excess_weight: float = 0.5, speed_weight: float = 0.0,
               lift_height: float = 0.002):
    """score(args, start): a walk of ``seconds`` s with the law's ``args`` from ``start`` = (carry, push:
    :class:`biped_jax.humanoid.walk3d.Push` on the torso during it): its steps within
    5 % of the gait's length and 10 % of its time, + 3 if up at the end, + its seconds up, + half its distance,
    - ``excess_weight`` times its mean |command - applied| (N m, summed over the joints), - ``lift_weight``
    times its share of samples with the stance sole above ``lift_height`` m after the stance's first 30 ms (a
    rebound or a rocking foot; 0: any loss of contact), - ``drift_weight`` times the pelvis's final distance
    from the centre line (m), - ``speed_weight`` times |its distance over its time up, over the gait's speed,
    - 1|."""
    prog = walk3d.program(walking.mass_class, walking.parallel)
    step, n = walk3d.stepper(prog, tracker.LAW), int(round(seconds / float(prog.mj_model.opt.timestep)))
    step_time = walking.step_time

    def score(args, start):
        carry, push = start

        def body(state, _):
            carry, up, good, distance, last, upright_steps, excess, lifted = state
            before = carry[1].memory
            carry, (command, applied) = step(args, push, carry)
            data, memory = carry[0], carry[1].memory
            landed = memory.steps != before.steps
            length = memory.foot[0] - before.foot[0]
            good += landed & up & (jnp.abs(length / step_length - 1) < 0.05) \
                & (jnp.abs((data.time - last) / step_time - 1) < 0.1)
            distance += jnp.where(landed & up, length, 0.0)
            up = up & walk3d.upright(data.qpos)
            sole = walker.sole_heights(prog.legs, data)[memory.stance]
            return (carry, up, good, distance, jnp.where(landed, data.time, last), upright_steps + up,
                    excess + jnp.where(up, jnp.sum(jnp.abs(command - applied)), 0.0),
                    lifted + (up & (memory.time > 0.03) & (sole > lift_height))), None

        zero = jnp.asarray(0.0)
        (carry, up, good, distance, _, upright_steps, excess, lifted), _ = jax.lax.scan(
            body, (carry, jnp.asarray(True), zero, zero, zero, zero, zero, zero), None, length=n)
        speed = distance / jnp.maximum(upright_steps / n * seconds, 1e-3) * step_time / step_length
        return (good + 3 * up + upright_steps / n * seconds + 0.5 * distance - excess_weight * excess / n
                - lift_weight * lifted / n - drift_weight * jnp.abs(carry[0].qpos[1])
                - speed_weight * jnp.abs(speed - 1))

    return score


def tune(walking: study.Walking, carries: list, generations: int, population: int, seconds: float,
         step_length: float, lift_weight: float = 0.0, sigma: float = 0.3, excess_weight: float = 0.5,
         speed_weight: float = 0.0, lift_height: float = 0.002) -> tracker.Gains:
    """CMA-ES over :class:`biped_jax.humanoid.tracker.Gains` from ``walking``'s, a candidate's score its
    :func:`walk_score` (``lift_weight``, ``excess_weight``, ``speed_weight``, ``lift_height``) averaged over
    ``carries`` (the starts, each (carry, push): :func:`starts`); one vmapped program of ``population`` walks
    per generation and start."""
    score = walk_score(walking, seconds, step_length, lift_weight, excess_weight=excess_weight,
                       speed_weight=speed_weight, lift_height=lift_height)
    scores = jax.jit(jax.vmap(lambda gains, carry: score(
        dataclasses.replace(walking.args, gains=dataclasses.replace(walking.args.gains, **gains)), carry),
        in_axes=(0, None)))
    base = {k: float(v) for k, v in dataclasses.asdict(walking.args.gains).items()}
    best = evolve(base, TUNE_SCALE, scores, carries, generations, population, sigma,
                  clip=lambda g: {**g, "fade": min(max(g["fade"], 0.05), 0.5)})
    return tracker.Gains(**best)  # yaw_ff and impact (not tuned) kept from walking's


def tune_lateral(walking: study.Walking, carries: list, generations: int, population: int, seconds: float,
                 step_length: float, lift_weight: float = 0.0, sigma: float = 0.5) -> dict:
    """CMA-ES over the lateral law's numbers (:data:`LATERAL_SCALE`) from ``walking``'s, a candidate's score
    its :func:`walk_score` (``lift_weight``, sideways drift weighed 2 per m) averaged over ``carries`` (the
    starts); one vmapped program of ``population`` walks per generation and start. Returns the numbers (a
    dict for :func:`biped_jax.studies.humanoid.tracker_walking`'s ``lateral``)."""
    score = walk_score(walking, seconds, step_length, lift_weight, drift_weight=2.0)
    scores = jax.jit(jax.vmap(lambda numbers, carry: score(dataclasses.replace(
        walking.args, params=dataclasses.replace(walking.args.params, **numbers)), carry), in_axes=(0, None)))
    base = {k: float(getattr(walking.args.params, k)) for k in LATERAL_SCALE}
    return evolve(base, LATERAL_SCALE, scores, carries, generations, population, sigma, seed=3)


def starts(walking: study.Walking, count: int, push: float = 0.0, seconds: float = 9.0) -> list:
    """The tuners' starts: the nominal one and ``count`` - 1 disturbed ones, as ((MJX data, law state), push);
    ``push`` > 0 (N s): each disturbed walk pushed that much sagittally at a third of its ``seconds`` and
    sideways at half, for 0.1 s, the signs alternating over the starts (the nominal walk unpushed)."""
    prog = walk3d.program(walking.mass_class, walking.parallel)
    qpos, qvel = walk3d.disturbed_starts(prog, walking.args.params, count - 1, seed=2, around=walking.start_state)
    signs = [(1.0, 1.0), (-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0)]
    pushed = [walk3d.pushes(push * signs[k % 4][0], push * signs[k % 4][1], seconds / 3, seconds / 2) if push
              else walk3d.NO_PUSH for k in range(count - 1)]
    return [(walking.start(*walking.start_state), walk3d.NO_PUSH)] + [
        (walking.start(q, v), p) for q, v, p in zip(qpos, qvel, pushed)]


def carried_across_touchdown(walking: study.Walking, tau: float, joints: list[int]) -> study.Walking:
    """``walking`` with the commands of the actuators ``joints`` carried across each touchdown: w new + (1 - w)
    the joint's command in the step before the touchdown, w = (time since the touchdown) / ``tau`` (s) clipped
    to [0, 1]. ``walking`` must be the tracker's (its state's ``memory.time``); the law's state becomes (the
    tracker's, the held commands (actuators,))."""
    inner = walking.law
    actuators = walk3d.program(walking.mass_class, walking.parallel).mj_model.nu
    mask = jnp.zeros(actuators).at[jnp.asarray(joints)].set(1.0)

    def control(args, prog, data, state):
        tracked, held = state
        command, s = inner.control(args, prog, data, tracked)
        w = jnp.clip(tracked.memory.time / tau, 0.0, 1.0)
        command = command + mask * (1.0 - w) * (held - command)
        return command, (s, command)

    def remember(args, prog, data, state, note, timestep):
        tracked, held = state
        s, command = note
        after = inner.remember(args, prog, data, tracked, s, timestep)
        return after, jnp.where(after.memory.steps != tracked.memory.steps, command, held)

    def start(qpos, qvel):
        data, tracked = walking.start(qpos, qvel)
        return data, (tracked, jax.device_put(jnp.zeros(actuators), jax.devices()[0]))

    law = walk3d.Law(f"{inner.name}_carried_{tau}_{'_'.join(map(str, joints))}", control, remember)
    return dataclasses.replace(walking, law=law, start=start)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gaits", type=Path, required=True, help="the output folder of `biped-jax reproduce`")
    parser.add_argument("--model", default="M2", choices=("M1", "M2", "M3", "M4"))
    parser.add_argument("--one-hip-roll-drive", action="store_true",
                        help="one drive on each hip roll instead of the tracker's two")
    parser.add_argument("--two-drives", nargs="+", default=None, choices=free_base.LEG_JOINTS,
                        help="the leg joints on two drives (default: the tracker's, each hip roll)")
    parser.add_argument("--gains", type=Path, default=None,
                        help="a result of this script to take the gains and lateral numbers from "
                             "(default: the model's tuned)")
    parser.add_argument("--clearance", type=float, default=None,
                        help="the swing foot's lift over the step's path mid-step, m (default: 0 on a step solved "
                             f"with a clearance, else {reference.SWING_CLEARANCE})")
    parser.add_argument("--gait-clearance", type=float, default=None,
                        help="solve the step again with the swing foot this high mid-step, m (the gait problem's "
                             "swing_clearance; 0: the study's optimum; default: the command's, "
                             "studies.humanoid.WALK_GAITS)")
    parser.add_argument("--clearance-ramp", type=float, default=0.1,
                        help="with --gait-clearance: the share of the step over which it rises and falls")
    parser.add_argument("--touchdown-speed", type=float, default=None,
                        help="with --gait-clearance: the swing foot's largest forward speed at touchdown, m/s")
    parser.add_argument("--drive-limits", action="store_true",
                        help="with --gait-clearance: the step within the walk's drives' lines and gear limits "
                             "(GaitSettings.drive_limits; it then minimises their Joule heat)")
    parser.add_argument("--carry-command", type=float, default=0.0, metavar="TAU",
                        help="carry every leg's sagittal command across a touchdown over TAU s (0: no)")
    parser.add_argument("--carry-all", action="store_true",
                        help="with --carry-command: carry all sixteen actuators' commands")
    parser.add_argument("--tune", type=int, default=0, help="CMA-ES generations before the walk")
    parser.add_argument("--population", type=int, default=24)
    parser.add_argument("--tune-seconds", type=float, default=9.0)
    parser.add_argument("--tune-starts", type=int, default=1,
                        help="the tuner's starts: the nominal one and this many minus one disturbed ones")
    parser.add_argument("--tune-push", type=float, default=0.0,
                        help="N s: the tuners' disturbed starts also pushed that much sagittally and sideways "
                             "(signs alternating; the nominal start unpushed)")
    parser.add_argument("--tune-lateral", type=int, default=0,
                        help="CMA-ES generations over the lateral law's numbers, before the gains' (16 walks of "
                             "6 s from --tune-starts starts each)")
    parser.add_argument("--tune-sigma", type=float, default=0.3, help="CMA-ES's first step, in TUNE_SCALE units")
    parser.add_argument("--lift-weight", type=float, default=0.0,
                        help="the tuner's penalty on the share of samples with the stance sole lifted")
    parser.add_argument("--lift-height", type=float, default=0.002,
                        help="the stance sole's height above which the tuner counts it lifted, m (0: any gap)")
    parser.add_argument("--excess-weight", type=float, default=0.5,
                        help="the gains tuner's penalty on the mean |command - applied| (N m)")
    parser.add_argument("--speed-weight", type=float, default=0.0,
                        help="the gains tuner's penalty on the walk's relative speed error")
    parser.add_argument("--steps", type=int, default=56, help="the measured walk's steps after the transient")
    parser.add_argument("--push-batch", type=int, default=0,
                        help="walks in each of the command's two push trials (0: none)")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    parser.add_argument("--name", default=None)
    args = parser.parse_args()
    if args.carry_command < 0:
        parser.error(f"--carry-command must be 0 s or more, got {args.carry_command}")
    if args.one_hip_roll_drive and args.two_drives:
        parser.error("--one-hip-roll-drive and --two-drives name the drives twice: give one")

    x, settings, trajectory = optimal_step(args.model, args.gaits)
    # the command's step (studies.humanoid.WALK_GAITS) unless --gait-clearance names another
    parallel = () if args.one_hip_roll_drive else None if args.two_drives is None else tuple(args.two_drives)
    step = study.walked_step(args.model, x, settings, trajectory, args.gait_clearance, args.touchdown_speed,
                             args.clearance_ramp, print, args.drive_limits or None, parallel)
    x, settings, trajectory = step.x, step.settings, step.trajectory
    if step.gait is not None:
        print(f"the step with {step.gait['swing_clearance_m']} m of swing clearance, landing at most "
              f"{step.gait['touchdown_forward_speed_mps']} m/s forward: {step.gait['status']}", flush=True)
    if args.clearance is None:
        args.clearance = reference.SWING_CLEARANCE if step.lift is None else step.lift
    gains = lateral = None
    if args.gains:
        controller = json.loads(args.gains.read_text())["rows"][0]["controller"]
        gains = tracker.Gains(**controller["gains"])
        lateral = {k: controller["lateral"][k] for k in LATERAL_SCALE}
    started = time.perf_counter()
    walk = lambda gains, lateral, earlier=None: study.tracker_walking(  # noqa: E731
        args.model, x, settings, trajectory, gains, args.clearance, parallel, lateral, earlier)
    walking = walk(gains, lateral)
    prog = walk3d.program(walking.mass_class, walking.parallel)
    torque = np.abs(np.asarray(walking.args.path.torque)).max(axis=0)
    print(f"inverse dynamics along the path ({time.perf_counter() - started:.1f} s): largest |torque| "
          + ", ".join(f"{prog.mj_model.actuator(j).name} {torque[j]:.2f}" for j in prog.layout.legs[0][1:5])
          + " N m (leg l standing)", flush=True)
    _, model = study.paper_model(args.model)
    if args.tune_lateral:
        lateral = tune_lateral(walking, starts(walking, args.tune_starts, args.tune_push, 6.0), args.tune_lateral, 16,
                               6.0, float(model.step_length), args.lift_weight)
        print("lateral numbers:", json.dumps(lateral), flush=True)
        walking = walk(walking.args.gains, lateral, walking)
    if args.tune:
        gains = tune(walking, starts(walking, args.tune_starts, args.tune_push, args.tune_seconds), args.tune,
                     args.population, args.tune_seconds,
                     float(model.step_length), args.lift_weight, args.tune_sigma, args.excess_weight,
                     args.speed_weight, args.lift_height)
        walking = walk(gains, {k: float(getattr(walking.args.params, k)) for k in LATERAL_SCALE}, walking)
    if args.carry_command:
        legs = prog.layout.legs
        joints = list(range(prog.mj_model.nu)) if args.carry_all else [leg[k] for leg in legs for k in tracker.SAGITTAL]
        walking = carried_across_touchdown(walking, args.carry_command, joints)
    started = time.perf_counter()
    entry, _ = study.walk_3d(walking, trajectory, args.steps, args.push_batch, print)
    row = {"model": args.model, "clearance_m": args.clearance,
           "gait_clearance_m": step.gait["swing_clearance_m"] if step.gait else 0.0,
           "clearance_ramp": step.settings.clearance_ramp,
           "touchdown_speed_mps": step.gait["touchdown_forward_speed_mps"] if step.gait else None,
           "gait_drive_limits": bool(step.gait and step.gait["drive_limits"]),
           "carry_command_s": args.carry_command, "carry_all": args.carry_all,
           "wall_s": time.perf_counter() - started,
           "path_largest_torque_Nm": {prog.mj_model.actuator(j).name: float(torque[j])
                                      for j in range(len(prog.layout.qvel))}, **entry}
    print(json.dumps({k: v for k, v in row.items() if not isinstance(v, (dict, list))}, indent=1), flush=True)
    save_results(args.name or f"humanoid_feedforward_{args.model}",
                 {"model": args.model, "tune": args.tune, "tune_lateral": args.tune_lateral,
                  "lift_weight": args.lift_weight, "lift_height": args.lift_height,
                  "excess_weight": args.excess_weight,
                  "speed_weight": args.speed_weight},
                 [row], args.out)


if __name__ == "__main__":
    main()
