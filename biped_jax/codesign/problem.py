"""Co-design of the sagittal biped: gear ratios, windings and link masses with the gait, motor in the loop.

A :class:`DriveDesign` is the hardware as arrays (traced, batchable with ``vmap``): per actuated joint
(H1, K1, H2, K2) a gear of ratio N and a motor winding, and the structural mass of each link. It maps
to the gait problem (:func:`gait_model`) as

- reflected inertia N^2 (J_rotor + J_gear) as the joint's armature in the MJX model;
- motor and gear mass as a point mass at the joint on the link carrying the drive (both hip drives in
  the torso, each knee drive at the knee end of its thigh; ``biped_jax.robots.design``);
- the objective: the Joule energy integral of R i^2 with i = T_m / k_t and T_m the motor torque
  through the gear (eq. 2.3, efficiency both ways); for identical drives it is a constant times the
  paper's integral of u^T u;
- the voltage limit: every operating point under the speed-torque line at the supply voltage, an
  augmented-Lagrangian constraint beside the power limit |qdot u| <= M_W.

So one compiled gait program (``GaitSolver``) solves any batch of designs, and the paper's problem is
the special case of ideal drives. Gradients of the optimal Joule energy with respect to the design come
from the envelope theorem (:func:`biped_jax.optim.augmented_lagrangian.optimal_value_gradient`): at a
converged gait, one gradient of the Lagrangian with the solver's multipliers (SLSQP's, see
:data:`SOLVER_OPTIONS`), no differentiation through the solver. Chosen over implicit differentiation
of the KKT system (needs the Lagrangian's Hessian through the rollout: a second-order program that
compiles for minutes on a small CPU) and over design variables as extra decision variables (couples
every design into one larger, worse conditioned gait problem and loses the warm-started independent
solves).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax import checks
from biped_jax.drives import model as drive_model
from biped_jax.dynamics import hybrid_step as hs
from biped_jax.gait import problem as gait
from biped_jax.gait.solver import stack_tree
from biped_jax.optim import augmented_lagrangian as al
from biped_jax.optim import sqp
from biped_jax.robots.design import PLANAR_DRIVE_MOUNTS, PLANAR_LINKS, Design, check_design

#: The paper's drive for the 12 kg robot (Section 2.3): the 42 V RE 25 winding, GP 32 A 66:1, 38 V supply.
REFERENCE_MOTOR, REFERENCE_GEARHEAD = "RE25-42V", "GP32A-66.22"
#: The co-design's gait solver: SLSQP (one design after another), as the study's. The batched augmented
#: Lagrangian (``GaitSolver``'s default) stops at a stationarity of 1e-2, and there neighbouring designs
#: land on different local optima: measured 2026-12-02 on the tests' 4-span grid at 66:1 * exp(+-0.03),
#: its J* were 5.24 / 5.80 / 4.64 with the gaits 0.58-0.66 rad apart, so the envelope gradient (-10.8 per
#: log N) and the difference of the optima disagreed; SLSQP's optima of the same three designs are
#: 5.789 / 5.472 / 5.174, 0.026 rad apart, and its multipliers give -10.240 against the difference's
#: -10.248. The iteration cap bounds a design without a gait (a too-high speed in a bisection).
SOLVER_OPTIONS = sqp.SQPOptions(max_iterations=300)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class DriveDesign:
    """The hardware of the sagittal biped (SI units; per-joint arrays in (H1, K1, H2, K2) order).

    Attributes:
      ratio: gear ratio N, (4,). gear_efficiency: eta, (4,). gear_inertia: referred to the motor
        side, kg m^2, (4,). gear_mass: kg, (4,).
      torque_constant: k_t, N m/A, (4,). resistance: R, ohm, (4,). rotor_inertia: kg m^2, (4,).
        motor_mass: kg, (4,).
      structure_mass: the links without drives (torso, thigh1, shank1, thigh2, shank2), kg, (5,).
      supply_voltage: V_s, V, ().
    """

    ratio: jax.Array
    gear_efficiency: jax.Array
    gear_inertia: jax.Array
    gear_mass: jax.Array
    torque_constant: jax.Array
    resistance: jax.Array
    rotor_inertia: jax.Array
    motor_mass: jax.Array
    structure_mass: jax.Array
    supply_voltage: jax.Array

    @property
    def total_mass(self) -> jax.Array:
        """Structure plus drives, kg."""
        return (jnp.sum(self.structure_mass, axis=-1) + jnp.sum(self.gear_mass, axis=-1)
                + jnp.sum(self.motor_mass, axis=-1))


def reflected_inertia(design: DriveDesign) -> jax.Array:
    """N^2 (J_rotor + J_gear) per joint, kg m^2, (4,): the drive's inertia seen at the joint."""
    return drive_model.reflected_inertia(design.ratio, design.rotor_inertia, design.gear_inertia)


