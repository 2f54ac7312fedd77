"""DONALD walking under contact in MJX: a statically stable heuristic gait through voltage-limited drives.

The paper's approach (Section 3): shift the pendulum mass over the support foot, tilt about the
support ankle to unload the other foot, swing it forward, set it down, move the pelvis forward over
it in double support, repeat. The hips are pitch joints and the ankles roll joints (robots.md), so
the legs and pelvis form a frame that is rigid in roll: in double support only the pendulum moves the
centre of mass sideways, and the ankle tilt that lifts the swing foot moves it further over the
support foot. The swing foot lands heel first (a kneeless leg ahead of the hip is pitched) and rolls
flat while the pelvis moves over it.

Every joint tracks its reference with a PD law whose torque is limited by the drive (RE 25 + GP 32 A
246:1): the motor torque at the current motor speed must lie under the speed-torque line at the
supply voltage (terminal voltage within +-V_s), and the output torque within the gear's intermittent
limit. The rotor and gear inertia enter as joint armature N^2 (J_rotor + J_gear).

Joint order of references, torques and drives: (ankle1, hip1, hip2, ankle2, pendulum), the
actuator order of ``models/donald.xml``. Angles in rad, torques in N m, time in s.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from biped_jax import drives, robots
from biped_jax.mjcf import DONALD_ACTUATED_JOINTS
from biped_jax.robot_specs import DonaldSpec

mjx = robots.import_mjx()

ANKLE1, HIP1, HIP2, ANKLE2, PENDULUM = range(5)
#: Supply voltage of DONALD's drives, V (ours: the paper gives none; the 24 V winding at its nominal).
DONALD_SUPPLY_VOLTAGE = 24.0
#: The motor: RE 25, 24 V winding (datasheet values).
DONALD_MOTOR = "RE25-118752"
#: The gear: GP 32 A, 4 stages, 245.96:1 (paper Table 7).
DONALD_GEAR = "GP32A-245.96"


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Drive:
    """A motor behind a gear at every actuated joint, in SI (a pytree: batchable).

    Attributes:
      ratio: N. efficiency: eta of the gear. torque_constant: k_t, N m/A. resistance: R, ohm.
      supply_voltage: V_s, V. gear_torque_limit: intermittent output torque, N m.
      reflected_inertia: N^2 (J_rotor + J_gear), kg m^2.
    """

    ratio: jax.Array
    efficiency: jax.Array
    torque_constant: jax.Array
    resistance: jax.Array
    supply_voltage: jax.Array
    gear_torque_limit: jax.Array
    reflected_inertia: jax.Array


def donald_drive(motor: str = DONALD_MOTOR, gear: str = DONALD_GEAR,
                 supply_voltage: float = DONALD_SUPPLY_VOLTAGE) -> Drive:
    """The drive of every DONALD joint from the catalogue; raises ValueError naming an unknown part."""
    catalogue = drives.load_catalogue()
    if motor not in catalogue.motors:
        raise ValueError(f"unknown motor {motor!r}; known: {', '.join(catalogue.motors)}")
    if gear not in catalogue.gearheads:
        raise ValueError(f"unknown gearhead {gear!r}; known: {', '.join(catalogue.gearheads)}")
    m, g = catalogue.motors[motor], catalogue.gearheads[gear]
    return Drive(ratio=jnp.asarray(g.ratio), efficiency=jnp.asarray(g.efficiency),
                 torque_constant=jnp.asarray(m.torque_constant), resistance=jnp.asarray(m.resistance),
                 supply_voltage=jnp.asarray(float(supply_voltage)),
                 gear_torque_limit=jnp.asarray(g.intermittent_torque),
                 reflected_inertia=jnp.asarray(g.ratio**2 * (m.rotor_inertia + g.inertia)))


def torque_limits(drive: Drive, joint_speed: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Lowest and highest joint torque the drive can give at ``joint_speed`` (rad/s), N m.

    Motor torque within k_t (+-V_s - k_t omega_m) / R (the speed-torque lines at +-V_s); through the
    gear with efficiency eta when the motor drives the load and 1/eta when the load drives the motor
    (eq. 2.3 inverted); clipped to the gear's intermittent output torque.
    """
    omega_m = drives.motor_speed(joint_speed, drive.ratio)
    back_emf = drive.torque_constant * omega_m
    motor_high = drive.torque_constant * (drive.supply_voltage - back_emf) / drive.resistance
    motor_low = drive.torque_constant * (-drive.supply_voltage - back_emf) / drive.resistance

    def to_joint(motor_torque):
        motoring = motor_torque * joint_speed >= 0
        factor = jnp.where(motoring, drive.efficiency, 1 / drive.efficiency)
        return motor_torque * drive.ratio * factor

    limit = drive.gear_torque_limit
    return jnp.clip(to_joint(motor_low), -limit, limit), jnp.clip(to_joint(motor_high), -limit, limit)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Gains:
    """PD gains per joint (ankle1, hip1, hip2, ankle2, pendulum): stiffness N m/rad, damping N m s/rad."""

    stiffness: jax.Array
    damping: jax.Array


