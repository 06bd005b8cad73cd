"""Learning, opt-in: the gyroscope's curve learned at the rests the watch judged, kept from run to run.

Per gyroscope axis an offset and a slope correction to the curve, and a slope beyond each edge of
the calibrated range (:class:`Learner`: a Kalman filter, the fitted curve its prior, the bias's
wander between rests its process noise; the file's correction holds the edge's value beyond its
range, so a unit used hotter or colder than its records were misses the curve's slope there, and
learning takes it from the rests out there), the
turn-on offset taken at the first rest, innovations beyond :data:`OUTLIER_SIGMAS` rejected (three
in a row: a new level), the corrections bounded. The learner takes each rest as the watch judged
it and the variance of the bias's wander since the rest it took last, as numbers
(:meth:`Learner.update`), not the watch (:mod:`tak_thermo_ros.core.link.watch` computes them).

:class:`LearnedState` is what a run keeps for the next (the learned file,
:mod:`tak_thermo_ros.formats.learned_file`), :func:`check_learned` bounds it wherever it is read,
:func:`learned_unit` folds it into a calibration; :func:`adjust` (the node's path) and
:func:`adjust_array` (``apply``'s) subtract what the output loses, float for float alike.

Imports numpy only (the node loads it).
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, NamedTuple, Sequence

import numpy as np

from tak_thermo_ros.core.link.model import AxisModel, Calibration, InputKind, UnitCalibration
from tak_thermo_ros.core.link.rest_noise import JudgedRest, beyond_slope_variances
from tak_thermo_ros.core.values import DEG_PER_H, finite_number
from tak_thermo_ros.errors import TakError

TURN_ON_SIGMAS = 5.0
"""A run's turn-on offset is taken (``turn_on: first_rest``) within this many standard deviations
of the repeatability (and the rest's own noise); beyond, it is not taken, and the line says by how much
(what moved it, the watch's tests tell: the offset alone cannot)."""
OUTLIER_SIGMAS = 4.0
"""Learning leaves out a rest whose innovation lies beyond this many standard deviations."""
OUTLIERS_IN_A_ROW = 3
"""... unless this many in a row: then the offset moved, and the learning takes the new level."""
OFFSET_BOUND_SIGMAS = 6.0
"""Learning bounds a gyroscope axis's offset correction to this many turn-on repeatabilities or the
offset curve's own span over the calibrated range, whichever is larger, on the unit's widest axis."""
VARIANCE_BOUNDS = 1000.0
"""A learned correction's variance read back is at most the square of this many bounds (a spread, not a value)."""
SLOPE_PRIOR_SHARE = 0.5
"""The prior of a slope correction: its standard deviation is this share of the curve's largest slope."""
BEYOND_BOUND_SIGMAS = 6.0
"""Learning bounds a slope beyond an edge of the calibrated range to this many of its prior's standard
deviations (the curve's own slope at the edge and the file's ``beyond`` spread)."""
MIN_SPREAD_RUNS = 5
"""The node takes the spread of its earlier runs' turn-on offsets for a repeatability from this many runs on
(as a fit takes a pool's: fewer power-ups leave the spread undetermined)."""


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
    :param below: ``(3,)`` the slope learned below the calibrated range's low edge (rad/s per degree C: the
        output loses ``below (T - low)`` under it); ``above`` above its high edge (``above (T - high)``).
    :param below_variance: ``(3,)`` its variance; empty: not learned yet (a file written before learning kept
        it), the prior then holds; ``above_variance`` alike.
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
    below: tuple[float, float, float] = (0.0, 0.0, 0.0)
    below_variance: tuple[float, ...] = ()
    above: tuple[float, float, float] = (0.0, 0.0, 0.0)
    above_variance: tuple[float, ...] = ()

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
                'turn_on_squares': list(self.turn_on_squares), 'below': list(self.below),
                'below_variance': list(self.below_variance), 'above': list(self.above),
                'above_variance': list(self.above_variance)}

    @classmethod
    def from_mapping(cls, raw: Mapping[str, Any], where: str) -> LearnedState:
        """Read :meth:`to_mapping` back.

        :raises TakError: naming ``where`` and the key, on a missing or bad value.
        """
        if not isinstance(raw, Mapping):
            msg = f'{where}: expected a mapping'
            raise TakError(msg)
        values: dict[str, Any] = {}
        for name in ('offset', 'offset_variance', 'slope', 'slope_variance', 'turn_on_sum', 'turn_on_squares',
                     'below', 'below_variance', 'above', 'above_variance'):
            if name.startswith(('turn_on', 'below', 'above')) and name not in raw:  # written before it kept them
                continue
            if name in ('below_variance', 'above_variance') and raw.get(name) == []:  # not learned yet
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
    notes = [note]
    for side, values, edge in (('below', state.below, gyro.temp_code_min), ('above', state.above, gyro.temp_code_max)):
        if any(values):  # a polynomial that holds its edge's value cannot carry them: said, and kept in `learned`
            notes.append(f'learned slope {side} {edge:.4g} C '
                         f'{" ".join(f"{v * DEG_PER_H:+.3g}" for v in values)} deg/h/C: not in this curve '
                         f'(it holds the edge\'s value); the node applies it from the learned section')
    learned = replace(gyro, axes=tuple(axes), notes=(*gyro.notes, *notes))  # type: ignore[arg-type]
    return replace(unit, gyro=learned)


