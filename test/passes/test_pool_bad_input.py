"""Issue 44 (and 43's item 2): pools and learned files under unlucky and bad input.

A record counted once by its content; a spread from too few records not written as known, and not
judged against; learned corrections bounded where read; only regular files read; the pool's solve
on sufficient statistics; the three "to settle" cases.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from everyday_watch import watch_run, watch_unit
from node_helpers import domain_id, node_command, ros_environment, run_to_exit
from tak_thermo_ros import cli
from tak_thermo_ros.cli.common import unwrap
from tak_thermo_ros.core.fit.handheld.system import System, solve
from tak_thermo_ros.core.fit.random_effects import RecordColumns, RecordStatistics, RecordSystem, absorbed
from tak_thermo_ros.core.link.model import MIN_TURN_ON_RECORDS, TurnOn, spread_interval
from tak_thermo_ros.core.link.learning import LearnedState, Learner, calibration_digest
from tak_thermo_ros.core.link.watch import WatchSettings
from tak_thermo_ros.core.simulation.everyday import everyday_scenario, simulate_everyday_record
from tak_thermo_ros.errors import TakError
from tak_thermo_ros.formats.bag import Topics, write_driver_record
from tak_thermo_ros.formats.calibration_file import load_unit, save_unit
from tak_thermo_ros.formats.kalibr import write_kalibr
from tak_thermo_ros.formats.learned_file import load_learned, save_learned
from tak_thermo_ros.passes import pool as pool_pass
from tak_thermo_ros.passes.fleet import distinct_units
from tak_thermo_ros.passes.run import StreamOptions

RAW = {'sample_rate_hz': 10.0, 'seed': 21, 'everyday': {'records': 7, 'record_minutes': 6.0}}
"""Seven records of about 6 minutes at 10 Hz (about 4,000 Imu messages each)."""
TAK_CALIB = [sys.executable, '-m', 'tak_thermo_ros.cli']


def run_cli(capsys, *argv) -> tuple[int, list[str]]:
    """``tak_calib argv``: its exit status and its statements (a wrapped line joined)."""
    status = cli.main([*argv, '--no-progress'])
    out = capsys.readouterr()
    return status, unwrap(out.out + out.err)


@pytest.fixture(scope='module')
def month(tmp_path_factory):
    """Seven records as bags (``rec00``..``rec06``), the unit's true noise models as a Kalibr file."""
    root = tmp_path_factory.mktemp('month')
    scenario, habits = everyday_scenario(RAW)
    simulated = []
    for index in range(7):
        simulated.append(simulate_everyday_record(scenario, habits, index))
        write_driver_record(root / f'rec{index:02d}', simulated[-1].record)
    write_kalibr(root / 'noise.yaml', {s: scenario.noise_truth(s) for s in ('accel', 'gyro')}, rostopic='/imu/data_raw')
    return root, simulated


@pytest.fixture(scope='module')
def five(month, tmp_path_factory):
    """The calibration of five records with the noise models: its gyro turn_on determined."""
    root, _ = month
    params = tmp_path_factory.mktemp('five') / 'five.yaml'
    records = [str(root / f'rec{index:02d}') for index in range(5)]
    assert cli.main(['fit', *records, '--noise', str(root / 'noise.yaml'), '-o', str(params), '--no-progress']) == 0
    return params


# ----- 1. a record identified by its content ---------------------------------------------------------


