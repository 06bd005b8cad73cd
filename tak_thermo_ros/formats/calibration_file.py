"""The calibration file: a ROS 2 parameters YAML that the node loads unchanged.

Layout::

    /**/compensator:
      ros__parameters:
        calibration:
          version: 1
          temp_code_ref: 8200.0
          temp_code_min: 7600.0
          temp_code_max: 9300.0
          x: {scale: 255.1, offset: -12.3, offset_span: 41.0,
              offset_shape: [b1, b2, b3], scale_shape: [a1, a2], residual_rms: 1.9}
          y: {...}
          z: {...}

ROS 2 parameters cannot hold empty lists, so a polynomial without temperature dependence is
written ``[0.0]``. Optional keys: ``residual_rms`` (counts; feeds the Imu covariance),
``scale_observable`` (``false`` when the scale was held at nominal), ``notes`` (list of
strings). Later model terms go under ``calibration`` beside the axes.

A sensor may carry its noise model (``noise``: ``white_noise_density``, ``bias_instability``,
``bias_instability_tau``, ``random_walk``, ``quantization``, ``rate_ramp``, three floats each,
SI units of the corrected output; ``update_rate`` Hz; ``source``; when fitted, the driver's
filter ``filter_time_constant`` and ``filter_share``, the Gauss-Markov processes
``gauss_markov`` and ``gauss_markov_time`` as three floats per process,
``random_walk_bound`` and ``bias_instability_bound``, and a fit's standard errors
``*_error``; every ``tak_calib fit`` writes one); the Imu covariance then comes from it
(:func:`~tak_thermo_ros.core.link.correction.acceleration_variance`).

The node key is :data:`NODE_KEY` (``/**/compensator``): rcl gives the parameters to a node named
``compensator`` in any namespace (two IMUs, two compensators in ``/imu0`` and ``/imu1``). Files
written before with the root key ``compensator:`` load as before (:func:`calibration_section`
takes the section of any key that holds ``ros__parameters.calibration``).

Effects (``tak_thermo_ros.core.effects``) go under ``calibration.effects.<name>.<param>``, one
float per parameter (no lists, so that every value is one ROS 2 parameter); a user-defined
effect also stores where its class lives::

          effects:
            thermal_lag: {tau_s: 1790.0, slope_x: 0.0012, slope_y: -0.0004, slope_z: 0.031}
            my_effect: {class: 'mymodule:MyEffect', amplitude_x: 1.2, ...}

An effect fitted on some axes only (``thermal_lag[xz]``, :mod:`~tak_thermo_ros.core.effects.held`)
keeps its entry and adds the string ``axes``; its amplitudes on the other axes are 0::

            thermal_lag: {axes: xz, tau_s: 1790.0, slope_x: 0.0012, slope_y: 0.0, slope_z: 0.031}

A calibration without effects has no ``effects`` key.

What the link was fitted from (``fitted_from``, beside ``version``): one entry per record in
each list (ROS 2 parameters hold lists of numbers or strings, not lists of mappings)::

          fitted_from:
            record: [real_driver]                  # the file name, for messages
            first_stamp_ns: [1700000000000000000]  # the earliest and latest sample stamps
            last_stamp_ns: [1700004244900000000]
            accel_samples: [8400]                  # per sensor (gyro_samples: driver input)
            gyro_samples: [8400]
            digest: [3f1c...]                      # SHA-256 of every sample (stamps and values)
            segment_ns: [68719476736]              # equal time segments of the record ...
            segment_first: [24738]
            segments: ['9a0b1c2d,...']             # ... and each one's digest ('-': no sample)

``validate`` and ``diagnose`` of that record, or of a part of it, say in their first line that
it is in-sample (:mod:`~tak_thermo_ros.core.records.provenance`). A file without ``fitted_from``
(written before it existed, or by hand) makes no claim either way.

:func:`calibration_from_mapping` is the single validator: the command-line tools call it on
the YAML, the node on its ``calibration.*`` parameters.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from tak_thermo_ros.formats.files import write_text_atomic  # noqa: F401 (re-exported: one writer of text files)
from tak_thermo_ros.formats.files import check_finite, read_regular_bytes, unreadable
from tak_thermo_ros.core.link.model import (
    AXES,
    CALIBRATION_VERSION,
    SENSORS,
    UNIT_CALIBRATION_VERSION,
    AxisModel,
    Calibration,
    MAG_SENSOR,
    SOURCE_KEYS,
    THERMAL_FITTED,
    THERMAL_NONE,
    THERMAL_STATES,
    InputKind,
    MagnetometerCalibration,
    NOT_DETERMINED,
    TurnOn,
    UnitCalibration,
    check_plausible,
    check_scale_positive,
)
from tak_thermo_ros.core.link.uncertainty import LinkUncertainty
from tak_thermo_ros.core.records.provenance import RecordPrint
from tak_thermo_ros.core.noise.model import NoiseModel, noise_model_from_mapping
from tak_thermo_ros.core.values import finite_number
from tak_thermo_ros.errors import CalibrationError, FitError, NoiseError, TakError

NODE_NAME = 'compensator'
NODE_KEY = f'/**/{NODE_NAME}'
"""The node key the files are written with: the node ``compensator`` in any namespace.

