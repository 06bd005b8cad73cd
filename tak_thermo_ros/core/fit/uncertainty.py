"""Standard errors that hold when the residual is correlated: the fit's sandwich with the residual's noise model.

A real sensor's residual is not white: its bias wanders (bias instability, random walk), and
what a model misses (a hysteresis memory, a step) lasts minutes. Least-squares errors that take
it as white shrink as ``1 / sqrt(samples)`` however slowly the residual moves; on the real
cycle they were 25-40 times too small. Here the fitted parameters' covariance is the sandwich::

    cov = A^-1 (sum_i W_i^T S_i W_i) A^-1,   A = sum_i J_i^T J_i / s_i^2,   W_i = J_i / s_i^2

with ``J_i`` the Jacobian of axis ``i``'s model over the samples fitted (its design columns and
the shared shape parameters' derivatives), ``s_i^2`` its residual variance, and ``S_i`` the
covariance of axis ``i``'s noise from a model of that noise (the axes' noises taken as
independent). For white noise ``S_i = s_i^2 I`` and this is the usual inverse Fisher matrix.

**The residual's noise model** (:func:`residual_noise`): white noise, Gauss-Markov processes
of correlation times on a log grid (:data:`MARKOV_PER_DECADE` a decade, from one sample to a
quarter of the longest averaging time measured: bias instability and flicker are sums of them) and
a random walk, each with a variance found by non-negative least squares on the residual's overlapping
Allan variance at octave averaging times up to an eighth of the run (:data:`MIN_BATCHES`),
weighted by its degrees of freedom. What each process would show in the *residual* is what it
shows in the noise less what the fit absorbs of it: the fit projects the noise onto the
complement of its Jacobian's columns, and the slow noise that moves a parameter is exactly the
part a residual no longer holds. So each process's expected Allan variance is that of its
projected covariance ``P S P`` (``P = I - Q Q^T``, ``Q`` an orthonormal basis of the axis's
Jacobian), computed exactly in ``O(k p)`` per averaging time from ``S Q`` (a Gauss-Markov
process's covariance applied by a forward and a backward first-order filter, a random walk's by
two running sums). A rise over the last two octaves measured continues as a random walk beyond
them (the conservative reading of slow noise one run cannot follow further: a flicker floor is
then over-stated, a walk is not under-stated).

The residual is taken as white, and the errors are the usual ones, when its Allan variance stays
inside white noise's chi-square band at every averaging time (:data:`WHITE_ALPHA`).

The model takes the samples as evenly spaced at their median interval. A run of more than
:data:`MAX_SERIES` samples is averaged over consecutive bins first (the slow noise the errors
depend on survives the averaging; the white part is carried by each bin's variance).

Checked over seeds (``bench/bench_coverage.py``, ``test/core/fit/test_uncertainty.py``): simulated runs with
bias instability (flicker), a random walk and a Gauss-Markov process and a hidden thermal lag;
the reported 2-sigma intervals of the lag's parameters must cover the truth 90-97 % of the time
(the white errors covered about 16 %).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import nnls
from scipy.signal import lfilter

from tak_thermo_ros.core.noise.allan import allan_variance
from tak_thermo_ros.core.simulation.noise import gauss_markov_allan_variance

MIN_BATCHES = 8
"""The Allan variance is measured at averaging times up to an eighth of the run (eight independent means)."""
MARKOV_PER_DECADE = 2
"""Gauss-Markov correlation times per decade in the residual's noise model."""
REWEIGHTINGS = 2
"""The noise model is fitted again this many times, weighted by its own prediction."""
MARKOV_LONGEST = 0.25
"""The longest Gauss-Markov correlation time is this share of the longest averaging time measured: a
rise over the last two octaves is read as a random walk, which goes on rising beyond them."""
MAX_SERIES = 16384
"""A longer series is averaged over consecutive bins to at most this many values first."""
WHITE_ALPHA = 0.01
"""The residual is taken as white when its Allan variance stays inside white noise's upper chi-square
limit at every averaging time measured, family-wise at this false-alarm probability."""
SHOWN_SHARE = 0.1
"""A process counts in what the errors assume (:class:`ErrorBasis`) where it holds at least this
share of the residual's Allan variance at some averaging time measured."""


