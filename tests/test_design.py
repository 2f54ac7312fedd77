"""Design parameters as arrays: no recompilation across designs, vmap over designs, and the same
dynamics as a freshly compiled MJCF file with those numbers."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from biped_jax.dynamics import interface
from biped_jax.dynamics import mjx_biped
from biped_jax.robots import design as design_lib
from biped_jax.robots import registry
from biped_jax.robots.mjcf import planar_pinned_xml
from biped_jax.robots.specs import PlanarBipedSpec

mjx = registry.import_mjx()

Q = jnp.array([0.2, 0.3, -0.1, 0.4, 0.6])
QD = jnp.array([1.0, -0.5, 0.3, 2.0, -1.0])
U = jnp.array([1.0, 2.0, -1.0, 0.5])
# MJCF files store inertias with 10 significant digits.
FILE_ROUNDING = 1e-9


def test_18kg_design_on_the_12kg_model_equals_the_18kg_file(biped12, biped18):
    """Masses (and the inertias that follow) of the 18 kg file applied as arrays to the 12 kg model
    give the 18 kg file's mass matrix, bias forces and accelerations in both variants."""
    heavy = mjx_biped.with_design(biped12, mjx_biped.planar_design("18kg"))
    acceleration = jax.jit(mjx_biped.stance_acceleration)
    np.testing.assert_allclose(acceleration(heavy.pinned, Q, QD, U),
                               acceleration(biped18.pinned, Q, QD, U), rtol=FILE_ROUNDING)
    qf, qfd = jax.jit(mjx_biped.pinned_to_floating)(biped18.pinned, Q, QD)
    mass_matrix = jax.jit(mjx_biped.mass_matrix)
    np.testing.assert_allclose(mass_matrix(heavy.floating, qf), mass_matrix(biped18.floating, qf),
                               rtol=FILE_ROUNDING)
    np.testing.assert_allclose(heavy.pinned.body_subtreemass, biped18.pinned.body_subtreemass,
                               rtol=1e-12)


def test_arbitrary_design_matches_a_freshly_compiled_mjcf():
    """Armature, damping and unequal link masses against MuJoCo C compiling a file with those numbers."""
    spec = PlanarBipedSpec(torso_mass=9.0, thigh_mass=1.5, shank_mass=0.8)
    fresh = mujoco.MjModel.from_xml_string(planar_pinned_xml(spec, "fresh"))
    layout = mjx_biped.planar_layouts()[0]
    armature = np.array([0.01, 0.02, 0.03, 0.04])
    damping = np.array([0.1, 0.0, 0.2, 0.3])
    fresh.dof_armature[layout.dof_ids] = armature
    fresh.dof_damping[layout.dof_ids] = damping
    data = mujoco.MjData(fresh)
    data.qpos[:], data.qvel[:], data.ctrl[:] = Q, QD, U
    mujoco.mj_forward(fresh, data)

    design = design_lib.Design(link_mass=jnp.array([9.0, 1.5, 0.8, 1.5, 0.8]),
                               joint_armature=jnp.asarray(armature), joint_damping=jnp.asarray(damping),
                               drive_mass=jnp.zeros(4))
    model = design_lib.apply_design(registry.load_mjx_model("biped5_pinned_12kg"), layout,
                                    design_lib.check_design(design, layout))
    np.testing.assert_allclose(jax.jit(mjx_biped.stance_acceleration)(model, Q, QD, U), data.qacc, rtol=1e-10)
    np.testing.assert_allclose(model.body_subtreemass, fresh.body_subtreemass, rtol=1e-12)


def test_changing_the_design_does_not_recompile_and_vmap_runs_many_designs(biped12):
    traces = []

    @jax.jit
    def end_state(design, controls):
        traces.append(1)  # runs only while tracing
        biped = mjx_biped.with_design(biped12, design)
        trajectory = interface.stance_rollout(interface.stance_dynamics(biped, "mjx"), Q, QD, controls)
        return trajectory.q[-1]

    controls = jnp.zeros((20, 4))
    light, heavy = mjx_biped.planar_design("12kg"), mjx_biped.planar_design("18kg")
    end_light = end_state(light, controls)
    end_heavy = end_state(heavy, controls)
    assert len(traces) == 1
    assert float(jnp.max(jnp.abs(end_light - end_heavy))) > 1e-6  # the design does change the motion

    batch = jax.tree.map(lambda a, b: jnp.stack([a, b, a]), light, heavy)
    batched = jax.jit(jax.vmap(end_state, in_axes=(0, None)))(batch, controls)
    np.testing.assert_allclose(batched[0], end_light, rtol=1e-12)
    np.testing.assert_allclose(batched[1], end_heavy, rtol=1e-12)


