"""The calibration watch: rests found in the stream, the calibration judged at each against the sensor's own noise.

A calibration is fitted once; a MEMS unit's offset curve moves in service (ageing, solder
stress, a hard landing, a new mount). The watch runs beside the correction, on its output
(the corrected accelerometer and gyroscope, their stamps and temperature: the node's messages,
or ``tak_calib validate``'s replay of a record: the same code, the same verdict):

1. **Rests, online** (:class:`RestFinder`): the offline detector's rule
   (:mod:`tak_thermo_ros.core.records.still`) on running windows of :data:`WINDOW_S` on the
   stamps' clock (at least :data:`MIN_WINDOW_SAMPLES` samples). A window is still when on every
   channel its variance stays below the noise model's per-sample variance times the chi-square
   quantile of :data:`FALSE_MOVE_PROBABILITY`; consecutive still windows form a rest while each
   window's mean agrees with the recent ones within :data:`MEAN_SIGMAS` standard errors; a rest
   loses its first and last window and counts from :data:`MIN_STILL_S`; a longer stillness is cut
   into rests of at most :data:`REST_MAX_S`. Per message: one comparison and one append to the
   window's buffer; a window's mean and variance once per window.
2. **The residual at a rest** (:class:`CalibrationWatch`): per gyroscope axis the corrected
   mean less the Earth rate's vertical part (with a latitude; its horizontal part, whose
   direction the heading sets, counts as noise); the corrected ``|f|`` less gravity.
3. **Its noise** from the calibration's noise models (white noise, quantisation, bias
   instability, random walk, rate ramp, Gauss-Markov processes: not white alone). The mean of
   a rest of ``T`` s has white variance ``N^2 / T``; two rests' means differ by the bias's
   wander between them: ``(4 B^2 / pi)(ln 2 + ln(S / T) / 2)`` for a flicker term ``B`` at a
   separation ``S`` (twice its Allan variance at ``S = T``), ``K^2 (gap + T1 / 3 + T2 / 3)`` for a
   random walk ``K``, ``2 s^2 (1 - exp(-S / T_c))`` for a Gauss-Markov process, ``(R S)^2`` for a
   ramp.
4. **The tests.** The first rest of a run gives the turn-on offset, judged against the
   calibration's turn-on repeatability where the file holds one (``turn_on``). From then on the
   rests' residuals (with ``turn_on``: the residuals, the turn-on offset their common random
   level; without: their differences from the first) have the covariance the noise model gives
   (a process with stationary increments: ``(D_i1 + D_j1 - D_ij) / 2`` from the variances ``D``
   of the pairwise differences), and generalised least squares tests three kinds of change: the
   offset moved (a constant beyond the turn-on spread), the offset stepped at some rest since the
   first, the offset's slope against temperature changed (:meth:`CalibrationWatch._test`). A
   sequential test of the generalised-likelihood kind (the CUSUM's, over every possible change
   point); its false alarms are bounded by spending :data:`FALSE_ALARMS_PER_HOUR` over the rests
   in proportion to their length (each rest's tests share ``rate x T / 3600``, split over the
   channels and the alternatives: by the union bound the expected number of false alarms per
   hour of rests is at most the rate).
5. **What moved**: the channel, the kind (offset or slope) and the size (gyro x offset +812 deg/h,
   gyro y slope +2.1 deg/h/C, accel z 3.2 mg), once a test fires; the verdict holds for the run.
6. **Learning, opt-in** (:class:`Learner`): per gyroscope axis an offset and a slope correction
   to the curve (a Kalman filter: the fitted curve is the prior, the bias's wander between rests
   its process noise), the turn-on offset taken at the first rest, innovations beyond
   :data:`OUTLIER_SIGMAS` rejected (three in a row: a new level), the corrections bounded.
7. **The turn-on offset of a run** (``turn_on``, off by default): the first rest's gyroscope
   residual (and, with a known gravity, the accelerometer's along its axis nearest the
   vertical) is taken as the run's offset, within :data:`TURN_ON_SIGMAS` of the repeatability,
   and subtracted from every message from the one that ends the rest on: the node and
   ``tak_calib apply`` run the same code on the same samples and agree float for float.

Imports numpy only (the node loads it).
"""

from __future__ import annotations

import math
import operator
from itertools import chain
from dataclasses import dataclass, field, replace
from statistics import NormalDist
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from tak_thermo_ros.core.link.model import AxisModel, Calibration, InputKind, UnitCalibration
from tak_thermo_ros.core.noise.model import FLICKER_FLOOR, NoiseModel
from tak_thermo_ros.core.records.still import (
    FALSE_MOVE_PROBABILITY,
    MEAN_SIGMAS,
    MIN_STILL_S,
    MIN_WINDOW_SAMPLES,
    RECENT_WINDOWS,
    WINDOW_S,
)
from tak_thermo_ros.core.values import EARTH_RATE, STANDARD_GRAVITY, finite_number, normal_gravity
from tak_thermo_ros.errors import TakError

REST_MAX_S = 60.0
"""A stillness longer than this is cut into rests of at most this length (a parked unit is judged too)."""
PERIOD_STEPS = 16
"""Stamp steps the finder measures the stream's period on before its first window."""
FALSE_ALARMS_PER_HOUR = 0.05
"""The stated false-alarm rate: at most this many "stale" verdicts per hour of rests of a unit
whose calibration holds (one in 20 hours of rests), by the union bound over every test."""
MAX_RESTS_JUDGED = 32
"""Rests a judgement looks at: the run's first and the latest ones (bounded work per rest)."""
SLOPE_SPAN_C = 1.0
"""The slope alternative is tested once the rests span at least this many degrees C."""
TURN_ON_SIGMAS = 5.0
"""A run's turn-on offset is taken (``turn_on: first_rest``) within this many standard deviations
of the repeatability (and the rest's own noise); beyond, it is not taken, and the line says by how much
(what moved it, the watch's tests tell: the offset alone cannot)."""
OUTLIER_SIGMAS = 4.0
"""Learning leaves out a rest whose innovation lies beyond this many standard deviations."""
OUTLIERS_IN_A_ROW = 3
"""... unless this many in a row: then the offset moved, and the learning takes the new level."""
GRAVITY_HEIGHT_SD = 3e-3
"""m/s^2: the spread of gravity with the place's height (about +-1 km) when only a latitude is known."""
GRAVITY_LATITUDE_SD = (9.8321849 - 9.7803253) / math.sqrt(12.0)
"""m/s^2: the spread of normal gravity over every latitude (uniform), when no latitude is given."""
VERTICAL_AXIS_COSINE = math.cos(math.radians(30.0))
"""The accelerometer's turn-on offset is taken along an axis within 30 degrees of the vertical only."""
OFFSET_BOUND_SIGMAS = 6.0
"""Learning bounds a gyroscope axis's offset correction to this many turn-on repeatabilities or the
offset curve's own span over the calibrated range, whichever is larger, on the unit's widest axis."""
VARIANCE_BOUNDS = 1000.0
"""A learned correction's variance read back is at most the square of this many bounds (a spread, not a value)."""
SLOPE_PRIOR_SHARE = 0.5
"""The prior of a slope correction: its standard deviation is this share of the curve's largest slope."""
UNDETERMINED_RATIO = 3.0
"""A rest's ``|f|`` is not judged when the calibration's own uncertainty there (against the run's first
rest: a tilt its file never determined) exceeds this many times the rest's noise; it is said instead."""
CHANNELS = ('gyro x', 'gyro y', 'gyro z', 'accel')
"""What the watch judges: each gyroscope axis, and the accelerometer's ``|f|``."""
ANOTHER_CALIBRATION = 'learned on another calibration'
"""How the watch's notice of a learned state it left (another calibration's) begins."""
MIN_SPREAD_RUNS = 5
"""The node takes the spread of its earlier runs' turn-on offsets for a repeatability from this many runs on
(as a fit takes a pool's: fewer power-ups leave the spread undetermined)."""
DEG_PER_H = 180.0 / math.pi * 3600.0
"""deg/h per rad/s."""
MG = 1e3 / STANDARD_GRAVITY
"""mg per m/s^2."""


