"""The optimal sagittal gait replayed on the 16-DoF humanoid under contact in MJX.

The gait optimiser's step (``biped_jax.gait``: pinned stance foot, rigid impact map) is replayed on the
humanoid with point feet on a ground plane (MuJoCo's soft contacts, friction 0.8). Lateral motion is
held by a planarising constraint: the free base is replaced by a planar one (slide x, slide z, hinge
about y), and the lateral joints, ankles and arms are held at zero by PD loops. The hips and knees run
feed-forward torques from the optimiser plus PD on the optimal joint paths.

The reference is phased by the stance leg's absolute angle theta (the optimiser's unactuated
coordinate), not by time: the joints track b(s(theta)), the hybrid-zero-dynamics form of the gait
(Westervelt et al. 2003), so a late or early step does not drag the swing leg off its path. The
support switches when the swing foot's ground force rises in the second half of the step.

Coordinates of the planarised model: qpos = (x, z, pitch, 16 joints); x, z the hip centre (the torso
frame) in metres, pitch about +y in rad, as in the floating planar model. Leg "l" is the planar
model's leg 1 at the start.
"""

from __future__ import annotations

import copy
import dataclasses
import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from biped_jax import gait, robots
from biped_jax import hybrid_step as hs
from biped_jax.mjcf import HUMANOID_ACTUATED_JOINTS

mjx = robots.import_mjx()

#: Physics step of the replay, s (contacts want a step well below the optimiser's 6 ms).
TIMESTEP = 1e-3
#: Physics steps per compiled call: the replay runs in chunks, one program for any duration.
CHUNK = 100
#: Samples of the reference over the step's phase: fixed, so every gait shares one program.
PHASE_SAMPLES = 201
#: Rotor-like inertia on the held ankle joints, kg m^2 (the point foot's own is 4e-9, too stiff for
#: a PD loop at 1 ms); it is of the order of a geared motor's reflected inertia.
ANKLE_ARMATURE = 1e-3
#: Extra height of the swing foot's path, m, largest mid-step and fading linearly to zero over the first
#: and the last :data:`CLEARANCE_RAMP` of the step. The optimal step sweeps the foot forward at about
#: 2 mm over the ground just before touchdown (its clearance constraint is active there); under contact,
#: millimetres of tracking error would scuff it and land it early.
SWING_CLEARANCE = 0.01
CLEARANCE_RAMP = 0.1
CLEARANCE_DAMPING = 0.03  # m/rad
#: Share of the step over which the reference blends from the robot's joints at touchdown into the
#: optimal path (the contact model's touchdown never lands exactly on the optimal posture).
OFFSET_FADE = 0.2
#: Contact of the feet: a stiff, critically damped soft contact (time constant 4 ms = 4 steps, MuJoCo's
#: default 20 ms lets the point foot sink and creep) and hard friction (impratio), so that the stance
#: foot acts like the optimiser's pin as long as the force stays inside the friction cone.
FOOT_SOLREF = (0.004, 1.0)
FOOT_SOLIMP = (0.95, 0.99, 0.001, 0.5, 2.0)
IMPRATIO = 10.0
#: The swing foot counts as landed when its ground force exceeds this in the second half of the step, N.
#: (Not a height: the sphere's lowest point lies below the shank end when the shank is tilted, 0.45 mm at
#: the 0.3 rad of touchdown, so a loaded foot's site can stay above the ground and a height test miss the
#: touchdown; measured.)
TOUCHDOWN_FORCE = 1.0
#: The robot has fallen when the hips drop below this height, m, or the torso pitches beyond 1 rad.
FALL_HEIGHT = 0.15

SIDES = ("l", "r")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Gains:
    """PD gains: sagittal hips and knees (N m/rad, N m s/rad) and the held joints."""

    sagittal_stiffness: float = 300.0
    sagittal_damping: float = 6.0
    held_stiffness: float = 200.0
    held_damping: float = 4.0


DEFAULT_GAINS = Gains()


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class GaitReference:
    """The optimal step sampled on a fixed phase grid (arrays; shapes independent of the gait's settings).

    Attributes:
      phase: s in [0, 1], shape (S,).
      stance_angle: theta(s) of the optimal step, strictly increasing, shape (S,), rad.
      stance_angle_slope: d theta / d s, shape (S,), rad.
      joints: (H1, K1, H2, K2)(s), leg 1 standing, shape (S, 4), rad.
      joint_slope: d joints / d s, shape (S, 4), rad.
      torque: the optimiser's torques (H1, K1, H2, K2), shape (S, 4), N m.
      step_time: t_f, s. speed: the gait's average speed, m/s.
    """

    phase: jax.Array
    stance_angle: jax.Array
    stance_angle_slope: jax.Array
    joints: jax.Array
    joint_slope: jax.Array
    torque: jax.Array
    step_time: jax.Array
    speed: jax.Array


