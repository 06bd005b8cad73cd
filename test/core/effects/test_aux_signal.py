"""Recorded auxiliary signals (``aux:TOPIC``): the effect, the file, the bags, the loop, the online core."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
import yaml

from conftest import SHORT
from tak_thermo_ros import cli
from tak_thermo_ros.formats.bag import read_driver_record, read_record
from tak_thermo_ros.formats.calibration_file import (
    calibration_from_mapping,
    calibration_to_mapping,
    load_unit,
    parse_parameters_yaml,
)
from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.effects import aux_effect_class, resolve_effect
from tak_thermo_ros.core.link.online import OnlineCompensator
from tak_thermo_ros.core.link.online_rules import STALE_SIGNAL, WAITING_FOR_SIGNAL, StaleTemperature
from tak_thermo_ros.core.records.record import align, require_signals
from tak_thermo_ros.core.simulation.imu import (
    SUPPLY_AXIS_WEIGHTS,
    SUPPLY_NOMINAL_VOLTS,
    SUPPLY_VOLTS_RMS,
    first_order_lag,
    simulate,
)
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.link.validate import validate_gravity
from tak_thermo_ros.errors import CalibrationError, FitError

SUPPLY = 'aux:/power/battery_state'
DRIFT = 3.0
"""Counts of offset per unit of the simulator's supply signal (axis x)."""


def supply_truth(drift: float = DRIFT) -> dict[str, float]:
    """The aux effect equal to the simulator's supply drift: slope = drift / volts per unit, no lag."""
    slopes = {f'slope_{axis}': drift * weight / SUPPLY_VOLTS_RMS for axis, weight in zip('xyz', SUPPLY_AXIS_WEIGHTS)}
    return {'tau_s': 0.0, 'reference': SUPPLY_NOMINAL_VOLTS, **slopes}


# ----- the effect ------------------------------------------------------------------------------


@pytest.mark.parametrize('tau_s', [0.0, 7.0])
def test_step_and_basis_agree_bit_for_bit_and_follow_a_first_order_lag(tau_s):
    """The series path equals the per-sample path exactly; tau 0 is the held value, tau > 0 its exact lag."""
    rng = np.random.default_rng(3)
    stamps = 1000.0 + np.cumsum(rng.uniform(0.5, 1.5, 400))
    values = 12.0 + 0.3 * np.sin(stamps / 30.0) + 0.01 * rng.standard_normal(400)
    effect = aux_effect_class(SUPPLY)(tau_s=tau_s, reference=12.0, slope_x=2.0)
    basis = effect.basis(stamps, values)
    state = effect.start(stamps[0], values[0])
    stepped = []
    for stamp, value in zip(stamps, values):
        state, row = effect.step(state, stamp, value)
        stepped.append(row)
    assert np.array_equal(basis, np.array(stepped))
    expected = first_order_lag(values, stamps, tau_s, values[0]) - 12.0
    if tau_s == 0.0:
        assert np.array_equal(basis[:, 0], values - 12.0)
    else:
        np.testing.assert_allclose(basis[:, 0], expected, rtol=0, atol=1e-12)
        assert np.max(np.abs(basis[:, 0] - (values - 12.0))) > 0.01  # the lag shows


def test_signal_names_resolve_to_one_class_each_and_bad_names_are_refused():
    """aux:TOPIC and aux:TOPIC:FIELD are effect names; the class is made once per name."""
    cls = resolve_effect(SUPPLY)
    assert cls is aux_effect_class(SUPPLY) and cls.name == SUPPLY and cls.needs_signal == SUPPLY
    other = resolve_effect('aux:/power/battery_state:current')
    assert other is not cls and other.needs_signal == 'aux:/power/battery_state:current'
    for bad in ('aux:power', 'aux:/a:b:c', 'aux:/a:'):
        with pytest.raises(FitError, match='aux:'):
            resolve_effect(bad)


def test_calibration_file_stores_aux_terms_under_ros_parameter_names():
    """aux_1 / aux_2 with string topic (and field) and flat floats; the one parser reads them back."""
    base = Scenario().truth()
    effects = (aux_effect_class(SUPPLY)(**supply_truth()),
               aux_effect_class('aux:/power/battery_state:current')(tau_s=30.0, reference=1.5, slope_z=-4.0))
    calibration = replace(base, effects=effects)
    mapping = calibration_to_mapping(calibration)
    stored = mapping['effects']
    assert list(stored) == ['aux_1', 'aux_2']
    assert stored['aux_1']['topic'] == '/power/battery_state' and 'field' not in stored['aux_1']
    assert stored['aux_2']['field'] == 'current'
    assert all(':' not in key and '/' not in key for entry in stored.values() for key in entry)
    text = yaml.safe_dump({'compensator': {'ros__parameters': {'calibration': mapping}}})
    again = calibration_from_mapping(parse_parameters_yaml(text)['compensator']['ros__parameters']['calibration'])
    assert again.effects == effects
    broken = json.loads(json.dumps(mapping))
    broken['effects']['aux_1']['topic'] = 'power'
    with pytest.raises(CalibrationError, match=r'calibration.effects.aux_1.topic'):
        calibration_from_mapping(broken)
    del broken['effects']['aux_1']['topic']
    with pytest.raises(CalibrationError, match=r'calibration.effects.aux_1'):
        calibration_from_mapping(broken)


