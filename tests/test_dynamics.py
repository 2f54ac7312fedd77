"""Physics checks of the walking step through its one interface (:mod:`biped_jax.dynamics.interface`),
against every backend (MJX, the closed-form chain, MuJoCo C): energy, impact momentum, ground reaction,
each backend's step against MuJoCo's ``mj_step``; the pinned and floating models' agreement, MJX against
MuJoCo C, and autodiff against finite differences."""

import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from conftest import BACKENDS, GRADIENT_START, GRADIENT_STEPS, ROLLOUT_STEPS, backend

from biped_jax.dynamics import interface, mjx_biped, planar_chain
from biped_jax.robots import planar_biped, registry

#: Tests sharing a compiled MJX program (or a module fixture's) with tests elsewhere carry one xdist_group
#: (the others are grouped by module, tests/conftest.py): pytest-xdist's loadgroup runs a group on one
#: worker, in order, so that the program compiles once instead of on two workers at the same time;
#: "mjx_quickstart" (the README quickstart's programs, the 50-step rollout and MJX's touchdown, and the
#: single-support program), "mjx_gradient" (the rollout's gradient), "mjx_forward" (mjx.forward
#: per model, as tests/test_models.py).

mjx = registry.import_mjx()


@pytest.mark.xdist_group("mjx_quickstart")
def test_the_group_holds_under_xdist(request):
    """Under pytest-xdist's loadgroup the group is in the test's id (its only channel to the scheduler):
    without it the shared programs compile on two workers at once (pytest 9.2 drops it, xdist #1386)."""
    if getattr(request.config.option, "loadgroup", False):
        assert request.node.nodeid.endswith("@mjx_quickstart"), request.node.nodeid

# A generic single-support state (knees bent, legs apart, everything moving) and torques.
Q = jnp.array([0.25, 0.2, 0.15, -0.45, 0.5])
QD = jnp.array([-1.2, 0.8, 1.5, -2.0, 1.0])
U = jnp.array([3.0, -2.0, 1.5, 0.5])

# Round-off tolerances in float64 for quantities of order one (linear solves of 7x7 systems).
EXACT = 1e-10


# ----------------------------------------------------------------------------- energy

