"""Model discovery: noise floor, residual views, and verdicts on runs with a hidden effect."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from conftest import SHORT
from conftest import noise_floor as noise_floor_of
from tak_thermo_ros.core.diagnose import build_views, diagnose, explained_fraction, fold_labels, noise_floor
from tak_thermo_ros.core.effects import LIBRARY, seconds_from_ns
from tak_thermo_ros.core.fit import fit_model, residual_counts
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import PROFILES, Scenario
from tak_thermo_ros.core.link.validate import validate_gravity


@pytest.mark.parametrize('sigma', [0.6, 1.5])
def test_noise_floor_includes_code_rounding_and_ignores_slow_structure_and_jumps(sigma):
    """The floor is sqrt(sigma^2 + 1/12) although the residual holds a slow drift and turntable jumps."""
    rng = np.random.default_rng(5)
    count = 40_000
    time_s = np.arange(count, dtype=float)
    segment = time_s // 60.0
    slow = 25.0 * np.sin(2.0 * np.pi * time_s / 7200.0) + 40.0 * (segment % 7)
    residual = np.round(slow[:, None] + rng.standard_normal((count, 3)) * sigma)
    breaks = np.concatenate(([True], segment[1:] != segment[:-1]))
    floor, used = noise_floor(residual, breaks)
    expected = math.sqrt(sigma ** 2 + 1.0 / 12.0)
    tolerance = 5.0 * 0.5 * math.sqrt(3.0 / used)  # five standard errors of an RMS
    np.testing.assert_allclose(floor, expected, rtol=tolerance)
    plain = float(np.std(residual[:, 0]))
    assert plain > 10.0 * expected  # the structure is there; the floor does not see it


def test_views_find_the_plateaus_and_the_direction_they_were_reached_from():
    """On the paper's five plateaus the views find five plateaus: first cooled to, then heated to."""
    run = simulate(SHORT)
    views = build_views(align(run.record))
    assert len(views.plateaus) == len(SHORT.plateaus_celsius)
    assert [p.approach for p in views.plateaus] == [-1, 1, 1, 1, 1]
    expected = [SHORT.temp_code_ref + SHORT.codes_per_celsius * (t - SHORT.reference_celsius)
                for t in SHORT.plateaus_celsius]
    np.testing.assert_allclose([p.temp_code for p in views.plateaus], expected, atol=0.1 * SHORT.codes_per_celsius)
    heating = views.rate[views.direction == 1]
    assert np.all(heating > 0.0)
    ramp = SHORT.ramp_celsius_per_minute * SHORT.codes_per_celsius / 60.0
    assert np.max(np.abs(views.rate)) == pytest.approx(ramp, rel=0.1)


def test_explained_fraction_is_the_share_of_variance_of_the_group_means():
    """A step of height 2 in unit-variance noise explains 1/2 of the variance (eta^2 = 1 / (1 + 1))."""
    rng = np.random.default_rng(1)
    labels = np.repeat([0, 1], 50_000)
    values = np.where(labels == 1, 1.0, -1.0) + rng.standard_normal(labels.size)
    assert explained_fraction(values, labels) == pytest.approx(0.5, abs=0.01)
    assert explained_fraction(rng.standard_normal(labels.size), labels) < 1e-3


def test_folds_deal_contiguous_blocks_round_robin():
    """Every fold holds blocks from the start, middle and end of the run, each contiguous.

    The first block is cut into one piece per fold, so every fold holds a piece of the first 5 %.
    """
    time_s = np.arange(10_000, dtype=float)
    labels = fold_labels(time_s, 5, 20)
    assert np.bincount(labels).tolist() == [1600] + [2100] * 4
    changes = np.count_nonzero(np.diff(labels))
    assert changes == 19 + 4
    for fold in range(5):
        where = np.flatnonzero(labels == fold)
        assert where.min() < 500 and where.max() > 7500
    whole = fold_labels(time_s, 5, 20, split_start=False)
    assert np.bincount(whole).tolist() == [2000] * 5
    assert np.count_nonzero(np.diff(whole)) == 19


# ------------------------------------------------------------------ verdicts on hidden effects

RATE_HZ = 0.25
"""Low sample rate keeps each run at 3-5k samples (seconds of CPU); the bench runs 0.5 Hz."""


def _scenario(profile: str, seed: int) -> Scenario:
    return replace(SHORT, sample_rate_hz=RATE_HZ, seed=seed, **PROFILES[profile])


def _code_range(scenario: Scenario) -> tuple[float, float]:
    temps = (scenario.start_celsius, *scenario.plateaus_celsius)
    return tuple(scenario.temp_code_ref + scenario.codes_per_celsius * (t - scenario.reference_celsius)
                 for t in (min(temps), max(temps)))  # type: ignore[return-value]


