"""Issue 31, item 3: the calibration file knows what it was fitted from; validate and diagnose of it say so.

Fit then validate the same record: the first line says it is in-sample and what that figure does
not show. A part of that record (its stamps inside the fitted span, its samples the same): in-sample
too. Another record of the same unit (another noise seed, the same stamps): no such line. A file
written before ``fitted_from`` existed: no claim either way.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import yaml
from hypothesis import given, strategies as st

from tak_thermo_ros import cli
from tak_thermo_ros.core.records.provenance import (
    IN_SAMPLE_OVERLAP,
    IN_SAMPLE_PART,
    IN_SAMPLE_WHOLE,
    PrintCollector,
    RecordPrint,
    in_sample_lines,
    recognise,
)
from tak_thermo_ros.core.records.record import ChannelRecord
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import CalibrationError
from tak_thermo_ros.formats.bag import write_driver_record, write_record
from tak_thermo_ros.formats.calibration_file import (
    flatten_parameters,
    load_unit,
    nest_parameters,
    parse_parameters_yaml,
    unit_from_mapping,
    unit_to_mapping,
)
from tak_thermo_ros.formats.bag import Topics
from tak_thermo_ros.passes.run import StreamOptions
from tak_thermo_ros.passes.validate import validate_bag
from tak_thermo_ros.formats.records import open_record

COUNTS_RUN = Scenario(sample_rate_hz=2.0, plateaus_celsius=(10.0, 30.0), plateau_hours=0.05,
                      ramp_celsius_per_minute=5.0, board_lag_s=20.0, dwell_s=20.0)
"""A short chamber run of the paper's codes (about 12 min at 2 Hz)."""
DRIVER_RUN = replace(COUNTS_RUN, output='imu', positions=((0.0, 0.0, 1.0),), record_references=False)
"""The same as a driver's Imu, static."""
OPTIONS = StreamOptions(topics=Topics(), progress=False)


def _run(*args: str) -> int:
    return cli.main([*args, '--no-progress'])


def _crop(record: ChannelRecord, low: float, high: float) -> ChannelRecord:
    """The samples of ``record`` between the fractions ``low`` and ``high`` of its counts (temperatures beside)."""
    count = len(record.counts_stamp_ns)
    rows = slice(int(low * count), int(high * count))
    first, last = record.counts_stamp_ns[rows][[0, -1]]
    temperature = (record.temp_stamp_ns >= first - 10**10) & (record.temp_stamp_ns <= last)
    return replace(record, counts_stamp_ns=record.counts_stamp_ns[rows], counts=record.counts[rows],
                   temp_stamp_ns=record.temp_stamp_ns[temperature], temp_code=record.temp_code[temperature])


@pytest.fixture(scope='module')
def counts_records(tmp_path_factory):
    root = tmp_path_factory.mktemp('provenance')
    record = simulate(COUNTS_RUN).record
    write_record(root / 'run.mcap', record)
    write_record(root / 'other.mcap', simulate(replace(COUNTS_RUN, seed=9)).record)
    write_record(root / 'part.mcap', _crop(record, 0.3, 0.8))
    assert _run('fit', str(root / 'run.mcap'), '-o', str(root / 'run.yaml')) == 0
    return root


def test_validate_of_the_fitted_record_says_in_its_first_line_that_it_is_in_sample(counts_records, capsys):
    root = counts_records
    capsys.readouterr()
    assert _run('validate', str(root / 'run.mcap'), '--params', str(root / 'run.yaml')) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == 'in-sample: run.mcap is the record run.yaml was fitted from (the same samples)'
    assert "fit's own residual" in lines[1] and 'does not show' in lines[1]
    assert all(len(line) <= 100 for line in lines[:2])


