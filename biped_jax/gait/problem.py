"""The periodic one-step gait problem of docs/gait-problem.md, transcribed so that its answer does not move
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
with its cost and violations there (:mod:`biped_jax.gait.solver`).

The problem lives in five modules, re-exported here as one namespace (``from biped_jax.gait import
problem as gait``; ``gait.simulate``): :mod:`~biped_jax.gait.settings`, :mod:`~biped_jax.gait.splines`,
:mod:`~biped_jax.gait.rollout`, :mod:`~biped_jax.gait.constraints`, :mod:`~biped_jax.gait.starts`.
"""

from biped_jax.gait.constraints import (
    CONSTRAINT_GROUPS,
    FORCE_SCALE,
    IMPULSE_SCALE,
    LENGTH_SCALE,
    POWER_SCALE,
    RATE_SCALE,
    TORQUE_SCALE,
    VOLTAGE_SCALE,
    constraint_groups,
    cost,
    cost_residuals,
    joule_energy,
    scaled_constraints,
    violations,
)
from biped_jax.gait.rollout import actuated_torque, simulate, zero_dynamics_acceleration
from biped_jax.gait.settings import (
    DYNAMICS,
    NO_FRICTION_LIMIT,
    NO_POWER_LIMIT,
    REFINEMENT,
    GaitModel,
    GaitSettings,
    GaitTrajectory,
    LimitParams,
    SpeedParams,
    StepParams,
    check_problem,
    check_step_bounds,
    gait_model,
    refined,
    with_limit_fraction,
    with_step_fraction,
)
from biped_jax.gait.splines import (
    basis,
    breakpoints,
    control_points,
    greville,
    grid,
    knot_vector,
    pack,
    reference,
    segment_starts,
    simpson_weights,
    stance_nodes,
)
from biped_jax.gait.starts import IMPACT_FAMILIES, START_FAMILIES, StartFamily, initial_guess, project

__all__ = [
    "CONSTRAINT_GROUPS",
    "DYNAMICS",
    "FORCE_SCALE",
    "GaitModel",
    "GaitSettings",
    "GaitTrajectory",
    "IMPACT_FAMILIES",
    "IMPULSE_SCALE",
    "LENGTH_SCALE",
    "LimitParams",
    "SpeedParams",
    "StepParams",
    "NO_FRICTION_LIMIT",
    "NO_POWER_LIMIT",
    "POWER_SCALE",
    "RATE_SCALE",
    "REFINEMENT",
    "START_FAMILIES",
    "StartFamily",
    "TORQUE_SCALE",
    "VOLTAGE_SCALE",
    "actuated_torque",
    "basis",
    "breakpoints",
    "check_problem",
    "check_step_bounds",
    "constraint_groups",
    "control_points",
    "cost",
    "cost_residuals",
    "gait_model",
    "greville",
    "grid",
    "initial_guess",
    "joule_energy",
    "knot_vector",
    "pack",
    "project",
    "reference",
    "refined",
    "with_limit_fraction",
    "with_step_fraction",
    "scaled_constraints",
    "segment_starts",
    "simpson_weights",
    "simulate",
    "zero_dynamics_acceleration",
    "stance_nodes",
    "violations",
]
