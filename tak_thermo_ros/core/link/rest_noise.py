"""The noise of rest means: each judged channel's noise terms, a rest as judged, the residuals' variances.

The calibration watch (:mod:`tak_thermo_ros.core.link.watch`) judges a rest's residuals against
their noise, from the calibration's noise models (white noise, quantisation, bias instability,
random walk, rate ramp, Gauss-Markov processes: not white alone). The mean of a rest of ``T`` s
has white variance ``N^2 / T``; two rests' means differ by the bias's wander between them:
``(4 B^2 / pi)(ln 2 + ln(S / T) / 2)`` for a flicker term ``B`` at a separation ``S`` (twice its
Allan variance at ``S = T``), ``K^2 (gap + T1 / 3 + T2 / 3)`` for a random walk ``K``,
``2 s^2 (1 - exp(-S / T_c))`` for a Gauss-Markov process, ``(R S)^2`` for a ramp.

:class:`ChannelNoise` holds one channel's terms (a fit's noise model judges its rests with it
too, :mod:`tak_thermo_ros.core.noise.rests`); :class:`JudgedRest` a rest's residuals with their
noise; :class:`RestNoise` the variances the watch's tests and its learning use (the Earth rate's
unknown part, the wander between two rests, a rest about the run's level, the calibration's own
error at the rests): a base of :class:`~tak_thermo_ros.core.link.watch.CalibrationWatch`, it reads
the watch's calibration, latitude and gravity.

Imports numpy only (the node loads it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from tak_thermo_ros.core.link.model import Calibration, UnitCalibration
from tak_thermo_ros.core.link.rests import Rest
from tak_thermo_ros.core.noise.model import FLICKER_FLOOR, NoiseModel
from tak_thermo_ros.core.values import EARTH_RATE

CHANNELS = ('gyro x', 'gyro y', 'gyro z', 'accel')
"""What the watch judges: each gyroscope axis, and the accelerometer's ``|f|``."""


@dataclass(frozen=True)
class ChannelNoise:
    """The noise terms of one judged channel, per axis or projected (SI units of the channel).

    :param white: white noise density, units/sqrt(Hz).
    :param quantization: units*s.
    :param flicker: bias instability ``B``, units.
    :param walk: random walk ``K``, units*sqrt(Hz).
    :param ramp: rate ramp ``R``, units/s.
    :param markov: ``((sigma, correlation time), ...)``.
    """

    white: float
    quantization: float
    flicker: float
    walk: float
    ramp: float
    markov: tuple[tuple[float, float], ...] = ()

    @classmethod
    def axis(cls, noise: NoiseModel, axis: int) -> ChannelNoise:
        """One axis of a noise model, each wander term at its one-sided 95 % upper limit (never understated)."""
        return cls(noise.white_noise_density[axis], noise.quantization[axis], noise.bias_instability_upper[axis],
                   noise.random_walk_upper[axis], noise.rate_ramp[axis],
                   tuple((s[axis], t[axis]) for s, t in zip(noise.gauss_markov, noise.gauss_markov_time)
                         if s[axis] > 0.0))

    @classmethod
    def projected(cls, noise: NoiseModel, weights: np.ndarray) -> ChannelNoise:
        """``sum_j w_j x_j`` of the three axes (``|f|`` along the up direction: weights ``u_j^2`` on variances)."""
        def mix(values: Sequence[float]) -> float:
            return float(math.sqrt(sum(w * v * v for w, v in zip(weights, values))))
        markov = tuple((mix(s), max(t)) for s, t in zip(noise.gauss_markov, noise.gauss_markov_time) if any(s))
        return cls(mix(noise.white_noise_density), mix(noise.quantization), mix(noise.bias_instability_upper),
                   mix(noise.random_walk_upper), mix(noise.rate_ramp), markov)

    def independent(self, duration_s: float) -> float:
        """The variance of a rest mean's own noise (white, quantisation): independent from rest to rest."""
        return self.white ** 2 / duration_s + 3.0 * self.quantization ** 2 / duration_s ** 2

    def slow(self, duration_s: float) -> float:
        """The variance of the bias's wander in a rest mean of this length (without its own noise).

        A flicker term's flat Allan variance, a random walk's ``K^2 T / 3``, each Gauss-Markov
        process's variance.
        """
        return ((FLICKER_FLOOR * self.flicker) ** 2 + self.walk ** 2 * duration_s / 3.0
                + sum(s * s for s, _ in self.markov))

    def level(self, duration_s: float) -> float:
        """The variance of a rest mean about the run's level: its own noise and the bias's wander at its length.

        The floor of such a mean: :meth:`independent` and :meth:`slow`.
        """
        return self.independent(duration_s) + self.slow(duration_s)

    def wander(self, separation_s: Any, gap_s: Any, first_s: Any, second_s: Any) -> Any:
        """The variance of the bias's wander between two rest means (see the module), without their own noise.

        Numbers, or arrays of them element by element (a fit's noise model judges every pair at once).
        """
        mean_length = 0.5 * (first_s + second_s)
        growth = 0.5 * np.log(np.maximum(separation_s / mean_length, 1.0))
        flicker = 4.0 * self.flicker ** 2 / math.pi * (math.log(2.0) + growth)
        walk = self.walk ** 2 * (gap_s + (first_s + second_s) / 3.0)
        markov = sum(2.0 * s * s * -np.expm1(-separation_s / t) for s, t in self.markov)
        return flicker + walk + markov + (self.ramp * separation_s) ** 2