def test_correction_needs_the_signal_and_names_it():
    """A calibration with an aux term refuses to correct without that signal's values."""
    calibration = replace(Scenario().truth(), effects=(aux_effect_class(SUPPLY)(**supply_truth()),))
    corrector = Corrector(calibration)
    assert corrector.signals == (SUPPLY,)
    counts = np.zeros((3, 3))
    with pytest.raises(CalibrationError, match='/power/battery_state'):
        corrector.correct(counts, np.full(3, 8200.0), stamp_s=np.arange(3.0))
    volts = np.array([12.0, 12.1, 12.2])
    with_signal = corrector.correct(counts, np.full(3, 8200.0), stamp_s=np.arange(3.0), aux={SUPPLY: volts})
    without_term = Corrector(Scenario().truth()).correct(counts, np.full(3, 8200.0))
    slopes = np.array([supply_truth()[f'slope_{a}'] for a in 'xyz'])
    scale = np.array([axis.scale for axis in calibration.axes])
    np.testing.assert_allclose((without_term - with_signal) * scale, (volts - 12.0)[:, None] * slopes, rtol=1e-9)


# ----- bags ------------------------------------------------------------------------------------


@pytest.mark.parametrize('kind', ['battery_state', 'float64'])
@pytest.mark.parametrize('output', ['counts', 'imu'])
def test_simulated_supply_is_recorded_and_read_back(tmp_path, kind, output):
    """record_supply writes the voltage (BatteryState or Float64) into counts and driver bags; bagio reads it as aux."""
    scenario = replace(SHORT, plateau_hours=0.05, plateaus_celsius=(10.0, 30.0), supply_voltage_drift=1.0,
                       record_supply='/power/battery_state', record_supply_type=kind, output=output)
    path = tmp_path / 'run.mcap'
    (tmp_path / 'scenario.yaml').write_text(yaml.safe_dump({
        'plateau_hours': 0.05, 'plateaus_celsius': [10.0, 30.0], 'supply_voltage_drift': 1.0,
        'record_supply': '/power/battery_state', 'record_supply_type': kind, 'output': output,
        'ramp_celsius_per_minute': SHORT.ramp_celsius_per_minute, 'board_lag_s': SHORT.board_lag_s,
        'dwell_s': SHORT.dwell_s}))
    assert cli.main(['simulate', '--scenario', str(tmp_path / 'scenario.yaml'), str(path)]) == 0
    run = simulate(scenario)
    expected_stamps, expected_volts = run.record.aux[SUPPLY]
    record = read_record(path, progress=False) if output == 'counts' else read_driver_record(path, progress=False)
    fields = ('temperature', 'current', 'charge', 'capacity', 'design_capacity', 'percentage')
    assert list(record.aux) == ([SUPPLY] if kind == 'float64' else [SUPPLY, *(f'{SUPPLY}:{f}' for f in fields)])
    stamps, volts = record.aux[SUPPLY]
    assert np.array_equal(stamps, expected_stamps)  # header stamp, or bag time = the stamp written
    assert np.array_equal(volts, expected_volts)
    assert np.all(np.abs(volts - SUPPLY_NOMINAL_VOLTS) < 5 * SUPPLY_VOLTS_RMS) and np.ptp(volts) > 0.01
    if kind == 'battery_state':
        assert np.array_equal(volts, volts.astype(np.float32).astype(float))
        assert np.all(np.isnan(record.aux[f'{SUPPLY}:current'][1]))  # unmeasured fields are NaN (REP)
    samples = align(record if output == 'counts' else record.channel('accel'))
    held = samples.aux[SUPPLY]
    index = np.searchsorted(stamps, samples.stamp_ns, side='right') - 1
    assert np.array_equal(held, volts[index])


def test_samples_before_the_first_signal_value_are_left_out_and_counted():
    """require_signals keeps the samples with a held value; the others are dropped by name."""
    run = simulate(replace(SHORT, plateau_hours=0.05, plateaus_celsius=(10.0, 30.0), record_supply='/p'))
    stamps, volts = run.record.aux['aux:/p']
    late = replace(run.record, aux={'aux:/p': (stamps[10:], volts[10:])})
    samples = align(late)
    kept = require_signals(samples, ['aux:/p'])
    assert np.all(np.isnan(samples.aux['aux:/p'][:kept.rows[0]]))
    assert kept.dropped['before_first_aux:/p'] == len(samples) - len(kept) > 0
    assert np.all(np.isfinite(kept.aux['aux:/p']))
    with pytest.raises(CalibrationError, match='aux:/q'):
        require_signals(samples, ['aux:/q'])


