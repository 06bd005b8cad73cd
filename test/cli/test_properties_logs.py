"""Property tests of ``tak_calib`` on mutated flight logs (PX4 ULog, ArduPilot ``.bin``) and calibration files.

The invariant of ``test/cli/test_properties.py`` (exit 0 with finite output, or exit 2 with one line
that is not an internal error; no traceback, no warning, no temporary left behind), and no
uncounted loss: when ``fit`` of a flight log succeeds, the accelerometer samples it fitted and
those it left out (counted by reason) add up to the samples the reader said the log holds.

Mutations: of the logged fields (NaN and infinite values, stamps repeated, back, far ahead or
with a bit flipped, a topic in two subscriptions, cut short or missing, temperatures in kelvin
or centi-degrees, the parameters a ``.bin`` reader undoes NaN, fractional or out of range), then
of the file's bytes (truncated, bits flipped); of a calibration file's text (a value replaced by
junk, NaN, a 5,000-digit integer or deep nesting, a line dropped, bits flipped). ``make test``
runs a small budget; ``make fuzz`` 25 times more (1,000 flight logs).
"""

from __future__ import annotations

import math
import re
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from conftest import examples
from cli.test_properties import _run, check_outcome
from tak_thermo_ros.core.simulation.powered import PoweredRun, simulate_powered
from tak_thermo_ros.formats.bag import read_imu_messages
from tak_thermo_ros.formats.dataflash import driver_messages, write_dataflash
from tak_thermo_ros.formats.ulog import driver_topics, write_ulog

RUN = PoweredRun(duration_s=240.0, accel_rate_hz=2.0, gyro_rate_hz=3.0, gyro_phase_s=0.13, board_tau_s=120.0,
                 self_heating_tau_s=20.0, seed=5)
"""Four minutes of a warming board: 481 accelerometer samples, enough to fit, quick to write and read."""
IDS = {'accel': 2490378, 'gyro': 2490634}
FIELD_VALUES = st.sampled_from([math.nan, math.inf, -math.inf, 1e30, -1e30, 0.0, 1e4])
PARAMETERS = {'AHRS_ORIENTATION': 0, 'INS_ACCOFFS_X': 0.05, 'INS_ACCSCAL_Y': 1.01, 'INS_GYROFFS_Z': 0.002,
              'INS_TCAL1_ENABLE': 0, 'INS_ACC_ID': 2490378}
PARAMETER_VALUES = st.sampled_from([math.nan, math.inf, -math.inf, 2.5, 38.0, 2.0, -1.0, 1e30, 1.0, 4e9])


@pytest.fixture(scope='module')
def pristine(tmp_path_factory):
    """The run's record, its logs' fields, and the calibration fitted from the clean ULog."""
    record = simulate_powered(RUN).record
    root = tmp_path_factory.mktemp('logs')
    topics = driver_topics(record, device_ids=IDS)
    accel = topics[('sensor_accel', 0)]
    count = len(accel['timestamp'])
    topics[('sensor_mag', 0)] = {'timestamp': accel['timestamp'], 'timestamp_sample': accel['timestamp_sample'],
                                 'device_id': np.full(count, 396809), 'x': np.full(count, 0.2),
                                 'y': np.full(count, 0.01), 'z': 0.4 + 1e-4 * accel['temperature'],
                                 'temperature': accel['temperature']}
    write_ulog(root / 'clean.ulg', topics)
    code, _, err = _run(['fit', str(root / 'clean.ulg'), '-o', str(root / 'params.yaml'), '--no-progress'])
    assert code == 0, err
    shared = replace(record, stamp_ns=record.accel_stamp_ns, accel_stamp_ns=None, gyro_stamp_ns=None,
                     gyro=record.gyro[:len(record.accel)])
    return Pristine(topics, driver_messages(shared)['IMU'], root / 'params.yaml')


class Pristine(tuple):
    """The clean ULog's topics, the ``.bin``'s IMU messages, the calibration (a short repr for Hypothesis)."""

    def __new__(cls, topics, imu, params):
        return super().__new__(cls, (topics, imu, params))

    def __repr__(self) -> str:
        return 'Pristine(...)'


