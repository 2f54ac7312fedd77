"""The drive-train part of the paper's study (``biped-jax reproduce`` and ``biped-jax drives``): Table 6,
the selection of a winding and a ratio per mass class, the paper's choice checked, Figs. 4-5, from the
study's gait trajectories (:func:`biped_jax.drives.selection.load_workspaces`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from biped_jax.drives import model as drive_model
from biped_jax.drives.selection import (
    IMPACT_WINDOW,
    JointWorkspace,
    best_without_thermal,
    longest_walk_without_thermal,
    plot_motor_workspace,
    requirements,
    select_drive,
)
from biped_jax.report import outputs

#: Which gaits each mass class's drive must serve (paper Table 3).
MASS_CLASS_GAITS = {"12kg": ("M1", "M2"), "18kg": ("M3", "M4")}
#: The paper's drive: the 42 V winding of the RE 25 on the 66:1 GP 32 A.
PAPER_CHOICE = ("RE25-42V", "GP32A-66.22")


def _walk(seconds: float | None) -> str:
    """How long a drive walks the study's gaits from 25 C before its winding reaches the rated
    temperature (:mod:`biped_jax.drives.thermal`), in words."""
    if seconds is None:
        return "walks indefinitely"
    return f"walks {seconds / 60:.1f} min from 25 C before its winding reaches its rated temperature"


def run_drive_study(out, gaits: dict[str, tuple[JointWorkspace, dict]]) -> dict:
    """Table 6, the selection per mass class, the paper's choice checked, Figs. 4-5; writes
    drives.json, drives.md, fig4_motor_M2.png and fig5_motor_M4.png into ``out``."""
    out = Path(out)
    catalogue = drive_model.load_catalogue()
    report = []
    lines = ["# Drive train (Table 6 and the motor selection)", "",
             f"Supply {catalogue.supply_voltage:g} V; samples within {IMPACT_WINDOW:.0%} of t_f of either "
             "end of the step are left out (the paper's neglected spikes), their maxima shown in brackets.", ""]
    for mass_class, names in MASS_CLASS_GAITS.items():
        available = [n for n in names if n in gaits and gaits[n][1]["converged"]]
        if not available:
            report.append({"mass_class": mass_class, "error": "no converged gait"})
            continue
        workspaces = [gaits[n][0] for n in available]
        merged = JointWorkspace(t=np.concatenate([w.t / w.step_time for w in workspaces]),
                                speed=np.concatenate([w.speed for w in workspaces]),
                                torque=np.concatenate([w.torque for w in workspaces]), step_time=1.0)
        table6 = requirements(merged)
        best, candidates = select_drive(workspaces, catalogue)
        paper = next(c for c in candidates if (c["motor"], c["gearhead"]) == PAPER_CHOICE)
        loose = best_without_thermal(candidates)
        enduring = longest_walk_without_thermal(candidates)
        slow_best, slow_candidates = select_drive(workspaces[:1], catalogue)
        slow_paper = next(c for c in slow_candidates if (c["motor"], c["gearhead"]) == PAPER_CHOICE)
        entry = {"mass_class": mass_class, "mass_kg": gaits[available[0]][1]["mass_kg"], "gaits": available,
                 "requirements": table6,
                 "recommended": None if best is None else {k: best[k] for k in (
                     "part", "motor", "gearhead", "nominal_voltage_V", "ratio", "joule_energy_J", "mass_kg")},
                 "paper_choice": {k: paper[k] for k in ("part", "feasible", "feasible_without_thermal", "reason",
                                                        "joule_energy_J", "walk_time_s")},
                 "recommended_without_thermal_check": None if loose is None else loose["part"],
                 "longest_walk_without_thermal_check": None if enduring is None else {
                     k: enduring[k] for k in ("part", "walk_time_s", "joule_energy_J", "mass_kg")},
                 f"recommended_for_{available[0]}_only": None if slow_best is None else slow_best["part"],
                 f"paper_choice_for_{available[0]}_only": {k: slow_paper[k] for k in ("feasible", "reason")},
                 "candidates": [{k: c[k] for k in ("part", "ratio", "nominal_voltage_V", "feasible",
                                                   "feasible_without_thermal", "reason", "joule_energy_J", "mass_kg",
                                                   "walk_time_s")}
                                for c in candidates]}
        report.append(entry)
        r = table6
        lines += [f"## {mass_class} ({', '.join(available)})", "",
                  "| Table 6 | value |", "|---|---|",
                  "| Operational torque | {:.2f}-{:.2f} N m |".format(*r["operational_torque_Nm"]),
                  f"| Maximum torque | {r['max_torque_Nm']:.2f} N m ({r['max_torque_with_impacts_Nm']:.2f}) |",
                  f"| Operational rpm | {r['operational_rpm'][0]:.0f}-{r['operational_rpm'][1]:.0f} rpm |",
                  f"| Maximum rpm | {r['max_rpm']:.0f} rpm ({r['max_rpm_with_impacts']:.0f}) |",
                  f"| Maximum power | {r['max_power_W']:.1f} W ({r['max_power_with_impacts_W']:.1f}) |", "",
                  f"- Recommended (all checks): **{best['part'] if best else 'none feasible'}**"
                  + (f", Joule energy {best['joule_energy_J']:.2f} J per step over the gaits" if best else ""),
                  f"- Paper's criterion (speed-torque line and gear limits, no thermal check): "
                  f"**{loose['part'] if loose else 'none feasible'}**",
                  f"- The paper's 42 V + 66:1: {'feasible' if paper['feasible'] else 'fails: ' + paper['reason']}"
                  f" (under the paper's criterion: {'passes' if paper['feasible_without_thermal'] else 'fails'});"
                  f" {_walk(paper['walk_time_s'])}",
                  "- The longest walk among the pairs passing the paper's criterion: "
                  + ("none passes" if enduring is None
                     else f"**{enduring['part']}**, {_walk(enduring['walk_time_s'])}"),
                  f"- For {available[0]} alone: {slow_best['part'] if slow_best else 'none feasible'} "
                  f"(the paper's choice: {'feasible' if slow_paper['feasible'] else slow_paper['reason']})", "",
                  f"{sum(c['feasible'] for c in candidates)} of {len(candidates)} winding x ratio pairs pass.", ""]
    outputs.write_json(out / "drives.json", report)
    outputs.write_text(out / "drives.md", "\n".join(lines) + "\n")
    for name, figure in (("M2", "fig4_motor_M2.png"), ("M4", "fig5_motor_M4.png")):
        if name in gaits:
            plot_motor_workspace(gaits[name][0], catalogue, (51, 66.22, 79), name, out / figure)
    return {"drives": report}
