"""Reports of gait solutions: the layout of the paper's Tables 4 and 5, results records, figures.

Every number is recomputed from the simulated trajectory (rates, accelerations and torques of the
rollout); units are converted to rpm only here, at the edge.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from biped_jax.drives.model import RPM
from biped_jax.gait.problem import CONSTRAINT_GROUPS
from biped_jax.robots.planar_biped import ACTUATED_INDEX
from biped_jax.gait.solver import GaitSolution
from biped_jax.report import outputs

JOINTS = ("H1", "K1", "H2", "K2")
#: Fraction of the step time at each end treated as "near an impact" when quoting spike-free maxima
#: for motor selection (the paper neglects the spikes near touchdown).
IMPACT_WINDOW = 0.05


def joint_statistics(solution: GaitSolution, impact_window: float = IMPACT_WINDOW) -> dict:
    """Per joint: mean and max |velocity| (rpm), max |acceleration| (rad/s^2), mean and max |torque|
    (N m), mean and max |power| (W), and the maxima outside ``impact_window`` x t_f of either end."""
    tr = solution.trajectory
    speed = np.abs(np.asarray(tr.qd)[:, ACTUATED_INDEX])
    acceleration = np.abs(np.asarray(tr.qdd)[:, ACTUATED_INDEX])
    torque = np.abs(np.asarray(tr.u))
    power = np.abs(speed * torque)
    # time averages by the trajectory's own quadrature (the grid is finer near the impacts)
    weights = np.asarray(tr.weights) / solution.step_time_s
    s = np.asarray(tr.t) / solution.step_time_s
    inside = (s >= impact_window) & (s <= 1 - impact_window)
    stats = {}
    for k, joint in enumerate(JOINTS):
        stats[joint] = {
            "vel_mean_rpm": float(weights @ speed[:, k] / RPM), "vel_max_rpm": float(speed[:, k].max() / RPM),
            "acc_max": float(acceleration[:, k].max()),
            "torque_mean": float(weights @ torque[:, k]), "torque_max": float(torque[:, k].max()),
            "power_mean": float(weights @ power[:, k]), "power_max": float(power[:, k].max()),
            "vel_max_rpm_outside_impacts": float(speed[inside, k].max() / RPM),
            "torque_max_outside_impacts": float(torque[inside, k].max()),
            "power_max_outside_impacts": float(power[inside, k].max()),
        }
    return stats


def results_record(solution: GaitSolution) -> dict:
    """The JSON record of one solution (the layout of results.json)."""
    tr = solution.trajectory
    return {
        "model": solution.name, "mass_kg": round(solution.mass_kg, 6), "speed_mps": solution.speed_mps,
        "power_limit_W": solution.power_limit_W, "step_length_m": solution.step_length_m,
        "status": solution.status, "cost": solution.cost, "cost_per_metre": solution.energy_per_metre,
        "t_f": solution.step_time_s,
        "max_violation": solution.max_violation,
        "violations": {name: {"value": value, "unit": CONSTRAINT_GROUPS[name][1]}
                       for name, value in solution.violations.items()},
        "stationarity": solution.stationarity, "outer_iterations": solution.outer_iterations,
        "gradients": solution.gradients, "wall_time_s": solution.wall_time_s,
        "joints": joint_statistics(solution),
        "max_vertical_force_N": float(np.max(np.asarray(tr.ground_force)[:, 1])),
        "impact_impulse_Ns": np.asarray(tr.touchdown.impulse).tolist(),
        "impact_window_fraction": IMPACT_WINDOW,
        "refinement": solution.refinement,
        "starts": solution.starts,
        "decision_vector": np.asarray(solution.x).tolist(),
    }


def markdown_table(solution: GaitSolution) -> str:
    """One model in the layout of the paper's Tables 4 and 5."""
    stats = joint_statistics(solution)
    rows = [("Velocities", None, None), ("Aver. (rpm)", "vel_mean_rpm", "{:.1f}"),
            ("Max. (rpm)", "vel_max_rpm", "{:.1f}"), ("Accelerations", None, None),
            ("Max. (rad/s^2)", "acc_max", "{:.0f}"), ("Torques", None, None),
            ("Aver. (Nm)", "torque_mean", "{:.3g}"), ("Max. (Nm)", "torque_max", "{:.3g}"),
            ("Power", None, None), ("Aver. (W)", "power_mean", "{:.3g}"), ("Max. (W)", "power_max", "{:.3g}")]
    lines = [f"### {solution.name}: {solution.mass_kg:.0f} kg, {solution.speed_mps} m/s, "
             f"M_W = {solution.power_limit_W:g} W: {solution.status}", "",
             "| | H1 | K1 | H2 | K2 |", "|---|---|---|---|---|"]
    for label, key, fmt in rows:
        if key is None:
            lines.append(f"| **{label}** | | | | |")
        else:
            lines.append(f"| {label} | " + " | ".join(fmt.format(stats[j][key]) for j in JOINTS) + " |")
    force = float(np.max(np.asarray(solution.trajectory.ground_force)[:, 1]))
    lines += ["", f"J = {solution.cost:.4g} N^2 m^2 s, t_f = {solution.step_time_s:.4g} s, "
              f"L = {solution.step_length_m:g} m, max. vertical contact force = {force:.1f} N, "
              f"largest violation = {solution.max_violation:.1e} (own units), "
              f"{solution.gradients} gradients", ""]
    if solution.refinement:
        check = solution.refinement
        lines += [f"Refinement check ({check['steps']} steps, same decision vector): J = {check['cost']:.4g} "
                  f"({100 * check['cost_change']:.3f} % change), power {100 * check['power_margin_fraction']:.2f} % "
                  f"of M_W over the limit at most, " + ("passed" if check["passed"] else
                                                         "FAILED: " + ", ".join(check["failed"])), ""]
    if solution.starts:
        costs = [f"{row['cost']:.4g} ({row['status']})" for row in solution.starts]
        lines += [f"Starts (coarse space): {', '.join(costs)}", ""]
    return "\n".join(lines)


