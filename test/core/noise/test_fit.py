"""Issue 25: a noise model that fits real sensors, and says when it does not.

Simulated sensors with what real ones have (a driver's low-pass filter and decimation, output
quantisation, a sum of Gauss-Markov processes, random walk), a sinusoid and a step that no noise
term makes, and the Kalibr file every estimator reads. The sensors' noise is drawn by the
simulator's own functions (``white_noise``, ``sensor_wander``, ``quantized``: what ``simulate``
adds to a driver's channels) without the thermal chamber, so that 20 seeds stay cheap.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from tak_thermo_ros.cli import main
from tak_thermo_ros.cli.common import noise_axis_lines
from tak_thermo_ros.core.noise.allan import (
    AllanAccumulator,
    allan_variance,
    confidence_interval,
    equivalent_degrees_of_freedom,
)
from tak_thermo_ros.core.noise.fit import BAND_CONFIDENCE, fit_noise
from tak_thermo_ros.core.noise.model import NoiseModel
from tak_thermo_ros.core.simulation.imu import quantized, sensor_wander, simulate, white_noise
from tak_thermo_ros.core.simulation.scenario import Scenario, scenario_from_mapping
from tak_thermo_ros.core.simulation.truth import AxisTruth
from tak_thermo_ros.errors import NoiseError
from tak_thermo_ros.formats.bag import write_driver_record
from tak_thermo_ros.formats.kalibr import kalibr_text

RATE = 10.0
HOURS = 3.0
GYRO = (
    AxisTruth(1.0, 0.0, (0.0,), (0.0,), noise_counts=1.0e-4 * math.sqrt(RATE), filter_time_constant=0.12,
              resolution=1.5e-4, gauss_markov=(3e-5,), gauss_markov_time=(1.0,), random_walk=3e-5),
    AxisTruth(1.0, 0.0, (0.0,), (0.0,), noise_counts=1.2e-4 * math.sqrt(RATE), filter_time_constant=0.2,
              resolution=2e-4, gauss_markov=(2e-5, 2e-5), gauss_markov_time=(0.5, 3.0), random_walk=2.5e-5),
    AxisTruth(1.0, 0.0, (0.0,), (0.0,), noise_counts=0.8e-4 * math.sqrt(RATE), resolution=1e-4,
              gauss_markov=(3e-5,), gauss_markov_time=(1.0,), random_walk=4e-5),
)
"""A gyroscope (rad/s) read by a driver at 10 Hz: a first-order low-pass at 40 Hz internal rate
(decimation 4) on x and y, every axis rounded to its resolution (0.5-0.75 of a sample's noise),
Gauss-Markov processes of 0.5-3 s, random walk."""
SENSOR = Scenario(output='imu', sample_rate_hz=RATE, decimation=4, gyro_unit=GYRO)


def static_noise(seed: int, hours: float = HOURS, sensor: Scenario = SENSOR) -> np.ndarray:
    """``(n, 3)``: the gyroscope's output at rest, as ``simulate`` draws it for a driver bag."""
    count = int(hours * 3600.0 * sensor.sample_rate_hz)
    scenario = replace(sensor, seed=seed)
    rng = np.random.default_rng(seed)
    noise = white_noise(scenario, scenario.gyro_unit, 1, rng, count)
    return quantized(noise + sensor_wander(scenario, scenario.gyro_unit, 1, count), scenario.gyro_unit)


@pytest.fixture(scope='module')
def twenty_fits():
    """20 seeds: the Allan variance of each 3 h record and its fit."""
    fits = []
    for seed in range(20):
        allan = allan_variance(static_noise(seed), RATE, per_octave=2)
        fits.append((allan, fit_noise(allan, source='static_run')))
    return fits


def test_the_simulated_sensor_is_what_its_truth_says():
    """The simulator's filter, decimation, rounding and Gauss-Markov processes have the truth's Allan variance."""
    truth = SENSOR.noise_truth('gyro')
    assert truth.filter_share[0] > 0.9 and truth.filter_share[2] == 0.0 and len(truth.gauss_markov) == 2
    allan = allan_variance(static_noise(99, hours=4.0), RATE, clusters=np.array([1, 2, 3, 6, 20, 60, 200]))
    # the flicker-rate degrees of freedom: fewer than white noise has, more than a walk
    low, high = confidence_interval(allan.avar, equivalent_degrees_of_freedom(allan, -1), 0.999)
    model = truth.allan_variance(allan.taus)
    assert np.all((low <= model) & (model <= high)), allan.avar / model


def test_the_model_follows_real_sensor_noise_within_the_band_and_recovers_density_walk_and_floor(twenty_fits):
    """Issue 25's done-when, over 20 seeds.

    At every averaging time of two samples and longer the model's Allan variance lies in the
    95 % band of the measured one (chi-square on its degrees of freedom, joint over the
    averaging times), and the white noise density, the random walk and the floor (the Allan
    deviation's minimum) are within 15 % of the truth on every axis of every seed.
    """
    truth = SENSOR.noise_truth('gyro')
    ratios = []
    for allan, fit in twenty_fits:
        assert all(axis.within for axis in fit.axes), [axis for axis in fit.axes if not axis.within]
        assert all(axis.step is None for axis in fit.axes)  # no false alarm of a step in 60 axes
        model = fit.model
        ratios.append([np.divide(model.white_noise_density, truth.white_noise_density),
                       np.divide(model.random_walk, truth.random_walk),
                       np.divide(model.floor(), truth.floor())])
    ratios = np.array(ratios)
    assert np.all(np.abs(ratios - 1.0) < 0.15), np.abs(ratios - 1.0).max(axis=(0, 2))
    # and the filter is found where there is one (its time constant within 10 %), not where there is none
    for _, fit in twenty_fits:
        assert fit.model.filter_share[2] == 0.0
        assert np.allclose(fit.model.filter_time_constant[:2], (0.12, 0.2), rtol=0.1)


def test_within_the_band_means_the_measured_band(twenty_fits):
    """The band is the measured Allan variance's chi-square interval: the model is inside it, point by point."""
    allan, fit = twenty_fits[0]
    judged = (allan.counts >= 2) & (allan.clusters >= 2)
    model = fit.model.allan_variance(allan.taus[judged])
    for axis in range(3):
        # the widest edf the band could take (white noise): inside even the narrowest interval's joint version
        edf = equivalent_degrees_of_freedom(allan, -1)[judged]
        low, high = confidence_interval(allan.avar[judged, axis], edf, 1.0 - (1.0 - BAND_CONFIDENCE) / judged.sum())
        assert np.all((low <= model[:, axis]) & (model[:, axis] <= high))


def test_a_sinusoid_is_said_not_fitted_silently():
    """A 50 s sinusoid on x: outside the band, a dip at its period after a bump; the axes without it are clean."""
    noise = static_noise(7, hours=2.0)
    time = np.arange(len(noise)) / RATE
    noise[:, 0] += 1.5e-4 * np.sin(2.0 * math.pi * time / 50.0)
    fit = fit_noise(allan_variance(noise, RATE, per_octave=2), source='static_run')
    assert not fit.axes[0].within and fit.axes[1].within and fit.axes[2].within
    dips = [m for m in fit.axes[0].misfits if m.kind == 'dip']
    assert any(36.0 <= m.at <= 72.0 for m in dips), fit.axes[0].misfits
    lines = noise_axis_lines('gyro', fit.model, 0, 'rad/s', fit)
    assert any('OUTSIDE the 95 % band' in line for line in lines)
    assert any(line.startswith('a periodic disturbance? period about') for line in lines), lines
    assert all(len(line) <= 95 for line in lines)


def test_a_step_is_said_with_where_and_how_large():
    """A jump of the bias by 1e-3 rad/s (200 deg/h) one third into the record: found there, at about its size."""
    noise = static_noise(8, hours=2.0)
    start = len(noise) // 3
    noise[start:, 1] += 1e-3
    fit = fit_noise(allan_variance(noise, RATE, per_octave=2), source='static_run')
    step = fit.axes[1].step
    assert step is not None and fit.axes[0].step is None and fit.axes[2].step is None
    assert step.time_s == pytest.approx(start / RATE, abs=5.0 * step.tau)
    assert step.size == pytest.approx(1e-3, rel=0.3)
    lines = noise_axis_lines('gyro', fit.model, 1, 'rad/s', fit)
    assert any(line.startswith('a step at ') and 'into the record' in line for line in lines), lines
    assert all(len(line) <= 95 for line in lines)


def test_the_streamed_step_statistics_equal_the_in_memory_ones():
    noise = static_noise(3, hours=0.5)
    noise[5000:, 2] += 1e-3
    streamed = AllanAccumulator(RATE, 3, per_octave=2, exact_max=512, max_bins=64)
    for start in range(0, len(noise), 7001):
        streamed.add(noise[start:start + 7001])
    result = streamed.result()
    exact = (result.strides == 1) & np.isfinite(result.peak[:, 0])  # kept at the powers of two
    assert np.array_equal(result.clusters[exact], 2 ** np.arange(exact.sum()))
    memory = allan_variance(noise, RATE, clusters=result.clusters[exact])
    assert np.allclose(result.peak[exact], memory.peak, rtol=1e-9)
    # where it lies: a term as large (rounded outputs tie; the two sums differ in the last digits)
    phase = np.concatenate([np.zeros((1, 3)), np.cumsum(noise, axis=0)])
    for i, m in enumerate(result.clusters[exact]):
        k = result.peak_index[exact][i]
        found = np.abs(phase[k + 2 * m, range(3)] - 2.0 * phase[k + m, range(3)] + phase[k, range(3)])
        assert np.allclose(found, memory.peak[i], rtol=1e-6)
    fit = fit_noise(result, source='static_run')
    assert fit.axes[2].step is not None and fit.axes[2].step.time_s == pytest.approx(500.0, abs=30.0)


def test_a_record_without_a_walk_writes_the_largest_walk_it_allows_and_says_so():
    """White noise and a Gauss-Markov process, 1 h: no walk shown; the bound covers a walk the record hides."""
    quiet = replace(SENSOR, gyro_unit=tuple(replace(a, random_walk=a.random_walk * 1e-3) for a in GYRO))
    bounds, shown = 0, 0
    for seed in range(10):
        allan = allan_variance(static_noise(seed, hours=1.0, sensor=quiet), RATE, per_octave=2)
        fit = fit_noise(allan, source='static_run')
        model = fit.model
        for axis, truth in enumerate(quiet.gyro_unit):
            walk, bound = model.random_walk[axis], model.random_walk_bound[axis]
            assert (walk > 0.0) != (bound > 0.0) and fit.axes[axis].walk_shown == (walk > 0.0)
            shown += walk > 0.0
            if bound > 0.0:
                bounds += 1
                assert bound >= truth.random_walk  # it covers the walk the record hides
        # and it is about the largest the record allows: the same record with a walk twice as large
        # (by whatever term the fit then takes it) has at least twice the Allan variance at its end
        loud = replace(SENSOR, gyro_unit=tuple(replace(a, random_walk=2.0 * max(b, k)) for a, b, k in
                                               zip(GYRO, model.random_walk_bound, model.random_walk)))
        again = fit_noise(allan_variance(static_noise(seed, hours=1.0, sensor=loud), RATE, per_octave=2),
                          source='static_run')
        longest = allan.taus[-3:]
        assert np.all(again.model.allan_variance(longest) >= 2.0 * model.allan_variance(longest))
    # a walk "shown" where there is next to none: the 2-sigma rule's false alarms, rare
    assert bounds >= 25 and shown <= 5
    axis = model.random_walk_bound.index(max(model.random_walk_bound))
    lines = noise_axis_lines('gyro', model, axis, 'rad/s', fit)
    assert any(line.startswith('random walk at most') and line.endswith(': none shown') for line in lines)
    text = kalibr_text({'gyro': model}, rostopic='/imu')
    assert 'upper bound, the record shows no walk' in text
    written = [k if k > 0.0 else b for k, b in zip(model.random_walk, model.random_walk_bound)]
    assert yaml.safe_load(text)['gyroscope_random_walk'] == pytest.approx(max(written), rel=1e-6)


# ---------------------------------------------------------------------------------------- Kalibr

def kalibr_accepts(raw) -> None:
    """Kalibr's own checks of an imu.yaml (ethz-asl/kalibr, kalibr_common/ConfigReader.py, ImuParameters).

    Quoted::

        def checkRosTopic(self, topic):
            if not isinstance(topic, str):
                self.raiseError("rostopic has to be a string")
        def checkUpdateRate(self, update_rate):
            if update_rate <= 0.0:
                self.raiseError("invalid update_rate")
        def checkAccelerometerStatistics(self, noise_density, random_walk):
            if noise_density <= 0.0:
                self.raiseError("invalid accelerometer_noise_density")
            if random_walk <= 0.0:
                self.raiseError("invalid accelerometer_random_walk")
        def checkGyroStatistics(self, noise_density, random_walk):
            if noise_density <= 0.0:
                self.raiseError("invalid gyroscope_noise_density")
            if random_walk <= 0.0:
                self.raiseError("invalid gyroscope_random_walk")

    and a missing key is "Field ... missing" (``catch_keyerror``); the file is read with
    ``yaml.safe_load``. OpenVINS reads the same four keys (under ``imu0:``), VINS-Fusion the same
    numbers as ``acc_n acc_w gyr_n gyr_w``: a walk of 0 leaves their bias without process noise.
    """
    if not isinstance(raw['rostopic'], str):
        raise AssertionError('rostopic has to be a string')
    if raw['update_rate'] <= 0.0:
        raise AssertionError('invalid update_rate')
    for prefix in ('accelerometer', 'gyroscope'):
        if f'{prefix}_noise_density' in raw or f'{prefix}_random_walk' in raw:
            if raw[f'{prefix}_noise_density'] <= 0.0:
                raise AssertionError(f'invalid {prefix}_noise_density')
            if raw[f'{prefix}_random_walk'] <= 0.0:
                raise AssertionError(f'invalid {prefix}_random_walk')


@pytest.fixture(scope='module')
def white_only_bag(tmp_path_factory):
    """A 40 min static driver bag at 20 Hz whose accelerometer shows no walk and whose gyroscope x is quantisation."""
    axis = {'noise_counts': 2e-3, 'bias_instability': 0.0, 'random_walk': 0.0}
    scenario = scenario_from_mapping({
        'output': 'imu', 'sample_rate_hz': 20.0, 'plateaus_celsius': [20.0], 'plateau_hours': 0.67,
        'positions': [[0.0, 0.0, 1.0]], 'record_references': False,
        'accel_unit': {'x': axis, 'y': axis, 'z': axis},
        'gyro_unit': {'x': {'noise_counts': 1e-5, 'resolution': 1e-3, 'random_walk': 1e-6},
                      'y': {'noise_counts': 4e-4, 'random_walk': 2e-5}, 'z': {'noise_counts': 4e-4}}})
    path = tmp_path_factory.mktemp('kalibr') / 'static.mcap'
    write_driver_record(path, simulate(scenario).driver)
    return path


def test_every_imu_yaml_tak_calib_writes_passes_kalibrs_checks(white_only_bag, tmp_path, capsys):
    output = tmp_path / 'imu.yaml'
    assert main(['noise', str(white_only_bag), '-o', str(output), '--no-progress']) == 0
    printed = capsys.readouterr().out
    raw = yaml.safe_load(output.read_text())
    kalibr_accepts(raw)
    assert 'random walk at most' in printed and ': none shown' in printed
    assert all(len(line) <= 100 for line in printed.splitlines() if line.startswith('  '))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0, 1e-2, allow_subnormal=False), min_size=12, max_size=12), st.floats(0.5, 1e4))
