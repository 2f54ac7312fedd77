"""Sequential quadratic programming (SciPy's SLSQP) on a
:class:`~biped_jax.optim.augmented_lagrangian.ConstrainedProblem`.

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
columns (:class:`CompiledSQP`; C = n without colouring) (forward-mode
autodiff through a long rollout costs minutes to compile on a small CPU). Forward differences (about
7 correct digits) were measured too coarse: from the same M2 start they led SLSQP into the worse
basin (J = 4.146) and never let it terminate; central ones are good to about 10 digits.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import minimize

from biped_jax.optim import augmented_lagrangian as al


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
        (:class:`CompiledSQP`); False differences every column alone (2n + 1 rollouts).
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
    step: float = 1e-5
    infeasible_above: float = 1e-3
    precondition: float | None = 1e-6
    acceptable_change: float = 1e-6
    acceptable_iterations: int = 10
    sparse: bool = True
    working_margin: float | None = None


#: Colour counts are padded to a multiple of this, so that problems of one shape whose sparsity
#: patterns differ slightly still share one compiled derivative program.
COLOUR_PADDING = 8


class CompiledSQP:
    """The compiled functions of one problem (one problem at a time, no batch dimension):
    ``value(x, params) -> (f, h, g)`` and ``derivatives(x, params) -> (f, h, g, grad f, jac h, jac g,
    jac r)``, jac r the residuals' Jacobian (an empty (0, n) array for a problem without residuals).

    The derivatives are central differences. With ``sparse`` (the default), columns that reach no
    output in common are perturbed together (Curtis, Powell and Reid, On the estimation of sparse
    Jacobian matrices, IMA J. Appl. Math. 13, 1974; SciPy's ``approx_derivative`` with ``sparsity``
    does the same): the gait's outputs are local in time (a B-spline control point moves four knot
    spans, a shooting node one segment), so its 200 columns in 32 knot spans need 27 colours (padded
    to 32: 65 rollouts instead of 401; 0.59 s -> about 0.08 s a Jacobian on the 2-core CPU). Without
    ``sparse`` every column is a colour of its own (the dense differences). Every row is still
    differenced along one column only, so the result equals the dense differences to rounding. The
    pattern (which outputs each column reaches) is probed once, at the first point asked for, by
    perturbing each column alone in the single-point program (:func:`sparsity_pattern`); it is a
    property of the problem's structure, not of the point (the gait has no branches that switch a
    dependence on or off; a test compares with dense differences at other points and designs). The
    objective's row is left out when it is a sum of squared residuals: grad f = 2 J_r^T r.
    """

    def __init__(self, problem: al.ConstrainedProblem, step: float = SQPOptions.step, sparse: bool = True):
        self.problem, self.step, self.sparse = problem, step, sparse
        self._outputs = jax.jit(functools.partial(_outputs, problem))
        self._coloured = jax.jit(functools.partial(_coloured_derivatives, problem, step))
        self.colouring: tuple | None = None  # (directions (C, n), colour of each column (n,), pattern (m, n))

    def value(self, x, params):
        """(f, h, g) at x."""
        return self._outputs(x, params)[:3]

    @property
    def rollouts(self) -> int | None:
        """Rollouts per Jacobian, 2C + 1 (None before the first one fixed the colouring)."""
        return None if self.colouring is None else 2 * self.colouring[0].shape[0] + 1

    def derivatives(self, x, params):
        """(f, h, g, grad f, jac h, jac g, jac r) at x by central differences."""
        if self.colouring is None:
            x = np.asarray(x, dtype=float)
            has_residuals = self.problem.residuals is not None
            if self.sparse:
                pattern = sparsity_pattern(self._outputs, x, params, has_residuals)
                colour = column_colours(pattern)
                count = -(-(colour.max(initial=-1) + 1) // COLOUR_PADDING) * COLOUR_PADDING
            else:  # every column alone
                rows = _pattern_rows(self._outputs(jnp.asarray(x), params), has_residuals).size
                pattern, colour, count = np.ones((rows, x.size), bool), np.arange(x.size), x.size
            directions = (np.arange(count)[:, None] == colour[None]).astype(float)
            self.colouring = (jnp.asarray(directions), jnp.asarray(colour), jnp.asarray(pattern))
        return self._coloured(x, params, *self.colouring)

    def always_seen(self, x, params) -> np.ndarray | None:
        """Inequality rows a working set (:attr:`SQPOptions.working_margin`) holds whatever their
        value at x, bool (m_g,); None: none beyond the margin's."""
        return None

    def lifted(self, x, f, h, g, tolerance: float):
        """A feasible point next to an infeasible iterate x, as (x', f'); None: none known (see
        :meth:`LimitMinimisation.lifted`)."""
        return None