def test_a_record_given_twice_in_any_spelling_is_counted_once(month, capsys, tmp_path, monkeypatch):
    """The same record by other spellings, a link, a copy and its .mcap beside it: one power-up, the rest named."""
    root, _ = month
    monkeypatch.chdir(root)
    os.symlink(root / 'rec00', tmp_path / 'linked')
    shutil.copytree(root / 'rec00', tmp_path / 'copied')
    shutil.copy(next((root / 'rec00').glob('*.mcap')), tmp_path / 'rec00.mcap')
    given = ['rec00', 'rec00/', './rec00', str(tmp_path / 'linked'), str(tmp_path / 'copied'),
             str(tmp_path / 'rec00.mcap'), 'rec02']
    status, lines = run_cli(capsys, 'fit', *given, '-o', str(tmp_path / 'dup.yaml'))
    assert status == 0, lines
    once = [line for line in lines if line.endswith('counted once')]
    assert len(once) == 5 and all(' the same record as rec00 (' in line for line in once), lines
    assert once[0] == 'rec00/: the same record as rec00 (the same path): counted once'
    assert any('linked: the same record as rec00 (through a link)' in line for line in once)
    assert any('copied: the same record as rec00 (the same ' in line for line in once)
    assert any(line.startswith('pool: 2 of 2 records') for line in lines), lines
    assert load_unit(tmp_path / 'dup.yaml').gyro.turn_on.records == 2


def test_one_flight_as_ulg_and_bin_is_one_record(month, capsys, tmp_path):
    """A flight written both as a ULog and a DataFlash log is one record; another record beside it stays."""
    from tak_thermo_ros.formats.dataflash import driver_messages, write_dataflash
    from tak_thermo_ros.formats.ulog import driver_topics, write_ulog
    root, simulated = month
    record = simulated[1].record
    write_ulog(tmp_path / 'flight.ulg', driver_topics(record, device_ids={'accel': 1, 'gyro': 2}),
               info={'sys_name': 'PX4'})
    write_dataflash(tmp_path / 'flight.bin', driver_messages(record), parameters={'AHRS_ORIENTATION': 0})
    status, lines = run_cli(capsys, 'fit', str(tmp_path / 'flight.ulg'), str(tmp_path / 'flight.bin'),
                            str(root / 'rec03'), '-o', str(tmp_path / 'p.yaml'))
    assert status == 0, lines
    assert lines[0] == (f'{tmp_path / "flight.bin"}: the same record as {tmp_path / "flight.ulg"} (the same '
                        f'{len(record.stamp_ns)} messages): counted once')
    assert any(line.startswith('pool: 2 of 2 records') for line in lines), lines


def test_fit_fleet_counts_a_linked_or_copied_unit_once(month, tmp_path):
    """A unit's folder through a link, or copied, or spelled otherwise, is one unit: named, counted once.

    (``fit-fleet`` says so: test/passes/test_pool.py::test_fit_fleet_takes_a_directory_of_records_per_unit.)
    """
    root, _ = month
    unit = tmp_path / 'unitA'
    unit.mkdir()
    for index in (0, 1):
        os.symlink(root / f'rec{index:02d}', unit / f'rec{index:02d}')
    os.symlink(unit, tmp_path / 'unitlink')
    shutil.copytree(unit, tmp_path / 'unitcopy', symlinks=False)
    (tmp_path / 'unitB').mkdir()
    os.symlink(root / 'rec02', tmp_path / 'unitB' / 'rec02')
    bags = [str(unit), str(tmp_path / 'unitlink'), str(tmp_path / 'unitcopy'), str(tmp_path / 'unitB'), f'{unit}/']
    kept, lines = distinct_units(bags, Topics())
    assert kept == [0, 3]
    assert lines == [f'{bags[1]}: the same unit as {bags[0]} (through a link): counted once',
                     f'{bags[2]}: the same unit as {bags[0]} (the same records): counted once',
                     f'{bags[4]}: the same unit as {bags[0]} (the same path): counted once']


@pytest.fixture(scope='module')
def tiny(tmp_path_factory):
    """Three tiny records (about a minute each) to build pools of copies from."""
    root = tmp_path_factory.mktemp('tiny')
    scenario, habits = everyday_scenario({'sample_rate_hz': 10.0, 'seed': 4,
                                          'everyday': {'records': 3, 'record_minutes': 1.0}})
    for index in range(3):
        write_driver_record(root / f'base{index}', simulate_everyday_record(scenario, habits, index).record)
    return root


