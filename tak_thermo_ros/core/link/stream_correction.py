"""The correction, and the validation statistics, over a run that arrives in blocks.

:class:`Corrector.correct` runs the effects with memory (``thermal_lag``, ``hysteresis``,
``warmup``) from their initial state on every call. :class:`BlockCorrector` carries their state
from one call to the next, so that correcting a run block by block gives the same floats as one
call on the whole run: an effect's signals are advanced with :meth:`Effect.step`, which every
effect's :meth:`Effect.basis` reproduces bit for bit. Without effects the correction has no
state and the blocks are corrected by :class:`Corrector` itself.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from tak_thermo_ros.core.link.correction import Corrector, OutOfRange, UnitCorrector
from tak_thermo_ros.core.effects.base import basis_from, effect_input
from tak_thermo_ros.core.link.effect_link import EffectLink
from tak_thermo_ros.core.link.model import Calibration, UnitCalibration
from tak_thermo_ros.core.link.validate import GravityError, RateError
from tak_thermo_ros.units import amount


class _CarriedEffectLink(EffectLink):
    """:class:`EffectLink` whose array path continues the effects' state from the previous call."""

    def __init__(self, calibration: Calibration, *, clamp: bool) -> None:
        super().__init__(calibration, clamp=clamp)
        self._block_states: list[Any] = [None] * len(self._offset_effects)
        self._started = False

    def reset(self) -> None:
        super().reset()
        self._block_states = [None] * len(self._offset_effects)
        self._started = False

    def offset_series(self, temp_code: np.ndarray, stamp_s: np.ndarray | None,
                      aux: Mapping[str, np.ndarray] | None = None) -> list[np.ndarray]:
        count = len(temp_code)
        stamps = np.zeros(count) if stamp_s is None else np.asarray(stamp_s, dtype=float)
        extra = [np.zeros(count), np.zeros(count), np.zeros(count)]
        for index, (effect, amplitudes) in enumerate(zip(self._offset_effects, self._amplitudes)):
            basis, self._block_states[index] = basis_from(effect, self._block_states[index], stamps,
                                                          effect_input(effect, temp_code, aux), started=self._started)
            for i, axis_amplitudes in enumerate(amplitudes):
                total = extra[i]
                for b, amplitude in enumerate(axis_amplitudes):
                    total = total + amplitude * basis[:, b]
                extra[i] = total
        if count:
            self._started = True
        return extra


class BlockCorrector(Corrector):
    """A :class:`Corrector` whose :meth:`correct` continues the run from the previous call.

    :meth:`reset` starts a new run. Everything else is :class:`Corrector`'s.
    """

    def __init__(self, calibration: Calibration, *, out_of_range: OutOfRange = OutOfRange.CLAMP) -> None:
        super().__init__(calibration, out_of_range=out_of_range)
        if calibration.effects:
            self._effect_link = _CarriedEffectLink(calibration, clamp=self._clamp)


class BlockUnitCorrector(UnitCorrector):
    """A :class:`UnitCorrector` of :class:`BlockCorrector` s: blocks of six (or three) channels."""

    def __init__(self, unit: UnitCalibration, *, out_of_range: OutOfRange = OutOfRange.CLAMP) -> None:
        super().__init__(unit, out_of_range=out_of_range)
        self.correctors = tuple(BlockCorrector(calibration, out_of_range=out_of_range)
                                for _, calibration in unit.sensors)
        self._accel = self.correctors[0]
        self._gyro = self.correctors[1] if len(self.correctors) > 1 else None


class ErrorSums:
    """Running sums of an error series ``(k, c)``: RMS, mean and largest magnitude per column."""

    def __init__(self, columns: int) -> None:
        self.count = 0
        self.total = np.zeros(columns)
        self.squares = np.zeros(columns)
        self.largest = np.zeros(columns)

    def add(self, error: np.ndarray) -> None:
        """Add a block of errors."""
        if not len(error):
            return
        error = np.asarray(error, dtype=float).reshape(len(error), -1)
        self.count += len(error)
        self.total += error.sum(axis=0)
        self.squares += (error ** 2).sum(axis=0)
        self.largest = np.maximum(self.largest, np.abs(error).max(axis=0))

    def rms(self) -> np.ndarray:
        return np.sqrt(self.squares / self.count) if self.count else np.full(len(self.total), math.nan)

    def mean(self) -> np.ndarray:
        return self.total / self.count if self.count else np.full(len(self.total), math.nan)

    def gravity_error(self) -> GravityError:
        """As :meth:`GravityError.of` of the whole series (one column)."""
        return GravityError(rms=float(self.rms()[0]), max=float(self.largest[0]), mean=float(self.mean()[0]))

    def rate_error(self) -> RateError:
        """As :meth:`RateError.of` of the whole series (three columns)."""
        rms, mean, largest = self.rms(), self.mean(), self.largest

        def triple(values: np.ndarray) -> tuple[float, float, float]:
            return float(values[0]), float(values[1]), float(values[2])
        return RateError(rms=triple(rms), mean=triple(mean), max=triple(largest))


class NoiseSums:
    """What ``validate`` keeps of the corrected error series beyond its RMS.

    Its means over 1, 60 and 600 s (:class:`~tak_thermo_ros.core.link.validate.AveragedError`) and
    its overlapping Allan variance (for a noise model when none is given), both over blocks in
    bounded memory.
    """

    def __init__(self, columns: int) -> None:
        from tak_thermo_ros.core.link.validate import AveragedError
        self.averaged = AveragedError(columns=columns)
        self.columns = columns
        self.allan = None
        self.sample_period_s = 0.0

    def add(self, stamp_s: np.ndarray, error: np.ndarray) -> None:
        """Add a block of the corrected error, ``(k, columns)``, at ``stamp_s``."""
        if not len(stamp_s):
            return
        self.averaged.add(stamp_s, error)
        if self.allan is None and len(stamp_s) > 1:
            from tak_thermo_ros.core.noise.allan import AllanAccumulator
            self.sample_period_s = max(float(np.median(np.diff(stamp_s))), 1e-9)
            self.allan = AllanAccumulator(1.0 / self.sample_period_s, self.columns)
        if self.allan is not None:
            self.allan.add(np.asarray(error, dtype=float).reshape(len(stamp_s), self.columns))


