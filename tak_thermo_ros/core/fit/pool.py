"""The fit of a pool of records of one unit: the hand-held fit with a turn-on offset per record.

A pool (:func:`~tak_thermo_ros.core.records.handheld.pooled`) is the rests (and short motions) of
many records, each a power-up. It goes through the hand-held fit
(:func:`~tak_thermo_ros.core.fit.handheld.fit_handheld`), which takes each record's turn-on
offset as a random effect (:mod:`~tak_thermo_ros.core.fit.random_effects`). This module adds what
only a pool allows:

- **the order of each axis's offset polynomial, chosen by leaving whole records out** (a prior, when
  given, gives its orders instead, :mod:`~tak_thermo_ros.core.fit.prior`): the pool's
  records in :data:`FOLDS` folds; each candidate order is fitted on the other folds (the variances
  of the whole pool's fit held, the rests alone) and judged on the fold's rests, each record's own
  offset taken off (the shape, what a calibration must carry to a record it never saw), as a
  chi-square against the rests' noise; the order with the lowest is kept (a lower one only within
  :data:`ORDER_TOLERANCE` of it), per gyroscope axis, and one for the accelerometer (its ``|f|``
  mixes the axes);
- **a pool that is not one unit**: the records' turn-on offsets screened
  (:func:`~tak_thermo_ros.core.fit.random_effects.screen_offsets`): a record far beyond the pool's
  spread is left out and the pool fitted again; offsets in two groups refuse the pool.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from tak_thermo_ros.core.fit.handheld import HandheldFit, HandheldSettings, fit_handheld
from tak_thermo_ros.core.fit.random_effects import screen_offsets
from tak_thermo_ros.core.link.correction import OutOfRange
from tak_thermo_ros.core.link.handheld_check import check_handheld
from tak_thermo_ros.core.link.model import AXES, InputKind, UnitCalibration
from tak_thermo_ros.core.records.handheld import HandheldRecord, numbered_rests, records_subset, rest_records
from tak_thermo_ros.core.values import SENSOR_NAMES
from tak_thermo_ros.errors import FitError

FOLDS = 5
"""The pool's records are held out in this many folds (each record once; fewer with fewer records)."""
MIN_RECORDS_FOR_ORDERS = 3
"""Fewer records than this: the orders are the span's (no fold to judge them on)."""
ORDER_TOLERANCE = 0.0
"""A lower order is kept when its held-out chi-square exceeds the best's by at most this: none (issue 39: the
order is not chosen below what the held-out records need; a higher order that misses them scores worse)."""
MIN_RECORDS_FOR_SCREENING = 3
"""Fewer records than this: no record is screened as another unit's (no spread to judge it by)."""


@dataclass(frozen=True)
class OrderChoice:
    """How a sensor's offset orders were chosen.

    :param candidates: the orders tried.
    :param scores: ``(candidates, 3)`` per axis the held-out chi-square over the pool's rests (the
        accelerometer: its ``|f|`` in every column).
    :param orders: per axis the order kept.
    :param rests: rests judged.
    """

    candidates: tuple[int, ...]
    scores: np.ndarray
    orders: tuple[int, int, int]
    rests: int


def _unit(fit: HandheldFit) -> UnitCalibration:
    return UnitCalibration(InputKind.IMU, fit.results['accel'].calibration, fit.results['gyro'].calibration)


def record_means(values: np.ndarray, group: np.ndarray, count: int, weights: np.ndarray | None = None) -> np.ndarray:
    """``(count, ...)`` each record's mean of ``values`` ``(n, ...)``, rows ``group`` ``(n,)`` (zeros: no row).

    :param weights: ``(n,)`` each row's weight (``None``: equal).
    """
    out = np.zeros((count, *values.shape[1:]))
    for index in range(count):
        rows = group == index
        if rows.any():
            out[index] = np.average(values[rows], axis=0, weights=None if weights is None else weights[rows])
    return out


def _rests(record: HandheldRecord) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each rest's record, its kept samples and its mean temperature, ``(k,)`` each."""
    interval, count, _, _ = numbered_rests(record)
    samples = np.bincount(interval, minlength=count).astype(float)
    temperature = np.bincount(interval, weights=record.still.temp_code, minlength=count) / np.maximum(samples, 1.0)
    return rest_records(record), samples, temperature