class Adjustment(NamedTuple):
    """What the output loses per message value (six: the accelerometer's, then the gyroscope's).

    ``offset + slope (T - reference) + below min(T - low, 0) + above max(T - high, 0)``: the run's
    turn-on offset and the learned curve, its slopes beyond the calibrated range ``low .. high``.
    """

    offset: tuple[float, ...]
    slope: tuple[float, ...]
    below: tuple[float, ...] = (0.0,) * 6
    above: tuple[float, ...] = (0.0,) * 6
    low: float = -math.inf
    high: float = math.inf

    def any(self) -> bool:
        """Whether it changes any value."""
        return any(self.offset) or any(self.slope) or any(self.below) or any(self.above)


@dataclass
class _AxisFilter:
    """One gyroscope axis's Kalman filter over the run: state ``(o, s, b, a)``.

    ``r = o + s (T - reference) + b min(T - low, 0) + a max(T - high, 0)``: an offset, a slope, and
    the slopes below and above the calibrated range.
    """

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
        self.low, self.high = float(low), float(high)
        below, above = beyond_slope_variances(gyro)
        self.beyond_prior = np.sqrt(np.vstack([below, above]))
        """``(2, 3)`` the prior's standard deviation of the slopes below and above the range (the watch's own)."""
        self.beyond_bound = BEYOND_BOUND_SIGMAS * self.beyond_prior
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
            beyond_variances = [start_variance[axis] if self.start.runs and len(start_variance) == 3
                                else float(self.beyond_prior[side, axis] ** 2)
                                for side, start_variance in enumerate((self.start.below_variance,
                                                                       self.start.above_variance))]
            self._filters.append(_AxisFilter(np.zeros(4), np.diag([offset_variance, slope_variance,
                                                                   *beyond_variances])))

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
        bounds = (('offset', 'deg/h', self.total_offset_bound), ('slope', 'deg/h/C', self.slope_bound),
                  ('below', 'deg/h/C', self.beyond_bound[0]), ('above', 'deg/h/C', self.beyond_bound[1]))
        for name, units, bound in bounds:
            values, variances = getattr(start, name), getattr(start, f'{name}_variance') or (0.0, 0.0, 0.0)
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
        return np.asarray(adjustment_at(temperature, self._adjustment(np.zeros((3, 4))), self.reference)[3:])

    def _row(self, temperature: float) -> np.ndarray:
        """``(4,)`` what each state of an axis's filter adds to the correction at a temperature."""
        return np.array([1.0, temperature - self.reference if self.learn_slope else 0.0,
                         min(temperature - self.low, 0.0), max(temperature - self.high, 0.0)])

    def _adjustment(self, states: np.ndarray) -> Adjustment:
        """The start's corrections and ``(3, 4)`` states of this run, per message value."""
        start = self.start
        parts = [[0.0] * 6 for _ in range(4)]
        for axis, state in enumerate(states):
            for part, (begun, value) in enumerate(zip((start.offset, start.slope, start.below, start.above), state)):
                parts[part][3 + axis] = float(begun[axis] + value)
        return Adjustment(*(tuple(part) for part in parts), self.low, self.high)  # type: ignore[arg-type]

    def adjustment(self) -> Adjustment:
        """What the output loses per message value: the start's corrections and this run's estimate."""
        return self._adjustment(np.array([axis_filter.state for axis_filter in self._filters]))

    def last_rests(self) -> list[JudgedRest | None]:
        """Per axis the rest its filter took last (``None``: none yet): :meth:`update` needs the wander since."""
        return [axis_filter.last for axis_filter in self._filters]

    def update(self, judged: JudgedRest, wander: Sequence[float]) -> Adjustment | None:
        """One rest: each axis's filter steps (the wander since the last rest), takes the rest unless an outlier.

        :param judged: the rest as the watch judged it (its residuals against the start's curve, their own noise).
        :param wander: per axis the variance of the bias's wander between :meth:`last_rests` and ``judged``
            (read only where the axis took a rest before).
        """
        h = self._row(judged.rest.temperature)
        used = False
        if self.first_residual is None:
            self.first_residual = (float(judged.residual[0]), float(judged.residual[1]), float(judged.residual[2]))
        for axis, axis_filter in enumerate(self._filters):
            residual = float(judged.residual[axis])  # against the start's curve
            if axis_filter.last is not None:
                axis_filter.covariance[0, 0] += max(wander[axis], 0.0)
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
                # the offset moved: a new level, the slopes kept
                axis_filter.state[0] = residual - float(h[1:] @ axis_filter.state[1:])
                kept = axis_filter.covariance[1:, 1:]
                covariance = np.zeros((4, 4))
                covariance[0, 0] = noise + float(h[1:] @ kept @ h[1:])
                covariance[1:, 1:] = kept
                axis_filter.covariance = covariance
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
            keep = np.eye(4) - np.outer(gain, h)  # Joseph's form: stays a covariance
            covariance = keep @ axis_filter.covariance @ keep.T + np.outer(gain, gain) * noise
            axis_filter.covariance = 0.5 * (covariance + covariance.T)
            total_offset = self.start.offset[axis] + axis_filter.state[0]
            bound = self.total_offset_bound[axis]
            axis_filter.state[0] = float(np.clip(total_offset, -bound, bound)) - self.start.offset[axis]
            total_slope = self.start.slope[axis] + axis_filter.state[1]
            axis_filter.state[1] = float(np.clip(total_slope, -self.slope_bound[axis], self.slope_bound[axis])) \
                - self.start.slope[axis]
            for side, begun in enumerate((self.start.below, self.start.above)):
                bound = float(self.beyond_bound[side, axis])
                axis_filter.state[2 + side] = float(np.clip(begun[axis] + axis_filter.state[2 + side], -bound,
                                                            bound)) - begun[axis]
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
        beyond: list[list[float]] = [[], [], [], []]  # below, its variance, above, its variance
        for axis, axis_filter in enumerate(self._filters):
            start_offset = self.start.offset[axis]
            for side, (begun, begun_variance) in enumerate(((self.start.below, self.start.below_variance),
                                                            (self.start.above, self.start.above_variance))):
                beyond[2 * side].append(float(begun[axis] + axis_filter.state[2 + side]))
                beyond[2 * side + 1].append(float(axis_filter.covariance[2 + side, 2 + side]))
            if axis_filter.last is None:
                offset.append(start_offset)
                offset_variance.append(self.start.offset_variance[axis])
                slope.append(self.start.slope[axis])
                slope_variance.append(self.start.slope_variance[axis] if self.start.runs
                                      else float(self.slope_prior[axis] ** 2))
                continue
            o, s = axis_filter.state[:2]
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
                       turn_on_runs=turn_on[0], turn_on_sum=turn_on[1], turn_on_squares=turn_on[2],  # type: ignore
                       below=tuple(beyond[0]), below_variance=tuple(beyond[1]), above=tuple(beyond[2]),
                       above_variance=tuple(beyond[3]))

    def values(self) -> list[tuple[str, str]]:
        """The diagnostics' learning figures."""
        offset, slope, below, above = self.adjustment()[:4]
        return [('learn.rests', str(self.rests)), ('learn.rejected', str(self.rejected)),
                ('learn.runs_before', str(self.start.runs)),
                ('learn.gyro_offset_deg_h', ' '.join(f'{v * DEG_PER_H:.4g}' for v in offset[3:])),
                ('learn.gyro_slope_deg_h_per_c', ' '.join(f'{v * DEG_PER_H:.3g}' for v in slope[3:])),
                ('learn.gyro_slope_below_deg_h_per_c', ' '.join(f'{v * DEG_PER_H:.3g}' for v in below[3:])),
                ('learn.gyro_slope_above_deg_h_per_c', ' '.join(f'{v * DEG_PER_H:.3g}' for v in above[3:]))]


