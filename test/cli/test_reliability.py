"""Bad input of every class gives one line and exit 2, or a counted rule.

Never a traceback, a NaN written with exit 0, a replaced special file or a temporary left behind.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import sqlite3
import stat
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from bag_writer import write_with_header_stamps
from conftest import CREEP_MODULE, SHORT
from node_helpers import start_process
from tak_thermo_ros.formats.bag import writer as bag_writer
from tak_thermo_ros.formats.bag import read_imu, read_record, write_record
from tak_thermo_ros.cli import main
from tak_thermo_ros.formats.calibration_file import save_calibration
from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.records.plausible import MAX_STAMP_NS
from tak_thermo_ros.formats.csv_log.options import CsvImportOptions
from tak_thermo_ros.formats.csv_log.reader import parse_csv_log
from tak_thermo_ros.formats.files import write_text_atomic
from tak_thermo_ros.core.records.drops import TEMP_CODE_LIMIT
from tak_thermo_ros.core.records.record import ChannelRecord, align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.errors import BagError, LogError, OutputError

TAK_CALIB = str(Path(sys.executable).with_name('tak_calib'))
TINY = replace(SHORT, plateau_hours=0.05, ramp_celsius_per_minute=5.0, board_lag_s=60.0, dwell_s=10.0)
"""About 1,400 samples at 1 Hz over the five plateaus: enough to fit, quick to write."""


def _one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith('tak_calib: error: ') and 'Traceback' not in err and 'internal error' not in err
    return lines[0]


def _leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.endswith(('.partial', '.old')))


@pytest.fixture(scope='module')
def tiny(tmp_path_factory):
    """A tiny calibration bag, its simulated run and the fitted file."""
    root = tmp_path_factory.mktemp('reliability')
    run = simulate(replace(TINY, seed=4))
    write_record(root / 'cal', run.record)
    assert main(['fit', str(root / 'cal'), '-o', str(root / 'params.yaml'), '--no-progress']) == 0
    return root, run


# ----- option bounds -------------------------------------------------------------------------

@pytest.mark.parametrize(('argv', 'option'), [
    (['validate', 'B', '--params', 'P', '--gravity', '-9.8'], '--gravity'),
    (['validate', 'B', '--params', 'P', '--gravity', 'nan'], '--gravity'),
    (['validate', 'B', '--params', 'P', '--gravity', '0'], '--gravity'),
    (['diagnose', 'B', '--params', 'P', '--gravity', 'inf'], '--gravity'),
    (['import-csv', 'L', '-o', 'O', '--acc-columns', 'a', 'b', 'c', '--temp-column', 't', '--gravity', '98'],
     '--gravity'),
    (['fit', 'B', '-o', 'P', '--settle-time', '-1'], '--settle-time'),
    (['fit', 'B', '-o', 'P', '--settle-time', 'nan'], '--settle-time'),
    (['diagnose', 'B', '--params', 'P', '--settle-time', 'inf'], '--settle-time'),
    (['fit', 'B', '-o', 'P', '--temp-code-ref', 'nan'], '--temp-code-ref'),
    (['fit', 'B', '-o', 'P', '--temp-code-ref', '1e9'], '--temp-code-ref'),
    (['fit', 'B', '-o', 'P', '--bias-order', '9'], '--bias-order'),
    (['fit', 'B', '-o', 'P', '--scale-order', '-1'], '--scale-order'),
    (['fit', 'B', '-o', 'P', '--nominal-scale', '0'], '--nominal-scale'),
    (['simulate', 'O', '--seed', '-1'], '--seed'),
    (['diagnose', 'B', '--params', 'P', '--folds', '1'], '--folds'),
    (['import-csv', 'L', '-o', 'O', '--acc-columns', 'a', 'b', 'c', '--temp-column', 't', '--acc-resolution', '0'],
     '--acc-resolution'),
    (['import-csv', 'L', '-o', 'O', '--acc-columns', 'a', 'b', 'c', '--temp-column', 't', '--temp-resolution',
      'nan'], '--temp-resolution'),
    (['import-csv', 'L', '-o', 'O', '--acc-columns', 'a', 'b', 'c', '--temp-column', 't', '--reference', '0', '0',
      'inf'], '--reference'),
    (['fit', 'B', '-o', 'P', '--nominal-scale', '1000', '2000'], '--nominal-scale'),
    (['fit', 'B', '-o', 'P', '--effects', 'warmup,bogus'], '--effects'),
    (['diagnose', 'B', '--params', 'P', '--candidates', 'library,nomodule_here:Effect'], '--candidates'),
    (['fit-fleet', 'B', '-o', 'O', '--flag-sigma', 'inf'], '--flag-sigma'),
    (['fit-fleet', 'B', '-o', 'O', '--gravity', 'nan'], '--gravity'),
    (['fit-fleet', 'B', '-o', 'O', '--gravity', '0'], '--gravity'),
    (['fit-fleet', 'B', '-o', 'O', '--folds', '1'], '--folds'),
    (['fit-fleet', 'B', '-o', 'O', '--workers', '0'], '--workers'),
    (['fit-fleet', 'B', '-o', 'O', '--candidates', 'bogus'], '--candidates'),
    (['fit-fleet', 'B', '-o', 'O', '--nominal-scale', '1', '2'], '--nominal-scale'),
])
def test_out_of_range_options_are_refused_in_one_line(argv, option, capsys):
    """Every numeric option is bounded where it is parsed: one line naming the option, exit 2."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f'argument {option}' in line