#: Largest backward travel of the stance angle (a fraction of its range over the step) that the
#: replay's phase clock absorbs, and only at the step's end (see :func:`gait_reference`).
PHASE_REVERSAL = 0.01


def _reversal_at_end(theta: np.ndarray) -> bool:
    """Whether theta increases strictly up to its maximum and only falls after it."""
    top = int(np.argmax(theta))
    return bool(np.all(np.diff(theta[:top + 1]) > 0) and np.all(np.diff(theta[top:]) <= 0))


def gait_reference(x, model: gait.GaitModel, settings: gait.GaitSettings,
                   trajectory: gait.GaitTrajectory, mass_class: str = "12kg") -> GaitReference:
    """The reference of a solved step (decision vector ``x``, its ``trajectory``, solved for the planar
    biped of ``mass_class``); raises ValueError if the stance angle does not advance monotonically
    (then it cannot phase the gait), except for a backward travel of at most :data:`PHASE_REVERSAL` of
    its range after its maximum (the phase clock is then flat there)."""
    x = np.asarray(x)
    phase = np.linspace(0.0, 1.0, PHASE_SAMPLES)
    joints = np.asarray(gait.reference(jnp.asarray(x), settings, phase)[0])
    step_time = float(model.step_length / model.speed)
    grid = np.asarray(trajectory.t) / step_time
    theta = np.asarray(trajectory.q)[:, 0]
    # The optimal gaits of 48 knot spans let the stance leg swing back by about 1e-4 rad in the last
    # grid points before touchdown (rate down to -0.7 rad/s over 0.5 % of the step): the phase clock
    # is the running maximum there, flat over that sliver. A larger reversal cannot phase the replay.
    envelope = np.maximum.accumulate(theta)
    small_reversal_at_end = _reversal_at_end(theta) and \
        envelope[-1] - theta[-1] <= PHASE_REVERSAL * (envelope[-1] - theta[0])
    if np.any(np.diff(theta) <= 0) and not small_reversal_at_end:
        raise ValueError(f"the stance angle of this gait does not increase monotonically "
                         f"(from {theta[0]:.3f} to {theta[-1]:.3f} rad): it cannot phase the replay")
    theta = envelope
    rate = np.asarray(trajectory.qd)[:, 0] * step_time
    joints = joints + clearance_offset(model, np.asarray(trajectory.q), grid, phase, mass_class)
    joint_slope = np.gradient(joints, phase, axis=0)
    # the gait's torques are samples of a continuous trajectory at its grid points: interpolate them
    u = np.asarray(trajectory.u)
    torque = np.column_stack([np.interp(phase, grid, u[:, k]) for k in range(u.shape[1])])
    return GaitReference(phase=jnp.asarray(phase), stance_angle=jnp.asarray(np.interp(phase, grid, theta)),
                         stance_angle_slope=jnp.asarray(np.interp(phase, grid, rate)),
                         joints=jnp.asarray(joints), joint_slope=jnp.asarray(joint_slope),
                         torque=jnp.asarray(torque), step_time=jnp.asarray(step_time),
                         speed=jnp.asarray(float(model.speed)))


def clearance_offset(model: gait.GaitModel, q: np.ndarray, grid: np.ndarray, phase: np.ndarray,
                     mass_class: str = "12kg") -> np.ndarray:
    """Offsets of (H1, K1, H2, K2), shape (S, 4), rad, that lift the swing foot to at least the clearance
    profile where the optimal step (its states ``q`` (T + 1, 5) at phases ``grid``) runs lower, without
    moving it forward: a damped least-squares step (:data:`CLEARANCE_DAMPING`) on the swing foot's (x, z)
    Jacobian with respect to (hip2, knee2), which is singular with a straight swing leg. The geometry is
    that of ``mass_class``'s planar biped; the masses are the gait's design."""
    biped = hs.with_design(hs.load_planar_biped(mass_class), model.design)
    states = jnp.asarray(np.column_stack([np.interp(phase, grid, q[:, k]) for k in range(q.shape[1])]))
    foot = lambda q_: hs.site_position(biped.pinned, q_, "foot2")[jnp.array([0, 2])]  # noqa: E731
    jacobians = np.asarray(jax.vmap(jax.jacfwd(foot))(states))[:, :, 3:5]
    height = np.asarray(jax.vmap(foot)(states))[:, 1]
    profile = SWING_CLEARANCE * np.minimum(1.0, np.minimum(phase, 1.0 - phase) / CLEARANCE_RAMP)
    lift = np.column_stack([np.zeros_like(phase), np.maximum(profile - height, 0.0)])
    normal = jacobians @ np.swapaxes(jacobians, 1, 2) + CLEARANCE_DAMPING**2 * np.eye(2)
    swing = np.einsum("sji,sj->si", jacobians, np.linalg.solve(normal, lift[..., None])[..., 0])
    return np.column_stack([np.zeros((len(phase), 2)), swing])


