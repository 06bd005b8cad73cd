"""Property tests of ``tak_calib`` under generated bad input (Hypothesis).

Invariant, whatever the input: exit 0 with finite output (the written YAML, JSON and Imu bag
are parsed, no NaN or infinity anywhere, nor in what is printed), or exit 2 with exactly one
stderr line ``tak_calib: error: ...`` that is not an internal error; never a traceback; never a
temporary ``.partial`` left behind; a pre-existing output unchanged byte for byte unless
``--force`` was given.

The commands run in-process (``tak_thermo_ros.cli.main``) for speed, a few as subprocesses.
The example budget keeps all of them under a minute in ``make test``; ``make fuzz`` (the
``long`` Hypothesis profile of ``conftest.py``) runs 25 times more.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import re
import shutil
import stat
import subprocess
import sys
import tempfile
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import event, given, settings
from hypothesis.control import currently_in_test_context
from hypothesis import strategies as st

from bag_writer import write_with_header_stamps
from conftest import SHORT, examples
from tak_thermo_ros.formats.bag import read_imu, read_record, write_record
from tak_thermo_ros.cli import main
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.errors import TakError

TAK_CALIB = str(Path(sys.executable).with_name('tak_calib'))
SMALL = replace(SHORT, plateau_hours=0.03, ramp_celsius_per_minute=8.0, board_lag_s=60.0, dwell_s=10.0, seed=21)
"""A few hundred samples over the five plateaus: enough for a fit, fast to write and read."""
NON_FINITE_WORD = re.compile(r'(?<![a-z_])(nan|inf|infinity)(?![a-z_])', re.IGNORECASE)


def _run(argv: list[str]) -> tuple[int, str, str]:
    """``main(argv)`` in-process: exit status, stdout, stderr; a warning counts as stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), \
            warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        try:
            code = main(argv)
        except SystemExit as exit_info:  # argparse
            code = exit_info.code if isinstance(exit_info.code, int) else 2
    text = err.getvalue() + ''.join(f'{w.category.__name__}: {w.message}\n' for w in caught)
    return code, out.getvalue(), text


def _finite_tree(value: object) -> bool:
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, dict):
        return all(_finite_tree(v) for v in value.values())
    if isinstance(value, list):
        return all(_finite_tree(v) for v in value)
    return True


def check_outcome(code: int, out: str, err: str, directory: Path, protected: dict[Path, bytes],
                  outputs: dict[Path, str]) -> None:
    """The invariant (module docstring); ``outputs`` maps a written path to yaml/json/imu/bag."""
    if currently_in_test_context():
        event(f'exit {code}')
    assert 'Traceback' not in err and 'Traceback' not in out
    leftovers = [p.name for p in directory.rglob('*') if p.name.endswith(('.partial', '.old'))]
    assert leftovers == [], leftovers
    for path, content in protected.items():
        assert path.read_bytes() == content, f'{path} was changed'
    if code == 2:
        lines = err.strip().splitlines()
        assert len(lines) == 1, err
        assert lines[0].startswith('tak_calib: error: '), err
        assert 'internal error' not in lines[0], err
        return
    assert code == 0, (code, err)
    assert err == '', err
    assert not NON_FINITE_WORD.search(out), out
    for path, kind in outputs.items():
        if path in protected:
            continue
        if kind == 'yaml':
            assert _finite_tree(yaml.safe_load(path.read_text())), path.read_text()
        elif kind == 'json':
            def refuse(constant: str) -> float:
                raise AssertionError(f'{path}: {constant} in the JSON')
            json.loads(path.read_text(), parse_constant=refuse)
        elif kind == 'imu':
            _, acceleration, _, covariance = read_imu(path)
            assert np.all(np.isfinite(acceleration)) and np.all(np.isfinite(covariance))
        elif kind == 'bag':
            record = read_record(path, progress=False)
            for array in (record.counts, record.temp_code, record.reference):
                assert np.all(np.isfinite(array))
        elif kind == 'driver_bag':
            from tak_thermo_ros.formats.bag import iter_blocks
            from tak_thermo_ros.core.link.model import InputKind
            for block in iter_blocks(path, kind=InputKind.IMU, progress=False):
                for array in (block.accel, block.gyro, block.temperature, block.mag):
                    assert np.all(np.isfinite(array))


# ----- CSV logs ------------------------------------------------------------------------------

