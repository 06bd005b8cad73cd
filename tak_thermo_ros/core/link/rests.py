"""Rests, online: the stillness of a stream of corrected samples, found as the samples arrive.

The calibration watch's first step (:mod:`tak_thermo_ros.core.link.watch`), on the correction's
output (the corrected accelerometer and gyroscope, their stamps and temperature): the offline
detector's rule (:mod:`tak_thermo_ros.core.records.still`) on running windows of :data:`WINDOW_S`
on the stamps' clock (at least :data:`MIN_WINDOW_SAMPLES` samples). A window is still when on every
channel its variance stays below the noise model's per-sample variance times the chi-square
quantile of :data:`FALSE_MOVE_PROBABILITY`; consecutive still windows form a rest while each
window's mean agrees with the recent ones within :data:`MEAN_SIGMAS` standard errors; a rest
loses its first and last window and counts from :data:`MIN_STILL_S`; a longer stillness is cut
into rests of at most :data:`REST_MAX_S`. Per message: one comparison and one append to the
window's buffer; a window's mean and variance once per window.

Imports numpy only (the node loads it).
"""

from __future__ import annotations

import math
from itertools import chain
from dataclasses import dataclass
from statistics import NormalDist
from typing import Callable, Sequence

import numpy as np

from tak_thermo_ros.core.noise.model import FLICKER_FLOOR, NoiseModel
from tak_thermo_ros.core.records.still import (
    FALSE_MOVE_PROBABILITY,
    MEAN_SIGMAS,
    MIN_STILL_S,
    MIN_WINDOW_SAMPLES,
    RECENT_WINDOWS,
    WINDOW_S,
)

REST_MAX_S = 60.0
"""A stillness longer than this is cut into rests of at most this length (a parked unit is judged too)."""
PERIOD_STEPS = 16
"""Stamp steps the finder measures the stream's period on before its first window."""


def chi2_quantile_ratio(dof: int, probability: float = FALSE_MOVE_PROBABILITY) -> float:
    """``chi2.ppf(1 - probability, dof) / dof`` by the Wilson-Hilferty cube.

    At most 2 % above the exact value from 7 degrees of freedom (a window judged still a little more readily).

    The node's import path holds no scipy; the offline detector's exact quantile differs from
    this by less than the windows' own scatter.
    """
    z = NormalDist().inv_cdf(1.0 - probability)
    k = 2.0 / (9.0 * dof)
    return (1.0 - k + z * math.sqrt(k)) ** 3


@dataclass(frozen=True)
class Rest:
    """A rest found online: its samples' corrected means and temperature.

    :param index: the rest's number in the run, from 1.
    :param start_ns: the start of its first window (stamps' clock).
    :param end_ns: the end of its last window.
    :param samples: samples averaged.
    :param duration_s: ``samples`` times the stream's period: the averaging time of its means.
    :param mean: ``(6,)`` the corrected means, accelerometer x y z (m/s^2) then gyroscope x y z (rad/s).
    :param temperature: its mean temperature input.
    :param closed_ns: the stamp of the message that ended it (the turn-on offset applies from it on).
    """

    index: int
    start_ns: int
    end_ns: int
    samples: int
    duration_s: float
    mean: tuple[float, ...]
    temperature: float
    closed_ns: int

    @property
    def centre_s(self) -> float:
        """The middle of the rest, seconds on the stamps' clock."""
        return (self.start_ns + self.end_ns) * 0.5e-9

    @property
    def up(self) -> np.ndarray:
        """``(3,)`` the measured up direction in the sensor frame (the specific force, normalised)."""
        accel = np.asarray(self.mean[:3])
        norm = float(np.linalg.norm(accel))
        return accel / norm if norm > 0.0 else np.array([0.0, 0.0, 1.0])


def window_variance(noise: NoiseModel, period_s: float, window_s: float) -> np.ndarray:
    """``(3,)`` per axis, the variance of one sample about its window's mean that the noise model allows.

    The white noise's per-sample variance ``N^2 / period`` (an upper bound for a driver's
    filtered noise), quantisation's at one sample, and what the slow processes add within a
    window: a flicker term's flat Allan variance, a random walk's ``K^2 W / 3``, each Gauss-Markov
    process's share ``min(1, W / T_c)`` of its variance.
    """
    white = np.asarray(noise.white_noise_density) ** 2 / period_s
    quantization = 3.0 * np.asarray(noise.quantization) ** 2 / period_s ** 2
    slow = (FLICKER_FLOOR * np.asarray(noise.bias_instability_upper)) ** 2 + \
        np.asarray(noise.random_walk_upper) ** 2 * window_s / 3.0
    for sigma, times in zip(noise.gauss_markov, noise.gauss_markov_time):
        slow = slow + np.asarray(sigma) ** 2 * np.minimum(1.0, window_s / np.asarray(times))
    return white + quantization + slow


