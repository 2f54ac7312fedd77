"""The batched interior point (biped_jax.optim.interior_point) on small problems with known optima and
multipliers, and its exact coloured derivatives against dense ones and central differences."""

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from biped_jax.optim import exact_derivatives as ed
from biped_jax.optim import interior_point
from biped_jax.optim import nlp

#: Optima to this relative accuracy: the solver's KKT tolerance is 1e-8.
OPTIMUM_TOLERANCE = 1e-7
#: Multipliers converge at the rate of the KKT error, a few digits fewer than the point.
MULTIPLIER_TOLERANCE = 1e-5


def hs071(x, target):
    """Hock and Schittkowski's problem 71 (IPOPT's tutorial problem), sum x^2 = target (40 there)."""
    f = x[0] * x[3] * (x[0] + x[1] + x[2]) + x[2]
    h = jnp.array([jnp.sum(x**2) - target])
    g = jnp.concatenate([jnp.array([25.0 - jnp.prod(x)]), 1.0 - x, x - 5.0])
    return f, h, g


@pytest.fixture(scope="module")
def hs071_result():
    starts = jnp.array([[1.0, 5.0, 5.0, 1.0], [2.0, 2.0, 2.0, 2.0], [1.5, 4.0, 4.0, 1.5]])
    return interior_point.solve(nlp.ConstrainedProblem(hs071), starts, jnp.full(3, 40.0))


