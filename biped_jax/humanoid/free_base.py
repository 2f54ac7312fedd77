"""The 16-DoF humanoid with its free base and flat feet, its drives in the loop, for the 3D walk.

The model is ``models/humanoid16_flatfoot_<mass class>.xml`` (free joint ``root`` on the torso, box
feet 0.16 x 0.09 m) with the contact of the planarised replay (:mod:`biped_jax.humanoid.model`) and every
actuated joint's drive: the gearhead's reflected inertia as the joint's armature, the torque clipped to
the drive's speed-torque line at the joint's speed (:func:`drive_torques`, the motor model DONALD's walk
uses: :func:`biped_jax.drives.model.torque_limits`). ``external_forces`` (the ground's force per body) is
the replay's, :func:`biped_jax.humanoid.model.external_forces`.

Coordinates: qpos = (x, y, z of the torso frame (m), its quaternion (w, x, y, z), 16 joints (rad) in
actuator order); qvel = (linear velocity (world, m/s), angular velocity (torso frame, rad/s), 16 joint
rates (rad/s)).
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from biped_jax.drives import model as drive_model
from biped_jax.humanoid.model import SIDES, TIMESTEP, external_forces, with_replay_contact  # noqa: F401 (re-exported)
from biped_jax.robots import registry
from biped_jax.robots.mjcf import HUMANOID_ACTUATED_JOINTS

#: The drive of every joint: the pair the drive-train study recommends for both mass classes under the
#: paper's criterion (speed-torque line and gear limits; docs/studies.md, "Drive train").
WALK_MOTOR, WALK_GEARHEAD = "RE25-118754", "GP32A-51"
#: A leg's joints in the model's (and the actuators') order.
LEG_JOINTS = ("hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle_pitch", "ankle_roll")


def walk_drives(motor: str = WALK_MOTOR, gearhead: str = WALK_GEARHEAD,
                supply_voltage: float | None = None, parallel: tuple[str, ...] = ()) -> drive_model.JointDrives:
    """One catalogue drive at every joint (fields of shape ()), at the catalogue's supply voltage unless
    given (V); ``parallel``: joints of both legs (names from :data:`LEG_JOINTS`) driven by two such drives on
    one shaft, fields then per actuator (16,). Raises ValueError naming an unknown part or joint."""
    catalogue = drive_model.load_catalogue()
    voltage = catalogue.supply_voltage if supply_voltage is None else supply_voltage
    drives = drive_model.catalogue_drives(motor, gearhead, voltage, catalogue)
    unknown = sorted(set(parallel) - set(LEG_JOINTS))
    if unknown:
        raise ValueError(f"unknown leg joint(s) {unknown} in parallel; known: {', '.join(LEG_JOINTS)}")
    if not parallel:
        return drives
    count = np.array([2.0 if name.rsplit("_", 1)[0] in parallel else 1.0 for name in HUMANOID_ACTUATED_JOINTS])
    # n identical motors on one shaft: n times the torque at every speed (the windings in parallel: R / n),
    # the gears' torque limits and the reflected inertias add up
    return dataclasses.replace(
        jax.tree.map(lambda field: jnp.broadcast_to(field, count.shape), drives),
        resistance=drives.resistance / count, gear_torque_limit=drives.gear_torque_limit * count,
        reflected_inertia=drives.reflected_inertia * count)


#: The humanoid's mass classes (``models/humanoid16_flatfoot_<mass class>.xml``).
MASS_CLASSES = ("12kg", "18kg")


def check_mass_class(mass_class: str) -> str:
    """``mass_class`` if it is one of :data:`MASS_CLASSES`, else a ValueError naming it."""
    if mass_class not in MASS_CLASSES:
        raise ValueError(f"unknown humanoid mass class {mass_class!r}; known: {', '.join(map(repr, MASS_CLASSES))}")
    return mass_class


def free_base_humanoid(mass_class: str = "12kg", drives: drive_model.JointDrives | None = None) -> mujoco.MjModel:
    """The flat-foot humanoid of ``mass_class`` with its free base, time step :data:`TIMESTEP`, the
    replay's foot contact, and each actuated joint's armature the drive's reflected inertia (``drives``,
    default :func:`walk_drives`)."""
    check_mass_class(mass_class)
    drives = walk_drives() if drives is None else drives
    spec = mujoco.MjSpec.from_file(str(registry.model_path(f"humanoid16_flatfoot_{mass_class}")))
    model = with_replay_contact(spec).compile()
    inertia = np.broadcast_to(np.asarray(drives.reflected_inertia, dtype=float), (model.nu,))
    for actuator in range(model.nu):
        model.dof_armature[model.jnt_dofadr[model.actuator_trnid[actuator, 0]]] = inertia[actuator]
    return model


@dataclasses.dataclass(frozen=True)
class FreeLayout:
    """Indices into the free-base model (static).

    Attributes:
      qpos, qvel: each actuator's joint in qpos and qvel, (16,).
      legs: the actuators of leg l and leg r in :data:`LEG_JOINTS` order, (2, 6).
      arms: the shoulder actuators, (4,).
      torso, feet, thighs: body ids (feet, thighs: (l, r)). foot_sites: site ids (l, r).
      mass: the robot's mass, kg.
    """

    qpos: tuple[int, ...]
    qvel: tuple[int, ...]
    legs: tuple[tuple[int, ...], tuple[int, ...]]
    arms: tuple[int, ...]
    torso: int
    feet: tuple[int, int]
    thighs: tuple[int, int]
    foot_sites: tuple[int, int]
    mass: float

    @classmethod
    def of(cls, model: mujoco.MjModel) -> "FreeLayout":
        names = [model.actuator(a).name for a in range(model.nu)]
        if tuple(names) != HUMANOID_ACTUATED_JOINTS:
            raise ValueError(f"the model's actuators {names} are not the humanoid's {HUMANOID_ACTUATED_JOINTS}")
        body = lambda name: int(model.body(name).id)  # noqa: E731
        return cls(qpos=tuple(int(model.joint(n).qposadr[0]) for n in names),
                   qvel=tuple(int(model.joint(n).dofadr[0]) for n in names),
                   legs=tuple(tuple(names.index(f"{j}_{s}") for j in LEG_JOINTS) for s in SIDES),
                   arms=tuple(i for i, n in enumerate(names) if n.startswith("shoulder")),
                   torso=body("torso"), feet=tuple(body(f"foot_{s}") for s in SIDES),
                   thighs=tuple(body(f"thigh_{s}") for s in SIDES),
                   foot_sites=tuple(int(model.site(f"foot_{s}").id) for s in SIDES),
                   mass=float(model.body_subtreemass[0]))


def drive_torques(drives: drive_model.JointDrives, command: jax.Array, joint_speed: jax.Array
                  ) -> tuple[jax.Array, jax.Array]:
    """(applied torque, (low, high) limits), shapes (J,), (2, J), N m: ``command`` (J,) clipped to what
    each drive gives at its joint's speed (J,), rad/s (the speed-torque line through the gear's
    efficiency, and the gear's intermittent torque); traceable."""
    low, high = drive_model.torque_limits(drives, joint_speed)
    return jnp.clip(command, low, high), jnp.stack([low, high])


