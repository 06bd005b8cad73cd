"""The gyroscope's problem: its rests (the rate known) and its turns (the rows linearised at each step).

A turn from rest ``a`` to rest ``b`` integrates the corrected rate to ``R``, which must carry
``u_b`` onto ``u_a`` (see :mod:`~tak_thermo_ros.core.fit.handheld`): :class:`GyroProblem` gives
the rests' rows once and the turns' whitened rows at a parameter vector; :func:`fit_gyro` runs
Gauss-Newton on them, lowering the turns' weight when they close worse than the noise predicts
(:data:`CHI2_SLACK`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.fit.handheld.layout import Terms, sensor_matrix
from tak_thermo_ros.core.fit.handheld.rests import Rests
from tak_thermo_ros.core.fit.handheld.system import MAX_ITERATIONS, Solved, System, converged, solve, solve_holding
from tak_thermo_ros.core.fit.random_effects import RecordSystem
from tak_thermo_ros.core.records.handheld import HandheldRecord, TurnClosure, closure_terms, earth_reference
from tak_thermo_ros.core.rotation import hat, integrate_segments, tangent_basis


CHUNK_SAMPLES = 20_000
"""Still samples per block of rows (bounded memory)."""


def _inverse(matrix: np.ndarray) -> np.ndarray:
    """The inverses of ``(n, 3, 3)`` matrices by the adjugate (many small systems at once)."""
    adjugate = np.empty_like(matrix)
    for i in range(3):
        for j in range(3):
            rows = [r for r in range(3) if r != j]
            cols = [c for c in range(3) if c != i]
            minor = (matrix[:, rows[0], cols[0]] * matrix[:, rows[1], cols[1]]
                     - matrix[:, rows[0], cols[1]] * matrix[:, rows[1], cols[0]])
            adjugate[:, i, j] = minor if (i + j) % 2 == 0 else -minor
    determinant = np.einsum('ni,ni->n', matrix[:, 0, :], adjugate[:, :, 0])
    return adjugate / determinant[:, None, None]


def _chunks(labels: np.ndarray) -> list[slice]:
    """Slices of whole runs of equal labels, about :data:`CHUNK_SAMPLES` samples each."""
    if not len(labels):
        return []
    starts = np.flatnonzero(np.diff(labels, prepend=labels[0] - 1) != 0)
    edges = [0]
    for start in starts[1:]:
        if start - edges[-1] >= CHUNK_SAMPLES:
            edges.append(int(start))
    edges.append(len(labels))
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]


class GyroProblem:
    """The gyroscope's still samples (linear rows) and turns (rows linearised at each step)."""

    def __init__(self, record: HandheldRecord, interval: np.ndarray, terms: Terms, still_bases: Sequence[np.ndarray],
                 turn_bases: Sequence[np.ndarray], up: np.ndarray, noise: np.ndarray, up_noise: np.ndarray,
                 latitude: float | None, records: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        self.terms = terms
        self.layout = terms.layout()
        self.sigma = np.maximum(np.asarray(noise, dtype=float), 1e-12)
        order = max(terms.bias_order, terms.scale_order)
        still = record.still
        still_record, turn_record = records if records is not None else (None, None)
        self.rests = Rests(still.counts[:, 3:6], still.temp_code, interval, terms, still_bases, noise, still_record)
        self.reference = earth_reference(up, interval, latitude)
        turn = record.turn
        self.turn_record = np.zeros(len(turn), dtype=np.int64) if turn_record is None else turn_record
        self.turn_counts = turn.counts[:, 3:6]
        self.turn_powers = terms.frame.powers(np.clip(turn.temp_code, terms.frame.low, terms.frame.high), order)
        self.turn_bases = turn_bases
        self.turn_stamps = turn.stamp_s
        self.turn_index = record.turn_index
        self.pairs = record.turns
        self.up = up
        self.up_noise = up_noise
        self.latitude = latitude

    def still_system(self) -> System | RecordSystem:
        """The rests' rows (linear: the rate at rest is known), compressed rest by rest."""
        force = earth_reference(self.up, self.rests.interval, self.latitude)
        if self.rests.columns is None:
            design, target = self.rests.design(force)
            return System.of_rows([np.column_stack([design.reshape(-1, self.layout.width), target.reshape(-1)]),
                                   self.rests.prior_rows()], self.layout.width)
        shared, slots, target = self.rests.split_design(force)
        rows = np.concatenate([shared, target[:, :, None]], axis=2).reshape(-1, shared.shape[2] + 1)
        return self.rests.pool_system(rows, slots.reshape(-1, 3), np.repeat(self.rests.row_record, 3))

    @property
    def turn_row_record(self) -> np.ndarray:
        """Each turn row's record (two rows per turn, :meth:`turn_rows`)."""
        record = np.zeros(len(self.pairs), dtype=np.int64)
        record[self.turn_index] = self.turn_record
        return np.repeat(record, 2)

    def rates(self, theta: np.ndarray, rows: slice) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], list]:
        """Some turn samples' corrected rates ``(m, 3)``, ``M(T)^-1``, their powers and bases."""
        powers = [p[rows] for p in self.turn_powers]
        bases = [b[rows] for b in self.turn_bases]
        counts = self.turn_counts[rows]
        designs = self.terms.designs(powers, np.zeros_like(counts), counts, bases, record=self.turn_record[rows])
        # The force columns are zero here: each axis's design times its terms is its offset.
        offsets = np.column_stack([design.matrix @ self.layout.axis_part(theta, axis)
                                   for axis, design in enumerate(designs)])
        inverse = _inverse(sensor_matrix(theta, self.layout, powers, self.terms.scale_order))
        return np.einsum('mab,mb->ma', inverse, counts - offsets), inverse, powers, bases

    def turn_rows(self, theta: np.ndarray, covariance_scale: float = 1.0, *, rows_needed: bool = True) -> TurnRows:
        """Two whitened rows ``[J | J theta - r]`` per turn, and the closure at ``theta``.

        The turns are integrated a block of whole turns at a time (bounded memory).

        :param rows_needed: ``False``: the closure only (the rows are left empty).
        """
        count = len(self.pairs)
        width = self.layout.width
        if not count:
            return TurnRows(np.zeros((0, width + 1)), _no_closure(), np.zeros((0, 2, 2)), np.zeros((0, 3, 2)),
                            np.zeros((0, 3, 3)))
        rotations = np.zeros((count, 3, 3))
        jacobians = np.zeros((len(self.turn_index), 3, 3))
        moved = np.zeros((count, 3, width))
        for rows in _chunks(self.turn_index):
            index = self.turn_index[rows]
            first, local = int(index[0]), int(index[-1] - index[0] + 1)
            rate, inverse, powers, bases = self.rates(theta, rows)
            rotation, jacobian = integrate_segments(rate, self.turn_stamps[rows], index - first, local, jacobian=True)
            rotations[first:first + local] = rotation
            jacobians[rows] = jacobian
            if not rows_needed:
                continue
            designs = self.terms.designs(powers, rate, self.turn_counts[rows], bases, record=self.turn_record[rows])
            # d rate / d theta = -M^-1 D, D block-diagonal by axis: each axis's columns take one column of C M^-1.
            carried = -jacobian @ inverse
            starts = np.flatnonzero(np.diff(index, prepend=-1) != 0)
            for axis, design in enumerate(designs):
                start = self.layout.starts[axis]
                block = carried[:, :, axis, None] * design.matrix[:, None, :]
                moved[index[starts], :, start:start + design.matrix.shape[1]] = np.add.reduceat(block, starts, axis=0)
        terms = closure_terms(rotations, jacobians, self.turn_index, self.pairs, self.up, self.up_noise, self.sigma)
        if not rows_needed:
            return TurnRows(np.zeros((0, width + 1)), terms.closure, np.zeros((0, 2, 2)), terms.basis, rotations)
        basis = terms.basis
        jacobian = -np.einsum('tab,tac,tcw->tbw', basis, hat(terms.carried), moved)
        whitening = np.linalg.cholesky(np.linalg.inv(terms.covariance * covariance_scale))  # L L^T = C^-1
        weight = np.swapaxes(whitening, 1, 2)
        rows_design = weight @ jacobian
        rows_target = np.einsum('tab,tb->ta', weight, np.einsum('tbw,w->tb', jacobian, theta) - terms.residual)
        rows = np.concatenate([rows_design, rows_target[:, :, None]], axis=2).reshape(-1, width + 1)
        closure = terms.closure
        return TurnRows(rows, closure, weight, basis, rotations)

    def frame_covariance(self, turns: TurnRows, solved: Solved, accel: Solved,
                         sensitivity: np.ndarray) -> np.ndarray:
        """What the accelerometer's errors add to the gyroscope's covariance through the up directions.

        The gyroscope's terms are in the frame the accelerometer's fit defines; an error of the
        accelerometer's terms turns the up directions of every interval together (``sensitivity``:
        ``d u_k / d theta_a`` as two tangent angles per interval), which the turns carry into the
        gyroscope's terms: ``S Cov_a S^T`` with ``S = H^-1 J^T W dr/du du/dtheta_a``.
        """
        if not len(self.pairs) or not len(accel.free):
            return np.zeros_like(solved.covariance)
        moved = np.einsum('kab,kbw->kaw', tangent_basis(self.up), sensitivity[:, :, accel.free])  # (k, 3, Wa)
        before, after = self.pairs[:, 0], self.pairs[:, 1]
        change = (np.einsum('tab,taw->tbw', turns.basis, turns.rotations @ moved[after])
                  - np.einsum('tab,taw->tbw', turns.basis, moved[before]))  # d r / d theta_a, (t, 2, Wa)
        target = -(turns.weight @ change).reshape(-1, len(accel.free))
        design = turns.rows[:, :-1][:, solved.free]
        gain = solved.inverse @ (design.T @ target)  # d theta_g / d theta_a
        return gain @ accel.covariance @ gain.T