STYLES = {"M1": "-", "M2": "-.", "M3": "--", "M4": ":"}


def plot_figure_2(solutions: list[GaitSolution], path: Path,
                  title: str = "Optimal steps (M1 solid, M2 dash-dot, M3 dashed, M4 dotted)") -> None:
    """Joint angle, velocity, torque and power over the step, models overlaid (paper Fig. 2)."""
    plt = outputs.pyplot()
    figure, axes = plt.subplots(4, 4, figsize=(14, 11), sharex=True, constrained_layout=True)
    for solution in solutions:
        tr = solution.trajectory
        t = np.asarray(tr.t)
        q = np.asarray(tr.q)[:, ACTUATED_INDEX]
        qd = np.asarray(tr.qd)[:, ACTUATED_INDEX]
        u = np.asarray(tr.u)
        style = STYLES.get(solution.name, "-")
        for k, joint in enumerate(JOINTS):
            axes[0, k].plot(t, q[:, k], style, label=solution.name)
            axes[1, k].plot(t, qd[:, k] / RPM, style)
            axes[2, k].plot(t, u[:, k], style)
            axes[3, k].plot(t, qd[:, k] * u[:, k], style)
            axes[0, k].set_title(joint)
    for row, label in enumerate(("angle [rad]", "velocity [rpm]", "torque [N m]", "power [W]")):
        axes[row, 0].set_ylabel(label)
    for axis in axes[3]:
        axis.set_xlabel("time [s]")
    for axis in axes.flat:
        axis.grid(alpha=0.3)
    axes[0, 0].legend()
    figure.suptitle(title)
    outputs.save_figure(figure, path, dpi=110)
    plt.close(figure)


def plot_figure_3(solutions: list[GaitSolution], path: Path) -> None:
    """|torque| against |rpm| per joint (paper Fig. 3)."""
    plt = outputs.pyplot()
    figure, axes = plt.subplots(1, 4, figsize=(15, 4), constrained_layout=True)
    for solution in solutions:
        tr = solution.trajectory
        speed = np.abs(np.asarray(tr.qd)[:, ACTUATED_INDEX]) / RPM
        torque = np.abs(np.asarray(tr.u))
        for k, joint in enumerate(JOINTS):
            axes[k].plot(speed[:, k], torque[:, k], STYLES.get(solution.name, "-"), marker=".",
                         markersize=3, label=solution.name)
            axes[k].set_title(joint)
            axes[k].set_xlabel("|velocity| [rpm]")
    axes[0].set_ylabel("|torque| [N m]")
    for axis in axes:
        axis.grid(alpha=0.3)
    axes[0].legend()
    outputs.save_figure(figure, path, dpi=110)
    plt.close(figure)


def plot_convergence(solutions: list[GaitSolution], path: Path) -> None:
    """Scaled constraint violation and cost against gradient evaluations, one line per model."""
    plt = outputs.pyplot()
    figure, (left, right) = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    for solution in solutions:
        gradients = [row["gradients"] for row in solution.history]
        left.semilogy(gradients, [max(row["violation"], 1e-12) for row in solution.history], marker="o",
                      markersize=3, label=solution.name)
        right.plot(gradients, [row["cost"] for row in solution.history], marker="o", markersize=3,
                   label=solution.name)
    left.set_title("largest scaled constraint violation")
    right.set_title("cost J [N^2 m^2 s]")
    for axis in (left, right):
        axis.set_xlabel("gradient evaluations")
        axis.grid(alpha=0.3)
        axis.legend()
    outputs.save_figure(figure, path, dpi=110)
    plt.close(figure)
