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


def number_in(name: str, value, low: float, high: float, unit: str) -> float:
    """``value`` if it is a finite real number in (low, high]."""
    real = not isinstance(value, bool) and isinstance(value, numbers.Real)
    if not (real and math.isfinite(value) and low < value <= high):
        raise ValueError(f"{name} must be a number in ({low:g}, {high:g}] {unit}, got {value!r}")
    return float(value)


def concrete(*trees) -> bool:
    """True when no leaf of ``trees`` is a JAX tracer: the values exist and can be checked (inside
    ``jit``, ``vmap`` or ``grad`` they do not, and the functions that accept both check only then)."""
    import jax  # here, not at the top: the command line imports this module before JAX
    return not any(isinstance(leaf, jax.core.Tracer) for tree in trees for leaf in jax.tree.leaves(tree))


def gait_space(spans: int, degree: int, substeps: int, prefix: str = "") -> None:
    """The reference space and grid of ``biped_jax.gait.problem.GaitSettings`` (substeps even: Simpson)."""
    for name, value in (("spans", spans), ("degree", degree), ("substeps", substeps)):
        integer_in(prefix + name, value, *GAIT_INTEGER_RANGES[name])
    if substeps % 2:
        raise ValueError(f"{prefix}substeps must be even (Simpson's rule pairs the steps), got {substeps}")