def _within(temperature: np.ndarray, within: tuple[float, float] | None) -> np.ndarray:
    """Which rests' mean temperatures lie within the range (``None``: all)."""
    if within is None:
        return np.ones(len(temperature), dtype=bool)
    return (temperature >= within[0]) & (temperature <= within[1])


def shape_residuals(record: HandheldRecord, unit: UnitCalibration, *, gravity: float, latitude: float | None,
                    out_of_range: OutOfRange = OutOfRange.CLAMP,
                    within: tuple[float, float] | None = None) -> dict[str, np.ndarray]:
    """Per rest of ``record`` its errors after ``unit``, each record's own mean taken off (its turn-on offset).

    :param within: only the rests whose mean temperature lies within this range (``None``: all).
    :returns: ``gyro``: ``(k, 3)`` the rate error at each rest; ``accel``: ``(k, 1)`` the ``|f|`` error;
        ``record``: ``(k,)`` each rest's record; ``samples``: ``(k,)`` its kept samples;
        ``temperature``: ``(k,)`` its mean temperature; ``up``: ``(k, 3)`` its corrected up direction.
        Each record's mean is the samples-weighted mean of its rests.
    """
    check = check_handheld(record, unit, gravity=gravity, latitude=latitude, out_of_range=out_of_range)
    rest_record, samples, temperature = _rests(record)
    keep = _within(temperature, within)
    rest_record, samples, temperature = rest_record[keep], samples[keep], temperature[keep]
    check = replace(check, rate_error=check.rate_error[keep], gravity_error=check.gravity_error[keep])
    out = {'record': rest_record, 'samples': samples, 'temperature': temperature, 'up': check.up[keep]}
    for sensor, errors in (('gyro', check.rate_error), ('accel', check.gravity_error[:, None])):
        out[sensor] = own_offsets(record, errors, keep)[1]
    return out


