"""Overlapping Allan variance of a rate signal, in memory and streamed in bounded memory.

For samples ``y_i`` of a rate (gyroscope, rad/s) or specific force (accelerometer, m/s^2)
taken every ``tau0 = 1 / rate`` seconds, the overlapping Allan variance at the cluster size
``m`` (averaging time ``tau = m tau0``) is, with ``x_k = y_0 + ... + y_(k-1)`` (``x_0 = 0``)
and ``n`` samples (IEEE 952, eq. C.21; IEEE 1139)::

    avar(tau) = sum_(k=0)^(n-2m) (x_(k+2m) - 2 x_(k+m) + x_k)^2 / (2 m^2 (n - 2m + 1))

``n - 2m + 1`` is the number of terms (``counts``). :func:`allan_variance` computes it exactly
for every cluster size; :class:`AllanAccumulator` computes the same sums block by block in
bounded memory:

- cluster sizes up to ``exact_max`` (default 8192 samples): exact, from a ring of the last
  ``2 exact_max + 1`` cumulative sums carried from block to block;
- larger cluster sizes (multiples of a bin size ``b``): from the cumulative sums kept at every
  ``b``-th sample only, i.e. the overlapping estimator of the ``b``-sample bin averages at
  cluster ``m / b`` (terms at stride ``b`` instead of 1). Each term has the same expectation,
  so the estimate is unbiased; it has a few fewer independent terms (``counts`` and
  :func:`equivalent_degrees_of_freedom` say how many). When more than ``2 max_bins`` bins
  are held, every other one is dropped and ``b`` doubles: the memory never grows past
  ``max_bins`` rows. The samples after the last full bin do not enter these cluster sizes.

The equivalent degrees of freedom follow Howe, Allan and Barnes (1981), the formulas of
IEEE 1139 for the overlapping estimator, per power-law noise type; the confidence interval
is the chi-square one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.errors import NoiseError

EXACT_MAX_CLUSTER = 8192
""":class:`AllanAccumulator` computes cluster sizes up to this many samples exactly."""
MAX_BINS = 65536
""":class:`AllanAccumulator` keeps at most about twice this many bin sums (then the bins double)."""


@dataclass(frozen=True)
class AllanVariance:
    """The overlapping Allan variance of ``samples`` samples of ``axes`` channels at ``rate`` Hz.

    :param taus: ``(t,)`` averaging times, s, increasing.
    :param avar: ``(t, axes)`` Allan variance, squared units of the samples.
    :param counts: ``(t,)`` number of terms in each sum.
    :param clusters: ``(t,)`` cluster sizes ``m`` (samples per average).
    :param strides: ``(t,)`` the stride of the terms in samples (1: fully overlapping; ``b``:
        the bin size of :class:`AllanAccumulator`'s long cluster sizes).
    :param rate: sample rate, Hz.
    :param samples: number of samples that entered the estimate.
    :param peak: ``(t, axes)`` the largest ``|x_(k+2m) - 2 x_(k+m) + x_k|`` of each sum (``m`` times
        the largest difference of adjacent cluster averages: a step in the record stands out
        there; :class:`AllanAccumulator` keeps it at the exact cluster sizes that are powers of
        two and at the binned ones, NaN at the others), or ``None``.
    :param peak_index: ``(t, axes)`` its ``k`` (the first sample of the first cluster).
    """

    taus: np.ndarray
    avar: np.ndarray
    counts: np.ndarray
    clusters: np.ndarray
    strides: np.ndarray
    rate: float
    samples: int
    peak: np.ndarray | None = None
    peak_index: np.ndarray | None = None

    @property
    def adev(self) -> np.ndarray:
        """Allan deviation ``(t, axes)``, units of the samples."""
        return np.sqrt(self.avar)

    @property
    def axes(self) -> int:
        """Number of channels."""
        return int(self.avar.shape[1])

    def select(self, keep: np.ndarray) -> AllanVariance:
        """The averaging times where ``keep`` (a boolean ``(t,)``) is true."""
        from dataclasses import replace
        return replace(self, taus=self.taus[keep], avar=self.avar[keep], counts=self.counts[keep],
                       clusters=self.clusters[keep], strides=self.strides[keep],
                       peak=None if self.peak is None else self.peak[keep],
                       peak_index=None if self.peak_index is None else self.peak_index[keep])


def cluster_sizes(largest: int, per_octave: int = 1, *, smallest: int = 1) -> np.ndarray:
    """Log-spaced whole cluster sizes from ``smallest`` to ``largest``, ``per_octave`` per doubling."""
    if per_octave < 1:
        msg = f'per_octave: expected at least 1, got {per_octave}'
        raise NoiseError(msg)
    if largest < smallest:
        return np.zeros(0, dtype=np.int64)
    steps = int(math.floor(math.log2(largest / smallest) * per_octave + 1e-9))
    grid = np.round(smallest * 2.0 ** (np.arange(steps + 1) / per_octave)).astype(np.int64)
    return np.unique(np.clip(grid, smallest, largest))


def largest_cluster(samples: int) -> int:
    """The largest cluster size used for ``samples`` samples: a third of the run (``counts >= n / 3``)."""
    return samples // 3


def _as_samples(values: np.ndarray, axes: int | None = None) -> np.ndarray:
    array = np.asarray(values, dtype=float)
    if array.ndim == 1:
        array = array[:, None]
    if array.ndim != 2 or (axes is not None and array.shape[1] != axes):
        want = f'(n, {axes})' if axes is not None else '(n,) or (n, k)'
        msg = f'Allan variance: expected samples of shape {want}, got {array.shape}'
        raise NoiseError(msg)
    if not np.all(np.isfinite(array)):
        bad = int(np.count_nonzero(~np.isfinite(array)))
        msg = f'Allan variance: {bad} sample values are not finite (NaN or infinite); the estimate needs every sample'
        raise NoiseError(msg)
    return array


def _check_rate(rate: float) -> float:
    if isinstance(rate, bool) or not isinstance(rate, (int, float, np.floating, np.integer)) \
            or not math.isfinite(float(rate)) or float(rate) <= 0.0:
        msg = f'Allan variance: the sample rate must be a positive finite number of Hz, got {rate!r}'
        raise NoiseError(msg)
    return float(rate)


def allan_variance(samples: np.ndarray, rate: float, *, per_octave: int = 1,
                   clusters: np.ndarray | None = None) -> AllanVariance:
    """The exact overlapping Allan variance of ``(n,)`` or ``(n, k)`` samples held in memory.

    :param rate: sample rate, Hz.
    :param per_octave: cluster sizes per doubling (ignored when ``clusters`` is given).
    :param clusters: the cluster sizes (default: log-spaced up to a third of the run).
    :raises NoiseError: a non-finite sample, a bad rate or shape.
    """
    rate = _check_rate(rate)
    values = _as_samples(samples)
    count = len(values)
    if clusters is None:
        clusters = cluster_sizes(largest_cluster(count), per_octave)
    clusters = np.asarray(clusters, dtype=np.int64)
    clusters = clusters[(clusters >= 1) & (2 * clusters <= count)]
    phase = np.zeros((count + 1, values.shape[1]))
    if count:
        np.cumsum(values - values[0], axis=0, out=phase[1:])
    avar = np.empty((len(clusters), values.shape[1]))
    peak = np.empty_like(avar)
    peak_index = np.zeros(avar.shape, dtype=np.int64)
    terms = np.empty(len(clusters), dtype=np.int64)
    for i, m in enumerate(clusters):
        second = phase[2 * m:] - 2.0 * phase[m:count + 1 - m] + phase[:count + 1 - 2 * m]
        terms[i] = len(second)
        avar[i] = np.einsum('ij,ij->j', second, second) / (2.0 * float(m) ** 2 * terms[i])
        peak[i], peak_index[i] = _peak(second)
    return AllanVariance(taus=clusters / rate, avar=avar, counts=terms, clusters=clusters,
                         strides=np.ones(len(clusters), dtype=np.int64), rate=rate, samples=count,
                         peak=peak, peak_index=peak_index)


def _peak(second: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per column the largest absolute value of ``second`` and its row (the largest and the least, no copy)."""
    columns = np.arange(second.shape[1])
    high, low = second.argmax(axis=0), second.argmin(axis=0)
    top, bottom = second[high, columns], -second[low, columns]
    up = top >= bottom
    return np.where(up, top, bottom), np.where(up, high, low)


class AllanAccumulator:
    """The overlapping Allan variance of any number of samples, added block by block.

    Memory: ``2 exact_max + 1`` plus at most ``2 max_bins + 2`` rows of ``axes`` floats,
    whatever the number of samples (see the module docstring for what is exact).

    :param rate: sample rate, Hz.
    :param axes: channels per sample.
    :param per_octave: cluster sizes per doubling.
    :param exact_max: the largest cluster size computed exactly.
    :param max_bins: the bin sums kept for the longer cluster sizes (about, see above).
    """

    def __init__(self, rate: float, axes: int = 3, *, per_octave: int = 1,
                 exact_max: int = EXACT_MAX_CLUSTER, max_bins: int = MAX_BINS) -> None:
        self.rate = _check_rate(rate)
        if axes < 1 or exact_max < 1 or max_bins < 4:
            msg = f'AllanAccumulator: axes >= 1, exact_max >= 1, max_bins >= 4 (got {axes}, {exact_max}, {max_bins})'
            raise NoiseError(msg)
        self.axes = axes
        self.per_octave = per_octave
        self.exact_max = exact_max
        self._exact = cluster_sizes(exact_max, per_octave)
        self._sum_sq = np.zeros((len(self._exact), axes))
        # The largest term (a step's mark) at one cluster size per octave, the powers of two: it
        # costs two passes over a block, as much as the sum of squares.
        self._tracked = (self._exact & (self._exact - 1)) == 0
        self._peak = np.where(self._tracked[:, None], 0.0, np.nan) * np.ones((1, axes))
        self._peak_index = np.zeros((len(self._exact), axes), dtype=np.int64)
        self._terms = np.zeros(len(self._exact), dtype=np.int64)
        self._history = np.zeros((1, axes))  # the last cumulative sums (x_0 = 0 at first)
        self._offset: np.ndarray | None = None
        self.samples = 0
        self.bin_size = max(1, exact_max // 8)
        self._bins = np.zeros((2 * max_bins + 2, axes))  # x at every bin_size-th sample, x_0 first
        self._bin_count = 1

    def add(self, block: np.ndarray) -> None:
        """Add the next ``(L,)`` or ``(L, axes)`` samples (in order, evenly spaced).

        :raises NoiseError: a non-finite value or a wrong shape (nothing of the block is added).
        """
        values = _as_samples(block, self.axes)
        if not len(values):
            return
        if self._offset is None:
            self._offset = values[0].copy()  # constant offsets do not change the variance: keep sums small
        start = self.samples + 1  # global index of the block's first cumulative sum
        phase = np.cumsum(values - self._offset, axis=0)
        phase += self._history[-1]
        joined = np.concatenate([self._history, phase])
        first_global = start - len(self._history)
        held = len(self._history)
        for i, m in enumerate(self._exact):
            begin = max(held, 2 * m - first_global)
            if begin >= len(joined):
                continue
            second = (joined[begin:] - 2.0 * joined[begin - m:len(joined) - m]
                      + joined[begin - 2 * m:len(joined) - 2 * m])
            self._sum_sq[i] += np.einsum('ij,ij->j', second, second)
            if self._tracked[i]:
                peak, where = _peak(second)
                larger = peak > self._peak[i]
                self._peak[i] = np.where(larger, peak, self._peak[i])
                # The term's k: its first cumulative sum's global index.
                self._peak_index[i] = np.where(larger, first_global + begin - 2 * m + where, self._peak_index[i])
            self._terms[i] += len(second)
        self._history = joined[-(2 * self.exact_max + 1):].copy()
        first_bin = -(-start // self.bin_size) * self.bin_size
        indices = np.arange(first_bin, start + len(values), self.bin_size)
        self._append_bins(phase[indices - start], indices)
        self.samples += len(values)

    def _append_bins(self, rows: np.ndarray, indices: np.ndarray) -> None:
        capacity = len(self._bins)
        while self._bin_count + len(rows) > capacity:
            kept = (self._bin_count + 1) // 2
            self._bins[:kept] = self._bins[:self._bin_count:2]
            self._bin_count = kept
            self.bin_size *= 2
            keep = indices % self.bin_size == 0
            rows, indices = rows[keep], indices[keep]
        self._bins[self._bin_count:self._bin_count + len(rows)] = rows
        self._bin_count += len(rows)

    def result(self) -> AllanVariance:
        """The Allan variance of everything added so far (exact part and binned part)."""
        used = self._terms > 0
        exact = self._exact[used]
        clusters = [exact]
        avar = [self._sum_sq[used] / (2.0 * exact[:, None].astype(float) ** 2 * self._terms[used, None])]
        peaks, peak_indices = [self._peak[used]], [self._peak_index[used]]
        counts = [self._terms[used]]
        strides = [np.ones(len(exact), dtype=np.int64)]
        largest = largest_cluster(self.samples)
        size = self.bin_size
        if largest > self.exact_max:
            grid = cluster_sizes(largest, self.per_octave, smallest=1)
            grid = np.unique(np.maximum(np.round(grid / size), 1).astype(np.int64) * size)
            grid = grid[(grid > self.exact_max) & (grid <= largest)]
            phase = self._bins[:self._bin_count]
            long_avar, long_counts, long_peak, long_index = [], [], [], []
            for m in grid:
                j = int(m // size)
                second = phase[2 * j:] - 2.0 * phase[j:len(phase) - j] + phase[:len(phase) - 2 * j]
                long_counts.append(len(second))
                long_avar.append(np.einsum('ij,ij->j', second, second) / (2.0 * float(m) ** 2 * max(len(second), 1)))
                peak, where = _peak(second) if len(second) else (np.zeros(self.axes), np.zeros(self.axes, np.int64))
                long_peak.append(peak)
                long_index.append(where * size)
            keep = np.asarray(long_counts, dtype=np.int64) > 0
            if np.any(keep):
                clusters.append(grid[keep])
                avar.append(np.asarray(long_avar)[keep])
                peaks.append(np.asarray(long_peak)[keep])
                peak_indices.append(np.asarray(long_index, dtype=np.int64)[keep])
                counts.append(np.asarray(long_counts, dtype=np.int64)[keep])
                strides.append(np.full(int(keep.sum()), size, dtype=np.int64))
        all_clusters = np.concatenate(clusters)
        return AllanVariance(taus=all_clusters / self.rate, avar=np.concatenate(avar).reshape(-1, self.axes),
                             counts=np.concatenate(counts), clusters=all_clusters,
                             strides=np.concatenate(strides), rate=self.rate, samples=self.samples,
                             peak=np.concatenate(peaks).reshape(-1, self.axes),
                             peak_index=np.concatenate(peak_indices).reshape(-1, self.axes))


def _edf_power_law(phases: np.ndarray, m: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Howe, Allan and Barnes (1981) for the overlapping Allan variance, ``phases`` = n + 1 points."""
    n = phases.astype(float)
    m = m.astype(float)
    edf = np.empty(len(n))
    with np.errstate(divide='ignore', invalid='ignore'):
        white_phase = (n + 1.0) * (n - 2.0 * m) / (2.0 * (n - m))
        flicker_phase = np.exp(np.sqrt(np.abs(np.log((n - 1.0) / (2.0 * m))
                                              * np.log((2.0 * m + 1.0) * (n - 1.0) / 4.0))))
        white_rate = (3.0 * (n - 1.0) / (2.0 * m) - 2.0 * (n - 2.0) / n) * 4.0 * m ** 2 / (4.0 * m ** 2 + 5.0)
        flicker_rate = np.where(m == 1.0, 2.0 * (n - 2.0) ** 2 / (2.3 * n - 4.9),
                                5.0 * n ** 2 / (4.0 * m * (n + 3.0 * m)))
        walk_rate = (n - 2.0) / m * ((n - 1.0) ** 2 - 3.0 * m * (n - 1.0) + 4.0 * m ** 2) / (n - 3.0) ** 2
    for value, formula in ((2, white_phase), (1, flicker_phase), (0, white_rate), (-1, flicker_rate), (-2, walk_rate)):
        edf = np.where(alpha == value, formula, edf)
    return edf


def equivalent_degrees_of_freedom(allan: AllanVariance, alpha: int | np.ndarray = 0) -> np.ndarray:
    """The equivalent degrees of freedom ``(t,)`` of each Allan variance for a power-law noise.

    ``alpha`` is the exponent of the rate's spectrum (scalar or ``(t,)``): 2 white phase
    (quantisation), 1 flicker phase, 0 white rate (angle / velocity random walk, the default),
    -1 flicker rate (bias instability), -2 random-walk rate. A binned cluster size (stride
    ``b``) counts as the overlapping estimator of the ``n / b`` bin averages at cluster ``m / b``.
    The result is at least 1 and at most the number of terms.
    """
    alphas = np.broadcast_to(np.asarray(alpha, dtype=np.int64), allan.taus.shape)
    if not np.all(np.isin(alphas, (2, 1, 0, -1, -2))):
        msg = f'equivalent degrees of freedom: alpha must be one of 2, 1, 0, -1, -2, got {np.unique(alphas)}'
        raise NoiseError(msg)
    strides = np.maximum(allan.strides, 1)
    phases = allan.samples // strides + 1
    m = np.maximum(allan.clusters // strides, 1)
    edf = _edf_power_law(phases, m, alphas)
    edf = np.where(np.isfinite(edf), edf, 1.0)
    return np.clip(edf, 1.0, np.maximum(allan.counts, 1).astype(float))


def confidence_interval(avar: np.ndarray, edf: np.ndarray, confidence: float = 0.683) -> tuple[np.ndarray, np.ndarray]:
    """The two-sided chi-square interval ``(low, high)`` of Allan variances with ``edf`` degrees of freedom.

    ``avar`` is ``(t,)`` or ``(t, k)``; ``edf`` is ``(t,)``. For Allan deviations take the square
    roots of both bounds.
    """
    from scipy.stats import chi2
    if not 0.0 < confidence < 1.0:
        msg = f'confidence: expected a probability in (0, 1), got {confidence}'
        raise NoiseError(msg)
    avar = np.asarray(avar, dtype=float)
    dof = np.asarray(edf, dtype=float)
    if avar.ndim == 2:
        dof = dof[:, None]
    low = avar * dof / chi2.ppf(0.5 + confidence / 2.0, dof)
    high = avar * dof / chi2.ppf(0.5 - confidence / 2.0, dof)
    return low, high
