"""Table 6 and the drive selection on synthetic workspaces with known answers."""

import numpy as np
import pytest

from biped_jax.drives import model as drive_model
from biped_jax.drives import selection as ds

CATALOGUE = drive_model.load_catalogue()


def _constant_workspace(torque=1.0, speed=5.0, samples=200):
    t = np.linspace(0, 1, samples)  # the gait's samples include both ends of the step
    return ds.JointWorkspace(t=t, speed=np.full((samples, 1), speed), torque=np.full((samples, 1), torque),
                             step_time=1.0)


def test_requirements_drop_the_impact_spikes_by_the_documented_rule():
    w = _constant_workspace()
    w.torque[0, 0] = 10.0  # a touchdown spike at t = 0
    w.speed[-1, 0] = 50.0  # and one at the end
    r = ds.requirements(w)
    assert r["max_torque_Nm"] == pytest.approx(1.0)
    assert r["max_torque_with_impacts_Nm"] == pytest.approx(10.0)
    assert r["max_rpm"] == pytest.approx(5.0 / drive_model.RPM)
    assert r["max_rpm_with_impacts"] == pytest.approx(50.0 / drive_model.RPM)
    assert r["operational_torque_Nm"] == pytest.approx([1.0, 1.0])
    assert r["max_power_W"] == pytest.approx(5.0)


def test_selection_on_a_workspace_with_a_known_answer():
    """1 N m at 5 rad/s, motoring. Joule loss = (R / k_t^2) (T / (N eta))^2 favours the largest N eta;
    the gear's 6000 rpm input limit caps N at 125.7, so among catalogue ratios 123:1 (3 stages,
    eta 0.7) wins, driven by the winding with the largest k_t^2 / R."""
    best, candidates = ds.select_drive([_constant_workspace()], CATALOGUE)
    assert best["gearhead"] == "GP32A-123"
    motor_constant = {m.part: m.torque_constant**2 / m.resistance for m in CATALOGUE.motors.values()}
    assert best["motor"] == max(motor_constant, key=motor_constant.get)
    too_fast = next(c for c in candidates if c["gearhead"] == "GP32A-132")
    assert not too_fast["feasible"] and "input speed" in too_fast["reason"]
    expected_joule = (CATALOGUE.motor(best["motor"]).resistance
                      * (1.0 / (123 * 0.7) / CATALOGUE.motor(best["motor"]).torque_constant) ** 2)
    assert best["joule_energy_J"] == pytest.approx(expected_joule, rel=1e-9)


def test_voltage_thermal_and_gear_limits_each_fail_with_their_reason():
    motor, supply = CATALOGUE.motor("RE25-42V"), 38.0
    # fast: the back-EMF alone exceeds the supply (k_t N omega = 0.0409 * 66.22 * 16 = 43 V)
    fast = ds.check_drive(_constant_workspace(0.1, 16.0), motor, CATALOGUE.gearhead("GP32A-66.22"), supply)
    assert not fast["feasible"] and fast["reason"].startswith("voltage")
    # strong: 2 N m through 66:1 at 70 % is 43 mNm RMS at the motor, above its 26 mNm
    strong = ds.check_drive(_constant_workspace(2.0, 1.0), motor, CATALOGUE.gearhead("GP32A-66.22"), supply)
    assert strong["failed_checks"] and all(r.startswith("thermal") for r in strong["failed_checks"])
    assert strong["feasible_without_thermal"]  # the paper's criterion has no thermal check
    assert not fast["feasible_without_thermal"]
    # how long it walks: the transient thermal model at the check's RMS motor current; indefinitely
    # (None) exactly where the thermal check passes
    from biped_jax.drives import thermal
    current = strong["rms_motor_torque_mNm"] * 1e-3 / motor.torque_constant
    assert strong["walk_time_s"] == pytest.approx(thermal.walk_time(current, motor, thermal.load_thermal()))
    assert 10.0 < strong["walk_time_s"] < 3600.0
    assert fast["walk_time_s"] is None and not any(r.startswith("thermal") for r in fast["failed_checks"])
    # 3 N m RMS is above the two-stage gear's 2.25 N m continuous rating
    gear = ds.check_drive(_constant_workspace(3.0, 0.1), motor, CATALOGUE.gearhead("GP32A-28"), supply)
    assert any("continuous" in r for r in gear["failed_checks"])
