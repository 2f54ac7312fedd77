"""Solving gait problems: many models in one batch of the batched interior point
(:mod:`biped_jax.optim.interior_point`), each solution re-simulated and judged
(:mod:`biped_jax.gait.verdict`: violations in own units, the refinement check, the status) by one
vmapped program per grid for the whole batch; the smallest power limit at which a gait walks.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax import checks
from biped_jax.dynamics import mjx_biped
from biped_jax.gait import problem as gait_problem
from biped_jax.gait import kinds, segmented, verdict
from biped_jax.optim import nlp
from biped_jax.optim import exact_derivatives
from biped_jax.optim import interior_point
from biped_jax.robots.specs import PLANAR_SPECS


#: The interior point's settings for a gait solved from a heuristic start (IPOPT's defaults; a warm
#: start near an optimum may begin from a smaller barrier parameter, ``mu_initial``): a KKT error of
#: 1e-8 in scaled units keeps every constraint group far below 1e-4 in its own unit (the scales in
#: :mod:`biped_jax.gait.problem` are at most 10 own units per scaled unit).
GAIT_SOLVER_OPTIONS = interior_point.InteriorPointOptions()


#: The smallest power limit by the interior point (:meth:`GaitSolver.minimise_power_limit`): stages of
#: min t + (w / J0) J over (x, t), J0 the start's J, for each weight w in turn, every stage from the last
#: one's point and multipliers; the last stage (w = 0) is the epigraph form min t itself. Its linear
#: objective gives the Newton steps no curvature until the multipliers of the active power rows are
#: right, and its optimal gaits are not unique (many gaits reach the same peak power): solved cold it
#: ran off to violations of order one and stopped infeasible (measured 2026-12-04, 48 and 12 spans,
#: M1-M4). With J beside t each stage is well posed, and its optimum and multipliers start the next
#: close to its own; at w = 0.001 the limit is within 0.05 % of the epigraph form's (12 spans, M1-M4).
LIMIT_ENERGY_WEIGHTS = (0.1, 0.01, 0.001, 0.0)
#: Rounds that lower the solve grid's power limit by the excess the refinement check finds between its
#: points (:meth:`GaitSolver.solve`, :meth:`GaitSolver.fastest_gait`): where the limit is active over much
#: of the step the power rises above it between the grid's samples; one round has sufficed in every case
#: measured (the fastest gaits of M1-M4, 2026-12-05).
POWER_TIGHTENING = 3
#: The first barrier parameter of every stage after the first (warm: the barrier's centring term
#: mu m / sum z moves t by about mu times the number m of power rows, 1,544 in the study's grid).
LIMIT_WARM_MU = 1e-4

#: The smallest batch the report's rollouts run as: a smaller batch is padded to it, so that every batch
#: of up to this many problems (the test suite's, the study's refined stage) shares one program per grid;
#: a larger one runs as :func:`~biped_jax.optim.interior_point.padded_batch` problems, as its solve did.
REPORT_BATCH = 8


def report_batch(batch: int) -> int:
    """The number of problems (``batch`` and padding) one report program rolls out at once."""
    return max(REPORT_BATCH, interior_point.padded_batch(batch))


def strongly_typed(leaf) -> jax.Array:
    """``leaf`` as a JAX array of its own dtype, not weakly typed (a weakly typed leaf, from a Python
    float, would compile a second program)."""
    leaf = jnp.asarray(leaf)
    return jnp.asarray(leaf, dtype=leaf.dtype)


def stack_tree(trees: list):
    """A batch (leading dimension B) of pytrees with strong float64 leaves: a weakly typed leaf (from a
    Python float) would compile a second program."""
    return jax.tree.map(lambda *leaves: jnp.asarray(jnp.stack(leaves), dtype=jnp.result_type(float)), *trees)


@dataclasses.dataclass
class GaitSolution:
    """One solved (or not) gait problem, with numpy arrays.

    Attributes:
      name: label (e.g. "M2"). mass_kg, speed_mps, power_limit_W, step_length_m, step_time_s: the problem.
      status: converged, infeasible, stalled, iteration limit or diverged (or grid dependent). cost: J, N^2 m^2 s.
      violations: largest violation per constraint group, own units. max_violation: their maximum
        (mixed units; each is checked against the tolerance in its own unit).
      stationarity: |grad of the Lagrangian|_inf (scaled). outer_iterations, gradients: counts.
      wall_time_s: the batch's solve time. x: the decision vector. trajectory: the simulated step.
      history: per block of the interior point's iterations: cost, scaled violation, KKT error, gradients.
      multipliers_eq, multipliers_in: the solver's multipliers of the scaled constraints at the
        optimum (see :func:`biped_jax.optim.nlp.optimal_value_gradient`).
      refinement: the refinement check (:func:`~biped_jax.gait.verdict.refinement_records`): J and
        violations on a grid ``gait_problem.REFINEMENT`` times finer, the same decision vector.
      starts: from :func:`solve_multistart`, every start's family, status and cost (the spread over
        starts: does the optimum look unique?).
      space: from :func:`biped_jax.gait.spaces.space_check`, J in the gait's space and in a finer one and
        the estimated error of the space.
    """

    name: str
    mass_kg: float
    speed_mps: float
    power_limit_W: float
    step_length_m: float
    step_time_s: float
    status: str
    cost: float
    violations: dict
    max_violation: float
    stationarity: float
    outer_iterations: int
    gradients: int
    wall_time_s: float
    x: np.ndarray
    trajectory: gait_problem.GaitTrajectory
    history: list
    multipliers_eq: np.ndarray
    multipliers_in: np.ndarray
    refinement: dict = dataclasses.field(default_factory=dict)
    starts: list = dataclasses.field(default_factory=list)
    space: dict = dataclasses.field(default_factory=dict)

    @property
    def energy_per_metre(self) -> float:
        """``cost`` per metre walked, J / L (N^2 m s for the paper's J)."""
        return self.cost / self.step_length_m


def _check_weights(energy_weights) -> tuple[float, ...]:
    """The continuation's weights as floats; ValueError naming them unless a non-empty list or tuple of
    finite numbers >= 0."""
    weights = energy_weights if isinstance(energy_weights, (list, tuple)) else ()
    if not weights or not all(isinstance(w, (int, float)) and not isinstance(w, bool) and np.isfinite(w)
                              and w >= 0 for w in weights):
        raise ValueError("energy_weights must be a non-empty list or tuple of numbers >= 0 (the weights of J "
                         f"beside the limit, stage by stage), got {energy_weights!r:.80}")
    return tuple(float(w) for w in weights)


def _merge_rows(rows, again: nlp.SolveResult, before: nlp.SolveResult) -> nlp.SolveResult:
    """``again``'s problems where ``rows`` (B,) bool, ``before``'s elsewhere; counts, time and history of
    both solves."""
    def pick(new, old):
        new, old = np.asarray(new), np.asarray(old)
        return np.where(rows.reshape((-1,) + (1,) * (old.ndim - 1)), new, old)
    fields = ("x", "cost", "equalities", "inequalities", "violation", "stationarity", "multipliers_eq",
              "multipliers_in")
    return dataclasses.replace(
        before, **{f: pick(getattr(again, f), getattr(before, f)) for f in fields},
        status=[a if r else b for r, a, b in zip(rows, again.status, before.status)],
        outer_iterations=before.outer_iterations + np.where(rows, again.outer_iterations, 0),
        gradients=before.gradients + np.where(rows, again.gradients, 0),
        wall_time_s=before.wall_time_s + again.wall_time_s, history=before.history + again.history)


def _check_options(options) -> None:
    """TypeError naming the type unless ``options`` are the interior point's."""
    if not isinstance(options, interior_point.InteriorPointOptions):
        raise TypeError("options must be biped_jax.optim.interior_point.InteriorPointOptions, got "
                        f"{type(options).__name__}")


#: How many sets of programs (one per GaitSettings and mass class template) a process keeps: every
#: :class:`GaitSolver` of the same settings shares one set, so that a second solver (another study's stage,
#: a script's second solver) does not trace and compile them again (about 25 s per problem kind and batch
#: shape at 4 knot spans on 2 cores, even with the compilation cache warm); a sweep over more settings
#: than this lets the least recently used go (their compiled programs with them, unless a solver still
#: holds them).
PROGRAM_SETS = 8


@functools.lru_cache(maxsize=PROGRAM_SETS)
def _programs(settings: gait_problem.GaitSettings, mass_class_template: str) -> dict:
    """The attributes of a :class:`GaitSolver` that depend only on ``settings`` and the template: the
    biped, the problem of every kind, the interior point's programs and colourings (filled on first
    use), the rollout checks and the initial guess."""
    biped = mjx_biped.load_planar_biped(mass_class_template)  # designs replace its masses

    def residuals(x, model):
        trajectory = gait_problem.simulate(x, model, biped, settings)
        equalities, inequalities = gait_problem.scaled_constraints(
            gait_problem.constraint_groups(trajectory, model, settings))
        return gait_problem.cost_residuals(trajectory, model.drives), equalities, inequalities

    # every kind of the problem (biped_jax.gait.kinds): the energy one in x, the others with their
    # columns beside x (the power limit, the step length, the speed)
    problems = {kind: kinds.kind_problem(kind, residuals, settings.size) for kind in kinds.KINDS}
    refined_settings = gait_problem.refined(settings)
    leg_length = PLANAR_SPECS[mass_class_template].leg_length
    return dict(
        biped=biped, leg_length=leg_length, problems=problems, problem=problems["energy"],
        limit_problem=problems["limit"], step_problem=problems["step"], speed_problem=problems["speed"],
        _interior={},     # (problem kind, options) -> the interior point's compiled programs
        _structures={},   # problem kind -> (the problem as the interior point sees it, its colouring)
        refined_settings=refined_settings,
        # the report's rollouts and verdict numbers, a batch per call: one program per grid and report_batch
        _checks={grid: jax.jit(jax.vmap(functools.partial(verdict.rollout_check, biped=biped, settings=grid)))
                 for grid in (settings, refined_settings)},
        _initial_guess=jax.jit(jax.vmap(functools.partial(gait_problem.initial_guess, settings=settings,
                                                          leg_length=leg_length))))


class GaitSolver:
    """Compiles once per :class:`~biped_jax.gait.problem.GaitSettings` and solves batches of models.

    Every solver of the same settings and mass-class template shares one set of programs (traced and
    compiled on first use) for the life of the process, whatever its options.

    ``require_refinement=False`` reports the refinement check without letting it decide the status:
    for the test suite's deliberately coarse grids (4 knot spans), where a gait solved on its grid is
    what the tests need and the check's figures are still recorded. ``check_refinement=False`` skips
    the check altogether (its rollout is then never compiled; ``refinement`` reads ``{"skipped": True}``):
    for a stage whose results only choose starts, such as the multistart's coarse space. Every reported
    solution has the check.
    """

    def __init__(self, settings: gait_problem.GaitSettings = gait_problem.GaitSettings(),
                 options: interior_point.InteriorPointOptions = GAIT_SOLVER_OPTIONS, mass_class_template: str = "12kg",
                 require_refinement: bool = True, check_refinement: bool = True):
        if not isinstance(settings, gait_problem.GaitSettings):
            raise TypeError(f"settings must be a GaitSettings, got {type(settings).__name__}")
        _check_options(options)
        self.settings, self.options = settings, options
        self.require_refinement = require_refinement and check_refinement
        self.check_refinement = check_refinement
        self.mass_class = mass_class_template
        # every solver of these settings and template shares one set of programs in this process
        self.__dict__.update(_programs(settings, mass_class_template))

    def with_options(self, **changes) -> "GaitSolver":
        """A solver sharing this one's compiled functions with other interior-point options."""
        return self.using(dataclasses.replace(self.options, **changes))

    def using(self, options: interior_point.InteriorPointOptions) -> "GaitSolver":
        """A solver sharing this one's compiled functions with ``options`` (options that change only the
        iteration count or the barrier's start share the compiled iterations too)."""
        _check_options(options)
        other = object.__new__(GaitSolver)
        other.__dict__.update(self.__dict__)
        other.options = options
        return other

    def _interior_point(self, kind: str, x0, batch, progress, multipliers=None, options=None) -> nlp.SolveResult:
        """The batched interior point on the energy problem (``kind`` "energy"), the smallest power
        limit's ("limit") or the free step length's ("step"), its colouring probed at the first
        problem's start and its programs compiled on first use, both kept for later batches of the same
        shape."""
        problem, structure = self.prepared(kind, x0, batch)
        options = options or self.options
        key = (kind, interior_point.loop_options(options))
        if key not in self._interior:
            self._interior[key] = interior_point.compile_problem(problem, options)
        return interior_point.solve(problem, x0, batch, options, structure=structure,
                        compiled=self._interior[key], multipliers=multipliers, progress=progress)

    def prepared(self, kind: str, x0, batch) -> tuple[nlp.ConstrainedProblem, exact_derivatives.Structure]:
        """(the problem as the interior point sees it, its colouring) for ``kind`` "energy", "limit",
        "step" or "speed", made on first use and kept. With several shooting segments the derivatives
        come from the split by segment (:func:`biped_jax.gait.segmented.local_problem`) and no colouring
        is probed: a segment's rows read its l columns (its node and the control points that reach it),
        its end's defect all of them, so a colouring of the whole problem needs at least l directions
        (measured: 32 to 48 against l = 20, from 4 to 96 knot spans), and its probe, 2 n evaluations of
        the problem, took 26 s at 96 spans on 2 cores. With one segment the colouring is probed at the
        first problem of ``x0`` (B, n) and ``batch``."""
        if kind not in self._structures:
            problem = self.problems[kind]
            if self.settings.segments > 1:
                problem = dataclasses.replace(problem, local=segmented.local_problem(self.biped, self.settings, kind))
                structure = exact_derivatives.unused_structure(x0.shape[1])
            else:
                first = jax.tree.map(lambda a: a[0], batch)
                structure = exact_derivatives.probe_structure(
                    problem, np.asarray(x0[0]), first,
                    linear_columns=(x0.shape[1] - 1,) if kinds.KINDS[kind].linear else ())
            self._structures[kind] = (problem, structure)
        return self._structures[kind]

    def check(self, x, models: gait_problem.GaitModel, refined: bool = False) -> verdict.GridCheck:
        """The batch ``x`` (B, n) re-simulated on the solve grid (``refined``: the refinement check's,
        ``gait_problem.REFINEMENT`` times finer) with every group's violation, J and finiteness, in one vmapped
        program (batches padded to :func:`report_batch`, sharded over the devices as the solve's);
        ``models`` with leading dimension B. Numpy leaves with leading dimension B."""
        x = jnp.asarray(x, dtype=jnp.result_type(float))
        batch = x.shape[0]
        size = report_batch(batch)
        # strongly typed leaves padded with copies of the first row: one program whatever the batch
        x, models = jax.tree.map(lambda a: interior_point.pad_rows(strongly_typed(a), size), (x, models))
        sharding = interior_point.batch_sharding(size)
        if sharding is not None:
            x, models = jax.device_put((x, models), sharding)
        checked = self._checks[self.refined_settings if refined else self.settings](x, models)
        return jax.tree.map(lambda a: np.asarray(a)[:batch], checked)

    def simulate(self, x, models: gait_problem.GaitModel) -> gait_problem.GaitTrajectory:
        """Batched rollout: x (B, n), models with leading dimension B; numpy leaves (B, ...)."""
        return self.check(x, models).trajectory

    def simulate_refined(self, x, models: gait_problem.GaitModel) -> gait_problem.GaitTrajectory:
        """:meth:`simulate` on the refinement check's grid (4x finer)."""
        return self.check(x, models, refined=True).trajectory

    def check_batch(self, names, models, x0=None, multipliers=None) -> np.ndarray | None:
        """Checks a batch before anything compiles: ``names`` a non-empty list of labels, ``models`` as
        many :class:`~biped_jax.gait.problem.GaitModel`, ``x0`` None or finite of shape (B, n) with
        n = ``settings.size``, ``multipliers`` None or (equalities (B, m_h), inequalities (B, m_g)).
        Raises TypeError / ValueError naming the argument; returns x0 as a numpy array (or None)."""
        names = checks.sequence("names", names, str, "label (str)")
        models = checks.sequence("models", models, gait_problem.GaitModel, "GaitModel (from gait_model)")
        size = checks.same_length(names=names, models=models)
        n = self.settings.size
        if x0 is not None:
            x0 = checks.finite_array("x0", x0, (size, n),
                                     f": one start per model, each of length settings.size = {n}")
        if multipliers is not None:
            if not isinstance(multipliers, (list, tuple)) or len(multipliers) != 2:
                raise TypeError("multipliers must be a pair (equalities (B, m_h), inequalities (B, m_g)), got "
                                f"{type(multipliers).__name__}")
            for label, value in zip(("multipliers[0] (equalities)", "multipliers[1] (inequalities)"), multipliers):
                checks.finite_array(label, value, (size, None), ": one row per model")
        return x0

    def solve(self, names: list[str], models: list[gait_problem.GaitModel], x0=None,
              progress: Callable[[int, dict], None] | None = None, multipliers=None,
              tightening: int | None = None) -> list[GaitSolution]:
        """Solves every model in one batch (one compiled program); x0 (B, n) warm-starts, and so do
        ``multipliers`` (equalities (B, m_h), inequalities (B, m_g): those of solutions of the same
        space, such as a neighbouring problem's). ``progress`` gets (iteration, row of (B,) arrays:
        "cost", "violation", "error", "done") after every block of iterations.

        A converged gait whose power exceeds its limit between the grid's samples (the refinement
        check's power group fails) is solved again, warm, with the limit on the solve grid lowered by
        that excess, up to ``tightening`` rounds (None: :data:`POWER_TIGHTENING` where the check
        decides the status, none where it is only recorded); ``refinement["solve_grid_power_limit_W"]``
        holds the limit posed on the solve grid (the model's own where no round ran)."""
        x0 = self.check_batch(names, models, x0, multipliers)
        rounds = self._tightening_rounds(tightening)
        batch = stack_tree(models)
        x0 = self._initial_guess(batch) if x0 is None else jnp.asarray(x0)
        result = self._interior_point("energy", x0, batch, progress, multipliers)
        result, posed, checked = self._hold_power_between_samples(
            "energy", result, lambda r: (r.x, batch),
            lambda limit: dataclasses.replace(batch, power_limit=jnp.asarray(limit)), np.asarray(batch.power_limit),
            rounds, progress, dataclasses.replace(self.options, mu_initial=LIMIT_WARM_MU))
        return self._with_posed_limit(self._report(names, batch, result, checked=checked), posed)

    def minimise_power_limit(self, names: list[str], models: list[gait_problem.GaitModel], x0,
                             progress: Callable[[int, dict], None] | None = None,
                             energy_weights: tuple = LIMIT_ENERGY_WEIGHTS) -> list[GaitSolution]:
        """The smallest power limit M_W at which each model walks: the interior point (all models in one
        batch) on (x, t = M_W / M_W0) minimising the limit (the epigraph form of the smallest
        largest joint power |qdot u| over feasible gaits), from ``x0`` (B, n), gaits feasible at the
        models' own limits M_W0. It runs :data:`LIMIT_ENERGY_WEIGHTS` (or
        ``energy_weights``: non-negative, the last normally 0) as a continuation: min t + (w / J0) J
        for each weight w in turn; with a last weight of 0 a converged result is a KKT point of the
        epigraph form min t, its multipliers those of that problem.

        Returns per model the gait found, as a :class:`GaitSolution` at the limit it keeps on both
        grids: ``power_limit_W`` is the larger of the limit reached on the solve grid (in
        ``refinement["solve_grid_limit_W"]``) and the gait's largest joint power on the refinement
        grid (the former alone for a solver without the refinement check), so that its status reads
        whether it is feasible (and grid independent) there; ``cost``
        is that gait's J (not minimised); the multipliers are those of the limit problem."""
        if x0 is None:
            raise ValueError("x0 is None: minimise_power_limit starts from gaits feasible at the models' "
                             "own limits, shape (B, n) (e.g. the x of solve()'s solutions, stacked)")
        x0 = self.check_batch(names, models, x0)
        weights = _check_weights(energy_weights)
        batch = stack_tree(models)
        start = np.concatenate([x0, np.ones((len(models), 1))], axis=1)
        result = self._continuation("limit", start, lambda w: gait_problem.LimitParams(batch, w),
                                    self.check(x0, batch).energy, progress, weights)
        x = result.x[:, :-1]
        solve_grid = result.x[:, -1] * np.asarray(batch.power_limit)
        limits, fine = solve_grid, None
        if self.check_refinement:
            # one refined rollout serves both the limit and the check: only the power group's violation
            # depends on the limit, and it is judged again at the limit kept
            fine = self.check(x, batch, refined=True)
            peak = np.max(np.abs(fine.trajectory.joint_power), axis=(1, 2))
            limits = np.maximum(solve_grid, peak)
            fine = dataclasses.replace(fine, violations={**fine.violations,
                                                         "power_limit": np.maximum(peak - limits, 0.0)})
        at_limit = dataclasses.replace(batch, power_limit=jnp.asarray(limits, dtype=jnp.result_type(float)))
        # J (not minimised here) is the re-simulated gait's; it does not depend on the limit
        solutions = self._report(names, at_limit, dataclasses.replace(result, x=x), cost_of_rollout=True,
                                 checked=(None, fine))
        for solution, limit in zip(solutions, solve_grid):
            solution.refinement["solve_grid_limit_W"] = float(limit)
        return solutions

    def solve_step_length(self, names: list[str], models: list[gait_problem.GaitModel], bounds,
                          x0=None, progress: Callable[[int, dict], None] | None = None) -> list[GaitSolution]:
        """The step length as a decision variable: for each model the gait and step length L within
        ``bounds`` (low, high) in m minimising the energy per metre J(L) / L at the model's speed, all
        models in one batch of the interior point on (x, l = L / L0), L0 each model's own step length
        (the start's; low <= L0 <= high). Every constraint moves with L: the touchdown's position, the
        step time L / v, so the clearance, impact and periodicity rows. ``x0`` (B, n): starts at L0
        (e.g. the x of :meth:`solve`'s solutions); None starts from the heuristic gait.

        Returns per model a :class:`GaitSolution` at the step length found (``step_length_m``,
        ``step_time_s``), ``cost`` that step's J (its :attr:`GaitSolution.energy_per_metre` the
        objective), judged and refinement-checked as :meth:`solve`'s; the multipliers are those of
        the problem in (x, l), the bounds' two last."""
        x0 = self.check_batch(names, models, x0)
        low, high = gait_problem.check_step_bounds(bounds, [float(m.step_length) for m in models], self.mass_class)
        batch = stack_tree(models)
        x0 = np.asarray(self._initial_guess(batch)) if x0 is None else x0
        start = np.concatenate([x0, np.ones((len(models), 1))], axis=1)
        lengths = np.asarray(batch.step_length)
        params = gait_problem.StepParams(batch, jnp.asarray(low / lengths), jnp.asarray(high / lengths))
        result = self._interior_point("step", jnp.asarray(start), params, progress)
        at_step = dataclasses.replace(batch, step_length=jnp.asarray(lengths * result.x[:, -1]))
        # J is the re-simulated step's at the length found (the objective is J / l)
        return self._report(names, at_step, dataclasses.replace(result, x=result.x[:, :-1]), cost_of_rollout=True)

    def fastest_gait(self, names: list[str], models: list[gait_problem.GaitModel], x0, bounds,
                     progress: Callable[[int, dict], None] | None = None,
                     energy_weights: tuple = LIMIT_ENERGY_WEIGHTS, tightening: int | None = None) -> list[GaitSolution]:
        """The fastest gait of each model: the largest speed v at which it walks within every
        constraint at its own power limit (and with real drives their supply voltage, and with
        ``settings.drive_limits`` the gears' limits), the step length L free within ``bounds`` (low,
        high) in m. The interior point (all models in one batch) on (x, l, c) with L = l L0 and
        v = v0 / c (L0, v0: each model's own; c, the pace relative to v0, minimised: max v), from ``x0``
        (B, n), gaits feasible at (L0, v0) such as :meth:`solve`'s, as a continuation over
        ``energy_weights`` (:data:`LIMIT_ENERGY_WEIGHTS`): min c + (w / E0) J / l for each w in turn,
        the last normally 0, whose converged result is a KKT point of max v itself (its multipliers
        those of that problem). v is bounded by :data:`biped_jax.gait.kinds.SPEED_CAP`.

        At the fastest gait the power limit is active over much of the step, and between the solve
        grid's points the power rises above it. Up to ``tightening`` rounds (None: as :meth:`solve`'s)
        then solve max v again (warm) with the limit on the solve grid lowered by the excess the 4x finer
        grid found (M_W,k+1 = M_W,k M_W / (M_W + excess)), so that the gait keeps M_W between the grid
        points too; ``refinement["solve_grid_power_limit_W"]`` holds the limit the last round
        posed on the solve grid (the model's own where no round ran).

        Returns per model a :class:`GaitSolution` at the speed and step length found (``speed_mps``,
        ``step_length_m``, ``step_time_s``) and at the model's own power limit, ``cost`` that gait's J
        (not minimised), judged and refinement-checked as :meth:`solve`'s."""
        if x0 is None:
            raise ValueError("x0 is None: fastest_gait starts from gaits feasible at the models' own speed and "
                             "step length, shape (B, n) (e.g. the x of solve()'s solutions, stacked)")
        x0 = self.check_batch(names, models, x0)
        weights = _check_weights(energy_weights)
        rounds = self._tightening_rounds(tightening)
        low, high = gait_problem.check_step_bounds(bounds, [float(m.step_length) for m in models], self.mass_class)
        batch = stack_tree(models)
        lengths, speeds = np.asarray(batch.step_length), np.asarray(batch.speed)
        own_limit = np.asarray(batch.power_limit)

        def params_at(limit, weight):
            posed = dataclasses.replace(batch, power_limit=jnp.asarray(limit))
            return gait_problem.SpeedParams(posed, jnp.asarray(low / lengths), jnp.asarray(high / lengths), weight)

        start = np.concatenate([x0, np.ones((len(models), 2))], axis=1)
        result = self._continuation("speed", start, functools.partial(params_at, own_limit),
                                    self.check(x0, batch).energy, progress, weights)

        def found_models(result):
            return dataclasses.replace(batch, step_length=jnp.asarray(lengths * result.x[:, -2]),
                                       speed=jnp.asarray(speeds / result.x[:, -1]))
        options = dataclasses.replace(self.options, mu_based_multipliers=True, mu_initial=LIMIT_WARM_MU)
        result, posed, checked = self._hold_power_between_samples(
            "speed", result, lambda r: (r.x[:, :-2], found_models(r)),
            lambda limit: params_at(limit, jnp.zeros(len(models))), own_limit, rounds, progress, options)
        solutions = self._report(names, found_models(result), dataclasses.replace(result, x=result.x[:, :-2]),
                                 cost_of_rollout=True, checked=checked)
        return self._with_posed_limit(solutions, posed)

    def _tightening_rounds(self, tightening: int | None) -> int:
        """The rounds of :meth:`_hold_power_between_samples` asked for (None: the default, see :meth:`solve`)."""
        if tightening is None:
            return POWER_TIGHTENING if self.require_refinement else 0
        checks.integer_in("tightening", tightening, 0, 10)
        if tightening and not self.check_refinement:
            raise ValueError(f"tightening={tightening} needs the refinement check, which this solver skips "
                             "(check_refinement=False): pass tightening=0")
        return tightening

    def _hold_power_between_samples(self, kind: str, result: nlp.SolveResult, gait_of, params_at, own_limit,
                                    rounds: int, progress, options) -> tuple:
        """The power limit held between the solve grid's samples, for ``kind``'s converged problems:
        each round re-simulates the gaits (``gait_of(result)`` -> (x (B, n), models at their own limits))
        on both grids and, where the refinement check fails on the power limit alone (another failed
        check would leave the gait grid dependent whatever the limit), solves the problem again warm
        (``options``) with the limit on the solve grid lowered by the excess between its samples,
        M_k+1 = M_k M_W / (M_W + excess) (``params_at(limits (B,))``: the kind's params posing them).
        The smallest power limit's problem needs no rounds: scaling its limit scales its optimum t and
        leaves its gait unchanged.

        Returns (result, the limits last posed (B,) W, the checks of the result's gaits on the solve
        grid and on the refinement grid (None, None without the refinement check))."""
        posed = np.asarray(own_limit, dtype=float)
        if not self.check_refinement:
            return result, posed, (None, None)
        for round_ in range(rounds + 1):
            x, models = gait_of(result)
            coarse, fine = self.check(x, models), self.check(x, models, refined=True)
            records = verdict.refinement_records(coarse.energy, fine, own_limit, self.refined_settings.steps)
            tighten = np.array([s == nlp.CONVERGED and verdict.power_alone(r)
                                for s, r in zip(result.status, records)])
            if round_ == rounds or not tighten.any():
                break
            excess = np.asarray(fine.violations["power_limit"])
            posed = np.where(tighten, posed * own_limit / (own_limit + excess), posed)
            again = self._interior_point(kind, jnp.asarray(result.x), params_at(posed), progress,
                                         (result.multipliers_eq, result.multipliers_in), options)
            result = _merge_rows(tighten, again, result)
        return result, posed, (coarse, fine)

    @staticmethod
    def _with_posed_limit(solutions: list[GaitSolution], posed) -> list[GaitSolution]:
        for solution, limit in zip(solutions, posed):
            solution.refinement["solve_grid_power_limit_W"] = float(limit)
        return solutions

    def _continuation(self, kind: str, start, params_at, j0, progress, energy_weights) -> nlp.SolveResult:
        """The interior point on a linear kind's min c + (w_k / J0) E over (x, extra) (c its last
        column, E its energy) for each w_k of ``energy_weights`` in turn (J0 (B,): each start's energy),
        every stage from the last one's point and multipliers; ``params_at(weights (B,))`` the kind's
        params. The result is the last stage's, with the iterations, derivative passes and time of all."""
        point, multipliers, stages = jnp.asarray(start), None, []
        # multipliers mu / s where none are known: z = 1 on some 1,500 power rows would weigh the
        # Hessian with a thousand times the curvature the optimum's few active rows carry
        first = dataclasses.replace(self.options, mu_based_multipliers=True)
        for k, weight in enumerate(energy_weights):
            params = params_at(jnp.asarray(weight / j0, dtype=jnp.result_type(float)))
            options = first if k == 0 else dataclasses.replace(first, mu_initial=LIMIT_WARM_MU)
            if progress:
                stage = lambda i, row, w=weight: progress(i, {**row, "energy_weight": w})  # noqa: E731
            result = self._interior_point(kind, point, params, progress and stage, multipliers, options)
            stages.append(result)
            point, multipliers = jnp.asarray(result.x), (result.multipliers_eq, result.multipliers_in)
        last = stages[-1]
        return dataclasses.replace(
            last, outer_iterations=sum(r.outer_iterations for r in stages),
            gradients=sum(r.gradients for r in stages), wall_time_s=sum(r.wall_time_s for r in stages),
            history=[row for r in stages for row in r.history])

    def _report(self, names: list[str], batch: gait_problem.GaitModel, result: nlp.SolveResult,
                cost_of_rollout: bool = False, checked: tuple = (None, None)) -> list[GaitSolution]:
        """GaitSolutions of a solver result on the models ``batch`` (leading dimension B): the batch
        re-simulated and checked on the refined grid by one program per grid, classified, then cut
        into one solution per problem. ``cost_of_rollout``: J is the re-simulated gait's, not the
        solver's objective. ``checked``: (the solve grid's, the refined grid's)
        :class:`~biped_jax.gait.verdict.GridCheck` of ``result.x`` where the caller has them (None:
        made here)."""
        coarse, fine = checked
        if coarse is None:
            coarse = self.check(result.x, batch)
        if fine is None and self.check_refinement:
            fine = self.check(result.x, batch, refined=True)
        numeric = jax.tree.map(np.asarray, batch)
        cost = coarse.energy if cost_of_rollout else np.asarray(result.cost)
        if fine is None:
            records = [{"skipped": True, "passed": None} for _ in names]
        else:
            records = verdict.refinement_records(cost, fine, numeric.power_limit, self.refined_settings.steps)
        mass = np.asarray(numeric.design.total_mass)
        history = [{k: np.asarray(v, dtype=float) for k, v in row.items() if k != "x"} for row in result.history]
        solutions = []
        for b, name in enumerate(names):
            violations = {k: float(v[b]) for k, v in coarse.violations.items()}
            status = verdict.classify(result.status[b], bool(coarse.finite[b]), violations, records[b],
                                      self.require_refinement)
            solutions.append(GaitSolution(
                name=name, mass_kg=float(mass[b]), speed_mps=float(numeric.speed[b]),
                power_limit_W=float(numeric.power_limit[b]), step_length_m=float(numeric.step_length[b]),
                step_time_s=float(numeric.step_length[b] / numeric.speed[b]), status=status,
                cost=float(cost[b]), violations=violations,
                max_violation=max(violations.values()), stationarity=float(result.stationarity[b]),
                outer_iterations=int(result.outer_iterations[b]), gradients=int(result.gradients[b]),
                wall_time_s=result.wall_time_s, x=np.asarray(result.x[b]),
                trajectory=jax.tree.map(lambda a: a[b], coarse.trajectory),
                history=[{k: float(v[b]) for k, v in row.items()} for row in history],
                multipliers_eq=result.multipliers_eq[b], multipliers_in=result.multipliers_in[b],
                refinement=records[b]))
        return solutions
