"""Reliability on the newer surfaces (issue 34): flight logs, CSV cells, calibration YAML, export, a sensor short.

Each trigger ends in exit 0 with finite output (what is left out counted and said), or exit 2
with one line naming the file and the problem and nothing written; no library warning text.
"""

from __future__ import annotations

import contextlib
import io
import math
import re
import subprocess
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from tak_thermo_ros.cli import main
from tak_thermo_ros.core.records.extremes import KEEP_EVERY_S, RATE_WINDOW_S, temperature_course
from tak_thermo_ros.core.simulation.powered import PoweredRun, simulate_powered
from tak_thermo_ros.formats.bag import write_driver_record
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.formats.dataflash import IMU_FORMAT, driver_messages, write_dataflash
from tak_thermo_ros.formats.ulog import driver_topics, write_ulog

WARM_UP = PoweredRun(duration_s=2700.0, accel_rate_hz=1.0, gyro_rate_hz=1.5, gyro_phase_s=0.13, board_tau_s=300.0,
                     self_heating_tau_s=30.0)
"""PX4's thermal calibration: a 45-min warm-up, each sensor on its own stamps (1 and 1.5 Hz: quick to fit)."""
SHORT_WARM_UP = replace(WARM_UP, duration_s=900.0, accel_rate_hz=2.0, gyro_rate_hz=3.0)
IDS = {'accel': 2490378, 'gyro': 2490634}


def run_command(argv: list[str]) -> tuple[int, str, str]:
    """``main(argv)`` in-process with every warning an error: exit status, stdout, stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
        warnings.simplefilter('error')
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def refused(argv: list[str], output: Path | None = None) -> str:
    """The one error line of a refused command (exit 2, nothing written at ``output``)."""
    code, _, err = run_command(argv)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, (code, err)
    assert lines[0].startswith('tak_calib: error: ') and 'internal error' not in lines[0], lines[0]
    assert output is None or not output.exists()
    return lines[0]


def succeeded(argv: list[str]) -> str:
    """The stdout of a command that succeeds (exit 0, nothing on stderr, no NaN printed)."""
    code, out, err = run_command(argv)
    assert code == 0 and err == '', (code, err)
    assert not re.search(r'(?<![a-z_])(nan|inf)(?![a-z_])', out, re.IGNORECASE), out
    return out


def _left_out(out: str, sensor: str) -> dict[str, int]:
    """A sensor's ``left out:`` counts in what ``fit`` printed."""
    found = re.search(rf'^{sensor}: left out: (.*)$', out, re.MULTILINE)
    if not found:
        return {}
    return {reason: int(count) for count, reason in re.findall(r'(\d+) ([a-z ]+)', found.group(1))}


@pytest.fixture(scope='module')
def warm_up():
    """The 45-min warm-up's driver record (simulated once)."""
    return simulate_powered(WARM_UP).record


@pytest.fixture(scope='module')
def short_warm_up():
    """A 15-min warm-up's driver record (the docs' flight-log scenario)."""
    return simulate_powered(SHORT_WARM_UP).record


def _mag_topic(topics, count: int) -> dict[str, np.ndarray]:
    accel = topics[('sensor_accel', 0)]
    return {'timestamp': accel['timestamp'][:count], 'timestamp_sample': accel['timestamp_sample'][:count],
            'device_id': np.full(count, 396809), 'x': np.full(count, 0.2), 'y': np.zeros(count),
            'z': np.full(count, 0.4), 'temperature': accel['temperature'][:count]}


# ----- 1. one sensor's shortage -------------------------------------------------------------------

