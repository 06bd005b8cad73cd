"""A long run's slow part in bounded memory, for the sandwich of a streamed fit's link terms.

A chamber run's offsets are fitted from every sample (:class:`~tak_thermo_ros.core.fit.stream.StreamingFit`),
and errors that take the residual as white shrink as one over the root of the samples however slowly
the bias wanders. In a run whose temperature rises with time a random walk of the bias reads as a
slope: on simulated chamber runs of 2.3 h the curve was off by 15-23 times the white errors (RMS)
(``bench/bench_curve_coverage.py``). The sandwich of :mod:`~tak_thermo_ros.core.fit.uncertainty`
needs the design and the residual in time order, not every sample: the slow noise that matters
survives averaging over consecutive bins. :class:`BinnedRun` keeps the means of consecutive bins
of samples (stamp, temperature code, reference, codes), at most :data:`MAX_BINS`; when they
fill, neighbours are merged and the bins hold twice as many samples. A bin's design row is the
model's row at its mean temperature and input (within a bin of seconds they barely move).
"""

from __future__ import annotations

import math

import numpy as np

from tak_thermo_ros.core.fit.design import Frame, axis_design
from tak_thermo_ros.core.fit.uncertainty import MAX_SERIES, Sandwich

MAX_BINS = 2 * MAX_SERIES
"""Bins kept before neighbours are merged (then at most :data:`~.uncertainty.MAX_SERIES`)."""
FIELDS = 8
"""Per bin: stamp s, temperature code, reference x y z, codes x y z (means)."""


class BinnedRun:
    """Means over consecutive bins of a run's samples, in time order (see the module's description).

    Kept as sums and counts: the bins of :attr:`size` samples, then one open bin being filled.
    """

    def __init__(self) -> None:
        self.size = 1
        self._sums = np.zeros((0, FIELDS))
        self._open = np.zeros(FIELDS)
        self._open_count = 0

    def add(self, stamp_s: np.ndarray, codes: np.ndarray, reference: np.ndarray, counts: np.ndarray) -> None:
        """A block of samples, after the ones before (``(k,)``, ``(k,)``, ``(k, 3)``, ``(k, 3)``)."""
        values = np.column_stack([stamp_s, codes, reference, counts]).astype(float)
        take = min(self.size - self._open_count, len(values))  # the open bin first
        self._open += values[:take].sum(axis=0)
        self._open_count += take
        values = values[take:]
        if self._open_count < self.size:
            return
        whole = len(values) // self.size * self.size
        closed = [self._open[None, :], values[:whole].reshape(-1, self.size, FIELDS).sum(axis=1)]
        self._sums = np.vstack([self._sums, *closed])
        self._open, self._open_count = values[whole:].sum(axis=0), len(values) - whole
        while len(self._sums) > MAX_BINS:  # neighbours into one: twice the samples per bin
            if len(self._sums) % 2:  # an odd last bin opens again, to be filled
                self._open += self._sums[-1]
                self._open_count += self.size
                self._sums = self._sums[:-1]
            self._sums = self._sums[0::2] + self._sums[1::2]
            self.size *= 2

    def bins(self) -> tuple[np.ndarray, np.ndarray]:
        """``(b, FIELDS)`` the bins' means (the open one too) and ``(b,)`` their sample counts."""
        counts = np.full(len(self._sums), float(self.size))
        sums = self._sums
        if self._open_count:
            sums = np.vstack([sums, self._open[None, :]])
            counts = np.append(counts, float(self._open_count))
        return sums / counts[:, None] if len(counts) else sums, counts

    def period(self) -> float:
        """The mean time between the bins' centres, s (``nan`` with fewer than two bins)."""
        means, _ = self.bins()
        if len(means) < 2:
            return math.nan
        return float((means[-1, 0] - means[0, 0]) / (len(means) - 1))


def axis_sandwich(run: BinnedRun, frame: Frame, axis: int, coefficients: np.ndarray, normal: np.ndarray,
                  variance: float, *, bias_order: int, scale_order: int, held_scale: float | None) -> np.ndarray | None:
    """The covariance of an axis's fitted columns with the residual's own noise model (the sandwich).

    :class:`~tak_thermo_ros.core.fit.uncertainty.Sandwich` over the bins (``add_means``): ``A`` the fit's
    normal matrix of the fitted columns over the residual variance, a bin's design row at its mean
    temperature and input, the noise model of the bins' mean residual. ``None``: too few bins to
    tell, or blocks not given in time order.

    :param coefficients: the fitted columns' values (an axis of one input: its offsets only, ``held_scale`` given).
    :param normal: ``(c, c)`` their normal matrix ``X^T X`` over every sample.
    """
    means, counts = run.bins()
    period = run.period()
    if (len(means) < 16 or not math.isfinite(period) or period <= 0.0 or variance <= 0.0
            or np.any(np.diff(means[:, 0]) <= 0.0)):  # too short, or not in time order: no noise model to take
        return None
    powers = frame.powers(np.clip(means[:, 1], frame.low, frame.high), max(bias_order, scale_order))
    design = axis_design(axis, powers, means[:, 2:5], means[:, 5:8], bias_order=bias_order, scale_order=scale_order,
                         held_scale=held_scale, with_target=True).matrix
    columns, target = design[:, :-1], design[:, -1]
    sandwich = Sandwich(len(coefficients), period)
    sandwich.add_means(columns, target - columns @ coefficients, counts, period, normal / variance, variance,
                       list(range(len(coefficients))))
    return sandwich.covariance()