# ----------------------------------------------------------------------------- the planarised model

def planarised_humanoid(mass_class: str = "12kg") -> mujoco.MjModel:
    """The point-foot humanoid of ``mass_class`` with its free base replaced by a planar one (slide x,
    slide z, hinge y at the hip centre): the planarising constraint. Time step :data:`TIMESTEP`."""
    if mass_class not in ("12kg", "18kg"):
        raise ValueError(f"unknown humanoid mass class {mass_class!r}; known: '12kg', '18kg'")
    spec = mujoco.MjSpec.from_file(str(robots.model_path(f"humanoid16_{mass_class}")))
    torso = spec.body("torso")
    spec.delete(spec.joint("root"))
    torso.pos = [0.0, 0.0, 0.0]
    for name, kind, axis in (("root_x", mujoco.mjtJoint.mjJNT_SLIDE, [1, 0, 0]),
                             ("root_z", mujoco.mjtJoint.mjJNT_SLIDE, [0, 0, 1]),
                             ("root_pitch", mujoco.mjtJoint.mjJNT_HINGE, [0, 1, 0])):
        torso.add_joint(name=name, type=kind, axis=axis)
    for side in SIDES:
        for joint in ("ankle_pitch", "ankle_roll"):
            spec.joint(f"{joint}_{side}").armature = ANKLE_ARMATURE
    for side in SIDES:
        foot = spec.geom(f"foot_{side}")
        foot.solref, foot.solimp = FOOT_SOLREF, FOOT_SOLIMP
    spec.option.timestep = TIMESTEP
    spec.option.impratio = IMPRATIO
    model = spec.compile()
    # the root joints were added after the legs in the spec's joint list; the body tree puts them first
    assert model.joint("root_x").qposadr[0] == 0 and model.joint("root_pitch").qposadr[0] == 2
    return model


@dataclasses.dataclass(frozen=True)
class Layout:
    """Indices into the planarised model (static)."""

    hip: tuple[int, int]  # qpos/qvel index of hip_pitch_l, hip_pitch_r
    knee: tuple[int, int]
    actuator_hip: tuple[int, int]
    actuator_knee: tuple[int, int]
    held_q: tuple[int, ...]  # every actuated joint's qpos index, actuator order
    foot_site: tuple[int, int]
    foot_body: tuple[int, int]

    @property
    def sagittal_q(self) -> list[int]:
        """qpos/qvel indices of (hip l, knee l, hip r, knee r): (H1, K1, H2, K2) with leg l standing."""
        return [self.hip[0], self.knee[0], self.hip[1], self.knee[1]]

    @property
    def sagittal_actuators(self) -> list[int]:
        """Actuator indices of (hip l, knee l, hip r, knee r)."""
        return [self.actuator_hip[0], self.actuator_knee[0], self.actuator_hip[1], self.actuator_knee[1]]

    @classmethod
    def of(cls, model: mujoco.MjModel) -> "Layout":
        joint = lambda name: int(model.joint(name).qposadr[0])  # noqa: E731 (hinges: qpos = dof index + 0)
        actuator = lambda name: int(model.actuator(name).id)  # noqa: E731
        for a, name in enumerate(HUMANOID_ACTUATED_JOINTS):
            assert model.actuator(a).name == name
            assert model.joint(name).qposadr[0] == model.joint(name).dofadr[0]  # planar base: no quaternion
        return cls(hip=tuple(joint(f"hip_pitch_{s}") for s in SIDES),
                   knee=tuple(joint(f"knee_{s}") for s in SIDES),
                   actuator_hip=tuple(actuator(f"hip_pitch_{s}") for s in SIDES),
                   actuator_knee=tuple(actuator(f"knee_{s}") for s in SIDES),
                   held_q=tuple(joint(name) for name in HUMANOID_ACTUATED_JOINTS),
                   foot_site=tuple(int(model.site(f"foot_{s}").id) for s in SIDES),
                   foot_body=tuple(int(model.body(f"foot_{s}").id) for s in SIDES))


# ----------------------------------------------------------------------------- control

def _interp(x, xp, fp):
    """np.interp along the first axis of fp (S,) or (S, k)."""
    if fp.ndim == 1:
        return jnp.interp(x, xp, fp)
    return jax.vmap(lambda column: jnp.interp(x, xp, column), in_axes=1, out_axes=-1)(fp)


def sagittal_state(layout: Layout, qpos, qvel, stance):
    """(theta, theta_dot, joints (H1, K1, H2, K2), their rates) with leg ``stance`` (0 = l, 1 = r) as
    leg 1."""
    hip, knee = jnp.array(layout.hip), jnp.array(layout.knee)
    order = jnp.stack([hip[stance], knee[stance], hip[1 - stance], knee[1 - stance]])
    theta = qpos[2] + qpos[order[0]] + qpos[order[1]]
    theta_dot = qvel[2] + qvel[order[0]] + qvel[order[1]]
    return theta, theta_dot, qpos[order], qvel[order], order


