"""Sequential quadratic programming (SciPy's SLSQP) on a :class:`~biped_jax.augmented_lagrangian.ConstrainedProblem`.

The batched augmented Lagrangian (:mod:`biped_jax.augmented_lagrangian`) is cheap per iteration and
vmaps over designs, but on the power-limited gait its penalty runs to the cap and its inner L-BFGS
wanders into worse basins: measured on M2 at 20 W (README, "Solvers"), SLSQP from the plain
straight-stance start reaches J = 2.8506 on our transcription, where the augmented Lagrangian from the
same start ends at 4.1-5.0 and, started *at* the SLSQP optimum, leaves it for 4.64. SQP keeps the
linearised constraints in every step (no penalty to tune) and its quasi-Newton matrix learns the
curvature of the Lagrangian, not of a penalty.

SLSQP (Kraft, A software package for sequential quadratic programming, DFVLR-FB 88-28, 1988) runs one
problem at a time on the CPU; what it calls is compiled once per problem shape: the value (f, h, g),
and its derivatives by central differences, 2n + 1 evaluations in one vmapped call (forward-mode
autodiff through a long rollout costs minutes to compile on a small CPU). Forward differences (about
7 correct digits) were measured too coarse: from the same M2 start they led SLSQP into the worse
basin (J = 4.146) and never let it terminate; central ones are good to about 10 digits.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import minimize

from biped_jax import augmented_lagrangian as al


@dataclasses.dataclass(frozen=True)
class SQPOptions:
    """Settings of :func:`solve`.

    Attributes:
      tolerance: largest scaled constraint violation accepted as feasible (as in
        :class:`~biped_jax.augmented_lagrangian.SolverOptions`).
      stationarity: largest |grad f + J^T lambda|_inf / max(1, |f|) accepted at convergence when SLSQP
        stops on its line search (its usual end with differenced derivatives).
      max_iterations: SLSQP iterations at most.
      accuracy: SLSQP's goal on the change of f (its ``ftol``).
      step: half-width of the central differences, relative to max(1, |x_i|).
      infeasible_above: a problem SLSQP abandons with a larger scaled violation is ``infeasible``,
        with a smaller one ``stalled``.
    """

    tolerance: float = 1e-6
    stationarity: float = 1e-3
    max_iterations: int = 800
    accuracy: float = 1e-10
    step: float = 1e-5
    infeasible_above: float = 1e-3


@dataclasses.dataclass(frozen=True)
class CompiledSQP:
    """The two compiled functions of one problem (one problem at a time, no batch dimension):
    ``value(x, params) -> (f, h, g)`` and ``derivatives(x, params) -> (f, h, g, grad f, jac h, jac g)``."""

    value: Callable
    derivatives: Callable


def compile_problem(problem: al.ConstrainedProblem, step: float = SQPOptions.step) -> CompiledSQP:
    """Jitted value and central-difference derivatives of ``problem`` (compiled on first call)."""
    value = jax.jit(problem.evaluate)
    evaluate_points = jax.vmap(problem.evaluate, in_axes=(0, None))

    @jax.jit
    def derivatives(x, params):
        steps = step * jnp.maximum(1.0, jnp.abs(x))
        size = x.shape[-1]
        points = jnp.concatenate([x[None], x[None] + jnp.diag(steps), x[None] - jnp.diag(steps)])
        f, h, g = evaluate_points(points, params)
        width = 2 * steps

        def slope(v):  # central differences, (outputs, n)
            return ((v[1:size + 1] - v[size + 1:]) / width.reshape((-1,) + (1,) * (v.ndim - 1))).T
        return f[0], h[0], g[0], slope(f), slope(h), slope(g)
    return CompiledSQP(value, derivatives)


def _solve_one(compiled: CompiledSQP, x0: np.ndarray, params, options: SQPOptions,
               progress: Callable[[int, float, float], None] | None):
    """SLSQP on one problem; returns (x, f, h, g, status, stationarity, iterations, evaluations,
    lam_eq, lam_in, trace) with our sign conventions (f + lam_eq.h + lam_in.g, lam_in >= 0); trace
    holds (f, scaled violation, evaluations so far) at the start and after every iteration."""
    cache: dict = {}
    counts = {"evaluations": 0}

    def value(x):
        key = x.tobytes()
        if key not in cache:
            counts["evaluations"] += 1
            f, h, g = compiled.value(jnp.asarray(x), params)
            cache.clear()
            cache[key] = (float(f), np.asarray(h), np.asarray(g))
        return cache[key]

    derivative_cache: dict = {}

    def derivatives(x):
        key = x.tobytes()
        if key not in derivative_cache:
            counts["evaluations"] += 2 * x.size + 1
            out = compiled.derivatives(jnp.asarray(x), params)
            derivative_cache.clear()
            derivative_cache[key] = tuple(np.asarray(a) for a in out)
        return derivative_cache[key]

    iterations = [0]
    f0, h0, g0 = value(np.asarray(x0, dtype=float))
    trace = [(f0, _scaled_violation(h0, g0), counts["evaluations"])]  # (f, violation, evaluations) per iteration

    def callback(x):
        iterations[0] += 1
        f, h, g = value(x)
        trace.append((f, _scaled_violation(h, g), counts["evaluations"]))
        if progress:
            progress(iterations[0], f, trace[-1][1])

    constraints = []
    if value(x0)[1].size:
        constraints.append({"type": "eq", "fun": lambda x: value(x)[1], "jac": lambda x: derivatives(x)[4]})
    if value(x0)[2].size:
        constraints.append({"type": "ineq", "fun": lambda x: -value(x)[2], "jac": lambda x: -derivatives(x)[5]})
    result = minimize(lambda x: value(x)[0], np.asarray(x0, dtype=float), jac=lambda x: derivatives(x)[3],
                      constraints=constraints, method="SLSQP", callback=callback,
                      options={"maxiter": options.max_iterations, "ftol": options.accuracy})
    x = np.asarray(result.x)
    f, h, g, grad, jac_h, jac_g = derivatives(x)
    multipliers = np.asarray(getattr(result, "multipliers", np.zeros(h.size + g.size)))
    lam_eq, lam_in = -multipliers[:h.size], np.maximum(multipliers[h.size:], 0.0)
    stationarity = float(np.max(np.abs(grad + jac_h.T @ lam_eq + jac_g.T @ lam_in), initial=0.0)
                         / max(1.0, abs(float(f))))
    violation = _scaled_violation(h, g)
    finite = bool(np.all(np.isfinite(x)) and np.isfinite(f))
    if not finite:
        status = al.DIVERGED
    elif violation <= options.tolerance and (result.status == 0 or stationarity <= options.stationarity):
        status = al.CONVERGED
    elif result.status == 9:  # iteration limit
        status = al.ITERATION_LIMIT
    elif violation <= options.tolerance:
        status = al.ITERATION_LIMIT  # feasible but not stationary: stopped short of an optimum
    else:
        status = al.INFEASIBLE if violation > options.infeasible_above else al.STALLED
    return x, f, h, g, status, stationarity, iterations[0], counts["evaluations"], lam_eq, lam_in, trace


def _history(traces, x, stationarity) -> list[dict]:
    """Per iteration a row of (B,) arrays like the augmented Lagrangian's (cost, violation, gradients:
    evaluations so far; penalty 0), a problem that finished early holding its last values; the last
    row has the solutions x and their stationarity."""
    length = max(len(trace) for trace in traces)
    padded = np.array([trace + [trace[-1]] * (length - len(trace)) for trace in traces])  # (B, T, 3)
    rows = [{"cost": padded[:, i, 0], "violation": padded[:, i, 1], "gradients": padded[:, i, 2].astype(int),
             "penalty": np.zeros(len(traces)), "stationarity": np.full(len(traces), np.nan)}
            for i in range(length)]
    rows[-1].update(x=x, stationarity=stationarity)
    return rows


def _scaled_violation(h, g) -> float:
    return float(max(np.max(np.abs(h), initial=0.0), np.max(g, initial=0.0), 0.0))


def solve(problem: al.ConstrainedProblem, x0, params, options: SQPOptions = SQPOptions(),
          compiled: CompiledSQP | None = None,
          progress: Callable[[int, int, float, float], None] | None = None) -> al.SolveResult:
    """Solves a batch of problems one after another with SLSQP.

    Args:
      problem: f, h, g (constraints scaled to order one, as for the augmented Lagrangian).
      x0: starting points, shape (B, n).
      params: per-problem data, leaves with leading dimension B.
      options: solver settings.
      compiled: from :func:`compile_problem`, to reuse across calls.
      progress: called after each SLSQP iteration with (problem index, iteration, f, scaled violation).

    Returns an :class:`~biped_jax.augmented_lagrangian.SolveResult` (``outer_iterations`` counts SLSQP
    iterations, ``gradients`` counts function evaluations, ``history`` one row per SLSQP iteration).
    """
    started = time.perf_counter()
    compiled = compiled or compile_problem(problem, options.step)
    x0 = np.asarray(x0, dtype=float)
    rows = []
    for b in range(x0.shape[0]):
        params_b = jax.tree.map(lambda a: a[b], params)
        report = (lambda i, f, v, b=b: progress(b, i, f, v)) if progress else None
        rows.append(_solve_one(compiled, x0[b], params_b, options, report))
    x, f, h, g, status, stationarity, iterations, evaluations, lam_eq, lam_in, traces = zip(*rows)
    violation = np.array([_scaled_violation(a, c) for a, c in zip(h, g)])
    cost = np.array(f, dtype=float)
    history = _history(traces, np.stack(x), np.array(stationarity))
    return al.SolveResult(x=np.stack(x), cost=cost, equalities=np.stack(h), inequalities=np.stack(g),
                          violation=violation, stationarity=np.array(stationarity), status=list(status),
                          outer_iterations=np.array(iterations), gradients=np.array(evaluations),
                          wall_time_s=time.perf_counter() - started, history=history,
                          multipliers_eq=np.stack(lam_eq), multipliers_in=np.stack(lam_in))
