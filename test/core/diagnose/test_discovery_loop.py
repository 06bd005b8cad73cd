"""The user's loop (diagnose, add the named effect, refit, diagnose again) and per-axis effects.

Each loop runs on a short simulated run with hidden effects; a second run of the same unit
(another noise seed) checks that the final calibration brings the |g| error to what the true
calibration gives on that run (the floor).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from conftest import SHORT
from conftest import noise_floor as noise_floor_of
from tak_thermo_ros.formats.calibration_file import (
    calibration_from_mapping,
    calibration_to_mapping,
    flatten_parameters,
)
from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.diagnose import ModelScore, design_files, design_run, diagnose
from tak_thermo_ros.core.diagnose.crossval import paired_block_t
from tak_thermo_ros.core.diagnose.verdict import per_axis_t_threshold
from tak_thermo_ros.core.effects import PER_AXIS, resolve_effect
from tak_thermo_ros.core.fit import fit_model, residual_counts
from tak_thermo_ros.core.records.record import AlignedSamples, align
from tak_thermo_ros.core.simulation.imu import chamber_profile, simulate
from tak_thermo_ros.core.simulation.scenario import PROFILES, Scenario
from tak_thermo_ros.formats.files import write_texts
from tak_thermo_ros.formats.scenario import load_scenario
from tak_thermo_ros.core.link.validate import validate_gravity
from tak_thermo_ros.errors import FitError

RATE_HZ = 0.1
"""About 2100 samples on the cycle profile: the loop's diagnoses stay at seconds of CPU each."""
MAX_STEPS = 4
MAX_CV_SAMPLES = 1100
"""The cross-validation fits use every second sample (the floor and the views use all)."""

WARMUP_AND_HYSTERESIS = {
    'warmup': {'tau_s': 1200.0, 'amplitude_x': 12.0, 'amplitude_y': -9.0, 'amplitude_z': 15.0},
    'hysteresis': {'width_codes': 40.0, 'amplitude_x': 3.0, 'amplitude_y': -2.5, 'amplitude_z': 2.0},
}
PER_AXIS_LAG = {
    'thermal_lag_per_axis': {'tau_s_x': 600.0, 'tau_s_y': 1800.0, 'tau_s_z': 3600.0,
                             'slope_x': 0.04, 'slope_y': -0.04, 'slope_z': 0.05},
}


def _scenario(effects: dict, seed: int) -> Scenario:
    return replace(SHORT, sample_rate_hz=RATE_HZ, seed=seed, effects=effects, **PROFILES['cycle'])


def run_loop(samples: AlignedSamples) -> tuple[list[str], list[str], object]:
    """Diagnose, add (or, for a per-axis form, swap in) the named effect, refit, until done.

    :returns: the verdicts in order, the effects of the final model, and its fit result.
    """
    effects: list[str] = []
    verdicts: list[str] = []
    result = fit_model(samples)
    for _ in range(MAX_STEPS):
        verdict = diagnose(result.calibration, samples, max_cv_samples=MAX_CV_SAMPLES).verdict
        verdicts.append(verdict)
        if verdict in ('none', 'unexplained'):
            break
        shared = getattr(resolve_effect(verdict), 'shared', None)
        if shared is not None and shared.name in effects:
            effects[effects.index(shared.name)] = verdict
        else:
            effects.append(verdict)
        result = fit_model(samples, effects=effects)
    return verdicts, effects, result


def assert_gravity_at_the_floor(scenario: Scenario, calibration, truth, samples_used: int, parameters: int) -> None:
    """|g| RMS of a second run with the loop's calibration within what estimated parameters cost.

    A least-squares model with ``p`` parameters per axis fitted on ``n`` samples predicts new
    data with variance ``sigma^2 (1 + p / n)``; five times that inflation is the tolerance.
    """
    second = align(simulate(replace(scenario, seed=scenario.seed + 100)).record)
    stamps = second.stamp_s
    found = validate_gravity(calibration, second.counts, second.temp_code, stamp_s=stamps).after.rms
    floor = validate_gravity(truth, second.counts, second.temp_code, stamp_s=stamps).after.rms
    assert found <= floor * math.sqrt(1.0 + 5.0 * parameters / samples_used), (found, floor)


def test_loop_on_warmup_plus_hysteresis_ends_on_none_with_only_the_true_effects():
    """Two hidden effects: the loop names both (a lag that mimics both is not kept) and ends 'none'."""
    scenario = _scenario(WARMUP_AND_HYSTERESIS, seed=3)
    run = simulate(scenario)
    samples = align(run.record)
    verdicts, effects, result = run_loop(samples)
    assert verdicts[-1] == 'none', verdicts
    assert sorted(effects) == ['hysteresis', 'warmup'], verdicts
    rms = np.sqrt(np.mean(residual_counts(result.calibration, samples) ** 2, axis=0))
    assert np.all(rms <= 1.05 * noise_floor_of(scenario)), rms
    assert_gravity_at_the_floor(scenario, result.calibration, run.truth, len(samples), parameters=7 + 4)


