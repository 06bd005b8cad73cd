"""The solve with held terms: a sensor's rows as a triangular factor, solved with some terms held.

:class:`System` holds the triangular factor of one record's weighted ``[X | y]``
(:class:`~tak_thermo_ros.core.fit.random_effects.RecordSystem` a pool's); :func:`solve` solves it
with terms held at given values (a pool's linear in its records), :func:`solve_holding` holds
undetermined terms (beyond :data:`BOUNDS`, in the order of :data:`HOLD_ORDER`) until every free one
is determined; :class:`Solved` is what a solve gives. :func:`converged` is the Gauss-Newton
loops' stopping rule (:data:`CONVERGED`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.fit.handheld.layout import Layout
from tak_thermo_ros.core.fit.random_effects import RecordSystem
from tak_thermo_ros.core.fit.solve import BlockedQR, Solution, solve_factor, triangular_factor
from tak_thermo_ros.core.fit.uncertainty import not_below
from tak_thermo_ros.core.link.model import AXES


BOUNDS = {'scale': 0.01, 'scale_T': 0.01, 'coupling': 0.01,
          ('offset', 'accel'): 0.05, ('offset', 'gyro'): 0.005}
"""Largest standard error of a fitted term: scale and its thermal terms 1 %; a coupling 10 mrad;
an offset and its thermal terms 50 mm/s^2 (5 mg) or 5 mrad/s (0.29 deg/s)."""
HOLD_ORDER = ('effect', 'scale_T', 'offset_T', 'coupling', 'scale', 'offset')
"""Which kind of undetermined term is held first."""
NULL_RELATIVE = 1e-9
"""A singular value of the scaled design below this fraction of the largest is a direction the data does not see."""
NULL_LEVERAGE = 0.01
"""A term with this much weight in such a direction is not determined at all."""
MAX_ITERATIONS = 15
CONVERGED = 1e-4
"""Gauss-Newton stops when no parameter moves by more than this fraction of its standard error."""


@dataclass
class System:
    """The triangular factor of the weighted ``[X | y]`` of one sensor's rows, and its row count."""

    factor: np.ndarray
    count: int

    @classmethod
    def of_rows(cls, blocks: Sequence[np.ndarray], width: int) -> System:
        accumulated = BlockedQR(width + 1)
        for block in blocks:
            if len(block):
                accumulated.add(block)
        return cls(accumulated.factor.copy(), accumulated.count)

    def plus(self, rows: np.ndarray, record: np.ndarray | None = None) -> System:
        """The system with more rows (``record``: a pool's rows' records, for :class:`RecordSystem` alike)."""
        if not len(rows):
            return self
        return System(triangular_factor(np.vstack([self.factor, rows]), self.factor.shape[0]),
                      self.count + len(rows))

    def normal(self) -> np.ndarray:
        """``(W + 1, W + 1)``: the normal matrix ``[X | y]^T [X | y]`` of every row."""
        return self.factor.T @ self.factor

    def reduced(self, held: dict[int, float]) -> tuple[System, list[int]]:
        """The system with the held columns' values moved into the target and the columns taken out."""
        width = self.factor.shape[1] - 1
        free = [j for j in range(width) if j not in held]
        target = self.factor[:, -1].copy()
        for j, value in held.items():
            target -= self.factor[:, j] * value
        matrix = np.column_stack([self.factor[:, free], target])
        return System(triangular_factor(matrix, len(free) + 1), self.count), free


@dataclass(frozen=True)
class Solved:
    """A sensor's solve: the full parameter vector, the free parameters' covariance, what was held."""

    theta: np.ndarray
    free: list[int]
    covariance: np.ndarray
    held: dict[int, float]
    solution: Solution
    dof: int
    inverse: np.ndarray
    system: object = field(default=None, repr=False)
    """The system solved (:class:`System` or :class:`RecordSystem`): :attr:`normal` from it."""
    variance: float = 0.0
    """The residual variance scale of the rows (the free terms' covariance is it times the inverse)."""
    widening: np.ndarray | None = None
    """Per free term how far :func:`record_robust` widened its variance (``None``: not applied)."""

    @property
    def normal(self) -> np.ndarray:
        """The normal matrix of the whole ``[X | y]`` (held columns too, ``(W + 1, W + 1)``): the link's uncertainty."""
        return self.system.normal()  # type: ignore[attr-defined]

    def errors(self, layout: Layout) -> dict[str, float]:
        deviations = np.sqrt(np.maximum(np.diag(self.covariance), 0.0))
        return {layout.names[j]: float(deviation) for j, deviation in zip(self.free, deviations)}


