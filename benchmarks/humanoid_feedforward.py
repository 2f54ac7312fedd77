"""A candidate 3D walk on the optimal gait itself: the humanoid's own inverse dynamics along the sagittal
optimum as feed-forward, phased by the stance angle, the tuned walker's lateral law beside it.

Not yet the walk of ``biped-jax humanoid`` (:mod:`biped_jax.humanoid.walker`, Raibert placement and PD):
this script measures the candidate that replaces it. The law, per physics step, with leg l or r standing:

- **Path and feed-forward.** The study's optimal step (``biped-jax reproduce``'s results.json) is put on
  the 3D humanoid with leg l standing, its foot flat and still, the swing foot level: the configuration,
  velocity and acceleration of every degree of freedom on the gait's own grid (the swing foot lifted as
  ``biped-jax humanoid``'s replay lifts it). Floating-base inverse dynamics of the walk's model,
  [S^T J_foot^T] [tau; lambda] = M qacc + bias, give the joint torques that make the humanoid itself
  (its feet, arms and the gearheads' reflected inertia, which the planar optimum does not carry) follow it
  (:func:`biped_jax.humanoid.free_base.single_support`); the run prints each joint's largest, which can
  exceed the optimum's own where the humanoid carries more than the planar model.
- **Phase.** s in [0, 1] from the stance angle theta = torso pitch + stance hip + stance knee, mapped from
  [theta at touchdown, theta at the step's end] onto the optimal step's (hybrid-zero-dynamics phasing,
  :func:`biped_jax.humanoid.controller.phase_of`): the legs follow the stance leg's progress, not a clock.
- **Sagittal joints.** Hip pitch, knee and ankle pitch of both legs: feed-forward(s) + PD to the path(s)
  (the offsets at touchdown fading out over ``fade`` of the step), except the stance hip, which holds the
  torso's pitch on the path's (and takes back the swing hip's feedback, so the swing leg does not tip the
  torso); the stance ankle adds ``ankle_w`` (theta_dot_ref(s) - theta_dot), clipped to 3 N m; the swing
  hip's target moves ``place`` rad per m/s of pelvis speed above the path's, late in the swing.
- **Lateral, yaw, arms**: the tuned walker's law (:func:`biped_jax.humanoid.walker.control`).
- **Touchdown**: the swing sole within 1 mm of the ground after s = 0.9, the swing foot 5 cm ahead of the
  stance foot and half a step time after the last touchdown.

Every torque is clipped to the drive's line (:func:`biped_jax.humanoid.free_base.drive_torques`);
``--parallel-hip-roll`` puts two drives on each hip roll (the 18 kg walk's drives already do). The walk
starts on the gait, at its state after a touchdown with leg l standing, moving sideways toward it at the
walker's ``side_speed``. ``--tune G`` runs G generations of CMA-ES over the law's eleven gains first
(``--population`` walks of ``--tune-seconds`` in one vmapped program per generation).

    python benchmarks/humanoid_feedforward.py --gaits OUT [--model M2] [--parallel-hip-roll]
        [--gains FILE.json] [--tune 0] [--seconds 12] [--name humanoid_feedforward_M2]
"""

import argparse
import dataclasses
import functools
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from _results import save_results

from biped_jax.commands import configure_jax

configure_jax()

from biped_jax.dynamics import mjx_biped  # noqa: E402
from biped_jax.gait import problem as gait_problem  # noqa: E402
from biped_jax.humanoid import controller, free_base, reference, walk3d, walker  # noqa: E402
from biped_jax.studies import humanoid as study  # noqa: E402

#: A leg's sagittal joints in :data:`biped_jax.humanoid.free_base.LEG_JOINTS`: hip pitch, knee, ankle pitch.
SAGITTAL = (2, 3, 4)
#: Largest torque of the stance ankle's phase-rate feedback, N m.
ANKLE_FEEDBACK_LIMIT = 3.0
#: Touchdown: earliest phase, how far the swing foot must be ahead of the stance foot (m), and the
#: shortest step as a share of the gait's step time.
TOUCHDOWN_PHASE, TOUCHDOWN_AHEAD, SHORTEST_STEP = 0.9, 0.05, 0.5


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Gains:
    """The law's gains (N m/rad, N m s/rad unless said): stance knee (kp, kd), swing leg (kp_sw, kd_sw),
    torso pitch through the stance hip (kp_t, kd_t), ankles' pitch (kp_a, kd_a), ankle_w (N m s/rad on
    the stance angle's rate), place (rad of swing hip per m/s), fade (share of the step over which the
    touchdown's offsets fade)."""

    kp: float
    kd: float
    kp_sw: float
    kd_sw: float
    kp_t: float
    kd_t: float
    kp_a: float
    kd_a: float
    ankle_w: float
    place: float
    fade: float