@st.composite
def ulog_changes(draw) -> list[tuple]:
    """Changes to a ULog's topics (see the module's description)."""
    topics = st.sampled_from(['sensor_accel', 'sensor_gyro', 'sensor_mag'])
    kinds = st.sampled_from(['value', 'stamp', 'device_id', 'drop', 'split', 'unit', 'cut'])
    changes = []
    for _ in range(draw(st.integers(0, 4))):
        kind, topic = draw(kinds), draw(topics)
        if kind == 'value':
            changes.append((kind, topic, draw(st.sampled_from(['x', 'y', 'z', 'temperature'])),
                            draw(st.integers(0, 10_000)), draw(FIELD_VALUES)))
        elif kind == 'stamp':
            changes.append((kind, topic, draw(st.integers(0, 10_000)),
                            draw(st.sampled_from(['repeat', 'back', 'ahead', 'flip'])), draw(st.integers(0, 63))))
        elif kind == 'unit':
            changes.append((kind, draw(st.sampled_from(['kelvin', 'centi']))))
        elif kind == 'cut':
            changes.append((kind, topic, draw(st.integers(0, 80))))
        else:
            changes.append((kind, topic))
    return changes


def _changed_stamp(stamps: np.ndarray, row: int, how: str, bit: int) -> np.ndarray:
    stamps = np.asarray(stamps, dtype=np.uint64).copy()
    if how == 'repeat' and row > 0:
        stamps[row] = stamps[row - 1]
    elif how == 'back' and row > 0:
        stamps[row] = max(int(stamps[row - 1]) - 1_000_000, 0)
    elif how == 'ahead':
        stamps[row] = stamps[row] + np.uint64(10 ** 12)
    elif how == 'flip':
        stamps[row] ^= np.uint64(1) << np.uint64(bit)
    return stamps


def _changed_topics(topics: dict, changes: list[tuple]) -> dict:
    changed = {key: {field: np.array(values) for field, values in fields.items()} for key, fields in topics.items()}
    for change in changes:
        kind = change[0]
        if kind == 'unit':
            for topic in ('sensor_accel', 'sensor_gyro'):
                fields = changed.get((topic, 0))
                if not isinstance(fields, dict):
                    continue
                fields['temperature'] = fields['temperature'] + 273.15 if change[1] == 'kelvin' \
                    else fields['temperature'] * 100.0
            continue
        key = (change[1], 0)
        if key not in changed or isinstance(changed[key], list):
            continue
        fields = changed[key]
        count = len(fields['timestamp'])
        if kind == 'value' and count:
            fields[change[2]] = fields[change[2]].astype(float)
            fields[change[2]][change[3] % count] = change[4]
        elif kind == 'stamp' and count:
            fields['timestamp_sample'] = _changed_stamp(fields['timestamp_sample'], change[2] % count, change[3],
                                                        change[4])
        elif kind == 'device_id' and count > 1:
            fields['device_id'] = fields['device_id'].copy()
            fields['device_id'][count // 2:] = 1234
        elif kind == 'drop':
            del changed[key]
        elif kind == 'split' and count > 1:
            third = count // 3
            changed[key] = [{f: v[third:] for f, v in fields.items()}, {f: v[:third] for f, v in fields.items()}]
        elif kind == 'cut':
            changed[key] = {f: v[:change[2]] for f, v in fields.items()}
    return changed


@st.composite
def bin_changes(draw) -> tuple[list[tuple], dict[str, float]]:
    """Changes to a ``.bin``'s IMU messages and its parameters."""
    changes = []
    for _ in range(draw(st.integers(0, 4))):
        kind = draw(st.sampled_from(['value', 'stamp', 'unit', 'cut']))
        if kind == 'value':
            changes.append((kind, draw(st.sampled_from(['AccX', 'AccZ', 'GyrY', 'T'])), draw(st.integers(0, 10_000)),
                            draw(FIELD_VALUES)))
        elif kind == 'stamp':
            changes.append((kind, draw(st.integers(0, 10_000)), draw(st.sampled_from(['repeat', 'back', 'ahead',
                                                                                      'flip'])),
                            draw(st.integers(0, 63))))
        elif kind == 'unit':
            changes.append((kind, draw(st.sampled_from(['kelvin', 'centi']))))
        else:
            changes.append((kind, draw(st.integers(0, 80))))
    parameters = dict(PARAMETERS)
    for name in draw(st.lists(st.sampled_from(sorted(PARAMETERS)), max_size=2)):
        parameters[name] = draw(PARAMETER_VALUES)
    return changes, parameters


def _changed_imu(values: dict, changes: list[tuple]) -> dict:
    changed = {name: np.array(column) for name, column in values.items()}
    for change in changes:
        count = len(changed['TimeUS'])
        if change[0] == 'value' and count:
            changed[change[1]] = changed[change[1]].astype(float)
            changed[change[1]][change[2] % count] = change[3]
        elif change[0] == 'stamp' and count:
            changed['TimeUS'] = _changed_stamp(changed['TimeUS'], change[1] % count, change[2], change[3])
        elif change[0] == 'unit':
            changed['T'] = changed['T'] + 273.15 if change[1] == 'kelvin' else changed['T'] * 100.0
        elif change[0] == 'cut':
            changed = {name: column[:change[1]] for name, column in changed.items()}
    return changed


BYTE_DAMAGE = st.one_of(st.just(('none',)), st.just(('none',)), st.tuples(st.just('truncate'), st.floats(0.0, 1.0)),
                        st.tuples(st.just('flip'), st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 7)),
                                                            min_size=1, max_size=8)))