def with_gains(model, layout: Layout, gains: Gains):
    """The MJX ``model`` with the PD loops' damping as joint damping (MJX's Euler step integrates it
    implicitly, which keeps stiff loops on light links stable at 1 ms) and the held joints' stiffness as
    joint springs about zero. :func:`control` adds the rest of the law; traceable."""
    sagittal = np.array(layout.hip + layout.knee)
    held = np.setdiff1d(np.array(layout.held_q), sagittal)
    damping = jnp.zeros_like(model.dof_damping).at[sagittal].set(gains.sagittal_damping).at[held].set(
        gains.held_damping)
    joints = np.array([i for i in range(model.njnt) if int(model.jnt_qposadr[i]) in set(held.tolist())])
    stiffness = jnp.zeros_like(model.jnt_stiffness).at[joints].set(gains.held_stiffness)
    return model.replace(dof_damping=damping, jnt_stiffness=stiffness)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Support:
    """What the controller keeps from the last touchdown.

    Attributes:
      stance: the supporting leg, 0 (l) or 1 (r).
      stance_angle: theta at that touchdown (the step's start), rad.
      offset: joints (H1, K1, H2, K2) minus the reference at the touchdown, shape (4,), rad; it fades out
        over the first :data:`OFFSET_FADE` of the step, so the reference starts where the robot is.
    """

    stance: jax.Array
    stance_angle: jax.Array
    offset: jax.Array


def phase_of(reference: GaitReference, support: Support, theta):
    """s: theta mapped linearly from [theta at touchdown, theta at the optimal step's end] onto the
    optimal step's [theta_0, theta_end], then through theta(s) (hybrid-zero-dynamics phasing that
    re-normalises every step, so a short or long step starts at s = 0)."""
    start, end = reference.stance_angle[0], reference.stance_angle[-1]
    stretch = (end - start) / (end - support.stance_angle)
    equivalent = start + (theta - support.stance_angle) * stretch
    return jnp.clip(jnp.interp(equivalent, reference.stance_angle, reference.phase), 0.0, 1.0)


def after_touchdown(layout: Layout, reference: GaitReference, qpos, qvel, stance) -> Support:
    """The support state when leg ``stance`` has just landed."""
    theta, _, joints, _, _ = sagittal_state(layout, qpos, qvel, stance)
    # keep a usable phase range if the robot lands far off the optimal posture
    theta = jnp.minimum(theta, reference.stance_angle[-1] - 0.1)
    return Support(stance=stance, stance_angle=theta, offset=joints - reference.joints[0])


def control(layout: Layout, reference: GaitReference, gains: Gains, qpos, qvel, support: Support):
    """Torques of the hips and knees (the other actuators are idle: their joints are held by springs and
    dampers, see :func:`with_gains`), shape (16,), N m; the phase s; the reference (H1, K1, H2, K2), rad.

    Law: u = u_ff(s) + K_p (q_ref(s) - q) + K_d (qdot_ref - qdot), the - K_d qdot part acting as joint
    damping; q_ref = b(s) + (1 - s / OFFSET_FADE)^3 offset for s < OFFSET_FADE, else b(s); qdot_ref =
    d q_ref / d s at the nominal pace ds/dt = 1 / t_f.
    """
    theta, _, joints, _, _ = sagittal_state(layout, qpos, qvel, support.stance)
    phase = phase_of(reference, support, theta)
    # the reference's rate at the nominal pace: a rate from the measured theta_dot would feed the stance
    # leg's joint rates back explicitly through the gains (unstable at 1 ms late in the step, measured)
    phase_rate = 1.0 / reference.step_time
    fade = jnp.maximum(1.0 - phase / OFFSET_FADE, 0.0)
    target = _interp(phase, reference.phase, reference.joints) + fade**3 * support.offset
    target_rate = (_interp(phase, reference.phase, reference.joint_slope)
                   - 3 * fade**2 / OFFSET_FADE * support.offset) * phase_rate
    sagittal = (_interp(phase, reference.phase, reference.torque)
                + gains.sagittal_stiffness * (target - joints) + gains.sagittal_damping * target_rate)
    hip, knee = jnp.array(layout.actuator_hip), jnp.array(layout.actuator_knee)
    stance = support.stance
    actuators = jnp.stack([hip[stance], knee[stance], hip[1 - stance], knee[1 - stance]])
    return jnp.zeros(len(layout.held_q)).at[actuators].set(sagittal), phase, target


# ----------------------------------------------------------------------------- the replay

