"""A streamed run's bins (``BinnedRun``) and the sandwich of its link terms (``axis_sandwich``)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tak_thermo_ros.core.fit import binned_run, stream
from tak_thermo_ros.core.fit.binned_run import BinnedRun
from tak_thermo_ros.core.fit.stream import StreamingFit
from tak_thermo_ros.core.records.record import AlignedSamples

RATE_HZ = 5.0
SLOPE, CURVATURE = 2e-5, -3e-7
"""The truth's offset curve about 20 C: rad/s per C and per C^2."""


@settings(max_examples=40, deadline=None)
@given(blocks=st.lists(st.integers(min_value=0, max_value=5000), min_size=1, max_size=12),
       limit=st.integers(min_value=4, max_value=64))
def test_bins_keep_every_sample_in_time_order_within_their_bound(blocks, limit):
    """Any blocks: the bins' counts add up to the samples, their weighted means to the sums, stamps in order."""
    original = binned_run.MAX_BINS
    binned_run.MAX_BINS = limit
    try:
        run = BinnedRun()
        total = sum(blocks)
        values = np.arange(total, dtype=float)
        start = 0
        for size in blocks:
            part = values[start:start + size]
            run.add(part, part * 2.0, np.column_stack([part] * 3), np.column_stack([part] * 3))
            start += size
        means, counts = run.bins()
    finally:
        binned_run.MAX_BINS = original
    assert int(counts.sum()) == total
    assert len(means) <= limit + 1
    if total:
        np.testing.assert_allclose((means * counts[:, None]).sum(axis=0),
                                   [values.sum(), 2.0 * values.sum(), *[values.sum()] * 6], rtol=1e-12)
        assert np.all(np.diff(means[:, 0]) > 0.0)


def _chamber(seed: int, walk: float) -> tuple[StreamingFit, float]:
    """A 1.5-h static run, z up, through plateaus from 0 to 40 C; the gyro's bias wanders (``walk`` rad/s/sqrt(s)).

    :returns: the fit after its result, and the truth's curve from the lowest to the highest temperature.
    """
    rng = np.random.default_rng([seed, 61])
    count = int(1.5 * 3600 * RATE_HZ)
    time_s = np.arange(count) / RATE_HZ
    plateaus = np.repeat(np.linspace(0.0, 40.0, 5), count // 5 + 1)[:count]
    temperature = plateaus
    lag = np.exp(-1.0 / (300.0 * RATE_HZ))
    board = np.empty(count)
    board[0] = temperature[0]
    for k in range(1, count):  # the board follows the chamber through a 5-minute lag
        board[k] = lag * board[k - 1] + (1.0 - lag) * temperature[k]
    n = board - 20.0
    curve = SLOPE * n + CURVATURE * n ** 2
    wander = np.cumsum(rng.standard_normal((count, 3)), axis=0) * walk / math.sqrt(RATE_HZ)
    counts = curve[:, None] + wander + rng.standard_normal((count, 3)) * 2e-3
    fit = StreamingFit(bias_order=3, scale_order=0, nominal_scale=(1.0, 1.0, 1.0), temp_code_ref=20.0)
    for start in range(0, count, 4000):
        rows = slice(start, start + 4000)
        fit.add(AlignedSamples(stamp_ns=(time_s[rows] * 1e9).astype(np.int64), counts=counts[rows],
                               temp_code=board[rows], reference=np.zeros((len(time_s[rows]), 3)), dropped={}))
    fit.result()
    n_low, n_high = board.min() - 20.0, board.max() - 20.0
    return fit, (SLOPE * n_high + CURVATURE * n_high ** 2) - (SLOPE * n_low + CURVATURE * n_low ** 2)


def _z(fit: StreamingFit, truth: float) -> float:
    """The x offset curve's edge-to-edge error over the standard error the link's uncertainty states."""
    result = fit.result()
    axis = result.calibration.axes[0]
    calibration = result.calibration
    reference = calibration.temp_code_ref
    low, high = calibration.temp_code_min - reference, calibration.temp_code_max - reference
    error = (axis.offset_drift(high) - axis.offset_drift(low)) - truth
    section = fit.uncertainty('gyro')
    variance = section.offset_change_variance(0, low, high)
    return float(error / math.sqrt(variance))


def test_a_wandering_bias_is_in_the_streamed_curves_uncertainty(monkeypatch):
    """Over 40 runs with a random walk the 2-sigma band holds the curve's span about 95 % of the time.

    The white errors hold it in fewer than half: the walk over a run whose temperature rises with
    time reads as a slope.
    """
    runs = [_chamber(seed, walk=2e-5) for seed in range(40)]
    covered = [abs(_z(*run)) <= 2.0 for run in runs]
    assert 0.85 <= np.mean(covered) <= 1.0
    monkeypatch.setattr(stream, 'axis_sandwich', lambda *args, **kwargs: None)
    assert np.mean([abs(_z(*run)) <= 2.0 for run in runs]) < 0.5


def test_white_noise_keeps_the_white_errors():
    """No wander: the band is the white-noise one (z RMS about 1, not inflated past 1.5x)."""
    z = np.array([_z(*_chamber(seed, walk=0.0)) for seed in range(20)])
    assert 0.6 <= math.sqrt(np.mean(z ** 2)) <= 1.5