HEAD_BYTES = 16
"""Damage lands after a file's first bytes (which tell the format apart: refused cases enough there)."""


def _damaged(path: Path, damage: tuple) -> None:
    data = bytearray(path.read_bytes())
    span = max(len(data) - HEAD_BYTES, 1)
    if damage[0] == 'truncate':
        del data[HEAD_BYTES + int(damage[1] * span):]
    elif damage[0] == 'flip':
        for where, bit in damage[1]:
            data[min(HEAD_BYTES + int(where * span), len(data) - 1)] ^= 1 << bit
    path.write_bytes(bytes(data))


def check_written(code: int, out: str, err: str, directory: Path, outputs: dict[Path, str]) -> None:
    """``check_outcome``, and an Imu bag ``apply`` wrote (``compensated``): finite, or no bag on a refusal."""
    checked = {path: kind for path, kind in outputs.items() if kind != 'compensated'}
    check_outcome(code, out, err, directory, {}, checked)
    for path, kind in outputs.items():
        if kind == 'compensated':
            assert (code == 0) == path.exists(), (code, out)
            if code == 0:
                messages = read_imu_messages(path, topic='/imu/data_compensated')
                for values in (messages.linear_acceleration, messages.angular_velocity,
                               messages.linear_acceleration_covariance, messages.angular_velocity_covariance):
                    assert np.all(np.isfinite(values))


def _reader_count(out: str) -> int | None:
    """The accelerometer samples the reader said the log holds."""
    found = re.search(r': (\d+) sensor_accel, ', out) or re.search(r'instance \d+: (\d+) IMU samples', out)
    return int(found.group(1)) if found else None


def check_nothing_lost(code: int, out: str) -> None:
    """A fit that succeeded: fitted plus left out (by reason) is every accelerometer sample the reader read."""
    if code != 0 or 'accelerometer: held at nominal' in out or 'accelerometer and gyroscope: held' in out:
        return
    read = _reader_count(out)
    fitted = re.search(r'^fitted (\d+) samples', out, re.MULTILINE)
    assert read is not None and fitted is not None, out
    left = re.search(r'^accelerometer: left out: (.*)$', out, re.MULTILINE)
    counted = sum(int(n) for n in re.findall(r'(\d+) [a-z]', left.group(1))) if left else 0
    assert int(fitted.group(1)) + counted == read, out


def _command(command: str, log: Path, params: Path, out: Path, instance: int) -> tuple[list[str], dict[Path, str]]:
    options = ['--no-progress', '--instance', str(instance)]
    if command == 'fit':
        return ['fit', str(log), '-o', str(out), *options], {out: 'yaml'}
    if command == 'apply':
        return ['apply', str(log), '--params', str(params), '-o', str(out), *options], {out: 'compensated'}
    return ['validate', str(log), '--params', str(params), *options], {}


COMMAND = st.sampled_from(['fit', 'fit', 'fit', 'apply', 'validate'])
INSTANCE = st.sampled_from([0, 0, 0, 0, 1])


def _check_command(kind: str, log: Path, command: str, params: Path, directory: Path, instance: int) -> None:
    """Run ``command`` on the log (``kind``: its format, for the event): one line, or its outputs written.

    After ``fit``, every sample is counted (:func:`check_nothing_lost`).
    """
    argv, outputs = _command(command, log, params, directory / 'out', instance)
    code, stdout, stderr = _run(argv)
    event(f'{kind} {command}: exit {code}')
    check_written(code, stdout, stderr, directory, outputs)
    if command == 'fit':
        check_nothing_lost(code, stdout)


