"""A solved design -> the model: the correction link (:class:`Calibration`) and how well it fits.

The last step of every fit: the coefficients of the paper's columns become each axis's
:class:`AxisModel` (back from ``u`` to raw code powers), the columns labelled with an effect's
amplitude become that effect's values (:func:`fitted_effects`), and the residual of the
calibration through the one correction path (:class:`Corrector`) gives the statistics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.effects.base import Effect
from tak_thermo_ros.core.fit.design import Column, Frame
from tak_thermo_ros.core.fit.summary import axes_lines, effect_lines
from tak_thermo_ros.core.fit.uncertainty import ErrorBasis
from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.link.model import AXES, AxisModel, Calibration
from tak_thermo_ros.core.link.model import check_scale_positive
from tak_thermo_ros.core.link.uncertainty import LinkUncertainty
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.errors import CalibrationError, FitError


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
    :param error_basis: what those errors assume (one sigma; how the residual is correlated,
        :mod:`~tak_thermo_ros.core.fit.uncertainty`), ``None`` without errors.

    It reports itself (:meth:`summary`: what ``tak_calib fit`` prints of a sensor); its link's
    terms with their errors' covariance are :attr:`covariance`, its effects' parameters with their
    errors :meth:`parameters`.
    """

    calibration: Calibration
    axes: tuple[AxisFit, AxisFit, AxisFit]
    samples: int
    dropped: dict[str, int]
    parameter_errors: dict[str, float] = field(default_factory=dict)
    error_basis: ErrorBasis | None = None

    @property
    def residual_rms(self) -> tuple[float, float, float]:
        """The RMS of the residual per axis x, y, z, in the link's input unit (counts, or the sensor's)."""
        return tuple(axis.residual_rms for axis in self.axes)

    @property
    def covariance(self) -> LinkUncertainty | None:
        """The link's terms (``x.offset``, ``x.scale_T1``, ``c_yx``, ...) with their errors' covariance, held ones too.

        ``None`` where the fit states none (:class:`~tak_thermo_ros.core.link.uncertainty.LinkUncertainty`).
        """
        return self.calibration.uncertainty

    def parameters(self) -> dict[str, tuple[float, float | None]]:
        """Each effect parameter ``'<effect>.<parameter>'`` -> ``(value, standard error or None)``, held ones at 0."""
        return {f'{effect.name}.{p.name}': (p.value, self.parameter_errors.get(f'{effect.name}.{p.name}'))
                for effect in self.calibration.effects for p in effect.parameters}

    def effect_lines(self, unit: str, *, calibration: Calibration | None = None) -> list[str]:
        """The effects' lines of :meth:`summary` (those of ``calibration``'s effects, if given)."""
        return effect_lines(self.calibration if calibration is None else calibration, self.parameter_errors,
                            self.error_basis, unit)

    def summary(self, sensor: str, unit: str, *, calibration: Calibration | None = None) -> str:
        """The fit's report, one statement per line: the link per axis, then the effects (:mod:`.summary`).

        :param sensor: the sensor's name as printed (``'accelerometer'``).
        :param unit: the unit of the link's output (``'counts'``, ``'m/s^2'``, ``'rad/s'``, ``'T'``).
        :param calibration: the link as written, where it differs from the one fitted (notes or iron added).
        """
        link = self.calibration if calibration is None else calibration
        return '\n'.join([*axes_lines(sensor, link, self.residual_rms, unit),
                          *self.effect_lines(unit, calibration=link)])


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


def held_scale_note(held: Sequence[bool], held_inputs: Sequence[str]) -> str:
    """The calibration note for axes whose scale was held at nominal (one input only)."""
    return (f'scale held at nominal on {", ".join(AXES[i] for i in range(3) if held[i])}: one input '
            f'only ({"; ".join(held_inputs)}), so scale and offset drift cannot be told apart; '
            f'the offset shape was fitted (scale_observable false)')


