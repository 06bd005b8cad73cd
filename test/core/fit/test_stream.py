"""The streaming fit (blocked QR, provisional reference carried over exactly) equals the in-memory fit."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from conftest import SHORT
from tak_thermo_ros.core.fit import fit_calibration
from tak_thermo_ros.core.records.record import AlignedSamples, align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.fit.stream import StreamingFit, fit_in_blocks
from tak_thermo_ros.errors import FitError


def blocks_of(samples: AlignedSamples, size: int) -> list[AlignedSamples]:
    return [AlignedSamples(stamp_ns=samples.stamp_ns[i:i + size], counts=samples.counts[i:i + size],
                           temp_code=samples.temp_code[i:i + size],
                           reference=None if samples.reference is None else samples.reference[i:i + size],
                           dropped=samples.dropped if i == 0 else {})
            for i in range(0, len(samples), size)]


def assert_equal_fits(streamed, whole, rel=1e-9):
    a, b = streamed.calibration, whole.calibration
    assert (a.temp_code_ref, a.temp_code_min, a.temp_code_max) == (b.temp_code_ref, b.temp_code_min, b.temp_code_max)
    assert a.notes == b.notes
    for axis_a, axis_b, stats_a, stats_b in zip(a.axes, b.axes, streamed.axes, whole.axes):
        assert axis_a.scale_observable == axis_b.scale_observable
        for name in ('scale', 'offset', 'offset_span', 'residual_rms'):
            assert getattr(axis_a, name) == pytest.approx(getattr(axis_b, name), rel=rel, abs=1e-12), name
        np.testing.assert_allclose(axis_a.offset_shape, axis_b.offset_shape, rtol=rel, atol=1e-12)
        np.testing.assert_allclose(axis_a.scale_shape, axis_b.scale_shape, rtol=rel, atol=1e-15)
        assert stats_a.bic == pytest.approx(stats_b.bic, rel=rel)
        assert stats_a.parameters == stats_b.parameters
    assert streamed.samples == whole.samples and streamed.dropped == whole.dropped


@pytest.mark.parametrize('block', [37, 1000, 50_000])
def test_streamed_fit_equals_fit_calibration(short_samples, block):
    """Any block size: the coefficients, residual RMS and BIC agree to 1e-9 relative."""
    assert_equal_fits(fit_in_blocks(blocks_of(short_samples, block)), fit_calibration(short_samples))


def test_temperature_range_growing_both_ways_and_given_reference(short_samples):
    """Blocks visited from the middle of the run outwards (the range grows many times), orders varied."""
    order = np.argsort(np.abs(short_samples.temp_code - np.median(short_samples.temp_code)), kind='stable')
    shuffled = AlignedSamples(stamp_ns=short_samples.stamp_ns[order], counts=short_samples.counts[order],
                              temp_code=short_samples.temp_code[order], reference=short_samples.reference[order],
                              dropped=short_samples.dropped)
    for options in ({}, {'bias_order': 2, 'scale_order': 0}, {'temp_code_ref': 1000.0}):
        assert_equal_fits(fit_in_blocks(blocks_of(shuffled, 500), **options),
                          fit_calibration(short_samples, **options), rel=1e-8)


def test_held_axis_and_driver_units():
    """A static driver run: every axis sees one input, scale held at nominal 1, offset in m/s^2."""
    run = simulate(replace(SHORT, output='imu', positions=((0.0, 0.0, 1.0),), record_references=True,
                           plateau_hours=0.2, seed=3))
    samples = align(run.driver.channel('accel'))
    whole = fit_calibration(samples, nominal_scale=(1.0, 1.0, 1.0))
    streamed = fit_in_blocks(blocks_of(samples, 999), nominal_scale=(1.0, 1.0, 1.0))
    assert all(not axis.scale_observable for axis in whole.calibration.axes)
    assert_equal_fits(streamed, whole)


def test_errors_match_the_in_memory_fit(short_samples):
    """Too few samples, no spread, held axis without nominal scale: the same messages."""
    few = blocks_of(AlignedSamples(stamp_ns=short_samples.stamp_ns[:20], counts=short_samples.counts[:20],
                                   temp_code=short_samples.temp_code[:20], reference=short_samples.reference[:20],
                                   dropped={}), 7)
    flat = replace(short_samples, temp_code=np.full(len(short_samples), 1234.0))
    one_input = replace(short_samples, reference=np.tile(short_samples.reference[:1], (len(short_samples), 1)))
    for samples, blocks in ((few[0], few), (flat, blocks_of(flat, 1000)), (one_input, blocks_of(one_input, 1000))):
        with pytest.raises(FitError) as expected:
            fit_calibration(samples if samples is not few[0] else _join(few))
        with pytest.raises(FitError) as got:
            fit_in_blocks(blocks)
        assert str(got.value) == str(expected.value)


def _join(blocks):
    return AlignedSamples(stamp_ns=np.concatenate([b.stamp_ns for b in blocks]),
                          counts=np.concatenate([b.counts for b in blocks]),
                          temp_code=np.concatenate([b.temp_code for b in blocks]),
                          reference=np.concatenate([b.reference for b in blocks]), dropped={})


def test_memory_does_not_hold_samples(short_samples):
    """The accumulator's arrays are a few small triangles, whatever the number of samples."""
    fit = StreamingFit()
    for block in blocks_of(short_samples, 1000):
        fit.add(block)
    assert sum(factor.nbytes for factor in fit._factors) == 3 * 8 * fit.columns ** 2
