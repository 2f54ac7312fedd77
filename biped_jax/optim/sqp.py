"""Sequential quadratic programming (SciPy's SLSQP) on a
:class:`~biped_jax.optim.nlp.ConstrainedProblem`.

The batched augmented Lagrangian (:mod:`biped_jax.optim.augmented_lagrangian`) is cheap per iteration and
vmaps over designs, but on the power-limited gait its penalty runs to the cap and its inner L-BFGS
wanders into worse basins: measured on M2 at 20 W (README, "Solvers"), SLSQP from the plain
straight-stance start reaches J = 2.8506 on our transcription, where the augmented Lagrangian from the
same start ends at 4.1-5.0 and, started *at* the SLSQP optimum, leaves it for 4.64. SQP keeps the
linearised constraints in every step (no penalty to tune) and its quasi-Newton matrix learns the
curvature of the Lagrangian, not of a penalty.

SLSQP (Kraft, A software package for sequential quadratic programming, DFVLR-FB 88-28, 1988) runs one
problem at a time on the CPU; what it calls is compiled once per problem shape: the value (f, h, g),
and its derivatives by central differences, 2C + 1 evaluations in one vmapped call for C colours of
columns (:mod:`biped_jax.optim.coloured`; C = n without colouring). Forward differences (about
7 correct digits) were measured too coarse: from the same M2 start they led SLSQP into the worse
basin (J = 4.146) and never let it terminate. The smallest limit of a problem is minimised the same
way (:mod:`biped_jax.optim.limit_minimisation`).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import minimize

from biped_jax.optim import coloured, nlp


@dataclasses.dataclass(frozen=True)
class SQPOptions:
    """Settings of :func:`solve`.

    Attributes:
      tolerance: largest scaled constraint violation accepted as feasible (as in
        :class:`~biped_jax.optim.augmented_lagrangian.SolverOptions`; the gait's 1e-5 is at most 1e-4 in
        every group's own unit). SLSQP's iterates near an optimum hover at 1e-6 to 3e-6.
      stationarity: largest |grad f + J^T lambda|_inf / max(1, |f|) accepted at convergence when SLSQP
        stops on its line search (its usual end with differenced derivatives).
      max_iterations: SLSQP iterations at most.
      accuracy: SLSQP's goal on the change of f (its ``ftol``).
      step: half-width of the central differences, relative to max(1, |x_i|).
      infeasible_above: a problem SLSQP abandons with a larger scaled violation is ``infeasible``,
        with a smaller one ``stalled``.
      precondition: for a problem with residuals (f = r . r), SLSQP runs in z with x = x0 + P z,
        P = (H + precondition lambda_max I)^(-1/2) and H = 2 J_r^T J_r the Gauss-Newton matrix at x0,
        so that its first quasi-Newton matrix (the identity) has the objective's scale; None: in x.
        Measured on M2 at 20 W carried from 16 into 32 knot spans (J = 2.8506 there): in x the first
        step goes to J = 37.7 and SLSQP needs 200 iterations to come back to 2.8145; preconditioned
        it starts at 2.832 and is there in 100.
      acceptable_change, acceptable_iterations: stop early when feasible (violation within
        tolerance) and f changed by at most acceptable_change * max(1, |f|) over the last
        acceptable_iterations iterations, and call that ``converged`` (IPOPT's "acceptable" end, which
        by default does not test stationarity either: SLSQP's quasi-Newton tail creeps for hundreds of
        iterations at the 1e-5 level, and its multipliers there leave |grad L| at 1e-3 to 1e-2; the
        stationarity is still reported). 0 disables it.
      sparse: colour the columns of the central differences by the problem's sparsity
        (:class:`~biped_jax.optim.coloured.CompiledSQP`); False differences every column alone (2n + 1 rollouts).
      working_margin: SLSQP sees only the inequality rows within this margin of active (g > -margin,
        scaled units) at its start; where it ends with a row it did not see at g > -tolerance, the
        rows within the margin there join and it goes on from that point (:func:`working_rows`).
        None (the default): every row, always. SLSQP's subproblem costs in proportion to its rows:
        of the gait's 4442 rows in 48 spans (torque, voltage, knee range, heights, forces at every
        grid point) about 700 lie within 1.5 of active, and an iteration costs half. Rows outside
        stay inactive at the end, so the optimum is the full problem's (their multipliers are zero).
        Measured 2026-12-03 (study's 48 spans, from each model's coarse optimum): the same iterates
        (180/224/174/242 iterations, J equal to 6 digits) in half the time; from heuristic starts in
        12 spans each new round restarts SLSQP's quasi-Newton matrix and M2's impact starts hit
        the iteration cap, so the study keeps it to its fine space.
    """

    tolerance: float = 1e-5
    stationarity: float = 1e-3
    max_iterations: int = 800
    accuracy: float = 1e-10
    step: float = coloured.STEP
    infeasible_above: float = 1e-3
    precondition: float | None = 1e-6
    acceptable_change: float = 1e-6
    acceptable_iterations: int = 10
    sparse: bool = True
    working_margin: float | None = None


def _to_numpy(a):
    return float(a) if np.ndim(a) == 0 else np.asarray(a)


def _last_call(function: Callable, on_call: Callable) -> Callable:
    """``function(x)`` remembering its last argument and result: SLSQP asks the objective and each
    constraint (and their derivatives) separately at the same point, and one rollout serves all.
    ``on_call(x)`` runs after each real call."""
    last: dict = {}

    def remembered(x):
        key = x.tobytes()
        if key not in last:
            last.clear()
            last[key] = function(x)
            on_call(x)
        return last[key]
    return remembered


def _solve_one(compiled: coloured.CompiledSQP, x0: np.ndarray, params, options: SQPOptions,
               progress: Callable[[int, float, float], None] | None, scale: np.ndarray | None = None):
    """SLSQP on one problem; returns (x, f, h, g, status, stationarity, iterations, evaluations,
    lam_eq, lam_in, trace) with our sign conventions (f + lam_eq.h + lam_in.g, lam_in >= 0); trace
    holds (f, scaled violation, evaluations so far) at the start and after every iteration.

    One function of about 70 lines on purpose: SLSQP's callback, the working-set rounds and the final
    classification share the evaluation count, the trace and the best feasible iterate, which split
    further would travel as mutable cells between functions."""
    counts = {"evaluations": 0}
    value = _last_call(lambda x: tuple(map(_to_numpy, compiled.value(jnp.asarray(x), params))),
                       lambda x: counts.update(evaluations=counts["evaluations"] + 1))
    derivatives = _last_call(lambda x: tuple(map(_to_numpy, compiled.derivatives(jnp.asarray(x), params))),
                             lambda x: counts.update(evaluations=counts["evaluations"] + compiled.rollouts))

    x0 = np.asarray(x0, dtype=float)
    if scale is None:
        scale = gauss_newton_scale(derivatives(x0)[6], options.precondition)  # x = x0 + scale @ z
    to_x = (lambda z: x0 + scale @ z) if scale is not None else (lambda z: z)
    iterations, acceptable = [0], [False]
    f0, h0, g0 = value(x0)
    trace = [(f0, _scaled_violation(h0, g0), counts["evaluations"])]  # (f, violation, evaluations) per iteration
    # the cheapest feasible iterate: where SLSQP ends infeasible (stalled on a degenerate problem) it
    # is still a feasible point, reported as stopped short of an optimum
    best = [(f0, x0)] if trace[0][1] <= options.tolerance else [(np.inf, None)]

    def callback(z):
        iterations[0] += 1
        f, h, g = value(to_x(z))  # every row: feasibility and the trace are the whole problem's
        trace.append((f, _scaled_violation(h, g), counts["evaluations"]))
        if trace[-1][1] <= options.tolerance and f < best[0][0]:
            best[0] = (f, to_x(np.array(z)))
        else:  # an iterate infeasible only on the limit, lifted to feasibility
            lifted = compiled.lifted(to_x(np.array(z)), f, h, g, options.tolerance)
            if lifted is not None and lifted[1] < best[0][0]:
                best[0] = (lifted[1], lifted[0])
        if progress:
            progress(iterations[0], f, trace[-1][1])
        if _acceptable(trace, options):
            acceptable[0] = True
            raise StopIteration

    def chain(jacobian):  # d/dz of a function of x
        return jacobian if scale is None else jacobian @ scale

    always = compiled.always_seen(x0, params)
    rows = working_rows(g0, options.working_margin, always)
    z = np.zeros_like(x0) if scale is not None else x0
    while True:
        result = minimize(lambda z: value(to_x(z))[0], z, jac=lambda z: chain(derivatives(to_x(z))[3]),
                          constraints=_constraints(value, derivatives, to_x, chain, h0.size, rows),
                          method="SLSQP", callback=callback,
                          options={"maxiter": options.max_iterations - iterations[0], "ftol": options.accuracy})
        z = np.asarray(result.x)
        unseen = np.ones(g0.size, bool)
        unseen[rows] = False
        g = value(to_x(z))[2]
        if not np.any(unseen & (g > -options.tolerance)) or iterations[0] >= options.max_iterations:
            break
        rows = np.union1d(rows, working_rows(g, options.working_margin, always))  # and on from here
        acceptable[0] = False
    x = to_x(z)
    ended_infeasible = _scaled_violation(*value(x)[1:]) > options.tolerance
    fallback = ended_infeasible and best[0][1] is not None
    if fallback:
        x = best[0][1]
    f, h, g, grad, jac_h, jac_g, _ = derivatives(x)
    lam_eq, lam_in = _multipliers(result, h.size, g.size, rows)
    stationarity = float(np.max(np.abs(grad + jac_h.T @ lam_eq + jac_g.T @ lam_in), initial=0.0)
                         / max(1.0, abs(float(f))))
    finite = bool(np.all(np.isfinite(x)) and np.isfinite(f))
    status = _status(finite, fallback, _scaled_violation(h, g), result.status, stationarity, acceptable[0], options)
    return x, f, h, g, status, stationarity, iterations[0], counts["evaluations"], lam_eq, lam_in, trace


def _constraints(value: Callable, derivatives: Callable, to_x: Callable, chain: Callable, equalities: int,
                 rows: np.ndarray) -> list[dict]:
    """SLSQP's constraint dicts in z: every equality, and the inequality ``rows`` of the working set
    (SciPy's sign: fun >= 0)."""
    constraints = []
    if equalities:
        constraints.append({"type": "eq", "fun": lambda z: value(to_x(z))[1],
                            "jac": lambda z: chain(derivatives(to_x(z))[4])})
    if rows.size:
        constraints.append({"type": "ineq", "fun": lambda z: -value(to_x(z))[2][rows],
                            "jac": lambda z: -chain(derivatives(to_x(z))[5][rows])})
    return constraints


def _multipliers(result, equalities: int, inequalities: int, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """SLSQP's multipliers in our signs (f + lam_eq.h + lam_in.g, lam_in >= 0), shapes (m_h,), (m_g,);
    zero on the inequality rows SLSQP did not see."""
    multipliers = np.asarray(getattr(result, "multipliers", np.zeros(equalities + rows.size)))
    lam_in = np.zeros(inequalities)
    lam_in[rows] = np.maximum(multipliers[equalities:], 0.0)
    return -multipliers[:equalities], lam_in


def _status(finite: bool, fallback: bool, violation: float, slsqp_status: int, stationarity: float,
            acceptable: bool, options: SQPOptions) -> str:
    """The outcome of one SLSQP solve: diverged (non-finite), converged (feasible at SLSQP's own end,
    stationary, or acceptable; never the feasible fallback iterate), iteration limit (SLSQP's cap, or
    feasible and not stationary), else infeasible or stalled by the size of the violation."""
    if not finite:
        return nlp.DIVERGED
    if not fallback and violation <= options.tolerance and (
            slsqp_status == 0 or stationarity <= options.stationarity or acceptable):
        return nlp.CONVERGED
    if slsqp_status == 9 or violation <= options.tolerance:  # SLSQP's iteration limit, or feasible but
        return nlp.ITERATION_LIMIT                            # stopped short of an optimum
    return nlp.INFEASIBLE if violation > options.infeasible_above else nlp.STALLED


def working_rows(g: np.ndarray, margin: float | None, always: np.ndarray | None = None) -> np.ndarray:
    """The inequality rows SLSQP sees at a point with (scaled) values ``g``, shape (m_g,): indices of
    those above -``margin`` or marked in ``always`` (every row for a margin of None), sorted."""
    if margin is None:
        return np.arange(g.size)
    return np.flatnonzero((g > -margin) | (False if always is None else always))


def gauss_newton_scale(jac_r: np.ndarray, regularisation: float | None) -> np.ndarray | None:
    """(H + regularisation lambda_max(H) I)^(-1/2) for the Gauss-Newton matrix H = 2 J_r^T J_r, shape
    (n, n); None without residuals or regularisation."""
    if regularisation is None or jac_r.shape[0] == 0:
        return None
    eigenvalues, vectors = np.linalg.eigh(2 * jac_r.T @ jac_r)
    shifted = np.maximum(eigenvalues, 0.0) + regularisation * max(float(eigenvalues[-1]), 1e-12)
    return (vectors / np.sqrt(shifted)) @ vectors.T


def _acceptable(trace: list, options: SQPOptions) -> bool:
    """Feasible and f settled over the last ``acceptable_iterations`` iterations."""
    window = options.acceptable_iterations
    if options.acceptable_change <= 0 or len(trace) <= window or trace[-1][1] > options.tolerance:
        return False
    costs = [row[0] for row in trace[-window - 1:]]
    return max(costs) - min(costs) <= options.acceptable_change * max(1.0, abs(costs[-1]))


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


def solve(problem: nlp.ConstrainedProblem, x0, params, options: SQPOptions = SQPOptions(),
          compiled: coloured.CompiledSQP | None = None,
          progress: Callable[[int, int, float, float], None] | None = None,
          scales: np.ndarray | None = None) -> nlp.SolveResult:
    """Solves a batch of problems one after another with SLSQP.

    Args:
      problem: f, h, g (constraints scaled to order one, as for the augmented Lagrangian).
      x0: starting points, shape (B, n).
      params: per-problem data, leaves with leading dimension B.
      options: solver settings.
      compiled: from :func:`compile_problem`, to reuse across calls.
      progress: called after each SLSQP iteration with (problem index, iteration, f, scaled violation).
      scales: per problem the change of variables x = x0 + scale z SLSQP runs in, shape (B, n, n),
        instead of the Gauss-Newton one of ``options.precondition`` (for an objective without
        residuals whose scale the caller knows).

    Returns an :class:`~biped_jax.optim.nlp.SolveResult` (``outer_iterations`` counts SLSQP
    iterations, ``gradients`` counts function evaluations, ``history`` one row per SLSQP iteration).
    """
    started = time.perf_counter()
    compiled = compiled or coloured.compile_problem(problem, options.step, options.sparse)
    x0 = np.asarray(x0, dtype=float)
    rows = []
    for b in range(x0.shape[0]):
        params_b = jax.tree.map(lambda a: a[b], params)
        report = (lambda i, f, v, b=b: progress(b, i, f, v)) if progress else None
        rows.append(_solve_one(compiled, x0[b], params_b, options, report,
                               None if scales is None else np.asarray(scales[b])))
    x, f, h, g, status, stationarity, iterations, evaluations, lam_eq, lam_in, traces = zip(*rows)
    violation = np.array([_scaled_violation(a, c) for a, c in zip(h, g)])
    cost = np.array(f, dtype=float)
    history = _history(traces, np.stack(x), np.array(stationarity))
    return nlp.SolveResult(x=np.stack(x), cost=cost, equalities=np.stack(h), inequalities=np.stack(g),
                          violation=violation, stationarity=np.array(stationarity), status=list(status),
                          outer_iterations=np.array(iterations), gradients=np.array(evaluations),
                          wall_time_s=time.perf_counter() - started, history=history,
                          multipliers_eq=np.stack(lam_eq), multipliers_in=np.stack(lam_in))
