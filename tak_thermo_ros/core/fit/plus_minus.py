"""The paper's own +/- method (eqs. 3-5).

With equal and opposite inputs ``+I`` and ``-I`` giving codes ``N+`` and ``N-`` at the same
temperature::

    dNs  = (N+ + N-) / 2          (3)
    Nc+  = (N+ - N-) / 2          (4)  (the paper prints '+'; the difference is meant)
    K    = Nc+ / I+               (5)

Done per temperature, this gives ``dNs(N_t)`` and ``K(N_t)`` point by point; polynomials
through those points give the same correction link as the least-squares fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.core.link.model import AXES, AxisModel, Calibration
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.errors import FitError


def plus_minus(code_plus, code_minus, input_plus):
    """Offset ``dNs`` and scale ``K`` from codes at ``+I`` and ``-I`` (eqs. 3-5).

    :returns: ``(offset, scale)``, scalars or arrays like the inputs.
    """
    code_plus = np.asarray(code_plus, dtype=float)
    code_minus = np.asarray(code_minus, dtype=float)
    offset = (code_plus + code_minus) / 2.0
    centred = (code_plus - code_minus) / 2.0
    return offset, centred / np.asarray(input_plus, dtype=float)


@dataclass(frozen=True)
class PlusMinusPoints:
    """Per-temperature results of the +/- method for one axis.

    :param temp_code: ``(m,)`` mean temperature code of each group.
    :param offset: ``(m,)`` ``dNs`` in counts.
    :param scale: ``(m,)`` ``K`` in counts per m/s^2.
    """

    temp_code: np.ndarray
    offset: np.ndarray
    scale: np.ndarray


def plus_minus_points(samples: AlignedSamples, axis: int, *, code_bin: float = 1.0,
                      min_samples: int = 5) -> PlusMinusPoints:
    """Group samples by temperature code and apply the +/- method where both signs exist.

    Uses the samples where the axis sees ``+|f|`` or ``-|f|`` of the largest magnitude and the
    other axes see nothing (the six +/-g positions).
    """
    if samples.reference is None:
        msg = 'the +/- method needs the reference stream'
        raise FitError(msg)
    reference = samples.reference
    magnitude = float(np.max(np.abs(reference[:, axis])))
    others = [j for j in range(3) if j != axis]
    pure = np.all(np.abs(reference[:, others]) < 1e-9, axis=1)
    plus = pure & np.isclose(reference[:, axis], magnitude)
    minus = pure & np.isclose(reference[:, axis], -magnitude)
    bins = np.round(samples.temp_code / code_bin)
    codes, offsets, scales = [], [], []
    for value in np.intersect1d(np.unique(bins[plus]), np.unique(bins[minus])):
        in_bin = bins == value
        up, down = plus & in_bin, minus & in_bin
        if up.sum() < min_samples or down.sum() < min_samples:
            continue
        offset, scale = plus_minus(samples.counts[up, axis].mean(), samples.counts[down, axis].mean(), magnitude)
        codes.append(samples.temp_code[up | down].mean())
        offsets.append(float(offset))
        scales.append(float(scale))
    if len(codes) < 2:
        msg = f'axis {AXES[axis]}: fewer than two temperatures with both +g and -g samples'
        raise FitError(msg)
    return PlusMinusPoints(np.asarray(codes), np.asarray(offsets), np.asarray(scales))


def fit_plus_minus(samples: AlignedSamples, *, bias_order: int = 3, scale_order: int = 2,
                   temp_code_ref: float, code_bin: float = 1.0) -> Calibration:
    """The correction link from +/- points: polynomials in ``n`` through ``dNs`` and ``K``.

    Each point is weighted by nothing but itself (one point per temperature group).
    """
    axes = []
    low, high = float(samples.temp_code.min()), float(samples.temp_code.max())
    for axis in range(3):
        points = plus_minus_points(samples, axis, code_bin=code_bin)
        n = points.temp_code - temp_code_ref
        offset_poly = np.polynomial.polynomial.polyfit(n, points.offset, bias_order)
        scale_poly = np.polynomial.polynomial.polyfit(n, points.scale, scale_order)
        scale = scale_poly[0]
        axes.append(AxisModel.from_polynomials(
            scale=scale, offset=offset_poly[0], offset_coeffs=offset_poly[1:],
            scale_coeffs=scale_poly[1:] / scale,
            code_offset_range=(low - temp_code_ref, high - temp_code_ref)))
    return Calibration(temp_code_ref=temp_code_ref, temp_code_min=low, temp_code_max=high,
                       axes=tuple(axes))  # type: ignore[arg-type]
