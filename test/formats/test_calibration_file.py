"""The calibration parameters YAML: round trip, validation of every key, atomic writes."""

from __future__ import annotations

import copy
import os
from pathlib import Path

import pytest
import yaml

from tak_thermo_ros.formats.calibration_file import (
    calibration_from_mapping,
    calibration_to_mapping,
    flatten_parameters,
    load_calibration,
    nest_parameters,
    save_calibration,
    write_text_atomic,
)
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.errors import CalibrationError


def _document(calibration) -> dict:
    return {'/**/compensator': {'ros__parameters': {'calibration': calibration_to_mapping(calibration)}}}


def test_round_trip(tmp_path):
    """`save` then load gives back the same calibration, bit for bit."""
    calibration = Scenario().truth()
    path = tmp_path / 'params.yaml'
    save_calibration(path, calibration, header='made by a test')
    assert load_calibration(path) == calibration
    assert path.read_text().startswith('# made by a test\n')


def test_files_are_written_with_the_any_namespace_key(tmp_path):
    """`/**/compensator` is the one node key of a written file: the node in any namespace."""
    path = tmp_path / 'params.yaml'
    save_calibration(path, Scenario().truth())
    assert list(yaml.safe_load(path.read_text())) == ['/**/compensator']


@pytest.mark.parametrize('key', ['compensator', '/**/compensator', '/**', '/imu0/compensator', 'renamed'])
def test_any_node_key_holding_a_calibration_loads(tmp_path, key):
    """Old files (`compensator:` at the root) and hand-edited keys load alike."""
    calibration = Scenario().truth()
    document = {key: {'ros__parameters': {'calibration': calibration_to_mapping(calibration)}}}
    path = tmp_path / 'params.yaml'
    path.write_text(yaml.safe_dump(document))
    assert load_calibration(path) == calibration


def test_a_merged_file_loads_the_section_that_holds_the_calibration(tmp_path):
    """A robot's file with other nodes' sections before the compensator's: that one is read."""
    calibration = Scenario().truth()
    document = {'/**': {'ros__parameters': {'use_sim_time': False}},
                '/ekf_filter_node': {'ros__parameters': {'frequency': 50.0}},
                '/**/compensator': {'ros__parameters': {'calibration': calibration_to_mapping(calibration)}}}
    path = tmp_path / 'params.yaml'
    path.write_text(yaml.safe_dump(document, sort_keys=False))
    assert load_calibration(path) == calibration


def test_ros_parameter_names_round_trip():
    """Flattening to ROS 2 parameter names and nesting back is lossless."""
    mapping = calibration_to_mapping(Scenario().truth())
    flat = flatten_parameters(mapping)
    assert 'calibration.x.offset_shape' in flat and 'calibration.temp_code_ref' in flat
    assert nest_parameters(flat) == mapping
    assert calibration_from_mapping(nest_parameters(flat)) == Scenario().truth()


def _set(document: dict, dotted: str, value) -> dict:
    document = copy.deepcopy(document)
    node = document['/**/compensator']['ros__parameters']
    *parents, last = dotted.split('.')
    for part in parents:
        node = node[part]
    if value is DELETE:
        del node[last]
    else:
        node[last] = value
    return document


DELETE = object()