def robot_design(design: DriveDesign) -> Design:
    """The MJX model's design arrays: structure masses, armature N^2 J, drive masses at the joints.
    A concrete design is checked (ValueError naming a non-positive or non-finite mass)."""
    result = Design(link_mass=design.structure_mass, joint_armature=reflected_inertia(design),
                    joint_damping=jnp.zeros_like(design.ratio),
                    drive_mass=design.motor_mass + design.gear_mass)
    if checks.concrete(design):
        check_design(result, hs.planar_layouts()[0])
    return result


def joint_drives(design: DriveDesign) -> drive_model.JointDrives:
    """The drives as the gait problem sees them (objective: Joule energy; constraint: voltage; the
    gear's torque is bounded by the gait's own torque bound, so no gear limit here)."""
    return drive_model.JointDrives(ratio=design.ratio, efficiency=design.gear_efficiency,
                                   torque_constant=design.torque_constant, resistance=design.resistance,
                                   supply_voltage=design.supply_voltage,
                                   gear_torque_limit=jnp.full_like(design.ratio, jnp.inf),
                                   reflected_inertia=reflected_inertia(design))


def gait_model(design: DriveDesign, speed, power_limit, step_length=0.2) -> gait.GaitModel:
    """The gait problem of a design (traceable: ``speed`` etc. may be arrays). The geometry is that of
    the paper's biped (planar-step.md); masses and drives come from ``design``. Concrete values are
    checked (:func:`biped_jax.gait.problem.check_problem`)."""
    if checks.concrete(speed, power_limit, step_length):
        gait.check_problem(speed, power_limit, step_length)
    return gait.GaitModel(design=robot_design(design), speed=jnp.asarray(speed, float),
                          step_length=jnp.asarray(step_length, float),
                          power_limit=jnp.asarray(power_limit, float), drives=joint_drives(design))


# ----------------------------------------------------------------------------- catalogue designs

def _structure_of(mass_class: str, drive_mass: float) -> np.ndarray:
    """The mass class's link masses with four drives of ``drive_mass`` taken out of the links that
    carry them, kg, (5,): the robot weighs its nominal mass with those drives fitted."""
    structure = np.asarray(hs.planar_design(mass_class).link_mass, dtype=float).copy()
    for mount in PLANAR_DRIVE_MOUNTS:
        structure[PLANAR_LINKS.index(mount)] -= drive_mass
    if np.any(structure <= 0):
        raise ValueError(f"drives of {drive_mass} kg each leave no structure in the {mass_class} biped")
    return structure


def catalogue_design(motor: str = REFERENCE_MOTOR, gearhead: str | tuple[str, ...] = REFERENCE_GEARHEAD,
                     mass_class: str = "12kg", total_mass: float | None = None,
                     supply_voltage: float | None = None,
                     catalogue: drive_model.Catalogue | None = None) -> DriveDesign:
    """A catalogue motor at all four joints with one gearhead, or one per joint (a tuple of four names
    in (H1, K1, H2, K2) order).

    The structure is the mass class's links less the reference drives (so the reference design weighs
    the nominal 12 or 18 kg); ``total_mass`` (kg) scales the structure uniformly to reach that total.
    ``supply_voltage`` defaults to the catalogue's (the paper's 38 V). Raises ValueError naming an
    unknown part or an unreachable total mass.
    """
    catalogue = catalogue or drive_model.load_catalogue()
    m = catalogue.motor(motor)
    names = (gearhead,) * 4 if isinstance(gearhead, str) else tuple(gearhead)
    if len(names) != 4:
        raise ValueError(f"give one gearhead or four (H1, K1, H2, K2), got {gearhead!r}")
    heads = [catalogue.gearhead(name) for name in names]
    reference = catalogue.motor(REFERENCE_MOTOR).mass + catalogue.gearhead(REFERENCE_GEARHEAD).mass
    structure = _structure_of(mass_class, reference)
    drives_mass = 4 * m.mass + sum(h.mass for h in heads)
    if total_mass is not None:
        if not (math.isfinite(total_mass) and total_mass > drives_mass):
            raise ValueError(f"total_mass must exceed the drives' {drives_mass:.2f} kg, got {total_mass!r}")
        structure = structure * (total_mass - drives_mass) / structure.sum()
    four = lambda value: jnp.full(4, float(value))  # noqa: E731
    voltage = catalogue.supply_voltage if supply_voltage is None else supply_voltage
    if not (math.isfinite(voltage) and voltage > 0):
        raise ValueError(f"supply_voltage must be positive, got {voltage!r}")
    per_joint = lambda field: jnp.array([getattr(h, field) for h in heads], dtype=float)  # noqa: E731
    return DriveDesign(ratio=per_joint("ratio"), gear_efficiency=per_joint("efficiency"),
                       gear_inertia=per_joint("inertia"), gear_mass=per_joint("mass"),
                       torque_constant=four(m.torque_constant),
                       resistance=four(m.resistance), rotor_inertia=four(m.rotor_inertia),
                       motor_mass=four(m.mass), structure_mass=jnp.asarray(structure),
                       supply_voltage=jnp.asarray(float(voltage)))


