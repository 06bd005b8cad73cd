"""The fit's columns: samples -> per axis the design matrix and its target.

Per axis the model is linear in the base coefficients and in every effect's amplitudes once the
effects' shapes are fixed. The columns come in one order, which every fit shares (in memory,
with effects, over blocks):

1. the paper's model: ``f u^0 .. f u^p`` (the scale polynomial, ``K0, K0 a1..ap``), then
   ``u^0 .. u^q`` (the offset polynomial, ``dNs0, c1..cq``), in ``u = (N_t - N_t,ref) / n_scale``
   (:class:`Frame`) for conditioning; an axis whose scale is held (one input only) has the
   offset polynomial alone and the target ``N - K0 f``;
2. each input effect's columns (terms in the specific force, e.g. ``f_j`` for cross-axis);
3. each offset effect's basis signals that the axis uses (their amplitudes).

Each column carries a :class:`Column` label: what a message calls it, and which effect's
parameter it holds, so that reading a solution back (:mod:`tak_thermo_ros.core.fit.model`)
needs no positions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.effects.base import Effect, checked_basis, effect_input
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.errors import FitError

MIN_SAMPLES_PER_PARAMETER = 10
INPUT_RESOLUTION = 1e-6
"""Two reference values closer than this (m/s^2) count as the same input."""
SCALE_POLYNOMIAL = 'the scale polynomial'
OFFSET_POLYNOMIAL = 'the offset polynomial'


def check_orders(bias_order: int, scale_order: int) -> None:
    """The polynomial orders a fit accepts: bias ``q >= 1``, scale ``p >= 0``."""
    if bias_order < 1 or scale_order < 0:
        msg = f'orders must be bias >= 1 and scale >= 0, got bias {bias_order}, scale {scale_order}'
        raise FitError(msg)


class ShortRecord(FitError):
    """A record with too few usable samples, or too little temperature spread, for a sensor's fit.

    One sensor's shortage: ``fit`` holds that sensor at nominal and says so where another
    sensor of the record can be fitted (``passes/fit.py``, ``cli/fit.py``).
    """


def check_observable(samples: AlignedSamples, bias_order: int, scale_order: int) -> None:
    """Enough samples, a reference, and a temperature spread for the orders (else a :class:`FitError`).

    :raises ShortRecord: too few samples, or too few distinct temperatures.
    """
    codes = samples.temp_code
    check_counts(len(samples), samples.reference is not None, np.unique(codes).size,
                 (float(codes.min()), float(codes.max())) if len(codes) else (0.0, 0.0), bias_order, scale_order)


def check_counts(count: int, has_reference: bool, distinct_codes: int, code_range: tuple[float, float],
                 bias_order: int, scale_order: int) -> None:
    """:func:`check_observable` on what a pass counted (the in-memory and the streaming fit alike)."""
    needed = MIN_SAMPLES_PER_PARAMETER * (bias_order + scale_order + 2)
    if count < needed:
        msg = (f'too few samples: {count} usable samples, need at least {needed} '
               f'for bias order {bias_order} and scale order {scale_order}')
        raise ShortRecord(msg)
    if not has_reference:
        msg = 'no reference stream: a fit needs the true specific force'
        raise FitError(msg)
    if distinct_codes < max(bias_order, scale_order) + 1:
        low, high = code_range
        msg = (f'no temperature spread: the temperature code spans only {low:g}..{high:g} '
               f'({distinct_codes} distinct codes), need at least {max(bias_order, scale_order) + 1}')
        raise ShortRecord(msg)


def not_excited(axis: int, term: str) -> FitError:
    """The error of a column the run cannot separate from the others on one axis."""
    return FitError(f'axis {"xyz"[axis]}: this run does not excite {term} (no fit)')


def single_input_axes(samples: AlignedSamples) -> tuple[bool, bool, bool]:
    """Per axis: whether the reference holds one value only (scale and offset inseparable)."""
    return tuple(np.unique(np.round(samples.reference[:, i] / INPUT_RESOLUTION)).size < 2
                 for i in range(3))  # type: ignore[return-value]


def held_scale(axis: int, held: Sequence[bool], nominal_scale: Sequence[float] | None,
               first_input: Sequence[float]) -> float | None:
    """The nominal scale axis ``axis`` is held at when it sees one input only (``None``: fitted).

    :param held: per axis, whether it sees one input only (:func:`single_input_axes`).
    :param first_input: the reference of the first sample (the one input, for the message).
    :raises FitError: a held axis without a positive nominal scale.
    """
    if not held[axis]:
        return None
    if nominal_scale is None or not nominal_scale[axis] > 0.0:
        msg = (f'axis {"xyz"[axis]} sees one input only ({first_input[axis]:g} m/s^2): its scale cannot be '
               f'fitted, give the nominal scale (counts per m/s^2) to hold it')
        raise FitError(msg)
    return float(nominal_scale[axis])


@dataclass(frozen=True)
class Frame:
    """Where the polynomials stand: ``u = (N_t - ref) / n_scale`` over the calibrated codes ``low..high``."""

    ref: float
    low: float
    high: float
    n_scale: float

    @classmethod
    def of_range(cls, low: float, high: float, temp_code_ref: float | None = None) -> Frame:
        """The frame of a run whose codes span ``low..high``; ``N_t,ref`` by default the middle, rounded."""
        ref = float(round((low + high) / 2.0)) if temp_code_ref is None else float(temp_code_ref)
        return cls(ref=ref, low=low, high=high, n_scale=max(abs(low - ref), abs(high - ref), 1.0))

    @classmethod
    def of_samples(cls, samples: AlignedSamples, temp_code_ref: float | None = None) -> Frame:
        """The frame of the samples' temperature codes."""
        return cls.of_range(float(samples.temp_code.min()), float(samples.temp_code.max()), temp_code_ref)

    @property
    def code_offset_range(self) -> tuple[float, float]:
        """``(low - ref, high - ref)``."""
        return self.low - self.ref, self.high - self.ref

    def powers(self, temp_code: np.ndarray, order: int) -> list[np.ndarray]:
        """``u^0 .. u^order`` of the codes."""
        return powers((temp_code - self.ref) / self.n_scale, order)


