"""The noise model of a measured Allan variance, and how well it follows the measurement.

:func:`fit_noise` fits, per axis, the terms of :class:`~tak_thermo_ros.core.noise.model.NoiseModel`
to an overlapping Allan variance:

1. **Linear in the squares.** For given correlation times (the driver's filter, Gauss-Markov
   processes) the Allan variance is linear in the squared terms, which non-negative least
   squares finds (``scipy.optimize.nnls``, columns normalised).
2. **Weights capped by the model's own error.** An averaging time with ``edf`` equivalent
   degrees of freedom is known to a relative ``sqrt(2 / edf)``; a model is not exact to better
   than its error ``e``, so each averaging time weighs ``1 / (model * sqrt(2 / edf + e^2))``.
   ``e`` starts at the numbers' precision (:data:`MODEL_ERROR`); when the model then does not
   follow the measurement within its band, ``e`` is the misfit's own spread beyond the
   estimates' and the axis is fitted again: the shortest averaging times (hundreds of thousands
   of degrees of freedom) no longer decide the fit alone, and a few per cent of misfit there
   is not paid for with a factor of two at the averaging times that matter. Three
   re-weightings divide by the model's prediction and use the degrees of freedom of the
   process that dominates it.
3. **The driver's filter** (a first-order low-pass on a share of the white noise): its time
   constant is searched on :data:`FILTER_GRID` (in sample periods), none included.
4. **Gauss-Markov processes** are added one at a time (correlation times on a log grid,
   :data:`GAUSS_MARKOV_PER_DECADE`) while the new process lowers the misfit (the deviance of
   the chi-square estimates, :func:`_solve`) by :data:`ADD_THRESHOLD`; at most :data:`MAX_GAUSS_MARKOV`.
5. **Terms the record does not demand are dropped** (bias instability, ramp, quantisation,
   random walk, in that order): when dropping one raises the misfit by less than
   :data:`DROP_THRESHOLD`, the model has none (not in a fit without a random walk among its
   terms, a run's own short-term model, whose flicker term competes with no walk). Where
   that leaves no random walk, ``random_walk_bound`` holds the largest walk the record allows:
   ``min over tau of sqrt(3 avar_high(tau) / tau)`` with ``avar_high`` the upper one-sided 95 %
   limit of the measured Allan variance, joint over the averaging times (every term adds, so
   a walk above that would lift the curve beyond what was measured).

**Goodness of fit** (:class:`AxisFit`): at every averaging time of two samples and longer, the
model against the :data:`BAND_CONFIDENCE` band of the measured Allan variance (chi-square on
its degrees of freedom, joint over the averaging times: Bonferroni); the worst ratio and
where; runs of averaging times outside named as a bump (the measurement above every term) or
a dip (below: a periodic disturbance vanishes at its period); a step (a jump in the record)
from the largest single term of the estimator (:attr:`AllanVariance.peak`) far beyond what
Gaussian noise gives. **IEEE 952's slope lines** (the tangents of slope -1, -1/2, 0, +1/2, +1
under the curve; each an upper bound of its term) are the cross-check
(:mod:`.cross_checks`: :class:`~.cross_checks.SlopeLines`; the step test, :func:`~.cross_checks.find_step`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from tak_thermo_ros.core.noise.cross_checks import SlopeLines, Step, _finite, find_step, slope_lines
from tak_thermo_ros.core.noise.model import (
    TERMS,
    NoiseModel,
    allan_terms,
    ar1_allan_variance,
    filtered_white_allan_variance,
    model_floor_tau,
)
from tak_thermo_ros.errors import NoiseError

FIT_TERMS = (*TERMS, 'filter', 'gauss_markov')
"""What :func:`fit_noise` can fit: the five IEEE 952 terms, the driver's filter, Gauss-Markov processes."""
MODEL_ERROR = (0.002, 0.3)
"""The relative error of a model's Allan variance that caps every averaging time's weight: at
least the first (the numbers' own precision), at most the second. A model that does not follow
the measurement at the first is fitted again with the error its misfit shows (:func:`_model_error`)."""
BAND_CONFIDENCE = 0.95
"""The band of the measured Allan variance the model must stay in, joint over the averaging times."""
FILTER_GRID = (0.3, 0.42, 0.6, 0.85, 1.2, 1.7, 2.4, 3.4, 4.8)
"""The driver filter's time constants tried, in sample periods."""
GAUSS_MARKOV_PER_DECADE = 5
"""Correlation times tried per decade for a Gauss-Markov process."""
MAX_GAUSS_MARKOV = 3
"""At most this many Gauss-Markov processes per axis."""
GAUSS_MARKOV_FALL = 8.0
"""A Gauss-Markov process is tried only where the measurement shows its fall: at this many times
its correlation time the Allan variance must still hold :data:`GAUSS_MARKOV_EDF` degrees of
freedom (else the few degrees of freedom at the longest averaging times let a random walk's
estimate bend like a bump)."""
GAUSS_MARKOV_EDF = 30.0
"""See :data:`GAUSS_MARKOV_FALL`."""
ADD_THRESHOLD = 16.0
"""A Gauss-Markov process (or the filter) joins when it lowers the misfit by this much: four sigmas,
for its two numbers and its correlation time chosen among a grid's."""
DROP_THRESHOLD = 4.0
"""A term stays only when dropping it raises the misfit by at least this (two sigmas): the record
shows a random walk, a bias-instability floor, a ramp, a quantisation only when they pass it."""
ITERATIONS = 3
"""Re-weightings of each solve (the first with the measured Allan variance)."""