@dataclass(frozen=True)
class JudgedRest:
    """A rest as the watch judged it: residuals per channel and their noise."""

    rest: Rest
    residual: np.ndarray
    """``(4,)`` per channel of :data:`CHANNELS`, SI."""
    independent: np.ndarray
    """``(4,)`` the variance of each residual's own noise (independent from rest to rest)."""
    up: np.ndarray
    noises: tuple[ChannelNoise, ...]
    """Each channel's noise terms at the rest's up direction."""
    calibration: tuple[np.ndarray, ...] = ()
    """Per channel how its residual moves with the errors of the calibration's terms (a row over the
    sensor's :class:`~tak_thermo_ros.core.link.uncertainty.LinkUncertainty` terms; empty: none stated)."""


def positive_part(covariance: np.ndarray) -> np.ndarray:
    """A symmetric matrix with its negative eigenvalues set to 0: the nearest covariance (Frobenius).

    The flicker term's pairwise variance ``(4 B^2 / pi)(ln 2 + ln(S / T) / 2)`` with ``T`` the two
    rests' mean length is exact for rests of one length only; a short rest between long ones makes
    the wander's covariance indefinite, and the larger the flicker against a rest's own noise, the
    nearer the whole covariance comes to singular: a healthy unit's 3-sigma rest then read 7 sigma.
    Its positive part is a covariance at every flicker (the random walk's is one already).
    """
    if not len(covariance):
        return covariance
    values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    if values.min() >= 0.0:
        return covariance
    return (vectors * np.maximum(values, 0.0)) @ vectors.T


