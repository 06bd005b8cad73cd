"""A pool of everyday records: fit, validate, diagnose and apply several records; bad pools; the short seed check."""

from __future__ import annotations

import json
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from paths import REPO
from tak_thermo_ros import cli
from tak_thermo_ros.core.simulation.everyday import everyday_scenario, everyday_truth, simulate_everyday_record
from tak_thermo_ros.formats.bag import write_driver_record
from tak_thermo_ros.formats.calibration_file import load_unit

sys.path.insert(0, str(REPO / 'bench'))
from everyday_check import check_seed, offset_errors  # noqa: E402

MONTH = {'sample_rate_hz': 10.0, 'seed': 21, 'everyday': {'records': 7, 'record_minutes': 10.0}}
"""Seven records of about 10 minutes at 10 Hz (6,000 Imu messages each)."""


def run_cli(capsys, *argv) -> tuple[int, list[str]]:
    """``tak_calib argv``: its exit status and the statements it printed (a line wrapped at 100 characters joined)."""
    from tak_thermo_ros.cli.common import unwrap
    status = cli.main([*argv, '--no-progress'])
    out = capsys.readouterr()
    return status, unwrap(out.out + out.err)


def write_month(directory: Path, raw: dict, indices, *, prefix: str = 'rec', ulog_ids: dict | None = None) -> list:
    """Records ``indices`` of a month as bags (or ULogs with ``ulog_ids``) in ``directory``; their simulations."""
    scenario, habits = everyday_scenario(raw)
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for index in indices:
        simulated = simulate_everyday_record(scenario, habits, index)
        if ulog_ids is None:
            write_driver_record(directory / f'{prefix}{index:02d}', simulated.record)
        else:
            from tak_thermo_ros.formats.ulog import driver_topics, write_ulog
            write_ulog(directory / f'{prefix}{index:02d}.ulg', driver_topics(simulated.record, device_ids=ulog_ids),
                       info={'sys_name': 'PX4'})
        written.append(simulated)
    return written


@pytest.fixture(scope='module')
def month(tmp_path_factory):
    """Five records to pool (rec00..rec04) and two held out (rec05, rec06), as bags."""
    root = tmp_path_factory.mktemp('month')
    pooled = write_month(root / 'pool', MONTH, range(5))
    write_month(root / 'held', MONTH, range(5, 7))
    return root, pooled


def test_fit_a_directory_of_records_one_line_each_then_the_pool(month, capsys, tmp_path):
    """``fit DIR``: a line per record, what the pool covers, what is held; the file holds the gyroscope's turn_on."""
    root, pooled = month
    params = tmp_path / 'p.yaml'
    status, lines = run_cli(capsys, 'fit', str(root / 'pool'), '-o', str(params))
    assert status == 0, lines
    for index in range(5):
        line = next(line for line in lines if line.startswith(f'rec{index:02d}: '))
        assert 'rests' in line and 'min at rest' in line and 'orientation' in line
    assert any(line.startswith('pool: 5 of 5 records') for line in lines)
    assert any(line.startswith('pool: heating at') for line in lines)
    assert any('the tilts determine the offsets on x y' in line for line in lines)
    assert any(line.startswith('gyroscope: turn-on repeatability x y z') for line in lines)
    assert sum('+- 1 sigma (never below what leaving each record out says):' in line for line in lines) == 2
    unit = load_unit(params)
    turn_on = unit.gyro.turn_on
    assert turn_on is not None and turn_on.records == 5
    truth = np.array([s.turn_on['gyro'] for s in pooled]).std(axis=0, ddof=1)
    # five power-ups: the spread is known to about a third; within three of its errors of the draws' own
    assert np.all(np.abs(np.array(turn_on.repeatability) - truth) < 3.0 * np.array(turn_on.repeatability_error)
                  + 2e-5)
    # within 3 deg of level the tilts tell the x and y offsets (b . u in |f|), to about a mg
    truth = everyday_truth(*everyday_scenario(MONTH)).accel
    errors = offset_errors(unit.accel)
    for axis in range(2):
        true = truth.axes[axis].offset + truth.axes[axis].offset_drift(unit.accel.temp_code_ref - truth.temp_code_ref)
        assert errors[axis] < 2e-2 and abs(unit.accel.axes[axis].offset - true) < 4.0 * errors[axis]
    assert 'x.offset' not in unit.accel.uncertainty.held and 'z.scale' in unit.accel.uncertainty.held
    assert unit.source['format'] == 'pool'


