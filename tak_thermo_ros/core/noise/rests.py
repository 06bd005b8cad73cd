"""A noise model from what a fit saw: the white noise within its rests, the wander between them.

Every fit has stretches where the unit's input is known and held: the rests of everyday and
hand-held records, a table run's plateaus, a static run's quiet length. What the fit leaves there
(the corrected output less what the unit should read) is the sensor's own noise, and it is the
yardstick the calibration watch judges a run's rests against (``docs/noise.md``, ``docs/watch.md``).
So every fit writes it (``source: fit``):

1. **Within the stretches, the white noise** (:func:`white_noise`): the Allan variance at one
   sample and at one window (:data:`~tak_thermo_ros.core.records.still.WINDOW_S`, half a second:
   between the means of successive windows of a stretch), pooled over every stretch, each
   ``N^2 / tau`` for white noise (the window's with the wander's share besides), each with its
   relative standard error ``sqrt(2 / edf)``. Where they agree the density is one sample's; more
   at one sample is quantisation (``3 Q^2 / tau^2``), less the driver's low-pass filter (its time
   constant solved from the ratio, :func:`~tak_thermo_ros.core.noise.model.filtered_white_allan_variance`),
   and the density the window's (the long-term one a rest's mean averages).
2. **Between the stretches, the wander** (:func:`fit_wander`): the stretches' mean residuals have the
   covariance the watch itself uses (:class:`~tak_thermo_ros.core.link.watch.ChannelNoise`: each
   mean's white noise, and between two means the flicker term's ``(4 B^2 / pi)(ln 2 + ln(S / T) / 2)``
   and the random walk's ``K^2 (gap + T1 / 3 + T2 / 3)``), and ``B`` and ``K`` are their restricted
   maximum likelihood (REML): the likelihood of the contrasts that no fixed effect reaches. The
   fixed effects are what the fit took off (the offset and scale polynomials in temperature) and
   each record's own level (its turn-on offset: the spread of turn-on offsets is not wander), so
   what the fit absorbed of the wander (a temperature polynomial follows a walk over a monotone
   warm-up) is not lost from the estimate.
3. **Seen, or bounded** (:class:`Term`): a term is *seen* when the data reject it being 0 by
   :data:`SEEN_DELTA` in ``-2 log L`` (two standard deviations); then its value and its standard
   error (half the profile likelihood's 68 % interval). Otherwise the value is 0 and its *bound*
   is the profile likelihood's one-sided 97.5 % upper limit (and never above what the window's
   Allan variance allows), written as ``bias_instability_bound`` / ``random_walk_bound``: never a 0
   that reads as known. The watch counts a bounded term at its bound
   (:attr:`~tak_thermo_ros.core.noise.model.NoiseModel.bias_instability_upper`), erring on the side
   of a wander it does not understate.

Gauss-Markov processes and a rate ramp are not estimated from rests (a few minutes between rests
do not tell a correlation time); a flicker term stands for them over the separations seen.

Numpy at import; scipy inside the functions that need it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from tak_thermo_ros.core.noise.model import (
    FLICKER_FLOOR,
    UPPER_SIGMAS,
    NoiseModel,
    filtered_white_allan_variance,
    floor_tau,
)
from tak_thermo_ros.core.records.still import MIN_WINDOW_SAMPLES, WINDOW_S

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
SIGNIFICANT_RATIO = 3.0
"""The white noise density from one sample lies this many standard errors of the difference outside what one
window's allows: quantisation (above) or a driver's filter (below)."""
MAX_MEANS_PER_RECORD = 64
"""A record's stretches are merged into at most this many means (a long static run, a day of plateaus)."""
SEGMENT_S = 3600.0
"""A record longer than this is judged in pieces this long, each with its own level: the wander is estimated
over the separations a run's rests span (the watch judges a run's first rest and its latest 31), not over a
day, where a bias instability's 1/f band has long ended in a real part."""
MAX_WINDOWS = 1 << 17
"""A run's windows (:class:`StretchWindows`) are made longer than half a second beyond this many."""