WAYS = ('same', 'slash', 'link', 'copy', 'rename', 'mcap')


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.tuples(st.integers(0, 2), st.sampled_from(WAYS)), min_size=1, max_size=6))
def test_a_pool_of_copies_links_and_renames_counts_each_content_once(tiny, made):
    """Whatever copies, links, renames and spellings a pool is built of, it pools each record's content once.

    The same records, the same rests, the same samples as the pool of the originals alone.
    """
    options = StreamOptions(topics=Topics(), progress=False)
    with tempfile.TemporaryDirectory() as scratch:
        paths, first = [], []
        for number, (index, way) in enumerate(made):
            base = tiny / f'base{index}'
            if index not in first:
                first.append(index)
            target = Path(scratch) / f'r{number}'
            if way == 'same':
                paths.append(str(base))
                continue
            if way == 'slash':
                paths.append(f'{base}/')
                continue
            if way == 'link':
                os.symlink(base, target)
            elif way in ('copy', 'rename'):
                shutil.copytree(base, target)
                if way == 'rename':  # the bag renamed, its storage file too
                    metadata = target / 'metadata.yaml'
                    for inner in list(target.glob('*.mcap')):
                        inner.rename(target / f'other_{inner.name}')
                        metadata.write_text(metadata.read_text().replace(inner.name, f'other_{inner.name}'))
            else:
                target = target.with_suffix('.mcap')
                shutil.copy(next(base.glob('*.mcap')), target)
            paths.append(str(target))
        opened = pool_pass.open_pool(paths, options)
        alone = pool_pass.open_pool([str(tiny / f'base{index}') for index in first], options)
    assert len(opened.entries) == len(first)
    assert [e.rests for e in opened.entries] == [e.rests for e in alone.entries]
    assert opened.record is not None and alone.record is not None
    assert np.array_equal(opened.record.still.counts, alone.record.still.counts)
    assert np.array_equal(opened.record.still_record, alone.record.still_record)


# ----- 2. a spread from too few records ----------------------------------------------------------------


def test_the_spread_interval_is_the_chi_square_one():
    """The factors said beside a spread are the 95 % chi-square interval (without scipy on the node's path)."""
    from scipy.stats import chi2
    for records in range(2, 41):
        dof = records - 1
        low, high = spread_interval(records)
        assert low == pytest.approx(math.sqrt(dof / chi2.ppf(0.975, dof)), rel=1e-9)
        assert high == pytest.approx(math.sqrt(dof / chi2.ppf(0.025, dof)), rel=1e-9)


def test_two_records_write_a_repeatability_not_determined_and_nothing_judges_against_it(month, capsys, tmp_path):
    """Two records: the file says "not determined"; the watch does not judge a first rest against it; apply says why.

    Before: 7.9e-09 rad/s written, the next healthy record called stale at rest 1, its offset refused as
    "a changed curve".
    """
    root, _ = month
    two = tmp_path / 'two.yaml'
    status, lines = run_cli(capsys, 'fit', str(root / 'rec00'), str(root / 'rec02'), '--noise',
                            str(root / 'noise.yaml'), '-o', str(two))
    assert status == 0, lines
    said = next(line for line in lines if line.startswith('gyroscope: turn-on repeatability'))
    assert said == ('gyroscope: turn-on repeatability not determined: 2 records, at least 5 needed; from 2 the '
                    '95 % interval of a spread is 0.45..32x its estimate; written so')
    assert 'turn_on: {repeatability: not determined, records: 2}' in two.read_text()
    unit = load_unit(two)
    assert unit.gyro.turn_on is not None and unit.gyro.known_turn_on is None
    status, lines = run_cli(capsys, 'validate', str(root / 'rec03'), '--params', str(two), '--json',
                            str(tmp_path / 'v.json'))
    assert status == 0, lines
    findings = json.loads((tmp_path / 'v.json').read_text())['calibration_watch']['findings']
    assert not any(finding['turn_on'] for finding in findings), findings
    status, lines = run_cli(capsys, 'apply', str(root / 'rec03'), '--params', str(two), '-o',
                            str(tmp_path / 'a.mcap'), '--turn-on', 'first-rest')
    assert status == 2 and lines[-1].startswith('tak_calib: error: --turn-on first-rest: the calibration holds no '
                                                'gyro turn-on repeatability (not determined: 2 records'), lines
    # a file written before the rule, with numbers from two records: read as not determined too
    old = tmp_path / 'old.yaml'
    written = TurnOn((7.9e-9, 4.7e-4, 8.5e-5), (7e-5, 3e-4, 7e-5), 2)
    save_unit(old, replace(unit, gyro=replace(unit.gyro, turn_on=written)))
    assert load_unit(old).gyro.known_turn_on is None


