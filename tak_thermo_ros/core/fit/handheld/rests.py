"""A sensor's still samples compressed rest by rest (:class:`Rests`): the rows both sensors' problems start from."""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.effects import CrossAxis
from tak_thermo_ros.core.fit.handheld.layout import Terms, joint
from tak_thermo_ros.core.fit.random_effects import TURN_ON, RecordColumns, RecordSystem


class Rests:
    """A sensor's still samples, compressed rest by rest.

    Within a rest the input (gravity along the rest's up direction, or the rate at rest) is
    constant, so each axis's model is linear in the temperature powers and the effects' basis
    signals there: the rest's samples are replaced by the triangular factor of
    ``[powers | bases | N]`` (a few rows instead of hundreds), which gives the same least squares
    for any parameters and input. Its rows go through :meth:`Terms.designs` like samples; the
    couplings' columns (constant over a rest) take the factor's first column (that of the
    constant power).

    A pool's records (``record``: each sample's) add their turn-on offsets' columns, constant over
    a rest like the couplings, with a prior row each (:meth:`prior_rows`, the spread
    ``turn_on_sigma``); each rest's mean row (the first of its factor, along the constant) is
    weighted by ``1 / sqrt(s^2 + n t^2)`` with ``t^2`` the rests' extra variance ``rest_variance``
    (:mod:`~tak_thermo_ros.core.fit.random_effects`).
    """

    def __init__(self, counts: np.ndarray, temperature: np.ndarray, interval: np.ndarray, terms: Terms,
                 bases: Sequence[np.ndarray], noise: np.ndarray, record: np.ndarray | None = None) -> None:
        self.terms = terms
        self.sigma = np.maximum(np.asarray(noise, dtype=float), 1e-12)
        self.turn_on_sigma = np.full(3, np.inf)
        self.rest_variance = np.zeros(3)
        self.layout = terms.layout()
        self.curve_rows = np.zeros((0, self.layout.width + 1))
        """A prior's rows on the curve terms (:meth:`~tak_thermo_ros.core.fit.prior.CurvePrior.rows`)."""
        self.count = int(interval.max()) + 1 if len(interval) else 0
        self.orders = max(terms.bias_order, terms.scale_order) + 1
        self.widths = [basis.shape[1] for basis in bases]
        regressors = np.column_stack([*terms.frame.powers(temperature, self.orders - 1), *bases])
        inner = regressors.shape[1]
        starts = np.flatnonzero(np.diff(interval, prepend=-1) != 0)
        ends = np.append(starts[1:], len(interval))
        factors, owners, remainder = [], [], np.zeros(3)
        records, sizes, means = [], [], []
        record = np.zeros(len(interval), dtype=np.int64) if record is None else np.asarray(record, dtype=np.int64)
        for start, end in zip(starts, ends):
            factor = np.linalg.qr(np.column_stack([regressors[start:end], counts[start:end]]), mode='r')
            kept = min(len(factor), inner)
            factors.append(factor[:kept])
            owners.append(np.full(kept, interval[start]))
            records.append(np.full(kept, record[start]))
            sizes.append(np.full(kept, end - start))
            means.append(np.arange(kept) == 0)
            remainder += np.sum(factor[kept:, inner:] ** 2, axis=0)
        compressed = np.vstack(factors) if factors else np.zeros((0, inner + 3))
        self.regressors = compressed[:, :inner]
        self.counts = compressed[:, inner:]
        self.interval = np.concatenate(owners) if owners else np.zeros(0, dtype=np.int64)
        self.row_record = np.concatenate(records) if records else np.zeros(0, dtype=np.int64)
        self.row_samples = np.concatenate(sizes) if sizes else np.zeros(0, dtype=np.int64)
        self.mean_row = np.concatenate(means) if means else np.zeros(0, dtype=bool)
        self.remainder = remainder
        self.samples = len(interval)
        pooled = len(self.layout.turn_on(0)) > 0
        self.columns = (RecordColumns(np.array([self.layout.turn_on(axis) for axis in range(3)]).T, self.layout.width)
                        if pooled else None)
        """A pool's turn-on columns apart (:class:`RecordColumns`), ``None`` for one record."""
        self.shared_terms = replace(terms, records=1)
        """The terms without the records' columns: a pool's shared columns, in the layout's order."""
        self.shared_layout = self.shared_terms.layout()

    def pool_system(self, shared: np.ndarray, slots: np.ndarray, record: np.ndarray) -> RecordSystem:
        """A pool's :class:`RecordSystem` of rows given apart (``[X_s | y]``, the turn-on slots) and the prior rows.

        The prior rows: a turn-on column's (:meth:`prior_rows`' first part) and a prior's on the curve terms.
        """
        assert self.columns is not None
        system = RecordSystem(self.columns)
        system.add_split(shared, slots, record)
        finite = np.isfinite(self.turn_on_sigma)
        system.add_prior(np.where(finite, 1.0 / np.where(finite, self.turn_on_sigma, 1.0), 0.0))
        system.add(self.curve_rows, np.full(len(self.curve_rows), -1))  # a prior's rows: no record's
        return system

    @property
    def weights(self) -> np.ndarray:
        """``(m, 3)`` each compressed row's weight per axis: ``1 / s``, a rest's mean row ``1 / sqrt(s^2 + n t^2)``."""
        extra = np.where(self.mean_row, self.row_samples, 0)[:, None] * self.rest_variance[None, :]
        return 1.0 / np.sqrt(self.sigma[None, :] ** 2 + extra)

    def prior_rows(self) -> np.ndarray:
        """``(k, W + 1)`` a row ``u_r / s_u = 0`` per turn-on column (none for one record, or held), a prior's rows."""
        rows = []
        for axis in range(3):
            for column in self.layout.turn_on(axis):
                if not np.isfinite(self.turn_on_sigma[axis]):
                    continue
                row = np.zeros(self.layout.width + 1)
                row[column] = 1.0 / self.turn_on_sigma[axis]
                rows.append(row)
        return np.vstack([np.array(rows).reshape(-1, self.layout.width + 1), self.curve_rows])

    @property
    def powers(self) -> list[np.ndarray]:
        """The compressed rows' temperature powers ``u^0 .. u^m``."""
        return [self.regressors[:, j] for j in range(self.orders)]

    def design(self, force: np.ndarray, *, weighted: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """The weighted design ``(m, 3, W)`` and target ``(m, 3)`` for the input ``force`` ``(m, 3)`` per row."""
        edges = np.cumsum([self.orders, *self.widths])
        bases = [self.regressors[:, a:b] for a, b in zip(edges[:-1], edges[1:])]
        designs = self.terms.designs(self.powers, force, self.counts, bases, record=self.row_record)
        constant = self.regressors[:, 0]
        for design in designs:
            coupling = [c for c, label in enumerate(design.columns)
                        if label.effect == CrossAxis.name or label.term == TURN_ON]
            design.matrix[:, coupling] *= constant[:, None]
        weights = self.weights if weighted else np.ones((len(self.counts), 3))
        return joint(designs, self.layout) * weights[:, :, None], self.counts * weights

    def split_design(self, force: np.ndarray, *, weighted: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A pool's :meth:`design` apart: no column per record (linear in the records).

        :returns: ``(m, 3, S)`` the shared columns, ``(m, 3, 3)`` the row's record's turn-on columns (one
            per axis), the target ``(m, 3)``.
        """
        edges = np.cumsum([self.orders, *self.widths])
        bases = [self.regressors[:, a:b] for a, b in zip(edges[:-1], edges[1:])]
        designs = self.shared_terms.designs(self.powers, force, self.counts, bases)
        constant = self.regressors[:, 0]
        for design in designs:
            coupling = [c for c, label in enumerate(design.columns) if label.effect == CrossAxis.name]
            design.matrix[:, coupling] *= constant[:, None]
        weights = self.weights if weighted else np.ones((len(self.counts), 3))
        slots = np.zeros((len(constant), 3, 3))
        slots[:, [0, 1, 2], [0, 1, 2]] = constant[:, None] * weights  # an axis's turn-on offset: constant
        return joint(designs, self.shared_layout) * weights[:, :, None], slots, self.counts * weights

    def shared_theta(self, theta: np.ndarray, design: np.ndarray, slots: np.ndarray) -> np.ndarray:
        """``design @ theta`` of a design apart (:meth:`split_design`): ``(m, 3)``."""
        assert self.columns is not None
        own = theta[self.columns.own[self.row_record]]  # (m, 3) each row's record's offsets
        return design @ theta[self.columns.shared[:-1]] + np.einsum('mab,mb->ma', slots, own)

    @property
    def extra_rss(self) -> float:
        """The weighted residual sum of squares the compression left out (no parameter changes it)."""
        return float(np.sum(self.remainder / self.sigma ** 2))
