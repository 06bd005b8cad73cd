"""Issue 31, item 4: a sudden level change is found and named as a step, not as a slow drift.

The scan (``core/records/steps.py``) against coloured noise (white, bias instability, random walk)
over seeds: no step where there is none; a step where there is one, its moment and size within
what the noise allows. The ``step`` effect fitted on simulated truth. The real thermal cycle: the
step at 17.03 min (-10.4 C) named on both sensors.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from conftest import EXAMPLES, SHORT
from paths import REPO
from tak_thermo_ros import cli
from tak_thermo_ros.core.effects import LIBRARY
from tak_thermo_ros.core.fit import fit_model, residual_counts
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.records.steps import STEP_SIGMAS, _line_ends, change_at, despiked, find_steps
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.noise import bias_wander

REAL = REPO / 'data' / 'tofupilot-imu-thermal' / 'imu_raw_data.csv'
RATE = 2.0
WANDERS = {
    'white': (0.0, 0.0),
    'bias instability': (0.5, 0.0),
    'random walk': (0.0, 0.1),
    'random walk, strong': (0.0, 1.0),
    'both': (0.5, 0.2),
}
"""Per case, the bias instability and the random walk (per sqrt(s)) beside a white noise of 1 per sample."""


def coloured(seed: int, count: int, instability: float, walk: float) -> np.ndarray:
    """``(count, 3)`` white noise of 1 per sample plus bias instability and random walk, seeded."""
    rng = np.random.default_rng(seed)
    return rng.standard_normal((count, 3)) + bias_wander([seed, 7], count, RATE, (instability,) * 3, (60.0,) * 3,
                                                         (walk,) * 3)


def with_step(noise: np.ndarray, seed: int) -> tuple[np.ndarray, int, np.ndarray]:
    """``(stepped, index, size)``: the noise with a step on x and z from sample ``index`` on, seeded.

    ``index`` drawn in the middle three fifths; ``size`` 12 times the spread of the noise's own level
    changes over 8 samples on each side (the scan's shortest scale), +x and -z, y unchanged.
    """
    count = len(noise)
    index = int(np.random.default_rng(seed).integers(count // 5, 4 * count // 5))
    change = _line_ends(noise, 8)[1]
    spread = 1.4826 * np.median(np.abs(change - np.median(change, axis=0)), axis=0)
    size = 12.0 * spread * np.array([1.0, 0.0, -1.0])
    return noise + size * (np.arange(count) >= index)[:, None], index, size


@pytest.mark.parametrize('case', list(WANDERS))
def test_no_step_is_found_in_coloured_noise_over_seeds(case):
    """12 seeds x 3 channels of 4000 samples per case: no step (bench/bench_steps.py: 500 seeds per case)."""
    instability, walk = WANDERS[case]
    found = [find_steps(coloured(seed, 4000, instability, walk)) for seed in range(12)]
    assert sum(len(steps) for steps in found) == 0


@pytest.mark.parametrize('case', list(WANDERS))
def test_a_step_in_coloured_noise_is_found_where_and_as_large_as_it_is(case):
    """A step on two channels at once: found at its sample, its size within 4 of its sigmas.

    Its size: 12 times the spread of the noise's own level changes over 8 samples on each side
    (the scan's shortest scale): 3 per-sample sigmas of white noise, 7 under the strong random walk.
    """
    instability, walk = WANDERS[case]
    for seed in range(3):
        stepped, index, size = with_step(coloured(100 + seed, 4000, instability, walk), seed)
        steps = find_steps(stepped)
        assert len(steps) >= 1
        step = steps[0]
        assert abs(step.index - index) <= 2
        assert np.all(np.abs(step.amplitude - size) < 4.0 * step.sigma)
        assert set(step.named) == {0, 2}


def test_a_warm_up_a_lag_and_a_spike_are_not_steps():
    """The residual of a missed warm-up or lag bends; an outlier is one sample: none is a step."""
    for effect in ('warmup', 'thermal_lag', 'hysteresis'):
        scenario = replace(SHORT, sample_rate_hz=0.5, effects={effect: {
            'warmup': {'tau_s': 300.0, 'amplitude_x': 40.0, 'amplitude_z': -30.0},
            'thermal_lag': {'tau_s': 300.0, 'slope_x': 0.3, 'slope_z': -0.3},
            'hysteresis': {'width_codes': 30.0, 'amplitude_y': 8.0, 'amplitude_z': -6.0}}[effect]})
        samples = align(simulate(scenario).record)
        residual = residual_counts(fit_model(samples).calibration, samples)
        assert find_steps(residual) == (), effect
    noise = coloured(3, 3000, 0.0, 0.0)
    noise[1500] += 40.0
    noise[0] -= 40.0
    assert find_steps(noise) == ()
    assert np.max(np.abs(despiked(noise))) < 6.0


def test_the_step_effect_recovers_the_moment_and_the_sizes():
    """A hidden step in a chamber run: the fitted moment between the same two samples, sizes within 4 errors."""
    scenario = replace(SHORT, sample_rate_hz=0.5, plateaus_celsius=(10.0, 30.0), plateau_hours=0.5)
    first = scenario.start_time_s  # the first sample's stamp
    truth = {'origin_s': first, 'at_s': 2345.6, 'amplitude_x': 5.0, 'amplitude_y': 0.0, 'amplitude_z': -4.0}
    samples = align(simulate(replace(scenario, effects={'step': truth})).record)
    result = fit_model(samples, effects=['step'])
    (step,) = result.calibration.effects
    assert step['origin_s'] == first
    fitted_basis = step.basis(samples.stamp_s, samples.temp_code)
    true_basis = LIBRARY['step'](**truth).basis(samples.stamp_s, samples.temp_code)
    assert np.array_equal(fitted_basis, true_basis)
    for axis in 'xyz':
        error = result.parameter_errors[f'step.amplitude_{axis}']
        assert abs(step[f'amplitude_{axis}'] - truth[f'amplitude_{axis}']) < 4.0 * error
        assert error < 0.5  # counts: the sizes are resolved
    rms = np.sqrt(np.mean(residual_counts(result.calibration, samples) ** 2, axis=0))
    floor = np.array([math.sqrt(a.noise_counts ** 2 + 1.0 / 12.0) for a in scenario.unit])
    assert np.all(rms < 1.1 * floor)


def test_the_step_example_applies_at_its_stamp():
    """The library's step is 0 before origin_s + at_s and 1 from it on, per sample as over a series."""
    step = LIBRARY['step'](**EXAMPLES['step'])
    stamps = step.stamp_s + np.array([-1.0, -1e-3, 0.0, 1e-3, 1.0])
    assert step.basis(stamps, np.zeros(5)).ravel().tolist() == [0.0, 0.0, 1.0, 1.0, 1.0]
    assert [step.step(None, s, 0.0)[1][0] for s in stamps.tolist()] == [0.0, 0.0, 1.0, 1.0, 1.0]


@pytest.fixture(scope='module')
def real_driver(tmp_path_factory):
    root = tmp_path_factory.mktemp('real_steps')
    assert cli.main(['import-csv', str(REAL), '-o', str(root / 'real_driver'), '--time-unit', 'us',
                     '--acc-columns', 'imu.acc.x', 'imu.acc.y', 'imu.acc.z', '--temp-column', 'imu.temperature',
                     '--gyro-columns', 'imu.gyro.x', 'imu.gyro.y', 'imu.gyro.z']) == 0
    assert cli.main(['fit', str(root / 'real_driver'), '-o', str(root / 'base.yaml'), '--no-progress']) == 0
    return root


def test_the_step_at_17_min_of_the_real_cycle_is_named_on_both_sensors(real_driver, capsys):
    """Diagnose names the step at 17.03 min (-10.4 C): gyro x up, accel z down, in one line, not a slow drift."""
    capsys.readouterr()
    assert cli.main(['diagnose', str(real_driver / 'real_driver'), '--params', str(real_driver / 'base.yaml'),
                     '--candidates', 'step', '--no-progress', '--json', str(real_driver / 'steps.json')]) == 0
    printed = capsys.readouterr().out
    line = next(line for line in printed.splitlines() if line.startswith('step: at 17.03 min (-10.4 C): '))
    assert 'gyro x +0.0022' in line and 'accel z -0.03' in line
    import json
    document = json.loads((real_driver / 'steps.json').read_text())
    for sensor, axis, sign in (('gyro', 'x', 1.0), ('accel', 'z', -1.0)):
        steps = document['sensors'][sensor]['steps']
        step = next(s for s in steps if abs(s['time_s'] - 1021.8) < 1.0)
        assert axis in step['axes'] and sign * step['change'][axis] > STEP_SIGMAS * step['sigma'][axis]
        assert step['temperature'] == pytest.approx(-10.4, abs=0.05)
    assert 'The residual steps: a step at 17.03 min (-10.4 C)' in ' '.join(printed.split())


def test_the_step_effect_on_the_real_cycle_is_placed_at_17_min(real_driver):
    """Fit --effects step --gyro-effects step: both sensors' step at the sample of 17.03 min."""
    from tak_thermo_ros.formats.calibration_file import load_unit
    params = real_driver / 'step.yaml'
    assert cli.main(['fit', str(real_driver / 'real_driver'), '-o', str(params), '--effects', 'step',
                     '--gyro-effects', 'step', '--no-progress']) == 0
    unit = load_unit(params)
    for sensor in ('accel', 'gyro'):
        (step,) = unit.sensor(sensor).effects
        assert step['at_s'] == pytest.approx(1021.8, abs=1.0)


def test_change_at_measures_another_channel_at_a_known_moment():
    noise = coloured(5, 3000, 0.0, 0.0)
    noise[1200:, 1] += 2.0
    change = change_at(noise, 1200)
    assert change.named == (1,) and abs(change.amplitude[1] - 2.0) < 4.0 * change.sigma[1]
    assert change_at(noise, 2) is None