@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Replay:
    """Samples of every physics step (leading dimension N), SI units.

    Attributes:
      t: time after the step, shape (N,), s. qpos, qvel: planarised state after the step, (N, 19).
      ctrl: torques applied during the step, (N, 16), N m. stance: supporting leg (0 = l, 1 = r) during
      the step, (N,). phase: s during the step, (N,). target: reference (H1, K1, H2, K2) during the step,
      (N, 4), rad. joints: the joints (H1, K1, H2, K2) it was compared with, (N, 4), rad.
      feet: foot positions (l, r) after the step, (N, 2, 3), m. foot_force: ground force on each foot
      during the step, (N, 2, 3), N.
    """

    t: jax.Array
    qpos: jax.Array
    qvel: jax.Array
    ctrl: jax.Array
    stance: jax.Array
    phase: jax.Array
    target: jax.Array
    joints: jax.Array
    feet: jax.Array
    foot_force: jax.Array


def contact_model(mass_class: str = "12kg") -> tuple[mujoco.MjModel, "Layout"]:
    """The planarised humanoid the replay simulates (MuJoCo C model) and where its joints are."""
    mj_model, layout, _ = _chunk_program(mass_class)
    return mj_model, layout


@functools.lru_cache(maxsize=None)
def _chunk_program(mass_class: str):
    """One compiled call that advances :data:`CHUNK` physics steps (cached per mass class)."""
    mj_model = planarised_humanoid(mass_class)
    layout = Layout.of(mj_model)
    foot_site, foot_body = jnp.array(layout.foot_site), jnp.array(layout.foot_body)

    def physics_step(model, reference, gains, carry, _):
        data, support = carry
        stance = support.stance
        ctrl, phase, target = control(layout, reference, gains, data.qpos, data.qvel, support)
        joints = sagittal_state(layout, data.qpos, data.qvel, stance)[2]
        data = mjx.forward(model, data.replace(ctrl=ctrl))
        # the contact force on each foot body (world frame) from MJX's Newton-Euler pass
        force = mjx.rne_postconstraint(model, data)._impl.cfrc_ext[foot_body, 3:]
        data = mjx.euler(model, data)
        feet = data.site_xpos[foot_site]
        landed = (force[1 - stance, 2] > TOUCHDOWN_FORCE) & (phase > 0.5)
        switched = after_touchdown(layout, reference, data.qpos, data.qvel, 1 - stance)
        support = jax.tree.map(lambda new, old: jnp.where(landed, new, old), switched, support)
        sample = Replay(t=data.time, qpos=data.qpos, qvel=data.qvel, ctrl=ctrl, stance=stance, phase=phase,
                        target=target, joints=joints, feet=feet, foot_force=force)
        return (data, support), sample

    @jax.jit
    def advance(model, reference, gains, data, support):
        step = functools.partial(physics_step, with_gains(model, layout, gains), reference, gains)
        return jax.lax.scan(step, (data, support), None, length=CHUNK)

    return mj_model, layout, advance


def initial_state(mj_model: mujoco.MjModel, layout: Layout, reference: GaitReference, mass_class: str):
    """(qpos, qvel) of the planarised humanoid at the optimal step's start, leg l standing at x = 0."""
    step_time = float(reference.step_time)
    q0 = np.zeros(5)
    q0[0], q0[gait.ACTUATED_INDEX] = reference.stance_angle[0], reference.joints[0]
    qd0 = np.zeros(5)
    qd0[0] = reference.stance_angle_slope[0] / step_time
    qd0[gait.ACTUATED_INDEX] = np.asarray(reference.joint_slope[0]) / step_time
    pinned = hs.load_planar_biped(mass_class).pinned
    qf, qfd = (np.asarray(a) for a in hs.pinned_to_floating(pinned, jnp.asarray(q0), jnp.asarray(qd0)))
    qpos, qvel = np.zeros(mj_model.nq), np.zeros(mj_model.nv)
    columns = sagittal_columns(layout, 0)
    qpos[columns], qvel[columns] = qf, qfd
    return qpos, qvel


def fallen(qpos: np.ndarray) -> bool:
    """Hips below :data:`FALL_HEIGHT`, the torso pitched beyond 1 rad, or the simulation diverged."""
    return bool(not np.all(np.isfinite(qpos)) or qpos[1] < FALL_HEIGHT or abs(qpos[2]) > 1.0)


