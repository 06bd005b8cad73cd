"""What a person reads of a fleet's prior: the prior's table, the units far out, each axis's source, validate's band.

The lines of ``fit-fleet --everyday`` (:mod:`~tak_thermo_ros.passes.fleet_prior`), of ``fit --prior`` (each
axis's +- where the records saw the unit and where the prior told its curve) and of ``validate`` of a pool
against a calibration with its uncertainty; one statement per line, each sensor in its own units.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from tak_thermo_ros.core.link.model import AXES
from tak_thermo_ros.core.values import SENSOR_NAMES
from tak_thermo_ros.units import reader_unit, significant

SENSOR_UNITS = {'accel': 'm/s^2', 'gyro': 'rad/s'}
TABLE_TEMPERATURES = 5
"""The prior's table shows its curves at this many temperatures over the fleet's span."""
POWER_NAMES = ('offset', 'slope', 'curvature', 'cubic', 'T^4', 'T^5', 'T^6', 'T^7', 'T^8')
"""The raw coefficients of an offset curve, by power of ``T - T_ref``."""


def _reader(sensor: str) -> tuple[str, float]:
    return reader_unit(SENSOR_UNITS[sensor])  # type: ignore[return-value]


def _with_prior(uncertainty) -> bool:
    """Whether a calibration's uncertainty came with a prior (it then says which temperatures its records saw)."""
    return uncertainty is not None and uncertainty.records_min is not None and bool(uncertainty.prior)


def source_lines(sensor: str, calibration) -> list[str]:
    """What came from the records and what from the prior: each axis's +- within the records' span, and beyond it.

    Within: the largest +- over the records' temperatures; beyond: at each end of the calibrated range
    the records did not reach (half a degree or more).
    """
    uncertainty = calibration.uncertainty
    if not _with_prior(uncertainty):
        return []
    small, factor = _reader(sensor)
    low, high = uncertainty.records_min, uncertainty.records_max
    axes = [i for i in range(3) if uncertainty.offset_variance(i, 0.0) > 0.0]

    def sd(index: int, temperatures: np.ndarray) -> float:
        n = np.asarray(temperatures, dtype=float) - calibration.temp_code_ref
        return math.sqrt(max(float(np.max(uncertainty.offset_variance(index, n))), 0.0)) * factor

    name = SENSOR_NAMES[sensor]
    within = ', '.join(f'{AXES[i]} {significant(sd(i, np.linspace(low, high, 9)), 3)}' for i in axes)
    lines = [f'{name}: curve +- ({small}) from the records, within {low:.1f}..{high:.1f} C: {within}']
    for edge in (calibration.temp_code_min, calibration.temp_code_max):
        if low - 0.5 <= edge <= high + 0.5:
            continue
        beyond = ', '.join(f'{AXES[i]} {significant(sd(i, np.array([edge])), 3)}' for i in axes)
        lines.append(f'{name}: curve +- ({small}) from the prior, at {edge:.1f} C: {beyond}')
    return lines


def prior_table(prior) -> list[str]:
    """The prior as a person reads it: per sensor the mean curve +- the units' spread, each term's spread.

    The curve at :data:`TABLE_TEMPERATURES` temperatures over the fleet's span (each group's when
    the units fall in groups); per axis the units' spread of each raw coefficient (offset, per C,
    per C^2, ...): what they disagree on.
    """
    from tak_thermo_ros.core.fit.fleet_prior import offset_band
    lines = []
    for sensor, fleet in prior.sensors.items():
        small, factor = _reader(sensor)
        temperatures = np.linspace(fleet.low, fleet.high, TABLE_TEMPERATURES)
        groups = len(fleet.groups)
        lines.append(f'{SENSOR_NAMES[sensor]} prior, {small}: mean curve +- the units\' spread, '
                     f'{len(fleet.units)} units' + (f', {groups} groups' if groups > 1 else ''))
        lines.append('  ' + ' ' * 9 + ''.join(f'{f"{t:.1f} C":>14}' for t in temperatures))
        for axis in AXES:
            if not any(name.startswith(f'{axis}.offset') for name in fleet.names):
                continue
            for k in range(groups):
                weights = np.eye(groups)[k] if groups > 1 else None
                band = offset_band(fleet, axis, temperatures, weights)
                label = f'{axis}' + (f' group {k + 1}' if groups > 1 else '')
                cells = ''.join(f'{significant(m * factor, 3, sign=True) + "+-" + significant(s * factor, 2):>14}'
                                for m, s in zip(band.mean, band.sd))
                lines.append(f'  {label:<9}{cells}')
        for axis in AXES:
            index = [i for i, name in enumerate(fleet.names) if name.startswith(f'{axis}.offset')]
            if not index:
                continue
            raw = [fleet.spread[i] * factor / fleet.basis.n_scale ** power for power, i in enumerate(index)]
            terms = ', '.join(f'{POWER_NAMES[power]} {significant(value, 2)}' for power, value in enumerate(raw))
            lines.append(f'  {axis} spread ({small}, per C^k): {terms}')
    return lines


