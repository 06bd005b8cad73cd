"""The paper's least-squares fit over a run that arrives in blocks, in memory that does not grow.

The same pipeline as in memory: each block's columns come from
:func:`~tak_thermo_ros.core.fit.design.axis_design` (the paper's ``f u^j`` and ``u^j``, then each
effect's columns, the target last), the triangular factor ``R`` of ``[X | N]`` is accumulated
block by block (:class:`~tak_thermo_ros.core.fit.solve.BlockedQR`, a tall-skinny QR that is as
accurate as a QR of the whole design and never forms ``X^T X``), and the solve and the model
are those of every fit (:func:`~tak_thermo_ros.core.fit.solve.solve_factor`,
:mod:`~tak_thermo_ros.core.fit.model`).

``N_t,ref`` and ``n_scale`` depend on the temperature range of the whole run, which is known
only at its end. :class:`StreamingFit` therefore builds the columns about a provisional
reference and scale (from the range seen so far, with room to double); when the range outgrows
them, and once at the end, ``R`` is carried over to the new reference exactly: the powers of
``u_new = a u_old + b`` are a fixed upper-triangular combination ``T`` of the old powers
(binomial coefficients), so ``R_new = R_old T`` is again triangular. Each change costs about
one rounding error of ``|R| |T|`` (``|T|`` is at most a few tens): the fitted values agree with
the in-memory fit to about 1e-11 relative. An axis that turns out to see one input only is
solved from ``R`` too: its columns ``[u^j | N - K0 f]`` are a fixed combination ``C`` of the
accumulated ones, and ``qr(R C)`` is their factor.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.effects.base import INPUT, Effect, basis_from, effect_input
from tak_thermo_ros.core.fit.base import check_separated
from tak_thermo_ros.core.fit.binned_run import BinnedRun, axis_sandwich
from tak_thermo_ros.core.fit.design import (
    INPUT_RESOLUTION,
    Column,
    Frame,
    axis_design,
    check_counts,
    check_orders,
    held_scale,
    not_excited,
)
from tak_thermo_ros.core.fit.link_uncertainty import HeldSpreads, block_normal, link_uncertainty
from tak_thermo_ros.core.fit.model import (
    FitResult,
    amplitude_errors,
    calibration_from,
    finish_fit_from_sums,
    fitted_effects,
    held_notes,
)
from tak_thermo_ros.core.fit.solve import BlockedQR, Solution, solve_factor
from tak_thermo_ros.core.fit.uncertainty import not_below
from tak_thermo_ros.core.link.model import AXES
from tak_thermo_ros.core.link.uncertainty import LinkUncertainty
from tak_thermo_ros.core.records.record import AlignedSamples

HEADROOM = 2.0
"""The provisional scale is rebuilt when a temperature code lies this many scales from the reference."""


def _power_change(a: float, b: float, order: int) -> np.ndarray:
    """``T`` with ``(a u + b)^j = sum_i T[i, j] u^i`` for j = 0..order (upper triangular)."""
    change = np.zeros((order + 1, order + 1))
    for j in range(order + 1):
        for i in range(j + 1):
            change[i, j] = math.comb(j, i) * a ** i * b ** (j - i)
    return change


class StreamingFit:
    """Accumulate the paper's fit over blocks of aligned samples; :meth:`result` solves it.

    The arguments are those of :func:`~tak_thermo_ros.core.fit.fit_calibration`, which
    :meth:`result` equals to rounding on the same samples.
    """

    def __init__(self, *, bias_order: int = 3, scale_order: int = 2, temp_code_ref: float | None = None,
                 nominal_scale: tuple[float, float, float] | None = None) -> None:
        check_orders(bias_order, scale_order)
        self.bias_order = bias_order
        self.scale_order = scale_order
        self.temp_code_ref = temp_code_ref
        self.nominal_scale = nominal_scale
        self.columns = bias_order + scale_order + 3
        self.count = 0
        self.low = math.inf
        self.high = -math.inf
        self._codes: set[float] = set()
        self._first_input: list[float] | None = None
        self._first_rounded: np.ndarray | None = None
        self._several_inputs = [False, False, False]
        self._frame: Frame | None = None
        self._blocked = [BlockedQR(self.columns) for _ in AXES]
        self._binned = BinnedRun()
        """The run's bins in time order, for the link's sandwich (:meth:`uncertainty`): bounded."""
        self.has_reference = True

    # ----- accumulation --------------------------------------------------------------------

    def add(self, samples: AlignedSamples) -> None:
        """Add a block of aligned samples (with the reference held on them)."""
        if not len(samples):
            return
        if samples.reference is None:
            self.has_reference = False
            return
        codes = np.asarray(samples.temp_code, dtype=float)
        self.low = min(self.low, float(codes.min()))
        self.high = max(self.high, float(codes.max()))
        if len(self._codes) <= max(self.bias_order, self.scale_order) + 1:
            self._codes.update(np.unique(codes)[:max(self.bias_order, self.scale_order) + 2].tolist())
        rounded = np.round(samples.reference / INPUT_RESOLUTION)
        if self._first_rounded is None:
            self._first_rounded = rounded[0].copy()
            self._first_input = [float(v) for v in samples.reference[0]]
        for i in range(3):
            if not self._several_inputs[i]:
                self._several_inputs[i] = bool(np.any(rounded[:, i] != self._first_rounded[i]))
        self._fit_frame_to_range()
        frame = self._frame
        assert frame is not None
        powers = frame.powers(codes, max(self.bias_order, self.scale_order))
        for i in range(3):
            self._blocked[i].add(axis_design(i, powers, samples.reference, samples.counts, bias_order=self.bias_order,
                                             scale_order=self.scale_order, with_target=True).matrix)
        self._binned.add(samples.stamp_s, codes, samples.reference, samples.counts)
        self.count += len(codes)

    def _fit_frame_to_range(self) -> None:
        frame = Frame.of_range(self.low, self.high)
        old = self._frame
        if old is None:
            self._frame = frame
            return
        if (abs(self.low - old.ref) <= HEADROOM * old.n_scale
                and abs(self.high - old.ref) <= HEADROOM * old.n_scale):
            return
        self._change_frame(frame)

    def _change_frame(self, new: Frame) -> None:
        """Carry every ``R`` over to columns in ``u_new`` (exact up to rounding)."""
        old = self._frame
        assert old is not None
        a = old.n_scale / new.n_scale
        b = (old.ref - new.ref) / new.n_scale
        q, p = self.bias_order, self.scale_order
        change = np.zeros((self.columns, self.columns))
        change[:p + 1, :p + 1] = _power_change(a, b, p)  # f u^0 .. f u^p
        change[p + 1:p + q + 2, p + 1:p + q + 2] = _power_change(a, b, q)  # u^0 .. u^q
        change[-1, -1] = 1.0
        for factor in self._blocked:
            factor.change_columns(change)
        self._frame = new

    @property
    def _factors(self) -> list[np.ndarray]:
        """The triangular factor of each axis (all the memory the accumulator holds)."""
        return [blocked.factor for blocked in self._blocked]

    # ----- solution -------------------------------------------------------------------------

    def check_observable(self) -> None:
        """The tests of :func:`fit_calibration` before it fits, with the same messages."""
        check_counts(self.count, self.has_reference, len(self._codes), (self.low, self.high), self.bias_order,
                     self.scale_order)

    def single_input_axes(self) -> tuple[bool, bool, bool]:
        """Per axis, whether the reference held one value only (as :func:`single_input_axes`)."""
        return tuple(not several for several in self._several_inputs)  # type: ignore[return-value]

    def frame(self) -> Frame:
        """The frame of the whole run (after :meth:`check_observable`)."""
        return Frame.of_range(self.low, self.high, self.temp_code_ref)

    def first_input(self) -> list[float]:
        """The reference of the run's first sample."""
        return list(self._first_input or [0.0, 0.0, 0.0])

    def result(self, *, dropped: dict[str, int] | None = None) -> FitResult:
        """The fitted calibration and its statistics, as :func:`fit_calibration` gives them.

        :raises FitError: when the data cannot determine the model (the same messages).
        """
        self.check_observable()
        q, p = self.bias_order, self.scale_order
        frame = self.frame()
        self._change_frame(frame)
        single, first_input = self.single_input_axes(), self.first_input()
        held: list[float | None] = []
        coefficients, sums = [], []
        for i, name in enumerate(AXES):
            held.append(held_scale(i, single, self.nominal_scale, first_input))
            factor = self._blocked[i]
            solution = factor.solution() if held[i] is None else self._offset_only(factor, held[i])
            check_separated(solution, name, q, p, held=held[i] is not None)
            coefficients.append(solution.coefficients)
            sums.append(solution.rss)
        calibration = calibration_from(frame, coefficients, bias_order=q, scale_order=p, held_scales=held,
                                       notes=held_notes(held, first_input))
        parameters = [len(beta) for beta in coefficients]
        return finish_fit_from_sums(calibration, sums, self.count, parameters, dropped=dict(dropped or {}))

    def uncertainty(self, sensor: str, spreads: HeldSpreads = HeldSpreads(), *,
                    direction_taken: bool = False) -> LinkUncertainty:
        """The link's own uncertainty after :meth:`result` (:mod:`~tak_thermo_ros.core.fit.link_uncertainty`).

        Per axis its offset and scale polynomials, the errors of the fitted ones from the residual
        with its own noise model (:func:`~tak_thermo_ros.core.fit.binned_run.axis_sandwich`: never
        below the white-noise errors), a held scale (an axis that saw one input) through its spread; the
        gyroscope's offsets only (at rest its scales multiply the Earth rate alone).

        :param direction_taken: the reference is the run's mean measured direction (a static run
            without reference topics): the offsets across it went into that direction (a tilt of
            the board), so their constants are undetermined: their spread is the default's.
        """
        q, p = self.bias_order, self.scale_order
        frame = self.frame()
        single, first_input = self.single_input_axes(), self.first_input()
        names, kinds, free, held, theta, blocks = [], [], [], [], [], []
        for i, name in enumerate(AXES):
            start = len(names)
            names += [f'{name}.scale' + (f'_T{j}' if j else '') for j in range(p + 1)]
            names += [f'{name}.offset' + (f'_T{j}' if j else '') for j in range(q + 1)]
            kinds += ['scale' if j == 0 else 'scale_T' for j in range(p + 1)]
            kinds += ['offset' if j == 0 else 'offset_T' for j in range(q + 1)]
            scale = held_scale(i, single, self.nominal_scale, first_input)
            factor = self._blocked[i]
            if scale is None:
                solution = factor.solution()
                values, fitted = solution.coefficients, list(range(p + q + 2))
            else:
                solution = self._offset_only(self._blocked[i], scale)
                values = np.concatenate([[scale], np.zeros(p), solution.coefficients])
                fitted = list(range(p + 1, p + q + 2))
                held += [start + j for j in range(p + 1)]
            design = factor.factor[:, :-1]
            variance = solution.rss / max(self.count - len(fitted), 1)
            normal = design.T @ design
            block = np.linalg.pinv(normal[np.ix_(fitted, fitted)]) * variance
            sandwich = axis_sandwich(self._binned, frame, i, solution.coefficients,
                                     normal[np.ix_(fitted, fitted)], variance, bias_order=q, scale_order=p,
                                     held_scale=scale)
            if sandwich is not None:  # the residual's wander moves the curve more than white noise would
                block = not_below(block, sandwich)
            free += [start + j for j in fitted]
            theta.append(values)
            blocks.append((block, variance))
        normal, gradient = block_normal([blocked.factor for blocked in self._blocked], theta)
        covariance = np.zeros((len(free), len(free)))
        variances = np.zeros(len(names))
        position = 0
        for i, (block, variance) in enumerate(blocks):
            covariance[position:position + len(block), position:position + len(block)] = block
            position += len(block)
            variances[i * (p + q + 2):(i + 1) * (p + q + 2)] = variance
        carried = None if sensor == 'accel' else [j for j in [*free, *held] if kinds[j] in ('offset', 'offset_T')]
        found = link_uncertainty(names, kinds, normal, gradient, free, covariance, variances, held, sensor=sensor,
                                 temperature_scale=frame.n_scale, spreads=spreads, carried=carried)
        if not direction_taken:
            return found
        along = int(np.argmax(np.abs(first_input)))
        across = [found.terms.index(f'{name}.offset') for i, name in enumerate(AXES) if i != along]
        matrix = found.covariance.copy()
        matrix[across, :] = 0.0
        matrix[:, across] = 0.0
        matrix[across, across] = spreads.spread(sensor, 'offset', 1.0) ** 2
        held_names = (*found.held, *(found.terms[j] for j in across))
        return LinkUncertainty.of(found.terms, matrix, found.temperature_scale, held_names,
                                  (*found.held_from, *(['default'] * len(across))), found.beyond)

    def _offset_only(self, factor: BlockedQR, scale: float) -> Solution:
        """The offset polynomial with the scale held: least squares of ``N - K0 f`` on ``u^0 .. u^q``.

        Those columns are ``[X | N] C``; the factor of ``R C`` is theirs.
        """
        q, p = self.bias_order, self.scale_order
        combination = np.zeros((self.columns, q + 2))
        for j in range(q + 1):
            combination[p + 1 + j, j] = 1.0
        combination[-1, -1] = 1.0
        combination[0, -1] = -scale  # the column f u^0 = f
        return solve_factor(np.linalg.qr(factor.factor @ combination, mode='r'), self.count)


