"""The magnetometer through the bags: fit (thermal link and iron), apply, validate; bad input refused.

A static chamber run of a unit with a drifting magnetometer calibrates its thermal link, a
rotation record of the installed unit its iron; a second static run with another profile,
corrected, has a field error at the noise floor.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from tak_thermo_ros.formats.bag import MAGNETIC_FIELD, iter_topic_arrays, write_driver_record
from tak_thermo_ros.cli import main
from tak_thermo_ros.errors import BagError
from tak_thermo_ros.core.link.correction import OutOfRange
from tak_thermo_ros.core.magnetometer.channel import MagCorrector
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.core.records.record import hold_last_index
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.simulation.magnetometer import MagnetometerTruth, rotation_record

TRUTH = MagnetometerTruth()
CHAMBER = Scenario(output='imu', plateaus_celsius=(5.0, 35.0, 20.0), plateau_hours=0.2, ramp_celsius_per_minute=1.0,
                   board_lag_s=120.0, positions=((0.0, 0.0, 1.0),), record_references=False, magnetometer=TRUTH,
                   seed=3)
"""About 1.8 h, static z up, 5..35 C: the offsets drift by 0.8-1.4 uT, seven times the noise."""
SECOND = replace(CHAMBER, plateaus_celsius=(30.0, 10.0, 25.0), seed=4)


@pytest.fixture(scope='module')
def bags(tmp_path_factory):
    root = tmp_path_factory.mktemp('mag')
    write_driver_record(root / 'cal', simulate(CHAMBER).driver)
    write_driver_record(root / 'run2', simulate(SECOND).driver)
    write_driver_record(root / 'iron', rotation_record(TRUTH, samples=2000, seed=5))
    write_driver_record(root / 'yaw', rotation_record(TRUTH, samples=2000, seed=6, turn='yaw'))
    assert main(['fit', str(root / 'cal'), '-o', str(root / 'p.yaml'), '--iron-run', str(root / 'iron'),
                 '--no-progress']) == 0
    return root


def test_fit_apply_validate_bring_the_field_error_to_the_noise_floor(bags, capsys):
    unit = load_unit(bags / 'p.yaml')
    assert unit.mag is not None and all(not axis.scale_observable for axis in unit.mag.thermal.axes)
    capsys.readouterr()
    assert main(['validate', str(bags / 'run2'), '--params', str(bags / 'p.yaml'), '--json', str(bags / 'v.json'),
                 '--no-progress']) == 0
    out = capsys.readouterr().out
    assert 'magnetometer field error' in out
    figures = json.loads((bags / 'v.json').read_text())['mag']
    # Static run: the error about the run's mean. After the correction it is the noise turned by
    # W (rows of norm about 1): within 15 % of 0.2 uT; before, the drift, several times more.
    soft = np.array(unit.mag.soft_iron).reshape(3, 3)
    floor = TRUTH.noise * np.linalg.norm(soft, axis=1)
    after, before = np.array(figures['after_rms_t']), np.array(figures['before_rms_t'])
    assert np.all(np.abs(after / floor - 1.0) < 0.15), after / floor
    assert np.all(before > 3.0 * TRUTH.noise), before
    assert figures['after_magnitude_rms_t'] < 1.15 * TRUTH.noise < figures['before_magnitude_rms_t']


def test_the_iron_is_the_simulated_one_and_apply_writes_the_corrected_field(bags, capsys):
    unit = load_unit(bags / 'p.yaml')
    inverse = np.linalg.inv(TRUTH.soft_matrix())
    inverse /= np.linalg.det(inverse) ** (1.0 / 3.0)
    assert np.max(np.abs(np.array(unit.mag.soft_iron).reshape(3, 3) - inverse)) < 0.01
    assert main(['apply', str(bags / 'run2'), '--params', str(bags / 'p.yaml'), '-o', str(bags / 'out'),
                 '--no-progress']) == 0
    assert 'MagneticField messages on /imu/mag_compensated' in capsys.readouterr().out
    arrays = list(iter_topic_arrays(bags / 'out', '/imu/mag_compensated', MAGNETIC_FIELD))
    written = np.concatenate([a['magnetic_field'] for a in arrays])
    covariance = arrays[0]['magnetic_field_covariance'][0]
    # apply is the vectorised MagCorrector on the held temperature.
    driver = simulate(SECOND).driver
    held = driver.temperature[hold_last_index(driver.temp_stamp_ns, driver.mag_stamp_ns)]
    expected = MagCorrector(unit.mag, out_of_range=OutOfRange.CLAMP).correct(driver.mag, held)
    assert np.array_equal(written, expected)
    assert covariance[0] > 0 and np.allclose(covariance.reshape(3, 3), covariance.reshape(3, 3).T)


def test_apply_writes_the_corrected_field_when_the_imu_sensors_have_their_own_stamps(bags, tmp_path, capsys):
    """The gyroscope in every other Imu message only: the magnetometer is corrected as on shared stamps."""
    unit = load_unit(bags / 'p.yaml')
    driver = simulate(SECOND).driver
    driver = replace(driver, gyro=driver.gyro[::2], accel_stamp_ns=driver.stamp_ns, gyro_stamp_ns=driver.stamp_ns[::2])
    write_driver_record(tmp_path / 'apart', driver)
    assert main(['apply', str(tmp_path / 'apart'), '--params', str(bags / 'p.yaml'), '-o', str(tmp_path / 'out'),
                 '--no-progress']) == 0
    assert 'MagneticField messages on /imu/mag_compensated' in capsys.readouterr().out
    arrays = list(iter_topic_arrays(tmp_path / 'out', '/imu/mag_compensated', MAGNETIC_FIELD))
    written = np.concatenate([a['magnetic_field'] for a in arrays])
    held = driver.temperature[hold_last_index(driver.temp_stamp_ns, driver.mag_stamp_ns)]
    assert np.array_equal(written, MagCorrector(unit.mag, out_of_range=OutOfRange.CLAMP).correct(driver.mag, held))


@pytest.mark.parametrize(('iron', 'expected'), [('yaw', 'covers too few orientations'),
                                                ('cal', 'covers too few orientations')])
def test_a_rotation_record_without_rotation_is_refused_in_one_line_and_nothing_written(bags, capsys, iron, expected):
    output = bags / f'refused_{iron}.yaml'
    assert main(['fit', str(bags / 'cal'), '-o', str(output), '--iron-run', str(bags / iron), '--no-progress']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('tak_calib: error: magnetometer:') and expected in err[0]
    assert not output.exists()


def test_a_topic_in_gauss_is_refused_and_nothing_written(bags, tmp_path, capsys):
    driver = simulate(replace(CHAMBER, plateau_hours=0.05)).driver
    write_driver_record(tmp_path / 'gauss', replace(driver, mag=driver.mag * 1e4))
    assert main(['fit', str(tmp_path / 'gauss'), '-o', str(tmp_path / 'p.yaml'), '--no-progress']) == 2
    err = capsys.readouterr().err.strip()
    assert 'not a field in tesla' in err and 'gauss' in err and '\n' not in err
    assert not (tmp_path / 'p.yaml').exists()
    assert main(['apply', str(tmp_path / 'gauss'), '--params', str(bags / 'p.yaml'), '-o', str(tmp_path / 'out'),
                 '--no-progress']) == 2
    assert 'not a field in tesla' in capsys.readouterr().err and not (tmp_path / 'out').exists()


def test_nan_fields_are_left_out_and_counted_and_a_record_of_nan_is_refused(bags, tmp_path, capsys):
    driver = simulate(replace(CHAMBER, plateau_hours=0.05)).driver
    mag = driver.mag.copy()
    mag[[10, 20, 30], 1] = np.nan
    write_driver_record(tmp_path / 'some', replace(driver, mag=mag))
    assert main(['fit', str(tmp_path / 'some'), '-o', str(tmp_path / 'p.yaml'), '--no-progress']) == 0
    out = capsys.readouterr().out
    assert 'magnetometer: left out: 3 non finite' in out
    write_driver_record(tmp_path / 'all', replace(driver, mag=np.full_like(driver.mag, np.nan)))
    assert main(['fit', str(tmp_path / 'all'), '-o', str(tmp_path / 'q.yaml'), '--no-progress']) == 2
    assert '/imu/mag' in capsys.readouterr().err and not (tmp_path / 'q.yaml').exists()
    assert math.isfinite(load_unit(tmp_path / 'p.yaml').mag.thermal.axes[1].offset)


def test_diagnose_works_on_the_magnetometer_like_on_the_other_sensors(bags, tmp_path, capsys):
    capsys.readouterr()
    assert main(['diagnose', str(bags / 'cal'), '--params', str(bags / 'p.yaml'), '--json', str(tmp_path / 'd.json'),
                 '--no-progress', '--candidates', 'thermal_lag,temperature_shape']) == 0
    out = capsys.readouterr().out
    assert 'magnetometer: verdict: none' in out
    mag = json.loads((tmp_path / 'd.json').read_text())['sensors']['mag']
    assert mag['verdict'] == 'none' and mag['unit'] == 'T'
    for axis in mag['axes'].values():
        assert abs(axis['heldout_rms'] / axis['noise_floor'] - 1.0) < 0.1
        assert abs(axis['noise_floor'] / TRUTH.noise - 1.0) < 0.1
    # A link too poor for the drift (a straight line for a cubic): diagnose sees it.
    assert main(['fit', str(bags / 'cal'), '-o', str(tmp_path / 'poor.yaml'), '--bias-order', '1',
                 '--no-progress']) == 0
    capsys.readouterr()
    assert main(['diagnose', str(bags / 'cal'), '--params', str(tmp_path / 'poor.yaml'), '--json',
                 str(tmp_path / 'poor.json'), '--no-progress', '--candidates', 'thermal_lag,temperature_shape']) == 0
    poor = json.loads((tmp_path / 'poor.json').read_text())['sensors']['mag']
    assert poor['verdict'] == 'temperature_shape'
    assert max(axis['heldout_rms'] / axis['noise_floor'] for axis in poor['axes'].values()) > 1.5


SIX = ((1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0), (0.0, 0.0, -1.0))


def test_a_reference_field_fits_the_scale_drift_and_a_static_run_that_turned_is_refused(tmp_path, capsys):
    # A table turning through six positions in a known (surveyed) field, recorded on /tak/reference_field.
    table = replace(CHAMBER, positions=SIX, dwell_s=60.0, record_references=True, plateau_hours=0.3)
    write_driver_record(tmp_path / 'table', simulate(table).driver)
    assert main(['fit', str(tmp_path / 'table'), '-o', str(tmp_path / 'p.yaml'), '--no-progress']) == 0
    out = capsys.readouterr().out
    assert 'magnetometer: reference field /tak/reference_field as recorded' in out
    link = load_unit(tmp_path / 'p.yaml').mag.thermal
    for axis, truth in zip(link.axes, TRUTH.scale_coeffs):
        assert axis.scale_observable
        # The linear scale drift per C: its error over a 30 C spread at 0.2 uT noise in a 48 uT field
        # on a few thousand samples is some 1e-6 per C; 2e-5 is far beyond it.
        assert abs(axis.scale_shape[0] - truth[0]) < 2e-5
    # The reference is the field outside the sensor's own iron: each axis's scale takes the soft
    # iron's diagonal with it (1.05, 0.96, 1.02, within the off-diagonal's pull).
    assert np.allclose([axis.scale for axis in link.axes], np.diag(TRUTH.soft_matrix()), atol=0.02)
    assert main(['validate', str(tmp_path / 'table'), '--params', str(tmp_path / 'p.yaml'), '--json',
                 str(tmp_path / 'v.json'), '--no-progress']) == 0
    # validate compares with the reference when the bag holds one.
    assert json.loads((tmp_path / 'v.json').read_text())['mag']['reference'] == '/tak/reference_field'
    # The same table recorded without the reference: the field turns, so the record is taken as a
    # rotation record for the iron, and six positions are too few orientations: refused in one line.
    unreferenced = replace(simulate(table).driver, mag_reference_stamp_ns=np.zeros(0, np.int64),
                           mag_reference=np.zeros((0, 3)))
    write_driver_record(tmp_path / 'turned', unreferenced)
    assert main(['fit', str(tmp_path / 'turned'), '-o', str(tmp_path / 'q.yaml'), '--no-progress']) == 2
    err = capsys.readouterr().err
    assert 'covers too few orientations (6 of the 20 sections' in err
    assert len(err.splitlines()) == 1 and not (tmp_path / 'q.yaml').exists()


def test_the_block_decoder_and_encoder_handle_magnetic_field_as_rosbags_does(tmp_path):
    from tak_thermo_ros.formats.bag import TYPESTORE, iter_blocks
    from tak_thermo_ros.formats.cdr.decoder import decode_messages
    from tak_thermo_ros.formats.cdr.encoder import encode_messages
    from tak_thermo_ros.core.link.model import InputKind
    driver = simulate(replace(CHAMBER, plateau_hours=0.02)).driver
    write_driver_record(tmp_path / 'bag', driver)
    blocks = {decoder: list(iter_blocks(tmp_path / 'bag', kind=InputKind.IMU, block_samples=500, decoder=decoder,
                                        progress=False)) for decoder in ('block', 'rosbags')}
    for name in ('mag_stamp_ns', 'mag'):
        by_block = np.concatenate([getattr(b, name) for b in blocks['block']])
        assert np.array_equal(by_block, np.concatenate([getattr(b, name) for b in blocks['rosbags']]))
        assert np.array_equal(by_block, getattr(driver, name))
    covariance = np.arange(9, dtype=float) * 1e-15
    raws = encode_messages(MAGNETIC_FIELD, driver.mag_stamp_ns[:50], {'magnetic_field': driver.mag[:50],
                                                                      'magnetic_field_covariance': covariance},
                           {'frame_id': 'mag_link'})
    decoded = decode_messages(raws, MAGNETIC_FIELD)
    assert np.array_equal(decoded['magnetic_field'], driver.mag[:50])
    for raw, stamp, field in zip(raws, driver.mag_stamp_ns[:50].tolist(), driver.mag[:50]):
        message = TYPESTORE.deserialize_cdr(raw, MAGNETIC_FIELD)
        assert message.header.frame_id == 'mag_link'
        assert message.header.stamp.sec * 10**9 + message.header.stamp.nanosec == stamp
        assert (message.magnetic_field.x, message.magnetic_field.y, message.magnetic_field.z) == tuple(field)
        assert np.array_equal(message.magnetic_field_covariance, covariance)
        assert TYPESTORE.serialize_cdr(message, MAGNETIC_FIELD) == raw


LAG = {'tau_s': 300.0, 'slope_x': 2.0e-7, 'slope_z': -1.5e-7}
"""A hidden thermal lag of the magnetometer's offset: tesla per degree C of lag (about 1 uT at 2 C/min)."""


