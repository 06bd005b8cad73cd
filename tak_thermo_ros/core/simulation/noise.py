"""The simulator's sensor noise beyond white: what real parts have, per axis, seeded.

- **Bias instability** ``B`` (flicker: a flat Allan deviation ``0.664 B``) is a sum of
  first-order Gauss-Markov processes with correlation times spaced evenly in log time
  (:data:`POLES_PER_DECADE` over :data:`POLE_DECADES`) and equal variances, which makes a 1/f
  spectrum between its poles: the Allan deviation is flat within +-5 % over two decades
  (:data:`FLAT_DECADES`) around the axis's ``bias_instability_tau``, at ``0.664 B`` (the
  variance is set so on average over that band in log time).
- **Random walk** ``K`` (rate / velocity random walk, units*sqrt(Hz)): the sum of independent
  increments of standard deviation ``K sqrt(dt)``, starting at 0 (Allan variance ``K^2 tau / 3``).
- **Gauss-Markov processes** (exponentially correlated; a bump in the Allan deviation at 1.89
  times the correlation time): per axis any number, each a standard deviation and a
  correlation time, stationary from the first sample.
- **A driver's low-pass filter and decimation** (:func:`filtered_white`): the white noise is
  drawn at ``decimation`` times the output rate, passed through a first-order low-pass of the
  given time constant and every ``decimation``-th sample kept; its long-term density stays
  ``noise_counts / sqrt(rate)``, its shortest averaging times fall below that.

The white noise stays where it was (``AxisTruth.noise_counts``: white noise density
``noise_counts / sqrt(rate)``; the per-sample standard deviation without a filter). These
processes draw from their own random streams (the scenario's seed and the sensor's index), so a
scenario without them draws exactly the same numbers as before. Rounding a driver's output to
its resolution (``AxisTruth.resolution``) is done by the simulator after the noise.
"""

from __future__ import annotations

import math

import numpy as np

from tak_thermo_ros.core.noise.model import FLICKER_FLOOR

POLES_PER_DECADE = 2
"""Gauss-Markov correlation times per decade of the bias-instability band."""
POLE_DECADES = 3.0
"""The correlation times span this many decades, centred on ``tau / 1.89``."""
FLAT_DECADES = 2.0
"""... which makes the Allan deviation flat within +-5 % over about this many decades around ``tau``
(from ``tau / 12`` to ``10 tau``); it falls as white noise above and as a random walk below."""
PEAK_RATIO = 1.8926
"""A Gauss-Markov process's Allan deviation peaks at ``tau = 1.89 T`` (its correlation time ``T``)."""


def gauss_markov_allan_variance(taus: np.ndarray, variance: float, correlation_time: float) -> np.ndarray:
    """The Allan variance of a first-order Gauss-Markov process (autocovariance ``variance e^(-|t|/T)``).

    ``(2 s^2 T / tau) [1 - T / (2 tau) (3 - 4 e^(-tau/T) + e^(-2 tau/T))]``: white (``2 s^2 T / tau``)
    well above ``T``, random walk (``K^2 = 2 s^2 / T``) well below.
    """
    taus = np.asarray(taus, dtype=float)
    ratio = correlation_time / taus
    return 2.0 * variance * ratio * (1.0 - ratio / 2.0 * (3.0 - 4.0 * np.exp(-1.0 / ratio) + np.exp(-2.0 / ratio)))


def bias_instability_poles(tau: float) -> np.ndarray:
    """The correlation times (s) of the Gauss-Markov processes behind a bias instability centred on ``tau``."""
    half = POLE_DECADES / 2.0
    count = int(round(POLE_DECADES * POLES_PER_DECADE)) + 1
    return tau / PEAK_RATIO * np.logspace(-half, half, count)


