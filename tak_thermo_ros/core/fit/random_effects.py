"""A pool's random effects: each power-up's turn-on offset, and what the rests add beyond white noise.

Records of one unit, each a power-up, share the unit's link against temperature; each adds its own
constant to every axis (the turn-on offset, the bias repeatability). Taken as a fixed term per
record it would cost the shape every record's between-record information; left out it would
leak into the shape (a record's offset seen as a change with its temperature). Here it is a
*random effect*: ``u_r ~ N(0, s_u^2)`` per record and axis, fitted as columns of the design with a
prior row ``u_r / s_u = 0`` each (Henderson's mixed-model equations: the link's coefficients are
then exactly the generalised least squares with the records' offsets integrated out).

A rest's mean carries more than the white noise ``s^2 / n``: the bias instability and the random
walk add about the same to every rest's mean whatever its length (``t^2``), which is where a
long rest's weight ends. Each rest's mean row (the first row of its compressed samples, the one
along the constant) is weighted by ``1 / sqrt(s^2 + n t^2)`` (in the units of one sample).

``s_u`` and ``t`` per axis are the restricted maximum likelihood (REML) of the pool (the
criterion is ``_Reml.__call__`` in :mod:`~tak_thermo_ros.core.fit.handheld`):
``log|V| + log|G| + log|C| + r' V^-1 r`` of the whitened system, minimised over their
logarithms (:func:`fit_variances`); the standard error of ``s_u`` comes from
the criterion's curvature (the observed information). With few records it is wide: the spread
of 10 offsets is known to about 25 %.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from tak_thermo_ros.core.fit.design import Column

TURN_ON = 'the turn-on offset'
"""The label of a record's turn-on offset column (:class:`~tak_thermo_ros.core.fit.design.Column`)."""
OUTLIER_ALPHA = 1e-3
"""A record's turn-on offset is another unit's when the others' spread leaves it that far out this seldom."""
GROUP_SIGMAS = 12.0
"""Two groups of records whose offsets lie this many spreads apart are two units (one in a thousand six-record
pools of one unit falls apart by 10.7)."""
MIN_GROUP = 3
"""A group of records needs this many (its own spread)."""
GRID_POINTS = 19
GRID_SWEEPS = 2
"""The variances are first searched on a grid of this many points per parameter (over nine decades), this many times,"""
SEARCH_CYCLES = 6
SEARCH_SETTLED = 0.01
"""... then by one-dimensional searches in turn, at most this many cycles, until none moves by this much (log)."""


def turn_on_columns(records: int) -> tuple[Column, ...]:
    """One column label per record (its offset on the axis)."""
    return tuple(Column(TURN_ON, '', f'r{record}') for record in range(records))


def record_indicators(record: np.ndarray, records: int) -> np.ndarray:
    """``(n, records)``: 1 in the column of each row's record."""
    record = np.asarray(record, dtype=np.int64)
    out = np.zeros((len(record), records))
    if len(record):
        out[np.arange(len(record)), record] = 1.0
    return out


@dataclass(frozen=True)
class Variances:
    """A sensor's variance components, per axis x y z (sensor units).

    :param turn_on: the turn-on offset's standard deviation over power-ups (``nan``: not determined).
    :param turn_on_error: its standard error.
    :param rest: what a rest's mean carries beyond the white noise (bias instability, random walk).
    :param determined: per axis whether the records determine its turn-on offset.
    """

    turn_on: np.ndarray
    turn_on_error: np.ndarray
    rest: np.ndarray
    determined: np.ndarray


