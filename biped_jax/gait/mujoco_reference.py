"""The gait rollout of ``biped_jax.gait.problem`` computed with MuJoCo C instead of MJX.

The same step (B-spline joint references prescribed, the stance angle's zero dynamics by classical
Runge-Kutta, torques from the actuated rows, inelastic impact, relabelling) with the physics in
MuJoCo's C library and the impact map in numpy. Two uses: the tests compare it with the MJX rollout
(MJX against MuJoCo C on the optimiser's own trajectories), and the gradient benchmark uses it, with
central finite differences, as the baseline a user without MJX would have.

Not differentiable and not batched; one :class:`CGaitRollout` per process.
"""

from __future__ import annotations

import mujoco
import numpy as np

from biped_jax.dynamics import impact
from biped_jax.robots import planar_biped
from biped_jax.gait import problem as gait_problem
from biped_jax.robots import registry as robots
from biped_jax.robots.planar_biped import ACTUATED_INDEX


class CGaitRollout:
    """MuJoCo C models of one biped (``mass_class`` as in :func:`biped_jax.gait.problem.gait_model`, nominal
    design) and scratch buffers for :meth:`simulate`."""

    def __init__(self, mass_class: str, settings: gait_problem.GaitSettings):
        self.settings = settings
        self.pinned = robots.load_mj_model(f"biped5_pinned_{mass_class}")
        self.floating = robots.load_mj_model(f"biped5_floating_{mass_class}")
        self.pinned_data = mujoco.MjData(self.pinned)
        self.floating_data = mujoco.MjData(self.floating)
        self._sites = [self.pinned.site(name).id for name in ("foot2", "hip", "knee1", "knee2")]
        self._mass = np.zeros((self.pinned.nv, self.pinned.nv))
        self._floating_mass = np.zeros((self.floating.nv, self.floating.nv))

    def _terms(self, q: np.ndarray, qd: np.ndarray):
        """Mass matrix and bias (qfrc_bias - qfrc_passive) at (q, qd); leaves the data's positions and
        velocities current."""
        m, d = self.pinned, self.pinned_data
        d.qpos[:], d.qvel[:] = q, qd
        mujoco.mj_fwdPosition(m, d)
        mujoco.mj_fwdVelocity(m, d)
        mujoco.mj_fullM(m, d, self._mass)
        return self._mass.copy(), d.qfrc_bias - d.qfrc_passive

    def _acceleration(self, theta: float, rate: float, ref) -> float:
        q, qd = self._assemble(theta, ref[0]), self._assemble(rate, ref[1])
        mass, bias = self._terms(q, qd)
        return float(gait_problem.stance_acceleration(mass, bias, ref[2]))

    @staticmethod
    def _assemble(theta, actuated) -> np.ndarray:
        full = np.zeros(5)
        full[0], full[planar_biped.ACTUATED_INDEX] = theta, actuated
        return full

    def simulate(self, x: np.ndarray, speed: float, step_length: float) -> gait_problem.GaitTrajectory:
        """The step of decision vector ``x`` (shape (settings.size,)) at ``speed`` m/s over
        ``step_length`` m; arrays as in :class:`biped_jax.gait.problem.GaitTrajectory` (numpy)."""
        m, d, settings = self.pinned, self.pinned_data, self.settings
        x = np.asarray(x, dtype=float)
        step_time = step_length / speed
        s = gait_problem.grid(settings)
        scale = np.array([1.0, 1.0 / step_time, 1.0 / step_time**2])[:, None, None]
        at_grid = np.stack([np.asarray(r) for r in gait_problem.reference(x, settings, s)]) * scale
        at_mid = np.stack([np.asarray(r) for r in gait_problem.reference(x, settings, 0.5 * (s[1:] + s[:-1]))]) * scale
        nodes = np.asarray(gait_problem.stance_nodes(x, settings))
        per_segment = settings.steps // settings.segments
        theta, rate, defects, y = [], [], [], nodes[0]
        f = lambda y_, ref: np.array([y_[1], self._acceleration(y_[0], y_[1], ref)])  # noqa: E731
        for k, dt in enumerate(np.diff(s) * step_time):  # classical Runge-Kutta on the zero dynamics
            if k % per_segment == 0:  # a segment starts from its shooting node
                if k:
                    defects.append(y - nodes[k // per_segment])
                y = nodes[k // per_segment]
                theta[-1:], rate[-1:] = [y[0]], [y[1]]
            k1 = f(y, at_grid[:, k])
            k2 = f(y + 0.5 * dt * k1, at_mid[:, k])
            k3 = f(y + 0.5 * dt * k2, at_mid[:, k])
            k4 = f(y + dt * k3, at_grid[:, k + 1])
            y = y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            theta.append(y[0])
            rate.append(y[1])
        rows = {name: [] for name in ("q", "qd", "qdd", "u", "force", "sites")}
        for k in range(len(s)):
            q, qd = self._assemble(theta[k], at_grid[0, k]), self._assemble(rate[k], at_grid[1, k])
            mass, bias = self._terms(q, qd)
            qdd = self._assemble(gait_problem.stance_acceleration(mass, bias, at_grid[2, k]), at_grid[2, k])
            rows["sites"].append(d.site_xpos[self._sites].copy())
            d.qacc[:] = qdd  # no contacts or limits in the pinned chain
            mujoco.mj_rnePostConstraint(m, d)
            rows["force"].append(d.cfrc_int[planar_biped.STANCE_BODY, [3, 5]].copy())
            for name, value in (("q", q), ("qd", qd), ("qdd", qdd), ("u", gait_problem.actuated_torque(mass, bias,
                                                                                                       qdd))):
                rows[name].append(np.array(value))
        positions = np.stack(rows["sites"])
        foot_velocity = self._site_velocity(m, d, "foot2", qd)
        return gait_problem.GaitTrajectory(
            t=s * step_time, weights=gait_problem.simpson_weights(settings) * step_time, q=np.stack(rows["q"]),
            qd=np.stack(rows["qd"]), qdd=np.stack(rows["qdd"]), u=np.stack(rows["u"]),
            ground_force=np.stack(rows["force"]), swing_foot=positions[:, 0, [0, 2]], heights=positions[:, 1:, 2],
            touchdown=self._touchdown(q, qd, d), swing_foot_velocity=foot_velocity[[0, 2]],
            continuity=np.array(defects).reshape(-1, 2))

    @staticmethod
    def _site_velocity(model, data, site: str, qd: np.ndarray) -> np.ndarray:
        """Linear velocity (3,) of a site, m/s; positions of ``data`` must be current."""
        jac = np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, data, jac, None, model.site(site).id)
        return jac @ qd

    def _touchdown(self, q: np.ndarray, qd: np.ndarray, pinned_data) -> impact.Touchdown:
        """Impact map and relabelling (as impact.touchdown) with MuJoCo C kinematics."""
        hip = pinned_data.site_xpos[self.pinned.site("hip").id]
        hip_velocity = self._site_velocity(self.pinned, pinned_data, "hip", qd)
        stance, knee1, hip1, hip2, knee2 = q
        qf = np.array([hip[0], hip[2], stance - knee1 - hip1, hip1, knee1, hip2, knee2])
        qfd = np.array([hip_velocity[0], hip_velocity[2], qd[0] - qd[1] - qd[2], *qd[ACTUATED_INDEX]])
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
        qfd_after, impulse = impact.inelastic_impact(self._floating_mass, jac, qfd, xp=np)
        relabelled, to_pinned = planar_biped.RELABEL, planar_biped.FLOATING_TO_PINNED
        q_next, qd_next = to_pinned @ qf[relabelled], to_pinned @ qfd_after[relabelled]
        return impact.Touchdown(q=q_next, qd=qd_next, impulse=impulse,
                                old_stance_foot_velocity=jacobians["foot1"] @ qfd_after,
                                floating_qd_before=qfd, floating_qd_after=qfd_after, floating_q=qf)