# ----------------------------------------------------------------------------- continuous gear ratio

def _stage_table(catalogue: drive_model.Catalogue):
    """Per gearhead stage: geometric-mean ratio, efficiency, inertia, mass (numpy, ascending ratio)."""
    stages = {}
    for g in catalogue.gearheads.values():
        stages.setdefault(g.stages, []).append(g)
    rows = []
    for _, heads in sorted(stages.items()):
        ratios = np.array([h.ratio for h in heads])
        rows.append((math.exp(np.mean(np.log(ratios))), heads[0].efficiency, heads[0].inertia, heads[0].mass))
    return np.array(rows)


def with_ratio(design: DriveDesign, log_ratio: jax.Array,
               catalogue: drive_model.Catalogue | None = None) -> DriveDesign:
    """``design`` with gear ratios exp(log_ratio) ((4,), traceable) and the gear's efficiency, inertia
    and mass interpolated linearly in log N between the GP 32 A stages (at each stage's geometric-mean
    ratio): a smooth stand-in for the stage steps, so the ratio can be a continuous design variable.
    Catalogue designs (:func:`catalogue_design`) carry the exact data of their gearhead."""
    table = _stage_table(catalogue or drive_model.load_catalogue())
    log_stage = jnp.log(table[:, 0])
    interpolate = lambda column: jnp.interp(log_ratio, log_stage, jnp.asarray(table[:, column]))  # noqa: E731
    return dataclasses.replace(design, ratio=jnp.exp(log_ratio), gear_efficiency=interpolate(1),
                               gear_inertia=interpolate(2), gear_mass=interpolate(3))


def nearest_gearhead(ratio: float, catalogue: drive_model.Catalogue | None = None) -> str:
    """The catalogue gearhead whose ratio is nearest to ``ratio`` in log scale; ValueError for a ratio
    more than a factor 2 outside the catalogue's range (no gearhead is near it)."""
    catalogue = catalogue or drive_model.load_catalogue()
    drive_model.check_ratio(ratio)
    ratios = [g.ratio for g in catalogue.gearheads.values()]
    if not 0.5 * min(ratios) <= ratio <= 2 * max(ratios):
        raise ValueError(f"gear ratio {ratio!r} is far outside the catalogue's {min(ratios):g}-{max(ratios):g}: "
                         "no gearhead is near it")
    return min(catalogue.gearheads.values(), key=lambda g: abs(math.log(g.ratio / ratio))).part


def stack(designs: list[DriveDesign]) -> DriveDesign:
    """A batch (leading dimension B) of designs."""
    return stack_tree(designs)


def unstack(designs: DriveDesign) -> list[DriveDesign]:
    size = designs.supply_voltage.shape[0]
    return [jax.tree.map(lambda a: a[b], designs) for b in range(size)]


# ----------------------------------------------------------------------------- batch evaluation

