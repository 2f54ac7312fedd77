"""Drive requirements from gait trajectories (the paper's Table 6) and the selection of a winding and
a gear ratio (Section 2.3, Figs. 4-5).

Rule for the spikes near touchdown (the paper drops them by hand): samples within ``impact_window``
x t_f of either end of the step are left out of every requirement and check; the full maxima are
reported beside them. "Operational" ranges are the 50th to 90th percentile, over the samples outside
the window, of the largest joint's |torque| (or |speed|) at each instant.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from biped_jax import checks
from biped_jax.drives import model as drive_model
from biped_jax.drives import thermal
from biped_jax.drives.model import MNM, RPM
from biped_jax.report import outputs
from biped_jax.robots.planar_biped import ACTUATED

IMPACT_WINDOW = 0.05


@dataclasses.dataclass(frozen=True)
class JointWorkspace:
    """Sampled joint demand of one step.

    Attributes:
      t: sample times, shape (T,), s. speed: joint rates, shape (T, J), rad/s. torque: joint torques,
      shape (T, J), N m. step_time: t_f, s.
    """

    t: np.ndarray
    speed: np.ndarray
    torque: np.ndarray
    step_time: float

    def __post_init__(self):
        t = checks.finite_array("JointWorkspace.t", self.t, (None,), ": sample times, s")
        checks.finite_array("JointWorkspace.speed", self.speed, (t.shape[0], None), ": one row per sample time")
        checks.finite_array("JointWorkspace.torque", self.torque, np.shape(self.speed), ": the shape of speed")
        checks.number_in("JointWorkspace.step_time", self.step_time, 0.0, math.inf, "s")

    def outside_impacts(self, window: float = IMPACT_WINDOW) -> np.ndarray:
        """Mask of the samples farther than window x t_f from either end, shape (T,)."""
        s = self.t / self.step_time
        return (s >= window) & (s <= 1 - window)


def trapezoid_weights(t: np.ndarray) -> np.ndarray:
    """Weights w, shape (T,), s, with w . f the trapezoidal integral of samples f at times t (T,)."""
    t = np.asarray(t, dtype=float)
    if t.size < 2:
        return np.ones_like(t)
    gaps = np.diff(t)
    return 0.5 * (np.concatenate([gaps, [0.0]]) + np.concatenate([[0.0], gaps]))


def requirements(workspace: JointWorkspace, window: float = IMPACT_WINDOW) -> dict:
    """Table 6 for one gait: torques in N m, speeds in rpm, power in W (SI except rpm at this edge)."""
    inside = workspace.outside_impacts(window)
    torque = np.abs(workspace.torque)
    speed = np.abs(workspace.speed)
    power = speed * torque
    peak_torque = torque[inside].max(axis=1)
    peak_speed = speed[inside].max(axis=1)
    return {
        "operational_torque_Nm": [float(np.percentile(peak_torque, 50)), float(np.percentile(peak_torque, 90))],
        "max_torque_Nm": float(peak_torque.max()),
        "operational_rpm": [float(np.percentile(peak_speed, 50) / RPM), float(np.percentile(peak_speed, 90) / RPM)],
        "max_rpm": float(peak_speed.max() / RPM),
        "max_power_W": float(power[inside].max()),
        "max_torque_with_impacts_Nm": float(torque.max()),
        "max_rpm_with_impacts": float(speed.max() / RPM),
        "max_power_with_impacts_W": float(power.max()),
        "impact_window_fraction": window,
    }


def _check_parts(workspace, motor, gear, supply_voltage, window) -> None:
    for name, value, kind in (("workspace", workspace, JointWorkspace), ("motor", motor, drive_model.Motor),
                              ("gear", gear, drive_model.Gearhead)):
        if not isinstance(value, kind):
            raise TypeError(f"{name} must be a {kind.__name__}, got {type(value).__name__}")
    checks.number_in("supply_voltage", supply_voltage, 0.0, math.inf, "V")
    checks.number_in("window", window, -1e-12, 0.5, "(fraction of the step)")


def check_drive(workspace: JointWorkspace, motor: drive_model.Motor, gear: drive_model.Gearhead,
                supply_voltage: float, window: float = IMPACT_WINDOW) -> dict:
    """Checks one motor and gearhead on every joint's samples outside the impact window.

    Returns {"feasible", "reason", "joule_energy_J", "mass_kg", "min_voltage_margin_V",
    "rms_motor_torque_mNm", "max_motor_rpm", "walk_time_s", ...}; reason names the first failed check
    with numbers. ``walk_time_s``: how long the most loaded motor walks this gait from the ambient
    before its winding reaches the rated temperature (:func:`biped_jax.drives.thermal.walk_time`;
    null where it walks indefinitely, which is the thermal check passing).
    """
    _check_parts(workspace, motor, gear, supply_voltage, window)
    drive_model.check_ratio(gear.ratio)
    inside = workspace.outside_impacts(window)
    speed, torque = workspace.speed[inside], workspace.torque[inside]
    motor_torque = np.asarray(drive_model.motor_torque(torque, speed, gear.ratio, gear.efficiency))
    motor_speed = np.asarray(drive_model.motor_speed(speed, gear.ratio))
    margin = np.asarray(drive_model.voltage_margin(motor_torque, motor_speed, motor, supply_voltage))
    # the samples may be unevenly spaced (the gait's grid): time averages by the trapezoidal rule
    weights = trapezoid_weights(workspace.t)[:, None]
    all_torque = np.asarray(drive_model.motor_torque(workspace.torque, workspace.speed, gear.ratio, gear.efficiency))
    rms_motor = np.sqrt(np.sum(weights * all_torque**2, axis=0) / weights.sum())
    rms_output = np.sqrt(np.sum(weights * workspace.torque**2, axis=0) / weights.sum())
    joule = float(np.sum(weights * np.asarray(drive_model.joule_loss(all_torque, motor))))
    checks = [
        (margin.min() >= 0, f"voltage: needs {supply_voltage - margin.min():.1f} V > {supply_voltage:g} V supply "
                            f"(operating point above the speed-torque line)"),
        (rms_motor.max() <= motor.nominal_torque,
         f"thermal: RMS motor torque {rms_motor.max() / MNM:.1f} mNm > nominal {motor.nominal_torque / MNM:.1f} mNm"),
        (np.abs(torque).max() <= gear.intermittent_torque,
         f"gear: peak output torque {np.abs(torque).max():.2f} N m > intermittent {gear.intermittent_torque} N m"),
        (rms_output.max() <= gear.continuous_torque,
         f"gear: RMS output torque {rms_output.max():.2f} N m > continuous {gear.continuous_torque} N m"),
        (np.abs(motor_speed).max() <= gear.max_input_speed,
         f"gear: input speed {np.abs(motor_speed).max() / RPM:.0f} rpm > {gear.max_input_speed / RPM:.0f} rpm"),
        (np.abs(motor_speed).max() <= motor.max_speed,
         f"motor: speed {np.abs(motor_speed).max() / RPM:.0f} rpm > {motor.max_speed / RPM:.0f} rpm"),
    ]
    failed = [reason for ok, reason in checks if not ok]
    return {"feasible_without_thermal": all(r.startswith("thermal") for r in failed),
            "part": f"{motor.part} + {gear.part}", "motor": motor.part, "nominal_voltage_V": motor.nominal_voltage,
            "gearhead": gear.part, "ratio": gear.ratio, "feasible": not failed,
            "reason": failed[0] if failed else "all checks pass", "failed_checks": failed,
            "joule_energy_J": joule, "mass_kg": motor.mass + gear.mass,
            "min_voltage_margin_V": float(margin.min()), "rms_motor_torque_mNm": float(rms_motor.max() / MNM),
            "walk_time_s": _finite_or_none(thermal.walk_time(float(rms_motor.max()) / motor.torque_constant, motor,
                                                             thermal.load_thermal())),
            "max_motor_rpm": float(np.abs(motor_speed).max() / RPM)}


def _finite_or_none(value: float) -> float | None:
    return value if math.isfinite(value) else None


def joint_verdicts(motors, heads, solution, supply_voltage: float, catalogue: drive_model.Catalogue) -> list[dict]:
    """Per joint (H1, K1, H2, K2) the catalogue check of its own motor and gearhead (names, four of each)
    on a solved gait (:func:`check_drive` on that joint's samples: speed-torque line, thermal, gear and
    speed limits) and the thermal margin, 1 - RMS motor torque / nominal torque."""
    trajectory = solution.trajectory
    t = np.asarray(trajectory.t)
    speed, torque = np.asarray(trajectory.joint_speed), np.asarray(trajectory.u)
    verdicts = []
    for j, (motor, head) in enumerate(zip(motors, heads)):
        workspace = JointWorkspace(t, speed[:, [j]], torque[:, [j]], solution.step_time_s)
        motor_data = catalogue.motor(motor)
        check = check_drive(workspace, motor_data, catalogue.gearhead(head), supply_voltage)
        verdicts.append({"joint": ACTUATED[j], "motor": motor, "gearhead": head,
                         "feasible": check["feasible"], "feasible_without_thermal": check["feasible_without_thermal"],
                         "reason": check["reason"],
                         "thermal_margin": 1.0 - check["rms_motor_torque_mNm"] * MNM / motor_data.nominal_torque,
                         "min_voltage_margin_V": check["min_voltage_margin_V"], "walk_time_s": check["walk_time_s"]})
    return verdicts


def drive_summary(motor: str, gearhead: str, solution, supply_voltage: float | None = None,
                  catalogue: drive_model.Catalogue | None = None) -> dict:
    """One catalogue motor and gearhead at every joint checked on a solved gait (:func:`joint_verdicts`)
    at ``supply_voltage`` V (None: the catalogue's): {"passes_catalogue_check", "passes_without_thermal",
    "reasons" (the failed joints' first failed checks), "walk_time_s" (the joint that heats most; None:
    every joint walks indefinitely), "joints"}."""
    catalogue = catalogue or drive_model.load_catalogue()
    voltage = catalogue.supply_voltage if supply_voltage is None else float(supply_voltage)
    joints = joint_verdicts((motor,) * 4, (gearhead,) * 4, solution, voltage, catalogue)
    times = [j["walk_time_s"] for j in joints if j["walk_time_s"] is not None]
    return {"passes_catalogue_check": all(j["feasible"] for j in joints),
            "passes_without_thermal": all(j["feasible_without_thermal"] for j in joints),
            "reasons": sorted({j["reason"] for j in joints if not j["feasible"]}),
            "walk_time_s": min(times) if times else None, "joints": joints}


def select_drive(workspaces: list[JointWorkspace], catalogue: drive_model.Catalogue,
                 window: float = IMPACT_WINDOW) -> tuple[dict | None, list[dict]]:
    """Every winding x ratio checked on all given gaits (all must pass); feasible ones ranked by Joule
    energy per step summed over the gaits, then mass. A candidate's ``walk_time_s`` is that of the gait
    that heats it most (None: every gait indefinitely). Returns (best or None, all candidates)."""
    workspaces = checks.sequence("workspaces", workspaces, JointWorkspace, "JointWorkspace")
    if not isinstance(catalogue, drive_model.Catalogue):
        raise TypeError("catalogue must be a Catalogue (biped_jax.drives.model.load_catalogue()), got "
                        f"{type(catalogue).__name__}")
    candidates = []
    for motor in catalogue.motors.values():
        for gear in catalogue.gearheads.values():
            results = [check_drive(w, motor, gear, catalogue.supply_voltage, window) for w in workspaces]
            failed = [r["reason"] for r in results if not r["feasible"]]
            candidate = dict(results[0])
            candidate.update(feasible=not failed, reason=failed[0] if failed else "all checks pass",
                             feasible_without_thermal=all(r["feasible_without_thermal"] for r in results),
                             joule_energy_J=float(sum(r["joule_energy_J"] for r in results)),
                             min_voltage_margin_V=min(r["min_voltage_margin_V"] for r in results),
                             walk_time_s=min((r["walk_time_s"] for r in results if r["walk_time_s"] is not None),
                                             default=None))
            candidates.append(candidate)
    feasible = sorted((c for c in candidates if c["feasible"]), key=lambda c: (c["joule_energy_J"], c["mass_kg"]))
    return (feasible[0] if feasible else None), candidates


def longest_walk_without_thermal(candidates: list[dict]) -> dict | None:
    """Among the candidates that pass every check but the thermal one, the one that walks longest before
    its winding reaches the rated temperature (a candidate that walks indefinitely passes the thermal
    check too, and comes first); None if none passes."""
    loose = [c for c in candidates if c["feasible_without_thermal"]]
    return max(loose, key=lambda c: (math.inf if c["walk_time_s"] is None else c["walk_time_s"], -c["joule_energy_J"]),
               default=None)


def best_without_thermal(candidates: list[dict]) -> dict | None:
    """The paper's criterion (speed-torque line and gear limits, no thermal check): the best by Joule
    energy, then mass."""
    ok = sorted((c for c in candidates if c["feasible_without_thermal"]),
                key=lambda c: (c["joule_energy_J"], c["mass_kg"]))
    return ok[0] if ok else None


def plot_motor_workspace(workspace: JointWorkspace, catalogue: drive_model.Catalogue, ratios, title: str, path,
                         windings=("RE25-30V", "RE25-42V", "RE25-48V"), window: float = IMPACT_WINDOW) -> None:
    """Required motor torque against rpm (all joints, outside the impact window) with the speed-torque
    lines of the given windings at the supply voltage, one panel per gear ratio (paper Figs. 4-5)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    inside = workspace.outside_impacts(window)
    figure, axes = plt.subplots(1, len(ratios), figsize=(5 * len(ratios), 4.2), constrained_layout=True)
    for axis, ratio in zip(np.atleast_1d(axes), ratios):
        gear = catalogue.gearhead(f"GP32A-{ratio:g}")
        torque = np.abs(np.asarray(drive_model.motor_torque(workspace.torque, workspace.speed, gear.ratio,
                                                       gear.efficiency)))[inside]
        speed = np.abs(workspace.speed[inside]) * gear.ratio / RPM
        axis.scatter(torque.ravel() / MNM, speed.ravel(), s=6, alpha=0.6, label="required (all joints)")
        line_torque = np.linspace(0, max(torque.max() / MNM * 1.2, 50), 50)
        for part in windings:
            motor = catalogue.motor(part)
            line = np.asarray(drive_model.max_speed_at_torque(line_torque * MNM, motor, catalogue.supply_voltage)) / RPM
            axis.plot(line_torque, line, label=f"{part} at {catalogue.supply_voltage:g} V")
        axis.set_title(f"{title}, gear {gear.ratio:g}:1")
        axis.set_xlabel("motor torque [mNm]")
        axis.set_ylim(bottom=0)
        axis.grid(alpha=0.3)
    np.atleast_1d(axes)[0].set_ylabel("motor speed [rpm]")
    np.atleast_1d(axes)[0].legend(fontsize=8)
    outputs.save_figure(figure, path, dpi=110)
    plt.close(figure)




