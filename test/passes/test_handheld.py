"""Hand-held records through tak_calib: what every command says first, fit, validate, apply, diagnose, bad records."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from paths import REPO
from tak_thermo_ros import cli
from tak_thermo_ros.core.diagnose import diagnose
from tak_thermo_ros.core.fit.handheld import HandheldSettings, fit_handheld
from tak_thermo_ros.core.link.handheld_check import check_handheld
from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.records.handheld import collect
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.records.still import find_still
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.simulation.motion import HandheldMotion
from tak_thermo_ros.formats.bag import read_imu_messages, write_driver_record
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.passes.handheld import at_rest, rest_samples

UNIT = {'effects': {'cross_axis': {'c_yx': 0.002, 'c_zx': -0.003, 'c_zy': 0.0015, 'c_xy': 0.001}},
        'gyro_effects': {'cross_axis': {'c_xy': 0.002, 'c_xz': -0.003, 'c_zy': 0.004}}}
CALIBRATION = Scenario(output='imu', sample_rate_hz=10.0, start_celsius=8.0, seed=11, **UNIT,
                       handheld=HandheldMotion(orientations=50, still_s=7.0, final_celsius=30.0, warmup_tau_s=300.0))
"""Seven minutes of a unit turned by hand while it warms from 8 C (10 Hz, 4600 Imu messages)."""
SECOND = replace(CALIBRATION, seed=12, start_celsius=12.0,
                 handheld=replace(CALIBRATION.handheld, orientations=15, final_celsius=25.0))


def run_cli(capsys, *argv) -> tuple[int, list[str]]:
    """``tak_calib argv``: its exit status and the lines it printed."""
    status = cli.main([*argv, '--no-progress'])
    out = capsys.readouterr()
    return status, (out.out + out.err).splitlines()


@pytest.fixture(scope='module')
def bags(tmp_path_factory):
    """The calibration record and a second record of the same unit, as driver bags."""
    directory = tmp_path_factory.mktemp('handheld')
    paths = {}
    for name, scenario in (('cal', CALIBRATION), ('run2', SECOND)):
        paths[name] = directory / name
        write_driver_record(paths[name], simulate(scenario).driver)
    return paths


def test_fit_says_what_the_record_holds_and_fits_both_sensors(bags, tmp_path, capsys):
    """The first line: a hand-held record; then topics, duration, span, rests and orientations, the plan; the file."""
    params = tmp_path / 'p.yaml'
    status, lines = run_cli(capsys, 'fit', str(bags['cal']), '-o', str(params))
    assert status == 0, lines
    assert lines[0].startswith('fit: a hand-held record (no reference topics, ')
    assert lines[1].startswith('record: /imu/data_raw 4,') and ' at 10 Hz, /imu/temperature ' in lines[1]
    assert lines[2].startswith('record: temperature 8..') and float(lines[2].split('(span ')[1].split()[0]) > 15.0
    assert lines[3].startswith('record: at rest ') and ' 50 rests of ' in lines[3]
    assert lines[4].startswith('record: ') and ' orientations at rest; faces up within 30 deg: +x -x ' in lines[4]
    assert lines[5] == 'fit: offset, scale and misalignment of both sensors against temperature'
    assert all(len(line) <= 100 for line in lines[:6])
    assert 'hand-held: ' in '\n'.join(lines) and any(line.startswith('turns: closure RMS ') for line in lines)
    unit = load_unit(params)
    accel = {effect.name: effect for effect in unit.accel.effects}['cross_axis']
    assert accel['c_xy'] == accel['c_xz'] == accel['c_yz'] == 0.0
    gauge = 'accelerometer: gauge c_xy = c_xz = c_yz = 0: corrected x along its x axis'
    assert any(note.startswith(gauge) for note in unit.accel.notes)
    assert [effect.name for effect in unit.gyro.effects] == ['cross_axis']
    assert params.read_text().startswith(f'# tak_thermo_ros calibration fitted from {bags["cal"]} (a hand-held record)')


def test_validate_and_apply_a_second_hand_held_record(bags, tmp_path, capsys):
    """validate: the rests' |g| and rate and the turns' closure fall to the noise; apply corrects every message."""
    params = tmp_path / 'p.yaml'
    assert run_cli(capsys, 'fit', str(bags['cal']), '-o', str(params))[0] == 0
    report = tmp_path / 'v.json'
    status, lines = run_cli(capsys, 'validate', str(bags['run2']), '--params', str(params), '--json', str(report))
    assert status == 0, lines
    assert lines[0] == "validate: |g| and the rate at the rests, and the turns' closure"
    figures = json.loads(report.read_text())
    assert figures['record'] == 'handheld' and figures['rests'] >= 13
    after, floor, before = figures['after'], figures['floor'], figures['before']
    assert after['gravity_rms'] < 1.5 * floor['gravity_rms'] < before['gravity_rms']
    assert np.all(np.array(after['rate_rms']) < 1.5 * np.array(floor['rate_rms']))
    assert after['closure_rms_rad'] < 1.5 * floor['closure_rms_rad'] < before['closure_rms_rad']
    output = tmp_path / 'out.mcap'
    status, lines = run_cli(capsys, 'apply', str(bags['run2']), '--params', str(params), '-o', str(output))
    assert status == 0, lines
    assert lines[1].startswith('record: /imu/data_raw ')
    assert lines[0] == 'apply: every message corrected with the calibration'
    written = read_imu_messages(output, topic='/imu/data_compensated')
    assert len(written.stamp_ns) == len(simulate(SECOND).driver.stamp_ns)
    diagnosis = tmp_path / 'd.json'
    report = tmp_path / 'report'
    status, lines = run_cli(capsys, 'diagnose', str(bags['run2']), '--params', str(params), '--json', str(diagnosis),
                            '--report', str(report))
    assert status == 0, lines
    assert lines[0].startswith('diagnose: the residual at the rests') and lines[5].startswith('turns: closure RMS ')
    # The gyroscope's misalignment is in the file but no rest shows it: said beside the model diagnosed (issue 31).
    said = ' '.join(line.strip() for line in lines)
    assert 'gyroscope: diagnosed' in said and '(model: base; cross_axis in the file, not diagnosed: no rate at rest)' \
        in said
    # The report of a hand-held record: one page with each sensor's verdict and figures, in the sensor's units.
    page = (report / 'report.html').read_text()
    assert page.count('verdict') >= 2 and 'accel/report.html' in page and 'gyro/report.html' in page
    gyro_page = (report / 'gyro' / 'report.html').read_text()
    accel_page = (report / 'accel' / 'report.html').read_text()
    assert 'deg/h' in gyro_page and 'mg' in accel_page and 'none' in gyro_page
    figures = json.loads(diagnosis.read_text())
    assert figures['handheld']['closure_rms_rad'] < 1.5 * figures['handheld']['closure_floor_rad']
    assert figures['sensors']['accel']['verdict'] == figures['sensors']['gyro']['verdict'] == 'none'


def test_bad_hand_held_records_get_one_line(tmp_path, capsys):
    """Never at rest, noise of a moving record, an input effect: exit 2, one line; turned away from one pose: a pool."""
    moving = tmp_path / 'moving'
    write_driver_record(moving, simulate(replace(CALIBRATION, handheld=replace(
        CALIBRATION.handheld, still_s=0.5, turn_s=3.0, orientations=20))).driver)
    status, lines = run_cli(capsys, 'fit', str(moving), '-o', str(tmp_path / 'p.yaml'))
    assert status == 2 and len(lines) == 1
    assert lines[0].startswith(f'tak_calib: error: {moving}: no reference topics and no still interval (the unit never '
                               f'rested 2 s or more')
    one = tmp_path / 'one'
    run = simulate(replace(CALIBRATION, handheld=replace(CALIBRATION.handheld, pattern='one_axis', orientations=2)))
    driver = run.driver
    rests = run.trajectory.segment % 2 == 0
    pose = run.trajectory.up[0] * 9.80665  # every rest in the first pose, the unit turned away and back between
    accel = np.where(rests[:, None], pose + (driver.accel - run.specific_force), driver.accel)
    write_driver_record(one, replace(driver, accel=accel))
    status, lines = run_cli(capsys, 'fit', str(one), '-o', str(tmp_path / 'one.yaml'))
    # rests in one pose, motion between: an everyday record, fitted as a pool of one (issue 43), not refused
    assert status == 0 and lines[0] == 'one: an everyday record (rests in one orientation, motion between): taken ' \
                                       'as a pool of one', lines
    cal = tmp_path / 'cal'
    write_driver_record(cal, simulate(CALIBRATION).driver)
    status, lines = run_cli(capsys, 'noise', str(cal))
    assert status == 2 and len(lines) == 1 and lines[0].endswith('a noise model needs a static record')
    status, lines = run_cli(capsys, 'fit', str(cal), '-o', str(tmp_path / 'p.yaml'), '--effects', 'scale_nonlinearity')
    assert status == 2 and len(lines) == 1 and 'not fitted from a hand-held record' in lines[0]
    assert not (tmp_path / 'p.yaml').exists()


def test_every_command_says_first_what_a_static_record_holds(tmp_path, capsys):
    """fit, apply, validate, diagnose and noise of a static driver run: the survey lines first, the plan for each."""
    static = tmp_path / 'static'
    write_driver_record(static, simulate(Scenario(output='imu', sample_rate_hz=2.0, plateaus_celsius=(10.0, 30.0),
                                                  plateau_hours=0.1, ramp_celsius_per_minute=2.0, board_lag_s=60.0,
                                                  positions=((0.0, 0.0, 1.0),), record_references=False)).driver)
    params = tmp_path / 'p.yaml'
    commands = {'fit': ['fit', str(static), '-o', str(params), '--bias-order', '2', '--scale-order', '0'],
                'apply': ['apply', str(static), '--params', str(params), '-o', str(tmp_path / 'out.mcap')],
                'validate': ['validate', str(static), '--params', str(params)],
                'diagnose': ['diagnose', str(static), '--params', str(params)],
                'noise': ['noise', str(static), '--params', str(params)]}
    for command, argv in commands.items():
        status, lines = run_cli(capsys, *argv)
        assert status == 0, (command, lines)
        if command in ('validate', 'diagnose'):  # the record the file was fitted from: said first (issue 31)
            assert lines[0].startswith('in-sample: static is the record p.yaml was fitted from'), lines[0]
            lines = lines[2:]
        assert lines[0].startswith(f'{command}: ') and ('static' in lines[0] or 'at rest' in lines[0]
                                                        or command == 'apply'), lines[0]
        assert lines[1].startswith('record: /imu/data_raw ') and lines[2].startswith('record: temperature 10')
        assert lines[3].startswith('record: at rest 100 % of the time, 1 rest of ')
        assert lines[4] == 'record: 1 orientation at rest; faces up within 30 deg: +z (1 of 6)'


def test_a_hidden_gyroscope_lag_is_named_and_the_refit_reaches_the_floor():
    """A chamber heats and cools a unit turned by hand: diagnose names thermal_lag; the refit reaches the floor."""
    scenario = Scenario(output='imu', sample_rate_hz=5.0, start_celsius=10.0, plateaus_celsius=(10.0, 35.0, 15.0),
                        plateau_hours=0.05, ramp_celsius_per_minute=2.0, board_lag_s=60.0, seed=3,
                        gyro_effects={'thermal_lag': {'tau_s': 300.0, 'slope_x': 4e-4, 'slope_y': -3e-4,
                                                      'slope_z': 2e-4}},
                        handheld=HandheldMotion(still_s=10.0, turn_s=2.5, temperature='chamber'))
    driver = simulate(scenario).driver
    record = collect(find_still(driver.stamp_ns, np.hstack([driver.accel, driver.gyro])), align(driver.six_channels()))
    base = fit_handheld(record)

    def unit(fitted) -> UnitCalibration:
        return UnitCalibration(InputKind.IMU, fitted.results['accel'].calibration, fitted.results['gyro'].calibration)

    samples, check = rest_samples(record, unit(base), gravity=9.80665, latitude=None)
    assert check.closure.rms_rad > 3.0 * check.closure.floor_rad  # the lag's bias breaks the turns too
    found = diagnose(at_rest(unit(base).gyro), samples['gyro'], candidates=['thermal_lag', 'hysteresis', 'warmup'])
    assert found.verdict == 'thermal_lag'
    refit = fit_handheld(record, HandheldSettings(effects={'gyro': ('thermal_lag',)}))
    lag = {effect.name: effect for effect in refit.results['gyro'].calibration.effects}['thermal_lag']
    assert abs(lag['tau_s'] - 300.0) < 4.0 * refit.results['gyro'].parameter_errors['thermal_lag.tau_s']
    after = check_handheld(record, unit(refit), gravity=9.80665)
    assert after.closure.rms_rad < 1.2 * after.closure.floor_rad
    assert np.all(after.rate_rms < 1.2 * after.rate_floor)
    assert np.all(np.array([a.residual_rms for a in refit.results['gyro'].calibration.axes])
                  < 1.02 * record.intervals.noise[3:6])


def test_a_counts_table_run_says_first_what_it_holds(tmp_path, capsys):
    """The paper's codes on a table: the reference's directions counted, the table plan, before the fit's lines."""
    from tak_thermo_ros.formats.bag import write_record
    bag = tmp_path / 'table'
    write_record(bag, simulate(Scenario(plateau_hours=0.1, ramp_celsius_per_minute=2.0, board_lag_s=60.0,
                                        dwell_s=30.0)).record)
    status, lines = run_cli(capsys, 'fit', str(bag), '-o', str(tmp_path / 'p.yaml'))
    assert status == 0, lines
    assert lines[0] == 'fit: a table run (reference topics): offset and scale against temperature per axis'
    assert lines[1].startswith('record: /tak/counts ') and ' at 1 Hz, /tak/temp_code ' in lines[1]
    assert lines[2].startswith('record: also /tak/reference ')
    assert lines[3].startswith('record: temperature code 7') and lines[3].endswith(')')
    assert lines[6] == 'record: the reference holds 10 directions'
    assert lines[7].startswith('fitted ')


