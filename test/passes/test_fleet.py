"""tak_calib fit-fleet: a simulated batch on a local Dask cluster and on a separately started one.

The batch: five units of the default design with a production spread of their coefficients,
one of them with an x offset far outside that spread (a hidden defect), and a corrupt bag.
Short runs (0.5 Hz, 12-minute plateaus) keep each unit at about a second of fitting.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import SHORT
from node_helpers import start_process
from tak_thermo_ros.formats.bag import write_record
from tak_thermo_ros.cli import main
from tak_thermo_ros.core.diagnose.fleet import (
    MAD_TO_SIGMA,
    MIN_UNITS_FOR_SPREAD,
    Spread,
    calibration_metrics,
    flag_units,
    majority_verdict,
    robust_spread,
)
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.truth import DEFAULT_UNIT
from tak_thermo_ros.passes.fleet import unit_names

BIN = Path(sys.executable).parent
TAK_CALIB = [sys.executable, '-m', 'tak_thermo_ros.cli']
BATCH = replace(SHORT, plateau_hours=0.2, sample_rate_hz=0.5)
"""The paper's five plateaus, 12 minutes each: about 1.75 h at 0.5 Hz (3150 samples)."""
VALIDATION = replace(BATCH, plateaus_celsius=(12.0, 30.0), plateau_hours=0.15)
OFFSET_SPREAD = 3.0
"""Unit-to-unit standard deviation of the offsets in the simulated batch, counts."""
DEFECT_OFFSET = 150.0
"""How far the defective unit's x offset lies from the design value: 50 x the batch spread."""
DEFECT = 'unit3'
FIT_OPTIONS = ['--bias-order', '4', '--settle-time', '4']
"""Non-default fit options: the fleet must hand them to every unit's fit."""


def _unit(rng: np.random.Generator, defect: bool):
    axes = []
    for axis in DEFAULT_UNIT:
        axes.append(replace(axis, scale=axis.scale + rng.normal(0.0, 0.3),
                            offset=axis.offset + rng.normal(0.0, OFFSET_SPREAD),
                            offset_coeffs=tuple(c * (1.0 + rng.normal(0.0, 0.05)) for c in axis.offset_coeffs)))
    if defect:
        axes[0] = replace(axes[0], offset=DEFAULT_UNIT[0].offset + DEFECT_OFFSET)
    return tuple(axes)


