"""The effect library: one correction path with effects, online state, calibration file, scenarios."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import yaml

from conftest import CREEP_MODULE, EXAMPLES
from tak_thermo_ros.formats.calibration_file import (
    calibration_from_mapping,
    calibration_to_mapping,
    flatten_parameters,
    load_calibration,
    nest_parameters,
    save_calibration,
)
from tak_thermo_ros.core.link.correction import Corrector, OutOfRange, forward_counts
from tak_thermo_ros.core.effects import LIBRARY, Effect, resolve_effect, seconds, seconds_from_ns
from tak_thermo_ros.core.link.model import Calibration
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario, scenario_from_mapping
from tak_thermo_ros.errors import CalibrationError, FitError, ScenarioError


USER_MODULE = CREEP_MODULE + '''

class NotAnEffect:
    name = 'nothing'
'''


def _effect(name: str) -> Effect:
    return LIBRARY[name](**EXAMPLES[name])


def _series(count: int = 3000, seed: int = 1):
    rng = np.random.default_rng(seed)
    stamps = 1.7e9 + np.cumsum(rng.uniform(0.5, 1.5, count))
    codes = np.round(8200.0 + np.cumsum(rng.normal(0.0, 3.0, count)))
    force = rng.normal(0.0, 6.0, (count, 3))
    return stamps, codes, force


@pytest.mark.parametrize('names', [[name] for name in EXAMPLES] + [list(EXAMPLES)])
def test_per_sample_and_series_paths_are_bit_identical(names):
    """correct_sample, message by message, equals correct() bit for bit, with every effect."""
    calibration = replace(Scenario().truth(), effects=tuple(_effect(name) for name in names))
    stamps, codes, force = _series()
    counts = np.round(forward_counts(calibration, force, codes, stamp_s=stamps))
    for policy in OutOfRange:
        corrector = Corrector(calibration, out_of_range=policy)
        bulk = corrector.correct(counts, codes, stamp_s=stamps)
        single = np.array([corrector.correct_sample(*row, code, stamp_s=stamp)
                           for row, code, stamp in zip(counts.tolist(), codes.tolist(), stamps.tolist())])
        assert np.array_equal(single, bulk)


@pytest.mark.parametrize('name', list(EXAMPLES))
def test_series_basis_equals_the_step_recurrence(name):
    """Each effect's fast series path performs the same float operations as its step()."""
    effect = _effect(name)
    stamps, codes, _ = _series(2000, seed=2)
    if effect.kind != 'offset':
        return
    state = effect.start(stamps[0], codes[0])
    rows = []
    for stamp, code in zip(stamps.tolist(), codes.tolist()):
        state, values = effect.step(state, stamp, code)
        rows.append(values)
    assert np.array_equal(effect.basis(stamps, codes), np.array(rows))


def test_correction_inverts_the_forward_model_with_effects():
    """f_hat(N(f)) = f with every effect at once (3x3 solve and fixed-point iterations)."""
    calibration = replace(Scenario().truth(), effects=tuple(_effect(name) for name in EXAMPLES))
    stamps, codes, force = _series()
    codes = np.clip(codes, calibration.temp_code_min, calibration.temp_code_max)
    counts = forward_counts(calibration, force, codes, stamp_s=stamps)
    recovered = Corrector(calibration).correct(counts, codes, stamp_s=stamps)
    np.testing.assert_allclose(recovered, force, rtol=0.0, atol=1e-10)


def test_reset_restarts_the_online_state():
    """After reset() the per-sample path starts from the initial state again."""
    calibration = replace(Scenario().truth(), effects=(_effect('thermal_lag'), _effect('warmup')))
    stamps, codes, force = _series(200)
    counts = np.round(forward_counts(calibration, force, codes, stamp_s=stamps))
    corrector = Corrector(calibration)
    first = [corrector.correct_sample(*row, code, stamp_s=stamp)
             for row, code, stamp in zip(counts.tolist(), codes.tolist(), stamps.tolist())]
    corrector.reset()
    again = [corrector.correct_sample(*row, code, stamp_s=stamp)
             for row, code, stamp in zip(counts.tolist(), codes.tolist(), stamps.tolist())]
    assert first == again
    corrector.reset()
    late = corrector.correct_sample(*counts[100].tolist(), codes[100], stamp_s=stamps[100])
    assert late != first[100]  # a restart mid-run starts the lag and the warm-up afresh


def test_initial_states_are_documented_ones():
    """Lag starts in equilibrium, the play centred, warm-up at 1: all three signals at the first sample."""
    assert LIBRARY['thermal_lag'](tau_s=10.0).step(LIBRARY['thermal_lag'](tau_s=10.0).start(5.0, 8000.0),
                                                   5.0, 8000.0)[1] == (0.0,)
    hysteresis = LIBRARY['hysteresis'](width_codes=10.0)
    assert hysteresis.step(hysteresis.start(0.0, 8000.0), 0.0, 8000.0)[1] == (0.0,)
    assert hysteresis.basis(np.zeros(3), np.array([8000.0, 8020.0, 8015.0])).ravel().tolist() == [0.0, 1.0, 0.0]
    warmup = LIBRARY['warmup'](tau_s=10.0)
    assert warmup.basis(np.array([3.0, 13.0]), np.zeros(2)).ravel().tolist() == [1.0, math.exp(-1.0)]


