"""A batched augmented-Lagrangian solver over optax L-BFGS.

Solves B problems of the same shape at once:

    minimise f(x; p)  subject to  h(x; p) = 0,  g(x; p) <= 0,

with x of shape (n,) and p a pytree of per-problem data. The constraints must be scaled to order one
by the caller. One compiled, vmapped value-and-gradient function of the augmented Lagrangian
(Powell-Hestenes-Rockafellar form) serves every iteration: the multipliers and the penalty are its
arguments, and the backtracking (Armijo) line search runs in Python over that same function, so
nothing is traced twice. Inner problems use ``optax.scale_by_lbfgs`` for the direction.

Reference: Nocedal & Wright, Numerical Optimization (2006), Sec. 17.3-17.4 (bound-constrained
Lagrangian, multiplier and penalty updates).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax

from biped_jax.optim import gauss_newton, line_search, nlp


@dataclasses.dataclass(frozen=True)
class SolverOptions:
    """Settings of :func:`solve`.

    Attributes:
      tolerance: largest scaled constraint violation accepted as feasible.
      stationarity: largest |gradient of the Lagrangian|_inf / max(1, |f|) accepted at convergence.
      max_outer: multiplier updates at most.
      max_inner: L-BFGS iterations per inner problem at most.
      penalty_initial, penalty_growth, penalty_max: rho schedule; rho grows when the violation did not
        fall to a quarter and is above 10 x tolerance (near the tolerance the multipliers finish the
        job); a problem still infeasible at penalty_max is declared infeasible when its scaled
        violation exceeds infeasible_above, else stalled (see :data:`nlp.STALLED`).
      memory: L-BFGS memory.
      armijo: sufficient-decrease constant of the line search; max_backtracks halvings at most.
      precondition_every: inner iterations between refreshes of the Gauss-Newton preconditioner
        (problems with residuals only).
      cap_first_step: keep optax's unit-length cap on the first L-BFGS step after each refresh;
        False takes the full Gauss-Newton step there (problems with residuals only).
      grow_after_inner_solved: grow the penalty only when the inner problem reached its tolerance (not
        when max_inner cut it short).
      acceptable_change, acceptable_iterations: a feasible problem (violation within tolerance) whose f
        changed by at most acceptable_change (relative) in each of the last acceptable_iterations
        outer iterations is converged even if the stationarity test is not met (IPOPT's "acceptable"
        termination, Waechter & Biegler 2006, Sec. 3.9: the multipliers of an ill-conditioned problem
        settle slower than x). 0 disables it.
    """

    tolerance: float = 1e-6
    stationarity: float = 1e-3
    max_outer: int = 40
    max_inner: int = 300
    penalty_initial: float = 10.0
    penalty_growth: float = 10.0
    penalty_max: float = 1e9
    memory: int = 20
    armijo: float = 1e-4
    max_backtracks: int = 30
    precondition_every: int = 50
    cap_first_step: bool = True
    infeasible_above: float = 1e-3
    grow_after_inner_solved: bool = False
    acceptable_change: float = 0.0
    acceptable_iterations: int = 3


@dataclasses.dataclass(frozen=True)
class CompiledProblem:
    """The compiled, vmapped functions :func:`solve` calls; build once with :func:`compile_problem`
    and reuse across solves of the same problem shape."""

    value_and_grad: Callable
    jacobian: Callable | None


def lagrangian_value(f, h, g, lam_eq, lam_in, rho):
    """The Powell-Hestenes-Rockafellar augmented Lagrangian of one problem (scalars and 1-D arrays):
    f + lam_eq.h + rho/2 |h|^2 + (|max(0, lam_in + rho g)|^2 - |lam_in|^2) / (2 rho)."""
    value = f + lam_eq @ h + 0.5 * rho * h @ h
    return value + jnp.sum(jnp.maximum(0.0, lam_in + rho * g) ** 2 - lam_in**2) / (2 * rho)


def compile_problem(problem: nlp.ConstrainedProblem) -> CompiledProblem:
    """value_and_grad of the augmented Lagrangian (and the residual Jacobian, if residuals exist)."""
    def lagrangian(x, params, lam_eq, lam_in, rho):
        f, h, g = problem.evaluate(x, params)
        return lagrangian_value(f, h, g, lam_eq, lam_in, rho), (f, h, g)
    value_and_grad = jax.jit(jax.vmap(jax.value_and_grad(lagrangian, has_aux=True)))
    jacobian = None
    if problem.residuals is not None:
        jacobian = gauss_newton.forward_difference_jacobian(problem.residuals)
    return CompiledProblem(value_and_grad, jacobian)


@dataclasses.dataclass(frozen=True)
class _OuterState:
    """What the outer iterations carry, one entry per problem of the batch: the iterate and its
    :class:`~biped_jax.optim.line_search.Point`, the multipliers and penalty (jax arrays), and the
    bookkeeping (numpy) that decides the status."""

    x: jax.Array
    point: line_search.Point
    lam_eq: jax.Array
    lam_in: jax.Array
    rho: jax.Array
    active: np.ndarray             # still iterating
    status: tuple                  # of str
    outer_iterations: np.ndarray
    gradients: np.ndarray          # gradient evaluations so far (a forward-difference Jacobian counts n)
    previous_violation: np.ndarray  # the progress measure of the last outer iteration
    stationarity: np.ndarray
    inner_tolerance: np.ndarray
    at_cap: np.ndarray             # outer iterations spent infeasible at the penalty cap
    settled: np.ndarray            # consecutive feasible outer iterations with the cost settled
    previous_cost: np.ndarray
    best_violation: np.ndarray


def _preconditioner(compiled: CompiledProblem, state: _OuterState, params, identity):
    """The Gauss-Newton change of variables at the state's iterate (the identity without residuals or
    where it is not finite) and the gradient evaluations it cost per problem."""
    if compiled.jacobian is None:
        return identity, np.zeros(state.x.shape[0], dtype=int)
    jac_r, jac_h, jac_g = compiled.jacobian(state.x, params)
    precondition = gauss_newton.preconditioner(jac_r, jac_h, jac_g, state.point.g, state.lam_in, state.rho)
    finite = jnp.all(jnp.isfinite(precondition), axis=(1, 2))[:, None, None]
    return jnp.where(finite, precondition, identity), state.active * state.x.shape[1]


def _inner_solve(state: _OuterState, params, compiled: CompiledProblem, lbfgs, options: SolverOptions,
                 identity) -> tuple[_OuterState, np.ndarray]:
    """Minimises the augmented Lagrangian at fixed multipliers and penalty (L-BFGS in preconditioned
    coordinates x = x_ref + P z, restarted with a fresh P every ``precondition_every`` iterations).
    Problems leave one by one (gradient below their inner tolerance, or the line search stalled) and
    wait, frozen, for the others, so a finished problem never forces extra line-search trials.
    Returns the state at the new iterates and the scaled gradient norm per problem."""
    init, direction_fn = lbfgs
    inner_active = state.active.copy()
    x, point, gradients = state.x, state.point, state.gradients.copy()
    evaluate = lambda x_: line_search.evaluate(compiled.value_and_grad, x_, params, state.lam_eq, state.lam_in,  # noqa: E731
                                    state.rho)
    gradient_norm = np.zeros(x.shape[0])
    for inner in range(options.max_inner):
        if inner == 0 or (compiled.jacobian is not None and inner % options.precondition_every == 0):
            precondition, spent = _preconditioner(compiled, dataclasses.replace(state, x=x, point=point),
                                                  params, identity)
            gradients += spent
            x_ref, z = x, jnp.zeros_like(x)
            lbfgs_state = init(z)
            grad_z = jnp.einsum("bnm,bn->bm", precondition, point.grad)
        update, slope, lbfgs_state = line_search.descent_direction(direction_fn, grad_z, lbfgs_state, z)
        z_new, new, accepted, spent = line_search.backtrack(
            lambda z_: evaluate(x_ref + jnp.einsum("bnm,bm->bn", precondition, z_)),
            z, update, slope, point, inner_active, options.armijo, options.max_backtracks)
        gradients += spent
        frozen = jnp.asarray(~inner_active)
        z = line_search.where(frozen, z, z_new)
        point = jax.tree.map(lambda old, new_: line_search.where(frozen, old, new_), point, new)
        grad_z = jnp.einsum("bnm,bn->bm", precondition, point.grad)
        x = x_ref + jnp.einsum("bnm,bm->bn", precondition, z)
        gradient_norm = np.asarray(jnp.max(jnp.abs(point.grad), axis=-1) / jnp.maximum(1.0, jnp.abs(point.f)))
        inner_active &= ~((gradient_norm <= state.inner_tolerance) | ~np.asarray(accepted))
        if not inner_active.any():
            break
    return dataclasses.replace(state, x=x, point=point, gradients=gradients), gradient_norm


def _update_multipliers(state: _OuterState, gradient_norm: np.ndarray, options: SolverOptions):
    """Multiplier and penalty updates after an inner solve (Nocedal & Wright, Framework 17.3), for the
    active problems. Progress is measured with complementarity, max(g, -lambda/rho) (Birgin & Martinez,
    Practical Augmented Lagrangian Methods, 2014): a strictly feasible inequality with a positive
    multiplier is not converged. Returns the new state and the progress measure (B,)."""
    h, g, lam_in, rho, active = state.point.h, state.point.g, state.lam_in, state.rho, state.active
    measure = np.asarray(nlp.violation(h, jnp.abs(jnp.maximum(g, -lam_in / rho[:, None]))))
    act = jnp.asarray(active)[:, None]
    lam_eq = jnp.where(act, state.lam_eq + rho[:, None] * h, state.lam_eq)
    lam_in = jnp.where(act, jnp.maximum(0.0, lam_in + rho[:, None] * g), lam_in)
    grow = active & (measure > 0.25 * state.previous_violation) & (measure > 10 * options.tolerance)
    if options.grow_after_inner_solved:
        # an inner problem cut short by max_inner says nothing about the penalty being too small:
        # growing it then only worsens the conditioning of the next one (Conn, Gould & Toint,
        # LANCELOT, 1992: rho grows only after an inner problem solved to its tolerance)
        grow &= gradient_norm <= state.inner_tolerance
    rho = jnp.where(jnp.asarray(grow), jnp.minimum(rho * options.penalty_growth, options.penalty_max), rho)
    return dataclasses.replace(
        state, lam_eq=lam_eq, lam_in=lam_in, rho=rho,
        stationarity=np.where(active, gradient_norm, state.stationarity),
        previous_violation=np.where(active, measure, state.previous_violation),
        outer_iterations=state.outer_iterations + active,
        inner_tolerance=np.where(active, np.maximum(0.1 * state.inner_tolerance, 0.3 * options.stationarity),
                                 state.inner_tolerance)), measure


def _classify(state: _OuterState, measure: np.ndarray, violation: np.ndarray, options: SolverOptions) -> _OuterState:
    """Ends the problems that are done: ``diverged`` (non-finite), ``converged`` (feasible with
    complementarity, and stationary or with the cost settled), infeasible or stalled at the penalty
    cap with the violation no longer falling; the others stay active."""
    cost = np.asarray(state.point.f)
    finite = np.asarray(jnp.all(jnp.isfinite(state.x), axis=-1)) & np.isfinite(cost)
    change = np.abs(cost - state.previous_cost) / np.maximum(1.0, np.abs(cost))
    active = state.active.copy()
    settled = np.where(active & (measure <= options.tolerance) & (change <= options.acceptable_change),
                       state.settled + 1, np.where(active, 0, state.settled))
    status, at_cap, best_violation = list(state.status), state.at_cap.copy(), state.best_violation.copy()
    rho = np.asarray(state.rho)
    for b in np.flatnonzero(active):
        if not finite[b]:
            status[b], active[b] = nlp.DIVERGED, False
        elif measure[b] <= options.tolerance and (
                state.stationarity[b] <= options.stationarity
                or (options.acceptable_change > 0 and settled[b] >= options.acceptable_iterations)):
            status[b], active[b] = nlp.CONVERGED, False
        elif rho[b] >= options.penalty_max and violation[b] > options.tolerance:
            at_cap[b] += 1
            # Penalty at its cap and the violation no longer falling: no feasible point nearby.
            if state.stationarity[b] <= options.stationarity or (
                    at_cap[b] >= 3 and violation[b] > 0.9 * best_violation[b]):
                status[b], active[b] = _at_cap(violation[b], options), False
        best_violation[b] = min(best_violation[b], violation[b])
    return dataclasses.replace(state, active=active, status=tuple(status), settled=settled, at_cap=at_cap,
                               best_violation=best_violation,
                               previous_cost=np.where(state.active, cost, state.previous_cost))


def _initial_state(problem: nlp.ConstrainedProblem, compiled: CompiledProblem, x, params,
                   options: SolverOptions) -> _OuterState:
    """Every problem active at x (B, n) with zero multipliers and the initial penalty."""
    batch = x.shape[0]
    rho = jnp.full((batch,), options.penalty_initial)
    _, h_shape, g_shape = jax.eval_shape(problem.evaluate, x[0], jax.tree.map(lambda a: a[0], params))
    lam_eq, lam_in = jnp.zeros((batch, h_shape.shape[0])), jnp.zeros((batch, g_shape.shape[0]))
    point = line_search.evaluate(compiled.value_and_grad, x, params, lam_eq, lam_in, rho)
    return _OuterState(
        x=x, point=point, lam_eq=lam_eq, lam_in=lam_in, rho=rho, active=np.ones(batch, dtype=bool),
        status=(nlp.ITERATION_LIMIT,) * batch, outer_iterations=np.zeros(batch, dtype=int),
        gradients=np.ones(batch, dtype=int), previous_violation=np.asarray(nlp.violation(point.h, point.g)),
        stationarity=np.full(batch, np.inf), inner_tolerance=np.full(batch, 1.0),
        at_cap=np.zeros(batch, dtype=int), settled=np.zeros(batch, dtype=int),
        previous_cost=np.full(batch, np.nan), best_violation=np.full(batch, np.inf))


def solve(problem: nlp.ConstrainedProblem, x0, params, options: SolverOptions = SolverOptions(),
          compiled: CompiledProblem | None = None,
          progress: Callable[[int, dict], None] | None = None) -> nlp.SolveResult:
    """Solves a batch of problems: outer iterations of an inner solve (:func:`_inner_solve`), the
    multiplier update (:func:`_update_multipliers`) and the status (:func:`_classify`) over a frozen
    :class:`_OuterState`.

    Args:
      problem: f, h, g (and optionally the objective's residuals).
      x0: starting points, shape (B, n).
      params: per-problem data, a pytree whose leaves have leading dimension B.
      options: solver settings.
      compiled: from :func:`compile_problem`, to reuse across calls (saves compiling).
      progress: called after each outer iteration with (iteration, history row).
    """
    started = time.perf_counter()
    compiled = compiled or compile_problem(problem)
    x = jnp.asarray(x0)
    batch, size = x.shape
    # optax caps the first step of a fresh L-BFGS at unit length; in Gauss-Newton-preconditioned
    # coordinates the identity is already the right scale and the cap can turn each restart into a
    # short gradient step (see SolverOptions.cap_first_step).
    optimiser = optax.scale_by_lbfgs(memory_size=options.memory,
                                     scale_init_precond=options.cap_first_step or compiled.jacobian is None)
    lbfgs = (jax.jit(jax.vmap(optimiser.init)), jax.jit(jax.vmap(lambda g, s, x_: optimiser.update(g, s, x_))))
    identity = jnp.broadcast_to(jnp.eye(size, dtype=x.dtype), (batch, size, size))

    state = _initial_state(problem, compiled, x, params, options)
    history = []
    for outer in range(options.max_outer):
        if outer:  # the multipliers or the penalty changed: a new inner objective
            state = dataclasses.replace(
                state, point=line_search.evaluate(compiled.value_and_grad, state.x, params, state.lam_eq,
                                                  state.lam_in, state.rho),
                gradients=state.gradients + state.active)
        state, gradient_norm = _inner_solve(state, params, compiled, lbfgs, options, identity)
        violation = np.asarray(nlp.violation(state.point.h, state.point.g))
        state, measure = _update_multipliers(state, gradient_norm, options)
        row = {"cost": np.asarray(state.point.f), "violation": violation, "penalty": np.asarray(state.rho),
               "gradients": state.gradients.copy(), "stationarity": state.stationarity.copy(),
               "x": np.asarray(state.x)}
        history.append(row)
        if progress:
            progress(outer, row)
        state = _classify(state, measure, violation, options)
        if not state.active.any():
            break
    status = [_at_cap(state.previous_violation[b], options)
              if state.active[b] and float(state.rho[b]) >= options.penalty_max
              and state.previous_violation[b] > options.tolerance else state.status[b] for b in range(batch)]
    h, g = state.point.h, state.point.g
    return nlp.SolveResult(x=np.asarray(state.x), cost=np.asarray(state.point.f), equalities=np.asarray(h),
                           inequalities=np.asarray(g), violation=np.asarray(nlp.violation(h, g)),
                           stationarity=state.stationarity, status=status, outer_iterations=state.outer_iterations,
                           gradients=state.gradients, wall_time_s=time.perf_counter() - started, history=history,
                           multipliers_eq=np.asarray(state.lam_eq), multipliers_in=np.asarray(state.lam_in))


def _at_cap(violation: float, options: SolverOptions) -> str:
    """The status of a problem left infeasible at the penalty cap: :data:`nlp.INFEASIBLE` when clearly
    so, :data:`nlp.STALLED` when the violation is small enough that a better inner solver might close it."""
    return nlp.INFEASIBLE if violation > options.infeasible_above else nlp.STALLED