def held_notes(held_scales: Sequence[float | None], first_input: Sequence[float]) -> tuple[str, ...]:
    """The calibration's notes: the held-scale note when an axis's scale was held, else none."""
    held = [scale is not None for scale in held_scales]
    held_inputs = [f'{AXES[i]} input {first_input[i]:.4g} at nominal scale {held_scales[i]:g}'
                   for i in range(3) if held[i]]
    return (held_scale_note(held, held_inputs),) if held_inputs else ()


def build_effect(cls: type[Effect], values: dict[str, float]) -> Effect:
    """An effect of fitted values (every parameter given); a value out of bounds is a :class:`FitError`."""
    try:
        return cls.from_values(values, key=f'effect {cls.name}', complete=True)
    except CalibrationError as err:
        msg = f'fitted {err}'
        raise FitError(msg) from None


def fitted_effects(effects: Sequence[Effect], columns: Sequence[Sequence[Column]],
                   coefficients: Sequence[np.ndarray]) -> tuple[Effect, ...]:
    """Each effect with its shape kept and its amplitudes read from the solution, in the order given.

    :param columns: per axis the design's column labels; ``coefficients``: per axis the solution.
    """
    values = {effect.name: {**{name: effect[name] for name in effect.shape_names()},
                            **{name: 0.0 for name in effect.held_names()}} for effect in effects}
    for labels, beta in zip(columns, coefficients):
        for label, value in zip(labels, beta):
            if label.effect:
                values[label.effect][label.parameter] = float(value)
    return tuple(build_effect(type(effect), values[effect.name]) for effect in effects)


def amplitude_errors(columns: Sequence[Column], deviations: np.ndarray) -> dict[str, float]:
    """``'<effect>.<amplitude>'`` -> standard error, for the columns that carry an effect's amplitude."""
    return {f'{label.effect}.{label.parameter}': float(deviation)
            for label, deviation in zip(columns, deviations) if label.effect}


def calibration_from(frame: Frame, coefficients: Sequence[np.ndarray], *, bias_order: int, scale_order: int,
                     held_scales: Sequence[float | None], notes: tuple[str, ...] = (),
                     effects: tuple[Effect, ...] = ()) -> Calibration:
    """The correction link of the solved designs of the three axes.

    :raises FitError: a fitted scale that is not positive.
    """
    axes = tuple(axis_from_coefficients(coefficients[i], bias_order=bias_order, scale_order=scale_order,
                                        n_scale=frame.n_scale, code_offset_range=frame.code_offset_range,
                                        name=AXES[i], held_scale=held_scales[i])
                 for i in range(3))
    return Calibration(temp_code_ref=frame.ref, temp_code_min=frame.low, temp_code_max=frame.high,
                       axes=axes, notes=notes, effects=effects)  # type: ignore[arg-type]


def finish_fit(calibration: Calibration, residual: np.ndarray, parameters: Sequence[int], *,
               dropped: dict[str, int], parameter_errors: dict[str, float] | None = None,
               error_basis: ErrorBasis | None = None) -> FitResult:
    """Per-axis residual RMS and BIC, the RMS recorded in the calibration, ``F_c > 0`` checked.

    :param residual: ``(k, 3)`` residual in counts over the samples the fit used.
    :param parameters: number of fitted parameters per axis.
    """
    sums = [float(np.sum(residual[:, i] ** 2)) for i in range(len(calibration.axes))]
    return finish_fit_from_sums(calibration, sums, len(residual), parameters, dropped=dropped,
                                parameter_errors=parameter_errors, error_basis=error_basis)


def finish_fit_from_sums(calibration: Calibration, residual_sums: Sequence[float], count: int,
                         parameters: Sequence[int], *, dropped: dict[str, int],
                         parameter_errors: dict[str, float] | None = None,
                         error_basis: ErrorBasis | None = None) -> FitResult:
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
                     samples=count, dropped=dict(dropped), parameter_errors=dict(parameter_errors or {}),
                     error_basis=error_basis)
