"""One sensor's link in the calibration file: its temperature range, axes, effects, sections; the magnetometer's iron.

:func:`_link_from_mapping` validates one sensor's mapping (the axes' keys, the effects, the optional
sections of :mod:`~tak_thermo_ros.formats.calibration_sections`, the bounds of
:mod:`~tak_thermo_ros.formats.calibration_checks`) into a :class:`~tak_thermo_ros.core.link.model.Calibration`;
:func:`_link_to_mapping` writes it back. The unit around them: :mod:`~tak_thermo_ros.formats.calibration_file`.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from tak_thermo_ros.core.link.model import (
    AXES,
    CALIBRATION_VERSION,
    AxisModel,
    Calibration,
    MAG_SENSOR,
    THERMAL_FITTED,
    THERMAL_NONE,
    THERMAL_STATES,
    InputKind,
    MagnetometerCalibration,
    NOT_DETERMINED,
    check_plausible,
    check_scale_positive,
)
from tak_thermo_ros.core.values import finite_number
from tak_thermo_ros.errors import CalibrationError, FitError
from tak_thermo_ros.formats.calibration_checks import (
    AXIS_KEYS,
    LIMITS,
    OPTIONAL_AXIS_KEYS,
    _check_keys,
    _check_limits,
    _coefficients,
    _numbers,
)
from tak_thermo_ros.formats.calibration_sections import (
    _noise_from_mapping,
    _turn_on_from_mapping,
    _uncertainty_from_mapping,
    noise_to_mapping,
)


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
