"""The 3D walking controller of the free-base humanoid: foot placement, torso attitude through the stance
hip, a timed swing; traceable, batched with ``vmap``.

One step is one stance phase of fixed duration T (the optimal gait's step time); both feet are flat boxes
(:mod:`biped_jax.humanoid.free_base`). The law, per physics step:

- **Foot placement** (Raibert's rule with the capture point's lateral term): the swing foot lands
  ``forward_gain v + speed_gain (v - v_des)`` ahead of the pelvis and ``width + lateral_gain v_y``
  beside it (m, world axes, v the pelvis velocity in m/s). Re-evaluated every physics step until
  touchdown: that continuous feedback is what balances the robot, sideways as much as forward.
- **Double support**: for ``transfer`` s after a touchdown both feet stay down and the torso's torque
  (below) moves from the leg that leaves support to the landed one (one hip holding the landing's
  transient alone saturated its drive).
- **Swing foot**: then from its lift-off point to the landing point on a smoothstep in the plane and a sin^2
  lift of ``clearance`` that returns to the ground at T (then 10 mm below it, so a late step still lands);
  the hip roll, hip pitch and knee follow the leg's inverse kinematics (thigh and shank lengths from the
  model) by PD; the ankle keeps the foot level in the world, so it lands flat.
- **Torso** (SIMBICON, Yin, Loken and van de Panne 2007): the torso's roll, pitch and yaw are held by PD
  in the world frame, through the stance hip: stance hip torque = - torso torque - swing hip torque, per
  axis (in double support the two hips share the torso's torque). The pitch target ``lean`` leans the
  torso forward; the roll target leans it over the stance foot by ``roll_lean``.
- **Stance leg**: the knee by PD to ``stance_knee``; the ankle keeps the foot level (pitch, roll) plus
  constant torques ``push`` (pitch) and ``roll_push`` (roll), and ``push_off`` late in the step.
- **Arms**: held at zero.
- **Touchdown**: the swing foot's sole is within 1 mm of the ground after ``0.95 T``; the legs swap.

Every torque is then clipped to the drive's speed-torque line by the caller
(:func:`biped_jax.humanoid.free_base.drive_torques`). Angles in rad, lengths in m, SI throughout.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from biped_jax.humanoid import free_base
from biped_jax.humanoid.free_base import FreeLayout

#: The swing foot counts as landed when its lowest corner is this close to the ground, m.
TOUCHDOWN_HEIGHT = 1e-3
#: Share of the step before which a touch of the swing foot does not end the step.
EARLIEST_TOUCHDOWN = 0.95
#: How far below the ground the swing foot is aimed once its step time is up, m.
LATE_DEPTH = 0.01
#: Share of the step over which the stance ankle pushes off (``WalkerParams.push_off``).
PUSH_OFF_SHARE = 0.3
#: Arm hold: stiffness (N m/rad), damping (N m s/rad).
ARM_GAINS = (10.0, 0.3)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class WalkerParams:
    """The controller's parameters (scalars or, batched, arrays with a leading batch axis). The defaults
    walk the 12 kg humanoid at the M2 gait's step time: tuned by CMA-ES over batched MJX walks (``python
    benchmarks/humanoid_tune.py``; the run in benchmarks/results/humanoid_tune_12kg_cpu.json).

    Attributes:
      step_time: T, s. speed: v_des after the ramp, m/s. ramp: time over which v_des rises from 0, s.
      clearance: swing foot lift, m. forward_gain, speed_gain: s (foot ahead of the pelvis per m/s of
      speed and of speed error). forward_offset: m. lateral_gain: s. width: foot from the pelvis's
      centre line, m. swing_end: share of T at which the foot reaches its landing point in the plane.
      stance_knee: rad. lean: torso pitch target, rad (forward +). push: stance ankle pitch torque, N m.
      roll_lean: torso roll toward the stance side, rad. roll_push: the stance ankle's roll torque times
      the swing side's sign (+1 for l), N m. kp_*, kd_*: PD gains, N m/rad and N m s/rad (swing leg,
      torso, knees, ankles, yaw).
      side_speed: the pelvis's lateral speed at the start, toward the first stance foot, m/s.
      settle: time over which the landed leg's knee target moves from its touchdown angle to
      ``stance_knee``, s (a jump in the target at touchdown makes the foot rebound).
      transfer: time after touchdown over which the torso's torque moves from the leg that just left
      support to the landed one, s (the landing's transient, held by one hip, saturates its drive).
      push_off: the stance ankle's extra pitch torque over the step's last :data:`PUSH_OFF_SHARE`, rising
      linearly to this value at T, N m (energy put in before the landing instead of lost in it).
    """

    step_time: float = 0.36
    speed: float = 0.555
    ramp: float = 1.5
    clearance: float = 0.0367
    forward_gain: float = 0.1005
    speed_gain: float = 0.0297
    forward_offset: float = 0.0009
    lateral_gain: float = 0.0625
    width: float = 0.0522
    swing_end: float = 0.8081
    stance_knee: float = 0.3603
    lean: float = 0.0503
    push: float = -1.098
    roll_lean: float = 0.0555
    roll_push: float = 0.8404
    kp_swing: float = 40.2306
    kd_swing: float = 1.2652
    kp_torso: float = 102.1231
    kd_torso: float = 9.065
    kp_knee: float = 71.3053
    kd_knee: float = 1.4785
    kp_ankle: float = 42.0149
    kd_ankle: float = 0.578
    kp_yaw: float = 31.9493
    kd_yaw: float = 0.5
    side_speed: float = 0.2368
    settle: float = 0.0334
    transfer: float = 1e-3
    push_off: float = 0.0

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if isinstance(value, (int, float)) and not np.isfinite(value):
                raise ValueError(f"WalkerParams.{field.name} must be finite, got {value!r}")
        for name in ("step_time", "ramp", "settle", "transfer"):
            value = getattr(self, name)
            if isinstance(value, (int, float)) and value <= 0:
                raise ValueError(f"WalkerParams.{name} must be positive, got {value!r} s")
        if isinstance(self.transfer, (int, float)) and isinstance(self.step_time, (int, float)) \
                and self.transfer >= self.step_time:
            raise ValueError(f"WalkerParams.transfer ({self.transfer!r} s) must be shorter than the step "
                             f"time ({self.step_time!r} s)")



#: The numbers tuned for the 18 kg robot (its hip rolls on two drives each, ``walk3d.PARALLEL_DRIVES``)
#: where they differ from the defaults (the 12 kg robot's): ``python benchmarks/humanoid_tune.py --model M4``,
#: the run in benchmarks/results/humanoid_tune_M4_cpu.json.
TUNED_18KG = {"clearance": 0.018, "forward_gain": 0.1058, "speed_gain": 0.0261, "forward_offset": 0.0015,
              "lateral_gain": 0.0819, "width": 0.05, "swing_end": 0.8532, "stance_knee": 0.2874,
              "lean": -0.0059, "push": -0.8065, "roll_lean": 0.0911, "roll_push": 0.6004, "kp_swing": 56.9186,
              "kd_swing": 0.9783, "kp_torso": 102.1298, "kd_torso": 8.3732, "kp_knee": 63.7813,
              "kd_knee": 1.435, "kp_ankle": 45.7295, "kd_ankle": 0.6521, "kp_yaw": 31.637,
              "side_speed": 0.2438, "settle": 0.0279, "transfer": 0.0082, "push_off": 0.2346}


#: Each mass class's tuned numbers where they differ from the defaults.
TUNED = {"12kg": {}, "18kg": TUNED_18KG}


def tuned(mass_class: str) -> WalkerParams:
    """The tuned controller of ``mass_class`` ('12kg': the defaults; '18kg': :data:`TUNED_18KG`)."""
    return WalkerParams(**TUNED[free_base.check_mass_class(mass_class)])


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class WalkerMemory:
    """What the controller keeps between physics steps.

    Attributes:
      stance: the supporting leg, 0 (l) or 1 (r). time: since the last touchdown, s.
      lift: the swing foot's body origin relative to the pelvis at lift-off, world axes, (3,), m.
      foot: the stance foot's body origin at its touchdown, (3,), m. steps: touchdowns so far.
      knee: the stance knee's angle at its touchdown, rad.
    """

    stance: jax.Array
    time: jax.Array
    lift: jax.Array
    foot: jax.Array
    steps: jax.Array
    knee: jax.Array


@dataclasses.dataclass(frozen=True)
class Legs:
    """The legs' geometry read from the model (static), m: each hip's offset from the pelvis's centre
    line, thigh and shank lengths, the ankle's height above the sole; the foot box's half sizes and geom
    ids (l, r)."""

    hip_y: float
    thigh: float
    shank: float
    sole: float
    half_foot: tuple[float, float, float]
    foot_geoms: tuple[int, int]

    @classmethod
    def of(cls, model: mujoco.MjModel) -> "Legs":
        foot = model.geom("foot_l")
        return cls(hip_y=float(model.body("thigh_l").pos[1]), thigh=float(-model.body("shank_l").pos[2]),
                   shank=float(-model.body("foot_l").pos[2]), sole=float(-foot.pos[2] + foot.size[2]),
                   half_foot=tuple(float(s) for s in foot.size),
                   foot_geoms=(int(model.geom("foot_l").id), int(model.geom("foot_r").id)))


def zyx_angles(r00, r10, r20, r21, r22, xp=jnp):
    """(roll, pitch, yaw), rad, Z-Y-X convention (pitch + leans the top forward, roll + tilts it toward -y),
    from the five entries of a rotation matrix they need (arrays of any shape, numpy with ``xp=np``)."""
    return xp.arctan2(r21, r22), xp.arctan2(-r20, xp.hypot(r21, r22)), xp.arctan2(r10, r00)


def torso_angles(rotation: jax.Array) -> jax.Array:
    """(roll, pitch, yaw) of a body rotation matrix (3, 3), rad (:func:`zyx_angles`)."""
    return jnp.stack(zyx_angles(rotation[0, 0], rotation[1, 0], rotation[2, 0], rotation[2, 1], rotation[2, 2]))


def leg_inverse_kinematics(legs: Legs, ankle: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(hip roll, hip pitch, knee), rad, that put the ankle at ``ankle`` (3,) from the hip, in the torso
    frame (the hip's yaw at zero); the knee bends forward (+), a leg too short is stretched straight."""
    x, y, z = ankle[0], ankle[1], ankle[2]
    roll = jnp.arctan2(y, -z)
    reach = jnp.hypot(y, z)
    cosine = (x * x + reach * reach - legs.thigh ** 2 - legs.shank ** 2) / (2 * legs.thigh * legs.shank)
    knee = jnp.arccos(jnp.clip(cosine, -1.0, 0.999))
    pitch = jnp.arctan2(-x, reach) - jnp.arctan2(legs.shank * jnp.sin(knee), legs.thigh + legs.shank * jnp.cos(knee))
    return roll, pitch, knee


def sole_heights(legs: Legs, data) -> jax.Array:
    """Height of each foot's lowest corner above the ground (l, r), (2,), m, at the kinematics of MJX
    ``data`` or of MuJoCo C's ``MjData`` (whose rotations are rows of 9)."""
    hx, hy, hz = legs.half_foot
    corners = jnp.asarray([[sx * hx, sy * hy, -hz] for sx in (-1, 1) for sy in (-1, 1)])
    return jnp.stack([jnp.min((data.geom_xpos[g] + corners @ jnp.reshape(data.geom_xmat[g], (3, 3)).T)[:, 2])
                      for g in legs.foot_geoms])


def desired_speed(params: WalkerParams, time) -> jax.Array:
    """v_des at ``time`` (s): the ramp from rest to ``params.speed``, m/s."""
    return params.speed * jnp.clip(time / params.ramp, 0.0, 1.0)


def landing_point(params: WalkerParams, side, velocity, time) -> jax.Array:
    """Where the swing foot (``side`` +1 for l, -1 for r) should land relative to the pelvis, (x, y), m."""
    return jnp.stack([params.forward_offset + params.forward_gain * velocity[0]
                      + params.speed_gain * (velocity[0] - desired_speed(params, time)),
                      side * params.width + params.lateral_gain * velocity[1]])


def control(params: WalkerParams, layout: FreeLayout, legs: Legs, data, memory: WalkerMemory) -> jax.Array:
    """Commanded torque of every actuator (16,), N m, at MJX ``data`` (its kinematics from the last
    ``mjx.step``); not yet clipped to the drives."""
    q, qd = data.qpos[jnp.asarray(layout.qpos)], data.qvel[jnp.asarray(layout.qvel)]
    rotation = data.xmat[layout.torso]
    angles = torso_angles(rotation)
    rate = rotation @ data.qvel[3:6]  # the torso's angular velocity, world frame
    pelvis, velocity = data.qpos[:3], data.qvel[:3]
    joints = jnp.asarray(layout.legs)
    stance, swing = joints[memory.stance], joints[1 - memory.stance]
    side = jnp.where(memory.stance == 1, 1.0, -1.0)  # the swing leg's side: +1 l, -1 r
    # the swing foot stays down while the landed leg takes the torso over (double support), then swings
    phase = jnp.maximum(memory.time - params.transfer, 0.0) / (params.step_time - params.transfer)
    # the swing ankle's target from the pelvis (world axes): the lift-off point blended into the landing
    # point in the plane, lifted off the ground and put back at T
    s = jnp.clip(phase / params.swing_end, 0.0, 1.0)
    blend = s * s * (3 - 2 * s)
    plane = (1 - blend) * memory.lift[:2] + blend * landing_point(params, side, velocity, data.time)
    height = (legs.sole + params.clearance * jnp.sin(jnp.pi * jnp.clip(phase, 0.0, 1.0)) ** 2
              - LATE_DEPTH * jnp.clip((phase - 1.0) / 0.1, 0.0, 1.0))
    ankle = rotation.T @ jnp.stack([plane[0], plane[1], height - pelvis[2]]) - jnp.stack([0.0, side * legs.hip_y, 0.0])
    roll, pitch, knee = leg_inverse_kinematics(legs, ankle)
    settled = jnp.clip(memory.time / params.settle, 0.0, 1.0)
    stance_knee = memory.knee + (params.stance_knee - memory.knee) * settled * settled * (3 - 2 * settled)
    pd = lambda kp, kd, target, joint: kp * (target - q[joint]) - kd * qd[joint]  # noqa: E731
    swing_yaw = pd(params.kp_yaw, params.kd_yaw, 0.0, swing[0])
    swing_roll = pd(params.kp_swing, params.kd_swing, roll, swing[1])
    swing_pitch = pd(params.kp_swing, params.kd_swing, pitch, swing[2])
    torso_roll = params.kp_torso * (side * params.roll_lean - angles[0]) - params.kd_torso * rate[0]
    torso_pitch = params.kp_torso * (params.lean - angles[1]) - params.kd_torso * rate[1]
    torso_yaw = params.kp_yaw * (0.0 - angles[2]) - params.kd_yaw * rate[2]
    # the hips' torques on the torso add up to the torso's torque; the landed leg takes it over in ``transfer``
    share = jnp.clip(memory.time / params.transfer, 0.0, 1.0)
    torque = jnp.zeros(len(layout.qpos))
    torque = (torque.at[swing[0]].set(swing_yaw - (1 - share) * torso_yaw)
              .at[swing[1]].set(swing_roll - (1 - share) * torso_roll)
              .at[swing[2]].set(swing_pitch - (1 - share) * torso_pitch)
              .at[swing[3]].set(pd(params.kp_knee, params.kd_knee, knee, swing[3])))
    torque = (torque.at[stance[0]].set(-share * torso_yaw - swing_yaw)
              .at[stance[1]].set(-share * torso_roll - swing_roll)
              .at[stance[2]].set(-share * torso_pitch - swing_pitch)
              .at[stance[3]].set(pd(params.kp_knee, params.kd_knee, stance_knee, stance[3])))
    push_off = params.push_off * jnp.clip((memory.time / params.step_time - 1.0) / PUSH_OFF_SHARE + 1.0, 0.0, 1.0)
    for leg, push, roll_push in ((swing, 0.0, 0.0), (stance, params.push + push_off, side * params.roll_push)):
        foot_pitch = angles[1] + q[leg[2]] + q[leg[3]] + q[leg[4]]
        foot_roll = angles[0] + q[leg[1]] + q[leg[5]]
        torque = torque.at[leg[4]].set(params.kp_ankle * -foot_pitch - params.kd_ankle * qd[leg[4]] + push)
        torque = torque.at[leg[5]].set(params.kp_ankle * -foot_roll - params.kd_ankle * qd[leg[5]] + roll_push)
    arms = jnp.asarray(layout.arms)
    return torque.at[arms].set(-ARM_GAINS[0] * q[arms] - ARM_GAINS[1] * qd[arms])


def remember(params: WalkerParams, layout: FreeLayout, legs: Legs, data, memory: WalkerMemory, timestep: float
             ) -> WalkerMemory:
    """The memory after a physics step that ended at MJX ``data``: the legs swap when the swing foot has
    landed (its sole within :data:`TOUCHDOWN_HEIGHT` after :data:`EARLIEST_TOUCHDOWN` of T)."""
    soles = sole_heights(legs, data)
    landed = (soles[1 - memory.stance] < TOUCHDOWN_HEIGHT) & (memory.time > EARLIEST_TOUCHDOWN * params.step_time)
    return after_step(layout, data, memory, landed, timestep)


def after_step(layout: FreeLayout, data, memory: WalkerMemory, landed, timestep: float) -> WalkerMemory:
    """The memory after a physics step that ended at MJX ``data``: the legs swapped where ``landed`` (the
    swing foot's touchdown, as the caller's law decides it), else ``timestep`` s later."""
    swing = 1 - memory.stance
    feet = data.xpos[jnp.asarray(layout.feet)]
    swapped = WalkerMemory(stance=swing, time=jnp.zeros_like(memory.time), lift=feet[memory.stance] - data.qpos[:3],
                           foot=feet[swing], steps=memory.steps + 1,
                           knee=data.qpos[jnp.asarray(layout.qpos)][jnp.asarray(layout.legs)[swing, 3]])
    kept = dataclasses.replace(memory, time=memory.time + timestep)
    return jax.tree.map(lambda new, old: jnp.where(landed, new, old), swapped, kept)
