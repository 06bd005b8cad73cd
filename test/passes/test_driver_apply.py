"""apply, validate and diagnose on driver bags: what goes into /imu/data_compensated and into the JSON."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from tak_thermo_ros.formats.bag import read_imu_messages, write_driver_record, write_record
from tak_thermo_ros.cli import main
from tak_thermo_ros.formats.calibration_file import load_unit, save_calibration
from tak_thermo_ros.core.link.correction import UnitCorrector, acceleration_variance
from tak_thermo_ros.core.records.record import DriverRecord, align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.simulation.truth import RATE_TABLE_POSITIONS, RATE_TABLE_RATES

RUN = Scenario(output='imu', plateaus_celsius=(5.0, 35.0), plateau_hours=0.25, ramp_celsius_per_minute=1.0,
               board_lag_s=300.0, dwell_s=30.0, positions=RATE_TABLE_POSITIONS, table_rates=RATE_TABLE_RATES,
               frame_id='imu_link', seed=21)
"""A short rate-table run (about 1.3 h at 1 Hz)."""

NON_FINITE = {10: (0, math.nan), 11: (5, math.inf), 500: (2, -math.inf), 501: (3, math.nan), 2000: (4, math.nan)}
"""Rows of the run to spoil: row -> (channel 0..5 = accel x y z, gyro x y z, value)."""


def _with_orientation(driver: DriverRecord, seed: int) -> DriverRecord:
    """A driver that reports an orientation (random unit quaternions) and a per-message covariance."""
    rng = np.random.default_rng(seed)
    quaternion = rng.standard_normal((len(driver.stamp_ns), 4))
    quaternion /= np.linalg.norm(quaternion, axis=1, keepdims=True)
    covariance = np.zeros((len(driver.stamp_ns), 9))
    covariance[:, [0, 4, 8]] = rng.uniform(1e-4, 1e-2, (len(driver.stamp_ns), 3))
    return replace(driver, orientation=quaternion, orientation_covariance=covariance)


def _spoiled(driver: DriverRecord) -> DriverRecord:
    accel, gyro = driver.accel.copy(), driver.gyro.copy()
    for row, (channel, value) in NON_FINITE.items():
        (accel if channel < 3 else gyro)[row, channel % 3] = value
    return replace(driver, accel=accel, gyro=gyro)


@pytest.fixture(scope='module')
def bags(tmp_path_factory):
    """A calibration bag and its fit; a second run of the unit with an orientation and spoiled messages."""
    root = tmp_path_factory.mktemp('driver_apply')
    calibration = simulate(RUN).driver
    write_driver_record(root / 'cal', calibration)
    assert main(['fit', str(root / 'cal'), '-o', str(root / 'p.yaml'), '--no-progress']) == 0
    second = _spoiled(_with_orientation(simulate(replace(RUN, seed=22)).driver, 5))
    write_driver_record(root / 'run2', second)
    return root, second


def test_apply_corrects_both_sensors_and_passes_the_rest_through(bags, capsys):
    """/imu/data_compensated: the corrector's output, stamps, frame, orientation and its covariance as given."""
    root, driver = bags
    assert main(['apply', str(root / 'run2'), '--params', str(root / 'p.yaml'), '-o', str(root / 'out'),
                 '--no-progress']) == 0
    stdout = capsys.readouterr().out
    assert f'dropped Imu messages: {len(NON_FINITE)} non finite' in stdout
    messages = read_imu_messages(root / 'out', topic='/imu/data_compensated')
    kept = np.setdiff1d(np.arange(len(driver.stamp_ns)), list(NON_FINITE))
    assert f'wrote {len(kept)} Imu messages on /imu/data_compensated' in stdout
    assert np.array_equal(messages.stamp_ns, driver.stamp_ns[kept])
    assert set(messages.frame_ids) == {'imu_link'}
    assert np.array_equal(messages.orientation, driver.orientation[kept])
    assert np.array_equal(messages.orientation_covariance, driver.orientation_covariance[kept])
    unit = load_unit(root / 'p.yaml')
    samples = align(driver.six_channels(), use_reference=False)
    assert np.array_equal(samples.rows, kept)
    expected = UnitCorrector(unit).correct(samples.counts, samples.temp_code, stamp_s=samples.stamp_s)
    assert np.array_equal(messages.linear_acceleration, expected[:, :3])
    assert np.array_equal(messages.angular_velocity, expected[:, 3:])
    accel_var, gyro_var = acceleration_variance(unit.accel), acceleration_variance(unit.gyro)
    assert np.all(messages.linear_acceleration_covariance == [accel_var[0], 0, 0, 0, accel_var[1], 0, 0, 0,
                                                              accel_var[2]])
    assert np.all(messages.angular_velocity_covariance == [gyro_var[0], 0, 0, 0, gyro_var[1], 0, 0, 0, gyro_var[2]])
    for variance, sensor in ((gyro_var, RUN.gyro_unit), (accel_var, RUN.accel_unit)):  # the noise, from the fit
        np.testing.assert_allclose(np.sqrt(variance), [a.noise_counts for a in sensor], rtol=0.05)


