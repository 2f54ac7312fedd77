"""One gait problem of the user's own (``biped-jax solve``): a mass class, a speed, a step length and a
power limit, and optionally catalogue drives (motor, gearhead, supply voltage), solved as the study
solves each of its models (every start family in the 4x coarser space, the cheapest carried into the
fine one; :func:`biped_jax.gait.multistart.solve_multistart`), optionally with its smallest power limit;
the study's files for that one problem, and with drives their catalogue check per joint."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

from biped_jax.gait import multistart
from biped_jax.gait import problem as gait_problem
from biped_jax.gait import report as gait_report
from biped_jax.report import outputs
from biped_jax.studies import paper


#: The step lengths the fastest gait may take when none are given (m): the study's 0.2 m and the
#: range its optimal steps span at 0.4-0.6 m/s (``--free-step-length`` on M1-M4).
FASTEST_STEP_BOUNDS = (0.1, 0.35)


@dataclasses.dataclass(frozen=True)
class Problem:
    """The problem ``biped-jax solve`` poses.

    Attributes:
      mass_class: "12kg" or "18kg" (the paper's bipeds). speed: m/s. step_length: m. power_limit: W,
        the bound on every actuated joint's |qdot u|.
      motor, gearhead: catalogue names (``biped_jax/data/maxon_catalogue.json``, such as "RE25-42V",
        "GP32A-66.22") of the drive at every joint; None for both: ideal drives (the paper's problem,
        J the joint-torque energy); one of them given: the other is the paper's (RE 25 42 V, 66:1). With
        a drive the robot carries its masses and reflected inertia, J is the motors' Joule energy and
        the gait keeps within the supply voltage.
      supply_voltage: V, with a drive only (None: the catalogue's).
    """

    mass_class: str = "12kg"
    speed: float = 0.555
    step_length: float = 0.2
    power_limit: float = 20.0
    motor: str | None = None
    gearhead: str | None = None
    supply_voltage: float | None = None

    @property
    def has_drive(self) -> bool:
        return self.motor is not None or self.gearhead is not None

    @property
    def parts(self) -> tuple[str, str]:
        """(motor, gearhead) catalogue names of the drive, the paper's where one is not given."""
        from biped_jax.codesign import REFERENCE_GEARHEAD, REFERENCE_MOTOR
        return self.motor or REFERENCE_MOTOR, self.gearhead or REFERENCE_GEARHEAD

    @property
    def name(self) -> str:
        name = f"{self.mass_class}, {self.speed:g} m/s, L = {self.step_length:g} m, M_W = {self.power_limit:g} W"
        return name + (", {} + {}".format(*self.parts) if self.has_drive else "")

    def model(self) -> gait_problem.GaitModel:
        """The gait problem (ValueError naming a bad value, an unknown part or a voltage without a drive,
        before anything compiles)."""
        if not self.has_drive:
            if self.supply_voltage is not None:
                raise ValueError(f"supply_voltage {self.supply_voltage!r} applies to a drive: give a motor or a "
                                 "gearhead")
            return gait_problem.gait_model(self.mass_class, self.speed, self.power_limit, self.step_length)
        from biped_jax import codesign
        design = codesign.catalogue_design(*self.parts, self.mass_class, supply_voltage=self.supply_voltage)
        return codesign.design_gait_model(design, self.speed, self.power_limit, self.step_length)


def run_solve(out: Path, problem: Problem, settings: gait_problem.GaitSettings = paper.STUDY_SETTINGS,
              smallest_power_limit: bool = False, progress: Callable[..., None] | None = None,
              free_step_length: tuple[float, float] | None = None, fastest: bool = False) -> dict:
    """Solves ``problem`` in ``settings``' space from every start family of the study and writes
    results.json (the problem, the settings, the solution with its refinement check and every start's
    outcome, and with ``smallest_power_limit`` the smallest limit at which it still walks),
    tables.md (the layout of the paper's Tables 4 and 5), fig2_trajectories.png, fig3_torque_rpm.png
    and trajectories.npz. With ``free_step_length`` (low, high) in m, the step length is then freed
    within those bounds from the solved gait (:meth:`~biped_jax.gait.solver.GaitSolver.solve_step_length`:
    the gait and length of least energy per metre at the problem's speed), recorded under
    "free_step_length" and drawn beside the fixed step in the figures. With ``fastest``, the fastest gait
    within the same limits (:meth:`~biped_jax.gait.solver.GaitSolver.fastest_gait`; its step length within
    ``free_step_length`` or :data:`FASTEST_STEP_BOUNDS`), under "fastest". Returns the results record."""
    say = progress or (lambda message, task=None: None)
    model = problem.model()
    if problem.has_drive:  # the gait within the gears' torque and input speed too
        settings = dataclasses.replace(settings, drive_limits=True)
    out.mkdir(parents=True, exist_ok=True)
    solvers = paper.study_solvers(settings)
    say(f"{problem.name}: {len(solvers.families)} starts in {solvers.coarse.settings.spans} knot spans, then the "
        f"best in {settings.spans}")
    solution, = multistart.solve_multistart(
        solvers.fine, ["gait"], [model], families=solvers.families, coarse=solvers.coarse,
        progress=lambda part, i, row: say(f"{part}: interior-point iteration {i}, J {float(row['cost'].min()):.4f}"),
        finished=lambda part, count: say(f"{part}: done", task=(part, count, count)))
    results = {"problem": dataclasses.asdict(problem), "settings": dataclasses.asdict(settings),
               "solution": gait_report.results_record(solution)}
    tables = [f"# {problem.name}", "", gait_report.markdown_table(solution)]
    drawn = [solution]
    if free_step_length is not None:
        say(f"the step length free in [{free_step_length[0]:g}, {free_step_length[1]:g}] m")
        free, = solvers.fine.solve_step_length(
            ["free_step"], [model], tuple(free_step_length), x0=solution.x[None],
            progress=lambda i, row: say(f"free step length: interior-point iteration {i}, "
                                        f"J/L {float(row['cost'].min()) / problem.step_length:.4f}"))
        results["free_step_length"] = {
            "bounds_m": list(free_step_length), "step_length_m": free.step_length_m,
            "cost_per_metre": free.energy_per_metre, "fixed_cost_per_metre": solution.energy_per_metre,
            "solution": gait_report.results_record(free)}
        tables += ["", f"## The step length free in [{free_step_length[0]:g}, {free_step_length[1]:g}] m", "",
                   f"L = {free.step_length_m:.4f} m ({free.status}): J/L = {free.energy_per_metre:.4g} against "
                   f"{solution.energy_per_metre:.4g} at L = {problem.step_length:g} m", "",
                   gait_report.markdown_table(free)]
        drawn.append(free)
    if smallest_power_limit:
        say("the smallest power limit at which it walks")
        minimum, = paper.minimal_power_limits(solvers.fine, [solution], [model], coarse=solvers.coarse_power,
                                              progress=paper.power_report(say))
        gait_at_minimum = minimum.pop("min_power_gait")
        results["smallest_power_limit"] = {**minimum, "gait": None if gait_at_minimum is None
                                           else gait_report.results_record(gait_at_minimum)}
        tables += ["", "## Smallest power limit with a feasible gait", "",
                   f"{'-' if minimum['min_power_limit_W'] is None else format(minimum['min_power_limit_W'], '.3f')} W "
                   f"(kept on {solvers.fine.refined_settings.steps} steps; status {minimum['min_power_status']})"]
    if fastest:
        bounds = tuple(free_step_length) if free_step_length is not None else FASTEST_STEP_BOUNDS
        say(f"the fastest gait (step length in [{bounds[0]:g}, {bounds[1]:g}] m)")
        quickest, = solvers.fine.fastest_gait(["fastest"], [model], solution.x[None], bounds,
                                               progress=paper.power_report(say))
        results["fastest"] = {"bounds_m": list(bounds), "speed_mps": quickest.speed_mps,
                              "step_length_m": quickest.step_length_m, "status": quickest.status,
                              "solution": gait_report.results_record(quickest)}
        tables += ["", "## The fastest gait", "",
                   f"v = {quickest.speed_mps:.4f} m/s at L = {quickest.step_length_m:.4f} m ({quickest.status}; "
                   f"J = {quickest.cost:.4g}, kept on {solvers.fine.refined_settings.steps} steps: "
                   f"{'yes' if quickest.refinement.get('passed') else 'no'})", "", gait_report.markdown_table(quickest)]
        drawn.append(quickest)
    if problem.has_drive:
        results["drives"] = _drive_check(problem, model, solution)
        tables += ["", "## The drive's catalogue check per joint", "", "| joint | motor | gearhead | verdict | "
                   "thermal margin |", "|---|---|---|---|---|"]
        tables += [f"| {v['joint']} | {v['motor']} | {v['gearhead']} | {v['reason']} | {v['thermal_margin']:.2f} |"
                   for v in results["drives"]["joints"]]
    outputs.write_json(out / "results.json", results)
    outputs.write_text(out / "tables.md", "\n".join(tables) + "\n")
    gait_report.plot_figure_2(drawn, out / "fig2_trajectories.png")
    gait_report.plot_figure_3(drawn, out / "fig3_torque_rpm.png")
    from biped_jax.drives import selection as drive_selection
    drive_selection.save_workspaces(out / "trajectories.npz", drawn)
    return results


def _drive_check(problem: Problem, model: gait_problem.GaitModel, solution) -> dict:
    """The catalogue check of the problem's drive at every joint on the solved gait of ``model``
    (:func:`biped_jax.drives.selection.drive_summary`: the verdict per joint and how long it walks)."""
    from biped_jax.drives import selection
    motor, gearhead = problem.parts
    voltage = float(model.drives.supply_voltage)
    return {"motor": motor, "gearhead": gearhead, "supply_voltage_V": voltage,
            **selection.drive_summary(motor, gearhead, solution, voltage)}