JUNK = st.sampled_from(['', 'nan', 'NaN', 'inf', '-inf', '1e400', '-1e400', 'abc', '0x10', '1,5', '"',
                        '1e999999999', '-0', '9' * 30, ' ', '1_000', '١٢'])
"""Field texts a log may hold by mistake."""


@st.composite
def csv_logs(draw) -> tuple[str, list[str]]:
    """A static thermal log (tab- or comma-delimited) with a few generated mistakes."""
    rows = draw(st.integers(2, 40))
    seconds = draw(st.sampled_from(['int', 'decimal', 'us']))
    start = draw(st.sampled_from([0, 1, 1_700_000_000, 2 ** 31 - 50]))
    delimiter = draw(st.sampled_from([',', '\t', ';']))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    table = []
    for i in range(rows):
        if seconds == 'us':
            time_text = str((start + i) * 1_000_000)
        elif seconds == 'decimal':
            time_text = f'{start + i * 0.25:.3f}'
        else:
            time_text = str(start + i)
        acc = np.array([0.2, -0.1, 9.8]) + rng.normal(0.0, 0.01, 3)
        temp = 20.0 + 20.0 * i / rows
        table.append([time_text, *(f'{v:.5f}' for v in acc), f'{temp:.3f}'])
    short: set[int] = set()
    blank: set[int] = set()
    for _ in range(draw(st.integers(0, 4))):
        row = draw(st.integers(0, rows - 1))
        kind = draw(st.sampled_from(['junk', 'big', 'duplicate_time', 'swap_rows', 'time', 'short_row',
                                     'blank_row', 'negative_time']))
        if kind == 'junk':
            table[row][draw(st.integers(0, 4))] = draw(JUNK)
        elif kind == 'big':
            table[row][draw(st.integers(1, 4))] = repr(draw(st.floats(allow_nan=True, allow_infinity=True)))
        elif kind == 'duplicate_time' and row > 0:
            table[row][0] = table[row - 1][0]
        elif kind == 'swap_rows' and row > 0:
            table[row], table[row - 1] = table[row - 1], table[row]
        elif kind == 'time':
            table[row][0] = draw(st.sampled_from(['2147483648', '1e19', '9223372036854775808', '1.5e9',
                                                  '4e9', '-1e-3', '1e-400']))
        elif kind == 'short_row':
            short.add(row)
        elif kind == 'blank_row':
            blank.add(row)
        elif kind == 'negative_time':
            table[row][0] = '-' + table[row][0]
    header = ['t', 'ax', 'ay', 'az', 'temp']
    if draw(st.booleans()) and draw(st.booleans()):
        header[draw(st.integers(0, 4))] = draw(st.sampled_from(['', 'x', 'ax ']))
    lines = ['' if i in blank else delimiter.join(r[:3] if i in short else r) for i, r in enumerate(table)]
    text = delimiter.join(header) + '\n' + ''.join(line + '\n' for line in lines)
    unit = 'us' if seconds == 'us' else 's'
    return text, ['--time-column', 't', '--time-unit', unit, '--acc-columns', 'ax', 'ay', 'az',
                  '--temp-column', 'temp']


@settings(max_examples=examples(60))
@given(log=csv_logs(), existing=st.booleans(), force=st.booleans(), storage=st.sampled_from(['mcap', 'sqlite3']))
def test_import_csv_of_generated_logs_keeps_the_invariant(log, existing, force, storage):
    """import-csv of a generated log: a finite bag with exit 0, or one line with exit 2."""
    text, options = log
    with tempfile.TemporaryDirectory() as name:
        directory = Path(name)
        (directory / 'log.csv').write_text(text, encoding='utf-8')
        out = directory / 'out'
        protected = {}
        if existing:
            out.write_bytes(b'precious')
            protected[out] = b'precious'
        argv = ['import-csv', str(directory / 'log.csv'), '-o', str(out), '--storage', storage, '--no-progress',
                *options, *(['--force'] if force else [])]
        code, stdout, stderr = _run(argv)
        check_outcome(code, stdout, stderr, directory, protected, {out: 'bag'})
        if existing:  # a regular file where a bag goes is refused even with --force
            assert code == 2


MAG_IN = {'T': 1.0, 'uT': 1e6, 'mT': 1e3, 'gauss': 1e4, 'mG': 1e7}
"""A field in tesla times this is the field in the unit."""


