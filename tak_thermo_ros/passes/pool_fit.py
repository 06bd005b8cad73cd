"""``tak_calib fit`` of a pool: the pool read once, fitted, and the fit as its file holds it.

The reading: :mod:`~tak_thermo_ros.passes.pool`. The fit itself: :func:`~tak_thermo_ros.core.fit.pool.fit_pool`
(or, with a fleet's prior, :func:`~tak_thermo_ros.core.fit.prior_fit.fit_with_prior`); the lines it prints:
:mod:`~tak_thermo_ros.passes.pool_lines`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from typing import Callable, Sequence

from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.records.provenance import RecordPrint
from tak_thermo_ros.core.values import SENSOR_NAMES
from tak_thermo_ros.passes.handheld import handheld_settings
from tak_thermo_ros.passes.pool import OpenedPool, open_pool
from tak_thermo_ros.passes.pool_lines import _reader, left_out_line
from tak_thermo_ros.passes.pool_records import PoolError
from tak_thermo_ros.passes.run import StreamOptions
from tak_thermo_ros.units import numbers


@dataclass(frozen=True)
class FittedPool:
    """``tak_calib fit`` of a pool: the records as read, the fit, and what goes into the file's ``source``."""

    opened: OpenedPool
    fit: object
    source: dict[str, str | int | float]
    lines: tuple[str, ...] = ()
    """With a prior: the unit's group, the turn-on repeatability taken, what came from the records and the prior."""
    fitted_from: tuple[RecordPrint, ...] = ()
    """The prints of the records fitted (the pooled ones the fit did not leave out): the file's ``fitted_from``."""


def fit_records(paths: Sequence[str | os.PathLike[str]], settings, options: StreamOptions, prior=None, *,
                say: Callable[[str], None] | None = None) -> FittedPool:
    """Read a pool once and fit it (:func:`~tak_thermo_ros.core.fit.pool.fit_pool`).

    :param settings: ``tak_calib fit``'s :class:`~tak_thermo_ros.passes.run.FitSettings`.
    :param prior: a fleet's prior (:func:`~tak_thermo_ros.core.fit.prior_fit.fit_with_prior`), a
        :class:`~tak_thermo_ros.core.fit.prior.CurvePrior` that only fixes the orders (a fleet's first pass), or
        ``None``.
    :param say: each line of reading the pool as soon as it is known (:func:`open_pool`).
    :raises PoolError: as :func:`open_pool`; ``FitError`` as the fit.
    """
    from tak_thermo_ros.core.fit.pool import TwoUnits, fit_pool
    from tak_thermo_ros.core.fit.prior import CurvePrior
    opened = open_pool(paths, options, say=say)
    assert opened.record is not None
    lines: tuple[str, ...] = ()
    try:
        if prior is None:
            fitted = fit_pool(opened.record, handheld_settings(settings))
        elif isinstance(prior, CurvePrior):  # the orders only (a fleet's first pass)
            fitted = fit_pool(opened.record, replace(handheld_settings(settings), prior=prior))
        else:
            from tak_thermo_ros.core.fit.prior_fit import fit_with_prior
            from tak_thermo_ros.passes.prior_lines import with_source_notes
            fitted, lines = with_source_notes(fit_with_prior(opened.record, handheld_settings(settings), prior))
    except TwoUnits as err:
        small, factor = _reader(err.sensor)
        sides = [f'{numbers(centre * factor, 3)} {small} ({", ".join(group)})'
                 for centre, group in zip(err.centres, err.groups)]
        msg = (f'the pool looks like two units: {SENSOR_NAMES[err.sensor]} {"xyz"[err.axis]} turn-on offsets near '
               f'{sides[0]} and near {sides[1]}, {err.spreads:.0f} spreads apart: give the records of one unit')
        raise PoolError(msg) from None
    used = [opened.entries[i] for i in opened.used]
    source: dict[str, str | int | float] = {
        'format': 'pool', 'temperature_rate_max': round(max(e.temperature_rate_max for e in used), 9),
        'rate_max': round(max(e.rate_max for e in used), 9)}
    devices = {(e.source or {}).get('accel_device_id'): e for e in used}
    if len(devices) == 1 and all(e.source is not None for e in used):
        for key in ('accel_device_id', 'gyro_device_id'):
            source[key] = int(used[0].source.get(key, 0))  # type: ignore[union-attr]
    left = {left.name for left in fitted.left_out}
    prints = tuple(e.record_print for e in used if e.name not in left and e.record_print is not None)
    return FittedPool(opened, fitted, source, lines, prints)


def pool_unit(fitted: FittedPool) -> UnitCalibration:
    """A pool's fit as the calibration file holds it: both sensors, the pool's source, what was pooled in its notes."""
    from tak_thermo_ros.core.fit.pool import order_line
    pool = fitted.fit
    results = pool.fit.results  # type: ignore[attr-defined]
    names = ', '.join(pool.record.record_names)  # type: ignore[attr-defined]
    notes = [f'pooled from {pool.record.records} records: {names}',  # type: ignore[attr-defined]
             *(order_line(sensor, choice) for sensor, choice in pool.orders.items()),  # type: ignore[attr-defined]
             *(left_out_line(left) for left in pool.left_out)]  # type: ignore[attr-defined]
    accel, gyro = (replace(results[sensor].calibration, notes=(*results[sensor].calibration.notes, *notes))
                   for sensor in ('accel', 'gyro'))
    return UnitCalibration(InputKind.IMU, accel=accel, gyro=gyro, source=fitted.source,
                           fitted_from=fitted.fitted_from)