class GravityCheck:
    """:func:`~tak_thermo_ros.core.link.validate.validate_gravity` accumulated over blocks.

    Beside the RMS and max of the |g| error it keeps (``noise``) that error's means over 1, 60 and
    600 s and its Allan variance (the |g| error itself, whatever the orientation, so that a table's
    positions are no steps in it) and the mean square of each axis's share of the measured
    direction (``direction_squares``: how a per-axis noise model projects onto |g|).
    ``raw_before``: *before* is the values as recorded (a driver's), not the nominal scale and offset.
    """

    def __init__(self, calibration: Calibration, *, gravity: float, out_of_range: OutOfRange,
                 raw_before: bool = False) -> None:
        self.gravity = gravity
        self.corrector = BlockCorrector(calibration, out_of_range=out_of_range)
        self.nominal = Corrector(calibration.uncorrected(as_recorded=raw_before), out_of_range=out_of_range)
        self.before = ErrorSums(1)
        self.after = ErrorSums(1)
        self.out_of_range = 0
        self.samples = 0
        self.noise = NoiseSums(1)
        self._direction_squares = np.zeros(3)

    @property
    def direction_squares(self) -> np.ndarray:
        """``(3,)`` the mean over the samples of the squared components of the measured unit direction."""
        return self._direction_squares / self.samples if self.samples else np.full(3, 1.0 / 3.0)

    def add(self, counts: np.ndarray, temp_code: np.ndarray, stamp_s: np.ndarray, *,
            aux: Mapping[str, np.ndarray] | None = None) -> None:
        """Add a block of aligned samples (``aux``: their held recorded signals, by name)."""
        after = self.corrector.correct(counts, temp_code, stamp_s=stamp_s, aux=aux)
        before = self.nominal.correct(counts, temp_code)
        magnitude = np.linalg.norm(after, axis=1)
        self.after.add(magnitude - self.gravity)
        self.before.add(np.linalg.norm(before, axis=1) - self.gravity)
        if len(after):
            stamps = np.asarray(stamp_s, dtype=float)
            self.noise.add(stamps, (magnitude - self.gravity)[:, None])
            unit = after / np.where(magnitude > 0.0, magnitude, 1.0)[:, None]
            self._direction_squares += np.sum(unit ** 2, axis=0)
        self.out_of_range += self.corrector.out_of_range_count(temp_code)
        self.samples += len(counts)

    def summary(self, record: str) -> str:
        """The |g| error before and after the correction, one statement per line (``record``: its name).

        In m/s^2 with mg beside (:func:`~tak_thermo_ros.units.amount`); ``tak_calib validate`` prints it.
        """
        lines = [f'|g| error over {self.samples} samples of {record} (gravity {self.gravity:g} m/s^2):']
        for label, sums in (('before', self.before), ('after ', self.after)):
            stats = sums.gravity_error()
            lines.append(f'  {label} correction: RMS {amount(stats.rms, "m/s^2")}, max {amount(stats.max, "m/s^2")}')
        return '\n'.join(lines)


class RateCheck:
    """:func:`~tak_thermo_ros.core.link.validate.validate_rate` accumulated over blocks.

    ``raw_before``: *before* is the values as recorded (a driver's), not the nominal scale and offset.
    """

    def __init__(self, calibration: Calibration, *, out_of_range: OutOfRange, raw_before: bool = False) -> None:
        self.corrector = BlockCorrector(calibration, out_of_range=out_of_range)
        self.nominal = Corrector(calibration.uncorrected(as_recorded=raw_before), out_of_range=out_of_range)
        self.before = ErrorSums(3)
        self.after = ErrorSums(3)
        self.out_of_range = 0
        self.samples = 0
        self.noise = NoiseSums(3)

    def add(self, rate: np.ndarray, temperature: np.ndarray, reference: np.ndarray, stamp_s: np.ndarray, *,
            aux: Mapping[str, np.ndarray] | None = None) -> None:
        """Add a block of aligned samples with their held rate reference (``aux`` as :meth:`GravityCheck.add`)."""
        after = self.corrector.correct(rate, temperature, stamp_s=stamp_s, aux=aux)
        before = self.nominal.correct(rate, temperature)
        self.after.add(after - reference)
        self.before.add(before - reference)
        self.noise.add(np.asarray(stamp_s, dtype=float), after - reference)
        self.out_of_range += self.corrector.out_of_range_count(temperature)
        self.samples += len(rate)

    def summary(self) -> str:
        """The rate error before and after the correction, RMS and mean per axis x y z, one statement per line.

        In rad/s with deg/h beside (:func:`~tak_thermo_ros.units.amount`); ``tak_calib validate`` prints it.
        """
        lines = [f'gyroscope error over {self.samples} samples (rate minus reference), per axis x y z:']
        for label, sums in (('before', self.before), ('after ', self.after)):
            stats = sums.rate_error()
            lines += [f'  {label} correction: RMS  {amount(stats.rms, "rad/s")}',
                      f'  {label} correction: mean {amount(stats.mean, "rad/s")}']
        return '\n'.join(lines)
