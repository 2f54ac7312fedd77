"""Exact derivatives of a problem whose rows are local: each belongs to one of S segments and reads a few
columns of x, and a few boundary rows read a few more. What a multiply-shot trajectory is: a shooting
segment's samples depend on its node and on the control points that reach it.

The Lagrangian is then a sum L = sum_k L_k(x[c_k]) + L_b(x[c_b], e(x[c_S])), so its Hessian is the sum of
small dense blocks, one per segment, each the Hessian of L_k in its own l columns: forward-over-reverse
automatic differentiation with l unit directions per segment, all segments at once (``vmap``), costs l
directions over the rollout's work where a column colouring of the whole problem needs one direction
per colour (about 2.5 times l for a B-spline trajectory: two columns may share a colour only when no
row of the Hessian meets both). The blocks are added into the (n, n) Hessian; the Jacobians' rows are
placed the same way.

The boundary rows may read values e that the last segment computes (a shooting segment's end state: the
step's touchdown and periodicity read it) instead of computing them again: the boundary is differentiated
in (its columns, e), and the chain rule through e(x[c_S]) takes e's Jacobian from the last segment's pass
and its curvature from the last segment's Lagrangian, to which dL_b/de . e is added. The boundary's
derivative pass then holds no copy of the segment's work (a shooting segment's rollout: half of the
derivatives' tracing and, at 4 segments, a third of their arithmetic).

:class:`LocalProblem` describes the split; :func:`derivatives` returns what
:func:`biped_jax.optim.exact_derivatives.derivatives` returns for the problem it splits, rows in that
problem's order.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax.optim import jacobian as jacobian_ops


@dataclasses.dataclass(frozen=True, eq=False)
class LocalProblem:
    """A problem's rows split into segments and a boundary.

    Attributes:
      segment: ``(x_local (l,), data_k, params) -> (r_k (a,), h_k (b,), g_k (c,), e_k (k,))``, one
        segment's rows (the same sizes for every segment; rows a segment does not own are computed and
        left out) and the values ``e_k`` the boundary reads of the last segment (not of its linear columns).
      boundary: ``(x_boundary (p,), e_last (k,), params) -> (r_b, h_b, g_b)``, the rows that are no
        segment's; the last segment's columns must be among ``boundary_columns`` (or ``n``, the padding).
      segment_columns: each segment's columns of x, (S, l) int; ``n`` (one past the last column) pads a
        segment with fewer columns (a column that is always zero).
      boundary_columns: the boundary's columns, (p,) int.
      segment_data: per-segment constants, a pytree of numpy arrays with leading dimension S.
      order_r, order_h, order_g: for each row of the problem (its r, h and g in its own order), where it
        is in the split's rows: the S segments' rows flattened (segment-major), then the boundary's.
      linear_objective: None: f = r . r; a column index i: f = x[i] + energy_weight(params) r . r.
      energy_weight: ``params -> weight`` of r . r beside a linear objective (None: 0, the rows r unused).
      linear_segment_columns: positions in a segment's columns (of ``segment_columns``' second axis) that
        enter only its equality rows h, each with a constant coefficient (the next shooting node, which
        enters only the defect end - node): their Hessian rows are zero and their Jacobian columns are
        ``linear_segment_h``, so they take no direction of the derivative passes.
      linear_segment_h: per linear column its d h_k / d column, (len(linear_segment_columns), b) as
        nested tuples (the same for every segment; r_k and g_k do not depend on it).
    """

    segment: Callable[[jax.Array, Any, Any], tuple]
    boundary: Callable[[jax.Array, Any], tuple]
    segment_columns: np.ndarray
    boundary_columns: np.ndarray
    segment_data: Any
    order_r: np.ndarray
    order_h: np.ndarray
    order_g: np.ndarray
    linear_objective: int | None = None
    energy_weight: Callable[[Any], Any] | None = None
    linear_segment_columns: tuple = ()
    linear_segment_h: tuple = ()

    def __post_init__(self):
        if np.shape(self.linear_segment_h)[:1] != (len(self.linear_segment_columns),):
            raise ValueError(f"linear_segment_h needs a row of d h / d column per linear column "
                             f"({len(self.linear_segment_columns)}), got shape {np.shape(self.linear_segment_h)}")

    def last_in_boundary(self, n: int) -> np.ndarray:
        """For each column of the last segment, a position of it in ``boundary_columns`` (p, one past
        them, for the padding column ``n``; of a column held twice, one: the boundary's derivatives in the
        two are added into the column's)."""
        where = {int(c): i for i, c in enumerate(np.asarray(self.boundary_columns))}
        p = len(self.boundary_columns)
        last = np.asarray(self.segment_columns)[-1]
        outside = sorted({int(c) for c in last} - set(where) - {n})
        if outside:
            raise ValueError(f"the boundary reads the last segment's values: its columns {outside} must be "
                             "among boundary_columns")
        return np.asarray([where.get(int(c), p) for c in last], np.int32)

    @property
    def curved_segment_columns(self) -> np.ndarray:
        """Positions in a segment's columns that take a direction of the second-order pass."""
        return np.setdiff1d(np.arange(self.segment_columns.shape[1]), np.asarray(self.linear_segment_columns, int))

    @property
    def directions(self) -> int:
        """Second-order directions per derivative pass: each segment's curved columns (the boundary's run
        alongside)."""
        return int(self.curved_segment_columns.shape[0])


def _lifted(order: np.ndarray, values, size: int):
    """``values`` (the problem's rows) placed at their split positions in a vector of ``size`` (zeros
    at the rows no one owns)."""
    return jnp.zeros(size, values.dtype).at[order].set(values)


def _second_order(function, point, directions):
    """((aux, grad L), their tangents along each of ``directions`` (d, len(point))) of
    ``function(point) -> (L, aux)``: forward over reverse."""
    def gradient(p):
        grad, aux = jax.grad(function, has_aux=True)(p)
        return aux, grad

    def along(direction):
        return jax.jvp(gradient, (point,), (direction,))
    primal, tangent = jax.vmap(along)(directions)
    return jax.tree.map(lambda a: a[0], primal), tangent


def derivatives(local: LocalProblem, x, params, weight, y, z, blocks: bool = False):
    """Values and exact derivatives at x (one problem), as
    :func:`biped_jax.optim.exact_derivatives.derivatives`: (f, h, g, grad L (n,), jac h (m_h, n),
    jac g (m_g, n), hessian of L (n, n)) for L = w f + y . h + z . g with f = r . r. ``blocks``: jac g
    as a :class:`~biped_jax.optim.jacobian.SegmentJacobian` (its segments' blocks, not an (m_g, n)
    array)."""
    n = x.shape[0]
    segments, width = local.segment_columns.shape
    padded = jnp.concatenate([x, jnp.zeros(1, x.dtype)])
    columns = jnp.asarray(local.segment_columns)
    boundary = local.boundary_columns
    p = boundary.shape[0]
    # the values the boundary reads of the last segment (and every segment's row sizes), by a plain
    # evaluation of it: their derivatives come from the segments' pass below
    last = local.segment(padded[columns[-1]], jax.tree.map(lambda a: a[-1], local.segment_data), params)
    end = last[3]
    ends = jax.eval_shape(local.boundary, jnp.zeros(p, x.dtype), end, params)
    b, c = (rows.shape[0] for rows in last[1:3])
    total_h, total_g = segments * b + ends[1].shape[0], segments * c + ends[2].shape[0]
    y_split = _lifted(local.order_h, y, total_h)
    z_split = _lifted(local.order_g, z, total_g)

    beside = 0.0 if local.energy_weight is None else local.energy_weight(params)  # r . r's weight beside x[i]
    residual_weight = weight if local.linear_objective is None else weight * beside

    def lagrangian(function, y_part, z_part, end_part=None):
        def value(point):
            rows = function(point)
            r, h, g = rows[:3]
            extra = 0.0 if end_part is None else end_part @ rows[3]
            return residual_weight * (r @ r) + y_part @ h + z_part @ g + extra, rows
        return value

    # the boundary in (its columns, e): its rows, their derivatives in both and dL_b / de
    (rows_e, grad_e), ((_, jh_e, jg_e), hess_e) = _second_order(
        lagrangian(lambda q: local.boundary(q[:p], q[p:], params), y_split[segments * b:], z_split[segments * c:]),
        jnp.concatenate([padded[boundary], end]), jnp.eye(p + end.shape[0], dtype=x.dtype))
    end_weight = jnp.zeros((segments, end.shape[0]), x.dtype).at[-1].set(grad_e[p:])

    curved = local.curved_segment_columns
    linear = np.asarray(local.linear_segment_columns, int)
    in_place = np.argsort(np.concatenate([curved, linear]))  # the tangents back in the segment's column order
    unit = jnp.eye(width, dtype=x.dtype)

    def one_segment(columns, data, y_k, z_k, end_k):
        """((rows, grad L_k), ((None, jac h_k (l, b), jac g_k (l, c), jac e_k (l, k)), the curved rows of
        L_k's Hessian (c, l))), L_k with dL_b / de . e_k for the last segment (the chain rule's curvature)."""
        point = padded[columns]
        function = lambda p, d=data: local.segment(p, d, params)  # noqa: E731
        (rows, grad), ((_, jh, jg, je), hess) = _second_order(lagrangian(function, y_k, z_k, end_k), point,
                                                               unit[curved])
        if linear.size:  # their Jacobian columns are constants (their Hessian rows are zero; e reads none)
            jh_linear = jnp.asarray(local.linear_segment_h, x.dtype)
            jh = jnp.concatenate([jh, jh_linear])[in_place]
            jg = jnp.concatenate([jg, jnp.zeros((linear.size, jg.shape[1]), x.dtype)])[in_place]
            je = jnp.concatenate([je, jnp.zeros((linear.size, je.shape[1]), x.dtype)])[in_place]
        return (rows, grad), ((None, jh, jg, je), hess)

    (rows_k, grad_k), ((_, jh_k, jg_k, je_k), hess_k) = jax.vmap(one_segment)(
        columns, local.segment_data, y_split[:segments * b].reshape(segments, b),
        z_split[:segments * c].reshape(segments, c), end_weight)
    # the chain rule through e: de / d(boundary columns), (p, k), from the last segment's pass
    de = jnp.zeros((p + 1, end.shape[0]), x.dtype).at[local.last_in_boundary(n)].add(je_k[-1])[:p]
    grad_e = grad_e[:p]  # dL_b / de . de / dx is in the last segment's gradient (its L_k holds it)
    jh_e, jg_e = (j[:p] + de @ j[p:] for j in (jh_e, jg_e))
    cross = hess_e[:p, p:] @ de.T
    hess_e = hess_e[:p, :p] + cross + cross.T + de @ hess_e[p:, p:] @ de.T

    grad = jnp.zeros(n + 1, x.dtype).at[columns].add(grad_k).at[boundary].add(grad_e)[:n]
    hessian = (jnp.zeros((n + 1, n + 1), x.dtype).at[columns[:, curved, None], columns[:, None, :]].add(hess_k)
               .at[boundary[:, None], boundary[None, :]].add(hess_e))[:n, :n]
    hessian = 0.5 * (hessian + hessian.T)

    def jacobian(per_segment, at_boundary, order):
        # per_segment (S, l, rows): d row / d local column; at_boundary (p, rows_b)
        return jacobian_ops.SegmentJacobian(
            segments=jnp.swapaxes(per_segment, 1, 2), boundary=at_boundary.T, columns=columns,
            boundary_columns=jnp.asarray(boundary), order=jnp.asarray(order), size=n)

    h = jnp.concatenate([rows_k[1].ravel(), rows_e[1]])[local.order_h]
    g = jnp.concatenate([rows_k[2].ravel(), rows_e[2]])[local.order_g]
    r = jnp.concatenate([rows_k[0].ravel(), rows_e[0]])[local.order_r]
    if local.linear_objective is None:
        f = r @ r
    else:
        f = x[local.linear_objective] + beside * (r @ r)
        grad = grad.at[local.linear_objective].add(weight)
    jac_g = jacobian(jg_k, jg_e, local.order_g)
    return (f, h, g, grad, jacobian_ops.dense(jacobian(jh_k, jh_e, local.order_h)),
            jac_g if blocks else jacobian_ops.dense(jac_g), hessian)
