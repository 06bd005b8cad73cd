"""A pool of records: each record's turn-on offset as a random effect (:mod:`~tak_thermo_ros.core.fit.random_effects`).

:func:`pooled_accel` and :func:`pooled_gyro` fit a pool's variances by REML (:class:`_Reml`, on
sufficient statistics) and the link in turn; :class:`TurnOnFit` holds each record's offset and
their spread, :func:`with_turn_on` writes it into the calibration's ``turn_on`` section.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from tak_thermo_ros.core.fit.handheld.accel import AccelProblem, fit_accel
from tak_thermo_ros.core.fit.handheld.gyro import GyroProblem, TurnRows, fit_gyro
from tak_thermo_ros.core.fit.handheld.layout import Layout
from tak_thermo_ros.core.fit.handheld.rests import Rests
from tak_thermo_ros.core.fit.handheld.system import Solved, record_robust
from tak_thermo_ros.core.fit.random_effects import RecordStatistics, Variances, absorbed, fit_variances
from tak_thermo_ros.core.link.model import AXES, Calibration
from tak_thermo_ros.core.records.handheld import earth_reference


@dataclass(frozen=True)
class TurnOnFit:
    """A sensor's turn-on offsets over a pool's records (random effects: :mod:`.random_effects`).

    :param variances: per axis the offsets' spread (the repeatability) with its error, and the rests' extra variance.
    :param offsets: ``(r, 3)`` each record's offset (its best linear unbiased prediction), sensor units.
    :param errors: ``(r, 3)`` their standard errors.
    """

    variances: Variances
    offsets: np.ndarray
    errors: np.ndarray


class _Reml:
    """``-2 log REML`` of a pool's variances (:mod:`~tak_thermo_ros.core.fit.random_effects`), on sufficient statistics.

    Only the rests' mean rows and the prior rows change with the variances: the other rows'
    statistics (:class:`~tak_thermo_ros.core.fit.random_effects.RecordStatistics`: the shared
    columns' normal matrix, per record its turn-on columns' blocks) are summed once, the mean rows
    are kept unweighted, split into their shared part and their record's turn-on part (and, for the
    accelerometer, each rest's two direction columns there, eliminated at each evaluation: the one
    combination of the three axes that the rest's unknown tilt leaves, as the fit's projection does).
    Each evaluation sums the weighted mean rows' statistics, integrates every record's turn-on
    offsets out (a small block per record,
    :func:`~tak_thermo_ros.core.fit.random_effects.absorbed`) and takes a Cholesky factor of the
    free shared terms: linear in the records and the rests.

    :param fixed: the statistics of the rows whose weights stay (the rests' other rows, the turns).
    :param mean: ``(k, 3, S + 1)`` the rests' mean rows' shared columns and target, unweighted.
    :param own: ``(k, 3, 3)`` their turn-on columns (the rest's record's, one per axis).
    :param record: ``(k,)`` each rest's record.
    :param samples: ``(k,)`` each rest's samples.
    :param directions: ``(k, 3, 2)`` the accelerometer's direction columns in the mean rows, or ``None``.
    """

    def __init__(self, rests: Rests, fixed: RecordStatistics, mean: np.ndarray, own: np.ndarray, record: np.ndarray,
                 samples: np.ndarray, held: dict[int, float], directions: np.ndarray | None = None) -> None:
        self.rests = rests
        columns = rests.columns
        assert columns is not None
        self.columns = columns
        self.fixed = fixed
        self.shared, self.own = mean, own
        self.record = np.asarray(record, dtype=np.int64)
        self.samples = samples.astype(float)
        self.directions = directions
        layout = rests.layout
        self.determined = turn_on_determined(layout, held)
        self.free = np.array([i for i, j in enumerate(columns.shared[:-1]) if int(j) not in held], dtype=np.int64)
        self.values = np.array([held.get(int(j), 0.0) for j in columns.shared[:-1]] + [-1.0])
        """``[X | y]`` times this: minus the target the held terms leave (held values, -1 on the target)."""
        self.records = len(layout.turn_on(0))

    def __call__(self, turn_on: np.ndarray, rest: np.ndarray) -> float:
        sigma = self.rests.sigma
        variance = sigma[None, :] ** 2 + self.samples[:, None] * np.asarray(rest, dtype=float)[None, :] ** 2
        weight = 1.0 / np.sqrt(variance)
        shared = self.shared * weight[:, :, None]
        own = self.own * weight[:, :, None]
        log_v = float(np.sum(np.log(variance / sigma[None, :] ** 2)))
        if self.directions is None:
            record = np.repeat(self.record, 3)
            shared, own = shared.reshape(-1, shared.shape[2]), own.reshape(-1, own.shape[2])
        else:  # per rest the one combination of the axes that the two direction columns leave
            weighted = self.directions * weight[:, :, None]
            across = np.cross(weighted[:, :, 0], weighted[:, :, 1])
            across /= np.linalg.norm(across, axis=1, keepdims=True)
            record = self.record
            shared, own = np.einsum('ka,kai->ki', across, shared), np.einsum('ka,kai->ki', across, own)
            gram = np.einsum('kai,kaj->kij', weighted, weighted)
            log_v += float(np.sum(np.log(np.maximum(np.linalg.det(gram), 1e-300))))
        statistics = self.fixed + RecordStatistics.of_rows(shared, own, record, self.columns.records)
        precision = np.where(self.determined, 1.0 / np.asarray(turn_on, dtype=float) ** 2, 0.0)
        found = absorbed(statistics, self.determined, precision)
        if found is None:
            return math.inf
        normal, log_own = found
        free, target = self.free, self.values
        # the held terms into the target: [X_f | y - X_h v], v the held values
        cross = -(normal[free] @ target)
        total = float(target @ normal @ target)
        try:
            factor = np.linalg.cholesky(normal[np.ix_(free, free)])
        except np.linalg.LinAlgError:
            return math.inf
        solved = np.linalg.solve(factor, cross)
        rss = total - float(solved @ solved)
        prior = sum(2.0 * self.records * math.log(turn_on[axis]) for axis in np.flatnonzero(self.determined))
        return log_v + prior + log_own + float(2.0 * np.sum(np.log(np.diag(factor)))) + rss


VARIANCE_ROUNDS = 3
"""The variances and the link are refitted in turn at most this many times."""
VARIANCE_SETTLED = 0.05
"""... until no variance moves by more than this fraction."""


def turn_on_fit(solved: Solved, layout: Layout, variances: Variances, records: int) -> TurnOnFit:
    """Each record's offset and its error from a solve, beside the spread."""
    offsets = np.zeros((records, 3))
    errors = np.full((records, 3), np.nan)
    deviations = dict(zip(solved.free, np.sqrt(np.maximum(np.diag(solved.covariance), 0.0))))
    for axis in range(3):
        for record, column in enumerate(layout.turn_on(axis)):
            offsets[record, axis] = solved.theta[column]
            errors[record, axis] = deviations.get(column, np.nan)
    return TurnOnFit(variances, offsets, errors)


def turn_on_determined(layout: Layout, held: dict[int, float]) -> np.ndarray:
    """Per axis whether its turn-on offsets are fitted (not held with the axis's offset)."""
    return np.array([bool(layout.turn_on(axis)) and not all(j in held for j in layout.turn_on(axis))
                     for axis in range(3)])


def _settled(before: np.ndarray, after: np.ndarray) -> bool:
    both = np.isfinite(before) & np.isfinite(after)
    return bool(np.all(np.abs(after[both] - before[both]) <= VARIANCE_SETTLED * np.maximum(np.abs(before[both]),
                                                                                           1e-300)))


def _normal(rows: np.ndarray) -> np.ndarray:
    """The normal matrix ``R^T R`` of rows ``(n, W + 1)``."""
    return rows.T @ rows


def _rests_reml(rests: Rests, design: np.ndarray, slots: np.ndarray, target: np.ndarray, held: dict[int, float],
                extra: np.ndarray | None = None, extra_record: np.ndarray | None = None,
                directions: np.ndarray | None = None) -> _Reml:
    """The REML of a sensor's rests from its unweighted compressed rows apart (:meth:`Rests.split_design`).

    ``extra``: rows already weighted ``(n, W + 1)``, of records ``extra_record``.
    """
    columns = rests.columns
    assert columns is not None
    rows = np.concatenate([design, target[:, :, None]], axis=2)  # (m, 3, S + 1)
    within = (rows[~rests.mean_row] / rests.sigma[None, :, None]).reshape(-1, rows.shape[2])
    records, size = columns.records, len(columns.shared)
    # a rest's rows after its first touch no turn-on column (the constant's column of its factor is 0 there);
    # a prior's rows on the curve terms are fixed rows of no record (shared columns only)
    curve = columns.split(rests.curve_rows, np.full(len(rests.curve_rows), -1))[0]
    fixed = RecordStatistics(_normal(within) + _normal(curve), np.zeros((records, size, 3)),
                             np.zeros((records, 3, 3)))
    if extra is not None and len(extra):
        assert extra_record is not None
        fixed = fixed + RecordStatistics.of_rows(*columns.split(extra, extra_record), extra_record, records)
    mean = rests.mean_row
    return _Reml(rests, fixed, rows[mean], slots[mean], rests.row_record[mean], rests.row_samples[mean], held,
                 None if directions is None else directions[mean])


def pooled_accel(problem: AccelProblem, up: np.ndarray, gauge: dict[int, float],
                 accel: Solved) -> tuple[Solved, np.ndarray, TurnOnFit]:
    """The accelerometer of a pool: its variances by REML and the link, in turn (each REML at the up directions)."""
    previous = np.concatenate([problem.turn_on_sigma, np.sqrt(problem.rest_variance)])
    variances = None
    for _ in range(VARIANCE_ROUNDS):
        design, slots, target = problem.split_design(problem.gravity * up[problem.interval], weighted=False)
        directions, _, _ = problem.direction_columns(accel.theta, up, weighted=False)
        criterion = _rests_reml(problem, design, slots, target, accel.held, directions=directions)
        start = np.sqrt(problem.rest_variance) + 0.1 * problem.sigma
        variances = fit_variances(criterion, problem.turn_on_sigma, start, criterion.determined, problem.sigma)
        problem.turn_on_sigma = np.where(criterion.determined, variances.turn_on, problem.turn_on_sigma)
        problem.rest_variance = variances.rest ** 2
        accel, up = fit_accel(problem, up, gauge)
        current = np.concatenate([problem.turn_on_sigma, variances.rest])
        if _settled(previous, current):
            break
        previous = current
    assert variances is not None
    # an axis seen through the tilts alone (near level: x and y at a tenth of their size) may leave its
    # spread within its own error of 0: the records do not tell it (its offsets stay the fit's random effects)
    told = variances.determined & (variances.turn_on_error < variances.turn_on)
    variances = replace(variances, turn_on=np.where(told, variances.turn_on, np.nan), determined=told)
    accel = record_robust(accel)
    return accel, up, turn_on_fit(accel, problem.layout, variances, len(problem.layout.turn_on(0)))


def pooled_gyro(problem: GyroProblem, gyro: Solved, turns: TurnRows, turn_scale: float,
                held: dict[int, float]) -> tuple[Solved, TurnRows, float, TurnOnFit]:
    """The gyroscope of a pool: its variances by REML (the turns' rows held) and the link, in turn."""
    rests = problem.rests
    previous = np.concatenate([rests.turn_on_sigma, np.sqrt(rests.rest_variance)])
    variances = None
    for _ in range(VARIANCE_ROUNDS):
        force = earth_reference(problem.up, rests.interval, problem.latitude)
        design, slots, target = rests.split_design(force, weighted=False)
        criterion = _rests_reml(rests, design, slots, target, gyro.held, extra=turns.rows,
                                extra_record=problem.turn_row_record)
        variances = fit_variances(criterion, rests.turn_on_sigma, np.sqrt(rests.rest_variance) + 0.1 * rests.sigma,
                                  criterion.determined, rests.sigma)
        rests.turn_on_sigma = np.where(criterion.determined, variances.turn_on, rests.turn_on_sigma)
        rests.rest_variance = variances.rest ** 2
        gyro, turns, turn_scale = fit_gyro(problem, held)
        current = np.concatenate([rests.turn_on_sigma, variances.rest])
        if _settled(previous, current):
            break
        previous = current
    assert variances is not None
    gyro = record_robust(gyro)
    return gyro, turns, turn_scale, turn_on_fit(gyro, problem.layout, variances, len(problem.layout.turn_on(0)))


def with_turn_on(calibration: Calibration, fitted: TurnOnFit, records: int) -> Calibration:
    """The calibration with its ``turn_on`` section when every axis's spread is determined, else a note why not.

    From fewer than :data:`~tak_thermo_ros.core.link.model.MIN_TURN_ON_RECORDS` records the section says
    ``not determined`` (and a note why).
    """
    from tak_thermo_ros.core.link.model import MIN_TURN_ON_RECORDS, TurnOn
    variances = fitted.variances
    if not np.all(variances.determined):
        held = ' '.join(name for name, ok in zip(AXES, variances.determined) if not ok)
        note = f'turn_on not written: the records do not determine the turn-on offset\'s spread on {held}'
        return replace(calibration, notes=(*calibration.notes, note))
    if records < MIN_TURN_ON_RECORDS:  # a spread of so few values is known to orders of magnitude: not written
        turn_on = TurnOn(repeatability=None, repeatability_error=None, records=records)
        note = f'turn_on {turn_on.why_not()}'
        return replace(calibration, turn_on=turn_on, notes=(*calibration.notes, note))
    turn_on = TurnOn(repeatability=tuple(float(v) for v in variances.turn_on),  # type: ignore[arg-type]
                     repeatability_error=tuple(float(e) if np.isfinite(e) else 0.0  # type: ignore[arg-type]
                                               for e in variances.turn_on_error),
                     records=records)
    return replace(calibration, turn_on=turn_on)