#: Each model's gains from this script's CMA-ES, as the runs in benchmarks/RESULTS.md found them: ``--tune 12``
#: from :data:`START`, then ``--tune 12 --lift-weight 20`` from there (M2 with ``--parallel-hip-roll``).
TUNED = {
    "M2": Gains(kp=467.55979463612584, kd=2.3877844060517908, kp_sw=98.24471804470495, kd_sw=6.83717260597028,
                kp_t=334.8495599077686, kd_t=17.34241193347014, kp_a=60.49809372678868, kd_a=3.2180128698869024,
                ankle_w=-10.322381664485071, place=-0.5853395203591996, fade=0.36215744372380027),
    "M4": Gains(kp=532.066737845733, kd=0.4761168447127277, kp_sw=230.0750942188896,
                kd_sw=5.584587555991759, kp_t=380.1768422872628, kd_t=14.970342741430022,
                kp_a=78.57841635823755, kd_a=3.0130945399253846, ankle_w=-12.123244075703028,
                place=0.5713431014477469, fade=0.34333709808633567),
}
#: The tuner's start where a model has no tuned gains: a hand-tuned first set (unclipped walks of M2).
START = Gains(kp=515.7, kd=0.48, kp_sw=230.4, kd_sw=6.40, kp_t=388.8, kd_t=14.66, kp_a=68.6, kd_a=3.00,
              ankle_w=-9.39, place=-0.046, fade=0.339)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Path3D:
    """The optimal step on the 3D humanoid, leg l standing, on the gait's grid (S samples).

    Attributes:
      phase: (S,). qpos: (S, nq), m and rad, the stance foot's body at x = 0. qvel: (S, nv). torque: the
      inverse dynamics' joint torques in actuator order, (S, 16), N m. pitch: the torso's, (S,), rad.
    """

    phase: jax.Array
    qpos: jax.Array
    qvel: jax.Array
    torque: jax.Array
    pitch: jax.Array


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Track:
    """What the law keeps from the last touchdown: the stance angle then (rad) and the sagittal joints'
    offsets from the path's start (stance hip, knee, ankle, swing hip, knee, ankle), (6,), rad."""

    stance_angle: jax.Array
    offset: jax.Array


def optimal_step(name: str, gaits: Path):
    """(mass class, GaitModel, GaitReference, trajectory) of the study's model ``name`` from ``gaits``."""
    x, settings, status = study.solved_gait(name, gait_problem.GaitSettings(), gaits, print)
    if status != "converged":
        print(f"warning: the {name} gait did not converge ({status})")
    mass_class, model = study.paper_model(name)
    biped = mjx_biped.load_planar_biped(mass_class)
    trajectory = jax.jit(lambda x_, m: gait_problem.simulate(x_, m, biped, settings))(jnp.asarray(x), model)
    return mass_class, model, reference.gait_reference(x, model, settings, trajectory, mass_class), trajectory


