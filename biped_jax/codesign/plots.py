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


def plot_optimisation(study: dict, path: Path) -> None:
    """Joule energy of every start over the iterations, the ratios of the best design, and every
    design's path in (knee ratio, legs' share of the mass)."""
    plt = outputs.pyplot()
    splits = study["path"].get("mass_splits")
    figure, axes = plt.subplots(1, 3 if splits else 2, figsize=(16 if splits else 11, 4.2), constrained_layout=True)
    joule = np.array(study["path"]["joule_J"], dtype=float)  # (iterations + 1, B)
    status = np.array(study["path"]["status"])
    masked = np.where(status == CONVERGED, joule, np.nan)
    axes[0].plot(masked, "-o", ms=3, alpha=0.7)
    axes[0].set_xlabel("co-design iteration")
    axes[0].set_ylabel("Joule energy per step [J]")
    axes[0].set_title("(d) 16 starts (converged gaits)")
    axes[0].grid(alpha=0.3)
    ratios = np.array(study["path"]["ratios"])  # (iterations + 1, B, 4)
    final = masked[-1]
    if np.any(np.isfinite(final)):
        best = int(np.nanargmin(final))
        for k, joint in enumerate(("H1", "K1", "H2", "K2")):
            axes[1].semilogy(ratios[:, best, k], "-o", ms=3, label=joint)
        axes[1].set_title(f"gear ratios of the best start ({final[best]:.3g} J)")
        axes[1].legend(fontsize=8)
    axes[1].set_xlabel("co-design iteration")
    axes[1].set_ylabel("gear ratio N")
    axes[1].grid(alpha=0.3, which="both")
    if splits:
        legs = np.array(splits)[:, :, 0]  # (iterations + 1, B)
        for b in range(legs.shape[1]):
            axes[2].semilogx(ratios[:, b, 1], legs[:, b], "-", lw=1, alpha=0.7)
            axes[2].plot(ratios[-1, b, 1], legs[-1, b], "k.", ms=5)
        axes[2].set_xlabel("knee gear ratio N (K1)")
        axes[2].set_ylabel("legs' share of the structure mass")
        axes[2].set_title("every design's path (dot: where it ended)")
        axes[2].grid(alpha=0.3, which="both")
    outputs.save_figure(figure, path, dpi=120)
    plt.close(figure)