_EDF_ROW = np.zeros(5, dtype=np.int64)
_EDF_ROW[[2, 0, -1, -2]] = (0, 1, 2, 3)
"""Row of the degrees-of-freedom table (alpha 2, 0, -1, -2) of a power-law exponent (indexed by alpha)."""
_ALPHA_OF = {'quantization': 2, 'white': 0, 'filtered': 0, 'bias_instability': -1, 'random_walk': -2,
             'rate_ramp': -2}
"""The power-law exponent of each column's noise (its equivalent degrees of freedom)."""


# ------------------------------------------------------------------------------------ results

@dataclass(frozen=True)
class Misfit:
    """A run of averaging times where the model leaves the band of the measurement.

    :param kind: ``bump`` (the measurement above every term the model has) or ``dip`` (below).
    :param low: the shortest averaging time of the run, s.
    :param high: the longest, s.
    :param ratio: the model's Allan deviation over the measured one where it is furthest out.
    :param at: that averaging time, s.
    """

    kind: str
    low: float
    high: float
    ratio: float
    at: float


@dataclass(frozen=True)
class AxisFit:
    """How one axis's model follows its measured Allan deviation.

    :param within: the model inside the band at every averaging time of two samples and longer.
    :param worst_ratio: the model's Allan deviation over the measured one where it is furthest
        out (in units of the band's half-width).
    :param worst_tau: that averaging time, s.
    :param band_low: the band there, as ratios of the measured Allan deviation.
    :param band_high: see ``band_low``.
    :param misfits: the runs outside the band.
    :param step: a jump in the record, or ``None``.
    :param walk_shown: whether the record shows a random walk (else ``random_walk_bound``).
    """

    within: bool
    worst_ratio: float
    worst_tau: float
    band_low: float
    band_high: float
    misfits: tuple[Misfit, ...] = ()
    step: Step | None = None
    walk_shown: bool = True

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return _finite({'within_band': self.within, 'worst_ratio': self.worst_ratio, 'worst_tau_s': self.worst_tau,
                        'band': [self.band_low, self.band_high], 'walk_shown': self.walk_shown,
                        'misfits': [vars(m) for m in self.misfits], 'step': vars(self.step) if self.step else None})


