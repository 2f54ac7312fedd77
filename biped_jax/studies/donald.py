"""`biped-jax donald`: DONALD's heuristic walk in MJX, its report, figures and a replay file."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import jax.numpy as jnp
import numpy as np

from biped_jax.donald import model as donald
from biped_jax.drives import model as drive_model
from biped_jax.drives.model import RPM
from biped_jax.report import outputs

#: Standing still after the last step, s (shows that the robot stays up).
FINAL_STAND = 1.0


def walk(steps: int = 8, gait: donald.DonaldGait = donald.DEFAULT_GAIT,
         gains: donald.Gains = donald.DEFAULT_GAINS,
         duration: float | None = None) -> tuple[donald.DonaldRun, drive_model.JointDrives]:
    """Simulates ``steps`` steps of ``gait`` and a final stand in MJX, for ``duration`` s (default: the
    gait's steps plus :data:`FINAL_STAND`; walks of one duration share one compiled program)."""
    if steps < 1:
        raise ValueError(f"steps must be at least 1, got {steps}")
    drive = donald.donald_drive()
    mj_model, model = donald.load_donald(drive)
    needed = walk_duration(gait, steps)
    if duration is None:
        duration = needed
    elif duration < needed:
        raise ValueError(f"duration {duration} s is shorter than the gait's {steps} steps and stand ({needed:.2f} s)")
    return donald.walker(mj_model, steps, duration)(model, gait, gains, drive), drive


def walk_duration(gait: donald.DonaldGait, steps: int) -> float:
    """The gait's ``steps`` steps plus the final stand, s."""
    return float(donald.keyframes(gait, steps)[1][-1]) + FINAL_STAND


def plot_walk(run: donald.DonaldRun, path: Path) -> None:
    """Centre of mass and feet over time (forward and sideways), and a top view."""
    plt = outputs.pyplot()
    t, com, feet = np.asarray(run.t), np.asarray(run.com), np.asarray(run.foot_position)
    touching, margin = donald.support_phases(run)
    figure, axes = plt.subplots(3, 1, figsize=(10, 10), constrained_layout=True)
    for k, (label, axis) in enumerate((("forward x [m]", axes[0]), ("sideways y [m]", axes[1]))):
        axis.plot(t, com[:, k], "k", label="centre of mass")
        for foot, colour in ((0, "tab:blue"), (1, "tab:orange")):
            axis.plot(t, feet[:, foot, k], color=colour, label=f"foot {foot + 1}")
        axis.set_ylabel(label)
        axis.grid(alpha=0.3)
    single = ~np.isnan(margin)
    axes[1].fill_between(t, -0.12, 0.12, where=single, color="0.9", label="single support")
    axes[0].legend(loc="upper left")
    axes[1].set_xlabel("time [s]")
    corners = np.asarray(donald.sole_corners(run))
    for s in np.flatnonzero(single)[::10]:
        foot = int(np.argmax(touching[s]))
        outline = corners[s, foot, [0, 1, 3, 2, 0], :2]
        axes[2].plot(outline[:, 0], outline[:, 1], color=("tab:blue", "tab:orange")[foot], lw=0.5)
    axes[2].plot(com[:, 0], com[:, 1], "k", lw=1, label="centre of mass")
    axes[2].plot(com[single, 0], com[single, 1], "r.", ms=2, label="in single support")
    axes[2].set_aspect("equal")
    axes[2].set_xlabel("x [m]")
    axes[2].set_ylabel("y [m]")
    axes[2].legend(loc="upper left")
    axes[2].set_title(f"top view: supporting sole and centre of mass (smallest margin "
                      f"{1e3 * np.nanmin(margin):.1f} mm)")
    outputs.save_figure(figure, path, dpi=110)
    plt.close(figure)


def plot_torque_speed(run: donald.DonaldRun, drive: drive_model.JointDrives, path: Path) -> None:
    """Joint torque against joint speed for every joint, with the drive's limits (speed-torque lines
    at +-V_s through the gear, and the gear's torque limit)."""
    plt = outputs.pyplot()
    speed, torque = np.asarray(run.joint_speed), np.asarray(run.torque)
    figure, axes = plt.subplots(1, 5, figsize=(18, 4), sharey=True, constrained_layout=True)
    line_speed = np.linspace(-5.0, 5.0, 201)
    low, high = (np.asarray(a) for a in drive_model.torque_limits(drive, jnp.asarray(line_speed)))
    for k, (axis, name) in enumerate(zip(axes, donald.DONALD_ACTUATED_JOINTS)):
        axis.plot(line_speed / RPM, high, "r-", lw=1, label=f"drive limit at {float(drive.supply_voltage):g} V")
        axis.plot(line_speed / RPM, low, "r-", lw=1)
        axis.plot(speed[:, k] / RPM, torque[:, k], ".", ms=2, label="walk")
        axis.set_title(name)
        axis.set_xlabel("joint speed [rpm]")
        axis.set_ylim(-1.2 * float(drive.gear_torque_limit), 1.2 * float(drive.gear_torque_limit))
        axis.grid(alpha=0.3)
    axes[0].set_ylabel("joint torque [N m]")
    axes[0].legend(loc="lower left", fontsize=8)
    outputs.save_figure(figure, path, dpi=110)
    plt.close(figure)


def run_donald(out: Path, steps: int = 8, progress: Callable[[str], None] | None = None,
               gait: donald.DonaldGait = donald.DEFAULT_GAIT, name: str = "donald") -> dict:
    """Walks, then writes {name}.json, {name}_walk.png, {name}_torque_speed.png and {name}_replay.npz
    (time and qpos, for ``biped-jax view donald --replay``)."""
    say = progress or (lambda message: None)
    out.mkdir(parents=True, exist_ok=True)
    say(f"compiling and simulating {steps} steps of DONALD in MJX")
    run, drive = walk(steps, gait)
    report = donald.walk_report(run, drive, donald.DEFAULT_GAINS)
    report["gait"] = {name: float(getattr(gait, name)) for name in gait.__dataclass_fields__}
    report["steps_commanded"] = steps
    # walking speed over the stepping itself (not the initial settle and final stand)
    report["speed_mps"] = report["distance_m"] / (steps * float(gait.step_time))
    outputs.write_json(out / f"{name}.json", report)
    plot_walk(run, out / f"{name}_walk.png")
    plot_torque_speed(run, drive, out / f"{name}_torque_speed.png")
    outputs.save_npz(out / f"{name}_replay.npz", compressed=True, t=np.asarray(run.t), qpos=np.asarray(run.qpos))
    return report


#: Smallest static-stability margin (m) a walk of the full contact solver must keep in single support
#: for its gait to count as verified: the optimiser sees a one-iteration solver, whose margins differ
#: from the full solver's by millimetres, so a margin of zero would be no margin at all.
VERIFIED_MARGIN = 0.005


def is_verified(report: dict, steps: int) -> bool:
    """A walk that did not fall, made every step and kept :data:`VERIFIED_MARGIN` in single support."""
    margin = report["min_support_margin_m"]
    return bool(not report["fell"] and report["steps"] >= steps and np.isfinite(margin) and margin >= VERIFIED_MARGIN)


def verify_candidates(gaits: list[dict], steps: int, say: Callable[[str], None]) -> list[dict]:
    """Walks each candidate (gait parameters by name) ``steps`` steps with MJX's full contact solver, all
    for one duration (one compiled program); returns per candidate its measured speed, margin, fall and
    whether it is verified (:func:`is_verified`)."""
    as_gait = lambda values: dataclasses.replace(  # noqa: E731
        donald.DEFAULT_GAIT, **{k: jnp.asarray(v) for k, v in values.items()})
    duration = max(walk_duration(as_gait(values), steps) for values in gaits)
    records = []
    for k, values in enumerate(gaits):
        gait = as_gait(values)
        run, drive = walk(steps, gait, duration=duration)
        report = donald.walk_report(run, drive, donald.DEFAULT_GAINS)
        record = {"gait": values, "steps": report["steps"], "fell": report["fell"],
                  "speed_mps": report["distance_m"] / (steps * float(gait.step_time)),
                  "min_support_margin_m": report["min_support_margin_m"],
                  "verified": is_verified(report, steps)}
        records.append(record)
        say(f"candidate {k + 1}/{len(gaits)}: {record['speed_mps']:.4f} m/s, margin "
            f"{1e3 * record['min_support_margin_m']:.1f} mm, {record['steps']} steps"
            + (", fell" if record["fell"] else "") + (", verified" if record["verified"] else ""))
    return records


def run_faster(out: Path, steps: int = 8, progress: Callable[[str], None] | None = None,
               resume: bool = False) -> dict:
    """Optimises the gait for speed (``biped_jax.donald.speed``), walks the default gait and every outer
    iterate with MJX's full contact solver (:func:`verify_candidates`), and walks the fastest verified
    one as :func:`run_donald` does (files named donald_faster*). donald_faster.json holds the walk, the
    optimisation and every candidate; the default gait is a candidate, so the result is never a gait
    that failed verification. The optimisation and the verification are kept in ``out/stages``;
    ``resume`` takes them back (:func:`biped_jax.report.outputs.stage`)."""
    from biped_jax.donald import speed as donald_speed
    say = progress or (lambda message: None)
    say("optimising DONALD's gait for speed (single shooting through MJX contact, an augmented Lagrangian "
        "over optax's L-BFGS)")
    key = {"steps": steps}
    result = outputs.stage(out, "donald_speed_optimisation", key, lambda: donald_speed.optimise(
        progress=lambda i, row: say(
            f"outer iteration {i + 1}: speed {-0.01 * float(row['cost'][0]):.4f} m/s, scaled violation "
            f"{float(row['violation'][0]):.1e}, gradients {int(row['gradients'][0])}")), resume, say)
    default = {name: float(getattr(donald.DEFAULT_GAIT, name)) for name in donald_speed.PARAMETERS}
    say(f"verifying the default gait and {len(result['iterates'])} iterates with the full contact solver")
    candidates = outputs.stage(out, "donald_speed_candidates", key, lambda: verify_candidates(
        [default] + [row["gait"] for row in result["iterates"]], steps, say), resume, say)
    verified = [c for c in candidates if c["verified"]]
    best = max(verified, key=lambda c: c["speed_mps"]) if verified else candidates[0]
    gait = dataclasses.replace(donald.DEFAULT_GAIT, **{k: jnp.asarray(v) for k, v in best["gait"].items()})
    report = run_donald(out, steps, progress, gait, name="donald_faster")
    report["optimisation"] = result
    report["candidates"] = candidates
    report["chosen_candidate"] = candidates.index(best)
    report["speed_gain_mps"] = best["speed_mps"] - candidates[0]["speed_mps"]
    outputs.write_json(out / "donald_faster.json", report)
    return report