DEFAULT_GAINS = Gains(stiffness=jnp.array([60.0, 40.0, 40.0, 60.0, 20.0]),
                      damping=jnp.array([3.0, 2.0, 2.0, 3.0, 1.0]))


def pd_torque(gains: Gains, drive: Drive, q, qd, q_ref, qd_ref) -> tuple[jax.Array, jax.Array]:
    """(applied torque, commanded torque), shape (5,) each: the PD command clipped to the drive."""
    command = gains.stiffness * (q_ref - q) + gains.damping * (qd_ref - qd)
    low, high = torque_limits(drive, qd)
    return jnp.clip(command, low, high), command


# ----------------------------------------------------------------------------- the heuristic gait

@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class DonaldGait:
    """The statically stable gait's parameters (traced: one compiled rollout serves every value).

    Attributes:
      step_angle: leg pitch alpha at the end of a swing and of a transfer, rad; each step moves the
        pelvis forward by about leg_length x sin(alpha).
      lift_angle: extra roll delta about the support ankle that lifts the swing foot, rad.
      pendulum_angle: pendulum swing over the support foot, rad (pi/2 = horizontal).
      shift_time, lift_time, swing_time, lower_time, transfer_time: phase durations, s.
    """

    step_angle: jax.Array
    lift_angle: jax.Array
    pendulum_angle: jax.Array
    shift_time: jax.Array
    lift_time: jax.Array
    swing_time: jax.Array
    lower_time: jax.Array
    transfer_time: jax.Array

    @property
    def step_time(self) -> jax.Array:
        return self.shift_time + self.lift_time + self.swing_time + self.lower_time + self.transfer_time


DEFAULT_GAIT = DonaldGait(step_angle=jnp.asarray(0.18), lift_angle=jnp.asarray(0.15),
                          pendulum_angle=jnp.asarray(1.4), shift_time=jnp.asarray(0.8),
                          lift_time=jnp.asarray(0.5), swing_time=jnp.asarray(0.8),
                          lower_time=jnp.asarray(0.5), transfer_time=jnp.asarray(0.8))
#: Standing still before the first step, s.
SETTLE_TIME = 0.5


def keyframes(gait: DonaldGait, steps: int) -> tuple[jax.Array, jax.Array]:
    """Poses (K, 5) and their times (K,) of ``steps`` steps, the first on foot 1 (swinging leg 2).

    Signs (models/donald.xml): a leg ahead of its hip has a negative hip angle; a positive ankle
    angle tilts the frame about a left (foot 1) support so that the right side rises; a negative
    pendulum angle puts the pendulum mass over the left foot.
    """
    pose = jnp.zeros(5)
    poses, durations = [pose, pose], [SETTLE_TIME]
    for k in range(steps):
        side = 1.0 if k % 2 == 0 else -1.0  # +1: support on foot 1 (left)
        support_hip, swing_hip = (HIP1, HIP2) if side > 0 else (HIP2, HIP1)
        phases = (
            (gait.shift_time, {PENDULUM: -side * gait.pendulum_angle}),
            (gait.lift_time, {ANKLE1: side * gait.lift_angle, ANKLE2: side * gait.lift_angle}),
            (gait.swing_time, {swing_hip: -gait.step_angle}),
            (gait.lower_time, {ANKLE1: 0.0, ANKLE2: 0.0}),
            (gait.transfer_time, {support_hip: gait.step_angle, swing_hip: 0.0}),
        )
        for duration, changes in phases:
            for joint, value in changes.items():
                pose = pose.at[joint].set(value)
            poses.append(pose)
            durations.append(duration)
    times = jnp.concatenate([jnp.zeros(1), jnp.cumsum(jnp.stack(durations))])
    return jnp.stack(poses), times