def powers(u: np.ndarray, order: int) -> list[np.ndarray]:
    """``u^0 .. u^order`` by repeated products."""
    out = [np.ones_like(u)]
    for _ in range(order):
        out.append(out[-1] * u)
    return out


@dataclass(frozen=True)
class Column:
    """A design column's label.

    :param term: what a message calls it (``'the offset polynomial'``, ``'cross_axis (c_xy)'``, ``'warmup'``).
    :param effect: the effect whose amplitude the column carries (``''``: the base model).
    :param parameter: that amplitude's name.
    """

    term: str
    effect: str = ''
    parameter: str = ''


@dataclass(frozen=True)
class AxisDesign:
    """One axis's design: ``matrix @ coefficients ~ target``, with a label per column."""

    matrix: np.ndarray
    target: np.ndarray
    columns: tuple[Column, ...]

    def system(self) -> tuple[np.ndarray, np.ndarray]:
        """``(matrix, target)``, as :func:`~tak_thermo_ros.core.fit.solve.least_squares` takes them."""
        return self.matrix, self.target

    @property
    def terms(self) -> list[str]:
        """Each column's name in messages."""
        return [column.term for column in self.columns]


def base_columns(held: bool, bias_order: int, scale_order: int) -> list[Column]:
    """The paper's model's labels: the scale polynomial (unless held), then the offset polynomial."""
    scale = [] if held else [Column(SCALE_POLYNOMIAL)] * (scale_order + 1)
    return scale + [Column(OFFSET_POLYNOMIAL)] * (bias_order + 1)


def input_columns(effects: Sequence[Effect], axis: int,
                  force: np.ndarray) -> tuple[list[np.ndarray], list[Column]]:
    """The input effects' columns on one axis (terms in the specific force ``(k, 3)``) and their labels."""
    values, labels = [], []
    for effect in effects:
        for name, column in effect.input_columns(axis, force):
            values.append(column)
            labels.append(Column(f'{effect.name} ({name})', effect.name, name))
    return values, labels


def offset_columns(bases: Sequence[tuple[Effect, np.ndarray]], axis: int) -> tuple[list[np.ndarray], list[Column]]:
    """The offset effects' basis signals ``(k, b)`` that one axis uses, and their labels (the amplitudes)."""
    values, labels = [], []
    for effect, basis in bases:
        used = effect.axis_columns()[axis]
        for b, name in zip(used, effect.amplitude_names()[axis]):
            values.append(basis[:, b])
            labels.append(Column(effect.name, effect.name, name))
    return values, labels


def axis_design(axis: int, powers_of_u: Sequence[np.ndarray], force: np.ndarray, counts: np.ndarray, *,
                bias_order: int, scale_order: int, held_scale: float | None = None,
                input_effects: Sequence[Effect] = (), offset_bases: Sequence[tuple[Effect, np.ndarray]] = (),
                with_target: bool = False) -> AxisDesign:
    """The design of one axis: the paper's model, then each effect's columns.

    :param powers_of_u: ``u^0 .. u^max(p, q)`` (:meth:`Frame.powers`).
    :param force: ``(k, 3)`` reference specific force; ``counts``: ``(k, 3)`` codes.
    :param held_scale: the nominal scale of an axis that sees one input only (its scale polynomial
        is left out and ``K0 f`` taken from the target).
    :param offset_bases: ``(effect, basis (k, b))`` of each offset effect, shapes fixed.
    :param with_target: put the target as the matrix's last column too (a block of ``[X | y]``).
    """
    held = held_scale is not None
    force_i = force[:, axis]
    target = counts[:, axis] - held_scale * force_i if held else counts[:, axis]
    extra_values, extra_labels = input_columns(input_effects, axis, force)
    offset_values, offset_labels = offset_columns(offset_bases, axis)
    extra_values += offset_values
    labels = base_columns(held, bias_order, scale_order) + extra_labels + offset_labels
    width = len(labels)
    # Filled in place: a 15-hour run at 100 Hz has 5.4 million rows, and each copy of the
    # design matrix costs 300 MB.
    matrix = np.empty((len(force_i), width + (1 if with_target else 0)))
    position = 0
    if not held:
        for j in range(scale_order + 1):
            np.multiply(force_i, powers_of_u[j], out=matrix[:, position])
            position += 1
    for j in range(bias_order + 1):
        matrix[:, position] = powers_of_u[j]
        position += 1
    for column in extra_values:
        matrix[:, position] = column
        position += 1
    if with_target:
        matrix[:, width] = target
    return AxisDesign(matrix=matrix, target=target, columns=tuple(labels))


