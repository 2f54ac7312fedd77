"""The free-base humanoid walking in 3D under contact in MJX: a walking law (:class:`Law`: the tracker of
the optimal step, :mod:`biped_jax.humanoid.tracker`, or the foot-placement walker, :data:`WALKER`), every
torque clipped to the drive's line, in compiled chunks of physics steps; pushes on the torso; a batch of
disturbed walks as one vmapped program; the walk's measures.

Coordinates as in :mod:`biped_jax.humanoid.free_base`. The walker's walk (:func:`walk`) starts at rest on
both feet with the knees at the controller's stance bend and the pelvis moving sideways toward the first
stance foot (l) at ``WalkerParams.side_speed``; the desired speed ramps up over ``WalkerParams.ramp``. The
tracker's starts on the gait (:func:`biped_jax.humanoid.tracker.start`); :func:`run` walks either.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from biped_jax.drives import model as drive_model
from biped_jax.dynamics import mjx_biped
from biped_jax.humanoid import free_base, walker
from biped_jax.robots import registry

mjx = registry.import_mjx()

#: Physics steps per compiled call: one program walks any duration.
CHUNK = 500
#: The constraint solver's iteration caps in the walk (MuJoCo's defaults are 100 and 50): MJX runs a
#: batch's solver loop until its slowest member converges, and the walk's few foot contacts converge in
#: a handful of Newton iterations (measured: 3 s of the default walk are bit-identical with the defaults).
SOLVER_ITERATIONS, LINE_SEARCH_ITERATIONS = 8, 8
#: The robot has fallen when its pelvis drops below this height (m) or the torso tilts beyond
#: :data:`FALL_TILT` (rad) in roll or pitch.
FALL_HEIGHT, FALL_TILT = 0.18, 0.6
#: A foot is in contact while the ground pushes on it with more than this, N.
CONTACT_FORCE = 1.0
#: A landing foot rebounds when its sole's lowest corner rises more than this above the ground, m, after its
#: first contact and before its planned lift-off: twice the depth to which a stance sole sinks into MuJoCo's
#: soft contact (about 0.05 mm). The ground's force alone is no test of that: mid-stance it drops to zero
#: for single physics steps with the sole still in the ground (measured on the tracker's walks: the sole at
#: -0.05 to +0.006 mm in those steps), which :func:`measures` counts apart as contact losses.
REBOUND_HEIGHT = 1e-4
#: Walks per call of the batched program (:func:`survive`): a larger batch is run in calls of this many.
#: A vmapped batch of 64 walks hangs XLA's CPU runtime in this version (jax 0.10.2: no progress, every
#: thread waiting, measured; 48 runs), so 64 runs are two calls of one compiled program.
BATCH_LANES = 32


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Push:
    """Constant forces on the torso's centre of mass, force p over [start p, start p + duration p): start,
    duration (P,) in s, force (P, 3) in N, world frame; push p's impulse is force p x duration p (N s).
    Batched: a leading batch axis on every field."""

    start: jax.Array
    duration: jax.Array
    force: jax.Array

    @property
    def impulse(self) -> jax.Array:
        """(..., P, 3), N s."""
        return self.force * self.duration[..., None]

    def at(self, time) -> jax.Array:
        """The total force at ``time`` (s), (3,), N."""
        on = (time >= self.start) & (time < self.start + self.duration)
        return jnp.sum(jnp.where(on[:, None], self.force, 0.0), axis=0)


#: No push: two pushes of zero force, the shape of :func:`pushes` (each number of pushes is its own program).
NO_PUSH = Push(start=jnp.zeros(2), duration=jnp.zeros(2), force=jnp.zeros((2, 3)))


def pushes(sagittal: float, lateral: float, sagittal_at: float, lateral_at: float, duration: float = 0.1) -> Push:
    """A sagittal push (impulse ``sagittal`` N s along +x; negative: backward) at ``sagittal_at`` s and a
    lateral one (``lateral`` N s along +y) at ``lateral_at`` s, each lasting ``duration`` s."""
    for name, value in (("duration", duration), ("sagittal_at", sagittal_at), ("lateral_at", lateral_at)):
        if not (np.isfinite(value) and value >= (1e-3 if name == "duration" else 0.0)):
            raise ValueError(f"{name} must be finite and {'at least 1 ms' if name == 'duration' else 'non-negative'}, "
                             f"got {value!r} s")
    for name, value in (("sagittal", sagittal), ("lateral", lateral)):
        if not np.isfinite(value):
            raise ValueError(f"the {name} impulse must be finite, got {value!r} N s")
    force = np.array([[sagittal / duration, 0.0, 0.0], [0.0, lateral / duration, 0.0]])
    return Push(start=jnp.asarray([sagittal_at, lateral_at]), duration=jnp.full(2, duration), force=jnp.asarray(force))


#: Leg joints driven by two of the recommended drives in parallel, per mass class: standing on one leg the
#: 18 kg robot's stance hip roll must hold 11.7 N m (docs/studies.md), more than one GP 32 A gives (6.5 N m).
PARALLEL_DRIVES = {"12kg": (), "18kg": ("hip_roll",)}


def walk_drives(mass_class: str = "12kg", parallel: tuple[str, ...] | None = None):
    """The drives of the walk of ``mass_class``: the recommended one at every joint, two in parallel at
    the joints ``parallel`` (leg joint names; default :data:`PARALLEL_DRIVES` of the mass class)."""
    chosen = PARALLEL_DRIVES[free_base.check_mass_class(mass_class)] if parallel is None else parallel
    return free_base.walk_drives(parallel=tuple(chosen))


def walk_model(mass_class: str = "12kg", parallel: tuple[str, ...] | None = None) -> mujoco.MjModel:
    """The free-base humanoid of the walk (:func:`free_base.free_base_humanoid`, the reflected inertia of
    :func:`walk_drives` at every joint) with the walk's solver caps."""
    model = free_base.free_base_humanoid(mass_class, walk_drives(mass_class, parallel))
    model.opt.iterations, model.opt.ls_iterations = SOLVER_ITERATIONS, LINE_SEARCH_ITERATIONS
    return model