@dataclass(frozen=True)
class ResidualNoise:
    """One axis's residual noise: per-sample variances of its processes at a steady period.

    :param white: variance of the white part per sample.
    :param markov: ``(variance, correlation time s)`` of each Gauss-Markov process.
    :param walk: variance of the random walk's increment per sample.
    :param period: the sample period, s.
    :param longest_s: the longest averaging time the Allan variance was measured at.
    :param shown: the correlation times of the Gauss-Markov processes that show in the residual
        (:data:`SHOWN_SHARE`); ``walk_shown``: whether the random walk does.
    """

    white: float
    markov: tuple[tuple[float, float], ...]
    walk: float
    period: float
    longest_s: float
    shown: tuple[float, ...] = ()
    walk_shown: bool = False

    @classmethod
    def white_only(cls, variance: float, period: float) -> ResidualNoise:
        """White noise of ``variance`` per sample."""
        return cls(white=float(variance), markov=(), walk=0.0, period=period, longest_s=period)


@dataclass(frozen=True)
class ErrorBasis:
    """What a fit's standard errors assume, in a few words for each printed ``+-``.

    :param correlated_s: the longest correlation time of the residual's noise model that matters
        (0: the residual is white at this rate).
    :param walk: whether its noise model holds a random walk (slow noise extrapolated beyond
        ``correlated_s``, the longest averaging time measured).
    :param correlated_errors: ``'<effect>.<parameter>'`` -> the part of its standard error that the
        correlated noise makes (without the white noise's share): it does not fall when the same
        run is sampled more densely.
    """

    correlated_s: float = 0.0
    walk: bool = False
    correlated_errors: dict[str, float] = field(default_factory=dict, compare=False)

    @property
    def white(self) -> bool:
        """Whether the errors take the residual as white."""
        return self.correlated_s <= 0.0 and not self.walk

    def text(self) -> str:
        """``'1 sigma, residual correlated over 240 s'``, ``'... beyond 9 min (a random walk)'`` or ``'... white'``."""
        if self.walk:
            return f'1 sigma, residual wanders beyond {duration_text(self.correlated_s)} (a random walk)'
        if self.white:
            return '1 sigma, residual white'
        return f'1 sigma, residual correlated over {duration_text(self.correlated_s)}'

    def as_dict(self) -> dict[str, object]:
        """JSON-ready form."""
        return {'sigma': 1, 'correlated_s': float(self.correlated_s), 'random_walk': bool(self.walk)}

    @classmethod
    def of(cls, noises: list[ResidualNoise]) -> ErrorBasis:
        """What the noise models of the axes say, together: the longest correlation, a walk on any axis."""
        if any(noise.walk_shown for noise in noises):
            return cls(correlated_s=max(noise.longest_s for noise in noises), walk=True)
        return cls(correlated_s=max((time for noise in noises for time in noise.shown), default=0.0))


def duration_text(seconds: float) -> str:
    """``'0.5 s'``, ``'240 s'``, ``'12 min'``, ``'2.1 h'``."""
    if seconds >= 3600.0:
        return f'{seconds / 3600.0:.2g} h'
    if seconds >= 600.0:
        return f'{seconds / 60.0:.0f} min'
    return f'{seconds:.2g} s' if seconds < 10.0 else f'{seconds:.0f} s'


# ----------------------------------------------------------------------------- operators

def _means(values: np.ndarray, span: int) -> np.ndarray:
    """Means over every ``span`` consecutive rows (``k - span + 1`` of them)."""
    total = np.concatenate([np.zeros((1, *values.shape[1:])), np.cumsum(values, axis=0)])
    return (total[span:] - total[:-span]) / span


def _differences(values: np.ndarray, span: int) -> np.ndarray:
    """The overlapping Allan variance's differences of adjacent ``span``-sample means (``k - 2 span + 1`` rows)."""
    means = _means(values, span)
    return means[span:] - means[:-span]


