"""Between a fit's stretches, the wander: the flicker ``B`` and random walk ``K`` by restricted maximum likelihood.

Steps 2 and 3 of :mod:`tak_thermo_ros.core.noise.rests` (its docstring tells the whole):
:class:`RestMeans` holds one channel's mean residual at each stretch and the fixed effects the
fit took off; :func:`fit_wander` gives its :class:`Wander`, each term a :class:`Term` seen (a value
and its standard error) or bounded (a profile likelihood's upper limit).

Numpy at import; scipy inside the functions that need it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from tak_thermo_ros.core.noise.white import White

SEEN_DELTA = 4.0
"""A wander term is seen when setting it to 0 raises ``-2 log L`` by at least this (two standard deviations)."""
BOUND_DELTA = 3.841459
"""``-2 log L`` above its minimum at a bound: the one-sided 97.5 % upper limit (chi-square of 1 at 95 %). Not
95 %: the flicker and the walk trade off over minutes, and a bound that understates is the failure to avoid."""
INTERVAL_DELTA = 1.0
"""... and at the ends of the 68 % interval that gives a seen term's standard error."""
GRID_POINTS = 15
"""Values per term on the first search (log-spaced over :data:`GRID_DECADES` decades, and 0)."""
GRID_DECADES = 6.0
MAX_MEANS_PER_RECORD = 64
"""A record's stretches are merged into at most this many means (a long static run, a day of plateaus)."""
SEGMENT_S = 3600.0
"""A record longer than this is judged in pieces this long, each with its own level: the wander is estimated
over the separations a run's rests span (the watch judges a run's first rest and its latest 31), not over a
day, where a bias instability's 1/f band has long ended in a real part."""


@dataclass(frozen=True)
class RestMeans:
    """One channel's residual at each stretch after the fit, and what the fit took off there.

    :param residual: ``(k,)`` the stretch's mean residual (SI units of the corrected output).
    :param start_s: ``(k,)`` its first sample's time (s, one clock per record); ``end_s`` its last.
    :param duration_s: ``(k,)`` its averaging time (its samples over the rate).
    :param white: ``(k,)`` the variance of its white noise per unit ``N^2``: ``1 / duration_s`` for an
        axis's mean of every sample; more when the fit kept every n-th sample only; a projection's
        (``|f|`` along the up direction) in units of one axis's density.
    :param record: ``(k,)`` the record (power-up) of each.
    :param design: ``(k, p)`` the fixed effects: the columns of what the fit took off (each record's
        own level, the polynomials in temperature); the wander is judged on what they cannot reach.
    :param extra: ``(k,)`` a variance each mean carries besides the sensor's noise, independent from one
        to the next (the Earth rate's horizontal part at an unknown heading), or zeros.
    """

    residual: np.ndarray
    start_s: np.ndarray
    end_s: np.ndarray
    duration_s: np.ndarray
    white: np.ndarray
    record: np.ndarray
    design: np.ndarray
    extra: np.ndarray

    def __len__(self) -> int:
        return len(self.residual)

    def segmented(self, length: float = SEGMENT_S) -> RestMeans:
        """Each record cut into pieces of at most ``length`` seconds, each a record of its own with its own level."""
        pieces = np.zeros(len(self), dtype=np.int64)
        for record in np.unique(self.record):
            rows = self.record == record
            pieces[rows] = np.floor((self.start_s[rows] - self.start_s[rows].min()) / length).astype(np.int64)
        if not np.any(pieces):
            return self
        _, segment = np.unique(np.column_stack([self.record, pieces]), axis=0, return_inverse=True)
        segment = segment.reshape(-1)
        levels = (segment[:, None] == np.arange(segment.max() + 1)[None, :]).astype(float)
        return replace(self, record=segment, design=np.hstack([levels, self.design]))

    def merged(self, most: int = MAX_MEANS_PER_RECORD) -> RestMeans:
        """At most ``most`` means per record: neighbours merged, weighted by their averaging times."""
        groups = np.zeros(len(self), dtype=np.int64)
        count = 0
        for record in np.unique(self.record):
            rows = np.flatnonzero(self.record == record)
            rows = rows[np.argsort(self.start_s[rows], kind='stable')]
            parts = min(len(rows), most)
            groups[rows] = count + (np.arange(len(rows)) * parts) // len(rows)
            count += parts
        if count == len(self):
            return self
        weight = self.duration_s
        total = np.bincount(groups, weights=weight, minlength=count)

        def mean(values: np.ndarray) -> np.ndarray:
            out = np.zeros((count, *values.shape[1:]))
            np.add.at(out, groups, values * weight.reshape(-1, *([1] * (values.ndim - 1))))
            return out / total.reshape(-1, *([1] * (values.ndim - 1)))

        def variance(values: np.ndarray) -> np.ndarray:
            return np.bincount(groups, weights=values * weight ** 2, minlength=count) / total ** 2

        start, end = np.full(count, np.inf), np.full(count, -np.inf)
        np.minimum.at(start, groups, self.start_s)
        np.maximum.at(end, groups, self.end_s)
        record = np.zeros(count, dtype=np.int64)
        record[groups] = self.record
        return RestMeans(residual=mean(self.residual), start_s=start, end_s=end, duration_s=total,
                         white=variance(self.white), record=record, design=mean(self.design),
                         extra=variance(self.extra))