def replay(reference: GaitReference, mass_class: str = "12kg", steps: int = 10, gains: Gains = DEFAULT_GAINS,
           progress=None) -> Replay:
    """Walks ``steps`` steps of ``reference`` on the planarised humanoid in MJX (stops early on a fall
    or after twice the nominal time); returns every physics step."""
    if steps < 1:
        raise ValueError(f"steps must be at least 1, got {steps}")
    mj_model, layout, advance = _chunk_program(mass_class)
    model = robots.put_mjx_model(mj_model)
    qpos, qvel = initial_state(mj_model, layout, reference, mass_class)
    data = mjx.forward(model, mjx.make_data(model).replace(qpos=jnp.asarray(qpos), qvel=jnp.asarray(qvel)))
    support = Support(stance=jnp.asarray(0), stance_angle=reference.stance_angle[0], offset=jnp.zeros(4))
    gains = jax.tree.map(jnp.asarray, gains)
    limit = 2.0 * steps * float(reference.step_time)
    chunks = []
    touchdowns = 0
    while True:
        (data, support), samples = advance(model, reference, gains, data, support)
        samples = jax.tree.map(np.asarray, samples)
        chunks.append(samples)
        touchdowns += int(np.sum(np.diff(samples.stance, append=int(support.stance)) != 0))
        down = fallen(samples.qpos[-1])
        if progress:
            progress(f"humanoid: t = {samples.t[-1]:.2f} s, {touchdowns} touchdowns"
                     + (", fallen" if down else ""))
        if touchdowns >= steps or down or samples.t[-1] >= limit:
            break
    run = jax.tree.map(lambda *parts: np.concatenate(parts), *chunks)
    # end the record at the fall: what follows (flailing, or a diverged simulation) is not a walk
    down = [i for i, q in enumerate(run.qpos) if fallen(q)]
    return run if not down else jax.tree.map(lambda a: a[:down[0] + 1], run)


# ----------------------------------------------------------------------------- analysis

#: Tracking errors are summarised outside this time after each touchdown, s (the contact model's
#: impact lasts some milliseconds; the rigid model's is instantaneous).
IMPACT_SETTLE = 0.02


def touchdown_indices(run: Replay) -> np.ndarray:
    """Indices k of the physics steps after which the swing foot touched down, shape (K,)."""
    return np.flatnonzero(np.diff(run.stance) != 0)


def sagittal_columns(layout: Layout, stance: int) -> list[int]:
    """Planarised-model columns of the floating planar coordinates (x, z, pitch, hip1, knee1, hip2, knee2)
    with leg ``stance`` as leg 1."""
    return [0, 1, 2, layout.hip[stance], layout.knee[stance], layout.hip[1 - stance], layout.knee[1 - stance]]


def rigid_impact(mj_model: mujoco.MjModel, layout: Layout, qpos: np.ndarray, qvel: np.ndarray,
                 stance: int) -> tuple[np.ndarray, np.ndarray]:
    """The optimiser's impact map on the humanoid (held joints locked, as in the planar model): the
    landing foot (leg ``1 - stance``) stops, M dqd = J^T Lambda. Returns (sagittal velocity jump,
    shape (7,), impulse on the landing foot (x, z), shape (2,), N s) at the pre-impact state."""
    data = mujoco.MjData(mj_model)
    data.qpos[:], data.qvel[:] = qpos, qvel
    mujoco.mj_forward(mj_model, data)
    mass = np.zeros((mj_model.nv, mj_model.nv))
    mujoco.mj_fullM(mj_model, data, mass)
    jac = np.zeros((3, mj_model.nv))
    mujoco.mj_jacSite(mj_model, data, jac, None, layout.foot_site[1 - stance])
    columns = sagittal_columns(layout, stance)
    before = qvel[columns]
    after, impulse = hs.inelastic_impact(mass[np.ix_(columns, columns)], jac[[0, 2]][:, columns], before, xp=np)
    return after - before, impulse


#: The isolated touchdown ends when the landing foot's speed has fallen below this share of its speed
#: before contact (the rigid map stops it completely; the soft contact only asymptotically).
STOPPED_FRACTION = 0.1


def c_model_with_gains(mj_model: mujoco.MjModel, layout: Layout, gains: Gains) -> mujoco.MjModel:
    """A copy of the MuJoCo C model with the PD loops' joint damping and springs of :func:`with_gains`."""
    model = copy.deepcopy(mj_model)
    tuned = with_gains(robots.put_mjx_model(mj_model), layout, gains)
    model.dof_damping[:] = np.asarray(tuned.dof_damping)
    model.jnt_stiffness[:] = np.asarray(tuned.jnt_stiffness)
    return model


def _foot_ground_force(model: mujoco.MjModel, data: mujoco.MjData, geom: int) -> np.ndarray:
    """World-frame force of the ground on ``geom`` during the last step, shape (3,), N."""
    total, force = np.zeros(3), np.zeros(6)
    for c in range(data.ncon):
        contact = data.contact[c]
        if geom in (contact.geom1, contact.geom2):
            mujoco.mj_contactForce(model, data, c, force)
            sign = 1.0 if contact.geom2 == geom else -1.0  # the frame's normal points from geom1 to geom2
            total += sign * contact.frame.reshape(3, 3).T @ force[:3]
    return total


def _momentum_and_site_speed(model: mujoco.MjModel, data: mujoco.MjData, site: int) -> tuple[np.ndarray, float]:
    """The robot's linear momentum, shape (3,), N s, and the speed of ``site``, m/s, at data's state."""
    mujoco.mj_forward(model, data)
    mujoco.mj_subtreeVel(model, data)
    velocity = np.zeros(6)
    mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_SITE, site, velocity, 0)
    return float(model.body_subtreemass[0]) * data.subtree_linvel[0].copy(), float(np.linalg.norm(velocity[3:]))