def bias_instability_variance(bias_instability: float, tau: float) -> float:
    """Each process's variance so that the flat Allan deviation of the sum is ``0.664 B``."""
    poles = bias_instability_poles(tau)
    half = FLAT_DECADES / 2.0
    band = tau * np.logspace(-half, half, 41)
    unit = sum(gauss_markov_allan_variance(band, 1.0, pole) for pole in poles)
    return float((FLICKER_FLOOR * bias_instability) ** 2 / np.mean(unit))


def bias_wander(seed: int | list[int], count: int, rate: float, bias_instability: tuple[float, ...],
                bias_instability_tau: tuple[float, ...], random_walk: tuple[float, ...],
                gauss_markov: tuple[tuple[tuple[float, float], ...], ...] = ()) -> np.ndarray:
    """``(count, 3)``: bias instability, random walk and Gauss-Markov processes per axis at ``rate`` Hz.

    ``gauss_markov``: per axis a tuple of ``(standard deviation, correlation time s)``. Zeros
    where an axis has none of them.
    """
    wander = np.zeros((count, 3))
    if count == 0:
        return wander
    rng = np.random.default_rng(seed)
    step = 1.0 / rate
    for axis in range(3):
        if bias_instability[axis] > 0.0:
            variance = bias_instability_variance(bias_instability[axis], bias_instability_tau[axis])
            for pole in bias_instability_poles(bias_instability_tau[axis]):
                wander[:, axis] += gauss_markov_process(rng, count, step, math.sqrt(variance), pole)
        if random_walk[axis] > 0.0:
            wander[:, axis] += np.cumsum(rng.standard_normal(count)) * (random_walk[axis] * math.sqrt(step))
    for axis, processes in enumerate(gauss_markov):
        for sigma, correlation_time in processes:
            if sigma > 0.0:
                wander[:, axis] += gauss_markov_process(rng, count, step, sigma, correlation_time)
    return wander


def gauss_markov_process(rng: np.random.Generator, count: int, step: float, sigma: float,
                         correlation_time: float) -> np.ndarray:
    """``(count,)`` a stationary first-order Gauss-Markov process of standard deviation ``sigma`` every ``step`` s.

    ``y_k = rho y_(k-1) + sqrt(1 - rho^2) sigma w_k`` with ``rho = exp(-step / T)``, stationary
    from the first sample (white noise through a first-order low-pass is one: :func:`filtered_white`).
    """
    from scipy.signal import lfilter
    decay = math.exp(-step / correlation_time)
    start = rng.standard_normal() * sigma
    drive = rng.standard_normal(count) * (sigma * math.sqrt(1.0 - decay * decay))
    return lfilter([1.0], [1.0, -decay], drive, zi=[decay * start])[0]


def filtered_white(rng: np.random.Generator, count: int, rate: float, density: float, time_constant: float,
                   decimation: int = 1) -> np.ndarray:
    """``(count,)`` white noise of long-term density ``density`` after a driver's low-pass and decimation.

    Drawn at ``decimation * rate``, filtered by a first-order low-pass of ``time_constant`` s
    (unity gain at DC), every ``decimation``-th sample kept. The output is an AR(1) process at
    ``rate`` with lag-one correlation ``exp(-1 / (rate time_constant))`` whatever the
    decimation (so the noise model's filter term is exact for it), its per-sample variance set
    so that its long-term density (the white noise density a Kalibr file holds) is ``density``.
    """
    if time_constant <= 0.0:
        return rng.standard_normal(count) * density * math.sqrt(rate)
    internal = rate * decimation
    step = 1.0 / (internal * time_constant)
    # Output AR(1): s^2 = v tanh(step/2), rho = exp(-decimation step), density^2 = s^2 coth(decimation step / 2) / rate.
    variance = density ** 2 * rate / (math.tanh(step / 2.0) / math.tanh(decimation * step / 2.0))
    sigma = math.sqrt(variance * math.tanh(step / 2.0))  # the filtered sequence's standard deviation
    fine = gauss_markov_process(rng, count * decimation, 1.0 / internal, sigma, time_constant)
    return fine[decimation - 1::decimation]
