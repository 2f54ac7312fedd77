"""DONALD walking under contact in MJX: a statically stable heuristic gait through voltage-limited drives.

The paper's approach (Section 3): shift the pendulum mass over the support foot, tilt about the
support ankle to unload the other foot, swing it forward, set it down, move the pelvis forward over
it in double support, repeat. The hips are pitch joints and the ankles roll joints (docs/models.md), so
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

from biped_jax.drives import model as drive_model
from biped_jax.robots import registry
from biped_jax.robots.mjcf import DONALD_ACTUATED_JOINTS
from biped_jax.robots.specs import DonaldSpec

mjx = registry.import_mjx()

ANKLE1, HIP1, HIP2, ANKLE2, PENDULUM = range(5)
#: Supply voltage of DONALD's drives, V (ours: the paper gives none; the 24 V winding at its nominal).
DONALD_SUPPLY_VOLTAGE = 24.0
#: The motor: RE 25, 24 V winding (datasheet values).
DONALD_MOTOR = "RE25-118752"
#: The gear: GP 32 A, 4 stages, 245.96:1 (paper Table 7).
DONALD_GEAR = "GP32A-245.96"


def donald_drive(motor: str = DONALD_MOTOR, gear: str = DONALD_GEAR,
                 supply_voltage: float = DONALD_SUPPLY_VOLTAGE) -> drive_model.JointDrives:
    """The drive of every DONALD joint from the catalogue (fields of shape ()); raises ValueError
    naming an unknown part."""
    return drive_model.catalogue_drives(motor, gear, supply_voltage)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Gains:
    """PD gains per joint (ankle1, hip1, hip2, ankle2, pendulum): stiffness N m/rad, damping N m s/rad."""

    stiffness: jax.Array
    damping: jax.Array


DEFAULT_GAINS = Gains(stiffness=jnp.array([60.0, 40.0, 40.0, 60.0, 20.0]),
                      damping=jnp.array([3.0, 2.0, 2.0, 3.0, 1.0]))


def pd_torque(gains: Gains, drive: drive_model.JointDrives, q, qd, q_ref, qd_ref) -> tuple[jax.Array, jax.Array,
                                                                                           jax.Array]:
    """(applied torque, commanded torque, (low, high) drive limits), shapes (5,), (5,), (2, 5): the PD
    command clipped to what the drive gives at the joint speed ``qd``."""
    command = gains.stiffness * (q_ref - q) + gains.damping * (qd_ref - qd)
    low, high = drive_model.torque_limits(drive, qd)
    return jnp.clip(command, low, high), command, jnp.stack([low, high])


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
      shift_time, lift_time, swing_time, lower_time: phase durations, s.
    """

    step_angle: jax.Array
    lift_angle: jax.Array
    pendulum_angle: jax.Array
    shift_time: jax.Array
    lift_time: jax.Array
    swing_time: jax.Array
    lower_time: jax.Array

    @property
    def step_time(self) -> jax.Array:
        return self.shift_time + self.lift_time + self.swing_time + self.lower_time


DEFAULT_GAIT = DonaldGait(step_angle=jnp.asarray(0.18), lift_angle=jnp.asarray(0.15),
                          pendulum_angle=jnp.asarray(1.4), shift_time=jnp.asarray(1.2),
                          lift_time=jnp.asarray(0.8), swing_time=jnp.asarray(0.8),
                          lower_time=jnp.asarray(0.5))
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
            # Unloading the rear foot lets the robot rock forward over the front foot's heel onto its
            # sole: the support leg comes upright, the swing leg trails behind.
            (gait.lift_time, {ANKLE1: side * gait.lift_angle, ANKLE2: side * gait.lift_angle,
                              support_hip: 0.0, swing_hip: gait.step_angle if k else 0.0}),
            (gait.swing_time, {swing_hip: -gait.step_angle}),
            (gait.lower_time, {ANKLE1: 0.0, ANKLE2: 0.0}),
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

