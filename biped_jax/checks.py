"""Argument checks shared by the public API and the command line, without importing JAX (so that the
command line refuses a bad value at once, before the seconds JAX and MuJoCo take to import).

Every check raises ValueError naming the parameter, the value, the unit and the allowed range.
"""

from __future__ import annotations

import math
import numbers

#: GaitSettings' integer fields: (smallest, largest).
GAIT_INTEGER_RANGES = {"spans": (1, 200), "degree": (2, 7), "substeps": (2, 400)}


def integer_in(name: str, value, low: int, high: int) -> int:
    """``value`` if it is an integer (not a bool) in [low, high]."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not low <= value <= high:
        raise ValueError(f"{name} must be an integer in [{low}, {high}], got {value!r}")
    return int(value)


def number_in(name: str, value, low: float, high: float, unit: str, include_low: bool = False) -> float:
    """``value`` if it is a finite real number in (low, high] (or [low, high] with ``include_low``)."""
    real = not isinstance(value, bool) and isinstance(value, numbers.Real)
    inside = real and math.isfinite(value) and (low <= value if include_low else low < value) and value <= high
    if not inside:
        bracket = "[" if include_low else "("
        raise ValueError(f"{name} must be a number in {bracket}{low:g}, {high:g}] {unit}, got {value!r}")
    return float(value)


def positive(name: str, value, unit: str) -> float:
    """``value`` if it is a finite number > 0."""
    return number_in(name, value, 0.0, math.inf, unit)


def gait_space(spans: int, degree: int, substeps: int, prefix: str = "") -> None:
    """The reference space and grid of ``biped_jax.gait.GaitSettings`` (substeps even: Simpson)."""
    for name, value in (("spans", spans), ("degree", degree), ("substeps", substeps)):
        integer_in(prefix + name, value, *GAIT_INTEGER_RANGES[name])
    if substeps % 2:
        raise ValueError(f"{prefix}substeps must be even (Simpson's rule pairs the steps), got {substeps}")