def test_loop_on_per_axis_time_constants_chooses_the_per_axis_lag_and_recovers_the_taus():
    """Per-axis lag: the per-axis form is the verdict, the loop ends 'none', each tau within 5 sigma."""
    scenario = _scenario(PER_AXIS_LAG, seed=5)
    run = simulate(scenario)
    samples = align(run.record)
    verdicts, effects, result = run_loop(samples)
    assert verdicts[-1] == 'none', verdicts
    assert effects == ['thermal_lag_per_axis'], verdicts
    fitted = result.calibration.effects[0]
    for axis in 'xyz':
        name = f'tau_s_{axis}'
        sigma = result.parameter_errors[f'thermal_lag_per_axis.{name}']
        truth = PER_AXIS_LAG['thermal_lag_per_axis'][name]
        assert abs(fitted[name] - truth) <= 5.0 * sigma, (name, fitted[name], truth, sigma)
        assert sigma < 0.1 * truth
    assert_gravity_at_the_floor(scenario, result.calibration, run.truth, len(samples), parameters=7 + 2)


# ------------------------------------------------------------------------- per-axis effects

def test_per_axis_lag_is_refused_when_the_axes_share_one_time_constant_and_taken_when_they_do_not():
    """The per-axis form costs two parameters.

    With equal time constants it gains nothing the held-out blocks can see and the shared lag is the verdict; with
    time constants a factor 2 apart it wins.
    """
    slopes = {f'slope_{a}': PER_AXIS_LAG['thermal_lag_per_axis'][f'slope_{a}'] for a in 'xyz'}
    equal = {'thermal_lag_per_axis': {**slopes, 'tau_s_x': 1800.0, 'tau_s_y': 1800.0, 'tau_s_z': 1800.0}}
    apart = {'thermal_lag_per_axis': {**slopes, 'tau_s_x': 1800.0, 'tau_s_y': 900.0, 'tau_s_z': 3600.0}}
    verdicts = {}
    for label, effects in (('equal', equal), ('apart', apart)):
        samples = align(simulate(_scenario(effects, seed=11)).record)
        result = diagnose(fit_model(samples).calibration, samples, candidates=['thermal_lag'],
                          max_cv_samples=MAX_CV_SAMPLES)
        assert [c.effect for c in result.per_axis_forms] == ['thermal_lag_per_axis'], result.message
        verdicts[label] = result.verdict
    assert verdicts == {'equal': 'thermal_lag', 'apart': 'thermal_lag_per_axis'}


def test_paired_block_t_is_large_for_a_gain_on_every_block_and_about_one_for_a_gain_on_one_block():
    """The block-to-block spread is the margin.

    A steady gain stands out, a gain confined to one block (a warm-up that decays inside it) cannot, however large, so
    the per-axis rule needs the floor test.
    """
    rng = np.random.default_rng(2)
    count = np.full(24, 100.0)
    shared_sse = 100.0 * (1.0 + 0.05 * rng.standard_normal((24, 3)))
    steady = shared_sse - 20.0
    local = shared_sse.copy()
    local[0] -= 5000.0

    def score(sse: np.ndarray) -> ModelScore:
        return ModelScore(effects=(), fold_sse=np.zeros((5, 3)), fold_samples=np.ones(5), block_sse=sse,
                          block_samples=count)

    assert np.all(paired_block_t(score(shared_sse), score(steady)) > 10.0)
    assert np.all(np.abs(paired_block_t(score(shared_sse), score(local)) - 1.0) < 0.05)
    assert per_axis_t_threshold(24) == pytest.approx(2.98, abs=0.01)


def test_per_axis_warmup_decaying_inside_the_first_block_is_named():
    """Warm-ups of 7 minutes on y, 20 on x and an hour on z on a 6-hour run (18-minute blocks) are named.

    Every fold holds a piece of the first block, and the per-axis form, which brings every axis to the
    floor, is the verdict although its gain over the shared form, confined to the first blocks, gives no
    large paired t.
    """
    effects = {'warmup_per_axis': {'tau_s_x': 1200.0, 'tau_s_y': 400.0, 'tau_s_z': 3600.0,
                                   'amplitude_x': 15.0, 'amplitude_y': -15.0, 'amplitude_z': 12.0}}
    samples = align(simulate(_scenario(effects, seed=12)).record)
    result = diagnose(fit_model(samples).calibration, samples, candidates=['warmup'],
                      max_cv_samples=MAX_CV_SAMPLES)
    assert result.verdict == 'warmup_per_axis', result.message
    assert not any(a.excess_significant for a in diagnose(result.calibration_after, samples, candidates=['warmup'],
                                                          max_cv_samples=MAX_CV_SAMPLES).axes)