def _differences_adjoint(differences: np.ndarray, span: int, count: int) -> np.ndarray:
    """The adjoint of :func:`_differences` (``count`` rows): ``D^T u``."""
    weights = np.zeros((count - span + 1, *differences.shape[1:]))
    weights[span:] += differences
    weights[:-span] -= differences
    total = np.concatenate([np.zeros((1, *weights.shape[1:])), np.cumsum(weights, axis=0)])
    rows = np.arange(count)
    return (total[np.minimum(rows, count - span) + 1] - total[np.maximum(rows - span + 1, 0)]) / span


def _markov_apply(values: np.ndarray, decay: float) -> np.ndarray:
    """``S v`` for a unit-variance Gauss-Markov process: ``S[s, t] = decay^|s - t|``."""
    forward = lfilter([1.0], [1.0, -decay], values, axis=0)
    backward = lfilter([1.0], [1.0, -decay], values[::-1], axis=0)[::-1]
    return forward + backward - values


def _walk_apply(values: np.ndarray) -> np.ndarray:
    """``S v`` for a random walk of unit increment variance per sample: ``S[s, t] = min(s, t) + 1``."""
    return np.cumsum(np.cumsum(values[::-1], axis=0)[::-1], axis=0)


# ------------------------------------------------------------------------------ the model

def residual_noise(residual: np.ndarray, period: float, basis: np.ndarray) -> ResidualNoise:
    """The noise model of one axis's residual (see the module docstring).

    :param residual: ``(k,)`` the residual over the samples fitted, in time order.
    :param period: their sample period, s.
    :param basis: ``(k, p)`` an orthonormal basis of the axis's Jacobian (what the fit absorbs).
    """
    residual = np.asarray(residual, dtype=float)
    count = len(residual)
    variance = float(np.mean(residual ** 2)) if count else 0.0
    longest = count // MIN_BATCHES
    if longest < 2 or variance <= 0.0:
        return ResidualNoise.white_only(variance * count / max(count - basis.shape[1], 1), period)
    spans = 2 ** np.arange(int(math.log2(longest)) + 1)
    taus = spans * period
    allan = allan_variance(residual, 1.0 / period, clusters=spans)
    measured = allan.avar[:, 0]
    freedom = np.empty(len(spans))
    for row, (span, differences) in enumerate(zip(spans, allan.counts)):
        freedom[row] = max(1.5 * differences / span, 1.0) if span > 1 else float(differences)
    top = float(taus[-1]) * MARKOV_LONGEST
    times = np.logspace(0.0, math.log10(max(top / period, 1.0)),
                        max(int(MARKOV_PER_DECADE * math.log10(max(top / period, 1.0))) + 1, 1)) * period
    # Per process: how it is applied (S Q) and its Allan variance before the fit absorbs any of it.
    processes = [('white', basis, 1.0 / spans)]
    processes += [('markov', _markov_apply(basis, math.exp(-period / time)),
                   gauss_markov_allan_variance(taus, 1.0, time)) for time in times]
    processes.append(('walk', _walk_apply(basis), spans / 3.0))
    squared = [(basis.T @ applied) for _, applied, _ in processes]  # Q^T S Q
    columns = np.empty((len(spans), len(processes)))
    for row, span in enumerate(spans):
        span = int(span)
        projected = _differences(basis, span)
        rows = len(projected)
        spread = _differences_adjoint(projected, span, count)  # D^T D Q
        gram = projected.T @ projected  # Q^T D^T D Q
        for index, (_, applied, raw) in enumerate(processes):
            absorbed = 2.0 * float(np.sum(applied * spread)) - float(np.sum(gram * squared[index]))
            columns[row, index] = max(raw[row] - absorbed / (2.0 * rows), 0.0)
    # What the fit absorbs at an averaging time costs its estimate degrees of freedom too.
    freedom = np.maximum(freedom * columns[:, 0] * spans, 1.0)
    white = float(np.sum(columns[:, 0] * measured * freedom) / np.sum(columns[:, 0] ** 2 * freedom))
    if _white_enough(measured, white * columns[:, 0], freedom):
        return replace(ResidualNoise.white_only(white, period), longest_s=float(taus[-1]))
    # Weighted by each averaging time's degrees of freedom over the variance expected there: the
    # measurement at first, then (twice) the model's own prediction, so that an estimate that came
    # out low by chance (few degrees of freedom: a skewed chi-square) does not pull the model down.
    expected = measured
    for _ in range(REWEIGHTINGS + 1):
        weights = np.sqrt(freedom) / np.maximum(expected, 1e-300)
        design = columns * weights[:, None]
        norms = np.linalg.norm(design, axis=0)
        norms[norms == 0.0] = 1.0
        solution, _ = nnls(design / norms, measured * weights)
        solution = solution / norms
        expected = np.maximum(columns @ solution, 1e-3 * measured)
    fitted = columns * solution[None, :]
    total = np.maximum(fitted.sum(axis=1), 1e-300)
    shares = (fitted / total[:, None]).max(axis=0)
    markov = tuple((float(value), float(time)) for value, time in zip(solution[1:-1], times))
    return ResidualNoise(white=float(solution[0]), markov=markov, walk=float(solution[-1]), period=period,
                         longest_s=float(taus[-1]),
                         shown=tuple(float(time) for time, share in zip(times, shares[1:-1]) if share >= SHOWN_SHARE),
                         walk_shown=bool(shares[-1] >= SHOWN_SHARE))


