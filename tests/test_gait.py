"""The gait problem: exact tracking inside the rollout, bad input, a short-horizon gait that
converges, and table values recomputed from the trajectory."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from biped_jax import augmented_lagrangian as al
from biped_jax import gait, gait_report, gait_solver
from biped_jax import hybrid_step as hs
from biped_jax.drives import RPM

# Short horizon for the tests: the same code as the study, fewer Euler steps.
SETTINGS = gait.GaitSettings(steps=20, degree=5)


@pytest.fixture(scope="module")
def solver(short_solver):
    assert short_solver.settings == SETTINGS
    return short_solver


@pytest.fixture(scope="module")
def m2_solution(paper_solutions):
    return paper_solutions[1]


@pytest.mark.parametrize("arguments, message", [
    (dict(speed=0.0), "speed must be positive, got 0.0"),
    (dict(speed=-0.4), "speed must be positive"),
    (dict(power_limit=0.0), "power_limit must be positive, got 0.0"),
    (dict(step_length=-0.2), "step_length must be positive"),
    (dict(step_length=0.7), "beyond the legs' reach"),
])
def test_bad_problem_data_is_rejected(arguments, message):
    values = dict(mass_class="12kg", speed=0.555, power_limit=20.0) | arguments
    with pytest.raises(ValueError, match=message):
        gait.gait_model(**values)


def test_reach_follows_the_robots_legs():
    """Kelly's biped has 0.8 m legs: a 0.7 m step is fine there, 1.6 m is not."""
    assert float(gait.gait_model("kelly", 0.7, 1e6, step_length=0.7).step_length) == 0.7
    with pytest.raises(ValueError, match="1.6 m is beyond the legs' reach"):
        gait.gait_model("kelly", 0.7, 1e6, step_length=1.6)


def test_unknown_mass_class_is_rejected():
    with pytest.raises(ValueError, match="'15kg'"):
        gait.gait_model("15kg", 0.5, 20.0)


def test_feedback_inside_the_rollout_tracks_the_reference_exactly(solver):
    """Deadbeat partial feedback linearisation: the actuated joints sit on the Bezier samples at every
    step, the applied torques reproduce the recorded accelerations in MJX, and relabelling makes the
    actuated positions periodic by construction."""
    model = gait.gait_model("12kg", 0.555, 20.0)
    # a batch of four strongly typed copies: the rollout program the paper fixture compiled
    batch = jax.tree.map(lambda a: jnp.asarray(jnp.stack([a] * 4), dtype=float), model)
    x = jax.jit(jax.vmap(lambda m: gait.initial_guess(m, SETTINGS)))(batch)
    trajectory = jax.tree.map(lambda a: a[0], solver.simulate(x, batch))
    reference = gait.bezier(gait.bezier_coefficients(x[0], SETTINGS), jnp.linspace(0, 1, SETTINGS.steps + 1))
    np.testing.assert_allclose(trajectory.q[:, gait.ACTUATED_INDEX], reference, atol=1e-10)
    np.testing.assert_allclose(trajectory.touchdown.q[gait.ACTUATED_INDEX], trajectory.q[0, gait.ACTUATED_INDEX],
                               atol=1e-12)
    biped = hs.with_design(solver.biped, model.design)
    pinned = hs.with_timestep(biped.pinned, float(trajectory.t[1]))
    k = 7
    qdd = jax.jit(hs.stance_acceleration)(pinned, trajectory.q[k], trajectory.qd[k], trajectory.u[k])
    np.testing.assert_allclose(qdd, trajectory.qdd[k], rtol=1e-9, atol=1e-9)


def test_short_horizon_gaits_of_all_four_models_converge_in_one_batch(paper_solutions):
    for solution in paper_solutions:
        assert solution.status == al.CONVERGED, (solution.name, solution.status, solution.violations)
        assert max(solution.violations.values()) <= gait_solver.VIOLATION_TOLERANCE
    # heavier and faster costs more effort (the paper's Tables 4-5 ordering)
    cost = {s.name: s.cost for s in paper_solutions}
    assert cost["M1"] < cost["M2"] < cost["M4"] and cost["M3"] < cost["M4"]


def test_short_horizon_gait_satisfies_the_constraints_on_its_trajectory(m2_solution):
    solution = m2_solution
    assert set(solution.violations) == set(gait.CONSTRAINT_GROUPS)
    assert max(solution.violations.values()) <= gait_solver.VIOLATION_TOLERANCE
    trajectory = solution.trajectory
    # Independently of the solver's bookkeeping: the touchdown lands L ahead, the power limit holds at
    # every step, and the next step starts where this one started.
    np.testing.assert_allclose(trajectory.swing_foot[-1], [0.2, 0.0], atol=1e-4)
    power = np.abs(np.asarray(trajectory.qd)[:-1, gait.ACTUATED_INDEX] * np.asarray(trajectory.u))
    assert power.max() <= 20.0 + 1e-4
    np.testing.assert_allclose(trajectory.touchdown.q, trajectory.q[0], atol=1e-4)
    np.testing.assert_allclose(trajectory.touchdown.qd, trajectory.qd[0], atol=1e-4)
    assert np.min(np.asarray(trajectory.ground_force)[:, 1]) >= -1e-4
    dt = float(trajectory.t[1])
    assert solution.cost == pytest.approx(float(np.sum(np.asarray(trajectory.u) ** 2) * dt), rel=1e-9)


