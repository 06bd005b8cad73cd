"""One solve: the linear least squares of a design, in memory or from its triangular factor.

Every fit of :mod:`tak_thermo_ros.core.fit` ends here: the paper's model alone, with the
effects' columns, or over a run that arrives in blocks. The columns are scaled to unit RMS
before the solve (the temperature powers and the effects' signals differ by orders of
magnitude), and the coefficients are scaled back. In memory the design goes to
``np.linalg.lstsq``; over blocks the triangular factor ``R`` of ``[X | y]`` is accumulated by a
tall-skinny QR (:class:`BlockedQR`, never forming ``X^T X``) and solved by :func:`solve_factor`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

SEPARATION = 1e-9
"""Smallest ratio of the scaled design's least to largest singular value that the paper's model accepts."""


@dataclass(frozen=True)
class Solution:
    """The least-squares solution of one axis.

    :param coefficients: per column, in the raw columns' units.
    :param scaled: the design with unit-RMS columns (in memory: ``(k, c)``; from a factor: its ``R``).
    :param norms: the RMS of each raw column (``coefficients * norms`` solves the scaled design).
    :param rss: residual sum of squares.
    :param rank: numerical rank of the scaled design.
    :param singular: its singular values, largest first.
    """

    coefficients: np.ndarray
    scaled: np.ndarray
    norms: np.ndarray
    rss: float
    rank: int
    singular: np.ndarray

    @property
    def width(self) -> int:
        """Number of columns."""
        return len(self.norms)

    def full_rank(self) -> bool:
        """Whether every column is determined."""
        return self.rank >= self.width

    def separated(self) -> bool:
        """Full rank, and no direction determined less than :data:`SEPARATION` of the best one."""
        return self.full_rank() and not self.singular[-1] < SEPARATION * self.singular[0]

    def without_design(self) -> Solution:
        """This solution without the scaled design (which may hold millions of rows), to keep."""
        return replace(self, scaled=self.scaled[:0])

    def first_dependent(self, names: Sequence[str]) -> str:
        """The name of the first column that makes the design rank-deficient."""
        for end in range(1, self.width + 1):
            if np.linalg.matrix_rank(self.scaled[:, :end]) < end:
                return names[end - 1]
        return names[-1]


def unit_norms(columns: np.ndarray, count: int | None = None) -> np.ndarray:
    """RMS of each column over ``count`` rows (default: the rows given); 1 for a zero column.

    From a triangular factor ``R`` pass the run's sample count: ``sum R^2`` over a column is its
    sum of squares over the run.
    """
    if count is None:
        norms = np.sqrt(np.mean(columns ** 2, axis=0))
    else:
        norms = np.sqrt(np.sum(columns ** 2, axis=0) / count)
    norms[norms == 0.0] = 1.0
    return norms


def least_squares(design: np.ndarray, target: np.ndarray, *, in_place: bool = True) -> Solution:
    """Solve ``design @ x ~ target`` in memory.

    :param in_place: scale ``design`` in place (it is not kept raw): a 15-hour run at 100 Hz has
        5.4 million rows, and each copy of the design matrix costs 300 MB. ``False`` keeps it, and
        the residual is then that of the raw columns, ``target - design @ coefficients``.
    """
    norms = unit_norms(design)
    if in_place:
        design /= norms
        scaled = design
    else:
        scaled = design / norms
    solution, _, rank, singular = np.linalg.lstsq(scaled, target, rcond=None)
    coefficients = solution / norms
    residual = target - scaled @ solution if in_place else target - design @ coefficients
    return Solution(coefficients=coefficients, scaled=scaled, norms=norms, rss=float(residual @ residual),
                    rank=int(rank), singular=singular)


def solve_factor(factor: np.ndarray, count: int) -> Solution:
    """Solve from the triangular factor ``R`` of ``[X | y]`` over ``count`` rows (:class:`BlockedQR`)."""
    triangle, target = factor[:-1, :-1], factor[:-1, -1]
    width = triangle.shape[1]
    norms = unit_norms(triangle, count)
    scaled = triangle / norms
    singular = np.linalg.svd(scaled, compute_uv=False)
    rank = int(np.count_nonzero(singular > np.finfo(float).eps * max(count, width) * singular[0]))
    solution = np.linalg.lstsq(scaled, target, rcond=None)[0]
    rss = float(factor[-1, -1] ** 2 + np.sum((scaled @ solution - target) ** 2))
    return Solution(coefficients=solution / norms, scaled=scaled, norms=norms, rss=rss, rank=rank,
                    singular=singular)


def triangular_factor(rows: np.ndarray, size: int) -> np.ndarray:
    """The triangular factor ``R`` of ``rows`` ``(k, c)`` as ``size`` rows (zero rows below when ``k < size``)."""
    factor = np.linalg.qr(rows, mode='r')
    if factor.shape[0] < size:
        factor = np.vstack([factor, np.zeros((size - factor.shape[0], factor.shape[1]))])
    return factor[:size]


class BlockedQR:
    """The triangular factor ``R`` of ``[X | y]``, accumulated block by block: ``R <- qr([R; block])``.

    As accurate as a QR of the whole design, in memory that does not grow with the rows.

    :param width: columns of ``[X | y]``.
    """

    def __init__(self, width: int) -> None:
        self.width = width
        self.factor = np.zeros((width, width))
        self.count = 0

    def add(self, block: np.ndarray) -> None:
        """Add rows ``(k, width)`` of ``[X | y]``."""
        self.factor = triangular_factor(np.vstack([self.factor, block]), self.width)
        self.count += len(block)

    def change_columns(self, change: np.ndarray) -> None:
        """Carry ``R`` over to the columns ``[X | y] @ change`` (``change`` upper triangular: ``R`` stays so)."""
        self.factor = self.factor @ change

    def solution(self) -> Solution:
        """The least-squares solution of ``X x ~ y`` over every row added."""
        return solve_factor(self.factor, self.count)