def test_a_part_of_the_fitted_record_is_in_sample_and_another_record_is_not(counts_records, capsys):
    root = counts_records
    capsys.readouterr()
    assert _run('validate', str(root / 'part.mcap'), '--params', str(root / 'run.yaml')) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first.startswith('in-sample: part.mcap is ') and 'of run.mcap, which run.yaml was fitted from' in first
    unit = load_unit(root / 'run.yaml')
    found = validate_bag(open_record(root / 'part.mcap', topics=OPTIONS.topics), unit, OPTIONS,
                         gravity=STANDARD_GRAVITY).in_sample
    assert found.kind == IN_SAMPLE_PART and found.compared >= 1
    assert found.as_dict()['fitted_from'] == 'run.mcap'
    # Another record of the same unit: the same stamps, other noise.
    assert _run('validate', str(root / 'other.mcap'), '--params', str(root / 'run.yaml')) == 0
    assert 'in-sample' not in capsys.readouterr().out
    assert validate_bag(open_record(root / 'other.mcap', topics=OPTIONS.topics), unit, OPTIONS,
                        gravity=STANDARD_GRAVITY).in_sample is None


def test_diagnose_of_the_fitted_record_says_so_first(counts_records, capsys):
    root = counts_records
    capsys.readouterr()
    assert _run('diagnose', str(root / 'run.mcap'), '--params', str(root / 'run.yaml'), '--candidates', 'warmup',
                '--max-samples', '2000') == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith('in-sample: run.mcap is the record run.yaml was fitted from')
    assert "fit's own" in lines[1]
    assert _run('diagnose', str(root / 'other.mcap'), '--params', str(root / 'run.yaml'), '--candidates', 'warmup',
                '--max-samples', '2000') == 0
    assert 'in-sample' not in capsys.readouterr().out


def test_a_file_from_before_makes_no_claim_either_way(counts_records, tmp_path, capsys):
    """Without fitted_from the file loads as before and validate says nothing of in- or out-of-sample."""
    root = counts_records
    document = parse_parameters_yaml((root / 'run.yaml').read_text())
    section = next(iter(document.values()))['ros__parameters']['calibration']
    assert 'fitted_from' in section
    del section['fitted_from']
    (tmp_path / 'old.yaml').write_text(yaml.safe_dump(document))
    assert load_unit(tmp_path / 'old.yaml').fitted_from == ()
    capsys.readouterr()
    assert _run('validate', str(root / 'run.mcap'), '--params', str(tmp_path / 'old.yaml')) == 0
    assert 'sample' not in capsys.readouterr().out.splitlines()[0]


def test_a_driver_record_fitted_then_validated_and_its_print_as_ros_parameters(tmp_path, capsys):
    """Both sensors hashed; the file's lists survive the node's flat ROS 2 parameters."""
    write_driver_record(tmp_path / 'driver', simulate(DRIVER_RUN).driver)
    assert _run('fit', str(tmp_path / 'driver'), '-o', str(tmp_path / 'driver.yaml')) == 0
    unit = load_unit(tmp_path / 'driver.yaml')
    (fitted,) = unit.fitted_from
    assert dict(fitted.samples) == {'accel': len(simulate(DRIVER_RUN).driver.stamp_ns)} | {
        'gyro': len(simulate(DRIVER_RUN).driver.stamp_ns)}
    assert 8 <= len(fitted.segments) <= 64
    flat = flatten_parameters(unit_to_mapping(unit))
    assert all(isinstance(value, (str, int, float, bool, list)) for value in flat.values())
    assert all(not isinstance(item, (dict, list)) for value in flat.values() if isinstance(value, list)
               for item in value)
    assert unit_from_mapping(nest_parameters(flat)) == unit
    capsys.readouterr()
    assert _run('validate', str(tmp_path / 'driver'), '--params', str(tmp_path / 'driver.yaml')) == 0
    assert capsys.readouterr().out.startswith('in-sample: driver is the record driver.yaml was fitted from')


@pytest.mark.parametrize(('key', 'value', 'match'), [
    ('record', 'run', 'expected a list'),
    ('digest', [1], 'expected a string'),
    ('first_stamp_ns', [1.5], 'expected a whole number'),
    ('accel_samples', [1, 2], '2 entries, 1 records'),
    ('colour', ['red'], 'unknown key'),
    ('segment_ns', [0], 'segment_ns must be > 0'),
])
def test_a_bad_fitted_from_is_refused_naming_the_key(key, value, match):
    unit = load_unit_mapping()
    mapping = unit_to_mapping(unit)
    mapping['fitted_from'][key] = value
    with pytest.raises(CalibrationError, match=match):
        unit_from_mapping(mapping)


