"""DONALD under contact in MJX: standing weight, the drive-limited PD loop, and a short walk."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from biped_jax.donald import model as donald
from biped_jax.drives import model as drive_model
from biped_jax.studies import donald as donald_study

STEPS = 2  # one compiled walker (2 steps) serves every test here

#: The walker's program is `biped-jax donald --steps 2`'s too (tests/test_cli.py): one worker runs both
#: (pytest-xdist --dist loadgroup), so that it compiles once.
pytestmark = pytest.mark.xdist_group("donald")


@pytest.fixture(scope="module")
def setup():
    drive = donald.donald_drive()
    mj_model, model = donald.load_donald(drive)
    # the same program as `biped-jax donald --steps 2` (shared through the persistent cache)
    duration = float(donald.keyframes(donald.DEFAULT_GAIT, STEPS)[1][-1]) + donald_study.FINAL_STAND
    return mj_model, model, drive, donald.walker(mj_model, STEPS, duration)


@pytest.fixture(scope="module")
def standing(setup):
    """Feet never lift: no tilt, no swing; the pendulum still moves out and holds."""
    _, model, drive, walk = setup
    gait = dataclasses.replace(donald.DEFAULT_GAIT, step_angle=jnp.asarray(0.0), lift_angle=jnp.asarray(0.0))
    return walk(model, gait, donald.DEFAULT_GAINS, drive)


@pytest.fixture(scope="module")
def walking(setup):
    _, model, drive, walk = setup
    return walk(model, donald.DEFAULT_GAIT, donald.DEFAULT_GAINS, drive)


def test_standing_robot_ground_force_equals_its_weight(setup, standing):
    mj_model = setup[0]
    weight = float(mj_model.body_mass.sum()) * 9.81
    force = np.asarray(standing.ground_force)
    t = np.asarray(standing.t)
    still = (t > 0.2) & (t < donald.SETTLE_TIME)  # settled on the soft contacts, pendulum not yet moving
    np.testing.assert_allclose(force[still, 2], weight, rtol=1e-3)
    np.testing.assert_allclose(force[still, :2], 0.0, atol=1e-3 * weight)
    assert np.all(donald.support_phases(standing)[0][still])  # both feet down


def test_pd_loop_holds_the_pendulum_with_the_expected_stiffness(standing):
    """At the end the pendulum holds its angle against gravity: error = m g l sin(q) / K_p."""
    spec = donald.DonaldSpec()
    q = float(np.asarray(standing.joint_angle)[-1, donald.PENDULUM])
    q_ref = float(np.asarray(standing.reference)[-1, donald.PENDULUM])
    gravity_torque = spec.pendulum_mass * 9.81 * spec.pendulum_length * np.sin(abs(q))
    expected_error = gravity_torque / float(donald.DEFAULT_GAINS.stiffness[donald.PENDULUM])
    assert abs(q_ref) == pytest.approx(float(donald.DEFAULT_GAIT.pendulum_angle))
    assert abs(q_ref - q) == pytest.approx(expected_error, rel=0.03)
    assert abs(float(np.asarray(standing.joint_speed)[-1, donald.PENDULUM])) < 1e-3


def test_drive_limits_follow_the_motor_line():
    """Torque limits from the datasheet numbers: k_t (+-V - k_t N omega) / R through the gear."""
    drive = donald.donald_drive()
    motor = drive_model.load_catalogue().motors[donald.DONALD_MOTOR]
    n, eta, v = 245.96, 0.60, donald.DONALD_SUPPLY_VOLTAGE
    speed = jnp.array([0.0, 1.0, 3.0, 3.9, 4.5, -2.0])
    low, high = (np.asarray(a) for a in drive_model.torque_limits(drive, speed))
    omega_m = n * np.asarray(speed)
    motor_high = motor.torque_constant * (v - motor.torque_constant * omega_m) / motor.resistance
    motor_low = motor.torque_constant * (-v - motor.torque_constant * omega_m) / motor.resistance
    expected_high = np.clip(np.where(motor_high * speed >= 0, eta, 1 / eta) * n * motor_high, -6.5, 6.5)
    expected_low = np.clip(np.where(motor_low * speed >= 0, eta, 1 / eta) * n * motor_low, -6.5, 6.5)
    np.testing.assert_allclose(high, expected_high, rtol=1e-12)
    np.testing.assert_allclose(low, expected_low, rtol=1e-12)
    # at the no-load speed the drive gives no more torque forward
    no_load = v / motor.torque_constant / n
    assert float(drive_model.torque_limits(drive, jnp.asarray(no_load))[1]) == pytest.approx(0.0, abs=1e-9)
    # the PD command is applied inside the limits and clipped onto them outside
    applied, command, _ = donald.pd_torque(donald.DEFAULT_GAINS, drive, jnp.zeros(5), jnp.full(5, 3.9),
                                           jnp.full(5, 0.2), jnp.full(5, 3.9))
    limit = float(drive_model.torque_limits(drive, jnp.asarray(3.9))[1])
    expected = np.minimum(np.asarray(command), limit)
    np.testing.assert_allclose(applied, expected, rtol=1e-12)
    assert np.any(np.asarray(command) > limit)  # the test exercises saturation


def test_walk_saturates_exactly_on_the_recorded_limits(walking):
    torque, command = np.asarray(walking.torque), np.asarray(walking.command)
    low, high = np.asarray(walking.torque_limit)[:, 0], np.asarray(walking.torque_limit)[:, 1]
    assert np.all(torque >= low - 1e-12) and np.all(torque <= high + 1e-12)
    np.testing.assert_allclose(torque, np.clip(command, low, high), atol=1e-12)


def test_short_walk_makes_forward_progress_statically_stable(walking):
    report = donald.walk_report(walking, donald.donald_drive(), donald.DEFAULT_GAINS)
    assert report["steps"] == STEPS
    assert not report["fell"]
    assert report["distance_m"] > 0.04  # about leg length x sin(step angle) per step after the first
    assert report["min_support_margin_m"] > 0.0
    assert report["single_support_fraction"] > 0.1


def test_unknown_drive_parts_are_named():
    with pytest.raises(ValueError, match="'RE99'"):
        donald.donald_drive(motor="RE99")
    with pytest.raises(ValueError, match="'GP32A-7'"):
        donald.donald_drive(gear="GP32A-7")


@pytest.mark.slow
def test_default_gait_is_feasible_for_the_speed_optimisation():
    """The optimiser starts from a feasible point: the default gait keeps the stability margin, foot
    clearance and pelvis height with the single-iteration (differentiable) contact solver, and the
    objective is the speed over steps 2 and 3 recomputed here from the centre of mass."""

    from biped_jax.donald import speed as donald_speed
    drive = donald.donald_drive()
    mj_model, model = donald_speed.differentiable_donald(drive)
    assert mj_model.opt.iterations == 1
    walk = donald.walker(mj_model, donald_speed.STEPS, donald_speed.DURATION)
    z = jnp.ones(len(donald_speed.PARAMETERS))
    # op by op around the compiled walk: the walk below is then the same program, compiled once
    objective, equalities, inequalities = donald_speed.speed_and_constraints(
        z, walk, model, donald.DEFAULT_GAINS, drive)
    assert equalities.size == 0 and float(jnp.max(inequalities)) <= 0  # at the duration bounds
    gait = donald_speed.gait_from_vector(z)  # the default gait
    for field in dataclasses.fields(gait):
        assert float(getattr(gait, field.name)) == pytest.approx(float(getattr(donald.DEFAULT_GAIT, field.name)))
    run = walk(model, gait, donald.DEFAULT_GAINS, drive)
    _, times = donald.keyframes(donald.DEFAULT_GAIT, donald_speed.STEPS)
    t, com_x = np.asarray(run.t), np.asarray(run.com)[:, 0]
    start, end = float(times[5]), float(times[13])  # ends of steps 1 and 3
    speed = (np.interp(end, t, com_x) - np.interp(start, t, com_x)) / (end - start)
    assert -0.01 * float(objective) == pytest.approx(speed, rel=1e-9)
    assert speed > 0.01


@pytest.mark.parametrize("changes, verified", [
    ({}, True),
    ({"fell": True}, False),
    ({"steps": 5}, False),  # a step short
    ({"min_support_margin_m": 0.004}, False),  # under the 5 mm verification margin
    ({"min_support_margin_m": float("nan")}, False),  # never in single support
])
def test_a_faster_gait_counts_only_when_the_full_solver_walks_it(changes, verified):
    report = {"fell": False, "steps": 6, "min_support_margin_m": 0.02} | changes
    assert donald_study.is_verified(report, steps=6) is verified


def test_a_walk_shorter_than_its_gait_is_rejected():
    needed = donald_study.walk_duration(donald.DEFAULT_GAIT, 2)
    with pytest.raises(ValueError, match="shorter than the gait's 2 steps"):
        donald_study.walk(2, duration=needed - 0.5)


def test_central_differences_give_the_exact_gradient_of_a_quadratic():
    """Central differences are exact for quadratics (whatever the step), through vmap, for the objective
    and every constraint; the value is the function's own and the parameters get no derivative."""
    import jax

    from biped_jax.optim import nlp
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
    np.testing.assert_allclose(smoothed(x[0], p[0])[0], evaluate(x[0], p[0])[0], rtol=0)
    assert float(jnp.abs(jax.grad(lambda p_: smoothed(x[0], p_)[0])(p[0])).max()) == 0.0