def test_a_short_magnetometer_is_held_and_said_and_both_imu_sensors_fitted_and_exported(warm_up, tmp_path):
    """PX4's thermal-calibration ULog whose sensor_mag holds 6 samples: the IMU fitted, the magnetometer held."""
    topics = driver_topics(warm_up, device_ids=IDS)
    topics[('sensor_mag', 0)] = _mag_topic(topics, 6)
    write_ulog(tmp_path / 'cal.ulg', topics)
    out = succeeded(['fit', str(tmp_path / 'cal.ulg'), '-o', str(tmp_path / 'p.yaml'), '--no-progress'])
    assert 'magnetometer: held at nominal (offset 0, scale 1, no iron): too few samples: 6 usable samples' in out
    assert 'counts' not in out
    unit = load_unit(tmp_path / 'p.yaml')
    assert unit.accel.needs_temperature and unit.gyro.needs_temperature
    assert not unit.mag.thermal.needs_temperature and unit.mag.thermal.notes[0].startswith('held at nominal')
    low, high = unit.accel.temp_code_min, unit.accel.temp_code_max
    assert high - low > 20.0
    exported = succeeded(['export', str(tmp_path / 'p.yaml'), '--format', 'px4', '-o', str(tmp_path / 'p.params')])
    assert 'wrote 34 parameters' in exported
    values = {line.split('\t')[2]: float(line.split('\t')[3])
              for line in (tmp_path / 'p.params').read_text().splitlines() if not line.startswith('#')}
    for letter in 'AG':
        assert values[f'TC_{letter}_ENABLE'] == 1
        assert values[f'TC_{letter}0_TMIN'] == pytest.approx(low, abs=1e-4)
        assert values[f'TC_{letter}0_TMAX'] == pytest.approx(high, abs=1e-4)
    # the other commands take the file: the held magnetometer is said where it cannot be diagnosed
    diagnosed = succeeded(['diagnose', str(tmp_path / 'cal.ulg'), '--params', str(tmp_path / 'p.yaml'),
                           '--no-progress'])
    assert 'magnetometer: not diagnosed: too few samples (6)' in diagnosed
    assert 'gyroscope: verdict' in diagnosed


def test_a_short_gyroscope_is_held_and_the_accelerometer_fitted_and_exported(short_warm_up, tmp_path):
    """sensor_gyro of 6 samples: the accelerometer fitted, the gyroscope held and said; both exports finite."""
    topics = driver_topics(short_warm_up, device_ids=IDS)
    topics[('sensor_gyro', 0)] = {field: values[:6] for field, values in topics[('sensor_gyro', 0)].items()}
    write_ulog(tmp_path / 'cal.ulg', topics)
    out = succeeded(['fit', str(tmp_path / 'cal.ulg'), '-o', str(tmp_path / 'p.yaml'), '--no-progress'])
    assert 'gyroscope: held at nominal (offset 0, scale 1): too few samples: 6 usable samples' in out
    assert 'fitted 1801 samples' in out
    unit = load_unit(tmp_path / 'p.yaml')
    assert unit.accel.needs_temperature and not unit.gyro.needs_temperature
    refused(['fit', str(tmp_path / 'cal.ulg'), '-o', str(tmp_path / 'q.yaml'), '--gyro-effects', 'thermal_lag',
             '--no-progress'], tmp_path / 'q.yaml')
    succeeded(['export', str(tmp_path / 'p.yaml'), '--format', 'px4', '-o', str(tmp_path / 'p.params')])
    succeeded(['export', str(tmp_path / 'p.yaml'), '--format', 'ardupilot', '-o', str(tmp_path / 'p.parm')])
    parm = dict(line.split() for line in (tmp_path / 'p.parm').read_text().splitlines() if not line.startswith('#'))
    assert float(parm['INS_TCAL1_TMIN']) == pytest.approx(unit.accel.temp_code_min, abs=1e-4)
    assert float(parm['INS_TCAL1_TMAX']) == pytest.approx(unit.accel.temp_code_max, abs=1e-4)
    assert all(float(parm[f'INS_TCAL1_GYR{order}_{axis}']) == 0.0 for order in (1, 2, 3) for axis in 'XYZ')


def test_a_gyroscope_whose_every_sample_is_left_out_is_held_by_fit_and_said_by_validate(short_warm_up, tmp_path):
    """INS_GYROFFS_Z of 1e30 makes every rate non-physical: fit holds the gyroscope, validate says it (no NaN)."""
    log = _bin_with(short_warm_up, tmp_path, parameters={'AHRS_ORIENTATION': 0, 'INS_GYROFFS_Z': 1e30})
    out = succeeded(['fit', str(log), '-o', str(tmp_path / 'p.yaml'), '--no-progress'])
    assert 'gyroscope: held at nominal (offset 0, scale 1): too few samples: 0 usable samples' in out
    out = succeeded(['validate', str(log), '--params', str(tmp_path / 'p.yaml'), '--no-progress'])
    assert 'gyroscope: no usable samples to validate (left out: 1801 non physical)' in out


