"""The periodic one-step gait problem of planar-step.md, transcribed so that its answer does not move
with the grid.

Parameterisation (see README, "Gait optimiser"): the four actuated joints are *prescribed* as clamped
B-splines q_a(s) in normalised time s = t / t_f, with their analytic first and second derivatives.
Only the stance angle theta is integrated: its zero dynamics, the unactuated row of
M(q) qdd + h(q, qd) = B u, solved for theta_dd given (q_a, qd_a, qdd_a), by classical Runge-Kutta
(4th order) on a grid aligned with the spline's knots (``substeps`` equal steps per knot span, so the
integrand is smooth inside every step and the method keeps its order). The zero dynamics may be
*multiple-shot* (``GaitSettings.segments`` > 1): every segment of knot spans starts from its own
stance state (theta, theta_dot), a decision variable, and continuity of theta and theta_dot across
segment boundaries is an equality constraint. Integrating the unstable stance pendulum open loop over
the whole step keeps the collocation optimum out of reach (a fitted one drifted 0.1 rad by touchdown);
over one span (about 1/16 of the step) it cannot drift. The torques are read from the
actuated rows at each grid point, the cost J = integral of u^T u dt is taken by composite Simpson
quadrature (4th order) and every path constraint is checked at every grid point, the start and the end
included. The start state is the spline's own value and slope, so the state, the torque, the ground
force and the power at t = 0 are those of a continuous trajectory. Relabelling makes the first control
point the mirror of the last, so the actuated positions are periodic by construction (hybrid zero
dynamics, Westervelt et al. 2003); the stance angle and all five rates are periodic through equality
constraints.

Decision vector x (shape (2 segments + 4 (spans + degree - 1),)): stance angle (rad) and rate (rad/s)
at the start, then the B-spline control points 1..n of (H1, K1, H2, K2) in rad, n = spans + degree - 1
(control point 0 mirrors control point n), then the stance angle and rate at the start of segments
1..segments-1 (the shooting nodes; none for single shooting).

:func:`refined` gives the same problem on a grid ``REFINEMENT`` times finer; a solution is reported
with its cost and violations there (:mod:`biped_jax.gait_solver`).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from scipy.interpolate import BSpline, CubicHermiteSpline

from biped_jax import checks
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
DYNAMICS = ("chain", "mjx")

#: Friction coefficient standing for "no friction limit" (Kelly's benchmark), the largest accepted.
NO_FRICTION_LIMIT = 1e3
#: Power limit standing for "no power limit" (Kelly's benchmark, the co-design's mass study), W.
NO_POWER_LIMIT = 1e6

#: The refinement check re-simulates a solution on a grid this many times finer.
REFINEMENT = 4


def _check_number(name: str, value, low: float, high: float, unit: str) -> None:
    checks.number_in(f"GaitSettings.{name}", value, low, high, unit)


@dataclasses.dataclass(frozen=True)
class GaitSettings:
    """What fixes array shapes and the problem's constant bounds (static: one compile per settings).

    Attributes:
      spans: knot spans of the joint references' B-splines.
      degree: their polynomial degree (2 to 7; 3, cubic, by default: accelerations continuous).
      substeps: Runge-Kutta steps per knot span, even (Simpson's rule pairs them); the grid has
        ``spans * substeps`` steps and every path constraint is checked at its points.
      grading: knot placement between uniform (0) and cosine-clustered at both impacts (1), where the
        optimal gait moves fastest.
      torque_bound: |u_i| <= torque_bound, N m.
      friction: friction coefficient of the stance foot and the impact.
      knee_max: largest knee flexion, rad (the smallest is 0).
      dynamics: "chain" (the closed-form planar-chain dynamics of :mod:`biped_jax.planar_chain`, equal
        to MJX's to rounding and several times faster to compile and differentiate) or "mjx" (MJX's
        forward pipeline). The touchdown impact map is MJX's in both.
      segments: shooting segments of the stance angle's zero dynamics, dividing ``spans``: 1 is single
        shooting from the start state; more start each segment (a run of spans / segments knot
        spans) from its own stance state, a decision variable, with continuity as equality
        constraints (multiple shooting: the unstable stance pendulum cannot drift over a segment).

    Raises ValueError naming the field, its value and the allowed range.
    """

    spans: int = 16
    degree: int = 3
    substeps: int = 8
    grading: float = 0.5
    torque_bound: float = 20.0
    friction: float = 0.8
    knee_max: float = 2.6
    dynamics: str = "chain"
    segments: int = 1

    def __post_init__(self):
        if self.dynamics not in DYNAMICS:
            raise ValueError(f"GaitSettings.dynamics must be one of {DYNAMICS}, got {self.dynamics!r}")
        checks.gait_space(self.spans, self.degree, self.substeps, prefix="GaitSettings.")
        checks.integer_in("GaitSettings.segments", self.segments, 1, self.spans)
        if self.spans % self.segments:
            raise ValueError(f"GaitSettings.segments must divide spans ({self.spans}), got {self.segments}")
        if isinstance(self.grading, bool) or not isinstance(self.grading, (int, float)) \
                or not 0.0 <= self.grading <= 1.0:
            raise ValueError(f"GaitSettings.grading must be in [0, 1], got {self.grading!r}")
        _check_number("torque_bound", self.torque_bound, 0.0, math.inf, "N m")
        # 1e3 is the "no friction limit" of Kelly's benchmark (kelly.NO_FRICTION_LIMIT): the cone then
        # only keeps F_z >= 0; a coefficient between 10 and that is a typo more likely than a foot
        _check_number("friction", self.friction, 0.0, NO_FRICTION_LIMIT, "(friction coefficient; 1e3: no limit)")
        _check_number("knee_max", self.knee_max, 0.0, math.pi, "rad")

    @property
    def control_points(self) -> int:
        """Control points per joint, the mirrored first one included."""
        return self.spans + self.degree

    @property
    def size(self) -> int:
        """Length of the decision vector: the stance state at every segment's start (the shooting
        nodes, 2 segments) and the free control points of the four joints."""
        return 2 * self.segments + 4 * (self.control_points - 1)

    @property
    def steps(self) -> int:
        """Runge-Kutta steps per walking step (grid intervals)."""
        return self.spans * self.substeps


def refined(settings: GaitSettings, factor: int = REFINEMENT) -> GaitSettings:
    """The same problem and decision vector on a grid ``factor`` times finer."""
    return dataclasses.replace(settings, substeps=settings.substeps * factor)


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


def check_problem(speed, power_limit, step_length, mass_class: str = "12kg") -> None:
    """Raises ValueError naming a speed (m/s), power limit (W) or step length (m) that is not a finite
    positive number (scalars or arrays, one value per problem), or a step beyond the legs' reach."""
    for name, value, unit in (("speed", speed, "m/s"), ("power_limit", power_limit, "W"),
                              ("step_length", step_length, "m")):
        values = np.asarray(value, dtype=float)
        if not np.all(np.isfinite(values) & (values > 0)):
            raise ValueError(f"{name} must be positive, got {values.tolist()} ({unit}; finite)")
    reach = 2 * PLANAR_SPECS[mass_class].leg_length
    if np.any(np.asarray(step_length) >= reach):
        raise ValueError(f"step_length {np.asarray(step_length).tolist()} m is beyond the legs' reach "
                         f"(< {reach:.3g} m)")