@dataclasses.dataclass(frozen=True)
class Program:
    """The walk's physics for one mass class and drive set: the MuJoCo C model, layout, legs' geometry,
    drives, the MJX model, and which constraint rows are each foot's contacts ((2, nefc), MJX's fixed
    contact slots)."""

    mj_model: mujoco.MjModel
    layout: free_base.FreeLayout
    legs: walker.Legs
    drives: drive_model.JointDrives
    model: object
    contact_rows: np.ndarray


@dataclasses.dataclass(frozen=True)
class Law:
    """A walking law on the walk's physics (static; one compiled program per law, mass class and drive set).

    ``control(args, prog, data, state) -> (command, note)``: every actuator's torque (16,), N m, before the
    drives clip it, at MJX ``data`` (its kinematics from the last step); ``note`` is passed on to
    ``remember(args, prog, data, state, note, timestep) -> state``, the law's memory after the physics step
    that ended at ``data``. ``args``: the law's parameters (a pytree of arrays, shared by a batch); ``state``:
    what it keeps between steps (a pytree whose ``stance`` or first leaf's ``stance`` is the supporting leg).
    """

    name: str
    control: Callable
    remember: Callable


def _walker_control(params: walker.WalkerParams, prog: Program, data, memory: walker.WalkerMemory):
    return walker.control(params, prog.layout, prog.legs, data, memory), None


def _walker_remember(params: walker.WalkerParams, prog: Program, data, memory: walker.WalkerMemory, _,
                     timestep: float) -> walker.WalkerMemory:
    return walker.remember(params, prog.layout, prog.legs, data, memory, timestep)


#: The foot-placement walker of :mod:`biped_jax.humanoid.walker` (args: ``WalkerParams``, state:
#: ``WalkerMemory``).
WALKER = Law("walker", _walker_control, _walker_remember)


