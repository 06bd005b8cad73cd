"""Driver bags (sensor_msgs/Imu in SI units, temperature in degrees C): the fit against the simulated truth.

Tolerances follow from the noise: a fitted curve (offset or gain over the calibrated temperature
range) is known to about ``noise / sqrt(samples per parameter)``; the tests allow
:data:`SIGMAS` of that (over six seeds the worst point of any curve stayed below 3).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tak_thermo_ros.formats.bag import Topics, write_driver_record
from tak_thermo_ros.cli import main
from tak_thermo_ros.cli.common import unwrap
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.core.link.model import Calibration, InputKind
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.simulation.truth import RATE_TABLE_POSITIONS, RATE_TABLE_RATES
from tak_thermo_ros.core.values import EARTH_RATE, STANDARD_GRAVITY, normal_gravity

SIGMAS = 5.0
BIAS_ORDER, SCALE_ORDER = 3, 2
PARAMETERS = BIAS_ORDER + SCALE_ORDER + 2
"""Fitted parameters per axis of the default model (scale and offset polynomials)."""

RATE_TABLE = Scenario(output='imu', plateau_hours=0.5, ramp_celsius_per_minute=1.0, board_lag_s=300.0,
                      dwell_s=30.0, positions=RATE_TABLE_POSITIONS, table_rates=RATE_TABLE_RATES, seed=1)
"""A rate-table calibration run (each axis up and down, resting and turning at +-1 rad/s), about 3 h."""

STATIC = Scenario(output='imu', plateau_hours=0.5, ramp_celsius_per_minute=1.0, board_lag_s=300.0,
                  positions=((0.0, 0.0, 1.0),), record_references=False, seed=2)
"""A static run as ``ros2 bag record`` of the driver alone gives: z up, no reference topics."""

INPUT_MAGNITUDE = {'accel': RATE_TABLE.gravity, 'gyro': 1.0}
"""The largest input of each sensor on the rate table: gravity, m/s^2; the table rate, rad/s."""


def _fit(bag: Path, output: Path, capsys, *options: str) -> str:
    assert main(['fit', str(bag), '-o', str(output), '--no-progress', *options]) == 0
    return '\n'.join(unwrap(capsys.readouterr().out))  # one statement a line, as printed before wrapping


def _curves(calibration: Calibration, temperature: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(offset, gain)`` per axis, ``(3, k)``, at absolute temperatures (degrees C)."""
    n = temperature - calibration.temp_code_ref
    offset = np.array([axis.offset + axis.offset_drift(n) for axis in calibration.axes])
    gain = np.array([axis.scale * axis.scale_factor(n) for axis in calibration.axes])
    return offset, gain


def _grid(calibration: Calibration) -> np.ndarray:
    return np.linspace(calibration.temp_code_min, calibration.temp_code_max, 61)


@pytest.fixture(scope='module')
def rate_table(tmp_path_factory):
    """The rate-table run, written in both storages, and fitted from each."""
    root = tmp_path_factory.mktemp('driver_fit')
    run = simulate(RATE_TABLE)
    return root, run


