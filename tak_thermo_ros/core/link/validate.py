"""Validation as in the paper's Figs. 4-5: |g| from the three corrected channels.

*Before* applies the nominal scale and offset only (every temperature term off), or for a
driver's values (``raw_before``) nothing: the values as recorded; *after* applies the whole
correction link. Meaningful on a static run, or on a turntable run whose
positions all see the same |g|.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from tak_thermo_ros.core.link.correction import Corrector, OutOfRange
from tak_thermo_ros.core.link.model import Calibration
from tak_thermo_ros.core.values import STANDARD_GRAVITY


@dataclass(frozen=True)
class GravityError:
    """Statistics of ``|g_hat| - g`` in m/s^2."""

    rms: float
    max: float
    mean: float

    @classmethod
    def of(cls, error: np.ndarray) -> GravityError:
        """Statistics of an error series."""
        return cls(rms=float(np.sqrt(np.mean(error ** 2))), max=float(np.max(np.abs(error))),
                   mean=float(np.mean(error)))

    def as_dict(self) -> dict[str, float]:
        """JSON-ready form."""
        return {'rms': self.rms, 'max': self.max, 'mean': self.mean}


@dataclass(frozen=True)
class GravityValidation:
    """|g| before and after correction.

    :param magnitude_before: ``(k,)`` |g| with nominal scale and offset only, m/s^2.
    :param magnitude_after: ``(k,)`` |g| after the full correction, m/s^2.
    """

    gravity: float
    magnitude_before: np.ndarray
    magnitude_after: np.ndarray
    out_of_range: int

    @property
    def before(self) -> GravityError:
        """Error statistics before correction."""
        return GravityError.of(self.magnitude_before - self.gravity)

    @property
    def after(self) -> GravityError:
        """Error statistics after correction."""
        return GravityError.of(self.magnitude_after - self.gravity)


def validate_gravity(calibration: Calibration, counts: np.ndarray, temp_code: np.ndarray, *,
                     gravity: float = STANDARD_GRAVITY,
                     out_of_range: OutOfRange = OutOfRange.CLAMP,
                     stamp_s: np.ndarray | None = None,
                     aux: Mapping[str, np.ndarray] | None = None, raw_before: bool = False) -> GravityValidation:
    """Compare |g| from the three channels with local gravity, before and after correction.

    :param stamp_s: ``(k,)`` stamps in seconds, needed by effects with memory.
    :param aux: ``(k,)`` held recorded signals by name, needed by ``aux:`` effects.
    :param raw_before: *before* is the values as recorded (a driver's), not the nominal scale and offset.
    """
    corrector = Corrector(calibration, out_of_range=out_of_range)
    after = corrector.correct(counts, temp_code, stamp_s=stamp_s, aux=aux)
    flat = Corrector(calibration.uncorrected(as_recorded=raw_before), out_of_range=out_of_range)
    before = flat.correct(counts, temp_code)
    return GravityValidation(gravity=gravity,
                             magnitude_before=np.linalg.norm(before, axis=1),
                             magnitude_after=np.linalg.norm(after, axis=1),
                             out_of_range=corrector.out_of_range_count(temp_code))


@dataclass(frozen=True)
class RateError:
    """Per-axis statistics of ``omega_hat - omega_ref``, rad/s: the gyroscope's bias error.

    :param rms: ``(3,)`` RMS per axis x, y, z.
    :param mean: ``(3,)`` mean per axis (the bias left after correction).
    :param max: ``(3,)`` largest absolute error per axis.
    """

    rms: tuple[float, float, float]
    mean: tuple[float, float, float]
    max: tuple[float, float, float]

    @classmethod
    def of(cls, error: np.ndarray) -> RateError:
        """Statistics of an ``(k, 3)`` error series."""
        def triple(values: np.ndarray) -> tuple[float, float, float]:
            return float(values[0]), float(values[1]), float(values[2])
        return cls(rms=triple(np.sqrt(np.mean(error ** 2, axis=0))), mean=triple(np.mean(error, axis=0)),
                   max=triple(np.max(np.abs(error), axis=0)))

    def as_dict(self) -> dict[str, dict[str, float]]:
        """JSON-ready form, per axis."""
        return {name: {'rms': self.rms[i], 'mean': self.mean[i], 'max': self.max[i]}
                for i, name in enumerate(('x', 'y', 'z'))}


@dataclass(frozen=True)
class RateValidation:
    """The gyroscope's rate error before and after correction.

    :param before: with the nominal scale and offset only.
    :param after: with the whole correction link.
    :param out_of_range: samples outside the calibrated temperature range.
    """

    before: RateError
    after: RateError
    out_of_range: int


def validate_rate(calibration: Calibration, rate: np.ndarray, temperature: np.ndarray,
                  reference: np.ndarray, *, out_of_range: OutOfRange = OutOfRange.CLAMP,
                  stamp_s: np.ndarray | None = None,
                  aux: Mapping[str, np.ndarray] | None = None, raw_before: bool = False) -> RateValidation:
    """Compare the corrected angular rate with the reference (zero on a static run), per axis.

    :param rate: ``(k, 3)`` the driver's angular velocity, rad/s.
    :param temperature: ``(k,)`` held temperature.
    :param reference: ``(k, 3)`` held true rate, rad/s.
    :param stamp_s: ``(k,)`` stamps in seconds, needed by effects with memory.
    :param raw_before: *before* is the rates as recorded, not the nominal scale and offset.
    """
    corrector = Corrector(calibration, out_of_range=out_of_range)
    after = corrector.correct(rate, temperature, stamp_s=stamp_s, aux=aux)
    flat = Corrector(calibration.uncorrected(as_recorded=raw_before), out_of_range=out_of_range)
    before = flat.correct(rate, temperature)
    return RateValidation(before=RateError.of(before - reference), after=RateError.of(after - reference),
                          out_of_range=corrector.out_of_range_count(temperature))


AVERAGING_TIMES_S: tuple[float, ...] = (1.0, 60.0, 600.0)
"""The averaging times at which ``validate`` gives the bias error of the corrected output."""


class AveragedError:
    """The RMS of an error series averaged over consecutive windows of ``tau`` seconds, per column.

    The bias error a navigator sees after averaging for ``tau``: what the correction leaves
    (a bias that stays) plus the noise's share at that averaging time. Accumulated over blocks
    in time order (a window may straddle two blocks); the last, incomplete window is left out.

    :param taus: averaging times, s.
    :param columns: columns of the error series.
    """

    def __init__(self, taus: tuple[float, ...] = AVERAGING_TIMES_S, columns: int = 3) -> None:
        self.taus = tuple(float(t) for t in taus)
        self.columns = columns
        self._start: float | None = None
        self._window = [-1] * len(self.taus)
        self._sum = [np.zeros(columns) for _ in self.taus]
        self._count = [0] * len(self.taus)
        self._squares = [np.zeros(columns) for _ in self.taus]
        self._windows = [0] * len(self.taus)

    def add(self, time_s: np.ndarray, error: np.ndarray) -> None:
        """Add a block: ``time_s`` ``(k,)`` seconds in increasing order, ``error`` ``(k, columns)``."""
        if not len(time_s):
            return
        error = np.asarray(error, dtype=float).reshape(len(time_s), -1)
        if self._start is None:
            self._start = float(time_s[0])
        for j, tau in enumerate(self.taus):
            # A stamp on a window's edge (to rounding) opens the next window.
            window = np.floor((np.asarray(time_s, dtype=float) - self._start) / tau + 1e-9).astype(np.int64)
            edges = np.flatnonzero(np.diff(window)) + 1
            starts = np.concatenate(([0], edges))
            stops = np.concatenate((edges, [len(window)]))
            for start, stop in zip(starts, stops):
                if window[start] != self._window[j]:
                    self._close(j)
                    self._window[j] = int(window[start])
                self._sum[j] += error[start:stop].sum(axis=0)
                self._count[j] += stop - start

    def _close(self, j: int) -> None:
        if self._count[j]:
            mean = self._sum[j] / self._count[j]
            self._squares[j] += mean ** 2
            self._windows[j] += 1
        self._sum[j] = np.zeros(self.columns)
        self._count[j] = 0

    def rms(self) -> dict[float, np.ndarray]:
        """``tau -> (columns,)`` RMS of the complete windows' means (NaN when no window completed)."""
        return {tau: (np.sqrt(self._squares[j] / self._windows[j]) if self._windows[j]
                      else np.full(self.columns, math.nan))
                for j, tau in enumerate(self.taus)}

    def windows(self) -> dict[float, int]:
        """``tau ->`` complete windows."""
        return {tau: self._windows[j] for j, tau in enumerate(self.taus)}