def test_hs071_reaches_its_known_optimum_and_multipliers(hs071_result):
    # Hock and Schittkowski (1981), problem 71; multipliers as IPOPT's tutorial reports them
    optimum = np.array([1.0, 4.74299963, 3.82114998, 1.37940829])
    result = hs071_result
    assert result.status == ["converged"] * 3
    np.testing.assert_allclose(result.cost, 17.0140173, rtol=OPTIMUM_TOLERANCE)
    np.testing.assert_allclose(result.x, np.tile(optimum, (3, 1)), rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(result.multipliers_eq[:, 0], 0.161468568, rtol=MULTIPLIER_TOLERANCE)
    np.testing.assert_allclose(result.multipliers_in[:, 0], 0.552293663, rtol=MULTIPLIER_TOLERANCE)  # product
    np.testing.assert_allclose(result.multipliers_in[:, 1], 1.087871244, rtol=MULTIPLIER_TOLERANCE)  # x1 >= 1
    assert np.all(result.multipliers_in[:, 2:] < 1e-7)  # inactive bounds
    assert np.all(result.outer_iterations < 40)


def test_the_envelope_gradient_of_hs071_is_its_multiplier(hs071_result):
    # d f* / d target = -lambda (f + lambda (sum x^2 - target)): the multiplier is the sensitivity
    bigger = interior_point.solve(nlp.ConstrainedProblem(hs071), hs071_result.x[:1], jnp.array([40.01]))
    slope = (bigger.cost[0] - hs071_result.cost[0]) / 0.01
    assert slope == pytest.approx(-hs071_result.multipliers_eq[0, 0], rel=1e-3)


def equality_qp(x, data):
    """min |x - a|^2 / 2 subject to A x = b, one inactive bound x <= 10."""
    a, matrix, b = data
    return 0.5 * jnp.sum((x - a) ** 2), matrix @ x - b, x - 10.0


def test_an_equality_constrained_problem_has_its_closed_form_solution():
    rng = np.random.default_rng(0)
    a, matrix, b = rng.normal(size=(2, 5)), rng.normal(size=(2, 2, 5)), rng.normal(size=(2, 2))
    result = interior_point.solve(nlp.ConstrainedProblem(equality_qp), np.zeros((2, 5)), (a, matrix, b))
    for k in range(2):
        multiplier = np.linalg.solve(matrix[k] @ matrix[k].T, matrix[k] @ a[k] - b[k])
        np.testing.assert_allclose(result.x[k], a[k] - matrix[k].T @ multiplier, atol=1e-8)
        np.testing.assert_allclose(result.multipliers_eq[k], multiplier, atol=1e-6)
        assert np.all(np.abs(result.multipliers_in[k]) < 1e-7)
    assert result.status == ["converged"] * 2


def active_and_inactive(x, _):
    """min (x1 - 1)^2 + (x2 - 2)^2 subject to x1 + x2 <= 2 (active at (0.5, 1.5), multiplier 1) and
    x1 <= 10 (inactive)."""
    return (x[0] - 1) ** 2 + (x[1] - 2) ** 2, jnp.zeros(0), jnp.array([x[0] + x[1] - 2.0, x[0] - 10.0])


def test_active_and_inactive_inequalities():
    result = interior_point.solve(nlp.ConstrainedProblem(active_and_inactive), jnp.array([[5.0, -3.0]]), jnp.zeros(1))
    assert result.status == ["converged"]
    np.testing.assert_allclose(result.x[0], [0.5, 1.5], atol=1e-8)
    np.testing.assert_allclose(result.multipliers_in[0], [1.0, 0.0], atol=1e-6)


def degenerate(x, _):
    """min x1^2 + x2^2 subject to x1 + x2 >= 1 twice (the active constraints linearly dependent:
    the multipliers are not unique, their sum is 1) and x2 >= 0.5 (weakly active: its multiplier
    is 0 at the optimum (0.5, 0.5), no strict complementarity)."""
    row = 1.0 - x[0] - x[1]
    return x[0] ** 2 + x[1] ** 2, jnp.zeros(0), jnp.array([row, row, 0.5 - x[1]])


def test_a_degenerate_problem_converges_to_its_optimum():
    result = interior_point.solve(nlp.ConstrainedProblem(degenerate), jnp.array([[3.0, 2.0]]), jnp.zeros(1))
    assert result.status == ["converged"]
    assert result.cost[0] == pytest.approx(0.5, abs=1e-8)
    # without strict complementarity an interior point's x converges like sqrt(mu) (mu ends at 1e-9)
    np.testing.assert_allclose(result.x[0], [0.5, 0.5], atol=1e-4)
    assert result.multipliers_in[0, :2].sum() == pytest.approx(1.0, abs=1e-3)  # as slowly as x
    assert result.multipliers_in[0, 2] == pytest.approx(0.0, abs=1e-3)


def infeasible(x, _):
    """x1^2 + x2^2 <= 1 and x1 >= 2: no feasible point (the least violated is (1.5, 0), 1.25 / 0.5)."""
    return x[0] ** 2 + x[1] ** 2, jnp.zeros(0), jnp.array([x[0] ** 2 + x[1] ** 2 - 1.0, 2.0 - x[0]])


def test_an_infeasible_problem_says_so_with_its_violation():
    result = interior_point.solve(nlp.ConstrainedProblem(infeasible), jnp.array([[0.5, 0.5]]), jnp.zeros(1),
                      interior_point.InteriorPointOptions(max_iterations=100))
    assert result.status == ["infeasible"]
    assert result.violation[0] > 0.1
    assert np.all(np.isfinite(result.x)) and np.isfinite(result.cost[0])


def test_batches_of_other_problems_and_sizes_share_one_program():
    from biped_jax.report.compile_profile import profile_compiles
    compiled = interior_point.compile_problem(nlp.ConstrainedProblem(hs071))
    batches = ([40.0, 38.0, 42.0, 41.0, 39.0], [39.0, 41.0, 40.5, 38.5, 41.5, 40.0], [40.0, 37.0, 43.0, 39.5, 42.0])
    with profile_compiles() as profile:
        for targets in batches:
            result = interior_point.solve(compiled.problem, np.tile([1.0, 5.0, 5.0, 1.0], (len(targets), 1)),
                              jnp.asarray(targets), compiled=compiled)
            assert result.status == ["converged"] * len(targets)
            assert result.x.shape == (len(targets), 4)
    # the memory check's compilation is the one the solve runs: the iterations compile once in all
    assert [e["name"] for e in profile.events].count("jit(_block)") == 1, profile.events
    # batches are padded (to 6 here): other targets, 5 and 6 problems run in one program
    assert compiled.block._cache_size() == 1
    assert compiled.initial._cache_size() == 1


def test_a_batch_is_sharded_over_every_device_jax_sees():
    """With two (host) devices the batch's leading axis is split over both, and every problem still
    reaches hs071's optimum: a fresh process, as the device count is fixed when JAX starts."""
    import os
    import subprocess
    import sys
    code = """
import jax, jax.numpy as jnp, numpy as np
from biped_jax.commands import configure_jax
configure_jax()
from biped_jax.optim import interior_point, nlp
from tests.test_interior_point import hs071
assert jax.device_count() == 2, jax.devices()
sharding = interior_point.batch_sharding(4)
assert sharding is not None and len(sharding.device_set) == 2
assert interior_point.batch_sharding(interior_point.padded_batch(3)) is not None  # an odd batch is padded, then split
starts = jnp.array([[1.0, 5.0, 5.0, 1.0], [2.0, 2.0, 2.0, 2.0], [1.5, 4.0, 4.0, 1.5], [1.2, 4.5, 4.0, 1.2]])
result = interior_point.solve(nlp.ConstrainedProblem(hs071), starts, jnp.full(4, 40.0))
assert result.status == ["converged"] * 4, result.status
np.testing.assert_allclose(result.cost, 17.0140173, rtol=1e-7)
"""
    flags = os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
    root = Path(__file__).resolve().parent.parent
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=root,
                         env={**os.environ, "XLA_FLAGS": flags.strip(), "PYTHONPATH": str(root)})
    assert run.returncode == 0, run.stderr[-3000:]


def test_batches_are_padded_to_few_sizes():
    sizes = [interior_point.padded_batch(b) for b in range(1, 50)]
    assert sorted(set(sizes)) == [1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64]
    assert all(b <= size <= 1.5 * b for b, size in zip(range(1, 50), sizes))


