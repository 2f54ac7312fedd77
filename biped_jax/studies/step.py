"""``biped-jax step``: one heuristic PD-controlled step of the sagittal biped per mass class
(:mod:`biped_jax.gait.heuristic_step`), with its touchdown, energy lost at the impact, a table and a figure.
A check of the hybrid step's physics from a plain controller, not an optimal gait (that is
``biped-jax reproduce``)."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from biped_jax.report import outputs

MASS_CLASSES = ("12kg", "18kg")


def _energies(pinned, floating, q, qd, floating_q, floating_qd):
    """Mechanical energy (J) of the pinned model before the impact and of the floating one after it: one
    compiled program for every mass class (MJX run op by op compiles every operation alone)."""
    from biped_jax.dynamics import mjx_biped
    return (mjx_biped.mechanical_energy(pinned, q, qd),
            mjx_biped.mechanical_energy(floating, floating_q, floating_qd))


def step_report(mass_class: str, gait) -> tuple[dict, dict]:
    """Simulates one heuristic step of a mass class; returns (JSON-ready summary, arrays for plots)."""
    import jax

    from biped_jax.dynamics import mjx_biped, planar_chain
    from biped_jax.gait import heuristic_step
    from biped_jax.robots import planar_biped

    biped = mjx_biped.load_planar_biped(mass_class)
    # the closed-form chain (equal to MJX to rounding; the chain's structure is the same for every mass
    # class, read here where the model is concrete); numpy from here: no op-by-op programs
    chain = planar_chain.PlanarChain.from_model(biped.pinned)
    trajectory, dt, index, impact, foot, foot_velocity = jax.tree.map(np.asarray, jax.jit(
        functools.partial(heuristic_step.simulate_step, gait=gait, chain=chain))(biped))
    index, dt = int(index), float(dt)
    pinned = mjx_biped.with_timestep(biped.pinned, dt)
    end = index if index > 0 else len(trajectory.u)
    u = trajectory.u[:end]
    summary = {
        "mass_class": mass_class,
        "mass_kg": float(np.sum(biped.pinned.body_mass)),
        "controller": {"stiffness_Nm_per_rad": gait.stiffness, "damping_Nms_per_rad": gait.damping},
        "nominal_step_time_s": gait.step_time,
        "timestep_s": dt,
        "touched_down": index > 0,
        "finite": bool(np.all(np.isfinite(trajectory.q))),
        "cost_int_u2_N2m2s": float(np.sum(u**2) * dt),
        "max_abs_torque_Nm": dict(zip(planar_biped.ACTUATED, np.abs(u).max(axis=0).tolist())),
        "max_vertical_force_N": float(np.max(trajectory.ground_force[:end, 1])),
        "min_vertical_force_N": float(np.min(trajectory.ground_force[:end, 1])),
    }
    if index > 0:
        before, after_floating = map(float, jax.jit(_energies)(pinned, biped.floating, trajectory.q[index],
                                                      trajectory.qd[index], impact.floating_q,
                                                      impact.floating_qd_after))
        summary.update({
            "touchdown_time_s": index * dt,
            "step_length_m": float(foot[index, 0]),
            "average_speed_mps": float(foot[index, 0] / (index * dt)),
            "impact_impulse_Ns": impact.impulse.tolist(),
            "old_stance_foot_velocity_after_impact_mps": impact.old_stance_foot_velocity.tolist(),
            "energy_before_impact_J": before,
            "energy_lost_at_impact_J": before - after_floating,
        })
    arrays = {"t": dt * np.arange(len(trajectory.q)), "q": np.asarray(trajectory.q),
              "u": np.asarray(trajectory.u), "force": np.asarray(trajectory.ground_force),
              "foot": np.asarray(foot), "end": end}
    return summary, arrays


def plot_steps(arrays: dict[str, dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from biped_jax.robots.planar_biped import ACTUATED, PINNED_COORDINATES

    figure, axes = plt.subplots(2, 2, figsize=(11, 7), constrained_layout=True)
    for (mass_class, a), style in zip(arrays.items(), ("-", "--")):
        end, t = a["end"], a["t"]
        for k, name in enumerate(PINNED_COORDINATES):
            axes[0, 0].plot(t[: end + 1], a["q"][: end + 1, k], style, color=f"C{k}",
                            label=f"{name} ({mass_class})")
        for k, name in enumerate(ACTUATED):
            axes[0, 1].plot(t[:end], a["u"][:end, k], style, color=f"C{k}", label=f"{name} ({mass_class})")
        axes[1, 0].plot(t[:end], a["force"][:end, 1], style, color="C0", label=f"F_z ({mass_class})")
        axes[1, 0].plot(t[:end], a["force"][:end, 0], style, color="C1", label=f"F_x ({mass_class})")
        axes[1, 1].plot(a["foot"][: end + 1, 0], a["foot"][: end + 1, 1], style, label=mass_class)
    titles = ("joint angles [rad]", "torques [N m]", "stance ground force [N]", "swing foot z vs x [m]")
    for axis, title in zip(axes.flat, titles):
        axis.set_title(title)
        axis.grid(alpha=0.3)
        axis.legend(fontsize=7, ncol=2)
    for axis in axes.flat[:3]:
        axis.set_xlabel("time [s]")
    outputs.save_figure(figure, path, dpi=120)
    plt.close(figure)


def markdown_table(summaries: list[dict]) -> str:
    rows = [("mass [kg]", "mass_kg", "{:.3f}"), ("touched down", "touched_down", "{}"),
            ("touchdown time [s]", "touchdown_time_s", "{:.3f}"), ("step length [m]", "step_length_m", "{:.3f}"),
            ("average speed [m/s]", "average_speed_mps", "{:.3f}"),
            ("J = int u^2 dt [N^2 m^2 s]", "cost_int_u2_N2m2s", "{:.2f}"),
            ("max F_z [N]", "max_vertical_force_N", "{:.1f}"), ("min F_z [N]", "min_vertical_force_N", "{:.1f}"),
            ("energy lost at impact [J]", "energy_lost_at_impact_J", "{:.3f}")]
    header = "| quantity | " + " | ".join(s["mass_class"] for s in summaries) + " |"
    lines = [header, "|---|" + "---|" * len(summaries)]
    for label, key, fmt in rows:
        cells = [fmt.format(s[key]) if key in s else "-" for s in summaries]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_report(out: Path, summaries: list[dict], arrays: dict[str, dict], wall_time_s: float) -> dict:
    """results.json, heuristic_step.md and heuristic_step.png of the simulated steps (``arrays``: per
    mass class, from :func:`step_report`)."""
    results = {"study": "one heuristic PD-controlled step per mass class (a physics check, not an optimal gait)",
               "wall_time_s": wall_time_s, "steps": summaries}
    outputs.write_json(out / "results.json", results)
    outputs.write_text(out / "heuristic_step.md", "# One heuristic walking step\n\n" + markdown_table(summaries))
    plot_steps(arrays, out / "heuristic_step.png")
    return results