def adjust(values: tuple[float, ...], temperature: float, adjustment: Adjustment, reference: float
           ) -> tuple[float, ...]:
    """A message's six values less :func:`adjustment_at`: the node's path (``apply``: :func:`adjust_array`)."""
    return tuple(map(operator.sub, values, adjustment_at(temperature, adjustment, reference)))


def adjustment_at(temperature: float, adjustment: Adjustment, reference: float) -> tuple[float, ...]:
    """``a + b (T - T_ref)`` per value, plus the slopes beyond the range's edges where learned.

    What :func:`adjust` subtracts at a temperature (the node keeps it per temperature).
    """
    offset, slope, below, above, low, high = adjustment
    dt = temperature - reference
    if not any(below) and not any(above):
        return tuple(a + b * dt for a, b in zip(offset, slope))
    under, over = min(temperature - low, 0.0), max(temperature - high, 0.0)
    return tuple(a + b * dt + c * under + d * over for a, b, c, d in zip(offset, slope, below, above))


def adjust_array(values: np.ndarray, temperature: np.ndarray, adjustment: Adjustment, reference: float) -> np.ndarray:
    """:func:`adjust` of ``(k, 6)`` values at ``(k,)`` temperatures: the same operations, the same floats."""
    offset, slope, below, above = (np.asarray(part, dtype=float) for part in adjustment[:4])
    temperature = np.asarray(temperature, dtype=float)
    dt = temperature - reference
    if not below.any() and not above.any():
        return values - (offset[None, :] + slope[None, :] * dt[:, None])
    under = np.minimum(temperature - adjustment.low, 0.0)
    over = np.maximum(temperature - adjustment.high, 0.0)
    return values - (offset[None, :] + slope[None, :] * dt[:, None] + below[None, :] * under[:, None]
                     + above[None, :] * over[:, None])