@pytest.mark.slow
@pytest.mark.xdist_group("mjx_quickstart")
@pytest.mark.parametrize("name", BACKENDS)
def test_energy_conserved_without_torque_and_error_is_first_order(biped12, rollout, name):
    """Every backend's semi-implicit Euler conserves energy to O(dt): halving dt halves the error.

    One compiled rollout of ROLLOUT_STEPS = 50 steps serves both step sizes; the errors are compared over
    the same 25 ms (25 steps at 1 ms against 50 steps at 0.5 ms).
    """
    # The energy from the closed-form chain (its own kinematics; its mass matrix is MJX's, test_planar_chain):
    # compiles in a second, MJX's in ten.
    chain = planar_chain.PlanarChain.from_model(biped12.pinned)

    @jax.jit
    def energy(model, q, qd):
        return jax.vmap(lambda q, qd: planar_chain.mechanical_energy(
            chain, model, planar_chain.kinematics(chain, model, q, qd), qd))(q, qd)

    errors = {}
    for dt, steps in ((1e-3, ROLLOUT_STEPS // 2), (5e-4, ROLLOUT_STEPS)):
        dynamics = backend(biped12, name, dt)
        trajectory = rollout(dynamics, Q, QD, jnp.zeros((ROLLOUT_STEPS, 4)))
        e = energy(biped12.pinned, trajectory.q[: steps + 1], trajectory.qd[: steps + 1])
        errors[dt] = float(jnp.max(jnp.abs(e - e[0])))
    # Stated tolerance: below 0.05 % of the ~42 J total energy at dt = 0.5 ms over 25 ms.
    assert errors[5e-4] < 0.02
    order = np.log2(errors[1e-3] / errors[5e-4])
    assert order == pytest.approx(1.0, abs=0.15), errors


# ----------------------------------------------------------------------------- ground reaction

def test_ground_reaction_of_a_robot_at_rest_is_its_weight(biped12):
    q = jnp.array([0.0, 0.3, -0.3, 0.2, 0.4])
    force = jax.jit(mjx_biped.ground_reaction)(biped12.pinned, q, jnp.zeros(5), jnp.zeros(5))
    weight = float(jnp.sum(biped12.pinned.body_mass)) * 9.81
    np.testing.assert_allclose(force, [0.0, weight], atol=EXACT * weight)


@pytest.fixture(scope="module")
def single_support(biped12):
    """One compiled program (MJX run op by op compiles every operation alone, for a minute) of
    everything the single-support checks below compare at a state (q, qd) under torques u: MJX's
    pinned-chain qdd and ground force, Newton's law for the centre of mass, and the floating model's
    accelerations under that force with what the pinned chain says they are.

    The centre of mass's and the hip's accelerations come from the closed-form planar chain
    (:mod:`biped_jax.dynamics.planar_chain`, its own kinematics: not MJX's recursive Newton-Euler and
    not MJX's composite inertia), whose second derivatives compile in seconds where MJX's take half a
    minute each."""
    pinned, floating = biped12.pinned, biped12.floating
    chain = planar_chain.PlanarChain.from_model(pinned)
    mj_floating = registry.load_mj_model("biped5_floating_12kg")
    shank1 = mujoco.mj_name2id(mj_floating, mujoco.mjtObj.mjOBJ_BODY, "shank1")
    foot1 = mujoco.mj_name2id(mj_floating, mujoco.mjtObj.mjOBJ_SITE, "foot1")

    def newton(q, qd, qdd):  # F = sum_i m_i (a_i - g), a_i = J_i qdd + Jdot_i qd of each centre of mass
        return planar_chain.root_force(chain, pinned, planar_chain.kinematics(chain, pinned, q, qd), qdd)

    def hip_acceleration(q, qd, qdd):  # d^2/dt^2 of the hip's (x, z), differentiated from its position
        def hip(q_):
            return planar_chain.site_positions(chain, pinned, planar_chain.kinematics(chain, pinned, q_, q_ * 0),
                                               ("hip",))[0]
        hip_velocity = lambda q_: jax.jvp(hip, (q_,), (qd,))[1]  # noqa: E731
        return jax.jvp(hip, (q,), (qdd,))[1] + jax.jvp(hip_velocity, (q,), (qd,))[1]

    def floating_accelerations(q, qd, u, qdd, force):  # the force applied to the free-floating model
        qf, qfd = mjx_biped.pinned_to_floating(pinned, q, qd)
        data = mjx.kinematics(floating, mjx.make_data(floating).replace(qpos=qf))
        force3 = jnp.array([force[0], 0.0, force[1]])
        torque3 = jnp.cross(data.site_xpos[foot1] - data.xipos[shank1], force3)
        xfrc = jnp.zeros((floating.nbody, 6)).at[shank1].set(jnp.concatenate([force3, torque3]))
        data = mjx.make_data(floating).replace(qpos=qf, qvel=qfd, ctrl=u, xfrc_applied=xfrc)
        qfdd = mjx.forward(floating, data).qacc
        stance, knee1, hip1, hip2, knee2 = qdd
        expected = jnp.concatenate([hip_acceleration(q, qd, qdd),
                                    jnp.stack([stance - knee1 - hip1, hip1, knee1, hip2, knee2])])
        return qfdd, expected

    @jax.jit
    def at(q, qd, u):
        qdd = mjx_biped.stance_acceleration(pinned, q, qd, u)
        force = mjx_biped.ground_reaction(pinned, q, qd, qdd)
        return {"qdd": qdd, "force": force, "newton": newton(q, qd, qdd),
                "floating": floating_accelerations(q, qd, u, qdd, force)}
    return at


@pytest.mark.xdist_group("mjx_quickstart")
@pytest.mark.parametrize("name", ["mjx", "mujoco"])
def test_ground_reaction_is_newtons_law_for_the_centre_of_mass(biped12, rollout, single_support, name):
    """MJX's ground force (its recursive Newton-Euler pass) is F = sum_i m_i (a_i - g), the centres of
    mass's accelerations from the closed-form chain; and the rollout's per-step force (MJX's, MuJoCo
    C's) is the same function of its states."""
    pinned = biped12.pinned
    assert planar_biped.STANCE_BODY == mujoco.mj_name2id(registry.load_mj_model("biped5_pinned_12kg"),
                                                          mujoco.mjtObj.mjOBJ_BODY, "shank1")
    here = single_support(Q, QD, U)
    assert float(jnp.linalg.norm(here["force"] - jnp.sum(pinned.body_mass) * 9.81 * jnp.array([0, 1]))) > 1.0
    np.testing.assert_allclose(here["force"], here["newton"], rtol=1e-10)
    trajectory = rollout(backend(biped12, name), Q, QD, jnp.tile(U, (ROLLOUT_STEPS, 1)))
    k = 37
    there = single_support(trajectory.q[k], trajectory.qd[k], U)
    np.testing.assert_allclose(trajectory.qdd[k], there["qdd"], rtol=1e-10)
    np.testing.assert_allclose(trajectory.ground_force[k], there["newton"], rtol=1e-10)


@pytest.mark.slow
@pytest.mark.xdist_group("mjx_quickstart")
def test_ground_reaction_applied_to_the_floating_model_reproduces_single_support(single_support):
    """Apply the computed foot force to the free-floating model: its joint and hip accelerations must
    equal the pinned chain's (Newton-Euler of an independent model, not the same formula)."""
    qfdd, expected = single_support(Q, QD, U)["floating"]
    np.testing.assert_allclose(qfdd, expected, atol=1e-8 * float(jnp.abs(expected).max()))


# ----------------------------------------------------------------------------- impact

def _pitch(xmat):
    return jnp.arctan2(xmat[0, 2], xmat[0, 0])


def angular_momentum_about(model, q, qd, point):
    """y-component of the floating model's angular momentum about a world point, kg m^2/s."""
    def kinematics(q_):
        data = mjx.kinematics(model, mjx.make_data(model).replace(qpos=q_))
        return data.xipos, jax.vmap(_pitch)(data.xmat)
    (position, _), (velocity, rate) = jax.jvp(kinematics, (q,), (qd,))
    r = position - point
    orbital = model.body_mass * (r[:, 2] * velocity[:, 0] - r[:, 0] * velocity[:, 2])
    return jnp.sum(orbital + model.body_inertia[:, 1] * rate)


@jax.jit  # one program for every backend's landing: op by op, MJX compiles each operation alone
def momenta_about_the_landing_foot(model, q, qd_before, qd_after):
    """The angular momentum about foot 2 before and after the touchdown (floating coordinates)."""
    foot2 = mjx_biped.site_position(model, q, "foot2")
    return angular_momentum_about(model, q, qd_before, foot2), angular_momentum_about(model, q, qd_after, foot2)


@pytest.fixture(scope="module", params=BACKENDS)
def landing(biped12, request):
    """The touchdown at (Q, QD) by each backend (one compiled program for each JAX backend)."""
    dynamics = backend(biped12, request.param)
    if request.param == "mujoco":
        return interface.touchdown(dynamics, Q, QD)
    return jax.jit(interface.touchdown)(dynamics, Q, QD)


@pytest.mark.xdist_group("mjx_quickstart")
def test_impact_conserves_angular_momentum_about_the_landing_foot(biped12, landing):
    before, after = momenta_about_the_landing_foot(biped12.floating, landing.floating_q, landing.floating_qd_before,
                                                   landing.floating_qd_after)
    assert abs(float(before)) > 0.1  # a real test: there is momentum to conserve
    assert float(after) == pytest.approx(float(before), abs=EXACT)


@pytest.mark.xdist_group("mjx_quickstart")
def test_impact_leaves_the_landing_foot_at_rest(biped12, landing):
    jac = impact_jumps(biped12.floating, landing.floating_q, landing.floating_qd_before,
                       landing.floating_qd_after)[1]  # the momentum balance's program
    assert float(jnp.linalg.norm(jac @ landing.floating_qd_before)) > 0.1
    np.testing.assert_allclose(jac @ landing.floating_qd_after, 0.0, atol=EXACT)


@jax.jit  # one program for every backend's landing (op by op, MJX compiles each operation alone)
def impact_jumps(floating, qf, before, after):
    """M (qd+ - qd-), the landing foot's Jacobian and the jump of the linear momentum, floating coordinates."""
    com_velocity = lambda qd: jax.jvp(functools.partial(mjx_biped.center_of_mass, floating), (qf,), (qd,))[1]  # noqa: E731
    return (mjx_biped.mass_matrix(floating, qf) @ (after - before), mjx_biped.foot_jacobian(floating, qf, "foot2"),
            jnp.sum(floating.body_mass) * (com_velocity(after) - com_velocity(before)))


@pytest.mark.xdist_group("mjx_quickstart")
def test_impact_momentum_balance(biped12, landing):
    """M (qd+ - qd-) = J^T Lambda, and the linear momentum jumps by the impulse."""
    jump, jac, momentum_jump = impact_jumps(biped12.floating, landing.floating_q, landing.floating_qd_before,
                                            landing.floating_qd_after)
    np.testing.assert_allclose(jump, jac.T @ landing.impulse, atol=EXACT)
    np.testing.assert_allclose(momentum_jump[jnp.array([0, 2])], landing.impulse, atol=EXACT)


@pytest.mark.xdist_group("mjx_quickstart")
def test_impact_relabels_legs_and_reports_the_old_stance_foot(biped12, landing):
    qf_after = landing.floating_qd_after
    # New leg 1 is old leg 2: the new stance knee rate is old knee2's post-impact rate, and so on.
    np.testing.assert_allclose(landing.qd[1:], qf_after[jnp.array([6, 5, 3, 4])], atol=EXACT)
    np.testing.assert_allclose(landing.qd[0], qf_after[2] + qf_after[5] + qf_after[6], atol=EXACT)
    old_stance, swing_velocity = feet_after_the_landing(biped12.floating, biped12.pinned, landing.floating_q, qf_after,
                                                        landing.q, landing.qd)
    np.testing.assert_allclose(landing.old_stance_foot_velocity, old_stance, atol=EXACT)
    # the new stance foot sits at the origin of the next step's pinned chain
    np.testing.assert_allclose(swing_velocity, landing.old_stance_foot_velocity, atol=1e-9)


@jax.jit  # one program for every backend's landing
def feet_after_the_landing(floating, pinned, floating_q, floating_qd, q, qd):
    """The old stance foot's velocity after the touchdown (floating coordinates) and the new swing foot's
    (the next step's pinned ones)."""
    return mjx_biped.foot_jacobian(floating, floating_q, "foot1") @ floating_qd, mjx_biped.swing_foot(pinned, q, qd)[1]


# ----------------------------------------------------------------------------- variants agree

@pytest.mark.slow
@pytest.mark.xdist_group("test_design")  # jit(pinned_to_floating) and the floating mass matrix of test_design
def test_pinned_and_floating_variants_agree(biped12):
    """With the foot pinned, the floating model reduces to the pinned one: G^T M_f G = M_p and
    G^T grav_f = grav_p, with G = d q_floating / d q_pinned (column i: the floating velocity of a unit
    velocity of pinned joint i, :func:`mjx_biped.pinned_to_floating` being the position map's JVP)."""
    pinned, floating = biped12.pinned, biped12.floating
    to_floating = jax.jit(mjx_biped.pinned_to_floating)
    qf = to_floating(pinned, Q, np.zeros(5))[0]
    g = jnp.stack([to_floating(pinned, Q, e)[1] for e in np.eye(5)], axis=1)
    mass_matrix, gravity = jax.jit(mjx_biped.mass_matrix), jax.jit(mjx_biped.generalized_gravity)
    np.testing.assert_allclose(g.T @ mass_matrix(floating, qf) @ g, mass_matrix(pinned, Q), atol=EXACT)
    np.testing.assert_allclose(g.T @ gravity(floating, qf), gravity(pinned, Q), atol=1e-9)


# ----------------------------------------------------------------------------- MJX against MuJoCo C

# MJX and MuJoCo C differ by floating-point reordering only; 1e-8 relative in float64.
MJX_VS_C = 1e-8


def _c_rollout(mj_model, q0, qd0, controls):
    data = mujoco.MjData(mj_model)
    data.qpos[:], data.qvel[:] = q0, qd0
    states = []
    for u in controls:
        data.ctrl[:] = u
        mujoco.mj_step(mj_model, data)
        states.append(np.concatenate([data.qpos, data.qvel]))
    return np.array(states)


@pytest.mark.xdist_group("mjx_quickstart")
@pytest.mark.parametrize("name", BACKENDS)
def test_every_backend_steps_as_mujoco_c(biped12, rollout, name):
    """Each backend's rollout through the interface against MuJoCo's own ``mj_step`` loop (the chain's
    explicit Euler is MuJoCo's semi-implicit one without damping, as in the stored models)."""
    mj_model = registry.load_mj_model("biped5_pinned_12kg")
    assert not np.any(mj_model.dof_damping)
    rng = np.random.default_rng(0)
    controls = rng.normal(scale=2.0, size=(ROLLOUT_STEPS, 4))
    trajectory = rollout(backend(biped12, name), Q, QD, controls)
    expected = _c_rollout(mj_model, np.asarray(Q), np.asarray(QD), controls)
    np.testing.assert_allclose(np.concatenate([trajectory.q[1:], trajectory.qd[1:]], axis=1), expected,
                               rtol=MJX_VS_C, atol=MJX_VS_C)


@pytest.mark.parametrize("name", ["biped5_floating_12kg", "humanoid16_18kg"])
@pytest.mark.xdist_group("mjx_forward")  # the same jit(mjx.forward) programs
def test_mjx_matches_mujoco_c_accelerations(name):
    """Random states and torques (humanoid high in the air, so no contact)."""
    mj_model = registry.load_mj_model(name)
    model = registry.put_mjx_model(mj_model)
    rng = np.random.default_rng(1)
    forward = jax.jit(mjx.forward)
    for _ in range(3):
        data = mujoco.MjData(mj_model)
        data.qpos[:] = mj_model.qpos0 + rng.normal(scale=0.3, size=mj_model.nq)
        if mj_model.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE:
            data.qpos[2] = 2.0
            data.qpos[3:7] /= np.linalg.norm(data.qpos[3:7])
        data.qvel[:] = rng.normal(size=mj_model.nv)
        data.ctrl[:] = rng.normal(scale=2.0, size=mj_model.nu)
        mujoco.mj_forward(mj_model, data)
        result = forward(model, mjx.put_data(mj_model, data))
        np.testing.assert_allclose(result.qacc, data.qacc, rtol=MJX_VS_C,
                                   atol=MJX_VS_C * np.abs(data.qacc).max())


# ----------------------------------------------------------------------------- gradients

def _directional_derivatives(value_and_grad, params, seed, directions=3):
    """(autodiff, central finite difference) directional derivatives along random directions, each
    shape (directions,), from one compiled ``value_and_grad`` (its value may carry an auxiliary output,
    ``(value, aux)``)."""
    value_fn = lambda p: jax.tree.leaves(value_and_grad(p)[0])[0]  # noqa: E731
    gradient = value_and_grad(params)[1]
    rng = np.random.default_rng(seed)
    epsilon = 1e-6  # central differences: truncation ~eps^2, round-off ~1e-16/eps
    analytic, finite = [], []
    for _ in range(directions):
        direction = jax.tree.map(lambda x: jnp.asarray(rng.normal(size=x.shape)), params)
        shifted = lambda s: jax.tree.map(lambda x, d: x + s * d, params, direction)  # noqa: E731
        finite.append(float((value_fn(shifted(epsilon)) - value_fn(shifted(-epsilon))) / (2 * epsilon)))
        analytic.append(float(sum(jnp.vdot(g, d) for g, d in zip(jax.tree.leaves(gradient),
                                                                  jax.tree.leaves(direction)))))
    return np.array(analytic), np.array(finite)


@pytest.mark.slow
@pytest.mark.xdist_group("mjx_gradient")
def test_rollout_gradient_matches_central_finite_differences(mjx_rollout_gradient):
    """d/d(q0, qd0, controls) of a cost of a whole rollout (20 steps in float64: states, torques, MJX's
    Newton-Euler ground force per step) and the swing foot's position and velocity at its end (MJX's
    forward kinematics), along random directions; the program the chain's gradient is compared with in
    test_planar_chain."""
    q0, qd0 = map(jnp.asarray, GRADIENT_START)
    params = (q0, qd0, jnp.asarray(np.random.default_rng(2).normal(size=(GRADIENT_STEPS, 4))))
    analytic, finite = _directional_derivatives(mjx_rollout_gradient, params, seed=2)
    assert np.all(np.abs(finite) > 1e-3)  # the cost does depend on the parameters
    np.testing.assert_allclose(analytic, finite, rtol=1e-6, atol=1e-8)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["mjx", "chain"])
def test_touchdown_gradient_matches_finite_differences(biped12, name):
    dynamics = backend(biped12, name)

    def impact_cost(qd):
        result = interface.touchdown(dynamics, Q, qd)
        return jnp.sum(result.qd ** 2) + jnp.sum(result.impulse) + result.old_stance_foot_velocity[1]
    # five random directions span the gradient's five components
    analytic, finite = _directional_derivatives(jax.jit(jax.value_and_grad(impact_cost)), QD, seed=4, directions=5)
    assert np.all(np.abs(finite) > 1e-3)
    np.testing.assert_allclose(analytic, finite, rtol=1e-6, atol=1e-8)


# ----------------------------------------------------------------------------- bad input

@pytest.mark.parametrize("name", BACKENDS)
def test_wrong_shapes_are_named(biped12, name):
    dynamics = backend(biped12, name)
    with pytest.raises(ValueError, match=r"controls must have shape \(T, 4\), got \(10, 3\)"):
        interface.stance_rollout(dynamics, Q, QD, jnp.zeros((10, 3)))
    with pytest.raises(ValueError, match=r"q0 must have shape \(5,\), got \(7,\)"):
        interface.stance_rollout(dynamics, jnp.zeros(7), QD, jnp.zeros((10, 4)))
    with pytest.raises(ValueError, match=r"qd must have shape \(5,\), got \(4,\)"):
        interface.touchdown(dynamics, Q, QD[:4])
    with pytest.raises(ValueError, match="mass class '15kg'"):
        mjx_biped.load_planar_biped("15kg")
