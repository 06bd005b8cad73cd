"""Allan variance (in memory and streamed), the IEEE 952 noise model and its fit, Kalibr files."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tak_thermo_ros.core.noise.allan import (
    AllanAccumulator,
    AllanVariance,
    allan_variance,
    cluster_sizes,
    confidence_interval,
    equivalent_degrees_of_freedom,
)
from tak_thermo_ros.formats.kalibr import kalibr_from_mapping, kalibr_text, kalibr_values, read_kalibr, write_kalibr
from tak_thermo_ros.formats.files import non_finite_number
from tak_thermo_ros.core.noise.model import (
    FLICKER_FLOOR,
    TERMS,
    NoiseModel,
    allan_terms,
    floor_tau,
    noise_model_from_mapping,
)
from tak_thermo_ros.core.noise.fit import fit_noise, fit_noise_model
from tak_thermo_ros.errors import NoiseError, OutputError


def _by_cluster_averages(samples: np.ndarray, m: int) -> np.ndarray:
    """The textbook form: half the mean squared difference of adjacent overlapping m-sample averages."""
    averages = np.array([samples[k:k + m].mean(axis=0) for k in range(len(samples) - m + 1)])
    differences = averages[m:] - averages[:-m]
    return 0.5 * np.mean(differences ** 2, axis=0)


def test_allan_variance_is_the_mean_square_difference_of_cluster_averages():
    rng = np.random.default_rng(3)
    samples = rng.standard_normal((600, 3)) + np.cumsum(rng.standard_normal((600, 3)), axis=0) * 0.1 + 5.0
    result = allan_variance(samples, 50.0, clusters=np.array([1, 3, 7, 40, 200]))
    for i, m in enumerate(result.clusters):
        assert result.avar[i] == pytest.approx(_by_cluster_averages(samples, int(m)), rel=1e-9)
        assert result.counts[i] == len(samples) - 2 * m + 1
    assert np.allclose(result.taus, result.clusters / 50.0)
    single = allan_variance(samples[:, 1], 50.0, clusters=np.array([1, 3, 7]))
    assert np.allclose(single.avar[:, 0], result.avar[:3, 1], rtol=1e-12)


def test_cluster_sizes_are_log_spaced_and_bounded():
    assert cluster_sizes(1000).tolist() == [2 ** k for k in range(10)]
    dense = cluster_sizes(1000, 4)
    assert dense[0] == 1 and dense[-1] <= 1000 and np.all(np.diff(dense) > 0)
    assert len(dense) > 3 * len(cluster_sizes(1000))
    with pytest.raises(NoiseError):
        cluster_sizes(10, 0)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(1, 700), min_size=1, max_size=12), st.integers(0, 10_000))
def test_accumulator_exact_part_equals_in_memory_for_any_blocks(sizes, seed):
    rng = np.random.default_rng(seed)
    samples = rng.standard_normal((sum(sizes), 3)) * [1.0, 10.0, 0.1] + [0.0, 9.8, -3.0]
    accumulator = AllanAccumulator(100.0, 3, exact_max=64, max_bins=8)
    start = 0
    for size in sizes:
        accumulator.add(samples[start:start + size])
        start += size
    streamed = accumulator.result()
    exact = streamed.strides == 1
    assert accumulator.samples == len(samples)
    reference = allan_variance(samples, 100.0, clusters=streamed.clusters[exact])
    assert np.array_equal(reference.clusters, streamed.clusters[exact])
    assert np.allclose(streamed.avar[exact], reference.avar, rtol=1e-9)
    assert np.array_equal(streamed.counts[exact], reference.counts)


def test_accumulator_long_clusters_are_the_bin_averages_allan_variance():
    """Beyond exact_max: the overlapping estimator of the b-sample bin averages, at cluster m / b."""
    rng = np.random.default_rng(1)
    samples = rng.standard_normal((200_000, 3)) + np.cumsum(rng.standard_normal((200_000, 3)), axis=0) * 0.01
    accumulator = AllanAccumulator(100.0, 3, exact_max=256, max_bins=64)
    for start in range(0, len(samples), 9999):
        accumulator.add(samples[start:start + 9999])
    result = accumulator.result()
    binned = result.strides > 1
    assert np.any(binned) and accumulator.bin_size == result.strides[binned][0]
    assert accumulator._bin_count <= 2 * 64 + 2  # bounded: the bins doubled instead of growing
    size = accumulator.bin_size
    averages = samples[:len(samples) // size * size].reshape(-1, size, 3).mean(axis=1)
    for m, avar in zip(result.clusters[binned], result.avar[binned]):
        assert avar == pytest.approx(allan_variance(averages, 100.0 / size, clusters=np.array([m // size])).avar[0],
                                     rel=1e-9)
        full = allan_variance(samples, 100.0, clusters=np.array([m]))
        assert avar == pytest.approx(full.avar[0], rel=0.6)  # same expectation, a few independent terms


def test_accumulator_memory_does_not_grow_with_the_run():
    accumulator = AllanAccumulator(1000.0, 3, exact_max=128, max_bins=32)
    rng = np.random.default_rng(0)
    for _ in range(40):
        accumulator.add(rng.standard_normal((5000, 3)))
    assert accumulator._history.shape == (2 * 128 + 1, 3)
    assert accumulator._bins.shape == (2 * 32 + 2, 3)
    assert accumulator.samples == 200_000
    result = accumulator.result()
    assert result.clusters.max() <= 200_000 // 3
    white = result.avar * result.taus[:, None] * 1000.0  # tau avar = sigma^2 / rate for white noise
    assert np.allclose(white[result.counts > 10_000], 1.0, rtol=0.1)


def test_bad_samples_are_refused_with_one_line():
    with pytest.raises(NoiseError, match='not finite'):
        allan_variance(np.array([1.0, np.nan, 2.0]), 10.0)
    accumulator = AllanAccumulator(10.0, 3)
    with pytest.raises(NoiseError, match=r'shape \(n, 3\)'):
        accumulator.add(np.zeros((5, 2)))
    with pytest.raises(NoiseError, match='sample rate'):
        AllanAccumulator(0.0)
    accumulator.add(np.zeros((0, 3)))
    assert accumulator.result().taus.size == 0


def _coverage(alpha_noise: str, m: int, seeds: int, n: int = 1024) -> float:
    covered = 0
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        white = rng.standard_normal(n)
        samples = white if alpha_noise == 'white' else np.cumsum(white)
        result = allan_variance(samples, 1.0, clusters=np.array([m]))
        alpha = 0 if alpha_noise == 'white' else -2
        low, high = confidence_interval(result.avar[:, 0], equivalent_degrees_of_freedom(result, alpha))
        truth = 1.0 / m if alpha_noise == 'white' else m / 3.0 + 1.0 / (6.0 * m)  # discrete random walk
        covered += int(low[0] <= truth <= high[0])
    return covered / seeds


@pytest.mark.parametrize(('noise', 'm'), [('white', 4), ('white', 64), ('walk', 16)])
def test_confidence_intervals_cover_the_truth_at_their_level(noise, m):
    """The 68.3 % chi-square interval covers the truth at its level.

    Over 400 seeds the 68.3 % chi-square interval (Howe's degrees of freedom) covers the truth
    68.3 % +- 3 binomial standard errors of the time.
    """
    seeds = 400
    coverage = _coverage(noise, m, seeds)
    assert abs(coverage - 0.683) < 3.0 * math.sqrt(0.683 * 0.317 / seeds)


def test_degrees_of_freedom_of_a_binned_cluster_are_those_of_the_bin_series():
    rng = np.random.default_rng(2)
    accumulator = AllanAccumulator(10.0, 3, exact_max=16, max_bins=256)
    accumulator.add(rng.standard_normal((20_000, 3)))
    result = accumulator.result()
    edf = equivalent_degrees_of_freedom(result)
    assert np.all(edf >= 1.0) and np.all(edf <= result.counts)
    assert np.all(np.diff(edf) < 0)  # fewer independent terms at longer averaging times
    with pytest.raises(NoiseError, match='alpha'):
        equivalent_degrees_of_freedom(result, 3)


def _model(**changes) -> NoiseModel:
    values = dict(white_noise_density=(1e-4, 2e-4, 3e-4), bias_instability=(5e-5, 0.0, 2e-5),
                  bias_instability_tau=(100.0, 50.0, 300.0), random_walk=(1e-6, 2e-6, 0.0), update_rate=200.0,
                  source='static_run', quantization=(1e-7, 0.0, 0.0), rate_ramp=(0.0, 0.0, 1e-9))
    values.update(changes)
    return NoiseModel(**values)


def test_model_allan_deviation_is_the_sum_of_the_five_terms():
    model = _model()
    taus = np.array([0.01, 1.0, 100.0, 1e4])
    q, n, b, k, r = (np.array(getattr(model, name)) for name in TERMS)
    expected = 3 * q ** 2 / taus[:, None] ** 2 + n ** 2 / taus[:, None] + (2 * math.log(2) / math.pi) * b ** 2 \
        + k ** 2 * taus[:, None] / 3 + r ** 2 * taus[:, None] ** 2 / 2
    assert np.allclose(model.allan_variance(taus), expected, rtol=1e-12)
    assert np.allclose(model.allan_deviation(taus), np.sqrt(expected))
    assert FLICKER_FLOOR == pytest.approx(0.6643, abs=1e-4)
    assert model.sample_variance() == pytest.approx(tuple(model.allan_variance([1.0 / 200.0])[0]), rel=1e-12)
    white = _model(bias_instability=(0.0,) * 3, random_walk=(0.0,) * 3, quantization=(0.0,) * 3, rate_ramp=(0.0,) * 3)
    assert white.sample_variance() == pytest.approx(tuple(w * w * 200.0 for w in white.white_noise_density), rel=1e-12)
    only_quantization = _model(white_noise_density=(0.0, 1e-4, 0.0))
    assert only_quantization.sample_variance()[0] > 0.0  # never 0 (REP 145: unknown) while the model has noise


@pytest.mark.parametrize(('key', 'value', 'match'), [
    ('white_noise_density', (1.0, -1.0, 0.0), r'white_noise_density\[y\]'),
    ('random_walk', (1.0, math.nan, 0.0), r'random_walk\[y\]'),
    ('bias_instability', (1.0, 2.0), 'three numbers'),
    ('bias_instability_tau', (0.0, 1.0, 1.0), r'bias_instability_tau\[x\]: expected a positive'),
    ('update_rate', 0.0, 'update_rate'),
    ('source', 'guess', 'source'),
])
def test_model_refuses_bad_values(key, value, match):
    with pytest.raises(NoiseError, match=match):
        _model(**{key: value})


def test_model_mapping_round_trips_and_names_bad_keys():
    model = _model(bias_instability_tau=(100.0, math.inf, 300.0))
    assert noise_model_from_mapping(model.to_mapping(), 'noise') == model
    assert model.to_json()['bias_instability_tau'] == [100.0, None, 300.0]
    assert json.loads(json.dumps(model.to_json(), allow_nan=False))['white_noise_density'] == [1e-4, 2e-4, 3e-4]
    with pytest.raises(NoiseError, match='noise.colour: unknown key'):
        noise_model_from_mapping({**model.to_mapping(), 'colour': 1}, 'noise')
    with pytest.raises(NoiseError, match='noise: missing key random_walk'):
        noise_model_from_mapping({k: v for k, v in model.to_mapping().items() if k != 'random_walk'}, 'noise')


def test_floor_tau_is_where_white_noise_and_random_walk_cross():
    white, walk = (1e-4, 2e-4, 1e-4), (1e-6, 1e-6, 0.0)
    analytic = floor_tau(white, (0.0,) * 3, walk)
    assert analytic[0] == pytest.approx(math.sqrt(3) * 1e-4 / 1e-6) and math.isinf(analytic[2])
    searched = floor_tau(white, (0.0,) * 3, walk, taus=(1.0, 1e5))
    assert searched[0] == pytest.approx(analytic[0], rel=0.01) and searched[1] == pytest.approx(analytic[1], rel=0.01)


def _exact_allan(model: NoiseModel, samples: int, rate: float) -> AllanVariance:
    clusters = cluster_sizes(samples // 3, 2)
    taus = clusters / rate
    return AllanVariance(taus=taus, avar=model.allan_variance(taus), counts=samples - 2 * clusters + 1,
                         clusters=clusters, strides=np.ones(len(clusters), dtype=np.int64), rate=rate,
                         samples=samples)


positive = st.floats(0.1, 10.0)


@settings(max_examples=40, deadline=None)
@given(positive, positive, positive, positive, st.booleans(), st.booleans())
def test_fit_recovers_every_term_of_a_noise_free_allan_variance(white, bias, walk, quantum, with_q, with_r):
    """On an Allan variance that is exactly a model's, the fit returns that model (or a simpler one that follows it)."""
    truth = _model(white_noise_density=(white * 1e-4,) * 3, bias_instability=(bias * 1e-5, 0.0, bias * 1e-5),
                   random_walk=(walk * 1e-7, walk * 1e-7, 0.0),
                   quantization=(quantum * 1e-6 if with_q else 0.0,) * 3,
                   rate_ramp=(1e-9 * walk if with_r else 0.0, 0.0, 0.0))
    allan = _exact_allan(truth, 10_000_000, 100.0)
    fit = fit_noise(allan, source='static_run')
    fitted = fit.model
    error = allan_terms(allan.taus)[:, None, :] * np.abs(fitted.coefficients() - truth.coefficients())
    for axis in range(3):
        dropped = (truth.coefficients()[axis] > 0.0) & (fitted.coefficients()[axis] == 0.0)
        if not np.any(dropped):
            # every term's contribution, at every averaging time, within 1e-5 of the Allan variance there
            assert np.all(error[:, axis] <= 1e-5 * allan.avar[:, axis, None])
        else:
            # a term the record cannot show (its share at the longest averaging times within their
            # few degrees of freedom) is left out: the simpler model still follows the curve, and a
            # walk left out lies under the bound written for it
            assert fit.axes[axis].within
            assert not dropped[TERMS.index('random_walk')] or truth.random_walk[axis] <= fitted.random_walk_bound[axis]
        assert not fitted.gauss_markov and not any(fitted.filter_share)
    assert fitted.source == 'static_run' and fitted.update_rate == 100.0


def test_fit_of_chosen_terms_leaves_the_others_zero_and_recovers_those_it_fits():
    """A white + bias-instability Allan variance fitted with those terms only (as a run's own residual is)."""
    truth = _model(white_noise_density=(2e-4, 1e-4, 3e-4), bias_instability=(1e-5, 3e-5, 0.0),
                   random_walk=(0.0, 0.0, 0.0), quantization=(0.0, 0.0, 0.0), rate_ramp=(0.0, 0.0, 0.0))
    allan = _exact_allan(truth, 10_000_000, 100.0)
    fitted = fit_noise_model(allan, source='residual', terms=('white_noise_density', 'bias_instability'))
    assert fitted.random_walk == (0.0, 0.0, 0.0) and fitted.rate_ramp == (0.0, 0.0, 0.0)
    assert fitted.quantization == (0.0, 0.0, 0.0)
    assert np.allclose(fitted.white_noise_density, truth.white_noise_density, rtol=1e-4)
    assert np.allclose(fitted.bias_instability, truth.bias_instability, rtol=1e-4, atol=1e-9)
    with pytest.raises(NoiseError, match='unknown terms flicker'):
        fit_noise_model(allan, source='residual', terms=('flicker',))
    with pytest.raises(NoiseError, match='no term'):
        fit_noise_model(allan, source='residual', terms=())


def test_fit_refuses_too_short_a_run():
    with pytest.raises(NoiseError, match='averaging times'):
        fit_noise_model(allan_variance(np.zeros((20, 3)), 10.0), source='residual')


def test_fit_of_white_noise_gives_its_density():
    """White noise of per-sample deviation s at rate f: density s / sqrt(f), within the estimate's error."""
    rng = np.random.default_rng(5)
    sigma, rate = np.array([0.01, 0.02, 0.005]), 100.0
    result = allan_variance(rng.standard_normal((300_000, 3)) * sigma, rate, per_octave=2)
    fitted = fit_noise_model(result, source='static_run')
    # tau=0.01 s alone has 3e5 degrees of freedom: the density to well under 1 %
    assert np.allclose(fitted.white_noise_density, sigma / math.sqrt(rate), rtol=0.01)
    low, high = confidence_interval(result.avar, equivalent_degrees_of_freedom(result), 0.999)
    model = fitted.allan_variance(result.taus)
    assert np.all((low <= model) & (model <= high))  # the fitted model inside every 99.9 % interval


# ----- Kalibr ---------------------------------------------------------------------------------------


def test_kalibr_file_round_trips_per_axis(tmp_path):
    models = {'accel': _model(source='residual'), 'gyro': _model(white_noise_density=(1e-5, 1e-5, 2e-5))}
    path = tmp_path / 'imu.yaml'
    write_kalibr(path, models, rostopic='/imu/data_raw')
    import yaml
    raw = yaml.safe_load(path.read_text())
    assert raw['gyroscope_noise_density'] == pytest.approx(2e-5, rel=1e-6)  # the largest axis
    assert raw['accelerometer_random_walk'] == pytest.approx(2e-6, rel=1e-6)
    assert raw['rostopic'] == '/imu/data_raw' and raw['update_rate'] == 200.0
    back = read_kalibr(path)
    for sensor, model in models.items():
        for name in (*TERMS, 'bias_instability_tau'):
            assert np.allclose(getattr(back[sensor], name), getattr(model, name), rtol=1e-6)
        assert back[sensor].source == 'file'
    with pytest.raises(OutputError):
        write_kalibr(path, models, rostopic='/imu')
    write_kalibr(path, models, rostopic='/imu', force=True)


def test_a_plain_kalibr_file_gives_the_same_numbers_on_every_axis():
    models, topic = kalibr_from_mapping({'gyroscope_noise_density': 1.7e-4, 'gyroscope_random_walk': 2e-5,
                                         'accelerometer_noise_density': 2e-3, 'accelerometer_random_walk': 3e-3,
                                         'rostopic': '/imu0', 'update_rate': 200})
    assert topic == '/imu0' and set(models) == {'accel', 'gyro'}
    gyro = models['gyro']
    assert gyro.white_noise_density == (1.7e-4,) * 3 and gyro.random_walk == (2e-5,) * 3
    assert gyro.bias_instability == (0.0,) * 3  # Kalibr has none: documented
    assert gyro.bias_instability_tau[0] == pytest.approx(math.sqrt(3) * 1.7e-4 / 2e-5)
    assert gyro.update_rate == 200.0 and gyro.source == 'file'


@pytest.mark.parametrize(('raw', 'match'), [
    ([1, 2], 'expected a Kalibr-style mapping'),
    ({'gyroscope_noise_density': 1e-4, 'gyroscope_random_walk': 1e-5}, 'update_rate: missing'),
    ({'gyroscope_noise_density': 1e-4, 'update_rate': 100}, 'gyroscope_random_walk: missing'),
    ({'gyroscope_noise_density': 1e-4, 'gyroscope_random_walk': 1e-5, 'update_rate': -1}, 'update_rate'),
    ({'gyroscope_noise_density': 'high', 'gyroscope_random_walk': 1e-5, 'update_rate': 100}, 'expected a number'),
    ({'gyroscope_noise_density': 1e-4, 'gyroscope_random_walk': 1e-5, 'update_rate': 100, 'gyro_bias': 1},
     'gyro_bias: unknown key'),
    ({'update_rate': 100, 'rostopic': '/imu'}, 'no accelerometer'),
    ({'gyroscope_noise_density': 1e-4, 'gyroscope_noise_density_xyz': [1e-4, 3e-4, 1e-4],
      'gyroscope_random_walk': 1e-5, 'update_rate': 100}, 'not the largest'),
    ({'gyroscope_noise_density': 1e-4, 'gyroscope_noise_density_xyz': [1e-4, 1e-4],
      'gyroscope_random_walk': 1e-5, 'update_rate': 100}, 'three numbers'),
])
def test_bad_kalibr_files_are_refused_with_one_line(raw, match):
    with pytest.raises(NoiseError, match=match):
        kalibr_from_mapping(raw)


def test_unreadable_noise_files_are_named(tmp_path):
    with pytest.raises(NoiseError, match='no such noise file'):
        read_kalibr(tmp_path / 'missing.yaml')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('a: [1\n')
    with pytest.raises(NoiseError, match='cannot read'):
        read_kalibr(bad)
    assert 'rostopic: ""' in kalibr_text({'gyro': _model()}, rostopic='')


def test_allan_terms_columns_are_the_unit_terms():
    taus = np.array([2.0])
    assert np.allclose(allan_terms(taus)[0], [3 / 4, 1 / 2, FLICKER_FLOOR ** 2, 2 / 3, 2.0])


term = st.floats(0.0, 1e3, allow_subnormal=False)
triple = st.tuples(term, term, term)


@settings(max_examples=60, deadline=None)
@given(triple, triple, triple, triple, triple, triple, st.floats(0.1, 1e5))
def test_any_model_round_trips_through_the_kalibr_text(white, bias, walk, bound, quantum, ramp, rate):
    """What is written reads back: the walk where measured, its bound where not; a density or walk of 0 refused."""
    import yaml
    tau = floor_tau(white, bias, walk, quantum, ramp, taus=(1e-3, 1e6))
    bound = tuple(0.0 if k > 0.0 else b for k, b in zip(walk, bound))
    model = NoiseModel(white_noise_density=white, bias_instability=bias, bias_instability_tau=tau, random_walk=walk,
                       update_rate=rate, source='residual', quantization=quantum, rate_ramp=ramp,
                       random_walk_bound=bound)
    if not any(w > 0.0 or b > 0.0 for w, b in zip(walk, bound)) or not any(model.sample_variance()):
        with pytest.raises(NoiseError, match='Kalibr refuses a value <= 0'):
            kalibr_text({'gyro': model}, rostopic='/imu')
        return
    raw = yaml.safe_load(kalibr_text({'gyro': model}, rostopic='/imu'))
    assert non_finite_number(raw) is None  # no floor on an axis: null there, never .nan or .inf
    back, topic = kalibr_from_mapping(raw)
    assert topic == '/imu' and set(back) == {'gyro'}
    written = kalibr_values(model)
    assert np.allclose(back['gyro'].white_noise_density, written['noise_density'], rtol=1e-6, atol=0.0)
    for name in ('bias_instability', 'random_walk', 'random_walk_bound', 'quantization', 'rate_ramp',
                 'bias_instability_tau'):
        assert np.allclose(getattr(back['gyro'], name), getattr(model, name), rtol=1e-6, atol=0.0), name
    assert back['gyro'].update_rate == rate