def solve(system: System, held: dict[int, float], width: int, *, rows: int | None = None,
          extra_rss: float = 0.0) -> Solved:
    """Solve with ``held`` fixed; the covariance of the free terms scaled by the weighted residual.

    :param rows: the degrees of freedom before the free terms (default the system's rows; a
        compressed system gives its samples' rows less the directions eliminated).
    :param extra_rss: residual the compression left out.
    """
    if isinstance(system, RecordSystem):
        return _solve_pool(system, held, width, rows=rows, extra_rss=extra_rss)
    reduced, free = system.reduced(held)
    theta = np.zeros(width)
    for j, value in held.items():
        theta[j] = value
    if not free:  # everything held: nothing to solve
        nothing = np.zeros((0, 0))
        solution = Solution(np.zeros(0), nothing, np.zeros(0), float(reduced.factor[-1, -1] ** 2), 0, np.zeros(0))
        return Solved(theta, free, nothing, dict(held), solution, max(system.count, 1), nothing, system)
    solution = solve_factor(reduced.factor, max(reduced.count, 1))
    theta[free] = solution.coefficients
    dof = max((system.count if rows is None else rows) - len(free), 1)
    variance = (solution.rss + extra_rss) / dof
    inverse, null_leverage = _inverses(solution)
    covariance = variance * inverse
    covariance[np.diag_indices_from(covariance)] = np.where(null_leverage > NULL_LEVERAGE, np.inf,
                                                            np.diag(covariance))
    return Solved(theta, free, covariance, dict(held), solution, dof, inverse, system, variance)


def _inverses(solution: Solution) -> tuple[np.ndarray, np.ndarray]:
    """``(X^T X)^-1`` of a solve and each column's weight in the directions it does not see.

    In the raw columns' units; the directions the solve does not see (:data:`NULL_RELATIVE`) left out.
    """
    singular = solution.singular
    _, _, vt = np.linalg.svd(solution.scaled)
    keep = singular > NULL_RELATIVE * singular[0] if len(singular) else np.zeros(0, dtype=bool)
    inverse = (vt[keep].T / singular[keep] ** 2) @ vt[keep]
    return inverse / np.outer(solution.norms, solution.norms), np.sum(vt[~keep] ** 2, axis=0)


def _solve_pool(system: RecordSystem, held: dict[int, float], width: int, *, rows: int | None,
                extra_rss: float) -> Solved:
    """:func:`solve` of a pool's system: the shared terms from the records' columns absorbed, then each record's.

    The same solution and covariance as one factor of the whole design, in time linear in the records:
    per record ``u_r = P_r^-1 (q_r - C_r beta)``; its covariance ``P_r^-1 P_r^-T + G_r V G_r^T`` with
    ``G_r = P_r^-1 C_r`` and ``V`` the shared terms', ``-G_r V`` with them, ``G_r V G_s^T`` between records.
    """
    theta = np.zeros(width)
    for j, value in held.items():
        theta[j] = value
    free = [j for j in range(width) if j not in held]
    pool = system.absorbed(held)
    solution = solve_factor(pool.factor, max(system.count, 1))
    theta[pool.shared] = solution.coefficients
    own = system.columns.own[:, pool.slots]  # (r, k')
    gain = np.linalg.solve(pool.pivot, pool.coupling) if own.size else np.zeros((len(own), 0, len(pool.shared)))
    if own.size:
        theta[own] = np.linalg.solve(pool.pivot, pool.target[:, :, None])[:, :, 0] - gain @ solution.coefficients
    dof = max((system.count if rows is None else rows) - len(free), 1)
    variance = (solution.rss + extra_rss) / dof
    shared_inverse, leverage = _inverses(solution)
    across = gain.reshape(-1, len(pool.shared))  # (r k', S')
    pivot_inverse = np.linalg.inv(pool.pivot) if own.size else np.zeros((len(own), 0, 0))
    inverse = np.zeros((len(free), len(free)))
    where = {j: i for i, j in enumerate(free)}
    shared_at = np.array([where[int(j)] for j in pool.shared], dtype=np.int64)
    own_at = np.array([where[int(j)] for j in own.ravel()], dtype=np.int64)
    inverse[np.ix_(shared_at, shared_at)] = shared_inverse
    carried = across @ shared_inverse
    inverse[np.ix_(own_at, shared_at)] = -carried
    inverse[np.ix_(shared_at, own_at)] = -carried.T
    between = carried @ across.T
    size = own.shape[1]
    for record, block in enumerate(pivot_inverse @ np.swapaxes(pivot_inverse, 1, 2)):
        between[record * size:(record + 1) * size, record * size:(record + 1) * size] += block
    inverse[np.ix_(own_at, own_at)] = between
    covariance = variance * inverse
    unseen = np.zeros(len(free), dtype=bool)
    unseen[shared_at] = leverage > NULL_LEVERAGE
    covariance[np.diag_indices_from(covariance)] = np.where(unseen, np.inf, np.diag(covariance))
    return Solved(theta, free, covariance, dict(held), solution, dof, inverse, system, variance)


def _bound(kind: str, sensor: str) -> float:
    if kind in ('offset', 'offset_T'):
        return BOUNDS['offset', sensor]
    return BOUNDS.get(kind, math.inf)