def test_the_discovery_loop_works_on_the_magnetometer(tmp_path, capsys):
    lagging = replace(CHAMBER, plateaus_celsius=(5.0, 35.0, 5.0, 35.0), ramp_celsius_per_minute=2.0,
                      board_lag_s=300.0, magnetometer=replace(TRUTH, effects={'thermal_lag': LAG}), seed=9)
    write_driver_record(tmp_path / 'run', simulate(lagging).driver)
    candidates = ['--candidates', 'thermal_lag,hysteresis,temperature_shape']

    def mag_verdict(params: str) -> dict:
        assert main(['diagnose', str(tmp_path / 'run'), '--params', str(tmp_path / params), '--json',
                     str(tmp_path / 'd.json'), '--no-progress', '--force', *candidates]) == 0
        return json.loads((tmp_path / 'd.json').read_text())['sensors']['mag']

    assert main(['fit', str(tmp_path / 'run'), '-o', str(tmp_path / 'base.yaml'), '--no-progress']) == 0
    assert mag_verdict('base.yaml')['verdict'] == 'thermal_lag'
    assert main(['fit', str(tmp_path / 'run'), '-o', str(tmp_path / 'lag.yaml'), '--no-progress',
                 '--mag-effects', 'thermal_lag']) == 0
    out = capsys.readouterr().out
    effect = load_unit(tmp_path / 'lag.yaml').mag.thermal.effects[0]
    errors = {m.group(1): float(m.group(2)) for m in __import__('re').finditer(r'(\w+) \S+ \+- (\S+)', out)
              if m.group(1) in ('tau_s', 'slope_x', 'slope_z')}
    # The errors are the fit's own (in tesla as in rad/s), and the truth lies within four of them.
    assert 0.5 < errors['tau_s'] < 30.0
    for name, true in LAG.items():
        assert abs(effect[name] - true) < 4.0 * errors[name], (name, effect[name], errors[name])
    after = mag_verdict('lag.yaml')
    assert after['verdict'] == 'none'
    assert all(abs(axis['heldout_rms'] / axis['noise_floor'] - 1.0) < 0.05 for axis in after['axes'].values())


