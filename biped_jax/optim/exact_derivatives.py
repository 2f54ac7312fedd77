"""Exact first and second derivatives of a :class:`~biped_jax.optim.nlp.ConstrainedProblem` by automatic
differentiation, the columns coloured by the problem's sparsity: what :mod:`biped_jax.optim.interior_point`
calls at every iteration.

One forward-over-reverse pass gives both: the reverse pass is the gradient of the Lagrangian
L = w f + y . h + z . g, and pushing C direction vectors through it (``jax.jvp``, vmapped) gives the
products of the constraints' Jacobian and of L's Hessian with each direction. With every column its own
direction (C = n) that is the dense Jacobian and Hessian; with the columns coloured so that two columns
of one colour never meet in a row of the Hessian's pattern, C is the colour count and every entry is read
back from the one product that holds it alone (Curtis, Powell and Reid 1974 for Jacobians; Coleman and
More, "Estimation of sparse Hessian matrices and graph coloring problems", Math. Prog. 28, 1984, for the
direct recovery of Hessians). A Hessian colouring is also a Jacobian colouring (two columns that share
a row are neighbours in the Hessian's pattern), so one set of directions serves both.

The gait's outputs are local in time (a B-spline control point moves four knot spans, a shooting node one
segment): in the study's 48 knot spans its 296 columns need about 50 colours.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax.optim import local_derivatives, nlp, sparsity


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Structure:
    """The colouring of one problem shape (arrays, so that problems of one shape share a program).

    Attributes:
      directions: one 0/1 row per colour, shape (C, n).
      colour: each column's colour, shape (n,) int.
      jacobian_pattern: which constraint rows (h, then g) each column reaches, shape (m_h + m_g, n) bool.
      hessian_pattern: which entries of the Lagrangian's Hessian may be nonzero, shape (n, n) bool.
    """

    directions: jax.Array
    colour: jax.Array
    jacobian_pattern: jax.Array
    hessian_pattern: jax.Array

    @property
    def colours(self) -> int:
        return self.directions.shape[0]


def dense_structure(size: int, constraints: int) -> Structure:
    """Every column its own colour and every entry possibly nonzero: the dense Jacobian and Hessian
    (for small problems and for checking a colouring)."""
    return Structure(directions=jnp.eye(size), colour=jnp.arange(size),
                     jacobian_pattern=jnp.ones((constraints, size), bool),
                     hessian_pattern=jnp.ones((size, size), bool))


def unused_structure(size: int) -> Structure:
    """No colouring (zero directions) for a problem of ``size`` columns whose ``local`` split computes
    its derivatives (:func:`derivatives` then never reads the structure)."""
    return Structure(directions=jnp.zeros((0, size)), colour=jnp.zeros(size, jnp.int32),
                     jacobian_pattern=jnp.zeros((0, size), bool), hessian_pattern=jnp.zeros((0, size), bool))


def probe_structure(problem: nlp.ConstrainedProblem, x, params, padding: int = sparsity.COLOUR_PADDING,
                    linear_columns=()) -> Structure:
    """The colouring of ``problem`` at one point ``x`` (n,) with one problem's ``params``: which rows
    each column reaches, probed by perturbing each column alone (at x and at a second, random point;
    :func:`biped_jax.optim.sparsity.sparsity_pattern`), the Hessian's pattern from it (rows of the
    residuals r, h and g: the Hessian of r . r, h_k and g_k only couples columns that meet in a row),
    its columns coloured greedily, the colour count padded to a multiple of ``padding`` so that
    problems whose patterns differ slightly still share one compiled program. ``linear_columns``: the
    columns every output depends on linearly (such as a bound that enters the constraints as a
    factor), whose Hessian rows and columns are zero; a column that reaches every row would otherwise
    make the Hessian's pattern dense."""
    has_residuals = problem.residuals is not None
    outputs = jax.jit(functools.partial(sparsity.problem_outputs, problem))
    pattern = sparsity.sparsity_pattern(outputs, np.asarray(x, dtype=float), params, has_residuals)
    rows = outputs(jnp.asarray(x), params)
    r_size, h_size, g_size = np.size(rows[3]), np.size(rows[1]), np.size(rows[2])
    # pattern rows: r, h, g (then f for a problem without residuals)
    coupled = pattern.astype(np.int32)
    hessian = (coupled.T @ coupled) > 0
    linear = np.zeros(hessian.shape[0], bool)
    linear[list(linear_columns)] = True
    hessian &= ~linear[:, None] & ~linear[None, :]
    # columns of one colour meet in no row of the Hessian's pattern (its recovery) nor of the
    # Jacobian's (which the Hessian's implies except for the linear columns)
    colour = sparsity.column_colours(np.concatenate([hessian, pattern]))
    count = min(-(-(colour.max(initial=-1) + 1) // padding) * padding, pattern.shape[1])
    directions = (np.arange(count)[:, None] == colour[None]).astype(float)
    return Structure(directions=jnp.asarray(directions), colour=jnp.asarray(colour),
                     jacobian_pattern=jnp.asarray(pattern[r_size:r_size + h_size + g_size]),
                     hessian_pattern=jnp.asarray(hessian))


def derivatives(problem: nlp.ConstrainedProblem, x, params, weight, y, z, structure: Structure,
                blocks: bool = False):
    """Values and exact derivatives at x (one problem; vmap for a batch).

    Args:
      problem: the problem. x: (n,). params: one problem's data.
      weight: the objective's weight w in L = w f + y . h + z . g (scalar).
      y, z: multipliers of h (m_h,) and g (m_g,).
      structure: the colouring (:func:`probe_structure` or :func:`dense_structure`).

    Returns (f, h, g, grad L (n,), jac h (m_h, n), jac g (m_g, n), hessian of L (n, n)). A problem with
    a ``local`` split takes it instead of the colouring
    (:func:`biped_jax.optim.local_derivatives.derivatives`); with ``blocks`` its jac g comes as a
    :class:`~biped_jax.optim.jacobian.SegmentJacobian` (the colouring's is always dense).
    """
    if problem.local is not None:
        return local_derivatives.derivatives(problem.local, x, params, weight, y, z, blocks)
    def gradient(point):
        def lagrangian(point):
            f, h, g = problem.evaluate(point, params)
            return weight * f + y @ h + z @ g, (f, h, g)
        grad, (f, h, g) = jax.grad(lagrangian, has_aux=True)(point)
        return (h, g, grad), f

    def along(direction):
        primal, tangent, f = jax.jvp(gradient, (x,), (direction,), has_aux=True)
        return primal, tangent, f

    primal, tangent, f = jax.vmap(along)(structure.directions)
    h, g, grad = (a[0] for a in primal)
    f = f[0]
    jac_h_t, jac_g_t, hess_t = tangent                     # (C, m_h), (C, m_g), (C, n)
    columns = structure.colour
    jacobian_t = jnp.concatenate([jac_h_t, jac_g_t], axis=1)[columns]    # (n, m): column i's products
    jacobian = jnp.where(structure.jacobian_pattern, jacobian_t.T, 0.0)  # (m, n)
    hessian = jnp.where(structure.hessian_pattern, hess_t[columns], 0.0)  # row j: H[:, j] (symmetric)
    hessian = 0.5 * (hessian + hessian.T)
    return f, h, g, grad, jacobian[:h.shape[0]], jacobian[h.shape[0]:], hessian


def directions(problem: nlp.ConstrainedProblem, structure: Structure) -> int:
    """Direction vectors one call of :func:`derivatives` pushes through the problem."""
    return structure.colours if problem.local is None else problem.local.directions
