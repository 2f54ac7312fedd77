"""Minimising a problem's limit itself: on (x, t), minimise t subject to the problem's constraints with
its limit scaled by t, on the problem's own compiled functions (the smallest feasible power limit of a
gait); solved by :func:`biped_jax.optim.sqp.solve` like any :class:`~biped_jax.optim.coloured.CompiledSQP`."""

from __future__ import annotations

from typing import Callable

import jax.numpy as jnp
import numpy as np

from biped_jax.optim.coloured import CompiledSQP


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
