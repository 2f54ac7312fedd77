"""Co-design: the motor in the loop (armature, drive masses, Joule energy, voltage limit), batches of
designs, and the gradient of the optimal Joule energy against re-solved optima."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import short_settings

from biped_jax import codesign
from biped_jax.codesign import optimise
from biped_jax.drives import model as drive_model
from biped_jax.drives.model import GCM2
from biped_jax.dynamics import mjx_biped
from biped_jax.gait import problem as gait_problem
from biped_jax.gait.solver import stack_tree
from biped_jax.optim import nlp

SPEED, POWER_LIMIT = 0.555, 20.0  # M2
LOG_STEP = 0.03  # central difference in log N
# central difference in log k_t: the active sets of the voltage and gear limits move with k_t (at the 66:1
# drive the gait meets the gears' limits too): 0.02 / 0.01 / 0.005 / 0.003 gave 2.2 / 0.69 / 0.10 / 0.004 %
WINDING_STEP = 0.003


def test_armature_is_ratio_squared_times_rotor_and_gear_inertia(biped12):
    """RE 25 42 V (10.7 g cm^2) through the GP 32 A 66.22:1 (0.7 g cm^2, motor side): the MJX models'
    dof_armature at the four actuated joints, pinned and floating."""
    design = codesign.catalogue_design("RE25-42V", "GP32A-66.22")
    expected = 66.22**2 * (10.7 + 0.7) * GCM2
    biped = mjx_biped.with_design(biped12, codesign.robot_design(design))
    for model, layout in zip((biped.pinned, biped.floating), mjx_biped.planar_layouts()):
        np.testing.assert_allclose(np.asarray(model.dof_armature)[layout.dof_ids], expected, rtol=1e-12)
    assert float(design.total_mass) == pytest.approx(12.0, abs=0.01)  # the structure is built for it


def test_mixed_gearheads_and_total_mass():
    design = codesign.catalogue_design("RE25-118752", ("GP32A-23", "GP32A-66.22", "GP32A-23", "GP32A-66.22"),
                                       total_mass=16.0)
    np.testing.assert_allclose(design.ratio, [23, 66.22, 23, 66.22])
    np.testing.assert_allclose(design.gear_mass, [0.16, 0.19, 0.16, 0.19])
    assert float(design.total_mass) == pytest.approx(16.0, rel=1e-12)


@pytest.mark.parametrize("call, message", [
    (lambda: codesign.catalogue_design("RE25-99V"), "unknown motor part 'RE25-99V'"),
    (lambda: codesign.catalogue_design(gearhead="GP32A-7"), "unknown gearhead part 'GP32A-7'"),
    (lambda: codesign.catalogue_design(total_mass=1.0), "total_mass must exceed the drives' 1.28 kg, got 1.0"),
    (lambda: codesign.catalogue_design(supply_voltage=-5.0), "supply_voltage must be positive, got -5.0"),
    (lambda: codesign.nearest_gearhead(-3.0), "gear ratio must be positive and finite, got -3.0"),
])
def test_bad_designs_are_rejected_naming_the_value(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_smooth_gear_efficiency_is_exact_away_from_the_switch():
    torque = jnp.array([2.0, -2.0, 2.0, -2.0, 0.3])
    speed = jnp.array([5.0, -5.0, -5.0, 5.0, 0.2])  # powers 10, 10, -10, -10, 0.06 W
    exact = drive_model.motor_torque(torque, speed, 66.0, 0.7)
    smooth = drive_model.smooth_motor_torque(torque, speed, 66.0, 0.7)
    np.testing.assert_allclose(smooth[:4], exact[:4], rtol=1e-8)
    assert exact[4] * 0.7**2 < smooth[4] < exact[4]  # blended between the two laws near zero power
    np.testing.assert_allclose(drive_model.smooth_motor_torque(torque, speed, 66.0, 1.0), torque / 66.0, rtol=1e-15)


@pytest.mark.slow
def test_joule_energy_of_identical_drives_is_a_constant_times_int_u2(paper_solutions):
    """The paper's objective is the special case: ideal drives give exactly J = int u^T u, identical
    lossless-gear drives R / (k_t N)^2 times it."""
    trajectory = paper_solutions[1].trajectory
    int_u2 = float(gait_problem.cost(trajectory))
    assert float(gait_problem.joule_energy(trajectory, drive_model.ideal_drives())) == pytest.approx(int_u2, rel=1e-12)
    design = dataclasses.replace(codesign.catalogue_design(), gear_efficiency=jnp.ones(4))
    joule = float(gait_problem.joule_energy(trajectory, codesign.joint_drives(design)))
    assert joule == pytest.approx(7.05 / (0.0409 * 66.22) ** 2 * int_u2, rel=1e-12)


def test_voltage_limit_is_the_speed_torque_line():
    """An operating point on the line at the supply voltage has zero excess; faster is positive."""
    design = codesign.catalogue_design()
    line = codesign.joint_drives(design)
    torque_motor = 0.05  # N m at the motor, motoring
    motor_speed = float(drive_model.max_speed_at_torque(torque_motor, drive_model.load_catalogue().motor("RE25-42V"),
                                                        38.0))
    joint_torque = torque_motor * 66.22 * 0.7
    joint_speed = motor_speed / 66.22
    # far from the efficiency switch (|T omega| >> 1 W), so the smooth law is the exact one
    excess = drive_model.voltage_excess(jnp.full(4, joint_torque), jnp.full(4, joint_speed), line)
    np.testing.assert_allclose(excess, 0.0, atol=1e-9)
    faster = drive_model.voltage_excess(jnp.full(4, joint_torque), jnp.full(4, 1.01 * joint_speed), line)
    np.testing.assert_allclose(faster, 0.0409 * 0.01 * motor_speed, rtol=1e-9)  # back-EMF of the extra 1 %


@pytest.fixture(scope="module")
def design_solver():
    """The solver of the tests' short space with the co-design's options (:data:`codesign.SOLVER_OPTIONS`:
    the interior point warm-started) and the drives' gear limits held (``drive_limits``, as the
    co-design study holds them)."""
    from biped_jax.gait.solver import GaitSolver
    return GaitSolver(dataclasses.replace(short_settings(), drive_limits=True), codesign.SOLVER_OPTIONS,
                      require_refinement=False)


@pytest.fixture(scope="module")
def ratio_batch(design_solver, paper_solutions):
    """The reference drive at log N - d, log N, log N + d, log N, warm-started from M2's ideal gait."""
    reference = codesign.catalogue_design()
    log_ratio = np.log(66.22) + np.array([-LOG_STEP, 0.0, LOG_STEP, 0.0])
    designs = [codesign.with_ratio(reference, jnp.full(4, t)) for t in log_ratio]
    x0 = np.tile(paper_solutions[1].x, (4, 1))
    return designs, log_ratio, codesign.solve_designs(design_solver, designs, SPEED, POWER_LIMIT, x0=x0)