def test_the_inertia_correction_ends_on_a_matrix_no_shift_makes_definite():
    """A Hessian with a NaN (a rollout that blew up) after a failed step (floor = the last shift): the
    shift grows until its cap and the factor comes back not finite (the iteration then fails and the
    problem ends, rather than the loop shifting by the same amount for ever)."""
    matrix = jnp.array([[1.0, jnp.nan], [jnp.nan, 1.0]])
    factor, delta = jax.jit(interior_point._inertia_corrected)(matrix, jnp.asarray(1.0), jnp.asarray(1.0))
    assert not np.all(np.isfinite(factor)) and float(delta) > 1e30
    # indefinite (eigenvalues 3, -1) with the last shift's third (1/3) below the floor 0.5: the floor
    # fails, and the shift grows 8x to the first that makes the matrix definite (the loop used to retry
    # the floor for ever here)
    indefinite = jnp.array([[1.0, 2.0], [2.0, 1.0]])
    factor, delta = jax.jit(interior_point._inertia_corrected)(indefinite, jnp.asarray(1.0), jnp.asarray(0.5))
    assert np.all(np.isfinite(factor)) and float(delta) == pytest.approx(4.0)


def test_options_name_a_bad_value():
    with pytest.raises(ValueError, match="tolerance must be a positive number, got -1"):
        interior_point.InteriorPointOptions(tolerance=-1.0)
    with pytest.raises(ValueError, match="max_iterations must be a positive integer, got 0"):
        interior_point.InteriorPointOptions(max_iterations=0)
    with pytest.raises(ValueError, match=r"x0 must have shape \(B, n\)"):
        interior_point.solve(nlp.ConstrainedProblem(hs071), jnp.ones(4), jnp.full(1, 40.0))
    with pytest.raises(ValueError, match=r"quorum must be a fraction in \(0, 1\], got 1.5"):
        interior_point.InteriorPointOptions(quorum=1.5)
    with pytest.raises(ValueError, match="patience must be a non-negative integer, got -1"):
        interior_point.InteriorPointOptions(patience=-1)


def test_a_batch_stops_a_few_iterations_after_its_quorum_has_finished():
    """Three starts at HS071's optimum finish in 5 iterations, a far one needs 14: with a quorum of 3/4
    and a patience of 2 the batch stops at 7, the far problem says it did not finish (with its
    violation), the others are exactly as without the rule; the rule shares the compiled program."""
    optimum = [1.0, 4.74299964, 3.82114998, 1.37940829]
    starts = jnp.array([optimum, optimum, optimum, [3.0, 0.5, 4.8, 4.5]])
    compiled = interior_point.compile_problem(nlp.ConstrainedProblem(hs071))
    options = interior_point.InteriorPointOptions(block=1, mu_initial=1e-6)
    waiting = interior_point.solve(compiled.problem, starts, jnp.full(4, 40.0), options, compiled=compiled)
    assert waiting.status == ["converged"] * 4 and waiting.outer_iterations[3] > 9
    early = interior_point.solve(compiled.problem, starts, jnp.full(4, 40.0),
                     dataclasses.replace(options, quorum=0.75, patience=2), compiled=compiled)
    finished = int(np.max(waiting.outer_iterations[:3]))
    assert early.status[:3] == ["converged"] * 3 and early.status[3] in ("iteration limit", "infeasible")
    assert early.outer_iterations[3] == finished + 2 and np.isfinite(early.violation[3])
    np.testing.assert_array_equal(early.x[:3], waiting.x[:3])
    assert compiled.block._cache_size() == 1


def banded(x, scale):
    """A chain x_k -> x_{k+1} whose rows reach three neighbouring columns (a colouring needs few
    colours), with products and sines so that every second derivative is non-trivial."""
    r = scale * (x[1:-1] ** 2 - x[:-2] * x[2:])
    h = jnp.sin(x[1:] * x[:-1]) - 0.1
    g = x[:-2] * x[1:-1] * x[2:] - 1.0
    return r, h, g


def test_coloured_derivatives_equal_dense_ones_and_central_differences():
    jax.config.update("jax_enable_x64", True)
    problem = nlp.ConstrainedProblem.from_residuals(banded)
    rng = np.random.default_rng(3)
    x = rng.normal(size=24)
    structure = ed.probe_structure(problem, x, 1.5, padding=1)
    assert structure.colours < 12  # banded: far fewer than the 24 columns
    y, z = rng.normal(size=23), rng.uniform(size=22)
    dense = ed.dense_structure(24, 45)
    coloured_parts = ed.derivatives(problem, x, 1.5, 0.7, y, z, structure)
    dense_parts = ed.derivatives(problem, x, 1.5, 0.7, y, z, dense)
    for a, b in zip(coloured_parts, dense_parts):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-13)
    f, h, g, grad, jac_h, jac_g, hessian = coloured_parts

    def lagrangian_gradient(point):
        return ed.derivatives(problem, point, 1.5, 0.7, y, z, structure)[3]
    step = 1e-6  # central differences in float64: error ~ step^2 f''' + eps / step, about 1e-9
    for i in range(24):
        e = np.eye(24)[i] * step
        f_plus, h_plus, g_plus = problem.evaluate(x + e, 1.5)
        f_minus, h_minus, g_minus = problem.evaluate(x - e, 1.5)
        np.testing.assert_allclose(jac_h[:, i], (h_plus - h_minus) / (2 * step), atol=1e-8)
        np.testing.assert_allclose(jac_g[:, i], (g_plus - g_minus) / (2 * step), atol=1e-8)
        difference = (lagrangian_gradient(x + e) - lagrangian_gradient(x - e)) / (2 * step)
        np.testing.assert_allclose(hessian[:, i], difference, atol=1e-6)
        assert grad[i] == pytest.approx(0.7 * (f_plus - f_minus) / (2 * step) + y @ jac_h[:, i] + z @ jac_g[:, i],
                                        abs=1e-7)