def test_effects_with_memory_need_stamps():
    """A calibration with a lag refuses a series without stamps, naming the effect."""
    calibration = replace(Scenario().truth(), effects=(_effect('thermal_lag'),))
    with pytest.raises(CalibrationError, match='thermal_lag'):
        Corrector(calibration).correct(np.zeros((3, 3)), np.full(3, 8200.0))


def test_stamp_conversion_is_the_same_offline_and_per_message():
    """seconds_from_ns on an array equals seconds(sec, nanosec) per message, bit for bit."""
    stamps_ns = np.array([1_700_000_000_123_456_789, 1_700_000_001_999_999_999, 5], dtype=np.int64)
    expected = [seconds(int(ns) // 1_000_000_000, int(ns) % 1_000_000_000) for ns in stamps_ns]
    assert seconds_from_ns(stamps_ns).tolist() == expected


def test_no_effects_keeps_the_base_link():
    """Without effects the corrector has no effect link and the calibration file no effects key."""
    calibration = Scenario().truth()
    assert Corrector(calibration)._effect_link is None
    assert 'effects' not in calibration_to_mapping(calibration)


def test_calibration_file_round_trip_with_effects(tmp_path, monkeypatch):
    """Effects survive the YAML file and the node's flat ROS parameters unchanged, user ones too."""
    (tmp_path / 'user_effects_rt.py').write_text(USER_MODULE)
    monkeypatch.chdir(tmp_path)
    creep = resolve_effect('user_effects_rt:Creep')(rate_x=0.5, rate_z=-1.25)
    calibration = replace(Scenario().truth(), effects=(*(_effect(name) for name in EXAMPLES), creep))
    path = tmp_path / 'params.yaml'
    save_calibration(path, calibration)
    loaded = load_calibration(path)
    assert loaded == calibration
    document = yaml.safe_load(path.read_text())
    entry = document['/**/compensator']['ros__parameters']['calibration']['effects']['creep']
    assert entry['class'] == 'user_effects_rt:Creep'
    flat = flatten_parameters(calibration_to_mapping(calibration))
    assert flat['calibration.effects.thermal_lag.tau_s'] == 300.0
    assert all(not isinstance(value, (list, dict)) for key, value in flat.items() if '.effects.' in key)
    assert calibration_from_mapping(nest_parameters(flat)) == calibration


@pytest.mark.parametrize(('change', 'message'), [
    ({'thermal_lagg': {'tau_s': 1.0}}, r'calibration\.effects\.thermal_lagg: .*unknown'),
    ({'thermal_lag': {'slope_x': 0.0, 'slope_y': 0.0, 'slope_z': 0.0}},
     r'calibration\.effects\.thermal_lag\.tau_s: missing'),
    ({'thermal_lag': {'tau_s': float('nan'), 'slope_x': 0.0, 'slope_y': 0.0, 'slope_z': 0.0}},
     r'calibration\.effects\.thermal_lag\.tau_s: must be finite'),
    ({'thermal_lag': {'tau_s': -5.0, 'slope_x': 0.0, 'slope_y': 0.0, 'slope_z': 0.0}},
     r'calibration\.effects\.thermal_lag\.tau_s: -5 is outside'),
    ({'warmup': {'tau_s': 5.0, 'amplitude_x': 'big', 'amplitude_y': 0.0, 'amplitude_z': 0.0}},
     r'calibration\.effects\.warmup\.amplitude_x: expected a number'),
    ({'hysteresis': {'width_codes': 5.0, 'amplitude_x': 0.0, 'amplitude_y': 0.0, 'amplitude_z': 0.0, 'gain': 1.0}},
     r'calibration\.effects\.hysteresis\.gain: unknown parameter'),
    ({'temperature_shape': {'knot_1': 8300.0, 'knot_2': 8100.0, 'slope_x_1': 0.0, 'slope_y_1': 0.0,
                            'slope_z_1': 0.0, 'slope_x_2': 0.0, 'slope_y_2': 0.0, 'slope_z_2': 0.0}},
     r'calibration\.effects\.temperature_shape\.knot_2: knots must increase'),
    ({'creep': {'class': 'no_such_module_b1:Creep', 'rate_x': 0.0}},
     r'calibration\.effects\.creep\.class: .*no module'),
    ({'thermal_lag': {'class': 'warmup', 'tau_s': 1.0}}, r'calibration\.effects\.thermal_lag\.class: .*not'),
    ({'thermal_lag': 3.0}, r'calibration\.effects\.thermal_lag: expected a mapping'),
    ({}, r'calibration\.effects: expected a mapping'),
])
def test_calibration_file_rejects_bad_effects(change, message):
    """One clear message naming the key: unknown effect, missing, non-finite, out of bounds, bad class."""
    mapping = calibration_to_mapping(Scenario().truth())
    mapping['effects'] = change
    with pytest.raises(CalibrationError, match=message):
        calibration_from_mapping(mapping)


def test_resolve_effect_accepts_user_classes_and_rejects_others(tmp_path, monkeypatch):
    """module:Class from the current directory works; a non-Effect class or unknown name is a FitError."""
    (tmp_path / 'user_effects_resolve.py').write_text(USER_MODULE)
    monkeypatch.chdir(tmp_path)
    assert resolve_effect('thermal_lag') is LIBRARY['thermal_lag']
    cls = resolve_effect('user_effects_resolve:Creep')
    assert cls.name == 'creep' and cls().amplitude_names() == (('rate_x',), ('rate_y',), ('rate_z',))
    with pytest.raises(FitError, match='not a subclass'):
        resolve_effect('user_effects_resolve:NotAnEffect')
    with pytest.raises(FitError, match='has no Missing'):
        resolve_effect('user_effects_resolve:Missing')
    with pytest.raises(FitError, match="'lag': unknown"):
        resolve_effect('lag')


def test_effects_are_immutable_values():
    """Effects compare by value, refuse attribute changes, and replace() checks bounds."""
    effect = _effect('warmup')
    assert effect == LIBRARY['warmup'](**EXAMPLES['warmup'])
    with pytest.raises(AttributeError):
        effect.tau_s = 3.0  # type: ignore[attr-defined]
    assert effect.replace(tau_s=50.0)['tau_s'] == 50.0 and effect['tau_s'] == 900.0
    with pytest.raises(CalibrationError, match='tau_s'):
        effect.replace(tau_s=0.0)
    assert [p.name for p in effect.parameters] == ['tau_s', 'amplitude_x', 'amplitude_y', 'amplitude_z']
    with pytest.raises(CalibrationError, match='given twice'):
        replace(Scenario().truth(), effects=(effect, effect))


def test_simulator_hides_effects_with_the_same_classes():
    """The counts of a run with an effect differ from the run without by the effect's own contribution."""
    base = Scenario(plateau_hours=0.2, sample_rate_hz=0.2, ramp_celsius_per_minute=2.0)
    hidden = replace(base, effects={'warmup': {'tau_s': 600.0, 'amplitude_z': 40.0}})
    plain, with_effect = simulate(base), simulate(hidden)
    difference = with_effect.record.counts - plain.record.counts
    stamps = seconds_from_ns(plain.record.counts_stamp_ns)
    expected = LIBRARY['warmup'](tau_s=600.0, amplitude_z=40.0).offsets(stamps, plain.true_temp_code)
    assert np.max(np.abs(difference - expected)) <= 1.0  # rounding of the codes only
    assert with_effect.truth.effects == (LIBRARY['warmup'](tau_s=600.0, amplitude_z=40.0),)


def test_supply_voltage_drift_is_an_unobserved_offset():
    """supply_voltage_drift adds a slow offset of the stated RMS on x, uncorrelated with temperature."""
    base = Scenario(plateau_hours=0.5, sample_rate_hz=0.2, ramp_celsius_per_minute=1.0, seed=4)
    plain, drifted = simulate(base), simulate(replace(base, supply_voltage_drift=5.0))
    difference = drifted.record.counts - plain.record.counts
    rms = np.sqrt(np.mean(difference ** 2, axis=0))
    assert 4.0 < rms[0] < 6.0
    np.testing.assert_allclose(rms[1:] / rms[0], [0.7, 0.5], atol=0.1)
    correlation = np.corrcoef(difference[:, 0], plain.true_temp_code)[0, 1]
    assert abs(correlation) < 0.5


@pytest.mark.parametrize(('raw', 'message'), [
    ({'effects': {'lag': {'tau_s': 1.0}}}, r'effects\.lag: .*unknown'),
    ({'effects': {'thermal_lag': {'tau': 1.0}}}, r'effects\.thermal_lag\.tau: unknown parameter'),
    ({'effects': {'thermal_lag': {'tau_s': 'long'}}}, r'effects\.thermal_lag\.tau_s: expected a finite number'),
    ({'effects': {'warmup': {'tau_s': -1.0}}}, r'effects\.warmup\.tau_s: -1 is outside'),
    ({'effects': ['thermal_lag']}, r'effects: expected a mapping'),
    ({'effects': {'warmup': 3}}, r'effects\.warmup: expected a mapping'),
    ({'supply_voltage_drift': -2.0}, r'supply_voltage_drift: must be'),
])
def test_scenario_effects_errors(raw, message):
    """Scenario YAML keys for effects fail with one message naming the key."""
    with pytest.raises(ScenarioError, match=message):
        scenario_from_mapping(raw)


def test_scenario_yaml_reads_effects():
    """`effects` and supply_voltage_drift parse from a scenario mapping."""
    scenario = scenario_from_mapping(yaml.safe_load(
        'effects:\n  thermal_lag: {tau_s: 1800, slope_z: 0.03}\nsupply_voltage_drift: 2\n'))
    assert scenario.effect_instances() == (LIBRARY['thermal_lag'](tau_s=1800.0, slope_z=0.03),)
    assert scenario.supply_voltage_drift == 2.0
    assert isinstance(scenario.truth(), Calibration) and scenario.truth().effects
