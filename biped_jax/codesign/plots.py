"""Figures of the co-design studies (from the JSON-ready results of ``biped_jax.studies.codesign``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from biped_jax.report import outputs

CONVERGED = "converged"


def plot_mass_scaling(study: dict, path: Path) -> None:
    """Peak joint power and Joule energy per metre against total mass, log-log, with the fits."""
    plt = outputs.pyplot()
    figure, axes = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    keys = (("peak_joint_power_W", "peak_power_exponent", "peak joint power [W]"),
            ("joule_energy_per_metre_J_per_m", "joule_per_metre_exponent", "Joule energy per metre [J/m]"))
    for axis, (key, fit_key, label) in zip(axes, keys):
        for colour, (speed, fit) in zip(("C0", "C1"), study["fits"].items()):
            rows = [r for r in study["designs"] if f"{r['speed_mps']}" == speed]
            ok = [r for r in rows if r["status"] == CONVERGED]
            mass = np.array([r["total_mass_kg"] for r in ok])
            value = np.array([r[key] for r in ok])
            axis.loglog(mass, value, "o", color=colour,
                        label=f"{speed} m/s: ~ M^{fit[fit_key]:.2f}" if ok else f"{speed} m/s")
            if len(ok) >= 2:
                line = np.exp(np.polyval(np.polyfit(np.log(mass), np.log(value), 1), np.log(mass)))
                axis.loglog(mass, line, "-", color=colour, alpha=0.6)
            failed = [r for r in rows if r["status"] != CONVERGED]
            if failed:
                axis.loglog([r["total_mass_kg"] for r in failed], [r[key] for r in failed], "x", color=colour,
                            label=f"{speed} m/s: not converged")
        axis.set_xlabel("total mass [kg]")
        axis.set_ylabel(label)
        axis.grid(alpha=0.3, which="both")
        axis.legend(fontsize=8)
    figure.suptitle("(a) requirement against robot mass: RE 25 42 V + GP 32 A 66:1, no power or voltage limit")
    outputs.save_figure(figure, path, dpi=120)
    plt.close(figure)


def plot_speed_limits(study: dict, path: Path) -> None:
    """Highest feasible speed against the gear ratio."""
    plt = outputs.pyplot()
    figure, axis = plt.subplots(figsize=(7, 4.2), constrained_layout=True)
    ratios = np.array(study["ratios"])
    speed = np.array(study["max_speed_mps"], dtype=float)
    bracket = np.array(study["bracket_mps"])
    axis.semilogx(ratios, speed, "o-", label="highest converged speed")
    axis.fill_between(ratios, bracket[:, 0], bracket[:, 1], alpha=0.2, label="bisection bracket")
    axis.set_xlabel("gear ratio N")
    axis.set_ylabel("speed [m/s]")
    axis.set_title(f"(b) {study['winding']} at {study['supply_voltage_V']:g} V, M_W = {study['power_limit_W']:g} W, "
                   "step 0.2 m")
    axis.grid(alpha=0.3, which="both")
    axis.legend(fontsize=8)
    outputs.save_figure(figure, path, dpi=120)
    plt.close(figure)


def plot_pareto(study: dict, path: Path) -> None:
    """Joule energy per metre against robot mass, one colour per winding, the Pareto front joined."""
    plt = outputs.pyplot()
    figure, axis = plt.subplots(figsize=(7.5, 4.8), constrained_layout=True)
    designs = study["designs"]
    windings = list(dict.fromkeys(r["winding"] for r in designs))
    for colour, winding in enumerate(windings):
        rows = [r for r in designs if r["winding"] == winding]
        ok = [r for r in rows if r["status"] == CONVERGED]
        axis.plot([r["total_mass_kg"] for r in ok], [r["joule_energy_per_metre_J_per_m"] for r in ok], "o",
                  color=f"C{colour}", label=winding)
        for r in ok:
            axis.annotate(f"{r['ratio'][0]:g}", (r["total_mass_kg"], r["joule_energy_per_metre_J_per_m"]),
                          fontsize=6, xytext=(3, 2), textcoords="offset points")
        failed = [r for r in rows if r["status"] != CONVERGED]
        if failed:
            axis.plot([r["total_mass_kg"] for r in failed], np.zeros(len(failed)), "x", color=f"C{colour}",
                      label=f"{winding}: no gait ({len(failed)})")
    front = sorted((designs[i] for i in study["pareto"]), key=lambda r: r["total_mass_kg"])
    axis.plot([r["total_mass_kg"] for r in front], [r["joule_energy_per_metre_J_per_m"] for r in front], "k-",
              lw=1, label="Pareto front")
    axis.set_xlabel("robot mass [kg]")
    axis.set_ylabel("Joule energy per metre [J/m]")
    axis.set_title("(c) catalogue ratios x windings at 0.555 m/s, 20 W, 38 V (labels: ratio)")
    axis.grid(alpha=0.3)
    axis.legend(fontsize=7)
    outputs.save_figure(figure, path, dpi=120)
    plt.close(figure)


def best_by_iteration(study: dict, problem: str) -> np.ndarray:
    """The lowest converged Joule energy (J) of ``problem``'s designs after each co-design iteration
    (NaN where none converged), (iterations + 1,)."""
    joule = np.array(study["path"]["joule_J"], dtype=float)  # (iterations + 1, B)
    status = np.array(study["path"]["status"])
    mine = np.array([d["problem"] == problem for d in study["designs"]])
    masked = np.where((status == CONVERGED) & mine[None], joule, np.inf)
    best = masked.min(axis=1)
    return np.where(np.isfinite(best), best, np.nan)


def plot_optimisation(study: dict, path: Path) -> None:
    """Study (d): per problem the best converged energy against the gait solves spent, the gradient
    method against CMA-ES; every design's path in (knee ratio, legs' share of the structure mass), in
    (hip ratio, hip winding's torque constant) and of the knee drives' place over the iterations."""
    plt = outputs.pyplot()
    figure, axes = plt.subplots(1, 4, figsize=(22, 4.6), constrained_layout=True)
    problems = [p["name"] for p in study["problems"]]
    colours = dict(zip(problems, ("tab:blue", "tab:red", "tab:green", "tab:purple")))
    starts = study["starts_per_problem"]
    for name in problems:
        best = best_by_iteration(study, name)
        axes[0].semilogy(starts * np.arange(1, len(best) + 1), best, "-o", ms=4, color=colours[name],
                         label=f"{name}: gradient (Adam, envelope theorem)")
        baseline = study.get("baseline", {}).get("per_problem", {}).get(name)
        if baseline:
            energies = np.array([np.nan if e is None else e for e in baseline["best_energy_J"]], dtype=float)
            axes[0].semilogy(baseline["solves"], energies, "--s", ms=4, color=colours[name], alpha=0.7,
                             label=f"{name}: CMA-ES")
        paper = study["per_problem"][name]["paper_design"]
        if paper["status"] == CONVERGED:
            axes[0].axhline(paper["joule_energy_J"], color=colours[name], lw=0.8, ls=":")
    axes[0].set_xlabel("gait solves")
    axes[0].set_ylabel("best Joule energy per step [J] (dotted: the paper's design)")
    axes[0].set_title(f"(d) {starts} starts per problem, converged gaits")
    axes[0].grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7)
    ratios = np.array(study["path"]["ratios"])  # (iterations + 1, B, 4)
    legs = np.array(study["path"]["mass_splits"])[:, :, 0]  # (iterations + 1, B)
    constants = np.array(study["path"]["torque_constants_Nm_per_A"]) * 1e3  # mN m/A
    for b, design in enumerate(study["designs"]):
        colour = colours[design["problem"]]
        for axis, x, y in ((axes[1], ratios[:, b, 1], legs[:, b]), (axes[2], ratios[:, b, 0], constants[:, b, 0])):
            axis.semilogx(x, y, "-", lw=0.8, alpha=0.6, color=colour)
            axis.plot(x[-1], y[-1], ".", ms=5, color=colour if design["status"] == CONVERGED else "0.6")
    axes[1].set_xlabel("knee gear ratio N (K1)")
    axes[1].set_ylabel("legs' share of the structure mass")
    axes[1].set_title("every design's path (dot: where it ended; grey: no converged gait)")
    axes[2].set_xlabel("hip gear ratio N (H1)")
    axes[2].set_ylabel("hip winding's torque constant k_t [mN m/A]")
    axes[2].set_title("ratio and winding (flat in k_t while the voltage limit is inactive)")
    offsets = study["path"].get("knee_drive_offsets")
    if offsets:
        offsets = np.array(offsets)  # (iterations + 1, B)
        for b, design in enumerate(study["designs"]):
            axes[3].plot(offsets[:, b], "-", lw=0.8, alpha=0.6, color=colours[design["problem"]])
    axes[3].set_xlabel("co-design iteration")
    axes[3].set_ylabel("knee drives' place (0 at the knee, 1 at the hip)")
    axes[3].set_title("where the knee drives sit")
    for axis in axes[1:]:
        axis.grid(alpha=0.3, which="both")
    outputs.save_figure(figure, path, dpi=120)
    plt.close(figure)