@dataclass(frozen=True)
class TurnRows:
    """The turns' whitened rows, their closure, and what the frame's error propagation needs."""

    rows: np.ndarray
    closure: TurnClosure
    weight: np.ndarray
    basis: np.ndarray
    rotations: np.ndarray


def _no_closure() -> TurnClosure:
    return TurnClosure(np.zeros(0), np.zeros(0), np.zeros(0))


def fit_gyro(problem: GyroProblem, held: dict[int, float]) -> tuple[Solved, TurnRows, float]:
    """The still rows once, the turn rows again at each Gauss-Newton step.

    When the turns' chi-square exceeds its expectation by more than :data:`CHI2_SLACK` (something
    the model lacks), their weight is lowered by it and the steps go on.

    :returns: the solve, the turns' rows at the last step, the factor on the turns' variance.
    """
    layout = problem.layout
    still = problem.still_system()
    rows, extra = 3 * problem.rests.samples, problem.rests.extra_rss
    start = dict(held)
    start.update({j: (1.0 if kind == 'scale' else 0.0) for j, kind in enumerate(layout.kinds)
                  if kind in ('scale', 'scale_T', 'coupling')})
    theta = solve(still, start, layout.width, rows=rows, extra_rss=extra).theta
    scale = 1.0
    for _ in range(MAX_ITERATIONS):
        turns = problem.turn_rows(theta, scale)
        solved = solve_holding(still.plus(turns.rows, problem.turn_row_record), held, layout, 'gyro',
                               rows=rows + len(turns.rows), extra_rss=extra)
        held = solved.held
        if converged(solved, theta):
            residual = turns.rows[:, :-1] @ solved.theta - turns.rows[:, -1]
            chi2 = float(residual @ residual) / max(len(turns.rows), 1)
            if chi2 <= CHI2_SLACK:
                break
            scale = chi2 * scale
        theta = solved.theta
    return solved, turns, scale


CHI2_SLACK = 1.3
"""The turns' chi-square per row may exceed 1 by this factor before their weight is lowered."""
