"""A fleet's prior: the mean curve of units of one kind and their spread around it, from each unit's information.

Each unit's records reduce to its information on its curve terms (:class:`~tak_thermo_ros.core.fit.prior.Information`:
``H_u``, ``g_u``, ``c_u``, in one basis). The units' curves are drawn around the kind's:
``theta_u ~ N(mean, S^2)``, ``S`` diagonal (per sensor, axis and term: the units' spread), so a unit's
marginal likelihood is Gaussian in closed form, and the restricted maximum likelihood (REML, the mean
integrated out) of ``S`` is::

    -2 log L = sum_u [log|I + H~_u| + c~_u - g~_u' M_u^-1 g~_u] + log|sum_u M_u^-1 H~_u| - 2 log|S|
               - b' (sum_u M_u^-1 H~_u)^-1 b,   H~ = S H S / phi, g~ = S g / phi, M = I + H~, b = sum_u M_u^-1 g~_u

(plus ``sum_u rows_u log phi`` when a common scale ``phi`` of the units' own noise is estimated too:
then this is exactly the REML of the linear mixed model on the units' data, what statsmodels' MixedLM
maximises; a test holds the two together). ``H_u`` may be singular: a unit that never saw the cold
tells nothing about the cold, and says nothing there. Minimised over ``log S`` (and ``log phi``) by
a bounded quasi-Newton search; the spread's standard errors from the criterion's curvature.

**A unit far outside the fleet** (another part, a damaged board) is named and left out
(:func:`screen`): its distance ``(theta_u - mean)' (S^2 + Cov(mean) + H_u^-1)^-1 (theta_u - mean)``
(the part of it the unit's records tell) beyond the chi-square's ``1 - OUTLIER_ALPHA / units`` quantile,
confirmed with the fleet fitted without it, one unit at a time.

**Groups** (Reginya et al. 2018: 250 MPU-9250 in six clusters of slopes): a mixture of ``K`` Gaussians,
each its own mean, one spread, fitted by expectation-maximisation on the units' information (the
deconvolution of Bovy et al. 2011, "extreme deconvolution", with diagonal spread); ``K`` is kept when
its Bayesian information criterion beats one group's by :data:`GROUP_BIC` and each group holds
:data:`MIN_GROUP_UNITS` units or more.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from tak_thermo_ros.core.fit.prior import Basis, Information, SensorPrior, curve_term
from tak_thermo_ros.errors import FitError

MIN_UNITS = 3
"""A prior needs this many units (a spread from two is no spread)."""
FEW_UNITS = 10
"""A prior from fewer units says so: its spread is known to about ``1 / sqrt(2 (units - 1))`` (a third at 6)."""
OUTLIER_ALPHA = 1e-3
"""A unit is far outside the fleet when a fleet of its kind would put one so far this seldom."""
UPPER_RISE = 3.84
"""A spread's upper bound is where the criterion has risen by this much (the 95 % chi-square of one term)."""
CANDIDATE_Z = 4.0
"""A unit whose estimate of a term lies this many robust spreads from the units' median is tested."""
MAX_GROUPS = 3
"""At most this many groups are tried."""
MIN_GROUP_UNITS = 5
"""A group holds at least this many units (its share of them)."""
GROUP_BIC = 10.0
"""More groups are kept when they lower the BIC by this much (very strong evidence, Kass and Raftery)."""
SURE_GROUP = 0.95
"""A unit belongs to a group when its records put it there with this probability; else a blend of the groups."""
EM_ITERATIONS = 300
EM_SETTLED = 1e-6
"""Expectation-maximisation stops after this many rounds, or when the log-likelihood moves less than this (relative)."""
EM_STARTS = 4
"""Starting points of each mixture (the best kept)."""
SPREAD_RANGE = (1e-4, 1e4)
"""The spread is searched within these multiples of the units' typical error (or of their spread, the larger)."""
TOLD = 1e-9
"""A term the units' information holds less than this share of its typical diagonal is told by no unit: left out."""


@dataclass(frozen=True)
class Group:
    """A group of units: its share, its mean curve terms and that mean's covariance.

    :param units: the units whose records put them in it (probability :data:`SURE_GROUP`).
    """

    weight: float
    mean: np.ndarray
    mean_covariance: np.ndarray
    units: tuple[str, ...] = ()


