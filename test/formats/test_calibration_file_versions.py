"""The calibration file, version 2 (a driver's Imu: accel and gyro) beside version 1: one parser for all.

The file (``load_unit``) and the node's parameters (rcl parses the same YAML; the node nests the
``calibration.*`` parameters and calls ``unit_from_mapping``) must agree on every file; limits and
unknown keys are refused naming the key; property tests check exact round trips of generated
calibrations and that junk never raises anything but :class:`CalibrationError`.
"""

from __future__ import annotations

import copy
from dataclasses import replace
from pathlib import Path

import pytest
import rclpy
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rclpy.context import Context
from rclpy.node import Node

from node_helpers import domain_id, ros_environment
from tak_thermo_ros.formats.calibration_checks import LIMITS
from tak_thermo_ros.formats.calibration_file import (
    flatten_parameters,
    load_calibration,
    load_unit,
    nest_parameters,
    save_unit,
    unit_from_mapping,
    unit_to_mapping,
    unit_yaml,
)
from tak_thermo_ros.core.effects import LIBRARY
from tak_thermo_ros.core.link.model import SENSOR_RANGE, AxisModel, Calibration, InputKind, TurnOn, UnitCalibration
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.errors import CalibrationError

V1_FILE = '''\
# written by tak_calib before version 2
compensator:
  ros__parameters:
    calibration:
      version: 1
      temp_code_ref: 8200.0
      temp_code_min: 7600.0
      temp_code_max: 8800.0
      notes: [scale held at nominal on z]
      x:
        scale: 255.1
        offset: -12.3
        offset_span: 39.720000000000006
        offset_shape: [0.0012588116817724066, 3.77643504531722e-07, 5.035246727089627e-10]
        scale_shape: [2.0e-06, 1.0e-09]
        residual_rms: 1.5
      y:
        scale: 254.3
        offset: 8.7
        offset_span: 33.36
        offset_shape: [-0.0011990407673860913, 5.995203836930456e-07, -2.997601918465228e-10]
        scale_shape: [-1.5e-06, 2.0e-09]
        residual_rms: 1.5
      z:
        scale: 256.0
        offset: 3.1
        offset_span: 28.08
        offset_shape: [0.0010683760683760685, -3.5612535612535615e-07, 1.0683760683760683e-09]
        scale_shape: [1.0e-06, -1.0e-09]
        residual_rms: 1.5
      effects:
        thermal_lag: {tau_s: 1800.0, slope_x: 0.02, slope_y: 0.0, slope_z: -0.03}
'''
"""A version-1 file exactly as tak_calib wrote it before version 2 existed (commit 9627f88)."""


def _driver_unit() -> UnitCalibration:
    """The simulator's true driver unit, with an effect on the gyroscope and a note."""
    unit = Scenario(output='imu').driver_truth()
    gyro = replace(unit.gyro, effects=(LIBRARY['thermal_lag'](tau_s=300.0, slope_x=4e-4, slope_z=-5e-4),),
                   notes=('scale held at nominal on x, y, z',))
    return replace(unit, gyro=gyro)


def _rcl_calibration(path: Path, tmp_path: Path, monkeypatch, index: int) -> dict:
    """The ``calibration.*`` parameters as rcl reads ``--params-file path`` into a node, nested."""
    for name, value in ros_environment(tmp_path, domain_id(index)).items():
        monkeypatch.setenv(name, value)
    context = Context()
    rclpy.init(args=['--ros-args', '--params-file', str(path)], context=context)
    try:
        node = Node('compensator', context=context, automatically_declare_parameters_from_overrides=True)
        try:
            flat = {f'calibration.{name}': parameter.value
                    for name, parameter in node.get_parameters_by_prefix('calibration').items()}
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    return nest_parameters(flat)


def test_v2_round_trip_is_exact(tmp_path):
    """save_unit then load_unit gives the same unit, effects and notes included, bit for bit."""
    unit = _driver_unit()
    save_unit(tmp_path / 'p.yaml', unit, header='a test')
    loaded = load_unit(tmp_path / 'p.yaml')
    assert loaded == unit and loaded.input_kind is InputKind.IMU
    text = (tmp_path / 'p.yaml').read_text()
    assert 'version: 2' in text and 'input: imu' in text and 'temperature_ref' in text and 'temp_code' not in text


