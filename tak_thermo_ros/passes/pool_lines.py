"""The lines a person reads of a pool: what it covers, its file's header, the turn-on repeatability, a record left out.

What each record's reading says (:func:`~tak_thermo_ros.passes.pool.entry_line`) stays with the
reading, :mod:`~tak_thermo_ros.passes.pool`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.values import SENSOR_NAMES
from tak_thermo_ros.passes.pool import OpenedPool
from tak_thermo_ros.units import numbers, reader_unit

TREND_C_PER_MIN = 0.05
"""A rest warming (cooling) faster than this is heating (cooling); slower, steady."""
BIN_C = 1.0
"""The pool's temperature coverage is counted in bins this wide."""


def coverage_lines(opened: OpenedPool, left_out: Sequence[str] = ()) -> list[str]:
    """What the pool covers: records, rests, the temperature span and its bins, heating and cooling.

    :param left_out: the names of records the fit left out after reading (counted as not pooled).
    """
    used = [opened.entries[i] for i in opened.used if opened.entries[i].name not in left_out]
    temperatures = np.concatenate([e.rest_temperatures for e in used])
    trends = np.concatenate([e.rest_trends for e in used])
    rests = len(temperatures)
    hours = sum(e.rest_s for e in used) / 3600.0
    low, high = float(temperatures.min()), float(temperatures.max())
    bins = np.floor(temperatures / BIN_C)
    span_bins = int(np.floor(high / BIN_C) - np.floor(low / BIN_C)) + 1
    lines = [f'pool: {len(used)} of {len(opened.entries)} records, {rests} rests, {hours:.2f} h at rest, '
             f'{low:.1f}..{high:.1f} C ({len(np.unique(bins))} of {span_bins} {BIN_C:g}-C bins hold a rest)']
    parts = []
    for word, mask in (('heating', trends > TREND_C_PER_MIN), ('cooling', trends < -TREND_C_PER_MIN)):
        if mask.any():
            parts.append(f'{word} at {int(mask.sum())} rests ({temperatures[mask].min():.1f}..'
                         f'{temperatures[mask].max():.1f} C)')
        else:
            parts.append(f'{word} at no rest')
    steady = int(np.sum(np.abs(trends) <= TREND_C_PER_MIN))
    both = _both_ways(temperatures, trends)
    lines.append(f'pool: {", ".join(parts)}, steady at {steady}; both ways within {both}')
    return lines


def _both_ways(temperatures: np.ndarray, trends: np.ndarray) -> str:
    """The temperature span where rests were seen both heating and cooling (what tells hysteresis and lag)."""
    heating, cooling = temperatures[trends > TREND_C_PER_MIN], temperatures[trends < -TREND_C_PER_MIN]
    if not len(heating) or not len(cooling):
        return 'no span'
    low, high = max(heating.min(), cooling.min()), min(heating.max(), cooling.max())
    return f'{low:.1f}..{high:.1f} C' if high > low else 'no span'


def pool_header(records: int, output: str, prior: str = '') -> str:
    """The header of a pool's calibration file (``prior``: its label, when fitted with one)."""
    return (f'tak_thermo_ros calibration fitted from a pool of {records} records (everyday records of one unit)\n'
            f'3 axes per sensor, a turn-on offset per record' + (f'\nwith the prior {prior}' if prior else '')
            + f'\nload with: ros2 run tak_thermo_ros compensator --ros-args --params-file {Path(output).name}')


def _reader(sensor: str) -> tuple[str, float]:
    """The unit a person reads a sensor's small values in (mg, deg/h) and its factor."""
    return reader_unit({'accel': 'm/s^2', 'gyro': 'rad/s'}[sensor])  # type: ignore[return-value]


def turn_on_line(sensor: str, fitted, records: int) -> str:
    """One statement: a sensor's turn-on repeatability per axis with its error (or which axes the records miss).

    From fewer records than :data:`~tak_thermo_ros.core.link.model.MIN_TURN_ON_RECORDS`: not determined, and why.
    """
    from tak_thermo_ros.core.link.model import MIN_TURN_ON_RECORDS, TurnOn
    variances = fitted.variances
    held = [name for name, ok in zip('xyz', variances.determined) if not ok]
    if records < MIN_TURN_ON_RECORDS:
        written = f'not written ({" ".join(held)}: not determined by these records)' if held else 'written so'
        return f'{SENSOR_NAMES[sensor]}: turn-on repeatability {TurnOn(None, None, records).why_not()}; {written}'
    small, factor = _reader(sensor)
    values = ' '.join('-' if not ok else numbers(v * factor, 3) + (f'+-{numbers(e * factor, 2)}' if np.isfinite(e)
                                                                   else '')
                      for v, e, ok in zip(variances.turn_on, variances.turn_on_error, variances.determined))
    tail = f' ({" ".join(held)}: not determined by these records)' if held else ''
    return f'{SENSOR_NAMES[sensor]}: turn-on repeatability x y z {values} {small}{tail}'


def left_out_line(left) -> str:
    """One statement: a record left out of the pool, and why."""
    small, factor = _reader(left.sensor)
    return (f'{left.name}: left out: another unit? its {SENSOR_NAMES[left.sensor]} {"xyz"[left.axis]} turn-on offset '
            f'{numbers(left.offset * factor, 3)} {small} lies {left.sigmas:.0f} times the other records\' spread '
            f'from their mean')
