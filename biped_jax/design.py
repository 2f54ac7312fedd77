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

#: Design links of the sagittal biped, in the order of ``Design.link_mass``.
PLANAR_LINKS = ("torso", "thigh1", "shank1", "thigh2", "shank2")
#: Actuated joints of the sagittal biped, in the order of u = (H1, K1, H2, K2).
PLANAR_ACTUATED = ("hip1", "knee1", "hip2", "knee2")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Design:
    """Design parameters of one robot.

    Attributes:
      link_mass: mass of each design link, shape (n_links,), kg. Each link keeps its shape: inertia
        scales with mass (uniform density), the centre of mass stays.
      joint_armature: reflected rotor inertia at each actuated joint, shape (n_joints,), kg m^2.
      joint_damping: viscous damping at each actuated joint, shape (n_joints,), N m s/rad.
    """

    link_mass: jax.Array
    joint_armature: jax.Array
    joint_damping: jax.Array


@dataclasses.dataclass(frozen=True)
class DesignLayout:
    """Where a :class:`Design` acts in one compiled model (static: numpy index arrays).

    Attributes:
      body_ids: body index of each design link, shape (n_links,).
      dof_ids: dof index of each actuated joint, shape (n_joints,).
      subtree: subtree[i, j] = 1 when body j lies in the subtree of body i, shape (nbody, nbody).
    """

    body_ids: np.ndarray
    dof_ids: np.ndarray
    subtree: np.ndarray

    def __hash__(self):  # layouts are small; hashing by content lets them be static jit arguments
        return hash((self.body_ids.tobytes(), self.dof_ids.tobytes(), self.subtree.tobytes()))

    def __eq__(self, other):
        return (isinstance(other, DesignLayout) and np.array_equal(self.body_ids, other.body_ids)
                and np.array_equal(self.dof_ids, other.dof_ids)
                and np.array_equal(self.subtree, other.subtree))


def design_layout(mj_model: mujoco.MjModel, links=PLANAR_LINKS, joints=PLANAR_ACTUATED) -> DesignLayout:
    """Builds the layout of ``links`` (body names) and ``joints`` (joint names) in ``mj_model``."""
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
    return DesignLayout(body_ids, mj_model.jnt_dofadr[joint_ids].astype(np.int32), subtree)


def nominal_design(mj_model: mujoco.MjModel, layout: DesignLayout) -> Design:
    """The design stored in the MJCF file."""
    return Design(
        link_mass=jnp.asarray(mj_model.body_mass[layout.body_ids]),
        joint_armature=jnp.asarray(mj_model.dof_armature[layout.dof_ids]),
        joint_damping=jnp.asarray(mj_model.dof_damping[layout.dof_ids]),
    )


def check_design(design: Design, layout: DesignLayout) -> Design:
    """Raises ValueError naming the offending value if ``design`` has a wrong shape, a non-positive
    mass, or a negative armature or damping. Call it outside ``jit`` (it reads concrete values)."""
    expected = {"link_mass": layout.body_ids.shape, "joint_armature": layout.dof_ids.shape,
                "joint_damping": layout.dof_ids.shape}
    for field, shape in expected.items():
        value = np.asarray(getattr(design, field))
        if value.shape != shape:
            raise ValueError(f"Design.{field} must have shape {shape}, got {value.shape}")
        if not np.all(np.isfinite(value)):
            raise ValueError(f"Design.{field} must be finite, got {value.tolist()}")
    mass = np.asarray(design.link_mass)
    if np.any(mass <= 0):
        raise ValueError(f"Design.link_mass must be positive, got {mass.tolist()} (kg)")
    for field in ("joint_armature", "joint_damping"):
        value = np.asarray(getattr(design, field))
        if np.any(value < 0):
            raise ValueError(f"Design.{field} must be non-negative, got {value.tolist()}")
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


def apply_design(model, layout: DesignLayout, design: Design):
    """Returns ``model`` (an ``mjx.Model``) carrying ``design``; traceable, so one compiled program
    serves every design under ``vmap``. Inertias scale with mass (each link keeps its shape)."""
    ids = layout.body_ids
    scale = design.link_mass / model.body_mass[ids]
    model = set_link_inertia(model, layout, design.link_mass, model.body_ipos[ids],
                             model.body_inertia[ids] * scale[:, None])
    return model.replace(
        dof_armature=model.dof_armature.at[layout.dof_ids].set(design.joint_armature),
        dof_damping=model.dof_damping.at[layout.dof_ids].set(design.joint_damping),
    )