@dataclass(frozen=True)
class Term:
    """A wander term as the rests show it.

    :param value: the estimate (0 when not seen); ``error`` its standard error (0 when not seen).
    :param bound: when not seen, the largest value the rests allow (one-sided 97.5 %); 0 when seen.
    """

    value: float
    error: float
    bound: float

    @property
    def seen(self) -> bool:
        """Whether the rests show the term (else it is bounded)."""
        return self.bound == 0.0 and self.value > 0.0


@dataclass(frozen=True)
class Wander:
    """One channel's wander between the stretches.

    :param flicker: the bias instability ``B`` (units); ``walk``: the random walk ``K`` (units*sqrt(Hz)).
    :param means: stretch means judged (merged: :data:`MAX_MEANS_PER_RECORD` per piece of a record);
        ``records``: records; ``contrasts``: the degrees of freedom the fixed effects leave (0: nothing
        to judge the wander on, both terms bounded by the window alone).
    """

    flicker: Term
    walk: Term
    means: int
    records: int
    contrasts: int


def unit_wander(means: RestMeans) -> tuple[np.ndarray, np.ndarray]:
    """``(k, k)`` twice: the covariance of the means' wander for a unit flicker term and for a unit random walk.

    Within each record, counted from its first stretch (a process with stationary increments:
    ``(D_i0 + D_j0 - D_ij) / 2`` from the variances ``D`` of the pairwise differences the watch
    uses, :meth:`~tak_thermo_ros.core.link.rest_noise.ChannelNoise.wander`, the flicker's negative part left out
    as the watch leaves it, :func:`~tak_thermo_ros.core.link.rest_noise.positive_part`); 0 between records.
    """
    from tak_thermo_ros.core.link.rest_noise import ChannelNoise, positive_part
    flicker_unit = ChannelNoise(0.0, 0.0, 1.0, 0.0, 0.0)
    walk_unit = ChannelNoise(0.0, 0.0, 0.0, 1.0, 0.0)
    count = len(means)
    covariances = np.zeros((2, count, count))
    centre = 0.5 * (means.start_s + means.end_s)
    for record in np.unique(means.record):
        rows = np.flatnonzero(means.record == record)
        rows = rows[np.argsort(means.start_s[rows], kind='stable')]
        # Every pair (earlier a, later b), as the watch takes two rests.
        later, earlier = np.tril_indices(len(rows), -1)
        a, b = rows[earlier], rows[later]
        arguments = (np.abs(centre[b] - centre[a]), np.maximum(0.0, means.start_s[b] - means.end_s[a]),
                     means.duration_s[a], means.duration_s[b])
        pairs = np.zeros((2, len(rows), len(rows)))
        for term, unit in enumerate((flicker_unit, walk_unit)):
            pairs[term, later, earlier] = pairs[term, earlier, later] = unit.wander(*arguments)
        to_first = pairs[:, :, 0]
        block = 0.5 * (to_first[:, :, None] + to_first[:, None, :] - pairs)
        block[0] = positive_part(block[0])  # as the watch takes it (the flicker's formula is not one for any lengths)
        covariances[np.ix_([0, 1], rows, rows)] = block
    return covariances[0], covariances[1]


