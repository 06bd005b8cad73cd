"""import-csv: a real MEMS IMU log becomes the bag contract; bad logs give one line naming the row or column."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from paths import REPO
from tak_thermo_ros.formats.bag import read_record
from tak_thermo_ros.cli import main
from tak_thermo_ros.formats.csv_log.options import CsvImportOptions
from tak_thermo_ros.formats.csv_log.reader import parse_csv_log, read_csv_log
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import LogError

REAL_LOG = REPO / 'data' / 'tofupilot-imu-thermal' / 'imu_raw_data.csv'
REAL_COLUMNS = ['--time-unit', 'us', '--acc-columns', 'imu.acc.x', 'imu.acc.y', 'imu.acc.z',
                '--temp-column', 'imu.temperature']
REAL_OPTIONS = CsvImportOptions(acc_columns=('imu.acc.x', 'imu.acc.y', 'imu.acc.z'),
                                temp_column='imu.temperature', time_unit='us')
SMALL_COLUMNS = ['--time-column', 't', '--acc-columns', 'ax', 'ay', 'az', '--temp-column', 'temp']


@pytest.fixture(scope='module')
def real_log():
    """The real log, imported with the defaults (0.001 m/s^2 and 0.01 C per code)."""
    return read_csv_log(REAL_LOG, REAL_OPTIONS)


def test_real_file_rows_units_and_rounding(real_log):
    """8400 rows; stamps are the microsecond column in ns; codes are round(a / 1e-3) and round(T / 0.01)."""
    record = real_log.record
    assert real_log.rows == 8400 and real_log.delimiter == '\t'
    assert record.counts.shape == (8400, 3) and record.temp_code.shape == (8400,)
    assert record.counts_stamp_ns[0] == 256551281491968 * 1000
    assert np.all(np.diff(record.counts_stamp_ns) > 0)
    assert 4200.0 < real_log.duration_s < 4300.0  # about 71 minutes at about 2 Hz
    # First data row of the file: acc.z -9.55327034 m/s^2, temperature 51.61518097 C.
    assert record.counts[0, 2] == -9553.0 and record.temp_code[0] == 5162.0
    np.testing.assert_array_equal(record.counts, np.round(real_log.acceleration / 1e-3))
    np.testing.assert_array_equal(record.temp_code, np.round(real_log.temperature / 0.01))
    assert record.nominal_scale == (1000.0, 1000.0, 1000.0)
    assert -17.7 < real_log.temperature.min() < -17.5 and 73.9 < real_log.temperature.max() < 74.1


def test_real_file_reference_is_the_mean_direction_scaled_to_gravity(real_log):
    """One reference message at the first stamp: |ref| = g along the mean measured acceleration."""
    record = real_log.record
    assert record.reference.shape == (1, 3)
    assert record.reference_stamp_ns[0] == record.counts_stamp_ns[0]
    reference = record.reference[0]
    assert math.isclose(float(np.linalg.norm(reference)), STANDARD_GRAVITY, rel_tol=1e-12)
    mean = real_log.acceleration.mean(axis=0)
    assert float(np.linalg.norm(np.cross(reference / STANDARD_GRAVITY, mean / np.linalg.norm(mean)))) < 1e-12
    assert reference[2] < -9.8 and abs(reference[0]) < 0.2 and abs(reference[1]) < 0.2  # z down
    assert real_log.max_tilt_deg < 2.0  # the board did not move


def test_cli_import_prints_the_reference_and_the_bag_holds_it(tmp_path, capsys):
    """tak_calib import-csv writes the bag (reference, nominal scale) and prints the reference it estimated."""
    bag = tmp_path / 'real'
    assert main(['import-csv', str(REAL_LOG), '-o', str(bag), *REAL_COLUMNS]) == 0
    out = capsys.readouterr().out
    assert '8400 rows (tab-delimited)' in out
    line = next(text for text in out.splitlines() if text.startswith('reference: that direction scaled to gravity'))
    printed = [float(v) for v in line.split('= (')[1].split(')')[0].split(',')]
    record = read_record(bag, require_reference=True, progress=False)
    np.testing.assert_allclose(record.reference[0], printed, atol=5e-5)
    assert record.nominal_scale == (1000.0, 1000.0, 1000.0)
    assert len(record.counts_stamp_ns) == 8400 and len(record.reference_stamp_ns) == 1


def test_units_g_milliseconds_semicolons_and_a_given_reference():
    """`g` is 9.80665 m/s^2, ms become ns, the delimiter is sniffed, a given reference is kept."""
    text = ['t;ax;ay;az;temp\n', '0;0.001;0;-1;20.00\n', '500;0.002;0;-1.001;20.50\n', '1000.5;0.001;0.001;-1;21.00\n']
    options = CsvImportOptions(acc_columns=('ax', 'ay', 'az'), temp_column='temp', time_column='t',
                               time_unit='ms', acc_unit='g', acc_resolution=0.01, temp_resolution=0.5,
                               reference=(0.0, 0.0, -9.8))
    log = parse_csv_log(text, options)
    assert log.delimiter == ';'
    np.testing.assert_array_equal(log.record.counts_stamp_ns, [0, 500_000_000, 1_000_500_000])
    expected = np.round(np.array([-1, -1.001, -1]) * STANDARD_GRAVITY / 0.01)
    np.testing.assert_array_equal(log.record.counts[:, 2], expected)
    np.testing.assert_array_equal(log.record.temp_code, [40.0, 41.0, 42.0])
    np.testing.assert_array_equal(log.record.reference[0], [0.0, 0.0, -9.8])
    assert not log.reference_estimated and log.record.nominal_scale == (100.0, 100.0, 100.0)


def _rows(*rows: str) -> str:
    return 't,ax,ay,az,temp\n' + ''.join(f'{row}\n' for row in rows)


GOOD = ('0.0,0.01,0.02,-9.80,20.0', '0.5,0.02,0.01,-9.81,20.5', '1.0,0.01,0.02,-9.79,21.0')
BAD_LOGS = {
    'missing column': ('t,ax,ay,az,temperature\n0,0,0,-9.8,20\n',
                       "no column 'temp' \\(columns: t, ax, ay, az, temperature; comma-delimited\\)"),
    'non-numeric row': (_rows(GOOD[0], GOOD[1], '1.0,0.01,abc,-9.79,21.0'),
                        "row 3 \\(line 4\\), column 'ay': 'abc' is not a finite number"),
    'empty field': (_rows(GOOD[0], '0.5,0.02,0.01,,20.5', GOOD[2]),
                    "row 2 \\(line 3\\), column 'az': '' is not a finite number"),
    'time backwards': (_rows(GOOD[0], GOOD[2], GOOD[1]),
                       "row 3 \\(line 4\\): time goes backwards in column 't'"),
    'time repeats': (_rows(GOOD[0], GOOD[1], GOOD[1]), "row 3 \\(line 4\\): time repeats in column 't'"),
    'constant temperature': (_rows('0,0.01,0.02,-9.80,25', '1,0.02,0.01,-9.81,25', '2,0.01,0.02,-9.79,25'),
                             "column 'temp' is constant \\(25\\) over all 3 rows: no temperature sweep"),
    'constant axis': (_rows('0,0.01,0,-9.80,20', '1,0.02,0,-9.81,21', '2,0.01,0,-9.79,22'),
                      "column 'ay' is constant \\(0\\) over all 3 rows: a stuck or disconnected axis"),
    'sweep below one code': (_rows('0,0.01,0.02,-9.80,25.001', '1,0.02,0.01,-9.81,25.002', '2,0.01,0.02,-9.79,25.0'),
                             "column 'temp' varies by only 0.002 C, less than one code of 0.01 C"),
    'saturating': (_rows(GOOD[0], '0.5,0.02,0.01,-40.0,20.5', GOOD[2]),
                   "row 2 \\(line 3\\), column 'az': -40 m/s\\^2 is -40000 counts .* it would saturate"),
    'ragged row': (_rows(GOOD[0], '0.5,0.02,0.01,-9.81', GOOD[2]), 'row 2 \\(line 3\\): 4 fields, the header has 5'),
    'empty file': ('', 'empty file \\(no header line\\)'),
    'header only': ('t,ax,ay,az,temp\n', 'no data rows after the header'),
}


@pytest.mark.parametrize('case', sorted(BAD_LOGS))
def test_bad_log_gives_one_line_and_exit_code_2(case, tmp_path, capsys):
    """Each bad log: exit code 2, one line 'tak_calib: error: <file>: ...' naming the row or column; no bag."""
    text, message = BAD_LOGS[case]
    log = tmp_path / 'log.csv'
    log.write_text(text)
    bag = tmp_path / 'out'
    assert main(['import-csv', str(log), '-o', str(bag), *SMALL_COLUMNS]) == 2
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f'tak_calib: error: {log}: ')
    assert captured.out == ''
    with pytest.raises(LogError, match=message):
        read_csv_log(log, CsvImportOptions(acc_columns=('ax', 'ay', 'az'), temp_column='temp', time_column='t'))
    assert not bag.exists()


def test_gyro_columns_make_a_driver_bag_with_the_logged_values(tmp_path, capsys):
    """--gyro-columns: the real log becomes a driver bag, values as logged (SI units), temperature in C."""
    from tak_thermo_ros.formats.bag import bag_input_kind, read_driver_record
    from tak_thermo_ros.core.link.model import InputKind
    gyro = ['--gyro-columns', 'imu.gyro.x', 'imu.gyro.y', 'imu.gyro.z']
    assert main(['import-csv', str(REAL_LOG), '-o', str(tmp_path / 'driver'), *REAL_COLUMNS, *gyro]) == 0
    assert 'no reference topic written' in capsys.readouterr().out
    assert bag_input_kind(tmp_path / 'driver') is InputKind.IMU
    driver = read_driver_record(tmp_path / 'driver', progress=False)
    table = np.genfromtxt(REAL_LOG, delimiter='\t', names=True)
    np.testing.assert_array_equal(driver.accel[:, 2], table['imuaccz'])
    np.testing.assert_array_equal(driver.gyro[:, 0], table['imugyrox'])
    np.testing.assert_array_equal(driver.temperature, table['imutemperature'])
    assert len(driver.reference_stamp_ns) == 0 and len(driver.rate_reference_stamp_ns) == 0
    assert np.all(driver.orientation_covariance[:, 0] == -1.0)  # REP 145: no orientation in a log


def test_gyro_unit_deg_per_second_is_converted_to_rad_per_second(tmp_path):
    """A log in deg/s is written in rad/s: 180 deg/s is pi rad/s."""
    lines = ['t,ax,ay,az,temp,gx,gy,gz']
    lines += [f'{i},{0.01 + 1e-3 * (i % 3)},{0.02 - 1e-3 * (i % 2)},{9.8 + 1e-3 * (i % 2)},{20 + i},180,-90,{i}'
              for i in range(30)]
    options = CsvImportOptions(acc_columns=('ax', 'ay', 'az'), temp_column='temp', time_column='t',
                               gyro_columns=('gx', 'gy', 'gz'), gyro_unit='deg/s')
    log = parse_csv_log(lines, options)
    assert log.driver is not None
    np.testing.assert_allclose(log.driver.gyro[0], (math.pi, -math.pi / 2, 0.0), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(log.driver.temperature, 20.0 + np.arange(30))
    with pytest.raises(LogError, match='gyro_unit'):
        CsvImportOptions(acc_columns=('ax', 'ay', 'az'), temp_column='temp', gyro_columns=('a', 'b', 'c'),
                         gyro_unit='rpm')


def _multi_rate_lines(rows: int = 60) -> tuple[list[str], np.ndarray, np.ndarray]:
    """A log: the gyroscope every row, the accelerometer every third, the temperature every second (empty cells)."""
    rng = np.random.default_rng(4)
    accel = np.array([0.1, -0.2, 9.8]) + rng.normal(0.0, 0.01, (rows, 3))
    gyro = rng.normal(0.0, 0.001, (rows, 3))
    lines = ['t,ax,ay,az,temp,gx,gy,gz']
    for i in range(rows):
        a = ','.join(f'{v:.6f}' for v in accel[i]) if i % 3 == 0 else ',,'
        temp = f'{20.0 + 0.2 * i:.2f}' if i % 2 == 0 else ''
        lines.append(f'{0.01 * i:.2f},{a},{temp},' + ','.join(f'{v:.6f}' for v in gyro[i]))
    return lines, accel, gyro


def test_sensors_at_their_own_rates_keep_their_own_samples(tmp_path, capsys):
    """Empty cells: each sensor's rows only, on its own stamps (nothing resampled); the bag round-trips them."""
    from tak_thermo_ros.formats.bag import read_driver_record
    lines, accel, gyro = _multi_rate_lines()
    options = CsvImportOptions(acc_columns=('ax', 'ay', 'az'), temp_column='temp', time_column='t',
                               gyro_columns=('gx', 'gy', 'gz'))
    driver = parse_csv_log(lines, options).driver
    assert not driver.shared_stamps
    np.testing.assert_array_equal(driver.sensor_stamps('accel'), np.arange(0, 60, 3) * 10_000_000)
    np.testing.assert_allclose(driver.accel, accel[::3], atol=1e-6)
    np.testing.assert_allclose(driver.gyro, gyro, atol=1e-6)
    np.testing.assert_array_equal(driver.temp_stamp_ns, np.arange(0, 60, 2) * 10_000_000)
    log = tmp_path / 'log.csv'
    log.write_text('\n'.join(lines) + '\n')
    assert main(['import-csv', str(log), '-o', str(tmp_path / 'bag'), '--acc-columns', 'ax', 'ay', 'az',
                 '--temp-column', 'temp', '--time-column', 't', '--gyro-columns', 'gx', 'gy', 'gz']) == 0
    assert 'each sensor on its own stamps, nothing resampled' in capsys.readouterr().out
    back = read_driver_record(tmp_path / 'bag', progress=False)
    assert np.array_equal(back.sensor_stamps('accel'), driver.sensor_stamps('accel'))
    np.testing.assert_array_equal(back.gyro, driver.gyro)


