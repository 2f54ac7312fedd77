"""How far a textbook 3D walking pattern gets on the free-base humanoid, with the drives' line and without.

Not the project's walking controller (that is :mod:`biped_jax.humanoid.walker`, run by ``biped-jax
humanoid``): a probe of what the hardware asks of a textbook pattern. The pattern is Kajita's ZMP preview
control (cart-table model at the standing centre of mass height, Q_e = 1, R = 1e-6, 1.6 s preview) over a
fixed footstep plan at the optimal M2 gait's step length and time (0.2 m, 0.360 s: 0.555 m/s), feet 0.13
m apart; the joints follow an analytic leg inverse kinematics (torso level, feet flat, the pelvis at
``--pelvis-height``) by PD (300 N m/rad on the legs), plus each sample's static torques standing on its
stance foot (:func:`biped_jax.humanoid.free_base.single_support_torques`, halved over both feet while
both stand) and a torso roll/pitch/yaw feedback through the stance hip. The humanoid is
:func:`~biped_jax.humanoid.free_base.free_base_humanoid` (the recommended drive's reflected inertia at
every joint) in MJX at 1 ms; with the line (default) every torque is clipped to it
(:func:`~biped_jax.humanoid.free_base.drive_torques`), with ``--unclipped`` not.

Reported: the planned steps walked before a fall (hips below 0.2 m), the speed over the middle steps
against the plan's, the torso's largest yaw, and per joint the largest and 95th-percentile |torque| and
the share of samples whose command lies beyond the drive's line at that speed.

    python benchmarks/humanoid_3d_probe.py [--unclipped] [--mass-class 12kg] [--pelvis-height 0.25]
"""

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
from _results import save_results

PREVIEW_DT = 0.005  # s
PREVIEW_SECONDS = 1.6
STANDING = 0.6  # s before the first step
LEG_GAINS = ((100.0, 2.0), (300.0, 5.0), (300.0, 5.0), (300.0, 5.0), (200.0, 3.0), (150.0, 2.0))  # per leg joint
ARM_GAINS = (30.0, 0.5)
TORSO_GAINS = ((30.0, 1.0), (30.0, 1.0), (10.0, 0.5))  # roll, pitch, yaw: N m/rad, N m s/rad


@dataclasses.dataclass(frozen=True)
class Geometry:
    """The legs' dimensions, m, read from the model: each hip's offset from the mid-plane, thigh and
    shank lengths, the sole's thickness and how far its centre lies ahead of the ankle."""

    hip_y: float
    thigh: float
    shank: float
    sole: float
    sole_ahead: float

    @classmethod
    def of(cls, mj_model) -> "Geometry":
        foot = mj_model.geom("foot_l")
        return cls(hip_y=float(mj_model.body("thigh_l").pos[1]), thigh=float(-mj_model.body("shank_l").pos[2]),
                   shank=float(-mj_model.body("foot_l").pos[2]), sole=float(2 * foot.size[2]),
                   sole_ahead=float(foot.pos[0]))


def leg_angles(geometry, ankle_from_hip):
    """(hip roll, hip pitch, knee) that put the ankle at ``ankle_from_hip`` (3,) (torso frame), m."""
    x, y, z = ankle_from_hip
    thigh, shank = geometry.thigh, geometry.shank
    roll = np.arctan2(y, -z)
    height = np.hypot(y, z)
    knee = np.arccos(np.clip((x * x + height * height - thigh ** 2 - shank ** 2) / (2 * thigh * shank), -1, 1))
    pitch = np.arctan2(-x, height) - np.arctan2(shank * np.sin(knee), thigh + shank * np.cos(knee))
    return roll, pitch, knee


def posture(mj_model, layout, geometry, pelvis, ankles):
    """qpos with the torso level at ``pelvis`` (3,) and the ankles at ``ankles`` (2, 3), feet flat."""
    qpos = np.array(mj_model.qpos0)
    qpos[:3], qpos[3:7] = pelvis, (1.0, 0.0, 0.0, 0.0)
    for leg, side in ((0, 1.0), (1, -1.0)):
        roll, pitch, knee = leg_angles(geometry, ankles[leg] - pelvis - np.array([0.0, side * geometry.hip_y, 0.0]))
        for joint, angle in zip(layout.legs[leg], (0.0, roll, pitch, knee, -(pitch + knee), -roll)):
            qpos[layout.qpos[joint]] = angle
    return qpos