@pytest.mark.slow
def test_a_batch_of_designs_converges_and_identical_designs_agree(design_solver, ratio_batch, paper_solutions):
    designs, _, solutions = ratio_batch
    for design, solution in zip(designs, solutions):
        assert solution.status == nlp.CONVERGED, (solution.status, solution.violations)
        record = codesign.design_record(design, solution)
        assert record["max_voltage_needed_V"] <= 38.0 + 1e-3
        assert record["peak_joint_power_W"] <= POWER_LIMIT + 1e-4
    # the refinement check weighs the problem's own objective, the Joule energy, on the 4x grid (not
    # the integral of u^T u, which differs by R / (k_t N)^2 and the gear's efficiency)
    model = codesign.design_gait_model(designs[1], SPEED, POWER_LIMIT)
    fine = jax.tree.map(lambda a: a[0], design_solver.simulate_refined(
        solutions[1].x[None], stack_tree([model])))
    joule, int_u2 = float(gait_problem.joule_energy(fine, model.drives)), float(gait_problem.cost(fine))
    assert solutions[1].refinement["cost"] == pytest.approx(joule, rel=1e-12)
    assert abs(joule / int_u2 - 1) > 0.05
    # the same design in another batch (four copies) solves to the same gait: designs do not interact
    again = codesign.solve_designs(design_solver, [designs[1]] * 4, SPEED, POWER_LIMIT,
                                   x0=np.tile(paper_solutions[1].x, (4, 1)))
    for solution in again + [solutions[3]]:
        np.testing.assert_allclose(solution.x, solutions[1].x, rtol=1e-9, atol=1e-12)
        assert solution.cost == pytest.approx(solutions[1].cost, rel=1e-10)
    # neighbouring designs share the optimum's branch (what the envelope gradient below needs): every
    # entry (angles in rad, the shooting nodes' stance rates in rad/s) within 5 % of its size
    assert np.max(np.abs(solutions[0].x - solutions[1].x) / np.maximum(1.0, np.abs(solutions[1].x))) < 0.05
    # motors make walking dearer than the ideal drives' J: armature, drive masses, R i^2 over int u^2
    assert solutions[1].cost != pytest.approx(paper_solutions[1].cost, rel=0.05)


SPLIT_STEP = 0.004  # central difference in the mass split's fractions


def test_the_mass_split_keeps_the_total_and_gives_the_design_back_at_its_own_split():
    reference = codesign.catalogue_design()
    own = np.asarray(codesign.mass_split(reference))
    np.testing.assert_allclose(own, [0.37354, 0.42008], atol=1e-5)  # Table 2 less the reference drives
    np.testing.assert_allclose(codesign.with_mass_split(reference, own).structure_mass, reference.structure_mass,
                               rtol=1e-14)
    moved = codesign.with_mass_split(reference, jnp.array([0.25, 0.6]))
    assert float(moved.total_mass) == pytest.approx(float(reference.total_mass), rel=1e-14)
    np.testing.assert_allclose(codesign.mass_split(moved), [0.25, 0.6], rtol=1e-14)
    mass = np.asarray(moved.structure_mass)
    assert mass[1] == mass[3] and mass[2] == mass[4]  # both legs alike


