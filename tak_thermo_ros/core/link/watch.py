"""The calibration watch: the calibration judged at each rest of a run against the sensor's own noise.

A calibration is fitted once; a MEMS unit's offset curve moves in service (ageing, solder
stress, a hard landing, a new mount). The watch runs beside the correction, on its output
(the corrected accelerometer and gyroscope, their stamps and temperature: the node's messages,
or ``tak_calib validate``'s replay of a record: the same code, the same verdict):

1. **Rests, online** (:mod:`tak_thermo_ros.core.link.rests`): the offline detector's rule on
   running windows on the stamps' clock; per message one comparison and one append.
2. **The residual at a rest** (:class:`CalibrationWatch`): per gyroscope axis the corrected
   mean less the Earth rate's vertical part (with a latitude; its horizontal part, whose
   direction the heading sets, counts as noise); the corrected ``|f|`` less gravity.
3. **Its noise** (:mod:`tak_thermo_ros.core.link.rest_noise`) from the calibration's noise models
   (white noise, quantisation, bias instability, random walk, rate ramp, Gauss-Markov
   processes: not white alone), the bias's wander between rests, the calibration's own error.
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
   gyro y slope +2.1 deg/h/C, accel z 3.2 mg), once a test fires; the verdict holds for the run
   (:mod:`tak_thermo_ros.core.link.watch_words`: the verdict, the figures, the log lines).
6. **Learning, opt-in** (:mod:`tak_thermo_ros.core.link.learning`): per gyroscope axis an offset
   and a slope correction to the curve, learned at the rests.
7. **The turn-on offset of a run** (``turn_on``, off by default): the first rest's gyroscope
   residual (and, with a known gravity, the accelerometer's along its axis nearest the
   vertical) is taken as the run's offset, within :data:`TURN_ON_SIGMAS` of the repeatability,
   and subtracted from every message from the one that ends the rest on: the node and
   ``tak_calib apply`` run the same code on the same samples and agree float for float.

Imports numpy only (the node loads it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from tak_thermo_ros.core.link.learning import (
    TURN_ON_SIGMAS,
    Adjustment,
    LearnedState,
    Learner,
    adjust_array,
    calibration_digest,
)
from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.link.rest_noise import CHANNELS, JudgedRest, RestNoise, positive_part
from tak_thermo_ros.core.link.rests import Rest, RestFinder
from tak_thermo_ros.core.link.student import estimated_spread_factor, two_sided_threshold
from tak_thermo_ros.core.link.watch_words import ChannelState, Finding, WatchWords
from tak_thermo_ros.core.noise.model import NoiseModel
from tak_thermo_ros.core.values import DEG_PER_H, MG, STANDARD_GRAVITY, normal_gravity
from tak_thermo_ros.errors import TakError

FALSE_ALARMS_PER_HOUR = 0.05
"""The stated false-alarm rate: at most this many "stale" verdicts per hour of rests of a unit
whose calibration holds (one in 20 hours of rests), by the union bound over every test."""
MAX_RESTS_JUDGED = 32
"""Rests a judgement looks at: the run's first and the latest ones (bounded work per rest)."""
SLOPE_SPAN_C = 1.0
"""The slope alternative is tested once the rests span at least this many degrees C."""
GRAVITY_HEIGHT_SD = 3e-3
"""m/s^2: the spread of gravity with the place's height (about +-1 km) when only a latitude is known."""
GRAVITY_LATITUDE_SD = (9.8321849 - 9.7803253) / math.sqrt(12.0)
"""m/s^2: the spread of normal gravity over every latitude (uniform), when no latitude is given."""
VERTICAL_AXIS_COSINE = math.cos(math.radians(30.0))
"""The accelerometer's turn-on offset is taken along an axis within 30 degrees of the vertical only."""
UNDETERMINED_RATIO = 3.0
"""A rest's ``|f|`` is not judged when the calibration's own uncertainty there (against the run's first
rest: a tilt its file never determined) exceeds this many times the rest's noise; it is said instead."""
ANOTHER_CALIBRATION = 'learned on another calibration'
"""How the watch's notice of a learned state it left (another calibration's) begins."""


@dataclass(frozen=True)
class Repeatability:
    """A turn-on repeatability the calibration file lacks, per axis (SI), and where it came from (a few words).

    ``runs``: how many power-ups it was estimated from (``None``: given, a data sheet's: taken as known).
    """

    repeatability: tuple[float, float, float]
    source: str
    runs: int | None = None


