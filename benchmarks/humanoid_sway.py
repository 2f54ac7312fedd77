"""Probe: the tracker's path with a lateral sway of the linear inverted pendulum, its roll torques as
feed-forward, the lateral law's numbers tuned for it; measured with the command's walk and push trials.

The tracker's path (:func:`biped_jax.humanoid.tracker.path_3d`) keeps the pelvis on the centre line, so
its stance foot's centre of pressure lies beyond the foot's inner edge through the stance. Here the pelvis
sways toward the stance foot as a linear inverted pendulum over the foot's centre, periodic and symmetric:
y(t) = c (1 - cosh(w (t - T/2)) / cosh(w T/2)), c the hip's offset from the centre line, w = sqrt(g / z_c)
with z_c the centre of mass's height mid-step; the hip rolls tilt each leg so its foot stays in place
(roll = atan2(-y, hip-to-ankle height)), the ankle rolls keep the feet flat; the base is placed so the
stance foot stays, and the inverse dynamics is taken again. The law adds the path's hip- and ankle-roll
torques (their sign flipped when leg r stands) to the tracker's. ``--lateral`` sets the walker's lateral
numbers (:class:`biped_jax.humanoid.walker.WalkerParams` fields, JSON); :data:`LATERAL` holds M2's, found
by CMA-ES over 16 walks of 6 s from the nominal and three disturbed starts per generation, 14
generations (the score: time upright, up at the end, sideways drift).

    python benchmarks/humanoid_sway.py --gaits OUT [--model M2] [--steps 56] [--push-batch 64]
"""

import argparse
import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from _results import save_results
from humanoid_feedforward import optimal_step

from biped_jax.humanoid import free_base, tracker, walk3d
from biped_jax.studies import humanoid as study

#: M2's lateral numbers for the swaying path (the walker's fields they replace).
LATERAL = {"M2": {"lateral_gain": 0.0522, "width": 0.0729, "kp_torso": 67.0707, "kd_torso": 9.4587,
                  "roll_push": 0.8753, "kp_swing": 28.708, "kd_swing": 1.3982, "side_speed": -0.0401,
                  "roll_lean": 0.0084}}
#: A leg's roll joints in :data:`biped_jax.humanoid.free_base.LEG_JOINTS`: hip roll, ankle roll.
ROLLS = (1, 5)


def swaying(prog: walk3d.Program, path: tracker.Path3D, step_time: float) -> tracker.Path3D:
    """``path`` with the pelvis swaying over the stance foot as a linear inverted pendulum (module text)."""
    m, layout = prog.mj_model, prog.layout
    qpos, qvel = np.asarray(path.qpos).copy(), np.asarray(path.qvel).copy()
    t = np.asarray(path.phase) * step_time
    data = mujoco.MjData(m)
    data.qpos[:] = qpos[len(t) // 2]
    mujoco.mj_kinematics(m, data)
    mujoco.mj_comPos(m, data)
    omega, c = np.sqrt(9.81 / float(data.subtree_com[0][2])), prog.legs.hip_y
    sway = c * (1 - np.cosh(omega * (t - step_time / 2)) / np.cosh(omega * step_time / 2))
    thighs = [m.body(f"thigh_{side}").id for side in "lr"]
    rolls = np.zeros((len(t), 2))
    for i in range(len(t)):
        data.qpos[:] = qpos[i]
        mujoco.mj_kinematics(m, data)
        for side in (0, 1):
            rolls[i, side] = np.arctan2(-sway[i], data.xpos[thighs[side]][2] - data.xpos[layout.feet[side]][2])
    rates = np.gradient(rolls, t, axis=0)
    foot = layout.feet[0]
    for i in range(len(t)):
        for side in (0, 1):
            hip, ankle = layout.legs[side][1], layout.legs[side][5]
            qpos[i, layout.qpos[hip]], qvel[i, layout.qvel[hip]] = rolls[i, side], rates[i, side]
            qpos[i, layout.qpos[ankle]], qvel[i, layout.qvel[ankle]] = -rolls[i, side], -rates[i, side]
        data.qpos[:] = qpos[i]
        mujoco.mj_kinematics(m, data)
        qpos[i, 1] += prog.legs.hip_y - data.xpos[foot][1]
        qpos[i, 0] -= data.xpos[foot][0]
        data.qpos[:] = qpos[i]
        mujoco.mj_kinematics(m, data)
        mujoco.mj_comPos(m, data)
        jacobian = np.zeros((3, m.nv))
        mujoco.mj_jacBody(m, data, jacobian, None, foot)
        qvel[i, :3] = -(jacobian[:, 3:] @ qvel[i, 3:])  # the stance foot still
    held = free_base.single_support(m)
    torque = np.stack([held(p, 0, v, a) for p, v, a in zip(qpos, qvel, np.gradient(qvel, t, axis=0))])
    return dataclasses.replace(path, qpos=jnp.asarray(qpos), qvel=jnp.asarray(qvel), torque=jnp.asarray(torque))


def control(args: tracker.TrackerArgs, prog: walk3d.Program, data, state: tracker.TrackerState):
    """The tracker's command plus the path's roll torques (mirrored when leg r stands)."""
    command, s = tracker.control(args, prog, data, state)
    now, layout = tracker.at_phase(args.path, s), prog.layout
    legs = jnp.asarray(layout.legs)
    mirror = jnp.where(state.stance == 0, 1.0, -1.0)
    for side, leg in ((0, legs[state.stance]), (1, legs[1 - state.stance])):
        for joint in ROLLS:
            command = command.at[leg[joint]].add(mirror * now.torque[layout.legs[side][joint]])
    return command, s


LAW = walk3d.Law("tracker_sway", control, tracker.remember)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gaits", type=Path, required=True, help="the output folder of `biped-jax reproduce`")
    parser.add_argument("--model", default="M2", choices=("M1", "M2", "M3", "M4"))
    parser.add_argument("--lateral", type=json.loads, default=None, help="the walker's lateral numbers, JSON")
    parser.add_argument("--steps", type=int, default=56)
    parser.add_argument("--push-batch", type=int, default=64)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    parser.add_argument("--name", default=None)
    args = parser.parse_args()

    x, settings, trajectory = optimal_step(args.model, args.gaits)
    plain = study.tracker_walking(args.model, x, settings, trajectory)
    prog = walk3d.program(plain.mass_class, plain.parallel)
    lateral = LATERAL.get(args.model, {}) if args.lateral is None else args.lateral
    params = dataclasses.replace(study.walk_params(args.model), **lateral)
    path = swaying(prog, jax.tree.map(jnp.asarray, plain.args.path), plain.step_time)
    law_args = tracker.TrackerArgs(tracker.gains_for(args.model), path, plain.args.gait, params)
    walking = dataclasses.replace(plain, law=LAW, args=walk3d.fixed_arrays(law_args),
                                  start_state=tracker.start_state(path, params),
                                  start=lambda q, v: tracker.start(prog, law_args, q, v))
    started = time.perf_counter()
    entry, _ = study.walk_3d(walking, trajectory, args.steps, args.push_batch, print)
    entry["controller"]["lateral"] = dataclasses.asdict(params)  # walk_3d records the walker's own
    row = {"model": args.model, "lateral": lateral, "wall_s": time.perf_counter() - started, **entry}
    print(json.dumps({k: v for k, v in row.items() if not isinstance(v, (dict, list))}, indent=1), flush=True)
    save_results(args.name or f"humanoid_sway_{args.model}", {"model": args.model}, [row], args.out)


if __name__ == "__main__":
    main()