def test_validate_apply_and_diagnose_take_several_records(month, capsys, tmp_path):
    """``validate`` and ``apply`` of two held-out records, ``diagnose`` of the pool with whole records held out."""
    root, _ = month
    params = tmp_path / 'p.yaml'
    assert run_cli(capsys, 'fit', str(root / 'pool'), '-o', str(params))[0] == 0
    held = [str(root / 'held' / 'rec05'), str(root / 'held' / 'rec06')]
    status, lines = run_cli(capsys, 'validate', *held, '--params', str(params), '--json', str(tmp_path / 'v.json'))
    assert status == 0, lines
    document = json.loads((tmp_path / 'v.json').read_text())
    assert document['record'] == 'pool' and len(document['turn_on_offsets']) == 2
    after, before = document['after'], document['before']
    # the link takes out the drift: the rests' rate after, each record's own offset off, far below before
    assert max(after['rate_shape_rms']) < 0.25 * max(before['rate_rms'])
    status, lines = run_cli(capsys, 'apply', *held, '--params', str(params), '-o', str(tmp_path / 'out'))
    assert status == 0, lines
    assert sorted(p.name for p in (tmp_path / 'out').iterdir()) == ['rec05', 'rec06']
    assert lines[0].startswith('rec05: wrote ') and lines[1].startswith('rec06: wrote ')
    status, lines = run_cli(capsys, 'diagnose', str(root / 'pool'), '--params', str(params), '--folds', '3')
    assert status == 0, lines
    assert any('the folds hold whole records out' in line for line in lines)
    assert any(line.startswith('accelerometer: not diagnosed') for line in lines)
    # the turns' closure, above the noise here, is said to be out of the verdict, and why (issue 43)
    closure = next(i for i, line in enumerate(lines) if line.startswith('turns: closure RMS '))
    assert lines[closure + 1] == 'turns: not in the verdict, which judges the rests: no turn was fitted (gyro ' \
                                 'scales held)', lines
    assert any(line.startswith('gyroscope: verdict: none') for line in lines), lines


def test_one_record_by_path_is_a_pool_of_one(month, capsys, tmp_path):
    """``fit REC`` of one everyday record: a pool of one, as the directory holding only it (issue 43).

    It was refused as a static run that moved; ``validate`` and ``diagnose`` of one record take it alike.
    """
    root, _ = month
    status, lines = run_cli(capsys, 'fit', str(root / 'pool' / 'rec02'), '-o', str(tmp_path / 'one.yaml'))
    assert status == 0, lines
    assert lines[0] == 'rec02: an everyday record (rests in one orientation, motion between): taken as a pool of one'
    assert any(line.startswith('pool: 1 of 1 records') for line in lines)
    assert 'turn-on repeatability: not estimated, one record (it takes two power-ups or more); none written' in lines
    alone = tmp_path / 'alone'
    alone.mkdir()
    (alone / 'rec02').symlink_to(root / 'pool' / 'rec02')
    assert run_cli(capsys, 'fit', str(alone), '-o', str(tmp_path / 'dir.yaml'))[0] == 0
    assert load_unit(tmp_path / 'one.yaml') == load_unit(tmp_path / 'dir.yaml')
    status, lines = run_cli(capsys, 'validate', str(root / 'held' / 'rec06'), '--params', str(tmp_path / 'one.yaml'))
    assert status == 0 and lines[1].startswith('rec06: ') and ' rests, ' in lines[1], lines
    assert any(line.startswith("gyroscope: this record's turn-on offset") for line in lines), lines
    status, lines = run_cli(capsys, 'diagnose', str(root / 'pool' / 'rec02'), '--params', str(tmp_path / 'one.yaml'),
                            '--folds', '3')
    assert status == 0, lines
    assert 'pool: 1 record; its own turn-on offset taken off; the folds hold time blocks out' in lines
    assert any(line.startswith('gyroscope: verdict: ') for line in lines), lines