def test_the_watch_judges_the_first_rest_against_a_determined_repeatability_only():
    """A tiny repeatability from two records is not judged against; from sixteen it is (and fires at rest 1)."""
    from everyday_watch import everyday_runs
    unit = watch_unit()
    run = everyday_runs(0, ('healthy',))['healthy']
    tiny = tuple(1e-9 for _ in range(3))
    fired = {}
    for records in (2, MIN_TURN_ON_RECORDS, 16):
        told = replace(unit, gyro=replace(unit.gyro, turn_on=TurnOn(tiny, tiny, records)))
        watch, _, _ = watch_run(run, told)
        fired[records] = any(finding.turn_on for finding in watch.findings.values())
    assert fired == {2: False, MIN_TURN_ON_RECORDS: True, 16: True}


# ----- 3. learned corrections bounded where read ----------------------------------------------------------


def _learned(path: Path, unit, **change) -> Path:
    """A learned file of ``unit`` (one run, four rests), its ``learned`` section then edited as ``change`` says."""
    state = LearnedState(offset=(1e-5, 0.0, 0.0), offset_variance=(1e-10,) * 3, slope=(0.0, 0.0, 0.0),
                         slope_variance=(1e-12,) * 3, reference=unit.gyro.temp_code_ref, runs=1, rests=4,
                         original=calibration_digest(unit))
    save_learned(path, unit, state)
    if change:
        import yaml
        document = yaml.safe_load(path.read_text())
        section = next(iter(document.values()))['ros__parameters']['learned']
        section.update(change)
        path.write_text(yaml.safe_dump(document, sort_keys=False))
    return path


def test_learned_corrections_beyond_their_bound_are_refused_where_read(five, capsys, tmp_path):
    """A learned file of 1e300 rad/s is refused by every command and the node's start, in one line naming the bound."""
    unit = load_unit(five)
    good = _learned(tmp_path / 'good.yaml', unit)
    assert load_learned(good, unit) is not None
    assert cli.main(['export', str(good), '--format', 'px4', '-o', str(tmp_path / 'x.params')]) == 0
    bound = Learner(unit, LearnedState()).total_offset_bound
    for name, value, words in (('offset', [1.0e300, 0.0, 0.0], 'learned.offset[0]: +2.063e+305 deg/h lies beyond '),
                               ('slope', [0.0, 0.5, 0.0], 'learned.slope[1]: +1.031e+05 deg/h/C lies beyond '),
                               ('above', [0.5, 0.0, 0.0], 'learned.above[0]: +1.031e+05 deg/h/C lies beyond '),
                               ('reference', 1.0e6, 'learned.reference: 1e+06 C lies outside the calibration')):
        bad = _learned(tmp_path / f'{name}.yaml', unit, **{name: value})
        for command in (['validate', str(tmp_path / 'nothing'), '--params', str(bad), '--no-progress'],
                        ['export', str(bad), '--format', 'px4', '-o', str(tmp_path / 'y.params')]):
            status = cli.main(command)
            lines = unwrap(capsys.readouterr().err)
            assert status == 2 and len(lines) == 1 and f'{bad}: {words}' in lines[0], lines
        with pytest.raises(TakError, match=words.split(': ')[0].replace('[', r'\[').replace(']', r'\]')):
            load_learned(bad, unit)
    assert 'the bound learning keeps on this calibration, +-' in lines[0] or 'outside' in lines[0]
    # at the bound itself (where learning clips): applied
    edge = LearnedState(offset=(float(bound[0]), 0.0, 0.0), original=calibration_digest(unit),
                        reference=unit.gyro.temp_code_ref)
    assert Learner(unit, edge).start.offset[0] == bound[0]
    with pytest.raises(TakError, match='lies beyond the bound learning keeps'):
        Learner(unit, replace(edge, offset=(float(bound[0]) * 1.001, 0.0, 0.0)))