@dataclass(frozen=True)
class Repeatability:
    """A turn-on repeatability the calibration file lacks, per axis (SI), and where it came from (a few words)."""

    repeatability: tuple[float, float, float]
    source: str


class WatchUnavailable(TakError):
    """The calibration gives the watch nothing to judge against (no noise model, no gyroscope)."""


def chi2_quantile_ratio(dof: int, probability: float = FALSE_MOVE_PROBABILITY) -> float:
    """``chi2.ppf(1 - probability, dof) / dof`` by the Wilson-Hilferty cube.

    At most 2 % above the exact value from 7 degrees of freedom (a window judged still a little more readily).

    The node's import path holds no scipy; the offline detector's exact quantile differs from
    this by less than the windows' own scatter.
    """
    z = NormalDist().inv_cdf(1.0 - probability)
    k = 2.0 / (9.0 * dof)
    return (1.0 - k + z * math.sqrt(k)) ** 3


def two_sided_threshold(probability: float) -> float:
    """``|z|`` beyond which a standard normal lies with ``probability``."""
    return NormalDist().inv_cdf(1.0 - max(probability, 1e-300) / 2.0)


# -- rests, online -----------------------------------------------------------------------------


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


# -- the noise of rest means -------------------------------------------------------------------


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


# -- the watch ---------------------------------------------------------------------------------


@dataclass
class Finding:
    """What moved on one channel, once its test fired.

    :param channel: one of :data:`CHANNELS`.
    :param kind: ``offset`` (turn-on beyond the repeatability, or a step) or ``slope``.
    :param size: the change, SI (rad/s, m/s^2; per degree C for a slope).
    :param z: its size over its standard deviation.
    :param rest: the rest at which the test fired.
    :param axis: the axis it is named on (``x``, ``y``, ``z``).
    :param turn_on: whether it is the first rest's turn-on offset.
    :param why: what the test judged it against, in words (the log line's).
    """

    channel: str
    kind: str
    size: float
    z: float
    rest: int
    axis: str
    turn_on: bool = False
    why: str = ''

    @property
    def sigma(self) -> float:
        """The standard deviation the change was judged against (its size over its z), SI."""
        return abs(self.size / self.z) if self.z else math.inf

    def judged(self) -> str:
        """``gyro x offset +812 deg/h: 12.3 sigma at rest 1 (1 sigma 66 deg/h: turn-on offset beyond ...)``."""
        if self.channel == 'accel':
            one = f'{self.sigma * MG:.3g} mg' + (' per C' if self.kind == 'slope' else '')
        else:
            one = f'{self.sigma * DEG_PER_H:.3g} deg/h' + ('/C' if self.kind == 'slope' else '')
        return f'{self.text()}: {abs(self.z):.1f} sigma at rest {self.rest} (1 sigma {one}; {self.why})'

    def text(self) -> str:
        """``gyro x offset +812 deg/h``, ``gyro y slope +2.1 deg/h/C``, ``accel z 3.2 mg``."""
        if self.channel == 'accel':
            return f'accel {self.axis} {self.size * MG:+.3g} mg' + (' per C' if self.kind == 'slope' else '')
        unit = 'deg/h/C' if self.kind == 'slope' else 'deg/h'
        return f'{self.channel} {self.kind} {self.size * DEG_PER_H:+.3g} {unit}'


@dataclass
class ChannelState:
    """One channel's figures at the latest rest (for the diagnostics)."""

    residual: float = math.nan
    z: float = 0.0


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


@dataclass(frozen=True)
class WatchSettings:
    """How the node (or a replay) runs the watch; the defaults are the node's.

    :param enabled: whether the watch runs (``-p watch:=false``: no rest is looked for).
    :param latitude: degrees, or ``None``.
    :param turn_on: take each run's turn-on offset at its first rest (``-p turn_on:=first_rest``).
    :param learn: what earlier runs learned (opt-in learning; a fresh :class:`LearnedState` to
        start), or ``None``: no learning.
    :param turn_on_repeatability: ``(accel, gyro)``: a turn-on repeatability per axis (SI; a data
        sheet's bias repeatability) for a sensor whose file holds none, or ``None``.
    """

    enabled: bool = True
    latitude: float | None = None
    turn_on: bool = False
    learn: LearnedState | None = None
    turn_on_repeatability: tuple[tuple[float, float, float] | None, tuple[float, float, float] | None] = (None, None)

    def repeatabilities(self) -> tuple[Repeatability | None, Repeatability | None]:
        """``(accel, gyro)`` what stands in for a file's missing turn-on repeatability.

        The parameter, else the spread of the turn-on offsets learning has seen over
        :data:`MIN_SPREAD_RUNS` runs or more (the gyroscope's), else ``None``.
        """
        learned = self.learn.turn_on_spread() if self.learn is not None else None
        out = []
        for sensor, given in zip(('accel', 'gyro'), self.turn_on_repeatability):
            if given is not None:
                out.append(Repeatability(tuple(float(v) for v in given), f'{sensor}_turn_on_repeatability'))
            elif sensor == 'gyro' and learned is not None:
                out.append(Repeatability(learned, f'the spread of {self.learn.turn_on_runs} earlier runs\' '
                                                  f'turn-on offsets (learned_file)'))
            else:
                out.append(None)
        return out[0], out[1]

    def watch(self, unit: UnitCalibration) -> CalibrationWatch:
        """The watch of a calibration under these settings.

        A learned state of another calibration (:func:`calibration_digest`) is left: learning starts
        afresh, said in the watch's :attr:`~CalibrationWatch.notices`.

        :raises WatchUnavailable: the calibration gives it nothing to judge against.
        """
        learner = None
        another = False
        if self.learn is not None:
            start = self.learn
            another = bool(start.original) and start.original != calibration_digest(unit)
            learner = Learner(unit, LearnedState() if another else start)
        watch = CalibrationWatch(unit, latitude=self.latitude, turn_on=self.turn_on, learner=learner,
                                 repeatabilities=self.repeatabilities())
        if another:
            watch.notices.append(f'{ANOTHER_CALIBRATION}: learning starts afresh (the learned file is replaced at '
                                 f'the first write)')
        return watch


