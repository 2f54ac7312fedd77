"""The nonlinear program the solvers take and what they return: a batchable
:class:`ConstrainedProblem` (f, h, g of x and per-problem data), its statuses, a :class:`SolveResult`,
the scaled violation, derivatives by central differences, and the optimal value's sensitivity to the
problem's data (envelope theorem).

    minimise f(x; p)  subject to  h(x; p) = 0,  g(x; p) <= 0,

x of shape (n,), p a pytree of per-problem data; the constraints scaled to order one by the caller.
Solved by :mod:`biped_jax.optim.interior_point` (batched, exact derivatives); DONALD's speed
optimisation (:mod:`biped_jax.donald.speed`) takes its central differences.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

#: A solve's outcomes (the gait's verdict adds "grid dependent").
CONVERGED, INFEASIBLE, ITERATION_LIMIT, DIVERGED = "converged", "infeasible", "iteration limit", "diverged"
#: No step accepted for several iterations with a violation too small to call the problem infeasible
#: (below the solver options' ``infeasible_above``): the solver stalled near a feasible point, which
#: says nothing about whether one exists.
STALLED = "stalled"


@dataclasses.dataclass(frozen=True)
class ConstrainedProblem:
    """A batchable constrained problem.

    Attributes:
      evaluate: ``(x, params) -> (f, h, g)``, the objective (scalar), the equalities and the
        inequalities (1-D arrays, possibly empty) from one evaluation, so that an expensive simulation
        behind all three runs once.
      residuals: optional ``(x, params) -> (r, h, g)`` with f = r . r (a least-squares objective; the
        sparsity probe then reads r's rows, :mod:`biped_jax.optim.sparsity`).
      local: optional :class:`~biped_jax.optim.local_derivatives.LocalProblem`, the same rows split by
        segment: the interior point's exact derivatives then cost a segment's columns
        (:func:`biped_jax.optim.exact_derivatives.derivatives`).
    """

    evaluate: Callable[[jax.Array, Any], tuple[jax.Array, jax.Array, jax.Array]]
    residuals: Callable[[jax.Array, Any], tuple[jax.Array, jax.Array, jax.Array]] | None = None
    local: Any = None

    @classmethod
    def from_functions(cls, objective, equalities, inequalities) -> "ConstrainedProblem":
        """From three separate functions of (x, params)."""
        return cls(lambda x, p: (objective(x, p), equalities(x, p), inequalities(x, p)))

    @classmethod
    def from_residuals(cls, residuals) -> "ConstrainedProblem":
        """From ``residuals(x, params) -> (r, h, g)``, the objective being r . r."""
        def evaluate(x, p):
            r, h, g = residuals(x, p)
            return r @ r, h, g
        return cls(evaluate, residuals)

    def with_central_differences(self, step: float) -> "ConstrainedProblem":
        """The same problem, its derivatives in x taken by central differences of half-width ``step``
        (in x's units) instead of automatic differentiation: see :func:`central_differences`."""
        return ConstrainedProblem(central_differences(self.evaluate, step))


def central_differences(evaluate: Callable, step: float) -> Callable:
    """``evaluate(x, params)`` whose reverse-mode derivative in x is the central difference
    (f(x + step e_i) - f(x - step e_i)) / (2 step) of every output, i = 1..n (params get none).

    For objectives that are rough on small scales, such as a long rollout through contact, whose exact
    gradient explodes (or is that of one contact event) while the trend over a parameter change of
    ``step`` is what an optimiser can use: the difference is the gradient of f smoothed over that
    width. A value with its derivative costs 2n + 1 evaluations, run as one vmapped call.
    """
    @jax.custom_vjp
    def smoothed(x, params):
        return evaluate(x, params)

    def forward(x, params):
        size = x.shape[-1]
        offsets = step * jnp.eye(size, dtype=x.dtype)
        points = jnp.concatenate([x[None], x + offsets, x - offsets])
        values = jax.vmap(evaluate, in_axes=(0, None))(points, params)
        centre = jax.tree.map(lambda v: v[0], values)
        # d output / d x_i, shape (n, *output shape)
        slopes = jax.tree.map(lambda v: (v[1:size + 1] - v[size + 1:]) / (2 * step), values)
        return centre, (slopes, params)

    def backward(residual, cotangent):
        slopes, params = residual
        parts = jax.tree.map(lambda s, c: jnp.tensordot(s, c, axes=c.ndim), slopes, cotangent)
        grad_x = sum(jax.tree.leaves(parts))
        return grad_x, jax.tree.map(jnp.zeros_like, params)

    smoothed.defvjp(forward, backward)
    return smoothed


@dataclasses.dataclass
class SolveResult:
    """Per-problem outcome, each array with leading batch dimension B.

    Attributes:
      x: solution, (B, n). cost: f, (B,). equalities, inequalities: h and g at x (scaled), (B, m).
      violation: largest scaled violation, (B,). stationarity: |grad Lagrangian|_inf / max(1, |f|), (B,).
      status: list of B strings. outer_iterations (the interior point's iterations), gradients
        (derivative evaluations): counts, (B,). wall_time_s: float.
      multipliers_eq, multipliers_in: the multipliers of h and g, (B, m) each (at a KKT point, the
        sensitivity of the optimal f to the problem data, see :func:`optimal_value_gradient`).
      history: per block of iterations, a dict of (B,) arrays: cost, violation, KKT error, barrier
        parameter, gradients, stationarity, done; the last row also the iterate x (B, n).
    """

    x: np.ndarray
    cost: np.ndarray
    equalities: np.ndarray
    inequalities: np.ndarray
    violation: np.ndarray
    stationarity: np.ndarray
    status: list
    outer_iterations: np.ndarray
    gradients: np.ndarray
    wall_time_s: float
    history: list
    multipliers_eq: np.ndarray
    multipliers_in: np.ndarray


def violation(h, g):
    """Largest scaled violation max(|h|_inf, max(g, 0)) per problem, over the last axis; shape (...,)."""
    parts = [jnp.zeros(h.shape[:-1])]
    if h.shape[-1]:
        parts.append(jnp.max(jnp.abs(h), axis=-1))
    if g.shape[-1]:
        parts.append(jnp.max(jnp.maximum(g, 0.0), axis=-1))
    return jnp.max(jnp.stack(parts), axis=0)


def optimal_value_gradient(problem: ConstrainedProblem, parameters_to_params: Callable) -> Callable:
    """Gradient of the optimal value f*(p) with respect to problem parameters, by the envelope theorem.

    At a KKT point x*(p) with multipliers (lam_eq, lam_in), strict complementarity and linearly
    independent active constraints, d f*/d theta = d/d theta [f + lam_eq . h + lam_in . g] at fixed
    x* and multipliers (Fiacco, Introduction to Sensitivity and Stability Analysis in Nonlinear
    Programming, 1983, Thm. 3.4.1; Nocedal & Wright Sec. 12.8 for the multipliers as sensitivities).
    One gradient of the Lagrangian: no differentiation through the solver's iterations.

    Args:
      problem: as solved.
      parameters_to_params: theta -> the solver's per-problem ``params`` (traceable).
    Returns a jitted, vmapped ``(theta, x, lam_eq, lam_in) -> d f*/d theta`` (same pytree as theta).
    """
    def lagrangian(theta, x, lam_eq, lam_in):
        f, h, g = problem.evaluate(x, parameters_to_params(theta))
        return f + lam_eq @ h + lam_in @ g
    return jax.jit(jax.vmap(jax.grad(lagrangian)))
