"""The magnetometer channel: its calibration file keys, its correction, the ellipsoid fit, the simulator."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import examples
from tak_thermo_ros.core.link.model import InputKind, MagnetometerCalibration, UnitCalibration
from tak_thermo_ros.core.magnetometer.channel import MagCorrector, check_tesla, magnetic_covariance
from tak_thermo_ros.core.magnetometer.iron import fit_ellipsoid
from tak_thermo_ros.formats.calibration_file import load_unit, save_unit, unit_from_mapping, unit_to_mapping
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario, scenario_from_mapping
from tak_thermo_ros.core.simulation.magnetometer import MagnetometerTruth, rotation_record
from tak_thermo_ros.errors import CalibrationError, FitError, ScenarioError, TakError

TRUTH = MagnetometerTruth()
STATIC = Scenario(output='imu', plateaus_celsius=(5.0, 35.0, 20.0), plateau_hours=0.25, ramp_celsius_per_minute=1.0,
                  board_lag_s=120.0, positions=((0.0, 0.0, 1.0),), record_references=False, magnetometer=TRUTH)


def normalised_inverse(truth: MagnetometerTruth) -> np.ndarray:
    """The fit's ``W``: ``S^-1`` with determinant 1."""
    inverse = np.linalg.inv(truth.soft_matrix())
    return inverse / np.linalg.det(inverse) ** (1.0 / 3.0)


def unit_with_mag() -> UnitCalibration:
    return Scenario(output='imu', magnetometer=TRUTH).driver_truth()


def test_the_file_holds_the_magnetometer_and_files_without_it_load_as_before(tmp_path):
    unit = unit_with_mag()
    path = tmp_path / 'params.yaml'
    save_unit(path, unit)
    loaded = load_unit(path)
    assert loaded.mag == unit.mag
    assert 'hard_iron' in path.read_text() and 'soft_iron' in path.read_text()
    without = replace(unit, mag=None)
    save_unit(tmp_path / 'imu.yaml', without)
    assert load_unit(tmp_path / 'imu.yaml').mag is None
    assert 'mag' not in unit_to_mapping(without)


@pytest.mark.parametrize(('change', 'key'), [
    (lambda m: m['mag'].update(soft_iron=[1.0, 0.1, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]), 'calibration.mag.soft_iron'),
    (lambda m: m['mag'].update(soft_iron=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0]), 'calibration.mag.soft_iron'),
    (lambda m: m['mag'].update(hard_iron=[0.0, 0.5, 0.0]), 'calibration.mag.hard_iron[1]'),
    (lambda m: m['mag'].update(hard_iron=[0.0, 0.0]), 'calibration.mag.hard_iron'),
    (lambda m: m['mag'].pop('soft_iron'), 'calibration.mag.soft_iron: missing'),
    (lambda m: m['mag'].update(hard_irn=[0.0, 0.0, 0.0]), 'calibration.mag.hard_irn: unknown key'),
    (lambda m: m['mag']['x'].update(offset=float('nan')), 'calibration.mag.x.offset'),
])
def test_bad_magnetometer_keys_are_refused_naming_the_key(change, key):
    mapping = unit_to_mapping(unit_with_mag())
    change(mapping)
    with pytest.raises(CalibrationError, match=key.replace('[', r'\[').replace(']', r'\]')):
        unit_from_mapping(mapping)


def test_counts_calibrations_have_no_magnetometer():
    unit = unit_with_mag()
    with pytest.raises(CalibrationError, match='calibration.mag'):
        UnitCalibration(InputKind.COUNTS, unit.accel, None, unit.mag)


def test_vectorised_and_per_sample_corrections_agree_bit_for_bit_and_undo_the_simulated_sensor():
    run = simulate(replace(STATIC, magnetometer=replace(TRUTH, noise=0.0), positions=((0.0, 0.0, 1.0), (1.0, 0.0, 0.0)),
                           dwell_s=60.0, record_references=True))
    driver, truth = run.driver, run.unit_truth.mag
    corrector = MagCorrector(truth)
    temperature = np.interp(driver.mag_stamp_ns, driver.temp_stamp_ns, driver.temperature)
    vectorised = corrector.correct(driver.mag, temperature)
    per_sample = np.array([corrector.correct_sample(tuple(v), t)
                           for v, t in zip(driver.mag.tolist(), temperature.tolist())])
    assert np.array_equal(vectorised, per_sample)
    # The exact correction (W = S^-1, the true link) gives the true field; the board temperature
    # is held between temperature messages, so allow the drift over 5 s of a ramp.
    held = driver.mag_reference[np.searchsorted(driver.mag_reference_stamp_ns, driver.mag_stamp_ns, side='right') - 1]
    assert np.max(np.abs(vectorised - held)) < 5e-9