def test_a_gyroscope_in_a_file_of_its_own_keeps_its_time_column(tmp_path):
    """--gyro-file: its own time column and rate; the same record as the columns in one file with empty cells."""
    lines, _, gyro = _multi_rate_lines()
    main_lines = [','.join(line.split(',')[:5]) for line in lines]
    main_lines = [line for line in main_lines if line.split(',')[1] or line.startswith('t')]  # accelerometer rows
    (tmp_path / 'accel.csv').write_text('\n'.join(main_lines) + '\n')
    (tmp_path / 'gyro.csv').write_text('time,gx,gy,gz\n' + ''.join(
        f'{0.01 * i:.2f},' + ','.join(f'{v:.6f}' for v in gyro[i]) + '\n' for i in range(len(gyro))))
    options = CsvImportOptions(acc_columns=('ax', 'ay', 'az'), temp_column='temp', time_column='t',
                               gyro_columns=('gx', 'gy', 'gz'), gyro_file=str(tmp_path / 'gyro.csv'),
                               gyro_time_column='time')
    driver = read_csv_log(tmp_path / 'accel.csv', options).driver
    np.testing.assert_array_equal(driver.sensor_stamps('gyro'), np.arange(60) * 10_000_000)
    np.testing.assert_array_equal(driver.sensor_stamps('accel'), np.arange(0, 60, 3) * 10_000_000)
    np.testing.assert_allclose(driver.gyro, gyro, atol=1e-6)
    with pytest.raises(LogError, match="bad.csv: no column 'gx'"):
        (tmp_path / 'bad.csv').write_text('time,x,y,z\n0,1,2,3\n')
        read_csv_log(tmp_path / 'accel.csv', replace(options, gyro_file=str(tmp_path / 'bad.csv')))