def program(mass_class: str = "12kg", parallel: tuple[str, ...] | None = None) -> Program:
    """The walk's pieces for ``mass_class`` (made once per mass class and set of joints driven by two drives,
    ``parallel``, default :data:`PARALLEL_DRIVES`: :func:`walk_drives`)."""
    return _program(mass_class, drive_set(mass_class, parallel))


def drive_set(mass_class: str, parallel: tuple[str, ...] | None = None) -> tuple[str, ...]:
    """The leg joints on two drives, sorted: ``parallel``, or :data:`PARALLEL_DRIVES` of the mass class."""
    chosen = PARALLEL_DRIVES[free_base.check_mass_class(mass_class)] if parallel is None else parallel
    return tuple(sorted(chosen))


@functools.lru_cache(maxsize=None)
def _program(mass_class: str, parallel: tuple[str, ...]) -> Program:
    """:func:`program` with ``parallel`` spelled out (one cache entry per drive set, however it was named)."""
    mj_model = walk_model(mass_class, parallel)
    legs = walker.Legs.of(mj_model)
    model = registry.put_mjx_model(mj_model)
    # MJX keeps a fixed set of contact slots (geom pairs) and rows per slot: each foot's rows, found once
    slots = registry.jax_fields(mjx_biped.forward(model, mjx.make_data(model)))
    geoms, first, size = (np.asarray(a) for a in (slots.contact.geom, slots.contact.efc_address, slots.contact.dim))
    rows = np.zeros((2, int(slots.efc_J.shape[0])))
    for pair, start, dim in zip(geoms, first, size):
        for foot, geom in enumerate(legs.foot_geoms):
            if geom in pair:
                rows[foot, start:start + 2 * (dim - 1)] = 1.0  # a pyramidal friction cone's rows
    return Program(mj_model, free_base.FreeLayout.of(mj_model), legs, walk_drives(mass_class, parallel), model, rows)


def stepper(prog: Program, law: Law = WALKER) -> Callable:
    """``step(args, push, (data, state)) -> ((data, state), (command, applied))``: one physics step of
    ``law`` on ``prog``, every torque clipped to its drive's line at the joint's speed
    (:func:`free_base.drive_torques`), ``push`` (:class:`Push`) on the torso."""
    layout, joint_speed = prog.layout, jnp.asarray(prog.layout.qvel)
    timestep = float(prog.mj_model.opt.timestep)

    def step(args, push, carry):
        data, state = carry
        command, note = law.control(args, prog, data, state)
        applied, _ = free_base.drive_torques(prog.drives, command, data.qvel[joint_speed])
        force = jnp.zeros((prog.mj_model.nbody, 6)).at[layout.torso, :3].set(push.at(data.time))
        data = mjx.step(prog.model, data.replace(ctrl=applied, xfrc_applied=force))
        return (data, law.remember(args, prog, data, state, note, timestep)), (command, applied)

    return step


def start_state(prog: Program, params: walker.WalkerParams) -> tuple[np.ndarray, np.ndarray]:
    """(qpos, qvel) of the start: standing on both flat feet, knees at ``params.stance_knee``, the pelvis
    moving toward foot l at ``params.side_speed`` (floats, not arrays)."""
    mj_model, layout = prog.mj_model, prog.layout
    knee = float(params.stance_knee)
    qpos = np.array(mj_model.qpos0)
    for leg in layout.legs:
        for joint, angle in zip(leg[2:5], (-knee / 2, knee, -knee / 2)):  # hip, knee, ankle: feet flat
            qpos[layout.qpos[joint]] = angle
    qpos[2] -= lowest_sole(prog, qpos)
    qvel = np.zeros(mj_model.nv)
    qvel[1] = float(params.side_speed)
    return qpos, qvel