class CalibrationWatch:
    """Judge a calibration at the rests of a run (see the module's description).

    :param unit: the calibration in force (a driver's: accelerometer and gyroscope, each with a noise model).
    :param latitude: degrees, or ``None`` (unknown: the Earth rate and gravity count as noise; gravity from the
        latitude, else standard gravity).
    :param turn_on: take the run's turn-on offset at its first rest and subtract it (``turn_on: first_rest``).
    :param learner: a :class:`Learner` (opt-in learning), or ``None``.
    :param repeatabilities: ``(accel, gyro)`` a turn-on repeatability for a sensor whose file holds none
        (:meth:`WatchSettings.repeatabilities`), or ``None``s: its first rest is then unjudged.
    :raises WatchUnavailable: when the calibration holds no gyroscope or a sensor has no noise model.
    """

    def __init__(self, unit: UnitCalibration, *, latitude: float | None = None, turn_on: bool = False,
                 learner: Learner | None = None,
                 repeatabilities: tuple[Repeatability | None, Repeatability | None] = (None, None)) -> None:
        reason = watch_unavailable(unit)
        if reason:
            raise WatchUnavailable(reason)
        self.unit = unit
        self.accel_noise: NoiseModel = unit.accel.noise  # type: ignore[assignment]
        self.gyro_noise: NoiseModel = unit.gyro.noise  # type: ignore[union-attr,assignment]
        self.latitude = latitude
        known = latitude is not None
        self.gravity = float(normal_gravity(latitude) if known else STANDARD_GRAVITY)
        self.gravity_sd = GRAVITY_HEIGHT_SD if known else math.hypot(GRAVITY_LATITUDE_SD, GRAVITY_HEIGHT_SD)
        self.gravity_known = known
        self.turn_on_enabled = turn_on
        self.learner = learner
        self.false_alarms_per_hour = FALSE_ALARMS_PER_HOUR
        """The false-alarm rate per hour of rests the tests are held to."""
        self.finder = RestFinder(self.accel_noise, self.gyro_noise, self._on_rest)
        self.take = self.finder.take
        """The per-message entry: ``take(stamp_ns, values, temperature)`` (:meth:`RestFinder.take`)."""
        self.pending: list[Rest] = []
        """Rests found, not judged yet (:meth:`judge` takes them; the node does so in its timer)."""
        self.judged: list[JudgedRest] = []
        self.first: JudgedRest | None = None
        self.findings: dict[str, Finding] = {}
        """Per channel what moved, from the first test that fired on it (the verdict holds for the run)."""
        self.channels = {name: ChannelState() for name in CHANNELS}
        self.rests_judged = 0
        self.rest_hours = 0.0
        self.notices: list[str] = []
        """Lines for the log: a verdict that changed, a turn-on offset taken or refused."""
        self.turn_on_offset = np.zeros(6)
        """The run's turn-on offset taken at its first rest (``turn_on``), per value of a message."""
        self.turn_on_lines: list[str] = []
        self.adjustment: tuple[tuple[float, ...], tuple[float, ...]] | None = None
        """What the output loses, per value of a message: ``a + b (T - T_ref)`` as ``(a, b)``; ``None``: nothing."""
        self.adjustment_version = 0
        self.on_adjustment: Callable[[tuple[tuple[float, ...], tuple[float, ...]] | None], None] | None = None
        """Told every new adjustment (the node's pipeline keeps it at hand)."""
        self.reference = learner.reference if learner is not None else float(unit.gyro.temp_code_ref)  # type: ignore
        """The temperature the adjustment's slope is counted from."""
        self._pairs: dict[tuple[int, int, int], float] = {}
        self._turn_on_sd = tuple(unit.sensor(sensor).known_turn_on for sensor in ('accel', 'gyro'))
        self.repeatability_source = tuple('the calibration file' if known is not None else
                                          (given.source if given is not None else '')
                                          for known, given in zip(self._turn_on_sd, repeatabilities))
        """Per sensor where the turn-on repeatability the first rest is judged against comes from (``''``: none)."""
        self._turn_on_share = tuple(2.0 if known is None and given is not None and given.source.endswith(
            '_turn_on_repeatability') else 1.0 for known, given in zip(self._turn_on_sd, repeatabilities))
        """Per sensor the turn-on variance's factor: a file of one power-up (no ``turn_on``) judged with a given
        repeatability carries that power-up's own turn-on offset in its curve: the run's less the file's, twice."""
        self._turn_on_sd = tuple(known if known is not None else given
                                 for known, given in zip(self._turn_on_sd, repeatabilities))
        self._covariances: dict[str, np.ndarray] = {}
        self.undetermined: list[tuple[int, float, float]] = []
        """Rests whose ``|f|`` the calibration leaves undetermined: ``(rest, its uncertainty, its noise)`` (SI)."""
        if learner is not None:
            self._set_adjustment(learner.adjustment())
        self._block_adjustment = self.adjustment

    # -- per message (rare path) and per rest -------------------------------------------------

    def _on_rest(self, rest: Rest) -> None:
        """A rest ended (in the message that ended it): queued; the turn-on offset taken at the first."""
        self.pending.append(rest)
        if rest.index == 1 and self.turn_on_enabled and self.learner is None:  # learning takes its own, judged
            self._take_turn_on(rest)

    def take_block(self, stamp_ns: np.ndarray, values: np.ndarray, temperature: np.ndarray) -> np.ndarray:
        """:meth:`take` of a block of samples, in order; their values as the node publishes them.

        ``(k,)`` stamps, ``(k, 6)`` corrected values and ``(k,)`` temperatures: each value less the
        adjustment in force after its own :meth:`take`. ``tak_calib apply --turn-on first-rest``:
        the same samples, the same rests, the same floats as the node.
        """
        take = self.take
        changes = []
        version = self.adjustment_version
        for index, (stamp, row, temp) in enumerate(zip(stamp_ns.tolist(), values.tolist(), temperature.tolist())):
            take(stamp, row, temp)
            if self.adjustment_version != version:
                version = self.adjustment_version
                changes.append((index, self.adjustment))
        out = np.array(values, dtype=float, copy=True)
        bounds = [*changes, (len(values), None)]
        adjustment = self._block_adjustment
        start = 0
        for index, following in bounds:
            if adjustment is not None and index > start:
                out[start:index] = adjust_array(values[start:index], temperature[start:index], adjustment,
                                                self.reference)
            start, adjustment = index, following
        self._block_adjustment = self.adjustment
        return out

    def finish(self) -> None:
        """The stream ended: a rest in progress ends, and every rest is judged."""
        self.finder.finish()
        self.judge()

    def judge(self) -> None:
        """Judge every rest found since the last call (the node: in its diagnostics timer)."""
        while self.pending:
            self._judge(self.pending.pop(0))

    # -- the residual and its noise ------------------------------------------------------------

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

    def residual(self, rest: Rest) -> JudgedRest:
        """The rest's residual per channel: gyroscope mean less the Earth rate, ``|f|`` less gravity."""
        up = rest.up
        mean = np.asarray(rest.mean)
        gyro = mean[3:] - self.expected_rate(up)
        if self.learner is not None:  # judged against the curve in force at the run's start
            gyro = gyro - self.learner.start_curve(rest.temperature)
        accel = float(np.linalg.norm(mean[:3])) - self.gravity
        noises = tuple(self.channel_noise(up))
        independent = np.array([noise.independent(rest.duration_s) for noise in noises])
        independent[:3] += self.heading_variance(up)
        return JudgedRest(rest, np.array([*gyro, accel]), independent, up, noises, self._calibration_rows(rest, up))

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
        beyond = np.asarray(uncertainty.beyond or (0.0, 0.0, 0.0))
        sides = []
        for edge in (calibration.temp_code_min, calibration.temp_code_max):
            n = edge - calibration.temp_code_ref
            step = max(1e-3 * (calibration.temp_code_max - calibration.temp_code_min), 1e-6)
            slope = np.array([(axis.offset_drift(n + step) - axis.offset_drift(n - step)) / (2.0 * step) / axis.scale
                              for axis in calibration.axes])
            sides.append(slope ** 2 + beyond ** 2 if calibration.needs_temperature else beyond ** 2)
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

    # -- the tests -------------------------------------------------------------------------------

    def _turn_on_repeatability(self, channel: int, up: np.ndarray) -> float | None:
        """The turn-on repeatability of a channel (``|f|``: projected on the up direction), or ``None``."""
        accel, gyro = self._turn_on_sd
        if channel < 3:
            return None if gyro is None else gyro.repeatability[channel]
        if accel is None:
            return None
        return float(math.sqrt(sum(u * u * r * r for u, r in zip(up, accel.repeatability))))

    def _turn_on_covariance(self, rests: list[JudgedRest], channel: int) -> np.ndarray:
        """``(k, k)`` the run's turn-on offset in the rests' residuals: one constant per gyroscope axis.

        ``|f|`` takes the accelerometer's turn-on offset ``t`` along each rest's up direction
        (``u_i . t``: it changes with the tilt), ``u_i' diag(R^2) u_j``.
        """
        accel, gyro = self._turn_on_sd
        if channel < 3:
            return np.full((len(rests), len(rests)), self._turn_on_share[1]
                           * gyro.repeatability[channel] ** 2)  # type: ignore[union-attr]
        ups = np.array([rest.up for rest in rests])
        return self._turn_on_share[0] * (ups * np.square(accel.repeatability)) @ ups.T  # type: ignore[union-attr]

    def _judge(self, rest: Rest) -> None:
        judged = self.residual(rest)
        self.rests_judged += 1
        self.rest_hours += rest.duration_s / 3600.0
        if self.first is None:
            self.first = judged
            unjudged = self.first_rest_unjudged()
            if unjudged:
                self.notices.append(f'calibration watch: rest 1 {unjudged}')
        else:
            self._accel_determined(judged)
            self.judged.append(judged)
            if len(self.judged) > MAX_RESTS_JUDGED - 1:
                gone = self.judged.pop(0).rest.index
                self._pairs = {key: value for key, value in self._pairs.items() if gone not in key[:2]}
        for channel in range(len(CHANNELS)):
            self._test(channel, judged)
        if self.learner is not None:
            adjustment = self.learner.update(self, judged)
            if adjustment is not None:
                self._set_adjustment(adjustment)

    def _accel_determined(self, judged: JudgedRest) -> None:
        """Whether the file determines ``|f|`` here against rest 1 (:data:`UNDETERMINED_RATIO`); said once."""
        uncertainty = float(math.sqrt(max(self.calibration_covariance([judged], 3, self.first)[0, 0], 0.0)))
        noise = math.sqrt(self.level_variance(judged, 3) - self._reference_variance(judged.up, 3))
        if uncertainty <= UNDETERMINED_RATIO * noise:
            return
        self.undetermined.append((judged.rest.index, uncertainty, noise))
        if len(self.undetermined) == 1:
            tilt = math.degrees(math.acos(min(1.0, float(abs(judged.up @ self.first.up)))))  # type: ignore[union-attr]
            self.notices.append(f'|f| not judged at rest {judged.rest.index} ({tilt:.0f} deg from rest 1): the '
                                f'calibration leaves it undetermined there (+-{uncertainty * MG:.2g} mg, noise '
                                f'{noise * MG:.2g} mg)')

    def _test(self, channel: int, judged: JudgedRest) -> None:
        """One channel at a rest: the alternatives tested on the run's residuals by generalised least squares.

        With the file's turn-on repeatability ``R`` the residuals themselves, their covariance
        ``s^2 11' + W + C`` (``s^2``: the turn-on offset's variance and what else is constant over the
        run, ``W`` each rest's own noise, ``C`` the wander since the first rest); the alternatives:
        the offset moved (a constant), a step at a later rest, a slope against ``T - T_ref``.
        Without ``R``: the differences from the first rest, the steps and the slope against ``T - T_1``.
        The rest's share of the false-alarm rate goes a third to the constant, a third to the slope
        and a third to the steps (without ``R``: half to the slope, half to the steps).
        """
        name = CHANNELS[channel]
        first = self.first
        rests = [first, *self.judged]  # type: ignore[list-item]
        state = self.channels[name]
        state.residual = float(judged.residual[channel])
        if channel == 3 and self.undetermined:
            left = {index for index, _, _ in self.undetermined}
            if judged.rest.index in left:
                return
            rests = [rest for rest in rests if rest.rest.index not in left]
        repeatability = self._turn_on_repeatability(channel, first.up)  # type: ignore[union-attr]
        count = len(rests)
        wander = self._wander_covariance(rests, channel)
        independent = np.array([rest.independent[channel] for rest in rests])
        temperatures = np.array([rest.rest.temperature for rest in rests])
        alternatives: list[tuple[np.ndarray, str, int, float]] = []  # (regressor, kind, since, share)
        if repeatability is not None:
            constant = (self._turn_on_covariance(rests, channel)
                        + self._constant_variance(first, channel))  # type: ignore[arg-type]
            y = np.array([rest.residual[channel] for rest in rests])
            covariance = constant + wander + np.diag(independent) + self.calibration_covariance(rests, channel)
            steps = count - 1
            if count == 1:
                alternatives.append((np.ones(1), 'offset', 1, 1.0))
            else:
                alternatives.append((np.ones(count), 'offset', 1, 0.25))
                alternatives.append((temperatures - self.reference, 'slope', 0, 0.5))
                alternatives += [(np.array([1.0 if i >= m else 0.0 for i in range(count)]), 'offset',
                                  rests[m].rest.index, 0.25 / steps) for m in range(1, count)]
        else:
            if count == 1:
                state.z = 0.0
                return
            y = np.array([rest.residual[channel] - first.residual[channel] for rest in rests[1:]])  # type: ignore
            covariance = (independent[0] + wander[1:, 1:] + np.diag(independent[1:])
                          + self.calibration_covariance(rests[1:], channel, first))
            steps = count - 1
            spread = float(np.ptp(temperatures)) >= SLOPE_SPAN_C
            step_share = 0.5 / steps if spread else 1.0 / steps
            if spread:
                alternatives.append((temperatures[1:] - temperatures[0], 'slope', 0, 0.5))
            alternatives += [(np.array([1.0 if i >= m else 0.0 for i in range(1, count)]), 'offset',
                              rests[m].rest.index, step_share) for m in range(1, count)]
        share = self.false_alarms_per_hour * judged.rest.duration_s / 3600.0 / len(CHANNELS)
        regressors = np.column_stack([x for x, _, _, _ in alternatives])
        floor = float(np.min(independent[1:] if repeatability is None else independent))
        solved = _solver(covariance, floor)(np.column_stack([y, regressors]))  # C^-1 y and C^-1 x of each
        weighted_y = solved[:, 0]
        informations = np.einsum('ij,ij->j', regressors, solved[:, 1:]).tolist()
        projections = (weighted_y @ regressors).tolist()
        best: tuple[float, float, float, str, int] | None = None  # (|z| / threshold, z, size, kind, since)
        for (_, kind, since, part), information, projection in zip(alternatives, informations, projections):
            if not information > 0.0:
                continue
            size = projection / information
            z = size * math.sqrt(information)
            ratio = abs(z) / two_sided_threshold(share * part)
            if best is None or ratio > best[0]:
                best = (ratio, z, size, kind, since)
        if best is None:
            return
        ratio, z, size, kind, since = best
        state.z = z
        if ratio >= 1.0:
            turn_on = kind == 'offset' and since == 1 and repeatability is not None
            twice = ', the file\'s power-up\'s too' if self._turn_on_share[int(channel < 3)] > 1.0 else ''
            where = ('turn-on offset beyond the repeatability ' + self._reader(channel, repeatability) + twice
                     if turn_on else f'since rest {since}' if kind == 'offset' else 'against temperature')
            size = size if channel < 3 else self._vertical(size, judged.up)
            self._found(Finding(name, kind, size, z, judged.rest.index, self._axis(channel, judged.up),
                                turn_on=turn_on, why=where), f'{abs(z):.1f} sigma, {where}')

    def _constant_variance(self, first: JudgedRest, channel: int) -> float:
        """What is constant over a run besides the turn-on offset.

        The first rest's wander, the Earth rate's vertical part without a latitude, gravity's uncertainty.
        """
        return first.noises[channel].slow(first.rest.duration_s) + self._reference_variance(first.up, channel)

    def _wander_covariance(self, rests: list[JudgedRest], channel: int) -> np.ndarray:
        """``(k, k)`` the covariance of the bias's wander at the rests, counted from the first (zero there).

        ``(D_i1 + D_j1 - D_ij) / 2`` from the wander's pairwise variances ``D`` (a process with
        stationary increments), its negative part left out (:func:`positive_part`).
        """
        count = len(rests)
        to_first = np.array([0.0, *(self.wander_variance(rests[0], rest, channel) for rest in rests[1:])])
        covariance = np.zeros((count, count))
        for i in range(1, count):
            covariance[i, i] = to_first[i]
            for k in range(1, i):
                value = 0.5 * (to_first[i] + to_first[k] - self.wander_variance(rests[i], rests[k], channel))
                covariance[i, k] = covariance[k, i] = value
        return positive_part(covariance)

    @staticmethod
    def _axis(channel: int, up: np.ndarray) -> str:
        return 'xyz'[channel] if channel < 3 else 'xyz'[int(np.argmax(np.abs(up)))]

    @staticmethod
    def _vertical(size: float, up: np.ndarray) -> float:
        """An ``|f|`` change as the offset of the axis nearest the vertical that gives it."""
        component = float(up[int(np.argmax(np.abs(up)))])
        return size / component

    @staticmethod
    def _reader(channel: int, value: float) -> str:
        return f'{value * DEG_PER_H:.3g} deg/h' if channel < 3 else f'{value * MG:.3g} mg'

    def _found(self, finding: Finding, why: str) -> None:
        if finding.channel in self.findings:
            return
        self.findings[finding.channel] = finding
        self.notices.append(f'calibration stale at rest {finding.rest}: {finding.text()} ({why})')

    # -- the turn-on offset of the run ---------------------------------------------------------

    def _take_turn_on(self, rest: Rest) -> None:
        """``turn_on: first_rest``: the first rest's offsets (within :data:`TURN_ON_SIGMAS`), subtracted from now on."""
        judged = self.residual(rest)
        offset = np.zeros(6)
        taken, refused = [], []
        accel_sd, gyro_sd = self._turn_on_sd
        gyro_taken = []
        for channel in range(3):
            if gyro_sd is None:
                break
            residual = float(judged.residual[channel])
            own = self.level_variance(judged, channel) + self.calibration_covariance([judged], channel)[0, 0]
            sigma = math.sqrt(own + self._turn_on_share[1] * gyro_sd.repeatability[channel] ** 2)
            if abs(residual) <= TURN_ON_SIGMAS * sigma:
                offset[3 + channel] = residual
                gyro_taken.append(f'{"xyz"[channel]} {residual * DEG_PER_H:+.3g}')
            else:
                refused.append(f'gyro {"xyz"[channel]} {residual * DEG_PER_H:+.4g} deg/h ({abs(residual) / sigma:.1f} '
                               f'sigma; repeatability {gyro_sd.repeatability[channel] * DEG_PER_H:.3g})')
        if gyro_taken:
            taken.append(f'gyro {" ".join(gyro_taken)} deg/h')
        if accel_sd is not None and self.gravity_known:
            up = judged.up
            axis = int(np.argmax(np.abs(up)))
            if abs(up[axis]) >= VERTICAL_AXIS_COSINE:
                size = self._vertical(float(judged.residual[3]), up)
                sigma = math.sqrt((self.level_variance(judged, 3) + self.calibration_covariance([judged], 3)[0, 0])
                                  / up[axis] ** 2 + self._turn_on_share[0] * accel_sd.repeatability[axis] ** 2)
                text = f'accel {"xyz"[axis]} {size * MG:+.3g} mg'
                if abs(size) <= TURN_ON_SIGMAS * sigma:
                    offset[axis] = size
                    taken.append(text)
                else:
                    refused.append(f'{text} ({abs(size) / sigma:.1f} sigma; repeatability '
                                   f'{accel_sd.repeatability[axis] * MG:.3g})')
        self.turn_on_offset = offset
        if taken:
            self.turn_on_lines.append(f'turn-on offset taken at rest 1: {"; ".join(taken)}')
        if refused:
            self.turn_on_lines.append(f'turn-on offset not taken at rest 1, beyond {TURN_ON_SIGMAS:g} sigma of the '
                                      f'file\'s repeatability and the rest\'s noise: {"; ".join(refused)}')
        self.notices.extend(self.turn_on_lines)
        self._set_adjustment((tuple(float(v) for v in offset), (0.0,) * 6))

    def _set_adjustment(self, adjustment: tuple[tuple[float, ...], tuple[float, ...]] | None) -> None:
        if adjustment is not None and not any(adjustment[0]) and not any(adjustment[1]):
            adjustment = None
        self.adjustment = adjustment
        self.adjustment_version += 1
        if self.on_adjustment is not None:
            self.on_adjustment(adjustment)

    # -- what it says ----------------------------------------------------------------------------

    def first_rest_unjudged(self) -> str:
        """Why a run's first rest is not judged (no turn-on repeatability for the gyroscope), or ``''``."""
        if self._turn_on_sd[1] is not None:
            return ''
        return ('unjudged: the calibration holds no gyro turn-on repeatability; later rests are judged against '
                'the first (give gyro_turn_on_repeatability, or learn over 5 runs)')

    def first_rest_words(self) -> str:
        """What the first rest is judged against (the status's ``first_rest``)."""
        unjudged = self.first_rest_unjudged()
        if unjudged:
            return unjudged
        gyro = self._turn_on_sd[1].repeatability  # type: ignore[union-attr]
        return (f'judged against the gyro turn-on repeatability {" ".join(f"{v * DEG_PER_H:.3g}" for v in gyro)} '
                f'deg/h x y z (from {self.repeatability_source[1]})')

    def what_to_do(self) -> str:
        """One line: refit, or what learning has done about what the watch found (``''``: nothing found)."""
        if not self.findings:
            return ''
        refit = 'refit from the records the unit made since (tak_calib fit REC... -o NEW.yaml)'
        learner = self.learner
        if learner is None:
            return f'{refit}, or learn it (learn: true); docs/watch.md'
        words = []
        for finding in self.findings.values():
            if finding.channel == 'accel':
                words.append(f'accel (not learned): {refit}')
                continue
            axis = 'xyz'.index(finding.channel[-1])
            since = learner.accepted_since[axis]
            words.append(f'learning takes {finding.channel}: its rests follow the learned curve from rest {since} on'
                         if since is not None else
                         f'learning is taking {finding.channel} ({learner.rejected} rests left out so far)')
        return '; '.join(words)

    @property
    def stale(self) -> bool:
        """Whether a test fired in this run."""
        return bool(self.findings)

    def verdict(self) -> str:
        """One line: ``calibration stale: ...`` or ``calibration holds ...`` (or no rest yet)."""
        if self.findings:
            moved = ', '.join(f.text() for f in self.findings.values())
            return f'calibration stale: {moved} (at rest {min(f.rest for f in self.findings.values())})'
        if not self.rests_judged:
            return 'calibration holds as far as known: no rest yet'
        return (f'calibration holds at {self.rests_judged} rests ({self.rest_hours * 60.0:.1f} min; '
                f'false alarms at most {self.false_alarms_per_hour:g} per hour of rests)')

    def values(self) -> list[tuple[str, str]]:
        """The figures as ``(key, value)`` pairs: per channel the residual at the last rest and its size in sigma."""
        values = [('rests', str(self.rests_judged)), ('rest_minutes', f'{self.rest_hours * 60.0:.2f}'),
                  ('false_alarms_per_hour', f'{self.false_alarms_per_hour:g}'),
                  ('windows', str(self.finder.windows)), ('still_windows', str(self.finder.still_windows))]
        last = self.judged[-1] if self.judged else self.first
        if last is not None:
            values.append(('since_last_rest_s', f'{max(0, self.finder.start_ns - last.rest.end_ns) * 1e-9:.1f}'))
            values.append(('last_rest_temperature', f'{last.rest.temperature:.4g}'))
        for channel, name in enumerate(CHANNELS):
            state = self.channels[name]
            key = name.replace(' ', '_')
            if channel < 3:
                values.append((f'{key}.bias_deg_h', f'{state.residual * DEG_PER_H:.4g}'))
            else:
                values.append(('accel.norm_error_mg', f'{state.residual * MG:.4g}'))
            values.append((f'{key}.sigma', f'{state.z:.3g}'))
        values.append(('accel.undetermined_rests', str(len(self.undetermined))))
        values.append(('first_rest', self.first_rest_words()))
        for finding in self.findings.values():
            values.append((f'stale.{finding.channel.replace(" ", "_")}', finding.judged()))
        if self.findings:
            values.append(('stale.what_to_do', self.what_to_do()))
        if self.learner is not None:  # learning takes the turn-on offset itself, whatever turn_on says
            offset = self.learner.adjustment()[0][3:]
            values.append(('turn_on', 'taken by learning: gyro x y z '
                                      f'{" ".join(f"{v * DEG_PER_H:+.4g}" for v in offset)} deg/h in force'
                           if self.learner.rests else 'learning takes it at the first rest'))
        elif self.turn_on_enabled:
            values.append(('turn_on', '; '.join(self.turn_on_lines) or 'waiting for the first rest'))
        if self.learner is not None:
            values += self.learner.values()
        return values

    def lines(self) -> list[str]:
        """What ``tak_calib validate`` prints: the verdict, what moved, the figures at the last rest (short lines)."""
        out = [self.verdict()]
        for finding in self.findings.values():
            out.append(f'  {finding.judged()}')
        if self.findings:
            out.append(f'  what to do: {self.what_to_do()}')
        unjudged = self.first_rest_unjudged()
        if unjudged and self.rests_judged:
            out.append(f'  rest 1 {unjudged}')
        if self.undetermined:
            _, uncertainty, noise = max(self.undetermined, key=lambda item: item[1] / item[2])
            out.append(f'  |f| not judged at {len(self.undetermined)} rests: the file leaves it undetermined there '
                       f'(+-{uncertainty * MG:.2g} mg, noise {noise * MG:.2g} mg)')
        last = self.judged[-1] if self.judged else self.first
        if last is not None:
            bias = ' '.join(f'{self.channels[n].residual * DEG_PER_H:+.3g}' for n in CHANNELS[:3])
            sigma = ' '.join(f'{self.channels[n].z:+.2g}' for n in CHANNELS[:3])
            rest = last.rest
            out.append(f'  last rest ({rest.index}: {rest.duration_s:.0f} s at {rest.temperature:.3g} C): '
                       f'gyro bias x y z {bias} deg/h')
            out.append(f'  last rest, in sigma of its noise: gyro x y z {sigma}; |f| error '
                       f'{self.channels["accel"].residual * MG:+.3g} mg ({self.channels["accel"].z:+.2g} sigma)')
        out.extend(f'  {line}' for line in self.turn_on_lines)
        return out


