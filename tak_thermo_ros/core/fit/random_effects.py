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
criterion is ``_Reml.__call__`` in :mod:`~tak_thermo_ros.core.fit.handheld.pooled`):
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


# ----- a pool's least squares, each record's own columns apart: linear in the records --------------------

ROUND_ROWS = 256
"""A record's rows are folded into its triangular factor this many at a time (every record of a round at once)."""


class RecordColumns:
    """Which columns of a pool's design are a record's own (its turn-on offsets), and the rest (shared).

    A row touches the shared columns and the own columns of at most one record (its rests and
    turns are its own): a least squares over ``W`` columns, ``k`` per record, is then solved in
    time linear in the records (each record's columns absorbed record by record) instead of
    ``W^3``.

    :param own: ``(r, k)`` the columns of each record's ``k`` slots (one per axis).
    :param width: ``W``, the columns of the design; the target is column ``W`` of a row.
    """

    def __init__(self, own: np.ndarray, width: int) -> None:
        self.own = np.asarray(own, dtype=np.int64).reshape(len(own), -1)
        self.width = width
        taken = set(self.own.ravel().tolist())
        self.shared = np.array([j for j in range(width) if j not in taken] + [width], dtype=np.int64)
        """The shared columns and the target (last)."""

    @property
    def records(self) -> int:
        """Records ``r``."""
        return len(self.own)

    @property
    def slots(self) -> int:
        """Own columns per record ``k``."""
        return self.own.shape[1]

    def split(self, rows: np.ndarray, record: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rows ``(..., W + 1)`` as their shared part ``(..., S + 1)`` and their record's slots ``(..., k)``.

        :param record: ``(...)`` each row's record (rows beside the last axis), ``-1``: no record's.
        """
        record = np.asarray(record, dtype=np.int64)
        slots = np.zeros((*rows.shape[:-1], self.slots))
        mine = record >= 0
        if np.any(mine):
            index = self.own[np.where(mine, record, 0)]  # (..., k)
            slots = np.take_along_axis(rows, index, axis=-1) * mine[..., None]
        return rows[..., self.shared], slots


def record_sums(values: np.ndarray, record: np.ndarray, count: int) -> np.ndarray:
    """``(count, ...)``: the sum of ``values`` ``(n, ...)`` over each record's rows (``record`` ``(n,)``; -1: none)."""
    out = np.zeros((count, *values.shape[1:]))
    record = np.asarray(record, dtype=np.int64)
    keep = record >= 0
    if not np.any(keep):
        return out
    order = np.argsort(record[keep], kind='stable')
    sorted_record = record[keep][order]
    starts = np.flatnonzero(np.diff(sorted_record, prepend=-1) != 0)
    out[sorted_record[starts]] = np.add.reduceat(values[keep][order], starts, axis=0)
    return out


@dataclass
class RecordStatistics:
    """The sufficient statistics of a pool's rows: their normal matrix in blocks (linear in the records).

    Over rows ``[X_s | Z_r | y]`` (shared columns, the record's own, the target):

    :param shared: ``(S + 1, S + 1)`` ``[X_s | y]^T [X_s | y]`` over every row.
    :param cross: ``(r, S + 1, k)`` per record ``[X_s | y]^T Z_r`` over its rows.
    :param own: ``(r, k, k)`` per record ``Z_r^T Z_r`` over its rows.

    A fleet's units are records of this kind too (a unit's own columns): these are what a prior
    over the shared columns adds to (``shared``) and what :func:`absorbed` reduces.
    """

    shared: np.ndarray
    cross: np.ndarray
    own: np.ndarray

    @classmethod
    def of_rows(cls, shared: np.ndarray, slots: np.ndarray, record: np.ndarray, records: int) -> RecordStatistics:
        """The statistics of rows split by :meth:`RecordColumns.split` (``(n, S + 1)``, ``(n, k)``, ``(n,)``)."""
        return cls(shared.T @ shared, record_sums(shared[:, :, None] * slots[:, None, :], record, records),
                   record_sums(slots[:, :, None] * slots[:, None, :], record, records))

    def __add__(self, other: RecordStatistics) -> RecordStatistics:
        return RecordStatistics(self.shared + other.shared, self.cross + other.cross, self.own + other.own)


def absorbed(statistics: RecordStatistics, free_slots: np.ndarray, precision: np.ndarray
             ) -> tuple[np.ndarray, float] | None:
    """The shared columns' normal matrix with every record's own columns integrated out, and ``log |Z'Z + P|``.

    ``[X_s | y]^T [X_s | y] - sum_r C_r (Z_r^T Z_r + P)^-1 C_r^T`` (the Schur complement, ``C_r`` the
    record's cross block), over the free slots only (a held slot is 0: it adds nothing).

    :param free_slots: ``(k,)`` which slots are fitted.
    :param precision: ``(k,)`` the prior's precision per slot (``1 / s_u^2``; 0: none).
    :returns: ``None`` when a record's block is not positive definite.
    """
    free = np.flatnonzero(free_slots)
    if not len(free) or not len(statistics.own):
        return statistics.shared, 0.0
    own = statistics.own[:, free][:, :, free] + np.diag(np.asarray(precision, dtype=float)[free])[None]
    cross = statistics.cross[:, :, free]
    try:
        factor = np.linalg.cholesky(own)
    except np.linalg.LinAlgError:
        return None
    half = np.linalg.solve(factor, np.swapaxes(cross, 1, 2))  # L^-1 C^T: (r, k, S + 1)
    normal = statistics.shared - np.einsum('rki,rkj->ij', half, half)
    return normal, float(2.0 * np.sum(np.log(np.diagonal(factor, axis1=1, axis2=2))))


@dataclass(frozen=True)
class Absorbed:
    """A :class:`RecordSystem` with its held columns taken out and every record's own columns absorbed.

    :param factor: ``(S' + 1, S' + 1)`` the triangular factor of the free shared columns and the target
        that is left (the records' own columns solved for any shared values).
    :param shared: the layout's free shared columns; ``slots``: the free slots.
    :param pivot: ``(r, k', k')`` per record the triangular block of its free own columns.
    :param coupling: ``(r, k', S')`` its rows' shared part; ``target``: ``(r, k')`` their target.
    """

    factor: np.ndarray
    shared: np.ndarray
    slots: np.ndarray
    pivot: np.ndarray
    coupling: np.ndarray
    target: np.ndarray


class RecordSystem:
    """The triangular factors of a pool's weighted rows, each record's own columns apart (see :class:`RecordColumns`).

    The rows that touch no record's columns go into one factor of ``[X_s | y]``; each record's rows
    into a factor of ``[Z_r | X_s | y]`` of its own, :data:`ROUND_ROWS` rows of every record at a time.
    The same least squares as one factor of the whole design (orthogonal steps only), in time linear
    in the records.
    """

    def __init__(self, columns: RecordColumns) -> None:
        from tak_thermo_ros.core.fit.solve import BlockedQR
        self.columns = columns
        size = columns.slots + len(columns.shared)
        self.shared = BlockedQR(len(columns.shared))
        self.factors = np.zeros((columns.records, size, size))
        self.count = 0

    def copy(self) -> RecordSystem:
        """Return an independent duplicate (rows added to it leave this one as it is)."""
        out = RecordSystem(self.columns)
        out.shared.factor, out.shared.count = self.shared.factor.copy(), self.shared.count
        out.factors, out.count = self.factors.copy(), self.count
        return out

    def plus(self, rows: np.ndarray, record: np.ndarray) -> RecordSystem:
        """A copy with more rows (:meth:`add`)."""
        out = self.copy()
        out.add(rows, record)
        return out

    def add(self, rows: np.ndarray, record: np.ndarray) -> None:
        """Rows ``(n, W + 1)`` of ``[X | y]``, each of record ``record`` ``(n,)`` (``-1``: of none)."""
        if len(rows):
            self.add_split(*self.columns.split(rows, record), record)

    def add_split(self, shared: np.ndarray, slots: np.ndarray, record: np.ndarray) -> None:
        """Rows given apart (:meth:`RecordColumns.split`): ``[X_s | y]`` ``(n, S + 1)``, ``Z`` ``(n, k)``."""
        if not len(shared):
            return
        record = np.asarray(record, dtype=np.int64)
        self.count += len(shared)
        none = record < 0
        if np.any(none):
            self.shared.add(shared[none])
        if not np.all(none):
            self._fold(np.hstack([slots[~none], shared[~none]]), record[~none])

    def add_prior(self, precision_root: np.ndarray) -> None:
        """One row ``u / s_u = 0`` per record and slot (``precision_root``: ``1 / s_u`` per slot; 0: none)."""
        root = np.asarray(precision_root, dtype=float)
        slots = np.flatnonzero(root > 0.0)
        count = self.columns.records
        if not len(slots) or not count:
            return
        rows = np.zeros((count * len(slots), self.factors.shape[2]))
        rows[np.arange(len(rows)), np.tile(slots, count)] = np.tile(root[slots], count)
        self._fold(rows, np.repeat(np.arange(count), len(slots)))
        self.count += len(rows)

    def _fold(self, joined: np.ndarray, record: np.ndarray) -> None:
        """Rows ``[Z_r | X_s | y]`` into their records' factors, a round of at most :data:`ROUND_ROWS` each."""
        size = self.factors.shape[1]
        order = np.argsort(record, kind='stable')
        record, joined = record[order], joined[order]
        starts = np.flatnonzero(np.diff(record, prepend=-1) != 0)
        lengths = np.diff(np.append(starts, len(record)))
        position = np.arange(len(record)) - np.repeat(starts, lengths)
        step = int(min(ROUND_ROWS, lengths.max()))
        for first in range(0, int(lengths.max()), step):
            now = (position >= first) & (position < first + step)
            ids, local = np.unique(record[now], return_inverse=True)
            batch = np.zeros((len(ids), size + step, size))
            batch[:, :size] = self.factors[ids]
            batch[local, size + position[now] - first] = joined[now]
            self.factors[ids] = np.linalg.qr(batch, mode='r')

    def normal(self) -> np.ndarray:
        """The normal matrix ``[X | y]^T [X | y]`` ``(W + 1, W + 1)`` of every row, each record's columns in place."""
        columns = self.columns
        out = np.zeros((columns.width + 1, columns.width + 1))
        out[np.ix_(columns.shared, columns.shared)] += self.shared.factor.T @ self.shared.factor
        for own, factor in zip(columns.own, self.factors):
            at = np.concatenate([own, columns.shared])
            out[np.ix_(at, at)] += factor.T @ factor
        return out

    def absorbed(self, held: dict[int, float]) -> Absorbed:
        """The held columns' values moved into the target and dropped; each record's free own columns absorbed.

        A slot is held when its column is held in every record (an axis whose offset is held).
        """
        from tak_thermo_ros.core.fit.solve import triangular_factor
        columns = self.columns
        shared = columns.shared[:-1]
        kept = np.array([j not in held for j in shared], dtype=bool)
        values = np.array([held.get(int(j), 0.0) for j in shared])
        slot_held = np.array([all(int(j) in held for j in columns.own[:, a]) for a in range(columns.slots)])
        slot_values = np.array([[held.get(int(j), 0.0) for j in row] for row in columns.own]).reshape(
            columns.records, columns.slots)
        k = columns.slots
        # the records' factors: [Z | X | y] -> [Z_free | X_free | y - X_held v - Z_held w]
        factors = self.factors
        held_own = np.einsum('rnk,rk->rn', factors[:, :, :k], slot_values * slot_held[None])
        target = factors[:, :, -1] - factors[:, :, k:-1] @ values - held_own
        reduced = np.concatenate([factors[:, :, :k][:, :, ~slot_held], factors[:, :, k:-1][:, :, kept],
                                  target[:, :, None]], axis=2)
        free_k = int(np.count_nonzero(~slot_held))
        if len(reduced):
            reduced = np.linalg.qr(reduced, mode='r')
        own = self.shared.factor
        own = np.column_stack([own[:, :-1][:, kept], own[:, -1] - own[:, :-1] @ values])
        rest = reduced[:, free_k:, free_k:].reshape(-1, own.shape[1])
        factor = triangular_factor(np.vstack([own, rest]), own.shape[1])
        return Absorbed(factor=factor, shared=shared[kept], slots=np.flatnonzero(~slot_held),
                        pivot=reduced[:, :free_k, :free_k], coupling=reduced[:, :free_k, free_k:-1],
                        target=reduced[:, :free_k, -1])