def initial(prog: Program, params: walker.WalkerParams, qpos: np.ndarray | None = None,
            qvel: np.ndarray | None = None):
    """(MJX data, walker memory) at the start (or at ``qpos``, ``qvel``), foot l standing."""
    if qpos is None or qvel is None:
        default_q, default_v = start_state(prog, params)
        qpos = default_q if qpos is None else qpos
        qvel = default_v if qvel is None else qvel
    data = mujoco.MjData(prog.mj_model)
    data.qpos[:], data.qvel[:] = qpos, qvel
    mujoco.mj_kinematics(prog.mj_model, data)
    feet = data.xpos[list(prog.layout.feet)]
    memory = walker.WalkerMemory(stance=jnp.asarray(0), time=jnp.asarray(0.0), lift=jnp.asarray(feet[1] - qpos[:3]),
                                 foot=jnp.asarray(feet[0]), steps=jnp.asarray(0),
                                 knee=jnp.asarray(qpos[prog.layout.qpos[prog.layout.legs[0][3]]]))
    mjx_data = mjx_biped.forward(prog.model,
                                 mjx.make_data(prog.model).replace(qpos=jnp.asarray(qpos), qvel=jnp.asarray(qvel)))
    # committed to the device, as the compiled walk's own carry is after a chunk: an uncommitted first carry
    # is another signature, and the second chunk would compile the walk again
    return jax.device_put((mjx_data, memory), jax.devices()[0])



def fixed_arrays(tree):
    """Every leaf as a float64 array of fixed (not weak) type: one compiled program whatever Python or
    numpy numbers the caller passed."""
    return jax.tree.map(lambda leaf: jnp.asarray(np.asarray(leaf, dtype=float)), tree)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Walk:
    """Samples of every physics step (leading dimension N), SI units.

    Attributes:
      t: time after the step, (N,), s. qpos, qvel: state after the step, (N, 23), (N, 22).
      command: torques the controller asked for during the step, (N, 16), N m; applied: what the drives
      gave (the command clipped to their line at the joint's speed), (N, 16), N m.
      stance: the supporting leg during the step (0 = l, 1 = r), (N,). feet: foot body origins after the
      step (l, r), (N, 2, 3), m. foot_force: the ground's force on each foot during the step, (N, 2, 3),
      N (world frame). soles: the height of each sole's lowest corner above the ground where the step's
      contacts were found (l, r), (N, 2), m (negative: sunk into the soft contact).
    """

    t: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    command: np.ndarray
    applied: np.ndarray
    stance: np.ndarray
    feet: np.ndarray
    foot_force: np.ndarray
    soles: np.ndarray


def ground_forces(prog: Program, data) -> jax.Array:
    """The ground's force on each foot (l, r) during the step that ended at MJX ``data``, (2, 3), N, world
    frame: each foot's share of the constraint force's free-base rows (J^T f of its contacts' rows), so the
    two add up to what changes the momentum. (MJX's ``rne_postconstraint`` differs from that by up to 1.6 %
    of the force under these box contacts, measured.)"""
    rows = jnp.asarray(prog.contact_rows)  # (2, nefc): which constraint rows are each foot's contacts
    fields = registry.jax_fields(data)
    return rows @ (fields.efc_J[:, :3] * fields.efc_force[:, None])


def _stance(state) -> jax.Array:
    """The supporting leg in a law's state (its ``stance``, or its first leaf's)."""
    return state.stance if hasattr(state, "stance") else state[0].stance


@functools.lru_cache(maxsize=None)
def _recorder(mass_class: str, parallel: tuple[str, ...], law: Law):
    """One compiled call that advances :data:`CHUNK` physics steps of ``law`` and samples each (cached)."""
    prog = _program(mass_class, parallel)
    step, feet = stepper(prog, law), jnp.asarray(prog.layout.feet)

    def sampled(args, push, carry, _):
        stance = _stance(carry[1])
        carry, (command, applied) = step(args, push, carry)
        data = carry[0]
        return carry, Walk(t=data.time, qpos=data.qpos, qvel=data.qvel, command=command, applied=applied,
                           stance=stance, feet=data.xpos[feet], foot_force=ground_forces(prog, data),
                           soles=walker.sole_heights(prog.legs, data))

    @jax.jit
    def advance(args, push, carry):
        return jax.lax.scan(functools.partial(sampled, args, push), carry, None, length=CHUNK)

    return advance


