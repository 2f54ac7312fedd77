"""The closed-form planar-chain dynamics against MJX and MuJoCo C: every quantity the interface reads
(:mod:`biped_jax.dynamics.interface`) at random states of a design with armature and damping, from each
backend, the touchdown, a rollout and its gradient, and bad models."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import GRADIENT_DT, GRADIENT_START, GRADIENT_STEPS, rollout_cost

from biped_jax.dynamics import interface, mjx_biped, planar_chain
from biped_jax.gait import problem as gait_problem
from biped_jax.robots import planar_biped

#: xdist groups: see tests/test_dynamics.py.

mjx = mjx_biped.mjx


@pytest.fixture(scope="module")
def designed_biped(biped12):
    """The 12 kg biped with a design unlike the file's: other masses, drive masses at the joints,
    armature and damping, so every parameter path is exercised."""
    design = mjx_biped.planar_design("12kg")
    design = dataclasses.replace(design, link_mass=design.link_mass * jnp.array([0.8, 1.1, 1.3, 0.9, 1.2]),
                                 joint_armature=jnp.array([0.01, 0.02, 0.015, 0.03]),
                                 joint_damping=jnp.array([0.1, 0.2, 0.3, 0.4]),
                                 drive_mass=jnp.array([0.3, 0.2, 0.3, 0.2]))
    return mjx_biped.with_design(biped12, design)


@pytest.fixture(scope="module")
def designed(designed_biped):
    return designed_biped.pinned


def test_structure_of_the_pinned_biped(biped12):
    chain = planar_chain.PlanarChain.from_model(biped12.pinned)
    np.testing.assert_array_equal(chain.actuated_dof, planar_biped.ACTUATED_INDEX)  # (H1, K1, H2, K2)
    np.testing.assert_array_equal(chain.parent, [-1, 0, 1, 2, 3])
    assert chain.site_body == {"foot1": 0, "knee1": 1, "hip": 2, "knee2": 4, "foot2": 4}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_quantity_equals_mjx(designed_biped, seed):
    """The backends (:mod:`biped_jax.dynamics.interface`: what the gait rollout reads, method by method)
    agree at random states: mass matrix, bias force, stance force, gait sites, the chain's and MuJoCo C's
    against MJX's (MuJoCo C's model carrying the design's arrays); and the chain's forward dynamics and
    mechanical energy are MJX's."""
    designed = designed_biped.pinned
    chain_dynamics, mjx_dynamics = (interface.stance_dynamics(designed_biped, name) for name in ("chain", "mjx"))
    c_dynamics = interface.stance_dynamics(designed_biped, "mujoco")
    rng = np.random.default_rng(seed)
    q, qd, u = (jnp.asarray(rng.normal(size=5)), jnp.asarray(3 * rng.normal(size=5)),
                jnp.asarray(5 * rng.normal(size=4)))
    foot1 = mjx.name2id(designed, mjx_biped.registry.mujoco.mjtObj.mjOBJ_SITE, "foot1")  # not a gait site
    chain, reference = (jax.tree.map(np.asarray, quantities) for quantities in
                        _both_backends(chain_dynamics, mjx_dynamics, q, qd, u, foot1))
    # MJX's Euler integrates damping implicitly; its forward pass's qacc is the explicit one
    np.testing.assert_allclose(chain["qdd"], reference["qdd"], rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(chain["mass"], reference["mass"], atol=1e-12)
    np.testing.assert_allclose(chain["bias"], reference["bias"], atol=1e-10)
    assert float(np.linalg.norm(reference["force"])) > 1.0
    np.testing.assert_allclose(chain["force"], reference["force"], atol=1e-9)
    np.testing.assert_allclose(chain["sites"], reference["sites"], atol=1e-14)
    c_mass, c_bias, c_data = c_dynamics.terms(np.asarray(q), np.asarray(qd))
    np.testing.assert_allclose(c_mass, reference["mass"], atol=1e-12)
    np.testing.assert_allclose(c_bias, reference["bias"], atol=1e-10)
    c_force, c_sites = c_dynamics.outputs(q, qd, chain["qdd"], c_data)
    np.testing.assert_allclose(c_force, reference["force"], atol=1e-9)
    np.testing.assert_allclose(c_sites, reference["sites"], atol=1e-14)
    np.testing.assert_allclose(chain["energy"], reference["energy"], rtol=1e-12)
    np.testing.assert_allclose(chain["foot1"], reference["foot1"], atol=1e-14)


@functools.partial(jax.jit, static_argnums=5)  # one program for every seed: op by op, MJX compiles each operation alone
def _both_backends(chain_dynamics, mjx_dynamics, q, qd, u, foot1: int):
    """What :func:`test_every_quantity_equals_mjx` compares, by the chain and by MJX: forward dynamics
    (the chain's from its closed forms, MJX's forward pass's qacc), the backends' terms and outputs at
    MJX's accelerations, the mechanical energy and the site foot1 (x, z)."""
    designed = mjx_dynamics.pinned
    data = mjx.forward(designed, mjx.make_data(designed).replace(qpos=q, qvel=qd, ctrl=u))
    qdd, _ = planar_chain.forward_dynamics(chain_dynamics.chain, designed, q, qd, u)
    found, states = {}, {}
    for name, dynamics, accelerations in (("chain", chain_dynamics, qdd), ("mjx", mjx_dynamics, data.qacc)):
        mass, bias, states[name] = dynamics.terms(q, qd)
        force, sites = dynamics.outputs(q, qd, qdd, states[name])
        found[name] = {"qdd": accelerations, "mass": mass, "bias": bias, "force": force, "sites": sites}
    state = states["chain"]
    found["chain"]["energy"] = planar_chain.mechanical_energy(chain_dynamics.chain, designed, state, qd)
    found["mjx"]["energy"] = mjx_biped.mechanical_energy(designed, q, qd)
    found["chain"]["foot1"] = planar_chain.site_positions(chain_dynamics.chain, designed, state, ("foot1",))[0]
    found["mjx"]["foot1"] = data.site_xpos[foot1][jnp.array([0, 2])]
    return found["chain"], found["mjx"]


@pytest.fixture(scope="module")
def landings(designed_biped):
    """(touchdown, swing foot's motion) -> of each backend at a state: one compiled program for each JAX
    backend (MJX run op by op compiles every operation alone; its touchdown is the program of every
    test's), MuJoCo C's as it is."""
    def both(dynamics, q, qd):
        return interface.touchdown(dynamics, q, qd), dynamics.swing_foot(q, qd)
    jitted = jax.jit(both)
    return {name: functools.partial(both if name == "mujoco" else jitted,
                                    interface.stance_dynamics(designed_biped, name))
            for name in ("chain", "mjx", "mujoco")}


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.xdist_group("mjx_quickstart")
@pytest.mark.parametrize("name", ["chain", "mujoco"])
def test_touchdown_and_swing_foot_equal_mjx(landings, seed, name):
    """The impact in the pinned chain's coordinates extended by the root's translation, and MuJoCo C's
    on its floating model, are MJX's impact on the floating model: every field of the touchdown
    (impulse, velocities, relabelled state), and the swing foot's motion, at random pre-impact states
    of a design with armature."""
    rng = np.random.default_rng(seed)
    q = np.array([0.2, 0.3, -0.4, 0.5, 0.1]) + 0.1 * rng.normal(size=5)
    qd = 2 * rng.normal(size=5)
    mine, motion = landings[name](q, qd)
    reference, reference_motion = landings["mjx"](jnp.asarray(q), jnp.asarray(qd))
    assert np.linalg.norm(reference.impulse) > 1.0  # a real impact
    for field in dataclasses.fields(reference):
        np.testing.assert_allclose(getattr(mine, field.name), getattr(reference, field.name),
                                   rtol=1e-11, atol=1e-12, err_msg=field.name)
    for closed, theirs in zip(motion, reference_motion):
        np.testing.assert_allclose(closed, theirs, atol=1e-13)


@pytest.mark.slow
@pytest.mark.xdist_group("mjx_gradient")
def test_rollout_and_its_gradient_equal_mjx(biped12, mjx_rollout_gradient):
    """20 Euler steps of 1.8 ms (no damping: MJX's implicit damping would differ by O(dt^2)), and the
    gradient of a cost of the whole rollout (its ground force per step) and the swing foot at its end with
    respect to the start state and the torques (MJX's program is the one
    test_dynamics checks against finite differences)."""
    chain = planar_chain.PlanarChain.from_model(biped12.pinned)
    pinned = mjx_biped.with_timestep(biped12.pinned, GRADIENT_DT)
    dynamics = planar_chain.ChainDynamics.of(pinned, chain)
    params = (*map(jnp.asarray, GRADIENT_START), jnp.asarray(np.random.default_rng(3).normal(size=(GRADIENT_STEPS, 4))))

    def chain_cost(params):
        trajectory = interface.stance_rollout(dynamics, *params)
        q, qd, qdd = trajectory.q, trajectory.qd, trajectory.qdd
        foot, foot_velocity = planar_chain.site_motion(chain, pinned, q[-1], qd[-1], "foot2")
        return rollout_cost(q, qd, qdd, trajectory.u, trajectory.ground_force, foot, foot_velocity), (
            q, trajectory.ground_force)

    (_, (q, force)), gradient = jax.jit(jax.value_and_grad(chain_cost, has_aux=True))(params)
    (_, reference), reference_gradient = mjx_rollout_gradient(params)
    np.testing.assert_allclose(q, reference.q, atol=1e-12)
    np.testing.assert_allclose(force, reference.ground_force, atol=1e-9)
    for mine, theirs in zip(gradient, reference_gradient):  # d/dq0, d/dqd0, d/du
        np.testing.assert_allclose(mine, theirs, rtol=1e-9, atol=1e-10)


def test_the_gait_rollout_traces_alike_with_either_dynamics(biped12):
    """The optimiser's rollout reads only the strategies' methods, checked equal above and, for the
    touchdown and the swing foot, in test_touchdown_and_swing_foot_equal_mjx; here MJX's is traced through
    the whole rollout (not compiled: that takes a minute) and gives the chain's shapes and dtypes."""
    model = gait_problem.gait_model("12kg", 0.555, 20.0)
    shapes = {}
    for dynamics in gait_problem.DYNAMICS:
        settings = gait_problem.GaitSettings(spans=4, substeps=2, dynamics=dynamics)
        x = gait_problem.initial_guess(model, settings)
        shapes[dynamics] = jax.eval_shape(functools.partial(gait_problem.simulate, biped=biped12, settings=settings),
                                          x, model)
    assert jax.tree.structure(shapes["chain"]) == jax.tree.structure(shapes["mjx"])
    assert jax.tree.leaves(shapes["chain"]) == jax.tree.leaves(shapes["mjx"])


def test_unknown_dynamics_is_rejected():
    from biped_jax import cli
    assert cli.DYNAMICS == gait_problem.DYNAMICS  # the command line's choices
    with pytest.raises(ValueError, match="dynamics must be one of .* got 'rk4'"):
        gait_problem.GaitSettings(dynamics="rk4")
    with pytest.raises(SystemExit):
        cli.main(["codesign", "--dynamics", "rk4"])
    # every traceable backend is a name the settings accept, MuJoCo C's is not (it does not trace)
    assert interface.TRACEABLE == gait_problem.DYNAMICS and set(interface.DYNAMICS) == {"chain", "mjx", "mujoco"}
    with pytest.raises(ValueError, match="dynamics must be one of .* got 'rk4'"):
        interface.stance_dynamics(None, "rk4")
    with pytest.raises(ValueError, match="dynamics must be one of .* got 'mujoco'"):
        gait_problem.GaitSettings(dynamics="mujoco")


def test_a_model_that_is_not_a_planar_chain_is_rejected(biped12):
    """The floating biped's root is a slide pair: not a hinge chain."""
    with pytest.raises(ValueError, match="one hinge per body"):
        planar_chain.PlanarChain.from_model(biped12.floating)
    tilted = biped12.pinned.replace(jnt_axis=biped12.pinned.jnt_axis.at[2].set(jnp.array([1.0, 0.0, 0.0])))
    with pytest.raises(ValueError, match="about \\+-y"):
        planar_chain.PlanarChain.from_model(tilted)
    chain = planar_chain.PlanarChain.from_model(biped12.pinned)
    state = planar_chain.kinematics(chain, biped12.pinned, jnp.zeros(5), jnp.zeros(5))
    with pytest.raises(ValueError, match="no site 'toe'"):
        planar_chain.site_positions(chain, biped12.pinned, state, ["hip", "toe"])
