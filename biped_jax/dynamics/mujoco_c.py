"""The MuJoCo C backend of the walking step (:class:`biped_jax.dynamics.interface.StanceDynamics`):
single support and the touchdown's impact from MuJoCo's C library, in numpy.

Not traceable and not batched: the independent reference that the tests compare the JAX backends with,
and the physics of the baseline a user without MJX would have (the gradient benchmark's central
differences, :mod:`biped_jax.gait.mujoco_reference`). One backend holds its own ``MjData`` buffers:
one per thread.
"""

from __future__ import annotations

import copy
import dataclasses

import mujoco
import numpy as np

from biped_jax.dynamics import impact
from biped_jax.robots import registry
from biped_jax.robots.planar_biped import GAIT_SITES, STANCE_BODY

#: The model arrays a design changes (``biped_jax.robots.design.apply_design``) and the step reads,
#: copied from an MJX model into MuJoCo's; the derived constants follow by ``mj_setConst``.
DESIGN_FIELDS = ("body_pos", "body_ipos", "body_mass", "body_inertia", "dof_armature", "dof_damping", "site_pos")

#: MuJoCo's integrators by ``opt.integrator``, as ``mj_step`` dispatches after ``mj_forward``.
_INTEGRATORS = {int(mujoco.mjtIntegrator.mjINT_EULER): mujoco.mj_Euler,
                int(mujoco.mjtIntegrator.mjINT_RK4): lambda m, d: mujoco.mj_RungeKutta(m, d, 4),
                int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST): mujoco.mj_implicit}


def _with_parameters(mj_model, mjx_model):
    """A copy of ``mj_model`` carrying ``mjx_model``'s design arrays and time step (concrete arrays;
    TypeError naming a traced one)."""
    model = copy.copy(mj_model)
    for name in DESIGN_FIELDS:
        value = getattr(mjx_model, name)
        try:
            getattr(model, name)[:] = np.asarray(value)
        except Exception as error:  # a tracer: the C library needs numbers
            raise TypeError(f"the MuJoCo C backend needs a concrete model; {name} is {type(value).__name__}"
                            ) from error
    model.opt.timestep = float(mjx_model.opt.timestep)
    data = mujoco.MjData(model)
    mujoco.mj_setConst(model, data)  # subtree masses and the like follow the new masses
    return model


@dataclasses.dataclass(eq=False)
class MujocoDynamics:
    """MuJoCo C models of one design (pinned chain, floating base) and their scratch buffers.

    Attributes:
      pinned, floating: ``mujoco.MjModel`` of the single-support chain and of the floating base.
    """

    pinned: mujoco.MjModel
    floating: mujoco.MjModel
    xp = np  # the array module of this backend's results

    def __post_init__(self):
        self.pinned_data = mujoco.MjData(self.pinned)
        self.floating_data = mujoco.MjData(self.floating)
        self._sites = [self.pinned.site(name).id for name in GAIT_SITES]

    @classmethod
    def of(cls, biped) -> "MujocoDynamics":
        """The backend of a :class:`~biped_jax.dynamics.mjx_biped.PlanarBiped` (its design included)."""
        return cls(pinned=_with_parameters(registry.load_mj_model("biped5_pinned_12kg"), biped.pinned),
                   floating=_with_parameters(registry.load_mj_model("biped5_floating_12kg"), biped.floating))

    @classmethod
    def nominal(cls, mass_class: str) -> "MujocoDynamics":
        """The backend of a mass class's stored design, read by MuJoCo alone (no MJX)."""
        return cls(pinned=registry.load_mj_model(f"biped5_pinned_{mass_class}"),
                   floating=registry.load_mj_model(f"biped5_floating_{mass_class}"))

    def terms(self, q, qd):
        m, d = self.pinned, self.pinned_data
        d.qpos[:], d.qvel[:] = q, qd
        mujoco.mj_fwdPosition(m, d)
        mujoco.mj_fwdVelocity(m, d)
        mass = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, mass)
        return mass, d.qfrc_bias - d.qfrc_passive, d

    def outputs(self, q, qd, qdd, data):
        data.qacc[:] = qdd  # no contacts or limits in the pinned chain
        mujoco.mj_rnePostConstraint(self.pinned, data)
        force = data.cfrc_int[STANCE_BODY, [3, 5]].copy()
        return force, data.site_xpos[self._sites][:, [0, 2]].copy()

    @staticmethod
    def _jacobian(model, data, site: str) -> np.ndarray:
        """d(site x, z)/dq, (2, nv); positions and ``cdof`` of ``data`` must be current."""
        jac = np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, data, jac, None, model.site(site).id)
        return jac[[0, 2]]

    def _pinned_site(self, q, qd, site: str) -> tuple[np.ndarray, np.ndarray]:
        """(position (x, z), velocity (x, z)) of a site of the pinned chain at (q, qd)."""
        m, d = self.pinned, self.pinned_data
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)  # the Jacobian reads cdof
        return d.site_xpos[m.site(site).id][[0, 2]].copy(), self._jacobian(m, d, site) @ qd

    def swing_foot(self, q, qd):
        return self._pinned_site(q, qd, "foot2")

    def step(self, state, u):
        m, d = self.pinned, self.pinned_data
        d.qpos[:], d.qvel[:] = state
        d.ctrl[:] = u
        mujoco.mj_forward(m, d)  # mj_step's forward pass, with the ground force read from it
        qdd = d.qacc.copy()
        force, _ = self.outputs(state[0], state[1], qdd, d)
        _INTEGRATORS[int(m.opt.integrator)](m, d)
        return (d.qpos.copy(), d.qvel.copy()), (qdd, force)

    def impact_system(self, q, qd) -> impact.ImpactSystem:
        hip, hip_velocity = self._pinned_site(q, qd, "hip")
        # the map is linear in (hip, angles): the rates map as the coordinates do
        qf, qfd = impact.floating_coordinates(hip, q, np), impact.floating_coordinates(hip_velocity, qd, np)
        m, d = self.floating, self.floating_data
        d.qpos[:] = qf
        mujoco.mj_fwdPosition(m, d)
        mass = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, mass)
        return impact.ImpactSystem(mass=mass, landing=self._jacobian(m, d, "foot2"),
                                   leaving=self._jacobian(m, d, "foot1"), velocity=qfd, floating_q=qf)