def solve_designs(solver, designs: list[DriveDesign], speed, power_limit, step_length=0.2, x0=None,
                  names: list[str] | None = None, progress=None,
                  summary: Callable[[str], None] | None = None) -> list:
    """Solves the gait of every design in one batch (one compiled program per batch size).

    ``speed`` (m/s), ``power_limit`` (W) and ``step_length`` (m) are scalars or one value per design;
    x0 (B, n) warm-starts (e.g. a solved reference gait repeated). Returns ``GaitSolution``s whose cost
    is the Joule energy (J), with status and per-group violations (the voltage limit among them);
    ``summary`` receives one line on the batch (statuses, gradients, time).
    """
    size = len(designs)
    per_design = lambda value: np.broadcast_to(np.asarray(value, dtype=float), (size,))  # noqa: E731
    speeds, limits, lengths = per_design(speed), per_design(power_limit), per_design(step_length)
    gait.check_problem(speeds, limits, lengths)
    models = [gait_model(d, v, p, length) for d, v, p, length in zip(designs, speeds, limits, lengths)]
    names = names or [f"design {b}" for b in range(size)]
    solutions = solver.solve(names, models, x0=x0, progress=progress)
    if summary:
        statuses = [s.status for s in solutions]
        summary(f"{statuses.count(al.CONVERGED)} of {size} converged "
                f"({', '.join(sorted(set(statuses) - {al.CONVERGED})) or 'all'}), "
                f"gradients per design up to {max(s.gradients for s in solutions)}, "
                f"{solutions[0].wall_time_s:.0f} s")
    return solutions


def design_record(design: DriveDesign, solution) -> dict:
    """A JSON-ready summary of one solved design: hardware, status, Joule energy (J and J/m; the
    objective, with the smooth efficiency switch, and with the exact one), the integral of u^T u, peak
    joint power, the largest voltage needed (exact efficiency law) and the violations."""
    trajectory = solution.trajectory
    drives = joint_drives(design)
    torque_at_motor = drive_model.motor_torque(trajectory.u, trajectory.joint_speed, drives.ratio,
                                               drives.efficiency)
    needed = np.abs(np.asarray(drive_model.voltage(
        torque_at_motor, drive_model.motor_speed(trajectory.joint_speed, drives.ratio), drives)))
    weights = np.asarray(trajectory.weights)[:, None]  # the trajectory's quadrature, s
    exact_joule = float(np.sum(weights * np.asarray(drive_model.joule_loss(torque_at_motor, drives))))
    return {
        "ratio": np.asarray(design.ratio).tolist(),
        "torque_constant_Nm_per_A": float(design.torque_constant[0]),
        "resistance_ohm": float(design.resistance[0]),
        "supply_voltage_V": float(design.supply_voltage),
        "total_mass_kg": float(design.total_mass),
        "armature_kgm2": np.asarray(reflected_inertia(design)).tolist(),
        "speed_mps": solution.speed_mps, "power_limit_W": solution.power_limit_W,
        "status": solution.status, "max_violation": solution.max_violation,
        "violations": solution.violations,
        "joule_energy_J": solution.cost,
        "joule_energy_exact_switch_J": exact_joule,
        "joule_energy_per_metre_J_per_m": solution.cost / solution.step_length_m,
        "int_u2_N2m2s": float(gait.cost(trajectory)),
        "peak_joint_power_W": float(np.max(np.abs(np.asarray(trajectory.joint_power)))),
        "max_voltage_needed_V": float(np.max(needed)),
    }


# ----------------------------------------------------------------------------- gradients and co-optimisation

def ratio_gradient(solver) -> Callable:
    """d J*/d log N per joint for a batch of converged solutions, by the envelope theorem.

    Returns ``gradient(designs, log_ratio, speed, power_limit, step_length, solutions) -> (B, 4)``
    (designs stacked with :func:`stack`; gear data follow the ratio as in :func:`with_ratio`).
    """
    catalogue = drive_model.load_catalogue()

    def parameters_to_model(theta):
        design, log_ratio, speed, power_limit, step_length = theta
        return gait_model(with_ratio(design, log_ratio, catalogue), speed, power_limit, step_length)

    envelope = al.optimal_value_gradient(solver.problem, parameters_to_model)

    def gradient(designs, log_ratio, speed, power_limit, step_length, solutions):
        size = log_ratio.shape[0]
        per = lambda value: jnp.broadcast_to(jnp.asarray(value, float), (size,))  # noqa: E731
        theta = (designs, jnp.asarray(log_ratio), per(speed), per(power_limit), per(step_length))
        x = jnp.stack([jnp.asarray(s.x) for s in solutions])
        lam_eq = jnp.stack([jnp.asarray(s.multipliers_eq) for s in solutions])
        lam_in = jnp.stack([jnp.asarray(s.multipliers_in) for s in solutions])
        return np.asarray(envelope(theta, x, lam_eq, lam_in)[1])
    return gradient