def beyond_slope_variances(calibration: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Per side of the calibrated range (low, high) and axis the variance of the offset's slope beyond it.

    The correction holds the edge's value beyond the range (it clamps): it misses the curve's own
    slope there, and what the file's ``beyond`` spread says the slope may be besides (sensor units
    per degree C, squared). Zero where the file states neither.
    """
    uncertainty = calibration.uncertainty
    beyond = np.asarray((uncertainty.beyond if uncertainty is not None else ()) or (0.0, 0.0, 0.0))
    sides = []
    for edge in (calibration.temp_code_min, calibration.temp_code_max):
        n = edge - calibration.temp_code_ref
        step = max(1e-3 * (calibration.temp_code_max - calibration.temp_code_min), 1e-6)
        slope = np.array([(axis.offset_drift(n + step) - axis.offset_drift(n - step)) / (2.0 * step) / axis.scale
                          for axis in calibration.axes])
        sides.append(slope ** 2 + beyond ** 2 if calibration.needs_temperature else beyond ** 2)
    return sides[0], sides[1]


class RestNoise:
    """The variances of rests' residuals: the Earth rate's unknown part, the wander, the calibration's error.

    A base of :class:`~tak_thermo_ros.core.link.watch.CalibrationWatch`; what it reads is the
    watch's (set in its ``__init__``), annotated below.
    """

    unit: UnitCalibration
    accel_noise: NoiseModel
    gyro_noise: NoiseModel
    latitude: float | None
    gravity_sd: float
    _covariances: dict[str, np.ndarray]
    """Per sensor :meth:`_terms_covariance`, once computed."""
    _pairs: dict[tuple[int, int, int], float]
    """:meth:`wander_variance` by ``(rest, rest, channel)``, once computed."""

    def expected_rate(self, up: np.ndarray) -> np.ndarray:
        """``(3,)`` the Earth rate's vertical part along the sensor axes (zero without a latitude)."""
        if self.latitude is None:
            return np.zeros(3)
        return EARTH_RATE * math.sin(math.radians(self.latitude)) * up

    def heading_variance(self, up: np.ndarray) -> np.ndarray:
        """``(3,)`` per axis the variance of the Earth rate's unknown part (its horizontal part, any heading)."""
        horizontal = EARTH_RATE * (math.cos(math.radians(self.latitude)) if self.latitude is not None else 1.0)
        return horizontal ** 2 * (1.0 - up ** 2) / 2.0

    def channel_noise(self, up: np.ndarray) -> list[ChannelNoise]:
        """The noise terms of each channel of :data:`CHANNELS` at an up direction."""
        return [*(ChannelNoise.axis(self.gyro_noise, axis) for axis in range(3)),
                ChannelNoise.projected(self.accel_noise, up ** 2)]

    def _calibration_rows(self, rest: Rest, up: np.ndarray) -> tuple[np.ndarray, ...]:
        """Per channel its residual's row over the file's terms (:meth:`LinkUncertainty.rows`); empty: none stated.

        The gyroscope's channels at the rest's rate, ``|f|`` as the accelerometer's axes along the up direction.
        """
        rows: list[np.ndarray] = []
        mean = np.asarray(rest.mean)
        for sensor, inputs in (('gyro', mean[3:]), ('accel', mean[:3])):
            calibration = self.unit.sensor(sensor)
            uncertainty = calibration.uncertainty
            if uncertainty is None:
                rows += [np.zeros(0)] * (3 if sensor == 'gyro' else 1)
                continue
            low, high = calibration.temp_code_min, calibration.temp_code_max
            temperature = min(max(rest.temperature, low), high)
            scales = np.array([axis.scale for axis in calibration.axes])
            per_axis = uncertainty.rows(temperature, inputs, calibration.temp_code_ref, scales)
            # beyond the calibrated range the correction holds the edge's value: off by the slope there times
            # the distance (columns: each axis's slope beyond the low edge, then beyond the high edge)
            outside = np.zeros((3, 6))
            below, above = min(rest.temperature - low, 0.0), max(rest.temperature - high, 0.0)
            outside[:, :3] = -below * np.eye(3)
            outside[:, 3:] = -above * np.eye(3)
            per_axis = np.hstack([per_axis, outside])
            rows += list(per_axis) if sensor == 'gyro' else [up @ per_axis]
        return tuple(rows)

    def _terms_covariance(self, sensor: str) -> np.ndarray:
        """The covariance of the errors :meth:`_calibration_rows` runs over: the file's terms, then beyond its range.

        Beyond an edge each axis's slope is the curve's own there (what holding the edge's value
        misses) beside the file's ``beyond`` spread, as an independent error per side.
        """
        cached = self._covariances.get(sensor)
        if cached is not None:
            return cached
        calibration = self.unit.sensor(sensor)
        uncertainty = calibration.uncertainty
        assert uncertainty is not None
        sides = beyond_slope_variances(calibration)
        count = len(uncertainty.terms)
        matrix = np.zeros((count + 6, count + 6))
        matrix[:count, :count] = uncertainty.covariance
        matrix[count:, count:] = np.diag(np.concatenate(sides))
        self._covariances[sensor] = matrix
        return matrix

    def calibration_covariance(self, rests: Sequence[JudgedRest], channel: int,
                               first: JudgedRest | None = None) -> np.ndarray:
        """``(k, k)`` the covariance of the calibration's own error in the rests' residuals on a channel.

        Common to every rest (the same file's errors at each rest's orientation and temperature);
        with ``first``: of their differences from it. Zero when the file states no uncertainty.
        """
        if not rests or not len(rests[0].calibration) or not len(rests[0].calibration[channel]):
            return np.zeros((len(rests), len(rests)))
        rows = np.array([rest.calibration[channel] for rest in rests])
        if first is not None:
            rows = rows - first.calibration[channel][None, :]
        return rows @ self._terms_covariance('gyro' if channel < 3 else 'accel') @ rows.T

    def wander_variance(self, first: JudgedRest, second: JudgedRest, channel: int) -> float:
        """The variance of the bias's wander between two rests' means on a channel (without their own noise).

        The wander's terms are the earlier rest's (``|f|``: projected on its up direction).
        """
        key = (first.rest.index, second.rest.index, channel)
        cached = self._pairs.get(key)
        if cached is not None:
            return cached
        a, b = (first, second) if first.rest.start_ns <= second.rest.start_ns else (second, first)
        separation = abs(b.rest.centre_s - a.rest.centre_s)
        gap = max(0.0, (b.rest.start_ns - a.rest.end_ns) * 1e-9)
        variance = a.noises[channel].wander(separation, gap, a.rest.duration_s, b.rest.duration_s)
        self._pairs[key] = variance
        return variance

    def pair_variance(self, first: JudgedRest, second: JudgedRest, channel: int) -> float:
        """The variance of the difference of two rests' residuals on a channel: their own noise and the wander."""
        return (first.independent[channel] + second.independent[channel]
                + self.wander_variance(first, second, channel))

    def level_variance(self, judged: JudgedRest, channel: int) -> float:
        """The variance of one rest's residual about the run's level: the floor of such a mean, Earth or gravity too."""
        up = judged.up
        variance = judged.noises[channel].level(judged.rest.duration_s)
        if channel < 3:
            variance += self.heading_variance(up)[channel]
        return variance + self._reference_variance(up, channel)

    def _reference_variance(self, up: np.ndarray, channel: int) -> float:
        """The variance of what a residual is counted from and is constant over a run.

        A gyroscope channel without a latitude: the Earth rate's vertical part (``sin(latitude)``
        anywhere in -1..1); ``|f|``: gravity's uncertainty.
        """
        if channel < 3:
            return (EARTH_RATE * up[channel]) ** 2 / 3.0 if self.latitude is None else 0.0
        return self.gravity_sd ** 2
