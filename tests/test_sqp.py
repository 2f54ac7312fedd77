"""SLSQP on a ConstrainedProblem (biped_jax.optim.sqp): known optima, multipliers in our sign convention,
infeasibility named, and on the gait: the same optimum from different start families."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from biped_jax.codesign import problem as codesign
from biped_jax.gait import problem as gait
from biped_jax.gait.solver import GaitSolver
from biped_jax.optim import nlp
from biped_jax.optim import coloured
from biped_jax.optim import limit_minimisation
from biped_jax.optim import sqp


def _projection_problem():
    """min |x - p|^2 s.t. x0 + x1 = 1, x0 >= 0.8 (as 0.8 - x0 <= 0): the nearest point of a ray."""
    return nlp.ConstrainedProblem.from_functions(
        lambda x, p: jnp.sum((x - p) ** 2), lambda x, p: jnp.array([x[0] + x[1] - 1.0]),
        lambda x, p: jnp.array([0.8 - x[0]]))


def test_known_optima_and_multipliers_of_a_batch():
    points = jnp.array([[1.0, 2.0], [3.0, 0.0]])
    result = sqp.solve(_projection_problem(), jnp.zeros((2, 2)), points)
    # the projection of (1, 2) onto x0 + x1 = 1 is (0, 1), cut by x0 >= 0.8: (0.8, 0.2), bound active;
    # (3, 0) projects to (2, -1) with the bound inactive
    np.testing.assert_allclose(result.x, [[0.8, 0.2], [2.0, -1.0]], atol=1e-7)
    assert result.status == [nlp.CONVERGED, nlp.CONVERGED]
    # KKT in our convention, grad f + lam_eq grad h + lam_in grad g = 0 with lam_in >= 0:
    # case 1: 2(x - p) = (-0.4, -3.6) = -lam_eq (1, 1) - lam_in (-1, 0) -> lam_eq = 3.6, lam_in = 3.2
    np.testing.assert_allclose(result.multipliers_eq[:, 0], [3.6, 2.0], atol=1e-6)
    np.testing.assert_allclose(result.multipliers_in[:, 0], [3.2, 0.0], atol=1e-6)
    assert np.all(result.stationarity < 1e-6)
    # one history row per iteration, the problem that finished first holding its values
    assert result.history[-1]["cost"] == pytest.approx(result.cost)
    assert len(result.history) == max(result.outer_iterations) + 1


def test_an_infeasible_problem_is_named_infeasible():
    problem = nlp.ConstrainedProblem.from_functions(
        lambda x, p: jnp.sum(x**2), lambda x, p: jnp.array([x[0]]), lambda x, p: jnp.array([p - x[0]]))
    result = sqp.solve(problem, jnp.ones((1, 2)), jnp.array([1.0]))
    assert result.status == [nlp.INFEASIBLE] and result.violation[0] >= 0.1


def test_a_solve_ended_infeasible_returns_its_cheapest_feasible_iterate():
    """min -2 x0 s.t. x0^2 <= 1 from 0: SLSQP's first step overshoots to x0 = 2 (infeasible). Stopped
    there, the result is the last feasible point (the start, an upper bound, `iteration limit`), not
    the infeasible iterate; given iterations it converges to x0 = 1."""
    problem = nlp.ConstrainedProblem(lambda x, p: (-2.0 * x[0] + 0.0 * x[1] ** 2, jnp.zeros(0),
                                                  jnp.array([x[0] ** 2 - 1.0])))
    short = sqp.solve(problem, np.zeros((1, 2)), jnp.zeros(1), sqp.SQPOptions(max_iterations=3))
    assert short.status == [nlp.ITERATION_LIMIT] and short.violation[0] == 0.0
    np.testing.assert_allclose(short.x[0], [0.0, 0.0])
    assert short.history[-1]["violation"][0] > 0.1  # SLSQP itself ended infeasible
    full = sqp.solve(problem, np.zeros((1, 2)), jnp.zeros(1), sqp.SQPOptions(max_iterations=50))
    assert full.status == [nlp.CONVERGED]
    np.testing.assert_allclose(full.x[0, 0], 1.0, atol=1e-6)


def _shared_load_problem():
    """min |x - (2, 2)|^2 s.t. x0 + x1 = 3, x_i <= L (params["limit"]): the limit enters linearly."""
    return nlp.ConstrainedProblem.from_residuals(
        lambda x, p: (x - 2.0, jnp.array([x[0] + x[1] - 3.0]), x - p["limit"]))


def test_the_smallest_limit_on_the_problems_own_compiled_functions():
    """LimitMinimisation: min t s.t. x0 + x1 = 3, x_i <= t L0 has t = 1.5 / L0 (the load shared
    evenly); its derivatives equal the explicit epigraph problem's, and an iterate infeasible only on
    the limit is lifted to the smallest t that holds it."""
    compiled = coloured.compile_problem(_shared_load_problem())
    limit = limit_minimisation.LimitMinimisation(compiled, lambda p, t: {"limit": p["limit"] * t})
    params = {"limit": jnp.array([3.0, 6.0])}
    result = sqp.solve(_shared_load_problem(), np.array([[1.0, 2.0, 1.0], [1.0, 2.0, 1.0]]), params,
                       compiled=limit)
    assert result.status == [nlp.CONVERGED, nlp.CONVERGED]
    np.testing.assert_allclose(result.x, [[1.5, 1.5, 0.5], [1.5, 1.5, 0.25]], atol=1e-7)

    epigraph = jax.jacfwd(lambda z: jnp.concatenate([z[:2] - 3.0 * z[2], jnp.array([z[0] + z[1] - 3.0])]))
    point, one = np.array([0.3, 2.1, 0.7]), {"limit": jnp.asarray(3.0)}
    f, h, g, grad, jac_h, jac_g, jac_r = limit.derivatives(point, one)
    expected = np.asarray(epigraph(jnp.asarray(point)))
    np.testing.assert_allclose(jac_g, expected[:2], atol=1e-8)
    np.testing.assert_allclose(jac_h, expected[2:], atol=1e-8)
    np.testing.assert_allclose(grad, [0.0, 0.0, 1.0])
    assert f == pytest.approx(0.7)
    assert jac_r.shape == (0, 3)
    # (2, 1) at t = 0.5 (limit 1.5): x0 is 0.5 over; lifted to t = 2 / 3, x0 exactly at the limit
    at = np.array([2.0, 1.0, 0.5])
    f, h, g = limit.value(at, one)
    (x_lifted, f_lifted) = limit.lifted(at, f, np.asarray(h), np.asarray(g), 1e-5)
    np.testing.assert_allclose(x_lifted, [2.0, 1.0, 2.0 / 3.0])
    assert f_lifted == pytest.approx(2.0 / 3.0)
    # infeasible off the limit (x0 + x1 = 4): no lift
    assert limit.lifted(np.array([3.0, 1.0, 2.0]), 2.0, np.array([1.0]), np.array([-3.0, -5.0]), 1e-5) is None


def test_a_working_set_of_rows_ends_at_the_full_problems_optimum():
    """min |x - (3, 3)|^2 s.t. x0 <= 1, x1 <= 2, x0 + x1 <= 10, from 0 with a working margin of 1.5:
    SLSQP first sees x0 <= 1 only (the others start 2 and 10 away) and ends at (1, 3), which breaks
    x1 <= 2; that row joins and it goes on to (1, 2), the full problem's optimum with its multipliers
    (4, 2, 0: zero on the row never seen). The limit minimisation's rows on the limit are seen however
    far from active they start."""
    problem = nlp.ConstrainedProblem.from_functions(
        lambda x, p: jnp.sum((x - p) ** 2), lambda x, p: jnp.zeros(0),
        lambda x, p: jnp.array([x[0] - 1.0, x[1] - 2.0, x[0] + x[1] - 10.0]))
    options = sqp.SQPOptions(working_margin=1.5)
    assert list(sqp.working_rows(np.array([-1.0, -2.0, -10.0]), 1.5)) == [0]
    screened = sqp.solve(problem, np.zeros((1, 2)), jnp.array([[3.0, 3.0]]), options)
    full = sqp.solve(problem, np.zeros((1, 2)), jnp.array([[3.0, 3.0]]))
    assert screened.status == full.status == [nlp.CONVERGED]
    np.testing.assert_allclose(screened.x, [[1.0, 2.0]], atol=1e-7)
    np.testing.assert_allclose(screened.multipliers_in, [[4.0, 2.0, 0.0]], atol=1e-6)
    np.testing.assert_allclose(full.multipliers_in, screened.multipliers_in, atol=1e-6)

    compiled = coloured.compile_problem(_shared_load_problem())
    limit = limit_minimisation.LimitMinimisation(compiled, lambda p, t: {"limit": p["limit"] * t})
    far = {"limit": jnp.array([6.0])}  # x_i - 6 t at (1, 2), t = 1: -5 and -4, outside the margin
    assert list(limit.always_seen(np.array([1.0, 2.0, 1.0]), {"limit": jnp.asarray(6.0)})) == [True, True]
    result = sqp.solve(_shared_load_problem(), np.array([[1.0, 2.0, 1.0]]), far, options, compiled=limit)
    assert result.status == [nlp.CONVERGED]
    np.testing.assert_allclose(result.x, [[1.5, 1.5, 0.25]], atol=1e-7)


def _banded_problem(with_residuals: bool):
    """Outputs local in x (residual i reaches x_i and x_i+1) but for one equality coupling the ends:
    two colours whatever the size (odd and even columns), three with an objective reaching x_0..x_2."""
    def residuals(x, p):
        return x[:-1] ** 2 - p * x[1:], jnp.array([x[0] + x[-1] - 1.0]), jnp.sin(x[::2])
    if with_residuals:
        return nlp.ConstrainedProblem.from_residuals(residuals)
    return nlp.ConstrainedProblem(lambda x, p: (jnp.sum(x[:3] ** 3), *residuals(x, p)[1:]))


@pytest.mark.parametrize("with_residuals", [True, False])
def test_coloured_differences_equal_the_exact_jacobian(with_residuals):
    """Columns reaching no output in common are differenced together (the Jacobian's sparsity probed
    once): 2 or 3 colours for 12 columns (padded to 8: 17 rollouts, not 25), every derivative equal to
    forward-mode autodiff's to the differences' accuracy, at a point far from the probe's."""
    problem = _banded_problem(with_residuals)
    compiled = coloured.compile_problem(problem)
    x0, params = jnp.linspace(0.2, 1.3, 12), 0.7
    compiled.derivatives(x0, params)  # probes the pattern here
    directions, colour, _ = compiled.colouring
    assert int(colour.max()) + 1 == (2 if with_residuals else 3) and directions.shape == (coloured.COLOUR_PADDING, 12)
    x = x0 + jnp.asarray(np.random.default_rng(3).uniform(-0.5, 0.5, 12))
    f, h, g, grad, jac_h, jac_g, jac_r = compiled.derivatives(x, params)
    exact = jax.jacfwd(lambda y: problem.evaluate(y, params))(x)
    for found, want in zip((grad, jac_h, jac_g), exact):
        np.testing.assert_allclose(found, want, rtol=1e-7, atol=1e-9)
    if with_residuals:
        exact_r = jax.jacfwd(lambda y: problem.residuals(y, params)[0])(x)
        np.testing.assert_allclose(jac_r, exact_r, rtol=1e-7, atol=1e-9)


