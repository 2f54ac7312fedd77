"""`biped-jax humanoid`: the optimal sagittal gait (M2 by default) replayed on the 16-DoF humanoid under
contact in MJX; report, figures and a replay file."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax.gait import problem as gait_problem
from biped_jax import humanoid
from biped_jax import robots
from biped_jax.report import animation
from biped_jax.report import outputs
from biped_jax.report import progress as progress_report
from biped_jax.studies import paper as study

#: The paper's drive of the 12 kg robot (Section 2.3), drawn beside the replay's joint demand.
PAPER_DRIVE = ("RE25-42V", 66.22)


#: The robustness trial (:func:`push_trial`): runs per batch, each push's impulse in the nominal batch
#: (N s; 0.5 N s changes the 12 kg robot's speed by 0.04 m/s), the sweep's largest impulse, how long each
#: push lasts (s), and the walk's length after the last push (s).
PUSH_BATCH, PUSH_IMPULSE, PUSH_SWEEP, PUSH_DURATION, PUSH_RECOVERY = 64, 0.5, 2.0, 0.1, 1.5
#: The 3D walk's models: the paper's two mass classes at the optimal gait's speed.
WALK_MODELS = ("M2", "M4")


class WalkGait(NamedTuple):
    """A model's step for the 3D walk (:data:`WALK_GAITS`): the study's optimum solved again with the swing
    foot's ``clearance`` (m) over the ground mid-step, the landing's forward speed at most
    ``touchdown_speed`` (m/s; None: no bound) and, with ``drive_limits``, within the speed-torque lines
    and gear limits of the walk's drives (:func:`planar_walk_drives`; the problem then minimises their
    Joule heat instead of the paper's integral of u^2)."""

    clearance: float
    touchdown_speed: float | None = None
    drive_limits: bool = False


#: The step each model's tracker walks where it is not the study's optimum with the swing foot lifted after
#: the optimisation (:func:`cleared_gait`), tracked with nothing added. M2's path then asks at most 1.06
#: times the drive's line (2.26 with the lift added to the optimum; docs/studies.md). M4 walks its optimum
#: with the lift: solved with the clearance and the landing's bound its path asks 1.7 times the line (the
#: stance knee at the step's end), and within two drives at each hip pitch and one at each knee
#: (``drive_limits``) 1.27, but its walk, retuned, was less robust to pushes (docs/studies.md).
WALK_GAITS = {"M2": WalkGait(0.01, 1.2)}
#: The interior point's options for a step solved again within its drives' lines (:func:`cleared_gait`).
DRIVE_LIMITED_OPTIONS = dataclasses.replace(study.IP_OPTIONS, max_iterations=200)


def paper_model(name: str) -> tuple[str, gait_problem.GaitModel]:
    """(mass class, problem) of one of the paper's models M1-M4."""
    rows = {r.name: r for r in study.PAPER_MODELS}
    if name not in rows:
        raise ValueError(f"unknown model {name!r}; known: {', '.join(rows)}")
    return rows[name].mass_class, study.paper_gait_models([rows[name]])[0]


def solved_gait(name: str, settings: gait_problem.GaitSettings, gaits: Path | None,
                progress: Callable[[str], None]) -> tuple[np.ndarray, gait_problem.GaitSettings, str]:
    """(decision vector, settings, status) of model ``name``: read from ``gaits``/results.json (written by
    ``biped-jax reproduce``) when given, else solved here."""
    if gaits is not None:
        source = gaits / "results.json"
        if not source.is_file():
            raise FileNotFoundError(f"no study results at {source}: run `biped-jax reproduce --out {gaits}` first")
        try:
            results = json.loads(source.read_text())
            records = {r["model"]: r for r in results["models"]}
            saved = gait_problem.GaitSettings(**results["settings"])
        except ValueError as error:  # JSONDecodeError is one; so are GaitSettings' checks
            raise ValueError(f"{source}: not a study result of `biped-jax reproduce` ({error})") from None
        except (KeyError, TypeError) as error:
            raise ValueError(f"{source}: not a study result of `biped-jax reproduce` (no {error})") from None
        if name not in records:
            raise ValueError(f"{source} holds no model {name!r}")
        x = np.asarray(records[name].get("decision_vector"), dtype=float)
        if x.shape != (saved.size,) or not np.all(np.isfinite(x)):
            raise ValueError(f"{source}: model {name}'s decision vector has shape {x.shape} or non-finite "
                             f"values; its settings need ({saved.size},)")
        return x, saved, records[name]["status"]
    from biped_jax.gait.solver import GaitSolver
    _, model = paper_model(name)
    progress(f"compiling the gait problem and solving {name}")
    solution = GaitSolver(settings).solve([name], [model], progress=lambda i, row: progress(
        f"{name}: outer iteration {i + 1}, largest scaled violation {np.max(row['violation']):.1e}"))[0]
    return solution.x, settings, solution.status


