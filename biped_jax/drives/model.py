"""Drive trains: the Maxon RE 25 + GP 32 A catalogue and a differentiable DC-motor and gear model.

The catalogue (``data/maxon_catalogue.json``) is in catalogue units; :func:`load_catalogue` converts
to SI once, so everything below works in N m, rad/s, A, V, W, kg m^2. The model is the standard DC
motor with the paper's eqs. 2.3-2.5:

  motor torque  T_m = T / (N eta) when the motor drives the load, T eta / N when back-driven;
  motor speed   omega_m = N omega;
  current       i = T_m / k_t;   Joule loss P_J = R i^2;   voltage V = R i + k_t omega_m;
  speed-torque line at supply V_s: omega_m <= (V_s - R T_m / k_t) / k_t (eq. 2.5 for an ideal motor).
"""

from __future__ import annotations

import dataclasses
import json
import math
from importlib import resources

import jax
import jax.numpy as jnp
import numpy as np

from biped_jax import checks

RPM = 2 * math.pi / 60  # rad/s per rpm
MNM = 1e-3  # N m per mN m
GCM2 = 1e-7  # kg m^2 per g cm^2


@dataclasses.dataclass(frozen=True)
class Motor:
    """A DC motor winding, SI units.

    Attributes:
      part: catalogue name; nominal_voltage: V; torque_constant: k_t, N m/A (= back-EMF constant,
      V s/rad); resistance: terminal resistance R, ohm; rotor_inertia: kg m^2; nominal_torque: max.
      continuous torque (thermal limit), N m; max_speed: rad/s; mass: kg; provenance, source: where
      the numbers come from.
    """

    part: str
    nominal_voltage: float
    torque_constant: float
    resistance: float
    rotor_inertia: float
    nominal_torque: float
    max_speed: float
    mass: float
    provenance: str
    source: str


@dataclasses.dataclass(frozen=True)
class Gearhead:
    """One planetary gearhead, SI units.

    Attributes:
      part: catalogue name; ratio: N (motor speed / output speed); stages: number of stages;
      efficiency: max. efficiency eta; continuous_torque, intermittent_torque: output limits, N m;
      max_input_speed: rad/s; inertia: referred to the input, kg m^2; mass: kg; provenance, source.
    """

    part: str
    ratio: float
    stages: int
    efficiency: float
    continuous_torque: float
    intermittent_torque: float
    max_input_speed: float
    inertia: float
    mass: float
    provenance: str
    source: str


@dataclasses.dataclass(frozen=True)
class Catalogue:
    """Motors and gearheads by part name, and the supply voltage (V)."""

    motors: dict[str, Motor]
    gearheads: dict[str, Gearhead]
    supply_voltage: float

    def motor(self, part: str) -> Motor:
        if part not in self.motors:
            raise ValueError(f"unknown motor part {part!r}; known: {', '.join(self.motors)}")
        return self.motors[part]

    def gearhead(self, part: str) -> Gearhead:
        if part not in self.gearheads:
            raise ValueError(f"unknown gearhead part {part!r}; known: {', '.join(self.gearheads)}")
        return self.gearheads[part]


def _gearhead_name(ratio: float) -> str:
    return f"GP32A-{ratio:g}"


def load_catalogue() -> Catalogue:
    """The shipped catalogue, converted to SI."""
    raw = json.loads(resources.files("biped_jax").joinpath("data/maxon_catalogue.json").read_text())
    motors = {}
    for m in raw["motors"]:
        motors[m["part"]] = Motor(
            part=m["part"], nominal_voltage=m["nominal_voltage_V"],
            torque_constant=m["torque_constant_mNm_per_A"] * MNM, resistance=m["terminal_resistance_ohm"],
            rotor_inertia=m["rotor_inertia_gcm2"] * GCM2, nominal_torque=m["nominal_torque_mNm"] * MNM,
            max_speed=m["max_speed_rpm"] * RPM, mass=m["mass_g"] * 1e-3, provenance=m["provenance"],
            source=m["source"])
    gearheads = {}
    for g in raw["gearhead_stages"]:
        for ratio in g["ratios"]:
            gearheads[_gearhead_name(ratio)] = Gearhead(
                part=_gearhead_name(ratio), ratio=float(ratio), stages=g["stages"],
                efficiency=g["max_efficiency"], continuous_torque=g["continuous_torque_Nm"],
                intermittent_torque=g["intermittent_torque_Nm"],
                max_input_speed=g["max_input_speed_rpm"] * RPM, inertia=g["inertia_gcm2"] * GCM2,
                mass=g["mass_g"] * 1e-3, provenance=g["provenance"], source=g["source"])
    return Catalogue(motors=motors, gearheads=gearheads, supply_voltage=raw["supply_voltage_V"])