@dataclasses.dataclass
class CoOptimisation:
    """The path of :func:`co_optimise`: per iteration the ratios (B, 4), Joule energies (B,), statuses,
    and the final designs and gaits."""

    ratios: list
    joule: list
    status: list
    designs: list
    solutions: list


def co_optimise(solver, designs: list[DriveDesign], speed, power_limit, step_length=0.2, x0=None,
                iterations: int = 6, max_step: float = 0.25, ratio_bounds=(14.0, 190.0),
                min_step: float = 0.02, solutions: list | None = None,
                progress: Callable[[str], None] | None = None) -> CoOptimisation:
    """Gear ratios per joint co-optimised with the gait, all designs of the batch at once.

    Projected, normalised gradient descent on log N (each joint moves at most ``max_step`` in log N
    per iteration, inside ``ratio_bounds``), the gradient from the envelope theorem at each re-solved
    (warm-started) optimum; a step that raises the Joule energy or loses feasibility is undone and
    the design's step halved. A design is frozen once its step falls below ``min_step`` (log N) or
    its gait does not converge; the loop ends early when every design is frozen (the batch keeps its
    shape, so a frozen design is still solved while others move, but its result is not taken).
    Gear data follow the ratio smoothly (:func:`with_ratio`); snap the result to the catalogue with
    :func:`nearest_gearhead` and re-solve to verify. ``solutions``: the designs' gaits if already solved
    (e.g. by :func:`solve_designs`), else they are solved first.
    """
    say = progress or (lambda message: None)
    gradient = ratio_gradient(solver)
    catalogue = drive_model.load_catalogue()
    base = stack(designs)
    theta = np.log(np.asarray(base.ratio, dtype=float))
    low, high = np.log(ratio_bounds[0]), np.log(ratio_bounds[1])
    step = np.full(len(designs), max_step)
    apply = jax.jit(jax.vmap(lambda d, t: with_ratio(d, t, catalogue)))
    if solutions is None:
        solutions = solve_designs(solver, unstack(apply(base, jnp.asarray(theta))), speed, power_limit,
                                  step_length, x0=x0, summary=progress)
    elif len(solutions) != len(designs):
        raise ValueError(f"give one solution per design: {len(solutions)} for {len(designs)} designs")
    path = CoOptimisation([], [], [], [], [])

    def record(theta_, solutions_):
        path.ratios.append(np.exp(theta_).tolist())
        path.joule.append([s.cost for s in solutions_])
        path.status.append([s.status for s in solutions_])

    record(theta, solutions)
    for k in range(iterations):
        moving = np.array([s.status == al.CONVERGED for s in solutions]) & (step >= min_step)
        if not moving.any():
            say(f"co-design stopped after {k} iterations: every design converged to its step floor or failed")
            break
        grad = gradient(base, theta, speed, power_limit, step_length, solutions)
        scale = np.maximum(np.max(np.abs(grad), axis=1, keepdims=True), 1e-12)
        trial = np.where(moving[:, None], np.clip(theta - step[:, None] * grad / scale, low, high), theta)
        x_warm = jnp.stack([jnp.asarray(s.x) for s in solutions])
        trial_solutions = solve_designs(solver, unstack(apply(base, jnp.asarray(trial))), speed, power_limit,
                                        step_length, x0=x_warm, summary=progress)
        better = moving & np.array([t.status == al.CONVERGED and t.cost < s.cost
                                    for s, t in zip(solutions, trial_solutions)])
        theta = np.where(better[:, None], trial, theta)
        solutions = [t if b else s for s, t, b in zip(solutions, trial_solutions, better)]
        step = np.where(better | ~moving, step, 0.5 * step)
        record(theta, solutions)
        best = min((s.cost for s in solutions if s.status == al.CONVERGED), default=math.nan)
        say(f"co-design iteration {k + 1}/{iterations}: {int(better.sum())} of {len(designs)} designs "
            f"improved, best Joule energy {best:.4g} J")
    path.designs = unstack(apply(base, jnp.asarray(theta)))
    path.solutions = solutions
    return path