@settings(max_examples=examples(20))
@given(changes=ulog_changes(), damage=BYTE_DAMAGE, command=COMMAND, instance=INSTANCE)
def test_commands_on_mutated_ulogs_keep_the_invariant_and_lose_nothing_uncounted(
        pristine, changes, damage, command, instance):
    """A ULog with changed fields, then damaged bytes: one line, or finite output with every sample counted."""
    topics, _, params = pristine
    with tempfile.TemporaryDirectory() as name:
        directory = Path(name)
        log = directory / 'log.ulg'
        write_ulog(log, _changed_topics(topics, changes))
        _damaged(log, damage)
        _check_command('ulog', log, command, params, directory, instance)


@settings(max_examples=examples(20))
@given(changes=bin_changes(), damage=BYTE_DAMAGE, command=COMMAND, instance=INSTANCE)
def test_commands_on_mutated_dataflash_logs_keep_the_invariant_and_lose_nothing_uncounted(
        pristine, changes, damage, command, instance):
    """A ``.bin`` with changed IMU messages and parameters, then damaged bytes: the same."""
    _, (fmt, columns, values), params = pristine
    imu_changes, parameters = changes
    with tempfile.TemporaryDirectory() as name:
        directory = Path(name)
        log = directory / 'log.bin'
        write_dataflash(log, {'IMU': (fmt, columns, _changed_imu(values, imu_changes))}, parameters=parameters)
        _damaged(log, damage)
        _check_command('bin', log, command, params, directory, instance)


YAML_JUNK = st.sampled_from(['.nan', '.inf', '-.inf', '1e400', '-1e308', '9' * 5000, '[' * 3000 + ']' * 3000,
                             '{a: ' * 3000 + '1' + '}' * 3000, 'abc', "''", '0', '-0', '[]', '{}', 'null', 'true',
                             '1_0', '7', '-1', '4294967296', '[1, 2.0]', '"\u0661"'])


@st.composite
def yaml_changes(draw) -> list[tuple]:
    """Changes to a calibration file's text: a value replaced, a line dropped or repeated, bits flipped."""
    changes = []
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(['value', 'value', 'drop', 'repeat', 'flip']))
        if kind == 'value':
            changes.append((kind, draw(st.integers(0, 10_000)), draw(YAML_JUNK)))
        elif kind == 'flip':
            changes.append((kind, draw(st.floats(0.0, 1.0)), draw(st.integers(0, 7))))
        else:
            changes.append((kind, draw(st.integers(0, 10_000))))
    return changes


def _changed_yaml(text: str, changes: list[tuple]) -> bytes:
    lines = text.splitlines()
    for change in changes:
        valued = [i for i, line in enumerate(lines) if re.match(r'\s*[\w.]+: \S', line)]
        if change[0] == 'value' and valued:
            row = valued[change[1] % len(valued)]
            key = lines[row].split(': ', 1)[0]
            lines[row] = f'{key}: {change[2]}'
        elif change[0] == 'drop' and lines:
            del lines[change[1] % len(lines)]
        elif change[0] == 'repeat' and lines:
            row = change[1] % len(lines)
            lines.insert(row, lines[row])
    data = bytearray('\n'.join(lines).encode() + b'\n')
    for change in changes:
        if change[0] == 'flip':
            data[min(int(change[1] * len(data)), len(data) - 1)] ^= 1 << change[2]
    return bytes(data)


@settings(max_examples=examples(12))
@given(changes=yaml_changes(), command=st.sampled_from(['export_px4', 'export_ardupilot', 'validate', 'apply']))
def test_commands_given_a_mutated_calibration_file_keep_the_invariant(pristine, changes, command):
    """A calibration file with junk, NaN, huge or deeply nested values, a line dropped or bits flipped."""
    topics, _, params = pristine
    with tempfile.TemporaryDirectory() as name:
        directory = Path(name)
        changed = directory / 'params.yaml'
        changed.write_bytes(_changed_yaml(params.read_text(), changes))
        log = params.parent / 'clean.ulg'
        out = directory / 'out'
        argv, outputs = {
            'export_px4': (['export', str(changed), '--format', 'px4', '-o', str(out)], {}),
            'export_ardupilot': (['export', str(changed), '--format', 'ardupilot', '-o', str(out)], {}),
            'validate': (['validate', str(log), '--params', str(changed), '--no-progress'], {}),
            'apply': (['apply', str(log), '--params', str(changed), '-o', str(out), '--no-progress'],
                      {out: 'compensated'}),
        }[command]
        code, stdout, stderr = _run(argv)
        event(f'yaml {command}: exit {code}')
        check_written(code, stdout, stderr, directory, outputs)
        if command.startswith('export') and code == 0:
            assert not re.search(r'(?<![a-z_])(nan|inf)(?![a-z_])', out.read_text(), re.IGNORECASE)