# ----- the loop --------------------------------------------------------------------------------


def _diagnose(bag, params, tmp_path, name) -> dict:
    out = tmp_path / f'{name}.json'
    assert cli.main(['diagnose', str(bag), '--params', str(params), '--json', str(out), '--no-progress']) == 0
    return json.loads(out.read_text())


def test_the_loop_with_a_recorded_supply_ends_at_the_floor(tmp_path, capsys):
    """`diagnose` names aux:/power/battery_state, fit adds it, diagnose says none.

    A second run's |g| is then at the floor.
    """
    scenario = replace(SHORT, seed=41, supply_voltage_drift=DRIFT, record_supply='/power/battery_state')
    (tmp_path / 'scenario.yaml').write_text(yaml.safe_dump({
        'plateau_hours': SHORT.plateau_hours, 'ramp_celsius_per_minute': SHORT.ramp_celsius_per_minute,
        'board_lag_s': SHORT.board_lag_s, 'dwell_s': SHORT.dwell_s, 'supply_voltage_drift': DRIFT,
        'record_supply': '/power/battery_state'}))
    first, second = tmp_path / 'first.mcap', tmp_path / 'second.mcap'
    assert cli.main(['simulate', '--scenario', str(tmp_path / 'scenario.yaml'), '--seed', '41', str(first)]) == 0
    assert cli.main(['simulate', '--scenario', str(tmp_path / 'scenario.yaml'), '--seed', '42', str(second)]) == 0
    base, with_supply = tmp_path / 'base.yaml', tmp_path / 'supply.yaml'
    assert cli.main(['fit', str(first), '-o', str(base), '--no-progress']) == 0

    verdict = _diagnose(first, base, tmp_path, 'base')
    assert verdict['verdict'] == SUPPLY

    assert cli.main(['fit', str(first), '--effects', SUPPLY, '-o', str(with_supply), '--no-progress']) == 0
    calibration = load_unit(with_supply).accel
    (effect,) = calibration.effects
    assert effect.name == SUPPLY
    truth = supply_truth()
    samples = align(read_record(first, progress=False))
    error_counts = np.sqrt(np.mean([axis.residual_rms ** 2 for axis in calibration.axes]))
    volts = samples.aux[SUPPLY]
    slope_error = error_counts / (np.std(volts) * math.sqrt(len(volts)))  # least-squares SE of a slope
    for axis in 'xyz':
        assert effect[f'slope_{axis}'] == pytest.approx(truth[f'slope_{axis}'], abs=6.0 * slope_error)
    assert effect['tau_s'] < 5 * 5.0  # no lag beyond the 5 s the voltage is sampled at

    again = _diagnose(first, with_supply, tmp_path, 'again')
    assert again['verdict'] == 'none'

    # The |g| floor: the second run corrected with the true link, the supply term included.
    second_samples = align(read_record(second, progress=False))
    true_link = replace(scenario.truth(), effects=(aux_effect_class(SUPPLY)(**truth),))
    floor = validate_gravity(true_link, second_samples.counts, second_samples.temp_code,
                             stamp_s=second_samples.stamp_s, aux=second_samples.aux).after.rms
    capsys.readouterr()
    out = tmp_path / 'validate.json'
    assert cli.main(['validate', str(second), '--params', str(with_supply), '--json', str(out)]) == 0
    fitted = json.loads(out.read_text())['after']['rms']
    out_base = tmp_path / 'validate_base.json'
    assert cli.main(['validate', str(second), '--params', str(base), '--json', str(out_base)]) == 0
    without = json.loads(out_base.read_text())['after']['rms']
    assert fitted <= 1.05 * floor
    assert without > 1.5 * floor  # the supply term matters on the second run


def test_a_recorded_supply_that_drives_nothing_is_tried_but_not_chosen():
    """With a warm-up hidden and the supply recorded but inert, diagnose tries aux:... and names warmup."""
    from tak_thermo_ros.core.diagnose import diagnose
    from tak_thermo_ros.core.fit import fit_model
    scenario = replace(SHORT, seed=43, record_supply='/power/battery_state',
                       effects={'warmup': {'tau_s': 1800.0, 'amplitude_x': 30.0, 'amplitude_z': -20.0}})
    samples = align(simulate(scenario).record)
    result = diagnose(fit_model(samples).calibration, samples)
    assert result.verdict == 'warmup', result.message
    tried = {candidate.effect: candidate for candidate in result.candidates}
    assert SUPPLY in tried and tried[SUPPLY].explained < tried['warmup'].explained
    assert all(SUPPLY not in step.effects for step in result.ladder)