def check_ratio(ratio: float) -> float:
    """Raises ValueError naming a non-positive or non-finite gear ratio."""
    if not (math.isfinite(ratio) and ratio > 0):
        raise ValueError(f"gear ratio must be positive and finite, got {ratio!r}")
    return ratio


def _check_concrete(name: str, value, unit: str, high: float = math.inf) -> None:
    """Raises ValueError naming ``value`` unless every element is finite and in (0, high]; values
    inside a trace pass unchecked (the drive functions are differentiated and vmapped)."""
    if not checks.concrete(value):
        return
    values = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(values) & (values > 0) & (values <= high)):
        limit = "> 0" if high == math.inf else f"in (0, {high:g}]"
        raise ValueError(f"{name} must be finite and {limit}{' ' + unit if unit else ''}, got {values.tolist()}")


# ----------------------------------------------------------------------------- the drive model

def motor_torque(joint_torque: jax.Array, joint_speed: jax.Array, ratio, efficiency) -> jax.Array:
    """Motor torque T_m, N m (eq. 2.3): T / (N eta) when motoring (T omega >= 0), T eta / N when the
    load back-drives the motor. Shapes broadcast; concrete ratios must be > 0, efficiencies in (0, 1]."""
    _check_concrete("gear ratio", ratio, "")
    _check_concrete("gear efficiency", efficiency, "", high=1.0)
    motoring = joint_torque * joint_speed >= 0
    return jnp.where(motoring, joint_torque / (ratio * efficiency), joint_torque * efficiency / ratio)


def motor_speed(joint_speed: jax.Array, ratio) -> jax.Array:
    """Motor speed omega_m = N omega, rad/s (eq. 2.4)."""
    _check_concrete("gear ratio", ratio, "")
    return ratio * joint_speed


def current(torque_at_motor: jax.Array, motor: Motor | JointDrives) -> jax.Array:
    """Winding current i = T_m / k_t, A (``motor``: a catalogue :class:`Motor` or the
    :class:`JointDrives` of a design; these electrical laws read its k_t and R)."""
    return torque_at_motor / motor.torque_constant


def joule_loss(torque_at_motor: jax.Array, motor: Motor | JointDrives) -> jax.Array:
    """Joule loss P_J = R i^2, W."""
    return motor.resistance * current(torque_at_motor, motor) ** 2


def voltage(torque_at_motor: jax.Array, speed_at_motor: jax.Array, motor: Motor | JointDrives) -> jax.Array:
    """Terminal voltage V = R i + k_t omega_m, V."""
    return motor.resistance * current(torque_at_motor, motor) + motor.torque_constant * speed_at_motor


def electrical_power(torque_at_motor: jax.Array, speed_at_motor: jax.Array, motor: Motor | JointDrives) -> jax.Array:
    """P_el = V i = mechanical power T_m omega_m + Joule loss, W."""
    return voltage(torque_at_motor, speed_at_motor, motor) * current(torque_at_motor, motor)


def no_load_speed(motor: Motor, supply_voltage: float) -> float:
    """No-load speed at a supply voltage, rad/s: eq. 2.5, n_mV = n_m V_s / V_m, with n_m = V_m / k_t."""
    _check_concrete("supply_voltage", supply_voltage, "V")
    return supply_voltage / motor.torque_constant