def test_validate_of_a_pool_says_in_sample_and_a_record_beyond_the_range_first(month, capsys, tmp_path):
    """In-sample said for pools (the pool fitted, one of its records, a mix); a record beyond the range said first.

    Issue 43: ``validate`` of the pool a file was fitted from said nothing of it, and a record whose
    rests lay beyond the calibrated range was said last, as a count of samples naming no record,
    after a turn-on spread that pointed at the turn-on.
    """
    root, _ = month
    params = tmp_path / 'p.yaml'
    assert run_cli(capsys, 'fit', str(root / 'pool'), '-o', str(params))[0] == 0
    assert len(load_unit(params).fitted_from) == 5
    status, lines = run_cli(capsys, 'validate', str(root / 'pool'), '--params', str(params))
    assert status == 0 and lines[0] == 'in-sample: these 5 records are the pool p.yaml was fitted from (the same ' \
                                       'samples)', lines
    assert "fit's own residual" in lines[1]
    status, lines = run_cli(capsys, 'validate', str(root / 'pool' / 'rec03'), '--params', str(params))
    assert lines[1] == 'in-sample: rec03 is one of the 5 records p.yaml was fitted from (the same samples)', lines
    status, lines = run_cli(capsys, 'validate', str(root / 'pool' / 'rec00'), str(root / 'held' / 'rec06'),
                            '--params', str(params))
    assert lines[0] == 'in-sample: 1 of the 2 records holds samples p.yaml was fitted from (rec00)', lines
    # rec05's rests reach 5.8 C, the pool's 9.4: said per record, with its share of rests, before any figure
    status, lines = run_cli(capsys, 'validate', str(root / 'held'), '--params', str(params))
    assert status == 0 and not any('in-sample' in line for line in lines), lines
    beyond = [i for i, line in enumerate(lines) if ' rests beyond the calibrated ' in line]
    assert len(beyond) == 1 and lines[beyond[0]].startswith('rec05: ') and lines[beyond[0]].endswith(': clamped')
    outside, rests = (int(word) for word in lines[beyond[0]].split()[1:5:3])
    rests_line = next(line for line in lines if line.startswith('rec05: ') and ' min at rest' in line)
    assert 1 <= outside <= rests and rests_line.startswith(f'rec05: {rests} rests, ')
    assert beyond[0] < min(i for i, line in enumerate(lines) if line.startswith(('|g| error', 'gyroscope: ')))
    assert not any(line.startswith('warning: ') for line in lines), lines


def test_another_unit_in_the_pool_is_left_out_two_units_are_refused(month, capsys, tmp_path):
    """A record of a unit whose gyroscope's offset lies 0.02 rad/s away is named and left out; 3 + 3 refused."""
    root, _ = month
    other = {**MONTH, 'seed': 5, 'gyro_unit': {'x': {'offset': 0.0221}}}
    pool = tmp_path / 'mixed'
    pool.mkdir()
    for index in range(5):
        (pool / f'rec{index:02d}').symlink_to(root / 'pool' / f'rec{index:02d}')
    write_month(pool, other, [0], prefix='other')
    status, lines = run_cli(capsys, 'fit', str(pool), '-o', str(tmp_path / 'p.yaml'))
    assert status == 0, lines
    left = [line for line in lines if line.startswith('other00: left out: another unit?')]
    assert len(left) == 1 and 'gyroscope x turn-on offset' in left[0], lines
    # what the pool covers counts the records fitted, said after the one left out (issue 43)
    covered = next(i for i, line in enumerate(lines) if line.startswith('pool: '))
    assert lines[covered].startswith('pool: 5 of 6 records') and lines.index(left[0]) < covered, lines
    assert load_unit(tmp_path / 'p.yaml').gyro.turn_on.records == 5
    halves = tmp_path / 'halves'
    halves.mkdir()
    for index in range(3):
        (halves / f'rec{index:02d}').symlink_to(root / 'pool' / f'rec{index:02d}')
    write_month(halves, other, range(3), prefix='other')
    status, lines = run_cli(capsys, 'fit', str(halves), '-o', str(tmp_path / 'q.yaml'))
    # each record's line as it is read, then the refusal in one line
    assert status == 2 and len(lines) == 7 and 'the pool looks like two units' in lines[-1], lines
    assert 'give the records of one unit' in lines[-1] and not (tmp_path / 'q.yaml').exists()


def test_flight_logs_of_another_device_are_left_out(capsys, tmp_path):
    """Flight logs pooled with bags; a ULog whose gyroscope's device_id differs is left out, named; 2 + 2 refused."""
    raw = {**MONTH, 'everyday': {'records': 5, 'record_minutes': 8.0}}
    write_month(tmp_path / 'logs', raw, range(3), ulog_ids={'accel': 11, 'gyro': 12})
    write_month(tmp_path / 'logs', raw, [3], ulog_ids={'accel': 11, 'gyro': 99}, prefix='stranger')
    write_month(tmp_path / 'logs', raw, [4])
    status, lines = run_cli(capsys, 'fit', str(tmp_path / 'logs'), '-o', str(tmp_path / 'p.yaml'))
    assert status == 0, lines
    assert 'stranger03.ulg: left out: another device (gyroscope device_id 99, the pool\'s 12)' in lines
    assert any(line.startswith('pool: 4 of 5 records') for line in lines)
    write_month(tmp_path / 'split', raw, range(2), ulog_ids={'accel': 11, 'gyro': 12})
    write_month(tmp_path / 'split', raw, range(2, 4), ulog_ids={'accel': 11, 'gyro': 99}, prefix='b')
    status, lines = run_cli(capsys, 'fit', str(tmp_path / 'split'), '-o', str(tmp_path / 'q.yaml'))
    assert status == 2 and 'devices in equal numbers' in lines[-1], lines
    assert sum(1 for line in lines if line.endswith(' orientation')) == 4  # each record's line as it is read