def watch_unavailable(unit: UnitCalibration) -> str:
    """Why the watch cannot judge this calibration, or ``''``."""
    if unit.input_kind is not InputKind.IMU or unit.gyro is None:
        return 'the watch needs a driver calibration (accelerometer and gyroscope)'
    missing = [sensor for sensor, calibration in unit.sensors if calibration.noise is None]
    if missing:
        return (f'the calibration holds no noise model for the {" and the ".join(missing)} (fit with --noise, '
                f'--noise-run or --noise-from-residual): nothing to judge a rest against')
    return ''


def turn_on_unavailable(unit: UnitCalibration) -> str:
    """What a driver calibration lacks to take the run's turn-on offset at its first rest, or ``''``.

    ``gyro turn_on section (...)``, for the caller's sentence; no gyroscope is :func:`watch_unavailable`'s to say.
    """
    if unit.gyro is not None and unit.gyro.turn_on is None:
        return ('gyro turn_on section (the turn-on repeatability, fitted from several records: '
                'tak_calib fit REC REC ...)')
    if unit.gyro is not None and unit.gyro.known_turn_on is None:
        return f'gyro turn-on repeatability ({unit.gyro.turn_on.why_not()})'  # type: ignore[union-attr]
    return ''


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


def _solver(covariance: np.ndarray, floor: float) -> Callable[[np.ndarray], np.ndarray]:
    """``X -> C^-1 X`` of ``(k, m)`` columns, ``C``'s eigenvalues kept at ``floor`` at least.

    ``C`` is a sum of approximations (the wander's pairwise variances need not make a positive
    definite matrix; the calibration's part cancels large terms): a direction it puts below the
    residuals' own noise (``floor``: the smallest of their independent variances, which every
    direction of the true covariance holds) would be trusted beyond any measurement.
    """
    values, vectors = np.linalg.eigh(covariance)
    values = np.maximum(values, max(floor, 1e-300))
    return lambda x: vectors @ ((vectors.T @ x) / values[:, None])


