"""`biped-jax humanoid`: the optimal sagittal gait (M2 by default) replayed on the 16-DoF humanoid under
contact in MJX; report, figures and a replay file."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax.gait import problem as gait_problem
from biped_jax import humanoid
from biped_jax import robots
from biped_jax.report import animation
from biped_jax.report import outputs
from biped_jax.studies import paper as study

#: The paper's drive of the 12 kg robot (Section 2.3), drawn beside the replay's joint demand.
PAPER_DRIVE = ("RE25-42V", 66.22)


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
                 gaits: Path | None = None, progress: Callable[[str], None] | None = None) -> dict:
    """Replays model ``name``'s optimal step for ``steps`` steps; writes humanoid.json, humanoid_walk.png,
    humanoid_tracking.png, humanoid_torque_speed.png, humanoid_replay.npz and the animation
    humanoid_walk.gif (:func:`biped_jax.report.animation.write_gif`; a warning instead where this machine
    has no OpenGL for headless rendering)."""
    from biped_jax.drives import model as drive_model
    from biped_jax.drives import selection as drive_selection
    from biped_jax.dynamics import mjx_biped
    say = progress or (lambda message: None)
    out.mkdir(parents=True, exist_ok=True)
    mass_class, model = paper_model(name)
    x, settings, status = solved_gait(name, settings, gaits, say)
    if status != "converged":
        say(f"warning: the {name} gait did not converge ({status}); replaying it anyway")
    biped = mjx_biped.load_planar_biped(mass_class)
    trajectory = jax.jit(lambda x_, m: gait_problem.simulate(x_, m, biped, settings))(jnp.asarray(x), model)
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
    say("rendering the walk")
    try:
        animation.write_gif(out / "humanoid_walk.gif", robots.load_mj_model(f"humanoid16_{mass_class}"), run.t,
                            replay_qpos)
    except RuntimeError as error:  # no OpenGL here: the walk's figures and replay file are still written
        say(f"warning: no animation of the walk ({error})")
    return report