def gait_model(mass_class: str, speed: float, power_limit: float, step_length: float = 0.2) -> GaitModel:
    """A problem of planar-step.md for the biped ``mass_class`` ("12kg", "18kg" or "kelly") with ideal
    drives (the paper's problem; ``biped_jax.codesign.gait_model`` fits real ones); raises ValueError
    naming a non-positive speed, limit or length, or a step beyond the legs' reach."""
    for name, value, unit in (("speed", speed, "m/s"), ("power_limit", power_limit, "W"),
                              ("step_length", step_length, "m")):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
            raise ValueError(f"{name} must be a number ({unit}), got {value!r}")
    design = hs.planar_design(mass_class)  # first: it names an unknown mass class
    check_problem(speed, power_limit, step_length, mass_class)
    return GaitModel(design=design, speed=jnp.asarray(float(speed)),
                     step_length=jnp.asarray(float(step_length)),
                     power_limit=jnp.asarray(float(power_limit)),
                     drives=drive_model.ideal_drives())


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class GaitTrajectory:
    """The simulated step, sampled at the T + 1 grid points (t = 0 and t = t_f included).

    Attributes:
      t: sample times, shape (T + 1,), s (uniform within each knot span).
      weights: composite Simpson weights of the samples, shape (T + 1,), s: the integral of f over the
        step is weights . f.
      q, qd, qdd: pinned states and accelerations, shape (T + 1, 5).
      u: torques (H1, K1, H2, K2), shape (T + 1, 4), N m.
      ground_force: stance (F_x, F_z), shape (T + 1, 2), N.
      swing_foot: (x, z) of the swing foot, shape (T + 1, 2), m. heights: z of hip, knee1, knee2,
        shape (T + 1, 3), m.
      touchdown: the impact at t_f and the next step's start.
      swing_foot_velocity: (x, z) at touchdown, shape (2,), m/s.
      continuity: the multiple shooting's defects, shape (segments - 1, 2): the stance angle (rad)
        and rate (rad/s) integrated to the end of segment j minus the node of segment j + 1.
    """

    t: jax.Array
    weights: jax.Array
    q: jax.Array
    qd: jax.Array
    qdd: jax.Array
    u: jax.Array
    ground_force: jax.Array
    swing_foot: jax.Array
    heights: jax.Array
    touchdown: hs.Touchdown
    swing_foot_velocity: jax.Array
    continuity: jax.Array

    @property
    def joint_speed(self) -> jax.Array:
        """Actuated joint rates (H1, K1, H2, K2) at every sample, shape (T + 1, 4), rad/s."""
        return self.qd[..., ACTUATED_INDEX]

    @property
    def joint_power(self) -> jax.Array:
        """qdot_i u_i, shape (T + 1, 4), W."""
        return self.joint_speed * self.u