def isolated_touchdown(model: mujoco.MjModel, layout: Layout, qpos: np.ndarray, qvel: np.ndarray,
                       ctrl: np.ndarray, stance: int, window: float = 0.02) -> dict:
    """The contact model's touchdown without the control loop's reaction to it: MuJoCo C stepped from
    (qpos, qvel), the state before the landing foot's (leg ``1 - stance``) first contact, with the
    torques ``ctrl`` of that moment held, once as is and once without the landing foot's contact (its
    twin), until the landing foot's speed falls below :data:`STOPPED_FRACTION` of its speed before
    contact or ``window`` s pass. ``model``: the simulated model, gains included
    (:func:`c_model_with_gains`). Returns (SI units) duration; the landing foot's ground impulse (x, z);
    the sagittal velocity change (7,) the contact caused (with minus twin: the same gravity, torques and
    damping act on both); the robot's linear momentum change, with minus twin, (x, z)."""
    geom = model.geom(f"foot_{SIDES[1 - stance]}").id
    site = layout.foot_site[1 - stance]
    columns = sagittal_columns(layout, stance)
    steps = max(1, int(round(window / model.opt.timestep)))
    twin_model = copy.deepcopy(model)
    twin_model.geom_contype[geom] = twin_model.geom_conaffinity[geom] = 0

    def run(simulated: mujoco.MjModel):
        data = mujoco.MjData(simulated)
        data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, ctrl
        momentum, speed0 = _momentum_and_site_speed(simulated, data, site)
        impulse, states = np.zeros(3), []
        for _ in range(steps):
            mujoco.mj_step(simulated, data)
            impulse += _foot_ground_force(simulated, data, geom) * simulated.opt.timestep
            now, speed = _momentum_and_site_speed(simulated, data, site)
            states.append((data.qvel[columns].copy(), impulse.copy(), now - momentum,
                           speed <= STOPPED_FRACTION * speed0))
        return states

    touching, twin = run(model), run(twin_model)
    end = next((i for i, state in enumerate(touching) if state[3]), steps - 1)
    velocity, impulse, momentum, _ = touching[end]
    return {"duration_s": (end + 1) * float(model.opt.timestep), "impulse_Ns": impulse[[0, 2]],
            "velocity_jump": velocity - twin[end][0], "momentum_change_Ns": (momentum - twin[end][2])[[0, 2]]}


def compare_touchdowns(run: Replay, mj_model: mujoco.MjModel, layout: Layout, gains: Gains) -> list[dict]:
    """Each touchdown of the replay against the rigid impact map, applied at the state just before the
    landing foot's first contact.

    Two views of the contact model's touchdown: in the replay itself (closed loop: the first contact's
    duration, impulse and peak force, and whether the landing foot leaves the ground again within
    :data:`IMPACT_SETTLE`), and isolated from the controller (:func:`isolated_touchdown`: torques held,
    until the foot has nearly stopped), whose impulse and velocity change are compared with the map's.
    """
    dt = float(mj_model.opt.timestep)
    model = c_model_with_gains(mj_model, layout, gains)
    settle = int(round(IMPACT_SETTLE / dt))
    records = []
    for k in touchdown_indices(run):
        stance = int(run.stance[k])
        landing = 1 - stance
        first = k  # the step in which the landing foot first carried force
        while first > 0 and run.foot_force[first - 1, landing, 2] > 0:
            first -= 1
        loaded = run.foot_force[first:first + settle, landing, 2] > 0
        contact_steps = int(np.argmin(loaded)) if not loaded.all() else len(loaded)
        closed_loop_impulse = run.foot_force[first:first + contact_steps, landing][:, [0, 2]].sum(axis=0) * dt
        before_q, before_v = run.qpos[first - 1], run.qvel[first - 1]
        predicted_jump, predicted_impulse = rigid_impact(mj_model, layout, before_q, before_v, stance)
        isolated = isolated_touchdown(model, layout, before_q, before_v, run.ctrl[first], stance, IMPACT_SETTLE)
        records.append({
            "time_s": float(run.t[first - 1]), "landing_leg": SIDES[landing],
            "impact_map_impulse_Ns": predicted_impulse.tolist(),
            "impact_map_velocity_jump": predicted_jump.tolist(),
            "replay_first_contact_s": contact_steps * dt,
            "replay_first_contact_impulse_Ns": closed_loop_impulse.tolist(),
            "replay_peak_force_N": float(run.foot_force[first:first + contact_steps, landing, 2].max()),
            # the landing foot left the ground again within IMPACT_SETTLE of its first contact
            "replay_rebound": bool(contact_steps < len(loaded)),
            "isolated_duration_s": isolated["duration_s"],
            "impulse_Ns": isolated["impulse_Ns"].tolist(),
            "velocity_jump": isolated["velocity_jump"].tolist(),
            "momentum_change_Ns": isolated["momentum_change_Ns"].tolist(),
            "impulse_relative_error": float(np.linalg.norm(isolated["impulse_Ns"] - predicted_impulse)
                                            / np.linalg.norm(predicted_impulse)),
            "velocity_jump_relative_error": float(np.linalg.norm(isolated["velocity_jump"] - predicted_jump)
                                                  / np.linalg.norm(predicted_jump)),
        })
    return records