@st.composite
def driver_csv_logs(draw) -> tuple[str, list[str]]:
    """A driver's log: Imu columns, a temperature column or none (constant or not), magnetometer columns in a unit.

    The board held still or turned; the field's unit said right or wrong; generated mistakes in any column.
    """
    rows = draw(st.integers(2, 30))
    temperature = draw(st.sampled_from(['none', 'constant', 'sweep']))
    with_mag, with_gyro = draw(st.booleans()), draw(st.booleans()) or draw(st.booleans())
    unit = draw(st.sampled_from(sorted(MAG_IN)))
    logged_unit = unit if draw(st.booleans()) else draw(st.sampled_from(sorted(MAG_IN)))
    turned = draw(st.booleans())
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    header = ['t', 'ax', 'ay', 'az', 'gx', 'gy', 'gz'] + (['temp'] if temperature != 'none' else [])
    header += ['mx', 'my', 'mz'] if with_mag else []
    table = []
    for i in range(rows):
        turn = np.linalg.qr(rng.normal(size=(3, 3)))[0] if turned else np.eye(3)
        acc = turn.T @ np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.01, 3)
        row = [f'{i * 0.1:.2f}', *(f'{v:.5f}' for v in acc), *(f'{v:.5f}' for v in rng.normal(0.0, 1e-3, 3))]
        if temperature != 'none':
            row.append('25.0' if temperature == 'constant' else f'{20.0 + i:.2f}')
        if with_mag:
            field = turn.T @ np.array([20e-6, 2e-6, 44e-6]) * MAG_IN[logged_unit]
            row += [repr(float(v)) for v in field]
        table.append(row)
    for _ in range(draw(st.integers(0, 3))):
        row, column = draw(st.integers(0, rows - 1)), draw(st.integers(1, len(header) - 1))
        table[row][column] = draw(JUNK)
    text = ','.join(header) + '\n' + ''.join(','.join(r) + '\n' for r in table)
    options = ['--time-column', 't', '--acc-columns', 'ax', 'ay', 'az']
    options += ['--gyro-columns', 'gx', 'gy', 'gz'] if with_gyro else []
    options += ['--temp-column', 'temp'] if temperature != 'none' else []
    options += ['--mag-columns', 'mx', 'my', 'mz', '--mag-unit', unit] if with_mag else []
    return text, options


@settings(max_examples=examples(30))
@given(log=driver_csv_logs(), storage=st.sampled_from(['mcap', 'sqlite3']))
def test_import_csv_of_generated_driver_logs_and_their_fit_keep_the_invariant(log, storage):
    """A driver log without a temperature, with a constant one, with a magnetometer in any unit; then fit."""
    text, options = log
    with tempfile.TemporaryDirectory() as name:
        directory = Path(name)
        (directory / 'log.csv').write_text(text, encoding='utf-8')
        out = directory / 'out'
        code, stdout, stderr = _run(['import-csv', str(directory / 'log.csv'), '-o', str(out), '--storage', storage,
                                     '--no-progress', *options])
        written = 'driver_bag' if '--gyro-columns' in options else 'bag'  # without a gyroscope: the paper's codes
        check_outcome(code, stdout, stderr, directory, {}, {out: written})
        if code == 0:
            params = directory / 'p.yaml'
            code, stdout, stderr = _run(['fit', str(out), '-o', str(params), '--no-progress'])
            check_outcome(code, stdout, stderr, directory, {}, {params: 'yaml'})


@pytest.fixture(scope='module')
def turned_run(tmp_path_factory):
    """A small record turned by hand (a magnetometer, a warming unit) and the calibration fitted from it."""
    from tak_thermo_ros.core.simulation.magnetometer import MagnetometerTruth, rotation_record
    from tak_thermo_ros.formats.bag import write_driver_record
    record = rotation_record(MagnetometerTruth(), samples=400, seed=91, temperature_celsius=15.0,
                             warm_to_celsius=30.0)
    root = tmp_path_factory.mktemp('turned')
    write_driver_record(root / 'cal', record)
    code, _, err = _run(['fit', str(root / 'cal'), '-o', str(root / 'params.yaml'), '--no-progress'])
    assert code == 0, err
    return record, root / 'params.yaml'


