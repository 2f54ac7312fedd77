"""Which outputs of a :class:`~biped_jax.optim.nlp.ConstrainedProblem` each decision variable reaches, and
a colouring of the variables by it (Curtis, Powell and Reid, "On the estimation of sparse Jacobian
matrices", IMA J. Appl. Math. 13, 1974): columns of one colour reach no output in common, so one
directional derivative serves them all (:mod:`biped_jax.optim.exact_derivatives`).
"""

from __future__ import annotations

from typing import Callable

import jax.numpy as jnp
import numpy as np

from biped_jax.optim import nlp

#: Colour counts are padded to a multiple of this, so that problems of one shape whose sparsity
#: patterns differ slightly still share one compiled derivative program.
COLOUR_PADDING = 8


def problem_outputs(problem: nlp.ConstrainedProblem, x, params):
    """(f, h, g, r) at one point; r empty for a problem without residuals."""
    if problem.residuals is None:
        f, h, g = problem.evaluate(x, params)
        return f, h, g, jnp.zeros(0, x.dtype)
    r, h, g = problem.residuals(x, params)
    return r @ r, h, g, r


def sparsity_pattern(outputs: Callable, x: np.ndarray, params, has_residuals: bool,
                     probe: float = 1e-3) -> np.ndarray:
    """Which outputs each column of x reaches, shape (m, n) bool, rows r, h, g, then f when there are no
    residuals: column i perturbed alone by ``probe`` max(1, |x_i|)
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