def applied_torque(run: Replay, layout: Layout, gains: Gains) -> np.ndarray:
    """Joint torques the loops applied, shape (N, 16), N m, actuator order: the hips' and knees' commands
    with their damping, and the held joints' spring-dampers (see :func:`with_gains`)."""
    joints = np.array(layout.held_q)
    torque = run.ctrl - gains.held_stiffness * run.qpos[:, joints] - gains.held_damping * run.qvel[:, joints]
    for actuator, joint in zip(layout.actuator_hip + layout.actuator_knee, layout.hip + layout.knee):
        torque[:, actuator] = run.ctrl[:, actuator] - gains.sagittal_damping * run.qvel[:, joint]
    return torque


def walk_report(run: Replay, mj_model: mujoco.MjModel, layout: Layout, reference: GaitReference,
                gains: Gains) -> dict:
    """Steps, distance, speed, fall, tracking errors, foot slip, friction use, torques and the touchdowns
    against the impact map (JSON-ready)."""
    dt = float(mj_model.opt.timestep)
    touchdowns = touchdown_indices(run)
    errors = run.joints - run.target
    settled = np.ones(len(run.t), bool)
    for k in touchdowns:
        settled[k + 1:k + 1 + int(round(IMPACT_SETTLE / dt))] = False
    stance_force = run.foot_force[np.arange(len(run.t)), run.stance]
    loaded = stance_force[:, 2] > 1.0
    slips = []
    bounds = np.concatenate([[0], touchdowns + 1, [len(run.t)]])
    for start, stop in zip(bounds[:-1], bounds[1:]):
        foot = run.feet[start:stop, int(run.stance[start]), 0]
        if len(foot):
            slips.append(float(foot.max() - foot.min()))
    duration = float(run.t[-1])
    distance = float(run.qpos[-1, 0] - run.qpos[0, 0])
    walked = float(run.t[touchdowns[-1]]) if len(touchdowns) else duration
    sagittal = layout.sagittal_actuators
    names = ("hip_pitch_l", "knee_l", "hip_pitch_r", "knee_r")
    torque = applied_torque(run, layout, gains)
    return {
        "steps": int(len(touchdowns)),
        "fell": fallen(run.qpos[-1]),
        "duration_s": duration,
        "distance_m": distance,
        "speed_mps": float((run.qpos[touchdowns[-1], 0] - run.qpos[0, 0]) / walked) if len(touchdowns) else 0.0,
        "gait_speed_mps": float(reference.speed),
        "step_time_s": float(np.mean(np.diff(run.t[touchdowns]))) if len(touchdowns) > 1 else None,
        "gait_step_time_s": float(reference.step_time),
        "step_lengths_m": np.diff(np.array([run.feet[k, 1 - run.stance[k], 0] for k in touchdowns])).tolist(),
        "tracking_error_rad": {
            "rms": float(np.sqrt(np.mean(errors[settled] ** 2))),
            "max": float(np.abs(errors[settled]).max()),
            "max_including_impacts": float(np.abs(errors).max()),
            "per_joint_rms_H1_K1_H2_K2": np.sqrt(np.mean(errors[settled] ** 2, axis=0)).tolist(),
        },
        "stance_foot_slip_m": max(slips) if slips else 0.0,
        "max_friction_use": float(np.max(np.abs(stance_force[loaded, 0]) / stance_force[loaded, 2]))
        if loaded.any() else None,
        "min_hip_height_m": float(run.qpos[:, 1].min()),
        "max_abs_torque_Nm": dict(zip(names, np.abs(torque[:, sagittal]).max(axis=0).tolist())),
        "gait_max_abs_torque_Nm": float(np.abs(np.asarray(reference.torque)).max()),
        "max_abs_held_torque_Nm": float(np.abs(np.delete(torque, sagittal, axis=1)).max()),
        "max_abs_lateral_angle_rad": float(np.abs(run.qpos[:, [
            int(mj_model.joint(f"{j}_{s}").qposadr[0]) for j in ("hip_yaw", "hip_roll", "ankle_roll")
            for s in SIDES]]).max()),
        "gains": {k: float(v) for k, v in dataclasses.asdict(gains).items()},
        "timestep_s": dt,
        "touchdowns": compare_touchdowns(run, mj_model, layout, gains),
    }