@settings(max_examples=examples(12))
@given(data=st.data(), command=st.sampled_from(('fit', 'apply', 'validate')), drop_temperature=st.booleans())
def test_commands_on_changed_rotation_records_keep_the_invariant(turned_run, data, command, drop_temperature):
    """NaN, huge and gauss-sized fields, NaN and implausible temperatures, stamps back, no temperature topic."""
    from tak_thermo_ros.formats.bag import write_driver_record
    record, params = turned_run
    mag, temperature, stamps = record.mag.copy(), record.temperature.copy(), record.mag_stamp_ns.copy()
    for row, value in data.draw(st.lists(st.tuples(st.integers(0, len(mag) - 1),
                                                   st.sampled_from([math.nan, math.inf, 1e300, 0.5])), max_size=5)):
        mag[row] = value
    for row, value in data.draw(st.lists(st.tuples(st.integers(0, len(temperature) - 1),
                                                   st.sampled_from([math.nan, 1e9, -300.0])), max_size=4)):
        temperature[row] = value
    for row in data.draw(st.lists(st.integers(1, len(stamps) - 1), max_size=3)):
        stamps[row] = stamps[row - 1]
    changed = replace(record, mag=mag, mag_stamp_ns=stamps, temperature=temperature)
    if drop_temperature:
        changed = replace(changed, temp_stamp_ns=np.zeros(0, dtype=np.int64), temperature=np.zeros(0))
    with tempfile.TemporaryDirectory() as name:
        directory = Path(name)
        write_driver_record(directory / 'bag', changed)
        out = directory / 'out'
        argv = {'fit': ['fit', str(directory / 'bag'), '-o', str(out)],
                'apply': ['apply', str(directory / 'bag'), '--params', str(params), '-o', str(out)],
                'validate': ['validate', str(directory / 'bag'), '--params', str(params), '--json', str(out)]}[command]
        code, stdout, stderr = _run([*argv, '--no-progress'])
        kinds = {'fit': 'yaml', 'apply': 'driver_bag', 'validate': 'json'}
        check_outcome(code, stdout, stderr, directory, {}, {} if command == 'apply' else {out: kinds[command]})


# ----- bags ----------------------------------------------------------------------------------

@pytest.fixture(scope='module')
def small_run(tmp_path_factory):
    """A small calibration run and the calibration fitted from it."""
    root = tmp_path_factory.mktemp('properties')
    run = simulate(SMALL)
    write_record(root / 'cal', run.record)
    code, _, err = _run(['fit', str(root / 'cal'), '-o', str(root / 'params.yaml'), '--no-progress'])
    assert code == 0, err
    return run, root / 'params.yaml'


@st.composite
def record_changes(draw, length: int, temp_length: int, reference_length: int) -> dict:
    """Changes to a run: temperature codes and references NaN/inf/huge, counts NaN/huge, header stamps back."""
    indices = st.integers(0, length - 1)
    return {
        'temp': draw(st.lists(st.tuples(st.integers(0, temp_length - 1),
                                        st.sampled_from([math.nan, math.inf, -math.inf, 1e9, -1e9, 1e300, 0.0,
                                                         9.99e6])), max_size=6)),
        'counts': draw(st.lists(st.tuples(indices, st.integers(0, 2),
                                          st.sampled_from([math.nan, math.inf, 1e12, -32768.0, 0.5])),
                                max_size=4)),
        'stamps': draw(st.lists(st.tuples(indices, st.sampled_from(['duplicate', 'back', 'far_back', 'forward'])),
                                max_size=4)),
        'reference': draw(st.lists(st.tuples(st.integers(0, reference_length - 1), st.integers(0, 2),
                                             st.sampled_from([math.nan, -math.inf, 1e300, 1999.0, 0.0])),
                                   max_size=3)),
    }


def _changed_record(record, changes: dict):
    temp_code = record.temp_code.copy()
    for row, value in changes['temp']:
        temp_code[row] = value
    counts = record.counts.copy()
    for row, axis, value in changes['counts']:
        counts[row, axis] = value
    reference = record.reference.copy()
    for row, axis, value in changes['reference']:
        reference[row, axis] = value
    headers = record.counts_stamp_ns.copy()
    for row, how in changes['stamps']:
        if row == 0:
            continue
        headers[row] = {'duplicate': headers[row - 1], 'back': headers[row - 1] - 10 ** 9,
                        'far_back': 10 ** 9, 'forward': headers[row] + 10 ** 12}[how]
    return replace(record, temp_code=temp_code, counts=counts, reference=reference), headers


COMMANDS = ('fit', 'apply', 'validate', 'diagnose')