# -- learning ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class LearnedState:
    """What the learning keeps from run to run: per gyroscope axis an offset and a slope correction.

    The corrections are the curve's: the learned output is the file's less ``offset + slope (T -
    reference)`` per axis (rad/s, rad/s per degree C).

    :param offset: ``(3,)`` the offset correction.
    :param offset_variance: ``(3,)`` its variance.
    :param slope: ``(3,)`` the slope correction.
    :param slope_variance: ``(3,)`` its variance.
    :param reference: the temperature the slope is counted from (the gyroscope's ``temp_code_ref``).
    :param runs: runs that contributed; ``rests`` rests used, ``rejected`` rests left out as outliers.
    :param original: a digest of the calibration the corrections apply to (:func:`calibration_digest`).
    :param turn_on_runs: runs whose first rest gave a turn-on offset; ``turn_on_sum`` and ``turn_on_squares``
        per axis the sum of those offsets and of their squares (rad/s; the spread of :meth:`turn_on_spread`).
    """

    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    offset_variance: tuple[float, float, float] = (0.0, 0.0, 0.0)
    slope: tuple[float, float, float] = (0.0, 0.0, 0.0)
    slope_variance: tuple[float, float, float] = (0.0, 0.0, 0.0)
    reference: float = 0.0
    runs: int = 0
    rests: int = 0
    rejected: int = 0
    original: str = ''
    turn_on_runs: int = 0
    turn_on_sum: tuple[float, float, float] = (0.0, 0.0, 0.0)
    turn_on_squares: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def turn_on_spread(self) -> tuple[float, float, float] | None:
        """Per axis the standard deviation of the runs' turn-on offsets (rad/s), from :data:`MIN_SPREAD_RUNS` runs on.

        Each run's first rest against the curve in force at its start: its turn-on offset, and what
        the rest's noise and the curve's error at that temperature add (a spread on the safe side).
        """
        count = self.turn_on_runs
        if count < MIN_SPREAD_RUNS:
            return None
        out = [math.sqrt(max(squares - total * total / count, 0.0) / (count - 1))
               for total, squares in zip(self.turn_on_sum, self.turn_on_squares)]
        return out[0], out[1], out[2]

    def to_mapping(self) -> dict[str, Any]:
        """Plain numbers and lists (a YAML section)."""
        return {'offset': list(self.offset), 'offset_variance': list(self.offset_variance), 'slope': list(self.slope),
                'slope_variance': list(self.slope_variance), 'reference': self.reference, 'runs': self.runs,
                'rests': self.rests, 'rejected': self.rejected, 'original': self.original,
                'turn_on_runs': self.turn_on_runs, 'turn_on_sum': list(self.turn_on_sum),
                'turn_on_squares': list(self.turn_on_squares)}

    @classmethod
    def from_mapping(cls, raw: Mapping[str, Any], where: str) -> LearnedState:
        """Read :meth:`to_mapping` back.

        :raises TakError: naming ``where`` and the key, on a missing or bad value.
        """
        if not isinstance(raw, Mapping):
            msg = f'{where}: expected a mapping'
            raise TakError(msg)
        values: dict[str, Any] = {}
        for name in ('offset', 'offset_variance', 'slope', 'slope_variance', 'turn_on_sum', 'turn_on_squares'):
            if name.startswith('turn_on') and name not in raw:  # a learned file written before it kept them
                continue
            triple = raw.get(name)
            bound = ' >= 0' if name.endswith(('variance', 'squares')) else ''
            numbers = (tuple(finite_number(v, f'{where}.{name}[{i}]') for i, v in enumerate(triple))
                       if isinstance(triple, (list, tuple)) and len(triple) == 3 else None)
            if numbers is None or (bound and min(numbers) < 0.0):
                msg = f'{where}.{name}: expected three finite numbers{bound}'
                raise TakError(msg)
            values[name] = numbers
        for name in ('runs', 'rests', 'rejected', 'turn_on_runs'):
            count = raw.get(name, 0)
            if isinstance(count, bool) or not isinstance(count, int) or count < 0:
                msg = f'{where}.{name}: expected a whole number >= 0'
                raise TakError(msg)
            values[name] = count
        values['reference'] = finite_number(raw.get('reference', 0.0), f'{where}.reference')
        values['original'] = str(raw.get('original', ''))
        return cls(**values)


