"""Whether a compensated run is a static run: decided by what the compensation leaves, not by a span.

A noise model is an independent yardstick (``source='static_run'``) when the run holds nothing
but the sensor's noise. A powered unit in a 20 C chamber warms by itself to 26 C: its raw output
drifts with those 6 C, but corrected by a calibration that covers the span, what is left is the
noise again, and the run is a static run. Whether it is, the compensated residual says:

- its **trend against temperature** (:func:`temperature_trend`): the run's samples in
  :data:`TREND_BINS` equal stretches of time, the changes of their mean residual from one
  stretch to the next regressed on the changes of their mean temperature, per axis. Differences,
  not levels: a random walk's levels follow any monotone temperature (a spurious regression), its
  differences do not. The slope's Student t over the stretches' own scatter (the residual's
  wander and correlation in it) must stay within :data:`TREND_T` on every axis, or the
  compensation leaves a drift with temperature;
- the run is **not a sweep**: its span is at most :data:`SWEEP_FRACTION` of the calibrated range
  (a sweep across the range excites every thermal effect the calibration may miss: its residual
  is what the model leaves, not noise), and inside that range (the calibration covers it).

Without a calibration nothing compensates the drift: only a run at constant temperature (within
``CONSTANT_TEMPERATURE_C``, :mod:`tak_thermo_ros.passes.noise`) is a static run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TREND_BINS = 16
"""Equal stretches of time whose mean residual and temperature the trend test compares."""
TREND_T = 4.0
"""Largest Student t of the trend's slope on any axis of a static run (15 differences: 0.13 % of
runs without a trend reach it per axis, about 1 % over two sensors' six axes)."""
SWEEP_FRACTION = 0.5
"""A compensated run spanning more than this share of the calibrated temperature range is a sweep."""
RANGE_SLACK = 0.05
"""How far (as a share of the calibrated range) a static run may reach beyond it: covered."""


@dataclass(frozen=True)
class TemperatureTrend:
    """What a compensation leaves of the drift with temperature, per axis.

    :param slope: ``(3,)`` residual per degree (per code) from stretch to stretch.
    :param t: ``(3,)`` that slope over its standard error (the stretches' own scatter).
    :param bins: the stretches compared (0: too few samples or no temperature change).
    """

    slope: np.ndarray
    t: np.ndarray
    bins: int

    @property
    def flat(self) -> bool:
        """Whether no axis shows a trend against temperature (``|t| <= TREND_T``)."""
        return bool(np.all(np.abs(self.t) <= TREND_T))

    @property
    def largest_t(self) -> float:
        """The largest ``|t|`` over the axes."""
        return float(np.max(np.abs(self.t))) if len(self.t) else 0.0


def temperature_trend(time_s: np.ndarray, temperature: np.ndarray, residual: np.ndarray, *,
                      bins: int = TREND_BINS) -> TemperatureTrend:
    """The trend of a residual ``(k, 3)`` against temperature, from the differences of stretch means.

    :param time_s: ``(k,)`` the samples' times (any origin); ``temperature`` ``(k,)`` theirs.
    """
    time_s = np.asarray(time_s, dtype=float)
    temperature = np.asarray(temperature, dtype=float)
    residual = np.asarray(residual, dtype=float).reshape(len(time_s), -1)
    axes = residual.shape[1]
    none = TemperatureTrend(np.zeros(axes), np.zeros(axes), 0)
    finite = np.isfinite(temperature) & np.all(np.isfinite(residual), axis=1)
    if finite.sum() < 4 * bins:
        return none
    time_s, temperature, residual = time_s[finite], temperature[finite], residual[finite]
    span = time_s.max() - time_s.min()
    labels = np.minimum(((time_s - time_s.min()) / max(span, 1e-12) * bins).astype(int), bins - 1)
    counts = np.bincount(labels, minlength=bins)
    used = counts > 0
    if used.sum() < 4:
        return none
    mean_t = np.bincount(labels, weights=temperature, minlength=bins)[used] / counts[used]
    mean_r = np.stack([np.bincount(labels, weights=residual[:, i], minlength=bins)[used]
                       for i in range(axes)], axis=1) / counts[used][:, None]
    d_t, d_r = np.diff(mean_t), np.diff(mean_r, axis=0)
    sxx = float(d_t @ d_t)
    if sxx <= 0.0:
        return none
    slope = (d_t @ d_r) / sxx
    scatter = d_r - np.outer(d_t, slope)
    dof = max(len(d_t) - 1, 1)
    error = np.sqrt(np.sum(scatter ** 2, axis=0) / dof / sxx)
    t = np.where(error > 0.0, slope / np.where(error > 0.0, error, 1.0), 0.0)
    return TemperatureTrend(slope, t, int(used.sum()))


def compensated_static(span: tuple[float, float], calibrated: tuple[float, float],
                       trends: list[TemperatureTrend]) -> tuple[bool, str]:
    """Whether a compensated run is a static run, and why in a few words.

    :param span: the run's lowest and highest temperature; ``calibrated`` the calibration's range.
    :param trends: per sensor, what the compensation leaves (:func:`temperature_trend`).
    """
    low, high = span
    c_low, c_high = calibrated
    width = max(c_high - c_low, 1e-12)
    if low < c_low - RANGE_SLACK * width or high > c_high + RANGE_SLACK * width:
        return False, 'beyond the calibrated range'
    if high - low > SWEEP_FRACTION * width:
        return False, f'a sweep over {100.0 * (high - low) / width:.0f} % of the calibrated range'
    worst = max((trend.largest_t for trend in trends), default=0.0)
    if not all(trend.flat for trend in trends):
        return False, f'the compensation leaves a trend with temperature (t {worst:.1f})'
    return True, f'compensated: no trend with temperature left (|t| at most {worst:.1f})'
