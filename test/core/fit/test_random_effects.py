"""A pool's random effects: the REML of a known random-intercept model, the screening of records, the pool's records."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tak_thermo_ros.core.fit.random_effects import fit_variances, screen_offsets
from tak_thermo_ros.core.records.handheld import HandheldRecord, pooled, records_subset
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.core.records.still import StillIntervals


def _one_way_criterion(means: np.ndarray, white: float):
    """``-2 log REML`` of ``y_rk = mu + u_r + e_rk``: records ``r`` of ``k`` rests, the white noise known, ``t`` = 0."""
    records, rests = means.shape
    y = means.reshape(-1)
    record = np.repeat(np.arange(records), rests)
    design = np.ones((len(y), 1))

    def criterion(turn_on: np.ndarray, rest: np.ndarray) -> float:
        s2u, s2 = turn_on[0] ** 2, white ** 2 + rest[0] ** 2
        cov = s2 * np.eye(len(y)) + s2u * (record[:, None] == record[None, :])
        inverse = np.linalg.inv(cov)
        xvx = design.T @ inverse @ design
        beta = np.linalg.solve(xvx, design.T @ inverse @ y)
        r = y - design @ beta
        return float(np.linalg.slogdet(cov)[1] + np.linalg.slogdet(xvx)[1] + r @ inverse @ r)

    return criterion


def test_the_reml_of_a_random_intercept_covers_its_truth_over_seeds():
    """Over 60 pools of 12 records the spread's REML lies within 2 of its errors of the truth about 95 % of the time."""
    covered = []
    for seed in range(60):
        rng = np.random.default_rng(seed)
        offsets = rng.standard_normal(12) * 3.0
        means = 10.0 + offsets[:, None] + rng.standard_normal((12, 4)) * 1.0
        found = fit_variances(_one_way_criterion(means, 1.0), np.array([1.0, 1.0, 1.0]), np.array([0.1, 0.1, 0.1]),
                              np.array([True, False, False]), np.array([1.0, 1.0, 1.0]))
        covered.append(abs(found.turn_on[0] - 3.0) <= 2.0 * found.turn_on_error[0])
    assert 0.85 <= np.mean(covered) <= 1.0


def test_screening_finds_another_unit_and_rarely_one_that_is_not():
    """A record 30 spreads away is left out; among 2000 pools of one unit (8 records) at most 0.5 % flag any."""
    rng = np.random.default_rng(1)
    precision = np.full((8, 3), 0.05)
    false = 0
    for _ in range(2000):
        screening = screen_offsets(rng.standard_normal((8, 3)), precision)
        false += bool(screening.outliers or screening.groups)
    assert false <= 10
    offsets = rng.standard_normal((8, 3))
    offsets[5, 1] += 30.0
    screening = screen_offsets(offsets, precision)
    assert [row[:2] for row in screening.outliers] == [(5, 1)] and not screening.groups
    offsets = rng.standard_normal((8, 3))
    offsets[4:, 0] += 40.0
    screening = screen_offsets(offsets, precision)
    assert screening.groups == ((0, 1, 2, 3), (4, 5, 6, 7)) and screening.axis == 0


def _record(counts: list[int], start: int) -> HandheldRecord:
    """A record with ``counts[i]`` still samples in interval ``i``, stamped from ``start`` ns, one second apart."""
    stamps = start + np.arange(sum(counts), dtype=np.int64) * 1_000_000_000
    interval = np.repeat(np.arange(len(counts)), counts)
    edges = np.cumsum([0, *counts])
    intervals = StillIntervals(start_ns=stamps[edges[:-1]], end_ns=stamps[edges[1:] - 1],
                               samples=np.array(counts), mean=np.zeros((len(counts), 6)), noise=np.ones(6),
                               window_samples=8, period_s=1.0, windows=len(stamps), still_windows=len(stamps),
                               gaps=np.zeros((0, 2), dtype=np.int64), first_ns=int(stamps[0]),
                               last_ns=int(stamps[-1]), count=len(stamps))
    still = AlignedSamples(stamp_ns=stamps, counts=np.zeros((len(stamps), 6)), temp_code=np.zeros(len(stamps)),
                           reference=None, dropped={}, rows=np.arange(len(stamps)))
    empty = AlignedSamples(stamp_ns=np.zeros(0, dtype=np.int64), counts=np.zeros((0, 6)), temp_code=np.zeros(0),
                           reference=None, dropped={}, rows=np.zeros(0, dtype=np.int64))
    return HandheldRecord(intervals=intervals, still=still, still_interval=interval, turn=empty,
                          turn_index=np.zeros(0, dtype=np.int64), turns=np.zeros((0, 2), dtype=np.int64))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.lists(st.integers(1, 5), min_size=1, max_size=4), min_size=1, max_size=5),
       st.lists(st.booleans(), min_size=5, max_size=5), st.booleans())
def test_a_pool_keeps_each_records_samples_and_a_subset_keeps_the_records_asked(shapes, keep, overlap):
    """Pooled, every sample keeps its record and its rest; records run forward in time; a subset keeps what it asks."""
    parts = [_record(counts, 0 if overlap else index * 10 ** 12) for index, counts in enumerate(shapes)]
    pool = pooled(parts, [f'r{i}' for i in range(len(parts))])
    assert pool.records == len(parts)
    assert np.array_equal(np.bincount(pool.still_record, minlength=len(parts)), [len(p.still) for p in parts])
    assert np.all(np.diff(pool.still.stamp_ns) > 0)  # overlapping records are set one after the other
    mask = np.array(keep[:len(parts)])
    if not mask.any():
        return
    subset = records_subset(pool, mask)
    assert subset.record_names == tuple(f'r{i}' for i in np.flatnonzero(mask))
    assert len(subset.still) == sum(len(p.still) for p, k in zip(parts, mask) if k)
    assert np.array_equal(np.bincount(subset.still_interval), np.concatenate(
        [np.array(counts) for counts, k in zip(shapes, mask) if k]))