# ----- outputs: regular files only, one overwrite rule ---------------------------------------

def _commands(root: Path, out: Path) -> dict[str, list[str]]:
    cal, params = str(root / 'cal'), str(root / 'params.yaml')
    return {
        'fit': ['fit', cal, '-o', str(out), '--no-progress'],
        'validate': ['validate', cal, '--params', params, '--json', str(out), '--no-progress'],
        'diagnose-json': ['diagnose', cal, '--params', params, '--json', str(out), '--candidates', 'warmup',
                          '--folds', '2', '--no-progress'],
        'apply': ['apply', cal, '--params', params, '-o', str(out), '--no-progress'],
        'simulate': ['simulate', str(out)],
    }


@pytest.mark.parametrize('command', ['fit', 'validate', 'diagnose-json', 'apply', 'simulate'])
@pytest.mark.parametrize('kind', ['fifo', 'symlink', 'directory', 'device'])
def test_special_files_are_never_replaced(tiny, tmp_path, command, kind, capsys):
    """A FIFO, a symbolic link.

    A non-output directory or a device node at an output path is refused in one line naming it, with or without
    --force, and stays what it was.
    """
    root, _ = tiny
    target = tmp_path / 'victim.txt'
    target.write_text('keep')
    out = tmp_path / 'out'
    if kind == 'fifo':
        os.mkfifo(out)
    elif kind == 'symlink':
        out.symlink_to(target)
    elif kind == 'directory':
        out.mkdir()
        (out / 'precious.txt').write_text('keep')
    else:
        os.mknod(out, 0o600 | stat.S_IFCHR, os.makedev(1, 3))  # the device numbers of /dev/null
    before = os.lstat(out)
    for force in ([], ['--force']):
        assert main(_commands(root, out)[command] + force) == 2
        line = _one_error_line(capsys.readouterr().err)
        assert str(out) in line and 'refusing' in line
    after = os.lstat(out)
    assert stat.S_IFMT(after.st_mode) == stat.S_IFMT(before.st_mode) and after.st_ino == before.st_ino
    assert target.read_text() == 'keep' and _leftovers(tmp_path) == []
    if kind == 'directory':
        assert [p.name for p in out.iterdir()] == ['precious.txt']


@pytest.mark.parametrize('command', ['fit', 'validate', 'diagnose-json', 'apply', 'simulate'])
def test_an_existing_output_is_refused_unless_force(tiny, tmp_path, command, capsys):
    """The overwrite rule, the same for every command.

    Refused naming the path and --force; with --force the output is replaced, and nothing temporary stays.
    """
    root, _ = tiny
    out = tmp_path / 'out'
    argv = _commands(root, out)[command]
    assert main(argv) == 0
    capsys.readouterr()
    marker = out / 'metadata.yaml' if out.is_dir() else out
    first = marker.read_bytes()
    os.utime(marker, ns=(0, 0))
    assert main(argv) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert str(out) in line and 'exists already' in line and '--force' in line
    assert marker.read_bytes() == first and os.stat(marker).st_mtime_ns == 0
    assert main([*argv, '--force']) == 0
    assert os.stat(marker).st_mtime_ns != 0 and _leftovers(tmp_path) == []