def subset(samples: AlignedSamples, mask: np.ndarray) -> AlignedSamples:
    """The samples where ``mask`` (every stream, the drop counts kept)."""
    return AlignedSamples(stamp_ns=samples.stamp_ns[mask], counts=samples.counts[mask],
                          temp_code=samples.temp_code[mask],
                          reference=None if samples.reference is None else samples.reference[mask],
                          dropped=dict(samples.dropped),
                          aux={name: values[mask] for name, values in samples.aux.items()})


@dataclass(frozen=True)
class FitRun:
    """The samples as a fit sees them: the training rows, the polynomials' frame, the held axes.

    :param samples: every sample (effects with memory run over the whole series).
    :param mask: the training rows; ``train``: ``samples`` there.
    :param single: per axis, whether the training reference holds one input only.
    :param first_input: the training reference's first sample.
    :param powers: ``u^0 .. u^max(p, q)`` over the training rows.
    """

    samples: AlignedSamples
    mask: np.ndarray
    train: AlignedSamples
    bias_order: int
    scale_order: int
    frame: Frame
    single: tuple[bool, bool, bool]
    nominal_scale: tuple[float, float, float] | None
    first_input: tuple[float, ...]
    powers: list[np.ndarray]

    @classmethod
    def prepare(cls, samples: AlignedSamples, *, bias_order: int = 3, scale_order: int = 2,
                temp_code_ref: float | None = None, nominal_scale: tuple[float, float, float] | None = None,
                train_mask: np.ndarray | None = None) -> FitRun:
        """Check the samples for the orders and set the run up.

        :raises FitError: a train mask of the wrong shape, orders out of range, too few samples,
            no reference, no temperature spread.
        """
        if train_mask is None:
            mask = np.ones(len(samples), dtype=bool)
        else:
            mask = np.asarray(train_mask, dtype=bool)
            if mask.shape != (len(samples),):
                msg = f'train_mask: expected {len(samples)} booleans, got shape {mask.shape}'
                raise FitError(msg)
        train = subset(samples, mask) if not mask.all() else samples
        check_orders(bias_order, scale_order)
        check_observable(train, bias_order, scale_order)
        frame = Frame.of_samples(train, temp_code_ref)
        return cls(samples=samples, mask=mask, train=train, bias_order=bias_order, scale_order=scale_order,
                   frame=frame, single=single_input_axes(train), nominal_scale=nominal_scale,
                   first_input=tuple(float(v) for v in train.reference[0]),
                   powers=frame.powers(train.temp_code, max(bias_order, scale_order)))

    def held_scale(self, axis: int) -> float | None:
        """The nominal scale axis ``axis`` is held at (``None``: its scale is fitted); see :func:`held_scale`."""
        return held_scale(axis, self.single, self.nominal_scale, self.first_input)

    def effect_input(self, effect: Effect | type[Effect]) -> np.ndarray:
        """What drives an offset effect over every sample.

        The temperature code as the corrector sees it (clamped to the calibrated range), or the recorded
        signal it names.
        """
        return effect_input(effect,  # type: ignore[arg-type]
                            np.clip(self.samples.temp_code, self.frame.low, self.frame.high), self.samples.aux)

    def basis(self, effect: Effect, inputs: np.ndarray, *, search: bool = False) -> np.ndarray:
        """An offset effect's basis signals ``(k, b)`` over every sample.

        In time order from its initial state (:func:`~tak_thermo_ros.core.effects.base.checked_basis`);
        ``inputs`` from :meth:`effect_input`.
        """
        return checked_basis(effect, self.samples.stamp_s, inputs, search=search)

    def design(self, axis: int, held: float | None, input_effects: Sequence[Effect] = (),
               offset_bases: Sequence[tuple[Effect, np.ndarray]] = ()) -> AxisDesign:
        """One axis's design over the training rows (:func:`axis_design`; ``offset_bases`` over those rows)."""
        return axis_design(axis, self.powers, self.train.reference, self.train.counts, bias_order=self.bias_order,
                           scale_order=self.scale_order, held_scale=held, input_effects=input_effects,
                           offset_bases=offset_bases)
