"""The gait problem's kinds: the energy problem in x, and the problems that pose it with a few columns
beside x (the power limit, the step length, the speed as decision variables). One record per kind
says how those columns change the model, the objective and the rows, so that the whole problem
(:func:`kind_problem`) and its split by shooting segment (:mod:`biped_jax.gait.segmented`) are the
same function of them.

- "energy": min J(x) (params a :class:`~biped_jax.gait.settings.GaitModel`).
- "limit": (x, t), every constraint at M_W = t M_W0, min t + w J
  (:class:`~biped_jax.gait.settings.LimitParams`): the smallest power limit.
- "step": (x, l), L = l L0 within bounds, min J / l, the energy per metre in J per L0 metres
  (:class:`~biped_jax.gait.settings.StepParams`).
- "speed": (x, l, c), L = l L0 within bounds and v = v0 / c (c the pace relative to the start's),
  min c + w J / l (:class:`~biped_jax.gait.settings.SpeedParams`): the fastest gait.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import jax.numpy as jnp

from biped_jax.gait.settings import with_limit_fraction, with_step_fraction
from biped_jax.optim import nlp

#: The fastest speed the "speed" kind may reach, m/s: its pace is bounded below by v0 / this (a bound
#: far above any walking speed of these robots, which keeps the step time positive).
SPEED_CAP = 5.0


#: The free step length's bound rows (g <= 0): low - l and l - high, l the first column beside x.
STEP_BOUNDS = (lambda extra, params: params.low - extra[0], lambda extra, params: extra[0] - params.high)


def _with_pace(model, pace):
    return dataclasses.replace(model, speed=model.speed / pace)


@dataclasses.dataclass(frozen=True)
class ProblemKind:
    """How a kind poses the gait problem with ``columns`` decision variables beside x (``extra``, the
    last columns of its decision vector).

    Attributes:
      columns: how many columns beside x.
      model: ``(params, extra) -> GaitModel`` the rows are posed on.
      per_metre: the objective's energy is J / l with l = extra[0] (the residuals scaled by
        1 / sqrt(l)).
      bounds: the rows after the gait's inequalities, each ``(extra, params) -> g (<= 0)``, a scalar.
      linear: the objective is extra[-1] + params.energy_weight * (the energy): minimise that column.
    """

    columns: int
    model: Callable
    per_metre: bool = False
    bounds: tuple[Callable, ...] = ()
    linear: bool = False

    def scaled_residuals(self, r, extra):
        """The energy's residuals r (r . r = J) as the objective takes them: r / sqrt(l) for an energy per
        metre (r . r = J / l), else r itself."""
        return r / jnp.sqrt(extra[0]) if self.per_metre else r

    def with_bounds(self, g, extra, params):
        """The inequalities ``g`` followed by the kind's bound rows."""
        if not self.bounds:
            return g
        return jnp.concatenate([g, jnp.stack([row(extra, params) for row in self.bounds])])


KINDS = {
    "energy": ProblemKind(0, lambda params, extra: params),
    "limit": ProblemKind(1, lambda params, extra: with_limit_fraction(params.model, extra[0]), linear=True),
    "step": ProblemKind(1, lambda params, extra: with_step_fraction(params.model, extra[0]), per_metre=True,
                        bounds=STEP_BOUNDS),
    "speed": ProblemKind(
        2, lambda params, extra: _with_pace(with_step_fraction(params.model, extra[0]), extra[1]), per_metre=True,
        bounds=STEP_BOUNDS + (lambda extra, params: params.model.speed / SPEED_CAP - extra[1],), linear=True),
}


def kind_problem(kind: str, residuals: Callable, size: int) -> nlp.ConstrainedProblem:
    """The whole problem of ``kind`` over (x, extra), x of length ``size``, from the energy problem's
    ``residuals(x, model) -> (r, h, g)`` (r . r = J)."""
    spec = KINDS[kind]
    if kind == "energy":
        return nlp.ConstrainedProblem.from_residuals(residuals)

    def scaled(point, params):
        x, extra = point[:size], point[size:]
        r, h, g = residuals(x, spec.model(params, extra))
        return spec.scaled_residuals(r, extra), h, spec.with_bounds(g, extra, params)

    if not spec.linear:
        return nlp.ConstrainedProblem.from_residuals(scaled)

    def evaluate(point, params):
        r, h, g = scaled(point, params)
        return point[-1] + params.energy_weight * (r @ r), h, g
    return nlp.ConstrainedProblem(evaluate)
