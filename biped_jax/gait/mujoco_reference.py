"""The gait rollout of ``biped_jax.gait.problem`` computed with MuJoCo C instead of MJX.

The same step (B-spline joint references prescribed, the stance angle's zero dynamics by classical
Runge-Kutta, torques from the actuated rows, inelastic impact, relabelling) with the physics in
MuJoCo's C library (the ``mujoco`` backend of :mod:`biped_jax.dynamics.interface`). Two uses: the
tests compare it with the MJX rollout (MJX against MuJoCo C on the optimiser's own trajectories), and
the gradient benchmark uses it, with central finite differences, as the baseline a user without MJX
would have.

Not differentiable and not batched; one :class:`CGaitRollout` per process.
"""

from __future__ import annotations

import numpy as np

from biped_jax.dynamics import interface
from biped_jax.dynamics.mujoco_c import MujocoDynamics
from biped_jax.gait import problem as gait_problem
from biped_jax.robots.planar_biped import pinned_coordinates


class CGaitRollout:
    """The MuJoCo C backend of one biped (``mass_class`` as in :func:`biped_jax.gait.problem.gait_model`,
    nominal design) for :meth:`simulate`."""

    def __init__(self, mass_class: str, settings: gait_problem.GaitSettings):
        self.settings = settings
        self.dynamics = MujocoDynamics.nominal(mass_class)

    def _acceleration(self, theta: float, rate: float, ref) -> float:
        q, qd = pinned_coordinates(theta, ref[0]), pinned_coordinates(rate, ref[1])
        mass, bias, _ = self.dynamics.terms(q, qd)
        return float(gait_problem.zero_dynamics_acceleration(mass, bias, ref[2]))

    def simulate(self, x: np.ndarray, speed: float, step_length: float) -> gait_problem.GaitTrajectory:
        """The step of decision vector ``x`` (shape (settings.size,)) at ``speed`` m/s over
        ``step_length`` m; arrays as in :class:`biped_jax.gait.problem.GaitTrajectory` (numpy)."""
        settings = self.settings
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
            q, qd = pinned_coordinates(theta[k], at_grid[0, k]), pinned_coordinates(rate[k], at_grid[1, k])
            mass, bias, data = self.dynamics.terms(q, qd)
            qdd = pinned_coordinates(gait_problem.zero_dynamics_acceleration(mass, bias, at_grid[2, k]), at_grid[2, k])
            force, positions = self.dynamics.outputs(q, qd, qdd, data)
            rows["sites"].append(positions)
            rows["force"].append(force)
            for name, value in (("q", q), ("qd", qd), ("qdd", qdd), ("u", gait_problem.actuated_torque(mass, bias,
                                                                                                       qdd))):
                rows[name].append(np.array(value))
        positions = np.stack(rows["sites"])
        _, foot_velocity = self.dynamics.swing_foot(q, qd)
        return gait_problem.GaitTrajectory(
            t=s * step_time, weights=gait_problem.simpson_weights(settings) * step_time, q=np.stack(rows["q"]),
            qd=np.stack(rows["qd"]), qdd=np.stack(rows["qdd"]), u=np.stack(rows["u"]),
            ground_force=np.stack(rows["force"]), swing_foot=positions[:, 0], heights=positions[:, 1:, 1],
            touchdown=interface.touchdown(self.dynamics, q, qd), swing_foot_velocity=foot_velocity,
            continuity=np.array(defects).reshape(-1, 2))
