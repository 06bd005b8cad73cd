"""The fit of a hand-held record: both sensors' links from still intervals and turns, no table.

A unit turned by hand has no recorded reference, but two things are known (Tedaldi et al.,
ICRA 2014, imu_tk; Basalt's ``calib_bias.hpp``): at rest the specific force has the magnitude
of local gravity and the rate is zero (or the Earth's), and a turn between two rests carries the
gravity direction seen before it onto the one seen after it. This module fits the paper's link
per axis (offset ``b(T)``, scale ``K(T)``) and the triad's misalignment (the ``cross_axis``
effect) of both sensors from those facts, with the same columns as every other fit
(:func:`~tak_thermo_ros.core.fit.design.axis_design`), the same solve from a triangular factor
(:class:`~tak_thermo_ros.core.fit.solve.BlockedQR`, :func:`~tak_thermo_ros.core.fit.solve.solve_factor`)
and the same model (:func:`~tak_thermo_ros.core.fit.model.calibration_from`,
:func:`~tak_thermo_ros.core.fit.model.finish_fit`, the residual through the one correction path).
The effects' shapes are searched by :func:`~tak_thermo_ros.core.fit.fit_model` itself on the
still samples with the reference the hand-held fit found.

**Accelerometer.** At rest ``N_s = M(T_s) g u_k + b(T_s) + noise`` with ``u_k`` the unknown up
direction of still interval ``k`` (two angles) and ``M = diag(K0 F_c(T)) + C``. Gauss-Newton on
the axes' parameters and every ``u_k`` together, the ``u_k`` eliminated interval by interval
(the rows projected onto the complement of their two columns), the axes weighted by their noise:
the errors of the parameters carry the unknown directions. Only ``|f|`` and relative
directions are known, so a rotation of the sensor frame is unobservable: three couplings are held
at zero (the *gauge*, as Basalt's lower-triangular matrix): ``c_xy = c_xz = c_yz = 0``, the
corrected x axis is the accelerometer's x sensitive axis and the corrected y axis lies in the
plane of its x and y axes.

**Gyroscope.** At rest ``N_s = M(T_s) omega_ref + b(T_s) + noise`` (``omega_ref`` zero, or the
Earth rate's vertical component along ``u_k`` at ``latitude``). A turn from interval ``a`` to
``b`` integrates the corrected rate (trapezoid rule) to ``R``, which must carry ``u_b`` onto
``u_a``: two rows ``E_a^T R u_b = 0`` per turn, linearised in the parameters through the
rotation's Jacobian (:func:`~tak_thermo_ros.core.rotation.integrate_segments`), weighted by
their predicted covariance (the gyroscope's white noise over the turn, the directions' errors).
All nine terms of the gyroscope's matrix are fitted: it is tied to the accelerometer's frame.
The accelerations of a turn (a lever arm) never enter: only still samples and rates are used.

**What a record cannot determine is held and said.** A term is held (scale 1, every other term
0) when the record does not determine it to within :data:`BOUNDS` (or not at all), in the order
of :data:`HOLD_ORDER`; each held group is one line and a note in the file. A temperature span
narrower than :data:`SPAN_PER_ORDER_C` per polynomial order lowers the orders (a span under
:data:`SPAN_PER_ORDER_C` holds every thermal term: offsets, scales and misalignment at one
temperature).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.effects import CrossAxis, Effect, resolve_effect
from tak_thermo_ros.core.effects.base import INPUT, checked_basis, effect_input
from tak_thermo_ros.core.fit.design import (
    OFFSET_POLYNOMIAL,
    SCALE_POLYNOMIAL,
    AxisDesign,
    Column,
    Frame,
    axis_design,
    subset,
)
from tak_thermo_ros.core.fit.link_uncertainty import HeldSpreads, link_uncertainty
from tak_thermo_ros.core.fit.model import FitResult, calibration_from, finish_fit, fitted_effects, residual_counts
from tak_thermo_ros.core.fit.prior import Basis, CurvePrior, Information
from tak_thermo_ros.core.fit.random_effects import (
    TURN_ON,
    RecordColumns,
    RecordStatistics,
    RecordSystem,
    Variances,
    absorbed,
    fit_variances,
    record_indicators,
    turn_on_columns,
)
from tak_thermo_ros.core.fit.solve import BlockedQR, Solution, solve_factor, triangular_factor
from tak_thermo_ros.core.link.model import AXES, Calibration
from tak_thermo_ros.core.link.uncertainty import LinkUncertainty
from tak_thermo_ros.core.records.handheld import (
    HandheldRecord,
    TurnClosure,
    closure_terms,
    earth_reference,
    merged_samples,
    numbered_rests,
    rest_records,
    sensor_samples,
)
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.core.rotation import hat, integrate_segments, tangent_basis
from tak_thermo_ros.core.values import SENSOR_NAMES, STANDARD_GRAVITY
from tak_thermo_ros.errors import FitError

SPAN_PER_ORDER_C = 2.0
"""Each order of a temperature polynomial needs this much temperature span, degrees C."""
ONE_TEMPERATURE_HALF_RANGE_C = 0.5
"""A calibration at one temperature states the range ``T +- this`` (a file needs a range)."""
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
GAUGE = ('c_xy', 'c_xz', 'c_yz')
"""The accelerometer's couplings held at zero: the corrected axes' frame (see the module's description)."""
MAX_ITERATIONS = 15
CONVERGED = 1e-4
"""Gauss-Newton stops when no parameter moves by more than this fraction of its standard error."""
CHUNK_SAMPLES = 20_000
"""Still samples per block of rows (bounded memory)."""


@dataclass(frozen=True)
class HandheldSettings:
    """The options of a hand-held fit.

    :param effects: per sensor, offset effects to fit beyond the paper's link (names, as ``--effects``).
    :param axis_orders: per sensor the offset polynomial's order per axis x y z, at most ``bias_order``
        (the terms beyond held at 0; a pool's orders chosen by leaving whole records out); ``None``: ``bias_order``.
    :param variances: a pool's variances per sensor, ``(turn-on spread (3,), rests' extra (3,))``, taken as
        given instead of their REML (the folds of the order's choice).
    :param turns: use the turns (``False``: the rests alone).
    :param prior: what units of its kind say about the curve (:mod:`~tak_thermo_ros.core.fit.prior`): its rows
        join the solve, and the fit stands in its basis, at its orders, over its temperatures too.
    :param held_spreads: a held term's spread where the records do not bound it (the file's uncertainty).
    """

    bias_order: int = 3
    scale_order: int = 2
    temp_code_ref: float | None = None
    gravity: float = STANDARD_GRAVITY
    latitude: float | None = None
    effects: dict[str, tuple] = field(default_factory=dict)
    axis_orders: dict[str, tuple[int, int, int]] | None = None
    variances: dict[str, tuple[np.ndarray, np.ndarray]] | None = None
    turns: bool = True
    prior: CurvePrior | None = None
    held_spreads: HeldSpreads = HeldSpreads()


@dataclass(frozen=True)
class PlateauRow:
    """The paper's +/- quantities (3)-(5) on one plateau and axis, beside the link's values there.

    :param temperature: the plateau's mean temperature, C.
    :param axis: 0, 1, 2.
    :param offset: ``(N+ + N-) / 2`` of the still means with the axis up and down.
    :param scale: ``(N+ - N-) / 2 / g``.
    :param link_offset: the fitted link's offset at that temperature.
    :param link_scale: the fitted link's scale at that temperature.
    :param tilt_deg: the larger of the two faces' tilts from the axis.
    """

    temperature: float
    axis: int
    offset: float
    scale: float
    link_offset: float
    link_scale: float
    tilt_deg: float


@dataclass(frozen=True)
class HandheldFit:
    """Both sensors fitted from a hand-held record.

    :param results: per sensor the fit (calibration, residual statistics, ``parameter_errors``:
        ``'x.scale'``, ``'x.offset'`` at the reference temperature, the couplings and effect terms).
    :param lines: what the record determined and what was held, one statement each.
    :param up: ``(k, 3)`` each still interval's up direction in the corrected frame.
    :param closure: the turns' closure after the fit; ``closure_before`` with the driver's values.
    :param plus_minus: the paper's quantities per plateau (empty unless the faces came in opposite pairs).
    :param orders: the bias and scale orders fitted (after the span rule).
    """

    results: dict[str, FitResult]
    lines: tuple[str, ...]
    up: np.ndarray
    closure: TurnClosure
    closure_before: TurnClosure
    plus_minus: tuple[PlateauRow, ...]
    orders: tuple[int, int]
    turn_on: dict[str, TurnOnFit] = field(default_factory=dict)
    """A pool's records (several power-ups): per sensor the turn-on offsets and their spread."""
    information: dict[str, Information] = field(default_factory=dict)
    """With a prior (one without rows too: a fleet's first pass), per sensor what the records say about every
    term the fit did not hold by construction, the prior's rows left out (:mod:`~tak_thermo_ros.core.fit.prior`)."""


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


# ----- the joint parameter vector of one sensor ------------------------------------------------------


@dataclass(frozen=True)
class _Layout:
    """The three axes' columns side by side: one parameter vector per sensor.

    :param columns: per axis its design's labels.
    :param starts: where each axis's columns begin.
    :param kinds: per parameter: ``scale``, ``scale_T``, ``offset``, ``offset_T``, ``coupling``, ``effect``.
    :param names: per parameter its name (``x.scale``, ``x.offset_T2``, ``cross_axis.c_yx``, ``warmup.amplitude_x``).
    """

    columns: tuple[tuple[Column, ...], ...]
    starts: tuple[int, ...]
    kinds: tuple[str, ...]
    names: tuple[str, ...]

    @classmethod
    def of(cls, columns: Sequence[tuple[Column, ...]]) -> _Layout:
        starts, kinds, names = [], [], []
        for axis, labels in enumerate(columns):
            starts.append(len(kinds))
            scale = offset = 0
            for label in labels:
                if label.term == SCALE_POLYNOMIAL:
                    kinds.append('scale' if scale == 0 else 'scale_T')
                    names.append(f'{AXES[axis]}.scale' + (f'_T{scale}' if scale else ''))
                    scale += 1
                elif label.term == OFFSET_POLYNOMIAL:
                    kinds.append('offset' if offset == 0 else 'offset_T')
                    names.append(f'{AXES[axis]}.offset' + (f'_T{offset}' if offset else ''))
                    offset += 1
                elif label.term == TURN_ON:
                    kinds.append('turn_on')
                    names.append(f'{AXES[axis]}.turn_on.{label.parameter}')
                else:
                    kinds.append('coupling' if label.effect == CrossAxis.name else 'effect')
                    names.append(f'{label.effect}.{label.parameter}')
        return cls(tuple(columns), tuple(starts), tuple(kinds), tuple(names))

    @property
    def width(self) -> int:
        return len(self.kinds)

    def axis_part(self, theta: np.ndarray, axis: int) -> np.ndarray:
        start = self.starts[axis]
        return theta[start:start + len(self.columns[axis])]

    def index(self, name: str) -> int:
        return self.names.index(name)

    def turn_on(self, axis: int) -> list[int]:
        """The columns of one axis's turn-on offsets (a pool's records), in record order."""
        start = self.starts[axis]
        return [start + j for j, label in enumerate(self.columns[axis]) if label.term == TURN_ON]

    def initial(self) -> np.ndarray:
        """Scale 1, everything else 0."""
        theta = np.zeros(self.width)
        theta[[i for i, kind in enumerate(self.kinds) if kind == 'scale']] = 1.0
        return theta


def _joint(designs: Sequence[AxisDesign], layout: _Layout) -> np.ndarray:
    """``(n, 3, W)``: each axis's design in its own columns of the sensor's parameter vector."""
    rows = len(designs[0].target)
    out = np.zeros((rows, 3, layout.width))
    for axis, design in enumerate(designs):
        start = layout.starts[axis]
        out[:, axis, start:start + design.matrix.shape[1]] = design.matrix
    return out


@dataclass
class _Terms:
    """What a sensor's design needs besides the force: the temperature powers, the effects and their bases."""

    frame: Frame
    bias_order: int
    scale_order: int
    effects: tuple[Effect, ...] = ()
    records: int = 1
    """A pool's records: each adds its turn-on offset's column per axis (a random effect)."""

    def designs(self, powers: Sequence[np.ndarray], force: np.ndarray, counts: np.ndarray,
                bases: Sequence[np.ndarray], record: np.ndarray | None = None) -> list[AxisDesign]:
        offset_bases = [(effect, basis) for effect, basis in zip(self.effects, bases)]
        designs = [axis_design(axis, powers, force, counts, bias_order=self.bias_order, scale_order=self.scale_order,
                               input_effects=(CrossAxis(),), offset_bases=offset_bases) for axis in range(3)]
        if self.records < 2:
            return designs
        indicators = record_indicators(np.zeros(len(force), dtype=np.int64) if record is None else record,
                                       self.records)
        labels = turn_on_columns(self.records)
        return [AxisDesign(np.hstack([design.matrix, indicators]), design.target, design.columns + labels)
                for design in designs]

    def layout(self) -> _Layout:
        dummy = np.zeros((1, 3))
        powers = [np.zeros(1)] * (max(self.bias_order, self.scale_order) + 1)
        bases = [np.zeros((1, len(effect.basis_suffixes()))) for effect in self.effects]
        return _Layout.of([design.columns for design in self.designs(powers, dummy, dummy, bases)])


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


def _matrix(theta: np.ndarray, layout: _Layout, powers: Sequence[np.ndarray], scale_order: int) -> np.ndarray:
    """``M(T)`` ``(n, 3, 3)``: ``K0 F_c(T)`` on the diagonal, the couplings off it."""
    count = len(powers[0])
    out = np.zeros((count, 3, 3))
    for axis in range(3):
        part = layout.axis_part(theta, axis)
        out[:, axis, axis] = sum(part[j] * powers[j] for j in range(scale_order + 1))
    for index, name in enumerate(layout.names):
        if layout.kinds[index] == 'coupling':
            channel, force = AXES.index(name[-2]), AXES.index(name[-1])
            out[:, channel, force] = theta[index]
    return out


# ----- the solve with held terms --------------------------------------------------------------------


@dataclass
class _System:
    """The triangular factor of the weighted ``[X | y]`` of one sensor's rows, and its row count."""

    factor: np.ndarray
    count: int

    @classmethod
    def of_rows(cls, blocks: Sequence[np.ndarray], width: int) -> _System:
        accumulated = BlockedQR(width + 1)
        for block in blocks:
            if len(block):
                accumulated.add(block)
        return cls(accumulated.factor.copy(), accumulated.count)

    def plus(self, rows: np.ndarray, record: np.ndarray | None = None) -> _System:
        """The system with more rows (``record``: a pool's rows' records, for :class:`RecordSystem` alike)."""
        if not len(rows):
            return self
        return _System(triangular_factor(np.vstack([self.factor, rows]), self.factor.shape[0]),
                       self.count + len(rows))

    def normal(self) -> np.ndarray:
        """``(W + 1, W + 1)``: the normal matrix ``[X | y]^T [X | y]`` of every row."""
        return self.factor.T @ self.factor

    def reduced(self, held: dict[int, float]) -> tuple[_System, list[int]]:
        """The system with the held columns' values moved into the target and the columns taken out."""
        width = self.factor.shape[1] - 1
        free = [j for j in range(width) if j not in held]
        target = self.factor[:, -1].copy()
        for j, value in held.items():
            target -= self.factor[:, j] * value
        matrix = np.column_stack([self.factor[:, free], target])
        return _System(triangular_factor(matrix, len(free) + 1), self.count), free


@dataclass(frozen=True)
class _Solved:
    """A sensor's solve: the full parameter vector, the free parameters' covariance, what was held."""

    theta: np.ndarray
    free: list[int]
    covariance: np.ndarray
    held: dict[int, float]
    solution: Solution
    dof: int
    inverse: np.ndarray
    system: object = field(default=None, repr=False)
    """The system solved (:class:`_System` or :class:`RecordSystem`): :attr:`normal` from it."""
    variance: float = 0.0
    """The residual variance scale of the rows (the free terms' covariance is it times the inverse)."""

    @property
    def normal(self) -> np.ndarray:
        """The normal matrix of the whole ``[X | y]`` (held columns too, ``(W + 1, W + 1)``): the link's uncertainty."""
        return self.system.normal()  # type: ignore[attr-defined]

    def errors(self, layout: _Layout) -> dict[str, float]:
        deviations = np.sqrt(np.maximum(np.diag(self.covariance), 0.0))
        return {layout.names[j]: float(deviation) for j, deviation in zip(self.free, deviations)}


def _solve(system: _System, held: dict[int, float], width: int, *, rows: int | None = None,
           extra_rss: float = 0.0) -> _Solved:
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
        return _Solved(theta, free, nothing, dict(held), solution, max(system.count, 1), nothing, system)
    solution = solve_factor(reduced.factor, max(reduced.count, 1))
    theta[free] = solution.coefficients
    dof = max((system.count if rows is None else rows) - len(free), 1)
    variance = (solution.rss + extra_rss) / dof
    inverse, null_leverage = _inverses(solution)
    covariance = variance * inverse
    covariance[np.diag_indices_from(covariance)] = np.where(null_leverage > NULL_LEVERAGE, np.inf,
                                                            np.diag(covariance))
    return _Solved(theta, free, covariance, dict(held), solution, dof, inverse, system, variance)


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
                extra_rss: float) -> _Solved:
    """:func:`_solve` of a pool's system: the shared terms from the records' columns absorbed, then each record's.

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
    return _Solved(theta, free, covariance, dict(held), solution, dof, inverse, system, variance)


def _bound(kind: str, sensor: str) -> float:
    if kind in ('offset', 'offset_T'):
        return BOUNDS['offset', sensor]
    return BOUNDS.get(kind, math.inf)


def _holds(solved: _Solved, layout: _Layout, sensor: str) -> dict[int, float]:
    """More terms to hold: the undetermined ones of the first kind in :data:`HOLD_ORDER` that has any."""
    deviations = np.sqrt(np.diag(solved.covariance))
    failing = [j for j, deviation in zip(solved.free, deviations)
               if not deviation <= _bound(layout.kinds[j], sensor)]
    for kind in HOLD_ORDER:
        chosen = [j for j in failing if layout.kinds[j] == kind]
        if chosen:
            return {j: (1.0 if kind == 'scale' else 0.0) for j in chosen}
    return {}


def _solve_holding(system: _System, held: dict[int, float], layout: _Layout, sensor: str, *,
                   rows: int | None = None, extra_rss: float = 0.0) -> _Solved:
    """:func:`_solve`, holding undetermined terms until every free one is determined.

    An axis whose offset is held holds its records' turn-on offsets too (the records cannot tell them).
    """
    held = dict(held)
    while True:
        solved = _solve(system, held, layout.width, rows=rows, extra_rss=extra_rss)
        more = _holds(solved, layout, sensor)
        for axis, name in enumerate(AXES):
            if layout.index(f'{name}.offset') in {**held, **more}:
                more.update({j: 0.0 for j in layout.turn_on(axis) if j not in held})
        if not more:
            return solved
        held.update(more)


# ----- the accelerometer ---------------------------------------------------------------------------


def _segments(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Starts of the runs of equal labels (non-decreasing) and each sample's run."""
    starts = np.flatnonzero(np.diff(labels, prepend=labels[0] - 1) != 0)
    run = np.cumsum(np.diff(labels, prepend=labels[0]) != 0)
    return starts, run


