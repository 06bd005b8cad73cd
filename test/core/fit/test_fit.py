"""Least-squares fit: recovery of known coefficients within the noise, the +/- method, ill-posed data."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from conftest import SHORT, noise_floor
from tak_thermo_ros.core.fit import fit_calibration
from tak_thermo_ros.core.fit.plus_minus import fit_plus_minus, plus_minus
from tak_thermo_ros.core.records.record import AlignedSamples, align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.errors import FitError


def _function_std(samples: AlignedSamples, axis: int, sigma: float, ref: float, grid_n: np.ndarray,
                  bias_order: int = 3, scale_order: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Standard deviation of the fitted dNs(n) and K0 F_c(n) on a grid, from sigma^2 (X'X)^-1."""
    n = samples.temp_code - ref
    scale = max(abs(n.min()), abs(n.max()))
    u = n / scale
    force = samples.reference[:, axis]
    design = np.column_stack([force * u ** j for j in range(scale_order + 1)] + [u ** j for j in range(bias_order + 1)])
    covariance = sigma ** 2 * np.linalg.inv(design.T @ design)
    grid_u = grid_n / scale
    gain_rows = np.column_stack([grid_u ** j for j in range(scale_order + 1)] + [0 * grid_u] * (bias_order + 1))
    offset_rows = np.column_stack([0 * grid_u] * (scale_order + 1) + [grid_u ** j for j in range(bias_order + 1)])
    offset_std = np.sqrt(np.einsum('ij,jk,ik->i', offset_rows, covariance, offset_rows))
    gain_std = np.sqrt(np.einsum('ij,jk,ik->i', gain_rows, covariance, gain_rows))
    return offset_std, gain_std


def test_fit_recovers_the_true_link_within_the_noise(short_run, short_samples):
    """Fitted dNs(n) and K0 F_c(n) lie within 5 standard errors of the truth over the whole range."""
    result = fit_calibration(short_samples)
    fitted, truth = result.calibration, short_run.truth
    sigma = noise_floor(short_run.scenario)
    low, high = fitted.code_offset_range()
    grid_n = np.linspace(low, high, 101)
    grid_true = grid_n + fitted.temp_code_ref - truth.temp_code_ref
    for i in range(3):
        offset_std, gain_std = _function_std(short_samples, i, sigma[i], fitted.temp_code_ref, grid_n)
        got_offset = fitted.axes[i].offset + fitted.axes[i].offset_drift(grid_n)
        true_offset = truth.axes[i].offset + truth.axes[i].offset_drift(grid_true)
        got_gain = fitted.axes[i].scale * fitted.axes[i].scale_factor(grid_n)
        true_gain = truth.axes[i].scale * truth.axes[i].scale_factor(grid_true)
        assert np.all(np.abs(got_offset - true_offset) < 5 * offset_std), f'axis {i} offset'
        assert np.all(np.abs(got_gain - true_gain) < 5 * gain_std), f'axis {i} gain'
        assert result.axes[i].residual_rms == pytest.approx(sigma[i], rel=0.05)


def test_fit_residual_is_at_the_noise_floor_and_reports_bic(short_run, short_samples):
    """Residual RMS equals the simulated noise floor; a lower-order model has a higher BIC."""
    full = fit_calibration(short_samples)
    too_simple = fit_calibration(short_samples, bias_order=1, scale_order=0)
    for i in range(3):
        assert full.axes[i].bic < too_simple.axes[i].bic
        assert too_simple.axes[i].residual_rms > 1.1 * noise_floor(short_run.scenario)[i]
    assert full.calibration.axes[0].residual_rms == full.axes[0].residual_rms


def test_plus_minus_equations():
    """Eqs. 3-5: offset is the half-sum, scale the half-difference over the input."""
    offset, scale = plus_minus(2512.0, -2488.0, 9.8)
    assert offset == 12.0 and scale == pytest.approx(2500.0 / 9.8)