# ----------------------------------------------------------------------------- the gait problem

#: Stationarity of the Lagrangian with central-difference derivatives at the interior point's optimum,
#: relative to the objective's gradient: the differences are good to about 1e-8 relative.
KKT_TOLERANCE = 1e-5


@pytest.fixture(scope="module")
def interior_gaits(short_solver, paper_solutions):
    """M1-M4 in the tests' short space (4 knot spans, a shooting segment each) from the default start
    family, in one batch of the batched interior point: the gait tests' solutions."""
    from biped_jax.studies import paper as study
    return short_solver, study.paper_gait_models(study.PAPER_MODELS), paper_solutions


def central_differences(evaluate, point, params, step=1e-6):
    """(f, h, g) at ``point`` and their derivatives (grad f (n,), jac h (m_h, n), jac g (m_g, n)) by
    central differences in float64 (error about 1e-9 relative), ``evaluate`` vmapped over the 2n + 1
    points: independent of the automatic differentiation the solver uses."""
    n = point.shape[0]
    offsets = step * np.eye(n)
    values = evaluate(np.concatenate([point[None], point + offsets, point - offsets]), params)
    f, h, g = (np.asarray(v[0]) for v in values)
    grad, jac_h, jac_g = ((np.asarray(v[1:n + 1]) - np.asarray(v[n + 1:])) / (2 * step) for v in values)
    return f, h, g, grad, jac_h.T, jac_g.T


def test_gaits_converge_to_kkt_points_checked_with_central_differences(interior_gaits):
    """Stationarity, dual feasibility and complementarity with the solver's multipliers and central
    differences of the problem (a wrong autodiff Jacobian or Hessian would leave the solver at a point
    where these fail; the derivatives themselves are checked against central differences in
    test_local_derivatives and below on a banded problem)."""
    from biped_jax.gait.solver import stack_tree
    solver, models, solutions = interior_gaits
    assert [s.status for s in solutions] == ["converged"] * 4
    assert all(s.max_violation < 1e-6 for s in solutions)
    batch = stack_tree(models)
    evaluate = jax.jit(jax.vmap(solver.problem.evaluate, in_axes=(0, None)))
    for b, solution in enumerate(solutions):
        model = jax.tree.map(lambda a: a[b], batch)
        f, h, g, grad, jac_h, jac_g = central_differences(evaluate, np.asarray(solution.x), model)
        lam_eq, lam_in = solution.multipliers_eq, solution.multipliers_in
        assert np.all(lam_in >= 0)
        stationarity = grad + jac_h.T @ lam_eq + jac_g.T @ lam_in
        assert np.max(np.abs(stationarity)) < KKT_TOLERANCE * np.max(np.abs(grad))
        assert np.max(np.abs(lam_in * g)) < 1e-6  # complementarity


def test_a_batch_larger_than_memory_is_solved_in_lanes_that_fit():
    problem = nlp.ConstrainedProblem(hs071)
    compiled = interior_point.compile_problem(problem)
    starts, targets = np.tile([1.0, 5.0, 5.0, 1.0], (5, 1)), jnp.asarray([40.0, 38.0, 42.0, 41.0, 39.0])
    whole = interior_point.solve(problem, starts, targets, compiled=compiled)
    needed = interior_point.program_memory(compiled, ed.dense_structure(4, 10), jnp.asarray(starts), targets,
                               (jnp.zeros((5, 1)), jnp.zeros((5, 9))))
    assert needed > 0
    assert list(compiled.memory.values()) == [needed]  # asked once per batch shape, not once per solve
    said = []
    pooled = interior_point.solve(problem, starts, targets, compiled=compiled, memory_budget=0.5 * needed,
                                  say=said.append)
    assert len(said) == 1 and "at a time, each lane taking the next problem" in said[0], said
    assert pooled.status == whole.status and pooled.x.shape == (5, 4)
    np.testing.assert_allclose(pooled.x, whole.x, atol=1e-10)
    np.testing.assert_allclose(pooled.multipliers_in, whole.multipliers_in, atol=1e-9)
    with pytest.raises(MemoryError, match="one problem's program needs about"):
        interior_point.solve(problem, starts, targets, compiled=compiled, memory_budget=1.0)