def upright(qpos):
    """Per sample (..., 23), numpy or JAX: the pelvis above :data:`FALL_HEIGHT` and the torso within
    :data:`FALL_TILT` in roll and pitch (False for a diverged state)."""
    roll, pitch, _ = attitude(qpos)
    return (qpos[..., 2] > FALL_HEIGHT) & (abs(roll) < FALL_TILT) & (abs(pitch) < FALL_TILT)


def fallen(qpos: np.ndarray) -> np.ndarray:
    """Per sample (..., 23): not :func:`upright`, or a diverged state."""
    return ~np.all(np.isfinite(qpos), axis=-1) | ~upright(qpos)


def attitude(qpos):
    """(roll, pitch, yaw) of the torso from the free joint's quaternion in qpos (..., 23), rad: the angles of
    :func:`walker.torso_angles` (:func:`walker.zyx_angles` of the quaternion's rotation); numpy or jax."""
    xp = jnp if isinstance(qpos, jax.Array) else np
    w, x, y, z = (qpos[..., 3 + i] for i in range(4))
    return walker.zyx_angles(1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y), 2 * (y * z + w * x),
                             1 - 2 * (x * x + y * y), xp)


def walk(params: walker.WalkerParams, mass_class: str = "12kg", steps: int = 20, push: Push = NO_PUSH,
         settle: float = 0.5, progress: Callable[[str], None] | None = None, seconds: float | None = None) -> Walk:
    """The walker's walk (:data:`WALKER`) from :func:`start_state`: until ``steps`` touchdowns after the speed
    ramp (and ``settle`` s more, to see the last landing), a fall, twice the nominal time or ``seconds``
    (rounded up to whole chunks of :data:`CHUNK` physics steps); returns every physics step, the record
    ending at a fall."""
    if int(steps) < 1:
        raise ValueError(f"steps must be at least 1, got {steps}")
    if seconds is not None and not seconds > 0:
        raise ValueError(f"seconds must be positive, got {seconds!r}")
    prog = program(mass_class)
    ramp_steps = int(np.ceil(float(params.ramp) / float(params.step_time)))
    limit = float(params.ramp) + 2.0 * int(steps) * float(params.step_time) + settle
    limit = limit if seconds is None else min(limit, seconds - 1e-9)
    return run(WALKER, params, initial(prog, params), mass_class, None, push, ramp_steps + int(steps), limit,
               settle, progress)


def run(law: Law, args, carry, mass_class: str = "12kg", parallel: tuple[str, ...] | None = None,
        push: Push = NO_PUSH, touchdowns_wanted: int | None = None, limit: float = 10.0, settle: float = 0.5,
        progress: Callable[[str], None] | None = None) -> Walk:
    """Walks ``law`` (parameters ``args``) from ``carry`` = (MJX data, the law's state) on the drives of
    ``mass_class`` and ``parallel`` until ``touchdowns_wanted`` touchdowns (and ``settle`` s more), a fall or
    ``limit`` s, in compiled chunks of :data:`CHUNK` physics steps; returns every physics step, the record
    ending at a fall."""
    advance = _recorder(mass_class, drive_set(mass_class, parallel), law)
    args, push = jax.device_put(fixed_arrays(args)), jax.device_put(fixed_arrays(push))
    chunks, done_at, landed = [], None, 0
    while True:
        carry, sample = advance(args, push, carry)
        chunks.append(jax.tree.map(np.asarray, sample))
        stance = np.concatenate([chunks[-2].stance[-1:] if len(chunks) > 1 else [], chunks[-1].stance])
        landed += int(np.count_nonzero(np.diff(stance)))
        t = float(chunks[-1].t[-1])
        down = bool(fallen(chunks[-1].qpos).any())
        if progress:
            progress(f"3D walk ({mass_class}, {law.name}): t = {t:.1f} s, {landed} touchdowns"
                     + (", fallen" if down else ""))
        if done_at is None and touchdowns_wanted is not None and landed >= touchdowns_wanted:
            done_at = t
        if down or t >= limit or (done_at is not None and t >= done_at + settle):
            break
    record = jax.tree.map(lambda *parts: np.concatenate(parts), *chunks)
    down = np.flatnonzero(fallen(record.qpos))
    return record if not len(down) else jax.tree.map(lambda a: a[:down[0] + 1], record)