@pytest.fixture(scope='module')
def batch(tmp_path_factory):
    """Five calibration bags, a validation bag for each, and a corrupt (truncated) sixth bag."""
    root = tmp_path_factory.mktemp('fleet')
    (root / 'bags').mkdir()
    (root / 'validation').mkdir()
    rng = np.random.default_rng(2026)
    bags, checks = [], []
    for index in range(5):
        name = f'unit{index}'
        unit = _unit(rng, defect=name == DEFECT)
        write_record(root / 'bags' / name, simulate(replace(BATCH, unit=unit, seed=index)).record)
        write_record(root / 'validation' / name, simulate(replace(VALIDATION, unit=unit, seed=100 + index)).record)
        bags.append(root / 'bags' / name)
        checks.append(root / 'validation' / name)
    broken = root / 'bags' / 'broken'
    write_record(broken, simulate(replace(BATCH, seed=99)).record)
    data = broken / 'broken.mcap'
    data.write_bytes(data.read_bytes()[:len(data.read_bytes()) // 2])
    bags.append(broken)
    checks.append(checks[0])
    return root, bags, checks


@pytest.fixture(scope='module')
def local_run(batch):
    """``tak_calib fit-fleet`` on the default local cluster, as a user runs it."""
    root, bags, checks = batch
    out = root / 'out_local'
    result = subprocess.run([*TAK_CALIB, 'fit-fleet', *map(str, bags), '-o', str(out), '--validate',
                             *map(str, checks), *FIT_OPTIONS], capture_output=True, text=True, timeout=600)
    return out, result


def test_every_unit_gets_the_file_tak_calib_fit_writes_for_its_bag_alone(batch, local_run, tmp_path):
    """Byte-identical params.yaml (hence equal numbers) to ``tak_calib fit BAG`` on the same bag."""
    _, bags, _ = batch
    out, result = local_run
    assert result.returncode == 0, result.stderr
    for bag in bags[:-1]:
        alone = tmp_path / bag.name / 'params.yaml'
        alone.parent.mkdir()
        assert main(['fit', str(bag), '-o', str(alone), *FIT_OPTIONS, '--no-progress']) == 0
        fleet = out / 'units' / bag.name / 'params.yaml'
        assert fleet.read_text() == alone.read_text()
        assert yaml.safe_load(fleet.read_text()) == yaml.safe_load(alone.read_text())
        assert 'bias order 4' in fleet.read_text()


def test_the_defective_unit_is_flagged_for_its_x_offset(local_run):
    """Only the unit with the hidden offset defect is flagged for x.offset, by far more than k sigmas."""
    out, _ = local_run
    document = json.loads((out / 'fleet.json').read_text())
    rows = {row['unit']: row for row in document['units']}
    flagged_offset = {unit for unit, row in rows.items() for flag in row['flags'] if flag['metric'] == 'x.offset'}
    assert flagged_offset == {DEFECT}
    flag = next(flag for flag in rows[DEFECT]['flags'] if flag['metric'] == 'x.offset')
    spread = document['spread']['x.offset']
    # The spread is the production spread of the four good units (about OFFSET_SPREAD); the defect
    # lies DEFECT_OFFSET above the design value.
    assert 0.3 * OFFSET_SPREAD < spread['robust_sigma'] < 3.0 * OFFSET_SPREAD
    assert flag['robust_sigmas'] > DEFECT_OFFSET / (3.0 * OFFSET_SPREAD)
    assert 'x.offset' in flag['reason'] and 'robust sigmas' in flag['reason']
    assert rows[DEFECT]['coefficients']['x']['offset'] - spread['median'] > 0.8 * DEFECT_OFFSET
    assert rows[DEFECT]['flagged']
    html_page = (out / 'fleet.html').read_text()
    assert f'<b>{DEFECT}</b>: x.offset' in html_page


def test_a_corrupt_bag_fails_alone_and_the_batch_goes_on(batch, local_run):
    """The truncated bag is one failed row with its one-line error; the five others are calibrated."""
    _, bags, _ = batch
    out, result = local_run
    document = json.loads((out / 'fleet.json').read_text())
    assert (document['units_total'], document['units_ok'], document['units_failed']) == (6, 5, 1)
    broken = next(row for row in document['units'] if row['unit'] == 'broken')
    assert broken['status'] == 'failed'
    assert broken['error'].startswith(f'fit: {bags[-1]}')
    assert '\n' not in broken['error']
    assert broken['coefficients'] is None and broken['flags'] == []
    assert not (out / 'units' / 'broken' / 'params.yaml').exists()
    assert 'exit status 2' in (out / 'units' / 'broken' / 'log.txt').read_text()
    assert 'broken: failed: fit:' in result.stdout
    assert '5 of 6 units calibrated, 1 failed' in result.stdout


def test_rows_hold_what_each_unit_wrote(local_run):
    """Each row's verdict, residuals and |g| error are those of the unit's own files."""
    out, result = local_run
    document = json.loads((out / 'fleet.json').read_text())
    for row in document['units']:
        if row['status'] != 'ok':
            continue
        directory = out / 'units' / row['unit']
        diagnosis = json.loads((directory / 'diagnose.json').read_text())
        validation = json.loads((directory / 'validation.json').read_text())
        params = yaml.safe_load((directory / 'params.yaml').read_text())['/**/compensator']['ros__parameters']
        assert row['verdict'] == diagnosis['verdict']
        assert row['validation_rms'] == validation['after']['rms']
        assert row['validation_rms'] < row['validation_rms_before']
        for axis in 'xyz':
            assert row['residual_rms'][axis] == params['calibration'][axis]['residual_rms']
            assert row['coefficients'][axis]['scale'] == params['calibration'][axis]['scale']
        assert 'OPENBLAS_NUM_THREADS=1' in (directory / 'log.txt').read_text()
        assert row['files']['params'] == f'units/{row["unit"]}/params.yaml'
    # One progress line per finished unit on stderr: unit, status, seconds.
    progress = [line for line in result.stderr.splitlines() if line.startswith('[')]
    assert len(progress) == 6
    assert sorted(line.split()[1] for line in progress) == sorted(row['unit'] for row in document['units'])
    assert all(line.split()[2] in ('ok', 'failed') and line.split()[4].startswith('s') for line in progress)


def test_fleet_html_is_self_contained(local_run):
    """Figures are embedded; nothing is fetched from elsewhere."""
    out, _ = local_run
    page = (out / 'fleet.html').read_text()
    assert page.count('data:image/png;base64,') >= 3
    assert 'src="http' not in page and '<link' not in page


def test_an_existing_fleet_json_is_refused_without_force(batch, local_run, capsys):
    """No silent overwrite: one-line error, exit 2, the finished batch untouched."""
    _, bags, _ = batch
    out, _ = local_run
    before = (out / 'fleet.json').read_bytes()
    assert main(['fit-fleet', str(bags[0]), '-o', str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith('tak_calib: error: ') and 'fleet.json: exists' in err and '--force' in err
    assert err.count('\n') == 1
    assert (out / 'fleet.json').read_bytes() == before


def test_validation_bags_must_pair_with_the_bags(batch, tmp_path, capsys):
    """One validation bag per unit, else a one-line error before any work."""
    _, bags, checks = batch
    assert main(['fit-fleet', *map(str, bags[:3]), '-o', str(tmp_path / 'out'),
                 '--validate', *map(str, checks[:2])]) == 2
    assert '--validate: 2 validation bags for 3 calibration bags' in capsys.readouterr().err
    assert not (tmp_path / 'out').exists()


def test_a_unit_whose_validation_run_lasts_9_minutes_is_calibrated(batch, tmp_path):
    """A validation run shorter than 600 s (validate --json): its 600-s figure null (not defined), the unit calibrated.

    Before, the NaN of that figure made validate refuse its JSON, and the unit failed. No library
    warning reaches stderr (only the fleet's own progress lines).
    """
    _, bags, _ = batch
    short = tmp_path / 'short'
    run = simulate(replace(BATCH, plateaus_celsius=(20.0,), plateau_hours=0.15, seed=55))
    assert (run.record.counts_stamp_ns[-1] - run.record.counts_stamp_ns[0]) / 1e9 < 600.0
    write_record(short, run.record)
    out = tmp_path / 'out'
    result = subprocess.run([*TAK_CALIB, 'fit-fleet', str(bags[0]), '-o', str(out), '--validate', str(short),
                             '--workers', '1', *FIT_OPTIONS], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    row = json.loads((out / 'fleet.json').read_text())['units'][0]
    assert row['status'] == 'ok' and math.isfinite(row['validation_rms']), row['error']
    taus = json.loads((out / 'units' / 'unit0' / 'validation.json').read_text())['averaged_bias_error']['taus']
    assert taus['600']['windows'] == 0 and taus['600']['rms'] is None
    assert taus['60']['windows'] > 0 and all(math.isfinite(v) for v in taus['60']['rms'])
    assert all(line.startswith(('fit-fleet: ', '[1/1] ')) for line in result.stderr.splitlines()), result.stderr


@pytest.mark.parametrize('where', ['output_link', 'fleet_json_link', 'params_fifo', 'log_link', 'units_link'])
def test_what_the_fleet_did_not_write_is_refused_before_any_unit_runs(batch, tmp_path, capsys, where):
    """A link (-o to a folder elsewhere too) or a FIFO among the outputs: one line, --force or not, nothing touched."""
    _, bags, _ = batch
    elsewhere = tmp_path / 'elsewhere'
    elsewhere.mkdir()
    (elsewhere / 'victim.txt').write_text('keep')
    out = tmp_path / 'out'
    unit = out / 'units' / 'unit0'
    if where == 'output_link':
        out.symlink_to(elsewhere, target_is_directory=True)
        special = out
    elif where == 'units_link':
        out.mkdir()
        (out / 'units').symlink_to(elsewhere, target_is_directory=True)
        special = out / 'units'
    else:
        unit.mkdir(parents=True)
        special = {'fleet_json_link': out / 'fleet.json', 'params_fifo': unit / 'params.yaml',
                   'log_link': unit / 'log.txt'}[where]
        if where == 'params_fifo':
            os.mkfifo(special)
        else:
            special.symlink_to(elsewhere / 'victim.txt')
    before = os.lstat(special)
    for force in ([], ['--force']):
        assert main(['fit-fleet', str(bags[0]), '-o', str(out), *force]) == 2
        err = capsys.readouterr().err
        assert err.count('\n') == 1 and err.startswith(f'tak_calib: error: {special}') and 'refusing' in err, err
    after = os.lstat(special)
    assert (after.st_mode, after.st_ino) == (before.st_mode, before.st_ino)
    assert [p.name for p in elsewhere.iterdir()] == ['victim.txt'] and (elsewhere / 'victim.txt').read_text() == 'keep'
    if where in ('fleet_json_link', 'params_fifo', 'log_link'):  # no unit ran: its directory as it was
        assert [p.name for p in unit.iterdir()] == ([] if where == 'fleet_json_link' else [special.name])


def test_every_fit_option_is_a_fleet_option():
    """The fit options are taken over from fit itself, none lost to a name clash."""
    from tak_thermo_ros.cli import build_parser
    commands = next(action for action in build_parser()._actions if action.dest == 'command')
    fit, fleet = commands.choices['fit'], commands.choices['fit-fleet']
    fleet_options = {option for action in fleet._actions for option in action.option_strings}
    fit_options = {option for action in fit._actions for option in action.option_strings}
    assert fit_options - fleet_options == {'--no-progress'}


def _kill_group(process: subprocess.Popen) -> None:
    try:
        os.killpg(process.pid, signal.SIGTERM)
        process.wait(timeout=20)
    except ProcessLookupError:
        return
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=20)


@pytest.fixture
def dask_cluster(tmp_path):
    """A Dask scheduler and one worker process started as separate commands, on 127.0.0.1."""
    scheduler_file = tmp_path / 'scheduler.json'
    logs = (tmp_path / 'scheduler.log').open('w'), (tmp_path / 'worker.log').open('w')
    scheduler = start_process([str(BIN / 'dask'), 'scheduler', '--host', '127.0.0.1', '--port', '0',
                               '--no-dashboard', '--scheduler-file', str(scheduler_file)],
                              stdout=logs[0], stderr=subprocess.STDOUT)
    processes = [scheduler]
    try:
        deadline = time.monotonic() + 60.0
        while not scheduler_file.exists() or not scheduler_file.read_text().strip():
            assert scheduler.poll() is None, (tmp_path / 'scheduler.log').read_text()
            assert time.monotonic() < deadline, 'the scheduler wrote no scheduler file'
            time.sleep(0.2)
        address = json.loads(scheduler_file.read_text())['address']
        assert address.startswith('tcp://127.0.0.1:')
        worker = start_process([str(BIN / 'dask'), 'worker', address, '--nworkers', '1', '--nthreads', '1',
                                '--host', '127.0.0.1', '--no-dashboard'],
                               stdout=logs[1], stderr=subprocess.STDOUT)
        processes.append(worker)
        from dask.distributed import Client
        with Client(address, timeout='30s') as client:
            client.wait_for_workers(1, timeout=60)
        yield address, worker
    finally:
        for process in reversed(processes):
            _kill_group(process)
        for log in logs:
            log.close()


def test_a_separately_started_scheduler_runs_the_units(batch, local_run, dask_cluster, tmp_path, capsys):
    """``--scheduler ADDRESS``: the external worker fits the units, to the same files as the local cluster."""
    _, bags, checks = batch
    address, worker = dask_cluster
    out = tmp_path / 'out'
    status = main(['fit-fleet', str(bags[3]), str(bags[-1]), '-o', str(out), '--scheduler', address,
                   '--validate', str(checks[3]), str(checks[0]), *FIT_OPTIONS])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    document = json.loads((out / 'fleet.json').read_text())
    assert [row['status'] for row in document['units']] == ['ok', 'failed']
    for row in document['units'][:1]:
        pid = int(row['worker'].rsplit(':', 1)[1])
        assert os.getpgid(pid) == worker.pid  # run by the worker started above (its process group)
        local = local_run[0] / 'units' / row['unit'] / 'params.yaml'
        assert (out / 'units' / row['unit'] / 'params.yaml').read_text() == local.read_text()
    assert len(document['units']) < MIN_UNITS_FOR_SPREAD and document['units_flagged'] == 0

    # --force replaces the finished batch; a batch in which every unit fails exits 2.
    status = main(['fit-fleet', str(bags[-1]), '-o', str(out), '--scheduler', address, '--force'])
    captured = capsys.readouterr()
    assert status == 2
    assert captured.err.strip().splitlines()[-1].startswith('tak_calib: error: all 1 units failed')
    document = json.loads((out / 'fleet.json').read_text())
    assert (document['units_total'], document['units_ok']) == (1, 0)


# ------------------------------------------------------------------------------ pure statistics

def test_robust_spread_of_known_values():
    """Median and 1.4826 x MAD, non-finite values left out."""
    spread = robust_spread([1.0, 2.0, 3.0, 4.0, 100.0, math.nan])
    assert spread.median == 3.0
    assert spread.sigma == pytest.approx(MAD_TO_SIGMA * 1.0)
    assert spread.units == 5
    assert Spread(median=1.0, sigma=0.0, units=5).sigmas(2.0) == math.inf


def test_robust_sigma_estimates_the_standard_deviation():
    """For many normal values, 1.4826 x MAD is their standard deviation (to its sampling error)."""
    values = np.random.default_rng(1).normal(10.0, 2.0, size=20000)
    spread = robust_spread(values.tolist())
    # Standard error of the MAD-based sigma: about 1.65 sigma / sqrt(n) = 0.023 here.
    assert spread.sigma == pytest.approx(2.0, abs=0.1)
    assert spread.median == pytest.approx(10.0, abs=0.05)


def test_flags_name_the_metric_and_the_sigmas():
    """The one unit off in one metric is flagged for that metric alone, with its signed sigmas."""
    table = {f'u{i}': {'x.offset': v, 'x.scale': 255.0 + 0.1 * i} for i, v in enumerate([1.0, 2.0, 3.0, 4.0, 5.0])}
    table['u5'] = {'x.offset': 40.0, 'x.scale': 255.2}
    flags = flag_units(table, k=5.0)
    assert [f.metric for f in flags['u5']] == ['x.offset']
    expected = (40.0 - 3.5) / (MAD_TO_SIGMA * 1.5)
    assert flags['u5'][0].sigmas == pytest.approx(expected)
    assert all(not flags[f'u{i}'] for i in range(5))
    assert flag_units(table, k=expected + 0.01)['u5'] == []


def test_no_spread_flags_below_the_minimum_batch():
    """Too few units to estimate a spread: nothing is flagged for the metrics."""
    table = {f'u{i}': {'x.offset': float(i ** 3)} for i in range(MIN_UNITS_FOR_SPREAD - 1)}
    assert all(not f for f in flag_units(table, k=0.1).values())


def test_a_value_off_a_shared_exact_value_is_flagged_without_sigmas():
    """More than half the units share a value exactly (sigma 0): another value is flagged."""
    table = {f'u{i}': {'x.scale_shape[1]': 0.0} for i in range(5)}
    table['u5'] = {'x.scale_shape[1]': 1e-6}
    flags = flag_units(table)
    assert [f.metric for f in flags['u5']] == ['x.scale_shape[1]']
    assert flags['u5'][0].as_dict()['robust_sigmas'] is None
    assert 'no spread' in flags['u5'][0].reason


def test_verdicts_against_the_majority():
    """A verdict other than the one more than half of the units share is flagged; no majority, no flag."""
    verdicts = {'a': 'none', 'b': 'none', 'c': 'thermal_lag', 'd': None}
    assert majority_verdict(verdicts) == 'none'
    flags = flag_units({}, verdicts)
    assert [f.metric for f in flags['c']] == ['verdict'] and not flags['a'] and not flags['d']
    assert majority_verdict({'a': 'none', 'b': 'hysteresis'}) is None
    assert all(not f for f in flag_units({}, {'a': 'none', 'b': 'hysteresis'}).values())


def test_calibration_metrics_name_every_coefficient():
    """Axes' coefficients by power, residual RMS, effect parameters."""
    calibration = {'x': {'scale': 255.0, 'offset': -1.0, 'offset_span': 3.0, 'offset_shape': [0.1, 0.2],
                         'scale_shape': [0.0], 'residual_rms': 1.5},
                   'effects': {'thermal_lag': {'tau_s': 900.0, 'slope_x': 0.1}, 'mine': {'class': 'm:C', 'a_x': 2.0}}}
    metrics = calibration_metrics(calibration)
    assert metrics == {'x.scale': 255.0, 'x.offset': -1.0, 'x.offset_span': 3.0, 'x.residual_rms': 1.5,
                       'x.offset_shape[1]': 0.1, 'x.offset_shape[2]': 0.2, 'x.scale_shape[1]': 0.0,
                       'effects.thermal_lag.tau_s': 900.0, 'effects.thermal_lag.slope_x': 0.1,
                       'effects.mine.a_x': 2.0}


def test_unit_names_stay_distinct():
    """A bag's name, with parents prepended while names clash."""
    assert unit_names(['/a/unit1', '/a/unit2']) == ['unit1', 'unit2']
    assert unit_names(['/line/u7/calib', '/line/u8/calib', '/x/other']) == ['u7_calib', 'u8_calib', 'other']
    assert unit_names(['/a/b c']) == ['b_c']


_values = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)


@settings(max_examples=60, deadline=None)
@given(columns=st.lists(st.lists(_values, min_size=2, max_size=2), min_size=1, max_size=12),
       verdicts=st.lists(st.sampled_from(['none', 'thermal_lag', 'unexplained']), min_size=12, max_size=12),
       order=st.randoms(use_true_random=False), k=st.floats(min_value=0.5, max_value=10.0))
def test_flags_do_not_depend_on_the_order_of_the_units(columns, verdicts, order, k):
    """Shuffling the units changes no unit's flags."""
    table = {f'u{i}': {'a': row[0], 'b': row[1]} for i, row in enumerate(columns)}
    given_verdicts = {unit: verdicts[i] for i, unit in enumerate(table)}
    units = list(table)
    order.shuffle(units)
    shuffled = {unit: table[unit] for unit in units}
    shuffled_verdicts = {unit: given_verdicts[unit] for unit in units}
    assert flag_units(table, given_verdicts, k=k) == flag_units(shuffled, shuffled_verdicts, k=k)


@settings(max_examples=60, deadline=None)
@given(values=st.lists(_values, min_size=1, max_size=15), k=st.floats(min_value=0.5, max_value=10.0),
       more=st.floats(min_value=0.0, max_value=10.0))
def test_a_larger_threshold_never_adds_flags(values, k, more):
    """Raising k can only remove flags."""
    table = {f'u{i}': {'a': v} for i, v in enumerate(values)}
    strict, loose = flag_units(table, k=k), flag_units(table, k=k + more)
    assert all({f.metric for f in loose[unit]} <= {f.metric for f in strict[unit]} for unit in table)