@pytest.fixture(scope='module')
def static_run(tmp_path_factory):
    """The static run (no reference topics) as an mcap bag."""
    root = tmp_path_factory.mktemp('driver_static')
    run = simulate(STATIC)
    write_driver_record(root / 'static', run.driver)
    return root, run


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_rate_table_fit_recovers_scale_offset_and_drift_of_both_sensors(rate_table, storage, capsys):
    """Offset and gain over the whole range, both sensors, every axis, within 5 sigma of the truth."""
    root, run = rate_table
    bag = root / f'cal_{storage}'
    write_driver_record(bag, run.driver, storage=storage)
    stdout = _fit(bag, root / f'params_{storage}.yaml', capsys)
    assert 'reference: /tak/reference and /tak/reference_rate as recorded' in stdout
    assert 'accelerometer, per axis x y z:' in stdout and 'gyroscope, per axis x y z:' in stdout
    unit = load_unit(root / f'params_{storage}.yaml')
    assert unit.input_kind is InputKind.IMU
    units = {'accel': RATE_TABLE.accel_unit, 'gyro': RATE_TABLE.gyro_unit}
    for sensor, calibration in unit.sensors:
        truth = run.unit_truth.sensor(sensor)
        samples = align(run.driver.channel(sensor))
        grid = _grid(calibration)
        offset, gain = _curves(calibration, grid)
        true_offset, true_gain = _curves(truth, grid)
        for i, axis in enumerate(calibration.axes):
            noise = units[sensor][i].noise_counts
            turning = np.count_nonzero(np.abs(samples.reference[:, i]) > 0.5 * INPUT_MAGNITUDE[sensor])
            offset_sigma = noise / math.sqrt(len(samples) / PARAMETERS)
            gain_sigma = noise / (INPUT_MAGNITUDE[sensor] * math.sqrt(turning / PARAMETERS))
            where = f'{sensor}.{"xyz"[i]}'
            assert axis.scale_observable, where
            assert np.max(np.abs(offset[i] - true_offset[i])) < SIGMAS * offset_sigma, where
            assert np.max(np.abs(gain[i] - true_gain[i])) < SIGMAS * gain_sigma, where
            # the tolerance is far below what there is to recover
            assert np.ptp(true_offset[i]) > 20.0 * SIGMAS * offset_sigma, where
            assert np.max(np.abs(true_gain[i] - 1.0)) > 3.0 * SIGMAS * gain_sigma, where
            # the residual is the white noise: RMS of n samples within a few 1/sqrt(2n)
            assert axis.residual_rms == pytest.approx(noise, rel=SIGMAS / math.sqrt(2.0 * len(samples))), where


def test_both_storages_give_the_same_calibration(rate_table, capsys):
    """The sqlite3 bag and the mcap bag of one run fit to the same file, value for value."""
    root, run = rate_table
    for storage in ('mcap', 'sqlite3'):
        if not (root / f'params_{storage}.yaml').exists():
            write_driver_record(root / f'cal_{storage}', run.driver, storage=storage)
            _fit(root / f'cal_{storage}', root / f'params_{storage}.yaml', capsys)
    assert load_unit(root / 'params_mcap.yaml') == load_unit(root / 'params_sqlite3.yaml')


def test_static_run_estimates_the_reference_holds_scale_and_recovers_the_gyro_drift(static_run, capsys):
    """No reference topics: gravity along the mean direction, rate zero, scales held at 1 and said once."""
    root, run = static_run
    stdout = _fit(root / 'static', root / 'static.yaml', capsys)
    lines = stdout.splitlines()
    mean = run.driver.accel.mean(axis=0)
    expected = STATIC.gravity * mean / np.linalg.norm(mean)
    line = next(line for line in lines if line.startswith('  = ('))
    assert 'reference (static run): mean measured direction scaled to gravity' in stdout
    assert f'({expected[0]:.4f}, {expected[1]:.4f}, {expected[2]:.4f}) m/s^2' in line
    assert 'rate reference (static run): zero' in lines
    for sensor in ('accelerometer', 'gyroscope'):
        notes = [line for line in lines if line.startswith(f'note: {sensor}: scale held at nominal on x, y, z')]
        assert len(notes) == 1 and notes[0].endswith('(scale_observable false)')
    unit = load_unit(root / 'static.yaml')
    for sensor, calibration in unit.sensors:
        assert [axis.scale for axis in calibration.axes] == [1.0, 1.0, 1.0]
        assert not any(axis.scale_observable for axis in calibration.axes)
        assert calibration.notes and 'scale held at nominal' in calibration.notes[0]
    # The gyroscope sees no rate: its offset curve is the true one (the scale does not enter).
    gyro, truth = unit.gyro, run.unit_truth.gyro
    samples = align(run.driver.channel('gyro'))
    grid = _grid(gyro)
    offset, _ = _curves(gyro, grid)
    true_offset, _ = _curves(truth, grid)
    for i in range(3):
        sigma = STATIC.gyro_unit[i].noise_counts / math.sqrt(len(samples) / (BIAS_ORDER + 1))
        assert np.max(np.abs(offset[i] - true_offset[i])) < SIGMAS * sigma
        assert np.ptp(true_offset[i]) > 20.0 * SIGMAS * sigma
    # The accelerometer, held at scale 1 against the estimated reference, predicts what it measured.
    accel = unit.accel
    reference = np.tile(expected, (len(grid), 1))
    true_force = np.tile([0.0, 0.0, STATIC.gravity], (len(grid), 1))
    predicted = accel.forward(reference, grid)
    measured = run.unit_truth.accel.forward(true_force, grid)
    for i in range(3):
        sigma = STATIC.accel_unit[i].noise_counts / math.sqrt(len(samples) / (BIAS_ORDER + 1))
        assert np.max(np.abs(predicted[:, i] - measured[:, i])) < SIGMAS * sigma