def cleared_gait(name: str, x: np.ndarray, settings: gait_problem.GaitSettings, clearance: float,
                 ramp: float | None = None, touchdown_speed: float | None = None,
                 progress: Callable[[str], None] | None = None, *, drives=None
                 ) -> tuple[np.ndarray, gait_problem.GaitSettings, str]:
    """(decision vector, settings, status) of model ``name``'s optimal step solved again with the swing foot
    held ``clearance`` m over the ground mid-step (:attr:`~biped_jax.gait.problem.GaitSettings.swing_clearance`;
    ``ramp``: its ``clearance_ramp``, default the settings'; ``touchdown_speed``: its
    ``touchdown_forward_speed``, m/s, default the settings'),
    from the step ``x`` under ``settings`` (the study's optimum; the interior point starts with the study's
    barrier, as from a cold start: the optimum violates the new rows). The humanoid then walks a path whose
    own torques include the lift, instead of a lift added to the optimum (which costs the swing hip several
    times the optimum's torque where it turns). ``drives``: the planar joints' drives
    (:class:`~biped_jax.drives.model.JointDrives`, e.g. :func:`planar_walk_drives`) whose lines and gear
    limits the step then keeps (``drive_limits``), minimising their Joule heat; solved from the step
    with the clearance alone (the second solve's status is returned)."""
    from biped_jax.gait.solver import GaitSolver
    settings = dataclasses.replace(settings, swing_clearance=float(clearance),
                                   clearance_ramp=settings.clearance_ramp if ramp is None else float(ramp),
                                   touchdown_forward_speed=settings.touchdown_forward_speed if touchdown_speed is None
                                   else float(touchdown_speed))
    _, model = paper_model(name)
    say = progress or (lambda message: None)
    stages = [(settings, model, study.IP_OPTIONS, f"with the swing foot {1e3 * clearance:g} mm up mid-step")]
    if drives is not None:  # M4's took 79-80 iterations from its cleared step (2026-12-07)
        stages.append((dataclasses.replace(settings, drive_limits=True), dataclasses.replace(model, drives=drives),
                       DRIVE_LIMITED_OPTIONS, "within its drives' lines"))
    for settings, model, options, what in stages:
        say(f"solving {name}'s step again {what}")
        solution = GaitSolver(settings).using(options).solve(
            [name], [model], x0=np.asarray(x)[None],
            progress=progress_report.iteration_progress(say, name, options.max_iterations))[0]
        x = solution.x
    return solution.x, settings, solution.status


def planar_walk_drives(name: str, parallel: tuple[str, ...] | None = None):
    """The drives of model ``name``'s 3D walk, two at the leg joints ``parallel`` (default
    :data:`biped_jax.humanoid.tracker.DRIVES`), at the planar biped's joints: hip and knee of one leg, then
    of the other, fields (4,) (the supply voltage ()); :class:`~biped_jax.drives.model.JointDrives`."""
    from biped_jax.humanoid import tracker, walk3d
    from biped_jax.robots.mjcf import HUMANOID_ACTUATED_JOINTS
    mass_class, _ = paper_model(name)
    drives = walk3d.walk_drives(mass_class, tracker.DRIVES if parallel is None else parallel)
    # the planar joints' order as the humanoid's Layout.sagittal_actuators (the legs' drives are alike)
    index = jnp.array([HUMANOID_ACTUATED_JOINTS.index(joint)
                       for joint in ("hip_pitch_l", "knee_l", "hip_pitch_r", "knee_r")])
    at_joints = lambda field: jnp.broadcast_to(field, (len(HUMANOID_ACTUATED_JOINTS),))[index]  # noqa: E731
    # a drive set with two motors somewhere has every field per actuator, the supply voltage included
    return dataclasses.replace(jax.tree.map(at_joints, drives),
                               supply_voltage=jnp.asarray(drives.supply_voltage).reshape(-1)[0])


