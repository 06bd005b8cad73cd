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
from typing import Mapping

import numpy as np

from tak_thermo_ros.core.link.effect_link import EffectLink
from tak_thermo_ros.core.link.model import Calibration, UnitCalibration, correction_terms, offset_and_gain

NOT_PROVIDED = -1.0
"""``covariance[0]`` of a quantity a ``sensor_msgs/msg/Imu`` does not carry (REP 145): an orientation a
driver does not estimate, or a sensor's sample a message does not hold (its values then zero)."""
NOT_PROVIDED_COVARIANCE: tuple[float, ...] = (NOT_PROVIDED, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
"""The whole covariance of such a quantity, as the node and ``tak_calib apply`` write it."""
BLOCK_SAMPLES = 16384
"""Samples per block of :meth:`Corrector.correct` (its scratch arrays stay in the CPU cache)."""


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
        self._axes = correction_terms(calibration)
        # A link without temperature terms reads no temperature: every input is taken at N_t,ref
        # (NaN where a record holds none), so that nothing downstream sees one.
        self._fixed = None if calibration.needs_temperature else self._ref
        # Effects (tak_thermo_ros.core.effects) take their own link; without them, the path below.
        self._effect_link = EffectLink(calibration, clamp=self._clamp) if calibration.effects else None
        self._held_temperature: float | None = None
        """The temperature (the object) :attr:`_held` was evaluated at, ``None`` before the first."""
        self._held: tuple[float, ...] = ()
        """``(offset_x, gain_x, offset_y, gain_y, offset_z, gain_z)`` at :attr:`_held_temperature`."""

    @property
    def signals(self) -> tuple[str, ...]:
        """Names (``aux:TOPIC``) of the recorded signals the correction needs besides the temperature."""
        return self._effect_link.signals if self._effect_link is not None else ()

    def reset(self) -> None:
        """Forget the online state of effects with memory (the node after a restart or a gap)."""
        if self._effect_link is not None:
            self._effect_link.reset()

    def code_offset(self, temp_code):
        """``n = N_t - N_t,ref`` after the out-of-range policy (scalar or array); 0 without temperature terms."""
        if self._fixed is not None:
            return np.zeros(np.shape(temp_code)) if isinstance(temp_code, np.ndarray) else 0.0
        if self._clamp:
            if isinstance(temp_code, np.ndarray):
                temp_code = np.clip(temp_code, self._low, self._high)
            else:
                temp_code = min(max(temp_code, self._low), self._high)
        return temp_code - self._ref

    def correct_sample(self, counts_x: float, counts_y: float, counts_z: float,
                       temp_code: float, *, stamp_s: float = 0.0,
                       aux: Mapping[str, float] | None = None) -> tuple[float, float, float]:
        """Specific force (m/s^2) of one sample from plain floats; the node's path.

        :param stamp_s: the sample's stamp in seconds (for model terms with memory).
        :param aux: held values of the recorded signals in :attr:`signals`, by name.
        """
        if self._fixed is not None:
            temp_code = self._fixed
        if self._effect_link is not None:
            return self._effect_link.correct_sample(counts_x, counts_y, counts_z, temp_code, stamp_s, aux)
        if temp_code is not self._held_temperature:  # a new temperature: the polynomials once, not per sample
            self._take_temperature(temp_code)
        offset_x, gain_x, offset_y, gain_y, offset_z, gain_z = self._held
        return (counts_x - offset_x) / gain_x, (counts_y - offset_y) / gain_y, (counts_z - offset_z) / gain_z

    def _take_temperature(self, temp_code: float) -> None:
        """Each axis's offset and gain at ``temp_code``, held until the temperature changes.

        A driver sends a temperature every few to hundreds of samples: the samples in between are
        corrected with the same offsets and gains (``offset_and_gain``, the same operations as the
        vectorised path: the same bits). Held by the temperature's identity (the online core hands
        the same float object over until the next temperature arrives): an equal value of another
        object is evaluated again, so that 0.0 and -0.0 never share a result.
        """
        # code_offset(temp_code) inline
        if self._fixed is not None:
            n = 0.0
        elif self._clamp:
            n = min(max(temp_code, self._low), self._high) - self._ref
        else:
            n = temp_code - self._ref
        x_axis, y_axis, z_axis = self._axes
        self._held = (*offset_and_gain(n, *x_axis), *offset_and_gain(n, *y_axis), *offset_and_gain(n, *z_axis))
        self._held_temperature = temp_code

    def correct_values(self, values: tuple[float, float, float], temp_code: float, *, stamp_s: float = 0.0,
                       aux: Mapping[str, float] | None = None) -> tuple[float, float, float]:
        """:meth:`correct_sample` of the three values of a tuple (one sensor's, in the node)."""
        return self.correct_sample(values[0], values[1], values[2], temp_code, stamp_s=stamp_s, aux=aux)

    def correct(self, counts: np.ndarray, temp_code: np.ndarray, *,
                stamp_s: np.ndarray | None = None, aux: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        """Specific force ``(k, 3)`` in m/s^2 from codes ``(k, 3)`` and temperature codes ``(k,)``.

        :param stamp_s: ``(k,)`` stamps in seconds (for model terms with memory).
        :param aux: ``(k,)`` held values of the recorded signals in :attr:`signals`, by name.
        """
        temp_code = self._temperatures(temp_code, len(counts))
        if self._effect_link is not None:
            return self._effect_link.correct(counts, temp_code, stamp_s, aux)
        counts = np.asarray(counts, dtype=float)
        size = len(counts)
        temp_code = np.broadcast_to(np.asarray(temp_code, dtype=float), (size,))
        out = np.empty_like(counts)
        # Blocks small enough for the CPU cache, with reused scratch arrays: millions of
        # samples go several times faster than with whole-array temporaries.
        scratch = np.empty((4, min(size, BLOCK_SAMPLES)))
        for start in range(0, size, BLOCK_SAMPLES):
            stop = min(start + BLOCK_SAMPLES, size)
            self._correct_block(counts[start:stop], temp_code[start:stop], out[start:stop],
                                scratch[:, :stop - start])
        return out

    def _temperatures(self, temp_code, size: int):
        """The temperature inputs the link reads: as given, or ``N_t,ref`` for a link without temperature terms."""
        if self._fixed is None:
            return temp_code
        return np.full(size, self._fixed)

    def _correct_block(self, counts: np.ndarray, temp_code: np.ndarray, out: np.ndarray,
                       scratch: np.ndarray) -> None:
        """:meth:`correct` of one block into ``out``: per axis the operations of ``offset_and_gain``, in place."""
        n, drift, factor, centred = scratch
        if self._clamp:
            np.clip(temp_code, self._low, self._high, out=n)
        else:
            n[...] = temp_code
        np.subtract(n, self._ref, out=n)
        for i, (scale, offset, span, shape_s, shape_c) in enumerate(self._axes):
            _horner_into(shape_s, n, drift)
            _horner_into(shape_c, n, factor)
            np.multiply(span, drift, out=drift)
            np.add(offset, drift, out=drift)
            np.subtract(counts[:, i], drift, out=centred)
            np.add(factor, 1.0, out=factor)
            np.multiply(scale, factor, out=factor)
            np.divide(centred, factor, out=out[:, i])

    def code_at_reference(self, counts: np.ndarray, temp_code: np.ndarray, *,
                          stamp_s: np.ndarray | None = None,
                          aux: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        """The paper's ``N_hat(0) = (N - dNs(n)) / F_c(n) + dNs0``, codes ``(k, 3)``.

        With effects: ``K0 f_hat + dNs0``, the code the same input gives at normal conditions
        without the effects.
        """
        temp_code = self._temperatures(temp_code, len(counts))
        if self._effect_link is not None:
            force = self._effect_link.correct(counts, temp_code, stamp_s, aux)
            return np.column_stack([axis.scale * force[:, i] + axis.offset
                                    for i, axis in enumerate(self.calibration.axes)])
        counts = np.asarray(counts, dtype=float)
        n = self.code_offset(np.asarray(temp_code, dtype=float))
        out = np.empty_like(counts)
        for i, axis in enumerate(self.calibration.axes):
            centred = counts[:, i] - (axis.offset + axis.offset_drift(n))
            out[:, i] = centred / axis.scale_factor(n) + axis.offset
        return out

    def predict_counts(self, specific_force: np.ndarray, temp_code: np.ndarray, *,
                       stamp_s: np.ndarray | None = None,
                       aux: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        """The forward model under this corrector's policy: unrounded codes ``(k, 3)``.

        The inverse of :meth:`correct` (effects included, from their initial state).
        """
        temp_code = self._temperatures(temp_code, len(specific_force))
        link = self._effect_link or EffectLink(self.calibration, clamp=self._clamp)
        return link.predict_counts(specific_force, temp_code, stamp_s, aux)

    def out_of_range_count(self, temp_code: np.ndarray) -> int:
        """How many temperature codes lie outside the calibrated range (none for a link without temperature terms)."""
        temp_code = np.asarray(temp_code, dtype=float)
        if self._fixed is not None:
            return 0
        return int(np.count_nonzero((temp_code < self._low) | (temp_code > self._high)))


def _horner_into(shape: tuple[float, ...], n: np.ndarray, out: np.ndarray) -> None:
    """``out = c1 n + ... + ck n^k`` in place, coefficients highest first, as ``offset_and_gain``."""
    np.multiply(0.0, n, out=out)
    for coefficient in shape:
        np.add(out, coefficient, out=out)
        np.multiply(out, n, out=out)


def forward_counts(calibration: Calibration, specific_force: np.ndarray, temp_code: np.ndarray, *,
                   stamp_s: np.ndarray | None = None,
                   aux: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
    """The whole forward model, effects included.

    (from their initial state), polynomials evaluated beyond the calibrated range: unrounded codes ``(k, 3)``; what a
    simulator and the tests run a unit through.

    :param stamp_s: ``(k,)`` stamps in seconds, needed by effects with memory.
    :param aux: ``(k,)`` held recorded signals by name, needed by ``aux:`` effects.
    """
    if not calibration.effects:
        return calibration.forward(specific_force, temp_code)
    return Corrector(calibration, out_of_range=OutOfRange.EXTRAPOLATE).predict_counts(
        specific_force, temp_code, stamp_s=stamp_s, aux=aux)


class UnitCorrector:
    """The correction of a whole IMU: one :class:`Corrector` per sensor, the same policy.

    With a driver calibration, :meth:`correct` and :meth:`correct_sample` take and return six
    channels (accel x y z, gyro x y z); with a counts calibration, three (the accelerometer).

    :param unit: the calibration of the unit.
    :param out_of_range: policy for temperatures outside the calibrated range.
    """

    def __init__(self, unit: UnitCalibration, *, out_of_range: OutOfRange = OutOfRange.CLAMP) -> None:
        self.unit = unit
        self.correctors = tuple(Corrector(calibration, out_of_range=out_of_range)
                                for _, calibration in unit.sensors)
        self._accel = self.correctors[0]
        self._gyro = self.correctors[1] if len(self.correctors) > 1 else None

    @property
    def channels(self) -> int:
        """3 (accelerometer) or 6 (accelerometer and gyroscope)."""
        return 3 * len(self.correctors)

    def reset(self) -> None:
        """Forget the online state of effects with memory, on every sensor."""
        for corrector in self.correctors:
            corrector.reset()

    @property
    def signals(self) -> tuple[str, ...]:
        """Names (``aux:TOPIC``) of the recorded signals any sensor's correction needs, in order."""
        return tuple(dict.fromkeys(name for corrector in self.correctors for name in corrector.signals))

    def correct(self, values: np.ndarray, temperature: np.ndarray, *,
                stamp_s: np.ndarray | None = None, aux: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        """Corrected ``(k, channels)`` from raw ``(k, channels)`` and the temperature input ``(k,)``.

        :param aux: ``(k,)`` held values of the recorded signals in :attr:`signals`, by name.
        """
        return np.hstack([corrector.correct(values[:, 3 * i:3 * i + 3], temperature, stamp_s=stamp_s, aux=aux)
                          for i, corrector in enumerate(self.correctors)])

    def correct_sample(self, values: tuple[float, ...], temperature: float, *,
                       stamp_s: float = 0.0, aux: Mapping[str, float] | None = None) -> tuple[float, ...]:
        """One sample of 3 or 6 plain floats; the node's path, bit-identical to :meth:`correct`."""
        accel = self._accel.correct_sample(values[0], values[1], values[2], temperature, stamp_s=stamp_s, aux=aux)
        if self._gyro is None:
            return accel
        return accel + self._gyro.correct_sample(values[3], values[4], values[5], temperature, stamp_s=stamp_s,
                                                 aux=aux)

    def out_of_range(self, temperature: np.ndarray) -> np.ndarray:
        """``(k,)`` whether each temperature lies outside the calibrated range of any sensor."""
        temperature = np.asarray(temperature, dtype=float)
        outside = np.zeros(len(temperature), dtype=bool)
        for _, calibration in self.unit.sensors:
            if not calibration.needs_temperature:
                continue
            outside |= (temperature < calibration.temp_code_min) | (temperature > calibration.temp_code_max)
        return outside

    def out_of_range_count(self, temperature: np.ndarray) -> int:
        """How many temperatures lie outside the calibrated range of any sensor."""
        return int(np.count_nonzero(self.out_of_range(temperature)))


def acceleration_variance(calibration: Calibration) -> tuple[float, float, float]:
    """Per-axis variance of the corrected output of one sensor: the noise model's, else the fit residual's.

    (m/s^2)^2 for an accelerometer, (rad/s)^2 for a gyroscope. With a noise model
    (``calibration.noise``) it is its per-sample variance (:meth:`NoiseModel.sample_variance`:
    ``white_noise_density^2 * update_rate`` per axis plus what the other terms add at one
    sample period; what a sample's error is, without the slow wander that a covariance per
    sample cannot describe). Without one, from the fit
    residual; zero where that is unknown (REP 145: an all-zero covariance means unknown).
    """
    if calibration.noise is not None:
        return calibration.noise.sample_variance()
    variances = []
    for axis in calibration.axes:
        rms = axis.residual_rms
        variances.append(0.0 if rms is None or not math.isfinite(rms) else (rms / axis.scale) ** 2)
    return variances[0], variances[1], variances[2]


def imu_covariances(variance: tuple[float, float, float],
                    angular_variance: tuple[float, float, float] | None = None,
                    ) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
    """Orientation, angular-velocity and linear-acceleration covariances of the Imu output.

    The one layout for the node and ``tak_calib apply``. REP 145: ``[0] = -1`` marks a
    quantity as not provided: the orientation always here (a driver's own orientation
    covariance is passed through by the caller), the angular velocity when there is no
    gyroscope calibration (``angular_variance`` None). Provided quantities get a diagonal
    covariance from the fit residual (all zero when unknown).
    """
    not_provided = NOT_PROVIDED_COVARIANCE

    def diagonal(values: tuple[float, float, float]) -> tuple[float, ...]:
        x, y, z = (float(v) for v in values)
        return (x, 0.0, 0.0, 0.0, y, 0.0, 0.0, 0.0, z)

    angular = not_provided if angular_variance is None else diagonal(angular_variance)
    return not_provided, angular, diagonal(variance)