def touchdowns(record: Walk) -> np.ndarray:
    """Sample indices at which a foot landed (the stance changes there), (K,)."""
    return np.flatnonzero(np.diff(record.stance)) + 1


def drive_ratio(drives: drive_model.JointDrives, torque: np.ndarray, joint_speed: np.ndarray) -> np.ndarray:
    """|torque| over what the drive gives at that speed on the torque's side of its line, (N, J)."""
    low, high = (np.asarray(a) for a in drive_model.torque_limits(drives, jnp.asarray(joint_speed)))
    return np.abs(torque) / np.where(torque >= 0, high, -low)


def measures(record: Walk, mass_class: str, params: walker.WalkerParams, gait_speed: float,
             gait_step_length: float, steady_after: float | None = None,
             parallel: tuple[str, ...] | None = None) -> dict:
    """The walk's figures (SI units), the steady part from the first touchdown after ``steady_after`` s
    (default: the speed ramp plus one step) to the last touchdown; the drives of ``mass_class`` with two
    at the joints ``parallel`` (default :data:`PARALLEL_DRIVES`).

    Keys: ``steps`` (touchdowns), ``fell``, ``speed_mps`` and ``speed_ratio`` (pelvis travel over time
    between the steady touchdowns, over the gait's speed), ``step_length_m`` and ``step_length_ratio``
    (mean distance along x between successive landing feet), ``step_time_s``, ``touchdowns`` (per steady
    touchdown: time, contact duration before the ground's force on the foot first vanishes again or it
    lifts off as planned, peak normal force, the sole's highest point after its first contact, rebound,
    contact lost, the longest time without force between its first contact and the next touchdown where
    the force vanishes), ``rebounds`` (landing feet whose sole rises more than :data:`REBOUND_HEIGHT` off
    the ground before their planned lift-off), ``contact_losses`` (landing feet on which the ground's force
    vanishes before then, however briefly), ``longest_contact_loss_s`` (the longest of those losses),
    ``highest_stance_sole_m`` (the highest a sole rose after its first contact, over the touchdowns),
    ``max_drive_torque_ratio`` (largest commanded |torque| over the drive line at that speed: above 1 the
    drive saturated and gave its line), ``saturated_share``, ``slip_max_m``
    (largest travel of a stance foot in the plane during its stance, after its first 20 ms),
    ``cost_of_transport`` (positive joint work over weight x distance), ``lateral_drift_m``, ``max_yaw_rad``.
    """
    prog = program(mass_class, parallel)
    layout = prog.layout
    fell = bool(fallen(record.qpos[-1]))
    landings = touchdowns(record)
    steady_after = float(params.ramp) + float(params.step_time) if steady_after is None else steady_after
    steady = landings[record.t[landings] > steady_after]
    joint_speed = record.qvel[:, list(layout.qvel)]
    ratio = drive_ratio(prog.drives, record.command, joint_speed)
    normal = record.foot_force[..., 2]
    events, rebounds, losses, slips = [], 0, 0, []
    for k, i in enumerate(landings):
        foot = int(record.stance[i])  # the landing foot is the new stance
        end = landings[k + 1] if k + 1 < len(landings) else len(record.t)
        touching = normal[i:end, foot] > CONTACT_FORCE
        first = int(np.argmax(touching)) if touching.any() else None
        lost = None if first is None else (np.flatnonzero(~touching[first:]) + first)
        left_early = bool(lost is not None and len(lost) and end < len(record.t))
        highest = None if first is None else float(record.soles[i + first:end, foot].max())
        rebounded = bool(highest is not None and highest > REBOUND_HEIGHT and end < len(record.t))
        duration = ((lost[0] if left_early else end - i) - (first or 0)) * float(prog.mj_model.opt.timestep)
        rebounds += rebounded and i in steady
        losses += left_early and i in steady
        longest_loss = 0.0 if first is None else longest_run(~touching[first:]) * float(prog.mj_model.opt.timestep)
        settled = min(i + 20, end - 1)
        travel = np.linalg.norm(record.feet[settled:end, foot, :2] - record.feet[settled, foot, :2], axis=-1)
        if i in steady and end < len(record.t):
            slips.append(float(travel.max(initial=0.0)))
        events.append({"t_s": float(record.t[i]), "foot": "lr"[foot], "contact_s": float(duration),
                       "peak_normal_force_N": float(normal[i:end, foot].max(initial=0.0)),
                       "highest_sole_m": highest, "rebound": rebounded, "contact_lost": left_early,
                       "longest_loss_s": float(longest_loss) if left_early else 0.0})
    steady_events = [e for e, i in zip(events, landings) if i in steady]
    figures = {"steps": int(len(landings)), "fell": fell, "steady_touchdowns": int(len(steady)),
               "touchdowns": steady_events, "rebounds": int(rebounds), "contact_losses": int(losses),
               "longest_contact_loss_s": max((e["longest_loss_s"] for e in steady_events), default=0.0),
               "highest_stance_sole_m": max((e["highest_sole_m"] for e in steady_events
                                             if e["highest_sole_m"] is not None), default=None)}
    if len(steady) >= 2:
        a, b = steady[0], steady[-1]
        span = float(record.t[b] - record.t[a])
        speed = float(record.qpos[b, 0] - record.qpos[a, 0]) / span
        landing_x = np.array([record.feet[i, record.stance[i], 0] for i in steady])
        lengths = np.diff(landing_x)
        window = slice(a, b)
        power = np.maximum(record.applied[window] * joint_speed[window], 0.0).sum(axis=1)
        work = float(power.sum() * float(prog.mj_model.opt.timestep))
        distance = float(record.qpos[b, 0] - record.qpos[a, 0])
        figures.update({
            "speed_mps": speed, "speed_ratio": speed / gait_speed,
            "step_length_m": float(lengths.mean()), "step_length_ratio": float(lengths.mean()) / gait_step_length,
            "step_length_range_m": [float(lengths.min()), float(lengths.max())],
            "step_time_s": span / (len(steady) - 1),
            "max_drive_torque_ratio": float(ratio[window].max()),
            "saturated_share": float((ratio[window] > 1.0 + 1e-9).mean()),
            "slip_max_m": float(max(slips, default=0.0)),
            "cost_of_transport": work / (layout.mass * 9.81 * distance) if distance > 0 else None,
            "lateral_drift_m": float(record.qpos[b, 1] - record.qpos[a, 1]),
            "max_yaw_rad": float(np.abs(attitude(record.qpos[a:b])[2]).max()),
        })
    return figures