def _command(command: str, bag: Path, params: Path, out: Path, force: bool) -> tuple[list[str], dict[Path, str]]:
    common = ['--no-progress', *(['--force'] if force else [])]
    if command == 'fit':
        return ['fit', str(bag), '-o', str(out), *common], {out: 'yaml'}
    if command == 'apply':
        return ['apply', str(bag), '--params', str(params), '-o', str(out), *common], {out: 'imu'}
    if command == 'validate':
        return ['validate', str(bag), '--params', str(params), '--json', str(out), *common], {out: 'json'}
    return (['diagnose', str(bag), '--params', str(params), '--json', str(out), '--candidates', 'warmup',
             '--folds', '2', *common], {out: 'json'})


def _prepare_output(out: Path, command: str, existing: bool) -> dict[Path, bytes]:
    """An existing output of the right kind when asked; what must stay unchanged without --force."""
    if not existing:
        return {}
    if command == 'apply':
        out.mkdir()
        (out / 'metadata.yaml').write_bytes(b'precious')
        return {out / 'metadata.yaml': b'precious'}
    out.write_bytes(b'precious')
    return {out: b'precious'}


@settings(max_examples=examples(14))
@given(data=st.data(), command=st.sampled_from(COMMANDS), storage=st.sampled_from(['mcap', 'sqlite3']),
       existing=st.booleans(), force=st.booleans())
def test_commands_on_changed_runs_keep_the_invariant(small_run, data, command, storage, existing, force):
    """`NaN` and huge temperature codes, bad counts, header stamps back (bag time increasing)."""
    run, params = small_run
    changes = data.draw(record_changes(len(run.record.counts), len(run.record.temp_code),
                                       len(run.record.reference)))
    record, headers = _changed_record(run.record, changes)
    with tempfile.TemporaryDirectory() as name:
        directory = Path(name)
        write_with_header_stamps(directory / 'bag', record, headers, storage=storage)
        out = directory / 'out'
        protected = _prepare_output(out, command, existing)
        if force:
            protected = {}
        argv, outputs = _command(command, directory / 'bag', params, out, force)
        code, stdout, stderr = _run(argv)
        check_outcome(code, stdout, stderr, directory, protected, outputs)
        if existing and not force:
            assert code == 2


def _storage_file(bag: Path) -> Path:
    return next(p for p in bag.iterdir() if p.suffix in ('.mcap', '.db3'))


@settings(max_examples=examples(14))
@given(command=st.sampled_from(COMMANDS), storage=st.sampled_from(['mcap', 'sqlite3']),
       damage=st.sampled_from(['truncate', 'flip']), fraction=st.floats(0.0, 1.0),
       flips=st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 7)), min_size=1, max_size=12))
def test_commands_on_damaged_bag_files_keep_the_invariant(small_run, tmp_path_factory, command, storage, damage,
                                                          fraction, flips):
    """A truncated or bit-flipped storage file (mcap or sqlite3)."""
    run, params = small_run
    with tempfile.TemporaryDirectory() as name:
        directory = Path(name)
        bag = directory / 'bag'
        cache = _pristine(tmp_path_factory, run, storage)
        shutil.copytree(cache, bag)
        storage_file = _storage_file(bag)
        data = bytearray(storage_file.read_bytes())
        if damage == 'truncate':
            del data[int(fraction * len(data)):]
        else:
            for where, bit in flips:
                position = min(int(where * len(data)), len(data) - 1)
                data[position] ^= 1 << bit
        storage_file.write_bytes(bytes(data))
        out = directory / 'out'
        argv, outputs = _command(command, bag, params, out, False)
        code, stdout, stderr = _run(argv)
        check_outcome(code, stdout, stderr, directory, {}, outputs)


_PRISTINE: dict[str, Path] = {}


def _pristine(tmp_path_factory, run, storage: str) -> Path:
    """The undamaged bag of the small run in ``storage``, written once."""
    if storage not in _PRISTINE:
        path = tmp_path_factory.mktemp(f'pristine_{storage}') / 'bag'
        write_record(path, run.record, storage=storage)
        _PRISTINE[storage] = path
    return _PRISTINE[storage]


# ----- a few real processes ------------------------------------------------------------------

