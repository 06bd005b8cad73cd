"""The iron and the thermal link of a magnetometer from one rotation record, at whatever temperatures.

A magnetometer turned through every orientation in the Earth's (constant) field sees points on
an ellipsoid. Its own thermal link acts on the whole field at the sensor, the iron's included::

    B_measured = F_c(T) (S b + h) + d(T)          per axis, n = T - T_ref
    F_c(T) = 1 + a1 n + ... + ap n^p              d(T) = c1 n + ... + cq n^q

so the corrected field ``W ((B_measured - d(T)) / F_c(T) - h)`` has one magnitude ``R`` in every
orientation and at every temperature: the ellipsoid's centre (and, through ``F_c``, its axes)
follows the temperature. That is :class:`~tak_thermo_ros.core.magnetometer.channel.MagCorrector`'s
path with a link of offset 0 and scale 1 (``d`` its offset drift, ``F_c`` its scale factor), then
the iron ``h``, ``W``: one record gives both, where a separate static chamber run was needed.

What the record determines decides what is fitted (:func:`fit_rotation`):

- no temperature, or one that spans less than :data:`MIN_THERMAL_SPAN_C`: the ellipsoid alone,
  the thermal link held (no temperature terms; said);
- otherwise the orders are lowered until each of ``order + 1`` temperature bands (equal counts
  of samples) is itself turned through enough orientations (its spread at least
  :data:`~tak_thermo_ros.core.magnetometer.iron.MIN_SPREAD`): a band held still cannot tell the
  centre's drift from the field; none left, the link is held and said.

The fit is least squares on ``|W (...)| / R - 1`` (scipy, analytic Jacobian) from the ellipsoid of
the whole record; the result passes ArduPilot's acceptance checks
(:func:`~tak_thermo_ros.core.magnetometer.iron.check_fit`). Values in tesla, temperatures in C.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.core.link.model import AxisModel, Calibration, MagnetometerCalibration, held_link
from tak_thermo_ros.core.magnetometer.iron import (
    MIN_SPREAD,
    SECTIONS_NEEDED,
    EllipsoidFit,
    algebraic_ellipsoid,
    check_fit,
    check_samples,
    fit_ellipsoid,
    sections_hit,
    spread_ratio,
)
from tak_thermo_ros.errors import FitError

MIN_THERMAL_SPAN_C = 2.0
"""Smallest temperature span, C, over which a rotation record's thermal drift is fitted."""
MICROTESLA = 1e6
"""The fit works in microtesla (fields of order 50): its numbers stay near one."""
SCALE_NOTE = 'scale K0 held at 1: a rotation record sees the field strength, not the gain'


@dataclass(frozen=True)
class RotationFit:
    """The magnetometer's correction from one rotation record, and how it was found.

    :param calibration: the thermal link (fitted, or held without temperature terms) and the iron.
    :param ellipsoid: the corrected record's figures (radius, residual, sections, spread; the iron
        at the reference temperature).
    :param bias_order: the order of the centre's drift fitted (0: the link held).
    :param scale_order: the order of the scale's drift fitted.
    :param lines: what was fitted and what was held, one statement each.
    """

    calibration: MagnetometerCalibration
    ellipsoid: EllipsoidFit
    bias_order: int
    scale_order: int
    lines: tuple[str, ...]


