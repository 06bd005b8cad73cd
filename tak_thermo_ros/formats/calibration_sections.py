"""The calibration file's optional sections of a sensor and of a unit: read and written.

A sensor's ``uncertainty`` (:class:`~tak_thermo_ros.core.link.uncertainty.LinkUncertainty`), ``turn_on``
(:class:`~tak_thermo_ros.core.link.model.TurnOn`) and ``noise``
(:class:`~tak_thermo_ros.core.noise.model.NoiseModel`); a unit's ``fitted_from`` (one
:class:`~tak_thermo_ros.core.records.provenance.RecordPrint` per record) and ``source``. The file's
layout: :mod:`~tak_thermo_ros.formats.calibration_file`.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

from tak_thermo_ros.core.link.model import NOT_DETERMINED, SENSORS, SOURCE_KEYS, TurnOn
from tak_thermo_ros.core.link.uncertainty import LinkUncertainty
from tak_thermo_ros.core.noise.model import NoiseModel, noise_model_from_mapping
from tak_thermo_ros.core.records.provenance import RecordPrint
from tak_thermo_ros.core.values import finite_number
from tak_thermo_ros.errors import CalibrationError, NoiseError
from tak_thermo_ros.formats.calibration_checks import _check_keys, _numbers, _strings


def _uncertainty_from_mapping(raw: Any, key: str) -> LinkUncertainty:
    """A sensor's ``uncertainty`` section (:meth:`LinkUncertainty.to_mapping`)."""
    if not isinstance(raw, Mapping):
        msg = f'{key}: expected a mapping'
        raise CalibrationError(msg)
    _check_keys(raw, key, ('terms', 'temperature_scale', 'covariance'),
                ('held', 'held_from', 'beyond', 'source', 'prior', 'records_share', 'records_min', 'records_max'))
    terms = _strings(raw['terms'], f'{key}.terms')
    count = len(terms)
    upper = _numbers(raw['covariance'], f'{key}.covariance', count * (count + 1) // 2)
    scale = finite_number(raw['temperature_scale'], f'{key}.temperature_scale')
    held = _strings(raw.get('held', []), f'{key}.held')
    held_from = _strings(raw.get('held_from', []), f'{key}.held_from')
    share = _numbers(raw['records_share'], f'{key}.records_share', count) if 'records_share' in raw else ()
    beyond = _numbers(raw['beyond'], f'{key}.beyond', 3) if 'beyond' in raw else ()
    source, prior = (str(raw.get(name, default)) for name, default in (('source', 'records'), ('prior', '')))
    seen = [finite_number(raw[name], f'{key}.{name}') if name in raw else None
            for name in ('records_min', 'records_max')]
    try:
        return LinkUncertainty(terms, upper, scale, held, held_from, beyond, source, prior, share, *seen)
    except CalibrationError as err:
        raise CalibrationError(f'{key}.{str(err).removeprefix("uncertainty.")}') from None


def _turn_on_from_mapping(raw: Any, key: str) -> TurnOn:
    """A sensor's ``turn_on`` section: ``repeatability`` and ``repeatability_error`` (x, y, z), ``records``.

    ``repeatability: not determined`` (and no error): fewer records than
    :data:`~tak_thermo_ros.core.link.model.MIN_TURN_ON_RECORDS` behind it.
    """
    if not isinstance(raw, Mapping):
        msg = f'{key}: expected a mapping'
        raise CalibrationError(msg)
    if raw.get('repeatability') == NOT_DETERMINED:
        _check_keys(raw, key, ('repeatability', 'records'))
        spread = error = None
    else:
        _check_keys(raw, key, ('repeatability', 'repeatability_error', 'records'))
        spread = _numbers(raw['repeatability'], f'{key}.repeatability', 3)
        error = _numbers(raw['repeatability_error'], f'{key}.repeatability_error', 3)
    records = raw['records']
    if isinstance(records, bool) or not isinstance(records, int):
        msg = f'{key}.records: expected a whole number, got {records!r}'
        raise CalibrationError(msg)
    try:
        return TurnOn(repeatability=spread, repeatability_error=error, records=records)  # type: ignore[arg-type]
    except CalibrationError as err:
        raise CalibrationError(f'{key}.{str(err).removeprefix("turn_on.")}') from None


def _noise_from_mapping(raw: Any, key: str) -> NoiseModel:
    """A sensor's ``noise`` section (:func:`noise_to_mapping`), its errors as calibration errors."""
    try:
        return noise_model_from_mapping(raw, key)
    except NoiseError as err:
        raise CalibrationError(str(err)) from None


def noise_to_mapping(noise: NoiseModel) -> dict[str, Any]:
    """A sensor's ``noise`` section.

    Three floats per term (x, y, z; SI units of the corrected output), ``update_rate`` (Hz) and
    ``source``. ``bias_instability_tau`` is left out when an axis's is infinite (a ROS 2
    parameter array of doubles cannot say it portably); loading then takes the floor of the
    other terms again.
    """
    mapping = noise.to_mapping()
    if not all(math.isfinite(v) for v in noise.bias_instability_tau):
        del mapping['bias_instability_tau']
    return mapping


FITTED_FROM = 'fitted_from'
FITTED_FROM_LISTS = {'record': str, 'first_stamp_ns': int, 'last_stamp_ns': int, 'digest': str, 'segment_ns': int,
                     'segment_first': int, 'segments': str}
"""The lists of ``fitted_from`` besides the samples per sensor (``accel_samples``, ``gyro_samples``)."""


def _fitted_from_mapping(raw: Any, key: str) -> tuple[RecordPrint, ...]:
    """The optional ``fitted_from`` section: one entry per record in each list (:class:`RecordPrint`)."""
    sample_keys = [f'{sensor}_samples' for sensor in SENSORS]
    if not isinstance(raw, Mapping):
        msg = f'{key}: expected a mapping of lists ({", ".join(FITTED_FROM_LISTS)}, accel_samples)'
        raise CalibrationError(msg)
    _check_keys(raw, key, (*FITTED_FROM_LISTS, 'accel_samples'), sample_keys)
    lists: dict[str, list] = {}
    for name in [*FITTED_FROM_LISTS, *sample_keys]:
        if name not in raw:
            continue
        values = raw[name]
        if not isinstance(values, (list, tuple)) or not values:
            msg = f'{key}.{name}: expected a list with one entry per record'
            raise CalibrationError(msg)
        kind = FITTED_FROM_LISTS.get(name, int)
        for i, value in enumerate(values):
            if kind is str and not isinstance(value, str) or kind is int and (
                    isinstance(value, bool) or not isinstance(value, int)):
                msg = f'{key}.{name}[{i}]: expected {"a string" if kind is str else "a whole number"}, got {value!r}'
                raise CalibrationError(msg)
        lists[name] = list(values)
    count = len(lists['record'])
    for name, values in lists.items():
        if len(values) != count:
            msg = f'{key}.{name}: {len(values)} entries, {count} records in {key}.record'
            raise CalibrationError(msg)
    prints = []
    for i in range(count):
        if lists['segment_ns'][i] <= 0 or lists['first_stamp_ns'][i] > lists['last_stamp_ns'][i]:
            msg = f'{key}: entry {i}: segment_ns must be > 0 and first_stamp_ns <= last_stamp_ns'
            raise CalibrationError(msg)
        samples = tuple((sensor, int(lists[f'{sensor}_samples'][i])) for sensor in SENSORS
                        if f'{sensor}_samples' in lists)
        prints.append(RecordPrint(name=lists['record'][i], first_stamp_ns=lists['first_stamp_ns'][i],
                                  last_stamp_ns=lists['last_stamp_ns'][i], samples=samples,
                                  digest=lists['digest'][i], segment_ns=lists['segment_ns'][i],
                                  segment_first=lists['segment_first'][i],
                                  segments=tuple(lists['segments'][i].split(','))))
    return tuple(prints)


def _fitted_from_to_mapping(prints: tuple[RecordPrint, ...]) -> dict[str, list]:
    """The ``fitted_from`` section: its lists, one entry per record."""
    mapping: dict[str, list] = {
        'record': [p.name for p in prints], 'first_stamp_ns': [int(p.first_stamp_ns) for p in prints],
        'last_stamp_ns': [int(p.last_stamp_ns) for p in prints]}
    for sensor in SENSORS:
        if all(sensor in dict(p.samples) for p in prints):
            mapping[f'{sensor}_samples'] = [int(dict(p.samples)[sensor]) for p in prints]
    mapping.update({'digest': [p.digest for p in prints], 'segment_ns': [int(p.segment_ns) for p in prints],
                    'segment_first': [int(p.segment_first) for p in prints],
                    'segments': [','.join(p.segments) for p in prints]})
    return mapping


def _source_from_mapping(raw: Any, key: str) -> dict[str, str | int | float]:
    """The optional ``source`` section (:data:`~tak_thermo_ros.core.link.model.SOURCE_KEYS`)."""
    if not isinstance(raw, Mapping):
        msg = f'{key}: expected a mapping of {", ".join(SOURCE_KEYS)}'
        raise CalibrationError(msg)
    source: dict[str, str | int | float] = {}
    for name, value in raw.items():
        kind = SOURCE_KEYS.get(str(name))
        if kind is None:
            msg = f'{key}.{name}: unknown key'
            raise CalibrationError(msg)
        if kind is str:
            if not isinstance(value, str):
                msg = f'{key}.{name}: expected a string, got {value!r}'
                raise CalibrationError(msg)
            source[str(name)] = value
        elif kind is int:
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 2 ** 32:
                msg = f'{key}.{name}: expected a whole number 0..2**32-1, got {value!r}'
                raise CalibrationError(msg)
            source[str(name)] = int(value)
        else:
            number = finite_number(value, f'{key}.{name}')
            if number < 0.0:
                msg = f'{key}.{name}: must be >= 0, got {number}'
                raise CalibrationError(msg)
            source[str(name)] = number
    return source