def stall_torque(motor: Motor, supply_voltage: float) -> float:
    """Torque at zero speed at a supply voltage, N m: k_t V_s / R."""
    _check_concrete("supply_voltage", supply_voltage, "V")
    return motor.torque_constant * supply_voltage / motor.resistance


def speed_torque_gradient(motor: Motor) -> float:
    """Slope of the speed-torque line, (rad/s) per N m: R / k_t^2."""
    return motor.resistance / motor.torque_constant**2


def max_speed_at_torque(torque_at_motor: jax.Array, motor: Motor, supply_voltage: float) -> jax.Array:
    """The speed-torque line at a supply voltage: the highest motor speed (rad/s) the supply allows
    at a motor torque |T_m| (N m)."""
    return no_load_speed(motor, supply_voltage) - speed_torque_gradient(motor) * jnp.abs(torque_at_motor)


def voltage_margin(torque_at_motor, speed_at_motor, motor: Motor, supply_voltage: float) -> jax.Array:
    """Supply voltage minus the voltage an operating point needs, V (>= 0: under the line).

    For motoring points (T_m omega_m >= 0) this is exactly k_t (line speed - |omega_m|); back-driven
    points need less voltage than the back-EMF alone.
    """
    _check_concrete("supply_voltage", supply_voltage, "V")
    needed = jnp.abs(voltage(torque_at_motor, speed_at_motor, motor))
    return supply_voltage - needed


# ----------------------------------------------------------------------------- drives in the gait problem

#: Supply voltage standing for "no voltage limit" (the paper's gait problem), V.
NO_VOLTAGE_LIMIT = 1e6


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class JointDrives:
    """The drive of each actuated joint, motor behind gear, as arrays (traced, batchable), SI units:
    the one drive model of the gait problem, the co-design and DONALD.

    Attributes:
      ratio: gear ratio N. efficiency: gear efficiency eta. torque_constant: k_t, N m/A.
      resistance: R, ohm. supply_voltage: V_s, V, shape ().
      gear_torque_limit: the gear's intermittent output torque, N m (inf: none).
      reflected_inertia: N^2 (J_rotor + J_gear), the drive's inertia at the joint, kg m^2.
      input_speed_limit: the gear's largest input (motor) speed, rad/s (inf: none).
    Per-joint fields have shape (n_joints,), or () for the same drive at every joint (DONALD's).
    """

    ratio: jax.Array
    efficiency: jax.Array
    torque_constant: jax.Array
    resistance: jax.Array
    supply_voltage: jax.Array
    gear_torque_limit: jax.Array
    reflected_inertia: jax.Array
    input_speed_limit: jax.Array


def reflected_inertia(ratio, rotor_inertia, gear_inertia) -> jax.Array:
    """N^2 (J_rotor + J_gear), kg m^2: the drive's inertia seen at the joint (J_gear on the motor side)."""
    return ratio**2 * (rotor_inertia + gear_inertia)


def ideal_drives(joints: int = 4) -> JointDrives:
    """Identical unit drives (N = eta = k_t = R = 1) without a voltage limit: their Joule energy is
    the paper's integral of u^T u, so the paper's gait problem is this special case."""
    ones = jnp.ones(joints)
    return JointDrives(ratio=ones, efficiency=ones, torque_constant=ones, resistance=ones,
                       supply_voltage=jnp.asarray(NO_VOLTAGE_LIMIT), gear_torque_limit=jnp.full(joints, jnp.inf),
                       reflected_inertia=jnp.zeros(joints), input_speed_limit=jnp.full(joints, jnp.inf))


def catalogue_drives(motor: str, gearhead: str, supply_voltage: float,
                     catalogue: Catalogue | None = None) -> JointDrives:
    """One catalogue motor behind one catalogue gearhead at every joint (fields of shape ()); raises
    ValueError naming an unknown part."""
    checks.number_in("supply_voltage", supply_voltage, 0.0, math.inf, "V")
    catalogue = catalogue or load_catalogue()
    m, g = catalogue.motor(motor), catalogue.gearhead(gearhead)
    return JointDrives(ratio=jnp.asarray(g.ratio), efficiency=jnp.asarray(g.efficiency),
                       torque_constant=jnp.asarray(m.torque_constant), resistance=jnp.asarray(m.resistance),
                       supply_voltage=jnp.asarray(float(supply_voltage)),
                       gear_torque_limit=jnp.asarray(g.intermittent_torque),
                       reflected_inertia=jnp.asarray(reflected_inertia(g.ratio, m.rotor_inertia, g.inertia)),
                       input_speed_limit=jnp.asarray(g.max_input_speed))