def test_plus_minus_method_agrees_with_least_squares():
    """On +/-g data the paper's +/- method and the least-squares fit give the same link within the noise."""
    six = ((1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0), (0.0, 0.0, -1.0))
    run = simulate(replace(SHORT, positions=six, seed=4))
    samples = align(run.record)
    least_squares = fit_calibration(samples).calibration
    paper = fit_plus_minus(samples, temp_code_ref=least_squares.temp_code_ref)
    sigma = noise_floor(run.scenario)
    low, high = least_squares.code_offset_range()
    grid = np.linspace(low, high, 51)
    for i in range(3):
        # Each +/- point averages about one dwell of samples per sign on a plateau; the polynomial
        # through the points has a few points' worth of noise at worst.
        samples_per_sign = int(SHORT.dwell_s * SHORT.sample_rate_hz)
        point_std = sigma[i] / np.sqrt(samples_per_sign)
        ls, pm = least_squares.axes[i], paper.axes[i]
        offset_gap = (ls.offset + ls.offset_drift(grid)) - (pm.offset + pm.offset_drift(grid))
        gain_gap = ls.scale * ls.scale_factor(grid) - pm.scale * pm.scale_factor(grid)
        assert np.max(np.abs(offset_gap)) < 5 * point_std
        assert np.max(np.abs(gain_gap)) < 5 * point_std / SHORT.gravity


def _subset(samples: AlignedSamples, keep: np.ndarray) -> AlignedSamples:
    return AlignedSamples(stamp_ns=samples.stamp_ns[keep], counts=samples.counts[keep],
                          temp_code=samples.temp_code[keep],
                          reference=None if samples.reference is None else samples.reference[keep],
                          dropped={})


def test_no_temperature_spread_is_refused(short_samples):
    """One plateau only: the fit refuses and says why."""
    codes, frequency = np.unique(short_samples.temp_code, return_counts=True)
    keep = short_samples.temp_code == codes[np.argmax(frequency)]
    assert keep.sum() > 200
    with pytest.raises(FitError, match='no temperature spread'):
        fit_calibration(_subset(short_samples, keep))


def test_too_few_samples_is_refused(short_samples):
    """Fewer than ten samples per parameter is refused."""
    with pytest.raises(FitError, match='too few samples: 50 usable'):
        fit_calibration(_subset(short_samples, np.arange(len(short_samples)) < 50))


def test_axis_with_one_input_needs_a_nominal_scale(short_samples):
    """An axis that never sees two inputs cannot be fitted without a nominal scale to hold."""
    keep = np.all(short_samples.reference == short_samples.reference[0], axis=1)
    only_one_position = _subset(short_samples, keep)
    with pytest.raises(FitError, match=r'axis x sees one input only .* give the nominal scale'):
        fit_calibration(only_one_position)


def test_inputs_that_do_not_cover_the_temperatures_are_refused(short_samples):
    """+g seen at two temperatures, -g at two others only: scale and offset shapes cannot be separated."""
    codes, frequency = np.unique(short_samples.temp_code, return_counts=True)
    plateaus = np.sort(codes[np.argsort(frequency)[-4:]])
    up = np.isin(short_samples.temp_code, plateaus[:2]) & (short_samples.reference[:, 0] > 9.0)
    down = np.isin(short_samples.temp_code, plateaus[2:]) & (short_samples.reference[:, 0] < -9.0)
    confounded = _subset(short_samples, up | down)
    with pytest.raises(FitError, match='axis x: the data cannot separate the model terms'):
        fit_calibration(confounded)


def test_no_reference_is_refused(short_samples):
    """A run without reference cannot be fitted."""
    with pytest.raises(FitError, match='no reference stream'):
        fit_calibration(AlignedSamples(stamp_ns=short_samples.stamp_ns, counts=short_samples.counts,
                                       temp_code=short_samples.temp_code, reference=None, dropped={}))
