"""What every reader checks of a record before the passes: stamps a bag can hold, no clock step, degrees Celsius.

One rule for every kind of record file (a CSV log at import, a PX4 ULog, an ArduPilot
DataFlash log, a driver bag), each refusing in its own words, naming the file:

- **Stamps a bag can hold**: :func:`stamp_ns_from_micros` turns a flight log's microseconds
  into nanoseconds without overflow; a stamp beyond what a bag holds (2038-01-19, or a
  corrupt ``TimeUS`` with a high bit set) becomes :data:`MAX_STAMP_NS`, far ahead of the
  run, which the stamp rule (:func:`~tak_thermo_ros.core.records.stamps.stamp_kept`) drops
  and counts as a ``stamp_jump``, as it does any message stamped far in the future.
- **No clock step** (:func:`clock_step`): among the stamps the stamp rule keeps, a step of
  :data:`CLOCK_STEP_S` (a year) or more, either way, is no pause but two clocks (a driver
  stamping from boot, then from the epoch after a time sync: some 54 years), or a corrupt
  first stamp; the record is refused, naming where the step is (:func:`refuse_clock_step`). (What a record spans never
  sets the memory a pass takes: :mod:`~tak_thermo_ros.core.records.extremes` holds its grid to
  the samples.)
- **Degrees Celsius** (:func:`temperature_unit_problem`): a driver's temperature (not a
  code) whose finite values are mostly implausible (outside
  :data:`~tak_thermo_ros.core.records.drops.TEMPERATURE_RANGE`: centi-degrees, a raw code), or
  mostly within :data:`KELVIN_BAND` (an IMU's working range, -50..150 C, read in kelvin), is
  refused with a hint; a few implausible values among good ones are ignored and counted, as
  before.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from tak_thermo_ros.core.records.drops import TEMPERATURE_RANGE
from tak_thermo_ros.core.records.stamps import NANOSECONDS, stamp_problems

MAX_STAMP_NS = (2 ** 31 - 1) * NANOSECONDS + 999_999_999
"""Latest stamp a bag holds (``Time.sec`` is an int32: 2038-01-19); a sample stamped beyond it or before 0 gets it."""
CLOCK_STEP_S = 365.25 * 86400.0
"""A year: a step between kept stamps of a year or more (either way) is a clock step, not a pause."""
CLOCK_STEP_HINT = ('two clocks (stamped from boot, then from the epoch?) or a corrupt stamp: keep one side, or split '
                   'the record there')
"""What a user does about a :func:`clock_step`."""
KELVIN_BAND = (223.15, 423.15)
"""Temperatures read as degrees Celsius that are an IMU's working range (-50..150 C) in kelvin."""
MOSTLY = 0.5
"""A share of the finite temperatures above which the record's unit is taken as wrong."""


def stamp_ns_from_micros(micros: np.ndarray) -> np.ndarray:
    """Int64 nanoseconds of a flight log's microsecond stamps, those a bag cannot hold set to :data:`MAX_STAMP_NS`.

    Any integer type (``uint64`` included) without overflow.
    """
    micros = np.asarray(micros)
    limit = MAX_STAMP_NS // 1000
    if micros.dtype.kind == 'u':
        outside = micros > np.uint64(limit)
    else:
        outside = (micros > limit) | (micros < 0)
    safe = np.where(outside, 0, micros).astype(np.int64)
    return np.where(outside, MAX_STAMP_NS, safe * 1000)


def clock_step(stamp_ns: np.ndarray) -> tuple[int, int] | None:
    """The first step of :data:`CLOCK_STEP_S` or more between stamps the stamp rule keeps, or ``None``.

    :param stamp_ns: a stream's stamps in log order.
    :returns: ``(row, step_ns)``: the row (0-based, log order) after the step and the step.
    """
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    if len(stamp_ns) < 2:
        return None
    masks, _ = stamp_problems(stamp_ns)
    kept = np.flatnonzero(~np.logical_or.reduce(list(masks.values())))
    steps = np.diff(stamp_ns[kept])
    large = np.flatnonzero(np.abs(steps) >= int(CLOCK_STEP_S * NANOSECONDS))
    if not large.size:
        return None
    return int(kept[large[0] + 1]), int(steps[large[0]])


def clock_step_words(step_ns: int, where: str) -> str:
    """``'jumps ahead by 53.9 years WHERE: HINT'`` / ``'goes back by 20.1 years WHERE: HINT'`` (a :func:`clock_step`).

    :param where: where the step is (``'at sample 2 of 200'``); ``HINT`` is :data:`CLOCK_STEP_HINT`.
    """
    years = abs(step_ns) / NANOSECONDS / CLOCK_STEP_S
    return f'{"jumps ahead" if step_ns > 0 else "goes back"} by {years:.3g} years {where}: {CLOCK_STEP_HINT}'


def refuse_clock_step(stamp_ns: np.ndarray, error: type[Exception], message: Callable[[int, int], str]) -> None:
    """Refuse stamps with a :func:`clock_step`: ``error(message(row, step_ns))``, the reader's words.

    :param message: the one-line refusal naming the file and where the step is (its end:
        :func:`clock_step_words`), from the row after the step and the step.
    """
    step = clock_step(stamp_ns)
    if step is not None:
        raise error(message(*step))


def temperature_unit_problem(temperature: np.ndarray) -> str | None:
    """Why a driver's temperatures are not degrees Celsius, or ``None`` (see the module's description)."""
    return temperature_counts_problem(*temperature_counts(temperature))


def temperature_counts(temperature: np.ndarray) -> tuple[int, int, int, float, float]:
    """``(finite, implausible, kelvin_like, low, high)`` of temperatures (degrees C): what the rule reads.

    The counts add over a record read in blocks (``low``, ``high``: the least and most of the
    finite values, ``inf`` and ``-inf`` without any).
    """
    values = np.asarray(temperature, dtype=float)
    values = values[np.isfinite(values)]
    low, high = TEMPERATURE_RANGE['imu']
    implausible = int(np.count_nonzero(~((values > low) & (values < high))))
    kelvin = int(np.count_nonzero((values >= KELVIN_BAND[0]) & (values <= KELVIN_BAND[1])))
    return (len(values), implausible, kelvin, float(values.min()) if len(values) else np.inf,
            float(values.max()) if len(values) else -np.inf)


def temperature_counts_problem(finite: int, implausible: int, kelvin_like: int, low: float, high: float) -> str | None:
    """:func:`temperature_unit_problem` from the counts of :func:`temperature_counts`."""
    if not finite:
        return None
    range_low, range_high = TEMPERATURE_RANGE['imu']
    if implausible > MOSTLY * finite:
        return (f'{implausible} of {finite} temperatures lie outside {range_low:g}..{range_high:g} C '
                f'({low:.6g}..{high:.6g}): not degrees Celsius (centi-degrees, or a raw code?)')
    if kelvin_like > MOSTLY * finite:
        return (f'{kelvin_like} of {finite} temperatures lie within {KELVIN_BAND[0]:g}..{KELVIN_BAND[1]:g} '
                f'({low:.6g}..{high:.6g}), an IMU\'s working range in kelvin, not degrees Celsius: convert them '
                f'(C = K - 273.15)')
    return None