def band_lines(check, calibration) -> tuple[list[str], dict[str, Any]]:
    """``validate`` of a pool against a calibration fitted with a prior: whether the rests' shapes lie within its +-.

    Per group of rests (within the records' span, beyond it: where the prior told the curve) the
    gyroscope's bias shape (each record's own offset off), beside what the file's +- and the white noise
    give for it: the curve's error at each rest less its record's mean (``phi_r' C phi_r - 2 phi_r' C
    phi_bar + phi_bar' C phi_bar``) and the white noise of the rest's mean less its record's. A shape well
    beyond it: the +- is too small there (or the unit has changed).

    :returns: the lines, and the same for the JSON document.
    """
    uncertainty = calibration.uncertainty
    if not _with_prior(uncertainty) or not len(check.temperature):
        return [], {}
    small, factor = _reader('gyro')
    low, high = uncertainty.records_min, uncertainty.records_max
    n = check.temperature - calibration.temp_code_ref
    samples = np.maximum(1.0 / np.maximum(check.white[:, 0], 1e-300), 1.0)  # weights: the rests' lengths
    curve = np.zeros((len(n), 3))
    for record in np.unique(check.record):
        rows = np.flatnonzero(check.record == record)
        weights = samples[rows] / samples[rows].sum()
        for axis in range(3):
            # the curve's error at a rest less its record's weighted mean: C_rr - 2 (C w)_r + w' C w
            between = uncertainty.offset_covariance_between(axis, n[rows][:, None], n[rows][None, :])
            carried = between @ weights
            curve[rows, axis] = np.diag(between) - 2.0 * carried + weights @ carried
    beyond = (check.temperature < low - 0.5) | (check.temperature > high + 0.5)
    lines, document = [], {}
    for label, rests in (('within', ~beyond), ('beyond', beyond)):
        if not rests.any():
            continue
        shape = np.sqrt(np.mean(check.shape[rests] ** 2, axis=0))
        expected = np.sqrt(np.mean(curve[rests] + check.white[rests], axis=0))
        lines.append(f'gyroscope: {int(rests.sum())} rests {label} the records\' {low:.1f}..{high:.1f} C: shape RMS '
                     f'{numbers_of(shape * factor)} {small} x y z')
        lines.append(f'gyroscope:   the file\'s +- and the white noise give {numbers_of(expected * factor)} '
                     f'(the +- alone {numbers_of(np.sqrt(np.mean(curve[rests], axis=0)) * factor)})')
        document[label] = {'rests': int(rests.sum()), 'shape_rms': shape.tolist(), 'expected_rms': expected.tolist(),
                           'curve_rms': np.sqrt(np.mean(curve[rests], axis=0)).tolist()}
    return lines, document


def numbers_of(values) -> str:
    """Three significant figures each, space-separated."""
    return ' '.join(significant(float(v), 3) for v in values)


def far_lines(prior) -> list[str]:
    """One statement per unit left out of a sensor's prior."""
    return [f'{far.name}: far outside the fleet ({far.term} {far.sigmas:+.1f} sigmas): not in its '
            f'{SENSOR_NAMES[far.sensor]} prior' for fleet in prior.sensors.values() for far in fleet.left_out]


def with_source_notes(fitted) -> tuple[Any, tuple[str, ...]]:
    """A :class:`~tak_thermo_ros.core.fit.prior_fit.PriorFit`'s pool with each sensor's source lines in its notes.

    :returns: the pool's fit, and what a person reads: the unit's group, the turn-on taken, each axis's source.
    """
    results = {}
    sources: list[str] = []
    for sensor, result in fitted.pool.fit.results.items():
        calibration = result.calibration
        lines = source_lines(sensor, calibration)
        sources += lines
        results[sensor] = replace(result, calibration=replace(calibration, notes=(*calibration.notes, *lines)))
    return replace(fitted.pool, fit=replace(fitted.pool.fit, results=results)), (*fitted.lines, *sources)


def unit_line(unit: str, path: str, records: int | None) -> str:
    """One statement per unit fitted: its records and their span, each sensor's worst +- over the range, its file."""
    from pathlib import Path
    from tak_thermo_ros.formats.calibration_file import load_unit
    calibration = load_unit(path)
    parts = []
    for sensor in ('gyro', 'accel'):
        link = calibration.sensor(sensor)
        uncertainty = link.uncertainty
        if not _with_prior(uncertainty):
            continue
        small, factor = _reader(sensor)
        grid = np.linspace(link.temp_code_min, link.temp_code_max, 9) - link.temp_code_ref
        worst = max(math.sqrt(max(float(np.max(uncertainty.offset_variance(i, grid))), 0.0)) * factor
                    for i in range(3) if uncertainty.offset_variance(i, 0.0) > 0.0)
        parts.append(f'{sensor} {significant(worst, 3)} {small}')
    told = f'{records} records' if records is not None else 'its records'
    shown = Path(path).name  # in OUT_DIR, named once at the end
    if not parts:
        return f'{unit}: {told}, far from the fleet: fitted from its own records alone -> {shown}'
    uncertainty = calibration.accel.uncertainty or calibration.gyro.uncertainty  # type: ignore[union-attr]
    return (f'{unit}: {told} {uncertainty.records_min:.1f}..{uncertainty.records_max:.1f} C, worst +- '
            f'{", ".join(parts)} -> {shown}')