def fit_variances(criterion: Callable[[np.ndarray, np.ndarray], float], start_turn_on: np.ndarray,
                  start_rest: np.ndarray, determined: np.ndarray, white: np.ndarray) -> Variances:
    """The REML of the turn-on offset's spread and the rests' extra variance, per axis.

    :param criterion: ``(turn_on (3,), rest (3,)) -> -2 log REML`` up to a constant.
    :param determined: per axis whether its turn-on offsets are determined (else held at ``start``, and its
        rests' extra variance at 0: an axis whose offset the records do not tell has no variance to tell either).
    :param white: per axis the white noise of one sample (sets the search's bounds).
    """
    from scipy.optimize import minimize_scalar
    determined = np.asarray(determined, dtype=bool)
    turn_axes = np.flatnonzero(determined)
    white = np.maximum(np.asarray(white, dtype=float), 1e-12)

    def unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        turn_on = np.array(start_turn_on, dtype=float)
        turn_on[turn_axes] = np.exp(p[:len(turn_axes)])
        rest = np.zeros(3)
        rest[turn_axes] = np.exp(p[len(turn_axes):])
        return turn_on, rest

    def objective(p: np.ndarray) -> float:
        value = criterion(*unpack(p))
        return value if math.isfinite(value) else 1e300

    start = np.concatenate([np.log(np.maximum(np.asarray(start_turn_on, dtype=float)[turn_axes], white[turn_axes]
                                              * 1e-3)),
                            np.log(np.maximum(np.asarray(start_rest, dtype=float)[turn_axes],
                                              white[turn_axes] * 1e-3))])
    bounds = ([(math.log(w * 1e-5), math.log(w * 1e4)) for w in white[turn_axes]]
              + [(math.log(w * 1e-5), math.log(w * 10.0)) for w in white[turn_axes]])
    # The criterion is flat where a variance is negligible (a plateau a gradient step can stop on):
    # each parameter first on a grid over its whole range, the others held, then by a bounded
    # one-dimensional search around it, in turn until nothing moves (the axes barely couple).
    start = np.clip(start, [b[0] for b in bounds], [b[1] for b in bounds])
    for _ in range(GRID_SWEEPS):
        for index, (low, high) in enumerate(bounds):
            grid = np.linspace(low, high, GRID_POINTS)
            values = []
            for point in grid:
                trial = start.copy()
                trial[index] = point
                values.append(objective(trial))
            start[index] = grid[int(np.argmin(values))]
    for _ in range(SEARCH_CYCLES):
        moved = 0.0
        for index, (low, high) in enumerate(bounds):
            def along(value: float, index: int = index) -> float:
                trial = start.copy()
                trial[index] = value
                return objective(trial)

            step = (high - low) / (GRID_POINTS - 1)
            found = minimize_scalar(along, bounds=(max(low, start[index] - step), min(high, start[index] + step)),
                                    method='bounded', options={'xatol': 1e-3})
            if found.fun < along(start[index]):
                moved = max(moved, abs(found.x - start[index]))
                start[index] = found.x
        if moved < SEARCH_SETTLED:
            break
    best = start
    turn_on, rest = unpack(best)
    error = np.full(3, np.nan)
    if len(turn_axes):
        curvature = _curvature(objective, best, len(turn_axes), bounds)
        # -2 log L: the observed information of log s_u is half the curvature; s_u's error by the delta method
        error[turn_axes] = turn_on[turn_axes] * np.sqrt(2.0 / np.maximum(curvature, 1e-12))
    out_turn = np.where(determined, turn_on, np.nan)
    return Variances(turn_on=out_turn, turn_on_error=error, rest=rest, determined=determined)