@pytest.mark.parametrize('argv', [
    ['validate', '{bag}', '--params', '{params}', '--gravity', 'nan'],
    ['fit', '{bag}', '-o', '/dev/null', '--force'],
    ['apply', '{bag}', '--params', '{params}', '-o', '{out}', '--storage', 'sqlite3'],
])
def test_subprocess_runs_keep_the_invariant(small_run, tmp_path, argv):
    """The same invariant through the console script: status, stderr and files as a user sees them."""
    run, params = small_run
    codes = run.record.temp_code.copy()
    codes[::7] = np.nan
    write_record(tmp_path / 'bag', replace(run.record, temp_code=codes))
    out = tmp_path / 'out'
    command = [a.format(bag=tmp_path / 'bag', params=params, out=out) for a in argv]
    result = subprocess.run([TAK_CALIB, *command], capture_output=True, text=True, timeout=120)
    check_outcome(result.returncode, result.stdout, result.stderr, tmp_path, {}, {out: 'imu'})
    assert Path('/dev/null').is_char_device()
    if command[0] == 'apply':
        assert result.returncode == 0 and 'ignored' in result.stdout and 'non-finite temperature codes' in result.stdout


# ----- options: every one checked before any input is read, any output opened or any work done --

class _BatchStarted(TakError):
    """Raised by the stand-in of fit-fleet's Dask batch: everything before it was checked and passed."""


def _batch_started(*args, **kwargs):
    raise _BatchStarted('the batch started')


def _typed_options() -> list[tuple[str, argparse.Action]]:
    """Every option of every command that converts its text (``type=``)."""
    from tak_thermo_ros.cli import build_parser
    commands = next(action for action in build_parser()._actions if action.dest == 'command')
    return [(name, action) for name, sub in commands.choices.items() for action in sub._actions
            if action.option_strings and action.type is not None]


def test_no_option_takes_a_bare_int_or_float():
    """A bare ``type=int`` / ``float`` takes nan, inf, 0 and -1: every numeric option is bounded in cli/options.py."""
    bare = [(name, action.option_strings[-1]) for name, action in _typed_options() if action.type in (int, float)]
    assert bare == []


NUMERIC_OPTIONS = sorted((name, action.option_strings[-1]) for name, action in _typed_options()
                         if getattr(action.type, '__name__', '') in ('number', 'whole number'))
"""(command, option) of every numeric option (its type is one of cli/options.py's bounded parsers)."""
OPTION_TEXTS = st.one_of(
    st.sampled_from(['nan', 'NaN', 'inf', '-inf', 'infinity', '1e400', '-1e400', '-1', '-0', '0', '1', '2', '3', '5',
                     '100', '101', '255', '256', '1000', '9.7', '9.80665', '9.9', '98', '-9.8', '1e-3', '-1e-3', '0.5',
                     '1e9', '1e7', '9999999', '90', '-90.5', '', 'x', '1_0', '0x10', ' 4', '4 ', '٣']),
    st.floats().map(repr), st.integers(-10 ** 20, 10 ** 20).map(str))


def _minimal_argv(command: str, missing: Path, out: Path) -> list[str]:
    """``command`` with inputs that do not exist and outputs in a directory that does not exist (fit-fleet: ``out``)."""
    return {
        'simulate': ['simulate', f'{missing}/out'],
        'fit': ['fit', f'{missing}/bag', '-o', f'{missing}/p.yaml'],
        'apply': ['apply', f'{missing}/bag', '--params', f'{missing}/p.yaml', '-o', f'{missing}/o'],
        'validate': ['validate', f'{missing}/bag', '--params', f'{missing}/p.yaml'],
        'import-csv': ['import-csv', f'{missing}/log.csv', '-o', f'{missing}/o', '--acc-columns', 'a', 'b', 'c',
                       '--temp-column', 't'],
        'diagnose': ['diagnose', f'{missing}/bag', '--params', f'{missing}/p.yaml'],
        'noise': ['noise', f'{missing}/bag'],
        'export': ['export', f'{missing}/p.yaml', '--format', 'px4', '-o', f'{missing}/o.params'],
        'play': ['play', f'{missing}/bag'],
        'fit-fleet': ['fit-fleet', f'{missing}/bag', '-o', str(out)],
        'carrier-simulate': ['carrier-simulate', '-o', f'{missing}/r.csv'],
        'carrier-fit': ['carrier-fit', f'{missing}/r.csv', '--no-gauge'],
        'carrier-budget': ['carrier-budget', '--json', f'{missing}/b.json'],
    }[command]


def _error_lines(stderr: str) -> list[str]:
    """The lines of stderr, but fit-fleet's progress line before its batch (``fit-fleet: N units on ...``)."""
    return [line for line in stderr.strip().splitlines() if not re.match(r'fit-fleet: \d+ units on ', line)]


