"""A constraint Jacobian kept in its segments' blocks, and the products the interior point takes of it.

A multiply-shot trajectory's inequality rows are local (:mod:`biped_jax.optim.local_derivatives`): each
shooting segment's rows read only that segment's l columns, a few boundary rows a few more. Held dense,
the gait's inequality Jacobian is (6 758 x 296) per problem in the study's grid, and the Newton system's
J^T diag(w) J alone costs m n^2 (about 0.6 GFLOP a problem and iteration); in blocks it is S (c x l)
blocks and costs S c l^2 (measured by ``benchmarks/ip_phases.py``). Every function here takes either
a :class:`SegmentJacobian` or a dense (m, n) array, so that the interior point runs one code for both
(the colouring path and small problems keep dense Jacobians).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SegmentJacobian:
    """The Jacobian of m rows with respect to n columns, by blocks.

    Attributes:
      segments: d row / d local column of each segment's rows, (S, c, l).
      boundary: the same for the boundary's rows, (c_b, p).
      columns: each segment's columns of x, (S, l) int (the index n pads: a column that is dropped).
      boundary_columns: the boundary's columns, (p,) int.
      order: for each of the m rows, its place among the split rows (the S segments' c rows each,
        segment-major, then the boundary's); split rows no row names are left out.
      size: n, the number of columns.
    """

    segments: jax.Array
    boundary: jax.Array
    columns: jax.Array
    boundary_columns: jax.Array
    order: jax.Array
    size: int = dataclasses.field(metadata=dict(static=True))

    @property
    def shape(self) -> tuple[int, int]:
        return (self.order.shape[-1], self.size)


def _split(jac: SegmentJacobian, values):
    """``values`` (m,) of the rows, placed at their split rows: ((S, c), (c_b,)), zero where no row is."""
    segments, rows, _ = jac.segments.shape
    split = jnp.zeros(segments * rows + jac.boundary.shape[0], values.dtype).at[jac.order].set(values)
    return split[:segments * rows].reshape(segments, rows), split[segments * rows:]


def _padded(v):
    return jnp.concatenate([v, jnp.zeros(1, v.dtype)])


def matvec(jac, v):
    """J v, (m,), for v (n,)."""
    if not isinstance(jac, SegmentJacobian):
        return jac @ v
    padded = _padded(v)
    segment_rows = jnp.einsum("scl,sl->sc", jac.segments, padded[jac.columns])
    return jnp.concatenate([segment_rows.ravel(), jac.boundary @ padded[jac.boundary_columns]])[jac.order]


def rmatvec(jac, w):
    """J^T w, (n,), for w (m,)."""
    if not isinstance(jac, SegmentJacobian):
        return jac.T @ w
    w_segments, w_boundary = _split(jac, w)
    out = jnp.zeros(jac.size + 1, w.dtype).at[jac.columns].add(jnp.einsum("scl,sc->sl", jac.segments, w_segments))
    return out.at[jac.boundary_columns].add(jac.boundary.T @ w_boundary)[:jac.size]


def gram(jac, w):
    """J^T diag(w) J, (n, n), for w (m,): a sum of one (l x l) block per segment."""
    if not isinstance(jac, SegmentJacobian):
        return jac.T @ (w[:, None] * jac)
    w_segments, w_boundary = _split(jac, w)
    blocks = jnp.einsum("sci,sc,scj->sij", jac.segments, w_segments, jac.segments)
    ends = jac.boundary.T @ (w_boundary[:, None] * jac.boundary)
    columns, boundary = jac.columns, jac.boundary_columns
    out = jnp.zeros((jac.size + 1, jac.size + 1), w.dtype)
    out = out.at[columns[:, :, None], columns[:, None, :]].add(blocks)
    out = out.at[boundary[:, None], boundary[None, :]].add(ends)
    return out[:jac.size, :jac.size]


def row_scaled(jac, scale):
    """diag(scale) J for scale (m,)."""
    if not isinstance(jac, SegmentJacobian):
        return scale[:, None] * jac
    s_segments, s_boundary = _split(jac, scale)
    return dataclasses.replace(jac, segments=jac.segments * s_segments[:, :, None],
                               boundary=jac.boundary * s_boundary[:, None])


def row_max_abs(jac):
    """The largest |derivative| of each row, (m,)."""
    if not isinstance(jac, SegmentJacobian):
        return jnp.max(jnp.abs(jac), axis=-1, initial=0.0)
    segment_rows = jnp.max(jnp.abs(jac.segments), axis=-1, initial=0.0)
    boundary_rows = jnp.max(jnp.abs(jac.boundary), axis=-1, initial=0.0)
    return jnp.concatenate([segment_rows.ravel(), boundary_rows])[jac.order]


def dense(jac):
    """J as a dense (m, n) array."""
    if not isinstance(jac, SegmentJacobian):
        return jac
    segments, rows, _ = jac.segments.shape
    m = jac.order.shape[-1]
    # each split row goes to its row of J; split rows no row names go past the end and are dropped
    target = jnp.full(segments * rows + jac.boundary.shape[0], m, jnp.int32).at[jac.order].set(
        jnp.arange(m, dtype=jnp.int32))
    into = jnp.zeros((m, jac.size + 1), jac.segments.dtype)
    into = into.at[target[:segments * rows].reshape(segments, rows)[:, :, None], jac.columns[:, None, :]].add(
        jac.segments, mode="drop")
    into = into.at[target[segments * rows:][:, None], jac.boundary_columns[None, :]].add(jac.boundary, mode="drop")
    return into[:, :jac.size]
