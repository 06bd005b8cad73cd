"""The REML of a fleet's spread: the units' information, scaled, and one Gaussian's restricted likelihood.

Each unit's records reduce to its information on its curve terms (:class:`~tak_thermo_ros.core.fit.prior.Information`:
``H_u``, ``g_u``, ``c_u``, in one basis; :class:`_Stats` holds them over common names). The units' curves are
drawn around the kind's: ``theta_u ~ N(mean, S^2)``, ``S`` diagonal (per sensor, axis and term: the units'
spread), so a unit's marginal likelihood is Gaussian in closed form, and the restricted maximum likelihood
(REML, the mean integrated out) of ``S`` is::

    -2 log L = sum_u [log|I + H~_u| + c~_u - g~_u' M_u^-1 g~_u] + log|sum_u M_u^-1 H~_u| - 2 log|S|
               - b' (sum_u M_u^-1 H~_u)^-1 b,   H~ = S H S / phi, g~ = S g / phi, M = I + H~, b = sum_u M_u^-1 g~_u

(plus ``sum_u rows_u log phi`` when a common scale ``phi`` of the units' own noise is estimated too:
then this is exactly the REML of the linear mixed model on the units' data, what statsmodels' MixedLM
maximises; a test holds the two together). ``H_u`` may be singular: a unit that never saw the cold
tells nothing about the cold, and says nothing there. Minimised over ``log S`` (and ``log phi``) by
a bounded quasi-Newton search; the spread's standard errors from the criterion's curvature.

The prior assembled from it: :mod:`~tak_thermo_ros.core.fit.fleet_prior`; a unit far outside the fleet:
:mod:`~tak_thermo_ros.core.fit.fleet_outliers`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.fit.prior import Information

MIN_UNITS = 3
"""A prior needs this many units (a spread from two is no spread)."""
SPREAD_RANGE = (1e-4, 1e4)
"""The spread is searched within these multiples of the units' typical error (or of their spread, the larger)."""


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
