"""The 3D walk on the optimal gait itself: the humanoid's own inverse dynamics along the sagittal optimum
as feed-forward, phased by the stance angle, the foot-placement walker's lateral law beside it.

The law (:data:`LAW`, a :class:`biped_jax.humanoid.walk3d.Law`), per physics step, leg l or r standing:

- **Path and feed-forward** (:func:`path_3d`). The study's optimal step is put on the 3D humanoid with leg l
  standing, its foot flat and still, the swing foot level and lifted to ``clearance`` mid-step
  (:func:`biped_jax.humanoid.reference.clearance_offset`), the pelvis swaying over the stance foot as a
  linear inverted pendulum, the feet kept level and in place (:func:`lateral_sway`): every degree of
  freedom's position, velocity and acceleration on the gait's own grid. Floating-base inverse dynamics of
  the walk's model with the stance foot's wrench alone moving the base
  (:func:`biped_jax.humanoid.free_base.single_support`) give the joint torques that make the humanoid
  itself follow it: its feet, arms and the gearheads' reflected inertia, which the planar optimum does not
  carry, included.
- **Phase.** s in [0, 1] from the stance angle theta = torso pitch + stance hip + stance knee, mapped from
  [theta at touchdown, theta at the step's end] onto the optimal step's (hybrid-zero-dynamics phasing,
  :func:`biped_jax.humanoid.controller.phase_of`): the legs follow the stance leg's progress, not a clock.
- **Sagittal joints.** Hip pitch, knee and ankle pitch of both legs: feed-forward(s) + PD to the path(s),
  the offsets at touchdown fading out over ``fade`` of the step, except the stance hip, which holds the
  torso's pitch on the path's (and takes back the swing hip's feedback, so the swing leg does not tip the
  torso), and the swing ankle, which keeps its foot level in the world as the path does (a foot tilted by
  the leg's tracking error scuffs the ground at the path's few millimetres of clearance); the stance ankle
  adds ``ankle_w`` (theta_dot_ref(s) - theta_dot), clipped to :data:`ANKLE_FEEDBACK_LIMIT`; the swing hip's
  target moves ``place`` rad per m/s of pelvis speed above the path's, late in the swing.
- **Lateral, yaw, arms**: the walker's law (:func:`biped_jax.humanoid.walker.control`: hip roll by the foot
  placement's lateral term, torso roll and yaw through the stance hip, ankle roll keeping the foot level),
  with its numbers for the swaying path (:data:`LATERAL`), plus the path's hip- and ankle-roll torques and
  ``yaw_ff`` of its hip-yaw torques as feed-forward (mirrored when leg r stands; without the yaw's the 12 kg
  walk settles 0.1 rad off its heading and drifts sideways).
- **Impact**: the sagittal joints' and the torso's damping ramp in over ``impact`` s after a touchdown (the
  touchdown is declared a millimetre before the impact, when the legs still move at their pre-impact rates).
- **Touchdown**: the swing sole within 1 mm of the ground after s = :data:`TOUCHDOWN_PHASE`, the swing foot
  :data:`TOUCHDOWN_AHEAD` ahead of the stance foot and :data:`SHORTEST_STEP` of the step time after the
  last touchdown.

The walk runs on :data:`DRIVES`: the recommended drive at every joint, two at each hip roll (standing on
one leg the 12 kg robot's hip roll needs 7.9 N m, the GP 32 A gives 6.5; with one drive the 12 kg walk
falls within a second). Angles in rad, lengths in m, SI throughout.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from biped_jax.humanoid import controller, free_base, reference, walk3d, walker

#: A leg's sagittal joints in :data:`biped_jax.humanoid.free_base.LEG_JOINTS`: hip pitch, knee, ankle pitch.
SAGITTAL = (2, 3, 4)
#: Largest torque of the stance ankle's phase-rate feedback, N m.
ANKLE_FEEDBACK_LIMIT = 3.0
#: Touchdown: earliest phase, how far the swing foot must be ahead of the stance foot (m), and the
#: shortest step as a share of the gait's step time.
TOUCHDOWN_PHASE, TOUCHDOWN_AHEAD, SHORTEST_STEP = 0.9, 0.05, 0.5
#: The leg joints on two drives in parallel (both mass classes).
DRIVES = ("hip_roll",)
#: A leg's roll joints in :data:`biped_jax.humanoid.free_base.LEG_JOINTS`: hip roll, ankle roll.
ROLLS = (1, 5)
#: A leg's hip yaw in :data:`biped_jax.humanoid.free_base.LEG_JOINTS`.
HIP_YAW = 0


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Gains:
    """The law's gains (N m/rad, N m s/rad unless said): stance knee (kp, kd), swing leg (kp_sw, kd_sw),
    torso pitch through the stance hip (kp_t, kd_t), ankles' pitch (kp_a, kd_a), ankle_w (N m s/rad on
    the stance angle's rate), place (rad of swing hip per m/s), fade (share of the step over which the
    touchdown's offsets fade), yaw_ff (the share of the path's hip-yaw torques fed forward, 0-1), impact
    (s after a touchdown over which the sagittal joints' and the torso's damping ramp in from zero, 0: none),
    impact_kp (the share of the stance knee's kp that ramps in with the damping, 0-1; 0: all of it at once),
    impact_kp_t (the same for the torso's kp_t)."""

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
    yaw_ff: float = 0.0
    impact: float = 0.0
    impact_kp: float = 0.0
    impact_kp_t: float = 0.0

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if isinstance(value, (int, float)) and not np.isfinite(value):
                raise ValueError(f"Gains.{field.name} must be finite, got {value!r}")
        if isinstance(self.fade, (int, float)) and not 0.0 < self.fade <= 1.0:
            raise ValueError(f"Gains.fade must be in (0, 1], got {self.fade!r}")
        if isinstance(self.impact, (int, float)) and self.impact < 0.0:
            raise ValueError(f"Gains.impact must be at least 0 s, got {self.impact!r}")
        for name in ("impact_kp", "impact_kp_t"):
            value = getattr(self, name)
            if isinstance(value, (int, float)) and not 0.0 <= value <= 1.0:
                raise ValueError(f"Gains.{name} must be in [0, 1], got {value!r}")


#: Each model's gains, tuned by CMA-ES over batched walks on its optimal gait (``python
#: benchmarks/humanoid_feedforward.py --tune``; the runs in benchmarks/RESULTS.md): M2 by ``--tune 12`` from
#: :data:`START`, then ``--tune 12 --lift-weight 20``, then ``--tune 10 --tune-starts 4 --lift-weight 20``
#: (the nominal start and three disturbed ones) with the swing foot kept level; M4 the same, then on the
#: swaying path with its :data:`LATERAL` numbers ``--tune 10 --tune-starts 4 --lift-weight 20
#: --excess-weight 2 --speed-weight 10``, and once more so (on another run of ``biped-jax reproduce``, whose
#: M4 gait the earlier gains walked only three steps from the nominal start), then twice more so with the torque
#: beyond the drive's line weighed ten times as much (``--excess-weight 20``: its largest command 6.8 -> 6.3
#: times the line, 4.6 -> 3.9 % of the samples beyond it). M2's ``impact`` was chosen from
#: walks at 0.01-0.07 s (its largest command fell from 7.6 to 2.7 times the drive's line); M4 has none (its
#: earlier gains with the damping ramped over 40 ms fell at the eleventh step). M2 walks the step of
#: :data:`biped_jax.studies.humanoid.WALK_GAITS` (the clearance and a soft landing in the gait problem):
#: its gains were tuned on it twice from the ones before (``--gait-clearance 0.01 --clearance 0 --tune 10
#: --tune-starts 4 --lift-weight 20 --excess-weight 2 --speed-weight 10``, first without the landing's bound,
#: then with ``--touchdown-speed 1.2``), then once more with its stance knee's stiffness ramped in over the
#: impact (``impact_kp`` 1: its largest command fell from 2.9 to 2.4 times the line on the same gains, 2.2
#: retuned).
TUNED = {
    "M2": Gains(kp=378.0145453961894, kd=3.9485102545840536, kp_sw=96.9881032774285, kd_sw=6.273364504660348,
                kp_t=350.30436016502955, kd_t=20.286907314240104, kp_a=41.96809411240331, kd_a=3.116068227677931,
                ankle_w=-12.88118615898178, place=-0.6723933251272604, fade=0.45734523059258714, yaw_ff=1.0,
                impact=0.04, impact_kp=1.0),
    "M4": Gains(kp=346.5380708583762, kd=0.1656910718633509, kp_sw=164.16071382807738, kd_sw=1.1394311582242076,
                kp_t=321.37475218964045, kd_t=7.9050472791261, kp_a=79.19917467853156, kd_a=2.477644298917071,
                ankle_w=-14.780604555339927, place=0.5045455996383155, fade=0.48815982403266905),
}
#: Each model's numbers of the lateral law for the swaying path (:class:`biped_jax.humanoid.walker.WalkerParams`
#: fields over :func:`biped_jax.studies.humanoid.walk_params`'s), tuned by CMA-ES from :data:`LATERAL_START`
#: over walks of 6 s from the nominal start and three disturbed ones (``python
#: benchmarks/humanoid_feedforward.py --tune-lateral``; the runs in benchmarks/RESULTS.md).
LATERAL = {
    "M2": {"lateral_gain": 0.1200, "width": 0.05346, "kp_torso": 27.22, "kd_torso": 11.68, "roll_push": 0.2019,
           "kp_swing": 23.55, "kd_swing": 1.846, "roll_lean": -0.01442},
    "M4": {"lateral_gain": 0.05073, "width": 0.06609, "kp_torso": 108.7, "kd_torso": 6.147, "roll_push": 0.6196,
           "kp_swing": 42.69, "kd_swing": 1.021, "roll_lean": 0.01881},
}
#: The lateral numbers under :data:`LATERAL`'s, and a model's without tuned ones: the walker's, its step on
#: the hip's line (the path's width), no lean into the stance and no sideways speed at the start beyond the
#: path's (the sway carries the pelvis).
LATERAL_START = {"width": 0.065, "roll_lean": 0.0, "side_speed": 0.0}
#: The gains of a model without tuned ones: a hand-tuned set (unclipped walks of M2), the tuner's start.
START = Gains(kp=515.7, kd=0.48, kp_sw=230.4, kd_sw=6.40, kp_t=388.8, kd_t=14.66, kp_a=68.6, kd_a=3.00,
              ankle_w=-9.39, place=-0.046, fade=0.339)


def gains_for(name: str) -> Gains:
    """:data:`TUNED` gains of the paper's model ``name``, else :data:`START`."""
    return TUNED.get(name, START)


def lateral_for(name: str) -> dict:
    """:data:`LATERAL` numbers of the paper's model ``name`` over :data:`LATERAL_START`."""
    return {**LATERAL_START, **LATERAL.get(name, {})}


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Path3D:
    """The optimal step on the 3D humanoid, leg l standing, on the gait's grid (S samples).

    Attributes:
      phase: (S,), increasing from 0 to 1. qpos: (S, nq), m and rad, the stance foot's body at x = 0.
      qvel: (S, nv). torque: the inverse dynamics' joint torques in actuator order, (S, 16), N m.
      pitch: the torso's, (S,), rad.
    """

    phase: jax.Array
    qpos: jax.Array
    qvel: jax.Array
    torque: jax.Array
    pitch: jax.Array


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class TrackerArgs:
    """The law's parameters: gains, the path, the gait (its stance angle by phase) and the walker's
    parameters of the lateral law (:class:`biped_jax.humanoid.walker.WalkerParams`)."""

    gains: Gains
    path: Path3D
    gait: reference.GaitReference
    params: walker.WalkerParams


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Track:
    """What the law keeps from the last touchdown: the stance angle then (rad) and the sagittal joints'
    offsets from the path's start (stance hip, knee, ankle, swing hip, knee, ankle), (6,), rad."""

    stance_angle: jax.Array
    offset: jax.Array


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class TrackerState:
    """The law's state: the walker's memory (support, time since touchdown, feet) and the track."""

    memory: walker.WalkerMemory
    track: Track

    @property
    def stance(self) -> jax.Array:
        return self.memory.stance


def path_3d(prog: walk3d.Program, model, trajectory, mass_class: str,
            clearance: float = reference.SWING_CLEARANCE) -> Path3D:
    """The optimal step (``trajectory`` of the gait ``model``, :func:`biped_jax.gait.problem.simulate`) on
    the humanoid of ``prog``: the gait's states on its grid, the swing foot lifted to ``clearance`` m, the
    pelvis swaying over the stance foot (:func:`lateral_sway`), the stance foot flat and still,
    accelerations by differences of the velocities, then the inverse dynamics (MuJoCo C)."""
    m, layout = prog.mj_model, prog.layout
    t, q, qd = (np.asarray(a) for a in (trajectory.t, trajectory.q, trajectory.qd))
    phase = t / t[-1]
    order = [2, 1, 3, 4]  # (H1, K1, H2, K2) in the pinned chain's coordinates; q[:, 0] the stance angle
    lift = reference.clearance_offset(model, q, phase, phase, mass_class, clearance)
    joints, rates = q[:, order] + lift, qd[:, order] + np.gradient(lift, t, axis=0)
    pitch = q[:, 0] - joints[:, 0] - joints[:, 1]
    pitch_rate = qd[:, 0] - rates[:, 0] - rates[:, 1]
    qpos, qvel = np.tile(m.qpos0, (len(t), 1)), np.zeros((len(t), m.nv))
    qpos[:, :3] = 0.0
    qpos[:, 3:7] = np.column_stack([np.cos(pitch / 2), 0 * pitch, np.sin(pitch / 2), 0 * pitch])
    qvel[:, 4] = pitch_rate
    for leg, (h, k), (hd, kd) in ((layout.legs[0], joints[:, :2].T, rates[:, :2].T),
                                  (layout.legs[1], joints[:, 2:].T, rates[:, 2:].T)):
        # hip, knee, and the ankle that keeps the foot level
        for joint, angle, rate in zip(SAGITTAL, (h, k, -(pitch + h + k)), (hd, kd, -(pitch_rate + hd + kd))):
            qpos[:, layout.qpos[leg[joint]]], qvel[:, layout.qvel[leg[joint]]] = angle, rate
    qpos, qvel = lateral_sway(prog, qpos, qvel, t)
    qpos, qvel = planted(prog, qpos, qvel)
    held = free_base.single_support(m)
    torque = np.stack([held(p, 0, v, a) for p, v, a in zip(qpos, qvel, np.gradient(qvel, t, axis=0))])
    return Path3D(*(jnp.asarray(a) for a in (phase, qpos, qvel, torque, pitch)))


def path_drive_ratio(prog: walk3d.Program, path: Path3D) -> np.ndarray:
    """The path's own torques (its inverse dynamics, the feed-forward) over what the drives of ``prog`` give
    at the path's joint speeds, (S, 16) (:func:`biped_jax.humanoid.walk3d.drive_ratio`): above 1 the path
    itself asks more than the drive's line, whatever the feedback does."""
    speed = np.asarray(path.qvel)[:, list(prog.layout.qvel)]
    return walk3d.drive_ratio(prog.drives, np.asarray(path.torque), speed)


def planted(prog: walk3d.Program, qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(qpos, qvel), (S, nq) and (S, nv), with the free base moved so that foot l stands still under its hip
    (x = 0, y = the hip's offset) with its sole on the ground: the base's position and linear velocity
    replaced, the joints' kept. The foot must be level at every sample (its angular velocity is then zero)."""
    m, foot = prog.mj_model, prog.layout.feet[0]
    qpos, qvel = qpos.copy(), qvel.copy()
    data = mujoco.MjData(m)
    for i in range(len(qpos)):
        data.qpos[:] = qpos[i]
        mujoco.mj_kinematics(m, data)
        qpos[i, :3] -= data.xpos[foot] - [0.0, prog.legs.hip_y, 0.0]
        data.qpos[:] = qpos[i]
        mujoco.mj_kinematics(m, data)
        mujoco.mj_comPos(m, data)  # the Jacobian below reads cdof and subtree_com
        jacobian = np.zeros((3, m.nv))
        mujoco.mj_jacBody(m, data, jacobian, None, foot)
        qvel[i, :3] = -(jacobian[:, 3:] @ qvel[i, 3:])  # the stance foot still (the free joint's columns: I)
    qpos[:, 2] -= float(walker.sole_heights(prog.legs, data)[0])  # foot level: its sole's height is the same at all
    return qpos, qvel


def sway_offset(t: np.ndarray, step_time: float, offset: float, com_height: float, gravity: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """The pelvis's lateral offset toward the stance foot and its rate, (S,) each, m and m/s, at times ``t``
    (s, in [0, ``step_time``]): a linear inverted pendulum over the stance foot's centre, periodic and
    symmetric over the step, y(t) = c (1 - cosh(w (t - T/2)) / cosh(w T/2)) with c = ``offset`` (the hip's
    offset from the centre line: y = 0 at both ends, on the centre line, and y = c where the pendulum would
    stand on the foot) and w = sqrt(g / z), z the centre of mass's height."""
    omega, half = np.sqrt(gravity / com_height), step_time / 2
    scale = offset / np.cosh(omega * half)
    return offset - scale * np.cosh(omega * (t - half)), -scale * omega * np.sinh(omega * (t - half))


#: Newton's iterations of the legs' inverse kinematics in :func:`lateral_sway` (it converges in three or four).
SWAY_ITERATIONS = 10


def lateral_sway(prog: walk3d.Program, qpos: np.ndarray, qvel: np.ndarray, t: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The path (qpos (S, nq), qvel (S, nv) at times ``t`` (S,), s; the pelvis on the centre line, the feet
    level) with the pelvis swaying toward the stance foot (l, +y) by :func:`sway_offset` (the centre of mass's
    height over the sole mid-step): each leg's joints but the knee solved (Newton on MuJoCo's Jacobians) so
    that its foot keeps its forward and lateral place and stays level while the pelvis moves sideways, their
    rates from the same Jacobians, so that the feet's horizontal velocities relative to the pelvis are the
    path's less the sway's. The base's position and linear velocity are left for :func:`planted`. Without
    the sway the stance foot's centre of pressure lies beyond the foot's inner edge through the stance
    (docs/studies.md)."""
    m, layout = prog.mj_model, prog.layout
    qpos, qvel = qpos.copy(), qvel.copy()
    qvel[:, :3] = 0.0  # the feet's velocities below are relative to the pelvis
    data = mujoco.MjData(m)
    data.qpos[:] = qpos[len(t) // 2]
    mujoco.mj_kinematics(m, data)
    mujoco.mj_comPos(m, data)
    height = float(data.subtree_com[0][2] - walker.sole_heights(prog.legs, data)[0])
    y, rate = sway_offset(t, float(t[-1]), prog.legs.hip_y, height, -float(m.opt.gravity[2]))
    jacobian = np.zeros((6, m.nv))

    def foot_jacobian(i, foot):
        data.qpos[:] = qpos[i]
        mujoco.mj_kinematics(m, data)
        mujoco.mj_comPos(m, data)  # mj_jacBody reads cdof and subtree_com
        mujoco.mj_jacBody(m, data, jacobian[:3], jacobian[3:], foot)
        return data.xpos[foot] - data.xpos[layout.torso], data.xmat[foot].reshape(3, 3)

    # The knees keep the path's angles and each foot's height relative to the pelvis is left free: near the
    # straight knee the pelvis cannot move sideways at its height (the leg would have to lengthen by
    # y^2 / 2 l, 0.6 mm at 2 cm); it drops by that much instead. The other five joints hold the foot's
    # forward and lateral place and its level.
    rows = [0, 1, 3, 4, 5]
    for i in range(len(t)):
        for side, foot in enumerate(layout.feet):
            moved = [j for k, j in enumerate(layout.legs[side]) if free_base.LEG_JOINTS[k] != "knee"]
            joints, dofs = [layout.qpos[j] for j in moved], [layout.qvel[j] for j in moved]
            place, _ = foot_jacobian(i, foot)
            place, velocity = place - [0.0, y[i], 0.0], jacobian[:3] @ qvel[i] - [0.0, rate[i], 0.0]
            for _ in range(SWAY_ITERATIONS):
                now, rotation = foot_jacobian(i, foot)
                tilt = 0.5 * np.array([rotation[1, 2] - rotation[2, 1], rotation[2, 0] - rotation[0, 2],
                                       rotation[0, 1] - rotation[1, 0]])  # the rotation back to level
                error = np.concatenate([place - now, tilt])[rows]
                if np.max(np.abs(error)) < 1e-13:
                    break  # the Jacobian is the converged pose's
                qpos[i, joints] += np.linalg.solve(jacobian[np.ix_(rows, dofs)], error)
            else:
                foot_jacobian(i, foot)
            wanted = np.concatenate([velocity, np.zeros(3)]) - jacobian @ qvel[i]
            qvel[i, dofs] += np.linalg.solve(jacobian[np.ix_(rows, dofs)], wanted[rows])
    return qpos, qvel


def at_phase(path: Path3D, s) -> Path3D:
    """Every field of ``path`` at phase ``s`` (linear between samples, held beyond the ends): one search
    for all of them."""
    i = jnp.clip(jnp.searchsorted(path.phase, s), 1, path.phase.shape[0] - 1)
    w = jnp.clip((s - path.phase[i - 1]) / (path.phase[i] - path.phase[i - 1]), 0.0, 1.0)
    return jax.tree.map(lambda column: column[i - 1] + w * (column[i] - column[i - 1]), path)


def control(args: TrackerArgs, prog: walk3d.Program, data, state: TrackerState):
    """Every actuator's command (16,), N m, and the phase s, at MJX ``data``."""
    gains, gait, layout, track = args.gains, args.gait, prog.layout, state.track
    q, qd = data.qpos[jnp.asarray(layout.qpos)], data.qvel[jnp.asarray(layout.qvel)]
    rotation = data.xmat[layout.torso]
    pitch, pitch_rate = walker.torso_angles(rotation)[1], (rotation @ data.qvel[3:6])[1]
    legs = jnp.asarray(layout.legs)
    stance, swing = legs[state.stance], legs[1 - state.stance]
    theta = pitch + q[stance[2]] + q[stance[3]]
    s = controller.phase_of(gait, controller.Support(state.stance, track.stance_angle, track.offset), theta)
    now = at_phase(args.path, s)
    fade = jnp.maximum(1.0 - s / gains.fade, 0.0) ** 3
    # the touchdown is declared with the foot a millimetre up, before the impact: the path's velocities are
    # already the post-impact ones, the legs' still the pre-impact ones, and full damping on that difference
    # asked up to 50 N m of the 12 kg robot's knee for the impact's few milliseconds (7x its drive's line)
    damped = jnp.where(gains.impact > 0.0, jnp.clip(state.memory.time / jnp.maximum(gains.impact, 1e-9), 0.0, 1.0), 1.0)
    ramped = lambda share: 1.0 - share * (1.0 - damped)  # noqa: E731  (a gain's ``share`` ramped in with the damping)
    place = -gains.place * (data.qvel[0] - now.qvel[0]) * s * s
    # the walker's law for roll, yaw and arms; its sagittal terms are overwritten below (and dropped by XLA)
    command = walker.control(args.params, layout, prog.legs, data, state.memory)
    feedback = {}
    for side, leg, (kp, kd) in ((0, stance, (gains.kp, gains.kd)), (1, swing, (gains.kp_sw, gains.kd_sw))):
        for k, joint in enumerate(SAGITTAL):
            j = layout.legs[side][joint]  # the path's joint (leg l standing)
            p, d = (gains.kp_a, gains.kd_a) if joint == 4 else (kp, kd)
            if side == 0 and joint == 2:
                p = d = 0.0  # the stance hip holds the torso instead
            if side == 0 and joint == 3:
                # the landing knee yields to the impact's velocity jump instead of springing back from it
                p = p * ramped(gains.impact_kp)
            target = now.qpos[layout.qpos[j]] + fade * track.offset[3 * side + k] \
                + (place if side == 1 and joint == 2 else 0.0)
            rate = now.qvel[layout.qvel[j]]
            if side == 1 and joint == 4:  # the swing foot level in the world, as on the path, whatever the leg
                target = -(pitch + q[leg[2]] + q[leg[3]])
                rate = -(pitch_rate + qd[leg[2]] + qd[leg[3]])
            feedback[side, joint] = p * (target - q[leg[joint]]) + damped * d * (rate - qd[leg[joint]])
            command = command.at[leg[joint]].set(now.torque[j] + feedback[side, joint])
    torso = (gains.kp_t * ramped(gains.impact_kp_t) * (now.pitch - pitch)
             - damped * gains.kd_t * (pitch_rate - now.qvel[4]))
    command = command.at[stance[2]].add(-torso - feedback[1, 2])
    theta_rate = pitch_rate + qd[stance[2]] + qd[stance[3]]
    pace = jnp.interp(s, gait.phase, gait.stance_angle_slope) / gait.step_time - theta_rate
    command = command.at[stance[4]].add(jnp.clip(gains.ankle_w * pace, -ANKLE_FEEDBACK_LIMIT, ANKLE_FEEDBACK_LIMIT))
    # the path's roll (and yaw_ff of its hip-yaw) torques on top of the lateral law, mirrored (sign flipped)
    # when leg r stands
    mirror = jnp.where(state.stance == 0, 1.0, -1.0)
    for side, leg in ((0, stance), (1, swing)):
        for joint, share in ((ROLLS[0], 1.0), (ROLLS[1], 1.0), (HIP_YAW, gains.yaw_ff)):
            command = command.at[leg[joint]].add(share * mirror * now.torque[layout.legs[side][joint]])
    return command, s


def track_after(args: TrackerArgs, prog: walk3d.Program, data, stance) -> Track:
    """The track when leg ``stance`` has just landed, at MJX ``data``."""
    layout = prog.layout
    q = data.qpos[jnp.asarray(layout.qpos)]
    legs, sagittal = jnp.asarray(layout.legs), jnp.asarray(SAGITTAL)
    now = jnp.concatenate([q[legs[stance][sagittal]], q[legs[1 - stance][sagittal]]])
    start = args.path.qpos[0, jnp.asarray([layout.qpos[layout.legs[side][joint]] for side in (0, 1)
                                           for joint in SAGITTAL])]
    theta = walker.torso_angles(data.xmat[layout.torso])[1] + now[0] + now[1]
    # keep a usable phase range where the robot lands far off the path
    return Track(stance_angle=jnp.minimum(theta, args.gait.stance_angle[-1] - 0.1), offset=now - start)


def remember(args: TrackerArgs, prog: walk3d.Program, data, state: TrackerState, s, timestep: float
             ) -> TrackerState:
    """The state after the physics step that ended at MJX ``data``: the legs swap at a touchdown (the module's
    rule), the track restarts there. (The track at touchdown is worked out every step and kept only then: a
    ``cond`` under ``vmap`` computes both branches anyway.)"""
    layout, memory = prog.layout, state.memory
    feet = data.xpos[jnp.asarray(layout.feet)]
    landed = ((walker.sole_heights(prog.legs, data)[1 - memory.stance] < walker.TOUCHDOWN_HEIGHT)
              & (s > TOUCHDOWN_PHASE) & (memory.time > SHORTEST_STEP * args.gait.step_time)
              & (feet[1 - memory.stance, 0] - feet[memory.stance, 0] > TOUCHDOWN_AHEAD))
    new = walker.after_step(layout, data, memory, landed, timestep)
    track = jax.tree.map(lambda a, b: jnp.where(landed, a, b), track_after(args, prog, data, new.stance), state.track)
    return TrackerState(new, track)


#: The tracker as a walking law (args: :class:`TrackerArgs`, state: :class:`TrackerState`).
LAW = walk3d.Law("tracker", control, remember)


def start_state(path: Path3D, params: walker.WalkerParams) -> tuple[np.ndarray, np.ndarray]:
    """(qpos, qvel) on the gait just after a touchdown, leg l standing, the pelvis also moving toward it
    sideways at ``params.side_speed`` (the lateral law's start)."""
    qpos, qvel = np.asarray(path.qpos[0]).copy(), np.asarray(path.qvel[0]).copy()
    qvel[1] += float(params.side_speed)
    return qpos, qvel


def start(prog: walk3d.Program, args: TrackerArgs, qpos: np.ndarray | None = None,
          qvel: np.ndarray | None = None) -> tuple:
    """(MJX data, :class:`TrackerState`) at ``qpos``, ``qvel`` (default :func:`start_state`), leg l standing."""
    if qpos is None or qvel is None:
        qpos, qvel = start_state(args.path, args.params)
    data, memory = walk3d.initial(prog, args.params, qpos, qvel)
    return data, TrackerState(memory, track_after(args, prog, data, jnp.asarray(0)))
