"""The scenario readers' one mapping-to-dataclass helper: the same words for the same mistakes, in every section."""

from __future__ import annotations

from dataclasses import dataclass

import pytest
import yaml

from tak_thermo_ros.core.simulation.everyday import everyday_from_mapping
from tak_thermo_ros.core.simulation.fleet import fleet_from_mapping
from tak_thermo_ros.core.simulation.mapping import fields_from_mapping, integer, number, numbers, whole_numbers
from tak_thermo_ros.core.simulation.motion import motion_from_mapping
from tak_thermo_ros.core.simulation.powered import PoweredRun, powered_from_mapping
from tak_thermo_ros.core.simulation.scenario import scenario_from_mapping
from tak_thermo_ros.errors import ScenarioError
from tak_thermo_ros.formats.scenario import load_powered


@dataclass(frozen=True)
class _Pair:
    second: float = 0.0
    first: int = 0


def _read(key, value):
    return integer(value, key) if key == 'first' else number(value, key)


def test_an_unknown_key_is_named_with_the_fields_in_their_order_or_sorted():
    """``{where}{key}: unknown {noun} (known: ...)``: the fields in the dataclass's order, or sorted."""
    with pytest.raises(ScenarioError, match=r'^s\.third: unknown key \(known: second, first\)$'):
        fields_from_mapping({'third': 1}, _Pair, 's.', _read, not_a_mapping='no')
    with pytest.raises(ScenarioError, match=r'^third: unknown pair key \(known: first, second\)$'):
        fields_from_mapping({'third': 1}, _Pair, '', _read, not_a_mapping='no', noun='pair key', sort_known=True)
    with pytest.raises(ScenarioError, match=r'^s\.first: unknown key \(known: second\)$'):
        fields_from_mapping({'first': 1}, _Pair, 's.', _read, not_a_mapping='no', exclude=('first',))
    with pytest.raises(ScenarioError, match='^a list, not a pair$'):
        fields_from_mapping([1], _Pair, 's.', _read, not_a_mapping='a list, not a pair')
    assert fields_from_mapping({'first': 2, 'second': 1}, _Pair, '', _read, not_a_mapping='no') == \
        {'first': 2, 'second': 1.0}


def test_the_first_bad_key_in_the_mappings_order_is_the_one_named():
    """Keys are judged in the mapping's order: an ill-typed key before an unknown one is named first."""
    with pytest.raises(ScenarioError, match='^first: expected an integer$'):
        fields_from_mapping({'first': 1.5, 'third': 1}, _Pair, '', _read, not_a_mapping='no')
    with pytest.raises(ScenarioError, match='^third: unknown key'):
        fields_from_mapping({'third': 1, 'first': 1.5}, _Pair, '', _read, not_a_mapping='no')


@pytest.mark.parametrize('value, kwargs, words', [
    (True, {}, 'expected a number'),
    ('1', {}, 'expected a number'),
    (float('nan'), {'finite': True}, 'expected a finite number'),
])
def test_a_number_is_an_int_or_a_float_not_a_bool(value, kwargs, words):
    """``number`` refuses a bool, a string and (``finite``) NaN, naming the key."""
    with pytest.raises(ScenarioError, match=f'^k: {words}$'):
        number(value, 'k', **kwargs)


def test_numbers_take_a_list_of_numbers_of_the_length_asked():
    """``numbers``: a list or tuple of numbers (no bools), of ``length`` when given, as floats."""
    assert numbers([1, 2.5], 'k') == (1.0, 2.5)
    for bad in (3, [1, True], ['a']):
        with pytest.raises(ScenarioError, match='^k: expected a list of numbers$'):
            numbers(bad, 'k')
    with pytest.raises(ScenarioError, match='^k: expected a list of 3 numbers$'):
        numbers([1, 2], 'k', what='a list of 3 numbers', length=3)


def test_whole_numbers_take_a_list_of_ints_not_floats_nor_bools():
    """``whole_numbers``: a list or tuple of ints (no bools, no floats, not even 1.0), of ``length`` when given."""
    assert whole_numbers([1, 2], 'k') == (1, 2) and whole_numbers((), 'k') == ()
    for bad in (3, [1, True], [1, 2.0], ['a']):
        with pytest.raises(ScenarioError, match='^k: expected a list of whole numbers$'):
            whole_numbers(bad, 'k')
    with pytest.raises(ScenarioError, match='^k: expected a list of 2 whole numbers$'):
        whole_numbers([1], 'k', what='a list of 2 whole numbers', length=2)


