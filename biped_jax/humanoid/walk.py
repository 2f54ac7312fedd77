"""The replay: the planarised humanoid walking the reference under contact in MJX, in compiled chunks
of physics steps."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from biped_jax.dynamics import mjx_biped
from biped_jax.robots import planar_biped
from biped_jax.humanoid.controller import (
    DEFAULT_GAINS,
    Gains,
    Support,
    after_touchdown,
    control,
    sagittal_state,
    with_gains,
)
from biped_jax.humanoid.model import Layout, external_forces, planarised_humanoid, sagittal_columns
from biped_jax.humanoid.reference import GaitReference
from biped_jax.robots import registry

mjx = registry.import_mjx()

#: Physics steps per compiled call: the replay runs in chunks, one program for any duration.
CHUNK = 100
#: The swing foot counts as landed when its ground force exceeds this in the second half of the step, N.
#: (Not a height: the sphere's lowest point lies below the shank end when the shank is tilted, 0.45 mm at
#: the 0.3 rad of touchdown, so a loaded foot's site can stay above the ground and a height test miss the
#: touchdown; measured.)
TOUCHDOWN_FORCE = 1.0
#: The robot has fallen when the hips drop below this height, m, or the torso pitches beyond 1 rad.
FALL_HEIGHT = 0.15


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Replay:
    """Samples of every physics step (leading dimension N), SI units.

    Attributes:
      t: time after the step, shape (N,), s. qpos, qvel: planarised state after the step, (N, 19).
      ctrl: torques applied during the step, (N, 16), N m. stance: supporting leg (0 = l, 1 = r) during
      the step, (N,). phase: s during the step, (N,). target: reference (H1, K1, H2, K2) during the step,
      (N, 4), rad. joints: the joints (H1, K1, H2, K2) it was compared with, (N, 4), rad.
      feet: foot positions (l, r) after the step, (N, 2, 3), m. foot_force: ground force on each foot
      during the step, (N, 2, 3), N.
    """

    t: jax.Array
    qpos: jax.Array
    qvel: jax.Array
    ctrl: jax.Array
    stance: jax.Array
    phase: jax.Array
    target: jax.Array
    joints: jax.Array
    feet: jax.Array
    foot_force: jax.Array


def contact_model(mass_class: str = "12kg") -> tuple[mujoco.MjModel, "Layout"]:
    """The planarised humanoid the replay simulates (MuJoCo C model) and where its joints are."""
    mj_model, layout, _ = _chunk_program(mass_class)
    return mj_model, layout


@functools.lru_cache(maxsize=None)
def _chunk_program(mass_class: str):
    """One compiled call that advances :data:`CHUNK` physics steps (cached per mass class)."""
    mj_model = planarised_humanoid(mass_class)
    layout = Layout.of(mj_model)
    foot_site, foot_body = jnp.array(layout.foot_site), jnp.array(layout.foot_body)

    def physics_step(model, reference, gains, carry, _):
        data, support = carry
        stance = support.stance
        ctrl, phase, target = control(layout, reference, gains, data.qpos, data.qvel, support)
        joints = sagittal_state(layout, data.qpos, data.qvel, stance)[2]
        data = mjx.forward(model, data.replace(ctrl=ctrl))
        # the contact force on each foot body (world frame) from MJX's Newton-Euler pass
        force = external_forces(model, data)[foot_body]
        data = mjx.euler(model, data)
        feet = data.site_xpos[foot_site]
        landed = (force[1 - stance, 2] > TOUCHDOWN_FORCE) & (phase > 0.5)
        switched = after_touchdown(layout, reference, data.qpos, data.qvel, 1 - stance)
        support = jax.tree.map(lambda new, old: jnp.where(landed, new, old), switched, support)
        sample = Replay(t=data.time, qpos=data.qpos, qvel=data.qvel, ctrl=ctrl, stance=stance, phase=phase,
                        target=target, joints=joints, feet=feet, foot_force=force)
        return (data, support), sample

    @jax.jit
    def advance(model, reference, gains, data, support):
        step = functools.partial(physics_step, with_gains(model, layout, gains), reference, gains)
        return jax.lax.scan(step, (data, support), None, length=CHUNK)

    return mj_model, layout, advance


#: Compiled once (the model an argument): MJX run op by op compiles every operation alone.
_pinned_to_floating = jax.jit(mjx_biped.pinned_to_floating)


def initial_state(mj_model: mujoco.MjModel, layout: Layout, reference: GaitReference, mass_class: str):
    """(qpos, qvel) of the planarised humanoid at the optimal step's start, leg l standing at x = 0."""
    step_time = float(reference.step_time)
    q0 = planar_biped.pinned_coordinates(reference.stance_angle[0], np.asarray(reference.joints[0], dtype=float))
    qd0 = planar_biped.pinned_coordinates(reference.stance_angle_slope[0] / step_time,
                                          np.asarray(reference.joint_slope[0], dtype=float) / step_time)
    pinned = mjx_biped.load_planar_biped(mass_class).pinned
    qf, qfd = (np.asarray(a) for a in _pinned_to_floating(pinned, jnp.asarray(q0), jnp.asarray(qd0)))
    qpos, qvel = np.zeros(mj_model.nq), np.zeros(mj_model.nv)
    columns = sagittal_columns(layout, 0)
    qpos[columns], qvel[columns] = qf, qfd
    return qpos, qvel


def fallen(qpos: np.ndarray) -> bool:
    """Hips below :data:`FALL_HEIGHT`, the torso pitched beyond 1 rad, or the simulation diverged."""
    return bool(not np.all(np.isfinite(qpos)) or qpos[1] < FALL_HEIGHT or abs(qpos[2]) > 1.0)


def replay(reference: GaitReference, mass_class: str = "12kg", steps: int = 10, gains: Gains = DEFAULT_GAINS,
           progress=None) -> Replay:
    """Walks ``steps`` steps of ``reference`` on the planarised humanoid in MJX (stops early on a fall
    or after twice the nominal time); returns every physics step."""
    if steps < 1:
        raise ValueError(f"steps must be at least 1, got {steps}")
    mj_model, layout, advance = _chunk_program(mass_class)
    model = registry.put_mjx_model(mj_model)
    qpos, qvel = initial_state(mj_model, layout, reference, mass_class)
    data = mjx_biped.forward(model, mjx.make_data(model).replace(qpos=jnp.asarray(qpos), qvel=jnp.asarray(qvel)))
    support = Support(stance=jnp.asarray(0), stance_angle=reference.stance_angle[0], offset=jnp.zeros(4))
    gains = jax.tree.map(jnp.asarray, gains)
    limit = 2.0 * steps * float(reference.step_time)
    chunks = []
    touchdowns = 0
    while True:
        (data, support), samples = advance(model, reference, gains, data, support)
        samples = jax.tree.map(np.asarray, samples)
        chunks.append(samples)
        touchdowns += int(np.sum(np.diff(samples.stance, append=int(support.stance)) != 0))
        down = fallen(samples.qpos[-1])
        if progress:
            progress(f"humanoid: t = {samples.t[-1]:.2f} s, {touchdowns} touchdowns"
                     + (", fallen" if down else ""))
        if touchdowns >= steps or down or samples.t[-1] >= limit:
            break
    run = jax.tree.map(lambda *parts: np.concatenate(parts), *chunks)
    # end the record at the fall: what follows (flailing, or a diverged simulation) is not a walk
    down = [i for i, q in enumerate(run.qpos) if fallen(q)]
    return run if not down else jax.tree.map(lambda a: a[:down[0] + 1], run)
