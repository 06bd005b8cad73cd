"""Fitting effects: recovery of hidden effects, train masks, user-defined effects, the CLI option."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import yaml

from conftest import CREEP_MODULE
from tak_thermo_ros.cli import main
from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.effects import LIBRARY, seconds_from_ns
from tak_thermo_ros.core.fit import fit_calibration, fit_model, residual_counts
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import PROFILES, Scenario
from tak_thermo_ros.errors import FitError

# Temperature codes on every sample: the hidden effects see the true code, the fit the recorded
# one; holding a code for several samples adds a small systematic error of its own (about one
# standard error on some amplitudes) that would blur what these tests check: the noise.
RUN = Scenario(plateau_hours=0.5, ramp_celsius_per_minute=1.0, board_lag_s=300.0, dwell_s=30.0,
               sample_rate_hz=0.5, temp_code_every=1)
TRUE = {
    'thermal_lag': {'tau_s': 900.0, 'slope_x': 0.02, 'slope_z': -0.03},
    'hysteresis': {'width_codes': 60.0, 'amplitude_y': 4.0, 'amplitude_z': -3.0},
    'scale_nonlinearity': {'k2_x': 0.02, 'k2_y': -0.015, 'k2_z': 0.01},
    'cross_axis': {'c_xy': 0.5, 'c_zx': -0.4, 'c_yz': 0.3},
    'warmup': {'tau_s': 1200.0, 'amplitude_x': 15.0, 'amplitude_z': -10.0},
    'temperature_shape': {'knot_1': 8500.0, 'slope_x_1': 0.04, 'slope_y_1': -0.03},
}
CASES = [('paper', 1), ('paper', 2), ('cycle', 3)]
STANDARD_ERRORS = 4.5
"""A fitted parameter lies within this many standard errors of the truth (false alarm ~1e-5)."""


def _floor(scenario: Scenario) -> np.ndarray:
    return np.array([math.sqrt(axis.noise_counts ** 2 + 1.0 / 12.0) for axis in scenario.unit])


def _gravity_rms(calibration, samples, gravity: float) -> float:
    force = Corrector(calibration).correct(samples.counts, samples.temp_code,
                                           stamp_s=seconds_from_ns(samples.stamp_ns))
    return float(np.sqrt(np.mean((np.linalg.norm(force, axis=1) - gravity) ** 2)))


@pytest.mark.parametrize('name', list(TRUE))
@pytest.mark.parametrize(('profile', 'seed'), CASES)
def test_hidden_effect_is_recovered(name, profile, seed):
    """Fit with the hidden effect: parameters within noise, residual at the floor, |g| of a second run better."""
    scenario = replace(RUN, seed=seed, effects={name: TRUE[name]}, **PROFILES[profile])
    samples = align(simulate(scenario).record)
    base = fit_calibration(samples)
    result = fit_model(samples, effects=[name])
    effect = result.calibration.effects[0]
    assert effect.name == name

    floor = _floor(scenario)
    rms = np.array([axis.residual_rms for axis in result.axes])
    assert np.all(rms <= 1.1 * floor), (rms / floor)

    if name == 'temperature_shape':
        # Knots are placed by the fit, not at the true kink: compare the offset curves instead,
        # within five standard errors of a curve with P parameters from k samples.
        calibration = result.calibration
        codes = np.linspace(calibration.temp_code_min, calibration.temp_code_max, 300)
        zero = np.zeros((len(codes), 3))
        error = (Corrector(calibration).predict_counts(zero, codes)
                 - Corrector(scenario.truth()).predict_counts(zero, codes))
        tolerance = 5.0 * floor * np.sqrt(np.array([axis.parameters for axis in result.axes]) / len(samples))
        assert np.all(np.max(np.abs(error), axis=0) <= tolerance)
    else:
        truth = LIBRARY[name].from_values(TRUE[name], complete=False)
        for parameter, value in truth.values.items():
            error = result.parameter_errors[f'{name}.{parameter}']
            assert 0.0 < error < math.inf
            assert abs(effect[parameter] - value) <= STANDARD_ERRORS * error, \
                (parameter, effect[parameter], value, error)

    second = align(simulate(replace(scenario, seed=seed + 100)).record)
    assert _gravity_rms(result.calibration, second, scenario.gravity) < _gravity_rms(
        base.calibration, second, scenario.gravity)


def test_base_model_without_effects_is_the_plain_fit(short_samples):
    """fit_model with no effects gives what fit_calibration gives."""
    plain = fit_calibration(short_samples)
    model = fit_model(short_samples)
    assert model.calibration == plain.calibration
    assert model.axes == plain.axes


def test_parameter_count_and_bic_include_effect_parameters(short_samples):
    """Per axis: base parameters + the effect's amplitudes on that axis + its shape parameters."""
    plain = fit_calibration(short_samples)
    lag = fit_model(short_samples, effects=['thermal_lag'])
    assert [axis.parameters for axis in lag.axes] == [axis.parameters + 2 for axis in plain.axes]
    crossed = fit_model(short_samples, effects=['cross_axis'])
    # Each channel has two of the six couplings.
    assert [axis.parameters for axis in crossed.axes] == [axis.parameters + 2 for axis in plain.axes]
    # No effect hidden in this run: the extra parameters cost more than they gain.
    assert all(with_lag.bic > without.bic for with_lag, without in zip(lag.axes, plain.axes))