class LimitMinimisation:
    """SLSQP's value and derivatives of "minimise the limit itself": on (x, t), minimise t subject to
    a compiled problem's constraints with its limit parameter scaled by t, built on that problem's
    compiled functions (no program of its own: the same shapes, the same compiled rollouts).

    ``at_limit(params, t)`` returns the problem's parameters with the limit scaled by the Python float
    t; the limit must enter the constraints linearly (the gait's scaled power constraint
    (|qdot u| - t M_W0) / P_s does), so that the column of t is exactly g(x, t + 1) - g(x, t): one
    rollout beside the 2C + 1 of the problem's Jacobian."""

    def __init__(self, compiled: CompiledSQP, at_limit: Callable):
        self.compiled, self.at_limit = compiled, at_limit
        self._column = None  # d g / d t of the last Jacobian (constant for a limit entering linearly)

    def _split(self, x_limit, params):
        x_limit = np.asarray(x_limit, dtype=float)
        t = float(x_limit[-1])
        return jnp.asarray(x_limit[:-1]), t, self.at_limit(params, t)

    def value(self, x_limit, params):
        """(t, h, g) at (x, t)."""
        x, t, scaled = self._split(x_limit, params)
        _, h, g = self.compiled.value(x, scaled)
        return t, h, g

    @property
    def rollouts(self) -> int | None:
        """Rollouts per Jacobian: the problem's and one for the limit's column."""
        inner = self.compiled.rollouts
        return None if inner is None else inner + 1

    def derivatives(self, x_limit, params):
        """(f, h, g, grad f, jac h, jac g, jac r) at (x, t); no residuals (jac r is (0, n + 1))."""
        x, t, scaled = self._split(x_limit, params)
        _, h, g, _, jac_h, jac_g, _ = map(np.asarray, self.compiled.derivatives(x, scaled))
        column = np.asarray(self.compiled.value(x, self.at_limit(params, t + 1.0))[2]) - g
        self._column = column
        n = x.size + 1
        return (t, h, g, np.append(np.zeros(x.size), 1.0),
                np.concatenate([jac_h, np.zeros((h.size, 1))], axis=1),
                np.concatenate([jac_g, column[:, None]], axis=1), np.zeros((0, n)))

    def always_seen(self, x_limit, params) -> np.ndarray:
        """The rows on the limit, bool (m_g,): however far from active at the start, lowering the
        limit brings them there (g(x, t + 1) - g(x, t) != 0)."""
        x, t, scaled = self._split(x_limit, params)
        g = np.asarray(self.compiled.value(x, scaled)[2])
        return np.asarray(self.compiled.value(x, self.at_limit(params, t + 1.0))[2]) != g

    def lifted(self, x_limit, f, h, g, tolerance: float):
        """(x, t', f') with t raised just enough that the constraints on the limit hold (to rounding)
        at an iterate that keeps every other constraint within ``tolerance``; None otherwise (or
        before the first Jacobian). The gait at an infeasible SLSQP iterate is still one that walks
        at a somewhat higher limit: where SLSQP stalls, the best of these is the answer so far."""
        column = self._column
        if column is None or np.max(np.abs(h), initial=0.0) > tolerance:
            return None
        on_limit = column < -1e-9 * np.max(np.abs(column))
        if np.max(g[~on_limit], initial=0.0) > tolerance:
            return None
        raise_by = max(0.0, float(np.max(g[on_limit] / -column[on_limit], initial=0.0)))
        lifted = np.array(x_limit, dtype=float)
        lifted[-1] += raise_by
        return lifted, f + raise_by


