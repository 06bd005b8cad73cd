"""The accelerometer's problem: gravity along each rest's unknown up direction.

At rest ``N_s = M(T_s) g u_k + b(T_s) + noise`` (see :mod:`~tak_thermo_ros.core.fit.handheld`):
:class:`AccelProblem` gives the rows with each rest's two direction columns projected out,
:func:`fit_accel` runs Gauss-Newton on the terms and the up directions together, the couplings of
:data:`GAUGE` held.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from tak_thermo_ros.core.fit.handheld.layout import Terms, sensor_matrix
from tak_thermo_ros.core.fit.handheld.rests import Rests
from tak_thermo_ros.core.fit.handheld.system import MAX_ITERATIONS, Solved, System, converged, solve_holding
from tak_thermo_ros.core.fit.random_effects import RecordSystem
from tak_thermo_ros.core.rotation import tangent_basis


GAUGE = ('c_xy', 'c_xz', 'c_yz')
"""The accelerometer's couplings held at zero: the corrected axes' frame (see the package's description)."""


def _segments(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Starts of the runs of equal labels (non-decreasing) and each sample's run."""
    starts = np.flatnonzero(np.diff(labels, prepend=labels[0] - 1) != 0)
    run = np.cumsum(np.diff(labels, prepend=labels[0]) != 0)
    return starts, run


class AccelProblem(Rests):
    """The accelerometer's rests (:class:`Rests`): the input is gravity along each rest's unknown up direction."""

    def __init__(self, counts: np.ndarray, temperature: np.ndarray, interval: np.ndarray, terms: Terms,
                 bases: Sequence[np.ndarray], gravity: float, noise: np.ndarray,
                 record: np.ndarray | None = None) -> None:
        super().__init__(counts, temperature, interval, terms, bases, noise, record)
        self.gravity = gravity

    def rows(self, theta: np.ndarray, up: np.ndarray, *, weighted: bool = True
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The weighted design ``(m, 3, W)``, target ``(m, 3)``, direction columns ``(m, 3, 2)``.

        And each row's run (of equal intervals, from 0) and each run's interval.
        """
        design, target = self.design(self.gravity * up[self.interval], weighted=weighted)
        return (design, target, *self.direction_columns(theta, up, weighted=weighted))

    def direction_columns(self, theta: np.ndarray, up: np.ndarray, *, weighted: bool = True
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`rows`' direction columns ``(m, 3, 2)``, each row's run and each run's interval."""
        tangent = tangent_basis(up)[self.interval] * self.gravity  # (m, 3, 2)
        matrix = sensor_matrix(theta, self.layout, self.powers, self.terms.scale_order)
        diagonal = np.einsum('maa->ma', matrix)
        couplings = matrix[0] - np.diag(np.diag(matrix[0])) if len(matrix) else np.zeros((3, 3))
        directions = (diagonal[:, :, None] * tangent
                      + self.regressors[:, 0, None, None] * np.einsum('il,mlb->mib', couplings, tangent))
        if weighted:
            directions = directions * self.weights[:, :, None]
        starts, run = _segments(self.interval)
        return directions, run, self.interval[starts]

    def system(self, theta: np.ndarray, up: np.ndarray) -> System | RecordSystem:
        if self.columns is None:
            design, target, directions, run, _ = self.rows(theta, up)
            projected = _project(directions, run, design, target)
            return System.of_rows([np.column_stack([projected[0].reshape(-1, self.layout.width),
                                                    projected[1].reshape(-1)]), self.prior_rows()], self.layout.width)
        # a pool: its design apart, the records' turn-on columns projected like the others (linear in the records)
        shared, slots, target = self.split_design(self.gravity * up[self.interval])
        directions, run, _ = self.direction_columns(theta, up)
        size = shared.shape[2]
        projected, target = _project(directions, run, np.concatenate([shared, slots], axis=2), target)
        rows = np.concatenate([projected[:, :, :size], target[:, :, None]], axis=2).reshape(-1, size + 1)
        return self.pool_system(rows, projected[:, :, size:].reshape(-1, 3), np.repeat(self.row_record, 3))

    def sensitivity(self, theta: np.ndarray, up: np.ndarray) -> np.ndarray:
        """``(k, 2, W)``: how each interval's best up direction (two tangent angles) moves with the terms."""
        out = np.zeros((self.count, 2, self.layout.width))
        design, _, directions, run, owners = self.rows(theta, up)
        starts = np.flatnonzero(np.diff(run, prepend=-1) != 0)
        q1, q2, factor = _orthonormal(directions, run)
        along = np.stack([np.add.reduceat(np.einsum('ma,maw->mw', q, design), starts, axis=0)
                          for q in (q1, q2)], axis=1)
        out[owners] = -np.linalg.solve(factor, along)
        return out

    def directions(self, theta: np.ndarray, up: np.ndarray) -> np.ndarray:
        """The up directions after one Gauss-Newton step given ``theta``."""
        new_up = up.copy()
        directions, run, owners = self.direction_columns(theta, up)
        if self.columns is None:
            design, target = self.design(self.gravity * up[self.interval])
            fitted = design @ theta
        else:
            design, slots, target = self.split_design(self.gravity * up[self.interval])
            fitted = self.shared_theta(theta, design, slots)
        step = _interval_step(directions, run, target - fitted)
        moved = up[owners] + np.einsum('kab,kb->ka', tangent_basis(up[owners]), step)
        new_up[owners] = moved / np.linalg.norm(moved, axis=1, keepdims=True)
        return new_up


def _orthonormal(directions: np.ndarray, run: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per run, an orthonormal basis ``q1, q2`` ``(m, 3)`` of the two direction columns, and ``R`` ``(r, 2, 2)``."""
    starts = np.flatnonzero(np.diff(run, prepend=-1) != 0)

    def total(values: np.ndarray) -> np.ndarray:
        return np.add.reduceat(values, starts, axis=0)

    first, second = directions[..., 0], directions[..., 1]
    norm1 = np.sqrt(total(np.sum(first * first, axis=1)))
    q1 = first / norm1[run][:, None]
    cross = total(np.sum(q1 * second, axis=1))
    rest = second - q1 * cross[run][:, None]
    norm2 = np.sqrt(total(np.sum(rest * rest, axis=1)))
    q2 = rest / norm2[run][:, None]
    factor = np.zeros((len(starts), 2, 2))
    factor[:, 0, 0], factor[:, 0, 1], factor[:, 1, 1] = norm1, cross, norm2
    return q1, q2, factor


def _project(directions: np.ndarray, run: np.ndarray, design: np.ndarray, target: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """The rows with each run's two direction columns projected out (the directions eliminated)."""
    starts = np.flatnonzero(np.diff(run, prepend=-1) != 0)
    q1, q2, _ = _orthonormal(directions, run)
    for q in (q1, q2):
        coefficient = np.add.reduceat(np.einsum('ma,maw->mw', q, design), starts, axis=0)
        design = design - q[:, :, None] * coefficient[run][:, None, :]
        along = np.add.reduceat(np.sum(q * target, axis=1), starts)
        target = target - q * along[run][:, None]
    return design, target


def _interval_step(directions: np.ndarray, run: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """Per run the two-angle step that best explains the residual by the direction columns."""
    starts = np.flatnonzero(np.diff(run, prepend=-1) != 0)
    q1, q2, factor = _orthonormal(directions, run)
    along = np.column_stack([np.add.reduceat(np.sum(q * residual, axis=1), starts) for q in (q1, q2)])
    return np.linalg.solve(factor, along[:, :, None])[:, :, 0]


def fit_accel(problem: AccelProblem, up: np.ndarray, held: dict[int, float]) -> tuple[Solved, np.ndarray]:
    """Gauss-Newton on the accelerometer's terms and the up directions; holds grow while terms are undetermined.

    :returns: the solve and the up directions.
    """
    layout = problem.layout
    theta = layout.initial()
    for j, value in held.items():
        theta[j] = value
    dof = 3 * problem.samples - 2 * problem.count
    for _ in range(MAX_ITERATIONS):
        solved = solve_holding(problem.system(theta, up), held, layout, 'accel', rows=dof,
                               extra_rss=problem.extra_rss)
        held = solved.held
        up = problem.directions(solved.theta, up)
        if converged(solved, theta):
            break
        theta = solved.theta
    return solved, up