def test_train_mask_uses_only_training_samples_but_the_whole_series_for_memory():
    """Counts outside the mask do not move the fit; the stamps and codes there still drive the lag."""
    scenario = replace(RUN, seed=5, effects={'thermal_lag': TRUE['thermal_lag']})
    samples = align(simulate(scenario).record)
    mask = (np.arange(len(samples)) // 500) % 4 != 1
    spoiled_counts = samples.counts.copy()
    spoiled_counts[~mask] += 1000.0
    spoiled = replace(samples, counts=spoiled_counts)
    clean_fit = fit_model(samples, effects=['thermal_lag'], train_mask=mask)
    spoiled_fit = fit_model(spoiled, effects=['thermal_lag'], train_mask=mask)
    assert clean_fit.calibration == spoiled_fit.calibration
    assert clean_fit.samples == int(mask.sum())
    held_out = residual_counts(clean_fit.calibration, samples)[~mask]
    assert np.all(np.sqrt(np.mean(held_out ** 2, axis=0)) <= 1.15 * _floor(scenario))
    with pytest.raises(FitError, match='train_mask'):
        fit_model(samples, effects=['thermal_lag'], train_mask=mask[:-1])


def test_an_instance_keeps_its_shape_and_refits_amplitudes():
    """An effect given as an instance keeps tau_s; only its amplitudes are fitted."""
    scenario = replace(RUN, seed=6, effects={'warmup': TRUE['warmup']})
    samples = align(simulate(scenario).record)
    result = fit_model(samples, effects=[LIBRARY['warmup'](tau_s=1200.0)])
    effect = result.calibration.effects[0]
    assert effect['tau_s'] == 1200.0
    assert abs(effect['amplitude_x'] - 15.0) <= STANDARD_ERRORS * result.parameter_errors['warmup.amplitude_x']
    assert 'warmup.tau_s' not in result.parameter_errors


def test_an_effect_the_run_cannot_excite_is_a_fit_error():
    """One orientation only: cross-axis coupling cannot be told from the offset, and the error says so."""
    scenario = replace(RUN, plateau_hours=0.3, positions=((0.0, 0.0, 1.0),), seed=7)
    samples = align(simulate(scenario).record)
    with pytest.raises(FitError, match='cross_axis'):
        fit_model(samples, effects=['cross_axis'], nominal_scale=scenario.nominal_scale)
    with pytest.raises(FitError, match="'lag': unknown"):
        fit_model(samples, effects=['lag'], nominal_scale=scenario.nominal_scale)


def test_user_defined_effect_through_the_command_line(tmp_path, monkeypatch, capsys):
    """tak_calib fit --effects module:Class fits a user effect, stores its class, and validate reads it."""
    (tmp_path / 'user_creep.py').write_text(CREEP_MODULE)
    monkeypatch.chdir(tmp_path)
    scenario = replace(RUN, seed=8, sample_rate_hz=0.2, effects={'user_creep:Creep': {'rate_z': 2.0}})
    (tmp_path / 'scenario.yaml').write_text(yaml.safe_dump({
        'seed': 8, 'sample_rate_hz': 0.2, 'plateau_hours': 0.5, 'ramp_celsius_per_minute': 1.0,
        'board_lag_s': 300.0, 'dwell_s': 30.0, 'temp_code_every': 1,
        'effects': {'user_creep:Creep': {'rate_z': 2.0}}}))
    assert main(['simulate', 'run', '--scenario', 'scenario.yaml', '--no-progress']) == 0
    assert main(['fit', 'run', '-o', 'params.yaml', '--effects', 'user_creep:Creep', '--no-progress']) == 0
    output = capsys.readouterr().out
    assert 'effect creep: rate_x' in output
    entry = yaml.safe_load((tmp_path / 'params.yaml').read_text())[
        '/**/compensator']['ros__parameters']['calibration']['effects']['creep']
    assert entry['class'] == 'user_creep:Creep'
    samples = align(simulate(scenario).record)
    result = fit_model(samples, effects=['user_creep:Creep'])
    assert abs(entry['rate_z'] - 2.0) <= STANDARD_ERRORS * result.parameter_errors['creep.rate_z']
    assert main(['validate', 'run', '--params', 'params.yaml', '--no-progress']) == 0
    with pytest.raises(SystemExit) as stop:  # refused where the option is parsed, before the bag is read
        main(['fit', 'run', '-o', 'bad.yaml', '--effects', 'user_creep:Nothing', '--no-progress'])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "argument --effects: effect 'user_creep:Nothing': module user_creep has no Nothing" in err