def test_table_values_are_recomputed_from_the_trajectory(m2_solution):
    stats = gait_report.joint_statistics(m2_solution)
    tr = m2_solution.trajectory
    speed = np.abs(np.asarray(tr.qd)[:-1][:, [2, 1, 3, 4]])
    torque = np.abs(np.asarray(tr.u))
    acceleration = np.abs(np.asarray(tr.qdd)[:, [2, 1, 3, 4]])
    for k, joint in enumerate(("H1", "K1", "H2", "K2")):
        assert stats[joint]["vel_mean_rpm"] == pytest.approx(speed[:, k].mean() * 60 / (2 * np.pi))
        assert stats[joint]["vel_max_rpm"] == pytest.approx(speed[:, k].max() / RPM)
        assert stats[joint]["acc_max"] == pytest.approx(acceleration[:, k].max())
        assert stats[joint]["torque_mean"] == pytest.approx(torque[:, k].mean())
        assert stats[joint]["power_max"] == pytest.approx((speed[:, k] * torque[:, k]).max())
        assert stats[joint]["power_max_outside_impacts"] <= stats[joint]["power_max"]
    record = gait_report.results_record(m2_solution)
    assert record["model"] == "M2" and record["mass_kg"] == pytest.approx(11.999)
    assert record["max_vertical_force_N"] == pytest.approx(np.max(np.asarray(tr.ground_force)[:, 1]))
    assert "| Max. (W) |" in gait_report.markdown_table(m2_solution)


def test_mjx_rollout_matches_mujoco_c_on_the_optimal_gait(m2_solution):
    """The optimiser's MJX rollout (controller, Euler, ground force, impact map) against the same step
    computed with MuJoCo's C library and a numpy impact map."""
    from biped_jax.mujoco_reference import CGaitRollout
    reference = CGaitRollout("12kg", SETTINGS).simulate(m2_solution.x, 0.555, 0.2)
    mjx_step = m2_solution.trajectory
    for name in ("q", "qd", "qdd", "u", "ground_force", "swing_foot", "heights", "swing_foot_velocity"):
        expected = np.asarray(getattr(reference, name))
        np.testing.assert_allclose(getattr(mjx_step, name), expected, rtol=1e-7,
                                   atol=1e-8 * (1 + np.abs(expected).max()), err_msg=name)
    for name in ("q", "qd", "impulse", "old_stance_foot_velocity"):
        np.testing.assert_allclose(getattr(mjx_step.touchdown, name), getattr(reference.touchdown, name),
                                   rtol=1e-7, atol=1e-8, err_msg=f"touchdown.{name}")


def test_lagrangian_gradient_matches_central_differences_of_mujoco_c(solver, m2_solution):
    """The gradient the optimiser follows (MJX autodiff of the augmented Lagrangian) against central
    differences of the same function evaluated with MuJoCo C."""
    from biped_jax.mujoco_reference import CGaitRollout
    model = gait.gait_model("12kg", 0.555, 20.0)
    rollout = CGaitRollout("12kg", SETTINGS)
    x = np.asarray(m2_solution.x) + 0.01 * np.cos(np.arange(SETTINGS.size))  # off the optimum
    h_size, g_size = (a.size for a in gait.scaled_constraints(gait.constraint_groups(
        m2_solution.trajectory, model, SETTINGS)))
    lam_eq, lam_in, rho = 0.3 * np.ones(h_size), 0.2 * np.ones(g_size), 50.0

    def lagrangian_c(x_):
        trajectory = rollout.simulate(x_, 0.555, 0.2)
        h, g = gait.scaled_constraints(gait.constraint_groups(trajectory, model, SETTINGS))
        return float(al.lagrangian_value(gait.cost(trajectory), h, g, lam_eq, lam_in, rho))

    # a batch of four, the shape paper_solutions compiled, so no new program is compiled here
    tile = lambda a: jnp.broadcast_to(jnp.asarray(a), (4,) + jnp.shape(a))  # noqa: E731
    (value, _), gradient = solver.compiled.value_and_grad(
        tile(x), jax.tree.map(tile, model), tile(lam_eq), tile(lam_in), tile(rho))
    assert float(value[0]) == pytest.approx(lagrangian_c(x), rel=1e-9)
    step = 1e-6
    central = np.array([(lagrangian_c(x + step * e) - lagrangian_c(x - step * e)) / (2 * step)
                        for e in np.eye(x.size)])
    np.testing.assert_allclose(gradient[0], central, rtol=1e-5, atol=1e-5 * np.abs(central).max())
