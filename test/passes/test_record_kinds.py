"""Every record a user has (issue 23): each command calibrates what the record determines and says what it does not.

Simulated records of the character of the public ones the issue names: a static IMU whose driver
publishes no temperature (a bag, and the same as CSV), a board with a magnetometer turned by hand
at one temperature (CSV with the field in gauss), a magnetometer turned while it warms up, a unit
never flipped, a rotation record without a temperature topic.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import yaml

from tak_thermo_ros.cli import main
from tak_thermo_ros.core.link.correction import OutOfRange
from tak_thermo_ros.core.link.model import THERMAL_FITTED, THERMAL_HELD, THERMAL_NONE
from tak_thermo_ros.core.link.online import OnlineCompensator
from tak_thermo_ros.core.magnetometer.channel import MagCorrector
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import scenario_from_mapping
from tak_thermo_ros.core.simulation.magnetometer import MagnetometerTruth, rotation_record, rotation_truth
from tak_thermo_ros.formats.bag import MAGNETIC_FIELD, bag_streams, iter_topic_arrays, write_driver_record
from tak_thermo_ros.formats.calibration_file import load_unit, unit_from_mapping, unit_to_mapping
from tak_thermo_ros.formats.kalibr import read_kalibr
from tak_thermo_ros.errors import CalibrationError

NOISE = {'noise_counts': 2.4e-4, 'bias_instability': 2.4e-5, 'bias_instability_tau': 30.0, 'random_walk': 6e-6}
ACCEL = {'noise_counts': 2.83e-3, 'bias_instability': 1e-4, 'bias_instability_tau': 30.0, 'random_walk': 4e-5}
STATIC = {'output': 'imu', 'sample_rate_hz': 2.0, 'plateaus_celsius': [20.0], 'plateau_hours': 1.0,
          'positions': [[0.0, 0.0, 1.0]], 'record_references': False,
          'gyro_unit': {'x': NOISE, 'y': NOISE, 'z': NOISE}, 'accel_unit': {'x': ACCEL, 'y': ACCEL, 'z': ACCEL}}
"""A 1 h static run at 2 Hz of a driver that publishes no temperature."""
TRUTH = MagnetometerTruth()
NOISE_T = TRUTH.noise
TURNS = 2000


def _no_temperature(driver):
    return replace(driver, temp_stamp_ns=np.zeros(0, dtype=np.int64), temperature=np.zeros(0))


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and err.startswith('tak_calib: error: ') and 'Traceback' not in err, err
    return err


def _written_field(bag) -> np.ndarray:
    return np.concatenate([a['magnetic_field'] for a in iter_topic_arrays(bag, '/imu/mag_compensated',
                                                                          MAGNETIC_FIELD)])


@pytest.fixture(scope='module')
def static_imu_only(tmp_path_factory):
    """The Imu-only static bag, the same record as a CSV without a temperature column, and the scenario."""
    root = tmp_path_factory.mktemp('imu_only')
    scenario = scenario_from_mapping(STATIC)
    driver = _no_temperature(simulate(scenario).driver)
    write_driver_record(root / 'static', driver)
    rows = ['t_ns,ax,ay,az,gx,gy,gz']
    rows += [f'{stamp},' + ','.join(repr(float(v)) for v in (*accel, *gyro))
             for stamp, accel, gyro in zip(driver.stamp_ns, driver.accel, driver.gyro)]
    (root / 'static.csv').write_text('\n'.join(rows) + '\n')
    return root, scenario


def test_noise_of_an_imu_only_static_bag_writes_a_kalibr_file(static_imu_only, capsys):
    root, scenario = static_imu_only
    assert bag_streams(root / 'static').temperature == 0
    assert main(['noise', str(root / 'static'), '-o', str(root / 'imu.yaml'), '--no-progress']) == 0
    assert 'rate reference (static run): zero' in capsys.readouterr().out
    raw = yaml.safe_load((root / 'imu.yaml').read_text())
    assert raw['rostopic'] == '/imu/data_raw' and raw['update_rate'] == pytest.approx(2.0)
    models = read_kalibr(root / 'imu.yaml')
    for sensor in ('accel', 'gyro'):
        truth = scenario.noise_truth(sensor).white_noise_density
        # 7200 samples per axis: the white density's scatter is about 2 % (one sigma).
        assert np.allclose(models[sensor].white_noise_density, truth, rtol=0.1), (sensor, truth)


def test_a_csv_without_temperature_imports_and_gives_the_same_noise(static_imu_only, capsys):
    root, _ = static_imu_only
    assert main(['import-csv', str(root / 'static.csv'), '-o', str(root / 'from_csv'), '--time-column', 't_ns',
                 '--time-unit', 'ns', '--acc-columns', 'ax', 'ay', 'az', '--gyro-columns', 'gx', 'gy', 'gz']) == 0
    assert 'no temperature column' in capsys.readouterr().out
    assert bag_streams(root / 'from_csv').temperature == 0
    assert main(['noise', str(root / 'from_csv'), '-o', str(root / 'csv.yaml'), '--no-progress']) == 0
    if not (root / 'imu.yaml').exists():
        assert main(['noise', str(root / 'static'), '-o', str(root / 'imu.yaml'), '--no-progress']) == 0
    # The same numbers as the bag's: the CSV carried every digit.
    body = [yaml.safe_load((root / name).read_text()) for name in ('csv.yaml', 'imu.yaml')]
    assert body[0] == body[1]


def test_what_needs_a_temperature_refuses_a_record_without_one_in_one_line(static_imu_only, tmp_path, capsys):
    root, _ = static_imu_only
    # The IMU's thermal fit: nothing else in the record (no magnetometer) to calibrate.
    assert main(['fit', str(root / 'static'), '-o', str(tmp_path / 'p.yaml'), '--no-progress']) == 2
    assert 'no temperature on /imu/temperature' in _one_line(capsys) and not (tmp_path / 'p.yaml').exists()
    # A calibration with temperature terms cannot correct it; nor can diagnose look at it.
    thermal = tmp_path / 'thermal.yaml'
    thermal.write_text(yaml.safe_dump({'/**/compensator': {'ros__parameters': {'calibration': unit_to_mapping(
        scenario_from_mapping({**STATIC, 'plateaus_celsius': [10.0, 30.0]}).driver_truth())}}}))
    for argv in (['apply', str(root / 'static'), '--params', str(thermal), '-o', str(tmp_path / 'out')],
                 ['validate', str(root / 'static'), '--params', str(thermal)],
                 ['diagnose', str(root / 'static'), '--params', str(thermal), '--json', str(tmp_path / 'd.json')]):
        assert main([*argv, '--no-progress']) == 2
        assert 'no temperature on /imu/temperature' in _one_line(capsys)
    assert not (tmp_path / 'out').exists() and not (tmp_path / 'd.json').exists()


def _hand_turned_csv(path, record) -> None:
    """A hobby board's log: Imu, a constant 25.0 C and the field in gauss (an HMC5883L's unit)."""
    rows = ['t,ax,ay,az,gx,gy,gz,temp,mx,my,mz']
    for stamp, accel, gyro, field in zip(record.stamp_ns, record.accel, record.gyro, record.mag):
        rows.append(f'{stamp * 1e-9:.3f},' + ','.join(f'{v:.5f}' for v in (*accel, *gyro)) + ',25.0,'
                    + ','.join(f'{v * 1e4:.7f}' for v in field))
    path.write_text('\n'.join(rows) + '\n')


def test_a_hand_turned_record_at_one_temperature_brings_the_field_strength_to_the_noise(tmp_path, capsys):
    record = rotation_record(TRUTH, samples=TURNS, seed=31, temperature_celsius=25.0)
    _hand_turned_csv(tmp_path / 'board.csv', record)
    assert main(['import-csv', str(tmp_path / 'board.csv'), '-o', str(tmp_path / 'board'), '--time-column', 't',
                 '--acc-columns', 'ax', 'ay', 'az', '--gyro-columns', 'gx', 'gy', 'gz', '--temp-column', 'temp',
                 '--mag-columns', 'mx', 'my', 'mz', '--mag-unit', 'gauss']) == 0
    assert 'constant at 25.00 C' in capsys.readouterr().out
    assert main(['fit', str(tmp_path / 'board'), '-o', str(tmp_path / 'p.yaml'), '--no-progress']) == 0
    out = capsys.readouterr().out
    assert 'accelerometer and gyroscope: held at nominal' in out and 'thermal link held' in out
    unit = load_unit(tmp_path / 'p.yaml')
    assert unit.accel.thermal == unit.gyro.thermal == THERMAL_NONE and unit.mag.thermal.thermal == THERMAL_HELD
    assert main(['apply', str(tmp_path / 'board'), '--params', str(tmp_path / 'p.yaml'), '-o',
                 str(tmp_path / 'out'), '--no-progress']) == 0
    before = np.linalg.norm(record.mag, axis=1)
    after = np.linalg.norm(_written_field(tmp_path / 'out'), axis=1)
    # The noise of |B| is the field's noise along it (0.2 uT; the CSV's 1e-11 T digits add nothing);
    # 2000 samples know a standard deviation to 1.6 %.
    assert after.std() < 1.1 * NOISE_T < 10 * NOISE_T < before.std()


def test_a_magnetometer_turned_as_it_warms_gives_iron_and_drift_and_corrects_a_second_record(tmp_path, capsys):
    first = rotation_record(TRUTH, samples=TURNS, seed=41, temperature_celsius=12.0, warm_to_celsius=38.0)
    second = rotation_record(TRUTH, samples=TURNS, seed=42, temperature_celsius=15.0, warm_to_celsius=35.0)
    write_driver_record(tmp_path / 'first', first)
    write_driver_record(tmp_path / 'second', second)
    assert main(['fit', str(tmp_path / 'first'), '-o', str(tmp_path / 'p.yaml'), '--no-progress']) == 0
    assert 'the iron and the thermal drift fitted together' in capsys.readouterr().out
    mag = load_unit(tmp_path / 'p.yaml').mag
    assert mag.thermal.thermal == THERMAL_FITTED and all(axis.offset_span > 0.5e-6 for axis in mag.thermal.axes)
    assert main(['apply', str(tmp_path / 'second'), '--params', str(tmp_path / 'p.yaml'), '-o',
                 str(tmp_path / 'out'), '--no-progress']) == 0
    corrected = _written_field(tmp_path / 'out')
    truth = rotation_truth(TRUTH, samples=TURNS, seed=42)
    # The corrected field is the true one times one number (the soft iron's isotropic part, which
    # no rotation record can see): take it out, then the error is the sensor's noise.
    factor = float(np.sum(corrected * truth) / np.sum(truth * truth))
    error = corrected / factor - truth
    assert np.all(np.sqrt(np.mean(error ** 2, axis=0)) < 1.15 * NOISE_T)
    cosine = np.sum(corrected * truth, axis=1) / np.linalg.norm(corrected, axis=1) / np.linalg.norm(truth, axis=1)
    direction = np.sqrt(np.mean(np.arccos(np.clip(cosine, -1.0, 1.0)) ** 2))
    # Noise across the field (two components of 0.2 uT on 48.4 uT): 5.8e-3 rad, 0.33 deg.
    assert direction < 1.15 * math.sqrt(2.0) * NOISE_T / np.linalg.norm(TRUTH.earth_field)
    # Without the temperature, the ellipsoid of the same record leaves the drift: twice the noise and more.
    write_driver_record(tmp_path / 'blind', _no_temperature(first))
    assert main(['fit', str(tmp_path / 'blind'), '-o', str(tmp_path / 'b.yaml'), '--no-progress']) == 0
    blind = MagCorrector(load_unit(tmp_path / 'b.yaml').mag).correct(second.mag, np.zeros(TURNS))
    assert np.linalg.norm(blind, axis=1).std() > 2.0 * NOISE_T > np.linalg.norm(corrected, axis=1).std()
    capsys.readouterr()
    assert main(['validate', str(tmp_path / 'second'), '--params', str(tmp_path / 'p.yaml'), '--no-progress']) == 0
    out = capsys.readouterr().out
    assert 'accelerometer and gyroscope: not validated' in out and 'a rotation record' in out


def test_a_unit_never_flipped_is_refused_in_one_line(tmp_path, capsys):
    write_driver_record(tmp_path / 'cap', rotation_record(TRUTH, samples=TURNS, seed=51, turn='cap'))
    assert main(['fit', str(tmp_path / 'cap'), '-o', str(tmp_path / 'p.yaml'), '--no-progress']) == 2
    err = _one_line(capsys)
    assert 'covers too few orientations' in err and 'of the 20 sections' in err
    assert not (tmp_path / 'p.yaml').exists()


def test_a_rotation_record_without_a_temperature_topic_gives_the_iron(tmp_path, capsys):
    record = _no_temperature(rotation_record(TRUTH, samples=TURNS, seed=61, temperature_celsius=20.0))
    write_driver_record(tmp_path / 'turned', record)
    assert main(['fit', str(tmp_path / 'turned'), '-o', str(tmp_path / 'p.yaml'), '--no-progress']) == 0
    assert 'no temperature on /imu/temperature' in capsys.readouterr().out
    unit = load_unit(tmp_path / 'p.yaml')
    assert unit.mag.thermal.thermal == THERMAL_NONE and not unit.needs_temperature
    inverse = np.linalg.inv(TRUTH.soft_matrix())
    inverse /= np.linalg.det(inverse) ** (1.0 / 3.0)
    assert np.max(np.abs(np.array(unit.mag.soft_iron).reshape(3, 3) - inverse)) < 0.01
    # At the reference temperature (20 C) the hard iron is the iron's plus the sensor's own offset.
    assert np.allclose(unit.mag.hard_iron, np.add(TRUTH.hard_iron, TRUTH.offset), atol=0.1e-6)


def test_links_without_temperature_terms_in_the_file():
    unit = scenario_from_mapping({**STATIC, 'plateaus_celsius': [10.0, 30.0]}).driver_truth()
    mapping = unit_to_mapping(unit)
    assert 'thermal' not in mapping['accel']  # a link with temperature terms: the file as before
    held = {**mapping['accel'], 'thermal': 'held', 'temperature_min': 25.0, 'temperature_max': 25.0,
            'temperature_ref': 25.0, **{axis: {**mapping['accel'][axis], 'offset_span': 0.0, 'offset_shape': [0.0],
                                               'scale_shape': [0.0]} for axis in 'xyz'}}
    none = {key: value for key, value in held.items() if not key.startswith('temperature_')}
    none['thermal'] = 'none'
    for accel, state in ((held, THERMAL_HELD), (none, THERMAL_NONE)):
        loaded = unit_from_mapping({**mapping, 'accel': accel})
        assert loaded.accel.thermal == state and loaded.needs_temperature  # the gyroscope keeps its terms
        assert unit_from_mapping(unit_to_mapping(loaded)) == loaded
    bad = {'thermal: sometimes': {**held, 'thermal': 'sometimes'},
           'thermal none with temperatures': {**none, 'temperature_ref': 25.0},
           'held with a drift': {**held, 'x': mapping['accel']['x']}}
    for case, accel in bad.items():
        with pytest.raises(CalibrationError, match=r'^calibration\.accel\.'):
            unit_from_mapping({**mapping, 'accel': accel})


def test_a_calibration_without_temperature_terms_corrects_without_waiting_for_one(tmp_path):
    record = _no_temperature(rotation_record(TRUTH, samples=600, seed=71))
    write_driver_record(tmp_path / 'turned', record)
    assert main(['fit', str(tmp_path / 'turned'), '-o', str(tmp_path / 'p.yaml'), '--no-progress']) == 0
    unit = load_unit(tmp_path / 'p.yaml')
    for channel, values in (('imu', (*record.accel[0], *record.gyro[0])), ('mag', tuple(record.mag[0]))):
        core = OnlineCompensator(unit, channel=channel, out_of_range=OutOfRange.CLAMP)
        result = core.process_values(1, 0, values, 0.0)
        assert isinstance(result, tuple) and not core.waiting_for_temperature
        status = core.status(10.0)
        assert 'waiting' not in status.message and status.value('calibrated_range').startswith('any')
    assert MagCorrector(unit.mag).correct_sample(tuple(record.mag[0]), float('nan')) == \
        tuple(MagCorrector(unit.mag).correct(record.mag[:1], np.array([55.0]))[0])
