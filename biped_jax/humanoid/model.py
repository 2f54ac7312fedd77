"""The planarised 16-DoF humanoid the replay simulates, and where its joints are.

Coordinates of the planarised model: qpos = (x, z, pitch, 16 joints); x, z the hip centre (the torso
frame) in metres, pitch about +y in rad, as in the floating planar model. Leg "l" is the planar
model's leg 1 at the start.
"""


from __future__ import annotations

import dataclasses

import mujoco

from biped_jax.robots import registry
from biped_jax.robots.mjcf import HUMANOID_ACTUATED_JOINTS

#: Physics step of the replay, s (contacts want a step well below the optimiser's 6 ms).
TIMESTEP = 1e-3
#: Rotor-like inertia on the held ankle joints, kg m^2 (the point foot's own is 4e-9, too stiff for
#: a PD loop at 1 ms); it is of the order of a geared motor's reflected inertia.
ANKLE_ARMATURE = 1e-3
#: Contact of the feet: a stiff, critically damped soft contact (time constant 4 ms = 4 steps, MuJoCo's
#: default 20 ms lets the point foot sink and creep) and hard friction (impratio), so that the stance
#: foot acts like the optimiser's pin as long as the force stays inside the friction cone.
FOOT_SOLREF = (0.004, 1.0)
FOOT_SOLIMP = (0.95, 0.99, 0.001, 0.5, 2.0)
IMPRATIO = 10.0

SIDES = ("l", "r")


def with_replay_contact(spec: mujoco.MjSpec) -> mujoco.MjSpec:
    """``spec`` (a humanoid's, point or flat feet) with the replays' time step :data:`TIMESTEP`, friction
    cone (:data:`IMPRATIO`) and foot contact (:data:`FOOT_SOLREF`, :data:`FOOT_SOLIMP`); changed in place."""
    for side in SIDES:
        foot = spec.geom(f"foot_{side}")
        foot.solref, foot.solimp = FOOT_SOLREF, FOOT_SOLIMP
    spec.option.timestep = TIMESTEP
    spec.option.impratio = IMPRATIO
    return spec


def external_forces(model, data):
    """The force of the surroundings (the ground) on each body at MJX ``data`` after its constraint
    forces are found (after ``mjx.forward``), world frame, (nbody, 3), N."""
    mjx = registry.import_mjx()
    return registry.jax_fields(mjx.rne_postconstraint(model, data)).cfrc_ext[:, 3:]


def planarised_humanoid(mass_class: str = "12kg") -> mujoco.MjModel:
    """The point-foot humanoid of ``mass_class`` with its free base replaced by a planar one (slide x,
    slide z, hinge y at the hip centre): the planarising constraint. Time step :data:`TIMESTEP`."""
    if mass_class not in ("12kg", "18kg"):
        raise ValueError(f"unknown humanoid mass class {mass_class!r}; known: '12kg', '18kg'")
    spec = mujoco.MjSpec.from_file(str(registry.model_path(f"humanoid16_{mass_class}")))
    torso = spec.body("torso")
    spec.delete(spec.joint("root"))
    torso.pos = [0.0, 0.0, 0.0]
    for name, kind, axis in (("root_x", mujoco.mjtJoint.mjJNT_SLIDE, [1, 0, 0]),
                             ("root_z", mujoco.mjtJoint.mjJNT_SLIDE, [0, 0, 1]),
                             ("root_pitch", mujoco.mjtJoint.mjJNT_HINGE, [0, 1, 0])):
        torso.add_joint(name=name, type=kind, axis=axis)
    for side in SIDES:
        for joint in ("ankle_pitch", "ankle_roll"):
            spec.joint(f"{joint}_{side}").armature = ANKLE_ARMATURE
    model = with_replay_contact(spec).compile()
    # the root joints were added after the legs in the spec's joint list; the body tree puts them first
    assert model.joint("root_x").qposadr[0] == 0 and model.joint("root_pitch").qposadr[0] == 2
    return model


@dataclasses.dataclass(frozen=True)
class Layout:
    """Indices into the planarised model (static)."""

    hip: tuple[int, int]  # qpos/qvel index of hip_pitch_l, hip_pitch_r
    knee: tuple[int, int]
    actuator_hip: tuple[int, int]
    actuator_knee: tuple[int, int]
    held_q: tuple[int, ...]  # every actuated joint's qpos index, actuator order
    foot_site: tuple[int, int]
    foot_body: tuple[int, int]

    @property
    def sagittal_q(self) -> list[int]:
        """qpos/qvel indices of (hip l, knee l, hip r, knee r): (H1, K1, H2, K2) with leg l standing."""
        return [self.hip[0], self.knee[0], self.hip[1], self.knee[1]]

    @property
    def sagittal_actuators(self) -> list[int]:
        """Actuator indices of (hip l, knee l, hip r, knee r)."""
        return [self.actuator_hip[0], self.actuator_knee[0], self.actuator_hip[1], self.actuator_knee[1]]

    @classmethod
    def of(cls, model: mujoco.MjModel) -> "Layout":
        joint = lambda name: int(model.joint(name).qposadr[0])  # noqa: E731 (hinges: qpos = dof index + 0)
        actuator = lambda name: int(model.actuator(name).id)  # noqa: E731
        for a, name in enumerate(HUMANOID_ACTUATED_JOINTS):
            assert model.actuator(a).name == name
            assert model.joint(name).qposadr[0] == model.joint(name).dofadr[0]  # planar base: no quaternion
        return cls(hip=tuple(joint(f"hip_pitch_{s}") for s in SIDES),
                   knee=tuple(joint(f"knee_{s}") for s in SIDES),
                   actuator_hip=tuple(actuator(f"hip_pitch_{s}") for s in SIDES),
                   actuator_knee=tuple(actuator(f"knee_{s}") for s in SIDES),
                   held_q=tuple(joint(name) for name in HUMANOID_ACTUATED_JOINTS),
                   foot_site=tuple(int(model.site(f"foot_{s}").id) for s in SIDES),
                   foot_body=tuple(int(model.body(f"foot_{s}").id) for s in SIDES))


def sagittal_columns(layout: Layout, stance: int) -> list[int]:
    """Planarised-model columns of the floating planar coordinates (x, z, pitch, hip1, knee1, hip2, knee2)
    with leg ``stance`` as leg 1."""
    return [0, 1, 2, layout.hip[stance], layout.knee[stance], layout.hip[1 - stance], layout.knee[1 - stance]]