# ----- 4. only regular files read ---------------------------------------------------------------------------


READ_EACH = """
import sys
from tak_thermo_ros.errors import TakError
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.formats.kalibr import read_kalibr
for path in sys.argv[1:]:
    for read in (load_unit, read_kalibr):
        try:
            read(path)
        except TakError as err:
            print(err)
"""


def test_a_fifo_socket_device_or_directory_is_refused_as_parameters_at_once(tmp_path):
    """``validate --params FIFO``: one line, exit 2; a FIFO, a socket, /dev/zero, a directory: each refused so.

    Before: a FIFO blocked ``open()`` for ever (and /dev/zero read for ever).
    """
    fifo = tmp_path / 'f.yaml'
    os.mkfifo(fifo)
    sock = tmp_path / 's.yaml'
    listener = socket.socket(socket.AF_UNIX)
    listener.bind(str(sock))
    try:
        result = subprocess.run([*TAK_CALIB, 'validate', str(tmp_path / 'rec'), '--params', str(fifo)],
                                capture_output=True, text=True, timeout=60)
        assert result.returncode == 2 and result.stderr.strip().splitlines() == [
            f'tak_calib: error: {fifo}: is a FIFO (named pipe), not a calibration file: only a regular file is read']
        kinds = {str(fifo): 'a FIFO (named pipe)', str(sock): 'a socket', '/dev/zero': 'a character device',
                 str(tmp_path): 'a directory'}
        result = subprocess.run([sys.executable, '-c', READ_EACH, *kinds], capture_output=True, text=True, timeout=60)
        assert result.stdout.splitlines() == [f'{path}: is {kind}, not a {what}: only a regular file is read'
                                              for path, kind in kinds.items()
                                              for what in ('calibration file', 'noise file')], result
    finally:
        listener.close()


def test_the_node_refuses_a_fifo_or_an_unbounded_learned_file_at_start(five, tmp_path):
    """``learned_file:=FIFO``, ``--params-file FIFO``, a learned file beyond its bound: one line, exit 2, no wait.

    Before: the FIFO blocked the node before its first line, deaf to SIGINT and SIGTERM.
    """
    env = ros_environment(tmp_path, domain_id(44))
    fifo = tmp_path / 'learned.yaml'
    os.mkfifo(fifo)
    bad = _learned(tmp_path / 'bad.yaml', load_unit(five), offset=[1.0e300, 0.0, 0.0])
    cases = ((['--params-file', str(fifo)], f'--params-file {fifo}: is a FIFO (named pipe): only a regular file'),
             (['-p', f'calibration_file:={fifo}'], f'{fifo}: is a FIFO (named pipe), not a calibration file'),
             (['--params-file', str(five), '-p', 'learn:=true', '-p', f'learned_file:={fifo}'],
              f'{fifo}: is a FIFO (named pipe), not a calibration file'),
             (['--params-file', str(five), '-p', 'learn:=true', '-p', f'learned_file:={bad}'],
              f'{bad}: learned.offset[0]: +2.063e+305 deg/h lies beyond the bound learning keeps'))
    for arguments, said in cases:
        result = run_to_exit(node_command(*arguments), env, timeout=60.0)
        assert result.returncode == 2, (arguments, result.stderr)
        assert 'cannot start: ' in result.stderr and said in result.stderr, result.stderr


# ----- 5. the pool's solve on sufficient statistics, lines as read ------------------------------------------