@pytest.mark.parametrize('name', sorted(PER_AXIS))
def test_per_axis_form_equals_the_shared_form_per_axis_and_both_paths_agree(name):
    """Axis i of the per-axis form is the shared effect with axis i's shape; step and series agree bit for bit."""
    cls = PER_AXIS[name]
    shared = cls.shared
    shape = [spec.name for spec in shared.shape][0]
    low, high = {'tau_s': (300.0, 3000.0), 'width_codes': (10.0, 60.0)}[shape]
    values = {f'{shape}_x': low, f'{shape}_y': math.sqrt(low * high), f'{shape}_z': high,
              **{f'{cls.amplitude.name}_{a}': v for a, v in zip('xyz', (1.5, -2.0, 0.5))}}
    effect = cls(**values)
    rng = np.random.default_rng(3)
    stamps = 1000.0 + np.cumsum(rng.uniform(0.5, 1.5, 4000))
    codes = np.round(np.cumsum(rng.normal(0.0, 2.0, 4000)))
    offsets = effect.offsets(stamps, codes)
    for i, axis in enumerate('xyz'):
        amplitude = f'{cls.amplitude.name}_{axis}'
        alone = shared(**{shape: values[f'{shape}_{axis}'], amplitude: values[amplitude]})
        np.testing.assert_array_equal(offsets[:, i], alone.offsets(stamps, codes)[:, i])
    state = effect.start(stamps[0], codes[0])
    rows = []
    for stamp, code in zip(stamps, codes):
        state, row = effect.step(state, stamp, code)
        rows.append(row)
    np.testing.assert_array_equal(np.array(rows), effect.basis(stamps, codes))


def test_per_axis_effect_round_trips_the_file_as_flat_ros_parameters_and_corrects_sample_by_sample():
    """The per-axis form lives under calibration.effects.<name>.<param> (valid ROS names) like any effect."""
    scenario = _scenario(PER_AXIS_LAG, seed=7)
    run = simulate(replace(scenario, plateaus_celsius=scenario.plateaus_celsius[:2]))
    truth = run.truth
    flat = flatten_parameters(calibration_to_mapping(truth))
    assert flat['calibration.effects.thermal_lag_per_axis.tau_s_y'] == 1800.0
    assert all(part.replace('_', '').isalnum() for key in flat for part in key.split('.'))
    again = calibration_from_mapping(calibration_to_mapping(truth))
    assert again.effects == truth.effects
    samples = align(run.record)
    corrector = Corrector(again)
    series = corrector.correct(samples.counts, samples.temp_code, stamp_s=samples.stamp_s)
    online = Corrector(again)
    one_by_one = np.array([online.correct_sample(*row, code, stamp_s=stamp) for row, code, stamp in
                           zip(samples.counts.tolist(), samples.temp_code.tolist(), samples.stamp_s.tolist())])
    np.testing.assert_array_equal(series, one_by_one)


def test_fit_rejects_the_shared_and_the_per_axis_form_together(short_samples):
    """Both forms at once are the same physics twice: a one-line error naming both."""
    with pytest.raises(FitError, match='thermal_lag.*thermal_lag_per_axis|thermal_lag_per_axis.*thermal_lag'):
        fit_model(short_samples, effects=['thermal_lag', 'thermal_lag_per_axis'])


# ------------------------------------------------------------------------- experiment design

def test_design_run_proposes_a_profile_that_separates_lag_from_hysteresis_better_than_the_run(tmp_path):
    """On the paper's staircase a lag and a hysteresis look alike.

    The proposed run separates them far better, and its files are a scenario the simulator loads and a schedule that
    follows the profile.
    """
    scenario = replace(SHORT, sample_rate_hz=RATE_HZ, seed=9,
                       effects={'thermal_lag': {'tau_s': 1500.0, 'slope_x': 0.03, 'slope_y': -0.03, 'slope_z': 0.04}})
    samples = align(simulate(scenario).record)
    result = diagnose(fit_model(samples).calibration, samples, candidates=['thermal_lag', 'hysteresis'])
    assert {c.effect for c in result.candidates[:2]} == {'thermal_lag', 'hysteresis'}
    design = design_run(result, samples)
    assert set(design.candidates) == {'thermal_lag', 'hysteresis'}
    assert design.best.separation_sigmas == max(p.separation_sigmas for p in design.tried)
    assert design.best.separation_sigmas > 2.0 * design.baseline_sigmas, design.as_dict()
    scenario_path, schedule_path, json_path = write_texts(tmp_path / 'design', design_files(design))
    proposed = load_scenario(scenario_path)
    assert proposed.duration_s() / 3600.0 == pytest.approx(design.best.hours)
    schedule = np.loadtxt(schedule_path, delimiter=',', skiprows=1)
    assert schedule[0, 0] == 0.0 and schedule[-1, 0] == pytest.approx(proposed.duration_s())
    np.testing.assert_allclose(schedule[:, 1], chamber_profile(proposed, schedule[:, 0]))
    assert set(schedule[1:, 1].round(3)) <= {round(t, 3) for t in proposed.plateaus_celsius}
