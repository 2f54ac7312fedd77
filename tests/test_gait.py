"""The gait problem: prescribed joints and consistent zero dynamics, the integrator's order, the
refinement check, the multistart's spread, bad input, short-horizon gaits that converge, and table
values recomputed from the trajectory."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import short_settings

from biped_jax.drives.model import RPM
from biped_jax.dynamics import mjx_biped
from biped_jax.gait import problem as gait_problem
from biped_jax.robots import planar_biped
from biped_jax.gait import report as gait_report
from biped_jax.gait import multistart
from biped_jax.gait import verdict
from biped_jax.gait import solver as gait_solver
from biped_jax.optim import nlp

# Short horizon for the tests: the same code as the study, fewer knot spans and steps.
SETTINGS = short_settings()


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
        gait_problem.gait_model(**values)


def test_reach_follows_the_robots_legs():
    """Kelly's biped has 0.8 m legs: a 0.7 m step is fine there, 1.6 m is not."""
    assert float(gait_problem.gait_model("kelly", 0.7, 1e6, step_length=0.7).step_length) == 0.7
    with pytest.raises(ValueError, match="1.6 m is beyond the legs' reach"):
        gait_problem.gait_model("kelly", 0.7, 1e6, step_length=1.6)


def test_kellys_benchmark_poses_its_problem():
    """biped_jax.studies.kelly imports and poses Kelly's problem (its "no friction limit" is a setting the
    checks accept: an import-time ValueError once broke `biped-jax kelly` without a test noticing)."""
    from biped_jax.studies import kelly
    assert kelly.KELLY_SETTINGS.friction == gait_problem.NO_FRICTION_LIMIT
    model = kelly.kelly_model()
    assert float(model.speed) == pytest.approx(0.5 / 0.7) and float(model.step_length) == 0.5
    with pytest.raises(ValueError, match="friction"):
        gait_problem.GaitSettings(friction=2e3)


def test_unknown_mass_class_is_rejected():
    with pytest.raises(ValueError, match="'15kg'"):
        gait_problem.gait_model("15kg", 0.5, 20.0)


@pytest.fixture(scope="module")
def heuristic(solver):
    """M2's heuristic start simulated with the solver's compiled rollout (batch of four copies, the
    shape the paper fixture compiled)."""
    model = gait_problem.gait_model("12kg", 0.555, 20.0)
    batch = jax.tree.map(lambda a: jnp.asarray(jnp.stack([a] * 4), dtype=float), model)
    x = jax.jit(jax.vmap(lambda m: gait_problem.initial_guess(m, SETTINGS)))(batch)
    return model, x[0], jax.tree.map(lambda a: np.asarray(a[0]), solver.simulate(x, batch))