@pytest.mark.parametrize("knee_offsets", [(0.0, 0.0), (0.4, 0.7)])
def test_drive_masses_match_point_masses_compiled_by_mujoco(knee_offsets):
    """Drives as arrays (point masses at the joints on their mounting links, the knee drives moved
    ``knee_offsets`` of the way up their thighs to the hips) against MuJoCo C compiling the file with a
    welded point-mass body at each drive: same accelerations, subtree masses and total mass. Hips sit
    at the torso's origin; the pinned chain runs foot -> knee1 -> hip, so knee1 is thigh1's origin and
    hip1 one thigh length above it, and knee2 lies one thigh length below thigh2's origin (hip2)."""
    spec = PlanarBipedSpec(torso_mass=9.0, thigh_mass=1.5, shank_mass=0.8)
    drive_mass = np.array([0.3, 0.25, 0.35, 0.2])  # hip1, knee1, hip2, knee2
    mjspec = mujoco.MjSpec.from_string(planar_pinned_xml(spec, "drives"))
    up1, up2 = knee_offsets
    mounts = [("torso", [0, 0, 0]), ("thigh1", [0, 0, up1 * spec.thigh_length]), ("torso", [0, 0, 0]),
              ("thigh2", [0, 0, -(1 - up2) * spec.thigh_length])]
    for (body, position), mass in zip(mounts, drive_mass):
        mjspec.body(body).add_body(pos=position, ipos=[0, 0, 0], mass=mass, inertia=[1e-12] * 3)
    fresh = mjspec.compile()
    data = mujoco.MjData(fresh)
    data.qpos[:], data.qvel[:], data.ctrl[:] = Q, QD, U
    mujoco.mj_forward(fresh, data)

    layout = mjx_biped.planar_layouts()[0]
    design = design_lib.Design(link_mass=jnp.array([9.0, 1.5, 0.8, 1.5, 0.8]), joint_armature=jnp.zeros(4),
                               joint_damping=jnp.zeros(4), drive_mass=jnp.asarray(drive_mass),
                               drive_offset=jnp.array([0.0, up1, 0.0, up2]))
    model = design_lib.apply_design(registry.load_mjx_model("biped5_pinned_12kg"), layout,
                                    design_lib.check_design(design, layout))
    np.testing.assert_allclose(jax.jit(mjx_biped.stance_acceleration)(model, Q, QD, U), data.qacc, rtol=1e-9)
    np.testing.assert_allclose(model.body_subtreemass[1], fresh.body_subtreemass[1], rtol=1e-12)
    assert float(design.total_mass) == pytest.approx(9.0 + 2 * 1.5 + 2 * 0.8 + drive_mass.sum())


@pytest.mark.parametrize("field, value, message", [
    ("link_mass", jnp.array([7.0, 1.0, -1.0, 1.0, 1.0]), "link_mass must be positive"),
    ("link_mass", jnp.ones(4), r"link_mass must have shape \(5,\), got \(4,\)"),
    ("joint_armature", -jnp.ones(4), "joint_armature must be non-negative"),
    ("joint_damping", jnp.full(4, jnp.nan), "joint_damping must be finite"),
    ("drive_mass", jnp.array([0.3, -0.1, 0.3, 0.3]), "drive_mass must be non-negative"),
    ("drive_offset", jnp.array([0.0, 1.5, 0.0, 0.0]), r"drive_offset must be within \[0, 1\]"),
    ("drive_offset", jnp.zeros(3), r"drive_offset must have shape \(4,\)"),
])
def test_bad_designs_are_rejected_naming_the_value(field, value, message):
    import dataclasses
    layout = mjx_biped.planar_layouts()[0]
    design = dataclasses.replace(mjx_biped.planar_design("12kg"), **{field: value})
    with pytest.raises(ValueError, match=message):
        design_lib.check_design(design, layout)


def test_unknown_link_name_is_rejected():
    with pytest.raises(ValueError, match="'tail'"):
        design_lib.design_layout(registry.load_mj_model("biped5_pinned_12kg"), ("torso", "tail"), ())
