"""Block-wise alignment: the blocks of a run read in log order, concatenated, equal align() of the whole."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from conftest import SHORT
from tak_thermo_ros.core.records.blocks import BlockAligner, concatenate
from tak_thermo_ros.core.records.record import ChannelRecord, align
from tak_thermo_ros.core.simulation.imu import simulate


def log_order_blocks(record: ChannelRecord, block_samples: int) -> list[ChannelRecord]:
    """Split a record as a bag reader would: messages in (stamp, stream) order, a block per main chunk.

    The main stream keeps its own order (a sample stamped earlier than the one before it is
    logged after it); recorded signals (``aux``) are streams 3, 4, ...
    """
    logged_at = np.maximum.accumulate(record.counts_stamp_ns) if len(record.counts_stamp_ns) else record.counts_stamp_ns
    names = list(record.aux)
    events = sorted([(int(s), 0, i) for i, s in enumerate(record.temp_stamp_ns)]
                    + [(int(s), 1, i) for i, s in enumerate(record.reference_stamp_ns)]
                    + [(int(s), 2, i) for i, s in enumerate(logged_at)]
                    + [(int(s), 3 + k, i) for k, name in enumerate(names) for i, s in enumerate(record.aux[name][0])])
    blocks, current = [], {k: [] for k in range(3 + len(names))}

    def flush():
        t, r, c = (np.array(current[k], dtype=np.int64) for k in (0, 1, 2))
        aux = {}
        for k, name in enumerate(names):
            rows = np.array(current[3 + k], dtype=np.int64)
            aux[name] = (record.aux[name][0][rows], record.aux[name][1][rows])
        blocks.append(ChannelRecord(counts_stamp_ns=record.counts_stamp_ns[c], counts=record.counts[c],
                                    temp_stamp_ns=record.temp_stamp_ns[t], temp_code=record.temp_code[t],
                                    reference_stamp_ns=record.reference_stamp_ns[r],
                                    reference=record.reference[r].reshape(-1, 3), frame_id=record.frame_id,
                                    input_kind=record.input_kind, aux=aux))
        for k in current:
            current[k] = []

    for _, stream, row in events:
        current[stream].append(row)
        if stream == 2 and len(current[2]) == block_samples:
            flush()
    flush()
    return blocks


def aligned_in_blocks(record: ChannelRecord, block_samples: int, **options):
    aligner = BlockAligner(reference_expected=record.has_reference, **options)
    parts = [aligner.push(block) for block in log_order_blocks(record, block_samples)]
    parts.append(aligner.finish())
    return concatenate(parts), aligner


def assert_same(blocked, whole):
    assert np.array_equal(blocked.stamp_ns, whole.stamp_ns)
    assert np.array_equal(blocked.counts, whole.counts, equal_nan=True)
    assert np.array_equal(blocked.temp_code, whole.temp_code)
    assert np.array_equal(blocked.rows, whole.rows)
    if whole.reference is None:
        assert blocked.reference is None
    else:
        assert np.array_equal(blocked.reference, whole.reference)
    assert blocked.dropped == whole.dropped
    assert blocked.ignored_temp_codes == whole.ignored_temp_codes
    assert blocked.ignored_references == whole.ignored_references
    assert sorted(blocked.aux) == sorted(whole.aux)
    for name, values in whole.aux.items():
        assert np.array_equal(blocked.aux[name], values, equal_nan=True), name


@pytest.fixture(scope='module')
def counts_record():
    """A short counts run with bad codes, samples before the first temperature and reference."""
    run = simulate(replace(SHORT, plateau_hours=0.1, seed=5))
    record = run.record
    counts = record.counts.copy()
    counts[10] = np.nan
    counts[20, 1] = 0.5
    counts[30, 2] = 32767.0
    # The first temperature and reference come after the first 25 samples.
    temp_stamp = record.temp_stamp_ns.copy()
    temp_stamp[0] = record.counts_stamp_ns[25]
    reference_stamp = record.reference_stamp_ns.copy()
    reference_stamp[0] = record.counts_stamp_ns[40]
    return replace(record, counts=counts, temp_stamp_ns=temp_stamp, reference_stamp_ns=reference_stamp)


@pytest.mark.parametrize('block_samples', [1, 7, 1000, 100_000])
@pytest.mark.parametrize('settle_time_s', [0.0, 45.0])
def test_counts_blocks_equal_whole_alignment(counts_record, block_samples, settle_time_s):
    """Held temperature and reference, drops by reason and rows equal align() for any block size."""
    whole = align(counts_record, settle_time_s=settle_time_s)
    blocked, aligner = aligned_in_blocks(counts_record, block_samples, settle_time_s=settle_time_s)
    assert {'non_finite', 'non_integer', 'saturated', 'before_first_temp_code',
            'before_first_reference'} <= set(whole.dropped)
    if settle_time_s:
        assert whole.dropped['settling'] > 0
    assert_same(blocked, whole)
    assert aligner.kept == len(whole) and aligner.dropped == whole.dropped


def test_pending_samples_are_bounded_and_still_exact(counts_record):
    """With few samples allowed to wait, sparse held streams still give the same alignment."""
    blocked, aligner = aligned_in_blocks(counts_record, 50, max_pending=3)
    assert_same(blocked, align(counts_record))
    assert len(aligner.state.pending_stamp_ns) == 0


def test_without_reference_as_apply_aligns(counts_record):
    """use_reference false (apply): no reference held, no reference drops."""
    whole = align(counts_record, use_reference=False)
    blocked, _ = aligned_in_blocks(counts_record, 333, use_reference=False)
    assert_same(blocked, whole)


@pytest.mark.parametrize('sensor', ['accel', 'gyro', 'six'])
def test_driver_blocks_equal_whole_alignment(sensor):
    """Driver Imu input (values in SI units, temperature in C): each sensor and the six channels."""
    run = simulate(replace(SHORT, output='imu', plateau_hours=0.1, seed=6,
                           positions=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
                           table_rates=(0.0, 1.0, -1.0)))
    driver = run.driver
    accel = driver.accel.copy()
    accel[3] = np.inf
    driver = replace(driver, accel=accel)
    record = driver.six_channels() if sensor == 'six' else driver.channel(sensor)
    use_reference = sensor != 'six'
    whole = align(record, use_reference=use_reference)
    blocked, _ = aligned_in_blocks(record, 257, use_reference=use_reference)
    assert whole.dropped.get('non_finite', 0) == (0 if sensor == 'gyro' else 1)
    assert_same(blocked, whole)


EDGE = 50
"""Block size of the tests that put a stamp problem on a block edge."""


@pytest.fixture(scope='module')
def unreliable_record(counts_record):
    """Bad temperature codes and references (ignored, not held), stamp problems on block edges, a supply signal.

    Sample ``EDGE`` repeats the stamp of the sample before it and sample ``3 * EDGE`` is stamped
    before it: both are the first of a block of ``EDGE`` samples. The recorded supply starts
    after the first 60 samples, holds a NaN (never held) and is logged at a lower rate.
    """
    record = counts_record
    stamps = record.counts_stamp_ns.copy()
    stamps[EDGE] = stamps[EDGE - 1]
    stamps[3 * EDGE] = stamps[3 * EDGE - 1] - 1_000_000
    stamps[5 * EDGE + 3] = stamps[5 * EDGE + 2] - 1_000_000  # inside a block too
    temp_code = record.temp_code.copy()
    temp_code[3] = np.nan
    temp_code[5] = 1.0e12
    temp_code[len(temp_code) // 2] = -np.inf
    reference = record.reference.copy()
    reference[2] = (np.nan, 0.0, 9.8)
    reference[len(reference) - 2] = (0.0, 1.0e5, 0.0)
    supply_stamps = stamps[60::7].copy()
    volts = 12.0 + 0.01 * np.sin(np.arange(len(supply_stamps)) / 9.0)
    volts[4] = np.nan
    return replace(record, counts_stamp_ns=stamps, temp_code=temp_code, reference=reference,
                   aux={'aux:/power/supply': (supply_stamps, volts)})


@pytest.mark.parametrize('block_samples', [1, 7, EDGE, 100_000])
@pytest.mark.parametrize('use_reference', [True, False])
def test_ignored_messages_stamp_problems_and_signals_across_blocks(unreliable_record, block_samples, use_reference):
    """Ignored counts, duplicate/backwards stamps at block edges and a held signal equal align() of the whole."""
    whole = align(unreliable_record, use_reference=use_reference)
    assert whole.ignored_temp_codes == {'non_finite': 2, 'implausible': 1}
    assert whole.ignored_references == ({'non_finite': 1, 'implausible': 1} if use_reference else {})
    assert whole.dropped['duplicate_stamp'] == 1 and whole.dropped['time_backwards'] == 2
    assert np.isnan(whole.aux['aux:/power/supply']).any() and np.isfinite(whole.aux['aux:/power/supply']).any()
    blocked, aligner = aligned_in_blocks(unreliable_record, block_samples, use_reference=use_reference)
    assert_same(blocked, whole)
    assert aligner.ignored_temp_codes == whole.ignored_temp_codes
    assert aligner.ignored_references == whole.ignored_references


def test_a_stamp_problem_on_a_block_edge_is_seen_from_the_carried_stamp(unreliable_record):
    """Without the previous block's last stamp the first sample of a block would pass."""
    blocks = log_order_blocks(unreliable_record, EDGE)
    aligner = BlockAligner(reference_expected=True)
    dropped = [aligner.push(block).dropped for block in blocks[:4]]
    assert len(blocks[1].counts_stamp_ns) == EDGE and blocks[1].counts_stamp_ns[0] == blocks[0].counts_stamp_ns[-1]
    assert sum(d.get('duplicate_stamp', 0) for d in dropped) == 1
    assert sum(d.get('time_backwards', 0) for d in dropped) == 1
