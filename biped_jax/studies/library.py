"""A gait library (``biped-jax library``): the optimal gaits of one biped over a grid of walking speeds and
step lengths at a power limit, solved as batches of the interior point and continued along the grid,
with the optimal step length at every speed and what the drives must deliver there.

- Every grid point is first solved from several heuristic start families (:data:`LIBRARY_FAMILIES`),
  all points and families in one batch of the 4x coarser space, the cheapest per point carried into
  the library's space (:func:`biped_jax.gait.multistart.solve_multistart`, the study's way): each point
  records every start's outcome (its spread) and the family kept, so that the map shows where the
  cheapest family changes.
- A point whose solve did not converge on its grid is solved again from its nearest converged
  neighbour's gait (nearest in grid steps; the decision vector is in normalised time, so a neighbour's
  gait is a start of the same shape), for a few rounds: a continuation along the grid, each round in
  the grid's own compiled program. Each point records where it started. (A gait that converged but
  fails the refinement check, "grid dependent", is kept: its grid, not its start, is the cause.)
- At every speed the step length is then freed (:meth:`~biped_jax.gait.solver.GaitSolver.solve_step_length`)
  from the grid's cheapest converged point per metre, within the grid's step lengths: the optimal-L
  curve, all speeds in one batch.
- Every point and every speed's optimal step is then solved again, warm, in a space with
  :data:`SPACE_FACTOR` times the knot spans, those still space dependent in twice that, and so on
  (:data:`SPACE_REFINEMENTS`; :func:`biped_jax.gait.spaces.refine_spaces`; the refinement
  check refines the rollout grid, not the joint paths' space, whose error dominates at long steps) and
  reported there, with J in both spaces and the estimated error of the finer one ("space dependent"
  where it exceeds 1 %).

Every point reports J, J / L, t_f, the status and the refinement check, and per joint the peak and RMS
torque, the peak speed and the peak power; on a catalogue drive (``LibraryGrid.drive``: the robot
carries it, J is the motors' Joule energy, the gait keeps the supply voltage and the gears' limits)
also the catalogue check per joint and how long it walks before a winding reaches its rated
temperature (:mod:`biped_jax.drives.thermal`). Written: ``library.json``, ``library.npz`` (arrays over the
grid, every point's gait sampled in time: :func:`sampled_gait`), ``library_map.png`` (J / L over
(speed, L) with the optimal-L curve) and ``library_drives.png`` (peak torque and speed per joint against
speed, at the optimal step length).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import numpy as np

from biped_jax import checks
from biped_jax.gait import multistart
from biped_jax.gait import problem as gait_problem
from biped_jax.gait import spaces, verdict
from biped_jax.gait.report import JOINTS
from biped_jax.gait.solver import GaitSolution, GaitSolver
from biped_jax.optim import interior_point, nlp
from biped_jax.report import outputs
from biped_jax.report.progress import iteration_progress
from biped_jax.robots.planar_biped import ACTUATED_INDEX

#: rad/s per rpm.
RPM = 2 * np.pi / 60

#: The library's default reference space: 16 knot spans, a shooting segment each, 4 Runge-Kutta steps per
#: span (the study's 48 spans are three times the work per point; see :data:`QUICK_SETTINGS`).
LIBRARY_SETTINGS = gait_problem.GaitSettings(spans=16, substeps=4)
#: ``--quick``: the library's space on a 3 x 3 grid (every file stamped), without the space check. 8 knot
#: spans left 6 of 9 points "grid dependent" (measured 2026-12-05).
QUICK_SETTINGS = LIBRARY_SETTINGS
#: The space check's knot spans, a multiple of the library's: every point's optimum solved again, warm, in
#: 3x the spans (48, the study's space; nested, so each solve starts at the 16-span optimum) and
#: reported there (:func:`biped_jax.gait.spaces.refine_spaces`). Measured on the default grid (2026-12-05):
#: the 16-span optima at 0.25 m lie 4.7-8.0 % above the collocation peer, the 48-span ones 0.6-2.0 %
#: above its optimum, the 96-span ones 0.15-0.6 %; 32 spans left them 1.6-2.5 % above. The first stage
#: takes every point (one compiled program: a 32-span check of all twelve took 119 s, the 48-span one
#: 184 s on 2 cores), the second only those its estimate leaves space dependent.
SPACE_FACTOR = 3
#: Then the points still "space dependent" once more in twice those spans (96): more knots only where
#: the estimate asks for them.
SPACE_REFINEMENT = 2
#: How many times :data:`SPACE_REFINEMENT` is applied after the first finer space. Once: at 0.3 m/s,
#: 0.25 m (a slow step of 0.83 s), the one default point still space dependent in 96 spans (estimate
#: 1.1 %, though 0.5 % above the collocation peer's optimum on 320 segments), a third stage in 192
#: spans went from the 96-span optimum to a dearer one (J 5.4373 against 5.1592) and cost 74 s of the
#: default library's 492 s (2-core CPU, 2026-12-05).
SPACE_REFINEMENTS = 1
#: The library's interior point: once 90 % of a batch's points have finished the others get 60 more
#: iterations (a point that needs more is re-solved from a converged neighbour, a better start than
#: more iterations from the heuristic one).
LIBRARY_OPTIONS = interior_point.InteriorPointOptions(max_iterations=150, quorum=0.9, patience=60)
#: The starts' interior point in the 4x coarser space (the study's 80 iterations): once 90 % of the
#: batch has finished, 20 more; a start still running then ends "iteration limit" and another family's
#: start is kept. Without it the default grid's 36 starts ran past 10 minutes on 2 cores, held by a few.
COARSE_OPTIONS = interior_point.InteriorPointOptions(max_iterations=80, quorum=0.9, patience=20)
#: The start families every grid point is solved from: the quick study's three (one straight-knee
#: family, two flexed-impact ones: the cheapest family changes with the step length).
LIBRARY_FAMILIES = (gait_problem.START_FAMILIES[1], gait_problem.IMPACT_FAMILIES[0], gait_problem.IMPACT_FAMILIES[1])
QUICK_SPEEDS, QUICK_STEP_LENGTHS = (0.3, 0.5, 0.7), (0.1, 0.2, 0.3)
QUICK_STAMP = "QUICK LOOK (biped-jax library --quick): 3 speeds x 3 step lengths; a coarse grid of speeds and lengths"


@dataclasses.dataclass(frozen=True)
class LibraryGrid:
    """The grid of a library.

    Attributes:
      mass_class: "12kg" or "18kg". speeds: walking speeds, m/s, increasing. step_lengths: step lengths,
        m, increasing. power_limit: the bound on every joint's |qdot u|, W.
      drive: None (ideal drives, the paper's problem) or (motor, gearhead) catalogue names of the drive
        at every joint. supply_voltage: its supply, V (None: the catalogue's).
    """

    mass_class: str = "12kg"
    speeds: tuple = (0.3, 0.45, 0.6, 0.75)
    step_lengths: tuple = (0.1, 0.175, 0.25)
    power_limit: float = 20.0
    drive: tuple | None = None
    supply_voltage: float | None = None

    def __post_init__(self):
        for name in ("speeds", "step_lengths"):
            values = getattr(self, name)
            if not isinstance(values, (list, tuple)) or not values:
                raise ValueError(f"{name} must be a non-empty list or tuple of numbers, got {values!r:.80}")
            numbers = np.asarray(values, dtype=float)
            if not np.all(np.diff(numbers) > 0):
                raise ValueError(f"{name} must increase, got {list(values)}")
        if self.drive is None and self.supply_voltage is not None:
            raise ValueError(f"supply_voltage {self.supply_voltage!r} applies to a drive: give a drive")
        self.models()  # names a bad speed, length, limit, mass class or part

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.speeds), len(self.step_lengths)

    def models(self) -> list[gait_problem.GaitModel]:
        """The grid's problems, speed-major ((speed i, length j) at i * len(step_lengths) + j)."""
        if self.drive is None:
            return [gait_problem.gait_model(self.mass_class, float(v), float(self.power_limit), float(length))
                    for v in self.speeds for length in self.step_lengths]
        from biped_jax import codesign
        design = codesign.catalogue_design(*self.drive, self.mass_class, supply_voltage=self.supply_voltage)
        return [codesign.design_gait_model(design, float(v), float(self.power_limit), float(length))
                for v in self.speeds for length in self.step_lengths]

    def names(self) -> list[str]:
        return [f"{v:g} m/s, {length:g} m" for v in self.speeds for length in self.step_lengths]


def _nearest_converged(index: int, converged: np.ndarray, shape: tuple[int, int]) -> int | None:
    """The converged grid point nearest to ``index`` in grid steps (ties: the lower index), or None."""
    if not converged.any():
        return None
    rows, cols = np.unravel_index(np.arange(converged.size), shape)
    row, col = np.unravel_index(index, shape)
    distance = np.abs(rows - row) + np.abs(cols - col)
    distance = np.where(converged, distance, np.iinfo(int).max)
    return int(np.argmin(distance))


def solve_grid(solver: GaitSolver, grid: LibraryGrid, rounds: int = 3,
               say: Callable[[str], None] | None = None, families=LIBRARY_FAMILIES,
               coarse: GaitSolver | None = None) -> tuple[list[GaitSolution], list[str]]:
    """The grid's optimal gaits (speed-major) and where each started ("<family>", the start family kept,
    or "from <name>" of the neighbour it was continued from): every point from every start family of
    ``families`` in one batch (in ``coarse``'s space, the cheapest carried into ``solver``'s;
    :func:`~biped_jax.gait.multistart.solve_multistart`: each solution's ``starts`` lists every
    family's outcome), then ``rounds`` rounds re-solving the points that did not converge from their
    nearest converged neighbour's gait."""
    say = say or (lambda message: None)
    names, models = grid.names(), grid.models()
    first = coarse or solver
    stage = {"starts": iteration_progress(say, f"starts ({len(families)} families)", first.options.max_iterations),
             "refined space": iteration_progress(say, "grid", solver.options.max_iterations)}
    solutions = multistart.solve_multistart(solver, names, models, families, coarse,
                                            progress=lambda part, i, row: stage[part](i, row))
    started = [next(start["family"] for start in s.starts if start["kept"]) for s in solutions]
    for k in range(rounds):
        converged = np.array([s.status == nlp.CONVERGED for s in solutions])
        say(f"round {k}: {int(converged.sum())} of {converged.size} points converged")
        # a gait that converged on its grid but fails the refinement check fails it from any start
        retry = [b for b in range(len(names)) if solutions[b].status not in (nlp.CONVERGED, verdict.GRID_DEPENDENT)]
        sources = {b: _nearest_converged(b, converged, grid.shape) for b in retry}
        retry = [b for b in retry if sources[b] is not None]
        if not retry:
            break
        # the retried points repeated up to the grid's size: the program the grid was solved with
        padded = [retry[i % len(retry)] for i in range(len(names))]
        again = solver.solve([names[b] for b in padded], [models[b] for b in padded],
                             x0=np.stack([solutions[sources[b]].x for b in padded]),
                             progress=iteration_progress(say, f"round {k + 1}, {len(retry)} points from neighbours",
                                                  solver.options.max_iterations))
        for b, solution in zip(retry, again):
            if solution.status == nlp.CONVERGED or solution.max_violation < solutions[b].max_violation:
                solution.starts = solutions[b].starts
                solutions[b], started[b] = solution, f"from {names[sources[b]]}"
    return solutions, started


def optimal_step_lengths(solver: GaitSolver, grid: LibraryGrid, solutions: list[GaitSolution],
                         say: Callable[[str], None] | None = None) -> list[GaitSolution | None]:
    """Per speed, the step length of least energy per metre within the grid's step lengths: the free
    step length solved from the cheapest converged grid point per metre at that speed, or that grid
    point where the free solve did not converge or ended dearer (None where no point converged); all
    speeds in one batch."""
    speeds, lengths = grid.shape
    picks = []
    for i in range(speeds):
        row = solutions[i * lengths:(i + 1) * lengths]
        usable = [j for j, s in enumerate(row) if s.status == nlp.CONVERGED]
        picks.append(None if not usable else i * lengths + min(usable, key=lambda j: row[j].energy_per_metre))
    chosen = [p for p in picks if p is not None]
    if not chosen:
        return [None] * speeds
    bounds = (float(grid.step_lengths[0]), float(grid.step_lengths[-1]))
    models = grid.models()
    free = solver.solve_step_length([f"{solutions[p].speed_mps:g} m/s, L free" for p in chosen],
                                    [models[p] for p in chosen], bounds,
                                    x0=np.stack([solutions[p].x for p in chosen]),
                                    progress=iteration_progress(say or (lambda message: None), "step length free",
                                                         solver.options.max_iterations))
    found = iter(free)
    optimal = []
    for p in picks:
        solution = None if p is None else next(found)
        # a local solve from the grid's best point may end in a dearer optimum (or not converge): the
        # grid point is then the best step known at that speed
        if solution is not None and not (solution.status == nlp.CONVERGED and
                                         solution.energy_per_metre <= solutions[p].energy_per_metre * (1 + 1e-6)):
            solution = solutions[p]
        optimal.append(solution)
    return optimal


def check_spaces(stages: list[GaitSolver], solver: GaitSolver, grid: LibraryGrid, solutions: list[GaitSolution],
                 optimal: list[GaitSolution | None], say: Callable[[str], None] | None = None
                 ) -> tuple[list[GaitSolution], list[GaitSolution | None]]:
    """The grid's points and every speed's optimal step (``solver``'s space) solved again in the first of
    ``stages``' spaces, all in one batch, those still space dependent in the next
    (:func:`biped_jax.gait.spaces.refine_spaces`); returns them as reported there. A
    speed's optimal step is then the cheapest per metre of its free step length and its grid points
    that reached an optimum in the finer space (the step length was found in the coarser one)."""
    speeds, lengths = grid.shape
    models = grid.models()
    free = [i for i, s in enumerate(optimal) if s is not None and not any(s is g for g in solutions)]
    names = grid.names() + [optimal[i].name for i in free]
    models = models + [dataclasses.replace(models[i * lengths], step_length=np.asarray(optimal[i].step_length_m))
                       for i in free]
    checked = spaces.refine_spaces(stages, solver, names, models, solutions + [optimal[i] for i in free],
                                   progress=iteration_progress(say or (lambda message: None), "space check",
                                                               stages[0].options.max_iterations))
    points, found = checked[:len(solutions)], dict(zip(free, checked[len(solutions):]))
    best = []
    for i, s in enumerate(optimal):
        if s is None:
            best.append(None)
            continue
        row = points[i * lengths:(i + 1) * lengths]
        # the free step's gait, or the grid point it was, in the finer space
        own = found[i] if i in found else row[[g is s for g in solutions[i * lengths:(i + 1) * lengths]].index(True)]
        # an optimum of the finer space, its space's estimated error within the tolerance or not
        usable = [c for c in (own, *row) if c.status in (nlp.CONVERGED, spaces.SPACE_DEPENDENT)]
        best.append(min(usable, key=lambda c: c.energy_per_metre) if usable else own)
    return points, best


#: Samples of every point's gait in ``library.npz``, evenly spaced in normalised time s = t / t_f.
GAIT_SAMPLES = 97


def sampled_gait(solution: GaitSolution, samples: int = GAIT_SAMPLES) -> dict:
    """A gait's pinned state and torques at ``samples`` points evenly spaced in s = t / t_f, linearly
    interpolated between its rollout grid's points: "q", "qd" (samples, 5) in rad and rad/s (the columns
    of a :class:`~biped_jax.gait.problem.GaitTrajectory`'s q: the stance angle, then the joints), "u"
    (samples, 4) in N m (H1, K1, H2, K2)."""
    tr = solution.trajectory
    t = np.asarray(tr.t)
    at = np.linspace(0.0, 1.0, samples) * t[-1]
    return {key: np.stack([np.interp(at, t, column) for column in np.asarray(getattr(tr, key)).T], axis=-1)
            for key in ("q", "qd", "u")}


def demand(solution: GaitSolution) -> dict:
    """What the drives must deliver on a gait, per joint (H1, K1, H2, K2): peak and RMS torque (N m),
    peak speed (rpm) and peak power (W)."""
    tr = solution.trajectory
    torque = np.asarray(tr.u)
    speed = np.abs(np.asarray(tr.qd)[:, ACTUATED_INDEX])
    weights = np.asarray(tr.weights)
    rms = np.sqrt(weights @ torque**2 / solution.step_time_s)
    return {"torque_peak_Nm": np.abs(torque).max(axis=0).tolist(), "torque_rms_Nm": rms.tolist(),
            "speed_peak_rpm": (speed.max(axis=0) / RPM).tolist(),
            "power_peak_W": np.abs(speed * torque).max(axis=0).tolist()}


def point_record(solution: GaitSolution, started: str, grid: LibraryGrid | None = None, catalogue=None) -> dict:
    """What ``library.json`` holds of one gait: its numbers, where it started, every start's outcome where
    it was started afresh, and on a drive (``grid.drive``) the catalogue check and the walk time
    (``catalogue``: the :class:`~biped_jax.drives.model.Catalogue`, None: the shipped one)."""
    record = {"speed_mps": solution.speed_mps, "step_length_m": solution.step_length_m, "status": solution.status,
              "cost": solution.cost, "cost_per_metre": solution.energy_per_metre, "t_f": solution.step_time_s,
              "max_violation": solution.max_violation, "refinement_passed": solution.refinement.get("passed"),
              "refined_cost": solution.refinement.get("cost"), "started": started, "starts": solution.starts,
              "space": solution.space or None, **demand(solution)}
    if grid is not None and grid.drive is not None:
        from biped_jax.drives import selection
        summary = selection.drive_summary(*grid.drive, solution, grid.supply_voltage, catalogue)
        record["drive_check"] = {k: summary[k] for k in ("passes_catalogue_check", "reasons", "walk_time_s")}
    return record


def indefinite_walk(optimal_step: list[dict | None]) -> dict:
    """On a drive, the speeds (m/s) at which the robot walks indefinitely at the optimal step length (its
    winding stays below its rated temperature: the thermal check passes), and the grid's bracket of the
    fastest such speed: ``up_to_mps`` the fastest speed that does (None: none), ``not_at_mps`` the slowest
    speed above it that does not (None: none)."""
    rows = [p for p in optimal_step if p is not None and p["status"] == nlp.CONVERGED]
    lasting = [p["speed_mps"] for p in rows if p["drive_check"]["walk_time_s"] is None]
    up_to = max(lasting) if lasting else None
    above = [p["speed_mps"] for p in rows if p["drive_check"]["walk_time_s"] is not None
             and (up_to is None or p["speed_mps"] > up_to)]
    return {"speeds_mps": lasting, "up_to_mps": up_to, "not_at_mps": min(above) if above else None}


def check_space_factor(space_factor, name: str = "space_factor") -> None:
    """Raises ValueError naming ``name`` unless ``space_factor`` is 0 (no space check) or an integer in
    [2, 8] (a finer space needs more knot spans)."""
    checks.integer_in(name, space_factor, 0, 8)
    if space_factor == 1:
        raise ValueError(f"{name} must be 0 (no space check) or at least 2, got 1")


def library_solvers(grid: LibraryGrid, settings: gait_problem.GaitSettings = LIBRARY_SETTINGS
                    ) -> tuple[GaitSolver, GaitSolver]:
    """(the library's solver in ``settings``' space, the starts' in the 4x coarser one), the drives' gear
    limits held where ``grid`` has a drive."""
    if grid.drive is not None:
        settings = dataclasses.replace(settings, drive_limits=True)
    fine = GaitSolver(settings, LIBRARY_OPTIONS, mass_class_template=grid.mass_class)
    # the starts only choose a family: no refinement check, as the study's coarse stage
    coarse = GaitSolver(multistart.coarse_settings(settings), COARSE_OPTIONS, mass_class_template=grid.mass_class,
                        check_refinement=False)
    return fine, coarse


def run_library(out: Path, grid: LibraryGrid, settings: gait_problem.GaitSettings = LIBRARY_SETTINGS,
                rounds: int = 3, say: Callable[[str], None] | None = None, solver: GaitSolver | None = None,
                families=LIBRARY_FAMILIES, space_factor: int = SPACE_FACTOR,
                space_solvers: list[GaitSolver] | None = None) -> dict:
    """Solves the library of ``grid`` in ``settings``' space from every start family of ``families``
    (:func:`library_solvers`; or with ``solver``, sharing its compiled programs, the starts solved in its
    own space), checks every optimum in a space with ``space_factor`` times the knot spans and those
    still space dependent in :data:`SPACE_REFINEMENT` times that, :data:`SPACE_REFINEMENTS` times (0: no
    space check; or in the spaces of the solvers ``space_solvers``, sharing their programs) and writes
    its files into ``out``; returns the library record (what ``library.json`` holds)."""
    checks.integer_in("rounds", rounds, 0, 20)
    check_space_factor(space_factor)
    say = say or (lambda message: None)
    solver, coarse = (solver, None) if solver is not None else library_solvers(grid, settings)
    settings = solver.settings
    if space_solvers is None and space_factor:
        space_solvers = [spaces.finer_solver(solver, space_factor)]
        for _ in range(SPACE_REFINEMENTS):
            space_solvers.append(spaces.finer_solver(space_solvers[-1], SPACE_REFINEMENT))
    out.mkdir(parents=True, exist_ok=True)
    say(f"{grid.mass_class}, {grid.power_limit:g} W: {grid.shape[0]} speeds x {grid.shape[1]} step lengths "
        f"x {len(families)} start families in one batch ({settings.spans} knot spans)")
    solutions, started = solve_grid(solver, grid, rounds, say, families, coarse)
    say("the optimal step length at every speed")
    optimal = optimal_step_lengths(solver, grid, solutions, say)
    if space_solvers:
        say(f"the space check: every optimum again in {space_solvers[0].settings.spans} knot spans"
            + "".join(f", then in {f.settings.spans} where still space dependent" for f in space_solvers[1:]))
        solutions, optimal = check_spaces(space_solvers, solver, grid, solutions, optimal, say)
    catalogue = None
    if grid.drive is not None:
        from biped_jax.drives import model as drive_model
        catalogue = drive_model.load_catalogue()
    record = {"mass_class": grid.mass_class, "power_limit_W": grid.power_limit,
              "drive": None if grid.drive is None else list(grid.drive), "speeds_mps": list(grid.speeds),
              "step_lengths_m": list(grid.step_lengths), "settings": dataclasses.asdict(settings),
              "space_check": None if not space_solvers else {"spans": [f.settings.spans for f in space_solvers],
                                                         "tolerance": spaces.SPACE_TOLERANCE,
                                                         "order": spaces.SPACE_ORDER},
              "families": [f.name for f in families],
              "joints": list(JOINTS),
              "points": [point_record(s, w, grid, catalogue) for s, w in zip(solutions, started)],
              "optimal_step": [None if s is None else point_record(
                  s, "grid point" if any(s is g for g in solutions) else "free step length", grid, catalogue)
                  for s in optimal]}
    if grid.drive is not None:
        record["indefinite_walk"] = indefinite_walk(record["optimal_step"])
    outputs.write_json(out / "library.json", record)
    shape = grid.shape
    arrays = {"speeds_mps": np.asarray(grid.speeds), "step_lengths_m": np.asarray(grid.step_lengths)}
    for key in ("cost", "cost_per_metre", "t_f"):
        arrays[key] = np.array([p[key] for p in record["points"]]).reshape(shape)
    arrays["converged"] = np.array([p["status"] == nlp.CONVERGED for p in record["points"]]).reshape(shape)
    # the space check's estimated relative error of J (NaN: not checked)
    arrays["space_error_estimate"] = np.array([(p["space"] or {}).get("error_estimate") for p in record["points"]],
                                              dtype=float).reshape(shape)
    # the family each point's gait started from (-1: continued from a neighbour)
    arrays["family_index"] = np.array([record["families"].index(p["started"]) if p["started"] in record["families"]
                                       else -1 for p in record["points"]]).reshape(shape)
    for key in ("torque_peak_Nm", "torque_rms_Nm", "speed_peak_rpm", "power_peak_W"):
        arrays[key] = np.array([p[key] for p in record["points"]]).reshape(*shape, 4)
    # every point's gait, for scripts that start from it (another solver, a controller)
    arrays["gait_s"] = np.linspace(0.0, 1.0, GAIT_SAMPLES)
    gaits = [sampled_gait(solution) for solution in solutions]
    for key in ("q", "qd", "u"):
        arrays[f"gait_{key}"] = np.stack([g[key] for g in gaits]).reshape(*shape, GAIT_SAMPLES, -1)
    arrays["optimal_step_length_m"] = np.array([np.nan if s is None else s.step_length_m for s in optimal])
    arrays["optimal_cost_per_metre"] = np.array([np.nan if s is None else s.energy_per_metre for s in optimal])
    outputs.save_npz(out / "library.npz", **arrays)
    plot_map(arrays, grid, out / "library_map.png", record["families"])
    plot_drives(record, out / "library_drives.png")
    return record


def plot_map(arrays: dict, grid: LibraryGrid, path: Path, families: list[str]) -> None:
    """J / L over (speed, step length), points that did not converge left blank, with the optimal-L curve
    and each point's start family (``families``, indexed by ``arrays["family_index"]``)."""
    plt = outputs.pyplot()
    figure, axis = plt.subplots(figsize=(7, 5), constrained_layout=True)
    value = np.where(arrays["converged"], arrays["cost_per_metre"], np.nan)
    mesh = axis.pcolormesh(arrays["speeds_mps"], arrays["step_lengths_m"], np.log10(value.T), shading="nearest")
    figure.colorbar(mesh, ax=axis, label="log10 J / L  [N^2 m s]")
    axis.plot(arrays["speeds_mps"], arrays["optimal_step_length_m"], "w-o", label="optimal step length")
    # the start family each point's gait came from: where it changes, so does the cheapest gait family
    v, length = np.meshgrid(arrays["speeds_mps"], arrays["step_lengths_m"], indexing="ij")
    for k, (family, marker) in enumerate(zip(families, "sD^v<>ph*")):
        kept = arrays["family_index"] == k
        if kept.any():
            axis.scatter(v[kept], length[kept], marker=marker, facecolors="none", edgecolors="k", s=40, label=family)
    axis.set_xlabel("speed [m/s]")
    axis.set_ylabel("step length [m]")
    axis.set_title(f"{grid.mass_class}, M_W = {grid.power_limit:g} W: energy per metre")
    axis.legend(loc="upper left", fontsize=8)
    outputs.save_figure(figure, path)
    plt.close(figure)


def plot_drives(record: dict, path: Path) -> None:
    """Peak torque and peak speed per joint against speed, at the optimal step length."""
    plt = outputs.pyplot()
    figure, (torque, speed) = plt.subplots(1, 2, figsize=(11, 4.5), constrained_layout=True)
    rows = [p for p in record["optimal_step"] if p is not None]
    v = [p["speed_mps"] for p in rows]
    for k, joint in enumerate(record["joints"]):
        torque.plot(v, [p["torque_peak_Nm"][k] for p in rows], "-o", label=f"{joint} peak")
        torque.plot(v, [p["torque_rms_Nm"][k] for p in rows], "--", color=torque.lines[-1].get_color(),
                    label=f"{joint} RMS")
        speed.plot(v, [p["speed_peak_rpm"][k] for p in rows], "-o", label=joint)
    torque.set_xlabel("speed [m/s]")
    torque.set_ylabel("joint torque [N m]")
    speed.set_xlabel("speed [m/s]")
    speed.set_ylabel("peak joint speed [rpm]")
    torque.legend(fontsize=8, ncol=2)
    speed.legend(fontsize=8)
    figure.suptitle(f"{record['mass_class']}, M_W = {record['power_limit_W']:g} W: drive demand at the optimal "
                    "step length")
    outputs.save_figure(figure, path)
    plt.close(figure)