@settings(max_examples=40, deadline=None)
@given(st.integers(2, 6), st.integers(2, 5), st.integers(0, 2**31 - 1), st.booleans())
def test_the_pools_solve_is_the_whole_designs(records, shared, seed, hold):
    """Each record's columns absorbed record by record: the dense solve's terms, covariance and residual."""
    rng = np.random.default_rng(seed)
    slots = 3
    width = shared + records * slots
    own = shared + np.arange(records * slots).reshape(records, slots)
    rows, owners = [], []
    for record in range(-1, records):
        count = int(rng.integers(2, 7)) if record >= 0 else 4
        block = np.zeros((count, width + 1))
        block[:, :shared] = rng.normal(size=(count, shared))
        if record >= 0:
            block[:, own[record]] = rng.normal(size=(count, slots))
        block[:, -1] = rng.normal(size=count)
        rows.append(block)
        owners.append(np.full(count, record))
    prior = np.zeros((records * slots, width + 1))
    prior[np.arange(records * slots), own.ravel()] = 0.7
    dense = System.of_rows([np.vstack(rows), prior], width)
    pooled = RecordSystem(RecordColumns(own, width))
    pooled.add(np.vstack(rows), np.concatenate(owners))
    pooled.add_prior(np.full(slots, 0.7))
    held = {0: 0.25, **({int(j): 0.0 for j in own[:, 1]} if hold else {})}
    expected = solve(dense, held, width, rows=40)
    found = solve(pooled, held, width, rows=40)
    assert found.free == expected.free
    assert np.allclose(found.theta, expected.theta, rtol=1e-9, atol=1e-12)
    assert np.allclose(found.covariance, expected.covariance, rtol=1e-8, atol=1e-12)
    assert found.solution.rss == pytest.approx(expected.solution.rss, rel=1e-9, abs=1e-12)
    # what a fleet's prior reads of a pool (its information): the whole design's normal matrix
    assert np.allclose(pooled.normal(), dense.normal(), rtol=1e-9, atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 5), st.integers(1, 4), st.integers(0, 2**31 - 1))
def test_a_records_columns_integrated_out_are_the_schur_complement(records, shared, seed):
    """:func:`absorbed` is the dense normal matrix's Schur complement and its determinant's record part."""
    rng = np.random.default_rng(seed)
    rows = rng.normal(size=(6 * records, shared + 1))
    slots = rng.normal(size=(6 * records, 3))
    record = np.repeat(np.arange(records), 6)
    statistics = RecordStatistics.of_rows(rows, slots, record, records)
    precision = np.array([0.5, 2.0, 1.0])
    normal, log_own = absorbed(statistics, np.ones(3, dtype=bool), precision)
    design = np.zeros((len(rows), 3 * records))
    design[np.arange(len(rows))[:, None], 3 * record[:, None] + np.arange(3)] = slots
    own = design.T @ design + np.diag(np.tile(precision, records))
    cross = rows.T @ design
    assert np.allclose(normal, rows.T @ rows - cross @ np.linalg.solve(own, cross.T), rtol=1e-9, atol=1e-9)
    assert log_own == pytest.approx(np.linalg.slogdet(own)[1], rel=1e-9)


def test_each_records_line_is_said_as_it_is_read(month, monkeypatch):
    """The pool says a record's line before it reads the next (200 records print from the first one on)."""
    root, _ = month
    events = []
    read = pool_pass.read_record

    def reading(record, *args, **kwargs):
        events.append(f'read {record.path.name}')
        return read(record, *args, **kwargs)

    monkeypatch.setattr(pool_pass, 'read_record', reading)
    pool_pass.open_pool([str(root / 'rec00'), str(root / 'rec01'), str(root / 'rec00')],
                        StreamOptions(topics=Topics(), progress=False), say=lambda line: events.append(line[:6]))
    assert events == [f'{root / "rec00"}'[:6], 'read rec00', 'rec00:', 'read rec01', 'rec01:']


# ----- 6. the three to settle ---------------------------------------------------------------------------------