class _Reml:
    """``-2 log`` of the restricted likelihood of one channel's means for a flicker ``B`` and a walk ``K``.

    The records are independent blocks. A fixed effect that lives in one block (its record's own
    level) is taken off there: the block is carried into the complement of its columns (an orthonormal
    basis of the contrasts they leave); the others enter the generalised least squares of the rest.
    REML depends on the contrasts' span alone, so every choice of basis gives the same criterion up to a
    constant. The blocks are padded to one size and solved together, at many points at once.
    """

    def __init__(self, means: RestMeans, own: np.ndarray, flicker: np.ndarray, walk: np.ndarray) -> None:
        scale = math.sqrt(float(np.median(own))) if np.median(own) > 0.0 else 1.0
        self.scale = scale
        design = np.asarray(means.design, dtype=float).reshape(len(means), -1)
        records = np.unique(means.record)
        local = np.zeros(design.shape[1], dtype=bool)
        for column in range(design.shape[1]):
            local[column] = len(np.unique(means.record[design[:, column] != 0.0])) <= 1
        blocks = []
        for record in records:
            rows = np.flatnonzero(means.record == record)
            columns = design[np.ix_(rows, np.flatnonzero(local))]
            contrasts = _complement(columns, len(rows))
            blocks.append((rows, contrasts))
        shared = design[:, ~local]
        size = max((contrasts.shape[1] for _, contrasts in blocks), default=0)
        count = len(blocks)
        self.eye = np.zeros((count, size, size))
        self.flicker = np.zeros((count, size, size))
        self.walk = np.zeros((count, size, size))
        data = np.zeros((count, size, 1 + shared.shape[1]))
        for index, (rows, contrasts) in enumerate(blocks):
            m = contrasts.shape[1]
            self.eye[index] = np.eye(size)
            if not m:
                continue
            self.eye[index, :m, :m] = contrasts.T @ np.diag(own[rows] / scale ** 2) @ contrasts
            self.flicker[index, :m, :m] = contrasts.T @ flicker[np.ix_(rows, rows)] @ contrasts
            self.walk[index, :m, :m] = contrasts.T @ walk[np.ix_(rows, rows)] @ contrasts
            data[index, :m, 0] = contrasts.T @ (means.residual[rows] / scale)
            data[index, :m, 1:] = contrasts.T @ shared[rows]
        # The shared columns' span in the contrasts: an orthonormal basis (collinear columns dropped).
        stacked = data[:, :, 1:].reshape(count * size, shared.shape[1])
        basis = _complement(stacked, count * size, span=True)
        self.data = np.concatenate([data[:, :, :1], basis.reshape(count, size, basis.shape[1])], axis=2)
        self.contrasts = sum(contrasts.shape[1] for _, contrasts in blocks) - basis.shape[1]

    def __call__(self, flicker2: float, walk2: float) -> float:
        """``-2 log L`` (up to a constant) at ``B^2 = flicker2``, ``K^2 = walk2`` (in the scaled units)."""
        return float(self.many(np.array([flicker2]), np.array([walk2]))[0])

    def many(self, flicker2: np.ndarray, walk2: np.ndarray) -> np.ndarray:
        """:meth:`__call__` at many points at once ``(g,)`` (batched; a point that is no covariance: 1e300)."""
        out = np.empty(len(flicker2))
        step = max(1, int(4e6 // max(self.flicker.size, 1)))
        for start in range(0, len(flicker2), step):
            b = np.asarray(flicker2[start:start + step], dtype=float)[:, None, None, None]
            k = np.asarray(walk2[start:start + step], dtype=float)[:, None, None, None]
            covariance = self.eye[None] + b * self.flicker[None] + k * self.walk[None]
            try:
                factor = np.linalg.cholesky(covariance)
            except np.linalg.LinAlgError:
                out[start:start + step] = [self._one(bb, kk) for bb, kk in zip(b.ravel(), k.ravel())]
                continue
            logdet = 2.0 * np.log(np.diagonal(factor, axis1=2, axis2=3)).sum(axis=(1, 2))
            whitened = np.linalg.solve(factor, np.broadcast_to(self.data, factor.shape[:2] + self.data.shape[1:]))
            gram = (np.swapaxes(whitened, 2, 3) @ whitened).sum(axis=1)
            out[start:start + step] = logdet + _restricted(gram)
        return out

    def _one(self, flicker2: float, walk2: float) -> float:
        covariance = self.eye + flicker2 * self.flicker + walk2 * self.walk
        try:
            factor = np.linalg.cholesky(covariance)
        except np.linalg.LinAlgError:
            return 1e300
        whitened = np.linalg.solve(factor, self.data)
        gram = (np.swapaxes(whitened, 1, 2) @ whitened).sum(axis=0)
        return float(2.0 * np.log(np.diagonal(factor, axis1=1, axis2=2)).sum() + _restricted(gram[None])[0])


def _restricted(gram: np.ndarray) -> np.ndarray:
    """``(g,)`` ``y' V^-1 y`` less what the shared fixed effects explain, plus ``log|X' V^-1 X|``."""
    total = gram[:, 0, 0].copy()
    if gram.shape[1] > 1:
        information = gram[:, 1:, 1:]
        sign, logdet = np.linalg.slogdet(information)
        projection = gram[:, 1:, 0]
        explained = np.einsum('gi,gi->g', projection, np.linalg.solve(information, projection[:, :, None])[:, :, 0])
        total += logdet - explained
        total[sign <= 0.0] = 1e300
    return total


def _complement(columns: np.ndarray, rows: int, *, span: bool = False) -> np.ndarray:
    """An orthonormal basis ``(rows, r)`` of the complement of ``columns``' span (``span``: of the span itself)."""
    columns = np.asarray(columns, dtype=float)
    columns = columns.reshape(rows, -1) if columns.size else np.zeros((rows, 0))
    if not columns.shape[1] or not rows:
        return np.zeros((rows, 0)) if span else np.eye(rows)
    left, singular, _ = np.linalg.svd(columns, full_matrices=True)
    rank = int(np.sum(singular > 1e-9 * singular.max())) if len(singular) and singular.max() > 0.0 else 0
    return left[:, :rank] if span else left[:, rank:]


def fit_wander(means: RestMeans, white: White, *, ceiling: tuple[float, float] | None = None) -> Wander:
    """A channel's flicker ``B`` and random walk ``K`` from its stretches' means (the module's REML).

    :param white: the channel's white noise: each mean's own noise is ``N^2 white + 3 Q^2 / T^2 + extra``.
    :param ceiling: ``(B, K)`` the largest each can be whatever the means say (from the window's Allan
        variance), or ``None``; a bound never exceeds it.
    """
    records = len(np.unique(means.record)) if len(means) else 0
    means = means.segmented().merged()
    ceiling = ceiling or (math.inf, math.inf)
    if not len(means):
        return Wander(Term(0.0, 0.0, ceiling[0]), Term(0.0, 0.0, ceiling[1]), 0, 0, 0)
    own = (white.density ** 2 * means.white + 3.0 * white.quantization ** 2 / means.duration_s ** 2
           + means.extra)
    flicker, walk = unit_wander(means)
    reml = _Reml(means, np.maximum(own, 1e-300), flicker, walk)
    if reml.contrasts < 2:
        return Wander(Term(0.0, 0.0, ceiling[0]), Term(0.0, 0.0, ceiling[1]), len(means), records, reml.contrasts)
    span = np.array([np.ptp(np.concatenate([means.start_s[means.record == r], means.end_s[means.record == r]]))
                     for r in np.unique(means.record)])
    # Scaled units: 1 is each mean's own noise; a walk of 1 adds that much over a record's span.
    flicker_unit, walk_unit = 1.0, 1.0 / math.sqrt(max(float(np.median(span)), 1e-9))
    grids = [np.concatenate([[0.0], unit * np.geomspace(10.0 ** (-GRID_DECADES + 2.0), 100.0, GRID_POINTS)])
             for unit in (flicker_unit, walk_unit)]

    def criterion(b: float, k: float) -> float:
        return reml(b * b, k * k)

    flicker_points, walk_points = np.meshgrid(grids[0], grids[1], indexing='ij')
    table = reml.many(flicker_points.ravel() ** 2, walk_points.ravel() ** 2).reshape(flicker_points.shape)
    best = np.unravel_index(int(np.argmin(table)), table.shape)
    search = _Search(criterion, (float(grids[0][best[0]]), float(grids[1][best[1]])), (grids[0][1], grids[1][1]))
    point, minimum = search.minimum()
    terms = [_term(search, index, point, minimum, reml.scale, ceiling[index]) for index in range(2)]
    return Wander(terms[0], terms[1], len(means), records, reml.contrasts)


class _Search:
    """Minimising ``-2 log L`` over one term with the other held, on a log scale (and at 0).

    :param start: a first point (the grid's best); ``smallest``: per term the least value searched
        beside 0 (the grid's first).
    """

    def __init__(self, criterion: Callable[[float, float], float], start: tuple[float, float],
                 smallest: tuple[float, float]) -> None:
        self.criterion = criterion
        self.start = start
        self.smallest = smallest

    def at(self, index: int, value: float, other: float) -> float:
        """The criterion with term ``index`` at ``value`` and the other at ``other``."""
        return self.criterion(value, other) if index == 0 else self.criterion(other, value)

    def best_other(self, index: int, value: float, guess: float) -> tuple[float, float]:
        """``(criterion, the other term)`` at its best with term ``index`` held at ``value``."""
        from scipy.optimize import minimize_scalar
        other = 1 - index
        floor = math.log(self.smallest[other])
        centre = max(math.log(guess) if guess > 0.0 else floor, floor)
        best = (self.at(index, value, 0.0), 0.0)
        for width in (1.5, 4.0, 8.0):  # the profile's best moves little from the last one: a narrow search first
            low, high = max(centre - width, floor), centre + width
            found = minimize_scalar(lambda u: self.at(index, value, math.exp(u)), bounds=(low, high),
                                    method='bounded', options={'xatol': 0.02})
            if found.fun < best[0]:
                best = (float(found.fun), math.exp(float(found.x)))
            if low + 0.05 < found.x < high - 0.05 or found.x <= floor + 0.05:
                break
            centre = float(found.x)
        return best

    def minimum(self) -> tuple[tuple[float, float], float]:
        """The point of least ``-2 log L`` from :attr:`start`: each term at its best in turn, three times."""
        point = list(self.start)
        value = self.criterion(*point)
        for _ in range(3):
            before = value
            for index in range(2):
                found, best = self.best_other(1 - index, point[1 - index], point[index])
                if found < value:
                    value, point[index] = found, best
            if before - value < 1e-3:
                break
        return (point[0], point[1]), value


def _term(search: _Search, index: int, point: tuple[float, float], minimum: float, scale: float,
          ceiling: float) -> Term:
    """One term from its profile likelihood: seen (value and error) or bounded."""
    from functools import lru_cache
    from scipy.optimize import brentq
    estimate, guess = point[index], point[1 - index]

    @lru_cache(maxsize=None)
    def profile(value: float) -> float:
        return search.best_other(index, value, guess)[0]

    def rise(value: float, delta: float) -> float:
        return profile(value) - minimum - delta

    def crossing(delta: float, start: float, factor: float, limit: float) -> float:
        """Where the profile rises by ``delta``, stepping from ``start`` by ``factor`` (up to ``limit``)."""
        low, high = start, start
        while rise(high, delta) < 0.0:
            low, high = high, high * factor
            if (factor > 1.0 and high >= limit) or (factor < 1.0 and high <= limit):
                return limit
        if low == high:
            return high
        return float(brentq(rise, min(low, high), max(low, high), args=(delta,), xtol=0.02 * max(low, high)))

    top = ceiling / scale if math.isfinite(ceiling) else 1e6 * search.smallest[index] / 1e-4
    if estimate > 0.0 and rise(0.0, SEEN_DELTA) >= 0.0:
        upper = crossing(INTERVAL_DELTA, estimate, 1.5, max(top, 4.0 * estimate))
        lower = 0.0 if rise(0.0, INTERVAL_DELTA) < 0.0 else crossing(INTERVAL_DELTA, estimate, 0.67, 0.0)
        return Term(estimate * scale, 0.5 * (upper - lower) * scale, 0.0)
    bound = crossing(BOUND_DELTA, max(estimate, search.smallest[index]), 2.0, top)
    return Term(0.0, 0.0, min(bound, top) * scale)


def temperature_columns(temperature: np.ndarray, reference: float, order: int) -> np.ndarray:
    """``(k, order + 1)``: ``1, n, ..., n^order`` of ``n = T - T_ref`` scaled to at most 1 (a design's columns)."""
    n = np.asarray(temperature, dtype=float) - reference
    span = float(np.max(np.abs(n))) if len(n) else 0.0
    n = n / span if span > 0.0 else n
    return np.column_stack([n ** power for power in range(order + 1)]) if len(n) else np.zeros((0, order + 1))