def _curvature(objective: Callable[[np.ndarray], float], at: np.ndarray, count: int,
               bounds: Sequence[tuple[float, float]]) -> np.ndarray:
    """The second derivative of ``objective`` along each of the first ``count`` parameters, the others profiled.

    The Schur complement of the numerical Hessian: the information on ``log s_u`` with the rests'
    variances free.
    """
    size = len(at)
    step = 0.05
    hessian = np.zeros((size, size))
    base = objective(at)

    def value(offsets: dict[int, float]) -> float:
        point = at.copy()
        for index, delta in offsets.items():
            point[index] += delta
        return objective(point)

    for i in range(size):
        plus, minus = value({i: step}), value({i: -step})
        hessian[i, i] = (plus - 2.0 * base + minus) / step ** 2
        for j in range(i):
            cross = (value({i: step, j: step}) - value({i: step, j: -step}) - value({i: -step, j: step})
                     + value({i: -step, j: -step})) / (4.0 * step ** 2)
            hessian[i, j] = hessian[j, i] = cross
    first, rest = hessian[:count, :count], hessian[count:, count:]
    coupling = hessian[:count, count:]
    if rest.size:
        inverse = np.linalg.pinv(rest)
        first = first - coupling @ inverse @ coupling.T
    return np.diag(first)


@dataclass(frozen=True)
class Screening:
    """Which records' turn-on offsets belong to the pool's unit.

    :param outliers: ``(record, axis, distance)`` of each record far beyond the other records' spread
        (the distance in units of that spread).
    :param groups: two groups of records (their numbers) when the offsets fall apart in two; else empty.
    :param gap_sigmas: how many spreads apart the two groups lie; ``axis`` on which.
    """

    outliers: tuple[tuple[int, int, float], ...]
    groups: tuple[tuple[int, ...], ...] = ()
    gap_sigmas: float = 0.0
    axis: int = 0


def screen_offsets(offsets: np.ndarray, precision: np.ndarray) -> Screening:
    """Records whose turn-on offset ``(r, 3)`` is not the pool's unit's.

    ``precision`` ``(r, 3)``: how well each record's own rests tell its offset (a floor under every
    spread). Two groups: sorted, the offsets split at their largest gap with at least
    :data:`MIN_GROUP` records on each side, the gap more than :data:`GROUP_SIGMAS` times the pooled
    standard deviation within the groups. An outlier: a record whose offset lies further from the
    others' mean, in units of their standard deviation (times ``sqrt(1 + 1/(r-1))``), than a
    Student t with ``r - 2`` degrees of freedom would once in ``1 / OUTLIER_ALPHA`` pools (with the
    ``r`` records tried); four records or more.
    """
    from scipy.stats import t as student
    offsets = np.asarray(offsets, dtype=float)
    precision = np.asarray(precision, dtype=float)
    count = len(offsets)
    for axis in range(offsets.shape[1]):
        values = offsets[:, axis]
        if not np.all(np.isfinite(values)) or count < 2 * MIN_GROUP:
            continue
        order = np.argsort(values)
        gaps = np.diff(values[order])
        inner = gaps[MIN_GROUP - 1:count - MIN_GROUP]
        split = int(np.argmax(inner)) + MIN_GROUP
        low, high = order[:split], order[split:]
        within = math.sqrt((np.sum((values[low] - values[low].mean()) ** 2)
                            + np.sum((values[high] - values[high].mean()) ** 2)) / (count - 2))
        spread = max(within, float(np.median(precision[:, axis])), 1e-300)
        if gaps[split - 1] > GROUP_SIGMAS * spread:
            return Screening((), (tuple(int(i) for i in sorted(low)), tuple(int(i) for i in sorted(high))),
                             float(gaps[split - 1] / spread), axis)
    outliers: dict[int, tuple[int, int, float]] = {}
    if count < 4:
        return Screening(())
    limit = float(student.isf(OUTLIER_ALPHA / (2.0 * count), count - 2))
    for axis in range(offsets.shape[1]):
        values = offsets[:, axis]
        if not np.all(np.isfinite(values)):
            continue
        for record in range(count):
            others = np.delete(values, record)
            spread = max(float(others.std(ddof=1)), float(np.median(precision[:, axis])), 1e-300)
            distance = abs(values[record] - others.mean()) / (spread * math.sqrt(1.0 + 1.0 / len(others)))
            if distance > limit and distance > outliers.get(record, (0, 0, 0.0))[2]:
                outliers[record] = (record, axis, float(distance))
    return Screening(tuple(sorted(outliers.values())))