def torque_limits(drives: JointDrives, joint_speed: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Lowest and highest joint torque the drives can give at ``joint_speed`` (rad/s), N m.

    Motor torque within k_t (+-V_s - k_t omega_m) / R (the speed-torque lines at +-V_s); through the
    gear with efficiency eta when the motor drives the load and 1/eta when the load drives the motor
    (eq. 2.3 inverted); clipped to the gear's intermittent output torque.
    """
    omega_m = motor_speed(joint_speed, drives.ratio)
    back_emf = drives.torque_constant * omega_m
    motor_high = drives.torque_constant * (drives.supply_voltage - back_emf) / drives.resistance
    motor_low = drives.torque_constant * (-drives.supply_voltage - back_emf) / drives.resistance

    def to_joint(motor_torque):
        motoring = motor_torque * joint_speed >= 0
        factor = jnp.where(motoring, drives.efficiency, 1 / drives.efficiency)
        return motor_torque * drives.ratio * factor

    limit = drives.gear_torque_limit
    return jnp.clip(to_joint(motor_low), -limit, limit), jnp.clip(to_joint(motor_high), -limit, limit)


#: Joint power over which the gear's efficiency switches smoothly from back-driven to motoring, W.
EFFICIENCY_SWITCH_POWER = 1.0


def smooth_motor_torque(joint_torque: jax.Array, joint_speed: jax.Array, ratio, efficiency,
                        switch_power: float = EFFICIENCY_SWITCH_POWER) -> jax.Array:
    """:func:`motor_torque` with the switch between T / (N eta) (motoring) and T eta / N (back-driven)
    blended over joint powers |T omega| of about ``switch_power`` (W): the exact switch puts a kink
    into the Joule energy at every sample where T omega changes sign, which stalls the gait solver's
    line searches. Equal to :func:`motor_torque` for eta = 1 and for |T omega| >> switch_power."""
    motoring = 0.5 * (1 + jnp.tanh(joint_torque * joint_speed / switch_power))
    return joint_torque / ratio * (motoring / efficiency + (1 - motoring) * efficiency)


def joule_residuals(joint_torque: jax.Array, joint_speed: jax.Array, drives: JointDrives, dt) -> jax.Array:
    """r with r . r = integral of R i^2 dt (Joule energy, J): sqrt(R dt) T_m / k_t, shape of the torques
    (T, n_joints); joint_torque in N m, joint_speed in rad/s, dt in s; T_m from
    :func:`smooth_motor_torque`."""
    torque_at_motor = smooth_motor_torque(joint_torque, joint_speed, drives.ratio, drives.efficiency)
    return jnp.sqrt(drives.resistance * dt) * torque_at_motor / drives.torque_constant


def required_voltage(joint_torque: jax.Array, joint_speed: jax.Array, drives: JointDrives) -> jax.Array:
    """The terminal voltage V each joint's motor needs, per sample and joint, V (signed); shapes as
    :func:`joule_residuals`."""
    torque_at_motor = smooth_motor_torque(joint_torque, joint_speed, drives.ratio, drives.efficiency)
    return voltage(torque_at_motor, motor_speed(joint_speed, drives.ratio), drives)


def voltage_excess(joint_torque: jax.Array, joint_speed: jax.Array, drives: JointDrives) -> jax.Array:
    """|V| - V_s per sample and joint, V (<= 0: the operating point lies under the speed-torque line
    at the supply voltage); shapes as :func:`joule_residuals`."""
    return jnp.abs(required_voltage(joint_torque, joint_speed, drives)) - drives.supply_voltage