def compile_problem(problem: al.ConstrainedProblem, step: float = SQPOptions.step,
                    sparse: bool = True) -> CompiledSQP:
    """Value and central-difference derivatives of ``problem``, compiled on first call (see
    :class:`CompiledSQP`)."""
    return CompiledSQP(problem, step, sparse)


def _outputs(problem: al.ConstrainedProblem, x, params):
    """(f, h, g, r) at one point; r empty for a problem without residuals."""
    if problem.residuals is None:
        f, h, g = problem.evaluate(x, params)
        return f, h, g, jnp.zeros(0, x.dtype)
    r, h, g = problem.residuals(x, params)
    return r @ r, h, g, r


def _steps(step, x):
    return step * jnp.maximum(1.0, jnp.abs(x))


def _coloured_derivatives(problem, step, x, params, directions, colour, pattern):
    """One vmapped rollout of the 2C + 1 points x, x +- (step_i over the columns i of colour c);
    row k of column i is read from colour(i)'s difference where the pattern says k depends on i.
    ``pattern`` rows: r, then h, then g, then f (f's row only for a problem without residuals)."""
    steps = _steps(step, x)
    points = jnp.concatenate([x[None], x[None] + directions * steps, x[None] - directions * steps])
    f, h, g, r = jax.vmap(functools.partial(_outputs, problem), in_axes=(0, None))(points, params)
    count = directions.shape[0]
    with_objective = problem.residuals is None
    rows = jnp.concatenate([r, h, g] + ([f[:, None]] if with_objective else []), axis=1)  # (2C + 1, m)
    differences = (rows[1:count + 1] - rows[count + 1:])                                   # (C, m)
    jacobian = jnp.where(pattern, differences[colour].T / (2 * steps), 0.0)               # (m, n)
    jac_r, jac_h, jac_g = jnp.split(jacobian[:r.shape[1] + h.shape[1] + g.shape[1]],
                                    [r.shape[1], r.shape[1] + h.shape[1]])
    grad = jacobian[-1] if with_objective else 2 * jac_r.T @ r[0]
    return f[0], h[0], g[0], grad, jac_h, jac_g, jac_r


def sparsity_pattern(outputs: Callable, x: np.ndarray, params, has_residuals: bool,
                     probe: float = 1e-3) -> np.ndarray:
    """Which outputs each column of x reaches, shape (m, n) bool, rows as in the coloured derivatives
    (r, h, g, then f when there are no residuals): column i perturbed alone by ``probe`` max(1, |x_i|)
    at x and at a second point (x moved by a random 10 ``probe`` in every column, so that a dependence
    whose slope vanishes at x still shows), in the compiled single-point program; an output that
    changes at all, bit for bit, depends on the column."""
    def rows(point):
        return _pattern_rows(outputs(jnp.asarray(point), params), has_residuals)
    scale = probe * np.maximum(1.0, np.abs(x))
    second = x + 10 * scale * np.random.default_rng(0).uniform(-1, 1, x.size)
    pattern = None
    for base in (x, second):
        centre = rows(base)
        columns = [rows(base + scale * (np.arange(x.size) == i)) != centre for i in range(x.size)]
        found = np.stack(columns, axis=1)
        pattern = found if pattern is None else pattern | found
    return pattern


def _pattern_rows(outputs, has_residuals: bool) -> np.ndarray:
    """The outputs (f, h, g, r) as one vector in the pattern's row order."""
    f, h, g, r = map(np.asarray, outputs)
    return np.concatenate([r, h, g] + ([np.atleast_1d(f)] if not has_residuals else []))