def test_report_directory_is_written_whole_and_replaced_only_with_force(tiny, tmp_path, capsys):
    """--report writes into a temporary directory renamed into place.

    An existing report is replaced only with --force; a directory holding anything else is never replaced.
    """
    root, _ = tiny
    report = tmp_path / 'report'
    argv = ['diagnose', str(root / 'cal'), '--params', str(root / 'params.yaml'), '--report', str(report),
            '--candidates', 'warmup', '--folds', '2', '--no-progress']
    assert main(argv) == 0
    assert f'wrote {report / "report.html"}' in capsys.readouterr().out
    assert (report / 'report.html').is_file() and _leftovers(tmp_path) == []
    assert main(argv) == 2 and 'exists already' in _one_error_line(capsys.readouterr().err)
    assert main([*argv, '--force']) == 0 and (report / 'report.html').is_file()
    (report / 'notes.txt').write_text('mine')
    assert main([*argv, '--force']) == 2
    assert 'refusing' in _one_error_line(capsys.readouterr().err) and (report / 'notes.txt').read_text() == 'mine'
    assert _leftovers(tmp_path) == []


def test_write_text_atomic_refuses_a_fifo_and_names_the_users_path(tmp_path, monkeypatch):
    """The text writer never replaces a special file; a failed write names the user's path."""
    fifo = tmp_path / 'pipe'
    os.mkfifo(fifo)
    with pytest.raises(OutputError, match='FIFO'):
        write_text_atomic(fifo, 'x')
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)

    def full_disk(handle, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    path = tmp_path / 'out.json'
    monkeypatch.setattr(os, 'fsync', lambda fd: full_disk(fd, b''))
    with pytest.raises(OSError) as err:
        write_text_atomic(path, 'x')
    assert err.value.filename == str(path) and err.value.errno == errno.ENOSPC
    assert list(tmp_path.iterdir()) == [fifo]


@pytest.mark.parametrize(('storage', 'failure'), [
    ('mcap', OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))),
    ('sqlite3', sqlite3.OperationalError('database or disk is full')),
])
def test_a_full_disk_during_a_bag_write_is_one_line_and_leaves_nothing(tmp_path, monkeypatch, capsys, storage,
                                                                       failure):
    """The storage failing half way.

    (simulated: the writer raises what a full disk raises) gives one line naming the user's bag, exit 2, and no
    temporary directory.
    """
    real_write = bag_writer.Writer.write
    written = []

    def failing_write(self, connection, timestamp, data):
        written.append(timestamp)
        if len(written) > 100:
            raise failure
        return real_write(self, connection, timestamp, data)

    monkeypatch.setattr(bag_writer.Writer, 'write', failing_write)
    scenario = tmp_path / 'tiny.yaml'
    scenario.write_text(yaml.safe_dump({'plateau_hours': 0.05, 'ramp_celsius_per_minute': 5.0}))
    out = tmp_path / 'bag'
    assert main(['simulate', str(out), '--scenario', str(scenario), '--storage', storage]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert line.startswith(f'tak_calib: error: {out}: cannot write bag (') and '.partial' not in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ['tiny.yaml']


@pytest.mark.parametrize(('signum', 'status', 'word'), [
    (signal.SIGTERM, 143, 'terminated'), (signal.SIGINT, 130, 'interrupted')])
def test_a_signal_during_a_bag_write_leaves_nothing(tmp_path, signum, status, word):
    """SIGTERM is handled like SIGINT: the partial bag is removed, one line, exit 143 (130)."""
    scenario = tmp_path / 'long.yaml'
    scenario.write_text(yaml.safe_dump({'plateau_hours': 3.0, 'sample_rate_hz': 20.0}))
    out = tmp_path / 'bag'
    # The test process ignores SIGINT while it starts the command, as a shell running `make test` in the
    # background does: start_process sets it back to the default in the child (an ignored SIGINT is
    # inherited, and the command would finish with exit 0).
    ignored = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        process = start_process([TAK_CALIB, 'simulate', str(out), '--scenario', str(scenario)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    finally:
        signal.signal(signal.SIGINT, ignored)
    deadline = time.monotonic() + 120.0
    while not any(p.name.endswith('.partial') for p in tmp_path.iterdir()):
        assert process.poll() is None and time.monotonic() < deadline, 'the bag write never started'
        time.sleep(0.02)
    time.sleep(0.2)
    process.send_signal(signum)
    _, err = process.communicate(timeout=60)
    assert process.returncode == status
    assert err.strip() == f'tak_calib: {word}'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['long.yaml']


# ----- temperature codes and stamps in a bag -------------------------------------------------

def test_non_finite_and_implausible_temperature_codes_are_not_held(tiny, tmp_path, capsys):
    """A NaN, infinite or implausible temperature code is ignored.

    (the previous good one is held, as in the node) and counted; apply writes finite Imu, validate prints finite RMS.
    """
    root, run = tiny
    codes = run.record.temp_code.copy()
    codes[[20, 40]] = np.nan
    codes[60] = np.inf
    codes[80] = -1e9
    record = replace(run.record, temp_code=codes)
    samples = align(record)
    assert samples.ignored_temp_codes == {'non_finite': 3, 'implausible': 1}
    clean = align(replace(run.record, temp_code=np.where(np.isin(np.arange(len(codes)), [20, 40, 60, 80]),
                                                         -TEMP_CODE_LIMIT * 2, codes)))
    assert np.all(np.isfinite(samples.temp_code)) and np.array_equal(samples.temp_code, clean.temp_code)
    bad_index = np.searchsorted(record.counts_stamp_ns, record.temp_stamp_ns[20])
    assert samples.temp_code[bad_index] == codes[19]  # the last good code before it, held

    write_record(tmp_path / 'bad', record)
    params = str(root / 'params.yaml')
    assert main(['apply', str(tmp_path / 'bad'), '--params', params, '-o', str(tmp_path / 'imu'), '--no-progress']) == 0
    out = capsys.readouterr().out
    assert 'ignored 3 non-finite temperature codes' in out and 'ignored 1 implausible' in out
    _, acceleration, _, _ = read_imu(tmp_path / 'imu')
    assert len(acceleration) == len(samples) and np.all(np.isfinite(acceleration))
    assert main(['validate', str(tmp_path / 'bad'), '--params', params, '--json', str(tmp_path / 'v.json'),
                 '--no-progress']) == 0
    out = capsys.readouterr().out
    assert 'nan' not in out.lower() and 'ignored 3 non-finite temperature codes' in out
    figures = json.loads((tmp_path / 'v.json').read_text())
    assert np.isfinite(figures['after']['rms']) and figures['after']['rms'] < 0.05
    assert main(['fit', str(tmp_path / 'bad'), '-o', str(tmp_path / 'p.yaml'), '--no-progress']) == 0
    assert 'ignored 3 non-finite temperature codes' in capsys.readouterr().out
    assert main(['diagnose', str(tmp_path / 'bad'), '--params', params, '--candidates', 'warmup', '--folds', '2',
                 '--no-progress']) == 0
    assert 'verdict:' in capsys.readouterr().out


def test_non_finite_and_implausible_references_are_not_held(tiny, tmp_path, capsys):
    """A reference message that is NaN, infinite or beyond 2000 m/s^2 is ignored like a bad temperature code.

    The previous one stays held; fit prints the count and fits the truth.
    """
    root, run = tiny
    reference = run.record.reference.copy()
    reference[5, 0] = np.nan
    reference[9, 2] = np.inf
    reference[12, 1] = 1e300
    record = replace(run.record, reference=reference)
    samples = align(record)
    assert samples.ignored_references == {'non_finite': 2, 'implausible': 1}
    assert np.all(np.isfinite(samples.reference)) and np.all(np.abs(samples.reference) < 20.0)
    stamps = record.reference_stamp_ns
    between = (samples.stamp_ns >= stamps[5]) & (samples.stamp_ns < stamps[6])
    assert between.any() and np.all(samples.reference[between] == reference[4])  # the last good one, held
    write_record(tmp_path / 'bad', record)
    assert main(['fit', str(tmp_path / 'bad'), '-o', str(tmp_path / 'p.yaml'), '--no-progress']) == 0
    out = capsys.readouterr().out
    assert 'ignored 2 non-finite reference messages' in out and 'ignored 1 implausible' in out


def test_counts_stamps_going_backwards_are_dropped_and_counted(tiny):
    """A counts sample stamped no later than the previous counts message (bag order) is left out.

    ``time_backwards`` or ``duplicate_stamp``; the kept samples keep their own codes.
    """
    _, run = tiny
    stamps = run.record.counts_stamp_ns.copy()
    stamps[100] = stamps[99]                 # duplicate
    stamps[200] = stamps[150]                # one stamp jumps back
    stamps[300:303] = stamps[300:303] - 5 * 10 ** 9  # a short stretch 5 s back
    samples = align(replace(run.record, counts_stamp_ns=stamps))
    reference = align(run.record)
    assert samples.dropped == {**reference.dropped, 'duplicate_stamp': 1, 'time_backwards': 2}
    # 301 and 302 follow 300 forwards: kept, with their own codes.
    removed = np.searchsorted(reference.stamp_ns, run.record.counts_stamp_ns[[100, 200, 300]])
    assert np.array_equal(samples.counts, np.delete(reference.counts, removed, axis=0))


def test_apply_prints_the_stamp_drops(tiny, tmp_path, capsys):
    """Header stamps that jump back inside a bag whose bag time increases.

    Apply drops them and names the count with the other drops.
    """
    root, run = tiny
    stamps = run.record.counts_stamp_ns.copy()
    stamps[50] = stamps[40]
    write_with_header_stamps(tmp_path / 'back', run.record, stamps)
    assert np.array_equal(read_record(tmp_path / 'back', progress=False).counts_stamp_ns, stamps)
    assert main(['apply', str(tmp_path / 'back'), '--params', str(root / 'params.yaml'), '-o',
                 str(tmp_path / 'imu'), '--no-progress']) == 0
    assert '1 time backwards' in capsys.readouterr().out
    stamps_out, _, _, _ = read_imu(tmp_path / 'imu')
    assert len(stamps_out) == len(stamps) - 1


def test_no_usable_temperature_code_is_one_line(tiny, tmp_path, capsys):
    """A bag whose temperature codes are all NaN leaves nothing to fit: one line, exit 2."""
    _, run = tiny
    record = replace(run.record, temp_code=np.full(len(run.record.temp_code), np.nan))
    write_record(tmp_path / 'nan', record)
    assert main(['fit', str(tmp_path / 'nan'), '-o', str(tmp_path / 'p.yaml'), '--no-progress']) == 2
    _one_error_line(capsys.readouterr().err)
    assert not (tmp_path / 'p.yaml').exists()


# ----- user effects --------------------------------------------------------------------------

BAD_EFFECTS = CREEP_MODULE + '''

class Raises(Creep):
    name = 'raises'

    def step(self, state, stamp_s, temp_code):
        return state, (1.0 / 0.0,)


class StartRaises(Creep):
    name = 'start_raises'

    def start(self, stamp_s, temp_code):
        raise RuntimeError('no clock')


class ReturnsNan(Creep):
    name = 'returns_nan'

    def step(self, state, stamp_s, temp_code):
        return state, (float('nan'),)


class WrongLength(Creep):
    name = 'wrong_length'

    def step(self, state, stamp_s, temp_code):
        return state, (1.0, 2.0)


class BasisWrongShape(Creep):
    name = 'basis_wrong_shape'

    def basis(self, stamp_s, temp_code):
        import numpy
        return numpy.zeros(3)


class SpaceRaises(Creep):
    name = 'space_raises'
    shape = (__import__('tak_thermo_ros.core.effects', fromlist=['ParameterSpec']).ParameterSpec(
        'tau_s', 100.0, 1.0, 1e4, 's'),)

    @classmethod
    def search_space(cls, time_s, temp_code):
        raise KeyError('tau_s')
'''


@pytest.mark.parametrize(('cls', 'message'), [
    ('Raises', 'effect raises: step() raised ZeroDivisionError: float division by zero'),
    ('StartRaises', 'effect start_raises: start() raised RuntimeError: no clock'),
    ('ReturnsNan', 'effect returns_nan: basis() returned non-finite values'),
    ('WrongLength', 'effect wrong_length: step() returned basis values of the wrong length'),
    ('BasisWrongShape', 'effect basis_wrong_shape: basis() returned shape (3,)'),
    ('SpaceRaises', "effect space_raises: search_space() raised KeyError: 'tau_s'"),
])
def test_a_failing_user_effect_is_one_line_naming_effect_and_method(tiny, tmp_path, monkeypatch, capsys, cls,
                                                                    message):
    """`fit` with a user effect that raises or returns NaN or a wrong shape.

    One line naming the effect and the method, no traceback, no file; --debug shows the traceback.
    """
    root, _ = tiny
    (tmp_path / 'bad_effects.py').write_text(BAD_EFFECTS)
    monkeypatch.syspath_prepend(str(tmp_path))
    argv = ['fit', str(root / 'cal'), '-o', str(tmp_path / 'p.yaml'), '--effects', f'bad_effects:{cls}',
            '--no-progress']
    assert main(argv) == 2
    assert message in _one_error_line(capsys.readouterr().err)
    assert not (tmp_path / 'p.yaml').exists()
    assert main(['--debug', *argv]) == 2
    err = capsys.readouterr().err
    assert 'Traceback' in err and err.strip().splitlines()[-1].startswith('tak_calib: error: effect ')


def test_a_user_effect_failing_at_correction_time_is_one_line(tiny, tmp_path, monkeypatch, capsys):
    """`apply` with a calibration whose user effect raises in step(): one line, no bag."""
    root, run = tiny
    (tmp_path / 'bad_effects.py').write_text(BAD_EFFECTS)
    monkeypatch.syspath_prepend(str(tmp_path))
    from bad_effects import Raises
    calibration = replace(run.truth, effects=(Raises(),))
    save_calibration(tmp_path / 'p.yaml', calibration)
    assert main(['apply', str(root / 'cal'), '--params', str(tmp_path / 'p.yaml'), '-o', str(tmp_path / 'imu'),
                 '--no-progress']) == 2
    assert 'effect raises: step() raised ZeroDivisionError' in _one_error_line(capsys.readouterr().err)
    assert not (tmp_path / 'imu').exists() and _leftovers(tmp_path) == []
    link = Corrector(calibration)
    with pytest.raises(Exception, match=r'effect raises: step\(\) raised ZeroDivisionError'):
        link.correct_sample(0.0, 0.0, 255.0, 8000.0, stamp_s=1.0)


# ----- CSV -----------------------------------------------------------------------------------

CSV_OPTIONS = CsvImportOptions(acc_columns=('ax', 'ay', 'az'), temp_column='temp', time_column='t')


def _csv(times: list[str]) -> list[str]:
    rows = [f'{t},{0.1 + 0.01 * i:.3f},{0.2 - 0.01 * i:.3f},{9.8 + 0.001 * i:.3f},{20 + i}'
            for i, t in enumerate(times)]
    return ['t,ax,ay,az,temp', *rows]


@pytest.mark.parametrize(('time', 'problem'), [
    ('-1', 'before 1970'),
    ('2147483648', 'after 2038'),
    ('1e999999999', 'after 2038'),
    ('9' * 40, 'after 2038'),
    ('-1e-999999', 'is not a number'),
])
def test_a_stamp_that_does_not_fit_a_bag_names_line_and_column(time, problem):
    """A stamp outside builtin_interfaces/Time (negative, past 2038, a huge exponent) in a middle row.

    One line naming the line and the column; never an overflow.
    """
    times = ['1', '2', time, '4']
    if problem == 'is not a number':
        with pytest.raises(LogError):
            parse_csv_log(_csv(times), CSV_OPTIONS, source='log.csv')
        return
    with pytest.raises(LogError, match=rf"log.csv: row 3 \(line 4\), column 't': .*{problem}"):
        parse_csv_log(_csv(times), CSV_OPTIONS, source='log.csv')


def test_the_last_representable_stamp_is_accepted():
    """The bound is the bag's, not tighter: 2**31 - 1 s (and fractions up to it) import."""
    log = parse_csv_log(_csv(['2147483646', '2147483647.999999999']), CSV_OPTIONS)
    assert log.record.counts_stamp_ns[-1] == MAX_STAMP_NS


def test_a_temperature_code_beyond_any_sensor_code_names_row_and_column():
    """A temperature resolution so fine that the codes leave +-1e7.

    Refused at the import, not written as codes that every command would ignore.
    """
    options = replace(CSV_OPTIONS, temp_resolution=1e-6)
    message = r"log.csv: row 1 \(line 2\), column 'temp': 20 C is a temperature code of 2e\+07"
    with pytest.raises(LogError, match=message):
        parse_csv_log(_csv(['1', '2', '3']), options, source='log.csv')


def test_csv_rows_are_converted_in_chunks(monkeypatch):
    """Chunk boundaries change nothing: the same arrays with chunks of 3 rows as with one chunk."""
    from tak_thermo_ros.formats.csv_log import table
    lines = _csv([str(i) for i in range(10)])
    whole = parse_csv_log(lines, CSV_OPTIONS)
    monkeypatch.setattr(table, 'CHUNK_ROWS', 3)
    chunked = parse_csv_log(lines, CSV_OPTIONS)
    assert np.array_equal(whole.record.counts, chunked.record.counts)
    assert np.array_equal(whole.record.counts_stamp_ns, chunked.record.counts_stamp_ns)
    assert np.array_equal(whole.temperature, chunked.temperature)


def test_csv_import_onto_dev_null_is_refused(tmp_path, capsys):
    """import-csv -o /dev/null: refused in one line, /dev/null untouched."""
    log = tmp_path / 'log.csv'
    log.write_text('\n'.join(_csv(['1', '2', '3'])) + '\n')
    before = os.lstat('/dev/null')
    argv = ['import-csv', str(log), '-o', '/dev/null', '--time-column', 't', '--acc-columns', 'ax', 'ay', 'az',
            '--temp-column', 'temp', '--force']
    assert main(argv) == 2
    assert '/dev/null' in _one_error_line(capsys.readouterr().err)
    after = os.lstat('/dev/null')
    assert stat.S_ISCHR(after.st_mode) and after.st_ino == before.st_ino and after.st_rdev == before.st_rdev


def test_write_record_refuses_an_existing_bag_unless_force(tmp_path):
    """write_record with an existing bag and force=False raises BagError naming the path."""
    record = ChannelRecord(counts_stamp_ns=np.array([1, 2], dtype=np.int64), counts=np.zeros((2, 3)),
                           temp_stamp_ns=np.array([1], dtype=np.int64), temp_code=np.array([8000.0]))
    write_record(tmp_path / 'b', record)
    with pytest.raises(BagError, match='exists already'):
        write_record(tmp_path / 'b', record)
    write_record(tmp_path / 'b', replace(record, counts=np.ones((2, 3))), force=True)
    assert np.array_equal(read_record(tmp_path / 'b', progress=False).counts, np.ones((2, 3)))
    assert _leftovers(tmp_path) == []


def test_a_full_disk_while_writing_the_report_names_the_report_directory(tiny, tmp_path, monkeypatch, capsys):
    """A figure that cannot be written: one line naming --report's directory, not the temporary one."""
    from tak_thermo_ros.reports import diagnose as report_module
    root, _ = tiny

    def full_disk(path, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(report_module, '_write_atomic', full_disk)
    out = tmp_path / 'report'
    argv = ['diagnose', str(root / 'cal'), '--params', str(root / 'params.yaml'), '--report', str(out),
            '--candidates', 'warmup', '--folds', '2', '--no-progress']
    assert main(argv) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert line == f'tak_calib: error: {out}: No space left on device'
    assert list(tmp_path.iterdir()) == []
