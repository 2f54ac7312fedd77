"""The gait problem's settings (reference space, grid, limits), one problem's data (:class:`GaitModel`,
a pytree batched over designs) and the simulated step (:class:`GaitTrajectory`)."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax import checks
from biped_jax.drives import model as drive_model
from biped_jax.dynamics import impact, interface
from biped_jax.dynamics import mjx_biped
from biped_jax.robots.design import Design
from biped_jax.robots.planar_biped import ACTUATED_INDEX
from biped_jax.robots.specs import PLANAR_SPECS

#: The single-support dynamics a rollout can use (:class:`GaitSettings`): the traceable backends.
DYNAMICS = interface.TRACEABLE

#: Friction coefficient standing for "no friction limit" (Kelly's benchmark), the largest accepted.
NO_FRICTION_LIMIT = 1e3
#: Power limit standing for "no power limit" (Kelly's benchmark, the co-design's mass study), W.
NO_POWER_LIMIT = 1e6

#: The largest swing clearance accepted, m: a tenth of the smaller biped's leg; beyond, a typo more
#: likely than a gait (the optimal steps lift the foot 40-60 mm mid-step).
MAX_SWING_CLEARANCE = 0.05

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
      dynamics: "chain" (the closed-form planar-chain dynamics of :mod:`biped_jax.dynamics.planar_chain`, equal
        to MJX's to rounding and several times faster to compile and differentiate) or "mjx" (MJX's
        forward pipeline); :mod:`biped_jax.dynamics.interface`.
      segments: shooting segments of the stance angle's zero dynamics, dividing ``spans``; None (the
        default) shoots one per knot span. 1 is single shooting from the start state; more start each
        segment (a run of spans / segments knot spans) from its own stance state, a decision
        variable, with continuity as equality constraints (multiple shooting: the unstable stance
        pendulum cannot drift over a segment, and the interior point's derivatives split by segment,
        :mod:`biped_jax.gait.segmented`, several times cheaper than over the whole step).
      drive_limits: hold the drives' gear limits at every sample: |u_i| within the gear's intermittent
        output torque (besides ``torque_bound``) and the motor speed N |qdot_i| within the gear's largest
        input speed (the ``gear_input_speed`` group). Off by default (the paper's problem: its ideal
        drives have none); the co-design's catalogue drives have them. On, every program has 8 more rows
        per sample; off, the group has none.
      swing_clearance: the swing foot's least height over the ground through mid-step, m; 0 (the
        default, the paper's problem) only keeps it above the ground. A real foot needs millimetres
        over the floor for its tracking error (the 3D humanoid lifts its foot 10 mm); in the problem the
        gait pays for the lift in its own torques instead of a lift added after the optimisation.
      clearance_ramp: the fraction of the step over which the clearance rises from 0 after lift-off and
        falls to 0 before touchdown, along a smoothstep (no corner: the swing leg's torques follow the
        profile's second derivative).
      touchdown_forward_speed: the swing foot's largest forward speed at touchdown, m/s (a row beside
        ``touchdown_descending``); None (the default, the paper's problem): no bound. With a clearance the
        optimum keeps the foot up to the end and whips it down and forward (the 12 kg gait with 10 mm lands
        at 2.0 m/s, its knee extending at 17 rad/s; without: 1.2 m/s, 1.4 rad/s), which a robot's landing
        leg must then absorb.

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
    segments: int | None = None
    drive_limits: bool = False
    swing_clearance: float = 0.0
    clearance_ramp: float = 0.1
    touchdown_forward_speed: float | None = None

    def __post_init__(self):
        if self.segments is None and not isinstance(self.spans, bool) and isinstance(self.spans, int):
            object.__setattr__(self, "segments", self.spans)  # one shooting segment per knot span
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
        if isinstance(self.swing_clearance, bool) or not isinstance(self.swing_clearance, (int, float)) \
                or not 0.0 <= self.swing_clearance <= MAX_SWING_CLEARANCE:
            raise ValueError(f"GaitSettings.swing_clearance must be a number in [0, {MAX_SWING_CLEARANCE:g}] m, "
                             f"got {self.swing_clearance!r}")
        _check_number("clearance_ramp", self.clearance_ramp, 1e-3, 0.5, "(fraction of the step)")
        if self.touchdown_forward_speed is not None:
            _check_number("touchdown_forward_speed", self.touchdown_forward_speed, -5.0, 5.0, "m/s (or None)")
        if not isinstance(self.drive_limits, bool):
            raise ValueError(f"GaitSettings.drive_limits must be True or False, got {self.drive_limits!r}")

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
        :func:`~biped_jax.drives.model.ideal_drives` (the default) that is the paper's J = integral of
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


def check_step_bounds(bounds, lengths: list[float], mass_class: str = "12kg") -> tuple[float, float]:
    """(low, high) in m from ``bounds``; ValueError naming them unless 0 < low <= every model's step
    length <= high < the legs' reach (2 leg lengths of ``mass_class``): the bounds of a free step length."""
    if not isinstance(bounds, (list, tuple)) or len(bounds) != 2 or not all(
            isinstance(b, (int, float)) and not isinstance(b, bool) and np.isfinite(b) for b in bounds):
        raise ValueError(f"bounds must be a pair (low, high) of step lengths in m, got {bounds!r:.80}")
    low, high = (float(b) for b in bounds)
    reach = 2 * PLANAR_SPECS[mass_class].leg_length
    if not 0 < low <= min(lengths) or not max(lengths) <= high < reach:
        raise ValueError(f"bounds ({low}, {high}) m must hold every model's step length "
                         f"({min(lengths):.3g}-{max(lengths):.3g} m, the start) with 0 < low and high below "
                         f"the legs' reach ({reach:.3g} m)")
    return low, high