def test_a_continuous_ratio_is_its_catalogue_gearhead_and_steps_smoothly_between_stages():
    """At every catalogue ratio of the 2- to 4-stage GP 32 A the continuous design carries that
    gearhead's own data; between two stages the data move monotonically with a derivative in log N
    that is continuous (zero at both ends of the gap, equal to central differences inside)."""
    catalogue = drive_model.load_catalogue()
    reference = codesign.catalogue_design()
    fields = ("gear_efficiency", "gear_inertia", "gear_mass", "gear_torque_limit", "gear_speed_limit")
    for name, head in catalogue.gearheads.items():
        if head.stages < 2:
            continue
        continuous = codesign.with_ratio(reference, jnp.full(4, np.log(head.ratio)))
        part = codesign.catalogue_design(gearhead=name)
        for field in fields:
            np.testing.assert_allclose(getattr(continuous, field), getattr(part, field), rtol=1e-12,
                                       err_msg=f"{name} {field}")
    efficiency = lambda t: codesign.with_ratio(reference, jnp.full(4, t)).gear_efficiency[0]  # noqa: E731
    slope = jax.grad(efficiency)
    low, high = np.log(33.0), np.log(51.0)  # the gap between the 2- and 3-stage gearheads
    for edge in (low, high):
        assert abs(float(slope(edge - 1e-9))) < 1e-6 and abs(float(slope(edge + 1e-9))) < 1e-6
    inside = np.linspace(low, high, 7)[1:-1]
    values = np.array([float(efficiency(t)) for t in inside])
    assert np.all(np.diff(values) < 0)  # 0.75 (2 stages) down to 0.70 (3 stages)
    h = 1e-5
    for t in inside:
        central = (float(efficiency(t + h)) - float(efficiency(t - h))) / (2 * h)
        assert float(slope(t)) == pytest.approx(central, rel=1e-6)


def test_the_projected_step_keeps_every_design_within_its_bounds():
    """A huge gradient either way: with a small rate each variable moves by its rate (log N and log k_t
    by the rate, the split by SPLIT_STEP_SCALE times it); with a large one it stops on its bound; a
    variable with low = high (the second design's own windings and split, held) never moves."""
    import optax

    theta = np.stack([codesign.design_variables(codesign.catalogue_design())] * 2)
    theta[0, codesign.PLACEMENT] = 0.5  # inside its bounds (a catalogue design's drives sit at the knees)
    theta = jnp.asarray(theta)
    low, high = (np.tile(b, (2, 1)) for b in codesign.design_bounds())
    held = np.r_[codesign.WINDINGS.start:codesign.PLACEMENT.stop]
    low[1, held], high[1, held] = theta[1, held], theta[1, held]
    adam = optax.inject_hyperparams(optax.adam)(learning_rate=0.25)
    rates = np.ones(11)
    rates[codesign.SPLIT] = codesign.SPLIT_STEP_SCALE
    for rate in (0.1, 4.0):
        state = jax.vmap(adam.init)(theta)
        state.hyperparams["learning_rate"] = jnp.full(2, rate)
        for sign in (1.0, -1.0):
            trial, _ = optimise._projected_step(adam, jnp.full((2, 11), 1e6 * sign), state, theta, jnp.asarray(rates),
                                                jnp.asarray(low), jnp.asarray(high))
            trial = np.asarray(trial)
            assert np.all(trial >= low) and np.all(trial <= high)
            np.testing.assert_array_equal(trial[1, held], theta[1, held])
            if rate < 1:  # inside the bounds: Adam's first step is the rate against the gradient's sign
                np.testing.assert_allclose(np.asarray(theta)[0] - trial[0], sign * rate * rates, rtol=1e-6)
            else:  # on the bound the gradient points away from
                np.testing.assert_array_equal(trial[0], low[0] if sign > 0 else high[0])
    # what a projected step can still use: nothing of a held variable, nothing pointing out at a bound
    grad = np.array([[1.0, -1.0, 1.0, -1.0] * 2 + [1.0, 1.0, -1.0]] * 2)
    at_bounds = np.where(grad > 0, low, high)  # every variable on the bound its gradient points out of
    assert not np.any(codesign.projected_gradient(grad, at_bounds, low, high))
    free = codesign.projected_gradient(grad, 0.5 * (low + high), low, high)
    np.testing.assert_array_equal(free[0], grad[0])
    assert not np.any(free[1, held]) and np.all(free[1, :4] == grad[1, :4])