class RestFinder:
    """Rests of a stream of corrected six-value samples, found as they arrive (see the module).

    :param accel_noise: the accelerometer's noise model; ``gyro_noise`` the gyroscope's.
    :param on_rest: called with each :class:`Rest` when it ends (in the message that ends it).
    """

    def __init__(self, accel_noise: NoiseModel, gyro_noise: NoiseModel, on_rest: Callable[[Rest], None]) -> None:
        self._noise = (accel_noise, gyro_noise)
        self._on_rest = on_rest
        self._buffer: list[Sequence[float]] = []
        self.append = self._buffer.append
        """Appends a message's values to the window in progress (the per-message protocol, below)."""
        self.start_ns = 0
        self.end_ns = 0
        """The window in progress, ``[start, end)``; both 0 until the period is known.

        The per-message protocol (:meth:`take`; the node's pipeline runs it inline): a message
        stamped outside ``[start_ns, end_ns)`` first calls :meth:`next_window`; then its values
        go to :attr:`append` (a reference to its tuple: cheaper than any arithmetic)."""
        self._measured: list[int] = []
        self.period_ns = 0
        """The stream's typical step between stamps (0: not known yet)."""
        self.window_ns = 0
        self._origin_ns = 0
        self._slot = 0
        self._window_temperature = math.nan
        self._sigma2 = np.zeros(6)
        self._sigma = np.zeros(6)
        self._ratio: dict[int, float] = {}
        self._min_samples = MIN_WINDOW_SAMPLES
        self._rows: list[tuple[np.ndarray, int, int, int, float]] = []
        """The current rest's still windows: ``(mean, samples, start_ns, end_ns, temperature)``."""
        self._recent: list[tuple[np.ndarray, int]] = []
        """The rest's latest windows (at most :data:`RECENT_WINDOWS`): ``(mean, samples)``; their sums below."""
        self._recent_sum = np.zeros(6)
        self._recent_samples = 0
        self._rounding = False
        self._edge_first = True
        self.rests = 0
        """Rests found so far."""
        self.windows = 0
        """Windows closed so far."""
        self.still_windows = 0

    def take(self, stamp_ns: int, values: Sequence[float], temperature: float) -> None:
        """One corrected message: six values (accelerometer x y z, gyroscope x y z) at its stamp."""
        if not self.start_ns <= stamp_ns < self.end_ns:
            self.next_window(stamp_ns, temperature)
        self.append(values)

    def finish(self) -> None:
        """The stream ended: the window in progress closes and a rest in progress ends."""
        if self.period_ns:
            self._close_window()
            self._end_rest()

    def next_window(self, stamp_ns: int, temperature: float) -> None:
        """A message stamped outside the window in progress: it closes, the next opens (or the period is measured)."""
        if not self.period_ns:
            self._measure(stamp_ns, temperature)
            return
        self._close_window()
        slot = (stamp_ns - self._origin_ns) // self.window_ns
        if slot != self._slot + 1:  # a gap (no interval crosses it) or a stamp before the window
            self._end_rest()
            if slot <= self._slot:
                self._origin_ns, slot = stamp_ns, 0
        self._open(slot, temperature)

    def _measure(self, stamp_ns: int, temperature: float) -> None:
        """The first messages: their steps give the period, hence the window (then the first window opens)."""
        self._buffer.clear()
        measured = self._measured
        if measured and stamp_ns <= measured[-1]:
            measured.clear()
        measured.append(stamp_ns)
        if len(measured) <= PERIOD_STEPS:
            return
        period = int(np.median(np.diff(measured)))
        self.period_ns = period
        self.window_ns = max(int(WINDOW_S * 1e9), MIN_WINDOW_SAMPLES * period)
        # a window that lost a sample or two (a non-finite message dropped) is still judged: at a low rate
        # it holds MIN_WINDOW_SAMPLES, and one missing would end every rest it falls in (2 % of them: most)
        self._min_samples = max(MIN_WINDOW_SAMPLES * 3 // 4, int(0.5 * self.window_ns / period))
        window_s = self.window_ns * 1e-9
        self._sigma2 = np.concatenate([window_variance(noise, period * 1e-9, window_s) for noise in self._noise])
        self._sigma = np.maximum(np.sqrt(self._sigma2), 1e-300)
        self._rounding = bool(np.any(self._sigma2 == 0.0))
        self._origin_ns = stamp_ns
        self._open(0, temperature)

    def _open(self, slot: int, temperature: float) -> None:
        self._slot = slot
        self.start_ns = self._origin_ns + slot * self.window_ns
        self.end_ns = self.start_ns + self.window_ns
        self._window_temperature = temperature

    def _close_window(self) -> None:
        """The window in progress: still or not, and what that does to the rest in progress."""
        buffer = self._buffer
        samples = len(buffer)
        self.windows += 1
        if samples < self._min_samples:
            buffer.clear()
            self._end_rest()
            return
        data = np.fromiter(chain.from_iterable(buffer), dtype=float, count=6 * samples).reshape(samples, 6)
        buffer.clear()
        total = data.sum(axis=0)
        squares = np.einsum('ij,ij->j', data, data)
        mean = total / samples
        # Sums of squares about zero: the corrected values are small beside their squares' precision
        # (|f| 9.8 m/s^2 against a variance of 1e-5: the cancellation costs 1e-11 of it).
        variance = (squares - total * mean) / (samples - 1)
        ratio = self._ratio.get(samples)
        if ratio is None:
            ratio = self._ratio[samples] = chi2_quantile_ratio(samples - 1)
        allowed = self._sigma2 * ratio
        if self._rounding:  # a channel without noise: its variance is the arithmetic's rounding
            allowed = np.maximum(allowed, (64.0 * np.spacing(np.abs(mean))) ** 2 * samples)
        if not (variance <= allowed).all():
            self._end_rest()
            return
        self.still_windows += 1
        if self._recent:
            error = self._sigma * math.sqrt(1.0 / samples + 1.0 / self._recent_samples)
            if (np.abs(mean - self._recent_sum / self._recent_samples) > MEAN_SIGMAS * error).any():
                self._end_rest()  # a slow tilt, or a knock into a new pose: a new rest
        self._recent.append((mean, samples))
        self._recent_sum = self._recent_sum + mean * samples
        self._recent_samples += samples
        if len(self._recent) > RECENT_WINDOWS:
            gone, count = self._recent.pop(0)
            self._recent_sum = self._recent_sum - gone * count
            self._recent_samples -= count
        self._rows.append((mean, samples, self.start_ns, self.end_ns, self._window_temperature))
        rows = self._rows
        first = 1 if self._edge_first else 0
        if len(rows) > first and (rows[-1][3] - rows[first][2]) * 1e-9 >= REST_MAX_S:
            self._emit(rows[first:], closed_ns=self.end_ns)
            self._rows = []
            self._edge_first = False  # the stillness goes on: the next rest has no edge at its start

    def _end_rest(self) -> None:
        """The stillness ended: its rows less its edges form a rest when long enough."""
        rows = self._rows
        first = 1 if self._edge_first else 0
        usable = rows[first:-1]
        if usable and (usable[-1][3] - usable[0][2]) * 1e-9 >= MIN_STILL_S:
            self._emit(usable, closed_ns=self.end_ns)
        self._rows = []
        self._recent = []
        self._recent_sum = np.zeros(6)
        self._recent_samples = 0
        self._edge_first = True

    def _emit(self, rows: list[tuple[np.ndarray, int, int, int, float]], *, closed_ns: int) -> None:
        samples = sum(row[1] for row in rows)
        mean = sum(row[0] * row[1] for row in rows) / samples
        temperature = sum(row[4] * row[1] for row in rows) / samples
        self.rests += 1
        self._on_rest(Rest(index=self.rests, start_ns=rows[0][2], end_ns=rows[-1][3], samples=samples,
                           duration_s=samples * self.period_ns * 1e-9, mean=tuple(float(v) for v in mean),
                           temperature=float(temperature), closed_ns=closed_ns))
