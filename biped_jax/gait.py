"""The periodic one-step gait problem of planar-step.md, by single shooting through MJX.

Parameterisation (see README, "Gait optimiser"): the four actuated joints follow Bezier polynomials in
normalised time s = t / t_f, tracked inside the rollout by collocated partial feedback linearisation
(Spong 1994) that commands, at every Euler step, the acceleration putting the joints exactly on the
next reference sample (deadbeat in the discrete dynamics). Only the stance angle evolves open loop,
so the shooting sensitivity is that of an inverted pendulum, not of the whole chain. Relabelling
makes the first Bezier coefficients the mirror of the last ones, so the actuated positions are
periodic by construction (hybrid zero dynamics, Westervelt et al. 2003).

Decision vector x (shape (2 + 4 n,), n the Bezier degree): stance angle (rad) and rate (rad/s) at the
start, then the Bezier coefficients 1..n of (H1, K1, H2, K2) in rad.

Torques, cost, power and the tables all use the torques the controller applies in the rollout.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax import drives as drive_model
from biped_jax import hybrid_step as hs
from biped_jax import planar_chain
from biped_jax.design import Design
from biped_jax.robot_specs import PLANAR_SPECS

mjx = hs.mjx

#: Pinned coordinates of the actuated joints in (H1, K1, H2, K2) order.
ACTUATED_INDEX = np.array([2, 1, 3, 4])
#: Relabelling in (H1, K1, H2, K2) order: the next step's (H1, K1, H2, K2) is this step's (H2, K2, H1, K1).
SWAP = np.array([2, 3, 0, 1])

# Scales that bring each constraint group to order one; the solver's scaled tolerance times these
# stays below 1e-4 in the group's own unit.
LENGTH_SCALE = 0.1  # m
RATE_SCALE = 1.0  # rad/s
FORCE_SCALE = 10.0  # N
IMPULSE_SCALE = 1.0  # N s
POWER_SCALE = 10.0  # W
TORQUE_SCALE = 10.0  # N m
VOLTAGE_SCALE = 10.0  # V

#: The single-support dynamics a rollout can use (:class:`GaitSettings`).
DYNAMICS = ("mjx", "chain")

#: Power limit standing for "no power limit" (Kelly's benchmark, the co-design's mass study), W.
NO_POWER_LIMIT = 1e6


@dataclasses.dataclass(frozen=True)
class GaitSettings:
    """What fixes array shapes and the problem's constant bounds (static: one compile per settings).

    Attributes:
      steps: Euler steps per walking step.
      degree: Bezier degree of the joint references.
      torque_bound: |u_i| <= torque_bound, N m.
      friction: friction coefficient of the stance foot and the impact.
      knee_max: largest knee flexion, rad (the smallest is 0).
      dynamics: "mjx" (MJX's forward pipeline) or "chain" (the closed-form planar-chain dynamics of
        :mod:`biped_jax.planar_chain`, equal to MJX's to rounding, about 10x faster to differentiate
        on a CPU and 4x faster to compile). The touchdown impact map is MJX's in both.
    """

    steps: int = 60
    degree: int = 6
    torque_bound: float = 20.0
    friction: float = 0.8
    knee_max: float = 2.6
    dynamics: str = "mjx"

    def __post_init__(self):
        if self.dynamics not in DYNAMICS:
            raise ValueError(f"dynamics must be one of {DYNAMICS}, got {self.dynamics!r}")

    @property
    def size(self) -> int:
        return 2 + 4 * self.degree


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class GaitModel:
    """One problem instance (traced: batch these to solve many models with one program).

    Attributes:
      design: link masses etc. of the biped.
      speed: average forward speed v, m/s.
      step_length: L, m.
      power_limit: M_W, W.
      drives: the joints' drives. The objective is their Joule energy, the integral of R i^2 (J); with
        :func:`~biped_jax.drives.ideal_drives` (the default) that is the paper's J = integral of
        u^T u (N^2 m^2 s) and the voltage constraint is inactive.
    """

    design: Design
    speed: jax.Array
    step_length: jax.Array
    power_limit: jax.Array
    drives: drive_model.JointDrives


def gait_model(mass_class: str, speed: float, power_limit: float, step_length: float = 0.2) -> GaitModel:
    """A problem of planar-step.md for the biped ``mass_class`` ("12kg", "18kg" or "kelly") with ideal
    drives (the paper's problem; ``biped_jax.codesign.gait_model`` fits real ones); raises ValueError
    naming a non-positive speed, limit or length, or a step beyond the legs' reach."""
    for name, value in (("speed", speed), ("power_limit", power_limit), ("step_length", step_length)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be positive, got {value!r}")
    design = hs.planar_design(mass_class)
    reach = 2 * PLANAR_SPECS[mass_class].leg_length
    if step_length >= reach:
        raise ValueError(f"step_length {step_length} m is beyond the legs' reach (< {reach:.3g} m)")
    return GaitModel(design=design, speed=jnp.asarray(float(speed)),
                     step_length=jnp.asarray(float(step_length)),
                     power_limit=jnp.asarray(float(power_limit)),
                     drives=drive_model.ideal_drives())


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class GaitTrajectory:
    """The simulated step.

    Attributes:
      t: sample times, shape (T + 1,), s. q, qd: pinned states, shape (T + 1, 5).
      qdd: accelerations, shape (T, 5). u: torques (H1, K1, H2, K2), shape (T, 4), N m.
      ground_force: stance (F_x, F_z), shape (T, 2), N.
      swing_foot: (x, z) of the swing foot, shape (T + 1, 2), m. heights: z of hip, knee1, knee2,
        shape (T + 1, 3), m.
      touchdown: the impact at t_f and the next step's start.
      swing_foot_velocity: (x, z) at touchdown, shape (2,), m/s.
      q0, qd0: the start state, shape (5,).
    """

    t: jax.Array
    q: jax.Array
    qd: jax.Array
    qdd: jax.Array
    u: jax.Array
    ground_force: jax.Array
    swing_foot: jax.Array
    heights: jax.Array
    touchdown: hs.Touchdown
    swing_foot_velocity: jax.Array

    @property
    def joint_speed(self) -> jax.Array:
        """Actuated joint rates (H1, K1, H2, K2) at steps 0..T-1, shape (T, 4), rad/s."""
        return self.qd[:-1, ACTUATED_INDEX]

    @property
    def joint_power(self) -> jax.Array:
        """qdot_i u_i, shape (T, 4), W."""
        return self.joint_speed * self.u


def bezier_coefficients(x: jax.Array, settings: GaitSettings) -> jax.Array:
    """All Bezier coefficients, shape (degree + 1, 4), rad: coefficient 0 mirrors coefficient n."""
    free = x[2:].reshape(settings.degree, 4)
    return jnp.concatenate([free[-1, SWAP][None], free])


def bezier(coefficients: jax.Array, s: jax.Array) -> jax.Array:
    """Bezier polynomial at s in [0, 1]: coefficients (n + 1, k), s (m,) -> (m, k)."""
    n = coefficients.shape[0] - 1
    k = np.arange(n + 1)
    binomial = np.array([math.comb(n, i) for i in k], dtype=float)
    basis = binomial * s[:, None] ** k * (1 - s[:, None]) ** (n - k)
    return basis @ coefficients


def bezier_rate(coefficients: jax.Array, s: jax.Array) -> jax.Array:
    """d/ds of :func:`bezier`, shape (m, k)."""
    n = coefficients.shape[0] - 1
    return n * bezier(coefficients[1:] - coefficients[:-1], s)


def _pinned_model(biped: hs.PlanarBiped, dt):
    # Damping, if a design adds it, is explicit so that the commanded acceleration is met exactly.
    pinned = hs.with_timestep(biped.pinned, dt)
    return pinned.replace(opt=pinned.opt.replace(
        disableflags=pinned.opt.disableflags | mjx.DisableBit.EULERDAMP))


def feedback_linearising_torque(mass, bias, desired):
    """Torques (H1, K1, H2, K2) that give the actuated coordinates the accelerations ``desired``.

    Collocated partial feedback linearisation: the unactuated stance row gives its acceleration,
    the actuated rows the torques. mass (5, 5); bias = qfrc_bias - qfrc_passive, (5,); desired (4,).
    """
    a, s = ACTUATED_INDEX, 0
    stance_acceleration = -(mass[s, a] @ desired + bias[s]) / mass[s, s]
    return mass[a][:, a] @ desired + mass[a, s] * stance_acceleration + bias[a]


_SITES = ("foot2", "hip", "knee1", "knee2")


def _desired_acceleration(q, qd, target, dt):
    """Actuated accelerations that put the joints on ``target`` after one Euler step, (4,)."""
    return ((target - q[ACTUATED_INDEX]) / dt - qd[ACTUATED_INDEX]) / dt


def _mjx_step(biped, pinned, dt):
    """One tracked Euler step through MJX's pipeline: (q, qd), target -> next state, outputs."""
    template = mjx.make_data(pinned)
    sites = jnp.array([mjx.name2id(pinned, hs.robots.mujoco.mjtObj.mjOBJ_SITE, name) for name in _SITES])

    @jax.checkpoint
    def step(state, target):
        q, qd = state
        data = mjx.fwd_velocity(pinned, mjx.fwd_position(pinned, template.replace(qpos=q, qvel=qd)))
        u = feedback_linearising_torque(mjx.full_m(pinned, data), data.qfrc_bias - data.qfrc_passive,
                                        _desired_acceleration(q, qd, target, dt))
        data = mjx.fwd_acceleration(pinned, mjx.fwd_actuation(pinned, data.replace(ctrl=u)))
        data = data.replace(qacc=data.qacc_smooth)
        force = hs._stance_force(pinned, data)
        positions = data.site_xpos[sites]
        data = mjx.euler(pinned, data)
        return (data.qpos, data.qvel), (data.qpos, data.qvel, data.qacc, u, force, positions)
    return step


def _chain_step(biped, pinned, dt):
    """The same step with the closed-form planar-chain dynamics (explicit damping, as with
    ``EULERDAMP`` disabled)."""
    chain = planar_chain.PlanarChain.from_model(biped.pinned)

    @jax.checkpoint
    def step(state, target):
        q, qd = state
        kinematics = planar_chain.kinematics(chain, pinned, q, qd)
        mass = planar_chain.mass_matrix(chain, pinned, kinematics)
        bias = planar_chain.bias_force(chain, pinned, kinematics, qd)
        u = feedback_linearising_torque(mass, bias, _desired_acceleration(q, qd, target, dt))
        qdd = jnp.linalg.solve(mass, planar_chain.actuated_force(chain, u) - bias)
        force = planar_chain.root_force(chain, pinned, kinematics, qdd)
        xz = planar_chain.site_positions(chain, pinned, kinematics, _SITES)
        positions = jnp.stack([xz[:, 0], jnp.zeros_like(xz[:, 0]), xz[:, 1]], axis=-1)
        q_next, qd_next = planar_chain.euler(q, qd, qdd, dt)
        return (q_next, qd_next), (q_next, qd_next, qdd, u, force, positions)
    return step


def simulate(x: jax.Array, model: GaitModel, biped: hs.PlanarBiped, settings: GaitSettings) -> GaitTrajectory:
    """One rollout of the step with feedback inside (pure; vmap over x and model)."""
    biped = hs.with_design(biped, model.design)
    step_time = model.step_length / model.speed
    dt = step_time / settings.steps
    pinned = _pinned_model(biped, dt)
    coefficients = bezier_coefficients(x, settings)
    s = jnp.linspace(0.0, 1.0, settings.steps + 1)
    reference = bezier(coefficients, s)
    q0 = jnp.zeros(5).at[0].set(x[0]).at[ACTUATED_INDEX].set(reference[0])
    qd0 = jnp.zeros(5).at[0].set(x[1]).at[ACTUATED_INDEX].set(
        bezier_rate(coefficients, s[:1])[0] / step_time)
    step = (_chain_step if settings.dynamics == "chain" else _mjx_step)(biped, pinned, dt)
    (q_end, qd_end), (q, qd, qdd, u, force, positions) = jax.lax.scan(step, (q0, qd0), reference[1:])
    foot_end, foot_velocity = hs.swing_foot(pinned, q_end, qd_end)
    end_positions = jnp.stack([hs.site_position(pinned, q_end, name) for name in _SITES])
    positions = jnp.concatenate([positions, end_positions[None]])
    return GaitTrajectory(
        t=dt * jnp.arange(settings.steps + 1),
        q=jnp.concatenate([q0[None], q]), qd=jnp.concatenate([qd0[None], qd]), qdd=qdd, u=u,
        ground_force=force, swing_foot=positions[:, 0, jnp.array([0, 2])], heights=positions[:, 1:, 2],
        touchdown=hs.touchdown(biped, q_end, qd_end), swing_foot_velocity=foot_velocity)


# ----------------------------------------------------------------------------- constraints

#: Constraint groups: name -> (kind, unit). Each group's violation is reported in its own unit.
CONSTRAINT_GROUPS = {
    "touchdown_position": ("equality", "m"),
    "periodicity_angle": ("equality", "rad"),
    "periodicity_rate": ("equality", "rad/s"),
    "swing_foot_height": ("inequality", "m"),
    "touchdown_descending": ("inequality", "m/s"),
    "heights": ("inequality", "m"),
    "knee_range": ("inequality", "rad"),
    "vertical_force": ("inequality", "N"),
    "friction_cone": ("inequality", "N"),
    "torque_bound": ("inequality", "N m"),
    "power_limit": ("inequality", "W"),
    "impact_impulse": ("inequality", "N s"),
    "liftoff": ("inequality", "m/s"),
    "voltage": ("inequality", "V"),
}


def constraint_groups(trajectory: GaitTrajectory, model: GaitModel, settings: GaitSettings) -> dict:
    """Each group's residuals in its own unit: equalities (= 0) and inequalities (<= 0)."""
    tr, impact = trajectory, trajectory.touchdown
    knees = tr.q[:, jnp.array([1, 4])]
    fx, fz = tr.ground_force[:, 0], tr.ground_force[:, 1]
    lx, lz = impact.impulse
    power = tr.joint_power
    return {
        "touchdown_position": jnp.array([tr.swing_foot[-1, 0] - model.step_length, tr.swing_foot[-1, 1]]),
        "periodicity_angle": impact.q[:1] - tr.q[0, :1],
        "periodicity_rate": impact.qd - tr.qd[0],
        "swing_foot_height": -tr.swing_foot[1:-1, 1],
        "touchdown_descending": tr.swing_foot_velocity[1:],
        "heights": -tr.heights.ravel(),
        "knee_range": jnp.concatenate([-knees.ravel(), (knees - settings.knee_max).ravel()]),
        "vertical_force": -fz,
        "friction_cone": jnp.concatenate([fx - settings.friction * fz, -fx - settings.friction * fz]),
        "torque_bound": (jnp.abs(tr.u) - settings.torque_bound).ravel(),
        "power_limit": (jnp.abs(power) - model.power_limit).ravel(),
        "impact_impulse": jnp.array([-lz, lx - settings.friction * lz, -lx - settings.friction * lz]),
        "liftoff": -impact.old_stance_foot_velocity[1:],
        "voltage": drive_model.voltage_excess(tr.u, tr.joint_speed, model.drives).ravel(),
    }


_SCALES = {"m": LENGTH_SCALE, "rad": 1.0, "rad/s": RATE_SCALE, "m/s": LENGTH_SCALE, "N": FORCE_SCALE,
           "N m": TORQUE_SCALE, "W": POWER_SCALE, "N s": IMPULSE_SCALE, "V": VOLTAGE_SCALE}


def scaled_constraints(groups: dict) -> tuple[jax.Array, jax.Array]:
    """(equalities, inequalities), each concatenated and scaled to order one."""
    equalities, inequalities = [], []
    for name, (kind, unit) in CONSTRAINT_GROUPS.items():
        value = groups[name] / _SCALES[unit]
        (equalities if kind == "equality" else inequalities).append(value)
    return jnp.concatenate(equalities), jnp.concatenate(inequalities)


def cost(trajectory: GaitTrajectory) -> jax.Array:
    """J = integral of u^T u dt over the step, N^2 m^2 s."""
    dt = trajectory.t[1] - trajectory.t[0]
    return dt * jnp.sum(trajectory.u**2)


def cost_residuals(trajectory: GaitTrajectory, drives: drive_model.JointDrives) -> jax.Array:
    """r with r . r = the objective, the drives' Joule energy (J = integral of u^T u for ideal
    drives), flattened, shape (4 T,)."""
    dt = trajectory.t[1] - trajectory.t[0]
    return drive_model.joule_residuals(trajectory.u, trajectory.joint_speed, drives, dt).ravel()


def joule_energy(trajectory: GaitTrajectory, drives: drive_model.JointDrives) -> jax.Array:
    """Integral of R i^2 over the step summed over the joints, J (= J for ideal drives)."""
    residuals = cost_residuals(trajectory, drives)
    return residuals @ residuals


def violations(groups: dict) -> dict:
    """Largest violation of each group in its own unit (0 when satisfied)."""
    out = {}
    for name, (kind, _) in CONSTRAINT_GROUPS.items():
        value = jnp.abs(groups[name]) if kind == "equality" else jnp.maximum(groups[name], 0.0)
        out[name] = jnp.max(value) if value.size else jnp.zeros(())
    return out


# ----------------------------------------------------------------------------- starting point

def initial_guess(model: GaitModel, settings: GaitSettings, leg_length: float = 0.29,
                  swing_lift: float = 0.5) -> jax.Array:
    """A heuristic start: straight legs mirrored about the vertical, swing knee and hip flexed mid-step,
    stance leg vaulting at the walking speed's rate. Shape (2 + 4 n,)."""
    stance = -jnp.arcsin(0.5 * model.step_length / leg_length)
    start = jnp.stack([stance, 0.0, -stance, 0.0])  # (H1, K1, H2, K2), torso upright
    end = start[SWAP]
    s = jnp.linspace(0.0, 1.0, settings.degree + 1)[1:, None]
    bump = 4 * s * (1 - s) * swing_lift * jnp.array([0.0, 0.0, -0.6, 1.0])
    coefficients = start + s * (end - start) + bump
    rate = 1.3 * model.speed / leg_length
    return jnp.concatenate([jnp.stack([stance, rate]), coefficients.ravel()])