def test_turn_on_repeatability_round_trips_and_bad_values_are_refused_naming_the_key(tmp_path):
    """A sensor's ``turn_on`` section round-trips exactly; a bad, missing or extra value is one CalibrationError."""
    unit = _driver_unit()
    turn_on = TurnOn(repeatability=(1e-4, 2e-4, 0.0), repeatability_error=(2e-5, 3e-5, 1e-6), records=16)
    unit = replace(unit, gyro=replace(unit.gyro, turn_on=turn_on))
    save_unit(tmp_path / 'p.yaml', unit)
    loaded = load_unit(tmp_path / 'p.yaml')
    assert loaded == unit and loaded.gyro.turn_on == turn_on and loaded.accel.turn_on is None
    document = yaml.safe_load((tmp_path / 'p.yaml').read_text())
    section = document['/**/compensator']['ros__parameters']['calibration']['gyro']['turn_on']
    for change, named in (({'repeatability': [1e-4, -2e-4, 0.0]}, 'turn_on.repeatability'),
                          ({'repeatability_error': [1e-4, float('nan'), 0.0]}, 'turn_on.repeatability_error'),
                          ({'records': 1}, 'turn_on.records'), ({'records': 2.5}, 'turn_on.records'),
                          ({'spread': [0.0, 0.0, 0.0]}, 'turn_on.spread')):
        bad = copy.deepcopy(document)
        bad['/**/compensator']['ros__parameters']['calibration']['gyro']['turn_on'] = {**section, **change}
        path = tmp_path / 'bad.yaml'
        path.write_text(yaml.safe_dump(bad))
        with pytest.raises(CalibrationError, match=named.replace('.', r'\.')):
            load_unit(path)


def test_v1_files_written_before_version_2_load_unchanged(tmp_path):
    """A file of the old format loads, as counts input, with every number as written."""
    path = tmp_path / 'v1.yaml'
    path.write_text(V1_FILE)
    unit = load_unit(path)
    assert unit.input_kind is InputKind.COUNTS and unit.gyro is None
    assert load_calibration(path) == unit.accel
    raw = yaml.safe_load(V1_FILE)['compensator']['ros__parameters']['calibration']
    assert unit.accel.temp_code_ref == 8200.0 and unit.accel.temp_code_max == 8800.0
    assert unit.accel.notes == ('scale held at nominal on z',)
    for name, axis in zip('xyz', unit.accel.axes):
        assert axis.scale == raw[name]['scale'] and axis.offset_shape == tuple(raw[name]['offset_shape'])
        assert axis.offset_span == raw[name]['offset_span'] and axis.residual_rms == 1.5
    assert unit.accel.effects == (LIBRARY['thermal_lag'](tau_s=1800.0, slope_x=0.02, slope_z=-0.03),)
    # written again, it is the same file body under the any-namespace node key
    assert unit_yaml(unit).splitlines() == ['/**/compensator:', *V1_FILE.splitlines()[2:]]


@pytest.mark.parametrize('version', [1, 2])
def test_one_parser_for_the_file_and_the_node_parameters(tmp_path, monkeypatch, version):
    """unit_from_mapping on the node's parameters (as rcl reads them, flat, nested again) equals load_unit."""
    path = tmp_path / 'p.yaml'
    if version == 1:
        path.write_text(V1_FILE)
    else:
        save_unit(path, _driver_unit())
    from_file = load_unit(path)
    nested = _rcl_calibration(path, tmp_path, monkeypatch, version)
    assert unit_from_mapping(nested) == from_file
    mapping = unit_to_mapping(from_file)
    assert unit_from_mapping(nest_parameters(flatten_parameters(mapping))) == from_file
    assert nest_parameters(flatten_parameters(mapping)) == mapping


