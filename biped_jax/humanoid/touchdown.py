"""The replay's touchdowns against the rigid impact map the optimiser assumes, in MuJoCo C: in the
replay itself and isolated from the controller."""

from __future__ import annotations

import copy

import mujoco
import numpy as np

from biped_jax.dynamics import impact
from biped_jax.humanoid.controller import Gains, with_gains
from biped_jax.humanoid.model import SIDES, Layout, sagittal_columns
from biped_jax.humanoid.walk import Replay
from biped_jax.robots import registry

#: Tracking errors are summarised outside this time after each touchdown, s (the contact model's
#: impact lasts some milliseconds; the rigid model's is instantaneous).
IMPACT_SETTLE = 0.02


def touchdown_indices(run: Replay) -> np.ndarray:
    """Indices k of the physics steps after which the swing foot touched down, shape (K,)."""
    return np.flatnonzero(np.diff(run.stance) != 0)


def rigid_impact(mj_model: mujoco.MjModel, layout: Layout, qpos: np.ndarray, qvel: np.ndarray,
                 stance: int) -> tuple[np.ndarray, np.ndarray]:
    """The optimiser's impact map on the humanoid (held joints locked, as in the planar model): the
    landing foot (leg ``1 - stance``) stops, M dqd = J^T Lambda. Returns (sagittal velocity jump,
    shape (7,), impulse on the landing foot (x, z), shape (2,), N s) at the pre-impact state."""
    data = mujoco.MjData(mj_model)
    data.qpos[:], data.qvel[:] = qpos, qvel
    mujoco.mj_forward(mj_model, data)
    mass = np.zeros((mj_model.nv, mj_model.nv))
    mujoco.mj_fullM(mj_model, data, mass)
    jac = np.zeros((3, mj_model.nv))
    mujoco.mj_jacSite(mj_model, data, jac, None, layout.foot_site[1 - stance])
    columns = sagittal_columns(layout, stance)
    before = qvel[columns]
    after, impulse = impact.inelastic_impact(mass[np.ix_(columns, columns)], jac[[0, 2]][:, columns], before, xp=np)
    return after - before, impulse


#: The isolated touchdown ends when the landing foot's speed has fallen below this share of its speed
#: before contact (the rigid map stops it completely; the soft contact only asymptotically).
STOPPED_FRACTION = 0.1


def c_model_with_gains(mj_model: mujoco.MjModel, layout: Layout, gains: Gains) -> mujoco.MjModel:
    """A copy of the MuJoCo C model with the PD loops' joint damping and springs of :func:`with_gains`."""
    model = copy.deepcopy(mj_model)
    tuned = with_gains(registry.put_mjx_model(mj_model), layout, gains)
    model.dof_damping[:] = np.asarray(tuned.dof_damping)
    model.jnt_stiffness[:] = np.asarray(tuned.jnt_stiffness)
    return model


def _foot_ground_force(model: mujoco.MjModel, data: mujoco.MjData, geom: int) -> np.ndarray:
    """World-frame force of the ground on ``geom`` during the last step, shape (3,), N."""
    total, force = np.zeros(3), np.zeros(6)
    for c in range(data.ncon):
        contact = data.contact[c]
        if geom in (contact.geom1, contact.geom2):
            mujoco.mj_contactForce(model, data, c, force)
            sign = 1.0 if contact.geom2 == geom else -1.0  # the frame's normal points from geom1 to geom2
            total += sign * contact.frame.reshape(3, 3).T @ force[:3]
    return total


def _momentum_and_site_speed(model: mujoco.MjModel, data: mujoco.MjData, site: int) -> tuple[np.ndarray, float]:
    """The robot's linear momentum, shape (3,), N s, and the speed of ``site``, m/s, at data's state."""
    mujoco.mj_forward(model, data)
    mujoco.mj_subtreeVel(model, data)
    velocity = np.zeros(6)
    mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_SITE, site, velocity, 0)
    return float(model.body_subtreemass[0]) * data.subtree_linvel[0].copy(), float(np.linalg.norm(velocity[3:]))