def momentum(model, data) -> tuple[jax.Array, jax.Array]:
    """(linear momentum (3,), N s; angular momentum about the centre of mass (3,), N m s) of the robot at
    MJX ``data`` (after ``mjx.forward``), world frame."""
    mjx = registry.import_mjx()
    data = mjx.subtree_vel(model, data)
    mass = model.body_subtreemass[0]
    fields = registry.jax_fields(data)
    return mass * fields.subtree_linvel[0], fields.subtree_angmom[0]


def single_support_torques(mj_model: mujoco.MjModel, qpos: np.ndarray, stance: int) -> np.ndarray:
    """The joint torques that hold pose ``qpos`` still on foot ``stance`` (0 = l, 1 = r) alone, in
    actuator order, (16,), N m: MuJoCo's inverse dynamics at zero velocity and acceleration with the
    ground's wrench on that foot chosen so that the free base needs no force (the whole weight on the
    foot, the centre of pressure where the pose puts it, wherever that is). What a drive must give to
    stand on one leg in that pose; e.g. a level pelvis with the other leg hanging loads the stance hip's
    roll joint with the weight of everything beyond it times its lever arm. For many poses of one model,
    :func:`single_support` once and call what it returns."""
    return single_support(mj_model)(qpos, stance)


def single_support(mj_model: mujoco.MjModel) -> Callable[..., np.ndarray]:
    """:func:`single_support_torques` of ``mj_model`` as a function of (qpos, stance, qvel=None,
    qacc=None), the model's contact-free copy and layout made once. With ``qvel`` and ``qacc`` (nv,)
    given, the inverse dynamics of that motion on the one foot (zero where not given): the torques a
    planned motion needs where the stance foot's ground wrench alone moves the free base."""
    layout = FreeLayout.of(mj_model)
    mj_model = copy.deepcopy(mj_model)
    mj_model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT  # the ground acts through the wrench alone
    data = mujoco.MjData(mj_model)

    def torques(qpos: np.ndarray, stance: int, qvel: np.ndarray | None = None,
                qacc: np.ndarray | None = None) -> np.ndarray:
        if stance not in (0, 1):
            raise ValueError(f"stance must be 0 (foot l) or 1 (foot r), got {stance!r}")
        qpos = np.asarray(qpos, dtype=float)
        if qpos.shape != (mj_model.nq,):
            raise ValueError(f"qpos must have shape ({mj_model.nq},), got {qpos.shape}")
        for name, value in (("qvel", qvel), ("qacc", qacc)):
            if value is not None and np.shape(value) != (mj_model.nv,):
                raise ValueError(f"{name} must have shape ({mj_model.nv},), got {np.shape(value)}")
        data.qpos[:] = qpos
        data.qvel[:] = 0.0 if qvel is None else qvel
        data.qacc[:] = 0.0 if qacc is None else qacc
        mujoco.mj_inverse(mj_model, data)  # the generalised force the motion (at rest: gravity) needs
        needed = data.qfrc_inverse.copy()
        foot = layout.feet[stance]
        point = data.xipos[foot].copy()

        def generalised(wrench):
            """J^T of the foot's wrench (force, torque at its centre of mass), (nv,)."""
            force = np.zeros(mj_model.nv)
            mujoco.mj_applyFT(mj_model, data, wrench[:3], wrench[3:], point, foot, force)
            return force

        # the ground's wrench on the foot carries the free base (6 rows, 6 unknowns); the joints give the rest
        columns = np.column_stack([generalised(unit) for unit in np.eye(6)])
        wrench = np.linalg.solve(columns[:6], needed[:6])
        return (needed - columns @ wrench)[list(layout.qvel)]

    return torques
