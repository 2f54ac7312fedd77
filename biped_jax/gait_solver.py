"""Solving gait problems: many models in one batched augmented-Lagrangian call, with status.

A solve is `converged` only when the solver converged *and* every constraint group's violation is at
most :data:`VIOLATION_TOLERANCE` in its own unit (m, rad, rad/s, N, N m, W, N s) on a fresh
re-simulation of the solution.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax import augmented_lagrangian as al
from biped_jax import gait
from biped_jax import hybrid_step as hs
from biped_jax.robot_specs import PLANAR_SPECS

#: Largest violation accepted, in each constraint group's own unit.
VIOLATION_TOLERANCE = 1e-4

#: Solver settings for the gait: scaled tolerance 1e-5 keeps every group below 1e-4 in its own unit
#: (the scales in ``biped_jax.gait`` are at most 10 own units per scaled unit).
GAIT_SOLVER_OPTIONS = al.SolverOptions(tolerance=1e-5, stationarity=1e-2, max_outer=25, max_inner=500,
                                       penalty_initial=10.0, penalty_max=1e6)


def stack_tree(trees: list):
    """A batch (leading dimension B) of pytrees with strong float64 leaves: a weakly typed leaf (from a
    Python float) would compile a second program."""
    return jax.tree.map(lambda *leaves: jnp.asarray(jnp.stack(leaves), dtype=jnp.result_type(float)), *trees)


@dataclasses.dataclass
class GaitSolution:
    """One solved (or not) gait problem, with numpy arrays.

    Attributes:
      name: label (e.g. "M2"). mass_kg, speed_mps, power_limit_W, step_length_m, step_time_s: the problem.
      status: converged, infeasible, iteration limit or diverged. cost: J, N^2 m^2 s.
      violations: largest violation per constraint group, own units. max_violation: their maximum
        (mixed units; each is checked against the tolerance in its own unit).
      stationarity: |grad of the Lagrangian|_inf (scaled). outer_iterations, gradients: counts.
      wall_time_s: the batch's solve time. x: the decision vector. trajectory: the simulated step.
      history: per outer iteration: cost, scaled violation, penalty, gradients.
      multipliers_eq, multipliers_in: the solver's final multiplier estimates of the scaled
        constraints (see :func:`biped_jax.augmented_lagrangian.optimal_value_gradient`).
    """

    name: str
    mass_kg: float
    speed_mps: float
    power_limit_W: float
    step_length_m: float
    step_time_s: float
    status: str
    cost: float
    violations: dict
    max_violation: float
    stationarity: float
    outer_iterations: int
    gradients: int
    wall_time_s: float
    x: np.ndarray
    trajectory: gait.GaitTrajectory
    history: list
    multipliers_eq: np.ndarray
    multipliers_in: np.ndarray


class GaitSolver:
    """Compiles once per :class:`~biped_jax.gait.GaitSettings` and solves batches of models."""

    def __init__(self, settings: gait.GaitSettings = gait.GaitSettings(),
                 options: al.SolverOptions = GAIT_SOLVER_OPTIONS, mass_class_template: str = "12kg"):
        self.settings, self.options = settings, options
        self.biped = hs.load_planar_biped(mass_class_template)  # designs replace its masses
        biped, settings_ = self.biped, settings

        def residuals(x, model):
            trajectory = gait.simulate(x, model, biped, settings_)
            equalities, inequalities = gait.scaled_constraints(
                gait.constraint_groups(trajectory, model, settings_))
            return gait.cost_residuals(trajectory, model.drives), equalities, inequalities

        self.problem = al.ConstrainedProblem.from_residuals(residuals)
        self.compiled = al.compile_problem(self.problem)
        self._simulate = jax.jit(jax.vmap(functools.partial(gait.simulate, biped=biped, settings=settings)))
        self._initial_guess = jax.jit(jax.vmap(functools.partial(
            gait.initial_guess, settings=settings, leg_length=PLANAR_SPECS[mass_class_template].leg_length)))

    def with_options(self, **changes) -> "GaitSolver":
        """A solver sharing this one's compiled functions with other solver options."""
        other = object.__new__(GaitSolver)
        other.__dict__.update(self.__dict__)
        other.options = dataclasses.replace(self.options, **changes)
        return other

    def simulate(self, x, models: gait.GaitModel) -> gait.GaitTrajectory:
        """Batched rollout: x (B, n), models with leading dimension B."""
        return self._simulate(x, models)

    def solve(self, names: list[str], models: list[gait.GaitModel], x0=None,
              progress: Callable[[int, dict], None] | None = None) -> list[GaitSolution]:
        """Solves every model in one batch (one compiled program); x0 (B, n) warm-starts."""
        batch = stack_tree(models)
        x0 = self._initial_guess(batch) if x0 is None else jnp.asarray(x0)
        result = al.solve(self.problem, x0, batch, self.options, compiled=self.compiled,
                          progress=progress)
        trajectories = self.simulate(jnp.asarray(result.x), batch)
        solutions = []
        for b, (name, model) in enumerate(zip(names, models)):
            trajectory = jax.tree.map(lambda a: np.asarray(a[b]), trajectories)
            groups = gait.constraint_groups(trajectory, model, self.settings)
            violations = {k: float(v) for k, v in gait.violations(groups).items()}
            status = result.status[b]
            if not np.all(np.isfinite(result.x[b])) or not np.all(np.isfinite(trajectory.u)):
                status = al.DIVERGED
            elif status == al.CONVERGED and max(violations.values()) > VIOLATION_TOLERANCE:
                status = al.ITERATION_LIMIT  # feasible only in the scaled sense: keep iterating
            solutions.append(GaitSolution(
                name=name, mass_kg=float(model.design.total_mass), speed_mps=float(model.speed),
                power_limit_W=float(model.power_limit), step_length_m=float(model.step_length),
                step_time_s=float(model.step_length / model.speed), status=status,
                cost=float(result.cost[b]), violations=violations,
                max_violation=max(violations.values()), stationarity=float(result.stationarity[b]),
                outer_iterations=int(result.outer_iterations[b]), gradients=int(result.gradients[b]),
                wall_time_s=result.wall_time_s, x=np.asarray(result.x[b]), trajectory=trajectory,
                history=[{k: float(v[b]) for k, v in row.items() if k != "x"} for row in result.history],
                multipliers_eq=result.multipliers_eq[b], multipliers_in=result.multipliers_in[b]))
        return solutions
