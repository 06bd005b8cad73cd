"""PX4 ULogs and ArduPilot DataFlash logs through every command; their parameters out, as the firmware applies them."""

from __future__ import annotations

import json
import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware import ardupilot_correction, px4_applied_offsets
from paths import REPO
from tak_thermo_ros.cli import main
from tak_thermo_ros.core.records.record import hold_signal, sensor_messages
from tak_thermo_ros.core.simulation.powered import PoweredRun, simulate_powered
from tak_thermo_ros.errors import FlightLogError
from tak_thermo_ros.formats.ardupilot_params import read_ardupilot_params
from tak_thermo_ros.formats.bag import read_driver_record, read_imu_messages, write_driver_record
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.formats.dataflash import IMU_FORMAT, driver_messages, read_dataflash, write_dataflash
from tak_thermo_ros.core.link.offset_cubic import static_offset
from tak_thermo_ros.formats.px4_params import read_px4_params
from tak_thermo_ros.formats.ulog import driver_topics, read_ulog, write_ulog

WARM_UP = PoweredRun(duration_s=900.0, accel_rate_hz=2.0, gyro_rate_hz=3.0, gyro_phase_s=0.13, board_tau_s=300.0,
                     self_heating_tau_s=30.0)
"""A short warm-up (15 min): the accelerometer at 2 Hz, the gyroscope at 3 Hz on its own stamps."""
IDS = {'accel': 2490378, 'gyro': 2490634}


@pytest.fixture(scope='module')
def logs(tmp_path_factory):
    """The warm-up as a ULog (own stamps) and as a DataFlash log (shared stamps), each fitted."""
    root = tmp_path_factory.mktemp('flight_logs')
    ulog = simulate_powered(WARM_UP)
    write_ulog(root / 'warm.ulg', driver_topics(ulog.record, device_ids=IDS), info={'sys_name': 'PX4'})
    binary = simulate_powered(replace(WARM_UP, gyro_rate_hz=2.0, gyro_phase_s=0.0, seed=3))
    write_dataflash(root / 'warm.bin', driver_messages(binary.record), parameters={'AHRS_ORIENTATION': 0})
    for log, params in (('warm.ulg', 'ulog.yaml'), ('warm.bin', 'bin.yaml')):
        assert main(['fit', str(root / log), '-o', str(root / params), '--no-progress']) == 0
    return root, ulog, binary