def calibration_digest(unit: UnitCalibration) -> str:
    """A short digest of a calibration's gyroscope curve: whether learned corrections still apply to it."""
    import hashlib
    gyro = unit.gyro
    axes = [(a.scale, a.offset, a.offset_span, a.offset_shape, a.scale_shape) for a in gyro.axes]  # type: ignore
    text = repr((gyro.temp_code_ref, gyro.temp_code_min, gyro.temp_code_max, axes))  # type: ignore[union-attr]
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def check_learned(unit: UnitCalibration, state: LearnedState, where: str) -> None:
    """The learned corrections within the bounds learning keeps on ``unit``: bounded where read as where learned.

    Every command reads a learned file's ``learned`` section so (against the file's own curve), the node its
    ``learned_file`` on its calibration: a correction beyond the bound (a hand-edited file, ``1e300``) is
    refused in one line naming the bound (:meth:`Learner._check_start`), never applied.

    :raises TakError: ``WHERE: learned.offset[0]: ... lies beyond the bound ...``.
    """
    if unit.input_kind is not InputKind.IMU or unit.gyro is None:
        return
    try:
        Learner(unit, replace(state, original=calibration_digest(unit)))
    except TakError as err:
        raise TakError(f'{where}: {err}') from None


def learned_unit(unit: UnitCalibration, state: LearnedState) -> UnitCalibration:
    """The calibration with the learned corrections folded into the gyroscope's curve (a file ``tak_calib`` reads).

    Per axis the offset ``dNs0`` grows by ``K0 offset`` and the offset polynomial by ``K0 slope n``
    (``n = T - T_ref``), re-normalised as the fit does; a link without temperature terms takes the
    offset only.
    """
    gyro: Calibration = unit.gyro  # type: ignore[assignment]
    axes = []
    low, high = gyro.code_offset_range()
    shift = state.reference - gyro.temp_code_ref
    for index, axis in enumerate(gyro.axes):
        offset = state.offset[index] - state.slope[index] * shift
        if not gyro.needs_temperature:
            axes.append(replace(axis, offset=axis.offset + axis.scale * offset))
            continue
        raw = [axis.offset_span * c for c in axis.offset_shape]
        raw[0] += axis.scale * state.slope[index]
        axes.append(AxisModel.from_polynomials(
            scale=axis.scale, offset=axis.offset + axis.scale * offset, offset_coeffs=raw,
            scale_coeffs=axis.scale_shape, code_offset_range=(low, high), residual_rms=axis.residual_rms,
            scale_observable=axis.scale_observable))
    note = (f'learned by the calibration watch from {state.rests} rests over {state.runs} runs: gyro offset '
            f'{" ".join(f"{v * DEG_PER_H:+.4g}" for v in state.offset)} deg/h, slope '
            f'{" ".join(f"{v * DEG_PER_H:+.3g}" for v in state.slope)} deg/h/C at {state.reference:g} C')
    learned = replace(gyro, axes=tuple(axes), notes=(*gyro.notes, note))  # type: ignore[arg-type]
    return replace(unit, gyro=learned)