def hidden_effect(name: str, seed: int, codes: tuple[float, float],
                  stamps: tuple[float, float] = (0.0, 1.0)) -> dict[str, float]:
    """True parameters of a hidden effect, drawn per seed: sizes and signs vary, not tuned to one.

    ``stamps``: the run's first and last stamps, s (a step's moment).
    """
    rng = np.random.default_rng(1000 + seed)

    def signed(low: float, high: float) -> float:
        return float(rng.choice([-1.0, 1.0]) * rng.uniform(low, high))

    draws = {
        'thermal_lag': lambda: {'tau_s': float(rng.uniform(900.0, 2700.0)),
                                **{f'slope_{a}': signed(0.02, 0.05) for a in 'xyz'}},
        'hysteresis': lambda: {'width_codes': float(rng.uniform(20.0, 80.0)),
                               **{f'amplitude_{a}': signed(2.0, 4.0) for a in 'xyz'}},
        'scale_nonlinearity': lambda: {f'k2_{a}': signed(0.02, 0.04) for a in 'xyz'},
        'cross_axis': lambda: {f'c_{i}{j}': signed(0.4, 1.0) for i in 'xyz' for j in 'xyz' if i != j},
        'warmup': lambda: {'tau_s': float(rng.uniform(600.0, 2400.0)),
                           **{f'amplitude_{a}': signed(8.0, 20.0) for a in 'xyz'}},
        'temperature_shape': lambda: {
            'knot_1': round(float(rng.uniform(codes[0] + 0.3 * (codes[1] - codes[0]),
                                              codes[0] + 0.7 * (codes[1] - codes[0])))),
            **{f'slope_{a}_1': signed(0.04, 0.08) for a in 'xyz'}},
        'step': lambda: {'origin_s': stamps[0], 'at_s': float(rng.uniform(0.2, 0.8)) * (stamps[1] - stamps[0]),
                         **{f'amplitude_{a}': signed(3.0, 6.0) for a in 'xyz'}},
    }
    return draws[name]()


CASES = [(name, profile, seed) for index, name in enumerate(LIBRARY)
         for profile, seed in (('paper', 2 * index + 1), ('cycle', 2 * index + 2))]
"""Every library effect on two temperature profiles, each with its own seed and parameters."""


@pytest.mark.parametrize(('effect', 'profile', 'seed'), CASES)
def test_diagnose_names_the_hidden_effect_and_adding_it_brings_the_floor(effect, profile, seed):
    """The verdict names the hidden effect; the refit reaches 1.1x the floor; |g| of a second run falls."""
    scenario = _scenario(profile, seed)
    stamps = seconds_from_ns(simulate(scenario).record.counts_stamp_ns[[0, -1]]) if effect == 'step' else (0.0, 1.0)
    scenario = replace(scenario, effects={effect: hidden_effect(effect, seed, _code_range(scenario),
                                                                (float(stamps[0]), float(stamps[1])))})
    samples = align(simulate(scenario).record)
    base = fit_model(samples)
    result = diagnose(base.calibration, samples)
    assert result.verdict == effect, result.message
    assert result.candidates[0].effect == effect
    assert any(a.excess_significant for a in result.axes)

    floor = noise_floor_of(scenario)
    np.testing.assert_allclose(result.noise_floor, floor, rtol=5.0 * 0.5 * math.sqrt(3.0 / len(samples)))
    refit = fit_model(samples, effects=[effect])
    rms = np.sqrt(np.mean(residual_counts(refit.calibration, samples) ** 2, axis=0))
    assert np.all(rms <= 1.1 * floor), rms / floor

    second = align(simulate(replace(scenario, seed=seed + 100)).record)
    stamps = seconds_from_ns(second.stamp_ns)
    before = validate_gravity(base.calibration, second.counts, second.temp_code, stamp_s=stamps).after.rms
    after = validate_gravity(refit.calibration, second.counts, second.temp_code, stamp_s=stamps).after.rms
    assert after < before


@pytest.mark.parametrize(('profile', 'seed'), [('paper', 31), ('cycle', 32)])
def test_diagnose_raises_no_false_alarm_on_a_run_without_hidden_effect(profile, seed):
    """The base model of a plain run is at the floor: the verdict is 'none'."""
    scenario = _scenario(profile, seed)
    samples = align(simulate(scenario).record)
    result = diagnose(fit_model(samples).calibration, samples)
    assert result.verdict == 'none', result.message
    assert not any(a.excess_significant for a in result.axes)
    for axis, floor in zip(result.axes, noise_floor_of(scenario)):
        assert axis.heldout_rms <= (1.0 + 5.0 * 0.5 * math.sqrt(2.0 / len(samples))) * floor