@pytest.mark.parametrize('read, raw, words', [
    (scenario_from_mapping, 3, 'scenario: expected a mapping of keys to values'),
    (scenario_from_mapping, {'nope': 1}, 'nope: unknown scenario key (known: sample_rate_hz, temp_code_every, '),
    (scenario_from_mapping, {'seed': 'a', 'nope': 1}, 'seed: expected an integer'),
    (scenario_from_mapping, {'record_references': 1}, 'record_references: expected true or false'),
    (scenario_from_mapping, {'sample_rate_hz': float('inf')}, 'sample_rate_hz: expected a finite number'),
    (scenario_from_mapping, {'unit': {'x': {'bogus': 1}}},
     'unit.x.bogus: unknown key (known: bias_instability, bias_instability_tau, filter_time_constant, '),
    (scenario_from_mapping, {'unit': {'x': {'scale': True}}}, 'unit.x.scale: expected a number'),
    (scenario_from_mapping, {'effects': {'warmup': {'tau_s': True}}}, 'effects.warmup.tau_s: expected a finite number'),
    (motion_from_mapping, 3, 'handheld: expected a mapping (every key optional: pattern, orientations, '),
    (motion_from_mapping, {'bogus': 1}, 'handheld.bogus: unknown key (known: pattern, orientations, '),
    (motion_from_mapping, {'lever_arm_m': [1, 'a']}, 'handheld.lever_arm_m: expected a list of three numbers'),
    (motion_from_mapping, {'orientations': 2.5}, 'handheld.orientations: expected an integer'),
    (motion_from_mapping, {'latitude_deg': 'a'}, 'handheld.latitude_deg: expected a number'),
    (everyday_from_mapping, 3, 'everyday: expected a mapping (every key optional: records, days, '),
    (everyday_from_mapping, {'bogus': 1}, 'everyday.bogus: unknown key (known: records, days, '),
    (everyday_from_mapping, {'ambient_celsius': [1]}, 'everyday.ambient_celsius: expected a list of 2 numbers'),
    (everyday_from_mapping, {'records': 1.5}, 'everyday.records: expected a whole number'),
    (fleet_from_mapping, [], 'fleet: expected a mapping (every key optional: units, gyro, accel, groups, '),
    (fleet_from_mapping, {'bogus': 1}, 'fleet.bogus: unknown key (known: units, gyro, accel, groups, group_slope, '),
    (fleet_from_mapping, {'gyro': [1, 2]}, 'fleet.gyro: expected a list of 4 numbers'),
    (fleet_from_mapping, {'other_part': [1.0]}, 'fleet.other_part: expected a list of any whole numbers'),
    (fleet_from_mapping, {'other_part': [True]}, 'fleet.other_part: expected a list of any whole numbers'),
    (fleet_from_mapping, {'units': 2.0}, 'fleet.units: expected a whole number'),
    (powered_from_mapping, 3, 'powered: expected a mapping of duration_s, start_celsius, '),
    (powered_from_mapping, {'accel_unit': 1}, 'powered.accel_unit: unknown key (known: accel_rate_hz, ambient_knots, '),
    (powered_from_mapping, {'up': 'x'}, "powered.up: 'x' is not what it takes"),
    (powered_from_mapping, {'duration_s': -1}, 'powered.duration_s: must be > 0'),
])
def test_every_section_says_its_mistakes_in_the_same_words(read, raw, words):
    """Each reader's message for a mistake, word for word (the helper changed none of them)."""
    with pytest.raises(ScenarioError) as caught:
        read(raw)
    assert str(caught.value).startswith(words)


@pytest.mark.parametrize('section', [None, 3, {}, {'bogus': 1}, {'ambient_knots': [[1, 'a']]}, {'seed': 'a'},
                                     {'duration_s': -1, 'bogus': 2}, {'up': [0, 0, 1], 'frame_id': 7}])
def test_a_powered_section_reads_as_the_scenario_file_reads_it(tmp_path, section):
    """``powered_from_mapping`` reads a ``powered:`` section as ``load_powered`` reads the file (same message)."""
    path = tmp_path / 'scenario.yaml'
    path.write_text(yaml.safe_dump({'powered': section}))
    try:
        from_file = load_powered(path)
    except ScenarioError as err:
        with pytest.raises(ScenarioError) as caught:
            powered_from_mapping(section)
        assert str(err) == f'{path}: {caught.value}'
    else:
        assert isinstance(from_file, PoweredRun)
        assert powered_from_mapping(section) == from_file
