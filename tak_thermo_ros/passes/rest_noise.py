"""The noise model every ``tak_calib fit`` writes, from what the fit saw (:mod:`~tak_thermo_ros.core.noise.rests`).

Two kinds of record give their stretches two ways:

- **A table run, a chamber run, a static run** (one streamed pass): the fit's pass also cuts each
  sensor's samples into half-second windows within stretches of a held reference
  (:class:`~tak_thermo_ros.core.noise.rests.StretchWindows`); after the fit the windows' means are
  corrected with the link just fitted (effects with memory run over them in time order), and the
  residual (corrected less reference) gives the white noise between successive windows and, in
  stretches of at most :data:`STRETCH_S`, the means the wander is judged on. The fixed effects:
  the offset polynomial in temperature and the reference times the scale polynomial, per axis.
- **Rests** (a hand-held record, a pool of everyday records): the still detector's sums of every
  sample of every rest give the white noise; each rest's mean residual after the fit
  (:func:`~tak_thermo_ros.core.link.handheld_check.check_handheld`: the gyroscope's rate less the
  Earth's vertical part, ``|f|`` less gravity) gives the wander. The fixed effects: each record's
  own level (its turn-on offset; the accelerometer's along each rest's up direction) and the
  offset polynomial in temperature (the accelerometer's along the up direction, its scale
  polynomial along its square). Near-level rests see the accelerometer's wander along the vertical
  only: that is written on every axis, and said. With a latitude, the Earth rate's horizontal part
  at each rest's unknown heading counts as each mean's own noise (as the watch counts it);
  without, it counts as wander (more than the sensor's: on the safe side).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.link.model import Calibration, UnitCalibration
from tak_thermo_ros.core.noise.rests import RestMeans, RestNoise, ShortSums, StretchWindows, rest_noise, \
    temperature_columns
from tak_thermo_ros.core.values import EARTH_RATE

STRETCH_S = 60.0
"""A long stretch (a static run) gives a mean every this many seconds (as the watch cuts a long rest)."""


def _orders(calibration: Calibration) -> tuple[int, int]:
    """The offset and scale polynomials' orders of a fitted link (0 for a scale without temperature terms)."""
    offset = max(len(axis.offset_shape) for axis in calibration.axes) if calibration.needs_temperature else 0
    scale = max(len(axis.scale_shape) if any(axis.scale_shape) else 0 for axis in calibration.axes) \
        if calibration.needs_temperature else 0
    return offset, scale


def streamed_noise(windows: StretchWindows, calibration: Calibration) -> RestNoise | None:
    """A sensor's noise model from its windows within a run's stretches (``None``: too few samples for one)."""
    rows = windows.rows()
    if len(rows) < 2 or not windows.window:
        return None
    plain = replace(calibration, effects=tuple(e for e in calibration.effects if e.needs_signal is None))
    stretch, start_ns, end_ns = rows[:, 0], rows[:, 1], rows[:, 2]
    temperature = rows[:, 9]
    centre_s = 0.5 * (start_ns + end_ns) * 1e-9
    residual = Corrector(plain).correct(rows[:, 3:6], temperature, stamp_s=centre_s) - rows[:, 6:9]
    period_s = windows.period_ns * 1e-9
    window_s = windows.window * period_s
    scales = np.array([axis.scale for axis in calibration.axes])
    same = stretch[1:] == stretch[:-1]
    short = ShortSums(period_s=period_s, window_s=window_s,
                      one=rows[:, 10:13].sum(axis=0) / scales ** 2, one_terms=len(rows) * (windows.window - 1),
                      window=0.5 * np.sum(np.diff(residual, axis=0)[same] ** 2, axis=0),
                      window_terms=int(np.count_nonzero(same)))
    # Each stretch cut into equal means of about STRETCH_S (the watch's formulas want neighbours alike).
    first = np.flatnonzero(np.concatenate([[True], ~same]))
    lengths = np.diff(np.concatenate([first, [len(rows)]]))
    pieces = np.maximum(1, np.round(lengths * window_s / STRETCH_S)).astype(np.int64)
    position = np.arange(len(rows)) - np.repeat(first, lengths)
    piece = position * np.repeat(pieces, lengths) // np.repeat(lengths, lengths)
    chunk = np.repeat(np.cumsum(pieces) - pieces, lengths) + piece
    count = int(pieces.sum())
    size = np.bincount(chunk, minlength=count).astype(float)

    def mean(values: np.ndarray) -> np.ndarray:
        return np.stack([np.bincount(chunk, weights=column, minlength=count) for column in
                         np.atleast_2d(values.T)], axis=-1) / size[:, None]

    chunk_start = np.full(count, np.inf)
    chunk_end = np.full(count, -np.inf)
    np.minimum.at(chunk_start, chunk, start_ns * 1e-9)
    np.maximum.at(chunk_end, chunk, end_ns * 1e-9)
    duration = size * window_s
    chunk_residual, chunk_reference = mean(residual), mean(rows[:, 6:9])
    chunk_temperature = mean(temperature)[:, 0]
    offset_order, scale_order = _orders(calibration)
    offset_columns = temperature_columns(chunk_temperature, calibration.temp_code_ref, offset_order)
    scale_columns = temperature_columns(chunk_temperature, calibration.temp_code_ref, scale_order)
    design = np.hstack([offset_columns, *(chunk_reference[:, [b]] * scale_columns for b in range(3))])
    channels = [RestMeans(residual=chunk_residual[:, axis], start_s=chunk_start, end_s=chunk_end,
                          duration_s=duration, white=1.0 / duration, record=np.zeros(count, dtype=np.int64),
                          design=design, extra=np.zeros(count))
                for axis in range(3)]
    return rest_noise(short, channels)


