"""The drive model against the DC-motor equations and the catalogue's own datasheet figures."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from biped_jax.drives import model as drive_model

CATALOGUE = drive_model.load_catalogue()
RE25_24V = CATALOGUE.motor("RE25-118752")


def test_stall_torque_and_no_load_speed_match_the_datasheet():
    """k_t V / R and V / k_t at the nominal 24 V against the datasheet's 243 mNm and 9560 rpm: the
    datasheet's no-load speed is 2.4 % below the ideal motor's (friction and brush drop, which the
    model leaves out; the ideal line errs on the optimistic side by that much)."""
    stall = drive_model.stall_torque(RE25_24V, 24.0)
    assert stall / drive_model.MNM == pytest.approx(243.0, rel=0.01)
    no_load = drive_model.no_load_speed(RE25_24V, 24.0) / drive_model.RPM
    assert no_load == pytest.approx(9560.0, rel=0.03)
    assert no_load == pytest.approx(408.0 * 24.0, rel=0.01)  # k_n V


def test_speed_torque_gradient_matches_the_datasheet():
    """R / k_t^2 in rpm/mNm against the datasheet's 40.3 rpm/mNm."""
    gradient = drive_model.speed_torque_gradient(RE25_24V) * drive_model.MNM / drive_model.RPM
    assert gradient == pytest.approx(40.3, rel=0.01)


def test_electrical_power_is_mechanical_power_plus_joule_loss_everywhere():
    rng = np.random.default_rng(0)
    torque = jnp.asarray(rng.normal(scale=0.1, size=200))
    speed = jnp.asarray(rng.normal(scale=800.0, size=200))
    for motor in CATALOGUE.motors.values():
        p_el = drive_model.electrical_power(torque, speed, motor)
        np.testing.assert_allclose(p_el, torque * speed + drive_model.joule_loss(torque, motor), rtol=1e-12,
                                   atol=1e-12)


def test_supply_voltage_scales_the_characteristic_line_as_eq_2_5():
    """n_mV = n_m V_s / V_m; the stall torque scales the same way; the slope does not change."""
    for motor in CATALOGUE.motors.values():
        rated = drive_model.no_load_speed(motor, motor.nominal_voltage)
        assert drive_model.no_load_speed(motor, 38.0) == pytest.approx(rated * 38.0 / motor.nominal_voltage)
        line = lambda t, v: drive_model.max_speed_at_torque(t, motor, v)  # noqa: E731
        assert float(line(0.05, 38.0) - line(0.10, 38.0)) == pytest.approx(
            float(line(0.05, 24.0) - line(0.10, 24.0)))
        # on the line the voltage needed equals the supply
        torque = 0.3 * drive_model.stall_torque(motor, 38.0)
        speed = line(torque, 38.0)
        assert float(drive_model.voltage(torque, speed, motor)) == pytest.approx(38.0, rel=1e-12)
        assert float(drive_model.voltage_margin(torque, 0.9 * speed, motor, 38.0)) > 0


def test_estimated_windings_follow_the_spec_table_at_38_volts():
    """No-load speed and stall torque at 38 V of the estimated windings (the catalogue's provenance,
    biped_jax/data/maxon_catalogue.json)."""
    expected = {"RE25-30V": (12400, 309), "RE25-42V": (8860, 221), "RE25-48V": (7750, 193)}
    for part, (speed_rpm, stall_mnm) in expected.items():
        motor = CATALOGUE.motor(part)
        assert drive_model.no_load_speed(motor, 38.0) / drive_model.RPM == pytest.approx(speed_rpm, rel=0.01)
        assert drive_model.stall_torque(motor, 38.0) / drive_model.MNM == pytest.approx(stall_mnm, rel=0.01)


def test_gear_reflects_torque_with_efficiency_depending_on_power_flow():
    gear = CATALOGUE.gearhead("GP32A-66.22")
    # motoring: the motor supplies the losses; back-driving: the load does
    assert float(drive_model.motor_torque(2.0, 1.0, gear.ratio, gear.efficiency)) == pytest.approx(
        2.0 / (66.22 * 0.7))
    assert float(drive_model.motor_torque(2.0, -1.0, gear.ratio, gear.efficiency)) == pytest.approx(
        2.0 * 0.7 / 66.22)
    assert float(drive_model.motor_speed(1.5, gear.ratio)) == pytest.approx(99.33)


def test_drive_model_is_differentiable():
    gear = CATALOGUE.gearhead("GP32A-66.22")
    motor = CATALOGUE.motor("RE25-42V")

    def joule(ratio):
        return drive_model.joule_loss(drive_model.motor_torque(3.0, 5.0, ratio, gear.efficiency), motor)
    # P_J ~ 1 / N^2, so d P_J / d N = -2 P_J / N
    assert float(jax.grad(joule)(66.0)) == pytest.approx(-2 * float(joule(66.0)) / 66.0, rel=1e-10)


def test_catalogue_integrity():
    assert CATALOGUE.supply_voltage == 38.0
    assert len(CATALOGUE.gearheads) == 3 + 6 + 10 + 13
    for entry in [*CATALOGUE.motors.values(), *CATALOGUE.gearheads.values()]:
        assert entry.provenance in ("datasheet", "estimate") and entry.source, entry.part
        assert entry.mass > 0
    for motor in CATALOGUE.motors.values():
        # SI: k_t in N m/A of order 0.02-0.05; the motor constant k_t / sqrt(R) is winding-independent
        assert 0.01 < motor.torque_constant < 0.1
        assert motor.torque_constant / math.sqrt(motor.resistance) == pytest.approx(0.0154, rel=0.03)
        assert 1e-7 < motor.rotor_inertia < 1e-5
    for gear in CATALOGUE.gearheads.values():
        assert 0.5 <= gear.efficiency <= 0.8 and gear.continuous_torque < gear.intermittent_torque
    # both ratios the paper names are catalogue parts
    assert CATALOGUE.gearhead("GP32A-66.22").stages == 3
    assert CATALOGUE.gearhead("GP32A-245.96").stages == 4


def test_unknown_parts_and_bad_ratios_are_rejected():
    with pytest.raises(ValueError, match="'RE40'"):
        CATALOGUE.motor("RE40")
    with pytest.raises(ValueError, match="'GP32A-67'"):
        CATALOGUE.gearhead("GP32A-67")
    for ratio in (0.0, -66.0, float("inf")):
        with pytest.raises(ValueError, match="gear ratio"):
            drive_model.check_ratio(ratio)