def fit_rotation(values: np.ndarray, temperature: np.ndarray | None, *, bias_order: int = 3,
                 scale_order: int = 2, temp_ref: float | None = None, where: str = 'rotation record',
                 held_because: str = '') -> RotationFit:
    """The iron, and the thermal link where the record determines it, from a rotation record.

    :param values: ``(k, 3)`` the measured field, tesla.
    :param temperature: ``(k,)`` the temperature held at each sample (degrees C), or ``None``.
    :param bias_order: highest order of the centre's drift tried (``fit --bias-order``).
    :param scale_order: highest order of the scale's drift tried (``fit --scale-order``), at most
        ``bias_order``.
    :param temp_ref: ``T_ref`` (default: the middle of the record's span, rounded).
    :param held_because: why the link is held when ``temperature`` is ``None`` (for the line).
    :raises FitError: one line: too few samples or orientations, or the acceptance checks.
    """
    values = np.asarray(values, dtype=float).reshape(-1, 3)
    spread = check_samples(values, where)
    centred = values - values.mean(axis=0)
    covered = sections_hit(centred / np.maximum(np.linalg.norm(centred, axis=1), 1e-300)[:, None])
    if covered < SECTIONS_NEEDED:
        msg = (f'{where}: covers too few orientations ({covered} of the 20 sections of the sphere, '
               f'{SECTIONS_NEEDED} needed): turn it through more, flip it over')
        raise FitError(msg)
    if temperature is None:
        return _held(values, None, where, held_because or 'no temperature')
    temperature = np.asarray(temperature, dtype=float)
    if not np.all(np.isfinite(temperature)):
        msg = f'{where}: {int(np.count_nonzero(~np.isfinite(temperature)))} temperatures are not finite'
        raise FitError(msg)
    low, high = float(temperature.min()), float(temperature.max())
    if high - low < MIN_THERMAL_SPAN_C:
        return _held(values, temperature, where, f'{low:.1f}..{high:.1f} C spans less than {MIN_THERMAL_SPAN_C:g} C')
    order, band = _covered_order(values, temperature, bias_order)
    if order == 0:
        return _held(values, temperature, where, f'the band {band} is not turned enough')
    scale = min(scale_order, order)
    ref = float(round((low + high) / 2.0)) if temp_ref is None else float(temp_ref)
    t_scale = max(abs(low - ref), abs(high - ref), 1.0)
    fitted = _least_squares(values * MICROTESLA, (temperature - ref) / t_scale, order, scale, where)
    matrix, hard, drift, gain = fitted
    determinant = float(np.linalg.det(matrix))
    if not determinant > 0.0:
        msg = f'{where}: the fit of the iron and the drift does not give an ellipsoid'
        raise FitError(msg)
    soft = matrix / determinant ** (1.0 / 3.0)
    soft = (soft + soft.T) / 2.0
    radius = determinant ** (-1.0 / 3.0) / MICROTESLA
    n_range = (low - ref, high - ref)
    axes = []
    for axis in range(3):
        drift_raw = [drift[axis, j] / MICROTESLA / t_scale ** (j + 1) for j in range(order)]
        gain_raw = [gain[axis, j] / t_scale ** (j + 1) for j in range(scale)]
        axes.append((drift_raw, gain_raw))
    notes = [SCALE_NOTE]
    if scale < scale_order:
        notes.append(f'scale drift order {scale} (of {scale_order} asked): the centre drift order caps it')
    link_axes = tuple(AxisModel.from_polynomials(scale=1.0, offset=0.0, offset_coeffs=drift_raw,
                                                 scale_coeffs=gain_raw, code_offset_range=n_range,
                                                 scale_observable=False)
                      for drift_raw, gain_raw in axes)
    link = Calibration(temp_code_ref=ref, temp_code_min=low, temp_code_max=high, axes=link_axes,  # type: ignore
                       notes=tuple(notes))
    mag = MagnetometerCalibration(link, tuple(float(v) for v in hard / MICROTESLA),  # type: ignore[arg-type]
                                  tuple(float(v) for v in soft.ravel()))
    ellipsoid = _figures(values, temperature, mag, radius, spread, where)
    mag = _with_residual(mag, ellipsoid.residual_rms)
    lines = [f'the iron and the thermal drift fitted together over {low:.1f}..{high:.1f} C (reference {ref:g} C)',
             f'centre drift order {order}, scale drift order {scale}']
    if order < bias_order:
        lines.append(f'centre drift order {order} of the {bias_order} asked: the band {band} is not turned enough')
    return RotationFit(mag, ellipsoid, order, scale, tuple(lines))


def _held(values: np.ndarray, temperature: np.ndarray | None, where: str, reason: str) -> RotationFit:
    """The ellipsoid alone, the thermal link held (no temperature terms), ``reason`` said."""
    fit = fit_ellipsoid(values, where=where)
    temperatures = None
    if temperature is not None and len(temperature):
        temperatures = (float(np.mean(temperature)), float(temperature.min()), float(temperature.max()))
    note = f'thermal link held (no temperature terms): {reason}'
    link = held_link(residual_rms=(fit.residual_rms,) * 3, temperatures=temperatures, notes=(SCALE_NOTE, note))
    mag = MagnetometerCalibration(link, fit.hard_iron, fit.soft_iron)
    return RotationFit(mag, fit, 0, 0, ())


def _covered_order(values: np.ndarray, temperature: np.ndarray, bias_order: int) -> tuple[int, str]:
    """The highest order (at most ``bias_order``) whose ``order + 1`` temperature bands are each turned enough.

    Also the first band that fails at the next order up, as ``'a..b C (spread s)'`` (empty if none).
    """
    order_by_temperature = np.argsort(temperature, kind='stable')
    failed = ''
    for order in range(bias_order, 0, -1):
        bands = np.array_split(order_by_temperature, order + 1)
        worst = None
        for rows in bands:
            spread = spread_ratio(values[rows]) if len(rows) >= 3 else 0.0
            if spread < MIN_SPREAD:
                worst = (float(temperature[rows].min()) if len(rows) else math.nan,
                         float(temperature[rows].max()) if len(rows) else math.nan, spread)
                break
        if worst is None:
            return order, failed
        failed = f'{worst[0]:.1f}..{worst[1]:.1f} C (spread {worst[2]:.2f} < {MIN_SPREAD:g})'
    return 0, failed