def load_donald(drive: drive_model.JointDrives | None = None, spec: DonaldSpec | None = None):
    """(MuJoCo model, MJX model) of DONALD with the drive's reflected inertia as joint armature."""
    mj_model = registry.load_mj_model("donald") if spec is None else mujoco.MjModel.from_xml_string(
        __import__("biped_jax.robots.mjcf", fromlist=["donald_xml"]).donald_xml(spec))
    drive = drive or donald_drive()
    dofs = [mj_model.joint(name).dofadr[0] for name in DONALD_ACTUATED_JOINTS]
    mj_model.dof_armature[dofs] = float(drive.reflected_inertia)
    return mj_model, registry.put_mjx_model(mj_model)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class DonaldRun:
    """A simulated walk, sampled every ``record_every`` physics steps.

    Attributes:
      t: times, shape (S,), s. qpos: (S, 12) (free joint 7 + 5 joints). qvel: (S, 11).
      joint_angle, joint_speed: the actuated joints in actuator order, (S, 5), rad and rad/s.
      torque: applied joint torques, (S, 5), N m. command: PD torques before the drive limit, (S, 5).
      torque_limit: the drive's (lowest, highest) torque at the joint speed of that step, (S, 2, 5).
      reference: joint references, (S, 5), rad. com: centre of mass, (S, 3), m.
      foot_position: foot-plate centres (foot 1, foot 2), (S, 2, 3), m.
      foot_rotation: their orientations, (S, 2, 3, 3). ground_force: total contact force on the
        robot in the world frame, (S, 3), N.
    """

    t: jax.Array
    qpos: jax.Array
    qvel: jax.Array
    joint_angle: jax.Array
    joint_speed: jax.Array
    torque: jax.Array
    command: jax.Array
    torque_limit: jax.Array
    reference: jax.Array
    com: jax.Array
    foot_position: jax.Array
    foot_rotation: jax.Array
    ground_force: jax.Array


def walker(mj_model: mujoco.MjModel, steps: int, duration: float, record_every: int = 10):
    """A compiled walk: ``walk(model, gait, gains, drive) -> DonaldRun``.

    ``model`` is the MJX model (its masses, armature and friction may differ from ``mj_model``'s, which
    only fixes names, sizes and the time step); ``steps`` steps are walked, then the robot stands until
    ``duration`` s. The state is sampled every ``record_every`` physics steps.
    """
    count = int(round(duration / mj_model.opt.timestep / record_every))
    foot_geoms = np.array([mj_model.geom(f"foot{k}").id for k in (1, 2)])
    joint_q = np.array([mj_model.joint(j).qposadr[0] for j in DONALD_ACTUATED_JOINTS])
    joint_v = np.array([mj_model.joint(j).dofadr[0] for j in DONALD_ACTUATED_JOINTS])

    @jax.jit
    def walk(model, gait: DonaldGait, gains: Gains, drive: drive_model.JointDrives) -> DonaldRun:
        poses, times = keyframes(gait, steps)

        def physics_step(data, _):
            q_ref, qd_ref = reference(poses, times, data.time)
            speed = data.qvel[joint_v]
            torque, command, limit = pd_torque(gains, drive, data.qpos[joint_q], speed, q_ref, qd_ref)
            data = mjx.step(model, data.replace(ctrl=torque))
            return data, (data.qpos[joint_q], speed, torque, command, limit, q_ref)

        def record_step(data, _):
            data, (angle, speed, torque, command, limit, q_ref) = jax.lax.scan(
                physics_step, data, None, length=record_every)
            # the last physics step's torque with the joint state it was computed from
            sample = (data.time, data.qpos, data.qvel, angle[-1], speed[-1], torque[-1], command[-1], limit[-1],
                      q_ref[-1],
                      data.subtree_com[0], data.geom_xpos[foot_geoms], data.geom_xmat[foot_geoms],
                      data.qfrc_constraint[:3])
            return data, sample

        data = mjx.forward(model, mjx.make_data(model))
        _, samples = jax.lax.scan(record_step, data, None, length=count)
        return DonaldRun(*samples)

    return walk


# ----------------------------------------------------------------------------- analysis

#: A foot-plate corner lower than this counts as touching the ground, m (contacts are soft).
CONTACT_HEIGHT = 2e-3


def sole_corners(run: DonaldRun, spec: DonaldSpec = DonaldSpec()) -> jax.Array:
    """World positions of the four bottom corners of each foot plate, shape (S, 2, 4, 3), m
    (traceable: the speed optimisation differentiates through it)."""
    hx, hy, hz = np.asarray(spec.foot_size) / 2
    local = np.array([[sx * hx, sy * hy, -hz] for sx in (-1, 1) for sy in (-1, 1)])
    rotation = jnp.reshape(run.foot_rotation, (*jnp.shape(run.foot_rotation)[:2], 3, 3))
    return jnp.asarray(run.foot_position)[:, :, None, :] + jnp.einsum("sfij,cj->sfci", rotation, local)