def gait_model(mass_class: str, speed: float, power_limit: float, step_length: float = 0.2) -> GaitModel:
    """A problem of docs/gait-problem.md for the biped ``mass_class`` ("12kg", "18kg" or "kelly") with
    ideal drives (the paper's problem; ``biped_jax.codesign.design_gait_model`` fits real ones);
    raises ValueError naming a non-positive speed, limit or length, or a step beyond the legs' reach.
    Numbers may be Python, numpy or 0-d JAX arrays (concrete: a traced value raises TypeError)."""
    for name, value, unit in (("speed", speed, "m/s"), ("power_limit", power_limit, "W"),
                              ("step_length", step_length, "m")):
        if isinstance(value, jax.core.Tracer):
            raise TypeError(f"{name} is traced (gait_model was called inside jit, vmap or grad): the model is "
                            "built and checked from concrete numbers; build it outside and pass it in, or use "
                            "biped_jax.codesign.design_gait_model, which traces")
        if isinstance(value, bool) or not (isinstance(value, (int, float, np.floating, np.integer))
                                           or (hasattr(value, "shape") and np.shape(value) == ()
                                               and (np.issubdtype(np.asarray(value).dtype, np.floating)
                                                    or np.issubdtype(np.asarray(value).dtype, np.integer)))):
            raise ValueError(f"{name} must be a number ({unit}), got {value!r}")
    design = mjx_biped.planar_design(mass_class)  # first: it names an unknown mass class
    check_problem(speed, power_limit, step_length, mass_class)
    return GaitModel(design=design, speed=jnp.asarray(float(speed)),
                     step_length=jnp.asarray(float(step_length)),
                     power_limit=jnp.asarray(float(power_limit)),
                     drives=drive_model.ideal_drives())


def with_limit_fraction(model: GaitModel, fraction) -> GaitModel:
    """``model`` with its power limit M_W scaled by ``fraction`` (traceable): the smallest power limit's
    problem in (x, t) poses every constraint at M_W = t M_W0."""
    return dataclasses.replace(model, power_limit=model.power_limit * fraction)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class LimitParams:
    """The smallest power limit's problem data, one problem (a batch: leading dimension B).

    Attributes:
      model: the gait problem at its own limit M_W0; the problem in (x, t) poses every constraint at
        M_W = t M_W0.
      energy_weight: the weight of J beside t in the objective t + energy_weight J (1 / (N^2 m^2 s)):
        positive, it picks the cheapest gait among those at (nearly) the smallest limit and gives the
        problem the curvature a linear objective lacks; 0 is the plain epigraph form.
    """

    model: GaitModel
    energy_weight: jax.Array


def with_step_fraction(model: GaitModel, fraction) -> GaitModel:
    """``model`` with its step length L scaled by ``fraction`` (traceable): the problem with a free
    step length in (x, l) poses every constraint (the touchdown's position, the step time L / v) at
    L = l L0."""
    return dataclasses.replace(model, step_length=model.step_length * fraction)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class StepParams:
    """The free-step-length problem's data, one problem (a batch: leading dimension B).

    Attributes:
      model: the gait problem at its start's step length L0 (m); the problem in (x, l) poses every
        constraint at L = l L0 and minimises the energy per metre J(l L0) / l (in J per L0 metres, so
        that its value at l = 1 is the fixed step's J).
      low, high: the bounds on l = L / L0 (0 < low <= 1 <= high).
    """

    model: GaitModel
    low: jax.Array
    high: jax.Array


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SpeedParams:
    """The fastest gait's problem data, one problem (a batch: leading dimension B).

    Attributes:
      model: the gait problem at its start's step length L0 (m) and speed v0 (m/s); the problem in
        (x, l, c) poses every constraint at L = l L0 and v = v0 / c and minimises the pace c (maximises
        v), with ``energy_weight`` times the energy per metre J / l beside it.
      low, high: the bounds on l = L / L0.
      energy_weight: as :class:`LimitParams`' (1 / (N^2 m^2 s)); 0 is max v itself.
    """

    model: GaitModel
    low: jax.Array
    high: jax.Array
    energy_weight: jax.Array


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
    touchdown: impact.Touchdown
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