def test_validate_on_a_driver_bag_reports_both_sensors(bags, capsys):
    """Rate table second run: |g| and the gyro's rate error fall to the noise; rows with NaN are left out."""
    root, driver = bags
    assert main(['validate', str(root / 'run2'), '--params', str(root / 'p.yaml'), '--json',
                 str(root / 'v.json'), '--no-progress']) == 0
    stdout = capsys.readouterr().out
    assert 'gyroscope error over' in stdout and "before: the driver's values as recorded" in stdout
    document = json.loads((root / 'v.json').read_text())
    gyro = document['gyro']
    assert gyro['samples'] == len(driver.stamp_ns) - sum(1 for _, (c, _) in NON_FINITE.items() if c >= 3)
    for axis, unit in zip('xyz', RUN.gyro_unit):
        assert gyro['after'][axis]['rms'] < 1.1 * unit.noise_counts
        assert gyro['before'][axis]['rms'] > 2.0 * unit.noise_counts
    assert document['after']['rms'] < document['before']['rms'] / 2.0


def test_apply_refuses_a_calibration_of_the_other_input_kind(bags, tmp_path, capsys):
    """A v1 (counts) calibration on a driver bag and a v2 one on a counts bag: one line, exit 2, no output."""
    root, _ = bags
    save_calibration(tmp_path / 'v1.yaml', Scenario().truth())
    counts_run = simulate(Scenario(plateaus_celsius=(15.0, 25.0), plateau_hours=0.05, dwell_s=30.0))
    write_record(tmp_path / 'counts', counts_run.record)
    for bag, params, says in ((root / 'run2', tmp_path / 'v1.yaml', 'holds a driver Imu'),
                              (tmp_path / 'counts', root / 'p.yaml', 'holds channel codes')):
        out = tmp_path / f'out_{bag.name}'
        assert main(['apply', str(bag), '--params', str(params), '-o', str(out), '--no-progress']) == 2
        error = capsys.readouterr().err
        assert error.count('\n') == 1 and error.startswith(f'tak_calib: error: {params} ')
        assert error.rstrip().endswith(f'{bag} {says}')
        assert not out.exists()


def test_diagnose_json_and_report_cover_both_sensors(bags, tmp_path, capsys):
    """sensors.accel and sensors.gyro: verdict, axes.{x,y,z}.{rms,noise_floor}, candidates; report pages for both."""
    root, _ = bags
    assert main(['diagnose', str(root / 'cal'), '--params', str(root / 'p.yaml'), '--json',
                 str(tmp_path / 'd.json'), '--report', str(tmp_path / 'report'), '--no-progress']) == 0
    capsys.readouterr()
    document = json.loads((tmp_path / 'd.json').read_text())
    assert set(document['sensors']) == {'accel', 'gyro'}
    for sensor, unit, name in (('accel', RUN.accel_unit, 'm/s^2'), ('gyro', RUN.gyro_unit, 'rad/s')):
        entry = document['sensors'][sensor]
        assert entry['verdict'] == 'none' and entry['unit'] == name and isinstance(entry['candidates'], list)
        for axis, truth in zip('xyz', unit):
            assert entry['axes'][axis]['noise_floor'] == pytest.approx(truth.noise_counts, rel=0.1)
            assert entry['axes'][axis]['rms'] == pytest.approx(truth.noise_counts, rel=0.1)
    # the top level keeps today's fields, for the accelerometer
    assert document['verdict'] == document['sensors']['accel']['verdict']
    assert document['axes'] == document['sensors']['accel']['axes']
    index = (tmp_path / 'report' / 'report.html').read_text()
    for sensor in ('accel', 'gyro'):
        assert (tmp_path / 'report' / sensor / 'report.html').exists()
        assert f'{sensor}/report.html' in index
        assert list((tmp_path / 'report' / sensor).glob('*.png'))
    # Each sensor's residual table in its reader's unit, three significant figures (not 0.001 0.001 0.001).
    from tak_thermo_ros.units import readable
    for sensor, name, shown in (('accel', 'm/s^2', 'mg'), ('gyro', 'rad/s', 'deg/h')):
        page = (tmp_path / 'report' / sensor / 'report.html').read_text()
        assert f'<th>RMS ({shown})</th>' in page
        for axis in 'xyz':
            rms = document['sensors'][sensor]['axes'][axis]['rms']
            assert f'<td>{readable(rms, name).split()[0]}</td>' in page
