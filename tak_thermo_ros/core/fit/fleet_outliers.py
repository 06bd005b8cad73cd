"""A unit far outside its fleet (another part, a damaged board): named and left out of the fleet's prior.

:func:`screen`: a unit's distance ``(theta_u - mean)' (S^2 + Cov(mean) + H_u^-1)^-1 (theta_u - mean)``
(the part of it the unit's records tell; :func:`distance`) beyond the chi-square's ``1 - OUTLIER_ALPHA / units``
quantile, confirmed with the fleet fitted without it (:func:`~tak_thermo_ros.core.fit.fleet_reml.reml`),
one unit at a time. What it leaves out: :class:`FarUnit`, in the prior
(:class:`~tak_thermo_ros.core.fit.fleet_prior.SensorFleet`) and its file.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.fit.fleet_reml import MIN_UNITS, Reml, _bounds, _Stats, reml, reml_criterion

OUTLIER_ALPHA = 1e-3
"""A unit is far outside the fleet when a fleet of its kind would put one so far this seldom."""
UPPER_RISE = 3.84
"""A spread's upper bound is where the criterion has risen by this much (the 95 % chi-square of one term)."""
CANDIDATE_Z = 4.0
"""A unit whose estimate of a term lies this many robust spreads from the units' median is tested."""


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