def test_effect_standard_errors_do_not_depend_on_the_sensor_unit():
    from tak_thermo_ros.core.fit import fit_model
    from tak_thermo_ros.core.records.record import align
    lagging = replace(CHAMBER, plateaus_celsius=(5.0, 35.0, 5.0), ramp_celsius_per_minute=2.0, plateau_hours=0.1,
                      board_lag_s=300.0, magnetometer=replace(TRUTH, effects={'thermal_lag': LAG}), seed=10)
    driver = simulate(lagging).driver
    record = driver.channel('mag')
    mean = record.counts.mean(axis=0)
    record = replace(record, reference_stamp_ns=np.zeros(1, np.int64), reference=mean.reshape(1, 3))
    samples = align(record)
    in_tesla = fit_model(samples, effects=['thermal_lag'], nominal_scale=(1.0, 1.0, 1.0))
    scaled = replace(samples, counts=samples.counts * 1e6, reference=samples.reference * 1e6)
    in_microtesla = fit_model(scaled, effects=['thermal_lag'], nominal_scale=(1.0, 1.0, 1.0))
    assert math.isclose(in_tesla.parameter_errors['thermal_lag.tau_s'],
                        in_microtesla.parameter_errors['thermal_lag.tau_s'], rel_tol=1e-3)
    assert in_tesla.parameter_errors['thermal_lag.tau_s'] > 0.5