def path_3d(prog: walk3d.Program, model, trajectory, mass_class: str) -> Path3D:
    """The step on the humanoid (:class:`Path3D`): the gait's states on its grid, the swing foot lifted as
    the replay's (:func:`biped_jax.humanoid.reference.clearance_offset`), accelerations by differences of the
    velocities; then the inverse dynamics."""
    m, layout = prog.mj_model, prog.layout
    t, q, qd = (np.asarray(a) for a in (trajectory.t, trajectory.q, trajectory.qd))
    phase = t / t[-1]
    order = [2, 1, 3, 4]  # (H1, K1, H2, K2) in the pinned chain's coordinates; q[:, 0] the stance angle
    lift = reference.clearance_offset(model, q, phase, phase, mass_class)  # the replay's swing clearance
    joints, rates = q[:, order] + lift, qd[:, order] + np.gradient(lift, t, axis=0)
    pitch = q[:, 0] - joints[:, 0] - joints[:, 1]
    pitch_rate = qd[:, 0] - rates[:, 0] - rates[:, 1]
    data = mujoco.MjData(m)
    qpos, qvel = np.zeros((len(t), m.nq)), np.zeros((len(t), m.nv))
    foot = layout.feet[0]
    for i in range(len(t)):
        qpos[i], qvel[i, 4] = m.qpos0, pitch_rate[i]
        qpos[i, :3] = 0.0
        qpos[i, 3:7] = [np.cos(pitch[i] / 2), 0.0, np.sin(pitch[i] / 2), 0.0]
        for leg, (h, k), (hd, kd) in ((layout.legs[0], joints[i, :2], rates[i, :2]),
                                      (layout.legs[1], joints[i, 2:], rates[i, 2:])):
            for joint, angle, rate in zip(SAGITTAL, (h, k, -(pitch[i] + h + k)), (hd, kd, -(pitch_rate[i] + hd + kd))):
                qpos[i, layout.qpos[leg[joint]]], qvel[i, layout.qvel[leg[joint]]] = angle, rate  # feet level
        data.qpos[:], data.qvel[:] = qpos[i], qvel[i]
        mujoco.mj_kinematics(m, data)
        mujoco.mj_comPos(m, data)
        qpos[i, [0, 2]] -= data.xpos[foot][[0, 2]]
        jacobian = np.zeros((3, m.nv))
        mujoco.mj_jacBody(m, data, jacobian, None, foot)
        qvel[i, :3] = -(jacobian[:, 3:] @ qvel[i, 3:])  # the stance foot still (the free joint's columns: I)
    data.qpos[:] = qpos[0]
    mujoco.mj_kinematics(m, data)
    qpos[:, 2] -= float(np.min(walker.sole_heights(prog.legs, data)))
    held = free_base.single_support(m)  # the inverse dynamics with the stance foot's wrench alone moving the base
    torque = np.stack([held(p, 0, v, a) for p, v, a in zip(qpos, qvel, np.gradient(qvel, t, axis=0))])
    return Path3D(*(jnp.asarray(a) for a in (phase, qpos, qvel, torque, pitch)))


def control(gains: Gains, path: Path3D, gait: reference.GaitReference, params: walker.WalkerParams,
            prog: walk3d.Program, data, memory: walker.WalkerMemory, track: Track):
    """Every actuator's command (16,), N m, and the phase s."""
    layout = prog.layout
    q, qd = data.qpos[jnp.asarray(layout.qpos)], data.qvel[jnp.asarray(layout.qvel)]
    rotation = data.xmat[layout.torso]
    pitch, pitch_rate = walker.torso_angles(rotation)[1], (rotation @ data.qvel[3:6])[1]
    legs = jnp.asarray(layout.legs)
    stance, swing = legs[memory.stance], legs[1 - memory.stance]
    theta = pitch + q[stance[2]] + q[stance[3]]
    s = controller.phase_of(gait, controller.Support(memory.stance, track.stance_angle, track.offset), theta)
    at = lambda column: jnp.interp(s, path.phase, column)  # noqa: E731
    fade = jnp.maximum(1.0 - s / gains.fade, 0.0) ** 3
    place = -gains.place * (data.qvel[0] - at(path.qvel[:, 0])) * s * s
    command = walker.control(params, layout, prog.legs, data, memory)  # lateral, yaw and arms
    feedback = {}
    for side, leg, (kp, kd) in ((0, stance, (gains.kp, gains.kd)), (1, swing, (gains.kp_sw, gains.kd_sw))):
        for k, joint in enumerate(SAGITTAL):
            j = layout.legs[side][joint]  # the path's joint (leg l standing)
            p, d = (gains.kp_a, gains.kd_a) if joint == 4 else (kp, kd)
            if side == 0 and joint == 2:
                p = d = 0.0  # the stance hip holds the torso instead
            target = at(path.qpos[:, layout.qpos[j]]) + fade * track.offset[3 * side + k] \
                + (place if side == 1 and joint == 2 else 0.0)
            rate = at(path.qvel[:, layout.qvel[j]])
            feedback[side, joint] = p * (target - q[leg[joint]]) + d * (rate - qd[leg[joint]])
            command = command.at[leg[joint]].set(at(path.torque[:, j]) + feedback[side, joint])
    torso = gains.kp_t * (at(path.pitch) - pitch) - gains.kd_t * (pitch_rate - at(path.qvel[:, 4]))
    command = command.at[stance[2]].add(-torso - feedback[1, 2])
    theta_rate = pitch_rate + qd[stance[2]] + qd[stance[3]]
    pace = jnp.interp(s, gait.phase, gait.stance_angle_slope) / gait.step_time - theta_rate
    command = command.at[stance[4]].add(jnp.clip(gains.ankle_w * pace, -ANKLE_FEEDBACK_LIMIT, ANKLE_FEEDBACK_LIMIT))
    return command, s


