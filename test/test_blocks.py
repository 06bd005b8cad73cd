"""Block-wise alignment: the blocks of a run read in log order, concatenated, equal align() of the whole."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from conftest import SHORT
from tak_thermo_ros.core.blocks import BlockAligner, concatenate
from tak_thermo_ros.core.record import ChannelRecord, align
from tak_thermo_ros.core.simulate import simulate


def log_order_blocks(record: ChannelRecord, block_samples: int) -> list[ChannelRecord]:
    """Split a record as a bag reader would: messages in (stamp, stream) order, a block per main chunk."""
    events = sorted([(int(s), 0, i) for i, s in enumerate(record.temp_stamp_ns)]
                    + [(int(s), 1, i) for i, s in enumerate(record.reference_stamp_ns)]
                    + [(int(s), 2, i) for i, s in enumerate(record.counts_stamp_ns)])
    blocks, current = [], {0: [], 1: [], 2: []}

    def flush():
        t, r, c = (np.array(current[k], dtype=np.int64) for k in (0, 1, 2))
        blocks.append(ChannelRecord(counts_stamp_ns=record.counts_stamp_ns[c], counts=record.counts[c],
                                    temp_stamp_ns=record.temp_stamp_ns[t], temp_code=record.temp_code[t],
                                    reference_stamp_ns=record.reference_stamp_ns[r],
                                    reference=record.reference[r].reshape(-1, 3), frame_id=record.frame_id,
                                    input_kind=record.input_kind))
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
