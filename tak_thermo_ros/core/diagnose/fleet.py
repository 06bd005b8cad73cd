"""Statistics over a production batch of calibrated units: robust spread and flags.

A batch is a table ``unit -> metric -> value`` (the coefficients of each unit's calibration,
its residual RMS per axis, its validation error). For every metric the batch's robust spread
is its median and ``sigma = 1.4826 * MAD`` (median absolute deviation; 1.4826 makes it the
standard deviation for normally distributed values, and a few wild units cannot inflate it).
A unit is flagged for a metric when its value lies more than ``k`` robust sigmas from the
median. A unit is also flagged when its diagnosis verdict differs from the verdict that more
than half of the diagnosed units share.

Pure numbers: no Dask, no bags. ``tak_thermo_ros.passes.fleet`` runs the batch and reports.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from tak_thermo_ros.core.link.model import AXES

MAD_TO_SIGMA = 1.4826
"""``1 / Phi^-1(3/4)``: the MAD of normally distributed values times this is their standard deviation."""
DEFAULT_FLAG_SIGMA = 5.0
MIN_UNITS_FOR_SPREAD = 5
"""A metric needs values from at least this many units before any unit is flagged for it."""


@dataclass(frozen=True)
class Spread:
    """The robust spread of one metric over the batch.

    :param median: median over the units that have the metric.
    :param sigma: ``1.4826 * MAD``; 0 when more than half of the values are equal.
    :param units: how many units have a finite value of the metric.
    """

    median: float
    sigma: float
    units: int

    def sigmas(self, value: float) -> float:
        """How many robust sigmas ``value`` lies from the median (signed; +-inf when sigma is 0)."""
        deviation = value - self.median
        if self.sigma > 0.0:
            return deviation / self.sigma
        return 0.0 if deviation == 0.0 else math.copysign(math.inf, deviation)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {'median': self.median, 'robust_sigma': self.sigma, 'units': self.units}


@dataclass(frozen=True)
class Flag:
    """Why one unit stands out of the batch.

    :param metric: the metric's name (``x.offset``, ``verdict``, ...).
    :param reason: one line for people.
    :param value: the unit's value (a number, or the verdict).
    :param sigmas: signed robust sigmas from the median (``None`` for the verdict; +-inf when
        the batch has no spread in this metric).
    """

    metric: str
    reason: str
    value: float | str
    sigmas: float | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (an infinite ``sigmas`` becomes ``null``, the reason says why)."""
        sigmas = self.sigmas if self.sigmas is None or math.isfinite(self.sigmas) else None
        return {'metric': self.metric, 'value': self.value, 'robust_sigmas': sigmas, 'reason': self.reason}


def robust_spread(values: Sequence[float]) -> Spread:
    """Median and ``1.4826 * MAD`` of the finite values.

    :raises ValueError: when no value is finite.
    """
    finite = np.asarray([v for v in values if math.isfinite(v)], dtype=float)
    if finite.size == 0:
        msg = 'robust_spread: no finite value'
        raise ValueError(msg)
    median = float(np.median(finite))
    sigma = MAD_TO_SIGMA * float(np.median(np.abs(finite - median)))
    return Spread(median=median, sigma=sigma, units=int(finite.size))


def batch_spreads(table: Mapping[str, Mapping[str, float]]) -> dict[str, Spread]:
    """The robust spread of every metric that at least one unit has a finite value for.

    :param table: unit name -> metric name -> value.
    """
    columns: dict[str, list[float]] = {}
    for metrics in table.values():
        for metric, value in metrics.items():
            if value is not None and math.isfinite(value):
                columns.setdefault(metric, []).append(float(value))
    return {metric: robust_spread(values) for metric, values in sorted(columns.items())}


def majority_verdict(verdicts: Mapping[str, str | None]) -> str | None:
    """The verdict more than half of the diagnosed units share, or ``None`` when none does."""
    given = [v for v in verdicts.values() if v is not None]
    if not given:
        return None
    counts = Counter(given)
    verdict, count = max(counts.items(), key=lambda item: (item[1], item[0]))
    return verdict if 2 * count > len(given) else None