def _least_squares(points: np.ndarray, u: np.ndarray, order: int, scale: int, where: str
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(M, h, c, a)`` minimising ``sum (|M e| - 1)^2``, ``e = (x - d(u)) / F_c(u) - h`` (microtesla).

    ``M`` symmetric (six numbers), ``d = sum_j c_j u^j`` (``j = 1..order``), ``F_c = 1 + sum_j
    a_j u^j`` (``j = 1..scale``), per axis. Started from the whole record's ellipsoid.
    """
    from scipy.optimize import least_squares
    hard0, soft0, radius0 = algebraic_ellipsoid(points, where)
    matrix0 = soft0 / radius0
    start = np.concatenate([matrix0[(0, 1, 2, 0, 0, 1), (0, 1, 2, 1, 2, 2)], hard0,
                            np.zeros(3 * order), np.zeros(3 * scale)])
    u_powers = np.column_stack([u ** (j + 1) for j in range(max(order, scale))])

    def unpack(theta: np.ndarray):
        m0, m1, m2, m3, m4, m5 = theta[:6]
        matrix = np.array([[m0, m3, m4], [m3, m1, m5], [m4, m5, m2]])
        hard = theta[6:9]
        drift = theta[9:9 + 3 * order].reshape(3, order)
        gain = theta[9 + 3 * order:].reshape(3, scale)
        return matrix, hard, drift, gain

    def parts(theta: np.ndarray):
        matrix, hard, drift, gain = unpack(theta)
        offset = u_powers[:, :order] @ drift.T
        factor = 1.0 + u_powers[:, :scale] @ gain.T
        centred = points - offset
        e = centred / factor - hard
        v = e @ matrix
        norm = np.linalg.norm(v, axis=1)
        return matrix, factor, centred, e, v, norm

    def residual(theta: np.ndarray) -> np.ndarray:
        return parts(theta)[-1] - 1.0

    def jacobian(theta: np.ndarray) -> np.ndarray:
        matrix, factor, centred, e, v, norm = parts(theta)
        unit = v / norm[:, None]
        w = unit @ matrix
        columns = [unit[:, 0] * e[:, 0], unit[:, 1] * e[:, 1], unit[:, 2] * e[:, 2],
                   unit[:, 0] * e[:, 1] + unit[:, 1] * e[:, 0], unit[:, 0] * e[:, 2] + unit[:, 2] * e[:, 0],
                   unit[:, 1] * e[:, 2] + unit[:, 2] * e[:, 1], -w[:, 0], -w[:, 1], -w[:, 2]]
        for axis in range(3):
            columns += [-w[:, axis] * u_powers[:, j] / factor[:, axis] for j in range(order)]
        for axis in range(3):
            columns += [-w[:, axis] * centred[:, axis] * u_powers[:, j] / factor[:, axis] ** 2 for j in range(scale)]
        return np.column_stack(columns)

    result = least_squares(residual, start, jac=jacobian, method='lm', x_scale='jac', xtol=1e-12, ftol=1e-12,
                           gtol=1e-12, max_nfev=200)
    if not np.all(np.isfinite(result.x)):
        msg = f'{where}: the fit of the iron and the thermal drift did not converge'
        raise FitError(msg)
    matrix, hard, drift, gain = unpack(result.x)
    if np.linalg.eigvalsh(matrix)[0] <= 0.0 or np.any(parts(result.x)[1] <= 0.0):
        msg = f'{where}: the fit of the iron and the thermal drift does not give an ellipsoid'
        raise FitError(msg)
    return matrix, hard, drift, gain


def corrected_field(mag: MagnetometerCalibration, values: np.ndarray, temperature: np.ndarray) -> np.ndarray:
    """``(k, 3)`` the field corrected by ``mag`` (the correction path itself, extrapolating)."""
    from tak_thermo_ros.core.link.correction import OutOfRange
    from tak_thermo_ros.core.magnetometer.channel import MagCorrector
    return MagCorrector(mag, out_of_range=OutOfRange.EXTRAPOLATE).correct(values, temperature)


def _figures(values: np.ndarray, temperature: np.ndarray, mag: MagnetometerCalibration, radius: float,
             spread: float, where: str) -> EllipsoidFit:
    """The corrected record's figures, through the correction path; ArduPilot's checks on them."""
    corrected = corrected_field(mag, values, temperature)
    magnitudes = np.linalg.norm(corrected, axis=1)
    fit = EllipsoidFit(hard_iron=mag.hard_iron, soft_iron=mag.soft_iron, radius=radius,  # type: ignore[arg-type]
                       residual_rms=float(np.sqrt(np.mean((magnitudes - radius) ** 2))), samples=len(values),
                       sections=sections_hit(corrected / magnitudes[:, None]), spread=spread)
    check_fit(fit, where=where)
    return fit


def _with_residual(mag: MagnetometerCalibration, rms: float) -> MagnetometerCalibration:
    """The link's per-axis ``residual_rms``: the corrected magnitude's, taken for each axis's noise."""
    from dataclasses import replace
    axes = tuple(replace(axis, residual_rms=float(rms)) for axis in mag.thermal.axes)
    return replace(mag, thermal=replace(mag.thermal, axes=axes))