def load_unit_mapping():
    """A counts calibration with one record's print."""
    from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
    collector = PrintCollector(('accel',))
    collector.add({'accel': ChannelRecord(np.arange(100, dtype=np.int64) * 10**9, np.ones((100, 3)), np.zeros(0),
                                          np.zeros(0))})
    return UnitCalibration(InputKind.COUNTS, COUNTS_RUN.truth(), fitted_from=(collector.finish('run'),))


@given(cuts=st.lists(st.integers(0, 400), max_size=8), seed=st.integers(0, 2**16))
def test_a_record_s_print_does_not_depend_on_its_blocks(cuts, seed):
    """Any split of the samples into blocks gives the same print; a crop's segments match the whole's."""
    rng = np.random.default_rng(seed)
    stamps = np.sort(rng.integers(0, 10**12, 400)).astype(np.int64)
    values = rng.normal(size=(400, 3))

    def collected(bounds, against=()):
        collector = PrintCollector(('accel',), against=against)
        for low, high in zip(bounds[:-1], bounds[1:]):
            collector.add({'accel': ChannelRecord(stamps[low:high], values[low:high], np.zeros(0), np.zeros(0))})
        return collector

    whole = collected([0, 400]).finish('whole')
    split = collected([0, *sorted(cuts), 400]).finish('split')
    assert replace(split, name='whole') == whole
    part = collected([100, 300], against=(whole,))
    found = recognise((whole,), part.finish('part'), part.segments_against())
    assert found is not None and found.kind in (IN_SAMPLE_PART, 'span')
    same = collected([0, 400], against=(whole,))
    assert same.recognition('same').kind == IN_SAMPLE_WHOLE
    changed = values.copy()
    changed[150:250] += 1e-9
    other = PrintCollector(('accel',), against=(whole,))
    other.add({'accel': ChannelRecord(stamps, changed, np.zeros(0), np.zeros(0))})
    assert other.recognition('other') is None


def test_a_print_is_recognised_only_by_its_samples():
    """Same stamps, one value changed: not the record; samples outside the span: not in-sample."""
    print_ = RecordPrint('a', 0, 10, (('accel', 2),), 'f' * 32, 1 << 30, 0, ('00000000',))
    assert recognise((print_,), replace(print_, digest='e' * 32), [{}]) is None
    assert recognise((print_,), replace(print_, digest='e' * 32, first_stamp_ns=11, last_stamp_ns=20), [{}]) is None
    # Inside the span and too short to compare a whole segment: it may be in-sample, and says so.
    inside = recognise((print_,), replace(print_, digest='e' * 32, first_stamp_ns=2, last_stamp_ns=8), [{}])
    assert inside.kind == 'span'
    assert in_sample_lines(inside, record='b', params='p.yaml', command='validate')[0].startswith('may be in-sample')


def test_a_record_that_holds_the_fitted_one_and_more_is_in_sample_for_its_share():
    """Issue 43: ``validate real_driver --params last.yaml`` (the last 48 of its 71 min fitted) said nothing.

    The fitted record's edge segments hold only its own samples, the longer record's more: only the
    segments both hold whole are compared, and the longer record is in-sample for the fitted share.
    """
    rng = np.random.default_rng(4)
    stamps = np.arange(400, dtype=np.int64) * 10**9 + 123_456_789
    values = rng.normal(size=(400, 3))

    def collected(rows, against=()):
        collector = PrintCollector(('accel',), against=against)
        collector.add({'accel': ChannelRecord(stamps[rows], values[rows], np.zeros(0), np.zeros(0))})
        return collector

    last = collected(slice(130, 400)).finish('last')
    whole = collected(slice(0, 400), against=(last,))
    found = whole.recognition('real_driver')
    assert found is not None and found.kind == IN_SAMPLE_OVERLAP and found.compared >= 8
    assert found.overlap_s == pytest.approx(269.0) and found.duration_s == pytest.approx(399.0)
    assert in_sample_lines(found, record='real_driver', params='last.yaml', command='validate')[0] == (
        'in-sample: 4.5 of the 6.7 min of real_driver are from last, which last.yaml was fitted from')
    other = values.copy()
    other[200] += 1e-9  # one sample of the shared span differs: another record
    changed = PrintCollector(('accel',), against=(last,))
    changed.add({'accel': ChannelRecord(stamps, other, np.zeros(0), np.zeros(0))})
    assert changed.recognition('other') is None