def reference(poses: jax.Array, times: jax.Array, t: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Joint angles and rates at time t, shape (5,) each: cosine blends between keyframes, at rest
    at every keyframe and after the last."""
    i = jnp.clip(jnp.searchsorted(times, t, side="right") - 1, 0, times.shape[0] - 2)
    duration = times[i + 1] - times[i]
    s = jnp.clip((t - times[i]) / duration, 0.0, 1.0)
    change = poses[i + 1] - poses[i]
    angle = poses[i] + 0.5 * (1 - jnp.cos(jnp.pi * s)) * change
    rate = jnp.where((t - times[i]) < duration, 0.5 * jnp.pi * jnp.sin(jnp.pi * s) / duration, 0.0) * change
    return angle, rate


# ----------------------------------------------------------------------------- simulation

def load_donald(drive: Drive | None = None, spec: DonaldSpec | None = None):
    """(MuJoCo model, MJX model) of DONALD with the drive's reflected inertia as joint armature."""
    mj_model = robots.load_mj_model("donald") if spec is None else mujoco.MjModel.from_xml_string(
        __import__("biped_jax.mjcf", fromlist=["donald_xml"]).donald_xml(spec))
    drive = drive or donald_drive()
    dofs = [mj_model.joint(name).dofadr[0] for name in DONALD_ACTUATED_JOINTS]
    mj_model.dof_armature[dofs] = float(drive.reflected_inertia)
    return mj_model, robots.put_mjx_model(mj_model)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class DonaldRun:
    """A simulated walk, sampled every ``record_every`` physics steps.

    Attributes:
      t: times, shape (S,), s. qpos: (S, 12) (free joint 7 + 5 joints). qvel: (S, 11).
      torque: applied joint torques, (S, 5), N m. command: PD torques before the drive limit, (S, 5).
      reference: joint references, (S, 5), rad. com: centre of mass, (S, 3), m.
      foot_position: foot-plate centres (foot 1, foot 2), (S, 2, 3), m.
      foot_rotation: their orientations, (S, 2, 3, 3). ground_force: total contact force on the
        robot in the world frame, (S, 3), N.
    """

    t: jax.Array
    qpos: jax.Array
    qvel: jax.Array
    torque: jax.Array
    command: jax.Array
    reference: jax.Array
    com: jax.Array
    foot_position: jax.Array
    foot_rotation: jax.Array
    ground_force: jax.Array


def simulate(model, gait: DonaldGait, gains: Gains, drive: Drive, steps: int, duration: float,
             record_every: int = 10) -> DonaldRun:
    """Walks ``steps`` steps (then stands) for ``duration`` s in MJX; pure and jittable with
    ``steps``, ``duration`` and ``record_every`` static."""
    dt = float(model.opt.timestep)
    count = int(round(duration / dt / record_every))
    poses, times = keyframes(gait, steps)
    foot_geoms = jnp.array([mjx.name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"foot{k}") for k in (1, 2)])
    data = mjx.make_data(model)
    data = data.replace(qpos=jnp.asarray(model.qpos0))
    joint_q = jnp.array([model.jnt_qposadr[mjx.name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j)]
                         for j in DONALD_ACTUATED_JOINTS])
    joint_v = jnp.array([model.jnt_dofadr[mjx.name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j)]
                         for j in DONALD_ACTUATED_JOINTS])

    def physics_step(data, _):
        q_ref, qd_ref = reference(poses, times, data.time)
        torque, command = pd_torque(gains, drive, data.qpos[joint_q], data.qvel[joint_v], q_ref, qd_ref)
        data = mjx.step(model, data.replace(ctrl=torque))
        return data, (torque, command, q_ref)

    def record_step(data, _):
        data, (torque, command, q_ref) = jax.lax.scan(physics_step, data, None, length=record_every)
        sample = (data.time, data.qpos, data.qvel, torque[-1], command[-1], q_ref[-1], data.subtree_com[0],
                  data.geom_xpos[foot_geoms], data.geom_xmat[foot_geoms], data.qfrc_constraint[:3])
        return data, sample

    data = mjx.forward(model, data)
    _, samples = jax.lax.scan(record_step, data, None, length=count)
    return DonaldRun(*samples)