def test_a_lane_whose_problem_finishes_takes_the_next_one():
    """Four HS071 problems, one far start (14 iterations) and three at the optimum (5 each), in two
    lanes: the far one keeps its lane while the other lane solves the three in turn, so the batch takes
    max(14, 5 + 5 + 5) iterations of its program instead of 14 + 5 (two batches of two one after
    another, or a batch of four waiting for its slowest); every problem's result is the one it has when
    the four run at once, and the lanes share one program."""
    optimum = [1.0, 4.74299964, 3.82114998, 1.37940829]
    starts = jnp.array([[3.0, 0.5, 4.8, 4.5], optimum, optimum, optimum])
    compiled = interior_point.compile_problem(nlp.ConstrainedProblem(hs071))
    options = interior_point.InteriorPointOptions(block=1, mu_initial=1e-6)
    together = interior_point.solve(compiled.problem, starts, jnp.full(4, 40.0), options, compiled=compiled)
    steps = []
    pooled = interior_point.solve(compiled.problem, starts, jnp.full(4, 40.0),
                                  dataclasses.replace(options, lanes=2), compiled=compiled,
                                  progress=lambda step, row: steps.append((step, int(row["done"].sum()))))
    its = together.outer_iterations
    assert its[0] > its[1] + 5 and pooled.status == together.status == ["converged"] * 4
    np.testing.assert_array_equal(pooled.outer_iterations, its)
    np.testing.assert_allclose(pooled.x, together.x, atol=1e-12)
    np.testing.assert_allclose(pooled.multipliers_eq, together.multipliers_eq, atol=1e-10)
    assert steps[-1] == (max(its[0], its[1] + its[2] + its[3]), 4)
    assert len(pooled.history) == max(its)  # one row per block of each problem's own iterations
    np.testing.assert_allclose(pooled.history[-1]["cost"], together.cost, rtol=1e-12)
    assert compiled.block._cache_size() == 2 and compiled.initial._cache_size() == 2  # four lanes, two
    with pytest.raises(ValueError, match="lanes must be a positive integer or None, got 0"):
        interior_point.InteriorPointOptions(lanes=0)


def test_the_smallest_power_limit_is_a_kkt_point_of_the_epigraph_form(interior_gaits):
    """From M2's and M4's optima at their own limits (the study's cold epigraph form stopped infeasible on
    both), the continuation (J's weight beside the limit down to 0) ends at KKT points of min t s.t.
    every constraint at M_W = t M_W0, checked with central differences
    of the limit problem: stationarity with the solver's multipliers, z >= 0, complementarity; the limit
    is the gait's own peak power on the solve grid (tight), far below the model's own."""
    import dataclasses
    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait.solver import stack_tree
    from biped_jax.studies import paper as study
    solver, models, solutions = interior_gaits
    picked = [1, 3]  # M2, M4
    solutions, models = [solutions[b] for b in picked], [models[b] for b in picked]
    power = solver.using(dataclasses.replace(study.IP_OPTIONS, max_iterations=150))
    minima = power.minimise_power_limit([s.name for s in solutions], models, np.stack([s.x for s in solutions]))
    assert [m.status for m in minima] == ["converged"] * 2, [(m.status, m.max_violation) for m in minima]
    batch = stack_tree(models)
    evaluate = jax.jit(jax.vmap(power.limit_problem.evaluate, in_axes=(0, None)))
    for b, (own, minimum) in enumerate(zip(solutions, minima)):
        model = jax.tree.map(lambda a: a[b], batch)
        own_limit = float(model.power_limit)
        t = minimum.refinement["solve_grid_limit_W"] / own_limit
        peak = float(np.max(np.abs(minimum.trajectory.joint_power)))
        assert peak == pytest.approx(t * own_limit, rel=1e-6)  # the limit is tight
        assert peak < 0.5 * float(np.max(np.abs(own.trajectory.joint_power)))
        point = np.concatenate([minimum.x, [t]])
        f, h, g, grad, jac_h, jac_g = central_differences(evaluate, point, gait_problem.LimitParams(model,
                                                                                                    np.asarray(0.0)))
        lam_eq, lam_in = minimum.multipliers_eq, minimum.multipliers_in
        assert f == pytest.approx(t) and np.max(np.abs(h)) < 1e-6 and np.max(g) < 1e-6
        assert np.all(lam_in >= 0)
        stationarity = grad + jac_h.T @ lam_eq + jac_g.T @ lam_in
        assert np.max(np.abs(stationarity)) < KKT_TOLERANCE * 1e2, np.max(np.abs(stationarity))
        assert np.max(np.abs(lam_in * g)) < 1e-6  # complementarity


