"""The gait rollout of ``biped_jax.gait`` computed with MuJoCo C instead of MJX.

The same step (Bezier references tracked by collocated partial feedback linearisation, semi-implicit
Euler, inelastic impact, relabelling) with the physics in MuJoCo's C library and the impact map in
numpy. Two uses: the tests compare it with the MJX rollout (MJX against MuJoCo C on the optimiser's
own trajectories), and the gradient benchmark uses it, with central finite differences, as the
baseline a user without MJX would have.

Not differentiable and not batched; one :class:`CGaitRollout` per process.
"""

from __future__ import annotations

import mujoco
import numpy as np

from biped_jax import gait, robots
from biped_jax import hybrid_step as hs


class CGaitRollout:
    """MuJoCo C models of one biped (``mass_class`` as in :func:`biped_jax.gait.gait_model`, nominal
    design) and scratch buffers for :meth:`simulate`."""

    def __init__(self, mass_class: str, settings: gait.GaitSettings):
        self.settings = settings
        self.pinned = robots.load_mj_model(f"biped5_pinned_{mass_class}")
        self.floating = robots.load_mj_model(f"biped5_floating_{mass_class}")
        # The commanded acceleration must be met exactly (as in gait._pinned_model).
        self.pinned.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_EULERDAMP
        self.pinned_data = mujoco.MjData(self.pinned)
        self.floating_data = mujoco.MjData(self.floating)
        self._sites = [self.pinned.site(name).id for name in ("foot2", "hip", "knee1", "knee2")]
        self._mass = np.zeros((self.pinned.nv, self.pinned.nv))
        self._floating_mass = np.zeros((self.floating.nv, self.floating.nv))

    def simulate(self, x: np.ndarray, speed: float, step_length: float) -> gait.GaitTrajectory:
        """The step of decision vector ``x`` (shape (2 + 4 n,)) at ``speed`` m/s over ``step_length`` m;
        arrays as in :class:`biped_jax.gait.GaitTrajectory` (numpy)."""
        m, d, settings = self.pinned, self.pinned_data, self.settings
        step_time = step_length / speed
        dt = step_time / settings.steps
        m.opt.timestep = dt
        coefficients = np.asarray(gait.bezier_coefficients(np.asarray(x), settings))
        s = np.linspace(0.0, 1.0, settings.steps + 1)
        reference = gait.bezier(coefficients, s)
        actuated = gait.ACTUATED_INDEX
        q = np.zeros(m.nq)
        q[0], q[actuated] = x[0], reference[0]
        qd = np.zeros(m.nv)
        qd[0], qd[actuated] = x[1], gait.bezier_rate(coefficients, s[:1])[0] / step_time
        rows = {name: [] for name in ("q", "qd", "qdd", "u", "force", "sites")}
        rows["q"].append(q.copy())
        rows["qd"].append(qd.copy())
        for target in reference[1:]:
            d.qpos[:], d.qvel[:] = q, qd
            mujoco.mj_fwdPosition(m, d)
            mujoco.mj_fwdVelocity(m, d)
            rows["sites"].append(d.site_xpos[self._sites].copy())
            mujoco.mj_fullM(m, d, self._mass)
            desired = ((target - q[actuated]) / dt - qd[actuated]) / dt
            u = gait.feedback_linearising_torque(self._mass, d.qfrc_bias - d.qfrc_passive, desired)
            d.ctrl[:] = u
            mujoco.mj_fwdActuation(m, d)
            mujoco.mj_fwdAcceleration(m, d)
            d.qacc[:] = d.qacc_smooth  # no contacts or limits in the pinned chain
            mujoco.mj_rnePostConstraint(m, d)
            rows["force"].append(d.cfrc_int[hs._STANCE_BODY, [3, 5]].copy())
            mujoco.mj_Euler(m, d)
            q, qd = d.qpos.copy(), d.qvel.copy()
            for name, value in (("q", q), ("qd", qd), ("qdd", d.qacc), ("u", u)):
                rows[name].append(np.array(value))
        d.qpos[:], d.qvel[:] = q, qd
        mujoco.mj_fwdPosition(m, d)
        rows["sites"].append(d.site_xpos[self._sites].copy())
        positions = np.stack(rows["sites"])
        foot_velocity = self._site_velocity(m, d, "foot2", qd)
        return gait.GaitTrajectory(
            t=dt * np.arange(settings.steps + 1), q=np.stack(rows["q"]), qd=np.stack(rows["qd"]),
            qdd=np.stack(rows["qdd"]), u=np.stack(rows["u"]), ground_force=np.stack(rows["force"]),
            swing_foot=positions[:, 0, [0, 2]], heights=positions[:, 1:, 2],
            touchdown=self._touchdown(q, qd, d), swing_foot_velocity=foot_velocity[[0, 2]])

    @staticmethod
    def _site_velocity(model, data, site: str, qd: np.ndarray) -> np.ndarray:
        """Linear velocity (3,) of a site, m/s; positions of ``data`` must be current."""
        jac = np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, data, jac, None, model.site(site).id)
        return jac @ qd

    def _touchdown(self, q: np.ndarray, qd: np.ndarray, pinned_data) -> hs.Touchdown:
        """Impact map and relabelling (as hybrid_step.touchdown) with MuJoCo C kinematics."""
        hip = pinned_data.site_xpos[self.pinned.site("hip").id]
        hip_velocity = self._site_velocity(self.pinned, pinned_data, "hip", qd)
        stance, knee1, hip1, hip2, knee2 = q
        qf = np.array([hip[0], hip[2], stance - knee1 - hip1, hip1, knee1, hip2, knee2])
        qfd = np.array([hip_velocity[0], hip_velocity[2], qd[0] - qd[1] - qd[2], *qd[[2, 1, 3, 4]]])
        m, d = self.floating, self.floating_data
        d.qpos[:] = qf
        mujoco.mj_fwdPosition(m, d)
        mujoco.mj_fullM(m, d, self._floating_mass)
        jacobians = {}
        for foot in ("foot1", "foot2"):
            jac = np.zeros((3, m.nv))
            mujoco.mj_jacSite(m, d, jac, None, m.site(foot).id)
            jacobians[foot] = jac[[0, 2]]
        jac = jacobians["foot2"]
        kkt = np.block([[self._floating_mass, -jac.T], [jac, np.zeros((2, 2))]])
        solution = np.linalg.solve(kkt, np.concatenate([self._floating_mass @ qfd, np.zeros(2)]))
        qfd_after, impulse = solution[:m.nv], solution[m.nv:]
        relabelled = hs._RELABEL
        q_next, qd_next = hs._FLOATING_TO_PINNED @ qf[relabelled], hs._FLOATING_TO_PINNED @ qfd_after[relabelled]
        return hs.Touchdown(q=q_next, qd=qd_next, impulse=impulse,
                            old_stance_foot_velocity=jacobians["foot1"] @ qfd_after,
                            floating_qd_before=qfd, floating_qd_after=qfd_after, floating_q=qf)