def save_workspaces(path, solutions) -> None:
    """Writes the joint demand of gait solutions (``GaitSolution``) to an .npz file."""
    from biped_jax.robots.planar_biped import ACTUATED_INDEX
    arrays = {}
    for s in solutions:
        tr = s.trajectory
        arrays[f"{s.name}_t"] = np.asarray(tr.t)
        arrays[f"{s.name}_speed"] = np.asarray(tr.qd)[:, ACTUATED_INDEX]
        arrays[f"{s.name}_torque"] = np.asarray(tr.u)
        arrays[f"{s.name}_meta"] = np.array([s.step_time_s, s.mass_kg, s.speed_mps,
                                             1.0 if s.status == "converged" else 0.0])
    outputs.save_npz(path, **arrays)


def load_workspaces(path) -> dict[str, tuple[JointWorkspace, dict]]:
    """Reads :func:`save_workspaces`' file: name -> (workspace, {mass_kg, speed_mps, converged}).

    Raises ValueError naming the file and the fault for anything else: not an ``.npz``, no gait in it,
    a gait with missing arrays, inconsistent shapes, or NaN or infinite samples."""
    try:
        arrays = outputs.read_npz(path)
    except ValueError as error:
        raise ValueError(f"{path}: not a gait file from `biped-jax reproduce` ({error})") from None
    names = [key[:-5] for key in arrays if key.endswith("_meta")]
    if not names:
        raise ValueError(f"{path}: no gait in it (expected NAME_meta, NAME_t, NAME_speed, NAME_torque arrays "
                         "as `biped-jax reproduce` writes them)")
    out = {}
    for name in names:
        missing = [f"{name}_{part}" for part in ("t", "speed", "torque") if f"{name}_{part}" not in arrays]
        if missing:
            raise ValueError(f"{path}: gait {name} lacks {', '.join(missing)}")
        meta, t, speed, torque = (np.asarray(arrays[f"{name}_{part}"], dtype=float)
                                  for part in ("meta", "t", "speed", "torque"))
        if meta.shape != (4,) or t.ndim != 1 or len(t) < 2 or speed.shape != (len(t), 4) \
                or torque.shape != (len(t), 4):
            raise ValueError(f"{path}: gait {name} has shapes meta {meta.shape}, t {t.shape}, speed {speed.shape}, "
                             f"torque {torque.shape}; expected (4,), (T,), (T, 4), (T, 4) with T >= 2")
        for part, values in (("meta", meta), ("t", t), ("speed", speed), ("torque", torque)):
            if not np.all(np.isfinite(values)):
                raise ValueError(f"{path}: gait {name} has {int(np.sum(~np.isfinite(values)))} NaN or "
                                 f"infinite values in {name}_{part}")
        step_time, mass, speed_mps, converged = meta
        if not (step_time > 0 and mass > 0 and speed_mps > 0):
            raise ValueError(f"{path}: gait {name} has step time {step_time} s, mass {mass} kg, speed "
                             f"{speed_mps} m/s; all must be positive")
        out[name] = (JointWorkspace(t=t, speed=speed, torque=torque, step_time=float(step_time)),
                     {"mass_kg": float(mass), "speed_mps": float(speed_mps), "converged": bool(converged)})
    return out