def footstep_plan(geometry, steps: int, length: float, step_time: float):
    """[(lift-off time, swing leg (0 l, 1 r), from (x, y), to (x, y))], the right foot first, a half step
    to start."""
    hip_y = geometry.hip_y
    feet = [np.array([0.0, hip_y]), np.array([0.0, -hip_y])]
    plan, t = [], STANDING
    for k in range(steps):
        leg = 1 - k % 2
        target = np.array([feet[1 - leg][0] + (length if k else length / 2), hip_y if leg == 0 else -hip_y])
        plan.append((t, leg, feet[leg].copy(), target))
        feet[leg], t = target, t + step_time
    return plan, t


def phase_of(plan, step_time, t):
    """(index of the step in the air, its phase in [0, 1)) at time t, or (None, None) when none is."""
    for k, (start, *_rest) in enumerate(plan):
        if start <= t < start + step_time:
            return k, (t - start) / step_time
    return None, None


def ankles_at(geometry, plan, step_time, clearance, t):
    """Both ankles (2, 3) at time t: a swing foot moves on a smoothstep in x, y, lifted by clearance sin^2."""
    sole = geometry.sole
    feet = [np.array([0.0, geometry.hip_y, sole]), np.array([0.0, -geometry.hip_y, sole])]
    for start, leg, origin, target in plan:
        if t < start:
            break
        if t < start + step_time:
            s = (t - start) / step_time
            blend = s * s * (3 - 2 * s)
            xy = (1 - blend) * origin + blend * target
            feet[leg] = np.array([xy[0], xy[1], sole + clearance * np.sin(np.pi * s) ** 2])
            break
        feet[leg] = np.array([target[0], target[1], sole])
    return np.stack(feet)