def own_offsets(record: HandheldRecord, errors: np.ndarray,
                keep: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each record's own mean of the errors at its rests (its turn-on offset), and the errors with it taken off.

    :param errors: ``(k, ...)`` an error at each rest of ``record`` (each rest kept by ``keep``).
    :param keep: ``(rests,)`` which of the record's rests ``errors`` holds (``None``: all).
    :returns: ``(records, ...)`` each record's samples-weighted mean of its rests' errors, and
        ``(k, ...)`` the errors less their record's mean.
    """
    rest_record, samples, _ = _rests(record)
    if keep is not None:
        rest_record, samples = rest_record[keep], samples[keep]
    own = record_means(errors, rest_record, record.records, samples)
    return own, errors - own[rest_record]


def _variance(sensor: str, residuals: dict[str, np.ndarray], fit: HandheldFit, noise: np.ndarray) -> np.ndarray:
    """``(k, c)`` each held-out rest's error variance: white over its samples plus the rests' extra."""
    samples = residuals['samples'][:, None]
    turn_on = fit.turn_on.get(sensor)
    rest = turn_on.variances.rest if turn_on is not None else np.zeros(3)
    if sensor == 'gyro':
        return noise[3:6][None, :] ** 2 / samples + rest[None, :] ** 2
    # |f| is the axes' errors along the up direction: their variances weighted by u^2
    per_axis = noise[:3][None, :] ** 2 / samples + np.where(np.isfinite(rest), rest, 0.0)[None, :] ** 2
    return np.sum(per_axis * residuals['up'] ** 2, axis=1, keepdims=True)


def choose_orders(record: HandheldRecord, settings: HandheldSettings, full: HandheldFit) -> dict[str, OrderChoice]:
    """Each sensor's offset orders by leaving whole records out (see the module's description).

    :param full: the pool's fit at ``settings``; its bias order (the span's) is the highest order tried.
    """
    top = full.orders[0]
    if record.records < MIN_RECORDS_FOR_ORDERS or top <= 1:
        return {}
    candidates = tuple(range(1, top + 1))
    given = {sensor: (np.where(np.isfinite(fitted.variances.turn_on), fitted.variances.turn_on, 1.0),
                      fitted.variances.rest) for sensor, fitted in full.turn_on.items()}
    folds = min(FOLDS, record.records)
    fold_of = np.arange(record.records) % folds
    scores = {'accel': np.zeros((len(candidates), 3)), 'gyro': np.zeros((len(candidates), 3))}
    judged = 0
    noise = record.intervals.noise
    for fold in range(folds):
        train, test = records_subset(record, fold_of != fold), records_subset(record, fold_of == fold)
        if not len(test.still) or not len(train.still):
            continue
        # extrapolation is not the order's to judge: the rests within the training's temperatures
        span = (float(train.still.temp_code.min()), float(train.still.temp_code.max()))
        judged += int(np.count_nonzero(_within(_rests(test)[2], span)))
        for index, order in enumerate(candidates):
            trial = replace(settings, bias_order=top, axis_orders={'accel': (order,) * 3, 'gyro': (order,) * 3},
                            variances=given, turns=False)
            try:
                fitted = fit_handheld(train, trial)
            except FitError:
                scores['accel'][index] += np.inf
                scores['gyro'][index] += np.inf
                continue
            residuals = shape_residuals(test, _unit(fitted), gravity=settings.gravity, latitude=settings.latitude,
                                        within=span)
            for sensor in ('accel', 'gyro'):
                variance = _variance(sensor, residuals, full, noise)
                scores[sensor][index] += np.sum(residuals[sensor] ** 2 / variance, axis=0)
    choices = {}
    for sensor in ('accel', 'gyro'):
        table = scores[sensor]
        kept = []
        for axis in range(3):
            best = float(np.min(table[:, axis]))
            kept.append(next(order for order, score in zip(candidates, table[:, axis])
                             if score <= best + ORDER_TOLERANCE))
        if sensor == 'accel':
            kept = [kept[0]] * 3
        choices[sensor] = OrderChoice(candidates, table, tuple(kept), judged)  # type: ignore[arg-type]
    return choices


def order_line(sensor: str, choice: OrderChoice) -> str:
    """One statement: the orders kept per axis, and by what."""
    orders = ' '.join(str(order) for order in choice.orders)
    what = 'per axis x y z' if sensor == 'gyro' else '(its |f|)'
    return (f'{SENSOR_NAMES[sensor]}: offset order {what} {orders}, chosen by leaving whole records out '
            f'({len(choice.candidates)} orders tried on {choice.rests} held-out rests)')


def fit_pool(record: HandheldRecord, settings: HandheldSettings = HandheldSettings()) -> PoolFit:
    """Fit a pool of records of one unit (see the module's description).

    The records left out as another unit's are left out once: the pool without them is fitted
    again and not screened again.

    :raises FitError: the pool's turn-on offsets fall in two groups (two units), or as :func:`fit_handheld`.
    """
    fitted, orders = _fit_orders(record, settings)
    if record.records < MIN_RECORDS_FOR_SCREENING:
        return PoolFit(fitted, record, orders)
    outliers = _another_unit(record, fitted)
    if not outliers:
        return PoolFit(fitted, record, orders)
    keep = np.array([name not in {o.name for o in outliers} for name in record.record_names])
    if keep.sum() < 2:
        msg = f'the pool holds no two records of one unit ({len(outliers)} of {record.records} far apart)'
        raise FitError(msg)
    record = records_subset(record, keep)
    fitted, orders = _fit_orders(record, settings)
    return PoolFit(fitted, record, orders, tuple(outliers))


def _fit_orders(record: HandheldRecord, settings: HandheldSettings) -> tuple[HandheldFit, dict[str, OrderChoice]]:
    """The pool's fit at the orders chosen by leaving whole records out (:func:`choose_orders`), and the choice."""
    full = fit_handheld(record, settings)
    orders = choose_orders(record, settings, full) if settings.prior is None else {}  # a prior gives its orders
    top = full.orders[0]
    if not orders or (settings.axis_orders is None
                      and all(order == top for choice in orders.values() for order in choice.orders)):
        return full, orders  # every order the span's: nothing held beyond the fit already made
    axis_orders = {sensor: choice.orders for sensor, choice in orders.items()}
    return fit_handheld(record, replace(settings, axis_orders=axis_orders)), orders


@dataclass(frozen=True)
class LeftOut:
    """A record left out of a pool: its turn-on offset far beyond the pool's spread (another unit?).

    :param offset: its offset on that axis, sensor units; ``sigmas``: how many spreads from the pool's.
    """

    name: str
    sensor: str
    axis: int
    offset: float
    sigmas: float


class TwoUnits(FitError):
    """A pool whose records' turn-on offsets fall in two groups: two units, refused.

    :param groups: the two groups' record names; ``centres``: their offsets' medians (sensor units).
    """

    def __init__(self, sensor: str, axis: int, groups: tuple[tuple[str, ...], tuple[str, ...]],
                 centres: tuple[float, float], spreads: float) -> None:
        super().__init__(f'the pool looks like two units: {SENSOR_NAMES[sensor]} {AXES[axis]} turn-on offsets near '
                         f'{centres[0]:.3g} and {centres[1]:.3g}, {spreads:.0f} spreads apart')
        self.sensor, self.axis, self.groups, self.centres, self.spreads = sensor, axis, groups, centres, spreads


@dataclass(frozen=True)
class PoolFit:
    """A pool's fit.

    :param fit: the hand-held fit of the records kept.
    :param record: the records kept (their pool).
    :param orders: per sensor how its orders were chosen (empty: the span's, too few records).
    :param left_out: each record left out as another unit's.
    """

    fit: HandheldFit
    record: HandheldRecord
    orders: dict[str, OrderChoice]
    left_out: tuple[LeftOut, ...] = ()


def _own_precision(record: HandheldRecord, sensor: str, rest: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``(r, 3)`` how well each record's own rests tell its offset: ``1 / sqrt(sum w / (s^2 / n + t^2))``.

    Not the offsets' errors from the fit, which carry the pool's spread (inflated by the very record
    that is another unit's). The gyroscope's rests see each axis whole (``w = 1``); the
    accelerometer's through ``|f|``, each axis along the rest's up direction (``w = u_a^2``: near
    level its x and y offsets at a tenth of their size).
    """
    rest_record, samples, _ = _rests(record)
    noise = record.intervals.noise[3:6] if sensor == 'gyro' else record.intervals.noise[:3]
    extra = np.where(np.isfinite(rest), rest, 0.0)
    seen = np.ones((len(rest_record), 3)) if sensor == 'gyro' else up[:len(rest_record)] ** 2
    information = np.zeros((record.records, 3))
    np.add.at(information, rest_record, seen / (noise[None, :] ** 2 / samples[:, None] + extra[None, :] ** 2))
    return 1.0 / np.sqrt(np.maximum(information, 1e-300))


def _another_unit(record: HandheldRecord, fitted: HandheldFit) -> list[LeftOut]:
    """Records whose turn-on offset is far beyond the pool's spread; two groups of offsets refuse the pool.

    :raises TwoUnits: the offsets fall in two groups.
    """
    found: dict[int, LeftOut] = {}
    for sensor in ('gyro', 'accel'):
        turn_on = fitted.turn_on.get(sensor)
        if turn_on is None:
            continue
        determined = turn_on.variances.determined
        offsets = np.where(determined[None, :], turn_on.offsets, np.nan)
        screening = screen_offsets(offsets, _own_precision(record, sensor, turn_on.variances.rest, fitted.up))
        if screening.groups:
            axis = screening.axis
            groups = tuple(tuple(record.record_names[i] for i in group) for group in screening.groups)
            centres = tuple(float(np.median(turn_on.offsets[list(group), axis])) for group in screening.groups)
            raise TwoUnits(sensor, axis, groups, centres, screening.gap_sigmas)  # type: ignore[arg-type]
        for index, axis, sigmas in screening.outliers:
            if index not in found:
                found[index] = LeftOut(record.record_names[index], sensor, axis, float(turn_on.offsets[index, axis]),
                                       sigmas)
    return [found[index] for index in sorted(found)]
