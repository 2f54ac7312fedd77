"""The gait problem split by shooting segment (biped_jax.gait.segmented) has the problem's rows, and its
segment-local exact derivatives (biped_jax.optim.local_derivatives) equal central differences of the
problem. ``benchmarks/local_derivatives.py`` checks them against the dense autodiff derivatives to
rounding (the energy and the power-limit problem, several segmentations) and times them."""

import dataclasses

import jax
import numpy as np
import pytest

from biped_jax.gait import problem as gait_problem
from biped_jax.gait import segmented
from biped_jax.optim import jacobian
from biped_jax.optim import local_derivatives as ld

#: Multiply shot in 4 segments of one knot span, the swing foot held 10 mm up mid-step (its rows read each
#: sample's phase) and landing at most 1 m/s forward (a second touchdown row).
SPACES = {"4 segments": gait_problem.GaitSettings(spans=4, segments=4, substeps=2, swing_clearance=0.01,
                                                  touchdown_forward_speed=1.0)}


def _space(settings):
    jax.config.update("jax_enable_x64", True)
    from biped_jax.gait.solver import GaitSolver
    solver = GaitSolver(settings, check_refinement=False)
    model = gait_problem.gait_model("18kg", 0.6, 15.0)
    x = np.asarray(solver._initial_guess(jax.tree.map(lambda a: a[None], model))[0])
    return solver, model, x + 0.02 * np.random.default_rng(4).normal(size=x.shape)  # off the start's symmetry


def _split(solver, model, x, kind):
    problem = solver.problem if kind == "energy" else solver.limit_problem
    point = x if kind == "energy" else np.concatenate([x, [0.8]])
    return problem, point, segmented.local_problem(solver.biped, solver.settings, kind)


def _the_blocks_products_equal_the_dense_ones(blocks, dense, rng):
    """Every product the interior point takes of the inequality Jacobian, by blocks and dense."""
    m, n = dense.shape
    assert blocks.shape == (m, n)
    v, w = rng.normal(size=n), rng.uniform(size=m)
    scale = rng.uniform(0.5, 2.0, size=m)
    np.testing.assert_allclose(jacobian.matvec(blocks, v), dense @ v, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(jacobian.rmatvec(blocks, w), dense.T @ w, rtol=1e-12, atol=1e-10)
    np.testing.assert_allclose(jacobian.gram(blocks, w), dense.T @ (w[:, None] * dense), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(jacobian.dense(jacobian.row_scaled(blocks, scale)), scale[:, None] * dense, rtol=1e-15)
    np.testing.assert_allclose(jacobian.row_max_abs(blocks), np.max(np.abs(dense), axis=1), rtol=1e-15)


def test_the_splits_derivatives_equal_central_differences_of_the_problem():
    solver, model, x = _space(SPACES["4 segments"])
    problem, point, local = _split(solver, model, x, "energy")
    assert local.directions < point.shape[0]
    step, n = 1e-6, point.shape[0]  # central differences in float64: error about 1e-9 relative
    offsets = step * np.eye(n)
    # one program evaluates the problem at the point and at every offset (two programs in all here)
    values = jax.jit(jax.vmap(problem.evaluate, in_axes=(0, None)))(
        np.concatenate([point[None], point + offsets, point - offsets]), model)
    f, h, g = (v[0] for v in values)
    slopes = [(v[1:n + 1] - v[n + 1:]) / (2 * step) for v in values]      # (n, ...) per output
    rng = np.random.default_rng(5)
    y, z = rng.normal(size=h.shape), rng.uniform(size=g.shape)
    split = jax.jit(ld.derivatives, static_argnums=(0, 6))  # jac g in blocks, as the interior point takes it
    f_, h_, g_, grad, jac_h, blocks, hessian = split(local, point, model, 0.7, y, z, True)
    jac_g = np.asarray(jacobian.dense(blocks))
    _the_blocks_products_equal_the_dense_ones(blocks, jac_g, rng)
    # the split's rows are the problem's
    assert float(f_) == pytest.approx(float(f), rel=1e-12)
    np.testing.assert_allclose(h_, h, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(g_, g, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(jac_h, slopes[1].T, atol=1e-7 * np.max(np.abs(jac_h)))
    np.testing.assert_allclose(jac_g, slopes[2].T, atol=1e-7 * np.max(np.abs(jac_g)))
    np.testing.assert_allclose(grad, 0.7 * slopes[0] + slopes[1] @ y + slopes[2] @ z, atol=1e-7 * np.max(np.abs(grad)))
    for i in range(n):  # the Hessian's columns: differences of the split's own gradient
        plus = split(local, point + offsets[i], model, 0.7, y, z, True)[3]
        minus = split(local, point - offsets[i], model, 0.7, y, z, True)[3]
        np.testing.assert_allclose(hessian[:, i], (plus - minus) / (2 * step), atol=1e-6 * np.max(np.abs(hessian)))


def test_linear_columns_come_with_their_constant_jacobian_rows():
    """A segment's linear columns take no derivative pass: their d h / d column must be given, one row per
    column (central differences above check the values)."""
    solver, _, _ = _space(SPACES["4 segments"])
    local = segmented.local_problem(solver.biped, solver.settings)
    assert np.shape(local.linear_segment_h) == (len(local.linear_segment_columns), 2)
    with pytest.raises(ValueError, match="linear_segment_h"):
        dataclasses.replace(local, linear_segment_h=((-1.0, 0.0),))


def test_the_boundary_reads_the_last_segments_end_through_columns_it_holds():
    """The boundary's rows read the last segment's end state, so the chain rule needs that segment's
    columns among the boundary's (the padding column excepted): a position of each there (one past them
    for the padding), and a split without one is refused, naming it."""
    solver, _, _ = _space(SPACES["4 segments"])
    local = segmented.local_problem(solver.biped, solver.settings)
    n = solver.settings.size
    positions = local.last_in_boundary(n)
    last = local.segment_columns[-1]
    held = last != n
    np.testing.assert_array_equal(local.boundary_columns[positions[held]], last[held])
    assert np.all(positions[~held] == len(local.boundary_columns)) and (~held).sum() == 2  # the next node: none
    missing = int(last[0])
    cut = dataclasses.replace(local, boundary_columns=local.boundary_columns[local.boundary_columns != missing])
    with pytest.raises(ValueError, match=rf"its columns \[{missing}\] must be among boundary_columns"):
        cut.last_in_boundary(n)