def longest_run(flags: np.ndarray) -> int:
    """The length of the longest run of True in ``flags`` (1-D), samples."""
    edges = np.diff(np.concatenate([[0], np.asarray(flags, dtype=int), [0]]))
    return int((np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)).max(initial=0))


@functools.lru_cache(maxsize=None)
def _survivor(mass_class: str, parallel: tuple[str, ...], law: Law, physics_steps: int):
    """One compiled program: a batch of walks of ``physics_steps`` steps (vmapped over the pushes and the
    start states, the law's parameters shared), each reporting whether it stayed up and its touchdowns."""
    step = stepper(_program(mass_class, parallel), law)

    def one(args, push, carry):
        def body(state, _):
            carry, up, steps = state
            stance = _stance(carry[1])
            carry, _ = step(args, push, carry)
            return (carry, up & upright(carry[0].qpos), steps + (_stance(carry[1]) != stance)), None

        ((data, _), up, steps), _ = jax.lax.scan(body, (carry, jnp.asarray(True), jnp.asarray(0)), None,
                                                 length=physics_steps)
        return up & jnp.all(jnp.isfinite(data.qpos)), steps

    return jax.jit(jax.vmap(one, in_axes=(None, 0, 0)))


def survive(params: walker.WalkerParams, pushes: Push, qpos: np.ndarray, qvel: np.ndarray,
            seconds: float, mass_class: str = "12kg") -> tuple[np.ndarray, np.ndarray]:
    """(stayed up (B,) bool, touchdowns (B,)) of B walks of the walker (:data:`WALKER`) of ``seconds`` s from
    start states ``qpos`` (B, 23) and ``qvel`` (B, 22), member b pushed by ``pushes`` (fields with a leading
    axis B): :func:`survive_from`."""
    prog = program(mass_class)
    qpos, qvel = np.asarray(qpos, dtype=float), np.asarray(qvel, dtype=float)
    batch = len(qpos)
    if qpos.shape != (batch, prog.mj_model.nq) or qvel.shape != (batch, prog.mj_model.nv):
        raise ValueError(f"qpos and qvel must have shapes (B, {prog.mj_model.nq}) and (B, {prog.mj_model.nv}), "
                         f"got {qpos.shape} and {qvel.shape}")
    return survive_from(WALKER, params, pushes, lambda b: initial(prog, params, qpos[b], qvel[b]), batch,
                        seconds, mass_class)