def flag_units(table: Mapping[str, Mapping[str, float]], verdicts: Mapping[str, str | None] | None = None, *,
               k: float = DEFAULT_FLAG_SIGMA) -> dict[str, list[Flag]]:
    """Flag every unit outside the batch's robust spread, and every unit whose verdict differs.

    A unit is flagged for a metric when ``|value - median| > k * sigma`` and the metric has
    values from at least :data:`MIN_UNITS_FOR_SPREAD` units; when sigma is 0 (more than half
    the units share one value) any other value is flagged. A unit is flagged for its verdict
    when more than half of the diagnosed units share another one. The result does not depend
    on the order of the units.

    :param table: unit name -> metric name -> value (non-finite values are ignored).
    :param verdicts: unit name -> diagnosis verdict (``None`` = not diagnosed).
    :param k: the flag threshold in robust sigmas, > 0.
    :returns: unit name -> its flags (metrics sorted by name, the verdict last), every unit of
        ``table`` and ``verdicts`` present.
    """
    if not k > 0.0:
        msg = f'flag threshold must be > 0 robust sigmas, got {k}'
        raise ValueError(msg)
    verdicts = verdicts or {}
    flags: dict[str, list[Flag]] = {unit: [] for unit in (*table, *verdicts)}
    for metric, spread in batch_spreads(table).items():
        if spread.units < MIN_UNITS_FOR_SPREAD:
            continue
        for unit, metrics in table.items():
            value = metrics.get(metric)
            if value is None or not math.isfinite(value):
                continue
            sigmas = spread.sigmas(float(value))
            if abs(sigmas) > k:
                if math.isfinite(sigmas):
                    reason = (f'{metric} = {value:.6g} is {sigmas:+.1f} robust sigmas from the batch median '
                              f'{spread.median:.6g} (sigma {spread.sigma:.3g}, limit {k:g})')
                else:
                    reason = (f'{metric} = {value:.6g} differs from the batch median {spread.median:.6g}, '
                              f'which more than half of the units share exactly (no spread)')
                flags[unit].append(Flag(metric=metric, reason=reason, value=float(value), sigmas=sigmas))
    majority = majority_verdict(verdicts)
    if majority is not None:
        for unit, verdict in verdicts.items():
            if verdict is not None and verdict != majority:
                flags[unit].append(Flag(metric='verdict', value=verdict,
                                        reason=f'verdict {verdict!r} differs from the batch majority {majority!r}'))
    return flags


def calibration_metrics(calibration: Mapping[str, Any]) -> dict[str, float]:
    """The flagged metrics of one unit from its ``calibration`` mapping (the parameters YAML).

    Per axis: ``scale``, ``offset``, ``offset_span``, ``residual_rms``, and every polynomial
    coefficient as ``offset_shape[i]`` / ``scale_shape[i]`` (``i`` = power of the code offset);
    per effect: ``effects.<name>.<parameter>``. A driver calibration (version 2) has them per
    sensor, prefixed ``accel.`` and ``gyro.``.
    """
    if 'accel' in calibration:
        return {f'{sensor}.{name}': value for sensor in ('accel', 'gyro')
                for name, value in _link_metrics(calibration.get(sensor) or {}).items()}
    return _link_metrics(calibration)


def _link_metrics(calibration: Mapping[str, Any]) -> dict[str, float]:
    metrics: dict[str, float] = {}
    for axis in AXES:
        entry = calibration.get(axis, {})
        for key in ('scale', 'offset', 'offset_span', 'residual_rms'):
            if key in entry:
                metrics[f'{axis}.{key}'] = float(entry[key])
        for key in ('offset_shape', 'scale_shape'):
            for power, value in enumerate(entry.get(key, ()), start=1):
                metrics[f'{axis}.{key}[{power}]'] = float(value)
    for name, parameters in (calibration.get('effects') or {}).items():
        for parameter, value in parameters.items():
            if parameter not in ('class', 'topic', 'field'):  # strings naming the class or signal
                metrics[f'effects.{name}.{parameter}'] = float(value)
    return metrics


def diagnosis_verdict(diagnosis: Mapping[str, Any] | None) -> str | None:
    """A unit's verdict from its ``diagnose --json``: per sensor for a driver bag (``accel none, gyro thermal_lag``)."""
    if not diagnosis:
        return None
    sensors = diagnosis.get('sensors')
    if isinstance(sensors, Mapping):
        return ', '.join(f'{name} {entry.get("verdict")}' for name, entry in sensors.items())
    return diagnosis.get('verdict')