def test_the_winding_moves_along_the_family_at_the_motor_constant():
    """log k_t as a variable: R follows as (k_t / k_t0)^2, so R / k_t^2 (the Joule energy per torque^2)
    stays; at its own winding a design is itself; the catalogue's windings lie on that line to 1 % (the
    two datasheet windings +0.5 % and -1.0 % of the 42 V one; the estimated windings are built on it)
    and bound the variable; snapping takes the winding at or below (the voltage need grows with k_t)."""
    catalogue = drive_model.load_catalogue()
    reference = codesign.catalogue_design()
    own = codesign.with_torque_constant(reference, jnp.log(reference.torque_constant))
    np.testing.assert_allclose(own.resistance, reference.resistance, rtol=1e-14)
    moved = codesign.with_torque_constant(reference, jnp.log(jnp.array([0.0234, 0.03, 0.04, 0.0468])))
    np.testing.assert_allclose(moved.resistance / moved.torque_constant**2,
                               reference.resistance / reference.torque_constant**2, rtol=1e-13)
    assert moved.rotor_inertia is reference.rotor_inertia and moved.motor_mass is reference.motor_mass
    for motor in catalogue.motors.values():
        assert motor.resistance / motor.torque_constant**2 == pytest.approx(
            float(reference.resistance[0] / reference.torque_constant[0]**2), rel=0.01)
    assert codesign.winding_range(catalogue) == pytest.approx((0.0234, 0.0468))
    assert codesign.nearest_winding(0.0409, catalogue) == "RE25-42V"
    assert codesign.nearest_winding(0.0408, catalogue) == "RE25-118754"  # 35.6 mNm/A, below
    assert codesign.nearest_winding(0.01, catalogue) == "RE25-118752"  # the smallest
    assert codesign.nearest_winding(0.1, catalogue) == "RE25-48V"
    with pytest.raises(ValueError, match="torque_constant must be positive"):
        codesign.nearest_winding(-1.0, catalogue)
    low, high = codesign.design_bounds()
    np.testing.assert_allclose(np.exp(low[codesign.WINDINGS]), 0.0234)
    np.testing.assert_allclose(np.exp(high[codesign.WINDINGS]), 0.0468)
    with pytest.raises(ValueError, match="torque_constant_bounds must be"):
        codesign.design_bounds(torque_constant_bounds=(0.05, 0.02))


@pytest.mark.slow
def test_the_gait_holds_the_gears_torque_and_input_speed(design_solver, ratio_batch):
    """With ``drive_limits`` the torque bound is also the gear's intermittent torque and the motor speed
    stays within the gear's input speed: the centre design's gait exceeds neither at its catalogue
    limits; with H1's torque limit and K1's input speed set 8 % below what that gait uses, the re-solved
    gait keeps both (on the solve grid), costs more, and converges. Without ``drive_limits`` the input
    speed group has no rows (the paper's problem keeps its programs)."""
    centre, solution = ratio_batch[0][1], ratio_batch[2][1]
    trajectory = solution.trajectory
    torque, motor_speed = np.abs(np.asarray(trajectory.u)), np.abs(np.asarray(trajectory.joint_speed)) * np.asarray(
        centre.ratio)
    assert np.all(torque.max(axis=0) <= np.asarray(centre.gear_torque_limit) + 1e-6)
    assert np.all(motor_speed.max(axis=0) <= np.asarray(centre.gear_speed_limit) + 1e-6)
    tight = dataclasses.replace(
        centre, gear_torque_limit=centre.gear_torque_limit.at[0].set(0.92 * torque[:, 0].max()),
        gear_speed_limit=centre.gear_speed_limit.at[1].set(0.92 * motor_speed[:, 1].max()))
    # in the batch size of 4 the module compiled (a batch of one would compile another program)
    limited = codesign.solve_designs(design_solver, [tight] * 4, SPEED, POWER_LIMIT, x0=np.tile(solution.x, (4, 1)))[0]
    assert limited.status == nlp.CONVERGED, (limited.status, limited.violations)
    u, omega = np.abs(np.asarray(limited.trajectory.u)), np.abs(np.asarray(limited.trajectory.joint_speed))
    assert u[:, 0].max() <= 0.92 * torque[:, 0].max() + 1e-6
    assert omega[:, 1].max() * float(tight.ratio[1]) <= float(tight.gear_speed_limit[1]) + 1e-6
    assert limited.violations["gear_input_speed"] < 1e-6 and limited.cost > solution.cost
    model = gait_problem.gait_model("12kg", SPEED, POWER_LIMIT)
    for limits, rows in ((False, 0), (True, 8)):
        settings = dataclasses.replace(short_settings(), drive_limits=limits)
        groups = jax.eval_shape(lambda tr: gait_problem.constraint_groups(tr, model, settings),
                                jax.tree.map(jnp.asarray, trajectory))
        assert groups["gear_input_speed"].shape == (rows * (settings.steps + 1),)


@pytest.fixture(scope="module")
def split_batch(design_solver, ratio_batch, paper_solutions):
    """The centre design of ``ratio_batch`` at leg_fraction -+ d and thigh_share -+ d."""
    centre = ratio_batch[0][1]
    own = np.asarray(codesign.mass_split(centre))
    offsets = SPLIT_STEP * np.array([[-1, 0], [1, 0], [0, -1], [0, 1]])
    designs = [codesign.with_mass_split(centre, jnp.asarray(own + d)) for d in offsets]
    x0 = np.tile(paper_solutions[1].x, (4, 1))
    return designs, codesign.solve_designs(design_solver, designs, SPEED, POWER_LIMIT, x0=x0)