def isolated_touchdown(model: mujoco.MjModel, layout: Layout, qpos: np.ndarray, qvel: np.ndarray,
                       ctrl: np.ndarray, stance: int, window: float = 0.02) -> dict:
    """The contact model's touchdown without the control loop's reaction to it: MuJoCo C stepped from
    (qpos, qvel), the state before the landing foot's (leg ``1 - stance``) first contact, with the
    torques ``ctrl`` of that moment held, once as is and once without the landing foot's contact (its
    twin), until the landing foot's speed falls below :data:`STOPPED_FRACTION` of its speed before
    contact or ``window`` s pass. ``model``: the simulated model, gains included
    (:func:`c_model_with_gains`). Returns (SI units) duration; the landing foot's ground impulse (x, z);
    the sagittal velocity change (7,) the contact caused (with minus twin: the same gravity, torques and
    damping act on both); the robot's linear momentum change, with minus twin, (x, z)."""
    geom = model.geom(f"foot_{SIDES[1 - stance]}").id
    site = layout.foot_site[1 - stance]
    columns = sagittal_columns(layout, stance)
    steps = max(1, int(round(window / model.opt.timestep)))
    twin_model = copy.deepcopy(model)
    twin_model.geom_contype[geom] = twin_model.geom_conaffinity[geom] = 0

    def run(simulated: mujoco.MjModel):
        data = mujoco.MjData(simulated)
        data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, ctrl
        momentum, speed0 = _momentum_and_site_speed(simulated, data, site)
        impulse, states = np.zeros(3), []
        for _ in range(steps):
            mujoco.mj_step(simulated, data)
            impulse += _foot_ground_force(simulated, data, geom) * simulated.opt.timestep
            now, speed = _momentum_and_site_speed(simulated, data, site)
            states.append((data.qvel[columns].copy(), impulse.copy(), now - momentum,
                           speed <= STOPPED_FRACTION * speed0))
        return states

    touching, twin = run(model), run(twin_model)
    end = next((i for i, state in enumerate(touching) if state[3]), steps - 1)
    velocity, impulse, momentum, _ = touching[end]
    return {"duration_s": (end + 1) * float(model.opt.timestep), "impulse_Ns": impulse[[0, 2]],
            "velocity_jump": velocity - twin[end][0], "momentum_change_Ns": (momentum - twin[end][2])[[0, 2]]}


def compare_touchdowns(run: Replay, mj_model: mujoco.MjModel, layout: Layout, gains: Gains) -> list[dict]:
    """Each touchdown of the replay against the rigid impact map, applied at the state just before the
    landing foot's first contact.

    Two views of the contact model's touchdown: in the replay itself (closed loop: the first contact's
    duration, impulse and peak force, and whether the landing foot leaves the ground again within
    :data:`IMPACT_SETTLE`), and isolated from the controller (:func:`isolated_touchdown`: torques held,
    until the foot has nearly stopped), whose impulse and velocity change are compared with the map's.
    """
    dt = float(mj_model.opt.timestep)
    model = c_model_with_gains(mj_model, layout, gains)
    settle = int(round(IMPACT_SETTLE / dt))
    records = []
    for k in touchdown_indices(run):
        stance = int(run.stance[k])
        landing = 1 - stance
        first = k  # the step in which the landing foot first carried force
        while first > 0 and run.foot_force[first - 1, landing, 2] > 0:
            first -= 1
        loaded = run.foot_force[first:first + settle, landing, 2] > 0
        contact_steps = int(np.argmin(loaded)) if not loaded.all() else len(loaded)
        closed_loop_impulse = run.foot_force[first:first + contact_steps, landing][:, [0, 2]].sum(axis=0) * dt
        before_q, before_v = run.qpos[first - 1], run.qvel[first - 1]
        predicted_jump, predicted_impulse = rigid_impact(mj_model, layout, before_q, before_v, stance)
        isolated = isolated_touchdown(model, layout, before_q, before_v, run.ctrl[first], stance, IMPACT_SETTLE)
        records.append({
            "time_s": float(run.t[first - 1]), "landing_leg": SIDES[landing],
            "impact_map_impulse_Ns": predicted_impulse.tolist(),
            "impact_map_velocity_jump": predicted_jump.tolist(),
            "replay_first_contact_s": contact_steps * dt,
            "replay_first_contact_impulse_Ns": closed_loop_impulse.tolist(),
            "replay_peak_force_N": float(run.foot_force[first:first + contact_steps, landing, 2].max()),
            # the landing foot left the ground again within IMPACT_SETTLE of its first contact
            "replay_rebound": bool(contact_steps < len(loaded)),
            "isolated_duration_s": isolated["duration_s"],
            "impulse_Ns": isolated["impulse_Ns"].tolist(),
            "velocity_jump": isolated["velocity_jump"].tolist(),
            "momentum_change_Ns": isolated["momentum_change_Ns"].tolist(),
            "impulse_relative_error": float(np.linalg.norm(isolated["impulse_Ns"] - predicted_impulse)
                                            / np.linalg.norm(predicted_impulse)),
            "velocity_jump_relative_error": float(np.linalg.norm(isolated["velocity_jump"] - predicted_jump)
                                                  / np.linalg.norm(predicted_jump)),
        })
    return records