@dataclass
class _AxisFilter:
    """One gyroscope axis's Kalman filter over the run: state ``(o, s)``, ``r = o + s (T - reference)``."""

    state: np.ndarray
    covariance: np.ndarray
    outliers: int = 0
    last: JudgedRest | None = None


@dataclass
class Learner:
    """Learn the gyroscope's curve at the rests (opt-in): see the module's description.

    :param unit: the calibration the corrections apply to (the original file's).
    :param start: what earlier runs learned (the learned file), or a fresh :class:`LearnedState`.
    """

    unit: UnitCalibration
    start: LearnedState = field(default_factory=LearnedState)
    rests: int = 0
    rejected: int = 0
    changed: bool = False
    _filters: list[_AxisFilter] = field(default_factory=list)
    accepted_since: list[int | None] = field(default_factory=lambda: [None, None, None])
    """Per axis the first rest of the latest run of rests it took (``None``: its latest rest was left out)."""
    first_residual: tuple[float, float, float] | None = None
    """The run's first rest's gyroscope residual against the start's curve (its turn-on offset, for the spread)."""

    def __post_init__(self) -> None:
        gyro: Calibration = self.unit.gyro  # type: ignore[assignment]
        reference = float(gyro.temp_code_ref)
        if not self.start.original:
            self.start = replace(self.start, reference=reference, original=calibration_digest(self.unit))
        self.reference = self.start.reference
        turn_on = gyro.known_turn_on
        self.repeatability = np.array(turn_on.repeatability) if turn_on is not None else None
        low, high = gyro.temp_code_min, gyro.temp_code_max
        grid = np.linspace(low - gyro.temp_code_ref, high - gyro.temp_code_ref, 201)
        slopes, spans = [], []
        for axis in gyro.axes:
            drift = axis.offset_drift(grid) / axis.scale
            spans.append(float(np.ptp(drift)) if gyro.needs_temperature else 0.0)
            slopes.append(float(np.max(np.abs(np.gradient(drift, grid)))) if gyro.needs_temperature else 0.0)
        self.learn_slope = gyro.needs_temperature
        self.slope_prior = np.array([max(SLOPE_PRIOR_SHARE * s, 1e-9) for s in slopes])
        self.slope_bound = 2.0 * self.slope_prior
        noise_level = np.asarray(gyro.noise.white_noise_density) if gyro.noise is not None else np.zeros(3)
        own = np.maximum(np.array(spans), 10.0 * noise_level)
        if self.repeatability is not None:
            own = np.maximum(own, OFFSET_BOUND_SIGMAS * self.repeatability)
        self.offset_prior = own / 2.0
        """The prior of the persistent offset correction before any run: the curve may have moved by this much."""
        # The clip is the unit's, not the axis's: an axis whose curve happens to be flat over the calibrated
        # range (a few hundred deg/h) can still shift by what its neighbours span (a shock, a new mount).
        self.offset_bound = np.full(3, float(own.max()))
        self._check_start(gyro)
        self._filters = []
        for axis in range(3):
            persistent = self.start.offset_variance[axis] if self.start.runs else self.offset_prior[axis] ** 2
            offset_variance = (self.repeatability[axis] ** 2 if self.repeatability is not None else 0.0) + persistent
            slope_variance = (self.start.slope_variance[axis] if self.start.runs else self.slope_prior[axis] ** 2)
            self._filters.append(_AxisFilter(np.zeros(2), np.diag([offset_variance, slope_variance])))

    @property
    def total_offset_bound(self) -> np.ndarray:
        """``(3,)`` the largest offset correction learning keeps (rad/s): the curve's, and a run's own turn-on."""
        return self.offset_bound + (TURN_ON_SIGMAS * self.repeatability if self.repeatability is not None else 0.0)

    def _check_start(self, gyro: Calibration) -> None:
        """What earlier runs learned, within the bounds learning keeps on this calibration (as read, as learned).

        :raises TakError: one line naming the value and the bound (a hand-edited or foreign learned file).
        """
        start = self.start
        low, high = gyro.temp_code_min, gyro.temp_code_max
        if not low - 1e-9 <= start.reference <= high + 1e-9:
            msg = (f'learned.reference: {start.reference:.6g} C lies outside the calibration\'s range '
                   f'{low:.4g}..{high:.4g} C: not applied')
            raise TakError(msg)
        bounds = (('offset', 'deg/h', self.total_offset_bound), ('slope', 'deg/h/C', self.slope_bound))
        for name, units, bound in bounds:
            values, variances = getattr(start, name), getattr(start, f'{name}_variance')
            for axis in range(3):
                # the learning clips at the bound itself: a value read back is within it (float for float)
                limit = float(bound[axis]) * (1.0 + 1e-9)
                if abs(values[axis]) > limit:
                    msg = (f'learned.{name}[{axis}]: {values[axis] * DEG_PER_H:+.4g} {units} lies beyond the bound '
                           f'learning keeps on this calibration, +-{bound[axis] * DEG_PER_H:.4g} {units}: not applied')
                    raise TakError(msg)
                if variances[axis] > (VARIANCE_BOUNDS * limit) ** 2:  # no filter's spread grows so: not a value
                    msg = (f'learned.{name}_variance[{axis}]: a spread of {math.sqrt(variances[axis]) * DEG_PER_H:.4g} '
                           f'{units} lies beyond {VARIANCE_BOUNDS:g} times the bound learning keeps on this '
                           f'calibration ({bound[axis] * DEG_PER_H:.4g} {units}): not applied')
                    raise TakError(msg)

    def start_curve(self, temperature: float) -> np.ndarray:
        """``(3,)`` the learned correction in force at the run's start, at a temperature."""
        return np.asarray(self.start.offset) + np.asarray(self.start.slope) * (temperature - self.reference)

    def adjustment(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """What the output loses per message value: the start's corrections and this run's estimate."""
        offset = [0.0] * 6
        slope = [0.0] * 6
        for axis, axis_filter in enumerate(self._filters):
            o, s = axis_filter.state  # zero until the filter takes its first rest
            total_slope = self.start.slope[axis] + s
            # a + b (T - T_ref) with the slope counted from the gyroscope's reference temperature
            offset[3 + axis] = float(self.start.offset[axis] + o)
            slope[3 + axis] = float(total_slope)
        return tuple(offset), tuple(slope)

    def update(self, watch: CalibrationWatch, judged: JudgedRest) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
        """One rest: each axis's filter steps (the wander since the last rest), takes the rest unless an outlier."""
        x = judged.rest.temperature - self.reference
        used = False
        if self.first_residual is None:
            self.first_residual = (float(judged.residual[0]), float(judged.residual[1]), float(judged.residual[2]))
        for axis, axis_filter in enumerate(self._filters):
            residual = float(judged.residual[axis])  # against the start's curve
            if axis_filter.last is not None:
                axis_filter.covariance[0, 0] += max(watch.wander_variance(axis_filter.last, judged, axis), 0.0)
            h = np.array([1.0, x if self.learn_slope else 0.0])
            noise = float(judged.independent[axis])
            predicted = float(h @ axis_filter.state)
            innovation_variance = float(h @ axis_filter.covariance @ h) + noise
            innovation = residual - predicted
            if axis_filter.last is not None and abs(innovation) > OUTLIER_SIGMAS * math.sqrt(innovation_variance):
                axis_filter.outliers += 1
                if axis_filter.outliers < OUTLIERS_IN_A_ROW:
                    self.rejected += 1
                    self.accepted_since[axis] = None
                    continue
                # the offset moved: a new level, the slope kept
                axis_filter.state[0] = residual - (axis_filter.state[1] * x if self.learn_slope else 0.0)
                axis_filter.covariance = np.diag([noise + axis_filter.covariance[1, 1] * x * x,
                                                  axis_filter.covariance[1, 1]])
                axis_filter.outliers = 0
                axis_filter.last = judged
                self.accepted_since[axis] = judged.rest.index
                used = True
                continue
            axis_filter.outliers = 0
            if self.accepted_since[axis] is None:
                self.accepted_since[axis] = judged.rest.index
            gain = axis_filter.covariance @ h / innovation_variance
            axis_filter.state = axis_filter.state + gain * innovation
            keep = np.eye(2) - np.outer(gain, h)  # Joseph's form: stays a covariance
            covariance = keep @ axis_filter.covariance @ keep.T + np.outer(gain, gain) * noise
            axis_filter.covariance = 0.5 * (covariance + covariance.T)
            total_offset = self.start.offset[axis] + axis_filter.state[0]
            bound = self.total_offset_bound[axis]
            axis_filter.state[0] = float(np.clip(total_offset, -bound, bound)) - self.start.offset[axis]
            total_slope = self.start.slope[axis] + axis_filter.state[1]
            axis_filter.state[1] = float(np.clip(total_slope, -self.slope_bound[axis], self.slope_bound[axis])) \
                - self.start.slope[axis]
            axis_filter.last = judged
            used = True
        if not used:
            return None
        self.rests += 1
        self.changed = True
        return self.adjustment()

    def state(self) -> LearnedState:
        """What to keep for the next run: the slope as learned; the offset as the mean over runs of the turn-on offsets.

        With the file's turn-on repeatability ``R``, a run's offset is the persistent correction plus
        its own turn-on (spread ``R``): the persistent correction moves towards the run's by the
        Kalman gain of that spread; without one, the run's offset is kept whole (nothing tells a
        turn-on from a moved curve).
        """
        offset, offset_variance, slope, slope_variance = [], [], [], []
        for axis, axis_filter in enumerate(self._filters):
            start_offset = self.start.offset[axis]
            if axis_filter.last is None:
                offset.append(start_offset)
                offset_variance.append(self.start.offset_variance[axis])
                slope.append(self.start.slope[axis])
                slope_variance.append(self.start.slope_variance[axis] if self.start.runs
                                      else float(self.slope_prior[axis] ** 2))
                continue
            o, s = axis_filter.state
            run_variance = float(axis_filter.covariance[0, 0])
            if self.repeatability is not None:
                prior = self.start.offset_variance[axis] if self.start.runs else float(self.offset_prior[axis] ** 2)
                gain = prior / (prior + self.repeatability[axis] ** 2 + run_variance)
                offset.append(float(start_offset + gain * o))
                offset_variance.append(float((1.0 - gain) * prior))
            else:
                offset.append(float(start_offset + o))
                offset_variance.append(run_variance)
            slope.append(float(self.start.slope[axis] + s))
            slope_variance.append(float(axis_filter.covariance[1, 1]))
        runs = self.start.runs + (1 if self.rests else 0)
        start = self.start
        first = self.first_residual
        turn_on = (start.turn_on_runs, start.turn_on_sum, start.turn_on_squares) if first is None else (
            start.turn_on_runs + 1, tuple(t + v for t, v in zip(start.turn_on_sum, first)),
            tuple(t + v * v for t, v in zip(start.turn_on_squares, first)))
        return replace(start, offset=tuple(offset), offset_variance=tuple(offset_variance),  # type: ignore
                       slope=tuple(slope), slope_variance=tuple(slope_variance), runs=runs,  # type: ignore[arg-type]
                       rests=start.rests + self.rests, rejected=start.rejected + self.rejected,
                       turn_on_runs=turn_on[0], turn_on_sum=turn_on[1], turn_on_squares=turn_on[2])  # type: ignore

    def values(self) -> list[tuple[str, str]]:
        """The diagnostics' learning figures."""
        offset, slope = self.adjustment()
        return [('learn.rests', str(self.rests)), ('learn.rejected', str(self.rejected)),
                ('learn.runs_before', str(self.start.runs)),
                ('learn.gyro_offset_deg_h', ' '.join(f'{v * DEG_PER_H:.4g}' for v in offset[3:])),
                ('learn.gyro_slope_deg_h_per_c', ' '.join(f'{v * DEG_PER_H:.3g}' for v in slope[3:]))]


def adjust(values: tuple[float, ...], temperature: float, adjustment: tuple[tuple[float, ...], tuple[float, ...]],
           reference: float) -> tuple[float, ...]:
    """A message's six values less ``a + b (T - T_ref)``: the node's path (``apply``: :func:`adjust_array`)."""
    return tuple(map(operator.sub, values, adjustment_at(temperature, adjustment, reference)))


def adjustment_at(temperature: float, adjustment: tuple[tuple[float, ...], tuple[float, ...]],
                  reference: float) -> tuple[float, ...]:
    """``a + b (T - T_ref)`` per value: what :func:`adjust` subtracts at a temperature (the node keeps it per T)."""
    offset, slope = adjustment
    dt = temperature - reference
    return tuple(a + b * dt for a, b in zip(offset, slope))


def adjust_array(values: np.ndarray, temperature: np.ndarray, adjustment: tuple[tuple[float, ...], tuple[float, ...]],
                 reference: float) -> np.ndarray:
    """:func:`adjust` of ``(k, 6)`` values at ``(k,)`` temperatures: the same operations, the same floats."""
    offset, slope = (np.asarray(part, dtype=float) for part in adjustment)
    dt = np.asarray(temperature, dtype=float) - reference
    return values - (offset[None, :] + slope[None, :] * dt[:, None])