@pytest.fixture(scope="module")
def winding_batch(design_solver, ratio_batch):
    """The centre design of ``ratio_batch`` on a supply voltage 10 % below what its gait needs, at
    log k_t -+ d (all four joints; the centre twice), warm-started from its gait."""
    centre, solution = ratio_batch[0][1], ratio_batch[2][1]
    needed = codesign.design_record(centre, solution)["max_voltage_needed_V"]
    low_supply = dataclasses.replace(centre, supply_voltage=jnp.asarray(0.9 * needed))
    log_kt = np.log(np.asarray(centre.torque_constant))
    designs = [codesign.with_torque_constant(low_supply, jnp.asarray(log_kt + d))
               for d in WINDING_STEP * np.array([-1.0, 0.0, 1.0, 0.0])]
    return designs, codesign.solve_designs(design_solver, designs, SPEED, POWER_LIMIT,
                                           x0=np.tile(solution.x, (4, 1)))


@pytest.mark.slow
def test_the_winding_matters_only_where_the_voltage_limit_binds(design_solver, ratio_batch, winding_batch):
    """Along the winding family the Joule energy R (T_m / k_t)^2 is the same, only the voltage need
    k_t (R/k_t^2 T_m + omega_m) grows with k_t: with the voltage limit inactive (38 V) d J*/d log k_t
    vanishes; on a supply 10 % below the gait's need it is positive and equals central differences of
    the optima re-solved at log k_t +- d."""
    designs, _, solutions = ratio_batch
    theta = np.stack([codesign.design_variables(d) for d in designs])
    gradient = codesign.design_gradient(design_solver)(codesign.stack(designs), theta, SPEED, POWER_LIMIT, 0.2,
                                                       solutions)[1]
    assert np.max(np.abs(gradient[codesign.WINDINGS])) < 1e-6 * np.max(np.abs(gradient[codesign.RATIOS]))
    designs, solutions = winding_batch
    assert [s.status for s in solutions] == [nlp.CONVERGED] * 4
    assert solutions[1].cost > ratio_batch[2][1].cost  # the low supply costs energy
    theta = np.stack([codesign.design_variables(d) for d in designs])
    gradient = codesign.design_gradient(design_solver)(codesign.stack(designs), theta, SPEED, POWER_LIMIT, 0.2,
                                                       solutions)[1]
    finite_difference = (solutions[2].cost - solutions[0].cost) / (2 * WINDING_STEP)
    assert finite_difference > 0.01 * solutions[1].cost
    assert gradient[codesign.WINDINGS].sum() == pytest.approx(finite_difference, rel=5e-3)