def _white_enough(measured: np.ndarray, white: np.ndarray, freedom: np.ndarray) -> bool:
    """Whether the residual's Allan variance stays within white noise's band at every averaging time.

    The upper one-sided chi-square limit on each averaging time's degrees of freedom, family-wise
    :data:`WHITE_ALPHA` over them.
    """
    from scipy.stats import chi2
    limit = chi2.ppf(1.0 - WHITE_ALPHA / len(measured), freedom) / freedom
    return bool(np.all(measured <= white * limit))


def noise_product(weighted: np.ndarray, noise: ResidualNoise) -> np.ndarray:
    """``W^T S W`` for ``(k, P)`` rows ``W`` and the covariance ``S`` of the noise model."""
    out = noise.white * (weighted.T @ weighted)
    for variance, time in noise.markov:
        if variance <= 0.0:
            continue
        decay = math.exp(-noise.period / time)
        # sum_t W_t x_t = x_0 c_0 + sum_u sqrt(1 - decay^2) w_u c_u, c_u = sum_(t >= u) decay^(t-u) W_t.
        reverse = lfilter([1.0], [1.0, -decay], weighted[::-1], axis=0)[::-1]
        out += variance * (np.outer(reverse[0], reverse[0]) + (1.0 - decay * decay) * (reverse[1:].T @ reverse[1:]))
    if noise.walk > 0.0:
        tails = np.cumsum(weighted[::-1], axis=0)[::-1]
        out += noise.walk * (tails.T @ tails)
    return out


def binned(values: np.ndarray, size: int) -> np.ndarray:
    """Means over consecutive bins of ``size`` rows (the last bin may be shorter)."""
    if size <= 1:
        return values
    count = len(values)
    edges = np.arange(0, count, size)
    sums = np.add.reduceat(values, edges, axis=0)
    lengths = np.diff(np.append(edges, count)).astype(float)
    return sums / lengths.reshape(-1, *([1] * (values.ndim - 1)))


