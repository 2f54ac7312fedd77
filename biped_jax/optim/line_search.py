"""The inner iteration's step of the batched augmented Lagrangian: a batch of points of the augmented
Lagrangian, L-BFGS's descent direction with a gradient fallback, and a backtracking (Armijo) line
search over one compiled value-and-gradient function, run in Python so that nothing is traced twice
(Nocedal & Wright, Numerical Optimization, 2006, Alg. 3.1)."""

from __future__ import annotations

import dataclasses
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Point:
    """The augmented Lagrangian at a batch of iterates: its value and gradient (B,), (B, n), and the
    objective and constraints it was made of, (B,), (B, m_h), (B, m_g)."""

    value: jax.Array
    f: jax.Array
    h: jax.Array
    g: jax.Array
    grad: jax.Array


def evaluate(lagrangian: Callable, x, params, lam_eq, lam_in, rho) -> Point:
    """The :class:`Point` at x from the compiled, vmapped value-and-gradient of the augmented
    Lagrangian (its auxiliary output (f, h, g))."""
    (value, (f, h, g)), grad = lagrangian(x, params, lam_eq, lam_in, rho)
    return Point(value, f, h, g, grad)


def where(mask, a, b):
    """Per problem: a where ``mask`` (B,), else b (any trailing shape)."""
    return jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, b)


def backtrack(evaluate_at: Callable, z, update, slope, point: Point, inner_active: np.ndarray,
              armijo: float, max_backtracks: int):
    """Backtracking (Armijo) along -update from z for every problem still in its inner loop.

    ``evaluate_at(z) -> Point``; ``armijo`` the sufficient-decrease constant, ``max_backtracks``
    halvings at most. Returns (z, point) with each problem's first accepted trial (or its
    old values), the accepted mask (B,) and the gradient evaluations spent per problem (B,)."""
    batch = z.shape[0]
    step = jnp.ones(batch)
    accepted = jnp.zeros(batch, dtype=bool)
    evaluations = np.zeros(batch, dtype=int)
    best_z, best = z, point
    for _ in range(max_backtracks):
        trial = z - step[:, None] * update
        t = evaluate_at(trial)
        evaluations += inner_active
        ok = jnp.isfinite(t.value) & (t.value <= point.value - armijo * step * slope) & ~accepted
        ok = ok & jnp.all(jnp.isfinite(t.grad), axis=-1)
        best_z = where(ok, trial, best_z)
        best = jax.tree.map(lambda new, old: where(ok, new, old), t, best)
        accepted = accepted | ok
        if bool(jnp.all(accepted | ~jnp.asarray(inner_active))):
            break
        step = jnp.where(accepted, step, 0.5 * step)
    return best_z, best, accepted, evaluations


def descent_direction(direction_fn: Callable, grad_z, lbfgs_state, z):
    """L-BFGS's step (to subtract) and its slope grad . step; the gradient itself where L-BFGS gives
    no descent direction or a non-finite one."""
    update, lbfgs_state = direction_fn(grad_z, lbfgs_state, z)
    slope = jnp.sum(grad_z * update, axis=-1)
    bad = ~(slope > 0) | ~jnp.all(jnp.isfinite(update), axis=-1)
    update = jnp.where(bad[:, None], grad_z, update)
    slope = jnp.where(bad, jnp.sum(grad_z * grad_z, axis=-1), slope)
    return update, slope, lbfgs_state
