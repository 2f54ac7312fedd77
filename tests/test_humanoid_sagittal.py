"""The 16-DoF humanoid, lateral joints held and arms still, moves in the sagittal plane exactly like
the planar five-link model whose links are the humanoid's composite bodies."""

import mujoco
import numpy as np
import pytest

from biped_jax.robots import registry

# Lumped into each planar link: the humanoid's arms and head ride on the torso, the foot on the shank.
GROUPS = {"torso": ("torso", "arm_l", "arm_r"), "thigh1": ("thigh_l",), "shank1": ("shank_l", "foot_l"),
          "thigh2": ("thigh_r",), "shank2": ("shank_r", "foot_r")}
SAGITTAL_JOINTS = ("hip_pitch_l", "knee_l", "hip_pitch_r", "knee_r")
# Both sides are exact rigid-body dynamics of the same bodies; only round-off differs.
TOLERANCE = 1e-9


def _composite(model, data, bodies):
    """Mass, centre (root body frame) and diagonal inertia of rigidly joined bodies at the current pose."""
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in bodies]
    mass = sum(model.body_mass[i] for i in ids)
    com = sum(model.body_mass[i] * data.xipos[i] for i in ids) / mass
    tensor = np.zeros((3, 3))
    for i in ids:
        rotation = data.ximat[i].reshape(3, 3)
        r = data.xipos[i] - com
        tensor += rotation @ np.diag(model.body_inertia[i]) @ rotation.T
        tensor += model.body_mass[i] * (r @ r * np.eye(3) - np.outer(r, r))
    # Planar motion spins about y only: the y products must vanish (an x-z product, as a flat foot
    # ahead of the ankle has, does not enter the sagittal dynamics).
    assert abs(tensor[0, 1]) < 1e-12 and abs(tensor[1, 2]) < 1e-12
    root_rotation = data.xmat[ids[0]].reshape(3, 3)
    return mass, root_rotation.T @ (com - data.xpos[ids[0]]), np.diag(tensor)


def _sagittal_equivalent(humanoid):
    """The planar floating model with the humanoid's composite links."""
    planar = registry.load_mj_model("biped5_floating_12kg")
    data = mujoco.MjData(humanoid)
    mujoco.mj_kinematics(humanoid, data)
    for link, bodies in GROUPS.items():
        i = mujoco.mj_name2id(planar, mujoco.mjtObj.mjOBJ_BODY, link)
        planar.body_mass[i], planar.body_ipos[i], planar.body_inertia[i] = _composite(humanoid, data,
                                                                                      bodies)
    mujoco.mj_setConst(planar, mujoco.MjData(planar))
    return planar


@pytest.mark.parametrize("name", ["humanoid16_12kg", "humanoid16_18kg", "humanoid16_flatfoot_12kg"])
def test_humanoid_sagittal_accelerations_equal_the_planar_model(name):
    humanoid = registry.load_mj_model(name)
    planar = _sagittal_equivalent(humanoid)
    rng = np.random.default_rng(4)
    dof = {j: humanoid.jnt_dofadr[mujoco.mj_name2id(humanoid, mujoco.mjtObj.mjOBJ_JOINT, j)]
           for j in SAGITTAL_JOINTS}
    qadr = {j: humanoid.jnt_qposadr[mujoco.mj_name2id(humanoid, mujoco.mjtObj.mjOBJ_JOINT, j)]
            for j in SAGITTAL_JOINTS}
    actuator = {j: mujoco.mj_name2id(humanoid, mujoco.mjtObj.mjOBJ_ACTUATOR, j) for j in SAGITTAL_JOINTS}
    sagittal = np.array([0, 2, 4] + [dof[j] for j in SAGITTAL_JOINTS])
    for _ in range(3):
        # planar state (x, z, pitch, hip1, knee1, hip2, knee2), rates and torques (H1, K1, H2, K2)
        q = np.concatenate([[0.1, 2.0], rng.normal(scale=0.4, size=5)])
        qd = rng.normal(size=7)
        u = rng.normal(scale=3.0, size=4)
        planar_data = mujoco.MjData(planar)
        planar_data.qpos[:], planar_data.qvel[:], planar_data.ctrl[:] = q, qd, u
        mujoco.mj_forward(planar, planar_data)

        data = mujoco.MjData(humanoid)
        data.qpos[[0, 2]] = q[:2]
        data.qpos[3:7] = [np.cos(q[2] / 2), 0.0, np.sin(q[2] / 2), 0.0]
        data.qvel[[0, 2, 4]] = qd[:3]  # free joint: linear (world), angular (body) = pitch rate
        for k, joint in enumerate(SAGITTAL_JOINTS):
            data.qpos[qadr[joint]], data.qvel[dof[joint]] = q[3 + k], qd[3 + k]
            data.ctrl[actuator[joint]] = u[k]
        mujoco.mj_forward(humanoid, data)
        mass = np.zeros((humanoid.nv, humanoid.nv))
        mujoco.mj_fullM(humanoid, data, mass)
        force = data.qfrc_actuator - data.qfrc_bias
        # Held joints: zero acceleration, so the sagittal rows decouple.
        held_acceleration = np.linalg.solve(mass[np.ix_(sagittal, sagittal)], force[sagittal])
        scale = np.abs(planar_data.qacc).max()
        np.testing.assert_allclose(held_acceleration, planar_data.qacc, atol=TOLERANCE * scale)