def projection(z, _params):
    """min |z - (2, 1)|^2 subject to z1 + z2 <= 2 and z1 >= -5: the optimum (1.5, 0.5), the first
    constraint active with multiplier 1, the second inactive."""
    return jnp.sum((z - jnp.array([2.0, 1.0])) ** 2), jnp.zeros(0), jnp.array([z[0] + z[1] - 2.0, -5.0 - z[0]])


def test_the_speed_optimisers_loop_finds_a_known_constrained_optimum():
    """DONALD's own augmented Lagrangian over optax's L-BFGS (biped_jax.donald.speed.minimise) on a
    problem with a known optimum: converged there, the multiplier update settled; with one outer
    iteration only it says "iteration limit", not converged."""
    from biped_jax.donald import speed as donald_speed
    from biped_jax.optim import nlp
    heard = []
    result = donald_speed.minimise(projection, jnp.zeros(2), progress=lambda i, row: heard.append(row))
    assert result["status"] == nlp.CONVERGED
    np.testing.assert_allclose(result["z"], [1.5, 0.5], atol=1e-3)
    assert result["cost"] == pytest.approx(0.5, abs=1e-3) and result["start_cost"] == pytest.approx(5.0)
    assert result["violation"] <= donald_speed.SPEED_OPTIONS.tolerance
    assert len(heard) == len(result["iterates"]) >= 2
    short = donald_speed.minimise(projection, jnp.zeros(2), dataclasses.replace(donald_speed.SPEED_OPTIONS,
                                                                                max_outer=1))
    assert short["status"] == nlp.ITERATION_LIMIT
