"""The paper's least squares: the correction link without effects, over a whole calibration run.

The first room of the fit: :mod:`tak_thermo_ros.core.fit.effects` adds the effects on top of
it, and :func:`tak_thermo_ros.core.fit.fit_model` is the one entry that users call.

The model is linear in ``(K0, K0 a1..ap, dNs0, c1..cq)`` with ``c_k = D b_k``: per axis the
design matrix has the columns ``f n^j`` (j = 0..p) and ``n^j`` (j = 0..q). Columns are built
in ``u = n / max|n|`` for conditioning and converted back to raw code powers afterwards.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.records.calibration_file import check_scale_positive
from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.link.model import AXES, AxisModel, Calibration
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.errors import CalibrationError, FitError

MIN_SAMPLES_PER_PARAMETER = 10
INPUT_RESOLUTION = 1e-6
"""Two reference values closer than this (m/s^2) count as the same input."""


@dataclass(frozen=True)
class AxisFit:
    """Fit statistics of one axis.

    :param residual_rms: RMS of ``N - model`` in counts.
    :param parameters: number of fitted parameters.
    :param bic: Bayesian information criterion ``k ln(RSS/k) + m ln k``.
    """

    residual_rms: float
    parameters: int
    bic: float


@dataclass(frozen=True)
class FitResult:
    """The fitted calibration and how well it fits.

    :param calibration: the fitted correction link.
    :param axes: statistics per axis x, y, z.
    :param samples: number of samples used.
    :param dropped: reason -> counts samples left out before the fit.
    :param parameter_errors: standard errors of the effects' fitted parameters,
        ``'<effect>.<parameter>'`` -> value in the parameter's unit (:func:`fit_model`).
    """

    calibration: Calibration
    axes: tuple[AxisFit, AxisFit, AxisFit]
    samples: int
    dropped: dict[str, int]
    parameter_errors: dict[str, float] = field(default_factory=dict)


def residual_counts(calibration: Calibration, samples: AlignedSamples) -> np.ndarray:
    """``N - model(f, N_t)`` in counts, ``(k, 3)``, through the correction path.

    ``N - K0 F_c f - dNs = K0 F_c (f_hat - f)``, with ``f_hat`` from :class:`Corrector`.
    With effects, ``N`` minus the corrector's forward model (:meth:`Corrector.predict_counts`,
    the exact inverse of its correction), effects with memory run over the whole series from
    their initial state.
    """
    if samples.reference is None:
        msg = 'residuals need the reference stream'
        raise FitError(msg)
    corrector = Corrector(calibration)
    if calibration.effects:
        return samples.counts - corrector.predict_counts(samples.reference, samples.temp_code,
                                                         stamp_s=samples.stamp_s, aux=samples.aux)
    error = corrector.correct(samples.counts, samples.temp_code) - samples.reference
    n = corrector.code_offset(samples.temp_code)
    gain = np.column_stack([axis.scale * axis.scale_factor(n) for axis in calibration.axes])
    return error * gain


def _check_observable(samples: AlignedSamples, bias_order: int, scale_order: int) -> None:
    parameters = bias_order + scale_order + 2
    needed = MIN_SAMPLES_PER_PARAMETER * parameters
    if len(samples) < needed:
        msg = (f'too few samples: {len(samples)} usable counts samples, need at least {needed} '
               f'for bias order {bias_order} and scale order {scale_order}')
        raise FitError(msg)
    if samples.reference is None:
        msg = 'no reference stream: a fit needs the true specific force'
        raise FitError(msg)
    distinct_codes = np.unique(samples.temp_code).size
    if distinct_codes < max(bias_order, scale_order) + 1:
        low, high = float(samples.temp_code.min()), float(samples.temp_code.max())
        msg = (f'no temperature spread: the temperature code spans only {low:g}..{high:g} '
               f'({distinct_codes} distinct codes), need at least {max(bias_order, scale_order) + 1}')
        raise FitError(msg)


def single_input_axes(samples: AlignedSamples) -> tuple[bool, bool, bool]:
    """Per axis, whether the reference holds one value only (scale and offset inseparable)."""
    return tuple(np.unique(np.round(samples.reference[:, i] / INPUT_RESOLUTION)).size < 2
                 for i in range(3))  # type: ignore[return-value]


def axis_from_coefficients(beta: Sequence[float], *, bias_order: int, scale_order: int, n_scale: float,
                           code_offset_range: tuple[float, float], name: str,
                           held_scale: float | None = None) -> AxisModel:
    """The axis model of a solved design in the normalised temperature ``u = (N_t - N_t,ref) / n_scale``.

    :param beta: the coefficients of ``f u^0 .. f u^p, u^0 .. u^q`` (scale fitted), or of
        ``u^0 .. u^q`` alone when the scale is held (``held_scale``); anything after them (an
        effect's amplitudes) is ignored.
    :param held_scale: the nominal scale an axis that sees one input only is held at.
    :raises FitError: a fitted scale that is not positive.
    """
    if held_scale is not None:
        return AxisModel.from_polynomials(
            scale=held_scale, offset=beta[0], offset_coeffs=[beta[j] / n_scale ** j for j in range(1, bias_order + 1)],
            scale_coeffs=(), code_offset_range=code_offset_range, scale_observable=False)
    scale = beta[0]
    if not scale > 0.0:
        msg = f'axis {name}: fitted scale {scale:g} counts per m/s^2 is not positive'
        raise FitError(msg)
    return AxisModel.from_polynomials(
        scale=scale, offset=beta[scale_order + 1],
        offset_coeffs=[beta[scale_order + 1 + j] / n_scale ** j for j in range(1, bias_order + 1)],
        scale_coeffs=[beta[j] / (scale * n_scale ** j) for j in range(1, scale_order + 1)],
        code_offset_range=code_offset_range)


def fit_calibration(samples: AlignedSamples, *, bias_order: int = 3, scale_order: int = 2,
                    temp_code_ref: float | None = None,
                    nominal_scale: tuple[float, float, float] | None = None) -> FitResult:
    """Fit the paper's model to aligned calibration samples.

    :param samples: counts with held temperature code and reference.
    :param bias_order: ``q``, order of ``F_s`` (>= 1).
    :param scale_order: ``p``, order of ``F_c`` (>= 0; 0 fits no scale change).
    :param temp_code_ref: ``N_t,ref``; default the middle of the calibrated range, rounded.
    :param nominal_scale: ``K0`` per axis, counts per m/s^2. Used, and required, only for an
        axis that sees a single input: there scale and offset cannot be told apart, so the
        scale is held at nominal (``F_c = 1``), the offset shape is fitted, and the axis is
        marked ``scale_observable = False``.
    :raises FitError: when the data cannot determine the model.
    """
    if bias_order < 1 or scale_order < 0:
        msg = f'orders must be bias >= 1 and scale >= 0, got bias {bias_order}, scale {scale_order}'
        raise FitError(msg)
    _check_observable(samples, bias_order, scale_order)
    low, high = float(samples.temp_code.min()), float(samples.temp_code.max())
    ref = float(round((low + high) / 2.0)) if temp_code_ref is None else float(temp_code_ref)
    n = samples.temp_code - ref
    n_scale = max(abs(low - ref), abs(high - ref), 1.0)
    u = n / n_scale
    powers = [np.ones_like(u)]
    for _ in range(max(bias_order, scale_order)):
        powers.append(powers[-1] * u)

    held = single_input_axes(samples)
    notes: list[str] = []
    held_inputs: list[str] = []
    axes_models: list[AxisModel] = []
    for i, name in enumerate(AXES):
        force = samples.reference[:, i]
        if held[i]:
            if nominal_scale is None or not nominal_scale[i] > 0.0:
                msg = (f'axis {name} sees one input only ({force[0]:g} m/s^2): its scale cannot be '
                       f'fitted, give the nominal scale (counts per m/s^2) to hold it')
                raise FitError(msg)
            axes_models.append(_fit_offset_only(samples.counts[:, i], force, powers, float(nominal_scale[i]),
                                                bias_order, n_scale, (low - ref, high - ref), name))
            held_inputs.append(f'{name} input {force[0]:.4g} at nominal scale {nominal_scale[i]:g}')
            continue
        # Filled and scaled in place (same values as column_stack then divide): a 15-hour run
        # at 100 Hz has 5.4 million rows, and each copy of the design matrix costs 300 MB.
        design = np.empty((len(samples), scale_order + bias_order + 2))
        for j in range(scale_order + 1):
            np.multiply(force, powers[j], out=design[:, j])
        for j in range(bias_order + 1):
            design[:, scale_order + 1 + j] = powers[j]
        norms = np.sqrt(np.mean(design ** 2, axis=0))
        norms[norms == 0.0] = 1.0
        design /= norms
        solution, _, rank, singular = np.linalg.lstsq(design, samples.counts[:, i], rcond=None)
        if rank < design.shape[1] or singular[-1] < 1e-9 * singular[0]:
            msg = (f'axis {name}: the data cannot separate the model terms '
                   f'(rank {rank} of {design.shape[1]}); the inputs and temperatures do not '
                   f'cover bias order {bias_order} and scale order {scale_order}')
            raise FitError(msg)
        del design
        axes_models.append(axis_from_coefficients(solution / norms, bias_order=bias_order, scale_order=scale_order,
                                                  n_scale=n_scale, code_offset_range=(low - ref, high - ref),
                                                  name=name))

    if held_inputs:
        notes.append(held_scale_note(held, held_inputs))
    calibration = Calibration(temp_code_ref=ref, temp_code_min=low, temp_code_max=high,
                              axes=tuple(axes_models), notes=tuple(notes))  # type: ignore[arg-type]
    residual = residual_counts(calibration, samples)
    parameters = [bias_order + 1 if held[i] else bias_order + scale_order + 2 for i in range(3)]
    return finish_fit(calibration, residual, parameters, dropped=samples.dropped)


def held_scale_note(held: Sequence[bool], held_inputs: Sequence[str]) -> str:
    """The calibration note for axes whose scale was held at nominal (one input only)."""
    return (f'scale held at nominal on {", ".join(AXES[i] for i in range(3) if held[i])}: one input '
            f'only ({"; ".join(held_inputs)}), so scale and offset drift cannot be told apart; '
            f'the offset shape was fitted (scale_observable false)')


def finish_fit(calibration: Calibration, residual: np.ndarray, parameters: Sequence[int], *,
               dropped: dict[str, int], parameter_errors: dict[str, float] | None = None) -> FitResult:
    """Per-axis residual RMS and BIC, the RMS recorded in the calibration, ``F_c > 0`` checked.

    :param residual: ``(k, 3)`` residual in counts over the samples the fit used.
    :param parameters: number of fitted parameters per axis.
    """
    sums = [float(np.sum(residual[:, i] ** 2)) for i in range(len(calibration.axes))]
    return finish_fit_from_sums(calibration, sums, len(residual), parameters, dropped=dropped,
                                parameter_errors=parameter_errors)


def finish_fit_from_sums(calibration: Calibration, residual_sums: Sequence[float], count: int,
                         parameters: Sequence[int], *, dropped: dict[str, int],
                         parameter_errors: dict[str, float] | None = None) -> FitResult:
    """:func:`finish_fit` from the residual sum of squares per axis over ``count`` samples."""
    stats = []
    final_axes = []
    for i, axis in enumerate(calibration.axes):
        rss = float(residual_sums[i])
        rms = math.sqrt(rss / count)
        bic = count * math.log(max(rss, 1e-300) / count) + parameters[i] * math.log(count)
        stats.append(AxisFit(residual_rms=rms, parameters=parameters[i], bic=bic))
        final_axes.append(replace(axis, residual_rms=rms))
    calibration = replace(calibration, axes=tuple(final_axes))
    try:
        check_scale_positive(calibration, key='fit')
    except CalibrationError as err:
        raise FitError(str(err)) from None
    return FitResult(calibration=calibration, axes=tuple(stats),  # type: ignore[arg-type]
                     samples=count, dropped=dict(dropped), parameter_errors=dict(parameter_errors or {}))


def _fit_offset_only(counts: np.ndarray, force: np.ndarray, powers: list[np.ndarray], scale: float,
                     bias_order: int, n_scale: float, code_offset_range: tuple[float, float],
                     name: str) -> AxisModel:
    """Offset polynomial of an axis whose scale is held at ``scale`` (``F_c = 1``)."""
    design = np.column_stack([powers[j] for j in range(bias_order + 1)])
    solution, _, rank, _ = np.linalg.lstsq(design, counts - scale * force, rcond=None)
    if rank < design.shape[1]:
        msg = f'axis {name}: the temperature codes do not cover bias order {bias_order}'
        raise FitError(msg)
    return axis_from_coefficients(solution, bias_order=bias_order, scale_order=0, n_scale=n_scale,
                                  code_offset_range=code_offset_range, name=name, held_scale=scale)