@dataclass
class Sandwich:
    """The pieces of the sandwich, added axis by axis (:meth:`add`), then :meth:`covariance`.

    :param size: parameters in all (every axis's own, then the shared ones).
    :param period: the samples' period, s.
    """

    size: int
    period: float
    information: np.ndarray = field(init=False)
    middle: np.ndarray = field(init=False)
    white: np.ndarray = field(init=False)
    noises: list[ResidualNoise] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.information = np.zeros((self.size, self.size))
        self.middle = np.zeros((self.size, self.size))
        self.white = np.zeros((self.size, self.size))

    def add(self, jacobian: np.ndarray, residual: np.ndarray, variance: float, rows: list[int]) -> None:
        """One axis: its Jacobian ``(k, q)`` over the parameters ``rows``, its residual and variance."""
        variance = max(float(variance), 1e-300)
        size = max(1, math.ceil(len(residual) / MAX_SERIES))
        mean_jacobian = binned(jacobian, size)
        self.add_means(mean_jacobian, binned(np.asarray(residual, dtype=float), size),
                       np.full(len(mean_jacobian), float(size)), self.period * size,
                       jacobian.T @ jacobian / variance, variance, rows)

    def add_means(self, mean_jacobian: np.ndarray, mean_residual: np.ndarray, counts: np.ndarray, period: float,
                  information: np.ndarray, variance: float, rows: list[int]) -> None:
        """One axis from its means over consecutive bins of samples (a streamed run keeps no more).

        :param mean_jacobian: ``(b, q)`` each bin's mean Jacobian row; ``mean_residual``: ``(b,)`` its mean residual.
        :param counts: ``(b,)`` the samples in each bin; ``period``: the time between bins, s.
        :param information: ``(q, q)`` ``J^T J / variance`` over every sample (exact, not from the bins).
        """
        variance = max(float(variance), 1e-300)
        self.information[np.ix_(rows, rows)] += information
        basis, _ = np.linalg.qr(mean_jacobian)
        noise = residual_noise(mean_residual, period, basis)
        self.noises.append(noise)
        # sum_t J_t e_t over a bin of n samples is n times the product of its means.
        weighted = mean_jacobian * (np.asarray(counts, dtype=float) / variance)[:, None]
        self.middle[np.ix_(rows, rows)] += noise_product(weighted, noise)
        self.white[np.ix_(rows, rows)] += noise.white * (weighted.T @ weighted)

    def covariance(self, *, correlated_only: bool = False) -> np.ndarray:
        """``A^+ M A^+``; ``correlated_only``: the middle without the white noise.

        That part does not average down when the same run is sampled more densely (a long run's
        amplitudes refitted on every sample, :func:`~tak_thermo_ros.passes.fit.fit_bag`).
        """
        inverse = np.linalg.pinv(self.information, rcond=1e-14, hermitian=True)
        middle = self.middle - self.white if correlated_only else self.middle
        return inverse @ middle @ inverse

    def basis(self) -> ErrorBasis:
        """What the errors assume."""
        return ErrorBasis.of(self.noises)


def not_below(model: np.ndarray, robust: np.ndarray) -> np.ndarray:
    """``model`` plus the positive part of ``robust - model``: a covariance never below the model's.

    Raised along the directions where ``robust`` (a sandwich: what the residual's own correlation, or
    the scatter of independent records, says) is larger; unchanged where it is not.
    """
    short = robust - model
    eigenvalues, vectors = np.linalg.eigh(0.5 * (short + short.T))
    return model + (vectors * np.maximum(eigenvalues, 0.0)) @ vectors.T


def weighted_sum_error(residual: np.ndarray, weights: np.ndarray, period: float = 1.0) -> float:
    """The standard error of ``sum_t w_t e_t`` for a residual ``e`` with its own correlation (its noise model).

    ``sqrt(w^T S w)`` with ``S`` the covariance of the residual's noise model
    (:func:`residual_noise`, its mean the only term fitted), not ``s |w|`` as for white noise.
    """
    residual = np.asarray(residual, dtype=float)
    count = len(residual)
    if count < 2:
        return math.inf
    size = max(1, math.ceil(count / MAX_SERIES))
    means = binned(residual - residual.mean(), size)
    weighted = binned(np.asarray(weights, dtype=float), size) * size
    bins = len(means)
    noise = residual_noise(means, period * size, np.full((bins, 1), 1.0 / math.sqrt(bins)))
    return math.sqrt(max(float(noise_product(weighted[:, None], noise)[0, 0]), 0.0))
