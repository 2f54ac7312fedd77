"""The augmented-Lagrangian solver finds the known optima of small problems, in batches, and says
so when a problem is infeasible or diverges."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from biped_jax.optim import augmented_lagrangian as al

from biped_jax.optim import nlp

OPTIONS = al.SolverOptions(tolerance=1e-8, stationarity=1e-6)
# The solver stops at scaled violation 1e-8 and stationarity 1e-6: solutions agree to about 1e-6.
SOLUTION_TOLERANCE = 1e-5


def test_equality_constrained_qp_batch_matches_the_kkt_solution():
    """min 1/2 x'Qx + c'x  s.t.  Ax = b, three right-hand sides solved in one batch."""
    q = jnp.array([[4.0, 1.0, 0.0], [1.0, 3.0, 0.5], [0.0, 0.5, 2.0]])
    c = jnp.array([1.0, -2.0, 0.5])
    a = jnp.array([[1.0, 1.0, 1.0], [1.0, -1.0, 2.0]])
    rhs = jnp.array([[1.0, 0.0], [2.0, 1.0], [-1.0, 3.0]])
    problem = nlp.ConstrainedProblem.from_functions(objective=lambda x, b: 0.5 * x @ q @ x + c @ x,
                                    equalities=lambda x, b: a @ x - b,
                                    inequalities=lambda x, b: jnp.zeros(0))
    result = al.solve(problem, jnp.zeros((3, 3)), rhs, OPTIONS)
    for k in range(3):
        kkt = np.block([[q, a.T], [a, np.zeros((2, 2))]])
        expected = np.linalg.solve(kkt, np.concatenate([-c, rhs[k]]))[:3]
        np.testing.assert_allclose(result.x[k], expected, atol=SOLUTION_TOLERANCE)
        assert result.status[k] == nlp.CONVERGED


@pytest.mark.parametrize("preconditioned", [False, True])
def test_inequality_constrained_qp_with_active_and_inactive_constraints(preconditioned):
    """min (x-p1)^2 + (y-p2)^2  s.t.  x + y <= 1, x >= 0: projection onto a half-plane; with and
    without the Gauss-Newton preconditioner (the objective is a sum of squares)."""
    def residuals(x, p):
        return x - p, jnp.zeros(0), jnp.array([x[0] + x[1] - 1.0, -x[0]])
    problem = (nlp.ConstrainedProblem.from_residuals(residuals) if preconditioned else
               nlp.ConstrainedProblem(lambda x, p: (lambda r, h, g: (r @ r, h, g))(*residuals(x, p))))
    targets = jnp.array([[1.0, 1.0], [0.2, 0.3], [-1.0, 3.0]])
    result = al.solve(problem, jnp.zeros((3, 2)), targets, OPTIONS)
    # (1,1) -> (0.5, 0.5); (0.2, 0.3) is feasible; (-1, 3) -> x = 0 and y = 1 (corner)
    np.testing.assert_allclose(result.x, [[0.5, 0.5], [0.2, 0.3], [0.0, 1.0]], atol=SOLUTION_TOLERANCE)
    np.testing.assert_allclose(result.cost, [0.5, 0.0, 5.0], atol=SOLUTION_TOLERANCE)
    assert result.status == [nlp.CONVERGED] * 3


@pytest.mark.parametrize("preconditioned", [False, True])
def test_double_integrator_minimum_effort_transfer(preconditioned):
    """x'' = u, (x, v): (0, 0) -> (1, 0) in 1 s, minimise the integral of u^2: u = 6 - 12 t, J = 12.

    Piecewise-constant u on 40 intervals with exact integration: the discrete optimum is the
    least-norm solution of the two linear end conditions (computed here), and tends to 12."""
    n, dt = 40, 1.0 / 40
    # exact zero-order-hold integration: end position and velocity are linear in u
    t_left = dt * np.arange(n)
    end_velocity = np.full(n, dt)
    end_position = dt * (1.0 - t_left) - dt**2 / 2
    a = np.stack([end_position, end_velocity])
    def residuals(u, p):
        return jnp.sqrt(dt) * u, jnp.asarray(a) @ u - jnp.array([1.0, 0.0]), jnp.zeros(0)
    problem = nlp.ConstrainedProblem.from_residuals(residuals)
    if not preconditioned:
        problem = nlp.ConstrainedProblem(problem.evaluate)
    result = al.solve(problem, jnp.zeros((1, n)), jnp.zeros((1,)), OPTIONS)
    least_norm = a.T @ np.linalg.solve(a @ a.T, [1.0, 0.0])
    np.testing.assert_allclose(result.x[0], least_norm, atol=1e-4)
    assert result.cost[0] == pytest.approx(dt * np.sum(least_norm**2), rel=1e-6)
    assert result.cost[0] == pytest.approx(12.0, rel=2e-3)  # discretisation error O(dt^2)
    np.testing.assert_allclose(result.x[0], 6 - 12 * (t_left + dt / 2), atol=0.02)


def test_infeasible_problem_is_reported_with_its_violation():
    problem = nlp.ConstrainedProblem.from_functions(objective=lambda x, p: jnp.sum(x**2),
                                    equalities=lambda x, p: jnp.zeros(0),
                                    inequalities=lambda x, p: jnp.array([x[0] - (-1.0), 1.0 - x[0]]))
    result = al.solve(problem, jnp.zeros((1, 1)), jnp.zeros((1,)), OPTIONS)
    assert result.status == [nlp.INFEASIBLE]
    assert result.violation[0] == pytest.approx(1.0, abs=1e-3)  # x = 0 splits the two demands


def test_a_tiny_violation_left_at_the_penalty_cap_is_stalled_not_infeasible():
    # x >= 1 and x <= 1 - 2e-5 cannot both hold; the best point misses each by 1e-5 (scaled), far below
    # what would justify calling a real problem infeasible.
    problem = nlp.ConstrainedProblem.from_functions(objective=lambda x, p: jnp.sum(x**2),
                                    equalities=lambda x, p: jnp.zeros(0),
                                    inequalities=lambda x, p: jnp.array([1.0 - x[0], x[0] - (1.0 - 2e-5)]))
    result = al.solve(problem, jnp.zeros((1, 1)), jnp.zeros((1,)), OPTIONS)
    assert result.status == [nlp.STALLED]
    assert result.violation[0] == pytest.approx(1e-5, rel=0.05)


def test_acceptable_termination_needs_feasibility_and_a_settled_cost():
    # stationarity -1 can never be met: only the acceptable rule can end the solve as converged
    problem = nlp.ConstrainedProblem.from_functions(objective=lambda x, p: jnp.sum((x - 2.0) ** 2),
                                    equalities=lambda x, p: jnp.array([x[0] - 1.0]),
                                    inequalities=lambda x, p: jnp.zeros(0))
    strict = dataclasses.replace(OPTIONS, stationarity=-1.0, max_outer=12)
    result = al.solve(problem, jnp.zeros((1, 2)), jnp.zeros((1,)), strict)
    assert result.status == [nlp.ITERATION_LIMIT] and result.outer_iterations[0] == 12
    acceptable = dataclasses.replace(strict, acceptable_change=1e-7, acceptable_iterations=3)
    result = al.solve(problem, jnp.zeros((1, 2)), jnp.zeros((1,)), acceptable)
    assert result.status == [nlp.CONVERGED] and result.outer_iterations[0] < 12
    np.testing.assert_allclose(result.x[0], [1.0, 2.0], atol=1e-6)


def test_nan_is_caught_and_reported_as_diverged():
    problem = nlp.ConstrainedProblem.from_functions(objective=lambda x, p: jnp.sum(x**2) + jnp.log(x[0] - 5.0),
                                    equalities=lambda x, p: jnp.zeros(0),
                                    inequalities=lambda x, p: jnp.zeros(0))
    result = al.solve(problem, jnp.zeros((1, 2)), jnp.zeros((1,)), OPTIONS)
    assert result.status == [nlp.DIVERGED]


def test_central_differences_give_the_exact_gradient_of_a_quadratic_and_solve_like_autodiff():
    """Central differences are exact for quadratics (whatever the step), through the solver's vmap,
    for the objective and every constraint; the solver then finds the same optimum as with autodiff."""
    import jax

    q = jnp.array([[3.0, 1.0], [1.0, 2.0]])

    def evaluate(x, p):
        return 0.5 * x @ q @ x - p @ x, jnp.array([x[0] - 2 * x[1] - 0.5]), jnp.array([x @ x - 1.0])
    smoothed = nlp.central_differences(evaluate, step=0.3)
    x = jnp.array([[0.4, -0.7], [1.5, 0.2]])
    p = jnp.array([[1.0, 2.0], [-1.0, 0.5]])
    weights = jnp.array([1.0, -2.0, 0.7])

    def scalar(fn):
        return lambda x_, p_: jnp.stack([o.sum() for o in fn(x_, p_)]) @ weights
    exact = jax.vmap(jax.grad(scalar(evaluate)))(x, p)
    differenced = jax.jit(jax.vmap(jax.grad(scalar(smoothed))))(x, p)
    np.testing.assert_allclose(differenced, exact, rtol=1e-12, atol=1e-12)
    # the value is the function's own, and the parameters get no derivative
    np.testing.assert_allclose(smoothed(x[0], p[0])[0], evaluate(x[0], p[0])[0], rtol=0)
    assert float(jnp.abs(jax.grad(lambda p_: smoothed(x[0], p_)[0])(p[0])).max()) == 0.0

    problem = nlp.ConstrainedProblem(evaluate)
    reference = al.solve(problem, jnp.zeros((2, 2)), p, OPTIONS)
    result = al.solve(problem.with_central_differences(0.3), jnp.zeros((2, 2)), p, OPTIONS)
    np.testing.assert_allclose(result.x, reference.x, atol=SOLUTION_TOLERANCE)
    assert result.status == reference.status == [nlp.CONVERGED] * 2