class WatchUnavailable(TakError):
    """The calibration gives the watch nothing to judge against (no noise model, no gyroscope)."""


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
        :data:`~tak_thermo_ros.core.link.learning.MIN_SPREAD_RUNS` runs or more (the gyroscope's), else ``None``.
        """
        learned = self.learn.turn_on_spread() if self.learn is not None else None
        out = []
        for sensor, given in zip(('accel', 'gyro'), self.turn_on_repeatability):
            if given is not None:
                out.append(Repeatability(tuple(float(v) for v in given), f'{sensor}_turn_on_repeatability'))
            elif sensor == 'gyro' and learned is not None:
                out.append(Repeatability(learned, f'the spread of {self.learn.turn_on_runs} earlier runs\' '
                                                  f'turn-on offsets (learned_file)', self.learn.turn_on_runs))
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


class CalibrationWatch(RestNoise, WatchWords):
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
        self.adjustment: Adjustment | None = None
        """What the output loses, per value of a message: ``a + b (T - T_ref)`` as ``(a, b)``; ``None``: nothing."""
        self.adjustment_version = 0
        self.on_adjustment: Callable[[Adjustment | None], None] | None = None
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
        self._turn_on_runs = tuple(known.records if known is not None else given.runs if given is not None else None
                                   for known, given in zip(self._turn_on_sd, repeatabilities))
        """Per sensor how many power-ups the repeatability was estimated from (``None``: given, taken as known)."""
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

    # -- the residual at a rest ----------------------------------------------------------------

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

    # -- the tests -------------------------------------------------------------------------------

    def _turn_on_repeatability(self, channel: int, up: np.ndarray) -> float | None:
        """The turn-on repeatability of a channel (``|f|``: projected on the up direction), or ``None``."""
        accel, gyro = self._turn_on_sd
        if channel < 3:
            return None if gyro is None else gyro.repeatability[channel]
        if accel is None:
            return None
        return float(math.sqrt(sum(u * u * r * r for u, r in zip(up, accel.repeatability))))

    def _turn_on_covariance(self, rests: list[JudgedRest], channel: int, probability: float = 0.0) -> np.ndarray:
        """``(k, k)`` the run's turn-on offset in the rests' residuals: one constant per gyroscope axis.

        ``|f|`` takes the accelerometer's turn-on offset ``t`` along each rest's up direction
        (``u_i . t``: it changes with the tilt), ``u_i' diag(R^2) u_j``; at a test's tail ``probability``
        a repeatability estimated from a few power-ups as a Student's t (``student.estimated_spread_factor``).
        """
        accel, gyro = self._turn_on_sd
        sensor = int(channel < 3)
        share = self._turn_on_share[sensor] * estimated_spread_factor(probability, self._turn_on_runs[sensor])
        if channel < 3:
            return np.full((len(rests), len(rests)), share * gyro.repeatability[channel] ** 2)  # type: ignore
        ups = np.array([rest.up for rest in rests])
        return share * (ups * np.square(accel.repeatability)) @ ups.T  # type: ignore[union-attr]

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
            wander = [0.0 if last is None else self.wander_variance(last, judged, axis)
                      for axis, last in enumerate(self.learner.last_rests())]
            adjustment = self.learner.update(judged, wander)
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
        independent = np.array([rest.independent[channel] for rest in rests])
        temperatures = np.array([rest.rest.temperature for rest in rests])
        alternatives: list[tuple[np.ndarray, str, int, float]] = []  # (regressor, kind, since, share)
        share = self.false_alarms_per_hour * judged.rest.duration_s / 3600.0 / len(CHANNELS)
        if repeatability is not None:
            # the turn-on alternative's tail (the offset since rest 1: all of a first rest's share, else a quarter)
            covariance = self.residual_covariance(rests, channel, share * (1.0 if count == 1 else 0.25))
            y = np.array([rest.residual[channel] for rest in rests])
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
            covariance = self.residual_covariance(rests, channel)
            steps = count - 1
            spread = float(np.ptp(temperatures)) >= SLOPE_SPAN_C
            step_share = 0.5 / steps if spread else 1.0 / steps
            if spread:
                alternatives.append((temperatures[1:] - temperatures[0], 'slope', 0, 0.5))
            alternatives += [(np.array([1.0 if i >= m else 0.0 for i in range(1, count)]), 'offset',
                              rests[m].rest.index, step_share) for m in range(1, count)]
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

    def residual_covariance(self, rests: list[JudgedRest], channel: int, tail: float = 0.0) -> np.ndarray:
        """The covariance of the rests' residuals on a channel as :meth:`_test` takes them (the first rest first).

        With a turn-on repeatability ``(k, k)``: of the residuals, the turn-on at a test's ``tail``
        (``student.estimated_spread_factor``; 0: the spread as known); without, ``(k-1, k-1)``: of their differences
        from the first rest.
        """
        first, wander = rests[0], self._wander_covariance(rests, channel)
        independent = np.array([rest.independent[channel] for rest in rests])
        if self._turn_on_repeatability(channel, first.up) is None:
            return (independent[0] + wander[1:, 1:] + np.diag(independent[1:])
                    + self.calibration_covariance(rests[1:], channel, first))
        constant = self._turn_on_covariance(rests, channel, tail) + self._constant_variance(first, channel)
        return constant + wander + np.diag(independent) + self.calibration_covariance(rests, channel)

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
        self._set_adjustment(Adjustment(tuple(float(v) for v in offset), (0.0,) * 6))

    def _set_adjustment(self, adjustment: Adjustment | None) -> None:
        if adjustment is not None and not adjustment.any():
            adjustment = None
        self.adjustment = adjustment
        self.adjustment_version += 1
        if self.on_adjustment is not None:
            self.on_adjustment(adjustment)


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