def _holds(solved: Solved, layout: Layout, sensor: str) -> dict[int, float]:
    """More terms to hold: the undetermined ones of the first kind in :data:`HOLD_ORDER` that has any."""
    deviations = np.sqrt(np.diag(solved.covariance))
    failing = [j for j, deviation in zip(solved.free, deviations)
               if not deviation <= _bound(layout.kinds[j], sensor)]
    for kind in HOLD_ORDER:
        chosen = [j for j in failing if layout.kinds[j] == kind]
        if chosen:
            return {j: (1.0 if kind == 'scale' else 0.0) for j in chosen}
    return {}


def solve_holding(system: System, held: dict[int, float], layout: Layout, sensor: str, *,
                  rows: int | None = None, extra_rss: float = 0.0) -> Solved:
    """:func:`solve`, holding undetermined terms until every free one is determined.

    An axis whose offset is held holds its records' turn-on offsets too (the records cannot tell them).
    """
    held = dict(held)
    while True:
        solved = solve(system, held, layout.width, rows=rows, extra_rss=extra_rss)
        more = _holds(solved, layout, sensor)
        for axis, name in enumerate(AXES):
            if layout.index(f'{name}.offset') in {**held, **more}:
                more.update({j: 0.0 for j in layout.turn_on(axis) if j not in held})
        if not more:
            return solved
        held.update(more)


MIN_ROBUST_RECORDS = 5
"""A pool of fewer records keeps the model's covariance alone (a scatter over so few records says little)."""


def record_robust(solved: Solved) -> Solved:
    """A pool's solve with its shared terms' covariance not below what leaving each record out says.

    The model weighs each rest's mean as independent of the record's other rests but for the
    record's turn-on offset; a bias that wanders within a power-up (its random walk, its
    instability) moves a record's rests together, and a curve fitted through them is off by more
    than the model's covariance states (on simulated months 1.7-2.0x in RMS: ``bench/bench_curve_coverage.py``).
    The records are independent of each other, so how far the shared terms move when one record
    is left out measures it whatever the correlation within a record (the delete-one-record
    jackknife; exact one-step for least squares)::

        d_r = (A - S_r)^-1 g_r,   V = (r - 1) / r  sum_r (d_r - mean d)(d_r - mean d)^T

    with ``A`` the shared terms' information (the records' own columns absorbed: the inverse of the
    solve's :attr:`Solved.inverse` there), ``S_r`` record ``r``'s share of it and ``g_r = X_r^T (y_r - X_r
    theta)`` its score at the solution, both from its triangular factor (``X_r^T X_r = R_r^T R_r``; its
    turns and its turn-on prior row included). Unlike the plain cluster sandwich it does not
    understate the terms a few records carry (a curve's edge that few records reached). The shared
    terms keep the model's covariance plus the positive part of ``V`` less it: never below the
    model's, raised along the directions the records say it is short. A system of one record, or
    of fewer than :data:`MIN_ROBUST_RECORDS`, is returned as it is.
    """
    system = solved.system
    if not isinstance(system, RecordSystem) or system.columns.records < MIN_ROBUST_RECORDS or not solved.free:
        return solved
    columns = system.columns
    records, slots = columns.records, columns.slots
    where = {j: i for i, j in enumerate(solved.free)}
    finite = np.isfinite(np.diag(solved.covariance))
    shared_local = [slots + m for m, j in enumerate(columns.shared[:-1]) if int(j) in where and finite[where[int(j)]]]
    shared = np.array([where[int(columns.shared[m - slots])] for m in shared_local], dtype=np.int64)
    if not len(shared):
        return solved
    information = np.linalg.pinv(solved.inverse[np.ix_(shared, shared)], hermitian=True)
    values = np.append(solved.theta, -1.0)
    moves = np.zeros((records, len(shared)))
    for record in range(records):
        factor = system.factors[record]
        index = np.concatenate([columns.own[record], columns.shared])
        score = -factor[:, :-1].T @ (factor @ values[index])
        normal = factor.T @ factor
        own = [m for m in range(slots) if int(columns.own[record, m]) in where]
        share = normal[np.ix_(shared_local, shared_local)]
        if own:  # the record's own offsets absorbed: its share of the shared terms' information
            across = normal[np.ix_(own, shared_local)]
            share = share - across.T @ np.linalg.solve(normal[np.ix_(own, own)], across)
        moves[record] = np.linalg.lstsq(information - share, score[shared_local], rcond=1e-12)[0]
    moves -= moves.mean(axis=0)
    robust = (records - 1.0) / records * (moves.T @ moves)
    covariance = solved.covariance.copy()
    covariance[np.ix_(shared, shared)] = not_below(covariance[np.ix_(shared, shared)], robust)
    before = np.diag(solved.covariance)
    widening = np.where(before > 0.0, np.diag(covariance) / np.where(before > 0.0, before, 1.0), 1.0)
    return replace(solved, covariance=covariance, widening=widening)


def converged(solved: Solved, previous: np.ndarray) -> bool:
    """No free term moved by more than :data:`CONVERGED` of its standard error."""
    deviations = np.sqrt(np.maximum(np.diag(solved.covariance), 1e-300))
    moved = np.abs(solved.theta[solved.free] - previous[solved.free]) / deviations
    return not len(moved) or float(np.max(moved)) < CONVERGED