BAD_FILES = [
    ('calibration.x.scale', DELETE, r'calibration\.x\.scale: missing'),
    ('calibration.version', DELETE, r'calibration\.version: missing'),
    ('calibration.version', 3, r'calibration\.version: unknown version 3'),
    ('calibration.temp_code_ref', 'warm', r'calibration\.temp_code_ref: expected a number'),
    ('calibration.y.offset', float('nan'), r'calibration\.y\.offset: must be finite'),
    ('calibration.z.offset_span', float('inf'), r'calibration\.z\.offset_span: must be finite'),
    ('calibration.x.scale', 0.0, r'calibration\.x\.scale: must be > 0'),
    ('calibration.x.scale', -255.0, r'calibration\.x\.scale: must be > 0'),
    ('calibration.temp_code_min', 9000.0, r'calibration\.temp_code_min: must be below temp_code_max'),
    ('calibration.y.scale_shape', [], r'calibration\.y\.scale_shape: expected 1 to 8 coefficients'),
    ('calibration.y.offset_shape', 'abc', r'calibration\.y\.offset_shape: expected a list'),
    ('calibration.y.offset_shape', [1.0, 'x'], r'calibration\.y\.offset_shape\[1\]: expected a number'),
    ('calibration.z.scale_shape', [-0.01], r'calibration\.z\.scale_shape: F_c <= 0 inside the calibrated range'),
    ('calibration.x.offset_span', -1.0, r'calibration\.x\.offset_span: must be >= 0'),
    ('calibration.x.colour', 'red', r'calibration\.x\.colour: unknown key'),
    ('calibration.x.scale', True, r'calibration\.x\.scale: expected a number'),
    ('calibration.z', 5, r'calibration\.z: expected a mapping'),
]


@pytest.mark.parametrize(('key', 'value', 'message'), BAD_FILES, ids=[f'{k}={v!r}'[:40] for k, v, _ in BAD_FILES])
def test_bad_files_name_the_key(tmp_path, key, value, message):
    """Each bad value gives one line that names the file and the key."""
    document = _set(_document(Scenario().truth()), key, value)
    path = tmp_path / 'bad.yaml'
    path.write_text(yaml.safe_dump(document))
    with pytest.raises(CalibrationError, match=message) as error:
        load_calibration(path)
    assert str(error.value).startswith(f'{path}: ')
    assert '\n' not in str(error.value)


@pytest.mark.parametrize(('text', 'message'), [
    ('', 'expected a mapping'),
    ('compensator: [1, 2]', r'compensator\.ros__parameters: missing'),
    ('compensator:\n  ros__parameters:\n    qos: reliable\n', r'ros__parameters\.calibration: missing'),
    ('compensator: {ros__parameters: {calibration: [}', 'not valid YAML at line 1'),
])
def test_malformed_documents(tmp_path, text, message):
    """Documents without the expected structure are refused with the path and the key."""
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(CalibrationError, match=message):
        load_calibration(path)


def test_missing_file(tmp_path):
    """A missing file is named."""
    with pytest.raises(CalibrationError, match='no such calibration file'):
        load_calibration(tmp_path / 'absent.yaml')


def test_integer_values_from_ros_parameters_are_accepted():
    """ROS 2 may hand integers (e.g. scale: 255); they are read as numbers."""
    mapping = calibration_to_mapping(Scenario().truth())
    mapping['x']['scale'] = 255
    mapping['x']['offset_shape'] = [0, 0, 0]
    calibration = calibration_from_mapping(mapping)
    assert calibration.axes[0].scale == 255.0 and calibration.axes[0].offset_shape == (0.0, 0.0, 0.0)


def test_atomic_write_keeps_the_old_file_on_failure(tmp_path, monkeypatch):
    """When the write fails half way, the old file stays and no temporary is left."""
    path = tmp_path / 'params.yaml'
    path.write_text('old')

    def broken_replace(source, target):
        raise OSError('disk full')

    monkeypatch.setattr(os, 'replace', broken_replace)
    with pytest.raises(OSError, match='disk full'):
        write_text_atomic(path, 'new')
    assert path.read_text() == 'old'
    assert sorted(p.name for p in Path(tmp_path).iterdir()) == ['params.yaml']


def test_saving_an_invalid_calibration_writes_nothing(tmp_path):
    """save_calibration validates before writing."""
    from dataclasses import replace
    calibration = Scenario().truth()
    bad_axis = replace(calibration.axes[0], scale_shape=(-0.01,))
    bad = replace(calibration, axes=(bad_axis, *calibration.axes[1:]))
    path = tmp_path / 'params.yaml'
    with pytest.raises(CalibrationError, match='F_c <= 0'):
        save_calibration(path, bad)
    assert not path.exists()