def test_a_record_whose_stamps_go_back_says_so_in_its_line(month, capsys, tmp_path):
    """Header stamps that jump back 200 s in the middle (the log time going on): the record's line says so."""
    from rosbags.rosbag2 import Reader, StoragePlugin, Writer
    from tak_thermo_ros.formats.bag import TYPESTORE
    root, _ = month
    jumped = tmp_path / 'jumped'
    with Reader(root / 'rec02') as reader, Writer(jumped, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        messages = [(c.topic, c.msgtype, t, raw) for c, t, raw in reader.messages()]
        middle = messages[len(messages) // 2][2]
        connections = {}
        for topic, msgtype, logged, raw in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=TYPESTORE)
            message = TYPESTORE.deserialize_cdr(raw, msgtype)
            if logged > middle:
                stamp = message.header.stamp.sec * 10 ** 9 + message.header.stamp.nanosec - 200_050_000_000
                message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, 10 ** 9)
            writer.write(connections[topic], logged, TYPESTORE.serialize_cdr(message, msgtype))
    status, lines = run_cli(capsys, 'fit', str(jumped), str(root / 'rec00'), '-o', str(tmp_path / 'p.yaml'))
    assert status == 0, lines
    assert lines[0].startswith('jumped: ') and lines[0].endswith('; its stamps go back once (by up to 200 s): no '
                                                                 'rest spans a jump'), lines
    assert lines[1].startswith('rec00: ') and 'stamps go back' not in lines[1]


def test_a_record_that_never_rested_takes_no_turn_on_offset_and_says_why(five, capsys, tmp_path):
    """A record the pool calls never rested: ``apply --turn-on first-rest`` finds no rest within the noise model.

    Its survey line shows the record's own quietest stretches (one record has no other yardstick);
    the watch's rests are those within the calibration's noise model, and it says so.
    """
    raw = {**RAW, 'everyday': {'records': 2, 'record_minutes': 4.0, 'rest_s': [0.5, 1.0]}}
    scenario, habits = everyday_scenario(raw)
    write_driver_record(tmp_path / 'moving', simulate_everyday_record(scenario, habits, 0).record)
    status, lines = run_cli(capsys, 'apply', str(tmp_path / 'moving'), '--params', str(five), '-o',
                            str(tmp_path / 'a.mcap'), '--turn-on', 'first-rest')
    assert status == 0, lines
    assert lines[-1].startswith("turn-on offset: no rest within the calibration's noise model (0 of "), lines


def test_a_few_non_finite_messages_leave_the_first_rests_offset_as_it_was(month, five):
    """2 % of the messages NaN (dropped) at 10 Hz: the same first rest, its offset within its noise.

    Before: a window short of one sample ended the rest: most rests were lost, the first one moved.
    """
    from everyday_watch import corrected_run
    _, simulated = month
    unit = load_unit(five)
    for run in simulated[5:7]:
        stamps, values, temperature = corrected_run(run, unit)
        keep = np.random.default_rng(run.index).random(len(stamps)) >= 0.02
        taken = []
        for rows in (np.ones(len(stamps), dtype=bool), keep):
            watch = WatchSettings(turn_on=True).watch(unit)
            watch.take_block(stamps[rows], values[rows], temperature[rows])
            assert watch.turn_on_lines and watch.turn_on_lines[0].startswith('turn-on offset taken at rest 1')
            first = watch.pending[0]
            taken.append((watch.turn_on_offset[3:].copy(), first.start_ns, first.duration_s))
        (intact, start, duration), (dropped, start_dropped, shorter) = taken
        assert abs(start_dropped - start) <= 1e9  # the same first rest, from the same window
        # the offsets of a rest and of most of it (a window short of three samples may end it sooner) differ
        # by the white noise of the part they do not share: well within the shorter one's noise
        noise = np.asarray(unit.gyro.noise.white_noise_density) / math.sqrt(min(duration, shorter))
        assert np.all(np.abs(dropped - intact) <= 1.5 * noise), (taken, noise)