def test_records_without_rests_one_record_and_no_span_are_said(capsys, tmp_path):
    """A record that never rests adds nothing; none with a rest: refused; one record, no span: said.

    One record: no turn-on repeatability; no temperature span: the offsets at one temperature.
    """
    restless = {**MONTH, 'everyday': {'records': 2, 'record_minutes': 4.0, 'rest_s': [0.5, 1.0]}}
    write_month(tmp_path / 'pool', MONTH, range(3))
    write_month(tmp_path / 'pool', restless, [0], prefix='moving')
    status, lines = run_cli(capsys, 'fit', str(tmp_path / 'pool'), '-o', str(tmp_path / 'p.yaml'))
    assert status == 0, lines
    assert any(line.startswith('moving00: no rest: its quietest windows move') and 'contributes nothing' in line
               for line in lines), lines
    for simulated in write_month(tmp_path / 'cold', MONTH, range(2), prefix='x'):  # then rewritten without temperature
        bare = replace(simulated.record, temp_stamp_ns=np.zeros(0, dtype=np.int64), temperature=np.zeros(0))
        write_driver_record(tmp_path / 'cold' / f'rec{simulated.index:02d}', bare)
        shutil.rmtree(tmp_path / 'cold' / f'x{simulated.index:02d}')
    status, lines = run_cli(capsys, 'fit', str(tmp_path / 'cold'), '-o', str(tmp_path / 'q.yaml'))
    assert status == 2 and lines[-1] == ('tak_calib: error: no record of the 2 given holds a rest with a temperature: '
                                         'nothing to fit')
    assert len(lines) == 3 and all('contributes nothing' in line for line in lines[:2]), lines
    write_month(tmp_path / 'one', MONTH, [0])
    status, lines = run_cli(capsys, 'fit', str(tmp_path / 'one'), '-o', str(tmp_path / 'one.yaml'))
    assert status == 0 and any(line.startswith('turn-on repeatability: not estimated, one record') for line in lines)
    assert load_unit(tmp_path / 'one.yaml').gyro.turn_on is None
    flat = {**MONTH, 'everyday': {'records': 3, 'record_minutes': 6.0, 'ambient_celsius': [20.0, 20.0],
                                  'ambient_drift_celsius': 0.0, 'self_heating_celsius': 0.0,
                                  'motion_heating_celsius': 0.0}}
    write_month(tmp_path / 'flat', flat, range(3))
    status, lines = run_cli(capsys, 'fit', str(tmp_path / 'flat'), '-o', str(tmp_path / 'flat.yaml'))
    assert status == 0, lines
    assert any(line.startswith('temperature span') and 'their temperature terms held at 0' in line for line in lines)


def test_a_record_whose_temperatures_are_in_kelvin_is_said_in_one_line_and_not_pooled(capsys, tmp_path):
    """A bag of a pool whose temperatures are in kelvin contributes nothing: its line says so, as for one record."""
    raw = {**MONTH, 'everyday': {'records': 3, 'record_minutes': 6.0}}
    simulated = write_month(tmp_path / 'pool', raw, range(3))
    shutil.rmtree(tmp_path / 'pool' / 'rec02')
    record = simulated[2].record
    write_driver_record(tmp_path / 'pool' / 'rec02', replace(record, temperature=record.temperature + 273.15))
    status, lines = run_cli(capsys, 'fit', str(tmp_path / 'pool'), '-o', str(tmp_path / 'p.yaml'))
    assert status == 0, lines
    said = [line for line in lines if line.startswith('rec02: ')]
    assert len(said) == 1 and said[0].startswith('rec02: /imu/temperature: '), lines
    assert 'in kelvin, not degrees Celsius: convert them' in said[0] and said[0].endswith('contributes nothing')
    assert any(line.startswith('pool: 2 of 3 records') for line in lines), lines


