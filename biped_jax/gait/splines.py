"""The joint references: clamped B-splines in normalised time on graded knots, the decision vector's
layout (stance nodes, control points), the grid and Simpson's weights."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from scipy.interpolate import BSpline

from biped_jax.gait.settings import GaitSettings
from biped_jax.robots.planar_biped import SWAP

# ----------------------------------------------------------------------------- the joint references

def breakpoints(settings: GaitSettings) -> np.ndarray:
    """Knot-span boundaries in normalised time, shape (spans + 1,), from 0 to 1."""
    uniform = np.linspace(0.0, 1.0, settings.spans + 1)
    return (1 - settings.grading) * uniform + settings.grading * 0.5 * (1 - np.cos(np.pi * uniform))


def knot_vector(settings: GaitSettings) -> np.ndarray:
    """The clamped knot vector, shape (spans + 2 degree + 1,)."""
    inner = breakpoints(settings)
    k = settings.degree
    return np.concatenate([np.zeros(k), inner, np.ones(k)])


def grid(settings: GaitSettings) -> np.ndarray:
    """The integration grid in normalised time, shape (steps + 1,): ``substeps`` equal steps per span."""
    edges = breakpoints(settings)
    fractions = np.arange(settings.substeps) / settings.substeps
    inner = (edges[:-1, None] + np.diff(edges)[:, None] * fractions[None]).ravel()
    return np.concatenate([inner, [1.0]])


def simpson_weights(settings: GaitSettings) -> np.ndarray:
    """Composite Simpson weights on :func:`grid` for an integral over s in [0, 1], shape (steps + 1,)."""
    weights = np.zeros(settings.steps + 1)
    pattern = np.ones(settings.substeps + 1)
    pattern[1:-1:2], pattern[2:-1:2] = 4.0, 2.0
    for j, width in enumerate(np.diff(breakpoints(settings))):
        h = width / settings.substeps
        weights[j * settings.substeps:(j + 1) * settings.substeps + 1] += h / 3 * pattern
    return weights


@functools.lru_cache(maxsize=64)
def _basis_cached(knots: tuple, degree: int, points: tuple) -> tuple:
    # extrapolate=True evaluates s = 1 on the last span (the limit from the left) instead of NaN
    spline = BSpline(np.array(knots), np.eye(len(knots) - degree - 1), degree)
    s = np.clip(np.array(points), 0.0, 1.0)
    return (spline(s), spline.derivative(1)(s), spline.derivative(2)(s))


def basis(settings: GaitSettings, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """B-spline basis and its first two derivatives in s at points ``s`` (m,), each (m, control_points)."""
    return _basis_cached(tuple(knot_vector(settings)), settings.degree, tuple(np.asarray(s, dtype=float)))


def control_points(x: jax.Array, settings: GaitSettings) -> jax.Array:
    """All control points, shape (control_points, 4), rad: point 0 mirrors the last one."""
    free = x[2:2 + 4 * (settings.control_points - 1)].reshape(settings.control_points - 1, 4)
    return jnp.concatenate([free[-1, SWAP][None], free])


def stance_nodes(x: jax.Array, settings: GaitSettings) -> jax.Array:
    """The shooting nodes: stance angle (rad) and rate (rad/s) at the start of every segment,
    shape (segments, 2); row 0 is the step's start state."""
    later = x[2 + 4 * (settings.control_points - 1):].reshape(settings.segments - 1, 2)
    return jnp.concatenate([x[None, :2], later])


def segment_starts(settings: GaitSettings) -> np.ndarray:
    """Normalised times of the shooting nodes, shape (segments,): every (spans / segments)-th
    breakpoint, from 0."""
    return breakpoints(settings)[:-1:settings.spans // settings.segments]


def pack(stance: jax.Array, points: jax.Array) -> jax.Array:
    """The decision vector from the shooting nodes (segments, 2) and the free control points
    (control_points - 1, 4): the inverse of :func:`stance_nodes` and :func:`control_points`."""
    stance, points = jnp.asarray(stance), jnp.asarray(points)
    return jnp.concatenate([stance[0], points.ravel(), stance[1:].ravel()])


def reference(x: jax.Array, settings: GaitSettings, s) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The actuated joints' reference and its first two derivatives in normalised time at ``s`` (m,):
    q_a, dq_a/ds, d2q_a/ds2, each (m, 4) (divide by t_f and t_f^2 for time derivatives)."""
    points = control_points(x, settings)
    return tuple(jnp.asarray(b) @ points for b in basis(settings, s))


def greville(settings: GaitSettings) -> np.ndarray:
    """Greville abscissae, shape (control_points,): where each control point acts most, so that
    control points set to f(abscissae) give a spline close to f."""
    knots, k = knot_vector(settings), settings.degree
    return np.array([knots[i + 1:i + k + 1].mean() for i in range(settings.control_points)])