@pytest.mark.slow
def test_the_gradient_check_judges_every_variable_on_its_own(design_solver, ratio_batch):
    """codesign.gradient_check at the centre design: each of the eleven variables +- its step and +- a
    quarter of it re-solved (in the batch size of 4 the module already compiled), every component within
    0.5 % of its central difference at the quarter steps, the coarser differences converging toward it
    (flat windings against 1 % of the largest component; the knee drives, at the knees, one-sided up the
    thigh). Moving the knee drives up toward the hips lowers
    the energy (the swing leg's inertia about the hip falls)."""
    designs, _, solutions = ratio_batch
    check, = codesign.gradient_check(design_solver, [designs[1]], [solutions[1]], SPEED, POWER_LIMIT, batch=4)
    assert all(check["re_solves_converged"])
    errors = "; ".join(f"{v} {e:.2g}" for v, e in zip(check["variables"], check["relative_error"]))
    assert check["max_relative_error"] < 5e-3, errors
    refinement = optimise.GRADIENT_CHECK_REFINEMENT
    np.testing.assert_allclose(check["steps"], np.asarray(check["coarse"]["steps"]) * refinement)
    # the differences converge: where the given steps leave more than 0.1 %, a quarter of them leaves less
    # (measured here with four times the steps: K1 0.92 % at 0.01 in log N, 0.10 % at 0.0025)
    fine, coarse = np.array(check["relative_error"]), np.array(check["coarse"]["relative_error"])
    assert np.all((coarse < 1e-3) | (fine < coarse)), (fine, coarse)
    envelope, central = np.array(check["envelope"]), np.array(check["central_differences"])
    assert np.max(np.abs(envelope[codesign.WINDINGS])) < 1e-6 * np.max(np.abs(envelope))
    assert np.max(np.abs(central[codesign.WINDINGS])) < 1e-3 * np.max(np.abs(central))
    assert envelope[codesign.PLACEMENT][0] < -0.01 * np.max(np.abs(envelope))
    # the one-sided differences from the design's own J*: their mean is the central difference where the
    # steps are equal; the drives' place, at the knee, has only the forward one (the central difference
    # there takes the re-solve at the knee, equal to the design's J* to the solver's tolerance)
    one_sided = np.array(check["one_sided_differences"])
    np.testing.assert_allclose(one_sided[:-1].mean(axis=1), central[:-1], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(one_sided[-1], [central[-1]] * 2, rtol=1e-5)
    smooth = check["max_relative_error_where_smooth"]
    assert smooth is None or smooth <= check["max_relative_error"]
    with pytest.raises(ValueError, match="steps must be 11 positive numbers"):
        codesign.gradient_check(design_solver, [designs[1]], [solutions[1]], SPEED, POWER_LIMIT, steps=(0.01,) * 6)


def test_a_variable_on_its_bound_is_judged_from_inside_to_second_order():
    """At an upper bound the check differences backward, at a lower one forward, through J* at the
    design and one finer (h) and one given (H) step inside: for 3 x + 5 x^2 + 7 x^3 at 0 that is
    3 - 7 h H exactly (Lagrange's three-point rule), both ways; the first-order one over H is off by 5 H."""
    cubic = lambda x: 3 * x + 5 * x**2 + 7 * x**3  # noqa: E731
    h, big = np.full(2, 0.0025), np.full(2, 0.01)
    costs = np.array([cubic(h[0]), cubic(h[1]), cubic(-h[0]), cubic(-h[1]),
                      cubic(big[0]), cubic(big[1]), cubic(-big[0]), cubic(-big[1])])
    second, first = optimise._inward(0.0, costs, h, big, np.array([1, -1]))
    np.testing.assert_allclose(second, 3 - 7 * 0.0025 * 0.01, rtol=1e-10)
    np.testing.assert_allclose(first, [3 - 5 * 0.01 + 7e-4, 3 + 5 * 0.01 + 7e-4], rtol=1e-10)
    low, high = codesign.design_bounds()
    theta = (low + high) / 2
    theta[0], theta[8] = high[0], low[8]
    assert optimise._at_bound(theta, (low, high)).tolist() == [1] + [0] * 7 + [-1, 0, 0]


def test_a_kink_is_told_from_curvature_by_the_one_sided_differences():
    """|theta| at 0 (one-sided differences -1 and 1) is a kink; theta^2 + theta at 0 with steps 0.01
    (0.99 and 1.01) is not; a flat variable under the floor is not either."""
    theta, step = np.zeros(3), 0.01
    points = np.concatenate([np.diag(np.full(3, step)), -np.diag(np.full(3, step))])
    functions = (np.abs, lambda t: t**2 + t, lambda t: 1e-9 * np.abs(t))
    costs = [functions[i % 3](points[i, i % 3]) for i in range(6)]
    one_sided = optimise._one_sided(0.0, costs, theta, points)
    np.testing.assert_allclose(one_sided, [[-1.0, 1.0], [0.99, 1.01], [-1e-9, 1e-9]], rtol=1e-9)
    assert optimise.kinks(one_sided, floor=0.01).tolist() == [True, False, False]


@pytest.mark.slow
def test_gradient_of_the_optimal_joule_energy_matches_re_solved_optima(design_solver, ratio_batch, split_batch):
    """Envelope-theorem gradient of J* at the centre design, with the interior point's multipliers,
    against central differences of the optima re-solved at log N +- d (all four joints together) and
    at the mass split's two fractions +- d."""
    designs, log_ratio, solutions = ratio_batch
    theta = np.stack([codesign.design_variables(d) for d in designs])
    gradient = codesign.design_gradient(design_solver)(codesign.stack(designs), theta, SPEED, POWER_LIMIT,
                                                       0.2, solutions)
    finite_difference = (solutions[2].cost - solutions[0].cost) / (2 * LOG_STEP)
    # 0.5 %: at 66:1 the gait meets H1's gear torque (interpolated in log N between the stages) and K1's
    # input speed (which falls as 1/N), so J* bends more within the +-d of the differences (0.24 % here)
    assert gradient[1, :4].sum() == pytest.approx(finite_difference, rel=5e-3)
    np.testing.assert_allclose(gradient[3], gradient[1], rtol=1e-12)
    _, split_solutions = split_batch
    assert [s.status for s in split_solutions] == [nlp.CONVERGED] * 4
    for variable in (0, 1):  # leg_fraction, thigh_share
        minus, plus = split_solutions[2 * variable], split_solutions[2 * variable + 1]
        finite_difference = (plus.cost - minus.cost) / (2 * SPLIT_STEP)
        assert gradient[1, codesign.SPLIT][variable] == pytest.approx(finite_difference, rel=5e-3), variable
    # the ratio-only gradient is the same program's first four columns
    per_joint = codesign.ratio_gradient(design_solver)(codesign.stack(designs), np.tile(log_ratio[:, None], (1, 4)),
                                                        SPEED, POWER_LIMIT, 0.2, solutions)
    np.testing.assert_allclose(per_joint, gradient[:, :4], rtol=1e-12)


@pytest.mark.slow
def test_co_optimisation_lowers_the_joule_energy_and_stops_when_every_design_is_frozen(
        design_solver, ratio_batch, paper_solutions):
    """One iteration from the batch's four designs: no design's optimum gets dearer (a worse trial is
    undone), the hips and K2 go to higher ratios where they move (the sign of the gradient at 66:1,
    where the current per joint torque falls as 1/N; K1's gait runs its gear at the input speed limit,
    N |qdot| = 6000 rpm, which pulls K1's ratio down), and the path records both iterates. With a step floor above
    the step, every design is frozen at once: no trial is solved."""
    designs, _, solutions = ratio_batch
    x0 = np.tile(paper_solutions[1].x, (4, 1))
    messages = []
    path = codesign.co_optimise(design_solver, designs, SPEED, POWER_LIMIT, x0=x0, iterations=1,
                                max_step=0.1, solutions=solutions, progress=messages.append)
    assert len(path.ratios) == len(path.joule) == 2
    before, after = np.array(path.joule[0]), np.array(path.joule[1])
    np.testing.assert_allclose(before, [s.cost for s in solutions], rtol=1e-12)
    assert np.all(after <= before) and np.any(after < before)
    not_k1 = np.array([0, 2, 3])
    moved = np.array(path.ratios[1])[:, not_k1] != np.array(path.ratios[0])[:, not_k1]
    assert np.all(np.array(path.ratios[1])[:, not_k1][moved] > np.array(path.ratios[0])[:, not_k1][moved])
    assert [s.cost for s in path.solutions] == list(after)
    # with the mass split free too: a design whose gait did not converge is masked (it keeps its point)
    # and never moves the others, which take the same step as in a batch without it
    # (the windings free as well: at 38 V their gradient is flat, so they stay)
    split = [codesign.co_optimise(design_solver, designs, SPEED, POWER_LIMIT, x0=x0, iterations=1, max_step=0.1,
                                  solutions=given, mass_split_bounds=codesign.MASS_SPLIT_BOUNDS,
                                  torque_constant_bounds=codesign.winding_range())
             for given in (solutions, [dataclasses.replace(solutions[0], status=nlp.ITERATION_LIMIT)] + solutions[1:])]
    free, masked = split
    assert masked.mass_splits[1][0] == masked.mass_splits[0][0] and masked.ratios[1][0] == masked.ratios[0][0]
    np.testing.assert_allclose(np.array(masked.mass_splits[1])[1:], np.array(free.mass_splits[1])[1:], rtol=1e-12)
    np.testing.assert_allclose(np.array(masked.joule[1])[1:], np.array(free.joule[1])[1:], rtol=1e-10)
    assert np.all(np.array(free.joule[1]) <= np.array(free.joule[0]))
    assert np.any(np.array(free.mass_splits[1]) != np.array(free.mass_splits[0]))
    np.testing.assert_array_equal(free.torque_constants[1], free.torque_constants[0])
    # the projected-gradient rule: with a tolerance no gradient passes, every design is stationary at once
    still = codesign.co_optimise(design_solver, designs, SPEED, POWER_LIMIT, x0=x0, iterations=3, max_step=0.1,
                                 solutions=solutions, gradient_tolerance=1e3, progress=messages.append)
    assert len(still.ratios) == 1 and still.stationary == [True] * 4 and "every design stationary" in messages[-1]
    frozen = codesign.co_optimise(design_solver, designs, SPEED, POWER_LIMIT, x0=x0, iterations=3,
                                  max_step=0.1, min_step=1.0, solutions=solutions, progress=messages.append)
    assert len(frozen.ratios) == 1 and "stopped after 0 iterations" in messages[-1]
    with pytest.raises(ValueError, match="one solution per design: 3 for 4"):
        codesign.co_optimise(design_solver, designs, SPEED, POWER_LIMIT, solutions=solutions[:3])


def test_the_reduction_against_the_paper_design_says_why_where_there_is_none():
    from biped_jax.studies import codesign as codesign_study
    paper, best = {"status": "converged", "joule_energy_J": 5.0}, {"joule_energy_J": 1.25}
    assert codesign_study.energy_reduction(paper, best) == {"paper_joule_energy_J": 5.0, "best_joule_energy_J": 1.25,
                                                            "reduction": 0.75}
    assert codesign_study.energy_reduction(paper, None) is None
    reduction = codesign_study.energy_reduction({"status": "grid dependent", "joule_energy_J": 9.0}, best)
    assert reduction["reduction"] is None and "no converged gait (grid dependent)" in reduction["reason"]


def test_the_verdicts_per_joint_agree_with_the_check_of_all_joints_together(paper_solutions):
    """Study (d)'s verdicts check each joint's motor and gearhead on its own samples: together they
    pass exactly when the selection's check of all four joints on one drive passes, with the same RMS
    torque; the thermal margin is 1 - RMS / nominal motor torque."""
    from biped_jax.drives import selection
    from biped_jax.studies import codesign as codesign_study
    catalogue = drive_model.load_catalogue()
    solution = paper_solutions[1]  # M2
    for motor, head in (("RE25-42V", "GP32A-66.22"), ("RE25-118754", "GP32A-51"), ("RE25-48V", "GP32A-190")):
        verdicts = selection.joint_verdicts((motor,) * 4, (head,) * 4, solution, 38.0, catalogue)
        trajectory = solution.trajectory
        whole = selection.check_drive(selection.JointWorkspace(
            np.asarray(trajectory.t), np.asarray(trajectory.joint_speed), np.asarray(trajectory.u),
            solution.step_time_s), catalogue.motor(motor), catalogue.gearhead(head), 38.0)
        assert all(v["feasible"] for v in verdicts) == whole["feasible"]
        assert all(v["feasible_without_thermal"] for v in verdicts) == whole["feasible_without_thermal"]
        worst = min(v["thermal_margin"] for v in verdicts)
        assert worst == pytest.approx(1 - whole["rms_motor_torque_mNm"] * 1e-3 / catalogue.motor(motor).nominal_torque)
    assert codesign_study.lowest_energy([{"joule_energy_J": 3.0}, {"joule_energy_J": 2.0}, {"joule_energy_J": 1.0}],
                                        [0, 1]) == 1
    assert codesign_study.lowest_energy([], []) is None


def test_the_codesign_command_names_each_problems_best_design_and_its_verdicts(tmp_path, monkeypatch):
    """What `biped-jax codesign --quick` prints at the end, from the study's result (the study itself
    replaced: it takes minutes)."""
    from biped_jax import commands
    from biped_jax.report import progress
    from biped_jax.studies import codesign as codesign_study
    verdicts = [{"joint": "H1", "feasible": False, "reason": "gear: input speed 8000 rpm > 6000 rpm"},
                {"joint": "K1", "feasible": True, "reason": "all checks pass"}]
    best = {"gearheads": ["GP32A-190"] * 4, "motors": ["RE25-30V"] * 4, "joule_energy_per_metre_J_per_m": 5.0,
            "passes_catalogue_check": False, "drive_verdicts": verdicts}
    per_problem = {
        "M2": {"best": 3, "best_design": best, "energy_reduction_vs_paper": {"reduction": 0.8},
               "best_passing_catalogue_check": {"index": 5, "gearheads": ["GP32A-66.22"] * 4,
                                                "motors": ["RE25-42V"] * 4, "joule_energy_J": 2.5}},
        "M4": {"best": 9, "best_design": best, "best_passing_catalogue_check": None,
               "energy_reduction_vs_paper": {"reduction": None, "reason": "the paper's design has no converged gait"}},
        "M9": {"best": None}}
    monkeypatch.setattr(codesign_study, "run_codesign", lambda *args, **kwargs: {"co_optimisation": {
        "per_problem": per_problem}})
    lines = []
    monkeypatch.setattr(progress.console, "print", lambda *args, **kwargs: lines.append(" ".join(map(str, args))))
    commands.codesign(tmp_path, None, 1, quick=True)
    text = "\n".join(lines)
    assert "(d) M2: best catalogue design GP32A-190" in text and "80% below the paper's design" in text
    assert "fails the catalogue check: H1 gear: input speed 8000 rpm > 6000 rpm" in text
    assert "the best passing the catalogue check: GP32A-66.22" in text and "2.5 J per step" in text
    assert "the paper's design has no converged gait" in text and "no converged design passes" in text
    assert "(d) M9: no snapped design has a converged gait" in text


def test_the_study_starts_from_the_paper_design_and_snaps_each_joint_to_the_catalogue():
    """Study (d)'s starts: the paper's design, then Sobol points within the bounds; the snap takes per
    joint the nearest gearhead and the winding at or below, the split kept."""
    from biped_jax.studies import codesign as codesign_study
    catalogue = drive_model.load_catalogue()
    paper = codesign.catalogue_design(mass_class="18kg", catalogue=catalogue)
    low, high = codesign.design_bounds()
    starts = codesign_study.design_starts(paper, 8, low, high)
    assert starts.shape == (8, 11) and np.all(starts >= low) and np.all(starts <= high)
    np.testing.assert_allclose(starts[0], codesign.design_variables(paper), rtol=1e-14)
    assert len({tuple(row) for row in starts}) == 8
    np.testing.assert_array_equal(codesign_study.design_starts(paper, 8, low, high), starts)  # seeded
    theta = codesign.design_variables(paper)
    theta[codesign.RATIOS] = np.log([180.0, 60.0, 20.0, 100.0])
    theta[codesign.WINDINGS] = np.log([0.040, 0.0409, 0.030, 0.0234])
    theta[codesign.SPLIT] = [0.3, 0.6]
    theta[codesign.PLACEMENT] = 0.8
    continuous = codesign.with_variables(paper, jnp.asarray(theta))
    motors, heads, design = codesign_study.snapped_design(continuous, "18kg", catalogue)
    assert motors == ("RE25-118754", "RE25-42V", "RE25-30V", "RE25-118752")
    assert heads == ("GP32A-190", "GP32A-66.22", "GP32A-21", "GP32A-103")
    np.testing.assert_allclose(design.torque_constant, [catalogue.motor(m).torque_constant for m in motors])
    np.testing.assert_allclose(design.resistance, [catalogue.motor(m).resistance for m in motors])
    np.testing.assert_allclose(design.ratio, [catalogue.gearhead(h).ratio for h in heads])
    np.testing.assert_allclose(codesign.mass_split(design), [0.3, 0.6], rtol=1e-12)
    np.testing.assert_allclose(design.drive_offset, [0.0, 0.8, 0.0, 0.8])
    with pytest.raises(ValueError, match="give one motor or four"):
        codesign.catalogue_design(("RE25-42V",) * 3)


def test_the_study_runs_its_designs_in_eight_lanes_on_a_cpu_unless_told():
    """Study (d)'s lanes: 8 on the CPU the tests run on (measured the fastest on 2 cores), the user's
    number where given (``biped-jax codesign --lanes``)."""
    from biped_jax.studies import codesign as codesign_study
    assert jax.default_backend() == "cpu"
    assert codesign_study.design_lanes() == codesign_study.CPU_LANES == 8
    assert codesign_study.design_lanes(32) == 32
