"""Design parameters as arrays, applied to an ``mjx.Model`` inside ``jit``.

A :class:`Design` holds numbers only (traced, batchable with ``vmap``); which bodies and joints they
act on is fixed by a :class:`DesignLayout` built once from names (static). Changing a design therefore
never recompiles: one compiled program serves every design of a robot.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from biped_jax.robots.planar_biped import PLANAR_ACTUATED, PLANAR_DRIVE_MOUNTS, PLANAR_DRIVE_SHIFTS, PLANAR_LINKS



@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Design:
    """Design parameters of one robot.

    Attributes:
      link_mass: mass of each design link, shape (n_links,), kg. Each link keeps its shape: inertia
        scales with mass (uniform density), the centre of mass stays.
      joint_armature: reflected rotor inertia at each actuated joint, shape (n_joints,), kg m^2.
      joint_damping: viscous damping at each actuated joint, shape (n_joints,), N m s/rad.
      drive_mass: mass of each joint's drive (motor + gear), shape (n_joints,), kg: a point mass at the
        joint, carried by the link the layout mounts it on (0 in the MJCF files).
      drive_offset: where along its link each drive sits, shape (n_joints,), a fraction in [0, 1]: 0
        at its joint, 1 at the joint the layout lets it move to (a knee drive up its thigh at the hip,
        with a transmission to the knee; :data:`~biped_jax.robots.planar_biped.PLANAR_DRIVE_SHIFTS`).
        None: every drive at its joint. Only the mass moves: the reflected inertia stays the joint's.
    """

    link_mass: jax.Array
    joint_armature: jax.Array
    joint_damping: jax.Array
    drive_mass: jax.Array
    drive_offset: jax.Array | None = None

    @property
    def total_mass(self) -> jax.Array:
        """Links plus drives, kg (shape: the batch shape)."""
        return jnp.sum(self.link_mass, axis=-1) + jnp.sum(self.drive_mass, axis=-1)


@dataclasses.dataclass(frozen=True)
class DesignLayout:
    """Where a :class:`Design` acts in one compiled model (static: numpy index arrays).

    Attributes:
      body_ids: body index of each design link, shape (n_links,).
      dof_ids: dof index of each actuated joint, shape (n_joints,).
      subtree: subtree[i, j] = 1 when body j lies in the subtree of body i, shape (nbody, nbody).
      drive_links: drive_links[i, k] = 1 when joint k's drive is mounted on design link i,
        shape (n_links, n_joints).
      drive_positions: each drive's position (its joint's anchor) in the frame of the body carrying
        it, shape (n_joints, 3), m.
      shift_positions: where each drive moves to at ``Design.drive_offset`` = 1 (the anchor of the
        joint it may move toward), in the same frames, shape (n_joints, 3), m.
    """

    body_ids: np.ndarray
    dof_ids: np.ndarray
    subtree: np.ndarray
    drive_links: np.ndarray
    drive_positions: np.ndarray
    shift_positions: np.ndarray

    def _arrays(self):
        return (self.body_ids, self.dof_ids, self.subtree, self.drive_links, self.drive_positions,
                self.shift_positions)

    def __hash__(self):  # layouts are small; hashing by content lets them be static jit arguments
        return hash(tuple(a.tobytes() for a in self._arrays()))

    def __eq__(self, other):
        return isinstance(other, DesignLayout) and all(
            np.array_equal(a, b) for a, b in zip(self._arrays(), other._arrays()))


def design_layout(mj_model: mujoco.MjModel, links=PLANAR_LINKS, joints=PLANAR_ACTUATED,
                  drive_mounts=PLANAR_DRIVE_MOUNTS, drive_shifts=PLANAR_DRIVE_SHIFTS) -> DesignLayout:
    """Builds the layout of ``links`` (body names), ``joints`` (joint names), the links carrying
    their drives (``drive_mounts``, one of ``links`` per joint) and the joints the drives may move
    toward along those links (``drive_shifts``, a joint name per joint; its own name keeps a drive
    at its joint) in ``mj_model``. The design links' inertias must be diagonal in the body frame (MJCF
    ``diaginertia``), as in every shipped model."""
    if not isinstance(mj_model, mujoco.MjModel):
        raise TypeError(f"mj_model must be a mujoco.MjModel (biped_jax.load_mj_model(name)), got "
                        f"{type(mj_model).__name__}")

    def index(kind, names):
        ids = []
        for name in names:
            i = mujoco.mj_name2id(mj_model, kind, name)
            if i < 0:
                raise ValueError(f"model {mj_model.names[:20]!r}... has no "
                                 f"{'body' if kind == mujoco.mjtObj.mjOBJ_BODY else 'joint'} {name!r}")
            ids.append(i)
        return np.asarray(ids, dtype=np.int32)

    body_ids = index(mujoco.mjtObj.mjOBJ_BODY, links)
    joint_ids = index(mujoco.mjtObj.mjOBJ_JOINT, joints)
    subtree = np.zeros((mj_model.nbody, mj_model.nbody))
    for j in range(mj_model.nbody):
        i = j
        while True:
            subtree[i, j] = 1.0
            if i == 0:
                break
            i = mj_model.body_parentid[i]
    unknown = [name for name in drive_mounts if name not in links]
    if len(drive_mounts) != len(joints) or unknown:
        raise ValueError(f"drive_mounts must name one of the design links {links} per joint {joints}, "
                         f"got {drive_mounts}")
    if len(drive_shifts) != len(joints):
        raise ValueError(f"drive_shifts must name a joint per joint {joints}, got {drive_shifts}")
    shift_ids = index(mujoco.mjtObj.mjOBJ_JOINT, drive_shifts)
    tilted = [name for name, i in zip(links, body_ids)
              if not np.allclose(mj_model.body_iquat[i], [1, 0, 0, 0])]
    if tilted:
        raise ValueError(f"design links {tilted} have inertia axes rotated from their body frame")
    data = mujoco.MjData(mj_model)
    mujoco.mj_kinematics(mj_model, data)
    drive_links = np.zeros((len(links), len(joints)))
    positions, shifts = np.zeros((len(joints), 3)), np.zeros((len(joints), 3))
    for k, (joint, shift, mount) in enumerate(zip(joint_ids, shift_ids, drive_mounts)):
        link = links.index(mount)
        drive_links[link, k] = 1.0
        body = body_ids[link]
        rotation = data.xmat[body].reshape(3, 3)
        positions[k] = rotation.T @ (data.xanchor[joint] - data.xpos[body])
        shifts[k] = rotation.T @ (data.xanchor[shift] - data.xpos[body])
    return DesignLayout(body_ids, mj_model.jnt_dofadr[joint_ids].astype(np.int32), subtree,
                        drive_links, positions, shifts)


def nominal_design(mj_model: mujoco.MjModel, layout: DesignLayout) -> Design:
    """The design stored in the MJCF file."""
    return Design(
        link_mass=jnp.asarray(mj_model.body_mass[layout.body_ids]),
        joint_armature=jnp.asarray(mj_model.dof_armature[layout.dof_ids]),
        joint_damping=jnp.asarray(mj_model.dof_damping[layout.dof_ids]),
        drive_mass=jnp.zeros(len(layout.dof_ids)),
    )


def _check_types(design, layout) -> None:
    if not isinstance(design, Design):
        raise TypeError(f"design must be a Design (e.g. biped_jax.dynamics.mjx_biped.planar_design()), got "
                        f"{type(design).__name__}")
    if not isinstance(layout, DesignLayout):
        raise TypeError(f"layout must be a DesignLayout (design_layout(mj_model)), got {type(layout).__name__}")


def check_design(design: Design, layout: DesignLayout) -> Design:
    """Raises ValueError naming the offending value if ``design`` has a wrong shape, a non-positive
    mass, or a negative armature or damping. Call it outside ``jit`` (it reads concrete values)."""
    _check_types(design, layout)
    expected = {"link_mass": layout.body_ids.shape, "joint_armature": layout.dof_ids.shape,
                "joint_damping": layout.dof_ids.shape, "drive_mass": layout.dof_ids.shape,
                "drive_offset": layout.dof_ids.shape}
    for field, shape in expected.items():
        if getattr(design, field) is None:  # drive_offset: every drive at its joint
            continue
        value = np.asarray(getattr(design, field))
        if value.shape != shape:
            raise ValueError(f"Design.{field} must have shape {shape}, got {value.shape}")
        if not np.all(np.isfinite(value)):
            raise ValueError(f"Design.{field} must be finite, got {value.tolist()}")
    mass = np.asarray(design.link_mass)
    if np.any(mass <= 0):
        raise ValueError(f"Design.link_mass must be positive, got {mass.tolist()} (kg)")
    for field in ("joint_armature", "joint_damping", "drive_mass", "drive_offset"):
        if getattr(design, field) is None:
            continue
        value = np.asarray(getattr(design, field))
        if np.any(value < 0):
            raise ValueError(f"Design.{field} must be non-negative, got {value.tolist()}")
    if design.drive_offset is not None and np.any(np.asarray(design.drive_offset) > 1):
        raise ValueError(f"Design.drive_offset must be within [0, 1], got {np.asarray(design.drive_offset).tolist()}")
    return design


def set_link_inertia(model, layout: DesignLayout, mass: jax.Array, com: jax.Array,
                     inertia: jax.Array):
    """Returns ``model`` with new inertial properties of the design links (traceable).

    Args:
      model: an ``mjx.Model``.
      layout: where the links are.
      mass: shape (n_links,), kg.
      com: centre of mass in the body frame, shape (n_links, 3), m.
      inertia: principal inertia about the centre of mass (axes as in the file), shape (n_links, 3),
        kg m^2.
    """
    ids = layout.body_ids
    body_mass = model.body_mass.at[ids].set(mass)
    return model.replace(
        body_mass=body_mass,
        body_ipos=model.body_ipos.at[ids].set(com),
        body_inertia=model.body_inertia.at[ids].set(inertia),
        # MuJoCo's mj_setConst derives these from the masses; MJX reads them, so keep them in step.
        body_subtreemass=jnp.asarray(layout.subtree) @ body_mass,
    )


def _point_inertia(mass, offset):
    """Diagonal of the inertia of point masses about a point they are offset from: mass (...,),
    offset (..., 3) -> (..., 3), kg m^2 (products of inertia are zero for the shipped links, whose
    drives lie on the principal axis through the centre of mass)."""
    squared = offset**2
    return mass[..., None] * (jnp.sum(squared, axis=-1, keepdims=True) - squared)


def drive_positions(layout: DesignLayout, drive_offset=None) -> jax.Array:
    """Each drive's position in the frame of the link carrying it, (n_joints, 3), m: at its joint,
    moved by ``drive_offset`` (n_joints,) of the way to the joint it may move toward."""
    at_joint = jnp.asarray(layout.drive_positions)
    if drive_offset is None:
        return at_joint
    return at_joint + drive_offset[:, None] * (jnp.asarray(layout.shift_positions) - at_joint)


def with_drive_masses(layout: DesignLayout, mass, com, inertia, drive_mass, drive_offset=None):
    """Each link's mass, centre of mass and inertia with the point masses of the drives it carries.

    mass (n_links,), com and inertia (n_links, 3), drive_mass (n_joints,), drive_offset (n_joints,)
    or None -> the same three, SI."""
    carried = jnp.asarray(layout.drive_links) * drive_mass[None, :]  # (n_links, n_joints)
    positions = drive_positions(layout, drive_offset)
    total = mass + jnp.sum(carried, axis=1)
    new_com = (mass[:, None] * com + carried @ positions) / total[:, None]
    inertia = (inertia + _point_inertia(mass, com - new_com)
               + jnp.sum(_point_inertia(carried, positions[None] - new_com[:, None]), axis=1))
    return total, new_com, inertia


def apply_design(model, layout: DesignLayout, design: Design):
    """Returns ``model`` (an ``mjx.Model``) carrying ``design``; traceable, so one compiled program
    serves every design under ``vmap``. Inertias scale with mass (each link keeps its shape), then the
    drives are added as point masses at their joints (or moved along their links by
    ``design.drive_offset``)."""
    _check_types(design, layout)
    ids = layout.body_ids
    scale = design.link_mass / model.body_mass[ids]
    model = set_link_inertia(model, layout, *with_drive_masses(
        layout, design.link_mass, model.body_ipos[ids], model.body_inertia[ids] * scale[:, None],
        design.drive_mass, design.drive_offset))
    return model.replace(
        dof_armature=model.dof_armature.at[layout.dof_ids].set(design.joint_armature),
        dof_damping=model.dof_damping.at[layout.dof_ids].set(design.joint_damping),
    )
