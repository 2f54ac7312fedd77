"""One gait problem of the user's own (``biped-jax solve``): a mass class, a speed, a step length and a
power limit, solved as the study solves each of its models (every start family in the 4x coarser space,
the cheapest carried into the fine one; :func:`biped_jax.gait.multistart.solve_multistart`), optionally
with its smallest power limit; the study's files for that one problem."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

from biped_jax.gait import multistart
from biped_jax.gait import problem as gait_problem
from biped_jax.gait import report as gait_report
from biped_jax.report import outputs
from biped_jax.studies import paper


@dataclasses.dataclass(frozen=True)
class Problem:
    """The problem ``biped-jax solve`` poses.

    Attributes:
      mass_class: "12kg" or "18kg" (the paper's bipeds). speed: m/s. step_length: m. power_limit: W,
        the bound on every actuated joint's |qdot u|.
    """

    mass_class: str = "12kg"
    speed: float = 0.555
    step_length: float = 0.2
    power_limit: float = 20.0

    @property
    def name(self) -> str:
        return f"{self.mass_class}, {self.speed:g} m/s, L = {self.step_length:g} m, M_W = {self.power_limit:g} W"

    def model(self) -> gait_problem.GaitModel:
        """The gait problem (ValueError naming a bad value, before anything compiles)."""
        return gait_problem.gait_model(self.mass_class, self.speed, self.power_limit, self.step_length)


def run_solve(out: Path, problem: Problem, settings: gait_problem.GaitSettings = paper.STUDY_SETTINGS,
              smallest_power_limit: bool = False, progress: Callable[..., None] | None = None) -> dict:
    """Solves ``problem`` in ``settings``' space from every start family of the study and writes
    results.json (the problem, the settings, the solution with its refinement check and every start's
    outcome, and with ``smallest_power_limit`` the smallest limit at which it still walks),
    tables.md (the layout of the paper's Tables 4 and 5), fig2_trajectories.png, fig3_torque_rpm.png
    and trajectories.npz. Returns the results record."""
    say = progress or (lambda message, task=None: None)
    model = problem.model()
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
    if smallest_power_limit:
        say("the smallest power limit at which it walks")
        minimum, = paper.minimal_power_limits(solvers.power, [solution], [model], coarse=solvers.coarse_power,
                                              progress=paper.power_report(say))
        gait_at_minimum = minimum.pop("min_power_gait")
        results["smallest_power_limit"] = {**minimum, "gait": None if gait_at_minimum is None
                                           else gait_report.results_record(gait_at_minimum)}
        tables += ["", "## Smallest power limit with a feasible gait", "",
                   f"{'-' if minimum['min_power_limit_W'] is None else format(minimum['min_power_limit_W'], '.3f')} W "
                   f"(kept on {solvers.fine.refined_settings.steps} steps; status {minimum['min_power_status']})"]
    outputs.write_json(out / "results.json", results)
    outputs.write_text(out / "tables.md", "\n".join(tables) + "\n")
    gait_report.plot_figure_2([solution], out / "fig2_trajectories.png")
    gait_report.plot_figure_3([solution], out / "fig3_torque_rpm.png")
    from biped_jax.drives import selection as drive_selection
    drive_selection.save_workspaces(out / "trajectories.npz", [solution])
    return results