@dataclasses.dataclass(frozen=True)
class WalkedStep:
    """The step a model's tracker walks (:func:`walked_step`).

    Attributes:
      x: the decision vector (n,) under ``settings``.
      settings: its gait problem's settings.
      trajectory: the step simulated on the planar biped.
      gait: the record of a step solved again (``humanoid.json``'s ``models.<name>.gait``), None for the
        study's optimum.
    """

    x: np.ndarray
    settings: gait_problem.GaitSettings
    trajectory: object
    gait: dict | None

    @property
    def lift(self) -> float | None:
        """The swing foot's lift added to the path, m: 0 on a step solved with its clearance, None for the
        tracker's default (:data:`biped_jax.humanoid.reference.SWING_CLEARANCE`) on the study's optimum."""
        return None if self.gait is None else 0.0


def walked_step(name: str, x: np.ndarray, settings: gait_problem.GaitSettings, trajectory=None,
                clearance: float | None = None, touchdown_speed: float | None = None, ramp: float | None = None,
                progress: Callable[[str], None] | None = None, drive_limits: bool | None = None,
                parallel: tuple[str, ...] | None = None) -> WalkedStep:
    """The step model ``name``'s tracker walks, from the study's optimum ``x`` under ``settings`` (simulated as
    ``trajectory`` where given): solved again with the swing foot's ``clearance`` (m) and the landing's
    ``touchdown_speed`` bound (m/s) where ``clearance`` is positive (:func:`cleared_gait`; ``ramp`` its
    ``clearance_ramp``; with ``drive_limits`` within the walk's drives, two at the leg joints ``parallel``:
    :func:`planar_walk_drives`), else the optimum itself. ``clearance`` None: the model's :data:`WALK_GAITS`
    entry (its landing bound and drive limits too, unless given), the optimum for a model without one."""
    if clearance is None:
        clearance, landing, limited = WALK_GAITS.get(name, WalkGait(0.0))
        touchdown_speed = landing if touchdown_speed is None else touchdown_speed
        drive_limits = limited if drive_limits is None else drive_limits
    drive_limits = bool(drive_limits)
    if not clearance:
        return WalkedStep(x, settings, simulated_step(name, x, settings) if trajectory is None else trajectory,
                          None)
    x, settings, status = cleared_gait(name, x, settings, clearance, ramp, touchdown_speed, progress,
                                       drives=planar_walk_drives(name, parallel) if drive_limits else None)
    trajectory = simulated_step(name, x, settings)
    return WalkedStep(x, settings, trajectory,
                      {"swing_clearance_m": clearance, "clearance_ramp": settings.clearance_ramp,
                       "touchdown_forward_speed_mps": touchdown_speed, "drive_limits": drive_limits,
                       "status": status,
                       "cost": float(gait_problem.cost(trajectory)), "added_lift_m": 0.0})


def simulated_step(name: str, x: np.ndarray, settings: gait_problem.GaitSettings):
    """The optimal step of model ``name`` (decision vector ``x`` under ``settings``) simulated on its planar
    biped (:func:`biped_jax.gait.problem.simulate`)."""
    from biped_jax.dynamics import mjx_biped
    mass_class, model = paper_model(name)
    biped = mjx_biped.load_planar_biped(mass_class)
    return jax.jit(lambda x_, m: gait_problem.simulate(x_, m, biped, settings))(jnp.asarray(x), model)


