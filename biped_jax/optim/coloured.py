"""Value and central-difference derivatives of a :class:`~biped_jax.optim.nlp.ConstrainedProblem` at one
point, compiled once per problem shape, the columns coloured by the problem's sparsity (Curtis, Powell
and Reid 1974): what :mod:`biped_jax.optim.sqp` calls.

Central differences, not autodiff: forward-mode autodiff through a long rollout costs minutes to
compile on a small CPU, and forward differences (about 7 correct digits) were measured too coarse for
SLSQP on the gait (README, "Solvers"); central ones are good to about 10 digits.
"""

from __future__ import annotations

import functools
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax.optim import nlp

#: Default half-width of the central differences, relative to max(1, |x_i|)
#: (:attr:`biped_jax.optim.sqp.SQPOptions.step`).
STEP = 1e-5

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

    def __init__(self, problem: nlp.ConstrainedProblem, step: float = STEP, sparse: bool = True):
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
        :meth:`~biped_jax.optim.limit_minimisation.LimitMinimisation.lifted`)."""
        return None


def compile_problem(problem: nlp.ConstrainedProblem, step: float = STEP,
                    sparse: bool = True) -> CompiledSQP:
    """Value and central-difference derivatives of ``problem``, compiled on first call (see
    :class:`CompiledSQP`)."""
    return CompiledSQP(problem, step, sparse)


def _outputs(problem: nlp.ConstrainedProblem, x, params):
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
