"""Single support of the sagittal biped behind one interface, in two implementations: the closed-form
planar chain (:class:`ChainDynamics`, :mod:`biped_jax.dynamics.planar_chain`) and MJX's pipeline
(:class:`MjxDynamics`), equal to rounding. A small strategy object chosen once by name
(:func:`stance_dynamics`): the gait rollout reads the mass matrix, bias force, ground force, sites,
swing foot and touchdown from it (the zero dynamics under prescribed joints); the heuristic step
advances the torque-driven step with :func:`stance_step` (MJX's step is the one under the
quickstart's :func:`biped_jax.dynamics.hybrid_step.stance_rollout`, the chain's the one under
:func:`biped_jax.dynamics.planar_chain.stance_rollout`)."""

from __future__ import annotations

import jax.numpy as jnp

from biped_jax.dynamics import impact
from biped_jax.dynamics import hybrid_step
from biped_jax.dynamics import planar_chain
from biped_jax.robots.planar_biped import GAIT_SITES

mjx = hybrid_step.mjx


class ChainDynamics:
    """Mass matrix, bias force, stance force, site positions, the swing foot's motion and the
    touchdown from :mod:`biped_jax.dynamics.planar_chain` (closed forms, no MJX)."""

    def __init__(self, biped: hybrid_step.PlanarBiped, chain: planar_chain.PlanarChain | None = None):
        """``chain``: the structure of ``biped.pinned`` when the model is traced (read from the model
        otherwise, which needs it concrete); every planar biped design has the same structure."""
        self.chain = planar_chain.PlanarChain.from_model(biped.pinned) if chain is None else chain
        self.pinned = biped.pinned

    def terms(self, q, qd):
        kinematics = planar_chain.kinematics(self.chain, self.pinned, q, qd)
        return (planar_chain.mass_matrix(self.chain, self.pinned, kinematics),
                planar_chain.bias_force(self.chain, self.pinned, kinematics, qd), kinematics)

    def outputs(self, q, qd, qdd, kinematics):
        force = planar_chain.root_force(self.chain, self.pinned, kinematics, qdd)
        return force, planar_chain.site_positions(self.chain, self.pinned, kinematics, GAIT_SITES)

    def swing_foot(self, q, qd):
        return planar_chain.site_motion(self.chain, self.pinned, q, qd, "foot2")

    def touchdown(self, q, qd):
        return impact.chain_touchdown(self.chain, self.pinned, q, qd)

    def step(self, state, u):
        return planar_chain.stance_step(self.chain, self.pinned, state, u)


class MjxDynamics:
    """The same quantities from MJX's forward pipeline."""

    def __init__(self, biped: hybrid_step.PlanarBiped):
        self.biped, self.pinned = biped, biped.pinned
        self.template = mjx.make_data(biped.pinned)
        self.sites = jnp.array([mjx.name2id(biped.pinned, hybrid_step.robots.mujoco.mjtObj.mjOBJ_SITE, name)
                                for name in GAIT_SITES])

    def terms(self, q, qd):
        data = mjx.fwd_velocity(self.pinned, mjx.fwd_position(self.pinned, self.template.replace(qpos=q, qvel=qd)))
        return mjx.full_m(self.pinned, data), data.qfrc_bias - data.qfrc_passive, data

    def outputs(self, q, qd, qdd, data):
        force = hybrid_step.stance_force(self.pinned, data.replace(qacc=qdd))
        return force, data.site_xpos[self.sites][:, jnp.array([0, 2])]

    def swing_foot(self, q, qd):
        return hybrid_step.swing_foot(self.pinned, q, qd)

    def touchdown(self, q, qd):
        return impact.touchdown(self.biped, q, qd)

    def step(self, state, u):
        return hybrid_step.stance_step(self.pinned, state, u)


#: The dynamics by name (``GaitSettings.dynamics``, the command line's ``--dynamics``).
DYNAMICS = {"chain": ChainDynamics, "mjx": MjxDynamics}


def stance_dynamics(biped: hybrid_step.PlanarBiped, name: str = "chain") -> ChainDynamics | MjxDynamics:
    """The single-support dynamics ``name`` (a key of :data:`DYNAMICS`) of ``biped``; ValueError naming
    another."""
    if name not in DYNAMICS:
        raise ValueError(f"dynamics must be one of {tuple(DYNAMICS)}, got {name!r}")
    return DYNAMICS[name](biped)


def stance_step(dynamics: ChainDynamics | MjxDynamics, state, u):
    """One step of single support under torques u (H1, K1, H2, K2) (N m) with the pinned model's
    ``opt.timestep``: ``state`` = (q, qd), (5,) each. Returns (the next state, (qdd, ground force
    (F_x, F_z) N)); MJX's integrator or semi-implicit Euler in the chain (equal without damping)."""
    return dynamics.step(state, u)