class _Rests:
    """A sensor's still samples, compressed rest by rest.

    Within a rest the input (gravity along the rest's up direction, or the rate at rest) is
    constant, so each axis's model is linear in the temperature powers and the effects' basis
    signals there: the rest's samples are replaced by the triangular factor of
    ``[powers | bases | N]`` (a few rows instead of hundreds), which gives the same least squares
    for any parameters and input. Its rows go through :meth:`_Terms.designs` like samples; the
    couplings' columns (constant over a rest) take the factor's first column (that of the
    constant power).

    A pool's records (``record``: each sample's) add their turn-on offsets' columns, constant over
    a rest like the couplings, with a prior row each (:meth:`prior_rows`, the spread
    ``turn_on_sigma``); each rest's mean row (the first of its factor, along the constant) is
    weighted by ``1 / sqrt(s^2 + n t^2)`` with ``t^2`` the rests' extra variance ``rest_variance``
    (:mod:`~tak_thermo_ros.core.fit.random_effects`).
    """

    def __init__(self, counts: np.ndarray, temperature: np.ndarray, interval: np.ndarray, terms: _Terms,
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
        return _joint(designs, self.layout) * weights[:, :, None], self.counts * weights

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
        return _joint(designs, self.shared_layout) * weights[:, :, None], slots, self.counts * weights

    def shared_theta(self, theta: np.ndarray, design: np.ndarray, slots: np.ndarray) -> np.ndarray:
        """``design @ theta`` of a design apart (:meth:`split_design`): ``(m, 3)``."""
        assert self.columns is not None
        own = theta[self.columns.own[self.row_record]]  # (m, 3) each row's record's offsets
        return design @ theta[self.columns.shared[:-1]] + np.einsum('mab,mb->ma', slots, own)

    @property
    def extra_rss(self) -> float:
        """The weighted residual sum of squares the compression left out (no parameter changes it)."""
        return float(np.sum(self.remainder / self.sigma ** 2))


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

    def __init__(self, rests: _Rests, fixed: RecordStatistics, mean: np.ndarray, own: np.ndarray, record: np.ndarray,
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
        self.determined = _determined(layout, held)
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


class _AccelProblem(_Rests):
    """The accelerometer's rests (:class:`_Rests`): the input is gravity along each rest's unknown up direction."""

    def __init__(self, counts: np.ndarray, temperature: np.ndarray, interval: np.ndarray, terms: _Terms,
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
        matrix = _matrix(theta, self.layout, self.powers, self.terms.scale_order)
        diagonal = np.einsum('maa->ma', matrix)
        couplings = matrix[0] - np.diag(np.diag(matrix[0])) if len(matrix) else np.zeros((3, 3))
        directions = (diagonal[:, :, None] * tangent
                      + self.regressors[:, 0, None, None] * np.einsum('il,mlb->mib', couplings, tangent))
        if weighted:
            directions = directions * self.weights[:, :, None]
        starts, run = _segments(self.interval)
        return directions, run, self.interval[starts]

    def system(self, theta: np.ndarray, up: np.ndarray) -> _System | RecordSystem:
        if self.columns is None:
            design, target, directions, run, _ = self.rows(theta, up)
            projected = _project(directions, run, design, target)
            return _System.of_rows([np.column_stack([projected[0].reshape(-1, self.layout.width),
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


def _fit_accel(problem: _AccelProblem, up: np.ndarray, held: dict[int, float]) -> tuple[_Solved, np.ndarray]:
    """Gauss-Newton on the accelerometer's terms and the up directions; holds grow while terms are undetermined.

    :returns: the solve and the up directions.
    """
    layout = problem.layout
    theta = layout.initial()
    for j, value in held.items():
        theta[j] = value
    dof = 3 * problem.samples - 2 * problem.count
    for _ in range(MAX_ITERATIONS):
        solved = _solve_holding(problem.system(theta, up), held, layout, 'accel', rows=dof,
                                extra_rss=problem.extra_rss)
        held = solved.held
        up = problem.directions(solved.theta, up)
        if _converged(solved, theta):
            break
        theta = solved.theta
    return solved, up


def _converged(solved: _Solved, previous: np.ndarray) -> bool:
    """No free term moved by more than :data:`CONVERGED` of its standard error."""
    deviations = np.sqrt(np.maximum(np.diag(solved.covariance), 1e-300))
    moved = np.abs(solved.theta[solved.free] - previous[solved.free]) / deviations
    return not len(moved) or float(np.max(moved)) < CONVERGED


# ----- the gyroscope ---------------------------------------------------------------------------------


class _GyroProblem:
    """The gyroscope's still samples (linear rows) and turns (rows linearised at each step)."""

    def __init__(self, record: HandheldRecord, interval: np.ndarray, terms: _Terms, still_bases: Sequence[np.ndarray],
                 turn_bases: Sequence[np.ndarray], up: np.ndarray, noise: np.ndarray, up_noise: np.ndarray,
                 latitude: float | None, records: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        self.terms = terms
        self.layout = terms.layout()
        self.sigma = np.maximum(np.asarray(noise, dtype=float), 1e-12)
        order = max(terms.bias_order, terms.scale_order)
        still = record.still
        still_record, turn_record = records if records is not None else (None, None)
        self.rests = _Rests(still.counts[:, 3:6], still.temp_code, interval, terms, still_bases, noise, still_record)
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

    def still_system(self) -> _System | RecordSystem:
        """The rests' rows (linear: the rate at rest is known), compressed rest by rest."""
        force = earth_reference(self.up, self.rests.interval, self.latitude)
        if self.rests.columns is None:
            design, target = self.rests.design(force)
            return _System.of_rows([np.column_stack([design.reshape(-1, self.layout.width), target.reshape(-1)]),
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
        inverse = _inverse(_matrix(theta, self.layout, powers, self.terms.scale_order))
        return np.einsum('mab,mb->ma', inverse, counts - offsets), inverse, powers, bases

    def turn_rows(self, theta: np.ndarray, covariance_scale: float = 1.0, *, rows_needed: bool = True) -> _TurnRows:
        """Two whitened rows ``[J | J theta - r]`` per turn, and the closure at ``theta``.

        The turns are integrated a block of whole turns at a time (bounded memory).

        :param rows_needed: ``False``: the closure only (the rows are left empty).
        """
        count = len(self.pairs)
        width = self.layout.width
        if not count:
            return _TurnRows(np.zeros((0, width + 1)), _no_closure(), np.zeros((0, 2, 2)), np.zeros((0, 3, 2)),
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
            return _TurnRows(np.zeros((0, width + 1)), terms.closure, np.zeros((0, 2, 2)), terms.basis, rotations)
        basis = terms.basis
        jacobian = -np.einsum('tab,tac,tcw->tbw', basis, hat(terms.carried), moved)
        whitening = np.linalg.cholesky(np.linalg.inv(terms.covariance * covariance_scale))  # L L^T = C^-1
        weight = np.swapaxes(whitening, 1, 2)
        rows_design = weight @ jacobian
        rows_target = np.einsum('tab,tb->ta', weight, np.einsum('tbw,w->tb', jacobian, theta) - terms.residual)
        rows = np.concatenate([rows_design, rows_target[:, :, None]], axis=2).reshape(-1, width + 1)
        closure = terms.closure
        return _TurnRows(rows, closure, weight, basis, rotations)

    def frame_covariance(self, turns: _TurnRows, solved: _Solved, accel: _Solved,
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
class _TurnRows:
    """The turns' whitened rows, their closure, and what the frame's error propagation needs."""

    rows: np.ndarray
    closure: TurnClosure
    weight: np.ndarray
    basis: np.ndarray
    rotations: np.ndarray


def _no_closure() -> TurnClosure:
    return TurnClosure(np.zeros(0), np.zeros(0), np.zeros(0))


def _fit_gyro(problem: _GyroProblem, held: dict[int, float]) -> tuple[_Solved, _TurnRows, float]:
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
    theta = _solve(still, start, layout.width, rows=rows, extra_rss=extra).theta
    scale = 1.0
    for _ in range(MAX_ITERATIONS):
        turns = problem.turn_rows(theta, scale)
        solved = _solve_holding(still.plus(turns.rows, problem.turn_row_record), held, layout, 'gyro',
                                rows=rows + len(turns.rows), extra_rss=extra)
        held = solved.held
        if _converged(solved, theta):
            residual = turns.rows[:, :-1] @ solved.theta - turns.rows[:, -1]
            chi2 = float(residual @ residual) / max(len(turns.rows), 1)
            if chi2 <= CHI2_SLACK:
                break
            scale = chi2 * scale
        theta = solved.theta
    return solved, turns, scale


CHI2_SLACK = 1.3
"""The turns' chi-square per row may exceed 1 by this factor before their weight is lowered."""


# ----- the fit of a hand-held record ------------------------------------------------------------------


def orders_for_span(span_c: float, bias_order: int, scale_order: int) -> tuple[int, int]:
    """The polynomial orders a temperature span determines: one order per :data:`SPAN_PER_ORDER_C`."""
    allowed = int(math.floor(max(span_c, 0.0) / SPAN_PER_ORDER_C + 1e-9))
    return min(bias_order, allowed), min(scale_order, allowed)


def gauge_rotation(matrix: np.ndarray) -> np.ndarray:
    """``Q`` with ``matrix = L Q``, ``L`` lower triangular with a positive diagonal (the accelerometer's gauge).

    A unit whose accelerometer's sensitivity matrix is ``M`` (sensor frame to channels) is
    corrected by a hand-held fit into the frame ``Q`` times the sensor frame; its accelerometer
    reads ``L`` there, its gyroscope ``M_g Q^T``.
    """
    orthogonal, upper = np.linalg.qr(np.asarray(matrix, dtype=float).T)  # M^T = Q^T L^T
    signs = np.sign(np.diag(upper))
    return (orthogonal * signs[None, :]).T


def sensitivity(calibration: Calibration, temperature: float) -> np.ndarray:
    """The sensor's matrix ``diag(K0 F_c(T)) + C`` at one temperature (channels per unit input)."""
    n = float(np.clip(temperature, calibration.temp_code_min, calibration.temp_code_max)) - calibration.temp_code_ref
    matrix = np.diag([axis.scale * float(axis.scale_factor(n)) for axis in calibration.axes])
    for effect in calibration.effects:
        if isinstance(effect, CrossAxis):
            matrix = matrix + np.array(effect.matrix())
    return matrix


def _offset_effects(specs: Sequence, sensor: str) -> tuple[type[Effect], ...]:
    """The effects asked for one sensor: offset effects only (the misalignment is always fitted)."""
    classes = []
    for spec in specs:
        cls = resolve_effect(spec)
        if cls is CrossAxis:
            continue
        if cls.kind == INPUT:
            msg = (f'effect {cls.name}: not fitted from a hand-held record (the {sensor} misalignment, cross_axis, '
                   f'is; a scale nonlinearity needs a table)')
            raise FitError(msg)
        classes.append(cls)
    return tuple(classes)


def _union_bases(effects: Sequence[Effect], frame: Frame, record: HandheldRecord
                 ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Each effect's basis over the still and turn samples together, in time order (effects with memory)."""
    if not effects:
        return [], []
    series, still_rows, turn_rows = merged_samples(record)
    still_bases, turn_bases = [], []
    for effect in effects:
        inputs = effect_input(effect, np.clip(series.temp_code, frame.low, frame.high), series.aux)
        basis = checked_basis(effect, series.stamp_s, inputs)
        still_bases.append(basis[still_rows])
        turn_bases.append(basis[turn_rows])
    return still_bases, turn_bases


def _calibration(solved: _Solved, layout: _Layout, terms: _Terms, notes: tuple[str, ...]) -> Calibration:
    """The correction link of a solve: the axes, the misalignment when any coupling was fitted, the effects."""
    betas = [layout.axis_part(solved.theta, axis) for axis in range(3)]
    fitted_couplings = any(layout.kinds[j] == 'coupling' for j in solved.free)
    effects = fitted_effects([CrossAxis(), *terms.effects], layout.columns, betas)
    if not fitted_couplings:
        effects = effects[1:]
    calibration = calibration_from(terms.frame, betas, bias_order=terms.bias_order, scale_order=terms.scale_order,
                                   held_scales=(None, None, None), notes=notes, effects=effects)
    held_scale = [layout.index(f'{name}.scale') in solved.held for name in AXES]
    axes = tuple(replace(axis, scale_observable=False) if held else axis
                 for axis, held in zip(calibration.axes, held_scale))
    return replace(calibration, axes=axes)  # type: ignore[arg-type]


def order_holds(layout: _Layout, orders: Sequence[int] | None) -> dict[int, float]:
    """The offset polynomial's terms beyond each axis's order, held at 0."""
    if orders is None:
        return {}
    held = {}
    for axis, order in enumerate(orders):
        start = layout.starts[axis]
        for j in range(start, start + len(layout.columns[axis])):
            name = layout.names[j]
            if layout.kinds[j] == 'offset_T' and int(name.rsplit('_T', 1)[1]) > order:
                held[j] = 0.0
    return held


ONE_ORIENTATION_DEG = 30.0
"""Rests whose up directions all lie within this of their mean are one orientation (near level, on ground
tilted by up to this at any heading): |f| tells the other axes' offsets through the tilts only, and cannot
tell them from the couplings with the gravity axis (``g c_zx u_x u_z`` against ``b_x u_x``: at 15 deg they
differ by 3 %: the fit's bounds would keep a coupling that took up a 10 mg offset)."""


def one_orientation(up: np.ndarray, kept: np.ndarray, layout: _Layout) -> tuple[str, dict[int, float]]:
    """When every rest lies in one orientation: the line that says so, and the accelerometer's terms it holds.

    At rest near one orientation ``|f| = g + b . u + g u' S u + ...`` (``u`` the up direction,
    ``S`` the scale errors and the couplings): the tilts of the rests tell the other axes'
    offsets (``b_x u_x``), with their temperature terms where the span allows, and their scales
    (``g s_x u_x^2``); what they cannot tell apart is held and said in one line: the gravity
    axis's scale and its temperature terms (at 1 g they act as its offset, which carries them),
    the couplings between the gravity axis and the others (``g c_zx u_x u_z`` acts as
    ``b_x u_x``) and the other axes' scales' temperature terms. What the rests do not determine
    beyond that is held by the fit's bounds. With up between the axes (no axis within
    :data:`~tak_thermo_ros.core.records.still.FACE_DEG` of it) every offset, scale and coupling is held.
    """
    from tak_thermo_ros.core.records.still import FACE_DEG
    if not len(up):
        return '', {}
    mean = np.average(up, axis=0, weights=np.maximum(kept, 1))
    mean /= np.linalg.norm(mean)
    spread = float(np.degrees(np.arccos(np.clip(np.min(up @ mean), -1.0, 1.0))))
    if spread > ONE_ORIENTATION_DEG:
        return '', {}
    gravity = int(np.argmax(np.abs(mean)))
    where = f'{spread:.1f} deg of one orientation'
    if abs(mean[gravity]) < math.cos(math.radians(FACE_DEG)):
        held = {j: (1.0 if kind == 'scale' else 0.0) for j, kind in enumerate(layout.kinds)
                if kind in ('scale', 'scale_T', 'coupling', 'offset', 'offset_T', 'turn_on')}
        return (f'accelerometer: every rest within {where}, up between the axes: |f| tells no axis\'s offset; '
                f'offsets, scales and misalignment held'), held
    name = AXES[gravity]
    held = {}
    for j, (kind, label) in enumerate(zip(layout.kinds, layout.names)):
        axis = AXES.index(label[0]) if label[1] == '.' else -1
        if kind == 'coupling':
            if name in label[-2:]:
                held[j] = 0.0
        elif axis == gravity and kind in ('scale', 'scale_T'):
            held[j] = 1.0 if kind == 'scale' else 0.0
        elif axis != gravity and kind == 'scale_T':
            held[j] = 0.0
    others = ' '.join(axis for axis in AXES if axis != name)
    line = (f'accelerometer: every rest within {where} ({"+-"[int(mean[gravity] < 0)]}{name} up): the tilts '
            f'determine the offsets on {others} (|f| = g + b . u + ...); the scale of {name} and the couplings '
            f'with {name} held')
    return line, held


def held_lines(sensor: str, solved: _Solved, layout: _Layout, *, gauge: Sequence[str] = (),
               source: str = 'this record', said: Sequence[int] = ()) -> list[str]:
    """One statement per kind of term the record did not determine (the gauge is said apart)."""
    name = SENSOR_NAMES[sensor]
    # :data:`BOUNDS` in the units a reader expects: 1 %, 10 mrad, 5 mg or 0.29 deg/s.
    offset = {'accel': f'{BOUNDS["offset", "accel"] / STANDARD_GRAVITY * 1e3:.0f} mg',
              'gyro': f'{math.degrees(BOUNDS["offset", "gyro"]):.2f} deg/s'}[sensor]
    scale, scale_t = (f'{100.0 * BOUNDS[kind]:g} %' for kind in ('scale', 'scale_T'))
    words = {'scale': ('scale held at 1 on', f'not determined to {scale}'),
             'scale_T': ("scale's temperature terms held at 0 on", f'not determined to {scale_t}'),
             'offset': ('offset held at 0 on', f'not determined to {offset}'),
             'offset_T': ("offset's temperature terms held at 0 on", f'not determined to {offset}'),
             'coupling': ('couplings held at 0:', f'not determined to {1e3 * BOUNDS["coupling"]:g} mrad'),
             'effect': ('effect terms held at 0:', 'not determined')}
    lines = []
    for kind in ('scale', 'scale_T', 'offset', 'offset_T', 'coupling', 'effect'):
        held = [j for j in solved.held if layout.kinds[j] == kind and layout.names[j].split('.')[-1] not in gauge
                and j not in said]
        if not held:
            continue
        if kind in ('coupling', 'effect'):
            what = ', '.join(layout.names[j].split('.')[-1] for j in held)
        else:
            what = ' '.join(sorted({layout.names[j].split('.')[0] for j in held}))
        lead, why = words[kind]
        lines.append(f'{name}: {lead} {what} ({why} by {source})')
    return lines


def fit_handheld(record: HandheldRecord, settings: HandheldSettings = HandheldSettings()) -> HandheldFit:
    """Fit both sensors of a hand-held record (see the module's description).

    :raises FitError: no still interval, too few samples, an effect that cannot be fitted so.
    """
    if not len(record.still):
        msg = ('no still interval: the unit never rested for 2 s or more (rest 5-10 s in each orientation, '
               'docs/handheld.md)')
        raise FitError(msg)
    temperature = record.still.temp_code
    low, high = float(temperature.min()), float(temperature.max())
    prior = settings.prior
    bias_order, scale_order = orders_for_span(high - low, settings.bias_order, settings.scale_order)
    if prior is not None:  # the prior tells what the span cannot: its orders
        bias_order, scale_order = prior.bias_order, prior.scale_order
    lines: list[str] = []
    notes: list[str] = []
    if (bias_order, scale_order) != (settings.bias_order, settings.scale_order) and prior is None:
        if bias_order == 0 and scale_order == 0:
            said = (f'temperature span {high - low:.2g} C ({low:.1f}..{high:.1f} C): offsets, scales and '
                    f'misalignment at {0.5 * (low + high):.1f} C, their temperature terms held at 0 (a fit against '
                    f'temperature needs {SPAN_PER_ORDER_C:g} C per order)')
        else:
            said = (f'temperature span {high - low:.3g} C ({low:.1f}..{high:.1f} C): bias order {bias_order} and '
                    f'scale order {scale_order} (asked {settings.bias_order} and {settings.scale_order}; '
                    f'{SPAN_PER_ORDER_C:g} C per order)')
        lines.append(said)
        notes.append(said)
    if high - low < 2.0 * ONE_TEMPERATURE_HALF_RANGE_C:
        middle = 0.5 * (low + high)
        low, high = middle - ONE_TEMPERATURE_HALF_RANGE_C, middle + ONE_TEMPERATURE_HALF_RANGE_C
    frame = Frame.of_range(low, high, settings.temp_code_ref) if prior is None else prior.frame(
        low, high, settings.temp_code_ref)
    effects = {sensor: _offset_effects(settings.effects.get(sensor, ()), sensor) for sensor in ('accel', 'gyro')}
    if any(effects.values()) and bias_order == 0:
        msg = 'effects need a temperature span: this record was taken at one temperature'
        raise FitError(msg)
    interval, count, turn_interval, used = numbered_rests(record)
    pool = record.records
    still_record = record.still_record
    rest_record = rest_records(record)
    noise = record.intervals.noise
    accel_counts = record.still.counts[:, :3]
    means = np.zeros((count, 3))
    np.add.at(means, interval, accel_counts)
    kept = np.bincount(interval, minlength=count)
    up = means / np.linalg.norm(means, axis=1, keepdims=True)
    measured = up  # the rests' orientation as recorded: one orientation or not, whatever the fit makes of it

    accel_terms = _Terms(frame, bias_order, scale_order, records=pool)
    level_line, level = one_orientation(measured, kept, accel_terms.layout())
    if level_line:
        lines.append(level_line)
        notes.append(level_line)
    axis_orders = settings.axis_orders or {}

    def accel_holds(layout: _Layout) -> dict[int, float]:
        """The gauge, one orientation's holds and the chosen orders' on a layout of the accelerometer."""
        held = {layout.index(f'cross_axis.{name}'): 0.0 for name in GAUGE}
        if level_line:
            held.update(one_orientation(measured, kept, layout)[1])
        held.update(order_holds(layout, axis_orders.get('accel')))
        return held

    def gyro_holds(layout: _Layout) -> dict[int, float]:
        """The chosen orders' holds on a layout of the gyroscope; one orientation holds its scales and couplings.

        Its frame is the accelerometer's, whose tilts take up the other axes' offsets: its misalignment
        is not told, nor its scale by motions closed on those tilts (the motions are not integrated).
        """
        held = order_holds(layout, axis_orders.get('gyro'))
        if level_line:
            held.update({j: (1.0 if kind == 'scale' else 0.0) for j, kind in enumerate(layout.kinds)
                         if kind in ('coupling', 'scale', 'scale_T')})
        return held

    gauge = accel_holds(accel_terms.layout())
    problem = _AccelProblem(accel_counts, temperature, interval, accel_terms, [], settings.gravity, noise[:3],
                            still_record)
    problem.turn_on_sigma = np.full(3, BOUNDS['offset', 'accel'])  # weak, until the pool's own spread is known
    _set_prior(problem, prior, 'accel')
    given = settings.variances or {}
    if 'accel' in given:
        problem.turn_on_sigma, problem.rest_variance = given['accel'][0], np.asarray(given['accel'][1]) ** 2
    accel, up = _fit_accel(problem, up, gauge)
    turn_on: dict[str, TurnOnFit] = {}
    if pool > 1 and 'accel' not in given:
        accel, up, turn_on['accel'] = _pooled_accel(problem, up, gauge, accel)
    shapes: dict[str, FitResult] = {}
    if effects['accel']:
        reference = settings.gravity * up[interval]
        samples = sensor_samples(record.still, 'accel', reference)
        if 'accel' in turn_on:  # a pool: each record's own offset off, the shapes searched on the rest
            samples = replace(samples, counts=samples.counts - turn_on['accel'].offsets[still_record])
        shaped = _shapes(samples, effects['accel'], accel, problem.layout, accel_terms, frame)
        shapes['accel'] = shaped
        offsets = tuple(effect for effect in shaped.calibration.effects if not isinstance(effect, CrossAxis))
        accel_terms = _Terms(frame, bias_order, scale_order, offsets, records=pool)
        still_bases, _ = _union_bases(accel_terms.effects, frame, record)
        gauge = accel_holds(accel_terms.layout())
        variances = problem.turn_on_sigma, problem.rest_variance
        problem = _AccelProblem(accel_counts, temperature, interval, accel_terms, still_bases, settings.gravity,
                                problem.sigma, still_record)
        problem.turn_on_sigma, problem.rest_variance = variances
        _set_prior(problem, prior, 'accel')
        accel, up = _fit_accel(problem, up, gauge)
        if pool > 1 and 'accel' not in given:
            accel, up, turn_on['accel'] = _pooled_accel(problem, up, gauge, accel)
    level = one_orientation(measured, kept, problem.layout)[1] if level_line else {}
    accel_layout = problem.layout
    accel_sigma = problem.sigma

    up_noise = float(np.sqrt(np.mean(accel_sigma ** 2))) / (settings.gravity * np.sqrt(np.maximum(kept, 1)))
    if not settings.turns or level:  # one orientation: see the gyroscope's holds below
        used = np.zeros(len(turn_interval), dtype=bool)
    turns_record = _with_turns(record, turn_interval, used)
    gyro_terms = _Terms(frame, bias_order, scale_order, records=pool)
    turn_record = (rest_record[turns_record.turns[turns_record.turn_index, 0]] if len(turns_record.turn_index)
                   else np.zeros(0, dtype=np.int64))
    gyro_problem = _GyroProblem(turns_record, interval, gyro_terms, [], [], up, noise[3:6], up_noise, settings.latitude,
                                records=(still_record, turn_record))
    gyro_problem.rests.turn_on_sigma = np.full(3, BOUNDS['offset', 'gyro'])
    _set_prior(gyro_problem.rests, prior, 'gyro')
    if 'gyro' in given:
        gyro_problem.rests.turn_on_sigma = given['gyro'][0]
        gyro_problem.rests.rest_variance = np.asarray(given['gyro'][1]) ** 2
    gyro_orders = gyro_holds(gyro_problem.layout)
    gyro, turns, turn_scale = _fit_gyro(gyro_problem, gyro_orders)
    if pool > 1 and 'gyro' not in given:
        gyro, turns, turn_scale, turn_on['gyro'] = _pooled_gyro(gyro_problem, gyro, turns, turn_scale, gyro_orders)
    if effects['gyro']:
        # The Earth rate (1e-4 rad/s at most) taken off at nominal scale: the scale's error (1e-3) leaves 1e-7.
        at_rest = record.still.counts[:, 3:6] - gyro_problem.reference
        if 'gyro' in turn_on:  # a pool: each record's own offset off, the shapes searched on the rest
            at_rest = at_rest - turn_on['gyro'].offsets[still_record]
        samples = replace(sensor_samples(record.still, 'gyro', np.zeros((len(interval), 3))), counts=at_rest)
        shaped = _shapes(samples, effects['gyro'], gyro, gyro_problem.layout, gyro_terms, frame)
        shapes['gyro'] = shaped
        gyro_terms = _Terms(frame, bias_order, scale_order, tuple(shaped.calibration.effects), records=pool)
        still_bases, turn_bases = _union_bases(gyro_terms.effects, frame, turns_record)
        variances = gyro_problem.rests.turn_on_sigma, gyro_problem.rests.rest_variance
        gyro_problem = _GyroProblem(turns_record, interval, gyro_terms, still_bases, turn_bases, up, noise[3:6],
                                    up_noise, settings.latitude, records=(still_record, turn_record))
        gyro_problem.rests.turn_on_sigma, gyro_problem.rests.rest_variance = variances
        _set_prior(gyro_problem.rests, prior, 'gyro')
        gyro_orders = gyro_holds(gyro_problem.layout)
        gyro, turns, turn_scale = _fit_gyro(gyro_problem, gyro_orders)
        if pool > 1 and 'gyro' not in given:
            gyro, turns, turn_scale, turn_on['gyro'] = _pooled_gyro(gyro_problem, gyro, turns, turn_scale,
                                                                    gyro_orders)
    through_frame = gyro_problem.frame_covariance(turns, gyro, accel, problem.sensitivity(accel.theta, up))
    gyro = replace(gyro, covariance=gyro.covariance + through_frame)
    closure = replace(turns.closure, seconds=turns_record.turn_seconds())

    gauge_line = 'accelerometer: gauge c_xy = c_xz = c_yz = 0: corrected x along its x axis, y in its x-y plane'
    source = 'this record' if pool < 2 else 'these records'
    chosen = order_holds(accel_layout, axis_orders.get('accel'))  # the orders' holds are said by the pool
    accel_held = held_lines('accel', accel, accel_layout, gauge=GAUGE, source=source, said=[*level, *chosen])
    gyro_held = held_lines('gyro', gyro, gyro_problem.layout, source=source, said=list(gyro_orders))
    if level:
        gyro_held.insert(0, 'gyroscope: scales and misalignment held, the motions not integrated: its frame is the '
                            'accelerometer\'s, which one orientation does not fix')
    coupled = any(accel_layout.kinds[j] == 'coupling' for j in accel.free)
    said_gauge = [gauge_line] if coupled or not level else []  # no coupling fitted: no gauge to say
    lines += [*said_gauge, *accel_held, *gyro_held]
    accel_cal = _calibration(accel, accel_layout, accel_terms, tuple(notes + said_gauge + accel_held))
    gyro_cal = _calibration(gyro, gyro_problem.layout, gyro_terms, tuple(notes + gyro_held))
    accel_cal = replace(accel_cal, uncertainty=_uncertainty(accel, accel_layout, 'accel', frame, settings))
    gyro_cal = replace(gyro_cal, uncertainty=_uncertainty(gyro, gyro_problem.layout, 'gyro', frame, settings))
    for sensor, solved, layout in (('accel', accel, accel_layout), ('gyro', gyro, gyro_problem.layout)):
        if pool > 1 and sensor not in turn_on:  # the variances were given
            spread, extra = given[sensor]
            determined = _determined(layout, solved.held)
            variances = Variances(np.where(determined, spread, np.nan), np.full(3, np.nan), np.asarray(extra),
                                  determined)
            turn_on[sensor] = _turn_on_fit(solved, layout, variances, pool)
    # A pool's residual at the rests: each record's own turn-on offset taken off
    own = {sensor: (turn_on[sensor].offsets[still_record] if sensor in turn_on else 0.0)
           for sensor in ('accel', 'gyro')}
    accel_samples = sensor_samples(record.still, 'accel', settings.gravity * up[interval])
    gyro_samples = sensor_samples(record.still, 'gyro', gyro_problem.reference)
    if pool > 1:
        accel_samples = replace(accel_samples, counts=accel_samples.counts - own['accel'])
        gyro_samples = replace(gyro_samples, counts=gyro_samples.counts - own['gyro'])
        accel_cal, gyro_cal = (_with_turn_on(calibration, turn_on[sensor], pool)
                               for sensor, calibration in (('accel', accel_cal), ('gyro', gyro_cal)))
    results = {
        'accel': _result(accel_cal, accel, accel_layout, accel_samples, record, shapes),
        'gyro': _result(gyro_cal, gyro, gyro_problem.layout, gyro_samples, record, shapes),
    }
    before = replace(gyro_problem.turn_rows(gyro_problem.layout.initial(), rows_needed=False).closure,
                     seconds=closure.seconds)
    if turn_scale > 1.0:
        lines.append(f'gyroscope: the turns close {math.sqrt(turn_scale):.2f}x worse than the noise predicts; '
                     f'their weight is lowered by that much')
    table = plateau_table(record.still, interval, up, accel_cal, settings.gravity)
    information = {}
    if prior is not None:  # what a fleet's prior is made of, or chooses a unit's group by
        span = (float(temperature.min()), float(temperature.max()))
        gyro_system = gyro_problem.still_system().plus(turns.rows, gyro_problem.turn_row_record)
        information = {'accel': _information(problem.system(accel.theta, up), problem, gauge, accel, frame, span),
                       'gyro': _information(gyro_system, gyro_problem.rests, gyro_orders, gyro, frame, span)}
    return HandheldFit(results=results, lines=tuple(lines), up=up, closure=closure, closure_before=before,
                       plus_minus=table, orders=(bias_order, scale_order), turn_on=turn_on, information=information)


def _set_prior(rests: _Rests, prior: CurvePrior | None, sensor: str) -> None:
    """A sensor's rests take a prior's rows on their curve terms (none without a prior)."""
    if prior is not None:
        rests.curve_rows = prior.rows(sensor, rests.layout.names)


def _information(system: _System | RecordSystem, rests: _Rests, structural: dict[int, float], solved: _Solved,
                 frame: Frame, span: tuple[float, float]) -> Information:
    """What the records say about every term not held by construction: the system's normal matrix, its prior rows out.

    ``structural``: the terms held by construction (the gauge, one orientation, the orders) go in at their values.
    """
    layout = rests.layout
    normal = system.normal() - rests.curve_rows.T @ rests.curve_rows
    free = [j for j in range(layout.width) if j not in structural]
    carry = np.zeros((layout.width + 1, len(free) + 1))  # [theta; -1] = carry [theta_free; -1]
    carry[free, np.arange(len(free))] = 1.0
    for j, value in structural.items():
        carry[j, -1] = -value
    carry[-1, -1] = 1.0
    held = tuple(layout.names[j] for j in solved.held if j not in structural)
    return Information(tuple(layout.names[j] for j in free), carry.T @ normal @ carry, Basis.of_frame(frame),
                       span[0], span[1], rows=system.count, held=held)


def _uncertainty(solved: _Solved, layout: _Layout, sensor: str, frame: Frame,
                 settings: HandheldSettings) -> LinkUncertainty:
    """The link's own uncertainty (:mod:`~tak_thermo_ros.core.fit.link_uncertainty`), held terms included.

    The gauge is no error (it defines the corrected frame: ``|f|`` and the rates at rest do not
    see it); the gyroscope's carries its offsets only (at rest its scales and couplings multiply
    the Earth rate alone: a few hundredths of a deg/h).
    """
    whole = solved.normal  # built from the system's factors: once
    normal = whole[:-1, :-1]
    gradient = whole[:-1, -1] - normal @ solved.theta
    names = layout.names
    held = [j for j in solved.held if names[j].split('.')[-1] not in GAUGE]
    offsets = [j for j in [*solved.free, *held] if layout.kinds[j] in ('offset', 'offset_T')]
    carried = None if sensor == 'accel' else offsets
    return link_uncertainty(names, layout.kinds, normal, gradient, solved.free, solved.covariance,
                            np.full(layout.width, solved.variance), held, sensor=sensor,
                            temperature_scale=frame.n_scale, spreads=settings.held_spreads, carried=carried)


# ----- a pool of records: the turn-on offsets as random effects ---------------------------------------

VARIANCE_ROUNDS = 3
"""The variances and the link are refitted in turn at most this many times."""
VARIANCE_SETTLED = 0.05
"""... until no variance moves by more than this fraction."""


def _turn_on_fit(solved: _Solved, layout: _Layout, variances: Variances, records: int) -> TurnOnFit:
    """Each record's offset and its error from a solve, beside the spread."""
    offsets = np.zeros((records, 3))
    errors = np.full((records, 3), np.nan)
    deviations = dict(zip(solved.free, np.sqrt(np.maximum(np.diag(solved.covariance), 0.0))))
    for axis in range(3):
        for record, column in enumerate(layout.turn_on(axis)):
            offsets[record, axis] = solved.theta[column]
            errors[record, axis] = deviations.get(column, np.nan)
    return TurnOnFit(variances, offsets, errors)


def _determined(layout: _Layout, held: dict[int, float]) -> np.ndarray:
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


def _rests_reml(rests: _Rests, design: np.ndarray, slots: np.ndarray, target: np.ndarray, held: dict[int, float],
                extra: np.ndarray | None = None, extra_record: np.ndarray | None = None,
                directions: np.ndarray | None = None) -> _Reml:
    """The REML of a sensor's rests from its unweighted compressed rows apart (:meth:`_Rests.split_design`).

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


def _pooled_accel(problem: _AccelProblem, up: np.ndarray, gauge: dict[int, float],
                  accel: _Solved) -> tuple[_Solved, np.ndarray, TurnOnFit]:
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
        accel, up = _fit_accel(problem, up, gauge)
        current = np.concatenate([problem.turn_on_sigma, variances.rest])
        if _settled(previous, current):
            break
        previous = current
    assert variances is not None
    # an axis seen through the tilts alone (near level: x and y at a tenth of their size) may leave its
    # spread within its own error of 0: the records do not tell it (its offsets stay the fit's random effects)
    told = variances.determined & (variances.turn_on_error < variances.turn_on)
    variances = replace(variances, turn_on=np.where(told, variances.turn_on, np.nan), determined=told)
    return accel, up, _turn_on_fit(accel, problem.layout, variances, len(problem.layout.turn_on(0)))


def _pooled_gyro(problem: _GyroProblem, gyro: _Solved, turns: _TurnRows, turn_scale: float,
                 held: dict[int, float]) -> tuple[_Solved, _TurnRows, float, TurnOnFit]:
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
        gyro, turns, turn_scale = _fit_gyro(problem, held)
        current = np.concatenate([rests.turn_on_sigma, variances.rest])
        if _settled(previous, current):
            break
        previous = current
    assert variances is not None
    return gyro, turns, turn_scale, _turn_on_fit(gyro, problem.layout, variances, len(problem.layout.turn_on(0)))


def _with_turn_on(calibration: Calibration, fitted: TurnOnFit, records: int) -> Calibration:
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


def _with_turns(record: HandheldRecord, pairs: np.ndarray, used: np.ndarray) -> HandheldRecord:
    """The record with its turns' intervals counted among the kept ones, turns without both left out."""
    if used.all():
        return replace(record, turns=pairs.reshape(-1, 2))
    keep_turn = np.flatnonzero(used)
    mapping = np.full(len(used), -1)
    mapping[keep_turn] = np.arange(len(keep_turn))
    rows = used[record.turn_index]
    return replace(record, turns=pairs[used], turn=subset(record.turn, rows),
                   turn_index=mapping[record.turn_index[rows]])


def _shapes(samples: AlignedSamples, effects: Sequence[type[Effect]], solved: _Solved, layout: _Layout,
            terms: _Terms, frame: Frame) -> FitResult:
    """The effects' shapes, searched by :func:`fit_model` on the still samples with the hand-held reference."""
    from tak_thermo_ros.core.fit import fit_model
    nominal = tuple(float(solved.theta[layout.index(f'{name}.scale')]) for name in AXES)
    try:
        return fit_model(samples, effects=tuple(effects), bias_order=max(terms.bias_order, 1),
                         scale_order=terms.scale_order, temp_code_ref=frame.ref, nominal_scale=nominal)
    except FitError as err:
        msg = f'the effects\' shapes on the still intervals: {err}'
        raise FitError(msg) from None


def _result(calibration: Calibration, solved: _Solved, layout: _Layout, samples: AlignedSamples,
            record: HandheldRecord, shapes: dict[str, FitResult]) -> FitResult:
    """The sensor's :class:`FitResult`: residual at the still samples through the correction path, the errors."""
    residual = residual_counts(calibration, samples)
    parameters = [sum(1 for j in solved.free if layout.starts[axis] <= j < layout.starts[axis]
                      + len(layout.columns[axis])) for axis in range(3)]
    errors = solved.errors(layout)
    for shaped in shapes.values():
        for effect in calibration.effects:
            for name in effect.shape_names():
                key = f'{effect.name}.{name}'
                if key in shaped.parameter_errors:
                    errors[key] = shaped.parameter_errors[key]
    return finish_fit(calibration, residual, parameters, dropped=record.dropped, parameter_errors=errors)


PLATEAU_C = 1.0
"""Successive still intervals on a plateau stay within this temperature of its first (the +/- table)."""
PLATEAU_RATE = 0.25 / 60.0
"""A still interval is on a plateau when the temperature moves less than this (C per second, a
quarter of a degree per minute) from it to the interval before it or to the one after it."""


def plateau_groups(temperature: np.ndarray, stamp_s: np.ndarray, interval: np.ndarray) -> list[np.ndarray]:
    """The still intervals of each plateau: successive in time, the temperature holding (:data:`PLATEAU_RATE`).

    Not by temperature alone: sorted by temperature, the rests of the ramps between the chamber's
    plateaus fill the gaps between them (a rest every few tenths of a degree at 1 C/min) and chain
    every plateau into one; the rests of a ramp belong to none.
    """
    count = len(temperature)
    start = np.full(count, np.inf)
    np.minimum.at(start, interval, np.asarray(stamp_s, dtype=float))
    order = np.argsort(start, kind='stable')
    times, temps = start[order], np.asarray(temperature, dtype=float)[order]
    if count > 1:
        # The slower of the two sides: a plateau's first and last rests have one steady side.
        step = np.abs(np.diff(temps)) / np.maximum(np.diff(times), 1e-9)
        rate = np.minimum(np.r_[step[:1], step], np.r_[step, step[-1:]])
    else:
        rate = np.zeros(count)
    groups: list[list[int]] = []
    open_group = False
    for position, index in enumerate(order):
        if rate[position] > PLATEAU_RATE:
            open_group = False
            continue
        if open_group and abs(temps[position] - temperature[groups[-1][0]]) <= PLATEAU_C:
            groups[-1].append(int(index))
        else:
            groups.append([int(index)])
            open_group = True
    return [np.array(group) for group in groups]


FACE_TILT_DEG = 10.0
"""A still interval rests on a face (the +/- table) when its up direction lies within this of an axis."""


def plateau_table(still: AlignedSamples, interval: np.ndarray, up: np.ndarray, calibration: Calibration,
                  gravity: float) -> tuple[PlateauRow, ...]:
    """The paper's eqs. (3)-(5) on each plateau where all six faces rested, beside the fitted link there."""
    from tak_thermo_ros.core.fit.plus_minus import plus_minus
    count = len(up)
    if not count:
        return ()
    kept = np.bincount(interval, minlength=count).astype(float)
    means = np.zeros((count, 3))
    np.add.at(means, interval, still.counts[:, :3])
    means /= kept[:, None]
    temperature = np.bincount(interval, weights=still.temp_code, minlength=count) / kept
    groups = plateau_groups(temperature, still.stamp_s, interval)
    cosine = math.cos(math.radians(FACE_TILT_DEG))
    rows: list[PlateauRow] = []
    for group in groups:
        faces = [(group[up[group, axis] > cosine], group[up[group, axis] < -cosine]) for axis in range(3)]
        if not all(len(plus) and len(minus) for plus, minus in faces):
            continue
        mean_t = float(np.average(temperature[group], weights=kept[group]))
        n = float(np.clip(mean_t, calibration.temp_code_min, calibration.temp_code_max)) - calibration.temp_code_ref
        for axis, (plus, minus) in enumerate(faces):
            code_plus = float(np.average(means[plus, axis], weights=kept[plus]))
            code_minus = float(np.average(means[minus, axis], weights=kept[minus]))
            offset, scale = plus_minus(code_plus, code_minus, gravity)
            link = calibration.axes[axis]
            tilt = float(np.degrees(np.arccos(np.clip(np.min(np.abs(up[np.concatenate([plus, minus]), axis])),
                                                      -1.0, 1.0))))
            rows.append(PlateauRow(temperature=mean_t, axis=axis, offset=float(offset), scale=float(scale),
                                   link_offset=float(link.offset + link.offset_drift(n)),
                                   link_scale=float(link.scale * link.scale_factor(n)), tilt_deg=tilt))
    return tuple(rows)
