"""The simulator's bias instability and random walk, recovered by the Allan-variance noise model."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tak_thermo_ros.core.noise.allan import allan_variance
from tak_thermo_ros.core.noise.fit import fit_noise_model
from tak_thermo_ros.core.noise.model import FLICKER_FLOOR
from tak_thermo_ros.core.simulation.imu import sensor_wander, simulate
from tak_thermo_ros.core.simulation.scenario import scenario_from_mapping
from tak_thermo_ros.core.simulation.noise import (
    bias_instability_poles,
    bias_instability_variance,
    gauss_markov_allan_variance,
)
from tak_thermo_ros.errors import ScenarioError

RATE = 2.0
WHITE = 1.7e-4  # rad/s/sqrt(Hz): a consumer MEMS gyroscope (0.6 deg/sqrt(h))
AXIS = {'noise_counts': WHITE * math.sqrt(RATE), 'bias_instability': 4.8e-5,  # 10 deg/h
        'bias_instability_tau': 100.0, 'random_walk': 3e-6}


def static_scenario(hours: float = 10.0):
    """A static run at constant temperature: the gyroscope's output is its offset plus its noise."""
    return scenario_from_mapping({
        'output': 'imu', 'sample_rate_hz': RATE, 'plateaus_celsius': [20.0], 'plateau_hours': hours,
        'positions': [[0.0, 0.0, 1.0]],
        'gyro_unit': {'x': AXIS, 'y': {**AXIS, 'bias_instability': 2.4e-5},
                      'z': {**AXIS, 'bias_instability': 2.4e-5, 'noise_counts': 0.5 * WHITE * math.sqrt(RATE)}}})


def test_gauss_markov_sum_is_flat_at_the_bias_instability_over_two_decades():
    """The analytic Allan deviation of the simulated flicker: 0.664 B within 5 % from tau/12 to 10 tau."""
    bias, tau = 3e-5, 200.0
    variance = bias_instability_variance(bias, tau)
    taus = np.geomspace(tau / 12.0, tau * 10.0, 60)
    adev = np.sqrt(sum(gauss_markov_allan_variance(taus, variance, pole) for pole in bias_instability_poles(tau)))
    assert np.all(np.abs(adev / (FLICKER_FLOOR * bias) - 1.0) < 0.05)


def test_gauss_markov_allan_variance_matches_a_simulated_process():
    rng = np.random.default_rng(4)
    pole, rate, count = 20.0, 10.0, 400_000
    decay = math.exp(-1.0 / (rate * pole))
    from scipy.signal import lfilter
    drive = rng.standard_normal(count) * math.sqrt(1.0 - decay ** 2)
    process = lfilter([1.0], [1.0, -decay], drive, zi=[decay * rng.standard_normal()])[0]
    result = allan_variance(process, rate, clusters=np.array([10, 100, 400, 1000]))
    assert np.allclose(result.avar[:, 0], gauss_markov_allan_variance(result.taus, 1.0, pole), rtol=0.1)


def test_fitted_noise_model_recovers_the_simulated_white_noise_bias_instability_and_random_walk():
    """Over 12 seeds of a 10 h static run at 2 Hz.

    Per seed: white density within 4 % (its short averaging times have ~1e5 degrees of freedom:
    0.5 % spread; the simulated flicker, flat only from tau/12 up, biases it 1-2 % low), bias
    instability within 25 % (its floor's averaging times hold ~100-400 degrees of freedom: 3-9 %
    spread, y axis the least visible), random walk within 40 % (its averaging times, 0.5 to 3 h,
    hold 2-15 degrees of freedom: 7-16 % spread). Mean over seeds within 10 % of the truth.
    """
    base = static_scenario()
    truth = base.noise_truth('gyro')
    ratios = []
    for seed in range(12):
        run = simulate(replace(base, seed=seed))
        fitted = fit_noise_model(allan_variance(run.driver.gyro, RATE), source='static_run')
        ratios.append([np.divide(getattr(fitted, name), getattr(truth, name))
                       for name in ('white_noise_density', 'bias_instability', 'random_walk')])
    ratios = np.array(ratios)
    assert np.all(np.abs(ratios[:, 0] - 1.0) < 0.04)
    assert np.all(np.abs(ratios[:, 1] - 1.0) < 0.25)
    assert np.all(np.abs(ratios[:, 2] - 1.0) < 0.40)
    assert np.all(np.abs(ratios.mean(axis=0) - 1.0) < 0.10)


def test_wander_draws_from_its_own_stream():
    """Adding wander to the gyroscope leaves the accelerometer and the gyroscope's white noise as they were."""
    quiet = replace(static_scenario(0.05), gyro_unit=tuple(replace(a, bias_instability=0.0, random_walk=0.0)
                                                           for a in static_scenario().gyro_unit))
    noisy = static_scenario(0.05)
    a, b = simulate(quiet).driver, simulate(noisy).driver
    assert np.array_equal(a.accel, b.accel)
    wander = sensor_wander(noisy, noisy.gyro_unit, 1, len(b.gyro))
    assert np.any(wander != 0.0)
    assert np.allclose(b.gyro - a.gyro, wander, rtol=0.0, atol=1e-15)


def test_counts_runs_carry_wander_too():
    base = scenario_from_mapping({'plateau_hours': 0.2, 'plateaus_celsius': [20.0]})
    walking = scenario_from_mapping({'unit': {'x': {'random_walk': 5.0}}}, base=base)
    a, b = simulate(base).record.counts, simulate(walking).record.counts
    assert np.array_equal(a[:, 1:], b[:, 1:]) and not np.array_equal(a[:, 0], b[:, 0])
    truth = walking.noise_truth('accel')
    assert truth.random_walk == (5.0, 0.0, 0.0) and truth.white_noise_density[0] == pytest.approx(1.5)


@pytest.mark.parametrize(('raw', 'match'), [
    ({'gyro_unit': {'x': {'bias_instability': -1.0}}}, 'gyro_unit.*.bias_instability'),
    ({'accel_unit': {'y': {'random_walk': math.inf}}}, 'accel_unit.*.random_walk'),
    ({'unit': {'z': {'bias_instability_tau': 0.0}}}, 'unit.*.bias_instability_tau'),
    ({'gyro_unit': {'x': {'flicker': 1.0}}}, 'unknown key'),
])
def test_bad_noise_keys_are_refused(raw, match):
    with pytest.raises(ScenarioError, match=match.replace('*', r'\*')):
        scenario_from_mapping(raw)
