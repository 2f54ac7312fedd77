"""The replay's report: steps, speed, tracking, slip, friction, torques and touchdowns (JSON-ready)."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from biped_jax.humanoid.controller import Gains
from biped_jax.humanoid.model import SIDES, Layout
from biped_jax.humanoid.reference import GaitReference
from biped_jax.humanoid.walk import Replay, fallen
from biped_jax.humanoid.touchdown import IMPACT_SETTLE, compare_touchdowns, touchdown_indices


def applied_torque(run: Replay, layout: Layout, gains: Gains) -> np.ndarray:
    """Joint torques the loops applied, shape (N, 16), N m, actuator order: the hips' and knees' commands
    with their damping, and the held joints' spring-dampers (see :func:`with_gains`)."""
    joints = np.array(layout.held_q)
    torque = run.ctrl - gains.held_stiffness * run.qpos[:, joints] - gains.held_damping * run.qvel[:, joints]
    for actuator, joint in zip(layout.actuator_hip + layout.actuator_knee, layout.hip + layout.knee):
        torque[:, actuator] = run.ctrl[:, actuator] - gains.sagittal_damping * run.qvel[:, joint]
    return torque


def walk_report(run: Replay, mj_model: mujoco.MjModel, layout: Layout, reference: GaitReference,
                gains: Gains) -> dict:
    """Steps, distance, speed, fall, tracking errors, foot slip, friction use, torques and the touchdowns
    against the impact map (JSON-ready)."""
    dt = float(mj_model.opt.timestep)
    touchdowns = touchdown_indices(run)
    errors = run.joints - run.target
    settled = np.ones(len(run.t), bool)
    for k in touchdowns:
        settled[k + 1:k + 1 + int(round(IMPACT_SETTLE / dt))] = False
    stance_force = run.foot_force[np.arange(len(run.t)), run.stance]
    loaded = stance_force[:, 2] > 1.0
    slips = []
    bounds = np.concatenate([[0], touchdowns + 1, [len(run.t)]])
    for start, stop in zip(bounds[:-1], bounds[1:]):
        foot = run.feet[start:stop, int(run.stance[start]), 0]
        if len(foot):
            slips.append(float(foot.max() - foot.min()))
    duration = float(run.t[-1])
    distance = float(run.qpos[-1, 0] - run.qpos[0, 0])
    walked = float(run.t[touchdowns[-1]]) if len(touchdowns) else duration
    sagittal = layout.sagittal_actuators
    names = ("hip_pitch_l", "knee_l", "hip_pitch_r", "knee_r")
    torque = applied_torque(run, layout, gains)
    return {
        "steps": int(len(touchdowns)),
        "fell": fallen(run.qpos[-1]),
        "duration_s": duration,
        "distance_m": distance,
        "speed_mps": float((run.qpos[touchdowns[-1], 0] - run.qpos[0, 0]) / walked) if len(touchdowns) else 0.0,
        "gait_speed_mps": float(reference.speed),
        "step_time_s": float(np.mean(np.diff(run.t[touchdowns]))) if len(touchdowns) > 1 else None,
        "gait_step_time_s": float(reference.step_time),
        "step_lengths_m": np.diff(np.array([run.feet[k, 1 - run.stance[k], 0] for k in touchdowns])).tolist(),
        "tracking_error_rad": {
            "rms": float(np.sqrt(np.mean(errors[settled] ** 2))),
            "max": float(np.abs(errors[settled]).max()),
            "max_including_impacts": float(np.abs(errors).max()),
            "per_joint_rms_H1_K1_H2_K2": np.sqrt(np.mean(errors[settled] ** 2, axis=0)).tolist(),
        },
        "stance_foot_slip_m": max(slips) if slips else 0.0,
        "max_friction_use": float(np.max(np.abs(stance_force[loaded, 0]) / stance_force[loaded, 2]))
        if loaded.any() else None,
        "min_hip_height_m": float(run.qpos[:, 1].min()),
        "max_abs_torque_Nm": dict(zip(names, np.abs(torque[:, sagittal]).max(axis=0).tolist())),
        "gait_max_abs_torque_Nm": float(np.abs(np.asarray(reference.torque)).max()),
        "max_abs_held_torque_Nm": float(np.abs(np.delete(torque, sagittal, axis=1)).max()),
        "max_abs_lateral_angle_rad": float(np.abs(run.qpos[:, [
            int(mj_model.joint(f"{j}_{s}").qposadr[0]) for j in ("hip_yaw", "hip_roll", "ankle_roll")
            for s in SIDES]]).max()),
        "gains": {k: float(v) for k, v in dataclasses.asdict(gains).items()},
        "timestep_s": dt,
        "touchdowns": compare_touchdowns(run, mj_model, layout, gains),
    }