@dataclass(frozen=True)
class ShortSums:
    """The Allan variance's terms within stretches, summed per channel (SI units of the corrected output).

    :param period_s: the sampling interval.
    :param window_s: the window the second sums are taken at (its mean's averaging time).
    :param one: ``(c,)`` the sum of half the squared step between successive samples; ``one_terms`` how many.
    :param window: ``(c,)`` the sum of half the squared step between successive windows' means; ``window_terms``.
    """

    period_s: float
    window_s: float
    one: np.ndarray
    one_terms: int
    window: np.ndarray
    window_terms: int


@dataclass(frozen=True)
class White:
    """One channel's noise within the stretches.

    :param density: the white noise density ``N`` (units/sqrt(Hz)); ``error`` its standard error.
    :param quantization: ``Q`` (units*s), 0 when one sample shows no more than white noise.
    :param filter_time_constant: a driver's first-order low-pass (s), 0 when one sample shows no less.
    """

    density: float
    error: float
    quantization: float = 0.0
    filter_time_constant: float = 0.0


def white_noise(sums: ShortSums, wander: np.ndarray | None = None) -> list[White]:
    """Each channel's white noise from the Allan variance at one sample and at one window.

    :param wander: ``(c,)`` the most the wander can add to the Allan variance at one window (its terms at
        their upper limits), or ``None`` (nothing).

    ``N^2 = tau avar(tau)`` at both times for white noise, and the window's holds the wander's share
    besides (0 up to ``wander``). Where one sample's lies within that range (within
    :data:`SIGNIFICANT_RATIO` standard errors of the difference) the white noise is all there is
    at the shortest times, and the density is one sample's (many more terms, no wander in it); where
    it lies above, the difference is quantisation, below, a driver's filter, and the density is the
    window's less half the wander's share, give or take all of it (the long-term one a rest's mean
    averages). Stretches too short for two windows (a table's 10-s dwells at 1 Hz) give it from one
    sample alone (no filter or quantisation told apart).
    """
    tau0, window = sums.period_s, sums.window_s
    out = []
    for channel in range(len(sums.window)):
        if sums.one_terms < 1:
            out.append(White(0.0, 0.0))
            continue
        at_one = float(sums.one[channel]) / sums.one_terms
        # Successive differences share a sample (successive windows' a mean): about 1.5 terms per degree of freedom.
        from_one = at_one * tau0
        one_error = math.sqrt(2.0 / max(sums.one_terms / 1.5, 1.0)) * from_one
        if sums.window_terms < 1:
            out.append(White(math.sqrt(from_one), 0.5 * one_error / math.sqrt(from_one) if from_one > 0 else 0.0))
            continue
        measured = float(sums.window[channel]) / sums.window_terms
        most = float(wander[channel]) * window if wander is not None else 0.0
        from_window = measured * window
        window_error = math.sqrt(2.0 / max(sums.window_terms / 1.5, 1.0)) * from_window
        allowed = SIGNIFICANT_RATIO * math.hypot(window_error, one_error)
        quantization = filter_constant = 0.0
        density2, error2 = from_one, one_error
        # What the window holds besides the wander: half its share taken off, give or take all of it.
        long_term = max(from_window - 0.5 * most, 0.5 * from_window)
        long_error = math.hypot(window_error, most / math.sqrt(12.0))
        if from_one > from_window + allowed:  # 3 Q^2 / tau^2 + N^2 / tau at both times: two unknowns
            at_window = long_term / window
            q2 = max((at_one - at_window * window / tau0) / (3.0 / tau0 ** 2 - 3.0 / (window * tau0)), 0.0)
            quantization = math.sqrt(q2)
            density2, error2 = max((at_window - 3.0 * q2 / window ** 2) * window, 0.5 * long_term), long_error
        elif from_one < from_window - most - allowed:
            filter_constant = _filter_time_constant(from_one / tau0 / (long_term / window), tau0, window)
            density2, error2 = long_term, long_error
            if filter_constant > 0.0:  # the filter has not quite faded at one window either
                fading = float(filtered_white_allan_variance(np.array([window]), 1.0 / tau0, filter_constant)[0])
                density2, error2 = long_term / (fading * window), long_error / (fading * window)
        density = math.sqrt(density2)
        out.append(White(density, 0.5 * error2 / density if density > 0.0 else 0.0, quantization, filter_constant))
    return out