def test_the_covariance_is_the_thermal_residual_turned_by_the_soft_iron():
    mag = unit_with_mag().mag
    covariance = np.array(magnetic_covariance(mag)).reshape(3, 3)
    soft = mag.soft_iron_matrix
    sigma = np.array([axis.residual_rms / axis.scale for axis in mag.thermal.axes])
    assert np.allclose(covariance, soft @ np.diag(sigma ** 2) @ soft.T, rtol=1e-12, atol=0.0)
    assert np.array_equal(covariance, covariance.T)
    unknown = replace(mag, thermal=replace(mag.thermal, axes=tuple(replace(a, residual_rms=None)
                                                                   for a in mag.thermal.axes)))
    assert magnetic_covariance(unknown) == (0.0,) * 9


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_the_ellipsoid_fit_recovers_hard_and_soft_iron_within_the_noise(seed):
    record = rotation_record(TRUTH, samples=2000, seed=seed)
    fit = fit_ellipsoid(record.mag)
    # The centre is the hard iron plus the sensor's own offset at the record's temperature
    # (20 C, the reference): the fit cannot tell them apart, nor need it.
    centre = np.array(TRUTH.hard_iron) + np.array(TRUTH.offset)
    # Standard error of a centre from k points on a sphere of radius r with noise s: about
    # s sqrt(3 / k); five of them.
    tolerance = 5.0 * TRUTH.noise * math.sqrt(3.0 / 2000)
    assert np.max(np.abs(np.array(fit.hard_iron) - centre)) < tolerance
    # W's elements: the same relative error, over the radius.
    radius = np.linalg.norm(TRUTH.earth_field)
    soft_error = np.max(np.abs(np.array(fit.soft_iron).reshape(3, 3) - normalised_inverse(TRUTH)))
    assert soft_error < 5.0 * TRUTH.noise / radius * math.sqrt(15.0 / 2000)
    assert abs(fit.residual_rms - TRUTH.noise) < 0.1 * TRUTH.noise
    assert fit.sections == 20


@pytest.mark.parametrize(('turn', 'why'), [('yaw', 'turn the unit about more than one axis'),
                                           ('cap', 'sections of the sphere')])
def test_a_record_covering_too_few_orientations_is_refused_in_one_line(turn, why):
    record = rotation_record(TRUTH, samples=2000, seed=4, turn=turn)
    with pytest.raises(FitError, match='covers too few orientations') as caught:
        fit_ellipsoid(record.mag)
    assert why in str(caught.value) and '\n' not in str(caught.value)


def test_bad_rotation_records_are_refused():
    record = rotation_record(TRUTH, samples=500, seed=5)
    values = record.mag.copy()
    values[10, 1] = np.nan
    with pytest.raises(FitError, match='1 samples are not finite'):
        fit_ellipsoid(values)
    with pytest.raises(FitError, match='needs at least 100'):
        fit_ellipsoid(record.mag[:50])
    with pytest.raises(FitError, match='field radius .* outside 15..95 uT'):
        fit_ellipsoid(record.mag * 1e4)  # gauss-sized numbers
    with pytest.raises(TakError, match='not a field in tesla .* gauss'):
        check_tesla(record.mag * 1e4, '/imu/mag')
    check_tesla(record.mag, '/imu/mag')


def _rotation(quaternion: tuple[float, float, float, float]) -> np.ndarray:
    w, x, y, z = np.array(quaternion) / np.linalg.norm(quaternion)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


_RECORD = rotation_record(TRUTH, samples=600, seed=6).mag
_FIT = fit_ellipsoid(_RECORD)


@settings(max_examples=examples(30), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.tuples(*[st.floats(-1.0, 1.0) for _ in range(4)]).filter(lambda q: sum(v * v for v in q) > 0.01))
def test_the_ellipsoid_fit_is_invariant_to_a_rotation_of_the_record(quaternion):
    rotation = _rotation(quaternion)
    fit = fit_ellipsoid(_RECORD @ rotation.T)
    assert np.allclose(fit.hard_iron, rotation @ np.array(_FIT.hard_iron), rtol=0.0, atol=1e-12)
    assert np.allclose(np.array(fit.soft_iron).reshape(3, 3),
                       rotation @ np.array(_FIT.soft_iron).reshape(3, 3) @ rotation.T, rtol=0.0, atol=1e-9)
    assert math.isclose(fit.radius, _FIT.radius, rel_tol=1e-9)
    assert math.isclose(fit.residual_rms, _FIT.residual_rms, rel_tol=1e-6)


def test_the_simulator_wires_the_magnetometer_into_driver_scenarios_only():
    run = simulate(STATIC)
    driver = run.driver
    assert len(driver.mag_stamp_ns) == len(driver.stamp_ns) and driver.mag.shape == (len(driver.stamp_ns), 3)
    # Without a magnetometer the other channels are unchanged (its own noise stream).
    plain = simulate(replace(STATIC, magnetometer=None)).driver
    assert np.array_equal(plain.accel, driver.accel) and np.array_equal(plain.gyro, driver.gyro)
    assert len(plain.mag_stamp_ns) == 0
    # The static field drifts with the temperature far beyond the noise.
    assert np.ptp(driver.mag[:, 0]) > 5 * TRUTH.noise
    assert isinstance(run.unit_truth.mag, MagnetometerCalibration)
    assert scenario_from_mapping({'output': 'imu', 'magnetometer': {'noise': 1e-7}}).magnetometer.noise == 1e-7
    with pytest.raises(ScenarioError, match='magnetometer.nois: unknown key'):
        scenario_from_mapping({'output': 'imu', 'magnetometer': {'nois': 1e-7}})
    with pytest.raises(ScenarioError, match='magnetometer: needs output: imu'):
        scenario_from_mapping({'magnetometer': {}})