@pytest.mark.parametrize('setting', ['first', 'second'])
def test_a_month_against_the_chamber_and_androids_line_short(setting):
    """Two seeds of a small month (8 records pooled, 3 held out): the pool's bias shape near the floor and the chamber.

    The long run (20 seeds of 16 records, both settings) is bench/bench_everyday.py. Here, on the
    setting the pool was built on and on the second one (a unit drawn apart, tilts up to 15 deg):
    the gyroscope's bias shape at the held-out rests within 1.2x the chamber calibration's and 2x
    the floor on every axis, over the seeds; Android's straight line above; |f| within 1.2x
    the chamber's or 2x the floor; the repeatability within 2 of its errors on most axes.
    """
    rows = [check_seed(seed, records=8, held_out=3, minutes=12.0, rate_hz=10.0, chamber_rate_hz=5.0,
                       setting=setting) for seed in (1, 2)]

    def shape(name: str) -> np.ndarray:
        return np.sqrt(np.mean([np.square(row['gyro_shape_rms'][name]) for row in rows], axis=0))

    assert np.all(shape('pool') <= 1.2 * shape('chamber')) and np.all(shape('pool') <= 2.0 * shape('truth'))
    # Android's line takes each power-up's offset for temperature (1.5x on the first setting's unit; the
    # second's turn-on spread is smaller beside the 10 Hz noise of these short records: above the pool only)
    assert np.mean(shape('android')) > (1.5 if setting == 'first' else 1.0) * np.mean(shape('pool'))
    gravity = {name: float(np.sqrt(np.mean([row['gravity_rms'][name] ** 2 for row in rows])))
               for name in ('pool', 'chamber', 'truth')}
    assert gravity['pool'] <= 1.2 * gravity['chamber'] or gravity['pool'] <= 2.0 * gravity['truth']
    assert sum(sum(row['covered']) for row in rows) >= 4


def test_fit_fleet_takes_a_directory_of_records_per_unit(month, capsys, tmp_path):
    """``fit-fleet UNIT_A/ UNIT_B/``: each unit's records pooled on the workers; each file as ``fit DIR`` writes it."""
    root, _ = month
    other = {**MONTH, 'seed': 5, 'everyday': {'records': 3, 'record_minutes': 6.0},
             'gyro_unit': {'x': {'offset': 0.0121}}}
    write_month(tmp_path / 'unitB', other, range(3))
    out = tmp_path / 'fleet'
    (tmp_path / 'unitlink').symlink_to(tmp_path / 'unitB')  # a unit given twice: named, counted once (issue 44)
    status = cli.main(['fit-fleet', str(root / 'pool'), str(tmp_path / 'unitB'), str(tmp_path / 'unitlink'), '-o',
                       str(out), '--workers', '1'])
    said = capsys.readouterr()
    assert status == 0, said
    from tak_thermo_ros.cli.common import unwrap
    assert (f'{tmp_path / "unitlink"}: the same unit as {tmp_path / "unitB"} (through a link): counted once'
            in unwrap(said.out)), said.out
    rows = {row['unit']: row for row in json.loads((out / 'fleet.json').read_text())['units']}
    assert len(rows) == 2 and {row['status'] for row in rows.values()} == {'ok'}
    assert load_unit(out / 'units' / 'unitB' / 'params.yaml').gyro.turn_on.records == 3
    (tmp_path / 'alone').mkdir()
    alone = tmp_path / 'alone' / 'params.yaml'
    assert run_cli(capsys, 'fit', str(tmp_path / 'unitB'), '-o', str(alone))[0] == 0
    assert (out / 'units' / 'unitB' / 'params.yaml').read_text() == alone.read_text()


def test_a_pool_fits_a_gyroscope_lag_through_its_motions(capsys, tmp_path):
    """``fit DIR --gyro-effects thermal_lag``: the lag's slopes from six everyday records, through the motions.

    Hidden: 300 s, 0.4 and -0.4 mrad/s per C on x and z. The effect follows the temperature
    recorded between the rests (the pool's temperature track), each record's offset apart.
    """
    lagged = {**MONTH, 'seed': 9, 'everyday': {'records': 6, 'record_minutes': 12.0},
              'gyro_effects': {'thermal_lag': {'tau_s': 300.0, 'slope_x': 0.0004, 'slope_z': -0.0004}}}
    write_month(tmp_path / 'pool', lagged, range(6))
    status, lines = run_cli(capsys, 'fit', str(tmp_path / 'pool'), '-o', str(tmp_path / 'p.yaml'),
                            '--gyro-effects', 'thermal_lag')
    assert status == 0, lines
    effect = load_unit(tmp_path / 'p.yaml').gyro.effects[0]
    assert effect.name == 'thermal_lag'
    assert effect['slope_x'] == pytest.approx(0.0004, rel=0.15)
    assert effect['slope_z'] == pytest.approx(-0.0004, rel=0.15)
    assert abs(effect['slope_y']) < 0.1 * 0.0004
    assert 150.0 < effect['tau_s'] < 450.0