def test_apply_says_when_the_calibration_has_no_magnetometer(bags, tmp_path, capsys):
    from tak_thermo_ros.formats.calibration_file import save_unit
    save_unit(tmp_path / 'imu_only.yaml', replace(load_unit(bags / 'p.yaml'), mag=None))
    capsys.readouterr()
    assert main(['apply', str(bags / 'run2'), '--params', str(tmp_path / 'imu_only.yaml'), '-o', str(tmp_path / 'out'),
                 '--no-progress']) == 0
    out = ' '.join(capsys.readouterr().out.split())
    assert 'holds no magnetometer: /imu/mag is not corrected' in out and 'MagneticField messages' not in out
    with pytest.raises(BagError, match='topic /imu/mag_compensated not found'):
        list(iter_topic_arrays(tmp_path / 'out', '/imu/mag_compensated', MAGNETIC_FIELD))


def test_a_rotation_record_outside_the_calibrated_range_is_said(bags, tmp_path, capsys):
    write_driver_record(tmp_path / 'hot', rotation_record(TRUTH, samples=600, seed=11, temperature_celsius=40.0))
    capsys.readouterr()
    assert main(['fit', str(bags / 'cal'), '-o', str(tmp_path / 'p.yaml'), '--iron-run', str(tmp_path / 'hot'),
                 '--no-progress']) == 0
    assert 'warning: magnetometer: 600 samples of' in capsys.readouterr().out


def test_validate_of_a_rotation_record_says_its_figure_is_the_spread_of_the_field_strength(bags, capsys):
    """|B| of a record that turns is compared with its own mean: the line says it is that spread (issue 31)."""
    capsys.readouterr()
    assert main(['validate', str(bags / 'iron'), '--params', str(bags / 'p.yaml'), '--no-progress']) == 0
    out = capsys.readouterr().out
    assert 'before correction: spread of |B|, RMS about its mean ' in out
    assert 'after  correction: spread of |B|, RMS about its mean ' in out
    assert 'correction: |B| ' not in out