def test_a_free_step_length_reaches_the_fixed_step_optimum_at_its_length(interior_gaits):
    """The step length as a decision variable (the problem in (x, l), J / l minimised): from M2's and M4's
    optima at 0.2 m (one per mass class; a batch of two, the library's program for two speeds) it
    converges inside its bounds, cheaper per metre than the 0.2 m step; the fixed-length problem solved
    at the length found has the same J (one solve of the step length is the optimum over the length),
    and solved 3 % shorter and longer it costs more per metre (a minimum over L, checked with re-solved
    optima, not with the free problem's derivatives)."""
    solver, models, solutions = interior_gaits
    bounds = (0.08, 0.3)
    pair = [1, 3]
    free = solver.solve_step_length([solutions[b].name for b in pair], [models[b] for b in pair], bounds,
                                    x0=np.stack([solutions[b].x for b in pair]))
    assert [s.status for s in free] == ["converged"] * 2, [(s.status, s.max_violation) for s in free]
    for b, found in zip(pair, free):
        assert bounds[0] * 1.05 < found.step_length_m < bounds[1] / 1.05  # the optimum is inside the bounds
        assert found.energy_per_metre < solutions[b].energy_per_metre
        assert found.step_time_s == pytest.approx(found.step_length_m / solutions[b].speed_mps)
    # one batch of four fixed-length problems (the program the gaits were solved with): M2 and M4 at the
    # length found, M2 3 % shorter and longer
    picked = [0, 1, 0, 0]
    factors = [1.0, 1.0, 0.97, 1.03]
    fixed = solver.solve(["M2", "M4", "M2 shorter", "M2 longer"],
                         [dataclasses.replace(models[pair[b]], step_length=np.asarray(f * free[b].step_length_m))
                          for b, f in zip(picked, factors)], x0=np.stack([free[b].x for b in picked]))
    assert [s.status for s in fixed] == ["converged"] * 4, [(s.status, s.max_violation) for s in fixed]
    np.testing.assert_allclose([s.cost for s in fixed[:2]], [free[0].cost, free[1].cost], rtol=1e-6)
    assert min(fixed[2].energy_per_metre, fixed[3].energy_per_metre) > free[0].energy_per_metre * (1 + 1e-6)


def test_more_knots_only_where_the_space_check_asks(interior_gaits):
    """``refine_spaces``: every gait into the first finer space, then only those it left "space
    dependent" (estimate |J - J_finer| / (factor - 1) / J_finer above 1 %), or grid dependent on the
    power limit alone (held by solving again only in the last stage), into the next; each gait's
    record lists every space it was solved in. The stages' solves are stand-ins with set optima (the
    real solve is the library test's), the projections and verdicts the real ones."""
    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait import spaces
    solver, models, solutions = interior_gaits
    # the relative change of J in each stage's space: M1 passes at once, M2 in the second, M3 never; M4
    # passes at once but its power rises above the limit between the first stage's samples (untightened)
    changes = {8: {"M1": -0.004, "M2": -0.05, "M3": -0.05, "M4": -0.001},
               16: {"M2": -0.004, "M3": -0.02, "M4": -0.001}}
    calls = []

    class Stage:
        def __init__(self, spans):
            self.settings = dataclasses.replace(solver.settings, spans=spans, segments=spans)

        def solve(self, names, models_, x0, progress=None, tightening=None):
            calls.append((self.settings.spans, list(names), tightening))
            assert x0.shape == (len(names), self.settings.size)
            given = {s.name: s for s in solutions}
            # J in this space: the given J with every stage's change up to this one
            factor = {n: np.prod([1 + c[n] for spans, c in changes.items() if spans <= self.settings.spans])
                      for n in names}
            converged = {"status": "converged", "refinement": {"passed": True, "failed": []}}
            power = {"status": "grid dependent", "refinement": {"passed": False, "failed": ["power_limit"]}}
            return [dataclasses.replace(given[n], x=np.asarray(x), space={}, cost=given[n].cost * factor[n],
                                        **(power if n == "M4" and tightening == 0 else converged))
                    for n, x in zip(names, x0)]

    stages = [Stage(8), Stage(16)]
    out = spaces.refine_spaces(stages, solver, [s.name for s in solutions], models,
                               [dataclasses.replace(s, space={}) for s in solutions])
    # only the last stage holds the power limit by solving again; M4 goes on to it for its power alone
    assert calls == [(8, ["M1", "M2", "M3", "M4"], 0), (16, ["M2", "M3", "M4"], None)]
    assert [s.status for s in out] == ["converged", "converged", spaces.SPACE_DEPENDENT, "converged"]
    assert [s.space["spans"] for s in out] == [[4, 8], [4, 8, 16], [4, 8, 16], [4, 8, 16]]
    for s, given in zip(out, solutions):
        assert s.space["cost"][0] == given.cost and s.space["cost"][-1] == s.cost
        assert s.space["error_estimate"] == pytest.approx(abs(s.space["cost"][-2] - s.cost) / s.cost)
        assert s.x.shape == (gait_problem.GaitSettings(spans=s.space["spans"][-1], substeps=4).size,)


