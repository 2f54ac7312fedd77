"""The free-base flat-foot humanoid in MJX: momentum balance under contact and in flight, the drives'
armature and torque clipping."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from biped_jax.drives import model as drive_model
from biped_jax.humanoid import free_base
from biped_jax.robots import registry
from biped_jax.robots.mjcf import HUMANOID_ACTUATED_JOINTS

mjx = registry.import_mjx()

STEPS = 60


@pytest.fixture(scope="module")
def robot():
    mj_model = free_base.free_base_humanoid("12kg")
    return mj_model, free_base.FreeLayout.of(mj_model), registry.put_mjx_model(mj_model)


@jax.jit
def _momenta(model, data, torques):
    """Euler steps under joint ``torques`` (steps, 16): per step (linear momentum, angular momentum about
    the centre of mass, the ground's force on the robot) at the step's start. One program for every
    rollout of the same length (the model, its time step included, is an argument)."""
    def step(data, u):
        data = mjx.forward(model, data.replace(ctrl=u))
        linear, angular = free_base.momentum(model, data)
        ground = jnp.sum(free_base.external_forces(model, data), axis=0)
        return mjx.euler(model, data), (linear, angular, ground)
    return jax.lax.scan(step, data, torques)[1]


def _rollout(model, layout, qpos, qvel, torques, dt=free_base.TIMESTEP):
    """:func:`_momenta` from (qpos, qvel) with the model's time step ``dt``, s."""
    model = model.replace(opt=model.opt.replace(timestep=jnp.asarray(dt, dtype=jnp.float64)))
    data = mjx.make_data(model).replace(qpos=qpos, qvel=qvel)
    return jax.tree.map(np.asarray, _momenta(model, data, torques))


def _standing(mj_model, layout, height):
    qpos = np.array(mj_model.qpos0)
    qpos[2] += height  # the model stands on its soles
    return jnp.asarray(qpos)


def test_the_ground_force_is_the_change_of_momentum_under_contact(robot):
    """Dropped 5 mm onto its flat feet with random joint torques: per 1 ms step the linear momentum
    changes by (ground force + weight) dt, the force read from MJX's constraint forces (what the walk
    reports per touchdown), while the feet carry it (the force reaches the weight)."""
    mj_model, layout, model = robot
    torques = jnp.asarray(np.random.default_rng(0).normal(0.0, 0.5, (STEPS, mj_model.nu)))
    linear, _, ground = _rollout(model, layout, _standing(mj_model, layout, 0.005), jnp.zeros(mj_model.nv), torques)
    weight = np.array([0.0, 0.0, -9.81 * layout.mass])
    change = np.diff(linear, axis=0) / free_base.TIMESTEP
    expected = ground[:-1] + weight
    assert np.max(ground[:, 2]) > 0.8 * 9.81 * layout.mass  # the contact carried it
    assert np.min(ground[:5, 2]) == 0.0  # and the first steps were in flight
    scale = 9.81 * layout.mass
    assert np.max(np.abs(change - expected)) < 0.02 * scale


def test_in_flight_the_joints_move_neither_the_centre_of_mass_nor_the_angular_momentum(robot):
    """High above the ground with random joint torques: the linear momentum changes by the weight alone
    and the angular momentum about the centre of mass stays (the torques are internal), to the Euler
    step's first-order error: over the same 30 ms, halving the time step halves both errors (one
    program for every rollout here: the step is a model array, the number of steps the same)."""
    mj_model, layout, model = robot
    rng = np.random.default_rng(1)
    qvel = np.zeros(mj_model.nv)
    qvel[:6] = rng.normal(0.0, 0.5, 6)
    torques = rng.normal(0.0, 1.0, (STEPS, mj_model.nu))  # one row per millisecond
    errors = []
    for repeat in (1, 2):
        dt = free_base.TIMESTEP / repeat
        linear, angular, ground = _rollout(model, layout, _standing(mj_model, layout, 1.0), jnp.asarray(qvel),
                                           jnp.asarray(np.repeat(torques, repeat, axis=0)[:STEPS]), dt)
        window = STEPS // 2 * repeat  # the first 30 ms
        assert np.all(ground == 0.0)
        weight = np.array([0.0, 0.0, -9.81 * layout.mass])
        errors.append((np.max(np.abs(np.diff(linear[:window], axis=0) / dt - weight)),
                       np.max(np.linalg.norm(angular[:window] - angular[0], axis=1))))
    (linear_error, angular_drift), (linear_half, angular_half) = errors
    assert linear_error < 0.01 * 9.81 * layout.mass
    assert 1.6 < linear_error / linear_half < 2.5
    assert 1.6 < angular_drift / angular_half < 2.5


def test_every_joint_carries_its_drives_reflected_inertia(robot):
    mj_model, layout, _ = robot
    drives = free_base.walk_drives()
    np.testing.assert_allclose(mj_model.dof_armature[list(layout.qvel)], float(drives.reflected_inertia))
    assert np.all(mj_model.dof_armature[:6] == 0.0)  # not on the free base


def test_the_torque_is_clipped_to_the_speed_torque_line_at_the_joints_speed():
    """Inside the line the command passes; beyond it the applied torque is the line's value at that
    speed (the gear's 6.5 N m at low speed, less where the back EMF bites), on both sides."""
    drives = free_base.walk_drives()
    speed = jnp.array([0.0, 0.0, 12.0, 12.0, -12.0, 12.0])
    command = jnp.array([3.0, -20.0, 20.0, 1.0, -20.0, -20.0])
    applied, (low, high) = free_base.drive_torques(drives, command, speed)
    ref_low, ref_high = drive_model.torque_limits(drives, speed)
    np.testing.assert_allclose(low, ref_low)
    np.testing.assert_allclose(high, ref_high)
    assert float(high[0]) == pytest.approx(6.5) and float(low[1]) == pytest.approx(-6.5)
    assert float(high[2]) < 6.5  # the motor's line at 12 rad/s, below the gear's limit
    np.testing.assert_allclose(applied, [3.0, -6.5, float(high[2]), 1.0, float(low[4]), float(low[5])])


def test_two_drives_in_parallel_give_twice_the_line_and_the_inertia():
    """Two of the drives on each hip roll: twice the torque at every speed on both sides (the same no-load
    speed), twice the gear's limit and the reflected inertia; the other joints keep one drive."""
    one, two = free_base.walk_drives(), free_base.walk_drives(parallel=("hip_roll",))
    rolls = [i for i, name in enumerate(HUMANOID_ACTUATED_JOINTS) if name.startswith("hip_roll")]
    others = [i for i in range(len(HUMANOID_ACTUATED_JOINTS)) if i not in rolls]
    for speed in (0.0, 8.0, -15.0, 40.0):
        single = np.asarray(drive_model.torque_limits(one, jnp.full(16, speed)))
        double = np.asarray(drive_model.torque_limits(two, jnp.full(16, speed)))
        np.testing.assert_allclose(double[:, rolls], 2 * single[:, rolls], rtol=1e-12)
        np.testing.assert_allclose(double[:, others], single[:, others], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(two.reflected_inertia)[rolls], 2 * float(one.reflected_inertia))
    assert float(np.asarray(drive_model.torque_limits(two, jnp.zeros(16))[1])[rolls[0]]) == pytest.approx(13.0)


def test_an_unknown_mass_class_or_part_is_named():
    with pytest.raises(ValueError, match="'9kg'"):
        free_base.free_base_humanoid("9kg")
    with pytest.raises(ValueError, match="GP32A-7"):
        free_base.walk_drives(gearhead="GP32A-7")
    with pytest.raises(ValueError, match="hip_rol"):
        free_base.walk_drives(parallel=("hip_rol",))
    model = free_base.free_base_humanoid("12kg")
    with pytest.raises(ValueError, match="got 2"):
        free_base.single_support_torques(model, model.qpos0, 2)
    with pytest.raises(ValueError, match=r"\(23,\)"):
        free_base.single_support_torques(model, model.qpos0[:7], 0)
    with pytest.raises(ValueError, match=r"qacc must have shape \(22,\)"):
        free_base.single_support(model)(model.qpos0, 0, qacc=np.zeros(23))


def test_standing_on_one_leg_loads_the_hip_roll_with_the_weight_beyond_it(robot):
    """MuJoCo's inverse dynamics with the ground's wrench on the stance foot: with a level pelvis the
    stance hip's roll joint carries the weight of everything beyond it times its lever arm (summed here
    body by body), whether the foot stands under the hip or under the centre of mass; there the ankle's
    roll torque vanishes (the centre of pressure under the centre of mass)."""
    mj_model, layout, _ = robot
    import mujoco
    data = mujoco.MjData(mj_model)
    mujoco.mj_kinematics(mj_model, data)
    hip = data.xpos[layout.thighs[0]]
    stance_leg = {layout.thighs[0], layout.feet[0], int(mj_model.body("shank_l").id)}
    lever = sum(mj_model.body_mass[b] * 9.81 * (hip[1] - data.xipos[b][1]) for b in range(1, mj_model.nbody)
                if b not in stance_leg)
    roll, ankle = layout.legs[0][1], layout.legs[0][5]
    standing = free_base.single_support_torques(mj_model, mj_model.qpos0, 0)
    assert standing[roll] == pytest.approx(lever, rel=1e-9) and lever > 5.0
    inclined = np.array(mj_model.qpos0)
    low, high = 0.0, 0.5  # the leg's inclination that puts the centre of mass over the foot
    for _ in range(50):
        phi = 0.5 * (low + high)
        inclined[layout.qpos[roll]], inclined[layout.qpos[ankle]] = -phi, phi
        low, high = (phi, high) if free_base.single_support_torques(mj_model, inclined, 0)[ankle] > 0 else (low, phi)
    over = free_base.single_support_torques(mj_model, inclined, 0)
    assert abs(over[ankle]) < 1e-6 * lever and over[roll] == pytest.approx(lever, rel=1e-9)
    mirrored = free_base.single_support_torques(mj_model, mj_model.qpos0, 1)
    assert mirrored[layout.legs[1][1]] == pytest.approx(-lever, rel=1e-9)


def test_a_whole_body_acceleration_loads_the_joints_as_tilted_gravity_would(robot):
    """The one-foot inverse dynamics of a motion: every body accelerating with the free base alone (a,
    joints still) needs the torques that holding still needs under gravity g - a (the equivalence
    principle), here 1 m/s^2 forward and 2 m/s^2 sideways: the stance hip's roll torque changes by more
    than 0.5 N m."""
    mj_model, layout, _ = robot
    import copy
    pose = np.array(mj_model.qpos0)
    moving = free_base.single_support(mj_model)
    a = np.array([1.0, 2.0, 0.0])
    qacc = np.zeros(mj_model.nv)
    qacc[:3] = a
    tilted = copy.deepcopy(mj_model)
    tilted.opt.gravity[:] = np.asarray(mj_model.opt.gravity) - a
    np.testing.assert_allclose(moving(pose, 0, qacc=qacc), free_base.single_support_torques(tilted, pose, 0),
                               rtol=1e-9, atol=1e-9)
    assert abs(moving(pose, 0, qacc=qacc)[layout.legs[0][1]] - moving(pose, 0)[layout.legs[0][1]]) > 0.5
