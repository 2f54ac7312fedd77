"""The co-design's hardware as arrays: a :class:`DriveDesign` (traced, batchable with ``vmap``) holds per
actuated joint (H1, K1, H2, K2) a gear of ratio N and a motor winding, and the structural mass of each
link. It maps to the gait problem (:func:`design_gait_model`) as

- reflected inertia N^2 (J_rotor + J_gear) as the joint's armature in the MJX model;
- motor and gear mass as a point mass on the link carrying the drive (both hip drives in the torso,
  each knee drive on its thigh, at the knee or moved up toward the hip by ``drive_offset``;
  ``biped_jax.robots.design``);
- the objective: the Joule energy integral of R i^2 with i = T_m / k_t and T_m the motor torque
  through the gear (eq. 2.3, efficiency both ways); for identical drives it is a constant times the
  paper's integral of u^T u;
- the voltage limit: every operating point under the speed-torque line at the supply voltage, a
  constraint beside the power limit |qdot u| <= M_W.

Catalogue designs (:func:`catalogue_design`) carry the exact data of a Maxon motor and gearhead; a
continuous gear ratio (:func:`with_ratio`) takes its stage's data, stepping smoothly between stages.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax import checks
from biped_jax.drives import model as drive_model
from biped_jax.dynamics import mjx_biped
from biped_jax.gait import problem as gait_problem
from biped_jax.gait.solver import stack_tree
from biped_jax.robots.design import Design, check_design
from biped_jax.robots.planar_biped import PLANAR_DRIVE_MOUNTS, PLANAR_LINKS


#: The paper's drive for the 12 kg robot (Section 2.3): the 42 V RE 25 winding, GP 32 A 66:1, 38 V supply.
REFERENCE_MOTOR, REFERENCE_GEARHEAD = "RE25-42V", "GP32A-66.22"


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class DriveDesign:
    """The hardware of the sagittal biped (SI units; per-joint arrays in (H1, K1, H2, K2) order).

    Attributes:
      ratio: gear ratio N, (4,). gear_efficiency: eta, (4,). gear_inertia: referred to the motor
        side, kg m^2, (4,). gear_mass: kg, (4,). gear_torque_limit: the gear's intermittent output
        torque, N m, (4,). gear_speed_limit: its largest input speed, rad/s, (4,).
      torque_constant: k_t, N m/A, (4,). resistance: R, ohm, (4,). rotor_inertia: kg m^2, (4,).
        motor_mass: kg, (4,).
      structure_mass: the links without drives (torso, thigh1, shank1, thigh2, shank2), kg, (5,).
      supply_voltage: V_s, V, ().
      drive_offset: where along its link each drive sits, (4,), 0 at its joint, 1 at the hip (the knee
        drives up their thighs; :class:`~biped_jax.robots.design.Design`); the hip drives stay.
    """

    ratio: jax.Array
    gear_efficiency: jax.Array
    gear_inertia: jax.Array
    gear_mass: jax.Array
    gear_torque_limit: jax.Array
    gear_speed_limit: jax.Array
    torque_constant: jax.Array
    resistance: jax.Array
    rotor_inertia: jax.Array
    motor_mass: jax.Array
    structure_mass: jax.Array
    supply_voltage: jax.Array
    drive_offset: jax.Array

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
                    drive_mass=design.motor_mass + design.gear_mass, drive_offset=design.drive_offset)
    if checks.concrete(design):
        check_design(result, mjx_biped.planar_layouts()[0])
    return result


def joint_drives(design: DriveDesign) -> drive_model.JointDrives:
    """The drives as the gait problem sees them (objective: Joule energy; constraints: the supply
    voltage, and where the gait's settings ask for them (``GaitSettings.drive_limits``) the gear's
    intermittent output torque and largest input speed)."""
    return drive_model.JointDrives(ratio=design.ratio, efficiency=design.gear_efficiency,
                                   torque_constant=design.torque_constant, resistance=design.resistance,
                                   supply_voltage=design.supply_voltage, gear_torque_limit=design.gear_torque_limit,
                                   reflected_inertia=reflected_inertia(design),
                                   input_speed_limit=design.gear_speed_limit)


def design_gait_model(design: DriveDesign, speed, power_limit, step_length=0.2) -> gait_problem.GaitModel:
    """The gait problem of a design (traceable: ``speed`` etc. may be arrays). The geometry is that of
    the paper's biped (docs/gait-problem.md); masses and drives come from ``design``. Concrete values are
    checked (:func:`biped_jax.gait.problem.check_problem`)."""
    if checks.concrete(speed, power_limit, step_length):
        gait_problem.check_problem(speed, power_limit, step_length)
    return gait_problem.GaitModel(design=robot_design(design), speed=jnp.asarray(speed, float),
                          step_length=jnp.asarray(step_length, float),
                          power_limit=jnp.asarray(power_limit, float), drives=joint_drives(design))


def _structure_of(mass_class: str, drive_mass: float) -> np.ndarray:
    """The mass class's link masses with four drives of ``drive_mass`` taken out of the links that
    carry them, kg, (5,): the robot weighs its nominal mass with those drives fitted."""
    structure = np.asarray(mjx_biped.planar_design(mass_class).link_mass, dtype=float).copy()
    for mount in PLANAR_DRIVE_MOUNTS:
        structure[PLANAR_LINKS.index(mount)] -= drive_mass
    if np.any(structure <= 0):
        raise ValueError(f"drives of {drive_mass} kg each leave no structure in the {mass_class} biped")
    return structure


def _four(kind: str, names: str | tuple[str, ...]) -> tuple[str, ...]:
    """One part name for all four joints, or four; ValueError naming any other count."""
    four = (names,) * 4 if isinstance(names, str) else tuple(names)
    if len(four) != 4:
        raise ValueError(f"give one {kind} or four (H1, K1, H2, K2), got {names!r}")
    return four


def catalogue_design(motor: str | tuple[str, ...] = REFERENCE_MOTOR,
                     gearhead: str | tuple[str, ...] = REFERENCE_GEARHEAD,
                     mass_class: str = "12kg", total_mass: float | None = None,
                     supply_voltage: float | None = None,
                     catalogue: drive_model.Catalogue | None = None) -> DriveDesign:
    """A catalogue motor and gearhead at all four joints, or one of either per joint (a tuple of four
    names in (H1, K1, H2, K2) order).

    The structure is the mass class's links less the reference drives (so the reference design weighs
    the nominal 12 or 18 kg); ``total_mass`` (kg) scales the structure uniformly to reach that total.
    ``supply_voltage`` defaults to the catalogue's (the paper's 38 V). Raises ValueError naming an
    unknown part or an unreachable total mass.
    """
    catalogue = catalogue or drive_model.load_catalogue()
    motors = [catalogue.motor(name) for name in _four("motor", motor)]
    heads = [catalogue.gearhead(name) for name in _four("gearhead", gearhead)]
    reference = catalogue.motor(REFERENCE_MOTOR).mass + catalogue.gearhead(REFERENCE_GEARHEAD).mass
    structure = _structure_of(mass_class, reference)
    drives_mass = sum(m.mass for m in motors) + sum(h.mass for h in heads)
    if total_mass is not None:
        if not (math.isfinite(total_mass) and total_mass > drives_mass):
            raise ValueError(f"total_mass must exceed the drives' {drives_mass:.2f} kg, got {total_mass!r}")
        structure = structure * (total_mass - drives_mass) / structure.sum()
    voltage = catalogue.supply_voltage if supply_voltage is None else supply_voltage
    if not (math.isfinite(voltage) and voltage > 0):
        raise ValueError(f"supply_voltage must be positive, got {voltage!r}")
    per_joint = lambda parts, field: jnp.array([getattr(p, field) for p in parts], dtype=float)  # noqa: E731
    return DriveDesign(ratio=per_joint(heads, "ratio"), gear_efficiency=per_joint(heads, "efficiency"),
                       gear_inertia=per_joint(heads, "inertia"), gear_mass=per_joint(heads, "mass"),
                       gear_torque_limit=per_joint(heads, "intermittent_torque"),
                       gear_speed_limit=per_joint(heads, "max_input_speed"),
                       torque_constant=per_joint(motors, "torque_constant"),
                       resistance=per_joint(motors, "resistance"), rotor_inertia=per_joint(motors, "rotor_inertia"),
                       motor_mass=per_joint(motors, "mass"), structure_mass=jnp.asarray(structure),
                       supply_voltage=jnp.asarray(float(voltage)), drive_offset=jnp.zeros(4))


def _stage_table(catalogue: drive_model.Catalogue):
    """Per gearhead stage (ascending ratio): smallest and largest catalogue ratio, efficiency, inertia,
    mass, intermittent output torque, largest input speed (numpy, (stages, 7)); one stage's gearheads
    share all but the ratio."""
    stages = {}
    for g in catalogue.gearheads.values():
        stages.setdefault(g.stages, []).append(g)
    rows = []
    for _, heads in sorted(stages.items()):
        ratios = [h.ratio for h in heads]
        first = heads[0]
        rows.append((min(ratios), max(ratios), first.efficiency, first.inertia, first.mass,
                     first.intermittent_torque, first.max_input_speed))
    return np.array(rows)


def _smoothstep(t: jax.Array) -> jax.Array:
    """0 below 0, 1 above 1, 3 t^2 - 2 t^3 between: C1 with zero slope at both ends."""
    t = jnp.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def with_ratio(design: DriveDesign, log_ratio: jax.Array,
               catalogue: drive_model.Catalogue | None = None) -> DriveDesign:
    """``design`` with gear ratios exp(log_ratio) ((4,), traceable) and the gear's efficiency, inertia,
    mass and limits (intermittent torque, input speed) of the GP 32 A stage whose catalogue ratios span
    N (exactly the catalogue's data there: a continuous design at a catalogue ratio is that gearhead),
    and in the gaps between stages (33-51:1, 190-246:1) a smooth step in log N from one stage's data to
    the next (3 t^2 - 2 t^3: continuous with its first derivative, so the envelope gradient with respect
    to log N has no jump for the co-design to stall on). The ratio can so be a continuous design variable;
    snapped to a catalogue gearhead, the design is checked again."""
    table = _stage_table(catalogue or drive_model.load_catalogue())
    values = jnp.asarray(table[:, 2:])  # (stages, 5)
    gap_low, gap_high = jnp.log(table[:-1, 1]), jnp.log(table[1:, 0])  # (stages - 1,) each
    steps = _smoothstep((log_ratio[..., None] - gap_low) / (gap_high - gap_low))  # (..., stages - 1)
    data = values[0] + jnp.einsum("...g,gc->...c", steps, values[1:] - values[:-1])  # (..., 5)
    return dataclasses.replace(design, ratio=jnp.exp(log_ratio), gear_efficiency=data[..., 0],
                               gear_inertia=data[..., 1], gear_mass=data[..., 2],
                               gear_torque_limit=data[..., 3], gear_speed_limit=data[..., 4])


#: The mass split's variables: the legs' share of the structure mass (both legs, drives excluded) and
#: the thighs' share of the legs' (both legs alike: the gait is periodic with the legs swapped).
MASS_SPLIT_NAMES = ("leg_fraction", "thigh_share")
#: Bounds of the mass split, ours: a design range around the paper's biped (Table 2 less the reference
#: drives: legs 0.374 of the 12 kg robot's 10.72 kg of structure, thighs 0.420 of the legs; 0.379 and
#: 0.449 at 18 kg) wide enough to see where the gait wants the mass, every link keeping at least a
#: quarter of its Table 2 mass (0.27 kg a thigh at 12 kg) so that a leg stays a structure that carries
#: its drive.
MASS_SPLIT_BOUNDS = ((0.2, 0.25), (0.5, 0.75))


def mass_split(design: DriveDesign) -> jax.Array:
    """(leg_fraction, thigh_share) of ``design``'s structure (:data:`MASS_SPLIT_NAMES`), (2,); legs
    averaged over both sides."""
    torso, thigh1, shank1, thigh2, shank2 = (design.structure_mass[..., i] for i in range(5))
    legs = thigh1 + shank1 + thigh2 + shank2
    return jnp.stack([legs / (torso + legs), (thigh1 + thigh2) / legs], axis=-1)


def with_mass_split(design: DriveDesign, split: jax.Array) -> DriveDesign:
    """``design`` with its structure mass (the same total) split as ``split`` = (leg_fraction,
    thigh_share) (2,), traceable: the torso scaled to (1 - leg_fraction) of the total, the thighs
    together to leg_fraction thigh_share, the shanks to leg_fraction (1 - thigh_share), each link of a
    pair by the same factor (so the design's own split gives the design back exactly). Inertias follow
    the masses (uniform density, the links keep their shapes: :class:`~biped_jax.robots.design.Design`)."""
    mass = design.structure_mass
    own = mass_split(design)
    torso = (1.0 - split[0]) / (1.0 - own[0])
    thighs = split[0] * split[1] / (own[0] * own[1])
    shanks = split[0] * (1.0 - split[1]) / (own[0] * (1.0 - own[1]))
    factors = jnp.stack([torso, thighs, shanks, thighs, shanks])  # the total kept: 1 - f + f t + f (1 - t) = 1
    return dataclasses.replace(design, structure_mass=mass * factors)


def with_torque_constant(design: DriveDesign, log_torque_constant: jax.Array) -> DriveDesign:
    """``design`` with the motor windings' torque constants exp(log_torque_constant) (N m/A, (4,),
    traceable), moving along the winding family of the design's own motor: the terminal resistance
    follows as R = R_0 (k_t / k_t0)^2 from the design's own winding (k_t0, R_0), so that the motor
    constant k_t / sqrt(R) stays the family's (the catalogue's RE 25 windings have R / k_t^2 within
    1 % of the 42 V winding's: the datasheet windings +0.5 % and -1.0 %, the estimated ones built on
    it), and the rotor inertia and mass stay (equal across the windings). Exact at the design's own
    winding; the Joule energy R (T_m / k_t)^2 does not change along the family, only the voltage
    V = k_t (R/k_t^2 T_m + omega_m) does."""
    torque_constant = jnp.exp(log_torque_constant)
    scale = torque_constant / design.torque_constant
    return dataclasses.replace(design, torque_constant=torque_constant, resistance=design.resistance * scale**2)


def winding_range(catalogue: drive_model.Catalogue | None = None) -> tuple[float, float]:
    """The smallest and largest torque constant of the catalogue's windings, N m/A: the bounds of the
    continuous winding variable (:func:`with_torque_constant`)."""
    catalogue = catalogue or drive_model.load_catalogue()
    constants = [m.torque_constant for m in catalogue.motors.values()]
    return min(constants), max(constants)


def nearest_winding(torque_constant: float, catalogue: drive_model.Catalogue | None = None) -> str:
    """The catalogue winding for a continuous torque constant (N m/A): the one with the largest k_t not
    above ``torque_constant`` (1e-6 relative tolerance), else the smallest. Below rather than nearest:
    along the family the Joule energy is the same and the voltage a gait needs grows with k_t, so a
    smaller k_t keeps the continuous design's voltage margin (at the price of more current).
    ValueError for a non-positive or non-finite torque constant."""
    catalogue = catalogue or drive_model.load_catalogue()
    if not (isinstance(torque_constant, (int, float, np.floating)) and math.isfinite(torque_constant)
            and torque_constant > 0):
        raise ValueError(f"torque_constant must be positive and finite (N m/A), got {torque_constant!r}")
    motors = sorted(catalogue.motors.values(), key=lambda m: m.torque_constant)
    below = [m for m in motors if m.torque_constant <= torque_constant * (1 + 1e-6)]
    return (below[-1] if below else motors[0]).part


def knee_drive_offset(design: DriveDesign) -> jax.Array:
    """How far up its thigh each knee drive sits, both knees averaged, (): 0 at the knee, 1 at the hip."""
    return 0.5 * (design.drive_offset[..., 1] + design.drive_offset[..., 3])


def with_knee_drive_offset(design: DriveDesign, offset) -> DriveDesign:
    """``design`` with both knee drives ``offset`` (a fraction in [0, 1], traceable) of the way up their
    thighs to the hips, a transmission carrying the torque to the knee (its mass, friction and
    compliance not modelled: the drive's own mass moves, its reflected inertia stays the knee's). The
    hip drives stay at the hips."""
    offset = jnp.asarray(offset, float)
    zero = jnp.zeros_like(offset)
    return dataclasses.replace(design, drive_offset=jnp.stack([zero, offset, zero, offset], axis=-1))


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
