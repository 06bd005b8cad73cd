"""Within a fit's stretches, the white noise: the Allan variance at one sample and at one window.

Step 1 of :mod:`tak_thermo_ros.core.noise.rests` (its docstring tells the whole): :class:`ShortSums`
holds the Allan variance's terms summed within the stretches, :func:`white_noise` gives each
channel's density (and a quantisation or a driver's filter where one sample and one window
disagree), :func:`wander_ceiling` the most wander the window's Allan variance allows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.core.noise.model import FLICKER_FLOOR, filtered_white_allan_variance

SIGNIFICANT_RATIO = 3.0
"""The white noise density from one sample lies this many standard errors of the difference outside what one
window's allows: quantisation (above) or a driver's filter (below)."""


@dataclass(frozen=True)
class ShortSums:
    """The Allan variance's terms within stretches, summed per channel (SI units of the corrected output).

    :param period_s: the sampling interval.
    :param window_s: the window the second sums are taken at (its mean's averaging time).
    :param one: ``(c,)`` the sum of half the squared step between successive samples; ``one_terms`` how many.
    :param window: ``(c,)`` the sum of half the squared step between successive windows' means; ``window_terms``.
    """

    period_s: float
    window_s: float
    one: np.ndarray
    one_terms: int
    window: np.ndarray
    window_terms: int


@dataclass(frozen=True)
class White:
    """One channel's noise within the stretches.

    :param density: the white noise density ``N`` (units/sqrt(Hz)); ``error`` its standard error.
    :param quantization: ``Q`` (units*s), 0 when one sample shows no more than white noise.
    :param filter_time_constant: a driver's first-order low-pass (s), 0 when one sample shows no less.
    """

    density: float
    error: float
    quantization: float = 0.0
    filter_time_constant: float = 0.0


def white_noise(sums: ShortSums, wander: np.ndarray | None = None) -> list[White]:
    """Each channel's white noise from the Allan variance at one sample and at one window.

    :param wander: ``(c,)`` the most the wander can add to the Allan variance at one window (its terms at
        their upper limits), or ``None`` (nothing).

    ``N^2 = tau avar(tau)`` at both times for white noise, and the window's holds the wander's share
    besides (0 up to ``wander``). Where one sample's lies within that range (within
    :data:`SIGNIFICANT_RATIO` standard errors of the difference) the white noise is all there is
    at the shortest times, and the density is one sample's (many more terms, no wander in it); where
    it lies above, the difference is quantisation, below, a driver's filter, and the density is the
    window's less half the wander's share, give or take all of it (the long-term one a rest's mean
    averages). Stretches too short for two windows (a table's 10-s dwells at 1 Hz) give it from one
    sample alone (no filter or quantisation told apart).
    """
    tau0, window = sums.period_s, sums.window_s
    out = []
    for channel in range(len(sums.window)):
        if sums.one_terms < 1:
            out.append(White(0.0, 0.0))
            continue
        at_one = float(sums.one[channel]) / sums.one_terms
        # Successive differences share a sample (successive windows' a mean): about 1.5 terms per degree of freedom.
        from_one = at_one * tau0
        one_error = math.sqrt(2.0 / max(sums.one_terms / 1.5, 1.0)) * from_one
        if sums.window_terms < 1:
            out.append(White(math.sqrt(from_one), 0.5 * one_error / math.sqrt(from_one) if from_one > 0 else 0.0))
            continue
        measured = float(sums.window[channel]) / sums.window_terms
        most = float(wander[channel]) * window if wander is not None else 0.0
        from_window = measured * window
        window_error = math.sqrt(2.0 / max(sums.window_terms / 1.5, 1.0)) * from_window
        allowed = SIGNIFICANT_RATIO * math.hypot(window_error, one_error)
        quantization = filter_constant = 0.0
        density2, error2 = from_one, one_error
        # What the window holds besides the wander: half its share taken off, give or take all of it.
        long_term = max(from_window - 0.5 * most, 0.5 * from_window)
        long_error = math.hypot(window_error, most / math.sqrt(12.0))
        if from_one > from_window + allowed:  # 3 Q^2 / tau^2 + N^2 / tau at both times: two unknowns
            at_window = long_term / window
            q2 = max((at_one - at_window * window / tau0) / (3.0 / tau0 ** 2 - 3.0 / (window * tau0)), 0.0)
            quantization = math.sqrt(q2)
            density2, error2 = max((at_window - 3.0 * q2 / window ** 2) * window, 0.5 * long_term), long_error
        elif from_one < from_window - most - allowed:
            filter_constant = _filter_time_constant(from_one / tau0 / (long_term / window), tau0, window)
            density2, error2 = long_term, long_error
            if filter_constant > 0.0:  # the filter has not quite faded at one window either
                fading = float(filtered_white_allan_variance(np.array([window]), 1.0 / tau0, filter_constant)[0])
                density2, error2 = long_term / (fading * window), long_error / (fading * window)
        density = math.sqrt(density2)
        out.append(White(density, 0.5 * error2 / density if density > 0.0 else 0.0, quantization, filter_constant))
    return out


def _filter_time_constant(ratio: float, tau0: float, window: float) -> float:
    """The first-order low-pass whose white noise's Allan variance at one sample is ``ratio`` of that at one window."""
    from scipy.optimize import brentq
    rate = 1.0 / tau0
    times = np.array([tau0, window])

    def excess(constant: float) -> float:
        at_one, at_window = filtered_white_allan_variance(times, rate, constant)
        return float(at_one / at_window) - ratio

    low, high = 1e-3 * tau0, window
    if excess(high) > 0.0:
        return high
    if excess(low) < 0.0:
        return 0.0
    return float(brentq(excess, low, high, xtol=1e-6 * tau0))


def wander_ceiling(sums: ShortSums, channel: int) -> tuple[float, float]:
    """``(B, K)`` the largest flicker and walk the Allan variance at one window allows on a channel.

    Every term adds to the Allan variance, so a flicker's flat ``(0.664 B)^2`` and a walk's
    ``K^2 tau / 3`` are at most it (taken at its upper one-sided 95 % limit); at one sample where
    the stretches are shorter than two windows.
    """
    terms, measured, tau = ((sums.window_terms, float(sums.window[channel]) / max(sums.window_terms, 1),
                             sums.window_s) if sums.window_terms else
                            (sums.one_terms, float(sums.one[channel]) / max(sums.one_terms, 1), sums.period_s))
    if terms < 1:
        return math.inf, math.inf
    upper = measured * (1.0 + 1.645 * math.sqrt(2.0 / max(terms / 1.5, 1.0)))
    return math.sqrt(upper) / FLICKER_FLOOR, math.sqrt(3.0 * upper / tau)