def rests_noise(record, unit: UnitCalibration, *, gravity: float, latitude: float | None) -> dict[str, RestNoise]:
    """Each sensor's noise model from a hand-held record's or a pool's rests (``{}``: its sums were not gathered)."""
    from tak_thermo_ros.core.link.handheld_check import check_handheld
    from tak_thermo_ros.core.records.handheld import numbered_rests, rest_records
    intervals = record.intervals
    if intervals.short_allan is None or intervals.short_terms is None or not len(record.still):
        return {}
    check = check_handheld(record, unit, gravity=gravity, latitude=latitude)
    number, count, _, _ = numbered_rests(record)
    kept_intervals = np.unique(record.still_interval)
    kept = np.bincount(number, minlength=count).astype(float)
    temperature = np.bincount(number, weights=record.still.temp_code, minlength=count) / np.maximum(kept, 1.0)
    period_s = intervals.period_s
    start_s = intervals.start_ns[kept_intervals] * 1e-9
    end_s = intervals.end_ns[kept_intervals] * 1e-9
    duration = intervals.samples[kept_intervals] * period_s
    # The mean of every n-th sample sees the white noise of its kept samples.
    white = 1.0 / np.maximum(np.minimum(kept, intervals.samples[kept_intervals]) * period_s, 1e-12)
    records = rest_records(record)
    indicators = (records[:, None] == np.arange(records.max() + 1)[None, :]).astype(float)
    sums = intervals.short_allan[kept_intervals].sum(axis=0)
    terms = intervals.short_terms[kept_intervals].sum(axis=0)
    window_s = intervals.window_samples * period_s
    out = {}
    for sensor, columns in (('accel', slice(0, 3)), ('gyro', slice(3, 6))):
        calibration = unit.sensor(sensor)
        short = ShortSums(period_s=period_s, window_s=window_s, one=sums[0, columns], one_terms=int(terms[0]),
                          window=sums[1, columns], window_terms=int(terms[1]))
        offset_order, scale_order = _orders(calibration)
        powers = temperature_columns(temperature, calibration.temp_code_ref, offset_order)[:, 1:]
        if sensor == 'gyro':
            design = np.hstack([indicators, powers])
            extra = np.zeros((count, 3))
            if latitude is not None:  # the Earth rate's horizontal part, at each rest's unknown heading
                extra = (EARTH_RATE * math.cos(math.radians(latitude))) ** 2 * (1.0 - check.up ** 2) / 2.0
            channels = [RestMeans(residual=check.rate_error[:, axis], start_s=start_s, end_s=end_s, duration_s=duration,
                                  white=white, record=records, design=design, extra=extra[:, axis])
                        for axis in range(3)]
            found = rest_noise(short, channels, kind='rests')
        else:
            up = check.up
            scale_powers = temperature_columns(temperature, calibration.temp_code_ref, scale_order)
            design = np.hstack([*(indicators * up[:, [j]] for j in range(3)),
                                *(powers * up[:, [j]] for j in range(3)),
                                *(scale_powers * up[:, [j]] ** 2 for j in range(3))])
            means = RestMeans(residual=check.gravity_error, start_s=start_s, end_s=end_s, duration_s=duration,
                              white=white, record=records, design=design, extra=np.zeros(count))
            found = rest_noise(short, [means], up=up, kind='rests')
        if found is not None:
            out[sensor] = found
    return out