def test_report_checks_a_batch_of_designs_and_sizes_in_one_program(solver, heuristic):
    """GaitSolver.check rolls a whole batch out in one vmapped program per grid: batches of one and five
    different problems (speeds, link masses) give the rows a direct vmapped rollout gives, each row
    its own problem's, and share one program (no program per batch size or
    member); the violations and J are those of the rows' own trajectories."""
    model, x, _ = heuristic
    xs = np.stack([x * (1 + 0.01 * k) for k in range(5)])
    models = gait_solver.stack_tree([dataclasses.replace(
        model, speed=jnp.asarray(0.5 + 0.01 * k),
        design=dataclasses.replace(model.design, link_mass=model.design.link_mass * (1 + 0.02 * k)))
        for k in range(5)])
    direct = jax.jit(jax.vmap(lambda x_, m: gait_problem.simulate(x_, m, solver.biped, SETTINGS)))(jnp.asarray(xs),
                                                                                                   models)
    program = solver._checks[SETTINGS]
    solver.check(xs[:4], jax.tree.map(lambda a: a[:4], models))  # as the fixture's batch of four
    before = program._cache_size()
    five, one = solver.check(xs, models), solver.check(xs[:1], jax.tree.map(lambda a: a[:1], models))
    assert before == 1 and program._cache_size() == before
    assert five.trajectory.u.shape == (5,) + direct.u.shape[1:] and five.energy.shape == (5,)
    np.testing.assert_allclose(five.trajectory.u, direct.u, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(one.trajectory.q, np.asarray(direct.q)[:1], rtol=1e-12, atol=1e-12)
    assert len(set(np.round(five.energy, 9))) == 5  # five problems, five different gaits
    for k in (0, 3):
        row = jax.tree.map(lambda a: a[k], direct)
        model_k = jax.tree.map(lambda a: a[k], models)
        groups = gait_problem.violations(gait_problem.constraint_groups(row, model_k, SETTINGS))
        for name, value in groups.items():
            assert five.violations[name][k] == pytest.approx(float(value), rel=1e-9, abs=1e-12), name
        assert five.energy[k] == pytest.approx(float(gait_problem.cost(row)), rel=1e-12)
    assert five.finite.all()


@pytest.mark.slow
def test_prescribed_joints_follow_the_spline_and_the_torques_give_its_accelerations(solver, heuristic):
    """The actuated joints are the B-spline and its derivatives at every sample; the applied torques
    reproduce the sampled accelerations through MJX's forward dynamics (so the unactuated row holds
    too); relabelling makes the actuated positions periodic by construction."""
    model, x, trajectory = heuristic
    step_time = float(model.step_length / model.speed)
    s = gait_problem.grid(SETTINGS)
    q, dq, ddq = (np.asarray(r) for r in gait_problem.reference(x, SETTINGS, s))
    a = planar_biped.ACTUATED_INDEX
    np.testing.assert_allclose(trajectory.q[:, a], q, atol=1e-12)
    np.testing.assert_allclose(trajectory.qd[:, a], dq / step_time, atol=1e-10)
    np.testing.assert_allclose(trajectory.qdd[:, a], ddq / step_time**2, atol=1e-8)
    np.testing.assert_allclose(trajectory.touchdown.q[a], trajectory.q[0, a], atol=1e-12)
    pinned = mjx_biped.with_design(solver.biped, model.design).pinned
    forward = jax.jit(jax.vmap(mjx_biped.stance_acceleration, (None, 0, 0, 0)))
    qdd = forward(pinned, trajectory.q, trajectory.qd, trajectory.u)
    np.testing.assert_allclose(qdd, trajectory.qdd, rtol=1e-9, atol=1e-8)


@pytest.mark.slow
def test_start_state_and_first_sample_are_consistent(solver, heuristic):
    """The start is the spline's value and slope with the decision vector's stance state, and the first
    sample's ground force is Newton-Euler's at that state and acceleration (no deadbeat sample)."""
    model, x, trajectory = heuristic
    step_time = float(model.step_length / model.speed)
    q0, dq0, _ = (np.asarray(r)[0] for r in gait_problem.reference(x, SETTINGS, np.zeros(1)))
    np.testing.assert_allclose(trajectory.q[0], np.r_[x[0], q0[[1, 0, 2, 3]]], atol=1e-12)
    np.testing.assert_allclose(trajectory.qd[0, planar_biped.ACTUATED_INDEX], dq0 / step_time, atol=1e-12)
    assert trajectory.qd[0, 0] == pytest.approx(float(x[1]))
    pinned = mjx_biped.with_design(solver.biped, model.design).pinned
    force = jax.jit(mjx_biped.ground_reaction)(pinned, trajectory.q[0], trajectory.qd[0], trajectory.qdd[0])
    np.testing.assert_allclose(trajectory.ground_force[0], force, rtol=1e-9, atol=1e-8)


@pytest.mark.slow
def test_integrator_and_quadrature_converge_at_fourth_order(biped12):
    """The same decision vector on grids 2, 4, 8, 16 steps per span against 64: the stance angle at
    touchdown and J converge at the 4th order of RK4 and Simpson (each halving divides the error by
    about 16). Single shooting: the whole step one integration from the start state (a heuristic start
    is not continuous across shooting nodes)."""
    model = gait_problem.gait_model("12kg", 0.555, 20.0)
    single_shot = dataclasses.replace(SETTINGS, segments=1)
    x = gait_problem.initial_guess(model, single_shot, family=gait_problem.START_FAMILIES[1])
    results = {}
    for substeps in (2, 4, 8, 16, 64):
        settings = dataclasses.replace(single_shot, substeps=substeps)
        trajectory = jax.jit(lambda x_: gait_problem.simulate(x_, model, biped12, settings))(x)
        results[substeps] = (float(trajectory.q[-1, 0]), float(trajectory.qd[-1, 0]),
                             float(gait_problem.cost(trajectory)))
    exact = np.array(results[64])
    errors = np.array([np.abs(np.array(results[n]) - exact) for n in (2, 4, 8, 16)])
    ratios = errors[:-1] / errors[1:]
    assert np.all(errors[-1] < 1e-5 * (1 + np.abs(exact))), errors
    # observed order log2(ratio) between 3.5 and 4.5 on the two finer pairs
    order = np.log2(ratios[1:])
    assert np.all((order > 3.5) & (order < 4.6)), order


@pytest.mark.slow
def test_refinement_check_flags_a_grid_dependent_gait(m2_solution, solver):
    """Every solution carries J and the violations on a grid four times finer; the check fails when J
    moves by more than 0.5 % or the power limit is broken there by more than 1 % of M_W."""
    check = m2_solution.refinement
    assert check["steps"] == gait_problem.REFINEMENT * SETTINGS.steps == solver.refined_settings.steps
    assert set(check["violations"]) == set(gait_problem.CONSTRAINT_GROUPS)
    assert check["passed"] == (not check["failed"])
    model = gait_problem.gait_model("12kg", 0.555, 20.0)
    batch = gait_solver.stack_tree([model] * 4)
    fine = solver.check(jnp.asarray(np.tile(m2_solution.x, (4, 1))), batch, refined=True)
    trajectory = jax.tree.map(lambda a: a[0], fine.trajectory)
    assert check["cost"] == pytest.approx(float(gait_problem.cost(trajectory)), rel=1e-12)
    first = jax.tree.map(lambda a: a[:1], fine)
    steps = solver.refined_settings.steps
    moved, = verdict.refinement_records([1.01 * check["cost"]], first, [20.0], steps)
    assert not moved["passed"] and moved["failed"][0] == "cost"
    # a gait that fails the check is not converged (the study's solvers enforce it)
    feasible = {k: 0.0 for k in gait_problem.CONSTRAINT_GROUPS}
    assert verdict.classify(nlp.CONVERGED, True, feasible, moved) == verdict.GRID_DEPENDENT
    assert verdict.classify(nlp.CONVERGED, True, feasible, moved, require_refinement=False) == nlp.CONVERGED
    assert verdict.classify(nlp.CONVERGED, True, feasible, {"passed": True}) == nlp.CONVERGED
    assert verdict.classify(nlp.CONVERGED, False, feasible, {"passed": True}) == nlp.DIVERGED
    assert verdict.classify(nlp.CONVERGED, True, feasible | {"power_limit": 1e-3},
                                {"passed": True}) == nlp.ITERATION_LIMIT
    tight = 0.5 * float(np.max(np.abs(trajectory.joint_power)))
    broken, = verdict.refinement_records([check["cost"]], solver.check(
        jnp.asarray(m2_solution.x[None]), gait_solver.stack_tree([gait_problem.gait_model("12kg", 0.555, tight)]),
        refined=True), [tight], steps)
    assert "power_limit" in broken["failed"] and broken["power_margin_fraction"] > 0.01
    # each row of a batch is judged on its own numbers: the tight row fails, the others do not move
    mixed = verdict.refinement_records([check["cost"], 1.01 * check["cost"]], jax.tree.map(
        lambda a: a[:2], fine), [20.0, 20.0], steps)
    assert mixed[0]["passed"] == check["passed"] and mixed[1]["failed"][0] == "cost"


@pytest.mark.slow
def test_short_horizon_gaits_of_all_four_models_converge_in_one_batch(paper_solutions):
    for solution in paper_solutions:
        assert solution.status in (nlp.CONVERGED, verdict.GRID_DEPENDENT), (solution.name, solution.status)
        assert max(solution.violations.values()) <= verdict.VIOLATION_TOLERANCE
    # heavier and faster costs more effort (the paper's Tables 4-5 ordering)
    cost = {s.name: s.cost for s in paper_solutions}
    assert cost["M1"] < cost["M2"] < cost["M4"] and cost["M3"] < cost["M4"]


@pytest.mark.slow
def test_short_horizon_gait_satisfies_the_constraints_on_its_trajectory(m2_solution):
    solution = m2_solution
    assert set(solution.violations) == set(gait_problem.CONSTRAINT_GROUPS)
    assert max(solution.violations.values()) <= verdict.VIOLATION_TOLERANCE
    trajectory = solution.trajectory
    # Independently of the solver's bookkeeping: the touchdown lands L ahead, the power limit holds at
    # every sample (start and end included), and the next step starts where this one started.
    np.testing.assert_allclose(trajectory.swing_foot[-1], [0.2, 0.0], atol=1e-4)
    power = np.abs(np.asarray(trajectory.qd)[:, planar_biped.ACTUATED_INDEX] * np.asarray(trajectory.u))
    assert power.max() <= 20.0 + 1e-4
    np.testing.assert_allclose(trajectory.touchdown.q, trajectory.q[0], atol=1e-4)
    np.testing.assert_allclose(trajectory.touchdown.qd, trajectory.qd[0], atol=1e-4)
    assert np.min(np.asarray(trajectory.ground_force)[:, 1]) >= -1e-4
    # J is Simpson's rule over the samples; the weights integrate the step time exactly
    weights = np.asarray(trajectory.weights)
    assert weights.sum() == pytest.approx(solution.step_time_s, rel=1e-12)
    assert solution.cost == pytest.approx(float(weights @ np.sum(np.asarray(trajectory.u) ** 2, axis=1)), rel=1e-9)


def test_the_swing_clearance_and_the_landing_speed_bound_the_swing_foot(m2_solution):
    """``GaitSettings.swing_clearance``: the swing foot's rows are its height under the profile, 0 at lift-off
    and touchdown, the clearance from 10 % of the step to 90 %, half of it half-way up the smoothstep; the
    optimum without it sweeps the foot lower than 10 mm near touchdown, so its rows there are violated.
    ``touchdown_forward_speed`` adds the foot's forward speed at touchdown over the bound to the rows that
    keep it descending."""
    from biped_jax.gait import constraints
    from biped_jax.studies import paper as study
    clearance = dataclasses.replace(short_settings(), swing_clearance=0.01)
    model = study.paper_gait_models(study.PAPER_MODELS[1:2])[0]
    trajectory = m2_solution.trajectory
    phase = np.asarray(trajectory.t) / float(trajectory.t[-1])
    held = np.asarray(gait_problem.constraint_groups(trajectory, model, clearance)["swing_foot_height"])
    plain = np.asarray(gait_problem.constraint_groups(trajectory, model, short_settings())["swing_foot_height"])
    profile = held - plain
    np.testing.assert_allclose(plain, -np.asarray(trajectory.swing_foot)[1:-1, 1])
    middle = (phase[1:-1] >= 0.1) & (phase[1:-1] <= 0.9)
    np.testing.assert_allclose(profile[middle], 0.01, rtol=1e-12)
    assert np.all(profile >= 0) and np.all(profile[~middle] < 0.01)
    np.testing.assert_allclose(np.asarray(constraints.clearance_profile(np.array([0.0, 0.05, 0.95, 1.0]), clearance)),
                               [0.0, 0.005, 0.005, 0.0], atol=1e-15)
    assert float(gait_problem.violations(gait_problem.constraint_groups(trajectory, model, clearance))
                 ["swing_foot_height"]) > 1e-3
    velocity = np.asarray(trajectory.swing_foot_velocity)
    landing = dataclasses.replace(clearance, touchdown_forward_speed=0.5)
    np.testing.assert_allclose(gait_problem.constraint_groups(trajectory, model, landing)["touchdown_descending"],
                               [velocity[1], velocity[0] - 0.5])
    assert velocity[0] > 0.5 and velocity[1] < 0  # the optimum lands moving forward and down


@pytest.mark.slow
def test_multistart_reports_the_spread_and_keeps_the_best(solver):
    """Four start families of M2 in one batch (the program the paper fixture compiled); the cheapest
    feasible one is kept and every start is listed."""
    model = gait_problem.gait_model("12kg", 0.555, 20.0)
    families = gait_problem.START_FAMILIES[:4]
    ends = []
    solution, = multistart.solve_multistart(solver, ["M2"], [model], families=families,
                                             finished=lambda stage, count: ends.append((stage, count)))
    assert ends == [("starts", 4)]  # one stage without a coarse space; its end is reported once
    assert [row["family"] for row in solution.starts] == [f.name for f in families]
    assert all(np.isfinite([row["cost"] for row in solution.starts]))
    assert solution.status in (nlp.CONVERGED, verdict.GRID_DEPENDENT), solution.status
    feasible = [row["cost"] for row in solution.starts if row["status"] in (nlp.CONVERGED, verdict.GRID_DEPENDENT)]
    assert feasible, solution.starts
    assert solution.cost <= min(feasible) * (1 + 1e-4)


@pytest.mark.slow
def test_table_values_are_recomputed_from_the_trajectory(m2_solution):
    stats = gait_report.joint_statistics(m2_solution)
    tr = m2_solution.trajectory
    speed = np.abs(np.asarray(tr.qd)[:, [2, 1, 3, 4]])
    torque = np.abs(np.asarray(tr.u))
    acceleration = np.abs(np.asarray(tr.qdd)[:, [2, 1, 3, 4]])
    average = np.asarray(tr.weights) / m2_solution.step_time_s  # time averages
    for k, joint in enumerate(("H1", "K1", "H2", "K2")):
        assert stats[joint]["vel_mean_rpm"] == pytest.approx(average @ speed[:, k] * 60 / (2 * np.pi))
        assert stats[joint]["vel_max_rpm"] == pytest.approx(speed[:, k].max() / RPM)
        assert stats[joint]["acc_max"] == pytest.approx(acceleration[:, k].max())
        assert stats[joint]["torque_mean"] == pytest.approx(average @ torque[:, k])
        assert stats[joint]["power_max"] == pytest.approx((speed[:, k] * torque[:, k]).max())
        assert stats[joint]["power_max_outside_impacts"] <= stats[joint]["power_max"]
    record = gait_report.results_record(m2_solution)
    assert record["model"] == "M2" and record["mass_kg"] == pytest.approx(11.999)
    assert record["max_vertical_force_N"] == pytest.approx(np.max(np.asarray(tr.ground_force)[:, 1]))
    assert record["refinement"] == m2_solution.refinement
    assert "| Max. (W) |" in gait_report.markdown_table(m2_solution)


@pytest.mark.parametrize("changes, message", [
    (dict(spans=0), "spans must be an integer in"),
    (dict(degree=1), "degree must be an integer in"),
    (dict(substeps=3), "substeps must be even"),
    (dict(substeps=2.5), "substeps must be an integer"),
    (dict(grading=1.5), "grading must be in"),
    (dict(torque_bound=-1.0), "torque_bound must be a number"),
    (dict(friction=float("nan")), "friction must be a number"),
    (dict(knee_max=float("nan")), "knee_max must be a number"),
    (dict(swing_clearance=10.0), r"swing_clearance must be a number in \[0, 0.05\] m, got 10.0"),  # mm for m
    (dict(swing_clearance=-0.01), "swing_clearance must be a number in"),
    (dict(swing_clearance=0.01, clearance_ramp=0.0), "clearance_ramp must be a number in"),
    (dict(touchdown_forward_speed=float("inf")), "touchdown_forward_speed must be a number in"),
])
def test_bad_settings_are_rejected(changes, message):
    with pytest.raises(ValueError, match=message):
        dataclasses.replace(SETTINGS, **changes)


def test_spaces_of_many_graded_spans_lay_out_their_segments():
    """The shooting segments of 48-128 graded knot spans (the space check's finer spaces): each segment's
    window of control points holds every point that reaches its samples, judged relative to the basis'
    size (the end spans' second derivatives reach 2e4 at 64 spans, where an absolute 1e-12 failed)."""
    from biped_jax.gait import segmented
    for spans in (48, 64, 128):
        first, window, data = segmented._layout(dataclasses.replace(SETTINGS, spans=spans, segments=spans))
        assert window == 1 + SETTINGS.degree and list(first) == list(range(spans))
        assert data["basis_grid"].shape[:3] == (spans, 3, SETTINGS.substeps + 1)


def test_the_coarse_space_halves_the_steps_per_span_where_they_stay_even():
    """The study's starts stage runs on 12 spans x 2 steps under the study's 48 x 4; its smallest power
    limit's first stage and a grid whose half would be odd keep their steps per span."""
    from biped_jax.studies import paper
    study = paper.study_solvers()
    assert (study.coarse.settings.spans, study.coarse.settings.substeps, study.coarse.settings.segments) == (12, 2, 12)
    assert (study.coarse_power.settings.spans, study.coarse_power.settings.substeps) == (12, 4)
    assert [paper.coarse_substeps(dataclasses.replace(SETTINGS, substeps=k)) for k in (2, 4, 6, 8)] == [2, 2, 6, 4]
    with pytest.raises(ValueError, match="substeps"):
        multistart.coarse_settings(paper.STUDY_SETTINGS, substeps=3)


@pytest.mark.slow
def test_projection_into_a_finer_space_keeps_the_curve(biped12):
    """Continuation: a coarse-space curve carried into a space with nested knots is the same curve."""
    fine = dataclasses.replace(SETTINGS, spans=8, segments=8)  # and into multiple shooting
    model = gait_problem.gait_model("12kg", 0.555, 20.0)
    x = np.asarray(gait_problem.initial_guess(model, SETTINGS, family=gait_problem.START_FAMILIES[2]))
    trajectory = jax.jit(lambda x_: gait_problem.simulate(x_, model, biped12, SETTINGS))(x)
    projected = gait_problem.project(x, SETTINGS, fine, trajectory)
    s = np.linspace(0, 1, 57)
    for a, b in zip(gait_problem.reference(jnp.asarray(x), SETTINGS, s), gait_problem.reference(jnp.asarray(projected),
                                                                                                fine, s)):
        np.testing.assert_allclose(a, b, atol=1e-9)
    # the shooting nodes: the coarse trajectory's stance state at the fine span starts (on its grid
    # where the spans coincide, interpolated in between)
    nodes = np.asarray(gait_problem.stance_nodes(jnp.asarray(projected), fine))
    on_grid = np.arange(SETTINGS.spans) * SETTINGS.substeps
    stance = np.stack([np.asarray(trajectory.q)[:, 0], np.asarray(trajectory.qd)[:, 0]], axis=-1)
    np.testing.assert_allclose(nodes[::2], stance[on_grid], atol=1e-12)
    dense = jax.jit(lambda x_: gait_problem.simulate(x_, model, biped12, dataclasses.replace(SETTINGS, substeps=64)))(x)
    between = gait_problem.breakpoints(fine)[1::2] * float(dense.t[-1])
    for k, series in enumerate((dense.q[:, 0], dense.qd[:, 0])):
        np.testing.assert_allclose(nodes[1::2, k], np.interp(between, dense.t, series), atol=1e-3)


@pytest.mark.slow
def test_mjx_rollout_matches_mujoco_c_on_the_optimal_gait(m2_solution):
    """The optimiser's MJX rollout (controller, Euler, ground force, impact map) against the same step
    computed with MuJoCo's C library and a numpy impact map."""
    from biped_jax.gait.mujoco_reference import CGaitRollout
    reference = CGaitRollout("12kg", SETTINGS).simulate(m2_solution.x, 0.555, 0.2)
    mjx_step = m2_solution.trajectory
    for name in ("q", "qd", "qdd", "u", "ground_force", "swing_foot", "heights", "swing_foot_velocity"):
        expected = np.asarray(getattr(reference, name))
        np.testing.assert_allclose(getattr(mjx_step, name), expected, rtol=1e-7,
                                   atol=1e-8 * (1 + np.abs(expected).max()), err_msg=name)
    for name in ("q", "qd", "impulse", "old_stance_foot_velocity"):
        np.testing.assert_allclose(getattr(mjx_step.touchdown, name), getattr(reference.touchdown, name),
                                   rtol=1e-7, atol=1e-8, err_msg=f"touchdown.{name}")


@pytest.mark.slow
def test_lagrangian_gradient_matches_central_differences_of_mujoco_c(solver, m2_solution):
    """The gradient of the Lagrangian f + y . h + z . g (MJX autodiff, the reverse pass the interior
    point's derivatives start from) against central differences of the same function evaluated with
    MuJoCo C."""
    from biped_jax.gait.mujoco_reference import CGaitRollout
    model = gait_problem.gait_model("12kg", 0.555, 20.0)
    rollout = CGaitRollout("12kg", SETTINGS)
    x = np.asarray(m2_solution.x) + 0.01 * np.cos(np.arange(SETTINGS.size))  # off the optimum
    h_size, g_size = (a.size for a in gait_problem.scaled_constraints(gait_problem.constraint_groups(
        m2_solution.trajectory, model, SETTINGS)))
    lam_eq, lam_in = 0.3 * np.ones(h_size), 0.2 * np.ones(g_size)

    def lagrangian(f, h, g):
        return f + h @ lam_eq + g @ lam_in

    def lagrangian_c(x_):
        trajectory = rollout.simulate(x_, 0.555, 0.2)
        h, g = gait_problem.scaled_constraints(gait_problem.constraint_groups(trajectory, model, SETTINGS))
        return float(lagrangian(gait_problem.cost(trajectory), h, g))

    value, gradient = jax.jit(jax.value_and_grad(lambda x_: lagrangian(*solver.problem.evaluate(x_, model))))(
        jnp.asarray(x))
    assert float(value) == pytest.approx(lagrangian_c(x), rel=1e-9)
    step = 1e-6
    central = np.array([(lagrangian_c(x + step * e) - lagrangian_c(x - step * e)) / (2 * step)
                        for e in np.eye(x.size)])
    np.testing.assert_allclose(gradient, central, rtol=1e-5, atol=1e-5 * np.abs(central).max())


@pytest.mark.slow
def test_multiple_shooting_reproduces_single_shooting_and_reports_its_defects(biped12):
    """A multiple-shot step whose nodes lie on the single-shot trajectory is that trajectory (the
    defects vanish); a node moved off it shows up as exactly that defect, the same in MuJoCo C."""
    from biped_jax.gait.mujoco_reference import CGaitRollout
    model = gait_problem.gait_model("12kg", 0.555, 20.0)
    single_shot = dataclasses.replace(SETTINGS, segments=1)
    multi = dataclasses.replace(SETTINGS, segments=SETTINGS.spans)
    x = gait_problem.initial_guess(model, single_shot, family=gait_problem.START_FAMILIES[1])
    single = jax.jit(lambda x_: gait_problem.simulate(x_, model, biped12, single_shot))(x)
    starts = np.arange(multi.segments) * (multi.steps // multi.segments)
    nodes = np.stack([np.asarray(single.q)[starts, 0], np.asarray(single.qd)[starts, 0]], axis=-1)
    x_multi = gait_problem.pack(nodes, gait_problem.control_points(x, single_shot)[1:])
    assert x_multi.shape == (multi.size,) == (single_shot.size + 2 * (multi.segments - 1),)
    simulate = jax.jit(lambda x_: gait_problem.simulate(x_, model, biped12, multi))
    shot = simulate(x_multi)
    for name in ("q", "qd", "u", "ground_force"):
        np.testing.assert_allclose(getattr(shot, name), getattr(single, name), atol=1e-12, err_msg=name)
    np.testing.assert_allclose(shot.continuity, 0.0, atol=1e-12)
    assert float(gait_problem.cost(shot)) == pytest.approx(float(gait_problem.cost(single)), rel=1e-12)
    moved = np.asarray(x_multi).copy()
    moved[-2:] += np.array([0.01, -0.2])  # the last node's stance angle and rate
    shot = simulate(jnp.asarray(moved))
    np.testing.assert_allclose(shot.continuity[-1], [-0.01, 0.2], atol=1e-12)
    np.testing.assert_allclose(shot.continuity[:-1], 0.0, atol=1e-12)
    groups = gait_problem.violations(gait_problem.constraint_groups(shot, model, multi))
    assert float(groups["continuity_angle"]) == pytest.approx(0.01)
    assert float(groups["continuity_rate"]) == pytest.approx(0.2)
    reference = CGaitRollout("12kg", multi).simulate(moved, 0.555, 0.2)
    np.testing.assert_allclose(shot.continuity, reference.continuity, atol=1e-9)
    np.testing.assert_allclose(shot.u, reference.u, rtol=1e-7, atol=1e-8)


def test_shooting_segments_must_divide_the_spans():
    with pytest.raises(ValueError, match="segments must divide spans"):
        dataclasses.replace(SETTINGS, segments=3)
    with pytest.raises(ValueError, match="segments must be an integer in"):
        dataclasses.replace(SETTINGS, segments=0)


def test_start_family_can_land_on_a_flexed_stance_knee():
    """``impact_knee`` flexes the stance knee at touchdown and, by the mirror, the swing knee at the
    start; the default families keep both straight."""
    model = gait_problem.gait_model("12kg", 0.555, 20.0)
    family = dataclasses.replace(gait_problem.START_FAMILIES[2], impact_knee=0.3)
    for chosen, knee in ((family, 0.3), (gait_problem.START_FAMILIES[2], 0.0)):
        x = gait_problem.initial_guess(model, SETTINGS, family=chosen)
        q = np.asarray(gait_problem.reference(x, SETTINGS, np.array([0.0, 1.0]))[0])  # (H1, K1, H2, K2) at 0, t_f
        assert q[1, 1] == pytest.approx(knee, abs=1e-12) and q[0, 3] == pytest.approx(knee, abs=1e-12)
        assert q[0, 1] == pytest.approx(0.0, abs=1e-12)
