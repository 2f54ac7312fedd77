"""A batched primal-dual interior-point solver in JAX: one compiled program solves B problems of one shape.

    minimise f(x; p)  subject to  h(x; p) = 0,  g(x; p) <= 0,

the constraints scaled to order one by the caller. The method is IPOPT's (Waechter and Biegler, "On the
implementation of an interior-point filter line-search algorithm for large-scale nonlinear programming",
Math. Prog. 106, 2006) and its filter line search:

- slacks s > 0 turn g(x) <= 0 into g(x) + s = 0, and the barrier -mu sum(log s) keeps them positive; mu
  falls (monotone, Fiacco-McCormick) each time the barrier problem is solved to kappa_eps mu;
- every iteration takes one Newton step on the barrier problem's KKT conditions with the exact Hessian
  of the Lagrangian and the exact constraint Jacobians (:mod:`biped_jax.optim.exact_derivatives`: one
  forward-over-reverse pass, no finite differences), the slacks and inequality multipliers eliminated, so
  that one dense (n + m_h) system remains per problem (a few hundred unknowns for the gait); the
  inequality Jacobian, where the derivatives give it in its shooting segments' blocks, enters that
  system block by block (:mod:`biped_jax.optim.jacobian`), never as a dense (m_g, n) matrix;
- inertia correction: that system, with a small regularisation -delta_c I of its equality block, has the
  right inertia exactly when the matrix W + J_g^T S^-1 Z J_g + delta_w I + J_h^T J_h / delta_c is
  positive definite, which one Cholesky factorisation tells; delta_w grows until it is (IPOPT's rule);
- the fraction-to-the-boundary rule keeps s and z positive; a backtracking filter line search accepts a
  step that lowers the constraint violation theta = |h|_1 + |g + s|_1 or the barrier objective
  phi = f - mu sum(log s) enough and is not dominated by an earlier iterate (the filter; Armijo on phi
  where theta is already small), with one second-order correction of the first trial (against the
  Maratos effect on curved constraints). Where the filter accepts no step, a feasibility step (the
  linearised constraints alone, backtracking on theta) stands in for IPOPT's restoration phase; a
  problem where neither moves for ``max_failures`` iterations stops (``stalled``, or ``infeasible``
  with its violation).

Batching is ``vmap`` over the problems of one ``jit``-compiled loop (``lax.while_loop``): a problem that
has finished keeps its state while the others go on. The iterations run in blocks of
:attr:`InteriorPointOptions.block` on the device, between which the caller sees the progress (and may
stop). With several devices the batch is sharded over them (``jax.sharding``, the batch axis split).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import os
import time
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax.optim import exact_derivatives, nlp
from biped_jax.optim import jacobian as jacobian_ops

#: Per-problem outcome codes inside the compiled loop (``status`` strings outside).
_RUNNING, _CONVERGED, _ACCEPTABLE, _STALLED, _LOCALLY_INFEASIBLE, _NOT_FINITE, _PADDING = range(7)


@dataclasses.dataclass(frozen=True)
class InteriorPointOptions:
    """Settings of :func:`solve` (defaults are IPOPT's where it has the same setting).

    Attributes:
      tolerance: the KKT error at which a problem is ``converged``: the largest of the scaled dual
        infeasibility |grad L|_inf / s_d, the constraint violation max(|h|_inf, |g + s|_inf) and the
        complementarity |s z|_inf / s_c (IPOPT's ``tol`` with its scalings s_d, s_c).
      feasibility: the largest scaled violation max(|h|_inf, max(g, 0)) a converged problem may keep.
      acceptable_tolerance, acceptable_iterations: a problem whose KKT error stays within the former for
        the latter consecutive iterations (and feasible within ``feasibility``) is converged too
        (IPOPT's "acceptable" end).
      max_iterations: iterations at most.
      block: iterations per call of the compiled loop (progress is reported between blocks).
      mu_initial: the first barrier parameter (smaller for a warm start near an optimum).
      slack_push: the smallest initial slack, so that a start on an active inequality begins inside.
      scaling_threshold: the objective and every constraint row are scaled at the start so that no
        gradient exceeds this (IPOPT's gradient-based scaling, ``nlp_scaling_max_gradient``); results
        and multipliers are those of the unscaled problem.
      objective_scale: a further factor on the objective inside the solver.
      equality_regularisation: the smallest diagonal entry of the equality Jacobian's triangular factor,
        relative to its largest (where the equality Jacobian loses rank).
      max_backtracks: trial points of one line search at most, and as many more for the feasibility
        step that follows a failed one.
      max_failures: consecutive failed line searches before a problem stops (``stalled`` or
        ``infeasible``).
      infeasible_above: a problem that stops with a larger scaled violation is ``infeasible``.
      mu_based_multipliers: inequality multipliers without a warm start begin at mu / s (IPOPT's
        ``bound_mult_init_method=mu-based``) instead of 1: for problems with many more inequality rows
        than can be active, such as an epigraph form over every sample of a trajectory.
      quorum, patience: once a fraction ``quorum`` of a batch's problems has finished, the others get
        ``patience`` more iterations (rounded up to blocks), then the batch stops and they end
        ``iteration limit`` (or ``infeasible`` above ``infeasible_above``) with their violations. A
        batched loop costs every lane an iteration until its last problem finishes, so a few slow
        problems (a co-design start far from any gait) otherwise set the time of the whole batch. The
        default (quorum 1) waits for every problem.
      lanes: problems iterated at once (None: the whole batch, as far as memory allows). A larger batch
        runs in that many lanes of one program, each lane taking the next waiting problem as soon as its
        own finishes: where the lanes' work is the device's limit (a CPU, a busy GPU), a batch then costs
        about the sum of its problems' iterations instead of its slowest problem's times the batch.
        ``quorum`` counts only once every problem has had a lane.
    """

    tolerance: float = 1e-8
    feasibility: float = 1e-8
    acceptable_tolerance: float = 1e-6
    acceptable_iterations: int = 10
    max_iterations: int = 300
    block: int = 10
    mu_initial: float = 0.1
    slack_push: float = 1e-2
    scaling_threshold: float = 100.0
    objective_scale: float = 1.0
    equality_regularisation: float = 1e-10
    max_backtracks: int = 40
    max_failures: int = 5
    infeasible_above: float = 1e-3
    mu_based_multipliers: bool = False
    quorum: float = 1.0
    patience: int = 0
    lanes: int | None = None

    def __post_init__(self):
        for name in ("tolerance", "feasibility", "acceptable_tolerance", "mu_initial", "slack_push",
                     "scaling_threshold", "objective_scale", "equality_regularisation", "infeasible_above"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < np.inf:
                raise ValueError(f"InteriorPointOptions.{name} must be a positive number, got {value!r}")
        for name in ("acceptable_iterations", "max_iterations", "block", "max_backtracks", "max_failures"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"InteriorPointOptions.{name} must be a positive integer, got {value!r}")
        if isinstance(self.quorum, bool) or not isinstance(self.quorum, (int, float)) or not 0 < self.quorum <= 1:
            raise ValueError(f"InteriorPointOptions.quorum must be a fraction in (0, 1], got {self.quorum!r}")
        if isinstance(self.patience, bool) or not isinstance(self.patience, int) or self.patience < 0:
            raise ValueError(f"InteriorPointOptions.patience must be a non-negative integer, got {self.patience!r}")
        if self.lanes is not None and (isinstance(self.lanes, bool) or not isinstance(self.lanes, int)
                                       or self.lanes < 1):
            raise ValueError(f"InteriorPointOptions.lanes must be a positive integer or None, got {self.lanes!r}")


# IPOPT's constants (Waechter and Biegler 2006, Sec. 2-3), not options there either.
_S_MAX = 100.0          # scaling threshold of the dual infeasibility and complementarity
_KAPPA_EPS = 10.0       # the barrier problem is solved when its error is within kappa_eps mu
_KAPPA_MU, _THETA_MU = 0.2, 1.5   # mu <- max(tol / 10, min(kappa_mu mu, mu^theta_mu))
_TAU_MIN = 0.99         # fraction to the boundary
_KAPPA_SIGMA = 1e10     # z stays within [mu / (kappa s), kappa mu / s]
_DELTA_FIRST, _DELTA_MIN, _DELTA_MAX = 1e-4, 1e-20, 1e40
_GROW_FIRST, _GROW, _SHRINK = 100.0, 8.0, 1.0 / 3.0
_INERTIA_TRIES = 100  # more than the growth from _DELTA_MIN to _DELTA_MAX takes
_ARMIJO = 1e-4
_GAMMA_THETA, _GAMMA_PHI, _GAMMA_ALPHA = 1e-5, 1e-8, 0.05   # the filter's margins, the smallest step
_S_THETA, _S_PHI, _SWITCH = 1.1, 2.3, 1.0                      # the switching condition
_FILTER_SIZE = 32       # filter entries kept (the oldest is replaced)
_ALPHA_SMALLEST = 1e-12  # no trial with a shorter step
_NEWTON, _CORRECTION, _RESTORATION = 0, 1, 2   # the kinds of trial point of a line search


class State(NamedTuple):
    """One problem's iterate and bookkeeping (a batch: every leaf with a leading dimension B)."""

    x: jax.Array
    s: jax.Array
    y: jax.Array
    z: jax.Array
    mu: jax.Array
    filter_theta: jax.Array
    filter_phi: jax.Array
    filter_next: jax.Array
    theta_min: jax.Array
    theta_max: jax.Array
    delta: jax.Array
    f: jax.Array
    h: jax.Array
    g: jax.Array
    error: jax.Array
    stationarity: jax.Array
    iteration: jax.Array
    acceptable: jax.Array
    failures: jax.Array
    evaluations: jax.Array
    code: jax.Array
    scale_f: jax.Array
    scale_h: jax.Array
    scale_g: jax.Array


def initial_state(problem: nlp.ConstrainedProblem, x0, params, y0, z0, mu) -> State:
    """The state at x0 (n,) before the first iteration: y and z hold the unscaled multipliers to start
    from, y0 (zero for a cold start) and z0 (<= 0 where unknown); mu is the first barrier parameter. The
    problem is not evaluated here: the first iteration evaluates it with its derivatives, scales it by
    them and then sets the slacks, multipliers, filter margins and f, h, g (:func:`_first_iteration`), so
    that this program compiles in a moment instead of holding a copy of the problem (measured: 2.4 s of
    compiling per problem shape at 48 knot spans on 2 cores)."""
    f, h, g = (jnp.zeros(a.shape, a.dtype) for a in jax.eval_shape(problem.evaluate, x0, params))
    mu = jnp.asarray(mu, x0.dtype)
    return State(x=x0, s=jnp.ones_like(g), y=y0, z=z0, mu=mu,
                 filter_theta=jnp.full(_FILTER_SIZE, jnp.inf, x0.dtype),
                 filter_phi=jnp.full(_FILTER_SIZE, jnp.inf, x0.dtype),
                 filter_next=jnp.zeros((), jnp.int32), theta_min=jnp.zeros((), x0.dtype),
                 theta_max=jnp.full((), jnp.inf, x0.dtype), delta=jnp.zeros((), x0.dtype), f=f, h=h, g=g,
                 error=jnp.asarray(jnp.inf, x0.dtype),
                 stationarity=jnp.asarray(jnp.inf, x0.dtype), iteration=jnp.zeros((), jnp.int32),
                 acceptable=jnp.zeros((), jnp.int32), failures=jnp.zeros((), jnp.int32),
                 evaluations=jnp.ones((), jnp.int32), code=jnp.asarray(_RUNNING, jnp.int32),
                 scale_f=jnp.ones((), x0.dtype), scale_h=jnp.ones_like(h), scale_g=jnp.ones_like(g))


def _row_scales(jacobian, threshold):
    """IPOPT's gradient-based scaling: each row multiplied by min(1, threshold / its largest
    derivative), so that no scaled gradient exceeds the threshold (rows without one keep 1)."""
    largest = jacobian_ops.row_max_abs(jacobian)
    return jnp.where(largest > threshold, threshold / jnp.maximum(largest, 1e-300), 1.0)


def _first_iteration(options, st: State, f, h, g, grad_f, jac_h, jac_g, hessian_f) -> tuple:
    """At the first iteration (derivatives of f alone at x0): the scales, and the scaled problem's
    gradient of the Lagrangian, Hessian (f's alone: no multipliers are known yet) and state. Slacks
    max(-g, slack_push); z from z0 where given, else 1 (IPOPT's bound_mult_init_val); y from y0."""
    scale_f = _row_scales(grad_f[None], options.scaling_threshold)[0] * options.objective_scale
    scale_h, scale_g = _row_scales(jac_h, options.scaling_threshold), _row_scales(jac_g, options.scaling_threshold)
    s = jnp.maximum(-scale_g * g, options.slack_push)
    z = jnp.where(st.z > 0, st.z * scale_f / scale_g, st.mu / s if options.mu_based_multipliers else 1.0)
    y = st.y * scale_f / scale_h
    grad = scale_f * grad_f + (scale_h[:, None] * jac_h).T @ y + jacobian_ops.rmatvec(jac_g, scale_g * z)
    theta = _theta(scale_h * h, scale_g * g, s)
    state = st._replace(s=s, y=y, z=z, scale_f=scale_f, scale_h=scale_h, scale_g=scale_g,
                        theta_min=1e-4 * jnp.maximum(1.0, theta), theta_max=1e4 * jnp.maximum(1.0, theta))
    return state, grad, scale_f * hessian_f


def _norm_inf(a):
    return jnp.max(jnp.abs(a), initial=0.0)


def _kkt_errors(grad, h, g, s, y, z, mu):
    """(scaled dual infeasibility, slack-form violation, scaled complementarity) at mu."""
    count = y.size + z.size
    s_d = jnp.maximum(_S_MAX, (jnp.sum(jnp.abs(y)) + jnp.sum(jnp.abs(z))) / max(count, 1)) / _S_MAX
    s_c = jnp.maximum(_S_MAX, jnp.sum(jnp.abs(z)) / max(z.size, 1)) / _S_MAX
    return _norm_inf(grad) / s_d, jnp.maximum(_norm_inf(h), _norm_inf(g + s)), _norm_inf(s * z - mu) / s_c


def violation(h, g):
    """max(|h|_inf, max(g, 0)) of one problem."""
    return jnp.maximum(_norm_inf(h), jnp.max(jnp.maximum(g, 0.0), initial=0.0))


def _factor(matrix, delta):
    """Cholesky factor of matrix + delta I (NaN where not positive definite)."""
    return jnp.linalg.cholesky(matrix + delta * jnp.eye(matrix.shape[0], dtype=matrix.dtype))


def _inertia_corrected(matrix, delta_last, floor):
    """(factor, delta): the smallest delta of IPOPT's sequence at which matrix + delta I is positive
    definite: ``floor`` first (0 unless the last step failed); then from delta_last / 3, or 1e-4,
    growing 8x (100x when the last iteration needed none)."""
    factor = _factor(matrix, floor)
    ok = jnp.all(jnp.isfinite(factor))
    first = jnp.where(delta_last == 0.0, _DELTA_FIRST, jnp.maximum(_DELTA_MIN, _SHRINK * delta_last))
    first = jnp.maximum(first, floor)

    def cond(carry):
        _, delta, ok, tries = carry
        return ~ok & (delta < _DELTA_MAX) & (tries < _INERTIA_TRIES)

    def body(carry):
        _, delta, _, tries = carry
        # from below ``first`` to it, then growing: with delta = first = floor a matrix that no shift
        # makes positive definite (one with a NaN) would otherwise be shifted by the same delta for ever
        delta = jnp.where(delta < first, first, delta * jnp.where(delta_last == 0.0, _GROW_FIRST, _GROW))
        factor = _factor(matrix, delta)
        return factor, delta, jnp.all(jnp.isfinite(factor)), tries + 1

    factor, delta, _, _ = jax.lax.while_loop(cond, body, (factor, floor, ok, jnp.zeros((), jnp.int32)))
    return factor, delta


def _to_boundary(v, dv, tau):
    """The largest step in (0, 1] that keeps v + step dv >= (1 - tau) v (v > 0)."""
    limits = jnp.where(dv < 0, -tau * v / jnp.where(dv < 0, dv, -1.0), jnp.inf)
    return jnp.minimum(1.0, jnp.min(limits, initial=jnp.inf))


def _solve_factored(factor, rhs):
    return jax.scipy.linalg.cho_solve((factor, True), rhs)


def newton_solver(condensed, jac_h, delta_last, floor, regularisation):
    """(solve, delta): ``solve(rhs_x, h) -> (dx, dy)`` of [[W_c + delta I, J_h^T], [J_h, 0]] [dx; dy] =
    [rhs_x; -h], factorised once for several right-hand sides.

    By the null-space method: J_h^T = [Y Z] [R; 0] (QR), so that J_h dx = -h fixes dx's part Y p_y and
    the reduced Hessian Z^T W_c Z gives the rest. The system has the inertia of a step to a minimum
    exactly when the reduced Hessian is positive definite, and Z^T (W_c + delta I) Z = Z^T W_c Z +
    delta I (Z orthonormal), so delta grows until its Cholesky factorisation succeeds
    (:func:`_inertia_corrected`) and nothing else is perturbed. R's diagonal is kept at least
    ``regularisation`` times its largest entry, where J_h loses rank.
    """
    size, equalities = jac_h.shape[1], jac_h.shape[0]
    if equalities == 0:
        factor, delta = _inertia_corrected(condensed, delta_last, floor)
        return (lambda rhs_x, h: (_solve_factored(factor, rhs_x), h)), delta
    q, r = jnp.linalg.qr(jac_h.T, mode="complete")           # (n, n), (n, m_h)
    r = r[:equalities]
    diagonal = jnp.diag(r)
    smallest = regularisation * jnp.maximum(jnp.max(jnp.abs(diagonal)), 1e-300)
    kept = jnp.where(diagonal < 0, -smallest, smallest)
    r = r + jnp.diag(jnp.where(jnp.abs(diagonal) < smallest, kept - diagonal, 0.0))
    range_basis, null_basis = q[:, :equalities], q[:, equalities:]
    reduced = null_basis.T @ condensed @ null_basis
    factor, delta = _inertia_corrected(reduced, delta_last, floor)

    def solve(rhs_x, h):
        p_y = jax.scipy.linalg.solve_triangular(r, -h, trans="T", lower=False)
        dx_range = range_basis @ p_y
        p_z = _solve_factored(factor, null_basis.T @ (rhs_x - condensed @ dx_range)) if size > equalities \
            else jnp.zeros(0, rhs_x.dtype)
        dx = dx_range + null_basis @ p_z
        dy = jax.scipy.linalg.solve_triangular(r, range_basis.T @ (rhs_x - condensed @ dx - delta * dx), lower=False)
        return dx, dy
    return solve, delta


def condensed_newton_solver(hessian, jac_h, jac_g, sigma, delta_last, floor, regularisation):
    """:func:`newton_solver` of the Newton system with the slacks and inequality multipliers
    eliminated: W_c = W + J_g^T diag(sigma) J_g (sigma = z / s; J_g dense or in blocks)."""
    return newton_solver(hessian + jacobian_ops.gram(jac_g, sigma), jac_h, delta_last, floor, regularisation)


def _theta(h, g, s):
    """The constraint violation of the slack form, |h|_1 + |g + s|_1."""
    return jnp.sum(jnp.abs(h)) + jnp.sum(jnp.abs(g + s))


def _phi(weight, f, s, mu):
    """The barrier objective w f - mu sum(log s)."""
    return weight * f - mu * jnp.sum(jnp.log(s))


def _filter_accepts(theta_t, phi_t, theta, phi, alpha, slope, st: State):
    """(acceptable, f-type) of a trial point (Waechter and Biegler 2006, Sec. 2.3): not dominated by
    the filter, below theta_max, and either Armijo on phi where the switching condition holds and theta
    is small (f-type: the filter is not augmented), or a sufficient decrease of theta or phi."""
    switching = (slope < 0) & (alpha * (-jnp.minimum(slope, 0.0)) ** _S_PHI > _SWITCH * theta ** _S_THETA)
    f_type = switching & (theta <= st.theta_min)
    armijo = phi_t <= phi + _ARMIJO * alpha * slope
    decrease = (theta_t <= (1 - _GAMMA_THETA) * theta) | (phi_t <= phi - _GAMMA_PHI * theta)
    dominated = jnp.any((theta_t >= st.filter_theta) & (phi_t >= st.filter_phi))
    ok = jnp.isfinite(theta_t) & jnp.isfinite(phi_t) & (theta_t <= st.theta_max) & ~dominated \
        & jnp.where(f_type, armijo, decrease)
    return ok, f_type & armijo


def _iterate(problem, options, structure, params, st: State) -> State:
    """One interior-point iteration of one problem, on the problem scaled by st.scale_f, scale_h,
    scale_g (set by the first iteration)."""
    first = st.iteration == 0
    f, h_raw, g_raw, grad, jac_h, jac_g, hessian = exact_derivatives.derivatives(
        problem, st.x, params, jnp.where(first, 1.0, st.scale_f), jnp.where(first, 0.0, st.scale_h * st.y),
        jnp.where(first, 0.0, st.scale_g * st.z), structure, blocks=True)
    started, grad_first, hessian_first = _first_iteration(options, st, f, h_raw, g_raw, grad, jac_h, jac_g, hessian)
    st = jax.tree.map(lambda a, b: jnp.where(first, a, b), started, st)
    grad, hessian = jnp.where(first, grad_first, grad), jnp.where(first, hessian_first, hessian)
    w, scale_h, scale_g = st.scale_f, st.scale_h, st.scale_g
    feasible = violation(h_raw, g_raw) <= options.feasibility
    h, g = scale_h * h_raw, scale_g * g_raw
    jac_h, jac_g = scale_h[:, None] * jac_h, jacobian_ops.row_scaled(jac_g, scale_g)
    dual, primal, complementarity = _kkt_errors(grad, h, g, st.s, st.y, st.z, 0.0)
    error = jnp.maximum(jnp.maximum(dual, primal), complementarity)
    acceptable = jnp.where((error <= options.acceptable_tolerance) & feasible, st.acceptable + 1, 0)
    converged = (error <= options.tolerance) & feasible
    accepted = acceptable >= options.acceptable_iterations

    # the barrier parameter falls once its problem is solved to kappa_eps mu
    barrier_error = jnp.maximum(jnp.maximum(*_kkt_errors(grad, h, g, st.s, st.y, st.z, st.mu)[::2]), primal)
    mu = jnp.where(barrier_error <= _KAPPA_EPS * st.mu,
                   jnp.maximum(options.tolerance / 10, jnp.minimum(_KAPPA_MU * st.mu, st.mu ** _THETA_MU)), st.mu)

    # the filter starts afresh with every barrier problem
    fresh = mu < st.mu
    st = st._replace(filter_theta=jnp.where(fresh, jnp.inf, st.filter_theta),
                     filter_phi=jnp.where(fresh, jnp.inf, st.filter_phi))

    # Newton step on the barrier KKT system, slacks and z eliminated
    s, z = st.s, st.z
    sigma = z / s
    floor = jnp.where(st.failures > 0, jnp.maximum(st.delta, _DELTA_FIRST) * _GROW_FIRST, 0.0)
    newton, delta = condensed_newton_solver(hessian, jac_h, jac_g, sigma, st.delta, floor,
                                            options.equality_regularisation)
    tau = jnp.maximum(_TAU_MIN, 1.0 - mu)

    def step(residual_h, residual_g):
        """(dx, dy, ds, largest step) for constraint residuals (h, g + s) (the Newton step's, or a
        second-order correction's)."""
        dx, dy = newton(-(grad + jacobian_ops.rmatvec(jac_g, sigma * residual_g + mu / s - z)), residual_h)
        ds = -residual_g - jacobian_ops.matvec(jac_g, dx)
        return dx, dy, ds, _to_boundary(s, ds, tau)

    dx, dy, ds, alpha_max = step(h, g + s)
    theta, phi = _theta(h, g, s), _phi(w, f, s, mu)
    # of phi along the step
    slope = (grad - jac_h.T @ st.y - jacobian_ops.rmatvec(jac_g, z)) @ dx - mu * jnp.sum(ds / s)
    descent = -jnp.minimum(slope, -1e-300)
    alpha_min = _GAMMA_ALPHA * jnp.where(
        slope < 0, jnp.minimum(_GAMMA_THETA, jnp.minimum(_GAMMA_PHI * theta / descent,
                                                         _SWITCH * theta ** _S_THETA / descent ** _S_PHI)),
        _GAMMA_THETA)

    # The trial points, one rollout each in one loop (a single copy of the rollout in the program):
    # the full Newton step; where the filter rejects it and it raised theta, one second-order correction
    # of it; then the Newton step halved down to alpha_min; where that fails too, a feasibility step
    # (the linearised constraints solved in the same metric, the objective left out) halved until theta
    # falls (a short stand-in for IPOPT's feasibility restoration phase: the point it leaves joins the
    # filter, so that the iteration cannot come back to it).
    dx_r, dy_r = newton(-jacobian_ops.rmatvec(jac_g, sigma * (g + s)), h)
    ds_r = -(g + s) - jacobian_ops.matvec(jac_g, dx_r)
    alpha_r0 = _to_boundary(s, ds_r, tau)

    def trial_body(carry):
        k, mode, alpha, _, _, first = carry
        h_first, g_first = first                          # scaled h and g + s at the full step
        dx_c, dy_c, ds_c, alpha_c = step(alpha_max * h + h_first, alpha_max * (g + s) + g_first)
        pick = lambda *choices: jnp.select([mode == _NEWTON, mode == _CORRECTION], choices[:2], choices[2])  # noqa: E731
        direction = (pick(dx, dx_c, dx_r), pick(dy, dy_c, dy_r), pick(ds, ds_c, ds_r))
        alpha = jnp.where(mode == _CORRECTION, alpha_c, alpha)
        s_t = s + alpha * direction[2]
        f_t, h_t, g_t = problem.evaluate(st.x + alpha * direction[0], params)
        theta_t = _theta(scale_h * h_t, scale_g * g_t, s_t)
        accepted, f_type = _filter_accepts(theta_t, _phi(w, f_t, s_t, mu), theta, phi, alpha, slope, st)
        restored = jnp.isfinite(theta_t) & jnp.isfinite(f_t) & (theta_t <= (1 - _ARMIJO * alpha) * theta)
        ok = jnp.where(mode == _RESTORATION, restored, accepted)
        # the next trial where this one fails
        correct = (k == 0) & (theta_t >= theta)
        halved = jnp.where(mode == _CORRECTION, 0.5 * alpha_max, 0.5 * alpha)
        restore = (mode != _RESTORATION) & (halved < alpha_min)
        after_newton = jnp.where(restore, _RESTORATION, _NEWTON)
        next_mode = jnp.where(mode == _RESTORATION, _RESTORATION,
                              jnp.where((mode == _NEWTON) & correct, _CORRECTION, after_newton))
        next_alpha = jnp.where(mode == _RESTORATION, 0.5 * alpha,
                               jnp.where((mode == _NEWTON) & correct, alpha, jnp.where(restore, alpha_r0, halved)))
        first = jax.tree.map(lambda new, old: jnp.where(k == 0, new, old), (scale_h * h_t, scale_g * g_t + s_t), first)
        result = (ok, f_type & (mode != _RESTORATION), mode, alpha, direction, (f_t, h_t, g_t))
        return k + 1, next_mode, next_alpha, ok, result, first

    initial = (jnp.zeros((), jnp.int32), jnp.asarray(_NEWTON), alpha_max, jnp.zeros((), bool),
               (jnp.zeros((), bool), jnp.zeros((), bool), jnp.asarray(_NEWTON), jnp.zeros_like(alpha_max),
                (dx, dy, ds), (f, h_raw, g_raw)), (h, g + s))
    trials, _, _, _, result, _ = jax.lax.while_loop(
        lambda carry: ~carry[3] & (carry[0] < 2 * options.max_backtracks) & (carry[2] > _ALPHA_SMALLEST),
        trial_body, initial)
    ok, f_type, mode, alpha, (dx, dy, ds), (f_t, h_t, g_t) = result
    restored = ok & (mode == _RESTORATION)
    moved, ok = ok, ok & ~restored
    alpha = jnp.where(moved, alpha, 0.0)
    s_new = jnp.where(moved, s + alpha * ds, s)
    dz = mu / s - z - sigma * ds
    alpha_z = _to_boundary(z, dz, tau)
    x_new, y_new = st.x + alpha * dx, st.y + alpha * dy
    z_new = jnp.where(moved, z + alpha_z * dz, z)
    z_new = jnp.clip(z_new, mu / (_KAPPA_SIGMA * s_new), _KAPPA_SIGMA * mu / s_new)
    failures = jnp.where(ok, 0, jnp.where(restored, st.failures, st.failures + 1))
    # an accepted step that is not f-type, and a restoration step, add the current point (with
    # margins) to the filter
    augment = (ok & ~f_type) | restored
    slot = st.filter_next % _FILTER_SIZE
    filter_theta = jnp.where(augment, st.filter_theta.at[slot].set((1 - _GAMMA_THETA) * theta), st.filter_theta)
    filter_phi = jnp.where(augment, st.filter_phi.at[slot].set(phi - _GAMMA_PHI * theta), st.filter_phi)
    backtracks = trials

    stationarity = _norm_inf(grad) / w / jnp.maximum(1.0, jnp.abs(f))  # of the unscaled problem's L
    finite = jnp.isfinite(error) & jnp.all(jnp.isfinite(dx))
    stopped = failures >= options.max_failures
    infeasible = stopped & (violation(h_raw, g_raw) > options.infeasible_above)
    code = jnp.select([~finite, converged, accepted, infeasible, stopped],
                      [_NOT_FINITE, _CONVERGED, _ACCEPTABLE, _LOCALLY_INFEASIBLE, _STALLED], _RUNNING)
    done = code != _RUNNING
    # a finished problem keeps the point its verdict is about
    keep = lambda old, new: jnp.where(done, old, new)  # noqa: E731
    return State(x=keep(st.x, x_new), s=keep(s, s_new), y=keep(st.y, y_new), z=keep(z, z_new), mu=mu,
                 filter_theta=filter_theta, filter_phi=filter_phi,
                 filter_next=st.filter_next + augment.astype(jnp.int32), theta_min=st.theta_min,
                 theta_max=st.theta_max, delta=delta,
                 f=keep(f, jnp.where(moved, f_t, f)), h=keep(h_raw, jnp.where(moved, h_t, h_raw)),
                 g=keep(g_raw, jnp.where(moved, g_t, g_raw)),
                 error=error, stationarity=stationarity, iteration=st.iteration + 1, acceptable=acceptable,
                 failures=failures,
                 evaluations=st.evaluations + exact_derivatives.directions(problem, structure) + backtracks + 2,
                 code=code.astype(jnp.int32), scale_f=w, scale_h=scale_h, scale_g=scale_g)


def _block(problem, options, structure, params, state: State, until) -> State:
    """Iterations of a batch of problems (``params``, ``state``: leading axis B) until each finishes or
    reaches iteration ``until`` (B,) (its own: the lanes of a batch may hold problems that started at
    different times); a lane that has stopped keeps its state while the others iterate. One loop whose
    body is the vmapped iteration (not the vmapped loop of one problem: the same arithmetic, but vmap's
    rule for a loop transforms its body more than once; the M1-M4 solve in a fresh process took 61 s
    instead of 66 s on an empty compilation cache, 2 cores, 2026-12-06)."""
    iterate = jax.vmap(functools.partial(_iterate, problem, options, structure))

    def running(st):
        return (st.code == _RUNNING) & (st.iteration < until)

    return jax.lax.while_loop(lambda st: jnp.any(running(st)),
                              lambda st: _lanes_where(running(st), iterate(params, st), st), state)


@dataclasses.dataclass(frozen=True)
class CompiledInteriorPoint:
    """The jitted, vmapped programs of one problem and options: build once with :func:`compile_problem`
    and reuse across solves of the same shape (``structure`` and ``params`` are arguments, so designs
    and colourings of one shape share the programs)."""

    problem: nlp.ConstrainedProblem
    options: InteriorPointOptions
    initial: Callable
    block: Callable
    #: :func:`program_memory` per batch shape: lowering the iteration program to ask XLA costs seconds
    memory: dict = dataclasses.field(default_factory=dict, compare=False, repr=False)


def loop_options(options: InteriorPointOptions) -> InteriorPointOptions:
    """``options`` less the settings the compiled iterations do not depend on (the first barrier
    parameter, the iteration budget, its blocks, the batch's quorum, patience and lanes): solves that differ
    only in those share programs."""
    return dataclasses.replace(options, mu_initial=0.1, max_iterations=1, block=1, quorum=1.0, patience=0,
                               lanes=None)


def compile_problem(problem: nlp.ConstrainedProblem, options: InteriorPointOptions = InteriorPointOptions()
                    ) -> CompiledInteriorPoint:
    """The interior point's programs for ``problem`` (compiled on first call), for every options that
    share :func:`loop_options` with ``options``."""
    options = loop_options(options)
    initial = jax.jit(jax.vmap(functools.partial(initial_state, problem), in_axes=(0, 0, 0, 0, None)))
    block = jax.jit(functools.partial(_block, problem, options))
    return CompiledInteriorPoint(problem, options, initial, block)


_STATUS = {_RUNNING: nlp.ITERATION_LIMIT, _CONVERGED: nlp.CONVERGED, _ACCEPTABLE: nlp.CONVERGED,
           _STALLED: nlp.STALLED, _LOCALLY_INFEASIBLE: nlp.INFEASIBLE, _NOT_FINITE: nlp.DIVERGED}


def _status(code: int, final_violation: float, options: InteriorPointOptions) -> str:
    if code == _RUNNING and final_violation > options.infeasible_above:
        return nlp.INFEASIBLE
    return _STATUS[code]


def padded_batch(batch: int) -> int:
    """The batch size a batch of ``batch`` problems runs as: the next power of two or 1.5 times one (1, 2,
    3, 4, 6, 8, 12, 16, 24, ...), so that batches of nearby sizes share a compiled program and padding
    leaves at most a third of the lanes idle; then up to a multiple of the devices JAX sees, so that
    :func:`batch_sharding` splits it over all of them."""
    size = 1 << max(batch - 1, 0).bit_length()
    size = 3 * size // 4 if size >= 4 and 3 * size // 4 >= batch else size
    devices = jax.device_count()
    return -(-size // devices) * devices


def pad_rows(leaf, size: int):
    """``leaf`` (B, ...) extended to (size, ...) by copies of its first row."""
    extra = size - leaf.shape[0]
    return leaf if extra == 0 else jnp.concatenate([leaf, jnp.repeat(leaf[:1], extra, axis=0)])


def batch_sharding(batch: int):
    """A sharding that splits the leading (batch) axis over every device JAX sees, or None on one
    device or when the batch does not divide evenly."""
    devices = jax.devices()
    if len(devices) < 2 or batch % len(devices):
        return None
    mesh = jax.sharding.Mesh(np.array(devices), ("batch",))
    return jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch"))


def solve(problem: nlp.ConstrainedProblem, x0, params, options: InteriorPointOptions = InteriorPointOptions(),
          structure: exact_derivatives.Structure | None = None, compiled: CompiledInteriorPoint | None = None,
          multipliers: tuple[Any, Any] | None = None,
          progress: Callable[[int, dict], None] | None = None, memory_budget: float | None = None,
          say: Callable[[str], None] | None = None) -> nlp.SolveResult:
    """Solves a batch of B problems of one shape in one compiled program.

    Args:
      problem: f, h, g (constraints scaled to order one).
      x0: starting points, shape (B, n).
      params: per-problem data, leaves with leading dimension B.
      options: solver settings.
      structure: the derivatives' colouring (:func:`~biped_jax.optim.exact_derivatives.probe_structure`),
        shared by the batch; None: dense (every column its own direction).
      compiled: from :func:`compile_problem` with the same :func:`loop_options`, to reuse across calls.
      multipliers: (y0 (B, m_h), z0 (B, m_g)) to warm-start with (of the unscaled problem; z0 <= 0 where
        unknown); None: zero and mu / s.
      progress: called after every block with (the iterations the lanes have run, {"cost", "violation",
        "error", "mu", "gradients", "stationarity": (B,), "done": (B,) bool}: each problem's latest
        values, inf for a problem still waiting for a lane).

    The problems run in lanes of one program (``options.lanes``, default the whole batch), padded to
    :func:`padded_batch` lanes (copies of the first problem that never iterate) so that batches of nearby
    sizes share a program; a lane whose problem finishes takes the next waiting one. Where the lanes'
    program needs more memory than ``memory_budget`` bytes (default: :data:`MEMORY_FRACTION` of what the
    device has free, XLA's own estimate of the compiled program), fewer lanes are used (``say``, default
    a logged warning, tells how many); a single problem that does not fit raises MemoryError before
    running.

    Returns an :class:`~biped_jax.optim.nlp.SolveResult`: ``outer_iterations`` counts interior-point
    iterations, ``gradients`` the problem evaluations (each derivative pass counted as its colours),
    ``history`` one row per block of each problem's own iterations (a problem that finished early
    repeats its last); the multipliers are the unscaled problem's (f + lam_eq.h + lam_in.g).
    """
    started = time.perf_counter()
    if compiled is None or compiled.options != loop_options(options):
        compiled = compile_problem(problem, options)
    x0 = jnp.asarray(x0, dtype=jnp.result_type(float))
    if x0.ndim != 2:
        raise ValueError(f"x0 must have shape (B, n), got shape {x0.shape}")
    batch, size = x0.shape
    f0, h0, g0 = jax.eval_shape(problem.evaluate, x0[0], jax.tree.map(lambda a: a[0], params))
    if structure is None:
        structure = exact_derivatives.dense_structure(size, h0.shape[0] + g0.shape[0])
    if multipliers is None:
        multipliers = (jnp.zeros((batch,) + h0.shape, x0.dtype), jnp.zeros((batch,) + g0.shape, x0.dtype))
    multipliers = tuple(jnp.asarray(m, x0.dtype) for m in multipliers)
    budget = available_memory() * MEMORY_FRACTION if memory_budget is None else memory_budget
    lanes = min(batch, options.lanes or batch)
    lanes = _lanes_that_fit(compiled, structure, x0[:lanes], jax.tree.map(lambda a: a[:lanes], params),
                            tuple(m[:lanes] for m in multipliers), budget, say)
    return _solve_pooled(compiled, options, structure, x0, params, multipliers, lanes, progress, started)


#: The share of the free device memory one batch's program may take (the rest: the arrays around it).
MEMORY_FRACTION = 0.7


def available_memory() -> float:
    """Bytes free for a program on JAX's first device: an accelerator's free memory, or the host's
    available memory (``MemAvailable``) on the CPU."""
    device = jax.devices()[0]
    stats = device.memory_stats() if device.platform != "cpu" else None
    if stats and "bytes_limit" in stats:
        return float(stats["bytes_limit"] - stats.get("bytes_in_use", 0))
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except OSError:
        pass
    return float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))


def program_memory(compiled: CompiledInteriorPoint, structure, x0, params, multipliers) -> float:
    """Bytes the iteration program of this batch (padded) needs, by XLA's analysis of the compiled
    program (arguments, outputs and temporaries); the program is compiled here and kept by JAX, so the
    solve that follows does not compile it again."""
    padded = padded_batch(x0.shape[0])
    sharding = batch_sharding(padded)  # as the solve will place the batch
    # the avals exactly as the solve's (weak types included), so that JAX keeps this compilation for it
    shaped = lambda a: jax.ShapeDtypeStruct((padded,) + a.shape[1:], a.dtype, sharding=sharding,  # noqa: E731
                                            weak_type=getattr(a, "weak_type", False))
    shapes = jax.tree.map(lambda a: shaped(jax.typeof(jnp.asarray(a))), (x0, params, multipliers))
    key = (str(jax.tree.structure((shapes, structure))), tuple(jax.tree.leaves(shapes)),
           tuple((np.shape(a), np.asarray(a).dtype.str) for a in jax.tree.leaves(structure)))
    if key in compiled.memory:
        return compiled.memory[key]
    state = jax.tree.map(shaped, jax.eval_shape(compiled.initial, shapes[0], shapes[1], shapes[2][0],
                                                shapes[2][1], 0.1))
    executable = compiled.block.lower(structure, shapes[1], state, np.ones(padded, np.int32)).compile()
    stats = executable.memory_analysis()
    needed = 0.0 if stats is None else float(  # a backend without the analysis: assume it fits
        stats.argument_size_in_bytes + stats.output_size_in_bytes + stats.temp_size_in_bytes
        - stats.alias_size_in_bytes)
    compiled.memory[key] = needed
    return needed


def _lanes_that_fit(compiled, structure, x0, params, multipliers, budget: float, say) -> int:
    """The largest number of lanes (problems iterated at once: all of x0's, or a :func:`padded_batch`
    size) whose program fits in ``budget`` bytes, by XLA's memory analysis scaled with the lanes."""
    batch = x0.shape[0]
    needed = program_memory(compiled, structure, x0, params, multipliers)
    if needed <= budget:
        return batch
    per_problem = needed / padded_batch(batch)
    chunk = max((b for b in range(1, batch) if padded_batch(b) == b and b * per_problem <= budget), default=0)
    if chunk == 0:
        raise MemoryError(f"one problem's program needs about {per_problem / 2**30:.2f} GiB, more than the "
                          f"{budget / 2**30:.2f} GiB this device has free for it")
    message = (f"{batch} problems at once need about {needed / 2**30:.1f} GiB, more than the "
               f"{budget / 2**30:.1f} GiB free for them: solving {chunk} at a time, each lane taking the next "
               f"problem as its own finishes")
    (say or logging.getLogger(__name__).warning)(message)
    return chunk


def _lanes_where(mask, fresh, old):
    """``old`` (a pytree of (L, ...) lane arrays) with the lanes where ``mask`` (L,) holds taken from
    ``fresh``."""
    return jax.tree.map(lambda a, b: jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, b), fresh, old)


_refilled = jax.jit(_lanes_where)


#: What :func:`_solve_pooled` reads of every lane after every block (the history and the progress).
_ROW_KEYS = ("cost", "violation", "error", "mu", "gradients", "stationarity")


def _lane_rows(state: State) -> dict:
    """What the host reads of every lane after a block: the rows' values, the code and the iteration."""
    return {"cost": state.f, "violation": jax.vmap(violation)(state.h, state.g), "error": state.error,
            "mu": state.mu, "gradients": state.evaluations, "stationarity": state.stationarity,
            "code": state.code, "iteration": state.iteration}


def _latest(rows: list) -> dict:
    """Each problem's last row as (B,) arrays (inf, and not done, for a problem still waiting for a lane)."""
    waiting = {key: np.inf for key in _ROW_KEYS} | {"done": False}
    return {key: np.asarray([(r[-1] if r else waiting)[key] for r in rows]) for key in waiting}


def _solve_pooled(compiled, options, structure, x0, params, multipliers, lanes, progress, started) -> nlp.SolveResult:
    """A batch of B problems solved in ``lanes`` lanes of one program (the whole batch where it fits):
    each lane iterates one problem and, as soon as it finishes, takes the next waiting one, so that a
    batch larger than its program costs the sum of its problems' iterations, not its slowest problem's
    iterations times its chunks (see :func:`solve`). While problems wait for a lane, the lanes run
    blocks of one iteration, so that a finished lane is refilled at once; then blocks of
    ``options.block``."""
    batch = x0.shape[0]
    y0, z0 = multipliers
    size = padded_batch(lanes)
    sharding = batch_sharding(size)

    def rows_of(problems):
        """x0, params, y0, z0 of ``problems`` (size,) (lanes without one: copies of the first problem)."""
        rows = jnp.asarray(np.maximum(problems, 0))
        taken = jax.tree.map(lambda a: jnp.asarray(a)[rows], (x0, params, y0, z0))
        return taken if sharding is None else jax.device_put(taken, sharding)

    def parked(state):
        """``state`` with the lanes that hold no problem marked as padding (they never iterate)."""
        return state._replace(code=jnp.where(jnp.asarray(lane >= 0), state.code, _PADDING))

    lane = np.where(np.arange(size) < batch, np.arange(size), -1)   # the problem in each lane, -1: none
    waiting = int(np.sum(lane >= 0))                                  # the next problem to start
    x, lane_params, y, z = rows_of(lane)
    state = parked(compiled.initial(x, lane_params, y, z, options.mu_initial))
    iterations = np.zeros(size, np.int32)
    results = [None] * batch     # per problem: its lane's final state, on the host
    rows = [[] for _ in range(batch)]   # per problem: its rows, one per block it ran
    steps, quorum_at = 0, None
    while np.any(lane >= 0):
        # one iteration at a time while problems wait (a lane that finished idles until its block ends)
        block = 1 if waiting < batch else options.block
        until = np.minimum(iterations + block, options.max_iterations).astype(np.int32)
        state = compiled.block(structure, lane_params, state, until)
        steps += block
        host = jax.tree.map(np.asarray, _lane_rows(state))
        iterations = host["iteration"]
        active = np.flatnonzero(lane >= 0)
        finished = (host["code"][active] != _RUNNING) | (iterations[active] >= options.max_iterations)
        for at in active:
            rows[lane[at]].append({key: host[key][at] for key in _ROW_KEYS} | {"done": host["code"][at] != _RUNNING})
        latest = _latest(rows)
        if quorum_at is None and waiting == batch and latest["done"].mean() >= options.quorum:
            quorum_at = steps
        if quorum_at is not None and steps - quorum_at >= options.patience:
            finished[:] = True                  # the quorum's patience is over: the rest stop here
        ended = active[finished]
        if len(ended):
            kept = jax.tree.map(lambda a: np.asarray(a[jnp.asarray(ended)]), state)
            for k, at in enumerate(ended):
                results[lane[at]] = jax.tree.map(lambda a: a[k], kept)
            starting = np.zeros(size, bool)
            for at in ended:
                lane[at], waiting = (waiting, waiting + 1) if waiting < batch else (-1, waiting)
                starting[at] = lane[at] >= 0
            if starting.any():
                x, new_params, y, z = rows_of(lane)
                fresh = compiled.initial(x, new_params, y, z, options.mu_initial)
                state, lane_params = _refilled(jnp.asarray(starting), (fresh, new_params), (state, lane_params))
                iterations = np.where(starting, 0, iterations)
            state = parked(state)
        if progress:
            progress(steps, latest)
    return _pooled_result(results, rows, options, time.perf_counter() - started)


def _pooled_result(results: list, rows: list, options, wall_time_s: float) -> nlp.SolveResult:
    """The batch's result from each problem's final state (on the host) and its rows per block (the
    history: a problem that finished early repeats its last row)."""
    final = jax.tree.map(lambda *leaves: np.stack(leaves), *results)
    count = max(len(r) for r in rows)
    history = [{key: np.asarray([r[min(k, len(r) - 1)][key] for r in rows]) for key in rows[0][0]}
               for k in range(count)]
    history[-1]["x"] = final.x
    viol = np.asarray([r[-1]["violation"] for r in rows])
    return nlp.SolveResult(
        x=final.x, cost=final.f, equalities=final.h, inequalities=final.g, violation=viol,
        stationarity=final.stationarity,
        status=[_status(int(c), float(v), options) for c, v in zip(final.code, viol)],
        outer_iterations=final.iteration, gradients=final.evaluations, wall_time_s=wall_time_s,
        history=history, multipliers_eq=final.y * final.scale_h / final.scale_f[:, None],
        multipliers_in=final.z * final.scale_g / final.scale_f[:, None])