def test_exponent_without_a_dot_is_a_number_for_the_file_and_for_rcl(tmp_path, monkeypatch):
    """``scale: 2.55e2`` is 255.0 for load_unit (YAML 1.1 would read a string) and for rcl."""
    path = tmp_path / 'p.yaml'
    path.write_text(V1_FILE.replace('scale: 255.1', 'scale: 2.55e2'))
    assert load_unit(path).accel.axes[0].scale == 255.0
    assert yaml.safe_load(path.read_text())['compensator']['ros__parameters']['calibration']['x']['scale'] == '2.55e2'
    nested = _rcl_calibration(path, tmp_path, monkeypatch, 3)
    assert nested['x']['scale'] == 255.0
    assert unit_from_mapping(nested) == load_unit(path)


def test_mixed_int_and_float_lists_are_refused_in_one_line(tmp_path):
    """A list of 0 and 1.5e-6 is refused by rcl, and by load_unit naming the file and the key."""
    path = tmp_path / 'p.yaml'
    path.write_text(V1_FILE.replace('scale_shape: [2.0e-06, 1.0e-09]', 'scale_shape: [0, 1.0e-09]'))
    with pytest.raises(CalibrationError) as error:
        load_unit(path)
    text = str(error.value)
    assert '\n' not in text and text.startswith(f'{path}: calibration.x.scale_shape: a list mixes integers')


def _v2_mapping() -> dict:
    return unit_to_mapping(_driver_unit())


def _set(mapping: dict, dotted: str, value) -> dict:
    mapping = copy.deepcopy(mapping)
    node = mapping
    *parents, last = dotted.split('.')
    for part in parents:
        node = node[part]
    node[last] = value
    return mapping


@pytest.mark.parametrize(('kind', 'dotted', 'value', 'named'), [
    (1, 'temp_code_maxx', 9000.0, 'calibration.temp_code_maxx: unknown key'),
    (2, 'accel.temperature_maxx', 40.0, 'calibration.accel.temperature_maxx: unknown key'),
    (2, 'gyro.x.scale_observabel', False, 'calibration.gyro.x.scale_observabel: unknown key'),
    (2, 'accel.temp_code_max', 40.0, 'calibration.accel.temp_code_max: unknown key'),
    (2, 'magnetometer', {}, 'calibration.magnetometer: unknown key'),
    (1, 'x.offset_span', 1e300, 'calibration.x.offset_span: |1e+300| is beyond 65536'),
    (1, 'x.offset', 1e308, 'calibration.x.offset: |1e+308| is beyond 65536'),
    (1, 'y.residual_rms', 1e200, 'calibration.y.residual_rms: |1e+200| is beyond 65536'),
    (2, 'gyro.x.offset_span', 1e300, 'calibration.gyro.x.offset_span: |1e+300| is beyond 10000'),
    (2, 'accel.z.offset', 1e308, 'calibration.accel.z.offset: |1e+308| is beyond 10000'),
    (2, 'gyro.y.residual_rms', 1e200, 'calibration.gyro.y.residual_rms: |1e+200| is beyond 10000'),
    (2, 'accel.x.scale', 0.0, 'calibration.accel.x.scale: must be > 0'),
    (2, 'gyro.z.scale', 3.0, 'calibration.gyro.z.scale: 3 is outside 0.5..2'),
    (2, 'gyro.temperature_max', 5000.0, 'calibration.gyro.temperature_max: 5000 is outside'),
    (2, 'input', 'counts', 'calibration.input: expected'),
])
def test_unknown_keys_and_unphysical_values_are_refused_naming_the_key(tmp_path, kind, dotted, value, named):
    """The same refusal from the mapping and from the file (with the file's name), in one line."""
    base = unit_to_mapping(UnitCalibration(InputKind.COUNTS, Scenario().truth())) if kind == 1 else _v2_mapping()
    mapping = _set(base, dotted, value)
    with pytest.raises(CalibrationError) as error:
        unit_from_mapping(mapping)
    assert str(error.value).startswith(named) and '\n' not in str(error.value)
    path = tmp_path / 'p.yaml'
    path.write_text(yaml.safe_dump({'compensator': {'ros__parameters': {'calibration': mapping}}}))
    with pytest.raises(CalibrationError) as from_file:
        load_unit(path)
    assert str(from_file.value) == f'{path}: {error.value}'


