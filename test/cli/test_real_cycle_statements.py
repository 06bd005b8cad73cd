"""What the commands say of a record like the real cycle: issue 31's smaller findings (item 5), each with a test.

(The hand-held gyroscope's label: ``test/passes/test_handheld.py``; a rotation record's |B|:
``test/passes/test_magnetometer.py``.)
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from paths import REPO
from tak_thermo_ros import cli
from tak_thermo_ros.core.diagnose import diagnose
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.formats.bag import Topics, write_driver_record
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.formats.scenario import load_scenario
from tak_thermo_ros.passes.diagnose import bounded_run
from tak_thermo_ros.passes.run import StreamOptions
from tak_thermo_ros.passes.validate import validate_bag
from tak_thermo_ros.reports.diagnose import write_report
from tak_thermo_ros.reports.diagnose_figures import gravity_series
from tak_thermo_ros.units import with_error
from tak_thermo_ros.formats.records import open_record

DOCS = REPO / 'docs'
OPTIONS = StreamOptions(topics=Topics(), progress=False)
STATIC_RAMP = Scenario(output='imu', sample_rate_hz=2.0, plateaus_celsius=(35.0,), start_celsius=5.0,
                       ramp_celsius_per_minute=1.0, plateau_hours=0.05, board_lag_s=60.0, positions=((0.0, 0.0, 1.0),),
                       record_references=False, seed=21)
"""A driver record like the real cycle's: one orientation, a ramp and no plateau to speak of (about 40 min)."""


def _run(capsys, *argv: str) -> tuple[int, str]:
    capsys.readouterr()
    status = cli.main([*argv, '--no-progress'])
    out = capsys.readouterr()
    return status, out.out + out.err


@pytest.fixture(scope='module')
def driver(tmp_path_factory):
    root = tmp_path_factory.mktemp('findings')
    write_driver_record(root / 'run', simulate(STATIC_RAMP).driver)
    assert cli.main(['fit', str(root / 'run'), '-o', str(root / 'base.yaml'), '--no-progress']) == 0
    return root


@pytest.fixture(scope='module')
def diagnosed(driver):
    """The fitted file, the record's accelerometer samples and their diagnosis (warm-up the candidate).

    Shared: neither the report nor the |g| series changes the diagnosis or the samples.
    """
    unit = load_unit(driver / 'base.yaml')
    samples = bounded_run(open_record(driver / 'run', topics=OPTIONS.topics), OPTIONS, unit=unit).samples['accel']
    return unit, samples, diagnose(unit.accel, samples, candidates=['warmup'])


def test_the_report_of_a_driver_record_speaks_of_degrees_draws_what_it_promises_and_no_panel_of_one_point(
        driver, diagnosed):
    """No 'temperature code' on the page, no green promised without a green curve, no one-point panels."""
    _, samples, result = diagnosed
    assert result.residual_after is None  # nothing named: no second curve
    files = write_report(result, samples, driver / 'report', sensor='accel', unit='m/s^2')
    page = (driver / 'report' / 'report.html').read_text()
    assert 'temperature code' not in page and 'codes' not in page.split('<h2>')[0]
    assert 'green' not in page
    names = {path.name for path in files.figures}
    assert 'residual_inputs.png' not in names and 'residual_plateaus.png' not in names
    assert 'One input per axis in this run (one orientation)' in page and 'temperature plateau' in page


def test_the_reports_g_before_is_validates_before(driver, diagnosed):
    """The same record and file: the report's |g| before and validate's are one computation (the values as recorded)."""
    unit, samples, result = diagnosed
    series = gravity_series(result, samples, 9.80665, as_recorded=True)
    report_before = float(np.sqrt(np.mean(series[0][1] ** 2)))
    validated = validate_bag(open_record(driver / 'run', topics=OPTIONS.topics), unit, OPTIONS, gravity=9.80665)
    assert report_before == pytest.approx(validated.gravity.before.gravity_error().rms, rel=1e-9)
    assert series[0][0] == 'as recorded (no correction)'


def test_noise_of_a_static_run_says_what_bias_instability_it_allows_not_zero(tmp_path, capsys):
    """The simulated 1e-4 m/s^2 hides under white noise and the walk: 'at most' a bound above it, never 'B 0'."""
    scenario = replace(load_scenario(DOCS / 'scenarios' / 'noise_static.yaml'), plateau_hours=3.0)
    write_driver_record(tmp_path / 'static', simulate(scenario).driver)
    status, out = _run(capsys, 'noise', str(tmp_path / 'static'))
    assert status == 0
    assert not re.search(r'bias instability B 0 ', out)
    said = re.findall(r'bias instability B (at most )?([0-9.e-]+) m/s\^2', out)
    assert len(said) == 3  # the accelerometer's three axes
    for bound, value in said:
        assert float(value) > 0.0 and (not bound or float(value) >= 1e-4)