# ----- 2. memory bounded by the samples, not the time they span -----------------------------------

def _jumped(record, first_ns: int, shift_ns: int):
    """The record stamped ``shift_ns`` later, but its first message (and temperature) at ``first_ns``."""
    def moved(stamps):
        if stamps is None:
            return None
        stamps = stamps + shift_ns
        stamps[0] = first_ns
        return stamps
    return replace(record, stamp_ns=moved(record.stamp_ns), temp_stamp_ns=moved(record.temp_stamp_ns),
                   accel_stamp_ns=moved(record.accel_stamp_ns), gyro_stamp_ns=moved(record.gyro_stamp_ns))


MEMORY_LIMIT = 1 << 30
"""Address space a fit of a 1,201-message record may take (before: a 5-s grid over 54 years, 10.9 GB)."""


def test_a_fit_holds_its_memory_to_the_samples_when_the_stamps_jump_by_years(tmp_path):
    """A bag whose first message is stamped 1 s after the epoch and the rest 54 years later: fit under 1 GiB."""
    record = simulate_powered(PoweredRun(duration_s=1200.0, accel_rate_hz=1.0, gyro_rate_hz=1.0)).record
    write_driver_record(tmp_path / 'bag', _jumped(record, 10 ** 9, 1_700_000_000 * 10 ** 9))
    script = ('import resource, sys\n'
              f'resource.setrlimit(resource.RLIMIT_AS, ({MEMORY_LIMIT}, {MEMORY_LIMIT}))\n'
              'from tak_thermo_ros.cli import main\n'
              'code = main(sys.argv[1:])\n'
              'print("peak", resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n'
              'raise SystemExit(code)\n')
    result = subprocess.run([sys.executable, '-c', script, 'fit', str(tmp_path / 'bag'), '-o', str(tmp_path / 'p.yaml'),
                             '--no-progress'], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert result.stderr == '' and (tmp_path / 'p.yaml').is_file()
    peak_kib = int(result.stdout.split('peak')[-1])
    assert peak_kib * 1024 < MEMORY_LIMIT


def test_the_temperature_course_grid_is_bounded_by_the_samples_and_unchanged_without_gaps():
    """54 years between two samples cost nothing; a record without long gaps gives the 5-s grid's figures."""
    rng = np.random.default_rng(3)
    stamps = np.cumsum(rng.uniform(0.5, 20.0, 2000))
    temperature = 20.0 + 10.0 * np.sin(stamps / 3000.0) + rng.normal(0.0, 0.05, len(stamps))
    grid = np.arange(stamps[0], stamps[-1] + 1e-9, KEEP_EVERY_S)  # the grid over the whole run, as before
    held = np.interp(grid, stamps, temperature)
    step = int(round(RATE_WINDOW_S / KEEP_EVERY_S))
    moves = np.diff(held[::step])
    course = temperature_course(stamps, temperature)
    assert course.rate_max == pytest.approx(np.abs(held[step:] - held[:-step]).max() / RATE_WINDOW_S, rel=1e-12)
    assert course.rise == pytest.approx(moves[moves > 0].sum(), rel=1e-12)
    assert course.fall == pytest.approx(-moves[moves < 0].sum(), rel=1e-12)
    jumped = temperature_course(np.r_[0.0, stamps + 1.7e9], np.r_[15.0, temperature])
    assert math.isfinite(jumped.rate_max) and jumped.low == pytest.approx(min(15.0, temperature.min()))


def test_a_clock_step_of_years_in_a_csv_or_a_flight_log_is_one_line(short_warm_up, tmp_path):
    """Stamped from boot, then from the epoch: refused naming the row (CSV) or the sample (ULog), nothing written."""
    rows = ['t,ax,ay,az,gx,gy,gz,temp'] + [
        f'{0 if i == 0 else 1_700_000_000 + i},0.01,0.02,9.81,0.001,0.002,0.003,{20 + i * 0.01:.2f}'
        for i in range(200)]
    (tmp_path / 'log.csv').write_text('\n'.join(rows) + '\n')
    line = refused(['import-csv', str(tmp_path / 'log.csv'), '-o', str(tmp_path / 'bag'), '--time-column', 't',
                    '--acc-columns', 'ax', 'ay', 'az', '--gyro-columns', 'gx', 'gy', 'gz', '--temp-column', 'temp',
                    '--no-progress'], tmp_path / 'bag')
    assert 'log.csv: row 2 (line 3)' in line and 'jumps ahead by 53.9 years' in line
    topics = driver_topics(short_warm_up, device_ids=IDS)
    for key in (('sensor_accel', 0), ('sensor_gyro', 0)):
        for field in ('timestamp', 'timestamp_sample'):
            topics[key][field] = topics[key][field] + 1_700_000_000 * 10 ** 6
            topics[key][field][0] = 1_000
    write_ulog(tmp_path / 'log.ulg', topics)
    line = refused(['fit', str(tmp_path / 'log.ulg'), '-o', str(tmp_path / 'p.yaml'), '--no-progress'],
                   tmp_path / 'p.yaml')
    assert 'log.ulg: sensor_accel instance 0: time jumps ahead by 53.9 years at sample 2' in line


def _bin_with(short_warm_up, directory: Path, change=None, parameters=None) -> Path:
    record = replace(short_warm_up, stamp_ns=short_warm_up.accel_stamp_ns, accel_stamp_ns=None, gyro_stamp_ns=None,
                     gyro=short_warm_up.gyro[:len(short_warm_up.accel)])  # both sensors in every IMU message
    messages = driver_messages(record)
    fmt, columns, values = messages['IMU']
    values = dict(values)
    if change is not None:
        change(values)
    path = directory / 'log.bin'
    write_dataflash(path, {'IMU': (fmt, columns, values)}, parameters=parameters or {'AHRS_ORIENTATION': 0})
    return path


def test_a_flipped_bit_in_a_dataflash_timeus_is_a_counted_stamp_jump(short_warm_up, tmp_path):
    """A TimeUS with bit 62 set (TimeUS*1000 overflowed before): dropped and counted, fit and apply finite."""
    def flip(values):
        values['TimeUS'] = values['TimeUS'].astype(np.uint64)
        values['TimeUS'][700] |= np.uint64(1) << np.uint64(62)
    log = _bin_with(short_warm_up, tmp_path, flip)
    out = succeeded(['fit', str(log), '-o', str(tmp_path / 'p.yaml'), '--no-progress'])
    assert _left_out(out, 'accelerometer').get('stamp jump') == 1
    assert 'fitted 1800 samples' in out
    applied = succeeded(['apply', str(log), '--params', str(tmp_path / 'p.yaml'), '-o', str(tmp_path / 'out'),
                         '--no-progress'])
    assert 'stamp jump' in applied and 'wrote 1800 Imu messages' in applied


# ----- 3. what was an internal error -------------------------------------------------------------

def _imu_format_without(column: str, replacement: str) -> tuple[str, str]:
    fmt, columns = IMU_FORMAT
    names = columns.split(',')
    index = names.index(column)
    names[index] = replacement
    return fmt, ','.join(names)


@pytest.mark.parametrize('case, expected', [
    ('AHRS_ORIENTATION', 'parameter AHRS_ORIENTATION is nan'),
    ('INS_TCAL1_ENABLE', 'parameter INS_TCAL1_ENABLE is nan'),
    ('INS_ACC_ID', 'parameter INS_ACC_ID is nan'),
    ('no_timeus', 'IMU messages have no column TimeUS'),
    ('no_accx', 'IMU messages have no column AccX'),
    ('t_as_text', "IMU column T is not a number (format character 'n')"),
])
def test_a_dataflash_log_that_was_an_internal_error_is_one_line(case, expected, short_warm_up, tmp_path):
    """A NaN parameter the reader undoes; an IMU format without TimeUS or AccX, or with T as text."""
    if case.isupper():
        log = _bin_with(short_warm_up, tmp_path, parameters={case: math.nan})
    else:
        record = short_warm_up
        count = len(record.accel)
        values = {'TimeUS': record.accel_stamp_ns // 1000, 'I': np.zeros(count, dtype=int), 'AccZ': record.accel[:, 2],
                  'T': np.linspace(20.0, 30.0, count)}
        if case == 'no_timeus':
            fmt, columns = _imu_format_without('TimeUS', 'TimeMS')
            values['TimeMS'] = values.pop('TimeUS')
        elif case == 'no_accx':
            fmt, columns = _imu_format_without('AccX', 'AccQ')
        else:
            fmt, columns = IMU_FORMAT
            fmt = fmt[:columns.split(',').index('T')] + 'n' + fmt[columns.split(',').index('T') + 1:]
            values['T'] = np.array([b'warm'] * count)
        log = tmp_path / 'log.bin'
        write_dataflash(log, {'IMU': (fmt, columns, values)})
    line = refused(['fit', str(log), '-o', str(tmp_path / 'p.yaml'), '--no-progress'], tmp_path / 'p.yaml')
    assert f'{log}: ' in line and expected in line, line


def test_a_csv_cell_beyond_the_csv_modules_limit_is_one_line(tmp_path):
    """A cell of 131,073 characters: the line named, nothing written."""
    text = 't,ax,ay,az,temp\n0,0,0,9.8,20\n1,0,0,' + '9' * 131_073 + ',21\n2,0,0,9.8,22\n'
    (tmp_path / 'log.csv').write_text(text)
    line = refused(['import-csv', str(tmp_path / 'log.csv'), '-o', str(tmp_path / 'bag'), '--time-column', 't',
                    '--acc-columns', 'ax', 'ay', 'az', '--temp-column', 'temp', '--no-progress'], tmp_path / 'bag')
    assert 'log.csv: line 3: not a delimited row (field larger than field limit' in line


@pytest.mark.parametrize('case', ['nested', 'long_integer'])
def test_a_calibration_yaml_nested_too_deeply_or_with_a_5000_digit_integer_is_one_line(case, tmp_path):
    """Export of such a file: one line naming it, nothing written."""
    value = '[' * 100_000 + ']' * 100_000 if case == 'nested' else '9' * 5000
    path = tmp_path / 'p.yaml'
    path.write_text(f'/**:\n  ros__parameters:\n    calibration:\n      version: {value}\n')
    line = refused(['export', str(path), '--format', 'px4', '-o', str(tmp_path / 'p.params')], tmp_path / 'p.params')
    words = 'nested too deeply' if case == 'nested' else 'an integer of more digits than Python converts'
    assert line.endswith(f'{path}: not a calibration file ({words})'), line


def test_a_ulog_that_sends_pyulog_round_in_circles_is_one_line(short_warm_up, tmp_path, monkeypatch):
    """The pyulog 1.2 parser seeks back for ever over some damaged files (found by the fuzz): one line, no hang."""
    import pyulog

    class Circling:
        """pyulog as it behaves on such a file: reads, seeks back, reads again (bounded here)."""

        def __init__(self, stream, topics):
            for _ in range(1_000_000):
                stream.read(3000)
                stream.seek(0)
            raise AssertionError('pyulog was never stopped')

    write_ulog(tmp_path / 'log.ulg', driver_topics(short_warm_up, device_ids=IDS))
    monkeypatch.setattr(pyulog, 'ULog', Circling)
    line = refused(['fit', str(tmp_path / 'log.ulg'), '-o', str(tmp_path / 'p.yaml'), '--no-progress'],
                   tmp_path / 'p.yaml')
    assert line.endswith('log.ulg: not a readable ULog (pyulog went round in circles over damaged data)')


# ----- 6. nothing lost silently -------------------------------------------------------------------

def test_non_finite_flight_log_temperatures_are_ignored_and_counted_as_a_bags_are(short_warm_up, tmp_path):
    """Every 36th temperature NaN in a ULog and a .bin: ignored, counted and said; the fit finite."""
    topics = driver_topics(short_warm_up, device_ids=IDS)
    temperature = topics[('sensor_accel', 0)]['temperature'].copy()
    temperature[1::36] = np.nan
    topics[('sensor_accel', 0)]['temperature'] = temperature
    write_ulog(tmp_path / 'log.ulg', topics)
    out = succeeded(['fit', str(tmp_path / 'log.ulg'), '-o', str(tmp_path / 'p.yaml'), '--no-progress'])
    assert f'ignored {int(np.isnan(temperature).sum())} non-finite temperatures' in out

    def nan_t(values):
        values['T'] = values['T'].copy()
        values['T'][1::30] = np.nan
    log = _bin_with(short_warm_up, tmp_path, nan_t)
    out = succeeded(['fit', str(log), '-o', str(tmp_path / 'q.yaml'), '--no-progress'])
    assert f'ignored {len(range(1, len(short_warm_up.accel), 30))} non-finite temperatures' in out


def test_a_ulog_topic_in_two_subscriptions_keeps_both(short_warm_up, tmp_path):
    """sensor_accel instance 0 logged in two parts: all 1,801 samples read and fitted, the join said."""
    topics = driver_topics(short_warm_up, device_ids=IDS)
    accel = topics[('sensor_accel', 0)]
    half = len(accel['timestamp']) // 2
    topics[('sensor_accel', 0)] = [{f: v[half:] for f, v in accel.items()}, {f: v[:half] for f, v in accel.items()}]
    write_ulog(tmp_path / 'log.ulg', topics)
    out = succeeded(['fit', str(tmp_path / 'log.ulg'), '-o', str(tmp_path / 'p.yaml'), '--no-progress'])
    assert '1801 sensor_accel' in out and 'fitted 1801 samples' in out
    assert 'sensor_accel in 2 subscriptions, joined in the order of their first stamps' in out


def test_flight_log_stamps_that_go_back_follow_the_bags_rule(short_warm_up, tmp_path):
    """Two accelerometer stamps back in a ULog, one repeated in a .bin: left out and counted, not re-sorted."""
    topics = driver_topics(short_warm_up, device_ids=IDS)
    stamps = topics[('sensor_accel', 0)]['timestamp_sample'].copy()
    stamps[100], stamps[101] = stamps[101], stamps[100]
    stamps[500] = stamps[499] - 3_000_000
    topics[('sensor_accel', 0)]['timestamp_sample'] = stamps
    write_ulog(tmp_path / 'log.ulg', topics)
    out = succeeded(['fit', str(tmp_path / 'log.ulg'), '-o', str(tmp_path / 'p.yaml'), '--no-progress'])
    assert _left_out(out, 'accelerometer') == {'time backwards': 2} and 'fitted 1799 samples' in out

    def repeat(values):
        values['TimeUS'] = values['TimeUS'].copy()
        values['TimeUS'][300] = values['TimeUS'][299]
    log = _bin_with(short_warm_up, tmp_path, repeat)
    out = succeeded(['fit', str(log), '-o', str(tmp_path / 'q.yaml'), '--no-progress'])
    assert _left_out(out, 'accelerometer') == {'duplicate stamp': 1}


# ----- 7. wrong output with exit 0 ----------------------------------------------------------------

def test_export_bounds_the_slot_from_the_files_instance_as_the_option(short_warm_up, tmp_path):
    """source.instance 7: PX4 has TC_A0..3, ArduPilot INS_TCAL1..3: refused as --instance 7 is; --instance chooses."""
    write_ulog(tmp_path / 'log.ulg', driver_topics(short_warm_up, device_ids=IDS))
    succeeded(['fit', str(tmp_path / 'log.ulg'), '-o', str(tmp_path / 'p.yaml'), '--no-progress'])
    document = yaml.safe_load((tmp_path / 'p.yaml').read_text())
    document['/**/compensator']['ros__parameters']['calibration']['source']['instance'] = 7
    (tmp_path / 'p.yaml').write_text(yaml.safe_dump(document))
    for firmware, words in (('px4', 'PX4 has TC_A0..3 and TC_G0..3 (instances 0..3)'),
                            ('ardupilot', 'ArduPilot has INS_TCAL1..3 (instances 0..2)')):
        line = refused(['export', str(tmp_path / 'p.yaml'), '--format', firmware, '-o', str(tmp_path / 'x')],
                       tmp_path / 'x')
        assert f'{tmp_path / "p.yaml"}: source.instance 7' in line and words in line
    out = succeeded(['export', str(tmp_path / 'p.yaml'), '--format', 'px4', '--instance', '1', '-o',
                     str(tmp_path / 'x')])
    assert 'TC_A1_TMIN' in (tmp_path / 'x').read_text() and 'wrote 34 parameters' in out


@pytest.mark.parametrize('cell', ['1_0', '\u0661\u0662', '\uff11\uff12', '1\u00a00'])
def test_a_csv_number_is_ascii_decimal(cell, tmp_path):
    """``1_0`` (10.0 to Python), Arabic-Indic and full-width digits: refused naming row and column."""
    text = f't,ax,ay,az,temp\n0,0.1,0,9.8,20\n1,{cell},0,9.8,21\n2,0.1,0,9.8,22\n'
    (tmp_path / 'log.csv').write_text(text, encoding='utf-8')
    line = refused(['import-csv', str(tmp_path / 'log.csv'), '-o', str(tmp_path / 'bag'), '--time-column', 't',
                    '--acc-columns', 'ax', 'ay', 'az', '--temp-column', 'temp', '--no-progress'], tmp_path / 'bag')
    assert "row 2 (line 3), column 'ax'" in line and 'not a finite number in ASCII decimal' in line
    (tmp_path / 'log.csv').write_text(f't,ax,ay,az,temp\n0,0.1,0,9.8,20\n{cell},0.1,0,9.8,21\n', encoding='utf-8')
    line = refused(['import-csv', str(tmp_path / 'log.csv'), '-o', str(tmp_path / 'bag'), '--time-column', 't',
                    '--acc-columns', 'ax', 'ay', 'az', '--temp-column', 'temp', '--no-progress'], tmp_path / 'bag')
    assert "row 2 (line 3), column 't'" in line and 'is not a number (ASCII decimal digits)' in line


def test_a_duplicated_csv_column_is_refused_naming_it(tmp_path):
    """Two ``ax`` columns: which one is meant cannot be told."""
    (tmp_path / 'log.csv').write_text('t,ax,ay,az,ax,temp\n0,0.1,0,9.8,5,20\n1,0.1,0,9.8,5,21\n')
    line = refused(['import-csv', str(tmp_path / 'log.csv'), '-o', str(tmp_path / 'bag'), '--time-column', 't',
                    '--acc-columns', 'ax', 'ay', 'az', '--temp-column', 'temp', '--no-progress'], tmp_path / 'bag')
    assert "column 'ax' appears 2 times in the header (columns 2, 5)" in line


def test_apply_leaves_a_corrupt_magnetic_field_out_and_counts_it_without_a_warning(tmp_path):
    """A field of 1e300 T in a hand-turned record: apply drops and counts it (it overflowed in numpy's norm)."""
    from tak_thermo_ros.core.simulation.magnetometer import MagnetometerTruth, rotation_record
    record = rotation_record(MagnetometerTruth(), samples=400, seed=91, temperature_celsius=15.0,
                             warm_to_celsius=30.0)
    write_driver_record(tmp_path / 'cal', record)
    succeeded(['fit', str(tmp_path / 'cal'), '-o', str(tmp_path / 'p.yaml'), '--no-progress'])
    mag = record.mag.copy()
    mag[0] = 1e300
    write_driver_record(tmp_path / 'bag', replace(record, mag=mag))
    out = succeeded(['apply', str(tmp_path / 'bag'), '--params', str(tmp_path / 'p.yaml'), '-o',
                     str(tmp_path / 'out'), '--no-progress'])
    assert 'wrote 399 MagneticField messages' in out and 'dropped MagneticField messages: 1 non finite' in out


def _accel_cells(row: int) -> str:
    """A CSV row's ax, ay, az: about 1 g, none of them constant."""
    return f'{0.01 * (row % 3)},{0.02 + 0.01 * (row % 2)},{9.81 + 0.001 * (row % 5)}'


# ----- 9. one clear line ------------------------------------------------------------------------

def test_infinite_rates_in_a_rotated_dataflash_log_are_counted_without_a_warning(short_warm_up, tmp_path):
    """Two infinite GyrX under AHRS_ORIENTATION 2: no numpy warning, the two counted as non-finite."""
    def infinite(values):
        values['GyrX'] = values['GyrX'].copy()
        values['GyrX'][[10, 20]] = [math.inf, -math.inf]
    log = _bin_with(short_warm_up, tmp_path, infinite, parameters={'AHRS_ORIENTATION': 2})
    out = succeeded(['fit', str(log), '-o', str(tmp_path / 'p.yaml'), '--no-progress'])
    assert _left_out(out, 'gyroscope').get('non finite') == 2


def test_magnetometer_columns_empty_in_every_row_are_said_so(tmp_path):
    """No cell of mx my mz given: said in those words, not a median of nan."""
    rows = ['t,ax,ay,az,gx,gy,gz,temp,mx,my,mz'] + [f'{i},{_accel_cells(i)},0.001,0.002,0.003,{20 + i},,,'
                                                    for i in range(30)]
    (tmp_path / 'log.csv').write_text('\n'.join(rows) + '\n')
    line = refused(['import-csv', str(tmp_path / 'log.csv'), '-o', str(tmp_path / 'bag'), '--time-column', 't',
                    '--acc-columns', 'ax', 'ay', 'az', '--gyro-columns', 'gx', 'gy', 'gz', '--temp-column', 'temp',
                    '--mag-columns', 'mx', 'my', 'mz', '--mag-unit', 'uT', '--no-progress'], tmp_path / 'bag')
    assert 'columns mx my mz are empty in every row: no magnetometer sample' in line


# ----- 10. temperatures in the wrong unit -------------------------------------------------------

@pytest.mark.parametrize('unit', ['kelvin', 'centi'])
def test_flight_log_bag_and_csv_temperatures_not_in_celsius_are_refused_with_a_hint(unit, short_warm_up, tmp_path):
    """One rule for every reader: mostly in kelvin's band of an IMU's range, or mostly implausible: refused."""
    change = (lambda t: t + 273.15) if unit == 'kelvin' else (lambda t: t * 100.0)
    words = 'in kelvin, not degrees Celsius: convert them' if unit == 'kelvin' else 'not degrees Celsius (centi'
    topics = driver_topics(short_warm_up, device_ids=IDS)
    for topic in ('sensor_accel', 'sensor_gyro'):
        topics[(topic, 0)]['temperature'] = change(topics[(topic, 0)]['temperature'])
    write_ulog(tmp_path / 'log.ulg', topics)
    line = refused(['fit', str(tmp_path / 'log.ulg'), '-o', str(tmp_path / 'p.yaml'), '--no-progress'],
                   tmp_path / 'p.yaml')
    assert 'log.ulg: sensor_accel.temperature: ' in line and words in line
    write_driver_record(tmp_path / 'bag', replace(short_warm_up, temperature=change(short_warm_up.temperature)))
    line = refused(['fit', str(tmp_path / 'bag'), '-o', str(tmp_path / 'p.yaml'), '--no-progress'],
                   tmp_path / 'p.yaml')
    assert f'{tmp_path / "bag"}: /imu/temperature: ' in line and words in line
    rows = ['t,ax,ay,az,gx,gy,gz,temp'] + [f'{i},{_accel_cells(i)},0.001,0.002,0.003,{change(20.0 + 0.1 * i):.2f}'
                                           for i in range(50)]
    (tmp_path / 'log.csv').write_text('\n'.join(rows) + '\n')
    line = refused(['import-csv', str(tmp_path / 'log.csv'), '-o', str(tmp_path / 'out'), '--time-column', 't',
                    '--acc-columns', 'ax', 'ay', 'az', '--gyro-columns', 'gx', 'gy', 'gz', '--temp-column', 'temp',
                    '--no-progress'], tmp_path / 'out')
    assert "log.csv: column 'temp': " in line and words in line


def test_a_reference_record_in_kelvin_is_refused_by_validate_diagnose_and_apply_too(tmp_path):
    """The same rule where the record holds references (a table run): not only fit refuses it (apply writes nothing)."""
    from tak_thermo_ros.core.simulation.imu import simulate
    from tak_thermo_ros.core.simulation.scenario import Scenario
    run = simulate(Scenario(sample_rate_hz=2.0, plateaus_celsius=(10.0, 30.0), plateau_hours=0.05,
                            ramp_celsius_per_minute=5.0, board_lag_s=5.0, dwell_s=5.0, output='imu')).driver
    write_driver_record(tmp_path / 'good', run)
    succeeded(['fit', str(tmp_path / 'good'), '-o', str(tmp_path / 'p.yaml'), '--no-progress'])
    write_driver_record(tmp_path / 'bag', replace(run, temperature=run.temperature + 273.15))
    for command in ('validate', 'diagnose', 'apply'):
        output = ['-o', str(tmp_path / 'out')] if command == 'apply' else []
        line = refused([command, str(tmp_path / 'bag'), '--params', str(tmp_path / 'p.yaml'), *output,
                        '--no-progress'], tmp_path / 'out')
        assert f'{tmp_path / "bag"}: /imu/temperature: ' in line, (command, line)
        assert 'in kelvin, not degrees Celsius: convert them' in line, (command, line)