Not ``/**`` (every node): a robot's parameters file often gathers many nodes, and ``/**`` would
hand ``calibration.*`` to each of them. A renamed node reads the file with
``-p calibration_file:=FILE`` (any key), or the key is edited to its name.
"""
AXIS_KEYS = ('scale', 'offset', 'offset_span', 'offset_shape', 'scale_shape')
OPTIONAL_AXIS_KEYS = ('residual_rms', 'scale_observable')
MAX_ORDER = 8


def _coefficients(value: Any, key: str) -> tuple[float, ...]:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (list, tuple)):
        msg = f'{key}: expected a list of numbers, got {type(value).__name__} {value!r}'
        raise CalibrationError(msg)
    if not 1 <= len(value) <= MAX_ORDER:
        msg = f'{key}: expected 1 to {MAX_ORDER} coefficients, got {len(value)}'
        raise CalibrationError(msg)
    return tuple(finite_number(item, f'{key}[{i}]') for i, item in enumerate(value))


def _check_keys(raw: Mapping, key: str, required: Sequence[str], optional: Sequence[str] = (), *,
                unknown_why: Mapping[str, str] | None = None) -> None:
    """Every ``required`` key in ``raw`` and no key beyond ``required`` and ``optional``.

    :param unknown_why: words after ``unknown key`` for some keys (why they do not belong here).
    :raises CalibrationError: ``KEY.NAME: missing`` (the first in ``required``'s order), else
        ``KEY.NAME: unknown key`` (the first by name).
    """
    for name in required:
        if name not in raw:
            msg = f'{key}.{name}: missing'
            raise CalibrationError(msg)
    unknown = sorted(str(name) for name in set(raw) - set(required) - set(optional))
    if unknown:
        msg = f'{key}.{unknown[0]}: unknown key{(unknown_why or {}).get(unknown[0], "")}'
        raise CalibrationError(msg)


def _axis_from_mapping(raw: Any, key: str) -> AxisModel:
    if not isinstance(raw, Mapping):
        msg = f'{key}: expected a mapping with keys {", ".join(AXIS_KEYS)}'
        raise CalibrationError(msg)
    _check_keys(raw, key, AXIS_KEYS, OPTIONAL_AXIS_KEYS)
    scale = finite_number(raw['scale'], f'{key}.scale')
    if scale <= 0.0:
        msg = f'{key}.scale: must be > 0, got {scale}'
        raise CalibrationError(msg)
    offset_span = finite_number(raw['offset_span'], f'{key}.offset_span')
    if offset_span < 0.0:
        msg = f'{key}.offset_span: must be >= 0 (the sign lives in offset_shape), got {offset_span}'
        raise CalibrationError(msg)
    residual_rms = None
    if 'residual_rms' in raw:
        residual_rms = finite_number(raw['residual_rms'], f'{key}.residual_rms')
        if residual_rms < 0.0:
            msg = f'{key}.residual_rms: must be >= 0, got {residual_rms}'
            raise CalibrationError(msg)
    scale_observable = raw.get('scale_observable', True)
    if not isinstance(scale_observable, bool):
        msg = f'{key}.scale_observable: expected true or false, got {scale_observable!r}'
        raise CalibrationError(msg)
    return AxisModel(
        scale=scale,
        offset=finite_number(raw['offset'], f'{key}.offset'),
        offset_span=offset_span,
        offset_shape=_coefficients(raw['offset_shape'], f'{key}.offset_shape'),
        scale_shape=_coefficients(raw['scale_shape'], f'{key}.scale_shape'),
        residual_rms=residual_rms,
        scale_observable=scale_observable,
    )


def effects_from_mapping(raw: Any, *, key: str = 'calibration.effects') -> tuple:
    """Validate the ``effects`` mapping and build the effects, in the mapping's order.

    :raises CalibrationError: naming the first wrong key (unknown effect, class that cannot be
        imported, missing, non-finite or out-of-bounds parameter).
    """
    from tak_thermo_ros.core.effects import aux_effect_class, held_form, resolve_effect
    from tak_thermo_ros.core.effects.aux_signal import signal_name
    from tak_thermo_ros.core.effects.held import parse_axes
    if not isinstance(raw, Mapping) or not raw:
        msg = f'{key}: expected a mapping of effect names to their parameters'
        raise CalibrationError(msg)
    effects = []
    for name, entry in raw.items():
        entry_key = f'{key}.{name}'
        if not isinstance(entry, Mapping):
            msg = f'{entry_key}: expected a mapping of parameter names to numbers'
            raise CalibrationError(msg)
        if 'topic' in entry:
            effects.append(_aux_effect_from_entry(entry, entry_key, aux_effect_class, signal_name))
            continue
        spec = entry.get('class', name)
        if not isinstance(spec, str):
            msg = f'{entry_key}.class: expected a string module:Class'
            raise CalibrationError(msg)
        try:
            cls = resolve_effect(spec)
        except FitError as err:
            where = f'{entry_key}.class' if 'class' in entry else entry_key
            msg = f'{where}: {err}'
            raise CalibrationError(msg) from None
        if cls.name != name:
            msg = f'{entry_key}.class: {spec} is the effect {cls.name!r}, not {name!r}'
            raise CalibrationError(msg)
        if 'axes' in entry:
            # Fitted on some axes only (core.effects.held): the others' amplitudes are 0.
            try:
                cls = held_form(cls, parse_axes(entry['axes'], f'{entry_key}.axes')
                                if isinstance(entry['axes'], str) else ())
            except FitError as err:
                msg = f'{err}' if isinstance(entry['axes'], str) else f'{entry_key}.axes: expected a string (e.g. xz)'
                raise CalibrationError(msg) from None
        values = {param: value for param, value in entry.items() if param not in ('class', 'axes')}
        effects.append(cls.from_values(values, key=entry_key, complete=True))
    return tuple(effects)


def _aux_effect_from_entry(entry: Mapping, entry_key: str, aux_effect_class, signal_name):
    """An auxiliary-signal effect from its entry: ``topic``, optional ``field``, then its numbers."""
    topic, field = entry['topic'], entry.get('field', '')
    for label, text in (('topic', topic), ('field', field)):
        if not isinstance(text, str):
            msg = f'{entry_key}.{label}: expected a string'
            raise CalibrationError(msg)
    try:
        cls = aux_effect_class(signal_name(topic, field))
    except FitError as err:
        msg = f'{entry_key}.topic: {err}'
        raise CalibrationError(msg) from None
    values = {param: value for param, value in entry.items() if param not in ('topic', 'field')}
    return cls.from_values(values, key=entry_key, complete=True)


def effects_to_mapping(effects: Any) -> dict[str, Any]:
    """The ``effects`` mapping of fitted effects (plain floats; ``class`` for user-defined ones).

    An auxiliary-signal effect (name ``aux:TOPIC[:FIELD]``, which a ROS 2 parameter name cannot
    hold) is stored as ``aux_1``, ``aux_2``, ... with the strings ``topic`` (and ``field``).
    """
    from tak_thermo_ros.core.effects import effect_spec, held_of, is_aux_effect
    from tak_thermo_ros.core.effects.aux_signal import split_signal_name
    from tak_thermo_ros.core.effects.held import axes_text
    mapping: dict[str, Any] = {}
    aux_count = 0
    for effect in effects:
        entry: dict[str, Any] = {}
        if is_aux_effect(effect):
            aux_count += 1
            topic, field = split_signal_name(effect.name)
            entry['topic'] = topic
            if field:
                entry['field'] = field
            entry.update({name: float(value) for name, value in effect.values.items()})
            mapping[f'aux_{aux_count}'] = entry
            continue
        spec = effect_spec(type(effect))
        key = held_of(type(effect)).name
        if spec != key:
            entry['class'] = spec
        if effect.fitted_axes != (0, 1, 2):
            entry['axes'] = axes_text(effect.fitted_axes)
        entry.update({name: float(value) for name, value in effect.values.items()})
        mapping[key] = entry
    return mapping


@dataclass(frozen=True)
class Limits:
    """What a calibration of one input kind may hold: bounds that follow from the physics.

    :param value: largest ``|offset|``, ``offset_span`` and ``residual_rms``, output units
        (counts: the 16-bit code range; imu: m/s^2 or rad/s far beyond any MEMS full scale).
    :param scale: open interval of ``K0`` (counts: counts per m/s^2; imu: a driver's factory
        scale is off by percent, not by a factor of two).
    :param temperature: interval of the temperature input (counts: codes; imu: degrees C,
        from absolute zero to a soldering iron).
    :param temperature_name: the keys' stem in the file (``temp_code`` or ``temperature``).
    """

    value: float
    scale: tuple[float, float]
    temperature: tuple[float, float]
    temperature_name: str


LIMITS = {
    InputKind.COUNTS: Limits(value=65536.0, scale=(0.0, 1.0e6), temperature=(-1.0e7, 1.0e7),
                             temperature_name='temp_code'),
    InputKind.IMU: Limits(value=1.0e4, scale=(0.5, 2.0), temperature=(-273.15, 1000.0),
                          temperature_name='temperature'),
}


def _check_limits(calibration: Calibration, limits: Limits, key: str) -> None:
    """Everything later computed from the calibration is finite, and the values are physical."""
    for end, value in (('ref', calibration.temp_code_ref), ('min', calibration.temp_code_min),
                       ('max', calibration.temp_code_max)):
        if not limits.temperature[0] <= value <= limits.temperature[1]:
            msg = (f'{key}.{limits.temperature_name}_{end}: {value:g} is outside '
                   f'{limits.temperature[0]:g}..{limits.temperature[1]:g}')
            raise CalibrationError(msg)
    n_low, n_high = calibration.code_offset_range()
    grid = np.linspace(n_low, n_high, 1001)
    for name, axis in zip(AXES, calibration.axes):
        low, high = limits.scale
        if not low < axis.scale < high:
            msg = f'{key}.{name}.scale: {axis.scale:g} is outside {low:g}..{high:g} (exclusive)'
            raise CalibrationError(msg)
        for field_name in ('offset', 'offset_span', 'residual_rms'):
            value = getattr(axis, field_name)
            if value is not None and abs(value) > limits.value:
                msg = f'{key}.{name}.{field_name}: |{value:g}| is beyond {limits.value:g}'
                raise CalibrationError(msg)
        with np.errstate(all='ignore'):
            drift = axis.offset_drift(grid)
            gain = axis.scale * axis.scale_factor(grid)
        if not (np.all(np.isfinite(drift)) and np.all(np.abs(drift) <= 2.0 * limits.value)):
            msg = f'{key}.{name}.offset_shape: the offset drift leaves +-{2.0 * limits.value:g} in the calibrated range'
            raise CalibrationError(msg)
        if not np.all(np.isfinite(gain)):
            msg = f'{key}.{name}.scale_shape: the scale is not finite in the calibrated range'
            raise CalibrationError(msg)


def _link_from_mapping(raw: Any, key: str, input_kind: InputKind, *, extra_keys: tuple[str, ...],
                       sensor: str) -> Calibration:
    """One sensor's :class:`Calibration` from its mapping (temperature range, axes, effects).

    :param sensor: ``counts``, ``accel``, ``gyro`` or ``mag`` (the plausible range of its correction).
    """
    limits = LIMITS[input_kind]
    stem = limits.temperature_name
    range_keys = (f'{stem}_ref', f'{stem}_min', f'{stem}_max')
    if not isinstance(raw, Mapping):
        msg = f'{key}: expected a mapping'
        raise CalibrationError(msg)
    thermal = raw.get('thermal', THERMAL_FITTED)
    if thermal not in THERMAL_STATES:
        msg = f'{key}.thermal: expected one of {", ".join(THERMAL_STATES)}, got {thermal!r}'
        raise CalibrationError(msg)
    # A link without any temperature (thermal: none) has no temperatures to state.
    needed = AXES if thermal == THERMAL_NONE else (*range_keys, *AXES)
    _check_keys(raw, key, needed, ('thermal', 'notes', 'effects', 'noise', 'turn_on', 'uncertainty', *extra_keys),
                unknown_why=dict.fromkeys(range_keys, ' (thermal: none holds no temperatures)'))
    ref, low, high = ((finite_number(raw[name], f'{key}.{name}') for name in range_keys)
                      if thermal != THERMAL_NONE else (0.0, 0.0, 0.0))
    if low >= high and thermal == THERMAL_FITTED or low > high:
        msg = f'{key}.{range_keys[1]}: must be below {range_keys[2]}, got {low} >= {high}'
        raise CalibrationError(msg)
    notes = raw.get('notes', [])
    if isinstance(notes, str) or not isinstance(notes, (list, tuple)) or not all(
            isinstance(note, str) for note in notes):
        msg = f'{key}.notes: expected a list of strings'
        raise CalibrationError(msg)
    axes = tuple(_axis_from_mapping(raw[name], f'{key}.{name}') for name in AXES)
    effects = effects_from_mapping(raw['effects'], key=f'{key}.effects') if 'effects' in raw else ()
    noise = _noise_from_mapping(raw['noise'], f'{key}.noise') if 'noise' in raw else None
    turn_on = _turn_on_from_mapping(raw['turn_on'], f'{key}.turn_on') if 'turn_on' in raw else None
    uncertainty = _uncertainty_from_mapping(raw['uncertainty'], f'{key}.uncertainty') if 'uncertainty' in raw else None
    try:
        calibration = Calibration(temp_code_ref=ref, temp_code_min=low, temp_code_max=high,
                                  axes=axes, version=CALIBRATION_VERSION,  # type: ignore[arg-type]
                                  notes=tuple(notes), effects=effects, noise=noise, thermal=thermal,
                                  turn_on=turn_on, uncertainty=uncertainty)
    except CalibrationError as err:
        raise CalibrationError(f'{key}.{str(err).removeprefix("calibration.")}') from None
    _check_limits(calibration, limits, key)
    check_scale_positive(calibration, key=key)
    check_plausible(calibration, sensor, key=key)
    return calibration


def _link_to_mapping(calibration: Calibration, input_kind: InputKind) -> dict[str, Any]:
    stem = LIMITS[input_kind].temperature_name
    mapping: dict[str, Any] = {}
    if calibration.thermal != THERMAL_FITTED:
        mapping['thermal'] = calibration.thermal
    if calibration.thermal != THERMAL_NONE:
        mapping.update({f'{stem}_ref': float(calibration.temp_code_ref),
                        f'{stem}_min': float(calibration.temp_code_min),
                        f'{stem}_max': float(calibration.temp_code_max)})
    if calibration.notes:
        mapping['notes'] = list(calibration.notes)
    for name, axis in zip(AXES, calibration.axes):
        entry: dict[str, Any] = {
            'scale': float(axis.scale),
            'offset': float(axis.offset),
            'offset_span': float(axis.offset_span),
            'offset_shape': [float(c) for c in axis.offset_shape],
            'scale_shape': [float(c) for c in axis.scale_shape],
        }
        if axis.residual_rms is not None:
            entry['residual_rms'] = float(axis.residual_rms)
        if not axis.scale_observable:
            entry['scale_observable'] = False
        mapping[name] = entry
    if calibration.effects:
        mapping['effects'] = effects_to_mapping(calibration.effects)
    if calibration.noise is not None:
        mapping['noise'] = noise_to_mapping(calibration.noise)
    if calibration.turn_on is not None:
        turn_on = calibration.turn_on
        if turn_on.repeatability is None or turn_on.repeatability_error is None:
            mapping['turn_on'] = {'repeatability': NOT_DETERMINED, 'records': int(turn_on.records)}
        else:
            mapping['turn_on'] = {'repeatability': [float(v) for v in turn_on.repeatability],
                                  'repeatability_error': [float(v) for v in turn_on.repeatability_error],
                                  'records': int(turn_on.records)}
    if calibration.uncertainty is not None:
        mapping['uncertainty'] = calibration.uncertainty.to_mapping()
    return mapping


def _strings(value: Any, key: str) -> tuple[str, ...]:
    if isinstance(value, str) or not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        msg = f'{key}: expected a list of strings'
        raise CalibrationError(msg)
    return tuple(value)


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


def _version(raw: Mapping[str, Any], key: str) -> int:
    if 'version' not in raw:
        msg = f'{key}.version: missing'
        raise CalibrationError(msg)
    version = raw['version']
    if (isinstance(version, bool) or not isinstance(version, (int, float))
            or version not in (CALIBRATION_VERSION, UNIT_CALIBRATION_VERSION)):
        msg = (f'{key}.version: unknown version {version!r} (this tool reads versions '
               f'{CALIBRATION_VERSION} and {UNIT_CALIBRATION_VERSION})')
        raise CalibrationError(msg)
    return int(version)


def unit_from_mapping(raw: Any, *, key: str = 'calibration') -> UnitCalibration:
    """Validate a ``calibration`` mapping of either version and build the :class:`UnitCalibration`.

    The single validator: the command-line tools call it on the YAML, the node on its
    ``calibration.*`` parameters at start-up and on every run-time update.

    - version 1 (the paper's counts input, accelerometer only): ``temp_code_ref/min/max``,
      ``x``, ``y``, ``z``, optional ``notes`` and ``effects``;
    - version 2 (``input: imu``, a driver's Imu and a temperature in degrees C): ``accel`` and
      ``gyro``, each with ``temperature_ref/min/max``, ``x``, ``y``, ``z``, optional ``notes``
      and ``effects``; optional ``mag`` (the magnetometer, tesla): the same keys plus
      ``hard_iron`` (3) and ``soft_iron`` (9, row-major, symmetric); optional ``source`` (what
      the record was, for an export: :data:`~tak_thermo_ros.core.link.model.SOURCE_KEYS`).

    :raises CalibrationError: naming the first wrong key.
    """
    if not isinstance(raw, Mapping):
        msg = f'{key}: expected a mapping'
        raise CalibrationError(msg)
    fitted_from = _fitted_from_mapping(raw[FITTED_FROM], f'{key}.{FITTED_FROM}') if FITTED_FROM in raw else ()
    if _version(raw, key) == CALIBRATION_VERSION:
        return UnitCalibration(InputKind.COUNTS, _link_from_mapping(raw, key, InputKind.COUNTS,
                                                                    extra_keys=('version', FITTED_FROM),
                                                                    sensor='counts'), fitted_from=fitted_from)
    _check_keys(raw, key, (), ('version', 'input', 'source', FITTED_FROM, *SENSORS, MAG_SENSOR))
    if raw.get('input') != InputKind.IMU.value:
        msg = (f'{key}.input: expected {InputKind.IMU.value!r} with version {UNIT_CALIBRATION_VERSION}, '
               f'got {raw.get("input")!r}')
        raise CalibrationError(msg)
    for sensor in SENSORS:
        if sensor not in raw:
            msg = f'{key}.{sensor}: missing'
            raise CalibrationError(msg)
    accel, gyro = (_link_from_mapping(raw[sensor], f'{key}.{sensor}', InputKind.IMU, extra_keys=(), sensor=sensor)
                   for sensor in SENSORS)
    mag = _mag_from_mapping(raw[MAG_SENSOR], f'{key}.{MAG_SENSOR}') if MAG_SENSOR in raw else None
    source = _source_from_mapping(raw['source'], f'{key}.source') if 'source' in raw else None
    return UnitCalibration(InputKind.IMU, accel, gyro, mag, source, fitted_from)


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


MAG_IRON_KEYS = ('hard_iron', 'soft_iron')
MAX_HARD_IRON_T = 1e-3
"""Largest ``|hard_iron|`` component a file may hold, tesla (1 mT: beyond any magnetometer's range)."""
SOFT_IRON_EIGENVALUES = (0.2, 5.0)
"""Eigenvalues a file's ``soft_iron`` may have (ArduPilot's diagonal bounds)."""


def _mag_from_mapping(raw: Any, key: str) -> MagnetometerCalibration:
    """The magnetometer: a sensor's keys (tesla) plus ``hard_iron`` (3) and ``soft_iron`` (9, row-major)."""
    thermal = _link_from_mapping(raw, key, InputKind.IMU, extra_keys=MAG_IRON_KEYS, sensor=MAG_SENSOR)
    for name in MAG_IRON_KEYS:
        if name not in raw:
            msg = f'{key}.{name}: missing'
            raise CalibrationError(msg)
    hard = _numbers(raw['hard_iron'], f'{key}.hard_iron', 3)
    soft = _numbers(raw['soft_iron'], f'{key}.soft_iron', 9)
    for i, value in enumerate(hard):
        if abs(value) > MAX_HARD_IRON_T:
            msg = f'{key}.hard_iron[{i}]: |{value:g}| T is beyond {MAX_HARD_IRON_T:g} T'
            raise CalibrationError(msg)
    matrix = np.array(soft).reshape(3, 3)
    if not np.allclose(matrix, matrix.T, rtol=0.0, atol=1e-9):
        msg = f'{key}.soft_iron: not symmetric (row-major 3x3; W[i][j] must equal W[j][i])'
        raise CalibrationError(msg)
    eigenvalues = np.linalg.eigvalsh((matrix + matrix.T) / 2.0)
    low, high = SOFT_IRON_EIGENVALUES
    if eigenvalues[0] <= low or eigenvalues[-1] >= high:
        msg = (f'{key}.soft_iron: eigenvalues {", ".join(f"{v:.3g}" for v in eigenvalues)} outside '
               f'{low:g}..{high:g} (exclusive)')
        raise CalibrationError(msg)
    return MagnetometerCalibration(thermal, hard, soft)  # type: ignore[arg-type]


def _numbers(value: Any, key: str, count: int) -> tuple[float, ...]:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (list, tuple)) or len(value) != count:
        msg = f'{key}: expected a list of {count} numbers'
        raise CalibrationError(msg)
    return tuple(finite_number(item, f'{key}[{i}]') for i, item in enumerate(value))


def unit_to_mapping(unit: UnitCalibration) -> dict[str, Any]:
    """The ``calibration`` mapping of a :class:`UnitCalibration` (plain floats, lists)."""
    if unit.input_kind is InputKind.COUNTS:
        mapping: dict[str, Any] = {'version': CALIBRATION_VERSION, **_link_to_mapping(unit.accel, InputKind.COUNTS)}
    else:
        mapping = {'version': UNIT_CALIBRATION_VERSION, 'input': unit.input_kind.value}
        for sensor, calibration in unit.sensors:
            mapping[sensor] = _link_to_mapping(calibration, unit.input_kind)
        if unit.mag is not None:
            mapping[MAG_SENSOR] = {**_link_to_mapping(unit.mag.thermal, unit.input_kind),
                                   'hard_iron': [float(v) for v in unit.mag.hard_iron],
                                   'soft_iron': [float(v) for v in unit.mag.soft_iron]}
        if unit.source:
            mapping['source'] = dict(unit.source)
    if unit.fitted_from:
        mapping[FITTED_FROM] = _fitted_from_to_mapping(unit.fitted_from)
    return mapping


def calibration_from_mapping(raw: Any, *, key: str = 'calibration') -> Calibration:
    """Validate a version-1 ``calibration`` mapping (counts input) and build its :class:`Calibration`.

    :raises CalibrationError: naming the first wrong key, or when the mapping is a driver
        calibration (version 2: use :func:`unit_from_mapping`).
    """
    unit = unit_from_mapping(raw, key=key)
    if unit.input_kind is not InputKind.COUNTS:
        msg = f'{key}.version: a driver calibration (accel and gyro); this use takes version {CALIBRATION_VERSION}'
        raise CalibrationError(msg)
    return unit.accel


def calibration_to_mapping(calibration: Calibration) -> dict[str, Any]:
    """The version-1 ``calibration`` mapping of a counts-input :class:`Calibration`."""
    return unit_to_mapping(UnitCalibration(InputKind.COUNTS, calibration))


def flatten_parameters(mapping: Mapping[str, Any], prefix: str = 'calibration') -> dict[str, Any]:
    """Flatten nested mappings into ROS 2 parameter names (``calibration.x.scale``)."""
    flat: dict[str, Any] = {}
    for name, value in mapping.items():
        dotted = f'{prefix}.{name}'
        if isinstance(value, Mapping):
            flat.update(flatten_parameters(value, dotted))
        else:
            flat[dotted] = value
    return flat


def nest_parameters(flat: Mapping[str, Any], prefix: str = 'calibration') -> dict[str, Any]:
    """Inverse of :func:`flatten_parameters`: rebuild the mapping under ``prefix``."""
    nested: dict[str, Any] = {}
    start = prefix + '.'
    for dotted, value in flat.items():
        if not dotted.startswith(start):
            continue
        parts = dotted[len(start):].split('.')
        node = nested
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
    return nested


class _ParameterLoader(yaml.SafeLoader):
    """YAML as ROS 2's parameter parser (rcl_yaml_param_parser) reads numbers.

    PyYAML follows YAML 1.1, where ``2.55e2`` and ``1e-9`` (no dot, or no exponent sign) are
    strings; rcl reads them as doubles. This loader reads them as rcl does, so that
    ``tak_calib`` and the node agree on every file.
    """


_ParameterLoader.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    re.compile(r'''^(?:[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?(?:[eE][-+]?[0-9]+)?
                |[-+]?\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                |[-+]?\.(?:inf|Inf|INF)
                |\.(?:nan|NaN|NAN))$''', re.X),
    list('-+0123456789.'))


def _check_uniform_lists(node: Any, key: str) -> None:
    """A parameter array that mixes integers and doubles is refused, as rcl refuses it."""
    if isinstance(node, Mapping):
        for name, value in node.items():
            _check_uniform_lists(value, f'{key}.{name}')
    elif isinstance(node, list):
        kinds = {type(item) for item in node}
        if int in kinds and float in kinds:
            msg = (f'{key}: a list mixes integers and floats, which ROS 2 parameters refuse; '
                   f'write every number with a decimal point (0.0, not 0)')
            raise CalibrationError(msg)


def parse_parameters_yaml(text: str) -> Any:
    """The document of a parameters YAML, numbers read as ROS 2 reads them.

    :raises yaml.YAMLError: when the text is not YAML.
    """
    return yaml.load(text, Loader=_ParameterLoader)  # noqa: S506 (a SafeLoader subclass)


def calibration_section(document: Any) -> Mapping[str, Any]:
    """The ``ros__parameters`` of a calibration file's node section, which holds ``calibration``.

    The section is the first key holding ``ros__parameters.calibration``, whatever its name
    (``/**/compensator``, the older ``compensator``, ``/imu0/compensator``, ``/**``); a file
    whose sections hold none names the first key in its error.

    :raises CalibrationError: when no section holds a calibration.
    """
    if not isinstance(document, Mapping) or not document:
        msg = f'expected a mapping {NODE_KEY}: ros__parameters: calibration: ...'
        raise CalibrationError(msg)
    for section in document.values():
        parameters = section.get('ros__parameters') if isinstance(section, Mapping) else None
        if isinstance(parameters, Mapping) and 'calibration' in parameters:
            return parameters
    node_key = next(iter(document))
    section = document[node_key]
    if not isinstance(section, Mapping) or 'ros__parameters' not in section:
        msg = f'{node_key}.ros__parameters: missing'
        raise CalibrationError(msg)
    msg = f'{node_key}.ros__parameters.calibration: missing'
    raise CalibrationError(msg)


LEARNED_KEY = 'learned'
"""The parameter beside ``calibration`` that holds the learning's state (a learned file)."""


def load_unit(path: str | os.PathLike[str]) -> UnitCalibration:
    """Read and validate a calibration parameters YAML of either version.

    :raises CalibrationError: one line naming the file and the wrong key.
    """
    loaded = load_unit_parameters(path)
    assert loaded is not None
    return loaded[0]


def load_unit_parameters(path: str | os.PathLike[str], *,
                         missing_ok: bool = False) -> tuple[UnitCalibration, Mapping[str, Any]] | None:
    """:func:`load_unit`, and the parameters beside ``calibration`` (the learned file's ``learned``).

    :param missing_ok: ``None`` when the file does not exist (else an error).
    :raises CalibrationError: one line naming the file and the wrong key.
    """
    path = Path(path)
    try:
        text = read_regular_bytes(path, 'calibration file', CalibrationError).decode('utf-8')
    except FileNotFoundError:
        if missing_ok:
            return None
        msg = f'{path}: no such calibration file'
        raise CalibrationError(msg) from None
    except (OSError, UnicodeDecodeError) as err:
        msg = f'{path}: cannot read calibration file ({getattr(err, "strerror", None) or err})'
        raise CalibrationError(msg) from None
    try:
        parameters = calibration_section(parse_parameters_yaml(text))
        _check_uniform_lists(parameters['calibration'], 'calibration')
        unit = unit_from_mapping(parameters['calibration'])
    except yaml.YAMLError as err:
        mark = getattr(err, 'problem_mark', None)
        where = f' at line {mark.line + 1}' if mark is not None else ''
        msg = f'{path}: not valid YAML{where}'
        raise CalibrationError(msg) from None
    except CalibrationError as err:
        msg = f'{path}: {err}'
        raise CalibrationError(msg) from None
    except (RecursionError, ValueError) as err:  # nested beyond Python's stack; an integer of 4,300+ digits
        msg = f'{path}: not a calibration file ({unreadable(err)})'
        raise CalibrationError(msg) from None
    if LEARNED_KEY in parameters:  # a learned file: its corrections judged as the node applies them
        from tak_thermo_ros.core.link.learning import LearnedState, check_learned
        try:
            check_learned(unit, LearnedState.from_mapping(parameters[LEARNED_KEY], f'{path}: {LEARNED_KEY}'),
                          str(path))
        except TakError as err:
            raise CalibrationError(str(err)) from None
    return unit, parameters


def load_calibration(path: str | os.PathLike[str]) -> Calibration:
    """Read and validate a version-1 calibration file (the paper's counts input).

    :raises CalibrationError: one line naming the file and the wrong key.
    """
    unit = load_unit(path)
    if unit.input_kind is not InputKind.COUNTS:
        msg = f'{path}: a driver calibration (accel and gyro); this use takes a counts calibration (version 1)'
        raise CalibrationError(msg)
    return unit.accel


def unit_yaml(unit: UnitCalibration, *, extra_parameters: Mapping[str, Any] | None = None,
              header: str = '') -> str:
    """The calibration file's text, either version."""
    parameters: dict[str, Any] = dict(extra_parameters or {})
    parameters['calibration'] = unit_to_mapping(unit)
    document = {NODE_KEY: {'ros__parameters': parameters}}
    body = yaml.safe_dump(document, sort_keys=False, default_flow_style=None, width=100)
    comment = ''.join(f'# {line}\n' for line in header.splitlines())
    return comment + body


def calibration_yaml(calibration: Calibration, *, extra_parameters: Mapping[str, Any] | None = None,
                     header: str = '') -> str:
    """The text of a version-1 calibration file (counts input)."""
    return unit_yaml(UnitCalibration(InputKind.COUNTS, calibration), extra_parameters=extra_parameters,
                     header=header)


def save_unit(path: str | os.PathLike[str], unit: UnitCalibration, *, header: str = '',
              extra_parameters: Mapping[str, Any] | None = None) -> None:
    """Validate (by a round trip through the one parser) and write the calibration file atomically.

    :param extra_parameters: parameters beside ``calibration`` (the learned file's ``learned``).
    :raises OutputError: a number in it is not finite (:func:`~tak_thermo_ros.formats.files.check_finite`).
    """
    text = unit_yaml(unit, extra_parameters=extra_parameters, header=header)
    document = parse_parameters_yaml(text)
    check_finite(document, path)
    unit_from_mapping(calibration_section(document)['calibration'])
    write_text_atomic(path, text)


def save_calibration(path: str | os.PathLike[str], calibration: Calibration, *,
                     header: str = '') -> None:
    """Validate and write a version-1 calibration file (counts input) atomically."""
    save_unit(path, UnitCalibration(InputKind.COUNTS, calibration), header=header)
