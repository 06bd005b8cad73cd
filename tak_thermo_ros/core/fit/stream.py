"""The paper's least-squares fit over a run that arrives in blocks, in memory that does not grow.

Per axis the fit of :func:`~tak_thermo_ros.core.fit.fit_calibration` is a linear least-squares
problem with the columns ``u^j`` (j = 0..q), ``f u^j`` (j = 0..p) and the target ``N``, where
``u = (N_t - N_t,ref) / n_scale``. Its triangular factor ``R`` of ``[X | N]`` is accumulated
block by block (a tall-skinny QR: ``R <- qr([R; block])``), which is as accurate as a QR of
the whole design and never forms ``X^T X``. The least-squares solution, the residual sum of
squares (``R``'s last diagonal entry squared) and the rank test follow from ``R`` alone.

``N_t,ref`` and ``n_scale`` depend on the temperature range of the whole run, which is known
only at its end. The columns are therefore built about a provisional reference and scale
(from the range seen so far, with room to double); when the range outgrows them, and once at
the end, ``R`` is carried over to the new reference exactly: the powers of
``u_new = a u_old + b`` are a fixed upper-triangular combination ``T`` of the old powers
(binomial coefficients), so ``R_new = R_old T`` is again triangular. Each change costs about
one rounding error of ``|R| |T|`` (``|T|`` is at most a few tens): the fitted values agree with
the in-memory fit to about 1e-11 relative.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.fit.base import (
    INPUT_RESOLUTION,
    MIN_SAMPLES_PER_PARAMETER,
    FitResult,
    axis_from_coefficients,
    finish_fit_from_sums,
    held_scale_note,
)
from tak_thermo_ros.core.link.model import AXES, AxisModel, Calibration
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.errors import CalibrationError, FitError

HEADROOM = 2.0
"""The provisional scale is rebuilt when a temperature code lies this many scales from the reference."""


def _power_change(a: float, b: float, order: int) -> np.ndarray:
    """``T`` with ``(a u + b)^j = sum_i T[i, j] u^i`` for j = 0..order (upper triangular)."""
    change = np.zeros((order + 1, order + 1))
    for j in range(order + 1):
        for i in range(j + 1):
            change[i, j] = math.comb(j, i) * a ** i * b ** (j - i)
    return change


@dataclass
class _Basis:
    """Provisional reference and scale of the columns: ``u = (N_t - ref) / scale``."""

    ref: float
    scale: float


class StreamingFit:
    """Accumulate the paper's fit over blocks of aligned samples; :meth:`result` solves it.

    The arguments are those of :func:`~tak_thermo_ros.core.fit.fit_calibration`, which
    :meth:`result` equals to rounding on the same samples.
    """

    def __init__(self, *, bias_order: int = 3, scale_order: int = 2, temp_code_ref: float | None = None,
                 nominal_scale: tuple[float, float, float] | None = None) -> None:
        if bias_order < 1 or scale_order < 0:
            msg = f'orders must be bias >= 1 and scale >= 0, got bias {bias_order}, scale {scale_order}'
            raise FitError(msg)
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
        self._basis: _Basis | None = None
        self._factors = [np.zeros((self.columns, self.columns)) for _ in AXES]
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
        self._fit_basis_to_range()
        basis = self._basis
        assert basis is not None
        u = (codes - basis.ref) / basis.scale
        order = max(self.bias_order, self.scale_order)
        powers = [np.ones_like(u)]
        for _ in range(order):
            powers.append(powers[-1] * u)
        block = np.empty((len(u), self.columns))
        q, p = self.bias_order, self.scale_order
        for j in range(q + 1):
            block[:, j] = powers[j]
        for i in range(3):
            force = samples.reference[:, i]
            for j in range(p + 1):
                np.multiply(force, powers[j], out=block[:, q + 1 + j])
            block[:, -1] = samples.counts[:, i]
            stacked = np.vstack([self._factors[i], block])
            factor = np.linalg.qr(stacked, mode='r')
            self._factors[i] = factor[:self.columns] if factor.shape[0] >= self.columns else np.vstack(
                [factor, np.zeros((self.columns - factor.shape[0], self.columns))])
        self.count += len(u)

    def _fit_basis_to_range(self) -> None:
        ref = float(round((self.low + self.high) / 2.0))
        scale = max(abs(self.low - ref), abs(self.high - ref), 1.0)
        basis = self._basis
        if basis is None:
            self._basis = _Basis(ref, scale)
            return
        if (abs(self.low - basis.ref) <= HEADROOM * basis.scale
                and abs(self.high - basis.ref) <= HEADROOM * basis.scale):
            return
        self._change_basis(_Basis(ref, scale))

    def _change_basis(self, new: _Basis) -> None:
        """Carry every ``R`` over to columns in ``u_new`` (exact up to rounding)."""
        old = self._basis
        assert old is not None
        a = old.scale / new.scale
        b = (old.ref - new.ref) / new.scale
        q, p = self.bias_order, self.scale_order
        change = np.zeros((self.columns, self.columns))
        change[:q + 1, :q + 1] = _power_change(a, b, q)
        change[q + 1:q + p + 2, q + 1:q + p + 2] = _power_change(a, b, p)
        change[-1, -1] = 1.0
        self._factors = [factor @ change for factor in self._factors]
        self._basis = new

    # ----- solution -------------------------------------------------------------------------

    def check_observable(self) -> None:
        """The tests of :func:`fit_calibration` before it fits, with the same messages."""
        q, p = self.bias_order, self.scale_order
        needed = MIN_SAMPLES_PER_PARAMETER * (q + p + 2)
        if self.count < needed:
            msg = (f'too few samples: {self.count} usable counts samples, need at least {needed} '
                   f'for bias order {q} and scale order {p}')
            raise FitError(msg)
        if not self.has_reference:
            msg = 'no reference stream: a fit needs the true specific force'
            raise FitError(msg)
        if len(self._codes) < max(q, p) + 1:
            msg = (f'no temperature spread: the temperature code spans only {self.low:g}..{self.high:g} '
                   f'({len(self._codes)} distinct codes), need at least {max(q, p) + 1}')
            raise FitError(msg)

    def single_input_axes(self) -> tuple[bool, bool, bool]:
        """Per axis, whether the reference held one value only (as :func:`single_input_axes`)."""
        return tuple(not several for several in self._several_inputs)  # type: ignore[return-value]

    def result(self, *, dropped: dict[str, int] | None = None) -> FitResult:
        """The fitted calibration and its statistics, as :func:`fit_calibration` gives them.

        :raises FitError: when the data cannot determine the model (the same messages).
        """
        self.check_observable()
        q, p = self.bias_order, self.scale_order
        low, high = self.low, self.high
        ref = float(round((low + high) / 2.0)) if self.temp_code_ref is None else float(self.temp_code_ref)
        n_scale = max(abs(low - ref), abs(high - ref), 1.0)
        self._change_basis(_Basis(ref, n_scale))
        held = self.single_input_axes()
        axes_models: list[AxisModel] = []
        sums: list[float] = []
        held_inputs: list[str] = []
        design = q + p + 2
        for i, name in enumerate(AXES):
            factor = self._factors[i]
            if held[i]:
                nominal = self.nominal_scale
                force0 = self._first_input[i] if self._first_input else 0.0
                if nominal is None or not nominal[i] > 0.0:
                    msg = (f'axis {name} sees one input only ({force0:g} m/s^2): its scale cannot be '
                           f'fitted, give the nominal scale (counts per m/s^2) to hold it')
                    raise FitError(msg)
                model, rss = self._offset_only(factor, float(nominal[i]), n_scale, (low - ref, high - ref), name)
                axes_models.append(model)
                sums.append(rss)
                held_inputs.append(f'{name} input {force0:.4g} at nominal scale {nominal[i]:g}')
                continue
            # Column order of fit_calibration: f u^0..f u^p, then u^0..u^q.
            order = list(range(q + 1, q + p + 2)) + list(range(q + 1))
            triangle = factor[:design, :design][:, order]
            target = factor[:design, -1]
            norms = np.sqrt(np.sum(triangle ** 2, axis=0) / self.count)
            norms[norms == 0.0] = 1.0
            scaled = triangle / norms
            singular = np.linalg.svd(scaled, compute_uv=False)
            rank = int(np.count_nonzero(singular > np.finfo(float).eps * max(self.count, design) * singular[0]))
            if rank < design or singular[-1] < 1e-9 * singular[0]:
                msg = (f'axis {name}: the data cannot separate the model terms '
                       f'(rank {rank} of {design}); the inputs and temperatures do not '
                       f'cover bias order {q} and scale order {p}')
                raise FitError(msg)
            solution = np.linalg.solve(scaled, target)
            axes_models.append(axis_from_coefficients(solution / norms, bias_order=q, scale_order=p, n_scale=n_scale,
                                                      code_offset_range=(low - ref, high - ref), name=name))
            sums.append(float(factor[-1, -1] ** 2 + np.sum((scaled @ solution - target) ** 2)))
        notes = (held_scale_note(held, held_inputs),) if held_inputs else ()
        calibration = Calibration(temp_code_ref=ref, temp_code_min=low, temp_code_max=high,
                                  axes=tuple(axes_models), notes=notes)  # type: ignore[arg-type]
        parameters = [q + 1 if held[i] else q + p + 2 for i in range(3)]
        return finish_fit_from_sums(calibration, sums, self.count, parameters, dropped=dict(dropped or {}))

    def _offset_only(self, factor: np.ndarray, scale: float, n_scale: float,
                     code_offset_range: tuple[float, float], name: str) -> tuple[AxisModel, float]:
        """Offset polynomial with the scale held: least squares of ``N - K0 f`` on the powers."""
        q = self.bias_order
        combination = np.zeros(self.columns)
        combination[-1] = 1.0
        combination[q + 1] = -scale  # the column f u^0 = f
        projected = factor @ combination
        triangle = factor[:q + 1, :q + 1]
        solution, _, rank, _ = np.linalg.lstsq(triangle, projected[:q + 1], rcond=None)
        singular = np.linalg.svd(triangle, compute_uv=False)
        rank = int(np.count_nonzero(singular > np.finfo(float).eps * max(self.count, q + 1) * singular[0]))
        if rank < q + 1:
            msg = f'axis {name}: the temperature codes do not cover bias order {q}'
            raise FitError(msg)
        rss = float(np.sum(projected[q + 1:] ** 2) + np.sum((triangle @ solution - projected[:q + 1]) ** 2))
        model = axis_from_coefficients(solution, bias_order=q, scale_order=0, n_scale=n_scale,
                                       code_offset_range=code_offset_range, name=name, held_scale=scale)
        return model, rss


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
    their state (:func:`~tak_thermo_ros.core.link.stream_correction.basis_from`). The design per axis
    is that of :func:`~tak_thermo_ros.core.fit.effects.fit_with_effects` with the shapes fixed.

    :param effects: effect instances (their shapes are kept, their amplitudes refitted).
    :param first_pass: the base fit of the same run (temperature range, held axes, count).
    """

    def __init__(self, effects: Sequence, first_pass: StreamingFit) -> None:
        from tak_thermo_ros.core.effects.base import INPUT
        self.effects = tuple(effects)
        self.input_effects = [e for e in self.effects if e.kind == INPUT]
        self.offset_effects = [e for e in self.effects if e.kind != INPUT]
        self.bias_order, self.scale_order = first_pass.bias_order, first_pass.scale_order
        self.nominal_scale = first_pass.nominal_scale
        first_pass.check_observable()
        self.low, self.high = first_pass.low, first_pass.high
        temp_code_ref = first_pass.temp_code_ref
        self.ref = float(round((self.low + self.high) / 2.0)) if temp_code_ref is None else float(temp_code_ref)
        self.n_scale = max(abs(self.low - self.ref), abs(self.high - self.ref), 1.0)
        self.held = first_pass.single_input_axes()
        self.first_inputs = list(first_pass._first_input or [0.0, 0.0, 0.0])
        if any(self.held) and self.nominal_scale is None:
            first_pass.result()  # raises the in-memory fit's message
        self._states: list = [None] * len(self.offset_effects)
        self._started = False
        self._factors: list[np.ndarray | None] = [None, None, None]
        self.count = 0

    def _design(self, axis: int, force: np.ndarray, powers: list[np.ndarray], counts: np.ndarray,
                bases: list[np.ndarray]) -> tuple[np.ndarray, list[str]]:
        q, p = self.bias_order, self.scale_order
        if self.held[axis]:
            columns = [powers[j] for j in range(q + 1)]
            names = ['the offset polynomial'] * (q + 1)
            target = counts[:, axis] - self.nominal_scale[axis] * force[:, axis]  # type: ignore[index]
        else:
            columns = [force[:, axis] * powers[j] for j in range(p + 1)] + [powers[j] for j in range(q + 1)]
            names = ['the scale polynomial'] * (p + 1) + ['the offset polynomial'] * (q + 1)
            target = counts[:, axis]
        for effect in self.input_effects:
            for name, column in effect.input_columns(axis, force):
                columns.append(column)
                names.append(f'{effect.name} ({name})')
        for effect, basis in zip(self.offset_effects, bases):
            for b in range(basis.shape[1]):
                columns.append(basis[:, b])
                names.append(effect.name)
        return np.column_stack([*columns, target]), names

    def add(self, samples: AlignedSamples) -> None:
        """Add the next block of aligned samples (in time order)."""
        from tak_thermo_ros.core.effects.base import effect_input
        from tak_thermo_ros.core.link.stream_correction import basis_from
        if not len(samples) or samples.reference is None:
            return
        codes = np.clip(np.asarray(samples.temp_code, dtype=float), self.low, self.high)
        stamps = samples.stamp_s
        bases = []
        for index, effect in enumerate(self.offset_effects):
            basis, self._states[index] = basis_from(effect, self._states[index], stamps,
                                                    effect_input(effect, codes, samples.aux), started=self._started)
            bases.append(basis)
        self._started = True
        u = (codes - self.ref) / self.n_scale
        powers = [np.ones_like(u)]
        for _ in range(max(self.bias_order, self.scale_order)):
            powers.append(powers[-1] * u)
        for i in range(3):
            block, self.names = self._design(i, samples.reference, powers, samples.counts, bases)
            previous = self._factors[i]
            stacked = block if previous is None else np.vstack([previous, block])
            factor = np.linalg.qr(stacked, mode='r')
            width = block.shape[1]
            if factor.shape[0] < width:
                factor = np.vstack([factor, np.zeros((width - factor.shape[0], width))])
            self._factors[i] = factor[:width]
        self.count += len(u)

    def result(self, *, dropped: dict[str, int], shape_errors: dict[str, float] | None = None,
               parameters: Sequence[int] | None = None) -> FitResult:
        """The calibration with the effects' amplitudes refitted over the whole run.

        :param shape_errors: standard errors of the shape parameters (from the subsample fit).
        :param parameters: fitted parameters per axis, shapes included (the subsample fit's;
            default: the amplitudes and base terms only).
        """
        q, p = self.bias_order, self.scale_order
        low, high, ref, n_scale = self.low, self.high, self.ref, self.n_scale
        betas, sums, widths, errors = [], [], [], dict(shape_errors or {})
        for i in range(3):
            factor = self._factors[i]
            assert factor is not None
            triangle, target = factor[:-1, :-1], factor[:-1, -1]
            width = triangle.shape[1]
            norms = np.sqrt(np.sum(triangle ** 2, axis=0) / self.count)
            norms[norms == 0.0] = 1.0
            scaled = triangle / norms
            solution, _, rank, _ = np.linalg.lstsq(scaled, target, rcond=None)
            singular = np.linalg.svd(scaled, compute_uv=False)
            rank = int(np.count_nonzero(singular > np.finfo(float).eps * max(self.count, width) * singular[0]))
            if rank < width:
                offender = next((self.names[end - 1] for end in range(1, width + 1)
                                 if np.linalg.matrix_rank(scaled[:, :end]) < end), self.names[-1])
                msg = (f'axis {AXES[i]}: the data cannot separate {offender} from the other model terms '
                       f'(the inputs and temperatures of this run do not excite it)')
                raise FitError(msg)
            beta = solution / norms
            rss = float(factor[-1, -1] ** 2 + np.sum((scaled @ solution - target) ** 2))
            betas.append(beta)
            sums.append(rss)
            widths.append(width)
            dof = max(self.count - (parameters[i] if parameters is not None else width), 1)
            covariance = (rss / dof) * np.linalg.inv(scaled.T @ scaled)
            amplitude_errors = np.sqrt(np.clip(np.diag(covariance), 0.0, None)) / norms
            position = (q + 1) if self.held[i] else (q + p + 2)
            for effect in self.input_effects:
                for name, _ in effect.input_columns(i, np.zeros((1, 3))):
                    errors[f'{effect.name}.{name}'] = float(amplitude_errors[position])
                    position += 1
            for effect in self.offset_effects:
                for name in effect.amplitude_names()[i]:
                    errors[f'{effect.name}.{name}'] = float(amplitude_errors[position])
                    position += 1
        axes_models = [axis_from_coefficients(betas[i], bias_order=q, scale_order=p, n_scale=n_scale,
                                              code_offset_range=(low - ref, high - ref), name=AXES[i],
                                              held_scale=(self.nominal_scale[i]  # type: ignore[index]
                                                          if self.held[i] else None))
                       for i in range(3)]
        fitted = []
        for effect in self.effects:
            values = {name: effect[name] for name in effect.shape_names()}
            for i in range(3):
                position = (q + 1) if self.held[i] else (q + p + 2)
                for other in self.input_effects:
                    columns = other.input_columns(i, np.zeros((1, 3)))
                    if other is effect:
                        for k, (name, _) in enumerate(columns):
                            values[name] = float(betas[i][position + k])
                    position += len(columns)
                for other in self.offset_effects:
                    names = other.amplitude_names()[i]
                    if other is effect:
                        for k, name in enumerate(names):
                            values[name] = float(betas[i][position + k])
                    position += len(names)
            try:
                fitted.append(type(effect).from_values(values, key=f'effect {effect.name}', complete=True))
            except CalibrationError as err:
                msg = f'fitted {err}'
                raise FitError(msg) from None
        held_inputs = [f'{AXES[i]} input {self.first_inputs[i]:.4g} '
                       f'at nominal scale {self.nominal_scale[i]:g}'  # type: ignore[index]
                       for i in range(3) if self.held[i]]
        notes = (held_scale_note(self.held, held_inputs),) if held_inputs else ()
        calibration = Calibration(temp_code_ref=ref, temp_code_min=low, temp_code_max=high, axes=tuple(axes_models),
                                  notes=notes, effects=tuple(fitted))  # type: ignore[arg-type]
        counted = list(parameters) if parameters is not None else widths
        return finish_fit_from_sums(calibration, sums, self.count, counted, dropped=dict(dropped),
                                    parameter_errors=errors)