def survive_from(law: Law, args, pushes: Push, start: Callable[[int], tuple], batch: int, seconds: float,
                 mass_class: str = "12kg", parallel: tuple[str, ...] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(stayed up (B,) bool, touchdowns (B,)) of ``batch`` walks of ``law`` of ``seconds`` s, member b from
    ``start(b)`` (its (MJX data, law state)) and pushed by ``pushes`` (fields with a leading axis B); one
    vmapped program of :data:`BATCH_LANES` walks, called as often as the batch needs (the last call padded
    with the first runs: one program shape)."""
    if np.ndim(pushes.force) != 3 or np.shape(pushes.force)[0] != batch:
        raise ValueError(f"pushes.force must have shape ({batch}, P, 3), got {np.shape(pushes.force)}")
    if not seconds > 0:
        raise ValueError(f"seconds must be positive, got {seconds!r}")
    parallel = drive_set(mass_class, parallel)
    steps = int(round(seconds / float(_program(mass_class, parallel).mj_model.opt.timestep)))
    program_ = _survivor(mass_class, parallel, law, steps)
    lanes = min(batch, BATCH_LANES)
    args, pushes = fixed_arrays(args), fixed_arrays(pushes)
    up, touchdowns = [], []
    for first in range(0, batch, lanes):
        members = [(first + k) % batch for k in range(lanes)]
        carry = jax.tree.map(lambda *a: jnp.stack(a), *[start(b) for b in members])
        part = jax.tree.map(lambda leaf: leaf[jnp.asarray(members)], pushes)
        stayed, steps_taken = program_(args, part, carry)
        keep = min(lanes, batch - first)
        up.append(np.asarray(stayed)[:keep])
        touchdowns.append(np.asarray(steps_taken)[:keep])
    return np.concatenate(up), np.concatenate(touchdowns)


def disturbed_starts(prog: Program, params: walker.WalkerParams, batch: int, seed: int = 0,
                     joint_error: float = 0.02, speed_error: float = 0.05,
                     around: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``batch`` start states around ``around`` = (qpos, qvel) (default :func:`start_state`): every joint off
    by up to ``joint_error`` rad (uniform), the pelvis's velocity off by up to ``speed_error`` m/s per axis,
    the feet put back on the ground; (qpos (B, 23), qvel (B, 22))."""
    qpos0, qvel0 = start_state(prog, params) if around is None else around
    rng = np.random.default_rng(seed)
    qpos, qvel = np.tile(qpos0, (batch, 1)), np.tile(qvel0, (batch, 1))
    joints = list(prog.layout.qpos)
    for b in range(batch):
        qpos[b, joints] += rng.uniform(-joint_error, joint_error, len(joints))
        qvel[b, :3] += rng.uniform(-speed_error, speed_error, 3)
        qpos[b, 2] -= lowest_sole(prog, qpos[b])
    return qpos, qvel


def lowest_sole(prog: Program, qpos: np.ndarray) -> float:
    """Height of the lowest corner of either foot above the ground at ``qpos`` (MuJoCo C kinematics), m."""
    data = mujoco.MjData(prog.mj_model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(prog.mj_model, data)
    return float(np.min(walker.sole_heights(prog.legs, data)))
