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


def sequence(name: str, value, kind: type, what: str) -> list:
    """``value`` as a list if it is a non-empty list or tuple of ``kind`` (``what`` names one item)."""
    if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)):
        raise TypeError(f"{name} must be a list or tuple (one {what} per problem), got "
                        f"{type(value).__name__} {value!r:.80}")
    if not value:
        raise ValueError(f"{name} is empty: give at least one {what}")
    for i, item in enumerate(value):
        if not isinstance(item, kind):
            raise TypeError(f"{name}[{i}] must be a {what}, got {type(item).__name__} {item!r:.80}")
    return list(value)


def same_length(**batches) -> int:
    """The common length of the named batches (None entries skipped); ValueError listing the lengths."""
    lengths = {name: len(value) for name, value in batches.items() if value is not None}
    if len(set(lengths.values())) > 1:
        raise ValueError("the batch must give one of each per problem; got "
                         + ", ".join(f"{count} {name}" for name, count in lengths.items()))
    return next(iter(lengths.values()))


def finite_array(name: str, value, shape: tuple, meaning: str = ""):
    """``value`` as a float numpy array of exactly ``shape`` with finite entries (None in ``shape``:
    any length); ValueError naming the shape wanted and the one given."""
    import numpy as np
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be an array of numbers of shape {shape}{meaning}, got "
                        f"{type(value).__name__}") from None
    if array.ndim != len(shape) or any(want is not None and want != got for want, got in zip(shape, array.shape)):
        wanted = "(" + ", ".join("any" if s is None else str(s) for s in shape) + (",)" if len(shape) == 1 else ")")
        raise ValueError(f"{name} must have shape {wanted}{meaning}, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite, got {int(np.sum(~np.isfinite(array)))} non-finite entries")
    return array