# ----------------------------------------------------------------------------- the joint references

def breakpoints(settings: GaitSettings) -> np.ndarray:
    """Knot-span boundaries in normalised time, shape (spans + 1,), from 0 to 1."""
    uniform = np.linspace(0.0, 1.0, settings.spans + 1)
    return (1 - settings.grading) * uniform + settings.grading * 0.5 * (1 - np.cos(np.pi * uniform))


def knot_vector(settings: GaitSettings) -> np.ndarray:
    """The clamped knot vector, shape (spans + 2 degree + 1,)."""
    inner = breakpoints(settings)
    k = settings.degree
    return np.concatenate([np.zeros(k), inner, np.ones(k)])


def grid(settings: GaitSettings) -> np.ndarray:
    """The integration grid in normalised time, shape (steps + 1,): ``substeps`` equal steps per span."""
    edges = breakpoints(settings)
    fractions = np.arange(settings.substeps) / settings.substeps
    inner = (edges[:-1, None] + np.diff(edges)[:, None] * fractions[None]).ravel()
    return np.concatenate([inner, [1.0]])


def simpson_weights(settings: GaitSettings) -> np.ndarray:
    """Composite Simpson weights on :func:`grid` for an integral over s in [0, 1], shape (steps + 1,)."""
    weights = np.zeros(settings.steps + 1)
    pattern = np.ones(settings.substeps + 1)
    pattern[1:-1:2], pattern[2:-1:2] = 4.0, 2.0
    for j, width in enumerate(np.diff(breakpoints(settings))):
        h = width / settings.substeps
        weights[j * settings.substeps:(j + 1) * settings.substeps + 1] += h / 3 * pattern
    return weights


@functools.lru_cache(maxsize=64)
def _basis_cached(knots: tuple, degree: int, points: tuple) -> tuple:
    # extrapolate=True evaluates s = 1 on the last span (the limit from the left) instead of NaN
    spline = BSpline(np.array(knots), np.eye(len(knots) - degree - 1), degree)
    s = np.clip(np.array(points), 0.0, 1.0)
    return (spline(s), spline.derivative(1)(s), spline.derivative(2)(s))