@pytest.mark.slow
def test_gait_derivatives_coloured_equal_dense():
    """The gait problem in 8 knot spans (8 shooting segments), with a catalogue motor's drives (the
    voltage rows and the Joule objective): the coloured central differences, probed on one design at
    its heuristic start, equal the dense ones (every column differenced alone, one point at a time
    through the single-point program) at another point and on another design to rounding, and need
    half the rollouts or fewer (a quarter in the study's 32 spans)."""
    settings = gait.GaitSettings(spans=8, segments=8, substeps=2)
    solver = GaitSolver(settings, check_refinement=False)
    models = [codesign.gait_model(codesign.catalogue_design(), 0.555, 20.0),
              codesign.gait_model(codesign.catalogue_design(mass_class="18kg"), 0.417, 25.0)]
    params = [jax.tree.map(lambda a: jnp.asarray(a, float), m) for m in models]
    x0 = gait.initial_guess(models[0], settings, solver.leg_length)
    differences = coloured.compile_problem(solver.problem)
    differences.derivatives(x0, params[0])
    colours = int(differences.colouring[1].max()) + 1
    assert colours <= settings.size // 2, colours
    x = np.asarray(x0) + 1e-2 * np.random.default_rng(4).standard_normal(settings.size)
    steps = sqp.SQPOptions.step * np.maximum(1.0, np.abs(x))

    def outputs(point, p):  # (f, h, g, r) as numpy, from the single-point program
        return [np.atleast_1d(np.asarray(a)) for a in differences._outputs(jnp.asarray(point), p)]
    for p in params:
        found = differences.derivatives(jnp.asarray(x), p)
        columns = [[(a - b) / (2 * h) for a, b in zip(outputs(x + h * e, p), outputs(x - h * e, p))]
                   for h, e in zip(steps, np.eye(x.size))]
        dense = [np.stack([column[k] for column in columns], axis=-1) for k in range(4)]  # f, h, g, r: (m, n)
        for k, want in ((4, dense[1]), (5, dense[2]), (6, dense[3])):  # the Jacobians of h, g and r
            np.testing.assert_allclose(found[k], want, rtol=0, atol=1e-8 * max(float(np.max(np.abs(want))), 1.0))
        # grad f: 2 J_r^T r beside f's own central difference (different truncation errors)
        np.testing.assert_allclose(found[3], dense[0][0], rtol=0, atol=1e-6 * float(np.max(np.abs(dense[0]))))