# ------------------------------------------------------------------------------- properties

def _finite(low: float, high: float) -> st.SearchStrategy[float]:
    return st.floats(low, high, allow_nan=False, allow_infinity=False)


@st.composite
def calibrations(draw, kind: InputKind, sensor: str = 'counts') -> Calibration:
    """A valid link: random coefficients inside the physical limits of the input kind and the sensor.

    The offset removed stays within the sensor's range (``SENSOR_RANGE``), as ``check_plausible`` asks.
    """
    limits = LIMITS[kind]
    bound = SENSOR_RANGE[sensor][0]
    low_t, high_t = (-40.0, 85.0) if kind is InputKind.IMU else (0.0, 20000.0)
    t_min = draw(_finite(low_t, high_t - 1.0))
    t_max = draw(_finite(t_min + 0.5, high_t))
    ref = draw(_finite(t_min, t_max))
    n_range = (t_min - ref, t_max - ref)
    reach = max(abs(n_range[0]), abs(n_range[1]), 1e-9)
    axes = []
    for _ in range(3):
        scale = draw(_finite(0.6, 1.9) if kind is InputKind.IMU else _finite(1e-3, 1e5))
        bias_order = draw(st.integers(1, 8))
        scale_order = draw(st.integers(0, 8))
        # offset polynomial: coefficients scaled to the range, normalised by from_polynomials
        offset_coeffs = [draw(_finite(-1.0, 1.0)) * 0.05 * bound / bias_order / reach ** (k + 1)
                         for k in range(bias_order)]
        # F_c stays within 1 +- 0.4 over the range
        scale_coeffs = [draw(_finite(-1.0, 1.0)) * 0.4 / scale_order / reach ** (k + 1) for k in range(scale_order)]
        residual = draw(st.none() | _finite(0.0, limits.value))
        axis = AxisModel.from_polynomials(scale=scale, offset=draw(_finite(-0.5 * bound, 0.5 * bound)),
                                          offset_coeffs=offset_coeffs, scale_coeffs=scale_coeffs,
                                          code_offset_range=n_range, residual_rms=residual,
                                          scale_observable=draw(st.booleans()))
        axes.append(axis)
    effects = ()
    if draw(st.booleans()):
        effects = (LIBRARY['thermal_lag'](tau_s=draw(_finite(1e-3, 1e8)), slope_x=draw(_finite(-1e3, 1e3)),
                                          slope_y=draw(_finite(-1e3, 1e3)), slope_z=draw(_finite(-1e3, 1e3))),)
    notes = tuple(draw(st.lists(st.text(st.characters(codec='utf-8', exclude_categories=('Cs', 'Cc')), max_size=30),
                                max_size=2)))
    return Calibration(temp_code_ref=ref, temp_code_min=t_min, temp_code_max=t_max, axes=tuple(axes),
                       notes=notes, effects=effects)


units = (calibrations(InputKind.COUNTS).map(lambda cal: UnitCalibration(InputKind.COUNTS, cal))
         | st.tuples(calibrations(InputKind.IMU, 'accel'), calibrations(InputKind.IMU, 'gyro')).map(
             lambda pair: UnitCalibration(InputKind.IMU, *pair)))

PROPERTY = settings(max_examples=60, deadline=None, database=None,
                    suppress_health_check=(HealthCheck.too_slow, HealthCheck.function_scoped_fixture))


@PROPERTY
@given(unit=units)
def test_generated_calibrations_round_trip_exactly_through_the_file(tmp_path, unit):
    """Every valid calibration comes back from its file equal, float for float."""
    path = tmp_path / 'p.yaml'
    save_unit(path, unit)
    assert load_unit(path) == unit
    mapping = unit_to_mapping(unit)
    assert unit_from_mapping(nest_parameters(flatten_parameters(mapping))) == unit