def basis(settings: GaitSettings, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """B-spline basis and its first two derivatives in s at points ``s`` (m,), each (m, control_points)."""
    return _basis_cached(tuple(knot_vector(settings)), settings.degree, tuple(np.asarray(s, dtype=float)))


def control_points(x: jax.Array, settings: GaitSettings) -> jax.Array:
    """All control points, shape (control_points, 4), rad: point 0 mirrors the last one."""
    free = x[2:2 + 4 * (settings.control_points - 1)].reshape(settings.control_points - 1, 4)
    return jnp.concatenate([free[-1, SWAP][None], free])


def stance_nodes(x: jax.Array, settings: GaitSettings) -> jax.Array:
    """The shooting nodes: stance angle (rad) and rate (rad/s) at the start of every segment,
    shape (segments, 2); row 0 is the step's start state."""
    later = x[2 + 4 * (settings.control_points - 1):].reshape(settings.segments - 1, 2)
    return jnp.concatenate([x[None, :2], later])


def segment_starts(settings: GaitSettings) -> np.ndarray:
    """Normalised times of the shooting nodes, shape (segments,): every (spans / segments)-th
    breakpoint, from 0."""
    return breakpoints(settings)[:-1:settings.spans // settings.segments]


def pack(stance: jax.Array, points: jax.Array) -> jax.Array:
    """The decision vector from the shooting nodes (segments, 2) and the free control points
    (control_points - 1, 4): the inverse of :func:`stance_nodes` and :func:`control_points`."""
    stance, points = jnp.asarray(stance), jnp.asarray(points)
    return jnp.concatenate([stance[0], points.ravel(), stance[1:].ravel()])


def reference(x: jax.Array, settings: GaitSettings, s) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The actuated joints' reference and its first two derivatives in normalised time at ``s`` (m,):
    q_a, dq_a/ds, d2q_a/ds2, each (m, 4) (divide by t_f and t_f^2 for time derivatives)."""
    points = control_points(x, settings)
    return tuple(jnp.asarray(b) @ points for b in basis(settings, s))


def greville(settings: GaitSettings) -> np.ndarray:
    """Greville abscissae, shape (control_points,): where each control point acts most, so that
    control points set to f(abscissae) give a spline close to f."""
    knots, k = knot_vector(settings), settings.degree
    return np.array([knots[i + 1:i + k + 1].mean() for i in range(settings.control_points)])


# ----------------------------------------------------------------------------- dynamics

def _assemble(theta, actuated):
    """Pinned coordinates (..., 5) from the stance coordinate (...,) and the actuated (..., 4)."""
    full = jnp.zeros(actuated.shape[:-1] + (5,), actuated.dtype)
    return full.at[..., 0].set(theta).at[..., ACTUATED_INDEX].set(actuated)


class _ChainDynamics:
    """Mass matrix, bias force, stance force, site positions, the swing foot's motion and the
    touchdown from :mod:`biped_jax.planar_chain` (closed forms, no MJX)."""

    def __init__(self, biped: hs.PlanarBiped):
        self.chain = planar_chain.PlanarChain.from_model(biped.pinned)
        self.pinned = biped.pinned

    def terms(self, q, qd):
        kinematics = planar_chain.kinematics(self.chain, self.pinned, q, qd)
        return (planar_chain.mass_matrix(self.chain, self.pinned, kinematics),
                planar_chain.bias_force(self.chain, self.pinned, kinematics, qd), kinematics)

    def outputs(self, q, qd, qdd, kinematics):
        force = planar_chain.root_force(self.chain, self.pinned, kinematics, qdd)
        return force, planar_chain.site_positions(self.chain, self.pinned, kinematics, _SITES)

    def swing_foot(self, q, qd):
        return planar_chain.site_motion(self.chain, self.pinned, q, qd, "foot2")

    def touchdown(self, q, qd):
        return hs.chain_touchdown(self.chain, self.pinned, q, qd)


class _MjxDynamics:
    """The same quantities from MJX's forward pipeline."""

    def __init__(self, biped: hs.PlanarBiped):
        self.biped, self.pinned = biped, biped.pinned
        self.template = mjx.make_data(biped.pinned)
        self.sites = jnp.array([mjx.name2id(biped.pinned, hs.robots.mujoco.mjtObj.mjOBJ_SITE, name)
                                for name in _SITES])

    def terms(self, q, qd):
        data = mjx.fwd_velocity(self.pinned, mjx.fwd_position(self.pinned, self.template.replace(qpos=q, qvel=qd)))
        return mjx.full_m(self.pinned, data), data.qfrc_bias - data.qfrc_passive, data

    def outputs(self, q, qd, qdd, data):
        force = hs.stance_force(self.pinned, data.replace(qacc=qdd))
        return force, data.site_xpos[self.sites][:, jnp.array([0, 2])]

    def swing_foot(self, q, qd):
        return hs.swing_foot(self.pinned, q, qd)

    def touchdown(self, q, qd):
        return hs.touchdown(self.biped, q, qd)


_SITES = ("foot2", "hip", "knee1", "knee2")


def stance_acceleration(mass, bias, actuated_acceleration):
    """The zero dynamics: theta_dd from the unactuated row of M qdd + bias = B u. mass (5, 5), bias =
    qfrc_bias - qfrc_passive (5,), actuated_acceleration (4,) in (H1, K1, H2, K2) order."""
    a = ACTUATED_INDEX
    return -(mass[0, a] @ actuated_acceleration + bias[0]) / mass[0, 0]


def actuated_torque(mass, bias, qdd):
    """Torques (H1, K1, H2, K2) from the actuated rows of M qdd + bias = B u, (4,), N m."""
    a = ACTUATED_INDEX
    return mass[a] @ qdd + bias[a]


def _dynamics(biped, settings):
    return (_ChainDynamics if settings.dynamics == "chain" else _MjxDynamics)(biped)


def simulate(x: jax.Array, model: GaitModel, biped: hs.PlanarBiped, settings: GaitSettings) -> GaitTrajectory:
    """One rollout of the step (pure; vmap over x and model): the prescribed joints, the stance
    angle's zero dynamics by RK4 from every shooting node over its segment (all segments at once),
    the outputs at every grid point (a segment's first point takes its node's state)."""
    biped = hs.with_design(biped, model.design)
    dynamics = _dynamics(biped, settings)
    step_time = model.step_length / model.speed
    segments, per_segment = settings.segments, settings.steps // settings.segments
    s = grid(settings)
    midpoints = 0.5 * (s[1:] + s[:-1])
    scale = jnp.stack([1.0, 1.0 / step_time, 1.0 / step_time**2])[:, None, None]
    at_grid = jnp.stack(reference(x, settings, s)) * scale          # (3, T + 1, 4): q_a, qd_a, qdd_a
    at_mid = jnp.stack(reference(x, settings, midpoints)) * scale   # (3, T, 4)
    h = jnp.asarray(np.diff(s)) * step_time

    def acceleration(theta, theta_dot, ref):
        q, qd = _assemble(theta, ref[0]), _assemble(theta_dot, ref[1])
        mass, bias, _ = dynamics.terms(q, qd)
        return stance_acceleration(mass, bias, ref[2])

    def rk4(state, inputs):
        start, middle, end, dt = inputs
        theta, rate = state
        k1 = (rate, acceleration(theta, rate, start))
        k2 = (rate + 0.5 * dt * k1[1], acceleration(theta + 0.5 * dt * k1[0], rate + 0.5 * dt * k1[1], middle))
        k3 = (rate + 0.5 * dt * k2[1], acceleration(theta + 0.5 * dt * k2[0], rate + 0.5 * dt * k2[1], middle))
        k4 = (rate + dt * k3[1], acceleration(theta + dt * k3[0], rate + dt * k3[1], end))
        theta_next = theta + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        rate_next = rate + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        return (theta_next, rate_next), jnp.stack([theta_next, rate_next])

    def by_segment(a):  # (3, T, 4) -> (segments, T / segments, 3, 4)
        return jnp.swapaxes(a, 0, 1).reshape(segments, per_segment, 3, 4)

    def shoot(node, starts, middles, ends, dt):
        return jax.lax.scan(rk4, (node[0], node[1]), (starts, middles, ends, dt))[1]

    nodes = stance_nodes(x, settings)
    after = jax.vmap(shoot)(nodes, by_segment(at_grid[:, :-1]), by_segment(at_mid),
                            by_segment(at_grid[:, 1:]), h.reshape(segments, per_segment))  # (segments, T / segments, 2)
    stance = jnp.concatenate([jnp.concatenate([nodes[:, None], after[:, :-1]], axis=1).reshape(-1, 2),
                              after[-1, -1:]])                            # (T + 1, 2)

    def outputs(theta_k, rate_k, ref):
        q, qd = _assemble(theta_k, ref[0]), _assemble(rate_k, ref[1])
        mass, bias, state = dynamics.terms(q, qd)
        qdd = _assemble(stance_acceleration(mass, bias, ref[2]), ref[2])
        force, positions = dynamics.outputs(q, qd, qdd, state)
        return q, qd, qdd, actuated_torque(mass, bias, qdd), force, positions

    q, qd, qdd, u, force, positions = jax.vmap(outputs)(stance[:, 0], stance[:, 1], jnp.swapaxes(at_grid, 0, 1))
    _, foot_velocity = dynamics.swing_foot(q[-1], qd[-1])
    return GaitTrajectory(
        t=jnp.asarray(s) * step_time, weights=jnp.asarray(simpson_weights(settings)) * step_time,
        q=q, qd=qd, qdd=qdd, u=u, ground_force=force, swing_foot=positions[:, 0], heights=positions[:, 1:, 1],
        touchdown=dynamics.touchdown(q[-1], qd[-1]), swing_foot_velocity=foot_velocity,
        continuity=after[:-1, -1] - nodes[1:])


# ----------------------------------------------------------------------------- constraints

#: Constraint groups: name -> (kind, unit). Each group's violation is reported in its own unit.
CONSTRAINT_GROUPS = {
    "continuity_angle": ("equality", "rad"),
    "continuity_rate": ("equality", "rad/s"),
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
        "continuity_angle": tr.continuity[:, 0],
        "continuity_rate": tr.continuity[:, 1],
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
    """J = integral of u^T u dt over the step (composite Simpson), N^2 m^2 s."""
    return trajectory.weights @ jnp.sum(trajectory.u**2, axis=-1)


def cost_residuals(trajectory: GaitTrajectory, drives: drive_model.JointDrives) -> jax.Array:
    """r with r . r = the objective, the drives' Joule energy (J = integral of u^T u for ideal
    drives), flattened, shape (4 (T + 1),): Simpson's weights are positive, so the quadrature stays a
    sum of squares."""
    return drive_model.joule_residuals(trajectory.u, trajectory.joint_speed, drives,
                                       trajectory.weights[:, None]).ravel()


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


# ----------------------------------------------------------------------------- starting points

@dataclasses.dataclass(frozen=True)
class StartFamily:
    """A family of heuristic gaits: the shape of a start, in the joint space (no solution involved).

    Attributes:
      name: label. swing_lift: how far the swing knee flexes mid-step (rad, roughly). stance_knee:
        flexion of the stance knee mid-stance, rad. torso_pitch: torso lean forward, rad (hips flex by
        it). rate_factor: the stance angle's start rate as a multiple of v / leg length.
        impact_knee: flexion of the stance knee at touchdown, rad (by the mirror, the swing knee's at
        the start), blended linearly in between.
    """

    name: str
    swing_lift: float = 0.5
    stance_knee: float = 0.0
    torso_pitch: float = 0.0
    rate_factor: float = 1.3
    impact_knee: float = 0.0


#: The multistart's families (:func:`initial_guess`), spanning the gait families seen in this problem:
#: stance knee straight or flexed, low or high swing, torso upright or leaning, slow or fast vault.
START_FAMILIES = (
    StartFamily("straight stance"),
    StartFamily("flexed stance", stance_knee=0.25),
    StartFamily("high swing", swing_lift=0.9),
    StartFamily("low swing, fast vault", swing_lift=0.3, rate_factor=1.7),
    StartFamily("leaning torso", torso_pitch=0.15, stance_knee=0.1),
    StartFamily("slow vault, flexed", stance_knee=0.15, swing_lift=0.7, rate_factor=1.0),
)

#: Families that land on a flexed stance knee (``impact_knee``), the axis along which the cheapest gaits
#: of this problem lie: measured on M2 without a power limit (multiple shooting, 16 spans), these three
#: reached J = 2.49-2.73 where every family of :data:`START_FAMILIES` stopped at 4.3-5.2 (README,
#: "Transcription and starts"). The study starts from these and the first of START_FAMILIES.
IMPACT_FAMILIES = (
    StartFamily("flexed stance, flexed impact", stance_knee=0.25, impact_knee=0.45),
    StartFamily("straight stance, flexed impact", impact_knee=0.45),
    StartFamily("high swing, flexed impact", swing_lift=0.9, impact_knee=0.3),
)


def initial_guess(model: GaitModel, settings: GaitSettings, leg_length: float = 0.29,
                  swing_lift: float | None = None, family: StartFamily = START_FAMILIES[0]) -> jax.Array:
    """A heuristic start of ``family``: legs mirrored about the vertical at the ends, the swing knee and
    hip flexed mid-step, the stance knee flexed mid-stance, the stance leg vaulting forward from
    ``-asin(L / 2 l)`` to its mirror along a parabola whose start rate is the family's. The curve is
    sampled at the Greville abscissae, the vault at the shooting nodes (:func:`segment_starts`).
    Shape (settings.size,)."""
    lift = family.swing_lift if swing_lift is None else swing_lift
    stance = -jnp.arcsin(0.5 * model.step_length / leg_length)
    # (H1, K1, H2, K2): a hip angle is the thigh against the torso, so leaning the torso forward by
    # ``torso_pitch`` flexes both hips by it.
    start = jnp.stack([stance, 0.0, -stance, family.impact_knee]) \
        + family.torso_pitch * jnp.array([-1.0, 0.0, -1.0, 0.0])
    end = start[SWAP]
    s = jnp.asarray(greville(settings))[1:, None]
    bump = 4 * s * (1 - s) * (lift * jnp.array([0.0, 0.0, -0.6, 1.0])
                              + family.stance_knee * jnp.array([0.5, 1.0, 0.0, 0.0]))
    coefficients = start + s * (end - start) + bump
    step_time = model.step_length / model.speed
    rate = family.rate_factor * model.speed / leg_length
    # theta(s) = stance (1 - 2 s) + curvature s (1 - s), with theta'(0) = rate t_f
    curvature = rate * step_time + 2 * stance
    knots = jnp.asarray(segment_starts(settings))
    theta = stance * (1 - 2 * knots) + curvature * knots * (1 - knots)
    theta_rate = (-2 * stance + curvature * (1 - 2 * knots)) / step_time
    return pack(jnp.stack([theta, theta_rate], axis=-1), coefficients)


def project(x: np.ndarray, source: GaitSettings, target: GaitSettings, trajectory: GaitTrajectory,
            samples: int = 400) -> np.ndarray:
    """The decision vector of ``source``'s space carried into ``target``'s (continuation from a coarse
    to a fine reference space): the control points by least squares on ``samples`` points (exact when
    the target's breakpoints contain the source's: the same grading, spans a multiple, since the fine
    space then contains the coarse curve), the shooting nodes from ``trajectory`` (x simulated in
    ``source``) by cubic Hermite interpolation of its stance angle and rate at the target's segment
    starts. Shape (target.size,)."""
    x = np.asarray(x, dtype=float)
    s = np.linspace(0.0, 1.0, samples)
    curve = np.asarray(reference(jnp.asarray(x), source, s)[0])
    points = np.linalg.lstsq(basis(target, s)[0], curve, rcond=None)[0]
    points[-1] = 0.5 * (points[-1] + points[0][SWAP])  # keep the mirror exact
    t = np.asarray(trajectory.t)
    # at a segment boundary the grid point carries the next node (the previous segment's end differs
    # from it by the defect); the grid's times are strictly increasing, as the interpolant needs
    angle = CubicHermiteSpline(t, np.asarray(trajectory.q)[:, 0], np.asarray(trajectory.qd)[:, 0])
    rate = CubicHermiteSpline(t, np.asarray(trajectory.qd)[:, 0], np.asarray(trajectory.qdd)[:, 0])
    starts = segment_starts(target) * t[-1]
    nodes = np.stack([angle(starts), rate(starts)], axis=-1)
    nodes[0] = x[:2]
    return np.asarray(pack(nodes, points[1:]))