def test_a_ulog_reads_each_sensor_on_its_own_stamps(logs):
    """The file written by pyulog, read back: each topic's samples at timestamp_sample, the temperature, the IDs."""
    root, sim, _ = logs
    log = read_ulog(root / 'warm.ulg', 0)
    for sensor, values in (('accel', sim.record.accel), ('gyro', sim.record.gyro)):
        stamps = sim.record.sensor_stamps(sensor)
        assert np.array_equal(log.stamps[sensor], stamps // 1000 * 1000)
        np.testing.assert_array_equal(log.values[sensor], values.astype(np.float32))
        assert log.device_ids[sensor] == IDS[sensor]
    assert len(log.stamps['gyro']) != len(log.stamps['accel']) and not log.shared_stamps
    np.testing.assert_array_equal(log.temperature, sim.record.temperature.astype(np.float32))


def test_fit_keeps_each_sensors_samples_and_records_the_source(logs, capsys):
    """The fit used every accelerometer and gyroscope sample; the file holds the log's format, instance and IDs."""
    root, sim, _ = logs
    unit = load_unit(root / 'ulog.yaml')
    assert unit.source['format'] == 'ulog' and unit.source['instance'] == 0
    assert (unit.source['accel_device_id'], unit.source['gyro_device_id']) == (IDS['accel'], IDS['gyro'])
    assert unit.source['temperature_rate_max'] > 0.05  # C/s: the self-heating start
    assert main(['validate', str(root / 'warm.ulg'), '--params', str(root / 'ulog.yaml'), '--no-progress']) == 0
    out = capsys.readouterr().out
    assert f'over {len(sim.record.gyro)} samples' in out  # the gyroscope's own samples, not the accelerometer's


def test_our_dataflash_reader_reads_what_dfreader_reads(logs):
    """The same IMU samples and temperature as pymavlink's DFReader (the reference reader)."""
    from pymavlink import DFReader
    root, _, _ = logs
    reference = DFReader.DFReader_binary(str(root / 'warm.bin'), zero_time_base=False)
    rows = []
    while (message := reference.recv_match(type=['IMU'])) is not None:
        rows.append((message.TimeUS, message.AccX, message.AccY, message.AccZ, message.GyrX, message.GyrY,
                     message.GyrZ, message.T))
    rows = np.array(rows)
    log = read_dataflash(root / 'warm.bin', 0)
    assert np.array_equal(log.stamps['accel'], rows[:, 0].astype(np.int64) * 1000)
    np.testing.assert_array_equal(log.values['accel'], rows[:, 1:4])
    np.testing.assert_array_equal(log.values['gyro'], rows[:, 4:7])
    np.testing.assert_array_equal(log.temperature, rows[:, 7])


def _rotation(orientation_deg: tuple[float, float, float]) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    roll, pitch, yaw = orientation_deg
    return Rotation.from_euler('ZYX', [yaw, pitch, roll], degrees=True).as_matrix()


def test_the_dataflash_reader_undoes_what_ardupilot_applied(tmp_path):
    """Board rotation, offsets and scale, an INS_TCAL1 in use: undone as the firmware applied them (raw back)."""
    sim = simulate_powered(replace(WARM_UP, duration_s=300.0, gyro_rate_hz=2.0, gyro_phase_s=0.0, seed=9))
    raw = sim.record
    temperature = raw.temperature
    params = {'AHRS_ORIENTATION': 2, 'INS_ACCOFFS_X': 0.1, 'INS_ACCOFFS_Y': -0.2, 'INS_ACCOFFS_Z': 0.3,
              'INS_ACCSCAL_X': 1.01, 'INS_ACCSCAL_Y': 0.99, 'INS_ACCSCAL_Z': 1.002, 'INS_GYROFFS_X': 0.01,
              'INS_GYROFFS_Y': -0.02, 'INS_GYROFFS_Z': 0.005, 'INS_TCAL1_ENABLE': 1, 'INS_TCAL1_TMIN': 5.0,
              'INS_TCAL1_TMAX': 30.0, 'INS_ACC1_CALTEMP': 20.0, 'INS_GYR1_CALTEMP': 22.0,
              **{f'INS_TCAL1_{s}{k}_{a}': v for s, base in (('ACC', 30.0), ('GYR', 4.0)) for k, scale in
                 ((1, 1.0), (2, 0.05), (3, -0.002)) for a, v in zip('XYZ', base * scale * np.array([1.0, -0.5, 0.8]))}}
    rotation = _rotation((0.0, 0.0, 90.0))
    scale = np.array([params[f'INS_ACCSCAL_{a}'] for a in 'XYZ'])
    accel = (raw.accel + ardupilot_correction(params, 0, 'ACC', temperature, 20.0)
             - [params[f'INS_ACCOFFS_{a}'] for a in 'XYZ']) * scale
    gyro = raw.gyro + ardupilot_correction(params, 0, 'GYR', temperature, 22.0) \
        - [params[f'INS_GYROFFS_{a}'] for a in 'XYZ']
    logged = replace(raw, accel=accel @ rotation.T, gyro=gyro @ rotation.T)
    write_dataflash(tmp_path / 'applied.bin', driver_messages(logged), parameters=params)
    log = read_dataflash(tmp_path / 'applied.bin', 0)
    np.testing.assert_allclose(log.values['accel'], raw.accel, atol=2e-5)
    np.testing.assert_allclose(log.values['gyro'], raw.gyro, atol=2e-6)
    assert 'board rotation 2' in ' '.join(log.lines) and 'INS_TCAL1_' in ' '.join(log.lines)


def _apply(root: Path, log: str, params: str, out: str):
    assert main(['apply', str(root / log), '--params', str(root / params), '-o', str(root / out),
                 '--no-progress']) == 0
    return read_imu_messages(root / out, topic='/imu/data_compensated')


def test_px4_parameters_applied_as_px4_applies_them_equal_apply(logs, capsys):
    """TC_A0/TC_G0 from export, PX4's formula on the raw ULog: apply's output, to float32 rounding; the IDs match."""
    root, sim, _ = logs
    assert main(['export', str(root / 'ulog.yaml'), '--format', 'px4', '-o', str(root / 'p.params')]) == 0
    said = capsys.readouterr().out
    params = read_px4_params((root / 'p.params').read_text())
    assert params['TC_A_ENABLE'] == params['TC_G_ENABLE'] == 1
    assert (params['TC_A0_ID'], params['TC_G0_ID']) == (IDS['accel'], IDS['gyro'])
    messages = _apply(root, 'warm.ulg', 'ulog.yaml', 'applied_ulog')
    log = read_ulog(root / 'warm.ulg', 0)
    step = {}
    for sensor, letter, field, cov in (('accel', 'A', 'linear_acceleration', 'linear_acceleration_covariance'),
                                       ('gyro', 'G', 'angular_velocity', 'angular_velocity_covariance')):
        carried = getattr(messages, cov)[:, 0] != -1.0
        assert np.array_equal(messages.stamp_ns[carried], log.stamps[sensor])
        temperature = hold_signal(log.temp_stamp_ns, log.temperature, log.stamps[sensor])
        every = px4_applied_offsets(params, letter, 0, temperature, IDS[sensor], hold=False)
        np.testing.assert_allclose(log.values[sensor] - every, getattr(messages, field)[carried],
                                   atol=float(np.abs(log.values[sensor]).max()) * 3e-7)
        held = px4_applied_offsets(params, letter, 0, temperature, IDS[sensor], hold=True)
        step[sensor] = float(np.abs(held - every).max())
    # the export says how far PX4's 1 C update rule lets the offset lag the curve: the largest step seen is within it
    said_gyro = float(re.search(r'gyroscope: PX4 updates the offset per 1 C change: up to ([0-9.e+-]+) deg/h',
                                said).group(1))
    assert 0.0 < step['gyro'] * 180.0 / math.pi * 3600.0 <= said_gyro * 1.01


def test_ardupilot_parameters_applied_as_ardupilot_applies_them_equal_apply(logs, capsys):
    """INS_TCAL1 from export, ArduPilot's correction and offsets calibrated at CALTEMP: apply's output."""
    root, _, _ = logs
    assert main(['export', str(root / 'bin.yaml'), '--format', 'ardupilot', '-o', str(root / 'p.parm')]) == 0
    assert 'no constant in INS_TCAL' in capsys.readouterr().out
    params = read_ardupilot_params((root / 'p.parm').read_text())
    assert params['INS_TCAL1_ENABLE'] == 1
    unit = load_unit(root / 'bin.yaml')
    messages = _apply(root, 'warm.bin', 'bin.yaml', 'applied_bin')
    log = read_dataflash(root / 'warm.bin', 0)
    caltemp = 20.0  # the ordinary calibration's temperature: its offsets are our curve's value there
    for sensor, code, field in (('accel', 'ACC', 'linear_acceleration'), ('gyro', 'GYR', 'angular_velocity')):
        temperature = hold_signal(log.temp_stamp_ns, log.temperature, log.stamps[sensor])
        offsets = static_offset(unit.sensor(sensor), np.array([caltemp]))[0]
        firmware = log.values[sensor] + ardupilot_correction(params, 0, code, temperature, caltemp) - offsets
        np.testing.assert_allclose(firmware, getattr(messages, field), atol=float(np.abs(log.values[sensor]).max())
                                   * 3e-7 + 2e-7)


def test_diagnose_says_a_one_way_warm_up_cannot_show_its_lag(logs, capsys):
    """A warm-up only: the lag it cannot separate is named, sized per minute of lag, and in the JSON."""
    root, _, _ = logs
    assert main(['diagnose', str(root / 'warm.ulg'), '--params', str(root / 'ulog.yaml'), '--json',
                 str(root / 'd.json'), '--no-progress', '--folds', '2']) == 0
    out = capsys.readouterr().out
    assert 'record: the temperature only rose' in out and 'cannot be told from the curve' in out
    record = json.loads((root / 'd.json').read_text())['record']
    assert record['one_way'] and record['lag_bend_per_minute']['gyro'] > 0.0


def _one_line_error(capsys, argv: list[str], output: Path) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('tak_calib: error: ') and 'Traceback' not in err[0]
    assert not output.exists()
    return err[0]


def _ulog_topics(sim, changes):
    topics = driver_topics(sim.record, device_ids=IDS)
    for (topic, field), values in changes.items():
        topics[(topic, 0)][field] = values(topics[(topic, 0)][field])
    return topics


@pytest.mark.parametrize('case', ['no_temperature', 'truncated_ulog', 'device_id_changes', 'missing_instance',
                                  'truncated_bin', 'bin_without_t', 'bin_missing_instance'])
def test_bad_flight_logs_are_one_line_exit_2_nothing_written(case, logs, tmp_path, capsys):
    """Each bad log: one line naming what is wrong, exit 2, no calibration file."""
    root, sim, _ = logs
    log = tmp_path / ('log.bin' if 'bin' in case else 'log.ulg')
    instance = '0'
    if case == 'no_temperature':
        write_ulog(log, _ulog_topics(sim, {(t, 'temperature'): lambda v: np.full(len(v), np.nan)
                                           for t in ('sensor_accel', 'sensor_gyro')}))
        expected = 'holds no temperature'
    elif case == 'truncated_ulog':
        data = (root / 'warm.ulg').read_bytes()
        log.write_bytes(data[:len(data) - 40])  # inside a message (a cut between two is a shorter whole log)
        expected = 'truncated or corrupt'
    elif case == 'device_id_changes':
        write_ulog(log, _ulog_topics(sim, {('sensor_gyro', 'device_id'): lambda v: np.where(
            np.arange(len(v)) < len(v) // 2, v, 1234)}))
        expected = 'device_id changes from 2490634 to 1234'
    elif case == 'missing_instance':
        log = root / 'warm.ulg'
        instance = '2'
        expected = 'no instance 2 of sensor_accel (instances in the log: 0'
    elif case == 'truncated_bin':
        data = (root / 'warm.bin').read_bytes()
        log.write_bytes(data[:len(data) - 5])
        expected = 'the log ends inside a message'
    elif case == 'bin_without_t':
        old = {'TimeUS': np.arange(20) * 10_000, 'AccZ': np.full(20, -9.8)}
        write_dataflash(log, {'IMU': ('QffffffII', 'TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA', old)})
        expected = 'IMU messages have no temperature T'
    else:
        log = root / 'warm.bin'
        instance = '1'
        expected = 'no IMU instance 1 (instances in the log: 0'
    line = _one_line_error(capsys, ['fit', str(log), '--instance', instance, '-o', str(tmp_path / 'p.yaml'),
                                    '--no-progress'], tmp_path / 'p.yaml')
    assert expected in line, line


def test_export_refuses_a_calibration_of_channel_codes(tmp_path, capsys, short_run):
    """The paper's codes are not what a firmware takes: one line, exit 2, nothing written."""
    from tak_thermo_ros.core.fit import fit_calibration
    from tak_thermo_ros.core.records.record import align
    from tak_thermo_ros.formats.calibration_file import save_calibration
    save_calibration(tmp_path / 'codes.yaml', fit_calibration(align(short_run.record)).calibration)
    line = _one_line_error(capsys, ['export', str(tmp_path / 'codes.yaml'), '--format', 'px4', '-o',
                                    str(tmp_path / 'out.params')], tmp_path / 'out.params')
    assert 'channel codes' in line


def test_imu_messages_that_carry_one_sensor_round_trip_through_a_bag(logs, tmp_path):
    """A record at two rates in a bag: one-sensor messages mark the other -1; read back, each sensor its own."""
    _, sim, _ = logs
    write_driver_record(tmp_path / 'bag', sim.record)
    for decoder in ('block', 'rosbags'):
        back = read_driver_record(tmp_path / 'bag', progress=False, decoder=decoder)
        for sensor, values in (('accel', sim.record.accel), ('gyro', sim.record.gyro)):
            assert np.array_equal(back.sensor_stamps(sensor), sim.record.sensor_stamps(sensor))
            np.testing.assert_array_equal(back.accel if sensor == 'accel' else back.gyro, values)


@given(st.lists(st.integers(0, 40), max_size=30), st.lists(st.integers(0, 40), max_size=30))
def test_sensor_messages_carry_every_sample_once_paired_only_at_equal_stamps(accel, gyro):
    """Any two stamp sequences: each sample in exactly one message, messages in stamp order, pairs share the stamp."""
    accel_stamps, gyro_stamps = np.array(accel, dtype=np.int64), np.array(gyro, dtype=np.int64)
    messages = sensor_messages(accel_stamps, gyro_stamps)
    assert np.all(np.diff(messages.stamp_ns) >= 0)
    for rows, stamps in ((messages.accel_row, accel_stamps), (messages.gyro_row, gyro_stamps)):
        assert sorted(rows[rows >= 0].tolist()) == list(range(len(stamps)))
        assert np.array_equal(stamps[rows[rows >= 0]], messages.stamp_ns[rows >= 0])
    assert np.all((messages.accel_row >= 0) | (messages.gyro_row >= 0))
    both = (messages.accel_row >= 0) & (messages.gyro_row >= 0)
    assert int(both.sum()) == sum(min(accel.count(s), gyro.count(s)) for s in set(accel) & set(gyro))


@given(st.integers(1, 2000))
def test_a_dataflash_log_cut_anywhere_is_read_whole_or_refused_in_one_line(cut):
    """Cutting the file at any byte: its messages up to there, or a FlightLogError (never another exception)."""
    data = _SMALL_BIN
    path = _SMALL_DIRECTORY / f'cut_{cut}.bin'
    path.write_bytes(data[:max(len(data) - cut, 0)])
    try:
        log = read_dataflash(path, 0)
    except FlightLogError as err:
        assert '\n' not in str(err)
    else:
        assert len(log.stamps['accel']) <= 40


_SMALL_DIRECTORY = Path(__import__('tempfile').mkdtemp(prefix='tak_dataflash_'))
write_dataflash(_SMALL_DIRECTORY / 'small.bin', {'IMU': (*IMU_FORMAT, {
    'TimeUS': np.arange(40) * 40_000, 'I': np.zeros(40, dtype=int), 'AccZ': np.full(40, -9.8),
    'T': np.linspace(20.0, 21.0, 40)})}, parameters={'AHRS_ORIENTATION': 0})
_SMALL_BIN = (_SMALL_DIRECTORY / 'small.bin').read_bytes()


def test_tclr_records_give_each_sensor_its_own_stamps(tmp_path):
    """A .bin of the firmware's learning records only (TCLR): accelerometer and gyroscope on their own stamps."""
    count = 30
    stamps = np.arange(count) * 100_000
    rows = {'TimeUS': np.concatenate([stamps, stamps + 37_000]), 'I': np.zeros(2 * count, dtype=int),
            'SType': np.repeat([0, 1], count), 'Temp': np.tile(np.linspace(20.0, 30.0, count), 2),
            'X': np.concatenate([np.full(count, 0.1), np.full(count, 0.01)]), 'Y': np.zeros(2 * count),
            'Z': np.concatenate([np.full(count, -9.8), np.zeros(count)])}
    write_dataflash(tmp_path / 'tclr.bin', {'TCLR': ('QBBffff', 'TimeUS,I,SType,Temp,X,Y,Z', rows)})
    log = read_dataflash(tmp_path / 'tclr.bin', 0)
    assert np.array_equal(log.stamps['accel'], stamps * 1000)
    assert np.array_equal(log.stamps['gyro'], (stamps + 37_000) * 1000)
    np.testing.assert_allclose(log.values['accel'][:, 2], -9.8, rtol=1e-6)
    assert not log.shared_stamps and 'TCLR' in log.lines[-1]


def test_simulate_writes_the_docs_flight_logs(tmp_path, capsys):
    """tak_calib simulate OUT.ulg / OUT.bin from docs/scenarios/px4_warm_up.yaml: what the docs show."""
    from tak_thermo_ros.cli.common import unwrap
    scenario = REPO / 'docs' / 'scenarios' / 'px4_warm_up.yaml'
    for name in ('warm_up.ulg', 'warm_up.bin'):
        assert main(['simulate', str(tmp_path / name), '--scenario', str(scenario)]) == 0
    out = '\n'.join(unwrap(capsys.readouterr().out))
    assert 'wrote' in out and '1801 sensor_accel (2 Hz), 2700 sensor_gyro (3 Hz)' in out
    assert read_ulog(tmp_path / 'warm_up.ulg', 0).count('gyro') == 2700
    assert read_dataflash(tmp_path / 'warm_up.bin', 0).shared_stamps
    assert main(['simulate', str(tmp_path / 'warm_up.ulg'), '--scenario', str(scenario)]) == 2  # exists: --force


def test_the_source_section_survives_the_nodes_parameters(logs):
    """calibration.source as ROS 2 parameters (flattened, nested back): the same unit, the source kept."""
    from tak_thermo_ros.formats.calibration_file import (
        flatten_parameters,
        nest_parameters,
        unit_from_mapping,
        unit_to_mapping,
    )
    root, _, _ = logs
    unit = load_unit(root / 'ulog.yaml')
    back = unit_from_mapping(nest_parameters(flatten_parameters(unit_to_mapping(unit))))
    assert back.source == unit.source and back.accel == unit.accel


def test_without_pyulog_a_ulog_is_one_line_naming_it(logs, tmp_path, capsys, monkeypatch):
    """An optional pyulog: a command given a ULog without it stops in one line naming the pip package."""
    root, _, _ = logs
    monkeypatch.setitem(__import__('sys').modules, 'pyulog', None)
    line = _one_line_error(capsys, ['fit', str(root / 'warm.ulg'), '-o', str(tmp_path / 'p.yaml'), '--no-progress'],
                           tmp_path / 'p.yaml')
    assert line.endswith("needs the optional Python package pyulog: pip install 'pyulog'")


def test_a_log_name_that_is_no_log_is_one_line(tmp_path, capsys):
    """A .ulg or .bin that is missing or holds something else: one line, not taken for a bag."""
    (tmp_path / 'text.bin').write_text('not a log\n')
    for name, expected in (('missing.ulg', 'no such file'), ('text.bin', 'neither a ULog nor a DataFlash log')):
        line = _one_line_error(capsys, ['fit', str(tmp_path / name), '-o', str(tmp_path / 'p.yaml')],
                               tmp_path / 'p.yaml')
        assert expected in line


@given(st.integers(1, 4000))
def test_a_ulog_cut_anywhere_is_read_whole_or_refused_in_one_line(cut):
    """Cutting a ULog at any byte: its samples up to there, or a FlightLogError (never another exception)."""
    path = _SMALL_DIRECTORY / f'cut_{cut}.ulg'
    path.write_bytes(_SMALL_ULOG[:max(len(_SMALL_ULOG) - cut, 0)])
    try:
        log = read_ulog(path, 0)
    except FlightLogError as err:
        assert '\n' not in str(err)
    else:
        assert log.count('accel') <= 120


write_ulog(_SMALL_DIRECTORY / 'small.ulg', driver_topics(simulate_powered(
    replace(WARM_UP, duration_s=60.0, accel_rate_hz=2.0, gyro_rate_hz=2.0)).record, device_ids=IDS))
_SMALL_ULOG = (_SMALL_DIRECTORY / 'small.ulg').read_bytes()
