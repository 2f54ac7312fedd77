"""The humanoid replay's pieces: the planarised model, the impact map on the humanoid, the reference and
the start state taken from a solved gait (the MJX contact replay itself is exercised by the CLI)."""

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from test_humanoid_sagittal import _sagittal_equivalent

from biped_jax.dynamics import mjx_biped
from biped_jax.gait import problem as gait_problem
from biped_jax import humanoid
from biped_jax.robots import registry
from biped_jax.robots.specs import PLANAR_SPECS

pytestmark = pytest.mark.slow  # MJX humanoid rollouts: minutes on the 2-core CPU


@pytest.fixture(scope="module")
def planarised():
    model = humanoid.planarised_humanoid("12kg")
    return model, humanoid.Layout.of(model)


def _mass_matrix(model, qpos):
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    mass = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, mass)
    return mass, data.qfrc_bias.copy()


def test_planarising_constraint_keeps_the_sagittal_dynamics(planarised):
    """The planar base only removes the lateral translation, roll and yaw: at the same pose the mass
    matrix and gravity of the remaining coordinates equal the free-base humanoid's."""
    model, _ = planarised
    free = registry.load_mj_model("humanoid16_12kg")
    rng = np.random.default_rng(0)
    joints = rng.normal(scale=0.3, size=16)
    x, z, pitch = 0.1, 0.3, 0.2
    planar_q = np.concatenate([[x, z, pitch], joints])
    free_q = np.concatenate([[x, 0.0, z, np.cos(pitch / 2), 0.0, np.sin(pitch / 2), 0.0], joints])
    planar_mass, planar_bias = _mass_matrix(model, planar_q)
    free_mass, free_bias = _mass_matrix(free, free_q)
    free_columns = np.concatenate([[0, 2, 4], 6 + np.arange(16)])  # world x, z, body pitch rate, joints
    armature = np.zeros(model.nv)
    armature[[model.joint(f"ankle_{k}_{s}").dofadr[0] for k in ("pitch", "roll") for s in "lr"]] = (
        humanoid.ANKLE_ARMATURE)
    np.testing.assert_allclose(planar_mass, free_mass[np.ix_(free_columns, free_columns)] + np.diag(armature),
                               atol=1e-12)
    np.testing.assert_allclose(planar_bias, free_bias[free_columns], atol=1e-10)
    assert model.opt.timestep == humanoid.TIMESTEP