def column_colours(pattern: np.ndarray) -> np.ndarray:
    """Greedy colouring of the columns, densest first: columns of one colour reach no row in common.
    Returns each column's colour, shape (n,) int."""
    colour = np.full(pattern.shape[1], -1)
    reached: list[np.ndarray] = []  # per colour, the rows its columns reach
    for column in np.argsort(-pattern.sum(axis=0), kind="stable"):
        rows = pattern[:, column]
        free = next((c for c, used in enumerate(reached) if not (used & rows).any()), len(reached))
        if free == len(reached):
            reached.append(np.zeros_like(rows))
        reached[free] |= rows
        colour[column] = free
    return colour


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


def _solve_one(compiled: CompiledSQP, x0: np.ndarray, params, options: SQPOptions,
               progress: Callable[[int, float, float], None] | None, scale: np.ndarray | None = None):
    """SLSQP on one problem; returns (x, f, h, g, status, stationarity, iterations, evaluations,
    lam_eq, lam_in, trace) with our sign conventions (f + lam_eq.h + lam_in.g, lam_in >= 0); trace
    holds (f, scaled violation, evaluations so far) at the start and after every iteration."""
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
        constraints = []
        if h0.size:
            constraints.append({"type": "eq", "fun": lambda z: value(to_x(z))[1],
                                "jac": lambda z: chain(derivatives(to_x(z))[4])})
        if rows.size:
            constraints.append({"type": "ineq", "fun": lambda z, rows=rows: -value(to_x(z))[2][rows],
                                "jac": lambda z, rows=rows: -chain(derivatives(to_x(z))[5][rows])})
        result = minimize(lambda z: value(to_x(z))[0], z, jac=lambda z: chain(derivatives(to_x(z))[3]),
                          constraints=constraints, method="SLSQP", callback=callback,
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
    multipliers = np.asarray(getattr(result, "multipliers", np.zeros(h.size + rows.size)))
    lam_eq, lam_in = -multipliers[:h.size], np.zeros(g.size)
    lam_in[rows] = np.maximum(multipliers[h.size:], 0.0)  # zero on the rows SLSQP did not see
    stationarity = float(np.max(np.abs(grad + jac_h.T @ lam_eq + jac_g.T @ lam_in), initial=0.0)
                         / max(1.0, abs(float(f))))
    violation = _scaled_violation(h, g)
    finite = bool(np.all(np.isfinite(x)) and np.isfinite(f))
    if not finite:
        status = al.DIVERGED
    elif not fallback and violation <= options.tolerance and (
            result.status == 0 or stationarity <= options.stationarity or acceptable[0]):
        status = al.CONVERGED
    elif result.status == 9:  # iteration limit
        status = al.ITERATION_LIMIT
    elif violation <= options.tolerance:
        status = al.ITERATION_LIMIT  # feasible but not stationary: stopped short of an optimum
    else:
        status = al.INFEASIBLE if violation > options.infeasible_above else al.STALLED
    return x, f, h, g, status, stationarity, iterations[0], counts["evaluations"], lam_eq, lam_in, trace


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


def solve(problem: al.ConstrainedProblem, x0, params, options: SQPOptions = SQPOptions(),
          compiled: CompiledSQP | None = None,
          progress: Callable[[int, int, float, float], None] | None = None,
          scales: np.ndarray | None = None) -> al.SolveResult:
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

    Returns an :class:`~biped_jax.optim.augmented_lagrangian.SolveResult` (``outer_iterations`` counts SLSQP
    iterations, ``gradients`` counts function evaluations, ``history`` one row per SLSQP iteration).
    """
    started = time.perf_counter()
    compiled = compiled or compile_problem(problem, options.step, options.sparse)
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
    return al.SolveResult(x=np.stack(x), cost=cost, equalities=np.stack(h), inequalities=np.stack(g),
                          violation=violation, stationarity=np.array(stationarity), status=list(status),
                          outer_iterations=np.array(iterations), gradients=np.array(evaluations),
                          wall_time_s=time.perf_counter() - started, history=history,
                          multipliers_eq=np.stack(lam_eq), multipliers_in=np.stack(lam_in))