@pytest.mark.parametrize(('profile', 'seed'), [('paper', 41), ('cycle', 42)])
def test_diagnose_calls_a_drift_from_the_unobserved_supply_voltage_unexplained(profile, seed):
    """A drift that follows a quantity missing from the bag is 'unexplained' and follows time."""
    scenario = replace(_scenario(profile, seed), supply_voltage_drift=3.0)
    samples = align(simulate(scenario).record)
    result = diagnose(fit_model(samples).calibration, samples)
    assert result.verdict == 'unexplained', result.message
    assert result.drivers[0].name == 'time'
    assert 'not in the bag' in result.message
    document = result.as_dict()
    assert set(document['axes']) == {'x', 'y', 'z'}
    assert all(set(c['rms_after']) == {'x', 'y', 'z'} for c in document['candidates'])


RIPPLE_MODULE = '''
import math
from tak_thermo_ros.core.effects import Effect, ParameterSpec


class Ripple(Effect):
    """An offset that follows a 40-minute cycle of the building's air conditioning."""

    name = 'ripple'
    summary = 'The offset follows the 40-minute cycle of the air conditioning, not the board temperature.'
    confirm = 'Log the air conditioning: the offset moves with its cycle at constant board temperature.'
    needs_stamps = True
    amplitude = ParameterSpec('amplitude', 0.0, -100.0, 100.0, 'counts')

    def start(self, stamp_s, temp_code):
        return stamp_s

    def step(self, state, stamp_s, temp_code):
        return state, (math.sin(2.0 * math.pi * (stamp_s - state) / 2400.0),)
'''


def test_diagnose_tries_a_user_defined_effect_and_names_it(tmp_path, monkeypatch):
    """A user's effect named as a candidate explains what the library calls 'unexplained'."""
    (tmp_path / 'ripple_effect.py').write_text(RIPPLE_MODULE, encoding='utf-8')
    monkeypatch.syspath_prepend(str(tmp_path))
    hidden = {'amplitude_x': 2.5, 'amplitude_y': -2.0, 'amplitude_z': 3.0}
    scenario = replace(_scenario('paper', 51), effects={'ripple_effect:Ripple': hidden})
    samples = align(simulate(scenario).record)
    base = fit_model(samples).calibration
    library_only = diagnose(base, samples)
    assert library_only.verdict == 'unexplained', library_only.message
    with_user = diagnose(base, samples, candidates=[*LIBRARY, 'ripple_effect:Ripple'])
    assert with_user.verdict == 'ripple', with_user.message
    assert with_user.candidates[0].confirm.startswith('Log the air conditioning')
    assert with_user.ladder[-1].effects == ('ripple',)
    assert np.all(np.array(with_user.ladder[-1].heldout_rms) <= 1.1 * noise_floor_of(scenario))


def test_noise_floor_rejects_glitches_in_a_drivers_si_units():
    """Isolated spikes in rad/s are left out as in codes: the floor stays at the white noise.

    The jump limit's least spread of half a code would reject nothing in rad/s; with
    ``least_spread=0`` (what diagnose uses for a driver's values) 30 spikes of 0.05 rad/s in
    6000 samples of 0.8 mrad/s noise leave the floor within its own statistical error.
    """
    rng = np.random.default_rng(8)
    sigma = 0.0008
    residual = rng.standard_normal((6000, 3)) * sigma
    residual[rng.choice(6000, size=30, replace=False), 0] += 0.05
    floor, used = noise_floor(residual, least_spread=0.0)
    tolerance = 5.0 * sigma * np.sqrt(3.0 / used) / 2.0  # five standard errors of the floor
    np.testing.assert_allclose(floor, sigma, atol=tolerance)
    inflated, _ = noise_floor(residual)  # the counts default rejects nothing here
    assert inflated[0] > 3.0 * sigma


def test_a_reason_every_failed_fold_gives_is_said_once():
    """``not tried`` lines name the folds and say a shared reason once, different reasons each."""
    from tak_thermo_ros.core.diagnose.crossval import _joined_failures
    reason = 'axis x: this run does not excite cross_axis (c_xz) (no fit)'
    assert _joined_failures([f'fold {k}: {reason}' for k in (1, 2, 3)]) == f'folds 1, 2, 3: {reason}'
    assert _joined_failures(['fold 2: a', 'fold 4: b']) == 'fold 2: a; fold 4: b'