def test_impact_map_on_the_humanoid_equals_the_optimisers(planarised):
    """With the held joints locked, the humanoid's rigid impact is the optimiser's impact map of the
    planar biped whose links are the humanoid's composite bodies."""
    model, layout = planarised
    planar = _sagittal_equivalent(registry.load_mj_model("humanoid16_12kg"))
    floating = registry.put_mjx_model(planar)
    qf = np.array([0.05, 0.27, 0.15, -0.45, 0.3, 0.2, 0.25])
    qfd = np.array([0.6, -0.2, -0.4, 1.5, -2.0, -3.0, 1.0])
    # put the landing foot (leg 2) on the ground
    qf[1] -= float(mjx_biped.site_position(floating, jnp.asarray(qf), "foot2")[2])
    expected_after, expected_impulse = (np.asarray(a) for a in jax.jit(mjx_biped.impact_map)(
        floating, jnp.asarray(qf), jnp.asarray(qfd)))
    qpos, qvel = np.zeros(model.nq), np.zeros(model.nv)
    columns = humanoid.sagittal_columns(layout, 0)
    qpos[columns], qvel[columns] = qf, qfd
    jump, impulse = humanoid.rigid_impact(model, layout, qpos, qvel, stance=0)
    np.testing.assert_allclose(impulse, expected_impulse, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(qfd + jump, expected_after, rtol=1e-8, atol=1e-10)


@pytest.fixture(scope="module")
def m2_reference(short_solver):
    """M2's heuristic start simulated at the tests' horizon with the solver's compiled rollout (its stance
    angle advances monotonically, so that it phases a replay)."""
    model = gait_problem.gait_model("12kg", 0.555, 20.0)
    settings = short_solver.settings
    batch = jax.tree.map(lambda a: jnp.asarray(a, dtype=jnp.result_type(float))[None], model)
    x = gait_problem.initial_guess(model, settings, leg_length=PLANAR_SPECS["12kg"].leg_length)
    trajectory = jax.tree.map(lambda a: np.asarray(a[0]), short_solver.simulate(x[None], batch))
    return x, model, settings, trajectory, humanoid.gait_reference(x, model, settings, trajectory)


@pytest.mark.slow
def test_reference_follows_the_simulated_gait(m2_reference):
    x, model, settings, tr, reference = m2_reference
    step_time = float(model.step_length / model.speed)
    phase = np.asarray(tr.t) / step_time
    theta = np.interp(phase, np.asarray(reference.phase), np.asarray(reference.stance_angle))
    np.testing.assert_allclose(theta, np.asarray(tr.q)[:, 0], atol=1e-3)
    # the stance leg's path is the optimiser's (only the swing foot's clearance is added)
    optimal = np.asarray(gait_problem.reference(jnp.asarray(x), settings, np.asarray(reference.phase))[0])
    np.testing.assert_allclose(np.asarray(reference.joints)[:, :2], optimal[:, :2], atol=1e-12)
    swing_offset = np.abs(np.asarray(reference.joints)[:, 2:] - optimal[:, 2:])
    # none at the start (the swing foot leaves the ground); bounded elsewhere (the heuristic's foot even
    # ends below the ground, where the offset lifts it)
    assert swing_offset[0].max() < 1e-12 and swing_offset.max() < 0.5
    assert float(reference.step_time) == pytest.approx(step_time)


def test_start_state_puts_the_stance_foot_at_rest_at_the_origin(m2_reference, planarised):
    _, gait_model, _, _, reference = m2_reference
    model, layout = planarised
    qpos, qvel = humanoid.initial_state(model, layout, reference, "12kg")
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = qpos, qvel
    mujoco.mj_forward(model, data)
    stance, swing = (data.site_xpos[layout.foot_site[k]] for k in (0, 1))
    np.testing.assert_allclose(stance[[0, 2]], 0.0, atol=1e-9)
    # the heuristic start: straight legs mirrored about the vertical, both feet on the ground
    np.testing.assert_allclose(swing[[0, 2]], [-float(gait_model.step_length), 0.0], atol=1e-9)
    jac = np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jac, None, layout.foot_site[0])
    np.testing.assert_allclose(jac @ qvel, 0.0, atol=1e-9)


def test_bad_input_is_rejected(m2_reference):
    x, model, settings, trajectory, reference = m2_reference
    with pytest.raises(ValueError, match="'20kg'"):
        humanoid.planarised_humanoid("20kg")
    with pytest.raises(ValueError, match="steps must be at least 1"):
        humanoid.replay(reference, steps=0)
    # a step whose stance leg rocks back mid-step: its angle cannot phase a replay
    q = np.array(trajectory.q)
    middle = len(q) // 2
    q[middle:, 0] = q[middle, 0] - 0.1 * (q[middle:, 0] - q[middle, 0])
    rocking = dataclasses.replace(trajectory, q=q)
    with pytest.raises(ValueError, match="monotonically"):
        humanoid.gait_reference(x, model, settings, rocking)


def test_a_sliver_of_backward_stance_travel_before_touchdown_is_absorbed(m2_reference):
    """The 48-span optima swing the stance leg back by about 1e-4 rad in the last grid points: the
    replay's phase clock is then the stance angle's running maximum (flat over that sliver), while a
    reversal of more than 1 % of the range still cannot phase a replay."""
    x, model, settings, trajectory, _ = m2_reference
    q = np.array(trajectory.q)
    q[-2:, 0] = q[-3, 0] - np.array([0.5e-4, 1e-4])
    reference = humanoid.gait_reference(x, model, settings, dataclasses.replace(trajectory, q=q))
    stance_angle = np.asarray(reference.stance_angle)
    assert np.all(np.diff(stance_angle) >= 0) and stance_angle[-1] == pytest.approx(q[-3, 0], abs=1e-12)
    q[-2:, 0] = q[-3, 0] - 0.02 * (q[-3, 0] - q[0, 0])
    with pytest.raises(ValueError, match="monotonically"):
        humanoid.gait_reference(x, model, settings, dataclasses.replace(trajectory, q=q))