def _filter_time_constant(ratio: float, tau0: float, window: float) -> float:
    """The first-order low-pass whose white noise's Allan variance at one sample is ``ratio`` of that at one window."""
    from scipy.optimize import brentq
    rate = 1.0 / tau0
    times = np.array([tau0, window])

    def excess(constant: float) -> float:
        at_one, at_window = filtered_white_allan_variance(times, rate, constant)
        return float(at_one / at_window) - ratio

    low, high = 1e-3 * tau0, window
    if excess(high) > 0.0:
        return high
    if excess(low) < 0.0:
        return 0.0
    return float(brentq(excess, low, high, xtol=1e-6 * tau0))


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
    uses, :meth:`~tak_thermo_ros.core.link.watch.ChannelNoise.wander`, the flicker's negative part left out
    as the watch leaves it, :func:`~tak_thermo_ros.core.link.watch.positive_part`); 0 between records.
    """
    from tak_thermo_ros.core.link.watch import ChannelNoise, positive_part
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


def wander_ceiling(sums: ShortSums, channel: int) -> tuple[float, float]:
    """``(B, K)`` the largest flicker and walk the Allan variance at one window allows on a channel.

    Every term adds to the Allan variance, so a flicker's flat ``(0.664 B)^2`` and a walk's
    ``K^2 tau / 3`` are at most it (taken at its upper one-sided 95 % limit); at one sample where
    the stretches are shorter than two windows.
    """
    terms, measured, tau = ((sums.window_terms, float(sums.window[channel]) / max(sums.window_terms, 1),
                             sums.window_s) if sums.window_terms else
                            (sums.one_terms, float(sums.one[channel]) / max(sums.one_terms, 1), sums.period_s))
    if terms < 1:
        return math.inf, math.inf
    upper = measured * (1.0 + 1.645 * math.sqrt(2.0 / max(terms / 1.5, 1.0)))
    return math.sqrt(upper) / FLICKER_FLOOR, math.sqrt(3.0 * upper / tau)


def temperature_columns(temperature: np.ndarray, reference: float, order: int) -> np.ndarray:
    """``(k, order + 1)``: ``1, n, ..., n^order`` of ``n = T - T_ref`` scaled to at most 1 (a design's columns)."""
    n = np.asarray(temperature, dtype=float) - reference
    span = float(np.max(np.abs(n))) if len(n) else 0.0
    n = n / span if span > 0.0 else n
    return np.column_stack([n ** power for power in range(order + 1)]) if len(n) else np.zeros((0, order + 1))


@dataclass(frozen=True)
class RestNoise:
    """A sensor's noise model from a fit's stretches, and what it was found from.

    :param model: the noise model (``source: fit``; errors and bounds in it).
    :param white: per axis the white noise within the stretches.
    :param wander: per axis the wander between them (one for every axis when ``shared``).
    :param shared: the wander is one projection's (``|f|`` along the vertical at the rests), written on every axis.
    :param kind: what the stretches were: ``rests`` (still intervals found in the record) or ``stretches``
        (a table run's plateaus, a static run's length).
    """

    model: NoiseModel
    white: tuple[White, ...]
    wander: tuple[Wander, ...]
    shared: bool = False
    kind: str = 'stretches'

    @property
    def means(self) -> int:
        """Stretch means the wander was judged on."""
        return max(w.means for w in self.wander)

    @property
    def records(self) -> int:
        """Records (power-ups) they come from."""
        return max(w.records for w in self.wander)


def rest_noise(short: ShortSums, channels: list[RestMeans], *, up: np.ndarray | None = None,
               kind: str = 'stretches') -> RestNoise | None:
    """A sensor's noise model: the white noise within the stretches, the wander between them (the module's steps).

    :param short: the sensor's three axes' sums within the stretches.
    :param channels: per axis its means (three), or one projection's (``|f|``) with ``up``.
    :param up: ``(k, 3)`` with one channel: each mean's up direction (its white noise is
        ``sum_j u_j^2 N_j^2``); the wander found is written on every axis.
    :param kind: ``rests`` or ``stretches`` (:class:`RestNoise`).
    :returns: ``None`` when the stretches hold too few samples for a white noise density.
    """
    whites = white_noise(short)
    if not all(white.density > 0.0 for white in whites):
        return None
    ceilings = [wander_ceiling(short, axis) for axis in range(3)]
    if len(channels) == 1:
        means = channels[0]
        squares = np.asarray(up, dtype=float) ** 2
        projected = replace(means, white=means.white * (squares @ np.array([w.density ** 2 for w in whites])))
        ceiling = (max(c[0] for c in ceilings), max(c[1] for c in ceilings))
        wanders = (fit_wander(projected, White(1.0, 0.0), ceiling=ceiling),) * 3
    else:
        wanders = tuple(fit_wander(means, white, ceiling=ceiling)
                        for means, white, ceiling in zip(channels, whites, ceilings))
    # The most the wander can add at one window: its terms at their upper limits.
    uppers = [(max(w.flicker.value + UPPER_SIGMAS * w.flicker.error, w.flicker.bound),
               max(w.walk.value + UPPER_SIGMAS * w.walk.error, w.walk.bound)) for w in wanders]
    whites = white_noise(short, np.array([(FLICKER_FLOOR * b) ** 2 + k * k * short.window_s / 3.0 for b, k in uppers]))

    def triple(values) -> tuple[float, float, float]:
        items = [float(v) for v in values]
        return items[0], items[1], items[2]

    white = triple(w.density for w in whites)
    flicker = triple(w.flicker.value for w in wanders)
    walk = triple(w.walk.value for w in wanders)
    quantization = triple(w.quantization for w in whites)
    filtered = triple(w.filter_time_constant for w in whites)
    model = NoiseModel(
        white_noise_density=white, bias_instability=flicker,
        bias_instability_tau=floor_tau(white, flicker, walk, quantization), random_walk=walk,
        update_rate=1.0 / short.period_s, source='fit', quantization=quantization,
        filter_time_constant=filtered, filter_share=triple(1.0 if f > 0.0 else 0.0 for f in filtered),
        random_walk_bound=triple(w.walk.bound for w in wanders),
        bias_instability_bound=triple(w.flicker.bound for w in wanders),
        white_noise_density_error=triple(w.error for w in whites),
        bias_instability_error=triple(w.flicker.error for w in wanders),
        random_walk_error=triple(w.walk.error for w in wanders))
    return RestNoise(model, tuple(whites), wanders, shared=len(channels) == 1, kind=kind)


class StretchWindows:
    """One sensor's samples in windows within stretches of a held reference: one row per window (bounded).

    A stretch is a run of samples whose reference does not change and whose stamps have no gap (more
    than 1.5 sampling intervals apart: a table settling, a turn, a lost message); it is cut into
    windows of :data:`~tak_thermo_ros.core.records.still.WINDOW_S` (at least
    :data:`~tak_thermo_ros.core.records.still.MIN_WINDOW_SAMPLES` samples; longer when the run would
    hold more than :data:`MAX_WINDOWS`), a stretch's last partial window left out. Per window: its
    stretch, first and last stamp, the means of the values, references and temperature, and the sum of
    half the squared steps between its successive samples. A consumer of a fit's aligned blocks
    (``tak_calib fit``'s pass over a table run or a static run).

    :param expected: about how many samples the run holds (sets the window so that the rows stay bounded).
    """

    COLUMNS = 13

    def __init__(self, expected: int = 0) -> None:
        self.expected = expected
        self.window = 0
        self.period_ns = 0.0
        self._tail: tuple[np.ndarray, ...] | None = None
        """The current stretch's samples not yet in a window (or the first samples, before the period is known)."""
        self._last: tuple[int, np.ndarray] | None = None
        self._stretch = 0
        self._rows: list[np.ndarray] = []

    def __call__(self, aligned) -> None:
        """One aligned block (stamps, values ``counts``, ``reference``, ``temp_code``), in time order."""
        if not len(aligned) or aligned.reference is None:
            return
        block = (np.asarray(aligned.stamp_ns, dtype=np.int64), np.asarray(aligned.counts, dtype=float),
                 np.asarray(aligned.reference, dtype=float), np.asarray(aligned.temp_code, dtype=float))
        if not self.window:
            if self._tail is not None:
                block = tuple(np.concatenate([old, new]) for old, new in zip(self._tail, block))
                self._tail = None
            steps = np.diff(block[0])
            steps = steps[steps > 0]
            if len(steps) < 2:
                self._tail = block
                return
            self.period_ns = float(np.median(steps))
            self.window = max(MIN_WINDOW_SAMPLES, int(round(WINDOW_S * 1e9 / self.period_ns)),
                              math.ceil(self.expected / MAX_WINDOWS))
        stamps, values, reference, temperature = block
        breaks = np.zeros(len(stamps), dtype=bool)
        if self._last is not None:
            breaks[0] = self._breaks(self._last[0], stamps[0], self._last[1], reference[0])
        breaks[1:] = self._breaks(stamps[:-1], stamps[1:], reference[:-1], reference[1:])
        self._last = (int(stamps[-1]), reference[-1])
        if self._tail is not None and not breaks[0]:  # the stretch goes on: its samples not yet in a window first
            tail = len(self._tail[0])
            stamps, values, reference, temperature = (np.concatenate([old, new]) for old, new in
                                                      zip(self._tail, block))
            breaks = np.concatenate([np.zeros(tail, dtype=bool), breaks])
        self._tail = None
        edges = np.concatenate([[0], np.flatnonzero(breaks[1:]) + 1, [len(stamps)]])
        w = self.window
        for start, end in zip(edges[:-1], edges[1:]):
            if breaks[start]:
                self._stretch += 1
            whole = start + (end - start) // w * w
            if whole > start:
                self._add(stamps[start:whole], values[start:whole], reference[start:whole],
                          temperature[start:whole])
            if end == len(stamps) and whole < end:
                self._tail = (stamps[whole:], values[whole:], reference[whole:], temperature[whole:])

    def _breaks(self, before, after, reference_before, reference_after):
        gap = (np.asarray(after) - np.asarray(before)) > 1.5 * self.period_ns
        change = np.any(np.abs(np.asarray(reference_after) - np.asarray(reference_before))
                        > 1e-9 * (1.0 + np.abs(np.asarray(reference_before))), axis=-1)
        return gap | change

    def _add(self, stamps: np.ndarray, values: np.ndarray, reference: np.ndarray, temperature: np.ndarray) -> None:
        w = self.window
        shaped = values.reshape(-1, w, 3)
        steps = 0.5 * np.sum(np.diff(shaped, axis=1) ** 2, axis=1)
        windows = len(shaped)
        self._rows.append(np.column_stack([
            np.full(windows, float(self._stretch)), stamps.reshape(-1, w)[:, 0].astype(float),
            stamps.reshape(-1, w)[:, -1].astype(float), shaped.mean(axis=1),
            reference.reshape(-1, w, 3).mean(axis=1), temperature.reshape(-1, w).mean(axis=1), steps]))

    def rows(self) -> np.ndarray:
        """``(windows, 13)`` per window: stretch, first and last stamp (ns), the means, the sums of half the steps.

        The columns: stretch, first stamp, last stamp, the values' means (3), the references' means (3),
        the temperature's mean, the sums of half the squared steps between successive samples (3).
        """
        return np.vstack(self._rows) if self._rows else np.zeros((0, self.COLUMNS))
