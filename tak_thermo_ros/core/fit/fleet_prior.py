"""A fleet's prior: the mean curve of units of one kind and their spread around it, from each unit's information.

Each unit's records reduce to its information on its curve terms (:class:`~tak_thermo_ros.core.fit.prior.Information`:
``H_u``, ``g_u``, ``c_u``, in one basis). The units' curves are drawn around the kind's:
``theta_u ~ N(mean, S^2)``, ``S`` diagonal (per sensor, axis and term: the units' spread), estimated by
the restricted maximum likelihood (:mod:`~tak_thermo_ros.core.fit.fleet_reml`: the criterion, its search,
the spread's errors).

**A unit far outside the fleet** (another part, a damaged board) is named and left out
(:func:`~tak_thermo_ros.core.fit.fleet_outliers.screen`, in :mod:`~tak_thermo_ros.core.fit.fleet_outliers`).

**Groups** (Reginya et al. 2018: 250 MPU-9250 in six clusters of slopes): a mixture of ``K`` Gaussians,
each its own mean, one spread, fitted by expectation-maximisation on the units' information (the
deconvolution of Bovy et al. 2011, "extreme deconvolution", with diagonal spread); ``K`` is kept when
its Bayesian information criterion beats one group's by :data:`GROUP_BIC` and each group holds
:data:`MIN_GROUP_UNITS` units or more. This module assembles the prior (:func:`fleet_prior`: the REML,
the screen, the groups) and draws its band (:func:`offset_band`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from tak_thermo_ros.core.fit.fleet_outliers import FarUnit, screen
from tak_thermo_ros.core.fit.fleet_reml import MIN_UNITS, SPREAD_RANGE, Reml, _marginal, _scaled, _Stats, reml
from tak_thermo_ros.core.fit.prior import Basis, Information, SensorPrior, curve_term
from tak_thermo_ros.errors import FitError

FEW_UNITS = 10
"""A prior from fewer units says so: its spread is known to about ``1 / sqrt(2 (units - 1))`` (a third at 6)."""
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