def _margin(point: np.ndarray, corners: np.ndarray) -> float:
    """Signed distance (m) of a 2-D point inside the convex hull of 2-4 corners (negative outside)."""
    if len(corners) < 3:  # an edge or a corner: nothing is inside
        a, b = corners[0], corners[-1]
        t = np.clip(np.dot(point - a, b - a) / max(np.dot(b - a, b - a), 1e-12), 0, 1)
        return -float(np.linalg.norm(point - (a + t * (b - a))))
    centre = corners.mean(axis=0)
    ordered = corners[np.argsort(np.arctan2(*(corners - centre).T[::-1]))]
    margin = np.inf
    for a, b in zip(ordered, np.roll(ordered, -1, axis=0)):
        edge = b - a
        normal = np.array([edge[1], -edge[0]]) / np.linalg.norm(edge)  # outward for counter-clockwise
        margin = min(margin, -float(np.dot(point - a, normal)))
    return margin


def support_phases(run: DonaldRun, spec: DonaldSpec = DonaldSpec()) -> tuple[np.ndarray, np.ndarray]:
    """Per sample: which feet touch the ground, (S, 2) bool, and the centre of mass's margin inside
    the support polygon in single support (NaN in double support or flight), (S,), m."""
    corners = np.asarray(sole_corners(run, spec))
    touching_corner = corners[..., 2] < CONTACT_HEIGHT
    touching = touching_corner.any(axis=2)
    com = np.asarray(run.com)[:, :2]
    margin = np.full(len(com), np.nan)
    for s in np.flatnonzero(touching.sum(axis=1) == 1):
        foot = int(np.argmax(touching[s]))
        margin[s] = _margin(com[s], corners[s, foot, touching_corner[s, foot], :2])
    return touching, margin


def walk_report(run: DonaldRun, drive: drive_model.JointDrives, gains: Gains, spec: DonaldSpec = DonaldSpec()) -> dict:
    """Steps, distance, falls, static-stability margin and the joints against the drive's limits."""
    touching, margin = support_phases(run, spec)
    single = ~np.isnan(margin)
    # A step is a touchdown: a foot in the air in one sample and on the ground in the next.
    touchdowns = int(np.sum(~touching[:-1] & touching[1:]))
    qpos = np.asarray(run.qpos)
    speed = np.asarray(run.joint_speed)
    torque = np.asarray(run.torque)
    low, high = np.asarray(run.torque_limit)[:, 0], np.asarray(run.torque_limit)[:, 1]
    # Share of the drive's torque available in the torque's direction at that speed (1: on the line).
    available = np.where(torque >= 0, high, -low)
    use = np.where(available > 1e-9, np.abs(torque) / np.maximum(available, 1e-9), 1.0)
    return {
        "steps": touchdowns,
        "distance_m": float(np.asarray(run.com)[-1, 0] - np.asarray(run.com)[0, 0]),
        "duration_s": float(np.asarray(run.t)[-1]),
        "fell": bool(qpos[:, 2].min() < 0.8 * qpos[0, 2]),
        "lowest_pelvis_m": float(qpos[:, 2].min()),
        "single_support_fraction": float(single.mean()),
        "min_support_margin_m": float(np.nanmin(margin)) if single.any() else float("nan"),
        "joints": {name: {"max_torque_Nm": float(np.abs(torque[:, k]).max()),
                          "max_speed_rad_s": float(np.abs(speed[:, k]).max()),
                          "max_fraction_of_drive_limit": float(use[:, k].max()),
                          "saturated_fraction": float(np.mean(np.abs(
                              np.asarray(run.command)[:, k] - torque[:, k]) > 1e-9))}
                   for k, name in enumerate(DONALD_ACTUATED_JOINTS)},
        "gains": {"stiffness_Nm_per_rad": np.asarray(gains.stiffness).tolist(),
                  "damping_Nms_per_rad": np.asarray(gains.damping).tolist()},
        "drive": {"ratio": float(drive.ratio), "supply_voltage_V": float(drive.supply_voltage),
                  "reflected_inertia_kgm2": float(drive.reflected_inertia),
                  "gear_torque_limit_Nm": float(drive.gear_torque_limit)},
    }
