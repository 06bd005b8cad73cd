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

The file's parts each have a module: one sensor's link (its axes, effects and bounds:
:mod:`~tak_thermo_ros.formats.calibration_link`), the optional sections (``uncertainty``, ``turn_on``,
``noise``, ``fitted_from``, ``source``: :mod:`~tak_thermo_ros.formats.calibration_sections`), and the
key lists and checks they share (:mod:`~tak_thermo_ros.formats.calibration_checks`). This module reads
and writes the whole file: the ``calibration`` mapping of a unit, the parameters YAML, load and save.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any, Mapping

import yaml

from tak_thermo_ros.formats.files import write_text_atomic  # noqa: F401 (re-exported: one writer of text files)
from tak_thermo_ros.formats.files import check_finite, read_regular_bytes, unreadable
from tak_thermo_ros.core.link.model import (
    CALIBRATION_VERSION,
    SENSORS,
    UNIT_CALIBRATION_VERSION,
    Calibration,
    MAG_SENSOR,
    InputKind,
    UnitCalibration,
)
from tak_thermo_ros.errors import CalibrationError, TakError
from tak_thermo_ros.formats.calibration_checks import _check_keys
from tak_thermo_ros.formats.calibration_link import _link_from_mapping, _link_to_mapping, _mag_from_mapping
from tak_thermo_ros.formats.calibration_sections import (
    FITTED_FROM,
    _fitted_from_mapping,
    _fitted_from_to_mapping,
    _source_from_mapping,
)

NODE_NAME = 'compensator'
NODE_KEY = f'/**/{NODE_NAME}'
"""The node key the files are written with: the node ``compensator`` in any namespace.

Not ``/**`` (every node): a robot's parameters file often gathers many nodes, and ``/**`` would
hand ``calibration.*`` to each of them. A renamed node reads the file with
``-p calibration_file:=FILE`` (any key), or the key is edited to its name.
"""


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
