"""How long a motor can walk: the winding's temperature under a gait's losses, by the two-node thermal
model of the catalogue (winding and housing).

The winding (heat capacity C_w) gains the Joule loss i^2 R(T_w), with copper's resistance rising as
R(T) = R_25 (1 + alpha (T - 25 C)), and passes heat to the housing through R_wh; the housing (C_h)
passes it to the air through R_ha. C_w = tau_w / R_wh and C_h = tau_m / R_ha from the catalogue's
thermal time constants of winding and motor (maxon's definitions). In temperature rises over the
ambient, Delta = (Delta_w, Delta_h), the model is linear, dDelta/dt = A Delta + b, and a constant loss
has the closed form Delta(t) = Delta_ss + exp(A t) (Delta_0 - Delta_ss).

A gait's step (a fraction of a second) is far shorter than the winding's time constant (seconds), so a
walk heats the winding as its mean loss does: the RMS motor current of the step.

The limit: the winding temperature at which the catalogue's nominal (maximum continuous) torque holds
the motor in steady state in this model, so that "walks indefinitely" is exactly the selection's
steady thermal check (RMS motor torque within the nominal torque). It lies below the winding's absolute
maximum (the catalogue's ratings carry their margin); for every RE 25 winding it is the same, since the
nominal torque over the motor constant k_t / sqrt(R) is the same loss.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from importlib import resources

import numpy as np
from scipy import linalg, optimize

from biped_jax.drives.model import Motor


@dataclasses.dataclass(frozen=True)
class MotorThermal:
    """The two-node thermal model's data, SI (K, W, s).

    Attributes:
      winding_housing: R_wh, K/W. housing_ambient: R_ha, K/W.
      winding_time_constant: tau_w, s. motor_time_constant: tau_m, s.
      temperature_coefficient: alpha of the winding's resistance, 1/K.
      ambient: the ambient temperature of the catalogue's ratings, C.
      provenance, source: where the numbers come from.
    """

    winding_housing: float
    housing_ambient: float
    winding_time_constant: float
    motor_time_constant: float
    temperature_coefficient: float
    ambient: float
    provenance: str = ""
    source: str = ""

    @classmethod
    def from_catalogue(cls, raw: dict) -> "MotorThermal":
        """From the catalogue's ``motor_thermal`` block."""
        return cls(winding_housing=raw["thermal_resistance_winding_housing_K_per_W"],
                   housing_ambient=raw["thermal_resistance_housing_ambient_K_per_W"],
                   winding_time_constant=raw["thermal_time_constant_winding_s"],
                   motor_time_constant=raw["thermal_time_constant_motor_s"],
                   temperature_coefficient=raw["copper_temperature_coefficient_per_K"],
                   ambient=raw["ambient_temperature_C"], provenance=raw["provenance"], source=raw["source"])


@functools.lru_cache(maxsize=1)
def load_thermal() -> MotorThermal:
    """The shipped catalogue's thermal model of the RE 25 frame (every winding)."""
    raw = json.loads(resources.files("biped_jax").joinpath("data/maxon_catalogue.json").read_text())
    return MotorThermal.from_catalogue(raw["motor_thermal"])


def _system(current: float, motor: Motor, thermal: MotorThermal, ambient: float) -> tuple[np.ndarray, np.ndarray]:
    """(A (2, 2), b (2,)) of dDelta/dt = A Delta + b at a constant RMS current (A), ambient in C."""
    c_w = thermal.winding_time_constant / thermal.winding_housing
    c_h = thermal.motor_time_constant / thermal.housing_ambient
    loss = current**2 * motor.resistance  # at 25 C
    rising = loss * thermal.temperature_coefficient  # W per K of winding rise
    base = loss * (1.0 + thermal.temperature_coefficient * (ambient - 25.0))
    a = np.array([[(rising - 1.0 / thermal.winding_housing) / c_w, 1.0 / (thermal.winding_housing * c_w)],
                  [1.0 / (thermal.winding_housing * c_h),
                   -(1.0 / thermal.winding_housing + 1.0 / thermal.housing_ambient) / c_h]])
    return a, np.array([base / c_w, 0.0])


def steady_rise(current: float, motor: Motor, thermal: MotorThermal, ambient: float | None = None) -> float:
    """The winding's steady temperature rise over the ambient at a constant RMS current, K; inf where
    the loss's growth with temperature outruns the cooling (thermal runaway)."""
    ambient = thermal.ambient if ambient is None else ambient
    a, b = _system(current, motor, thermal, ambient)
    if np.max(np.linalg.eigvals(a).real) >= 0:
        return math.inf
    return float(-np.linalg.solve(a, b)[0])


def rated_temperature(motor: Motor, thermal: MotorThermal) -> float:
    """The winding temperature the nominal torque holds in steady state at the rated ambient, C: the
    limit of :func:`walk_time` (see the module's docstring)."""
    return thermal.ambient + steady_rise(motor.nominal_torque / motor.torque_constant, motor, thermal)


def winding_temperature(t, current: float, motor: Motor, thermal: MotorThermal, ambient: float | None = None,
                        start=None) -> np.ndarray:
    """The winding's temperature, C, at times ``t`` (s, any shape) under a constant RMS current (A), from
    ``start`` ((winding, housing) temperatures, C; default both at the ambient)."""
    ambient = thermal.ambient if ambient is None else ambient
    a, b = _system(current, motor, thermal, ambient)
    delta0 = np.zeros(2) if start is None else np.asarray(start, dtype=float) - ambient
    steady = -np.linalg.solve(a, b)
    times = np.asarray(t, dtype=float)
    rises = [(steady + linalg.expm(a * s) @ (delta0 - steady))[0] for s in times.ravel()]
    return ambient + np.asarray(rises).reshape(times.shape)


def walk_time(current: float, motor: Motor, thermal: MotorThermal, ambient: float | None = None,
              limit: float | None = None) -> float:
    """How long a motor starting at the ambient can carry a constant RMS current (A) before its winding
    reaches ``limit`` (C; default :func:`rated_temperature`), s; inf where it never does (the steady
    rise stays below). Raises ValueError naming a negative or non-finite current."""
    if not (math.isfinite(current) and current >= 0):
        raise ValueError(f"current must be a finite RMS current >= 0 A, got {current!r}")
    ambient = thermal.ambient if ambient is None else ambient
    limit = rated_temperature(motor, thermal) if limit is None else limit
    if ambient >= limit:
        return 0.0
    if steady_rise(current, motor, thermal, ambient) <= (limit - ambient) * (1 + 1e-9):  # at the rating: forever
        return math.inf
    excess = lambda s: float(winding_temperature(s, current, motor, thermal, ambient)) - limit  # noqa: E731
    high = thermal.winding_time_constant
    while excess(high) < 0:  # the rise from the ambient is monotone: bracket the crossing
        high *= 2.0
    return float(optimize.brentq(excess, 0.0, high, xtol=1e-6, rtol=1e-10))