def test_latitude_adds_the_vertical_earth_rate_to_the_gyro_reference(static_run, capsys):
    """--latitude 48: the reference gains Omega_E sin(48 deg) along up; the gyro offsets shift by it."""
    root, run = static_run
    if not (root / 'static.yaml').exists():
        _fit(root / 'static', root / 'static.yaml', capsys)
    stdout = _fit(root / 'static', root / 'latitude.yaml', capsys, '--latitude', '48')
    mean = run.driver.accel.mean(axis=0)
    up = mean / np.linalg.norm(mean)
    earth = EARTH_RATE * math.sin(math.radians(48.0)) * up
    assert ("rate reference (static run): the Earth rate's vertical component at latitude 48 deg = "
            f'({earth[0]:.3e}, {earth[1]:.3e}, {earth[2]:.3e}) rad/s') in stdout
    plain, with_earth = load_unit(root / 'static.yaml').gyro, load_unit(root / 'latitude.yaml').gyro
    for i in range(3):
        # scale held at 1: the measured rate is offset + 1 * reference, so the offset moves by the reference
        assert with_earth.axes[i].offset == pytest.approx(plain.axes[i].offset - earth[i], abs=1e-12)
        np.testing.assert_allclose(with_earth.axes[i].offset_drift(np.linspace(-15, 15, 7)),
                                   plain.axes[i].offset_drift(np.linspace(-15, 15, 7)), rtol=0, atol=1e-12)
    # Local gravity from the latitude (WGS-84 normal gravity, no --gravity given): the accelerometer's
    # reference grows by g(48) - g0 along up, its offsets (scale held) fall by as much.
    grown = (normal_gravity(48.0) - STANDARD_GRAVITY) * up
    plain_accel, local_accel = load_unit(root / 'static.yaml').accel, load_unit(root / 'latitude.yaml').accel
    for i in range(3):
        assert local_accel.axes[i].offset == pytest.approx(plain_accel.axes[i].offset - grown[i], abs=1e-9)
    assert f'scaled to gravity {normal_gravity(48.0):.6g} m/s^2' in stdout


def test_normal_gravity_follows_the_wgs84_ellipsoid():
    """Somigliana's formula: 9.7803 m/s^2 at the equator, 9.8322 at the poles, 9.8062 at 45 deg (WGS-84)."""
    assert normal_gravity(0.0) == pytest.approx(9.7803253, abs=1e-7)
    assert normal_gravity(90.0) == pytest.approx(9.8321849, abs=1e-7)
    assert normal_gravity(-90.0) == normal_gravity(90.0)
    assert normal_gravity(45.0) == pytest.approx(9.806198, abs=1e-6)


def test_topic_names_are_options(rate_table, capsys):
    """A bag with other topic names fits to the same calibration when the names are given."""
    root, run = rate_table
    topics = Topics(raw_imu='/driver/imu', temperature='/driver/temperature', reference='/table/force',
                    reference_rate='/table/rate')
    write_driver_record(root / 'renamed', run.driver, topics=topics)
    write_driver_record(root / 'default_names', run.driver)
    _fit(root / 'default_names', root / 'default.yaml', capsys)
    _fit(root / 'renamed', root / 'renamed.yaml', capsys, '--raw-imu-topic', '/driver/imu', '--temp-topic',
         '/driver/temperature', '--reference-topic', '/table/force', '--reference-rate-topic', '/table/rate')
    assert load_unit(root / 'renamed.yaml') == load_unit(root / 'default.yaml')
    # Without the names the bag holds no Imu topic that tak_calib knows: one line naming it.
    assert main(['fit', str(root / 'renamed'), '-o', str(root / 'x.yaml'), '--no-progress']) == 2
    error = capsys.readouterr().err
    assert error.count('\n') == 1 and error.startswith('tak_calib: error: ') and '/imu/data_raw' in error
    assert not (root / 'x.yaml').exists()