@dataclass(frozen=True)
class NoiseFit:
    """A fitted noise model, how it follows the measurement, and the slope-line cross-check.

    :param model: the model (:class:`~tak_thermo_ros.core.noise.model.NoiseModel`).
    :param axes: per axis x, y, z its :class:`AxisFit`.
    :param slope_lines: IEEE 952's slope lines of the same measurement.
    :param band_from: the shortest averaging time judged (two samples), s.
    """

    model: NoiseModel
    axes: tuple[AxisFit, AxisFit, AxisFit]
    slope_lines: SlopeLines
    band_from: float
    objective: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0))

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (the model is written beside it; a floor that is none is null)."""
        return _finite({'band_confidence': BAND_CONFIDENCE, 'band_from_tau_s': self.band_from,
                        'axes': {name: axis.as_dict() for name, axis in zip('xyz', self.axes)},
                        'slope_lines': self.slope_lines.as_dict(), 'floor': list(self.model.floor())})


# ------------------------------------------------------------------------------------ columns

@dataclass(frozen=True)
class _Design:
    """The columns of one candidate model at the usable averaging times, and what each is."""

    columns: np.ndarray  # (t, c): each column's Allan variance per unit coefficient
    labels: tuple[str, ...]
    alphas: np.ndarray  # (t, c): the power-law exponent of each column's noise at each tau
    filter_time_constant: float
    gauss_markov_times: tuple[float, ...]


def _design(taus: np.ndarray, rate: float, allowed: frozenset[str], filter_time_constant: float,
            gauss_markov_times: Sequence[float]) -> _Design:
    unit = allan_terms(taus)
    columns, labels = [], []
    for i, name in enumerate(TERMS):
        if name in allowed:
            columns.append(unit[:, i])
            labels.append('white' if name == 'white_noise_density' else name)
    if filter_time_constant > 0.0:
        columns.append(filtered_white_allan_variance(taus, rate, filter_time_constant))
        labels.append('filtered')
    alphas = [np.full(len(taus), _ALPHA_OF[label]) for label in labels]
    for time in gauss_markov_times:
        columns.append(ar1_allan_variance(taus * rate, 1.0 / (rate * time)))
        labels.append(f'gm:{time!r}')
        alphas.append(np.where(taus < 0.5 * time, -2, np.where(taus <= 4.0 * time, -1, 0)))
    return _Design(columns=np.column_stack(columns), labels=tuple(labels), alphas=np.column_stack(alphas),
                   filter_time_constant=filter_time_constant, gauss_markov_times=tuple(gauss_markov_times))


@dataclass(frozen=True)
class _Solution:
    design: _Design
    measured: np.ndarray
    coefficients: np.ndarray
    predicted: np.ndarray
    objective: float
    edf: np.ndarray


def _solve(design: _Design, measured: np.ndarray, edf_of: dict[int, np.ndarray], spacing: np.ndarray,
           model_error: float) -> _Solution:
    """Weighted NNLS of ``measured`` on the design, re-weighted with the prediction; its misfit.

    ``spacing``: each averaging time's share of an octave (at most 1): neighbouring averaging
    times of one record are strongly correlated, so two per octave count as one.
    """
    from scipy.optimize import nnls
    # An averaging time whose measured Allan variance is 0 (an output stuck between two codes)
    # says nothing on a relative scale: it is left out.
    spacing = np.where(measured > 0.0, spacing, 0.0)
    tiny = float(np.max(measured, initial=0.0)) * 1e-12 or 1e-300
    reference = np.maximum(measured, tiny)
    edf = edf_of[0]
    coefficients = np.zeros(design.columns.shape[1])
    predicted = reference
    for _ in range(ITERATIONS):
        sigma = np.sqrt(2.0 / edf + model_error ** 2)
        weights = np.sqrt(spacing) / (reference * sigma)
        matrix = design.columns * weights[:, None]
        scale = np.linalg.norm(matrix, axis=0)
        scale[scale == 0.0] = 1.0
        scaled, _residual = nnls(matrix / scale, measured * weights, maxiter=50 * matrix.shape[1])
        coefficients = scaled / scale
        parts = design.columns * coefficients
        predicted = np.maximum(parts.sum(axis=1), tiny)
        reference = predicted
        dominant = np.argmax(parts, axis=1)
        rows = np.arange(len(dominant))
        edf = edf_of['table'][_EDF_ROW[design.alphas[rows, dominant]], rows]
    # The misfit: the deviance of a chi-square (gamma) estimate on its degrees of freedom, the model's
    # own error folded in (2 / nu = 2 / edf + model_error^2); ~ the squared normalised log ratio when
    # nu is large, and as skewed as the estimate is when it is small.
    nu = 2.0 / (2.0 / edf + model_error ** 2)
    ratio = np.maximum(measured, tiny) / predicted
    deviance = nu * (ratio - 1.0 - np.log(ratio))
    return _Solution(design=design, measured=measured, coefficients=coefficients, predicted=predicted,
                     objective=float(np.sum(spacing * deviance)), edf=edf)


def _spacing(taus: np.ndarray) -> np.ndarray:
    """Each averaging time's share of an octave on a log axis (half the distance to both neighbours), at most 1."""
    if len(taus) < 2:
        return np.ones(len(taus))
    steps = np.diff(np.log2(taus))
    share = np.concatenate([[steps[0]], (steps[:-1] + steps[1:]) / 2.0, [steps[-1]]])
    return np.minimum(share, 1.0)