def track_after(prog: walk3d.Program, path: Path3D, gait: reference.GaitReference, data, stance) -> Track:
    """The track when leg ``stance`` has just landed."""
    layout = prog.layout
    q = data.qpos[jnp.asarray(layout.qpos)]
    legs = jnp.asarray(layout.legs)
    now = jnp.concatenate([q[legs[stance][jnp.asarray(SAGITTAL)]], q[legs[1 - stance][jnp.asarray(SAGITTAL)]]])
    start = jnp.stack([path.qpos[0, layout.qpos[layout.legs[side][joint]]] for side in (0, 1) for joint in SAGITTAL])
    theta = walker.torso_angles(data.xmat[layout.torso])[1] + now[0] + now[1]
    # keep a usable phase range where the robot lands far off the path
    return Track(stance_angle=jnp.minimum(theta, gait.stance_angle[-1] - 0.1), offset=now - start)


def stepper(prog: walk3d.Program):
    """``step(args, carry, push) -> (carry, (command, applied))`` of one physics step; args = (gains, path,
    gait, walker params), carry = (MJX data, walker memory, track), ``push`` on the torso
    (:class:`biped_jax.humanoid.walk3d.Push`)."""
    layout = prog.layout
    timestep = float(prog.mj_model.opt.timestep)

    def step(args, carry, push: walk3d.Push = walk3d.NO_PUSH):
        gains, path, gait, params = args
        data, memory, track = carry
        command, s = control(gains, path, gait, params, prog, data, memory, track)
        applied, _ = free_base.drive_torques(prog.drives, command, data.qvel[jnp.asarray(layout.qvel)])
        force = jnp.zeros((prog.mj_model.nbody, 6)).at[layout.torso, :3].set(push.at(data.time))
        data = walk3d.mjx.step(prog.model, data.replace(ctrl=applied, xfrc_applied=force))
        feet = data.xpos[jnp.asarray(layout.feet)]
        landed = ((walker.sole_heights(prog.legs, data)[1 - memory.stance] < walker.TOUCHDOWN_HEIGHT)
                  & (s > TOUCHDOWN_PHASE) & (memory.time > SHORTEST_STEP * gait.step_time)
                  & (feet[1 - memory.stance, 0] - feet[memory.stance, 0] > TOUCHDOWN_AHEAD))
        new = walker.after_step(layout, data, memory, landed, timestep)
        landed_track = track_after(prog, path, gait, data, new.stance)
        track = jax.tree.map(lambda a, b: jnp.where(landed, a, b), landed_track, track)
        return (data, new, track), (command, applied)

    return step


def start_state(path: Path3D, params: walker.WalkerParams) -> tuple[np.ndarray, np.ndarray]:
    """(qpos, qvel) on the gait after a touchdown, leg l standing, moving toward it sideways at
    ``params.side_speed``."""
    qpos, qvel = np.asarray(path.qpos[0]).copy(), np.asarray(path.qvel[0]).copy()
    qvel[1] += float(params.side_speed)
    return qpos, qvel


def start(prog: walk3d.Program, path: Path3D, gait: reference.GaitReference, params: walker.WalkerParams,
          qpos: np.ndarray | None = None, qvel: np.ndarray | None = None):
    """(MJX data, walker memory, track) at ``qpos``, ``qvel`` (default :func:`start_state`)."""
    if qpos is None or qvel is None:
        qpos, qvel = start_state(path, params)
    data, memory = walk3d.initial(prog, params, qpos, qvel)
    return data, memory, track_after(prog, path, gait, data, jnp.asarray(0))


