"""The gait problem split by shooting segment (:class:`biped_jax.optim.local_derivatives.LocalProblem`),
for exact derivatives at the cost of a segment's columns rather than of the whole problem's colours.

Segment k owns its grid samples (its node and the steps after it; the last segment also the step's end)
and its shooting defect; it reads its node, the control points whose B-splines reach it and the next
node. The boundary rows (touchdown, periodicity, impact) read the first sample (the first node and the
first span's control points), the last segment's columns and that segment's integrated end state (the
chain rule through it: :mod:`biped_jax.optim.local_derivatives`). The rows are the
same functions as :func:`biped_jax.gait.rollout.simulate` and :func:`biped_jax.gait.constraints.
constraint_groups` compute (shared code), in the problem's order by a fixed permutation; a test checks
the split against the problem to rounding.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax.drives import model as drive_model
from biped_jax.dynamics import mjx_biped
from biped_jax.dynamics.interface import stance_dynamics, touchdown
from biped_jax.gait import constraints
from biped_jax.gait.rollout import sample_outputs, shoot, time_scale
from biped_jax.gait.kinds import KINDS
from biped_jax.gait.settings import GaitSettings
from biped_jax.gait.splines import basis, grid, simpson_weights
from biped_jax.optim.local_derivatives import LocalProblem
from biped_jax.robots.planar_biped import ACTUATED_INDEX, SWAP, pinned_coordinates


def _control_columns(settings: GaitSettings) -> np.ndarray:
    """x's column of every control point's entry, (control_points, 4): point 0 mirrors the last free
    point with the legs swapped (:func:`biped_jax.gait.splines.control_points`)."""
    free = 2 + np.arange(4 * (settings.control_points - 1)).reshape(settings.control_points - 1, 4)
    return np.concatenate([free[-1, np.asarray(SWAP)][None], free])


def _node_columns(settings: GaitSettings) -> np.ndarray:
    """x's columns of every shooting node (angle, rate), (segments, 2)."""
    later = 2 + 4 * (settings.control_points - 1) + np.arange(2 * (settings.segments - 1)).reshape(-1, 2)
    return np.concatenate([np.array([[0, 1]]), later])