def test_kalibr_text_is_written_only_when_kalibr_accepts_it(values, rate):
    """Whatever the model, the text is refused in one line or it passes Kalibr's checks."""
    white, walk, bound, quantum = (tuple(values[i:i + 3]) for i in range(0, 12, 3))
    bound = tuple(0.0 if k > 0.0 else b for k, b in zip(walk, bound))
    model = NoiseModel(white_noise_density=white, bias_instability=(0.0,) * 3, bias_instability_tau=(1.0,) * 3,
                       random_walk=walk, update_rate=rate, source='static_run', quantization=quantum,
                       random_walk_bound=bound)
    try:
        text = kalibr_text({'gyro': model, 'accel': model}, rostopic='/imu/data_raw')
    except NoiseError as err:
        assert 'Kalibr refuses a value <= 0' in str(err)
        return
    kalibr_accepts(yaml.safe_load(text))


def test_a_kalibr_file_with_the_new_terms_reads_back_as_the_model(twenty_fits, tmp_path):
    from tak_thermo_ros.formats.kalibr import read_kalibr, write_kalibr
    model = twenty_fits[0][1].model
    write_kalibr(tmp_path / 'imu.yaml', {'gyro': model}, rostopic='/imu')
    back = read_kalibr(tmp_path / 'imu.yaml')['gyro']
    taus = np.geomspace(0.2, 3000.0, 30)
    assert np.allclose(back.allan_variance(taus), model.allan_variance(taus), rtol=1e-5)
    assert back.gauss_markov_time == pytest.approx(model.gauss_markov_time, rel=1e-6) or not model.gauss_markov