@functools.lru_cache(maxsize=None)
def recorder(mass_class: str, parallel: tuple[str, ...]):
    """One compiled call: :data:`walk3d.CHUNK` physics steps, each sampled as :class:`walk3d.Walk`."""
    prog = walk3d.program(mass_class, parallel)
    step, feet = stepper(prog), jnp.asarray(prog.layout.feet)

    def sampled(args, carry, _):
        stance = carry[1].stance
        carry, (command, applied) = step(args, carry)
        data = carry[0]
        return carry, walk3d.Walk(t=data.time, qpos=data.qpos, qvel=data.qvel, command=command, applied=applied,
                                  stance=stance, feet=data.xpos[feet], foot_force=walk3d.ground_forces(prog, data))

    return jax.jit(lambda args, carry: jax.lax.scan(functools.partial(sampled, args), carry, None,
                                                    length=walk3d.CHUNK))


def walk(mass_class: str, parallel: tuple[str, ...], args, carry, seconds: float) -> walk3d.Walk:
    """The walk from ``carry`` for ``seconds`` s or until a fall (the record ends there)."""
    advance, chunks = recorder(mass_class, parallel), []
    while True:
        carry, sample = advance(args, carry)
        chunks.append(jax.tree.map(np.asarray, sample))
        if walk3d.fallen(chunks[-1].qpos).any() or chunks[-1].t[-1] >= seconds:
            break
    record = jax.tree.map(lambda *parts: np.concatenate(parts), *chunks)
    down = np.flatnonzero(walk3d.fallen(record.qpos))
    return record if not len(down) else jax.tree.map(lambda a: a[:down[0] + 1], record)


def disturbed_start(prog, path: Path3D, params: walker.WalkerParams, rng) -> tuple[np.ndarray, np.ndarray]:
    """(qpos, qvel) of :func:`start_state` with every joint off by up to 0.02 rad and the pelvis's velocity by
    up to 0.05 m/s per axis (uniform, from ``rng``), the feet put back on the ground."""
    qpos, qvel = start_state(path, params)
    joints = list(prog.layout.qpos)
    qpos[joints] += rng.uniform(-0.02, 0.02, len(joints))
    qvel[:3] += rng.uniform(-0.05, 0.05, 3)
    qpos[2] -= walk3d._lowest_sole(prog, qpos)
    return qpos, qvel


def push_trial(prog, args, batch: int, impulse: float, seconds: float, seed: int = 0) -> dict:
    """``batch`` walks from disturbed starts (every joint within 0.02 rad, the pelvis's velocity within
    0.05 m/s per axis of :func:`start_state`, feet put back on the ground), each pushed for
    ``study.PUSH_DURATION`` s with ``impulse`` N s along +-x at 4 s and along +-y four gait steps later
    (random signs), for ``seconds`` s: one vmapped program of ``walk3d.BATCH_LANES`` walks, called as often
    as the batch needs. Returns the signs, who stayed up and the success rate."""
    gains, path, gait, params = args
    rng = np.random.default_rng(seed)
    step_time = float(gait.step_time)
    signs = rng.choice([-1.0, 1.0], size=(batch, 2))
    starts, runs = [], []
    for b in range(batch):
        starts.append(start(prog, path, gait, params, *disturbed_start(prog, path, params, rng)))
        runs.append(walk3d.pushes(signs[b, 0] * impulse, signs[b, 1] * impulse, 4.0, 4.0 + 4 * step_time,
                                  study.PUSH_DURATION))
    step, n = stepper(prog), int(round(seconds / float(prog.mj_model.opt.timestep)))

    def one(carry, push):
        def body(state, _):
            carry, up = state
            carry, _ = step(args, carry, push)
            return (carry, up & walk3d.upright(carry[0].qpos)), None

        (_, up), _ = jax.lax.scan(body, (carry, jnp.asarray(True)), None, length=n)
        return up

    lanes = min(batch, walk3d.BATCH_LANES)
    run = jax.jit(jax.vmap(one))
    up = []
    for first in range(0, batch, lanes):  # the last call padded with the first runs: one program shape
        members = [(first + k) % batch for k in range(lanes)]
        stacked = jax.tree.map(lambda *a: jnp.stack(a), *[starts[b] for b in members])
        pushed = jax.tree.map(lambda *a: jnp.stack(a), *[walk3d._arrays(runs[b]) for b in members])
        up.append(np.asarray(run(stacked, pushed))[:min(lanes, batch - first)])
    up = np.concatenate(up)
    return {"batch": batch, "impulse_Ns": impulse, "signs": signs.tolist(), "stayed_up": up.tolist(),
            "success_rate": float(up.mean()), "seconds": seconds}