def preview_com(zmp, height):
    """The centre of mass path (N, 2) whose cart-table ZMP follows ``zmp`` (N, 2), by preview control."""
    import scipy.linalg
    dt = PREVIEW_DT
    a = np.array([[1, dt, dt * dt / 2], [0, 1, dt], [0, 0, 1]])
    b = np.array([[dt ** 3 / 6], [dt * dt / 2], [dt]])
    c = np.array([[1, 0, -height / 9.81]])
    p = scipy.linalg.solve_discrete_are(a, b, c.T @ c, 1e-6)
    scale = 1e-6 + (b.T @ p @ b)[0, 0]
    gain = (b.T @ p @ a) / scale
    closed, x_future, preview = a - b @ gain, c.T, []
    for _ in range(int(PREVIEW_SECONDS / dt)):
        preview.append((b.T @ x_future)[0, 0] / scale)
        x_future = closed.T @ x_future
    preview = np.array(preview)
    path = np.zeros_like(zmp)
    for axis in range(2):
        state = np.array([zmp[0, axis], 0.0, 0.0])
        for k in range(len(zmp)):
            ahead = zmp[np.minimum(np.arange(k + 1, k + 1 + len(preview)), len(zmp) - 1), axis]
            path[k, axis] = state[0]
            state = a @ state + b[:, 0] * (-(gain @ state)[0] + preview @ ahead)
    return path


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mass-class", default="12kg", choices=("12kg", "18kg"))
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--pelvis-height", type=float, default=0.25, help="m (the straight leg reaches 0.31)")
    parser.add_argument("--clearance", type=float, default=0.03, help="swing foot lift, m")
    parser.add_argument("--unclipped", action="store_true", help="torques not clipped to the drives' line")
    parser.add_argument("--feed-forward", default="static", choices=("static", "inverse-dynamics"),
                        help="each sample's torques standing still in its pose (default), or the plan's "
                             "inverse dynamics on the stance foot in single support")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    parser.add_argument("--name", default=None, help="results file stem")
    args = parser.parse_args()
    from biped_jax.commands import configure_jax
    configure_jax()
    import jax
    import jax.numpy as jnp
    import mujoco
    from biped_jax.humanoid import free_base
    from biped_jax.robots import registry
    mjx = registry.import_mjx()

    step_length, step_time = 0.2, 0.2 / 0.555
    drives = free_base.walk_drives()
    mj_model = free_base.free_base_humanoid(args.mass_class, drives)
    layout = free_base.FreeLayout.of(mj_model)
    data = mujoco.MjData(mj_model)
    geometry = Geometry.of(mj_model)
    standing = ankles_at(geometry, [], step_time, 0.0, 0.0)
    data.qpos[:] = posture(mj_model, layout, geometry, np.array([0.0, 0.0, args.pelvis_height]), standing)
    mujoco.mj_kinematics(mj_model, data)
    mujoco.mj_comPos(mj_model, data)
    com_offset = data.subtree_com[0] - data.qpos[:3]  # the torso frame to the centre of mass, standing

    plan, end = footstep_plan(geometry, args.steps, step_length, step_time)
    end += 1.0
    grid = np.arange(int(end / PREVIEW_DT) + 1) * PREVIEW_DT
    zmp = []
    for t in grid:
        k, _ = phase_of(plan, step_time, t)
        feet = ankles_at(geometry, plan, step_time, 0.0, t)[:, :2]
        under = feet[1 - plan[k][1]] if k is not None else feet.mean(axis=0)
        zmp.append(under + np.array([geometry.sole_ahead, 0.0]))
    com = preview_com(np.array(zmp), float(data.subtree_com[0][2]))

    timestep = mj_model.opt.timestep
    times = np.arange(int(end / timestep)) * timestep
    feed_forward = np.zeros((len(times), mj_model.nu))
    stance = np.full(len(times), -1)
    statics = free_base.single_support(mj_model)
    planned = np.empty((len(times), mj_model.nq))
    for k, t in enumerate(times):
        centre = np.array([np.interp(t, grid, com[:, 0]), np.interp(t, grid, com[:, 1])])
        pelvis = np.array([*(centre - com_offset[:2]), args.pelvis_height])
        planned[k] = posture(mj_model, layout, geometry, pelvis,
                             ankles_at(geometry, plan, step_time, args.clearance, t))
        air, _ = phase_of(plan, step_time, t)
        stance[k] = -1 if air is None else 1 - plan[air][1]
    joints = planned[:, list(layout.qpos)]
    rates = np.gradient(joints, timestep, axis=0)
    # the plan's generalised velocity and acceleration: the torso level, so no angular terms
    qvel = np.concatenate([np.gradient(planned[:, :3], timestep, axis=0), np.zeros((len(times), 3)), rates], axis=1)
    qacc = np.gradient(qvel, timestep, axis=0)
    ideal = np.full_like(joints, np.nan)  # the plan's inverse dynamics on its stance foot (single support)
    for k in range(0, len(times), 5):  # every 5 ms, held (both feet: the static halves)
        on = [stance[k]] if stance[k] >= 0 else [0, 1]
        feed_forward[k:k + 5] = np.mean([statics(planned[k], f) for f in on], axis=0)
        if stance[k] >= 0:
            ideal[k:k + 5] = statics(planned[k], stance[k], qvel[k], qacc[k])
    if args.feed_forward == "inverse-dynamics":
        feed_forward = np.where(np.isnan(ideal), feed_forward, ideal)

    model = registry.put_mjx_model(mj_model)
    kp = jnp.asarray([g[0] for g in LEG_GAINS] * 2 + [ARM_GAINS[0]] * 4)
    kd = jnp.asarray([g[1] for g in LEG_GAINS] * 2 + [ARM_GAINS[1]] * 4)
    torso_k, torso_d = (jnp.asarray([g[i] for g in TORSO_GAINS]) for i in (0, 1))
    legs = jnp.asarray(layout.legs)
    clip = not args.unclipped

    def physics_step(data, sample):
        target, rate, ff, on = sample
        q, qd = data.qpos[jnp.asarray(layout.qpos)], data.qvel[jnp.asarray(layout.qvel)]
        command = ff + kp * (target - q) + kd * (rate - qd)
        rot = data.xmat[layout.torso]
        angles = jnp.stack([jnp.arctan2(-rot[1, 2], rot[2, 2]), jnp.arctan2(-rot[2, 0], rot[0, 0]),
                            jnp.arctan2(rot[1, 0], rot[0, 0])])
        turn_back = torso_k * angles + torso_d * data.qvel[3:6]  # hip torques (roll, pitch, yaw)
        share = jnp.where(on < 0, 0.5, jnp.where(on == jnp.arange(2), 1.0, 0.0))
        for leg in (0, 1):
            for axis, joint in ((0, 1), (1, 2), (2, 0)):
                command = command.at[legs[leg, joint]].add(share[leg] * turn_back[axis])
        applied, limits = free_base.drive_torques(drives, command, qd)
        data = mjx.euler(model, mjx.forward(model, data.replace(ctrl=applied if clip else command)))
        return data, (data.qpos[2], data.subtree_com[layout.torso], data.qpos[3:7], command,
                      applied if clip else command, limits)

    run = jax.jit(lambda data, samples: jax.lax.scan(physics_step, data, samples))
    qpos0 = posture(mj_model, layout, geometry, np.array([*(com[0] - com_offset[:2]), args.pelvis_height]), standing)
    data = mjx.forward(model, mjx.make_data(model).replace(qpos=jnp.asarray(qpos0)))
    chunk, parts, started = 1000, [], time.perf_counter()
    for first in range(0, len(times) - chunk + 1, chunk):
        window = slice(first, first + chunk)
        data, part = run(data, tuple(jnp.asarray(a[window]) for a in (joints, rates, feed_forward, stance)))
        parts.append(jax.tree.map(np.asarray, part))
        if parts[-1][0][-1] < 0.2:
            break
    height, centre, quat, command, applied, limits = (np.concatenate(p) for p in zip(*parts))
    seconds = time.perf_counter() - started
    n = len(height)
    fallen = np.flatnonzero(height < 0.2)
    last = fallen[0] if len(fallen) else n
    walked = sum(1 for start, *_ in plan if start + step_time <= times[last - 1])
    first_mid = int((STANDING + 4 * step_time) / timestep)
    last_mid = int((STANDING + (args.steps - 1) * step_time) / timestep)
    speed = ((centre[last_mid, 0] - centre[first_mid, 0]) / (times[last_mid] - times[first_mid])
             if last_mid < last else None)
    w, x, y, z = quat.T
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    line = np.where(command > 0, limits[:, 1], limits[:, 0])
    beyond = np.abs(command) > np.abs(line)
    walking = (times[:n] > STANDING) & (np.arange(n) < last)
    names = [mj_model.actuator(a).name for a in range(mj_model.nu)]
    per_joint = {name: {"max_Nm": float(np.abs(applied[walking, a]).max()),
                        "p95_Nm": float(np.percentile(np.abs(applied[walking, a]), 95)),
                        "beyond_line_share": float(beyond[walking, a].mean())} for a, name in enumerate(names)}
    # what perfect tracking of the plan would ask, single support between the fourth and the last steps
    mid = (stance >= 0) & (times > STANDING + 3 * step_time) & (times < STANDING + (args.steps - 2) * step_time)
    plan_speed = rates[mid]
    ideal_limits = np.stack([np.asarray(x) for x in free_base.drive_torques(drives, jnp.asarray(ideal[mid]),
                                                                              jnp.asarray(plan_speed))[1]])
    ideal_line = np.where(ideal[mid] > 0, ideal_limits[1], ideal_limits[0])
    plan_needs = {name: {"max_Nm": float(np.abs(ideal[mid, a]).max()),
                         "p95_Nm": float(np.percentile(np.abs(ideal[mid, a]), 95)),
                         "beyond_line_share": float((np.abs(ideal[mid, a]) > np.abs(ideal_line[:, a])).mean())}
                  for a, name in enumerate(names)}
    row = {"mass_class": args.mass_class, "clipped_to_drive_line": clip, "pelvis_height_m": args.pelvis_height,
           "feed_forward": args.feed_forward, "plan_inverse_dynamics_single_support": plan_needs,
           "steps_planned": args.steps, "steps_walked": walked, "fell": bool(len(fallen)),
           "speed_ratio": None if speed is None else speed / (step_length / step_time),
           "largest_yaw_rad": float(np.abs(yaw[:last]).max()), "simulated_s": float(times[n - 1]),
           "wall_s": seconds, "joints": per_joint}
    print(f"{args.mass_class}, {'clipped to the line' if clip else 'unclipped'}: {walked} of {args.steps} steps, "
          f"{'fell' if row['fell'] else 'did not fall'}, speed ratio {row['speed_ratio']}, largest yaw "
          f"{row['largest_yaw_rad']:.2f} rad")
    for name in names[:12]:
        j, ideal_j = per_joint[name], plan_needs[name]
        print(f"  {name:14s} max {j['max_Nm']:6.1f} N m, 95 % {j['p95_Nm']:5.1f} N m, beyond the line "
              f"{100 * j['beyond_line_share']:4.1f} % of samples; the plan's inverse dynamics max "
              f"{ideal_j['max_Nm']:5.1f}, 95 % {ideal_j['p95_Nm']:5.1f} N m, beyond "
              f"{100 * ideal_j['beyond_line_share']:4.1f} %")
    settings = {"drive": f"{free_base.WALK_MOTOR} + {free_base.WALK_GEARHEAD}", "step_length_m": step_length,
                "step_time_s": step_time, "preview": {"dt_s": PREVIEW_DT, "horizon_s": PREVIEW_SECONDS}}
    save_results(args.name or f"humanoid_3d_probe_{args.mass_class}_{'clipped' if clip else 'unclipped'}",
                 settings, [row], args.out)


if __name__ == "__main__":
    main()