def test_driver_bag_fits_the_supply_on_the_accelerometer_and_nothing_on_the_gyroscope(tmp_path):
    """`fit --effects / --gyro-effects aux:...` on a driver bag: accel slopes recover the truth, gyro's are ~0."""
    drift = 0.01  # m/s^2 per unit of the supply signal
    (tmp_path / 'scenario.yaml').write_text(yaml.safe_dump({
        'output': 'imu', 'plateau_hours': SHORT.plateau_hours, 'ramp_celsius_per_minute': SHORT.ramp_celsius_per_minute,
        'board_lag_s': SHORT.board_lag_s, 'dwell_s': SHORT.dwell_s, 'supply_voltage_drift': drift,
        'record_supply': '/power/battery_state', 'record_supply_type': 'float64'}))
    bag, params = tmp_path / 'run.mcap', tmp_path / 'params.yaml'
    assert cli.main(['simulate', '--scenario', str(tmp_path / 'scenario.yaml'), str(bag)]) == 0
    assert cli.main(['fit', str(bag), '--effects', SUPPLY, '--gyro-effects', SUPPLY, '-o', str(params),
                     '--no-progress']) == 0
    unit = load_unit(params)
    truth = supply_truth(drift)
    driver = read_driver_record(bag, progress=False)
    volts = align(driver.channel('accel')).aux[SUPPLY]
    accel = unit.accel.effects[0]
    for i, axis in enumerate('xyz'):
        slope_error = unit.accel.axes[i].residual_rms / (np.std(volts) * math.sqrt(len(volts)))
        assert accel[f'slope_{axis}'] == pytest.approx(truth[f'slope_{axis}'], abs=6.0 * slope_error)
    # The gyroscope sees no supply: whatever its term fits is far below its noise.
    gyro = unit.gyro.effects[0]
    samples = align(driver.channel('gyro'))
    contribution = gyro.offsets(samples.stamp_s, samples.aux[SUPPLY])
    spread = np.std(contribution, axis=0)
    assert np.all(spread < 0.1 * np.array([axis.residual_rms for axis in unit.gyro.axes]))


# ----- the online core -------------------------------------------------------------------------


def test_online_core_waits_for_holds_and_drops_a_stale_signal_like_the_temperature():
    """No value yet: waiting_for_signal; stale: held (hold) or dropped (drop); the output equals correct_sample."""
    calibration = replace(Scenario().truth(), effects=(aux_effect_class(SUPPLY)(**supply_truth()),))
    core = OnlineCompensator(calibration, temp_timeout_s=1.0)
    assert core.signals == (SUPPLY,)
    core.process_temperature(8200.0, 0.0)
    assert core.process_counts(1, 0, 10.0, 20.0, 2500.0, 0.1) == WAITING_FOR_SIGNAL
    assert core.status(0.1).value(f'signal {SUPPLY}') == 'none'
    assert core.process_signal(SUPPLY, math.nan, 0.15) is False
    assert core.process_signal(SUPPLY, 12.3, 0.2)
    got = core.process_counts(1, 500_000_000, 10.0, 20.0, 2500.0, 0.3)
    expected = Corrector(calibration).correct_sample(10.0, 20.0, 2500.0, 8200.0, stamp_s=1.5, aux={SUPPLY: 12.3})
    assert got == expected
    core.process_temperature(8200.0, 5.0)
    assert isinstance(core.process_counts(2, 0, 10.0, 20.0, 2500.0, 5.0), tuple)  # stale signal held
    status = core.status(5.0)
    assert status.level == 2 and f'{SUPPLY} stale' in status.message
    core.set_policies(stale_temperature=StaleTemperature.DROP)
    assert core.process_counts(3, 0, 10.0, 20.0, 2500.0, 5.1) == STALE_SIGNAL
    assert core.dropped[WAITING_FOR_SIGNAL] == 1 and core.dropped[STALE_SIGNAL] == 1
    assert core.signal_rejected[SUPPLY] == 1 and core.signal_messages[SUPPLY] == 2
    assert core.received == core.published + core.dropped_total()


def test_scenario_refuses_a_supply_topic_or_type_it_cannot_write():
    """record_supply must be an absolute topic without ':'; record_supply_type one of the two types."""
    from tak_thermo_ros.core.simulation.scenario import scenario_from_mapping
    from tak_thermo_ros.errors import ScenarioError
    with pytest.raises(ScenarioError, match='record_supply'):
        scenario_from_mapping({'record_supply': 'power'})
    with pytest.raises(ScenarioError, match='record_supply_type'):
        scenario_from_mapping({'record_supply': '/p', 'record_supply_type': 'int8'})
    assert simulate(replace(SHORT, plateau_hours=0.05, plateaus_celsius=(10.0, 30.0))).record.aux == {}