#: CMA-ES: each gain's unit step.
TUNE_SCALE = {"kp": 60.0, "kd": 1.5, "kp_sw": 60.0, "kd_sw": 1.5, "kp_t": 60.0, "kd_t": 3.0, "kp_a": 10.0,
              "kd_a": 0.3, "ankle_w": 5.0, "place": 0.3, "fade": 0.1}


def tune(prog, args, carries: list, generations: int, population: int, seconds: float, step_length: float,
         step_time: float, lift_weight: float = 0.0, sigma: float = 0.3) -> Gains:
    """CMA-ES over :class:`Gains` from ``args[0]``: a candidate's score is its steps within 5 % of the gait's
    length and 10 % of its time, + 3 if up at the end, + its seconds up, + half its distance, - half its mean
    |command - applied| (N m), - ``lift_weight`` times its share of samples with the stance sole above 2 mm
    after the stance's first 30 ms (a rebound or a rocking foot); one vmapped program of ``population``
    walks per generation and start; a candidate's score is its mean over ``carries`` (the starts)."""
    import cma
    step, n = stepper(prog), int(round(seconds / float(prog.mj_model.opt.timestep)))

    def score(gains, carry):
        def body(state, _):
            carry, up, good, distance, last, upright_steps, excess, lifted = state
            before = carry[1]
            carry, (command, applied) = step((gains,) + tuple(args[1:]), carry)
            data, memory = carry[0], carry[1]
            landed = memory.steps != before.steps
            length = memory.foot[0] - before.foot[0]
            good += landed & up & (jnp.abs(length / step_length - 1) < 0.05) \
                & (jnp.abs((data.time - last) / step_time - 1) < 0.1)
            distance += jnp.where(landed & up, length, 0.0)
            up = up & walk3d.upright(data.qpos)
            sole = walker.sole_heights(prog.legs, data)[memory.stance]
            return (carry, up, good, distance, jnp.where(landed, data.time, last), upright_steps + up,
                    excess + jnp.where(up, jnp.sum(jnp.abs(command - applied)), 0.0),
                    lifted + (up & (memory.time > 0.03) & (sole > 0.002))), None

        zero = jnp.asarray(0.0)
        (_, up, good, distance, _, upright_steps, excess, lifted), _ = jax.lax.scan(
            body, (carry, jnp.asarray(True), zero, zero, zero, zero, zero, zero), None, length=n)
        return (good + 3 * up + upright_steps / n * seconds + 0.5 * distance - 0.5 * excess / n
                - lift_weight * lifted / n)

    scores = jax.jit(jax.vmap(score, in_axes=(0, None)))
    names, base = list(TUNE_SCALE), args[0]
    decode = lambda z: Gains(**{k: abs(getattr(base, k) + TUNE_SCALE[k] * z[i]) if k not in ("ankle_w", "place")  # noqa: E731
                                else getattr(base, k) + TUNE_SCALE[k] * z[i] for i, k in enumerate(names)})
    es = cma.CMAEvolutionStrategy(np.zeros(len(names)), sigma, {"popsize": population, "seed": 1, "verbose": -9})
    best = (-np.inf, base)
    for generation in range(generations):
        started = time.perf_counter()
        candidates = es.ask()
        chosen = [decode(z) for z in candidates]
        chosen = [dataclasses.replace(g, fade=min(max(g.fade, 0.05), 0.5)) for g in chosen]
        batch = jax.tree.map(lambda *a: jnp.asarray(np.array(a, dtype=float)), *chosen)
        values = np.mean([np.asarray(scores(batch, carry)) for carry in carries], axis=0)
        es.tell(candidates, list(-values))
        if values.max() > best[0]:
            best = (float(values.max()), jax.tree.map(lambda a: float(a[int(values.argmax())]), batch))
        print(f"generation {generation}: best {values.max():.2f}, overall {best[0]:.2f} "
              f"({time.perf_counter() - started:.0f} s)", flush=True)
    return best[1]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gaits", type=Path, required=True, help="the output folder of `biped-jax reproduce`")
    parser.add_argument("--model", default="M2", choices=("M1", "M2", "M3", "M4"))
    parser.add_argument("--parallel-hip-roll", action="store_true",
                        help="two drives on each hip roll (the 18 kg walk's drives have them anyway)")
    parser.add_argument("--gains", type=Path, default=None,
                        help="a result of this script to take the gains from (default: TUNED, else START)")
    parser.add_argument("--tune", type=int, default=0, help="CMA-ES generations before the walk")
    parser.add_argument("--population", type=int, default=24)
    parser.add_argument("--tune-seconds", type=float, default=9.0)
    parser.add_argument("--tune-starts", type=int, default=1,
                        help="the tuner's starts: the nominal one and this many minus one disturbed ones")
    parser.add_argument("--tune-sigma", type=float, default=0.3, help="CMA-ES's first step, in TUNE_SCALE units")
    parser.add_argument("--lift-weight", type=float, default=0.0,
                        help="the tuner's penalty on the share of samples with the stance sole lifted")
    parser.add_argument("--seconds", type=float, default=12.0, help="the measured walk's length, s")
    parser.add_argument("--push-batch", type=int, default=0,
                        help="walks from disturbed starts in each push trial (0: none; trials at 0 and "
                             "--push-impulse N s)")
    parser.add_argument("--push-impulse", type=float, default=0.5, help="each push's impulse, N s")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    parser.add_argument("--name", default=None)
    args = parser.parse_args()

    mass_class, model, gait, trajectory = optimal_step(args.model, args.gaits)
    parallel = set(walk3d.PARALLEL_DRIVES[mass_class]) | ({"hip_roll"} if args.parallel_hip_roll else set())
    parallel = tuple(sorted(parallel))
    prog = walk3d.program(mass_class, parallel)
    started = time.perf_counter()
    path = path_3d(prog, model, trajectory, mass_class)
    print(f"inverse dynamics along the path ({time.perf_counter() - started:.1f} s): largest |torque| "
          + ", ".join(f"{prog.mj_model.actuator(j).name} {float(np.abs(path.torque[:, j]).max()):.2f}"
                      for j in prog.layout.legs[0][1:5]) + " N m (leg l standing)", flush=True)
    params = study.walk_params(args.model)
    gains = Gains(**json.loads(args.gains.read_text())["rows"][0]["gains"]) if args.gains \
        else TUNED.get(args.model, START)
    arrays = walk3d._arrays((gains, path, gait, params))
    carry = start(prog, path, gait, params)
    if args.tune:
        rng = np.random.default_rng(2)
        carries = [carry] + [start(prog, path, gait, params, *disturbed_start(prog, path, params, rng))
                             for _ in range(args.tune_starts - 1)]
        gains = tune(prog, arrays, carries, args.tune, args.population, args.tune_seconds,
                     float(model.step_length), float(model.step_length / model.speed), args.lift_weight,
                     args.tune_sigma)
        arrays = walk3d._arrays((gains, path, gait, params))
    started = time.perf_counter()
    record = walk(mass_class, parallel, arrays, carry, args.seconds)
    landings = walk3d.touchdowns(record)
    # the steady part from the third touchdown: the walk starts on the gait, without a ramp
    steady_after = float(record.t[landings[2]]) - 1e-9 if len(landings) > 3 else None
    figures = walk3d.measures(record, mass_class, params, float(model.speed), float(model.step_length),
                              steady_after=steady_after)
    row = {"model": args.model, "mass_class": mass_class, "parallel_drives": list(parallel), "seconds": args.seconds,
           "walked_s": float(record.t[-1]),
           "walk_wall_s": time.perf_counter() - started, "gains": dataclasses.asdict(gains),
           "path_largest_torque_Nm": {prog.mj_model.actuator(j).name: float(np.abs(path.torque[:, j]).max())
                                      for j in range(len(prog.layout.qvel))}, **figures}
    for impulse in ((0.0, args.push_impulse) if args.push_batch else ()):
        started = time.perf_counter()
        trial = push_trial(prog, arrays, args.push_batch, impulse, 4.0 + 4 * float(gait.step_time) + 4.0)
        row[f"push_{impulse:g}Ns"] = trial
        print(f"pushed at {impulse} N s each way: {trial['success_rate']:.2f} of {args.push_batch} stay up "
              f"({time.perf_counter() - started:.0f} s)", flush=True)
    print(json.dumps({k: v for k, v in row.items() if not isinstance(v, (dict, list))}, indent=1), flush=True)
    save_results(args.name or f"humanoid_feedforward_{args.model}", {"model": args.model, "tune": args.tune},
                 [row], args.out)


if __name__ == "__main__":
    main()