def _layout(settings: GaitSettings):
    """Per segment: its control-point window (first point), the basis at its samples and midpoints
    restricted to the window, its steps in normalised time and its Simpson weights."""
    segments, per = settings.segments, settings.steps // settings.segments
    window = settings.spans // settings.segments + settings.degree
    s = grid(settings)
    mid = 0.5 * (s[1:] + s[:-1])
    at_grid, at_mid = np.stack(basis(settings, s)), np.stack(basis(settings, mid))  # (3, T + 1, P), (3, T, P)
    weights = simpson_weights(settings)
    first = np.arange(segments) * (settings.spans // settings.segments)
    grid_rows = np.arange(segments)[:, None] * per + np.arange(per + 1)[None]      # (S, per + 1)
    mid_rows = np.arange(segments)[:, None] * per + np.arange(per)[None]           # (S, per)
    cols = first[:, None] + np.arange(window)[None]                                # (S, window)
    b_grid = np.take_along_axis(at_grid[:, grid_rows], cols[None, :, None, :], axis=3)  # (3, S, per + 1, w)
    b_mid = np.take_along_axis(at_mid[:, mid_rows], cols[None, :, None, :], axis=3)
    # the window holds every control point that reaches the segment's samples (up to rounding, relative to
    # each derivative's size: the second derivative reaches 2e4 on the short end spans of 64 graded spans)
    outside = at_grid[:, grid_rows].sum(axis=3) - b_grid.sum(axis=3)
    scale = np.abs(at_grid).max(axis=(1, 2))[:, None, None]
    if np.abs(outside / scale).max() > 1e-12:
        raise AssertionError("a control point outside the window reaches a segment")
    owned = np.ones((segments, per + 1))
    owned[:-1, -1] = 0.0  # a segment's end sample is the next node's (the last one's is the step's end)
    data = {"basis_grid": np.moveaxis(b_grid, 0, 1), "basis_mid": np.moveaxis(b_mid, 0, 1),
            "ds": np.diff(s)[mid_rows], "weights": weights[np.minimum(grid_rows, settings.steps)] * owned,
            "phase": s[grid_rows]}
    return first, window, data


class _Split:
    """Builds the split for one settings, biped and problem kind (:data:`biped_jax.gait.kinds.KINDS`)."""

    def __init__(self, biped: mjx_biped.PlanarBiped, settings: GaitSettings, kind: str = "energy"):
        if settings.dynamics not in ("chain", "mjx"):
            raise ValueError(f"unknown dynamics {settings.dynamics!r}")
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {tuple(KINDS)}, got {kind!r}")
        self.biped, self.settings, self.kind, self.spec = biped, settings, kind, KINDS[kind]
        self.n = settings.size + self.spec.columns
        self.segments, self.per = settings.segments, settings.steps // settings.segments
        self.first, self.window, self.data = _layout(settings)
        controls, nodes = _control_columns(settings), _node_columns(settings)
        limit = list(range(settings.size, self.n))  # the columns beside x
        rows = []
        for k in range(self.segments):
            following = nodes[k + 1] if k + 1 < self.segments else np.full(2, self.n)
            rows.append(np.concatenate([nodes[k], controls[self.first[k]:self.first[k] + self.window].ravel(),
                                        following, limit]))
        self.segment_columns = np.stack(rows).astype(np.int32)
        start = np.concatenate([nodes[0], controls[:settings.degree + 1].ravel()])
        last = self.segment_columns[-1, :-2 - len(limit)]  # the last segment's node and control points
        self.boundary_columns = np.concatenate([start, last, limit]).astype(np.int32)
        self.start_size = start.shape[0]

    # -- where the problem's rows are in the split

    def _sample(self, t: int) -> tuple[int, int]:
        """(segment, position) of grid sample t."""
        return (t // self.per, t % self.per) if t < self.settings.steps else (self.segments - 1, self.per)

    def orders(self, shapes: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """order_r, order_h, order_g (see LocalProblem); ``shapes``: each sample group's (blocks, C)."""
        steps, segments, per = self.settings.steps, self.segments, self.per
        r_size = (per + 1) * 4
        order_r = [self._sample(t)[0] * r_size + self._sample(t)[1] * 4 + j for t in range(steps + 1) for j in range(4)]
        split_h = segments * 2
        order_h = [k * 2 for k in range(segments - 1)] + [k * 2 + 1 for k in range(segments - 1)]
        order_h += list(range(split_h, split_h + 2 + 1 + 5))
        offsets, at = {}, 0  # each sample group's offset in a segment's g
        for name in constraints.SAMPLE_GROUPS:
            offsets[name] = at
            at += shapes[name][0] * (per + 1) * shapes[name][1]
        g_size, split_g = at, segments * at
        landing = 1 + (self.settings.touchdown_forward_speed is not None)  # touchdown_descending's rows
        boundary = {"touchdown_descending": (0, landing), "impact_impulse": (landing, 3), "liftoff": (landing + 3, 1)}
        boundary_size = sum(count for _, count in boundary.values())
        order_g = []
        for name, (kind, _) in constraints.CONSTRAINT_GROUPS.items():
            if kind != "inequality":
                continue
            if name in boundary:
                first, count = boundary[name]
                order_g += list(range(split_g + first, split_g + first + count))
                continue
            blocks, width = shapes[name]
            samples = range(1, steps) if name == "swing_foot_height" else range(steps + 1)
            for block in range(blocks):
                for t in samples:
                    k, p = self._sample(t)
                    base = k * g_size + offsets[name] + block * (per + 1) * width + p * width
                    order_g += list(range(base, base + width))
        # the kind's bounds, after the gait's rows
        order_g += [split_g + boundary_size + k for k in range(len(self.spec.bounds))]
        return tuple(np.asarray(o, dtype=np.int32) for o in (order_r, order_h, order_g))

    # -- the rows of one segment

    def _model(self, params, local):
        """The gait model the rows are posed on: ``params`` itself, or the kind's model at its columns
        beside x (the last of ``local``)."""
        return self.spec.model(params, self._extra(local))

    def _extra(self, local):
        return local[local.shape[0] - self.spec.columns:]

    def _dynamics(self, model):
        """(the stance dynamics of ``model``'s design, its step time in s)."""
        return (stance_dynamics(mjx_biped.with_design(self.biped, model.design), self.settings.dynamics),
                model.step_length / model.speed)

    def _samples(self, local, data, model):
        """The segment's samples: (q, qd, qdd, u, force, positions) at its per + 1 grid points and the
        state integrated to its end (2,)."""
        dynamics, step_time = self._dynamics(model)
        node, points = local[:2], local[2:2 + 4 * self.window].reshape(self.window, 4)
        scale = time_scale(step_time)
        at_grid = jnp.einsum("dpw,wj->dpj", data["basis_grid"], points) * scale   # (3, per + 1, 4)
        at_mid = jnp.einsum("dpw,wj->dpj", data["basis_mid"], points) * scale     # (3, per, 4)
        by_step = lambda a: jnp.swapaxes(a, 0, 1)  # noqa: E731  (3, P, 4) -> (P, 3, 4)
        after = shoot(dynamics, node, by_step(at_grid[:, :-1]), by_step(at_mid), by_step(at_grid[:, 1:]),
                      data["ds"] * step_time)                                     # (per, 2)
        stance = jnp.concatenate([node[None], after])                              # (per + 1, 2)
        outputs = jax.vmap(lambda *a: sample_outputs(dynamics, *a))(stance[:, 0], stance[:, 1], by_step(at_grid))
        return dynamics, step_time, outputs, after[-1]

    def segment(self, local, data, params):
        """One segment's rows (r, h, g) and its integrated end state (2,), which the boundary reads of
        the last segment."""
        model = self._model(params, local)
        _, step_time, (q, qd, _, u, force, positions), end = self._samples(local, data, model)
        speed = qd[:, ACTUATED_INDEX]
        # sqrt(R w t_f) as sqrt(R w) sqrt(t_f): the weights of the samples a segment does not own are 0,
        # where the square root's derivative is not finite, and t_f moves with a free step length
        r = self._residuals(u, speed, model, data["weights"]) * jnp.sqrt(step_time)
        r = self.spec.scaled_residuals(r, self._extra(local))  # r . r = J / l for an energy per metre
        groups = constraints.sample_groups(q, u, force, positions[:, 0], positions[:, 1:, 1], speed, data["phase"],
                                           model, self.settings)
        following = local[2 + 4 * self.window:4 + 4 * self.window]
        h = (end - following) / jnp.asarray(_DEFECT_SCALES, end.dtype)
        g = jnp.concatenate([(groups[name] / constraints.group_scale(name)).ravel()
                             for name in constraints.SAMPLE_GROUPS])
        return r, h, g, end

    @staticmethod
    def _residuals(u, speed, model, dt):
        return drive_model.joule_residuals(u, speed, model.drives, dt[:, None]).ravel()

    # -- the boundary rows

    def boundary(self, columns, end, params):
        """The rows at the step's ends from the first sample's columns, the last segment's (its node and
        control points, the columns beside x) and that segment's integrated end state ``end`` (2,)
        (:meth:`segment`'s last output): the samples at the touchdown are that state's, so the boundary
        holds no rollout of its own."""
        start, local = columns[:self.start_size], columns[self.start_size:]
        model = self._model(params, local)
        dynamics, step_time = self._dynamics(model)
        scale = time_scale(step_time)[:, 0]                                       # (3, 1)
        # the reference at each end: the first span's control points at s = 0, the last segment's at s = 1
        first_basis = jnp.asarray(np.stack(basis(self.settings, np.zeros(1)))[:, 0, :self.settings.degree + 1])
        ref0 = (first_basis @ start[2:].reshape(self.settings.degree + 1, 4)) * scale
        points = local[2:2 + 4 * self.window].reshape(self.window, 4)
        ref1 = (jnp.asarray(self.data["basis_grid"][-1, :, -1]) @ points) * scale
        q0, qd0 = (pinned_coordinates(value, ref, jnp) for value, ref in ((start[0], ref0[0]), (start[1], ref0[1])))
        q1, qd1, _, _, _, positions = sample_outputs(dynamics, end[0], end[1], ref1)
        _, foot_velocity = dynamics.swing_foot(q1, qd1)
        ends = {"q0": q0, "qd0": qd0, "swing_foot_end": positions[0], "swing_foot_velocity": foot_velocity,
                "touchdown": touchdown(dynamics, q1, qd1)}
        groups = constraints.boundary_groups(ends, model, self.settings)
        h = jnp.concatenate([groups[n] / constraints.group_scale(n) for n in _BOUNDARY_EQUALITIES])
        g = jnp.concatenate([groups[n] / constraints.group_scale(n) for n in _BOUNDARY_INEQUALITIES])
        g = self.spec.with_bounds(g, self._extra(local), params)
        return jnp.zeros(0, columns.dtype), h, g


#: A segment's defect rows, end - next node, are scaled by these (angle, rate): the rows' only
#: dependence on the next node, so its Jacobian columns are -1 / these (``linear_segment_h``).
_DEFECT_SCALES = (constraints.group_scale("continuity_angle"), constraints.group_scale("continuity_rate"))
_BOUNDARY_EQUALITIES = ("touchdown_position", "periodicity_angle", "periodicity_rate")
_BOUNDARY_INEQUALITIES = ("touchdown_descending", "impact_impulse", "liftoff")


#: Each sample group's (blocks, components) (:func:`biped_jax.gait.constraints.sample_groups`) without
#: ``GaitSettings.drive_limits``; with them the gear group has four components (:func:`sample_shapes`).
SAMPLE_SHAPES = {"swing_foot_height": (1, 1), "heights": (1, 3), "knee_range": (2, 2), "vertical_force": (1, 1),
                 "friction_cone": (2, 1), "torque_bound": (2, 4), "power_limit": (2, 4), "voltage": (2, 4),
                 "gear_input_speed": (2, 0)}


def sample_shapes(settings: GaitSettings) -> dict:
    """Each sample group's (blocks, components) in ``settings``."""
    return {**SAMPLE_SHAPES, "gear_input_speed": (2, 4 if settings.drive_limits else 0)}


def local_problem(biped: mjx_biped.PlanarBiped, settings: GaitSettings, kind: str = "energy") -> LocalProblem:
    """The split of the gait problem of ``kind`` (:data:`biped_jax.gait.kinds.KINDS`: "energy", params a
    GaitModel; "limit", "step", "speed", with their columns beside x and their params) whose rows, in
    the problem's order, are those of :func:`biped_jax.gait.kinds.kind_problem` (the
    :class:`~biped_jax.gait.solver.GaitSolver`'s ``problems[kind]``)."""
    split = _Split(biped, settings, kind)
    order_r, order_h, order_g = split.orders(sample_shapes(settings))
    return LocalProblem(segment=split.segment, boundary=split.boundary, segment_columns=split.segment_columns,
                        boundary_columns=split.boundary_columns, segment_data=split.data,
                        order_r=order_r, order_h=order_h, order_g=order_g,
                        linear_objective=split.n - 1 if split.spec.linear else None,
                        # the next node enters only the defect, end - node, scaled as h's two rows
                        linear_segment_columns=(2 + 4 * split.window, 3 + 4 * split.window),
                        linear_segment_h=tuple(map(tuple, np.diag(-1 / np.asarray(_DEFECT_SCALES)))),
                        energy_weight=(lambda params: params.energy_weight) if split.spec.linear else None)