@pytest.mark.slow
def test_gait_solutions_are_kkt_points_and_fixed_points():
    """M2 at 20 W in a 2-span space from a straight-stance and a flexed-impact start: both end at KKT
    points (feasible in every group in its own unit, |grad f + J^T lambda| small with SLSQP's
    multipliers), and solving again from the cheaper one stays there (the augmented Lagrangian, started
    at the study's M2 optimum, left it for a 63 % dearer one: README "Solvers")."""
    settings = gait.GaitSettings(spans=2, substeps=4, segments=2)
    model = gait.gait_model("12kg", 0.555, 20.0)
    solver = GaitSolver(settings, require_refinement=False).using(sqp.SQPOptions(max_iterations=300))
    families = (gait.START_FAMILIES[0], gait.IMPACT_FAMILIES[1])
    x0 = jnp.stack([gait.initial_guess(model, settings, solver.leg_length, family=f) for f in families])
    solutions = solver.solve(["straight", "flexed impact"], [model, model], x0=x0)
    for solution in solutions:
        assert solution.status == nlp.CONVERGED, (solution.status, solution.violations)
        assert solution.max_violation <= 1e-4 and solution.stationarity <= 1e-3
        assert np.all(solution.multipliers_in >= 0)
    best = min(solutions, key=lambda s: s.cost)
    again, = solver.solve(["again"], [model], x0=jnp.asarray(best.x)[None])
    assert again.status == nlp.CONVERGED
    assert again.cost == pytest.approx(best.cost, rel=1e-6)
    assert again.outer_iterations <= 5

    # the smallest power limit from the cheaper gait: SLSQP on (x, M_W) minimising M_W
    minimum, = solver.minimise_power_limit(["smallest"], [model], best.x[None])
    assert minimum.status == nlp.CONVERGED, (minimum.status, minimum.violations)
    assert minimum.stationarity <= 1e-3  # a KKT point of min M_W: the limit is locally smallest
    solve_grid = minimum.refinement["solve_grid_limit_W"]
    assert solve_grid < 0.9 * 20.0
    peak = np.max(np.abs(minimum.trajectory.joint_power))
    assert peak == pytest.approx(solve_grid, rel=1e-3)  # the limit binds (else it was not the smallest)
    # the reported limit is one the gait keeps on the finer grid too
    assert minimum.power_limit_W >= solve_grid
    assert minimum.refinement["violations"]["power_limit"] <= 1e-6
    assert minimum.cost == pytest.approx(float(gait.cost(minimum.trajectory)), rel=1e-9)