def test_an_imported_still_board_is_a_static_run_not_a_table_run(tmp_path, capsys):
    """Issue 43: a CSV of a board lying still, imported (its reference one constant direction), was called a table run.

    ``fit`` said "a table run (reference topics): offset and scale against temperature", then held
    every scale: one input per axis. A reference in one direction is a static run's, said so.
    """
    log = REPO / 'data' / 'tofupilot-imu-thermal' / 'imu_raw_data.csv'
    bag, params = tmp_path / 'real', tmp_path / 'base.yaml'
    assert run_cli(capsys, 'import-csv', str(log), '-o', str(bag), '--time-unit', 'us', '--acc-columns', 'imu.acc.x',
                   'imu.acc.y', 'imu.acc.z', '--temp-column', 'imu.temperature')[0] == 0
    status, lines = run_cli(capsys, 'fit', str(bag), '-o', str(params), '--settle-time', '60')
    assert status == 0, lines
    assert lines[0] == 'fit: a static run (its reference in one direction, one orientation)', lines
    assert 'record: the reference holds 1 direction' in lines
    assert 'fit: offsets against temperature, scales held' in lines
    assert not any(axis.scale_observable for axis in load_unit(params).accel.axes)


def test_the_six_faces_with_a_gap_print_the_papers_table_in_lines_of_100_characters(tmp_path, capsys, monkeypatch):
    """The six faces at three plateaus, 1 s of a turn lost: eqs. (3)-(5) per plateau, the turn not used, said.

    Every line the hand-held fit adds is at most 100 characters (the per-axis summary lines that every
    driver fit prints are the shared format's, left out here).
    """
    scenario = Scenario(output='imu', sample_rate_hz=5.0, start_celsius=10.0, plateaus_celsius=(10.0, 20.0, 30.0),
                        plateau_hours=0.05, ramp_celsius_per_minute=5.0, board_lag_s=30.0, seed=13, **UNIT,
                        handheld=HandheldMotion(pattern='six_faces', temperature='chamber', still_s=12.0, turn_s=3.0))
    run = simulate(scenario)
    driver = run.driver
    keep = np.ones(len(driver.stamp_ns), dtype=bool)
    keep[np.flatnonzero(run.trajectory.segment == 2 * 10 + 1)[3:8]] = False  # 1 s of the 11th turn lost
    monkeypatch.chdir(tmp_path)  # short paths, as a user's
    bag = Path('six')
    write_driver_record(bag, replace(driver, stamp_ns=driver.stamp_ns[keep], accel=driver.accel[keep],
                                     gyro=driver.gyro[keep], orientation=driver.orientation[keep],
                                     orientation_covariance=driver.orientation_covariance[keep]))
    status, lines = run_cli(capsys, 'fit', str(bag), '-o', 'p.yaml')
    assert status == 0, lines
    assert lines[4] == 'record: 6 orientations at rest; faces up within 30 deg: +x -x +y -y +z -z (6 of 6)'
    assert 'hand-held: 1 turns not used (across a gap in the stamps)' in lines
    header = lines.index("the paper's +/- method per plateau with all six faces, (3) offset and (5) scale, "
                         "beside the link:")
    rows = lines[header + 1:header + 10]
    temperatures, axes = [float(row.split()[0]) for row in rows], [row.split()[2] for row in rows]
    assert np.allclose(temperatures, np.repeat([10.0, 20.0, 30.0], 3), atol=1.0), temperatures
    assert axes == ['x:', 'y:', 'z:'] * 3
    assert all(' m/s^2, (5) ' in row and '; faces tilted <= ' in row for row in rows)
    own = [line for line in lines if not line.startswith(('  x: residual', '  y: residual', '  z: residual'))]
    assert all(len(line) <= 100 for line in own), [line for line in own if len(line) > 100]
