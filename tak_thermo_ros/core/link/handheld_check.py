"""What a calibration leaves on a hand-held record: the rests' |g| and rate, the turns' closure.

Without a table the truth of a hand-held record is known only where the fit took it from: at
rest the corrected specific force has the magnitude of local gravity and the corrected rate is
zero (or the Earth's vertical component), and a turn's corrected rates integrate to a rotation
that carries one rest's up direction onto the next's. ``validate`` and ``diagnose`` measure a
calibration against these on a record the fit did not see, through the one correction path
(:class:`~tak_thermo_ros.core.link.correction.UnitCorrector`, effects with memory run over the
still and turn samples together in time order).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from tak_thermo_ros.core.link.correction import OutOfRange, UnitCorrector
from tak_thermo_ros.core.link.model import UnitCalibration
from tak_thermo_ros.core.records.handheld import (
    HandheldRecord,
    TurnClosure,
    closure_terms,
    earth_reference,
    merged_samples,
    numbered_rests,
)
from tak_thermo_ros.core.rotation import integrate_segments


@dataclass(frozen=True)
class HandheldCheck:
    """One calibration's errors on a hand-held record.

    :param gravity_error: ``(k,)`` per still interval, ``|mean corrected specific force| - g``, m/s^2.
    :param rate_error: ``(k, 3)`` per still interval, mean corrected rate minus the rate at rest, rad/s.
    :param closure: the turns' closure with the corrected rates and up directions.
    :param up: ``(k, 3)`` each interval's corrected up direction.
    :param samples: still samples used.
    :param out_of_range: samples outside the calibrated temperature range.
    :param gravity_floor: the RMS |g| error the noise alone leaves (each rest's mean of white noise), m/s^2.
    :param rate_floor: ``(3,)`` likewise for the rate per axis, rad/s.
    :param rest_outside: ``(k,)`` per still interval, the share of its samples outside the calibrated
        temperature range.
    """

    gravity_error: np.ndarray
    rate_error: np.ndarray
    closure: TurnClosure
    up: np.ndarray
    samples: int
    out_of_range: int
    gravity_floor: float = 0.0
    rate_floor: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rest_outside: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def gravity_rms(self) -> float:
        """RMS of the intervals' |g| error, m/s^2."""
        return float(np.sqrt(np.mean(self.gravity_error ** 2))) if len(self.gravity_error) else 0.0

    @property
    def rate_rms(self) -> np.ndarray:
        """``(3,)`` RMS of the intervals' rate error per axis, rad/s."""
        return np.sqrt(np.mean(self.rate_error ** 2, axis=0)) if len(self.rate_error) else np.zeros(3)


def corrected(record: HandheldRecord, unit: UnitCalibration, *, out_of_range: OutOfRange = OutOfRange.CLAMP
              ) -> tuple[np.ndarray, np.ndarray, int]:
    """The still and turn samples corrected, ``(n, 6)`` and ``(m, 6)``, and the samples out of range."""
    series, still_rows, turn_rows = merged_samples(record)
    corrector = UnitCorrector(unit, out_of_range=out_of_range)
    values = corrector.correct(series.counts, series.temp_code, stamp_s=series.stamp_s, aux=series.aux)
    return values[still_rows], values[turn_rows], corrector.out_of_range_count(series.temp_code)


def check_handheld(record: HandheldRecord, unit: UnitCalibration, *, gravity: float, latitude: float | None = None,
                   out_of_range: OutOfRange = OutOfRange.CLAMP) -> HandheldCheck:
    """The errors ``unit`` leaves on ``record`` (a driver calibration: both sensors)."""
    still, turn, outside = corrected(record, unit, out_of_range=out_of_range)
    interval, count, pairs, used = numbered_rests(record)
    kept = np.bincount(interval, minlength=count).astype(float)
    means = np.zeros((count, 6))
    np.add.at(means, interval, still)
    means /= np.maximum(kept, 1.0)[:, None]
    magnitude = np.linalg.norm(means[:, :3], axis=1)
    up = means[:, :3] / np.where(magnitude > 0.0, magnitude, 1.0)[:, None]
    rest = earth_reference(up, np.arange(count), latitude)
    noise = record.intervals.noise
    up_noise = float(np.sqrt(np.mean(noise[:3] ** 2))) / (gravity * np.sqrt(np.maximum(kept, 1.0)))
    rows = used[record.turn_index] if len(record.turn_index) else np.zeros(0, dtype=bool)
    renumber = np.cumsum(used) - 1
    turn_index = renumber[record.turn_index[rows]]
    rotations, jacobians = integrate_segments(turn[rows, 3:6], record.turn.stamp_s[rows], turn_index,
                                              int(used.sum()), jacobian=True)
    closure = closure_terms(rotations, jacobians, turn_index, pairs[used], up, up_noise, noise[3:6]).closure
    seconds = record.turn_seconds()[used]
    per_rest = 1.0 / np.maximum(kept, 1.0)
    gravity_floor = float(np.sqrt(np.mean(per_rest * (up ** 2 @ noise[:3] ** 2)))) if count else 0.0
    rate_floor = np.sqrt(np.mean(per_rest)) * noise[3:6] if count else np.zeros(3)
    beyond = UnitCorrector(unit).out_of_range(record.still.temp_code).astype(float)
    rest_outside = np.bincount(interval, weights=beyond, minlength=count) / np.maximum(kept, 1.0)
    return HandheldCheck(gravity_error=magnitude - gravity, rate_error=means[:, 3:6] - rest,
                         closure=replace(closure, seconds=seconds), up=up, samples=len(still),
                         out_of_range=outside, gravity_floor=gravity_floor, rate_floor=rate_floor,
                         rest_outside=rest_outside)
