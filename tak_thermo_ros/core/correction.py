"""The correction link (the paper's Fig. 2): one implementation, two paths.

``Corrector.correct`` takes numpy arrays (fit residuals, ``apply``, ``validate``);
``Corrector.correct_sample`` takes plain floats (the node, one message at a time). Both run
the same operations in the same order, so they agree bit for bit; a test holds them to it.

The correction of one axis::

    f_hat = (N - dNs0 - D F_s(n)) / (K0 F_c(n))

and the paper's code at normal conditions::

    N_hat(0) = (N - dNs(n)) / F_c(n) + dNs0
"""

from __future__ import annotations

import enum
import math

import numpy as np

from tak_thermo_ros.core.model import Calibration


class OutOfRange(str, enum.Enum):
    """What the correction does with a temperature code outside the calibrated range."""

    CLAMP = 'clamp'
    """Use the nearest edge of the calibrated range (bounded error, never extrapolates)."""
    EXTRAPOLATE = 'extrapolate'
    """Evaluate the polynomials beyond the range (follows a trend, may diverge)."""


class Corrector:
    """Apply a :class:`Calibration` to channel codes.

    :param calibration: the calibrated correction link.
    :param out_of_range: policy for temperature codes outside the calibrated range.
    """

    def __init__(self, calibration: Calibration, *,
                 out_of_range: OutOfRange = OutOfRange.CLAMP) -> None:
        self.calibration = calibration
        self.out_of_range = OutOfRange(out_of_range)
        self._ref = float(calibration.temp_code_ref)
        self._low = float(calibration.temp_code_min)
        self._high = float(calibration.temp_code_max)
        self._clamp = self.out_of_range is OutOfRange.CLAMP
        # Per axis: (K0, dNs0, D, reversed F_s coefficients, reversed F_c coefficients).
        self._axes = tuple(
            (float(a.scale), float(a.offset), float(a.offset_span),
             tuple(float(c) for c in reversed(a.offset_shape)),
             tuple(float(c) for c in reversed(a.scale_shape)))
            for a in calibration.axes)

    def code_offset(self, temp_code):
        """``n = N_t - N_t,ref`` after the out-of-range policy (scalar or array)."""
        if self._clamp:
            if isinstance(temp_code, np.ndarray):
                temp_code = np.clip(temp_code, self._low, self._high)
            else:
                temp_code = min(max(temp_code, self._low), self._high)
        return temp_code - self._ref

    def correct_sample(self, counts_x: float, counts_y: float, counts_z: float,
                       temp_code: float, *, stamp_s: float = 0.0) -> tuple[float, float, float]:
        """Specific force (m/s^2) of one sample from plain floats; the node's path.

        :param stamp_s: the sample's stamp in seconds (for model terms with memory).
        """
        n = self.code_offset(temp_code)
        result = []
        for counts, (scale, offset, span, shape_s, shape_c) in zip(
                (counts_x, counts_y, counts_z), self._axes):
            drift = 0.0 * n
            for coefficient in shape_s:
                drift = (drift + coefficient) * n
            factor = 0.0 * n
            for coefficient in shape_c:
                factor = (factor + coefficient) * n
            result.append((counts - (offset + span * drift)) / (scale * (factor + 1.0)))
        return result[0], result[1], result[2]

    def correct(self, counts: np.ndarray, temp_code: np.ndarray, *,
                stamp_s: np.ndarray | None = None) -> np.ndarray:
        """Specific force ``(k, 3)`` in m/s^2 from codes ``(k, 3)`` and temperature codes ``(k,)``.

        :param stamp_s: ``(k,)`` stamps in seconds (for model terms with memory).
        """
        counts = np.asarray(counts, dtype=float)
        n = self.code_offset(np.asarray(temp_code, dtype=float))
        out = np.empty_like(counts)
        for i, (scale, offset, span, shape_s, shape_c) in enumerate(self._axes):
            drift = 0.0 * n
            for coefficient in shape_s:
                drift = (drift + coefficient) * n
            factor = 0.0 * n
            for coefficient in shape_c:
                factor = (factor + coefficient) * n
            out[:, i] = (counts[:, i] - (offset + span * drift)) / (scale * (factor + 1.0))
        return out

    def code_at_reference(self, counts: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """The paper's ``N_hat(0) = (N - dNs(n)) / F_c(n) + dNs0``, codes ``(k, 3)``."""
        counts = np.asarray(counts, dtype=float)
        n = self.code_offset(np.asarray(temp_code, dtype=float))
        out = np.empty_like(counts)
        for i, axis in enumerate(self.calibration.axes):
            centred = counts[:, i] - (axis.offset + axis.offset_drift(n))
            out[:, i] = centred / axis.scale_factor(n) + axis.offset
        return out

    def out_of_range_count(self, temp_code: np.ndarray) -> int:
        """How many temperature codes lie outside the calibrated range."""
        temp_code = np.asarray(temp_code, dtype=float)
        return int(np.count_nonzero((temp_code < self._low) | (temp_code > self._high)))


def acceleration_variance(calibration: Calibration) -> tuple[float, float, float]:
    """Per-axis variance of the corrected specific force, (m/s^2)^2, from the fit residual.

    Zero where the residual is unknown (REP 145: an all-zero covariance means unknown).
    """
    variances = []
    for axis in calibration.axes:
        rms = axis.residual_rms
        variances.append(0.0 if rms is None or not math.isfinite(rms) else (rms / axis.scale) ** 2)
    return variances[0], variances[1], variances[2]