def test_control_law_is_feed_forward_plus_pd_on_the_phased_reference(m2_reference, planarised):
    """At the step's start the law gives u_ff + K_d qdot_ref (joints on the reference), the reference's
    rate at the nominal pace whatever the measured rates (the - K_d qdot part is the model's joint
    damping), and - K_p per radian of a swing-knee error (which leaves the phase alone)."""
    *_, reference = m2_reference
    model, layout = planarised
    gains = humanoid.DEFAULT_GAINS
    qpos, qvel = humanoid.initial_state(model, layout, reference, "12kg")
    support = humanoid.Support(stance=jnp.asarray(0), stance_angle=reference.stance_angle[0], offset=jnp.zeros(4))
    law = jax.jit(lambda q, v: humanoid.control(layout, reference, gains, q, v, support))
    u, phase, target = (np.asarray(a) for a in law(qpos, qvel))
    actuators = layout.sagittal_actuators
    assert float(phase) == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(target, np.asarray(reference.joints[0]), atol=1e-9)
    expected = (np.asarray(reference.torque[0])
                + gains.sagittal_damping * np.asarray(reference.joint_slope[0]) / float(reference.step_time)
                + gains.sagittal_stiffness * (target - qpos[layout.sagittal_q]))
    np.testing.assert_allclose(u[actuators], expected, rtol=1e-9, atol=1e-9)
    assert np.count_nonzero(np.delete(u, actuators)) == 0
    rates = qvel + np.random.default_rng(0).normal(0.0, 1.0, qvel.shape)
    np.testing.assert_allclose(np.asarray(law(qpos, rates)[0]), u, atol=1e-12)
    bent = qpos.copy()
    bent[layout.knee[1]] += 0.01
    change = np.asarray(law(bent, qvel)[0]) - u
    np.testing.assert_allclose(change[actuators], [0.0, 0.0, 0.0, -0.01 * gains.sagittal_stiffness], atol=1e-9)


def test_isolated_touchdown_balances_momentum_and_stops_the_foot(planarised):
    """A swing foot landing at 0.63 m/s on the soft ground (torques held at zero, the PD loops' damping
    acting): the robot's linear momentum changes by the landing foot's ground impulse (the other foot
    in the air; gravity and damping cancel against the twin without that contact), the ground pushes
    up and back on a foot moving down and forward, and the foot comes to rest within the window."""
    model, layout = planarised
    planar = _sagittal_equivalent(registry.load_mj_model("humanoid16_12kg"))
    floating = registry.put_mjx_model(planar)
    qf = np.array([0.05, 0.27, 0.0, 0.3, 1.2, -0.3, 0.1])  # leg 2 reaching ahead, leg 1 folded up
    qfd = np.array([0.6, -0.2, 0.0, 0.0, 0.0, 0.0, 0.0])  # the whole robot moving forward and down
    qf[1] -= float(mjx_biped.site_position(floating, jnp.asarray(qf), "foot2")[2]) - 5e-4  # 0.5 mm above the ground
    assert float(mjx_biped.site_position(floating, jnp.asarray(qf), "foot1")[2]) > 0.1
    qpos, qvel = np.zeros(model.nq), np.zeros(model.nv)
    columns = humanoid.sagittal_columns(layout, 0)
    qpos[columns], qvel[columns] = qf, qfd
    simulated = humanoid.c_model_with_gains(model, layout, humanoid.DEFAULT_GAINS)
    result = humanoid.isolated_touchdown(simulated, layout, qpos, qvel, np.zeros(model.nu), stance=0, window=0.05)
    impulse = result["impulse_Ns"]
    assert impulse[1] > 0.5 and impulse[0] < 0
    # to the Euler discretisation (the momentum is evaluated at the next positions): 5e-5 measured
    np.testing.assert_allclose(result["momentum_change_Ns"], impulse, rtol=1e-3)
    assert result["duration_s"] < 0.05
    # the model handed in is left as it was (the twin's contact switched back on)
    assert simulated.geom_contype[simulated.geom("foot_r").id] == model.geom_contype[model.geom("foot_r").id]
