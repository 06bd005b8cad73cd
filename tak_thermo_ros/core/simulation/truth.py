"""The true sensor of a simulated run: an axis's channel (:class:`AxisTruth`), default units and tables.

The chamber run (:mod:`.imu`), the powered board (:mod:`.powered`) and the everyday records
(:mod:`.everyday`) draw their channels from these axes: the paper's model without noise is
:func:`exact_output`; the defaults are a counts unit, a driver's accelerometer and gyroscope,
the turntable's positions and a rate table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.core.link.model import AxisModel

_SQRT1_2 = math.sqrt(0.5)
_SQRT1_3 = math.sqrt(1.0 / 3.0)
DEFAULT_POSITIONS: tuple[tuple[float, float, float], ...] = (
    (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0),
    (0.0, 1.0, 0.0), (0.0, -1.0, 0.0),
    (0.0, 0.0, 1.0), (0.0, 0.0, -1.0),
    (_SQRT1_2, _SQRT1_2, 0.0), (0.0, -_SQRT1_2, _SQRT1_2),
    (-_SQRT1_2, 0.0, -_SQRT1_2), (_SQRT1_3, _SQRT1_3, _SQRT1_3),
)
"""Turntable positions: the direction of 'up' in the sensor frame (specific force / g)."""


@dataclass(frozen=True)
class AxisTruth:
    """The true channel of one axis (raw polynomial coefficients in ``n = N_t - N_t,ref``).

    :param scale: ``K0``, counts per m/s^2 per cycle.
    :param offset: ``dNs0``, counts.
    :param offset_coeffs: ``(c1, ...)``: ``dNs(n) - dNs0 = c1 n + c2 n^2 + ...``, counts.
    :param scale_coeffs: ``(a1, ...)`` of ``F_c(n) = 1 + a1 n + ...``.
    :param noise_counts: standard deviation of the white noise, counts (per sample: the white
        noise density is ``noise_counts / sqrt(sample_rate_hz)``).
    :param bias_instability: the flicker bias ``B``, counts (driver: m/s^2 or rad/s), whose Allan
        deviation is flat at ``0.664 B`` over two decades around ``bias_instability_tau``
        (:mod:`tak_thermo_ros.core.simulation.noise`). 0 = off.
    :param bias_instability_tau: s, the middle of that flat band.
    :param random_walk: the bias's random walk ``K``, counts*sqrt(Hz) (Allan variance ``K^2 tau / 3``). 0 = off.
    :param gauss_markov: standard deviations of Gauss-Markov processes in the bias (counts; driver
        units), one per process; empty = none.
    :param gauss_markov_time: their correlation times, s (as many).
    :param filter_time_constant: s, a driver's first-order low-pass on the white noise, run at
        ``Scenario.decimation`` times the output rate before every ``decimation``-th sample is
        kept (the density ``noise_counts / sqrt(rate)`` is the long-term one). 0 = none.
    :param resolution: a driver output's quantum (driver units): the output is rounded to whole
        multiples of it. 0 = none (a counts run is rounded to whole codes anyway).
    """

    scale: float
    offset: float
    offset_coeffs: tuple[float, ...]
    scale_coeffs: tuple[float, ...]
    noise_counts: float = 1.5
    bias_instability: float = 0.0
    bias_instability_tau: float = 100.0
    random_walk: float = 0.0
    gauss_markov: tuple[float, ...] = ()
    gauss_markov_time: tuple[float, ...] = ()
    filter_time_constant: float = 0.0
    resolution: float = 0.0

    def link(self, code_offset_range: tuple[float, float], residual_rms: float | None = None) -> AxisModel:
        """This axis as a link's :class:`AxisModel`, ``F_s`` normalised over ``code_offset_range``."""
        return AxisModel.from_polynomials(scale=self.scale, offset=self.offset, offset_coeffs=self.offset_coeffs,
                                          scale_coeffs=self.scale_coeffs, code_offset_range=code_offset_range,
                                          residual_rms=residual_rms)


def exact_output(unit: tuple[AxisTruth, ...], inputs: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``(k, 3)``: the paper's model without noise for inputs ``(k, 3)`` at ``n = T - T_ref`` ``(k,)``."""
    return np.column_stack([a.link((-1.0, 1.0)).forward(inputs[:, i], n) for i, a in enumerate(unit)])


DEFAULT_UNIT: tuple[AxisTruth, AxisTruth, AxisTruth] = (
    AxisTruth(255.1, -12.3, (0.05, 1.5e-5, 2.0e-8), (2.0e-6, 1.0e-9)),
    AxisTruth(254.3, 8.7, (-0.04, 2.0e-5, -1.0e-8), (-1.5e-6, 2.0e-9)),
    AxisTruth(256.0, 3.1, (0.03, -1.0e-5, 3.0e-8), (1.0e-6, -1.0e-9)),
)

DEFAULT_DRIVER_ACCEL: tuple[AxisTruth, AxisTruth, AxisTruth] = (
    AxisTruth(1.0021, 0.051, (2.0e-3, 1.2e-5, 1.0e-7), (1.1e-4, 1.5e-6), noise_counts=0.004),
    AxisTruth(0.9983, -0.034, (-1.6e-3, 1.6e-5, -8.0e-8), (-0.9e-4, 2.0e-6), noise_counts=0.004),
    AxisTruth(1.0012, 0.082, (1.2e-3, -0.8e-5, 2.4e-7), (0.6e-4, -1.0e-6), noise_counts=0.005),
)
"""A MEMS accelerometer as its driver reports it: m/s^2 (factory scale about 1), drift per degree C."""

DEFAULT_DRIVER_GYRO: tuple[AxisTruth, AxisTruth, AxisTruth] = (
    AxisTruth(1.0013, 0.0021, (3.0e-4, 2.0e-6, -3.0e-8), (5.0e-5, 1.0e-7), noise_counts=0.0008),
    AxisTruth(0.9991, -0.0013, (-2.2e-4, 3.0e-6, 2.0e-8), (-4.0e-5, 2.0e-7), noise_counts=0.0008),
    AxisTruth(1.0024, 0.0030, (1.5e-4, -2.5e-6, 4.0e-8), (3.0e-5, -1.5e-7), noise_counts=0.0009),
)
"""A MEMS gyroscope as its driver reports it: rad/s; bias drift of about 0.4 deg/s over 25 C."""

RATE_TABLE_POSITIONS: tuple[tuple[float, float, float], ...] = tuple(
    tuple(sign * (1.0 if j == i else 0.0) for j in range(3))  # type: ignore[misc]
    for i in range(3) for sign in (1.0, -1.0) for _ in range(3))
RATE_TABLE_RATES: tuple[float, ...] = (0.0, 1.0, -1.0) * 6
"""A rate table: each axis up and down, resting then turning at +-1 rad/s about the vertical
(the axis that is up), so every gyroscope axis sees three rates and the accelerometer +-g."""