def test_a_flight_logs_survey_counts_each_sensor_at_its_own_rate(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli.main(['simulate', 'warm_up.ulg', '--scenario', str(DOCS / 'scenarios' / 'px4_warm_up.yaml')]) == 0
    status, out = _run(capsys, 'fit', 'warm_up.ulg', '-o', 'imu.yaml')
    assert status == 0
    assert 'record: sensor_accel 1,801 at 2 Hz, sensor_gyro 2,700 at 3 Hz; 15 min' in out
    assert '/imu/data_raw' not in out
    capsys.readouterr()
    status = cli.main(['export', 'imu.yaml', '--format', 'px4', '-o', 'imu.params'])
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert status == 0
    assert any('load it in QGroundControl' in line and 'reboot the board' in line for line in lines)
    assert any('redo the accelerometer and gyroscope calibrations' in line and '2.0..31.9 C' in line for line in lines)
    assert any('constant offset into TC_A0_X0_* and TC_G0_X0_*' in line for line in lines)
    assert all(len(line) <= 100 for line in lines)


def test_an_effect_parameter_is_named_by_the_input_and_value_and_error_share_their_decimals(driver, capsys):
    status, out = _run(capsys, 'fit', str(driver / 'run'), '-o', str(driver / 'h.yaml'), '--gyro-effects',
                       'hysteresis', '--force')
    assert status == 0
    assert 'effect hysteresis: width ' in out and 'width_codes' not in out
    for value, error in re.findall(r'([-+]?\d[\d.]*) \+- (\d[\d.]*)', out):
        decimals = [len(text.split('.')[1]) if '.' in text else 0 for text in (value, error)]
        assert decimals[0] == decimals[1], (value, error)
    assert with_error(-1188.43, 3.61) == '-1188.4 +- 3.6'
    assert with_error(0.01035, 8.4e-05) == '0.010350 +- 0.000084'
    assert with_error(217.7158, 3.3) == '217.7 +- 3.3'
    assert with_error(217.7158, 110.4) == '220 +- 110'
    assert with_error(-1234.5, 2e3) == '-1200 +- 2000'


def test_the_errors_of_the_walk_through_fit_in_one_line_of_100_characters(driver, tmp_path, capsys, monkeypatch):
    """A term one orientation cannot excite, a CSV read in the wrong time unit, a calibration given as --noise."""
    monkeypatch.chdir(driver)
    status, out = _run(capsys, 'fit', 'run', '-o', 'x.yaml', '--effects', 'cross_axis')
    assert status == 2 and out.strip() == ('tak_calib: error: accelerometer: axis x: this run does not excite '
                                           'cross_axis (c_xz) (no fit)')
    (tmp_path / 'log.csv').write_text('timestamp,ax,ay,az,temp\n' + ''.join(
        f'{256551281491968 + 500000 * k},0.1,0.0,-9.8,{20 + k * 0.1}\n' for k in range(20)))
    monkeypatch.chdir(tmp_path)
    status, out = _run(capsys, 'import-csv', 'log.csv', '-o', 'bag', '--time-unit', 's', '--acc-columns', 'ax', 'ay',
                       'az', '--temp-column', 'temp')
    assert status == 2 and len(out.strip()) <= 110 and '(--time-unit?)' in out, out  # 235 characters before
    monkeypatch.chdir(driver)
    status, out = _run(capsys, 'validate', 'run', '--params', 'base.yaml', '--noise', 'base.yaml')
    last = out.strip().splitlines()[-1]
    assert status == 2 and len(last) <= 100 and 'a calibration file, not a noise model' in last, last


def test_the_papers_table_on_every_plateau_of_a_six_face_record_with_slow_ramps(tmp_path, capsys, monkeypatch):
    """Five chamber plateaus at 1 C/min: eqs. (3)-(5) on each of the five (the ramps' rests chained them into one)."""
    scenario = replace(load_scenario(DOCS / 'scenarios' / 'handheld_six_faces.yaml'), ramp_celsius_per_minute=1.0)
    monkeypatch.chdir(tmp_path)
    write_driver_record(Path('six'), simulate(scenario).driver)
    status, out = _run(capsys, 'fit', 'six', '-o', 'six.yaml')
    assert status == 0
    rows = [line for line in out.splitlines() if re.match(r'\s+-?\d+\.\d C x: \(3\)', line)]
    temperatures = [float(row.split()[0]) for row in rows]
    assert np.allclose(temperatures, [5.0, 15.0, 20.0, 30.0, 35.0], atol=0.6), temperatures