def _parses(action: argparse.Action, text: str) -> bool:
    try:
        action.type(text)
    except argparse.ArgumentTypeError:
        return False
    return True


@settings(max_examples=examples(80))
@given(option=st.sampled_from(NUMERIC_OPTIONS), text=OPTION_TEXTS)
def test_a_numeric_option_is_refused_in_one_line_before_any_input_is_read(option, text):
    """Every numeric option of every command, any text: refused in one line naming it, or taken.

    Taken, the command goes on to its first input or output, which does not exist: one line naming
    that path, so that no option is checked after an input was read or an output opened. Nothing
    is written either way (fit-fleet: its batch is never reached with a refused option).
    """
    from unittest import mock
    command, name = option
    action = dict((a.option_strings[-1], a) for c, a in _typed_options() if c == command)[name]
    count = {None: 1, '+': 1}.get(action.nargs, action.nargs)
    if count != 1 and text.startswith('-') and not re.fullmatch(r'-\d+|-\d*\.\d+', text):
        return  # argparse reads '-1e-3' after an option of several values as an option of its own
    with tempfile.TemporaryDirectory() as name_dir:
        directory = Path(name_dir)
        missing, out = directory / 'missing', directory / 'out'
        words = [f'{name}={text}'] if count == 1 else [name, *[text] * count]
        with mock.patch('tak_thermo_ros.passes.fleet.run_batch', _batch_started):
            code, stdout, stderr = _run([*_minimal_argv(command, missing, out), *words])
        assert code == 2 and 'Traceback' not in stderr
        lines = _error_lines(stderr)
        assert len(lines) == 1 and lines[0].startswith('tak_calib: error: '), stderr
        assert 'internal error' not in lines[0]
        if not _parses(action, text):
            assert f'argument {name}' in lines[0], lines[0]
            assert sorted(p.name for p in directory.iterdir()) == []
        elif command == 'fit-fleet':
            assert lines[0].endswith('the batch started'), lines[0]
            assert [p.name for p in directory.iterdir()] == ['out'] and list(out.iterdir()) == []
        else:
            assert str(missing) in lines[0] and 'argument' not in lines[0], lines[0]
            assert sorted(p.name for p in directory.iterdir()) == []


FLEET_TEXTS = {
    '--workers': st.sampled_from([None, '1', '2', '0', '-1', '257', 'nan', 'two', '1.5']),
    '--flag-sigma': st.sampled_from([None, '5', '0.1', '1e6', '0', '-3', 'nan', 'inf', '-inf', '']),
    '--folds': st.sampled_from([None, '2', '5', '100', '0', '1', '101', 'nan']),
    '--gravity': st.sampled_from([None, '9.81', '9.7', '9.9', 'nan', 'inf', '0', '-1', '-9.81', '98.1']),
    '--candidates': st.sampled_from([None, 'warmup', 'library', 'warmup,thermal_lag', 'aux:/power/battery_state',
                                     'bogus', 'warmup,bogus', 'nomodule_here:Effect', ':', '']),
    '--settle-time': st.sampled_from([None, '0', '4', '-1', 'nan']),
    '--bias-order': st.sampled_from([None, '0', '4', '9', '-1']),
    '--effects': st.sampled_from([None, 'warmup', 'bogus']),
}


@settings(max_examples=examples(40))
@given(data=st.data())
def test_fit_fleet_options_are_checked_before_its_cluster_starts(data):
    """fit-fleet's own options and those it takes over from fit and diagnose, generated.

    A refused one: exit 2, one line naming it, nothing made (not even OUT_DIR); all taken: the
    batch is reached (a stand-in that stops there), OUT_DIR made and empty.
    """
    from unittest import mock
    chosen = {option: data.draw(texts, label=option) for option, texts in FLEET_TEXTS.items()}
    with tempfile.TemporaryDirectory() as name:
        directory = Path(name)
        (directory / 'cal').mkdir()
        out = directory / 'out'
        argv = ['fit-fleet', str(directory / 'cal'), '-o', str(out)]
        argv += [f'{option}={text}' for option, text in chosen.items() if text is not None]
        with mock.patch('tak_thermo_ros.passes.fleet.run_batch', _batch_started):
            code, stdout, stderr = _run(argv)
        lines = _error_lines(stderr)
        assert code == 2 and len(lines) == 1 and lines[0].startswith('tak_calib: error: '), stderr
        actions = {a.option_strings[-1]: a for c, a in _typed_options() if c == 'fit-fleet'}
        refused = [option for option, text in chosen.items() if text is not None and not _parses(actions[option], text)]
        if refused:
            assert 'argument --' in lines[0] and any(f'argument {option}' in lines[0] for option in refused), lines[0]
            assert not out.exists()
        else:
            assert lines[0].endswith('the batch started'), lines[0]
            assert list(out.iterdir()) == []


