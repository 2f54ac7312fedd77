"""Closed-form dynamics of a planar chain of hinges: the pinned five-link biped in a few dense operations.

MJX's general pipeline walks the kinematic tree level by level with many small operations per step;
their adjoints dominate a rollout's gradient on a CPU (``benchmarks/RESULTS.md``, profile). For a chain
whose joints all turn about the world y axis, the same quantities have short closed forms:

- angle of body i: theta_i = sum over its joints j (ancestors and itself) of s_j q_j, with s_j = +-1
  the joint axis's y component;
- body origins p_i = sum over ancestors-or-self j of R(theta_parent(j)) pos_j, centres of mass
  c_i = p_i + R(theta_i) ipos_i, with R the rotation about +y in the (x, z) plane;
- Jacobian of a point r on body i: column j is s_j (d_z, -d_x), d = r - p_j, for j an ancestor-or-self;
- M = sum_i m_i Jc_i^T Jc_i + I_yy,i w_i^T w_i + diag(armature) (w_i: row of angular Jacobian);
- bias (Coriolis, centrifugal, gravity) = sum_i m_i Jc_i^T (Jdot_i qd - g) (planar rotation has no
  velocity product in the angular terms);
- ground force at the pinned root = sum_i m_i (a_ci - g): the only external force besides gravity.

The model's parameters (masses, inertias, positions, armature, damping) are read from the ``mjx.Model``
at each call, so designs applied as arrays (``biped_jax.robots.design``) work unchanged under ``jit`` and
``vmap``; the chain's structure (parents, axis signs, sites, actuators) is fixed at construction.
Every quantity is checked against MJX in ``tests/test_planar_chain.py`` (to 1e-10).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from biped_jax.dynamics import impact
from biped_jax.robots.planar_biped import GAIT_SITES


@dataclasses.dataclass(frozen=True, eq=False)
class PlanarChain:
    """The fixed structure of a planar chain (numpy; bodies 1..nbody-1 of the model, one hinge each).

    Attributes:
      ancestors: (n, n), 1 where body column j is body row i or one of its ancestors.
      parent: (n,), index of each body's parent body (-1: the world).
      axis_sign: (n,), the y component (+-1) of each body's hinge axis.
      actuated_dof: (n_actuators,), the dof each actuator drives (gear 1).
      site_body: name -> body index of each site. site_index: name -> the model's site id.
    """

    ancestors: np.ndarray
    parent: np.ndarray
    axis_sign: np.ndarray
    actuated_dof: np.ndarray
    site_body: dict
    site_index: dict

    @property
    def size(self) -> int:
        return len(self.parent)

    def _key(self) -> tuple:
        return (self.ancestors.tobytes(), self.parent.tobytes(), self.axis_sign.tobytes(),
                self.actuated_dof.tobytes(), tuple(sorted(self.site_body.items())),
                tuple(sorted(self.site_index.items())))

    # equal by content: a backend carries the chain as static pytree data, so that chains read anew
    # from the same model share compiled programs
    def __eq__(self, other) -> bool:
        return isinstance(other, PlanarChain) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    @classmethod
    def from_model(cls, model) -> "PlanarChain":
        """The structure of an ``mjx.Model`` (or ``mujoco.MjModel``) with concrete structure arrays.

        Raises ValueError naming the first feature outside a planar hinge chain about y.
        """
        nbody = int(model.nbody)
        n = nbody - 1
        jnt_type = np.asarray(model.jnt_type)
        if int(model.njnt) != n or np.any(jnt_type != mujoco.mjtJoint.mjJNT_HINGE):
            raise ValueError(f"a planar chain needs one hinge per body, got joint types {jnt_type.tolist()}")
        joint_body = np.asarray(model.jnt_bodyid)
        if not np.array_equal(joint_body, np.arange(1, nbody)):
            raise ValueError(f"joint j must belong to body j + 1, got bodies {joint_body.tolist()}")
        axis = np.asarray(model.jnt_axis)
        if not np.allclose(np.abs(axis[:, 1]), 1.0) or not np.allclose(axis[:, [0, 2]], 0.0):
            raise ValueError(f"every hinge must turn about +-y, got axes {axis.tolist()}")
        if not np.allclose(np.asarray(model.jnt_pos), 0.0):
            raise ValueError("every hinge must sit at its body's origin")
        identity = np.array([1.0, 0.0, 0.0, 0.0])
        for name in ("body_quat", "body_iquat"):
            if not np.allclose(np.asarray(getattr(model, name))[1:], identity):
                raise ValueError(f"{name} must be the identity for a planar chain")
        parent = np.asarray(model.body_parentid)[1:] - 1
        ancestors = np.zeros((n, n))
        for i in range(n):
            j = i
            while j >= 0:
                ancestors[i, j] = 1.0
                j = parent[j]
        trnid = np.asarray(model.actuator_trnid)[:, 0]
        gear = np.asarray(model.actuator_gear)
        if not np.allclose(gear[:, 0], 1.0) or not np.allclose(gear[:, 1:], 0.0):
            raise ValueError("actuators must drive their joints with gear 1")
        names = [bytes(model.names[int(model.name_siteadr[k]):]).split(b"\0", 1)[0].decode()
                 for k in range(int(model.nsite))]
        return cls(ancestors=ancestors, parent=parent, axis_sign=np.sign(axis[:, 1]),
                   actuated_dof=np.asarray(model.jnt_dofadr)[trnid],
                   site_body={name: int(np.asarray(model.site_bodyid)[k]) - 1 for k, name in enumerate(names)},
                   site_index={name: k for k, name in enumerate(names)})


def _rotate(theta: jax.Array, v: jax.Array) -> jax.Array:
    """Rotation about +y of (x, z) vectors: theta (...,), v (..., 2) -> (..., 2)."""
    c, s = jnp.cos(theta), jnp.sin(theta)
    return jnp.stack([c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1]], axis=-1)


def _xz(a: jax.Array) -> jax.Array:
    return a[..., jnp.array([0, 2])]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ChainState:
    """Kinematics of one configuration and velocity (world x-z plane, SI).

    Attributes:
      angle: body angles theta, (n,), rad. origin: body origins (= joint positions), (n, 2), m.
      com: centres of mass, (n, 2), m. com_jacobian: (n, 2, n). angular_jacobian: (n, n).
      com_bias_acceleration: Jdot qd of each centre of mass, (n, 2), m/s^2.
    """

    angle: jax.Array
    origin: jax.Array
    com: jax.Array
    com_jacobian: jax.Array
    angular_jacobian: jax.Array
    com_bias_acceleration: jax.Array


def _lever_columns(points: jax.Array, origin: jax.Array, angular_jacobian: jax.Array) -> jax.Array:
    """Jacobian-like columns s_j (d_z, -d_x), d = point_i - origin_j, masked to body i's joints:
    points (i, 2) on bodies i, origin (n, 2), angular_jacobian (i, n) -> (i, 2, n)."""
    d = points[:, None, :] - origin[None, :, :]  # (i, j, 2)
    columns = jnp.stack([d[..., 1], -d[..., 0]], axis=-1) * angular_jacobian[..., None]
    return jnp.swapaxes(columns, 1, 2)


def kinematics(chain: PlanarChain, model, q: jax.Array, qd: jax.Array) -> ChainState:
    """Positions, Jacobians and velocity-product accelerations of the chain at (q, qd), each (n,)."""
    ancestors = jnp.asarray(chain.ancestors)
    angular_jacobian = ancestors * jnp.asarray(chain.axis_sign)[None, :]
    angle = angular_jacobian @ q
    has_parent = chain.parent >= 0
    parent_angle = jnp.where(jnp.asarray(has_parent), angle[np.maximum(chain.parent, 0)], 0.0)
    origin = ancestors @ _rotate(parent_angle, _xz(model.body_pos[1:]))
    com = origin + _rotate(angle, _xz(model.body_ipos[1:]))
    com_jacobian = _lever_columns(com, origin, angular_jacobian)
    # d/dt of the columns: d/dt (c_i - p_j) = v_ci - v_pj. Joint j's origin is fixed on body j (its own
    # hinge gives it no lever), so its velocity comes from the same columns.
    origin_velocity = _lever_columns(origin, origin, angular_jacobian) @ qd
    com_velocity = com_jacobian @ qd
    com_bias_acceleration = _lever_columns(com_velocity, origin_velocity, angular_jacobian) @ qd
    return ChainState(angle=angle, origin=origin, com=com, com_jacobian=com_jacobian,
                      angular_jacobian=angular_jacobian, com_bias_acceleration=com_bias_acceleration)


def _gravity(model) -> jax.Array:
    return _xz(model.opt.gravity)


def mass_matrix(chain: PlanarChain, model, state: ChainState) -> jax.Array:
    """Joint-space inertia with armature, (n, n), kg m^2."""
    mass = model.body_mass[1:]
    inertia = model.body_inertia[1:, 1]
    translational = jnp.einsum("i,iaj,iak->jk", mass, state.com_jacobian, state.com_jacobian)
    rotational = jnp.einsum("i,ij,ik->jk", inertia, state.angular_jacobian, state.angular_jacobian)
    return translational + rotational + jnp.diag(model.dof_armature)


def bias_force(chain: PlanarChain, model, state: ChainState, qd: jax.Array) -> jax.Array:
    """Coriolis, centrifugal and gravity terms less the passive (damping) force, (n,), N m: MJX's
    ``qfrc_bias - qfrc_passive`` (no springs in the chain)."""
    mass = model.body_mass[1:]
    acceleration = state.com_bias_acceleration - _gravity(model)[None, :]
    return jnp.einsum("i,iaj,ia->j", mass, state.com_jacobian, acceleration) + model.dof_damping * qd


def mechanical_energy(chain: PlanarChain, model, state: ChainState, qd: jax.Array) -> jax.Array:
    """Kinetic plus gravitational potential energy of the chain at ``state`` (of (q, qd)), J (scalar):
    :func:`biped_jax.dynamics.mjx_biped.mechanical_energy` in closed form."""
    potential = -jnp.sum(model.body_mass[1:] * (state.com @ _gravity(model)))
    return 0.5 * qd @ mass_matrix(chain, model, state) @ qd + potential


def root_force(chain: PlanarChain, model, state: ChainState, qdd: jax.Array) -> jax.Array:
    """Force (F_x, F_z) the world exerts on the root body through its hinge, (2,), N: the rate of
    change of the chain's linear momentum less gravity."""
    mass = model.body_mass[1:]
    acceleration = state.com_jacobian @ qdd + state.com_bias_acceleration - _gravity(model)[None, :]
    return jnp.einsum("i,ia->a", mass, acceleration)