def fit_in_blocks(blocks: Sequence[AlignedSamples], **options) -> FitResult:
    """:class:`StreamingFit` over a sequence of aligned blocks (drop counts summed)."""
    fit = StreamingFit(**options)
    dropped: dict[str, int] = {}
    for block in blocks:
        fit.add(block)
        for reason, count in block.dropped.items():
            dropped[reason] = dropped.get(reason, 0) + count
    return fit.result(dropped=dropped)


class StreamingEffectFit:
    """The amplitudes of effects with fixed shapes, with the base model, over blocks in time order.

    The second pass of a long run's fit with effects: the shapes (time constants, widths,
    knots) come from a fit on a subsample; here every amplitude and the base model are solved
    by a blocked QR over the whole run, the effects' signals continued across blocks from
    their state (:func:`~tak_thermo_ros.core.effects.base.basis_from`). The design per axis
    is that of :func:`~tak_thermo_ros.core.fit.effects.fit_with_effects` with the shapes fixed.

    :param effects: effect instances (their shapes are kept, their amplitudes refitted).
    :param first_pass: the base fit of the same run (temperature range, held axes, count).
    """

    def __init__(self, effects: Sequence[Effect], first_pass: StreamingFit) -> None:
        self.effects = tuple(effects)
        self.input_effects = [e for e in self.effects if e.kind == INPUT]
        self.offset_effects = [e for e in self.effects if e.kind != INPUT]
        self.bias_order, self.scale_order = first_pass.bias_order, first_pass.scale_order
        first_pass.check_observable()
        self.frame = first_pass.frame()
        self.first_inputs = first_pass.first_input()
        single = first_pass.single_input_axes()
        if any(single) and first_pass.nominal_scale is None:
            first_pass.result()  # raises the in-memory fit's message
        self.held = [held_scale(i, single, first_pass.nominal_scale, self.first_inputs) for i in range(3)]
        self._states: list = [None] * len(self.offset_effects)
        self._started = False
        self._blocked: list[BlockedQR | None] = [None, None, None]
        self.columns: list[tuple[Column, ...]] = [(), (), ()]
        self.count = 0

    def add(self, samples: AlignedSamples) -> None:
        """Add the next block of aligned samples (in time order)."""
        if not len(samples) or samples.reference is None:
            return
        codes = np.clip(np.asarray(samples.temp_code, dtype=float), self.frame.low, self.frame.high)
        stamps = samples.stamp_s
        bases = []
        for index, effect in enumerate(self.offset_effects):
            basis, self._states[index] = basis_from(effect, self._states[index], stamps,
                                                    effect_input(effect, codes, samples.aux), started=self._started)
            bases.append((effect, basis))
        self._started = True
        powers = self.frame.powers(codes, max(self.bias_order, self.scale_order))
        for i in range(3):
            design = axis_design(i, powers, samples.reference, samples.counts, bias_order=self.bias_order,
                                 scale_order=self.scale_order, held_scale=self.held[i],
                                 input_effects=self.input_effects, offset_bases=bases, with_target=True)
            if self._blocked[i] is None:
                self._blocked[i] = BlockedQR(design.matrix.shape[1])
            self._blocked[i].add(design.matrix)  # type: ignore[union-attr]
            self.columns[i] = design.columns
        self.count += len(codes)

    def result(self, *, dropped: dict[str, int], shape_errors: dict[str, float] | None = None,
               parameters: Sequence[int] | None = None) -> FitResult:
        """The calibration with the effects' amplitudes refitted over the whole run.

        :param shape_errors: standard errors of the shape parameters (from the subsample fit).
        :param parameters: fitted parameters per axis, shapes included (the subsample fit's;
            default: the amplitudes and base terms only).
        """
        betas, sums, widths, errors = [], [], [], dict(shape_errors or {})
        for i in range(3):
            factor = self._blocked[i]
            assert factor is not None
            solution = factor.solution()
            if not solution.full_rank():
                raise not_excited(i, solution.first_dependent([column.term for column in self.columns[i]]))
            betas.append(solution.coefficients)
            sums.append(solution.rss)
            widths.append(solution.width)
            dof = max(self.count - (parameters[i] if parameters is not None else solution.width), 1)
            covariance = (solution.rss / dof) * np.linalg.inv(solution.scaled.T @ solution.scaled)
            errors.update(amplitude_errors(self.columns[i],
                                           np.sqrt(np.clip(np.diag(covariance), 0.0, None)) / solution.norms))
        calibration = calibration_from(self.frame, betas, bias_order=self.bias_order, scale_order=self.scale_order,
                                       held_scales=self.held, notes=held_notes(self.held, self.first_inputs),
                                       effects=fitted_effects(self.effects, self.columns, betas))
        counted = list(parameters) if parameters is not None else widths
        return finish_fit_from_sums(calibration, sums, self.count, counted, dropped=dict(dropped),
                                    parameter_errors=errors)