@dataclass(frozen=True)
class FarUnit:
    """A unit left out of a prior: its distance from the fleet, and the term furthest out.

    :param distance: the chi-square of its curve terms against the fleet's spread and its own errors.
    :param dof: the terms its records tell; ``probability`` of a distance so far in a fleet of its kind.
    :param term: the term furthest out, ``sigmas`` how far (the fleet's spread and its own error).
    """

    name: str
    sensor: str
    distance: float
    dof: int
    probability: float
    term: str
    sigmas: float


@dataclass(frozen=True)
class SensorFleet:
    """A sensor's prior from a fleet: the groups' means, the units' spread, what was left out.

    :param names: the curve terms (in :attr:`basis`).
    :param spread: ``(P,)`` the units' standard deviation about their group's mean, per term;
        ``spread_error`` its error.
    :param units: the units it was estimated from; ``records`` their records.
    :param low: the lowest temperature any of their records saw; ``high`` the highest.
    :param left_out: units far outside (named, not in the prior).
    :param untold: curve terms no unit's records tell (not in the prior: a fit holds them as before).
    :param scale: the units' own noise scale (1: their fits' errors taken as they are).
    """

    sensor: str
    names: tuple[str, ...]
    basis: Basis
    groups: tuple[Group, ...]
    spread: np.ndarray
    spread_error: np.ndarray
    units: tuple[str, ...]
    low: float
    high: float
    records: int = 0
    left_out: tuple[FarUnit, ...] = ()
    untold: tuple[str, ...] = ()
    scale: float = 1.0

    @property
    def inflation(self) -> float:
        """The spread's variance widened for a prediction from few units (:func:`_t_inflation`)."""
        return _t_inflation(len(self.units))

    @property
    def mean(self) -> np.ndarray:
        """The fleet's mean ``(P,)`` over its groups, by their weights."""
        return sum(group.weight * group.mean for group in self.groups)

    def blend(self, weights: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        """The Gaussian nearest the groups' mixture at ``weights``: mean and covariance.

        The covariance: the spread (:attr:`inflation` for few units), each group mean's error, the groups' scatter.
        """
        weights = np.asarray(weights, dtype=float) / float(np.sum(weights))
        mean = sum(w * group.mean for w, group in zip(weights, self.groups))
        covariance = np.diag(self.inflation * self.spread ** 2)
        for w, group in zip(weights, self.groups):
            offset = group.mean - mean
            covariance = covariance + w * (group.mean_covariance + np.outer(offset, offset))
        return mean, covariance

    def membership(self, information: Information) -> np.ndarray:
        """``(K,)`` the probability of each group given a unit's information (its curve terms, this basis)."""
        if len(self.groups) == 1:
            return np.ones(1)
        stats = _Stats.of([information], self.names)
        logs = np.array([math.log(group.weight) - 0.5 * _marginal(stats, group.mean, self.spread)[0]
                         for group in self.groups])
        logs -= logs.max()
        return np.exp(logs) / np.exp(logs).sum()

    def prior_for(self, information: Information | None = None, label: str = '') -> tuple[SensorPrior, str]:
        """The Gaussian a unit's fit takes, and one statement of which group (``information``: its records', or none).

        One group: the fleet's mean and spread (and the mean's own error). Several: the group its records
        put it in (:data:`SURE_GROUP`), else the blend of the groups at its probabilities.
        """
        if len(self.groups) == 1:
            mean, covariance = self.blend([1.0])
            return SensorPrior(self.names, mean, covariance, label), ''
        if information is None:
            weights = np.array([group.weight for group in self.groups])
            mean, covariance = self.blend(weights)
            return SensorPrior(self.names, mean, covariance, label), 'no records to choose a group: the groups blended'
        weights = self.membership(information.in_basis(self.basis))
        best = int(np.argmax(weights))
        if weights[best] >= SURE_GROUP:
            weights = np.eye(len(self.groups))[best]
            said = f'group {best + 1} of {len(self.groups)} (probability {100.0 * float(weights[best]):.0f} %)'
        else:
            said = ('between groups ' + ', '.join(f'{i + 1} {100.0 * w:.0f} %' for i, w in enumerate(weights))
                    + ': the groups blended')
        mean, covariance = self.blend(weights)
        return SensorPrior(self.names, mean, covariance, label), said


def _t_inflation(units: int) -> float:
    """``(t_{units - 1} / z)^2`` at 95 %: a Gaussian stand-in for a prediction from a spread estimated from ``units``.

    A new unit's curve about a mean and a spread estimated from ``U`` units is Student-t with ``U - 1``
    degrees of freedom, not Gaussian: its Gaussian stand-in is this much wider (1.56 at 7 units, 1.02 at 100).
    """
    from scipy.stats import norm, t
    return float((t.ppf(0.975, max(units, 2) - 1) / norm.ppf(0.975)) ** 2)


# ----- the units' statistics, scaled ------------------------------------------------------------------


@dataclass(frozen=True)
class _Stats:
    """Every unit's ``H`` ``(U, P, P)``, ``g`` ``(U, P)``, ``c`` ``(U,)`` and rows over common names."""

    hessian: np.ndarray
    gradient: np.ndarray
    constant: np.ndarray
    rows: np.ndarray

    @classmethod
    def of(cls, units: Sequence[Information], names: Sequence[str]) -> _Stats:
        parts = [unit.aligned(names) for unit in units]
        return cls(np.array([p[0] for p in parts]).reshape(len(units), len(names), len(names)),
                   np.array([p[1] for p in parts]).reshape(len(units), len(names)),
                   np.array([p[2] for p in parts], dtype=float), np.array([u.rows for u in units], dtype=float))

    def subset(self, keep: np.ndarray) -> _Stats:
        return _Stats(self.hessian[keep], self.gradient[keep], self.constant[keep], self.rows[keep])

    @property
    def count(self) -> int:
        return len(self.gradient)

    def errors(self) -> np.ndarray:
        """``(P,)`` a typical unit's error per term (from the units that tell it)."""
        diagonal = np.einsum('upp->up', self.hessian)
        told = np.where(diagonal > 0.0, diagonal, np.nan)
        return 1.0 / np.sqrt(np.nanmedian(told, axis=0))

    def estimates(self) -> np.ndarray:
        """``(U, P)`` each unit's own estimate (pseudo-inverse; an untold term ``nan``)."""
        out = np.full(self.gradient.shape, np.nan)
        for u in range(self.count):
            hessian = self.hessian[u]
            scale = np.sqrt(np.maximum(np.diag(hessian), 0.0))
            told = scale > 0.0
            if not told.any():
                continue
            block = hessian[np.ix_(told, told)] / np.outer(scale[told], scale[told])
            out[u, told] = np.linalg.lstsq(block, self.gradient[u, told] / scale[told], rcond=1e-10)[0] / scale[told]
        return out


def _scaled(stats: _Stats, spread: np.ndarray, phi: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``H~`` ``(U, P, P)``, ``g~`` ``(U, P)`` and ``M = I + H~``."""
    hessian = stats.hessian * spread[None, :, None] * spread[None, None, :] / phi
    gradient = stats.gradient * spread[None, :] / phi
    return hessian, gradient, hessian + np.eye(len(spread))[None]


def _logdet(matrix: np.ndarray) -> np.ndarray:
    sign, value = np.linalg.slogdet(matrix)
    return np.where(sign > 0, value, np.inf)


def _marginal(stats: _Stats, mean: np.ndarray, spread: np.ndarray, phi: float = 1.0) -> np.ndarray:
    """``(U,)``: ``-2 log`` each unit's likelihood, its curve drawn from ``N(mean, spread^2)`` (up to a constant)."""
    hessian, gradient, matrix = _scaled(stats, spread, phi)
    centred = mean / spread
    total = gradient + centred[None, :]
    solved = np.linalg.solve(matrix, total[..., None])[..., 0]
    return (_logdet(matrix) + stats.constant / phi - np.einsum('up,up->u', total, solved)
            + float(centred @ centred) + stats.rows * math.log(phi))


def reml_criterion(stats: _Stats, spread: np.ndarray, phi: float = 1.0, *,
                   restricted: bool = True) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """``-2 log REML`` of the spread (see the module's description), the mean, its covariance, the gradient.

    The gradient along ``log spread`` (``phi`` held) is the expectation identity of the likelihood:
    ``2 U - 2 sum_u E[d~_uk^2]``, ``d~_u = (theta_u - mean) / spread`` under the units' posterior (and, for the
    restricted likelihood, the mean's: ``E d~ = M^-1 (g~ - H~ m~)``, ``Cov d~ = M^-1 + M^-1 H~ A^-1 H~ M^-1``).

    :param restricted: ``False``: ``-2 log`` the likelihood at the best mean (maximum likelihood's, for the BIC).
    """
    size = len(spread)
    hessian, gradient, matrix = _scaled(stats, spread, phi)
    inverse_m = np.linalg.inv(matrix)
    solved_h = inverse_m @ hessian
    solved_g = np.einsum('upq,uq->up', inverse_m, gradient)
    a = solved_h.sum(axis=0)
    a = 0.5 * (a + a.T)
    b = solved_g.sum(axis=0)
    try:
        factor = np.linalg.cholesky(a)
    except np.linalg.LinAlgError:
        return math.inf, np.full(size, np.nan), np.full((size, size), np.nan), np.zeros(size)
    inverse = np.linalg.inv(a)
    centred = inverse @ b
    value = float(np.sum(_logdet(matrix) + stats.constant / phi - np.einsum('up,up->u', gradient, solved_g)
                         + stats.rows * math.log(phi)) - b @ centred)
    expected = solved_g - solved_h @ centred  # E d~ per unit
    variance = np.einsum('upp->up', inverse_m)
    if restricted:
        value += 2.0 * np.sum(np.log(np.diag(factor))) - 2.0 * np.sum(np.log(spread))
        variance = variance + np.einsum('upq,qr,upr->up', solved_h, inverse, solved_h)
    slope = 2.0 * stats.count - 2.0 * np.sum(expected ** 2 + variance, axis=0)
    return value, spread * centred, inverse * np.outer(spread, spread), slope


@dataclass(frozen=True)
class Reml:
    """One Gaussian's REML: the mean, its covariance, the spread and its error, the scale, the criterion."""

    mean: np.ndarray
    mean_covariance: np.ndarray
    spread: np.ndarray
    spread_error: np.ndarray
    phi: float
    criterion: float


def _bounds(stats: _Stats) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per term the search's bounds on ``log spread`` and its start (the estimates' excess spread)."""
    errors = stats.errors()
    estimates = stats.estimates()
    with np.errstate(all='ignore'):
        naive = np.nanstd(estimates, axis=0, ddof=1) if stats.count > 1 else np.zeros(len(errors))
    naive = np.where(np.isfinite(naive), naive, errors)
    typical = np.maximum(errors, naive)
    start = np.sqrt(np.maximum(naive ** 2 - errors ** 2, (0.3 * errors) ** 2))
    low, high = np.log(SPREAD_RANGE[0] * typical), np.log(SPREAD_RANGE[1] * typical)
    return low, high, np.clip(np.log(start), low, high)


def reml(stats: _Stats, *, scale: bool = False, restricted: bool = True, start: np.ndarray | None = None) -> Reml:
    """The REML of one Gaussian over the units (``scale``: the units' noise scale ``phi`` estimated too).

    :param restricted: ``False``: the maximum likelihood instead (a mixture's one group, for the BIC).
    :param start: a spread to start from (a nearby fleet's), else the units' excess spread.
    """
    from scipy.optimize import minimize
    low, high, first = _bounds(stats)
    if start is not None:
        first = np.clip(np.log(start), low, high)
    if scale:
        low, high, first = np.append(low, -20.0), np.append(high, 20.0), np.append(first, 0.0)

    def objective(p: np.ndarray) -> float:
        value = reml_criterion(stats, np.exp(p[:len(low) - scale]), math.exp(p[-1]) if scale else 1.0,
                               restricted=restricted)[0]
        return value if math.isfinite(value) else 1e300

    def with_slope(p: np.ndarray) -> tuple[float, np.ndarray]:
        value, _, _, slope = reml_criterion(stats, np.exp(p), restricted=restricted)
        return (value, slope) if math.isfinite(value) else (1e300, np.zeros(len(p)))

    found = minimize(objective if scale else with_slope, first, jac=not scale, method='L-BFGS-B',
                     bounds=list(zip(low, high)), options={'maxiter': 500, 'ftol': 1e-12, 'gtol': 1e-7})
    best = found.x
    spread = np.exp(best[:len(low) - scale])
    phi = math.exp(best[-1]) if scale else 1.0
    value, mean, mean_covariance, _ = reml_criterion(stats, spread, phi, restricted=restricted)
    slope = None if scale else (lambda p: with_slope(p)[1])
    error = spread * _log_errors(objective, best, low, high, slope=slope)[:len(spread)]
    return Reml(mean, mean_covariance, spread, error, phi, value)


def _log_errors(objective, at: np.ndarray, low: np.ndarray, high: np.ndarray, step: float = 0.05,
                slope=None) -> np.ndarray:
    """Standard errors of the parameters (logarithms) from the curvature of ``-2 log L``: ``sqrt(2 (Hess^-1)_kk)``.

    The curvature from differences of ``slope`` (the criterion's gradient) when given, else of the criterion.
    A parameter at a bound (a spread the units do not show) has none (``nan``).
    """
    size = len(at)
    inside = (at > low + step) & (at < high - step)
    free = np.flatnonzero(inside)
    hessian = np.zeros((size, size))

    def moved(moves: dict[int, float]) -> np.ndarray:
        point = at.copy()
        for index, delta in moves.items():
            point[index] += delta
        return point

    if slope is not None:
        for i in free:
            hessian[:, i] = (slope(moved({i: step})) - slope(moved({i: -step}))) / (2.0 * step)
        hessian = 0.5 * (hessian + hessian.T)
    else:
        base = objective(at)
        for i in free:
            hessian[i, i] = (objective(moved({i: step})) - 2.0 * base + objective(moved({i: -step}))) / step ** 2
            for j in free[free < i]:
                cross = (objective(moved({i: step, j: step})) - objective(moved({i: step, j: -step}))
                         - objective(moved({i: -step, j: step})) + objective(moved({i: -step, j: -step})))
                hessian[i, j] = hessian[j, i] = cross / (4 * step ** 2)
    out = np.full(size, np.nan)
    if len(free):
        try:
            covariance = 2.0 * np.linalg.inv(hessian[np.ix_(free, free)])
            out[free] = np.sqrt(np.where(np.diag(covariance) > 0.0, np.diag(covariance), np.nan))
        except np.linalg.LinAlgError:
            pass
    return out


# ----- a unit far outside ---------------------------------------------------------------------------


def distance(stats: _Stats, mean: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each unit's chi-square against ``N(mean, covariance)`` over what its records tell; its terms, its z per term.

    ``Q = z~' (H~ (I + H~))^+ z~`` with ``z = g - H mean`` in the root of ``covariance`` (``H~ = R' H R``):
    the unit's own estimate's distance ``(theta - mean)' (covariance + H^-1)^-1 (theta - mean)`` where
    ``H`` is regular, and only along what its records tell where it is not.
    """
    root = np.linalg.cholesky(covariance + 1e-300 * np.eye(len(mean)))
    count = stats.count
    q, dof, z = np.zeros(count), np.zeros(count, dtype=int), np.zeros((count, len(mean)))
    estimates = stats.estimates()
    for u in range(count):
        hessian = root.T @ stats.hessian[u] @ root
        centred = root.T @ (stats.gradient[u] - stats.hessian[u] @ mean)
        values, vectors = np.linalg.eigh(0.5 * (hessian + hessian.T))
        keep = values > 1e-6
        along = vectors[:, keep].T @ centred
        q[u] = float(np.sum(along ** 2 / (values[keep] * (1.0 + values[keep]))))
        dof[u] = int(keep.sum())
        with np.errstate(all='ignore'):
            own = np.diag(np.linalg.pinv(stats.hessian[u]))
            z[u] = (estimates[u] - mean) / np.sqrt(np.diag(covariance) + own)
    return q, dof, np.where(np.isfinite(z), z, 0.0)


def upper_spread(stats: _Stats, fitted: Reml, rise: float = UPPER_RISE) -> np.ndarray:
    """Per term the spread's upper bound: where ``-2 log REML`` rises by ``rise`` (the others held), upwards."""
    from scipy.optimize import brentq
    low, high, _ = _bounds(stats)
    out = fitted.spread.copy()
    for k in range(len(out)):
        def excess(log_spread: float, k: int = k) -> float:
            trial = fitted.spread.copy()
            trial[k] = math.exp(log_spread)
            value = reml_criterion(stats, trial)[0]
            return (value if math.isfinite(value) else 1e300) - fitted.criterion - rise

        start = math.log(fitted.spread[k])
        if excess(high[k]) <= 0.0:
            out[k] = math.exp(high[k])
        elif high[k] > start:
            out[k] = math.exp(brentq(excess, start, high[k], xtol=1e-3))
    return out


def _candidates(stats: _Stats) -> list[int]:
    """Units whose own estimate of some term lies far from the others' median (robust: no masking), farthest first.

    Per term the units' estimates about their median, in units of ``1.4826 MAD`` widened by the unit's own
    error; beyond :data:`CANDIDATE_Z` a unit is a candidate, to be confirmed by the exact test.
    """
    estimates = stats.estimates()
    own = 1.0 / np.sqrt(np.maximum(np.einsum('upp->up', stats.hessian), 1e-300))
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', RuntimeWarning)
        centre = np.nanmedian(estimates, axis=0)
        spread = 1.4826 * np.nanmedian(np.abs(estimates - centre), axis=0)
        z = np.abs(estimates - centre) / np.sqrt(spread ** 2 + own ** 2)
    worst = np.nanmax(np.where(np.isfinite(z), z, np.nan), axis=1)
    worst = np.where(np.isfinite(worst), worst, 0.0)
    return [int(u) for u in np.argsort(-worst) if worst[u] > CANDIDATE_Z]


def screen(stats: _Stats, names: Sequence[str], unit_names: Sequence[str], sensor: str,
           fitted: Reml) -> tuple[np.ndarray, Reml, list[FarUnit]]:
    """Units far outside the fleet, each tested against the fleet without it (left out one at a time).

    The units tested: the robust candidates (:func:`_candidates`: an outlier cannot hide by widening the
    spread it is judged by), and the one farthest by the fleet's own fit.

    :returns: which units are kept, the fleet's REML without the others, the units left out.
    """
    from scipy.stats import chi2
    keep = np.ones(stats.count, dtype=bool)
    left: list[FarUnit] = []
    q, dof, _ = distance(stats, fitted.mean, np.diag(fitted.spread ** 2) + fitted.mean_covariance)
    probability = np.where(dof > 0, chi2.sf(q, np.maximum(dof, 1)), 1.0)
    farthest = int(np.argmin(probability))
    tried = _candidates(stats)
    if farthest not in tried and probability[farthest] < OUTLIER_ALPHA:
        tried.append(farthest)
    for index in tried:
        if keep.sum() <= MIN_UNITS:
            break
        without = keep.copy()
        without[index] = False
        others = reml(stats.subset(without), start=fitted.spread)
        single = stats.subset(np.arange(stats.count) == index)
        # against the others' spread at its upper bound: a few units may agree by chance more than their kind
        upper = upper_spread(stats.subset(without), others)
        q1, dof1, z1 = distance(single, others.mean, np.diag(upper ** 2) + others.mean_covariance)
        p1 = float(chi2.sf(q1[0], max(int(dof1[0]), 1)))
        if not (dof1[0] > 0 and p1 < OUTLIER_ALPHA / stats.count):
            continue
        term = int(np.argmax(np.abs(z1[0])))
        left.append(FarUnit(unit_names[index], sensor, float(q1[0]), int(dof1[0]), p1, names[term],
                            float(z1[0, term])))
        keep, fitted = without, others
    if left:
        fitted = reml(stats.subset(keep))
    return keep, fitted, left


# ----- groups ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Mixture:
    """``K`` groups with one spread, fitted by expectation-maximisation (maximum likelihood)."""

    weights: np.ndarray
    means: np.ndarray
    spread: np.ndarray
    responsibilities: np.ndarray
    log_likelihood: float

    def bic(self, units: int) -> float:
        """``-2 log L + parameters ln units`` (each group's mean and share, the spread)."""
        count, size = self.means.shape
        return -2.0 * self.log_likelihood + (count * size + size + count - 1) * math.log(units)


def _e_step(stats: _Stats, weights: np.ndarray, means: np.ndarray, spread: np.ndarray) -> tuple[np.ndarray, float]:
    logs = np.column_stack([math.log(max(w, 1e-300)) - 0.5 * _marginal(stats, mean, spread)
                            for w, mean in zip(weights, means)])
    top = logs.max(axis=1, keepdims=True)
    total = top[:, 0] + np.log(np.exp(logs - top).sum(axis=1))
    return np.exp(logs - total[:, None]), float(np.sum(total))


def _m_step(stats: _Stats, responsibilities: np.ndarray, spread: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                                      np.ndarray]:
    """The groups' shares and means (weighted generalised least squares), the spread (the deconvolution's update)."""
    hessian, gradient, matrix = _scaled(stats, spread)
    solved_h = np.linalg.solve(matrix, hessian)
    solved_g = np.linalg.solve(matrix, gradient[..., None])[..., 0]
    inverse = np.linalg.inv(matrix)
    means = []
    spread_sq = np.zeros(len(spread))
    for k in range(responsibilities.shape[1]):
        weight = responsibilities[:, k]
        a = np.einsum('u,upq->pq', weight, solved_h)
        centred = np.linalg.lstsq(0.5 * (a + a.T), weight @ solved_g, rcond=1e-12)[0]
        means.append(spread * centred)
        # each unit's curve given the group: mean M^-1 (g~ + m~), covariance M^-1 (scaled)
        posterior = np.linalg.solve(matrix, (gradient + centred[None, :])[..., None])[..., 0]
        spread_sq += weight @ ((posterior - centred[None, :]) ** 2 + np.einsum('upp->up', inverse))
    shares = responsibilities.mean(axis=0)
    return shares, np.array(means), spread * np.sqrt(spread_sq / stats.count)


def mixture(stats: _Stats, count: int, start: Reml, *, seed: int = 0) -> Mixture:
    """``count`` groups by expectation-maximisation from :data:`EM_STARTS` starts (the best likelihood kept)."""
    rng = np.random.default_rng(seed)
    estimates = stats.estimates()
    errors = stats.errors()
    # the units' own estimates, each untold term at the fleet's mean, in units of the spread
    points = np.where(np.isfinite(estimates), estimates, start.mean[None, :]) / np.maximum(start.spread, errors)
    best: Mixture | None = None
    for _ in range(EM_STARTS):
        centres = [points[rng.integers(stats.count)]]
        for _ in range(1, count):  # k-means++
            gaps = np.min([np.sum((points - c) ** 2, axis=1) for c in centres], axis=0)
            centres.append(points[rng.choice(stats.count, p=gaps / gaps.sum()) if gaps.sum() > 0
                                  else rng.integers(stats.count)])
        nearest = np.argmin([np.sum((points - c) ** 2, axis=1) for c in centres], axis=0)
        responsibilities = np.eye(count)[nearest] * 0.9 + 0.1 / count
        spread = start.spread.copy()
        previous = -math.inf
        for _ in range(EM_ITERATIONS):
            weights, means, spread = _m_step(stats, responsibilities, spread)
            spread = np.maximum(spread, SPREAD_RANGE[0] * errors)
            responsibilities, value = _e_step(stats, weights, means, spread)
            if abs(value - previous) <= EM_SETTLED * max(abs(value), 1.0):
                break
            previous = value
        found = Mixture(weights, means, spread, responsibilities, value)
        if best is None or found.log_likelihood > best.log_likelihood:
            best = found
    assert best is not None
    return best


# ----- the prior ------------------------------------------------------------------------------------


def fleet_prior(units: Mapping[str, Information], sensor: str, basis: Basis, *,
                records: Mapping[str, int] | None = None, groups: int = MAX_GROUPS) -> SensorFleet:
    """A sensor's prior from its units' information (see the module's description).

    :param units: per unit its information (any basis; carried to ``basis``; its curve terms taken).
    :param groups: at most this many groups tried (1: one Gaussian).
    :raises FitError: fewer than :data:`MIN_UNITS` units, or no curve term any unit tells.
    """
    if len(units) < MIN_UNITS:
        msg = f'{sensor}: a prior needs {MIN_UNITS} units or more, got {len(units)}'
        raise FitError(msg)
    names_all = sorted({name for info in units.values() for name in info.curve().names},
                       key=lambda n: (curve_term(n)[0], curve_term(n)[1], curve_term(n)[2]))  # type: ignore[index]
    curves = {name: info.curve().in_basis(basis) for name, info in units.items()}
    stats = _Stats.of(list(curves.values()), names_all)
    diagonal = np.einsum('upp->p', stats.hessian)
    told = diagonal > TOLD * np.maximum(np.nanmedian(np.where(diagonal > 0, diagonal, np.nan)), 1e-300)
    told &= np.sum(np.einsum('upp->up', stats.hessian) > 0.0, axis=0) >= MIN_UNITS
    names = tuple(n for n, ok in zip(names_all, told) if ok)
    if not names:
        msg = f'{sensor}: no unit\'s records tell any term of its curve'
        raise FitError(msg)
    unit_names = list(curves)
    stats = _Stats.of([curves[name] for name in unit_names], names)
    fitted = reml(stats)
    keep, fitted, left = screen(stats, names, unit_names, sensor, fitted)
    kept_names = tuple(name for name, ok in zip(unit_names, keep) if ok)
    kept = stats.subset(keep)
    result = [Group(1.0, fitted.mean, fitted.mean_covariance, kept_names)]
    spread, spread_error = fitted.spread, fitted.spread_error
    if groups > 1 and kept.count >= 2 * MIN_GROUP_UNITS:
        one = reml(kept, restricted=False)
        size = len(names)
        best, best_bic = None, one.criterion + 2 * size * math.log(kept.count)
        for count in range(2, groups + 1):
            if kept.count < count * MIN_GROUP_UNITS:
                break
            found = mixture(kept, count, fitted)
            if (found.bic(kept.count) < best_bic - GROUP_BIC
                    and np.all(found.responsibilities.sum(axis=0) >= MIN_GROUP_UNITS)):
                best, best_bic = found, found.bic(kept.count)
        if best is not None:
            result = _groups(kept, best, kept_names)
            spread, spread_error = best.spread, np.full(len(names), np.nan)
    low = min(curves[name].low for name in kept_names)
    high = max(curves[name].high for name in kept_names)
    total = sum((records or {}).get(name, 0) for name in kept_names)
    return SensorFleet(sensor, names, basis, tuple(result), spread, spread_error, kept_names, low, high, total,
                       tuple(left), tuple(n for n, ok in zip(names_all, told) if not ok), fitted.phi)


def _groups(stats: _Stats, found: Mixture, unit_names: Sequence[str]) -> list[Group]:
    """The mixture's groups, each mean's covariance from its units' information (weighted by their shares)."""
    hessian, _, matrix = _scaled(stats, found.spread)
    solved = np.linalg.solve(matrix, hessian)
    out = []
    for k in range(len(found.weights)):
        weight = found.responsibilities[:, k]
        a = np.einsum('u,upq->pq', weight, solved)
        covariance = np.linalg.pinv(0.5 * (a + a.T)) * np.outer(found.spread, found.spread)
        members = tuple(name for name, r in zip(unit_names, weight) if r >= SURE_GROUP)
        out.append(Group(float(found.weights[k]), found.means[k], covariance, members))
    return out


@dataclass(frozen=True)
class Band:
    """A curve's band at temperatures: the prior's mean and its standard deviation (spread and the mean's error)."""

    temperature: np.ndarray
    mean: np.ndarray
    sd: np.ndarray = field(repr=False)


def offset_band(fleet: SensorFleet, axis: str, temperature: np.ndarray, weights: Sequence[float] | None = None) -> Band:
    """The prior's band of an axis's offset curve (its group blend at ``weights``; ``None``: the fleet's)."""
    names = [name for name in fleet.names if name.startswith(f'{axis}.offset')]
    index = [fleet.names.index(name) for name in names]
    mean, covariance = fleet.blend(weights if weights is not None else [g.weight for g in fleet.groups])
    powers = fleet.basis.powers(temperature, len(index) - 1)
    block = covariance[np.ix_(index, index)]
    return Band(np.asarray(temperature, dtype=float), powers @ mean[index],
                np.sqrt(np.einsum('kp,pq,kq->k', powers, block, powers)))