def site_positions(chain: PlanarChain, model, state: ChainState, names) -> jax.Array:
    """World (x, z) of named sites, (len(names), 2), m."""
    unknown = [name for name in names if name not in chain.site_index]
    if unknown:
        raise ValueError(f"the chain has no site {unknown[0]!r}")
    bodies = np.array([chain.site_body[name] for name in names])
    local = _xz(model.site_pos[np.array([chain.site_index[name] for name in names])])
    return state.origin[bodies] + _rotate(state.angle[bodies], local)


def site_motion(chain: PlanarChain, model, q: jax.Array, qd: jax.Array, name: str) -> tuple[jax.Array, jax.Array]:
    """World (x, z) position (2,), m, and velocity (2,), m/s, of a named site at (q, qd)."""
    def position(q_):
        return site_positions(chain, model, kinematics(chain, model, q_, jnp.zeros_like(q_)), (name,))[0]
    return jax.jvp(position, (q,), (qd,))


def site_jacobian(chain: PlanarChain, model, q: jax.Array, name: str) -> jax.Array:
    """d(site x, z)/dq of a named site, (2, n)."""
    return jax.jacfwd(lambda q_: site_motion(chain, model, q_, jnp.zeros_like(q_), name)[0])(q)


def actuated_force(chain: PlanarChain, u: jax.Array) -> jax.Array:
    """Generalised force of actuator torques u (n_actuators,) -> (n,), N m."""
    return jnp.zeros(chain.size, u.dtype).at[chain.actuated_dof].add(u)


