"""The two-node thermal model of the motors (how long a drive walks): its closed form against a
numerical integration of the same network, energy balance in steady state, the limit at the catalogue's
rating, and the walk time's behaviour."""

import math

import numpy as np
import pytest
from scipy import integrate

from biped_jax.drives import model as drive_model
from biped_jax.drives import thermal

CATALOGUE = drive_model.load_catalogue()
THERMAL = thermal.load_thermal()
MOTOR = CATALOGUE.motor("RE25-42V")
NOMINAL_CURRENT = MOTOR.nominal_torque / MOTOR.torque_constant


def _integrated(current, times, ambient=25.0):
    """The network written out as ODEs (heat capacities from the time constants, the loss rising with
    the winding's temperature), integrated numerically: the winding's temperature at ``times``."""
    c_w = THERMAL.winding_time_constant / THERMAL.winding_housing
    c_h = THERMAL.motor_time_constant / THERMAL.housing_ambient

    def rates(_, temperatures):
        winding, housing = temperatures
        loss = current**2 * MOTOR.resistance * (1 + THERMAL.temperature_coefficient * (winding - 25.0))
        to_housing = (winding - housing) / THERMAL.winding_housing
        return [(loss - to_housing) / c_w, (to_housing - (housing - ambient) / THERMAL.housing_ambient) / c_h]
    return integrate.solve_ivp(rates, (0, times[-1]), [ambient, ambient], t_eval=times, rtol=1e-10,
                               atol=1e-10, method="LSODA").y[0]


def test_the_closed_form_is_the_integrated_network():
    times = np.array([1.0, 10.0, 60.0, 600.0, 3000.0])
    for current, ambient in ((1.5 * NOMINAL_CURRENT, 25.0), (0.8 * NOMINAL_CURRENT, 40.0)):
        closed = thermal.winding_temperature(times, current, MOTOR, THERMAL, ambient=ambient)
        np.testing.assert_allclose(closed, _integrated(current, times, ambient), rtol=1e-7, atol=1e-6)


def test_in_steady_state_the_loss_leaves_through_both_resistances():
    """Delta_w = P(T_w) (R_wh + R_ha), the loss at the winding's own temperature."""
    current = 1.3 * NOMINAL_CURRENT
    rise = thermal.steady_rise(current, MOTOR, THERMAL)
    loss = current**2 * MOTOR.resistance * (1 + THERMAL.temperature_coefficient * rise)
    assert rise == pytest.approx(loss * (THERMAL.winding_housing + THERMAL.housing_ambient), rel=1e-12)
    late = thermal.winding_temperature(1e5, current, MOTOR, THERMAL)
    assert float(late) == pytest.approx(25.0 + rise, rel=1e-9)
    # a loss that grows faster with temperature than the motor sheds it runs away
    runaway = 1.01 / math.sqrt(MOTOR.resistance * THERMAL.temperature_coefficient
                               * (THERMAL.winding_housing + THERMAL.housing_ambient))
    assert thermal.steady_rise(runaway, MOTOR, THERMAL) == math.inf


def test_the_walk_lasts_forever_exactly_within_the_nominal_torque():
    """The limit is the winding temperature the nominal torque holds in steady state: the same for every
    RE 25 winding (equal motor constants), below the winding's absolute maximum (125 C)."""
    limits = [thermal.rated_temperature(m, THERMAL) for m in CATALOGUE.motors.values()]
    assert max(limits) - min(limits) < 5.0 and 60.0 < min(limits) < 125.0
    assert thermal.walk_time(NOMINAL_CURRENT, MOTOR, THERMAL) == math.inf
    assert thermal.walk_time(0.99 * NOMINAL_CURRENT, MOTOR, THERMAL) == math.inf
    times = [thermal.walk_time(f * NOMINAL_CURRENT, MOTOR, THERMAL) for f in (1.02, 1.2, 1.5, 2.0, 3.0)]
    assert all(math.isfinite(t) for t in times) and times == sorted(times, reverse=True)
    # at the time found the winding is at the limit, earlier below it
    t, current = times[2], 1.5 * NOMINAL_CURRENT
    limit = thermal.rated_temperature(MOTOR, THERMAL)
    assert float(thermal.winding_temperature(t, current, MOTOR, THERMAL)) == pytest.approx(limit, abs=1e-6)
    assert float(thermal.winding_temperature(0.9 * t, current, MOTOR, THERMAL)) < limit
    # far above the rating the winding heats as its own heat capacity alone: t ~ C_w Delta / P
    current = 6.0 * NOMINAL_CURRENT
    loss = current**2 * MOTOR.resistance
    adiabatic = THERMAL.winding_time_constant / THERMAL.winding_housing * (limit - 25.0) / loss
    assert thermal.walk_time(current, MOTOR, THERMAL) == pytest.approx(adiabatic, rel=0.25)
    with pytest.raises(ValueError, match="current must be a finite RMS current >= 0 A, got nan"):
        thermal.walk_time(float("nan"), MOTOR, THERMAL)