def test_a_gait_library_over_speeds_and_step_lengths(interior_gaits, tmp_path):
    """``biped-jax library``'s study on a 2 x 2 grid in the tests' space (4 knot spans) with its space
    check in 8: every point converged in 4 spans and reached an optimum in 8, cheaper there (the finer
    space holds the coarser gait), so much cheaper (4-19 %) that the space check calls every point
    "space dependent" with its estimated error |J4 - J8| / (2 - 1) / J8; each gait's drive demand
    within the problem's limits (peak power at most M_W, RMS torque at most the peak); the optimal step
    length at each speed inside the grid's lengths and no dearer per metre than any grid point at that
    speed; the files' arrays equal to the JSON; a point that did not converge restarts from its nearest
    converged neighbour."""
    from biped_jax.gait import spaces
    from biped_jax.report import outputs
    from biped_jax.studies import library
    solver = interior_gaits[0]
    grid = library.LibraryGrid("12kg", (0.45, 0.6), (0.15, 0.2), 20.0)
    # one start family in the solver's own space: the gait tests' program (a batch of four)
    family = library.LIBRARY_FAMILIES[0]
    finer = spaces.finer_solver(solver, 2)
    record = library.run_library(tmp_path, grid, solver=solver, families=(family,), space_solvers=[finer])
    points = record["points"]
    assert record["space_check"] == {"spans": [8], "tolerance": spaces.SPACE_TOLERANCE, "order": spaces.SPACE_ORDER}
    assert [p["status"] for p in points] == [spaces.SPACE_DEPENDENT] * 4, [p["status"] for p in points]
    assert all(p["started"] == family.name and [s["family"] for s in p["starts"]] == [family.name] for p in points)
    for p in points:
        space = p["space"]
        coarse, fine = space["cost"]
        assert space["spans"] == [4, 8] and space["status_finer"] == "converged" and fine == p["cost"]
        assert 0.75 * coarse < fine < 0.97 * coarse
        assert space["error_estimate"] == pytest.approx((coarse - fine) / fine) and not space["passed"]
        assert max(p["power_peak_W"]) <= 20.0 * (1 + 1e-6) and max(p["torque_peak_Nm"]) <= 20.0 * (1 + 1e-6)
        assert all(rms <= peak for rms, peak in zip(p["torque_rms_Nm"], p["torque_peak_Nm"]))
        assert p["cost_per_metre"] == pytest.approx(p["cost"] / p["step_length_m"])
    for i, best in enumerate(record["optimal_step"]):
        assert best["status"] == spaces.SPACE_DEPENDENT and 0.15 <= best["step_length_m"] <= 0.2
        row = points[2 * i:2 * i + 2]
        assert best["cost_per_metre"] <= min(p["cost_per_metre"] for p in row) * (1 + 1e-7)  # solver tolerance
        assert best["speed_mps"] == pytest.approx(grid.speeds[i]) and best["space"]["spans"] == [4, 8]
    arrays = outputs.read_npz(tmp_path / "library.npz")
    np.testing.assert_allclose(arrays["cost_per_metre"].ravel(), [p["cost_per_metre"] for p in points])
    np.testing.assert_allclose(arrays["space_error_estimate"].ravel(), [p["space"]["error_estimate"] for p in points])
    # every point's gait sampled in time: within its peak torque, reaching most of it between the samples
    assert arrays["gait_q"].shape == (2, 2, library.GAIT_SAMPLES, 5) and arrays["gait_u"].shape[-1] == 4
    peaks = np.abs(arrays["gait_u"]).max(axis=2).reshape(4, 4)
    torque_peak = np.array([p["torque_peak_Nm"] for p in points])
    assert np.all(peaks <= torque_peak * (1 + 1e-9)) and np.all(peaks.max(axis=1) >= 0.8 * torque_peak.max(axis=1))
    np.testing.assert_allclose(arrays["optimal_step_length_m"], [b["step_length_m"] for b in record["optimal_step"]])
    assert np.all(arrays["family_index"] == 0)
    assert (tmp_path / "library_map.png").stat().st_size > 0 and (tmp_path / "library_drives.png").stat().st_size > 0
    converged = np.array([True, False, False, True])
    assert library._nearest_converged(1, converged, (2, 2)) == 0
    assert library._nearest_converged(2, converged, (2, 2)) == 0
    assert library._nearest_converged(2, np.array([False, False, False, True]), (2, 2)) == 3
    assert library._nearest_converged(0, np.zeros(4, bool), (2, 2)) is None
    # on a drive: the fastest speed whose optimal step passes the thermal check, bracketed by the grid
    rows = [{"speed_mps": v, "status": status, "drive_check": {"walk_time_s": walk}} for v, status, walk in
            ((0.2, "converged", None), (0.3, "converged", None), (0.4, "converged", 300.0),
             (0.5, "iteration limit", None), (0.6, "converged", 60.0))]
    assert library.indefinite_walk(rows + [None]) == {"speeds_mps": [0.2, 0.3], "up_to_mps": 0.3, "not_at_mps": 0.4}
    assert library.indefinite_walk(rows[2:]) == {"speeds_mps": [], "up_to_mps": None, "not_at_mps": 0.4}


