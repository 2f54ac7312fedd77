"""Every robot loads in MuJoCo and MJX, the committed MJCF files match their generators, and bad
input is rejected with an error naming the value."""

import dataclasses

import jax
import mujoco
import numpy as np
import pytest

from biped_jax.robots import mjcf
from biped_jax.robots import registry
from biped_jax.robots.specs import DonaldSpec, HumanoidSpec, PlanarBipedSpec

mjx = registry.import_mjx()

# Table 2 masses sum to 11.999 and 17.998 kg; the flat-foot humanoid adds two 0.2 kg feet (ours).
TOTAL_MASS = {"12kg": 11.999, "18kg": 17.998, "kelly": 40.0}


def test_committed_models_match_generators():
    """models/*.xml are exactly what biped_jax.robots.mjcf writes, so no variant can drift."""
    directory = registry.models_dir()
    sources = mjcf.model_sources()
    assert sorted(p.name for p in directory.glob("*.xml")) == sorted(sources)
    for name, text in sources.items():
        assert (directory / name).read_text() == text, f"{name} is stale: run python -m biped_jax.robots.mjcf"


def test_a_model_and_its_variants_are_one_program(biped12):
    """jit specialises on whether arguments are committed to a device (``mjx.put_model`` commits, ``jnp.array``
    does not), so a model whose arrays were committed gave a second program for the same computation
    wherever an uncommitted leaf or state met it (``with_timestep``, a rollout's end state): the loaded
    models are uncommitted, and the rollout of the model, of its ``with_timestep`` and ``with_design``
    variants lowers to one program (traced, not compiled), which a committed copy does not."""
    from biped_jax.dynamics import interface, mjx_biped
    for model in (biped12.pinned, biped12.floating, registry.load_mjx_model("donald")):
        assert not [x for x in jax.tree.leaves(model) if isinstance(x, jax.Array) and x.committed]
    state, controls = np.zeros(5), np.zeros((3, 4))

    def lowered(pinned):
        dynamics = interface.stance_dynamics(dataclasses.replace(biped12, pinned=pinned), "mjx")
        return jax.jit(interface.stance_rollout).lower(dynamics, state, state, controls).as_text()
    program = lowered(biped12.pinned)
    assert lowered(mjx_biped.with_timestep(biped12.pinned, 1e-3)) == program
    assert lowered(mjx_biped.with_design(biped12, mjx_biped.planar_design("18kg")).pinned) == program
    committed = jax.tree.map(lambda x: jax.device_put(x, jax.devices()[0]) if isinstance(x, jax.Array) else x,
                             biped12.pinned)
    assert lowered(committed) != program


@pytest.mark.parametrize("name", sorted(registry.ROBOTS))
@pytest.mark.xdist_group("mjx_forward")  # the same jit(mjx.forward) programs
def test_model_loads_and_steps_in_mujoco_and_mjx(name):
    mj_model = registry.load_mj_model(name)
    mj_data = mujoco.MjData(mj_model)
    if mj_model.nkey:
        mujoco.mj_resetDataKeyframe(mj_model, mj_data, 0)
    mujoco.mj_forward(mj_model, mj_data)
    model = registry.put_mjx_model(mj_model)
    data = mjx.put_data(mj_model, mj_data)
    data = jax.jit(mjx.forward)(model, data)
    np.testing.assert_allclose(data.qacc, mj_data.qacc, atol=1e-6 * (1 + np.abs(mj_data.qacc).max()))
    if name.startswith(("biped5", "humanoid")):
        mass_class = name.rsplit("_", 1)[1]
        spec = HumanoidSpec()
        extra = (0.0 if name.startswith("biped5") else
                 2 * (spec.flat_foot_mass if "flatfoot" in name else spec.point_foot_mass))
        assert np.sum(mj_model.body_mass) == pytest.approx(TOTAL_MASS[mass_class] + extra, abs=1e-6)


def test_kelly_biped_follows_kelly_2017():
    """Link centres of mass and inertias of Kelly's benchmark, checked on the standing floating model
    against the numbers of the paper (not the spec object)."""
    model = registry.load_mj_model("biped5_floating_kelly")
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_forward(model, data)
    height = {name: data.xipos[model.body(name).id][2] for name in ("torso", "thigh1", "shank2")}
    assert height["torso"] == pytest.approx(0.8 + 0.425)  # hip at 0.8 m, COM 0.425 m above it
    assert height["thigh1"] == pytest.approx(0.8 - 0.163)  # 0.163 m below the hip
    assert height["shank2"] == pytest.approx(0.4 - 0.128)  # 0.128 m below the knee
    pitch_inertia = {name: model.body_inertia[model.body(name).id][1] for name in ("torso", "thigh1", "shank1")}
    assert pitch_inertia == pytest.approx({"torso": 2.22, "thigh1": 1.08, "shank1": 0.93})
    com_height = (2 * 3.2 * 0.272 + 2 * 6.8 * 0.637 + 20 * 1.225) / 40
    assert data.subtree_com[0][2] == pytest.approx(com_height)


def test_donald_masses_follow_table_7():
    spec = DonaldSpec()
    model = registry.load_mj_model("donald")
    # 4 joint modules (motor+gear+encoder and base plate), 2 links, 2 foot plates, the pendulum bob.
    expected = 4 * (0.376 + 0.137) + 2 * 0.103 + 2 * 0.570 + spec.pendulum_mass
    assert np.sum(model.body_mass) == pytest.approx(expected, abs=1e-9)
    assert model.nu == 5 and model.nv == 6 + 5


def test_humanoid_has_16_actuated_joints_and_free_base():
    model = registry.load_mj_model("humanoid16_12kg")
    assert model.nu == 16 and model.nv == 6 + 16 and model.njnt == 17
    assert model.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE


def test_unknown_model_name_is_named_in_the_error():
    with pytest.raises(ValueError, match="'biped7'"):
        registry.load_mj_model("biped7")


def test_malformed_mjcf_names_the_file(tmp_path):
    bad = tmp_path / "broken.xml"
    bad.write_text("<mujoco><worldbody><body name='a'><joint type='hinge'/></worldbody></mujoco>")
    with pytest.raises(ValueError, match="broken.xml"):
        registry.load_mj_model_from_path(bad)
    with pytest.raises(FileNotFoundError, match="missing.xml"):
        registry.load_mj_model_from_path(tmp_path / "missing.xml")


@pytest.mark.parametrize("field, value", [("thigh_mass", 0.0), ("shank_length", -0.15),
                                          ("torso_mass", float("nan"))])
def test_non_positive_spec_values_are_rejected(field, value):
    with pytest.raises(ValueError, match=field):
        PlanarBipedSpec(**{field: value})


def test_centre_of_mass_beyond_the_link_is_rejected():
    with pytest.raises(ValueError, match="thigh_com 0.5"):
        PlanarBipedSpec(thigh_com=0.5)


def test_humanoid_and_donald_specs_reject_bad_values():
    with pytest.raises(ValueError, match="foot"):
        HumanoidSpec(foot="wooden")
    with pytest.raises(ValueError, match="link_length"):
        DonaldSpec(link_length=0.0)


def test_models_directory_is_inside_an_installed_package_or_the_source_tree():
    directory = registry.models_dir()
    assert (directory / "biped5_pinned_12kg.xml").is_file()
    assert directory.name == "models"