def forward_dynamics(chain: PlanarChain, model, q, qd, u) -> tuple[jax.Array, ChainState]:
    """qdd (n,), rad/s^2, under actuator torques u, with the state's kinematics."""
    state = kinematics(chain, model, q, qd)
    qdd = jnp.linalg.solve(mass_matrix(chain, model, state),
                           actuated_force(chain, u) - bias_force(chain, model, state, qd))
    return qdd, state


def euler(q: jax.Array, qd: jax.Array, qdd: jax.Array, dt) -> tuple[jax.Array, jax.Array]:
    """Semi-implicit Euler, as MJX's ``euler``: the rates first, then the angles with the new rates."""
    qd_next = qd + dt * qdd
    return q + dt * qd_next, qd_next


def impact_system(chain: PlanarChain, model, q: jax.Array, qd: jax.Array) -> impact.ImpactSystem:
    """The touchdown's impact in the pinned chain's angles extended by the translation (x, z) of its
    root: every point moves as r = p + r_pinned(q), so the inertia is
    [[m I, sum_i m_i Jc_i], [sum_i m_i Jc_i^T, M_pinned]] (armature included); the floating model's
    mechanics in other coordinates (the same impulse and velocities to rounding,
    ``tests/test_dynamics.py``). Why: MJX's impact map on the floating model was two thirds of the gait
    rollout's compile time (18.5 s of 27 s in 48 knot spans)."""

    def to_floating(q_):  # as mjx_biped.pinned_to_floating
        return impact.floating_coordinates(site_motion(chain, model, q_, jnp.zeros_like(q_), "hip")[0], q_)

    state = kinematics(chain, model, q, qd)
    mass = model.body_mass[1:]
    momentum = jnp.einsum("i,iaj->aj", mass, state.com_jacobian)  # (2, n): linear momentum per rate
    translation = jnp.eye(2, dtype=q.dtype)
    inertia = jnp.block([[jnp.sum(mass) * translation, momentum],
                         [momentum.T, mass_matrix(chain, model, state)]])
    # the floating base's rates: the root's translation moves the hip alike, the angles map as positions do
    to_floating_rates = jnp.concatenate([jnp.concatenate([translation, jnp.zeros((5, 2), q.dtype)]),
                                         jax.jacfwd(to_floating)(q)], axis=1)
    return impact.ImpactSystem(
        mass=inertia, landing=jnp.concatenate([translation, site_jacobian(chain, model, q, "foot2")], 1),
        leaving=jnp.concatenate([translation, site_jacobian(chain, model, q, "foot1")], 1),
        velocity=jnp.concatenate([jnp.zeros(2, q.dtype), qd]), floating_q=to_floating(q),
        to_floating=to_floating_rates)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ChainDynamics:
    """The closed-form backend of :class:`biped_jax.dynamics.interface.StanceDynamics` (a pytree: the
    pinned model's parameters as data, its structure static; batchable over designs).

    Attributes:
      chain: the structure of ``pinned`` (every planar biped design has the same).
      pinned: the design's pinned ``mjx.Model`` (its parameters are read at each call).
    """

    pinned: object
    chain: PlanarChain = dataclasses.field(metadata={"static": True})

    @classmethod
    def of(cls, pinned, chain: PlanarChain | None = None) -> "ChainDynamics":
        """``chain``: the structure of ``pinned`` when the model is traced (read from the model
        otherwise, which needs its structure arrays concrete)."""
        return cls(pinned=pinned, chain=PlanarChain.from_model(pinned) if chain is None else chain)

    def terms(self, q, qd):
        return _terms(self.chain, self.pinned, q, qd)

    def outputs(self, q, qd, qdd, state):
        force = root_force(self.chain, self.pinned, state, qdd)
        return force, site_positions(self.chain, self.pinned, state, GAIT_SITES)

    def swing_foot(self, q, qd):
        return site_motion(self.chain, self.pinned, q, qd, "foot2")

    def step(self, state, u):
        """One step under actuator torques u, semi-implicit Euler with ``opt.timestep`` (as MJX's
        ``euler``; explicit damping: MJX's with ``EULERDAMP`` disabled, identical without damping):
        (q, qd) -> ((q, qd) next, (qdd (n,), the root (stance) force (2,)))."""
        q, qd = state
        qdd, kin = forward_dynamics(self.chain, self.pinned, q, qd, u)
        force = root_force(self.chain, self.pinned, kin, qdd)
        return euler(q, qd, qdd, self.pinned.opt.timestep), (qdd, force)

    def impact_system(self, q, qd) -> impact.ImpactSystem:
        return _impact_system(self.chain, self.pinned, q, qd)


# The rollout's terms and the impact map as jitted functions: the solver's derivative programs call them
# at many points (four per Runge-Kutta step, at every touchdown) and JAX then traces and transforms each
# one's program once per signature instead of at every call (the M1-M4 solve at 4 knot spans: 50 s in a
# fresh process on an empty compilation cache instead of 61 s, 2 cores, 2026-12-06).
@functools.partial(jax.jit, static_argnums=0)
def _terms(chain: PlanarChain, model, q, qd):
    state = kinematics(chain, model, q, qd)
    return mass_matrix(chain, model, state), bias_force(chain, model, state, qd), state


_impact_system = jax.jit(impact_system, static_argnums=0)