def test_the_fastest_gaits_are_kkt_points_of_max_speed(interior_gaits, tmp_path):
    """``biped-jax top-speed``'s study in the tests' space: from a slow start (0.3 m/s) the continuation
    (J's weight beside the pace down to 0) ends at KKT points of max v over (gait, step length, speed),
    checked with central differences of that problem: stationarity with the solver's multipliers,
    z >= 0, complementarity, for ideal drives at 10 and 20 W (12 kg) and 20 W (18 kg) and for a
    catalogue drive (voltage limit, no power limit), at the limit posed on the solve grid (lowered by
    the excess between its points where the 4x grid fails on the power limit alone); more power is
    faster and so is less mass; the drive's gait keeps its supply voltage by the catalogue check's own
    arithmetic where the gait's smooth efficiency switch equals it; the energy problem posed at the
    speed and step length found converges from that gait; the JSON holds the record."""
    import json

    from biped_jax.gait import problem as gait_problem
    from biped_jax.gait.solver import stack_tree
    from biped_jax.studies import paper as study
    from biped_jax.studies import top_speed
    solver = interior_gaits[0]
    fast = solver.using(dataclasses.replace(study.IP_OPTIONS, max_iterations=150))
    bounds = (0.08, 0.3)
    chosen = [top_speed.TopSpeedProblem("12kg", power_limit=10.0), top_speed.TopSpeedProblem("12kg", power_limit=20.0),
              top_speed.TopSpeedProblem("18kg", power_limit=20.0),
              top_speed.TopSpeedProblem("12kg", drive=("RE25-42V", "GP32A-66.22"))]
    # the rounds run although the short space's check is not required
    starts, found = top_speed.solve_top_speeds(fast, chosen, bounds, tightening=3)
    fastest = [found.get(b) for b in range(len(chosen))]
    assert [s and s.status for s in fastest] == ["converged"] * 4, [(s.status, s.max_violation) for s in starts]
    models = [p.model() for p in chosen]
    batch = stack_tree(models)
    evaluate = jax.jit(jax.vmap(fast.speed_problem.evaluate, in_axes=(0, None)))
    for b, found_b in enumerate(fastest):
        assert found_b.speed_mps > 1.2 * top_speed.START_SPEED
        # the limit the last round posed on the solve grid: lowered by the excess between its points where
        # the 4x grid failed on the power limit alone (at 4 knot spans other groups fail there too)
        posed = found_b.refinement["solve_grid_power_limit_W"]
        assert posed <= found_b.power_limit_W
        if found_b.refinement["failed"] == ["power_limit"]:
            assert posed < found_b.power_limit_W, found_b.refinement
        model = dataclasses.replace(jax.tree.map(lambda a: a[b], batch), power_limit=np.asarray(posed))
        extra = [found_b.step_length_m / float(model.step_length), float(model.speed) / found_b.speed_mps]
        params = gait_problem.SpeedParams(model, np.asarray(bounds[0] / 0.2), np.asarray(bounds[1] / 0.2),
                                          np.asarray(0.0))
        f, h, g, grad, jac_h, jac_g = central_differences(evaluate, np.concatenate([found_b.x, extra]), params)
        lam_eq, lam_in = found_b.multipliers_eq, found_b.multipliers_in
        assert f == pytest.approx(extra[1]) and np.max(np.abs(h)) < 1e-6 and np.max(g) < 1e-6
        assert np.all(lam_in >= 0)
        stationarity = grad + jac_h.T @ lam_eq + jac_g.T @ lam_in
        assert np.max(np.abs(stationarity)) < KKT_TOLERANCE * 1e2, (b, np.max(np.abs(stationarity)))
        assert np.max(np.abs(lam_in * g)) < 1e-6  # complementarity
    v = [s.speed_mps for s in fastest]
    assert v[0] < v[1] and v[2] < v[1], v
    at_speed = [dataclasses.replace(m, step_length=np.asarray(s.step_length_m), speed=np.asarray(s.speed_mps))
                for m, s in zip(models, fastest)]
    again = solver.solve([s.name for s in fastest], at_speed, x0=np.stack([s.x for s in fastest]))
    assert [s.status for s in again] == ["converged"] * 4, [(s.status, s.max_violation) for s in again]
    # the drive's gait under its speed-torque line by the catalogue check's arithmetic (the exact switch
    # of the gear's efficiency) where the gait's smooth switch equals it, |T omega| >= 5 W (tanh(5) = 1 -
    # 1e-4); within the 1 W blend the two differ by up to T / N (1 / eta - eta) / 2 at the motor
    from biped_jax.drives import model as drive_model
    catalogue = drive_model.load_catalogue()
    motor, gear = catalogue.motor("RE25-42V"), catalogue.gearhead("GP32A-66.22")
    torque, speed = np.asarray(fastest[3].trajectory.u), np.asarray(fastest[3].trajectory.joint_speed)
    margin = np.asarray(drive_model.voltage_margin(
        drive_model.motor_torque(torque, speed, gear.ratio, gear.efficiency),
        drive_model.motor_speed(speed, gear.ratio), motor, float(models[3].drives.supply_voltage)))
    outside_blend = np.abs(torque * speed) >= 5.0
    assert outside_blend.sum() > 10 and margin[outside_blend].min() >= -1e-3, margin[outside_blend].min()
    record = top_speed.write_top_speed(tmp_path, fast, chosen, starts, found, bounds)
    assert "drive_check" in record["problems"][3] and "drive_check" not in record["problems"][0]
    assert json.loads((tmp_path / "top_speed.json").read_text())["problems"][1]["top_speed_mps"] == v[1]
    assert (tmp_path / "top_speed.png").stat().st_size > 0