def _snapshot(directory: Path) -> dict[str, tuple]:
    """Every entry under ``directory`` (links not followed): its type and its content or target."""
    entries = {}
    for path in sorted(directory.rglob('*')):
        mode = os.lstat(path).st_mode
        if stat.S_ISLNK(mode):
            entries[str(path.relative_to(directory))] = ('link', os.readlink(path))
        elif stat.S_ISREG(mode):
            entries[str(path.relative_to(directory))] = ('file', path.read_bytes())
        else:
            entries[str(path.relative_to(directory))] = (stat.S_IFMT(mode),)
    return entries


def _make(path: Path, kind: str, elsewhere: Path) -> None:
    if kind == 'file':
        path.write_bytes(b'precious')
    elif kind == 'dir':
        path.mkdir()
    elif kind == 'fifo':
        os.mkfifo(path)
    elif kind == 'link_to_dir':
        path.symlink_to(elsewhere, target_is_directory=True)
    elif kind == 'link':
        path.symlink_to(elsewhere / 'victim.txt')


@settings(max_examples=examples(40))
@given(out_dir=st.sampled_from(['absent', 'dir', 'link_to_dir', 'file', 'fifo']),
       units=st.sampled_from(['dir', 'link_to_dir']),
       fleet_json=st.sampled_from(['absent', 'file', 'link', 'fifo']),
       unit_file=st.sampled_from(['absent', 'file', 'link', 'fifo']),
       unit_name=st.sampled_from(['params.yaml', 'diagnose.json', 'validation.json', 'log.txt']),
       validating=st.booleans(), force=st.booleans())
def test_fit_fleet_applies_the_overwrite_rule_to_every_output_before_it_starts(
        out_dir, units, fleet_json, unit_file, unit_name, validating, force):
    """OUT_DIR, fleet.json, units/<unit>/ and each unit's files in any state, with or without --force.

    A link (to a folder elsewhere too), a FIFO or a file where a directory goes, or an existing
    output without --force: refused in one line before anything is touched; else the batch is
    reached with everything as it was. Never a file replaced, deleted or written through.
    """
    from unittest import mock
    with tempfile.TemporaryDirectory() as name:
        root = Path(name)
        elsewhere = root / 'elsewhere'
        elsewhere.mkdir()
        (elsewhere / 'victim.txt').write_bytes(b'keep')
        (root / 'cal').mkdir()
        out = root / 'out'
        _make(out, out_dir, elsewhere)
        if out_dir == 'dir':
            _make(out / 'fleet.json', fleet_json, elsewhere)
            _make(out / 'units', units, elsewhere)
            if units == 'dir':
                (out / 'units' / 'cal').mkdir()
                _make(out / 'units' / 'cal' / unit_name, unit_file, elsewhere)
        before = _snapshot(root)
        argv = ['fit-fleet', str(root / 'cal'), '-o', str(out), *(['--validate', str(root / 'cal')] if validating
                                                                  else []), *(['--force'] if force else [])]
        with mock.patch('tak_thermo_ros.passes.fleet.run_batch', _batch_started):
            code, stdout, stderr = _run(argv)
        lines = _error_lines(stderr)
        assert code == 2 and len(lines) == 1 and lines[0].startswith('tak_calib: error: '), stderr
        special = out_dir in ('link_to_dir', 'file', 'fifo') or (out_dir == 'dir' and (
            fleet_json in ('link', 'fifo') or units == 'link_to_dir'
            or (unit_file in ('link', 'fifo') and (unit_name != 'validation.json' or validating))))
        existing = out_dir == 'dir' and (fleet_json == 'file' or (
            units == 'dir' and unit_file == 'file' and (unit_name != 'validation.json' or validating)))
        if special or (existing and not force):
            assert 'refusing' in lines[0] or 'exists already' in lines[0], lines[0]
            assert _snapshot(root) == before
        else:
            assert lines[0].endswith('the batch started'), lines[0]
            after = _snapshot(root)
            assert {key: value for key, value in after.items() if key != 'out'} == {
                key: value for key, value in before.items() if key != 'out'}
