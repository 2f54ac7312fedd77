"""How fast it can walk (``biped-jax top-speed``): the fastest gait of each mass class under a range of
power limits, the curve v_max(M_W), and on catalogue drives (motor, gearhead, supply voltage, the motor
model in the loop), all problems in one batch.

- Every problem is first solved at a slow start (:data:`START_SPEED`, :data:`START_STEP_LENGTH`) from the
  heuristic gait, all in one batch; a start that converged on its grid serves (the fastest gait gets
  its own refinement check).
- From each converged start :meth:`~biped_jax.gait.solver.GaitSolver.fastest_gait` maximises the speed
  with the step length free within the bounds: a converged optimisation (a KKT point of max v), not a
  bisection; the power held between the grid's samples by its tightening rounds.
- A drive's problem has no power limit of its own (:data:`~biped_jax.gait.problem.NO_POWER_LIMIT`): its
  supply voltage (the speed-torque line), its gear's torque and input speed bound the gait. Its
  fastest gait then gets the catalogue check per joint, and how long it walks from 25 C before the
  winding reaches its rated temperature (:mod:`biped_jax.drives.thermal`).

Written: ``top_speed.json`` (every problem: its start, its fastest gait with status and refinement
check, the drive demand, and for drives the catalogue check) and ``top_speed.png`` (v_max against M_W
per mass class, with each drive's top speed drawn at the peak joint power its gait needs).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import numpy as np

from biped_jax.gait import problem as gait_problem
from biped_jax.gait import verdict
from biped_jax.gait.solver import GaitSolution, GaitSolver
from biped_jax.optim import nlp
from biped_jax.report import outputs
from biped_jax.report.progress import iteration_progress
from biped_jax.studies.library import LIBRARY_OPTIONS, demand

#: The space of the top-speed study: the library's (16 knot spans, 4 Runge-Kutta steps each), with the
#: drives' gear limits held at every sample (ideal drives have none, so their problems are unchanged).
TOP_SPEED_SETTINGS = gait_problem.GaitSettings(spans=16, substeps=4, drive_limits=True)
#: The start every fastest gait is continued from: a slow walk that every problem below can walk.
START_SPEED, START_STEP_LENGTH = 0.3, 0.2
#: The step lengths a fastest gait may take, m (:data:`biped_jax.studies.solve.FASTEST_STEP_BOUNDS`).
STEP_BOUNDS = (0.1, 0.35)
#: The power limits of the v_max(M_W) curve, W.
POWER_LIMITS = (5.0, 10.0, 20.0, 40.0)
#: The drives whose top speed is reported: the paper's RE 25 (42 V winding) on the three GP 32 A ratios
#: of its Figs. 4-5, at the catalogue's supply voltage.
DRIVES = (("RE25-42V", "GP32A-51"), ("RE25-42V", "GP32A-66.22"), ("RE25-42V", "GP32A-79"))
MASS_CLASSES = ("12kg", "18kg")
QUICK_POWER_LIMITS, QUICK_DRIVES = (10.0, 20.0), DRIVES[1:2]
QUICK_STAMP = "QUICK LOOK (biped-jax top-speed --quick): two power limits and the paper's drive"


@dataclasses.dataclass(frozen=True)
class TopSpeedProblem:
    """One question: how fast the ``mass_class`` biped walks with ideal drives under ``power_limit`` W, or
    (``drive`` = (motor, gearhead) catalogue names) on that drive at every joint, supplied with
    ``supply_voltage`` V (None: the catalogue's), with no power limit beside the drive's own."""

    mass_class: str
    power_limit: float | None = None
    drive: tuple[str, str] | None = None
    supply_voltage: float | None = None

    def __post_init__(self):
        if (self.power_limit is None) == (self.drive is None):
            raise ValueError(f"a top-speed problem takes a power limit or a drive, got power_limit="
                             f"{self.power_limit!r}, drive={self.drive!r}")
        self.model(START_SPEED)  # names a bad mass class, limit, part or voltage

    @property
    def name(self) -> str:
        if self.drive is None:
            return f"{self.mass_class}, {self.power_limit:g} W"
        return f"{self.mass_class}, {self.drive[0]} + {self.drive[1]}"

    def model(self, speed: float = START_SPEED) -> gait_problem.GaitModel:
        """The problem at ``speed`` m/s and the start's step length."""
        if self.drive is None:
            return gait_problem.gait_model(self.mass_class, speed, self.power_limit, START_STEP_LENGTH)
        from biped_jax import codesign
        design = codesign.catalogue_design(*self.drive, self.mass_class, supply_voltage=self.supply_voltage)
        model = codesign.design_gait_model(design, speed, gait_problem.NO_POWER_LIMIT, START_STEP_LENGTH)
        # a catalogue design has every drive at its joint (offset 0): written as the paper's designs write it
        # (None), so that ideal and catalogue drives batch together in the same programs
        return dataclasses.replace(model, design=dataclasses.replace(model.design, drive_offset=None))


def problems(mass_classes=MASS_CLASSES, power_limits=POWER_LIMITS, drives=DRIVES,
             supply_voltage: float | None = None) -> list[TopSpeedProblem]:
    """Per mass class one problem per power limit (W), then one per drive ((motor, gearhead) names)."""
    return ([TopSpeedProblem(m, power_limit=float(p)) for m in mass_classes for p in power_limits]
            + [TopSpeedProblem(m, drive=tuple(d), supply_voltage=supply_voltage) for m in mass_classes for d in drives])


def _drive_check(problem: TopSpeedProblem, solution: GaitSolution, catalogue) -> dict:
    """The catalogue check per joint of the problem's drive on its fastest gait, and how long it walks."""
    from biped_jax.drives import selection
    summary = selection.drive_summary(*problem.drive, solution, problem.supply_voltage, catalogue)
    return {k: summary[k] for k in ("passes_catalogue_check", "passes_without_thermal", "walk_time_s", "joints")}


def record_of(problem: TopSpeedProblem, start: GaitSolution, fastest: GaitSolution | None) -> dict:
    """What ``top_speed.json`` holds of one problem."""
    entry = {"name": problem.name, "mass_class": problem.mass_class, "power_limit_W": problem.power_limit,
             "drive": None if problem.drive is None else list(problem.drive),
             "start": {"speed_mps": start.speed_mps, "step_length_m": start.step_length_m, "status": start.status},
             "top_speed_mps": None, "status": start.status if fastest is None else fastest.status}
    if fastest is not None:
        entry.update({"top_speed_mps": fastest.speed_mps, "step_length_m": fastest.step_length_m,
                      "t_f": fastest.step_time_s, "cost": fastest.cost, "max_violation": fastest.max_violation,
                      "refinement_passed": fastest.refinement.get("passed"),
                      "refinement_failed": fastest.refinement.get("failed"),
                      "solve_grid_power_limit_W": fastest.refinement.get("solve_grid_power_limit_W"),
                      **demand(fastest)})
    return entry


def solve_top_speeds(solver: GaitSolver, chosen: list[TopSpeedProblem], bounds: tuple[float, float] = STEP_BOUNDS,
                     say: Callable[[str], None] | None = None, tightening: int | None = None
                     ) -> tuple[list[GaitSolution], dict[int, GaitSolution]]:
    """The slow start of every problem of ``chosen`` (one batch) and, from each converged one, its fastest
    gait with the step length within ``bounds`` m (one batch; ``tightening`` as
    :meth:`~biped_jax.gait.solver.GaitSolver.fastest_gait`'s). Returns (the starts, {index in ``chosen``:
    fastest gait})."""
    say = say or (lambda message: None)
    if not chosen:
        raise ValueError("no top-speed problems: give at least one power limit or drive")
    gait_problem.check_step_bounds(bounds, [START_STEP_LENGTH], chosen[0].mass_class)
    names, models = [p.name for p in chosen], [p.model() for p in chosen]
    say(f"{len(chosen)} problems at {START_SPEED:g} m/s in one batch ({solver.settings.spans} knot spans)")
    starts = solver.solve(names, models, progress=iteration_progress(say, "start", solver.options.max_iterations))
    # a start converged on its grid serves, whether or not it passes the refinement check: the fastest
    # gait is judged on its own
    usable = [b for b, s in enumerate(starts) if s.status in (nlp.CONVERGED, verdict.GRID_DEPENDENT)]
    if not usable:
        return starts, {}
    say(f"the fastest gait of {len(usable)} problems (step length in [{bounds[0]:g}, {bounds[1]:g}] m)")
    fastest = solver.fastest_gait([names[b] for b in usable], [models[b] for b in usable],
                                  np.stack([starts[b].x for b in usable]), bounds,
                                  progress=iteration_progress(say, "fastest gait", solver.options.max_iterations),
                                  tightening=tightening)
    return starts, dict(zip(usable, fastest))


def run_top_speed(out: Path, chosen: list[TopSpeedProblem], settings: gait_problem.GaitSettings = TOP_SPEED_SETTINGS,
                  bounds: tuple[float, float] = STEP_BOUNDS, say: Callable[[str], None] | None = None,
                  solver: GaitSolver | None = None) -> dict:
    """The fastest gait of every problem of ``chosen`` (:func:`solve_top_speeds`) in ``settings``' space
    with the drives' gear limits (or with ``solver``, sharing its compiled programs); writes
    ``top_speed.json`` and ``top_speed.png`` into ``out`` and returns the record. A problem whose slow
    start does not converge reports that status and no top speed."""
    solver = solver or GaitSolver(dataclasses.replace(settings, drive_limits=True), LIBRARY_OPTIONS)
    starts, found = solve_top_speeds(solver, chosen, bounds, say)
    return write_top_speed(out, solver, chosen, starts, found, bounds)


def write_top_speed(out: Path, solver: GaitSolver, chosen: list[TopSpeedProblem], starts: list[GaitSolution],
                    found: dict[int, GaitSolution], bounds: tuple[float, float]) -> dict:
    """The record of :func:`solve_top_speeds`' results (each drive's fastest gait with its catalogue
    check), written to ``out``/top_speed.json with its figure ``top_speed.png``; returns it."""
    from biped_jax.drives import model as drive_model
    out.mkdir(parents=True, exist_ok=True)
    catalogue = drive_model.load_catalogue()
    entries = []
    for b, problem in enumerate(chosen):
        entry = record_of(problem, starts[b], found.get(b))
        if problem.drive is not None and b in found:
            entry["drive_check"] = _drive_check(problem, found[b], catalogue)
        entries.append(entry)
    record = {"settings": dataclasses.asdict(solver.settings), "start_speed_mps": START_SPEED,
              "start_step_length_m": START_STEP_LENGTH, "step_bounds_m": list(bounds), "problems": entries}
    outputs.write_json(out / "top_speed.json", record)
    plot_top_speeds(record, out / "top_speed.png")
    return record


def plot_top_speeds(record: dict, path: Path) -> None:
    """v_max against M_W per mass class, each drive's top speed at the peak joint power its fastest gait
    needs; filled markers for gaits converged and kept on the 4x grid, hollow for the others."""
    plt = outputs.pyplot()
    figure, axis = plt.subplots(figsize=(7, 4.5), constrained_layout=True)
    rows = [p for p in record["problems"] if p["top_speed_mps"] is not None]
    for mass_class in sorted({p["mass_class"] for p in record["problems"]}):
        curve = sorted((p["power_limit_W"], p["top_speed_mps"]) for p in rows
                       if p["mass_class"] == mass_class and p["drive"] is None)
        line = axis.plot(*zip(*curve), "-", label=f"{mass_class}, ideal drives")[0] if curve else None
        color = None if line is None else line.get_color()
        for p in (p for p in rows if p["mass_class"] == mass_class):
            # filled: converged and kept on the 4x grid; hollow: not (its status in top_speed.json)
            at = p["power_limit_W"] if p["drive"] is None else max(p["power_peak_W"])
            color = axis.plot(at, p["top_speed_mps"], "o" if p["drive"] is None else "s", color=color,
                              markerfacecolor=None if p["status"] == nlp.CONVERGED else "none")[0].get_color()
        for p in (p for p in rows if p["mass_class"] == mass_class and p["drive"] is not None):
            axis.annotate(p["drive"][1].replace("GP32A-", "") + ":1", (max(p["power_peak_W"]), p["top_speed_mps"]),
                          textcoords="offset points", xytext=(5, -3), fontsize=8, color=color)
    axis.set_xscale("log")
    axis.set_xlabel("power limit M_W per joint [W] (squares: a drive's peak joint power)")
    axis.set_ylabel("fastest walking speed [m/s]")
    axis.set_title("How fast it can walk (step length free)")
    if axis.get_legend_handles_labels()[0]:
        axis.legend(loc="lower right")
    outputs.save_figure(figure, path)
    plt.close(figure)
