"""A calibration checked on a pool: ``validate`` (every rest before and after it, by record) and ``diagnose``.

Each record is read once, as for ``fit`` (:func:`~tak_thermo_ros.passes.pool.open_pool`); a record's
rests beyond the calibrated range are said first (:func:`outside_lines`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np

from tak_thermo_ros.core.fit.pool import own_offsets, record_means
from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.errors import TakError
from tak_thermo_ros.passes.pool import OpenedPool, open_pool
from tak_thermo_ros.passes.run import StreamOptions


def check_driver_unit(unit, params: str) -> None:
    """A pool is checked against a driver calibration only (accelerometer and gyroscope).

    :raises TakError: ``unit`` (read from ``params``) is not one.
    """
    if unit.input_kind is not InputKind.IMU or unit.gyro is None:
        msg = f'{params}: a pool of records takes a driver calibration (accelerometer and gyroscope)'
        raise TakError(msg)


@dataclass(frozen=True)
class PoolCheck:
    """``validate`` of a pool: every rest's errors before (nominal) and after the calibration, by record.

    :param own: ``(r, 3)`` each record's mean rate error at rest after the calibration (its turn-on offset).
    :param shape: ``(k, 3)`` the rests' rate errors after, each record's own mean taken off.
    :param temperature: ``(k,)`` each rest's mean temperature; ``record`` its record; ``white`` ``(k, 3)`` the
        white noise's variance of its mean rate less its record's (what the shape holds of the noise).
    """

    opened: OpenedPool
    before: object
    after: object
    own: np.ndarray
    shape: np.ndarray
    temperature: np.ndarray = field(default_factory=lambda: np.zeros(0))
    record: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    white: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def shape_rms(self) -> np.ndarray:
        """``(3,)`` RMS of the rests' rate errors with each record's own offset taken off."""
        return np.sqrt(np.mean(self.shape ** 2, axis=0)) if len(self.shape) else np.zeros(3)


def validate_records(paths: Sequence[str | os.PathLike[str]], unit, options: StreamOptions, *, gravity: float,
                     latitude: float | None, out_of_range, say: Callable[[str], None] | None = None) -> PoolCheck:
    """The rests of a pool's records before and after ``unit`` (each record read once, as for ``fit``)."""
    from tak_thermo_ros.core.link.handheld_check import check_handheld
    from tak_thermo_ros.passes.handheld import nominal_unit
    opened = open_pool(paths, options, against=unit.fitted_from, say=say)
    record = opened.record
    assert record is not None
    before = check_handheld(record, nominal_unit(unit), gravity=gravity, latitude=latitude, out_of_range=out_of_range)
    after = check_handheld(record, unit, gravity=gravity, latitude=latitude, out_of_range=out_of_range)
    own, shape = own_offsets(record, after.rate_error)
    from tak_thermo_ros.core.fit.pool import _rests
    rest_record, samples, temperature = _rests(record)
    per_record = np.bincount(rest_record, weights=samples, minlength=record.records)
    # a rest's mean less its record's samples-weighted mean: s^2 / n - s^2 / N of white noise
    white = record.intervals.noise[3:6][None, :] ** 2 * (1.0 / samples - 1.0 / per_record[rest_record])[:, None]
    return PoolCheck(opened, before, after, own, shape, temperature, rest_record, white)


def outside_lines(check: PoolCheck, unit, policy) -> list[str]:
    """Per record whose rests reach beyond the calibrated temperature range: how many, how far, what was done.

    Said before the figures: a record beyond the range carries what the clamp (or the extrapolation)
    leaves in its rests' errors, which its turn-on offset would otherwise be blamed for.
    """
    from tak_thermo_ros.core.records.handheld import rest_records
    record = check.opened.record
    ranges = [(c.temp_code_min, c.temp_code_max) for _, c in unit.sensors if c.needs_temperature]
    if record is None or not ranges or not len(check.after.rest_outside):
        return []
    low, high = max(r[0] for r in ranges), min(r[1] for r in ranges)
    owner = rest_records(record)
    entries = {entry.name: entry for entry in check.opened.entries}
    done = 'clamped' if policy.value == 'clamp' else 'extrapolated'
    lines = []
    for index, name in enumerate(record.record_names):
        mine = owner == index
        outside = int(np.count_nonzero(check.after.rest_outside[mine] > 0.0))
        if outside:
            rests = entries[name].temperature or (low, high)
            lines.append(f'{name}: {outside} of its {int(mine.sum())} rests beyond the calibrated {low:.1f}..'
                         f'{high:.1f} C (its rests {rests[0]:.1f}..{rests[1]:.1f} C): {done}')
    return lines


def bounded_pool(paths: Sequence[str | os.PathLike[str]], options: StreamOptions, *, gravity: float,
                 latitude: float | None, max_samples: int, unit, say: Callable[[str], None] | None = None):
    """``diagnose`` of a pool: the rests' samples with their references, each record's own offset taken off.

    The references are a hand-held record's (gravity along each rest's corrected up direction, zero
    rate); each record's turn-on offset (its samples' mean residual after ``unit``, per axis) is
    taken off, so that what remains is the link's shape; ``groups`` give each sample's record
    (the folds hold whole records out; a pool of one record holds out time blocks).

    :returns: the :class:`~tak_thermo_ros.passes.diagnose.BoundedRun` and the pool as read.
    """
    from tak_thermo_ros.core.fit.model import residual_counts
    from tak_thermo_ros.passes.diagnose import BoundedRun
    from tak_thermo_ros.passes.handheld import rest_samples
    opened = open_pool(paths, options, samples=max_samples, say=say)
    record = opened.record
    assert record is not None
    samples, check = rest_samples(record, unit, gravity=gravity, latitude=latitude)
    groups = record.still_record
    for sensor, aligned in samples.items():
        own = record_means(residual_counts(unit.sensor(sensor), aligned), groups, record.records)
        samples[sensor] = replace(aligned, counts=aligned.counts - own[groups])
    usable = {sensor: len(aligned) for sensor, aligned in samples.items()}
    run = BoundedRun(input_kind=InputKind.IMU, samples=samples, usable=usable, stride=record.stride,
                     reference_lines=(), survey=None, handheld=check,
                     groups={sensor: groups for sensor in samples} if record.records > 1 else None)
    return run, opened
