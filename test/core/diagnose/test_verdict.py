"""Issue 16, verdicts against the sensor's noise model: simulated driver runs with bias wander.

The units wander like a consumer MEMS part (the simulator's bias instability and random walk):
gyroscope white noise 1.2e-4 rad/s/sqrt(Hz), bias instability 1.5e-5 rad/s (3 deg/h), random walk
1e-6 rad/s*sqrt(Hz); accelerometer 1.5e-3 m/s^2/sqrt(Hz), 4e-4 m/s^2, 2e-5 m/s^2*sqrt(Hz).

(a) A small gyroscope thermal lag, below the per-sample floor but large at 30-60 s averaging, is
    named against a noise model from a static run (``--noise-run``), and the refit says ``none``.
(b) Bias wander without a thermal effect: ``none`` on both sensors, with that white noise and with
    ten times less (5 seeds each here; 20 seeds each in ``bench/bench_noise_verdicts.py``).
(c) A large lag with wander: the lag, then ``none``.
Also: a drift beyond the noise model is ``unexplained`` naming the averaging time and the excess;
the whitening filter, the averaging bins and the averaged bias error of ``validate``.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import replace

import numpy as np
import pytest

from tak_thermo_ros.formats.bag import write_driver_record
from tak_thermo_ros.cli import main
from tak_thermo_ros.core.diagnose import diagnose
from tak_thermo_ros.core.diagnose.verdict import student_t_quantile
from tak_thermo_ros.core.diagnose.yardstick import AllanCheck, allan_check, bin_labels, simulate_noise, whitener
from tak_thermo_ros.core.fit import fit_model, residual_counts
from tak_thermo_ros.core.link.validate import AveragedError
from tak_thermo_ros.formats.kalibr import write_kalibr
from tak_thermo_ros.core.noise.residual import RESIDUAL_LONGEST_TAU_S, model_from_residual
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.simulation.truth import (
    DEFAULT_DRIVER_ACCEL,
    DEFAULT_DRIVER_GYRO,
    RATE_TABLE_POSITIONS,
    RATE_TABLE_RATES,
)

GYRO = (1.2e-4, 1.5e-5, 1e-6)
"""White noise density, bias instability, random walk of the simulated gyroscope (rad/s units)."""
ACCEL = (1.5e-3, 4e-4, 2e-5)
"""The same for the accelerometer (m/s^2 units)."""


def _unit(axes, terms, rate_hz: float, quiet: float, walks: bool = True):
    white, bias, walk = terms
    return tuple(replace(a, noise_counts=quiet * white * math.sqrt(rate_hz), bias_instability=bias,
                         random_walk=walk if walks else 0.0) for a in axes)


def wandering_run(*, seed: int, rate_hz: float = 1.0, slope: float = 0.0, quiet: float = 1.0,
                  walks: bool = True) -> Scenario:
    """About 1.7 h on the rate table, 2 C/min ramps; a gyroscope lag (tau 300 s, +-slope on x, z).

    ``walks=False``: bias instability without the random walk.
    """
    lag = {'thermal_lag': {'tau_s': 300.0, 'slope_x': slope, 'slope_y': 0.0, 'slope_z': -slope}} if slope else {}
    return Scenario(output='imu', plateaus_celsius=(5.0, 35.0, 5.0, 35.0), ramp_celsius_per_minute=2.0,
                    plateau_hours=0.2, board_lag_s=300.0, dwell_s=30.0, positions=RATE_TABLE_POSITIONS,
                    table_rates=RATE_TABLE_RATES, gyro_effects=lag, seed=seed, sample_rate_hz=rate_hz,
                    gyro_unit=_unit(DEFAULT_DRIVER_GYRO, GYRO, rate_hz, quiet, walks),
                    accel_unit=_unit(DEFAULT_DRIVER_ACCEL, ACCEL, rate_hz, quiet, walks))


def _diagnose(scenario: Scenario, sensor: str, effects=(), *, own_noise: bool = False):
    """Diagnose against the true noise model (``--noise``), or as without one (``own_noise``)."""
    samples = align(simulate(scenario).driver.channel(sensor))
    calibration = fit_model(samples, effects=effects).calibration
    if own_noise:
        return diagnose(calibration, samples,
                        noise=model_from_residual(residual_counts(calibration, samples), samples.stamp_ns))
    return diagnose(calibration, samples, noise=scenario.noise_truth(sensor))


# ----------------------------------------------------------------------------- (a), the CLI

@pytest.fixture(scope='module')
def small_lag_story(tmp_path_factory):
    """A small gyroscope lag at 5 Hz; a one-hour static run of the same unit at 20 C for the noise model."""
    root = tmp_path_factory.mktemp('noise_verdicts')
    scenario = wandering_run(seed=3, rate_hz=5.0, slope=3e-5)
    static = replace(scenario, plateaus_celsius=(20.0,), start_celsius=20.0, plateau_hours=1.0,
                     positions=((0.0, 0.0, 1.0),), table_rates=(), record_references=False, gyro_effects={},
                     seed=9)
    write_driver_record(root / 'cal', simulate(scenario).driver)
    write_driver_record(root / 'static', simulate(static).driver)
    write_kalibr(root / 'imu.yaml', {s: scenario.noise_truth(s) for s in ('accel', 'gyro')}, rostopic='/imu/data_raw')

    def at(name: str) -> str:
        return str(root / name)
    commands = [
        ['fit', at('cal'), '-o', at('base.yaml')],
        ['diagnose', at('cal'), '--params', at('base.yaml'), '--noise-run', at('static'), '--json', at('base.json'),
         '--report', at('report')],
        ['fit', at('cal'), '-o', at('lag.yaml'), '--gyro-effects', 'thermal_lag'],
        ['diagnose', at('cal'), '--params', at('lag.yaml'), '--noise-run', at('static'), '--json', at('lag.json')],
    ]
    for command in commands:
        assert main([*command, '--no-progress']) == 0, command
    return root


def test_a_small_gyro_lag_below_the_per_sample_floor_is_named_and_the_refit_is_none(small_lag_story):
    base = json.loads((small_lag_story / 'base.json').read_text())
    gyro = base['sensors']['gyro']
    assert gyro['verdict'] == 'thermal_lag'
    assert base['sensors']['accel']['verdict'] == 'none'
    for axis in ('x', 'z'):
        summary = gyro['axes'][axis]
        # Per sample the lag hides in the white noise: the residual RMS is within 25 % of the white floor ...
        assert summary['rms'] < 1.25 * summary['white_floor']
        # ... yet its held-out averages stand well above what the noise model predicts.
        assert summary['heldout_rms'] > 1.4 * summary['noise_floor']
    lag = json.loads((small_lag_story / 'lag.json').read_text())
    assert lag['sensors']['gyro']['verdict'] == 'none' and lag['sensors']['accel']['verdict'] == 'none'
    assert all(entry['consistent'] for entry in lag['sensors']['gyro']['allan'])


def test_diagnose_json_holds_each_sensors_noise_model(small_lag_story):
    """The contract: sensors.<gyro|accel>.noise with three numbers per term and the source."""
    document = json.loads((small_lag_story / 'base.json').read_text())
    for sensor, (white, _, _) in (('gyro', GYRO), ('accel', ACCEL)):
        noise = document['sensors'][sensor]['noise']
        assert noise['source'] == 'static_run'
        for key in ('white_noise_density', 'bias_instability', 'random_walk'):
            assert len(noise[key]) == 3 and all(v >= 0.0 for v in noise[key])
        # An hour of static run gives the white noise density to a few per cent.
        assert np.allclose(noise['white_noise_density'], white, rtol=0.1)
    assert document['averaging_time_s'] > 1.0


def test_without_a_noise_model_the_verdict_says_where_its_yardstick_comes_from(small_lag_story, capsys):
    assert main(['diagnose', str(small_lag_story / 'cal'), '--params', str(small_lag_story / 'lag.yaml'),
                 '--json', str(small_lag_story / 'own.json'), '--no-progress', '--force',
                 '--max-samples', '6000', '--candidates', 'hysteresis']) == 0
    out = capsys.readouterr().out
    assert "fitted to this run's own residual" in out
    document = json.loads((small_lag_story / 'own.json').read_text())
    assert document['sensors']['gyro']['noise']['source'] == 'residual'
    assert main(['diagnose', str(small_lag_story / 'cal'), '--params', str(small_lag_story / 'lag.yaml'),
                 '--noise', str(small_lag_story / 'imu.yaml'), '--noise-run', str(small_lag_story / 'static')]) == 2
    assert 'give one noise model source, not both' in capsys.readouterr().err


def test_validate_prints_the_averaged_bias_error_next_to_the_noise_model(small_lag_story, capsys):
    json_path = small_lag_story / 'validate.json'
    assert main(['validate', str(small_lag_story / 'cal'), '--params', str(small_lag_story / 'lag.yaml'),
                 '--noise', str(small_lag_story / 'imu.yaml'), '--json', str(json_path), '--force']) == 0
    out = capsys.readouterr().out
    assert 'deg/h' in out and 'mg' in out and 'noise model' in out
    gyro = json.loads(json_path.read_text())['gyro']['averaged_bias_error']
    assert gyro['source'] == 'file' and set(gyro['taus']) == {'1', '60', '600'}
    one = gyro['taus']['1']
    # At 1 s the error is the white noise: its RMS agrees with the model's Allan deviation.
    assert np.allclose(one['rms'], one['noise_model'], rtol=0.25)


def test_the_report_shows_the_allan_deviation_before_and_after_the_effect_against_the_model(small_lag_story):
    page = (small_lag_story / 'report' / 'gyro' / 'report.html').read_text()
    assert (small_lag_story / 'report' / 'gyro' / 'allan.png').stat().st_size > 10_000
    assert 'Against the noise model' in page and 'static_run' in page
    table = page.split('Largest Allan deviation ratio')[1].split('</table>')[0]
    assert '<td>base</td>' in table and '<td>base + thermal_lag</td>' in table


# ----------------------------------------------------------------------- (b) and (c), core

@pytest.mark.parametrize('quiet', [1.0, 0.1], ids=['consumer_white', 'white_ten_times_lower'])
def test_b_bias_wander_alone_is_none_on_both_sensors(quiet):
    """5 seeds x 2 sensors: at most one verdict other than none, and never an effect or voltage advice.

    The rule's rate is measured over 20 seeds per case in bench/bench_noise_verdicts.py.
    """
    verdicts = [_diagnose(wandering_run(seed=seed, quiet=quiet), sensor)
                for seed in range(5) for sensor in ('gyro', 'accel')]
    others = [d for d in verdicts if d.verdict != 'none']
    assert len(others) <= 1, [(d.verdict, d.message) for d in others]
    assert all(d.verdict in ('none', 'unexplained') for d in verdicts)


def test_c_a_large_lag_with_wander_is_named_then_none():
    scenario = wandering_run(seed=11, slope=1.5e-4)
    first = _diagnose(scenario, 'gyro')
    assert first.verdict == 'thermal_lag'
    assert first.allan[0][1].consistent is False  # the base residual is beyond the noise model
    refit = _diagnose(scenario, 'gyro', effects=('thermal_lag',))
    assert refit.verdict == 'none'


def test_a_drift_beyond_the_noise_model_is_unexplained_naming_the_averaging_time():
    """A supply-voltage drift (periods 0.4-2 h) far above the wander: the message names tau and the excess."""
    scenario = replace(wandering_run(seed=2), supply_voltage_drift=0.02)
    result = _diagnose(scenario, 'accel')
    assert result.verdict == 'unexplained'
    match = re.search(r'residual Allan deviation ([\d.]+)x the noise model at tau ([\d.]+) (s|h) on ([xyz])',
                      result.message)
    assert match and float(match.group(1)) > 2.0


# ------------------------------------------------- without a noise model: the run's own short-term noise

def test_without_a_noise_model_bias_instability_alone_is_none():
    """No --noise: 3 seeds x 2 sensors of bias instability (no walk), white noise ten times lower.

    The residual stands far above the white floor, and no effect explains it; its Allan deviation
    beyond half a minute stays within the bound of white noise and bias instability fitted up to
    half a minute, so the verdict is ``none``, said of this sensor's own noise. At most one other
    verdict (20 seeds: ``bench/bench_noise_verdicts.py --own-noise``).
    """
    verdicts = [_diagnose(wandering_run(seed=seed, quiet=0.1, walks=False), sensor, own_noise=True)
                for seed in range(3) for sensor in ('gyro', 'accel')]
    others = [d for d in verdicts if d.verdict != 'none']
    assert len(others) <= 1, [(d.verdict, d.message) for d in others]
    said = [d for d in verdicts if "consistent with this sensor's own noise at every averaging time" in d.message]
    # The rule at work: these were above the white floor, which alone would have said unexplained.
    assert len(said) >= 3
    assert all(max(a.heldout_rms / a.noise_floor for a in d.axes) > 1.5 for d in said)
    assert not any('supply voltage' in d.message for d in said)


def test_without_a_noise_model_a_drift_names_tau_the_excess_and_the_walk_that_would_explain_it():
    """A supply-voltage drift: ``unexplained``, naming the averaging time, the excess and the walk it would take."""
    result = _diagnose(replace(wandering_run(seed=2), supply_voltage_drift=0.02), 'accel', own_noise=True)
    assert result.verdict == 'unexplained'
    assert result.noise.source == 'residual' and result.noise.random_walk == (0.0, 0.0, 0.0)
    match = re.search(r'residual Allan deviation ([\d.]+)x the noise model at tau ([\d.]+) (s|h) on ([xyz])',
                      result.message)
    assert match and float(match.group(1)) > 2.0
    assert float(match.group(2)) * (3600.0 if match.group(3) == 'h' else 1.0) > RESIDUAL_LONGEST_TAU_S
    walk = re.search(r'rate random walk.*?at least ([\d.e+-]+) ([\d.e+-]+) ([\d.e+-]+) \(x y z', result.message)
    assert walk, result.message
    # The drift is far beyond the part's own walk: what it would take is several times the true one.
    assert max(float(v) for v in walk.groups()) > 3.0 * ACCEL[2]


def test_the_walk_an_excess_implies_is_the_simulated_walk():
    """Bias instability and random walk, no model given: the least walk explaining the excess is the true one.

    2 seeds x 2 sensors x 3 axes; the Allan variance at the longest averaging times of a 1.7 h run
    has about 10 degrees of freedom (40 % in variance, 20 % in the walk), and the least walk is the
    largest over several averaging times: the median within a factor 2 of the truth.
    """
    ratios = []
    for seed in range(2):
        run = simulate(wandering_run(seed=500 + seed, quiet=0.1))
        for sensor, terms in (('gyro', GYRO), ('accel', ACCEL)):
            samples = align(run.driver.channel(sensor))
            residual = residual_counts(fit_model(samples).calibration, samples)
            noise = model_from_residual(residual, samples.stamp_ns)
            # White noise and bias instability up to half a minute: the latter within 35 % of the truth.
            assert np.allclose(noise.bias_instability, terms[1], rtol=0.35)
            floor = np.std(np.diff(residual, axis=0), axis=0) / math.sqrt(2.0)
            check = allan_check(residual, 1.0, noise, floor)
            ratios += list(check.walk_to_explain(RESIDUAL_LONGEST_TAU_S) / terms[2])
    assert 0.5 < float(np.median(ratios)) < 2.0, ratios


def test_walk_to_explain_closes_the_largest_gap_beyond_the_given_time():
    taus = np.array([10.0, 100.0, 1000.0])
    model = np.full((3, 3), 1e-3)
    walk = np.array([1e-4, 0.0, 3e-5])
    residual = np.sqrt(model ** 2 + walk[None, :] ** 2 * taus[:, None] / 3.0)
    residual[0, 1] = 5e-3  # an excess at 10 s, before the time given: not counted
    check = AllanCheck(taus=taus, residual_adev=residual, model_adev=model, bound=np.full((3, 3), 2.0),
                       source='residual')
    assert np.allclose(check.walk_to_explain(30.0), walk, rtol=1e-9, atol=1e-15)
    assert check.walk_to_explain(1e4).tolist() == [0.0, 0.0, 0.0]


# ------------------------------------------------------------------------------ the pieces

def test_the_allan_test_of_noise_the_model_predicts_rarely_fails():
    """200 residuals drawn from the model itself: the family-wise 1 % test fails on at most 3 %."""
    gyro = wandering_run(seed=0).noise_truth('gyro')
    floor = np.array(gyro.white_noise_density)  # at 1 Hz the per-sample floor equals the density
    failures = sum(not allan_check(simulate_noise(gyro, 4000, 1.0, floor, [seed]), 1.0, gyro, floor).consistent
                   for seed in range(200))
    assert failures <= 6


def test_the_whitening_filter_makes_the_model_noise_nearly_white_at_the_white_level():
    gyro = wandering_run(seed=0).noise_truth('gyro')
    floor = np.array(gyro.white_noise_density) / math.sqrt(30.0)  # 30 s means
    time_s = np.arange(3000) * 30.0
    noise = simulate_noise(gyro, 3000, 30.0, floor, [5])
    whitened = whitener(gyro, time_s, floor ** 2)(noise)[100:]
    assert np.all(np.std(noise, axis=0) > 3.0 * floor)  # the wander dominates the raw series
    # The filter's bias instability is one Gauss-Markov process where the simulator sums several:
    # white to within a few per cent of correlation, at the white level to within 25 %.
    assert np.all((np.std(whitened, axis=0) > 0.9 * floor) & (np.std(whitened, axis=0) < 1.25 * floor))

    def lag_one(series: np.ndarray) -> np.ndarray:
        return np.array([np.corrcoef(series[1:, i], series[:-1, i])[0, 1] for i in range(3)])
    assert np.all(lag_one(noise) > 0.5) and np.all(np.abs(lag_one(whitened)) < 0.1)


def test_averaging_bins_never_straddle_a_turntable_move():
    time_s = np.arange(600) * 0.5
    breaks = np.zeros(600, dtype=bool)
    breaks[[0, 130, 333]] = True
    labels = bin_labels(time_s, breaks, 20.0, 0.5)
    segment = np.cumsum(breaks)
    for label in np.unique(labels[labels >= 0]):
        assert len(np.unique(segment[labels == label])) == 1
        assert np.count_nonzero(labels == label) <= 40


def test_averaged_error_equals_the_means_of_whole_windows_over_any_blocks():
    rng = np.random.default_rng(1)
    time_s = np.arange(1300) * 0.1
    error = rng.standard_normal((1300, 3))
    averaged = AveragedError(taus=(1.0, 60.0), columns=3)
    for block in np.array_split(np.arange(1300), 7):
        averaged.add(time_s[block], error[block])
    found = averaged.rms()
    # 129 whole windows of 1 s (the last, still open, is left out); 2 of 60 s.
    expected = np.sqrt(np.mean(error[:1290].reshape(-1, 10, 3).mean(axis=1) ** 2, axis=0))
    assert np.allclose(found[1.0], expected) and averaged.windows()[60.0] == 2


def test_student_t_quantile_is_scipys():
    assert student_t_quantile(0.975, 9) == pytest.approx(2.2622, abs=1e-4)
    assert student_t_quantile(0.995, 19) == pytest.approx(2.8609, abs=1e-4)  # the printed tables