KEYS = ('version', 'input', 'accel', 'gyro', 'x', 'y', 'z', 'scale', 'offset', 'offset_span', 'offset_shape',
        'scale_shape', 'residual_rms', 'scale_observable', 'notes', 'effects', 'thermal_lag', 'tau_s', 'slope_x',
        'temp_code_ref', 'temp_code_min', 'temp_code_max', 'temperature_ref', 'temperature_min',
        'temperature_max', 'class')
scalars = (st.none() | st.booleans() | st.integers(-10 ** 400, 10 ** 400) | st.floats()
           | st.text(max_size=12) | st.sampled_from(['imu', 'counts', 'mymodule:Nothing', 'os:system']))
junk = st.recursive(scalars, lambda inner: st.lists(inner, max_size=4)
                    | st.dictionaries(st.sampled_from(KEYS) | st.integers(0, 3) | st.text(max_size=5), inner,
                                      max_size=6), max_leaves=30)


def _paths(node, prefix=()):
    yield prefix
    if isinstance(node, dict):
        for key, value in node.items():
            yield from _paths(value, (*prefix, key))
    elif isinstance(node, list):
        for index, value in enumerate(node):
            yield from _paths(value, (*prefix, index))


def _replaced(node, path, value):
    if not path:
        return value
    node = copy.copy(node)
    node[path[0]] = _replaced(node[path[0]], path[1:], value)
    return node


@st.composite
def mutated(draw):
    """A valid mapping (either version) with one value anywhere replaced by junk, or a key added."""
    counts = unit_to_mapping(UnitCalibration(InputKind.COUNTS, Scenario().truth()))
    base = draw(st.sampled_from([_v2_mapping(), counts]))
    paths = list(_paths(base))
    path = draw(st.sampled_from(paths))
    if draw(st.booleans()) or not path:
        return _replaced(base, path, draw(junk))
    target = base
    for part in path[:-1]:
        target = target[part]
    if isinstance(target, dict):
        target = copy.copy(target)
        for _ in range(draw(st.integers(1, 2))):
            target[draw(st.sampled_from(KEYS) | st.integers(0, 3) | st.text(max_size=3))] = draw(junk)
        return _replaced(base, path[:-1], target)
    return _replaced(base, path, draw(junk))


@PROPERTY
@given(raw=junk | mutated())
def test_junk_mappings_raise_calibration_error_and_nothing_else(raw):
    """unit_from_mapping either builds a unit or raises CalibrationError: never another exception."""
    try:
        unit = unit_from_mapping(raw)
    except CalibrationError as err:
        assert '\n' not in str(err)
        return
    assert isinstance(unit, UnitCalibration)


@PROPERTY
@given(raw=junk | mutated())
def test_junk_files_raise_calibration_error_and_nothing_else(tmp_path, raw):
    """A file holding junk under calibration: load_unit raises CalibrationError only, naming the file."""
    path = tmp_path / 'p.yaml'
    try:
        text = yaml.safe_dump({'compensator': {'ros__parameters': {'calibration': raw}}})
    except (yaml.YAMLError, OverflowError):
        return
    path.write_text(text)
    try:
        load_unit(path)
    except CalibrationError as err:
        assert str(err).startswith(f'{path}: ') and '\n' not in str(err)


def test_huge_integer_is_refused_not_overflowed():
    """An integer beyond float range (valid YAML) is a CalibrationError naming the key."""
    mapping = _set(_v2_mapping(), 'gyro.x.offset', 10 ** 400)
    with pytest.raises(CalibrationError, match=r'^calibration\.gyro\.x\.offset: '):
        unit_from_mapping(mapping)


@pytest.mark.parametrize('where', ['accel.x', 'gyro.effects.thermal_lag'])
def test_keys_of_mixed_types_are_refused_not_crashed(where):
    """YAML allows integer keys: an axis or an effect with keys 1 and 'zz' is refused naming one."""
    mapping = copy.deepcopy(_v2_mapping())
    node = mapping
    for part in where.split('.'):
        node = node[part]
    node[1] = 2.0
    node['zz'] = 3.0
    with pytest.raises(CalibrationError, match=rf'^calibration\.{where.replace(".", "[.]")}\.1: unknown'):
        unit_from_mapping(mapping)