def plot_walk(run: humanoid.Replay, com: np.ndarray, path: Path) -> None:
    """Centre of mass, hips and feet over time (forward and height)."""
    plt = outputs.pyplot()
    figure, axes = plt.subplots(2, 1, figsize=(10, 7), sharex=True, constrained_layout=True)
    for k, (axis, label) in enumerate(zip(axes, ("forward x [m]", "height z [m]"))):
        column = (0, 2)[k]
        axis.plot(run.t, com[:, column], "k", label="centre of mass")
        for foot, colour in ((0, "tab:blue"), (1, "tab:orange")):
            axis.plot(run.t, run.feet[:, foot, column], color=colour, label=f"foot {humanoid.SIDES[foot]}")
        axis.set_ylabel(label)
        axis.grid(alpha=0.3)
    for k in humanoid.touchdown_indices(run):
        for axis in axes:
            axis.axvline(run.t[k], color="0.8", lw=0.5)
    axes[0].legend(loc="upper left")
    axes[1].set_xlabel("time [s] (grey: touchdowns)")
    outputs.save_figure(figure, path, dpi=110)
    plt.close(figure)


def plot_tracking(run: humanoid.Replay, path: Path) -> None:
    """Each sagittal joint (labelled by stance and swing leg) against its reference, and the errors."""
    plt = outputs.pyplot()
    figure, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True, constrained_layout=True)
    for k, name in enumerate(("stance hip", "stance knee", "swing hip", "swing knee")):
        colour = f"C{k}"
        axes[k // 2].plot(run.t, run.joints[:, k], color=colour, label=name)
        axes[k // 2].plot(run.t, run.target[:, k], "--", color=colour, lw=0.8, label=f"{name} reference")
        axes[2].plot(run.t, 1e3 * (run.joints[:, k] - run.target[:, k]), color=colour, lw=0.8, label=name)
    for axis, label in zip(axes, ("hips [rad]", "knees [rad]", "tracking error [mrad]")):
        axis.set_ylabel(label)
        axis.grid(alpha=0.3)
        axis.legend(loc="upper right", fontsize=8, ncol=2)
    axes[2].set_xlabel("time [s]")
    outputs.save_figure(figure, path, dpi=110)
    plt.close(figure)


def com_path(mj_model, qpos: np.ndarray) -> np.ndarray:
    """Whole-body centre of mass at each sample, shape (N, 3), m (MuJoCo C kinematics)."""
    import mujoco
    data = mujoco.MjData(mj_model)
    out = np.empty((len(qpos), 3))
    for i, q in enumerate(qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(mj_model, data)
        mujoco.mj_comPos(mj_model, data)
        out[i] = data.subtree_com[0]
    return out


def free_base_qpos(qpos: np.ndarray) -> np.ndarray:
    """Planarised (x, z, pitch, joints) states as the humanoid16 model's free-base qpos, shape (N, 23),
    for ``biped-jax view humanoid16_12kg --replay``."""
    x, z, pitch = qpos[:, 0], qpos[:, 1], qpos[:, 2]
    zeros = np.zeros_like(x)
    return np.column_stack([x, zeros, z, np.cos(pitch / 2), zeros, np.sin(pitch / 2), zeros, qpos[:, 3:]])


def run_humanoid(out: Path, name: str = "M2", steps: int = 10,
                 settings: gait_problem.GaitSettings = gait_problem.GaitSettings(),
                 gaits: Path | None = None, progress: Callable[[str], None] | None = None,
                 walk_models: tuple[str, ...] = WALK_MODELS, walk_steps: int = 20,
                 push_batch: int = PUSH_BATCH, law: str = "tracker") -> dict:
    """Replays model ``name``'s optimal step for ``steps`` steps on the planarised humanoid, then walks each
    of ``walk_models`` in 3D on the free-base humanoid with ``law`` (:data:`LAWS`; ``walk_steps`` steps after
    the start's transient, push trials of ``push_batch`` runs; 0: none; the tracker on the step of
    :data:`WALK_GAITS` where the model has one, recorded under the walk's ``gait``). Writes humanoid.json (the 3D walks
    under ``models``), humanoid_walk.png, humanoid_tracking.png, humanoid_torque_speed.png, humanoid_replay.npz,
    humanoid_walk3d_<model>.npz and the animations humanoid_walk.gif and humanoid_walk3d_<model>.gif
    (:func:`biped_jax.report.animation.write_gif`; a warning instead where this machine has no OpenGL for
    headless rendering)."""
    for model_name in walk_models:
        paper_model(model_name)  # an unknown name fails here, before any compilation
    if int(walk_steps) < 1:
        raise ValueError(f"walk_steps must be at least 1, got {walk_steps}")
    if int(push_batch) < 0:
        raise ValueError(f"push_batch must be 0 or more, got {push_batch}")
    if law not in LAWS:
        raise ValueError(f"unknown law {law!r}; known: {', '.join(LAWS)}")
    from biped_jax.drives import model as drive_model
    from biped_jax.drives import selection as drive_selection
    say = progress or (lambda message: None)
    out.mkdir(parents=True, exist_ok=True)
    mass_class, model = paper_model(name)
    x, settings, status = solved_gait(name, settings, gaits, say)
    if status != "converged":
        say(f"warning: the {name} gait did not converge ({status}); replaying it anyway")
    trajectory = simulated_step(name, x, settings)
    reference = humanoid.gait_reference(x, model, settings, trajectory, mass_class)
    say(f"compiling the humanoid's contact simulation and walking {steps} steps")
    run = humanoid.replay(reference, mass_class, steps, progress=say)
    mj_model, layout = humanoid.contact_model(mass_class)
    report = humanoid.walk_report(run, mj_model, layout, reference, humanoid.DEFAULT_GAINS)
    report.update({"model": name, "mass_class": mass_class, "gait_status": status,
                   "gait_settings": dataclasses.asdict(settings),
                   "steps_commanded": steps})
    outputs.write_json(out / "humanoid.json", report)
    com = com_path(mj_model, run.qpos)
    plot_walk(run, com, out / "humanoid_walk.png")
    plot_tracking(run, out / "humanoid_tracking.png")
    torque = humanoid.applied_torque(run, layout, humanoid.DEFAULT_GAINS)[:, layout.sagittal_actuators]
    workspace = drive_selection.JointWorkspace(t=run.t, speed=run.qvel[:, layout.sagittal_q], torque=torque,
                                               step_time=float(run.t[-1]))  # the whole walk: no window
    winding, ratio = PAPER_DRIVE
    drive_selection.plot_motor_workspace(workspace, drive_model.load_catalogue(), (ratio,),
                                         f"humanoid replay of {name}",
                                         out / "humanoid_torque_speed.png", windings=(winding,), window=0.0)
    replay_qpos = free_base_qpos(run.qpos)
    outputs.save_npz(out / "humanoid_replay.npz", compressed=True, t=run.t, qpos=replay_qpos)
    animations = [(out / "humanoid_walk.gif", robots.load_mj_model(f"humanoid16_{mass_class}"), run.t, replay_qpos)]
    report["models"] = {}
    for model_name in walk_models:
        if model_name == name:
            x_walked, settings_walked, walked = x, settings, trajectory
        else:
            x_walked, settings_walked, _ = solved_gait(model_name, settings, gaits, say)
            walked = None
        if law == "tracker":
            step = walked_step(model_name, x_walked, settings_walked, walked, progress=say)
            walking = tracker_walking(model_name, step.x, step.settings, step.trajectory, clearance=step.lift)
            walked = step.trajectory
        else:
            step = None
            walked = simulated_step(model_name, x_walked, settings_walked) if walked is None else walked
            walking = walker_walking(model_name)
        entry, record = walk_3d(walking, walked, walk_steps, push_batch, say)
        if step is not None and step.gait is not None:
            entry["gait"] = step.gait
        report["models"][model_name] = entry
        outputs.write_json(out / "humanoid.json", report)
        outputs.save_npz(out / f"humanoid_walk3d_{model_name}.npz", compressed=True, t=record.t, qpos=record.qpos)
        from biped_jax.humanoid import walk3d
        animations.append((out / f"humanoid_walk3d_{model_name}.gif",
                           walk3d.program(walking.mass_class, walking.parallel).mj_model, record.t, record.qpos))
    say("rendering the walks")
    for path, mj_model_, t, qpos in animations:
        try:
            animation.write_gif(path, mj_model_, t, qpos)
        except RuntimeError as error:  # no OpenGL here: the walk's figures and replay file are still written
            say(f"warning: no animation of the walk ({error})")
            break
    return report



def gait_cost_of_transport(trajectory, mass: float, step_length: float) -> float:
    """Positive joint work of the optimal step over weight x step length (the 3D walk's measure)."""
    power = np.maximum(np.asarray(trajectory.u) * np.asarray(trajectory.qd)[:, 1:], 0.0).sum(axis=1)
    return float(np.asarray(trajectory.weights) @ power) / (mass * 9.81 * step_length)


def walk_params(name: str):
    """The controller's parameters for model ``name``: its mass class's tuned set
    (:func:`biped_jax.humanoid.walker.tuned`) at the model's speed and step time."""
    from biped_jax.humanoid import walker
    mass_class, model = paper_model(name)
    speed, step_length = float(model.speed), float(model.step_length)
    return dataclasses.replace(walker.tuned(mass_class), speed=speed, step_time=step_length / speed)


#: The 3D walk's laws (``--law``): ``tracker`` follows the optimal step itself
#: (:mod:`biped_jax.humanoid.tracker`), ``walker`` places its feet by Raibert's rule
#: (:mod:`biped_jax.humanoid.walker`).
LAWS = ("tracker", "walker")
#: The tracker's walk starts on the gait: its first touchdowns are not counted as steady.
TRACKER_TRANSIENT = 2


@dataclasses.dataclass(frozen=True)
class Walking:
    """One model's 3D walk: the law and its parameters, the drives (two at the joints ``parallel``), the
    start (``start_state`` = (qpos, qvel) and ``start(qpos, qvel)`` -> (MJX data, the law's state)), when the
    walk is steady (s: the push trials push then), how many touchdowns come before the counted steps and
    whether the measures' steady part starts after them (else after the walker's ramp and a step:
    :func:`biped_jax.humanoid.walk3d.measures`)."""

    name: str
    law: object
    args: object
    mass_class: str
    parallel: tuple[str, ...]
    start_state: tuple
    start: Callable
    steady_at: float
    transient_touchdowns: int
    steady_after_transient: bool

    @property
    def step_time(self) -> float:
        return float(walk_params(self.name).step_time)


def walker_walking(name: str) -> Walking:
    """Model ``name`` on the foot-placement walker, from rest, its speed ramped up."""
    from biped_jax.humanoid import walk3d
    mass_class, _ = paper_model(name)
    params = walk_params(name)
    prog = walk3d.program(mass_class)
    return Walking(name, walk3d.WALKER, params, mass_class, walk3d.drive_set(mass_class),
                   walk3d.start_state(prog, params), lambda q, v: walk3d.initial(prog, params, q, v),
                   float(params.ramp) + 4 * float(params.step_time),
                   int(np.ceil(float(params.ramp) / float(params.step_time))), False)


def tracker_walking(name: str, x: np.ndarray, settings: gait_problem.GaitSettings, trajectory,
                    gains=None, clearance: float | None = None, parallel: tuple[str, ...] | None = None,
                    lateral: dict | None = None, earlier: Walking | None = None) -> Walking:
    """Model ``name`` on the tracker of its optimal step (decision vector ``x`` under ``settings``, simulated
    as ``trajectory``), from the gait's state after a touchdown: ``gains`` (default
    :func:`biped_jax.humanoid.tracker.gains_for`), the lateral law's numbers ``lateral`` (fields of
    :class:`biped_jax.humanoid.walker.WalkerParams`, over :func:`biped_jax.humanoid.tracker.lateral_for`'s),
    the swing foot's ``clearance`` (m, default :data:`biped_jax.humanoid.reference.SWING_CLEARANCE`), two
    drives at the joints ``parallel`` (default :data:`biped_jax.humanoid.tracker.DRIVES`). ``earlier``: this
    function's walk of the same step, clearance and drives, whose path and gait reference are reused (both
    together some 6 s on a 2-core CPU; neither depends on the gains or the lateral numbers), else both are
    computed."""
    from biped_jax.humanoid import reference, tracker, walk3d
    mass_class, model = paper_model(name)
    params, lateral = walk_params(name), {**tracker.lateral_for(name), **(lateral or {})}
    unknown = sorted(set(lateral) - {f.name for f in dataclasses.fields(params)})
    if unknown:
        raise ValueError(f"unknown lateral numbers {unknown}; they are fields of WalkerParams")
    params = dataclasses.replace(params, **lateral)
    parallel = walk3d.drive_set(mass_class, tracker.DRIVES if parallel is None else parallel)
    prog = walk3d.program(mass_class, parallel)
    if earlier is not None:
        path, gait = earlier.args.path, earlier.args.gait
    else:
        gait = reference.gait_reference(x, model, settings, trajectory, mass_class)
        path = tracker.path_3d(prog, model, trajectory, mass_class,
                               reference.SWING_CLEARANCE if clearance is None else clearance)
    args = tracker.TrackerArgs(tracker.gains_for(name) if gains is None else gains, path, gait, params)
    return Walking(name, tracker.LAW, walk3d.fixed_arrays(args), mass_class, parallel,
                   tracker.start_state(path, params), lambda q, v: tracker.start(prog, args, q, v),
                   8 * float(params.step_time), TRACKER_TRANSIENT, True)


def push_trial(walking: Walking, batch: int, impulse: float | None, seed: int = 0) -> dict:
    """``batch`` walks from disturbed starts (:func:`biped_jax.humanoid.walk3d.disturbed_starts` around the
    walk's start), each pushed once sagittally (at ``walking.steady_at``) and once sideways (four steps
    later), random signs, in one vmapped program (:func:`biped_jax.humanoid.walk3d.survive_from`).
    ``impulse`` (N s) for every run, or None: run b's impulse ``PUSH_SWEEP (b + 0.5) / batch`` (the sweep).
    Returns the runs' impulses, who stayed up, the success rate and, for the sweep, the impulse at which half
    the runs fall (:func:`half_fall_impulse`)."""
    from biped_jax.humanoid import walk3d
    prog = walk3d.program(walking.mass_class, walking.parallel)
    qpos, qvel = walk3d.disturbed_starts(prog, walk_params(walking.name), batch, seed, around=walking.start_state)
    rng = np.random.default_rng(seed + 1)
    level = (np.full(batch, impulse) if impulse is not None
             else PUSH_SWEEP * (np.arange(batch) + 0.5) / batch)
    signs = rng.choice([-1.0, 1.0], size=(batch, 2))
    sagittal_at = walking.steady_at
    lateral_at = sagittal_at + 4 * walking.step_time
    runs = [walk3d.pushes(forward * i, sideways * i, sagittal_at, lateral_at, PUSH_DURATION)
            for i, (forward, sideways) in zip(level, signs)]
    stacked = jax.tree.map(lambda *a: jnp.stack(a), *runs)
    up, _ = walk3d.survive_from(walking.law, walking.args, stacked, lambda b: walking.start(qpos[b], qvel[b]), batch,
                                lateral_at + PUSH_RECOVERY, walking.mass_class, walking.parallel)
    record = {"batch": batch, "impulses_Ns": level.tolist(), "signs": signs.tolist(), "stayed_up": up.tolist(),
              "success_rate": float(up.mean()), "sagittal_at_s": sagittal_at, "lateral_at_s": lateral_at,
              "duration_s": PUSH_DURATION, "walk_s": lateral_at + PUSH_RECOVERY}
    if impulse is None:
        record["half_fall_impulse_Ns"] = half_fall_impulse(level, up)
    return record


def half_fall_impulse(impulse: np.ndarray, up: np.ndarray) -> float | None:
    """The impulse (N s) at which a logistic fit of falling against impulse crosses one half: 0.0 where it
    crosses below zero or more than 90 % of the runs fell (half fall unpushed, or nearly), None where fewer
    than 10 % fell (no crossing within the sweep)."""
    import scipy.optimize
    fell = ~np.asarray(up, dtype=bool)
    if fell.mean() < 0.1:
        return None
    if fell.mean() > 0.9:
        return 0.0
    x = np.asarray(impulse, dtype=float)

    def loss(theta):
        z = theta[0] + theta[1] * x
        return float(np.sum(np.logaddexp(0.0, z) - fell * z))

    fit = scipy.optimize.minimize(loss, np.array([-1.0, 1.0]), method="Nelder-Mead")
    a, b = fit.x
    return max(0.0, float(-a / b)) if b > 0 else None


def walk_3d(walking: Walking, trajectory, steps: int, batch: int, progress: Callable[[str], None]
            ) -> tuple[dict, object]:
    """The 3D walk ``walking`` (:mod:`biped_jax.humanoid.walk3d`): ``steps`` steps after its transient
    touchdowns, the walk's figures, the push trials (nominal impulse and sweep, ``batch`` runs each), the cost
    of transport against the optimal step's (``trajectory``) and, for the tracker, the largest of its path's
    own torques over the drive's line (:func:`biped_jax.humanoid.tracker.path_drive_ratio`; the joint and
    phase). Returns (the record for humanoid.json, the walk)."""
    from biped_jax.humanoid import free_base, tracker, walk3d
    name, mass_class = walking.name, walking.mass_class
    _, model = paper_model(name)
    params = walk_params(name)
    speed, step_length = float(model.speed), float(model.step_length)
    progress(f"compiling the 3D walk ({mass_class}, {walking.law.name}) and walking {name}")
    prog = walk3d.program(mass_class, walking.parallel)
    wanted = walking.transient_touchdowns + int(steps)
    record = walk3d.run(walking.law, walking.args, walking.start(*walking.start_state), mass_class, walking.parallel,
                        touchdowns_wanted=wanted, limit=walking.steady_at + 2.0 * wanted * walking.step_time + 0.5,
                        progress=progress)
    landings = walk3d.touchdowns(record)
    steady_after = None  # the walker's: after its ramp and a step
    if walking.steady_after_transient:
        steady_after = float(record.t[landings[walking.transient_touchdowns - 1]]) + 1e-9 \
            if len(landings) >= walking.transient_touchdowns else float(record.t[-1])
    figures = walk3d.measures(record, mass_class, params, speed, step_length, steady_after, walking.parallel)
    gait_cot = gait_cost_of_transport(trajectory, prog.layout.mass, step_length)
    entry = {"free_base": True, "law": walking.law.name, "mass_class": mass_class, "gait_speed_mps": speed,
             "gait_step_length_m": step_length,
             "drive": f"{free_base.WALK_MOTOR} + {free_base.WALK_GEARHEAD} at every joint" + "".join(
                 f", two in parallel at each {joint}" for joint in walking.parallel),
             "controller": dataclasses.asdict(params) if walking.law is walk3d.WALKER else {
                 "gains": {k: float(v) for k, v in dataclasses.asdict(walking.args.gains).items()},
                 "lateral": {k: float(v) for k, v in dataclasses.asdict(walking.args.params).items()}},
             "steps_after_transient": max(0, figures["steps"] - walking.transient_touchdowns),
             **figures, "gait_cost_of_transport": gait_cot}
    if entry.get("cost_of_transport") is not None:
        entry["cost_of_transport_ratio"] = entry["cost_of_transport"] / gait_cot
    if walking.law is tracker.LAW:
        ratio = tracker.path_drive_ratio(prog, walking.args.path)
        sample, joint = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        entry["path_max_drive_torque_ratio"] = float(ratio[sample, joint])
        entry["path_max_drive_torque_at"] = {"joint": prog.mj_model.actuator(int(joint)).name,
                                             "phase": float(np.asarray(walking.args.path.phase)[sample])}
    if batch:
        progress(f"{name}: {batch} pushed walks at {PUSH_IMPULSE} N s, then {batch} over 0-{PUSH_SWEEP} N s")
        entry["push_nominal"] = push_trial(walking, batch, PUSH_IMPULSE)
        entry["push_sweep"] = push_trial(walking, batch, None, seed=1)
        entry["push_success_rate"] = entry["push_nominal"]["success_rate"]
        entry["push_half_fall_impulse_Ns"] = entry["push_sweep"]["half_fall_impulse_Ns"]
    return entry, record