def _band(measured: np.ndarray, edf: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """The joint two-sided band of measured Allan variances on ``edf`` (Bonferroni over ``count``)."""
    from scipy.stats import chi2
    alpha = (1.0 - BAND_CONFIDENCE) / max(count, 1)
    return (measured * edf / chi2.ppf(1.0 - alpha / 2.0, edf), measured * edf / chi2.ppf(alpha / 2.0, edf))


# ------------------------------------------------------------------------------------ the fit

def fit_noise(allan: Any, *, source: str, update_rate: float | None = None, min_terms: int = 2,
              terms: Sequence[str] | None = None) -> NoiseFit:
    """The noise model of each axis of an Allan variance, its goodness of fit and the slope lines.

    :param allan: an :class:`~tak_thermo_ros.core.noise.allan.AllanVariance` of a rate signal.
    :param source: ``file``, ``static_run`` or ``residual``.
    :param update_rate: Hz (default: the Allan variance's sample rate).
    :param min_terms: averaging times with fewer terms than this are left out.
    :param terms: what is fitted (:data:`FIT_TERMS` by default); the others are zero.
    :raises NoiseError: fewer than five usable averaging times, or not three axes, or an unknown term.
    """
    from tak_thermo_ros.core.noise.allan import equivalent_degrees_of_freedom
    terms = FIT_TERMS if terms is None else tuple(terms)
    if allan.axes != 3:
        msg = f'noise model: expected three axes, got {allan.axes}'
        raise NoiseError(msg)
    usable = (allan.counts >= min_terms) & np.all(np.isfinite(allan.avar), axis=1)
    if int(np.count_nonzero(usable)) < len(TERMS):
        msg = (f'noise model: only {int(np.count_nonzero(usable))} averaging times with enough data '
               f'({allan.samples} samples at {allan.rate:g} Hz); at least {len(TERMS)} are needed')
        raise NoiseError(msg)
    unknown = sorted(set(terms) - set(FIT_TERMS))
    if unknown or not set(terms) & set(TERMS):
        msg = (f'noise model: unknown terms {", ".join(unknown)} (known: {", ".join(FIT_TERMS)})' if unknown else
               'noise model: no term to fit')
        raise NoiseError(msg)
    allowed = frozenset(terms)
    rate = allan.rate
    taus = allan.taus[usable]
    clusters = allan.clusters[usable].astype(float)
    judged = clusters >= 2.0
    edf_of = {alpha: equivalent_degrees_of_freedom(allan, alpha)[usable] for alpha in (2, 0, -1, -2)}
    edf_of['table'] = np.vstack([edf_of[2], edf_of[0], edf_of[-1], edf_of[-2]])  # type: ignore[index]
    solutions = []
    for axis in range(3):
        measured = allan.avar[usable, axis]
        solution = _fit_axis(taus, rate, measured, edf_of, allowed, MODEL_ERROR[0])
        if not _within(solution, measured, judged):
            # The model does not follow the measurement to the numbers' precision: the misfit says
            # how well any term can be known; fitted again with that error, no averaging time
            # (the shortest ones hold the most degrees of freedom) decides alone.
            error = _model_error(solution, _spacing(taus))
            if error > MODEL_ERROR[0]:
                solution = _fit_axis(taus, rate, measured, edf_of, allowed, error)
        solutions.append(solution)
    model = _model_of(solutions, taus, rate, update_rate or rate, source, allowed, judged)
    axes = tuple(_goodness(solution, allan, usable, axis, judged, bool(model.random_walk[axis] > 0.0
                                                                       or 'random_walk' not in allowed))
                 for axis, solution in enumerate(solutions))
    return NoiseFit(model=model, axes=axes, slope_lines=slope_lines(allan, usable & (allan.clusters >= 2)),
                    band_from=2.0 / rate, objective=tuple(s.objective for s in solutions))  # type: ignore[arg-type]


def _fit_axis(taus: np.ndarray, rate: float, measured: np.ndarray, edf_of: dict[int, np.ndarray],
              allowed: frozenset[str], model_error: float) -> _Solution:
    """One axis: the filter searched, Gauss-Markov processes added, terms the record does not demand dropped."""
    fitted = _spacing(taus)
    filters = (0.0, *(t / rate for t in FILTER_GRID)) if 'filter' in allowed and 'white_noise_density' in allowed \
        else (0.0,)

    def solve(constant: float, times: Sequence[float], terms: frozenset[str]) -> _Solution:
        return _solve(_design(taus, rate, terms, constant, times), measured, edf_of, fitted, model_error)

    def best_filter(times: Sequence[float], terms: frozenset[str]) -> _Solution:
        """The filter's time constant: the best of the grid, refined between its neighbours; none unless it pays."""
        from scipy.optimize import minimize_scalar
        tried = [solve(f, times, terms) for f in filters]
        best = int(np.argmin([s.objective for s in tried]))
        if best == 0:
            return tried[0]
        low, high = filters[max(best - 1, 1)], filters[min(best + 1, len(filters) - 1)]
        found = minimize_scalar(lambda x: solve(math.exp(x), times, terms).objective,
                                bounds=(math.log(low), math.log(high)), method='bounded', options={'xatol': 0.02})
        refined = min(solve(math.exp(found.x), times, terms), tried[best], key=lambda s: s.objective)
        # A filter is two numbers, as a Gauss-Markov process: kept on the same evidence.
        return refined if refined.objective < tried[0].objective - ADD_THRESHOLD else tried[0]
    if not np.any(measured > 0.0):
        return solve(0.0, (), allowed)
    terms = allowed
    best = best_filter((), terms)
    if 'gauss_markov' in allowed:
        shown = taus[edf_of[0] >= GAUSS_MARKOV_EDF]
        low, high = max(3.0 / rate, float(taus[0])), float(shown.max()) / GAUSS_MARKOV_FALL if len(shown) else 0.0
        count = max(int(round(math.log10(high / low) * GAUSS_MARKOV_PER_DECADE)) + 1, 1) if high > low else 0
        grid = np.geomspace(low, high, count) if count else np.zeros(0)
        while len(best.design.gauss_markov_times) < MAX_GAUSS_MARKOV:
            times = best.design.gauss_markov_times
            candidates = [solve(best.design.filter_time_constant, (*times, float(t)), terms)
                          for t in grid if all(abs(math.log(t / old)) > 0.3 for old in times)]
            if not candidates:
                break
            trial = min(candidates, key=lambda s: s.objective)
            if trial.objective > best.objective - ADD_THRESHOLD:
                break
            best = trial
    # The filter shapes the shortest averaging times, the processes added and the terms dropped the
    # longer ones: the filter is searched again only when a process was added.
    changed = bool(best.design.gauss_markov_times)
    # The simplest model the record supports: a term whose removal costs less than DROP_THRESHOLD goes
    # (the flat flicker term must not stand in for a walk, nor a walk for what the record cannot show).
    # A fit without a walk among its terms (a run's own short-term model) keeps its few terms: the
    # flicker term is its only slow one, and it competes with no walk.
    for name in ('bias_instability', 'rate_ramp', 'quantization', 'random_walk') if 'random_walk' in allowed else ():
        if name not in best.design.labels:
            continue
        simpler = solve(best.design.filter_time_constant, best.design.gauss_markov_times, terms - {name})
        if best.coefficients[best.design.labels.index(name)] == 0.0 or \
                simpler.objective < best.objective + DROP_THRESHOLD:
            best, terms = simpler, terms - {name}
    if changed and len(filters) > 1:
        best = min(best, best_filter(best.design.gauss_markov_times, terms), key=lambda s: s.objective)
    return best


def _model_error(solution: _Solution, spacing: np.ndarray) -> float:
    """The model's relative error its misfit shows: the log ratios' spread beyond the estimates' own.

    ``sqrt(mean(ln^2 (measured / model) - 2 / edf))`` (weighted by ``spacing``), within :data:`MODEL_ERROR`.
    """
    seen = solution.measured > 0.0
    excess = np.log(solution.measured[seen] / solution.predicted[seen]) ** 2 - 2.0 / solution.edf[seen]
    spread = float(np.sum(spacing[seen] * excess) / max(float(np.sum(spacing[seen])), 1e-300))
    return float(np.clip(math.sqrt(max(spread, 0.0)), MODEL_ERROR[0], MODEL_ERROR[1]))


def _within(solution: _Solution, measured: np.ndarray, judged: np.ndarray) -> bool:
    low, high = _band(measured, solution.edf, int(np.count_nonzero(judged)))
    inside = (low <= solution.predicted) & (solution.predicted <= high)
    return bool(np.all(inside[judged]))


def _model_of(solutions: list[_Solution], taus: np.ndarray, rate: float, update_rate: float, source: str,
              allowed: frozenset[str], judged: np.ndarray) -> NoiseModel:
    """The :class:`NoiseModel` of three axes' solutions (Gauss-Markov processes in slots by size)."""
    values = {name: [0.0, 0.0, 0.0] for name in (*TERMS, 'filter_time_constant', 'filter_share')}
    slots = max((len(s.design.gauss_markov_times) for s in solutions), default=0)
    sigmas = [[0.0, 0.0, 0.0] for _ in range(slots)]
    times = [[1.0, 1.0, 1.0] for _ in range(slots)]
    for axis, solution in enumerate(solutions):
        coefficients = dict(zip(solution.design.labels, solution.coefficients))
        for name in TERMS:
            label = 'white' if name == 'white_noise_density' else name
            values[name][axis] = math.sqrt(max(coefficients.get(label, 0.0), 0.0))
        filtered = max(coefficients.get('filtered', 0.0), 0.0)
        white = values['white_noise_density'][axis] ** 2 + filtered
        values['white_noise_density'][axis] = math.sqrt(white)
        if filtered > 0.0 and white > 0.0:
            values['filter_time_constant'][axis] = solution.design.filter_time_constant
            values['filter_share'][axis] = min(filtered / white, 1.0)
        bumps = sorted(((coefficients[f'gm:{t!r}'], t) for t in solution.design.gauss_markov_times
                        if coefficients[f'gm:{t!r}'] > 0.0), reverse=True)
        for slot, (variance, time) in enumerate(bumps):
            sigmas[slot][axis], times[slot][axis] = math.sqrt(variance), time
    used = [i for i in range(slots) if any(sigmas[i])]
    model = NoiseModel(bias_instability_tau=(1.0, 1.0, 1.0), update_rate=update_rate, source=source,
                       gauss_markov=tuple(tuple(sigmas[i]) for i in used),  # type: ignore[arg-type]
                       gauss_markov_time=tuple(tuple(times[i]) for i in used),  # type: ignore[arg-type]
                       **{name: tuple(value) for name, value in values.items()})  # type: ignore[arg-type]
    floor = model_floor_tau(model, (float(taus[judged].min()) if np.any(judged) else float(taus.min()),
                                    float(taus.max())))
    bound = [0.0, 0.0, 0.0]
    if 'random_walk' in allowed:
        for axis, solution in enumerate(solutions):
            if model.random_walk[axis] == 0.0:
                bound[axis] = _walk_bound(taus, solution, judged)
    from dataclasses import replace
    return replace(model, bias_instability_tau=floor, random_walk_bound=tuple(bound))


def _walk_bound(taus: np.ndarray, solution: _Solution, judged: np.ndarray) -> float:
    """The largest random walk the measurement allows: ``min sqrt(3 avar_high / tau)``.

    ``avar_high``: the upper one-sided limit of each measured Allan variance, jointly at
    :data:`BAND_CONFIDENCE` over the averaging times (Bonferroni), on the degrees of freedom of
    the process that dominates there. Every term adds to the Allan variance, so a walk above
    this would have lifted the curve beyond what was measured at some averaging time.
    """
    from scipy.stats import chi2
    if not np.any(judged):
        return 0.0
    edf = solution.edf[judged]
    level = (1.0 - BAND_CONFIDENCE) / int(np.count_nonzero(judged))
    high = solution.measured[judged] * edf / chi2.ppf(level, edf)
    return float(np.min(np.sqrt(3.0 * high / taus[judged])))


# ------------------------------------------------------------------------------ goodness of fit

def _goodness(solution: _Solution, allan: Any, usable: np.ndarray, axis: int, judged: np.ndarray,
              walk_shown: bool) -> AxisFit:
    """The model against the measured band at every averaging time of two samples and longer."""
    taus = allan.taus[usable]
    measured, predicted = solution.measured, solution.predicted
    step = find_step(allan, axis, usable)
    if not np.any(judged) or not np.any(measured > 0.0):
        return AxisFit(within=True, worst_ratio=1.0, worst_tau=float(taus[0]), band_low=1.0, band_high=1.0,
                       step=step, walk_shown=walk_shown)
    low, high = _band(measured, solution.edf, int(np.count_nonzero(judged)))
    with np.errstate(divide='ignore', invalid='ignore'):
        above = np.log(predicted / np.maximum(high, 1e-300)) / np.maximum(np.log(high / measured), 1e-12)
        below = np.log(np.maximum(low, 1e-300) / predicted) / np.maximum(np.log(measured / low), 1e-12)
    excess = np.where(judged, np.maximum(above, below), -np.inf)
    worst = int(np.argmax(excess))
    outside = judged & ((predicted > high) | (predicted < low))
    misfits = []
    index = 0
    while index < len(taus):
        if not outside[index]:
            index += 1
            continue
        kind = 'dip' if predicted[index] > high[index] else 'bump'
        end = index
        while end + 1 < len(taus) and outside[end + 1] and (predicted[end + 1] > high[end + 1]) == (kind == 'dip'):
            end += 1
        run = np.arange(index, end + 1)
        far = run[int(np.argmax(np.abs(np.log(predicted[run] / measured[run]))))]
        misfits.append(Misfit(kind=kind, low=float(taus[index]), high=float(taus[end]),
                              ratio=float(math.sqrt(predicted[far] / measured[far])), at=float(taus[far])))
        index = end + 1
    return AxisFit(within=not bool(np.any(outside)), worst_ratio=float(math.sqrt(predicted[worst] / measured[worst])),
                   worst_tau=float(taus[worst]), band_low=float(math.sqrt(low[worst] / measured[worst])),
                   band_high=float(math.sqrt(high[worst] / measured[worst])), misfits=tuple(misfits), step=step,
                   walk_shown=walk_shown)


def fit_noise_model(allan: Any, *, source: str, update_rate: float | None = None,
                    min_terms: int = 2, terms: Sequence[str] | None = None) -> NoiseModel:
    """The noise model of each axis of an Allan variance (:func:`fit_noise`).

    :param terms: the terms fitted (default: all, :data:`FIT_TERMS`).
    :raises NoiseError: fewer than five usable averaging times, or not three axes, or an unknown term.
    """
    return fit_noise(allan, source=source, update_rate=update_rate, min_terms=min_terms, terms=terms).model
