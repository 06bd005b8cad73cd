"""The noise model every plain ``tak_calib fit`` writes (issue 39 item 1), against the simulators' truth.

The long run (20 seeds, a pool of 16 records and a chamber run each, the watch over held-out records)
is ``bench/bench_rest_noise.py``; here a few short seeds of each generator, the estimator's parts, and
every kind of record through the command.
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from paths import REPO
from tak_thermo_ros.cli import main
from tak_thermo_ros.core.link.rest_noise import ChannelNoise
from tak_thermo_ros.core.noise.model import UPPER_SIGMAS, NoiseModel, noise_model_from_mapping
from tak_thermo_ros.core.noise.rests import StretchWindows
from tak_thermo_ros.core.noise.wander import RestMeans, fit_wander
from tak_thermo_ros.core.noise.white import ShortSums, White, white_noise
from tak_thermo_ros.core.simulation.everyday import everyday_scenario, simulate_everyday_record
from tak_thermo_ros.core.simulation.noise import bias_wander, filtered_white
from tak_thermo_ros.formats.bag import write_driver_record
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.formats.calibration_sections import noise_to_mapping

sys.path.insert(0, str(REPO / 'bench'))
from bench_rest_noise import judge_file, unit_yaml  # noqa: E402
from everyday_check import month, pool_of  # noqa: E402

TERMS = ('white_noise_density', 'bias_instability', 'random_walk')


def short_sums(samples: np.ndarray, rate: float, window: int, stretch: int) -> ShortSums:
    """The within-stretch sums of ``(n, c)`` samples cut into stretches of ``stretch`` samples."""
    usable = len(samples) // stretch * stretch
    pieces = samples[:usable].reshape(-1, stretch, samples.shape[1])
    one = 0.5 * np.sum(np.diff(pieces, axis=1) ** 2, axis=(0, 1))
    whole = stretch // window * window
    means = pieces[:, :whole].reshape(len(pieces), -1, window, samples.shape[1]).mean(axis=2)
    return ShortSums(1.0 / rate, window / rate, one, len(pieces) * (stretch - 1),
                     0.5 * np.sum(np.diff(means, axis=1) ** 2, axis=(0, 1)), len(pieces) * (means.shape[1] - 1))


def test_white_noise_within_stretches_and_a_drivers_filter():
    """White noise: its density within three of its errors; a driver's low-pass: its time constant within 15 %."""
    rng = np.random.default_rng(4)
    rate, density = 50.0, 1.2e-4
    white = rng.standard_normal((200_000, 2)) * density * math.sqrt(rate)
    filtered = filtered_white(rng, 200_000, rate, density, 0.06, 1)
    found = white_noise(short_sums(np.column_stack([white, filtered]), rate, 25, 1500))
    for channel in range(3):
        assert abs(found[channel].density - density) < 3.0 * found[channel].error, found[channel]
        assert found[channel].error < 0.02 * density
    assert found[0].filter_time_constant == 0.0 and found[0].quantization == 0.0
    assert found[2].filter_time_constant == pytest.approx(0.06, rel=0.15)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(1, 3000), min_size=1, max_size=6))
def test_stretch_windows_are_the_same_whatever_the_blocks(cuts):
    """The windows of a run (a reference change, a gap) are the same however the pass cuts it into blocks."""
    rng = np.random.default_rng(1)
    count = 4000
    stamps = np.arange(count, dtype=np.int64) * 20_000_000
    stamps[2500:] += 3_000_000_000
    reference = np.zeros((count, 3))
    reference[1200:] = 9.8
    values = rng.standard_normal((count, 3))
    temperature = np.linspace(20.0, 21.0, count)

    def rows(edges):
        windows = StretchWindows()
        for start, end in zip(edges[:-1], edges[1:]):
            windows(_Block(stamps, values, reference, temperature, start, end))
        return windows.rows()

    whole = rows([0, count])
    edges = sorted({0, count, *(c for c in cuts if c < count)})
    np.testing.assert_array_equal(rows(edges), whole)
    assert len(np.unique(whole[:, 0])) == 3  # three stretches: the reference change, the gap


class _Block:
    """An aligned block's fields (what :class:`StretchWindows` reads)."""

    def __init__(self, stamps, values, reference, temperature, start, end):
        self.stamp_ns, self.counts = stamps[start:end], values[start:end]
        self.reference, self.temp_code = reference[start:end], temperature[start:end]

    def __len__(self):
        return len(self.stamp_ns)


def test_merged_and_segmented_means_keep_their_averages():
    """Merging neighbours keeps the time-weighted mean and the total time; an hour-long piece gets its own level."""
    count = 300
    start = np.arange(count) * 65.0
    means = RestMeans(residual=np.sin(np.arange(count)), start_s=start, end_s=start + 60.0,
                      duration_s=np.full(count, 60.0), white=np.full(count, 1.0 / 60.0),
                      record=np.zeros(count, dtype=np.int64), design=np.ones((count, 1)), extra=np.zeros(count))
    merged = means.merged(most=50)
    assert len(merged) == 50 and merged.duration_s.sum() == pytest.approx(count * 60.0)
    assert np.sum(merged.residual * merged.duration_s) == pytest.approx(np.sum(means.residual * 60.0))
    assert merged.white == pytest.approx(np.full(50, 1.0 / 360.0))
    pieces = means.segmented(3600.0)
    assert len(np.unique(pieces.record)) == math.ceil(start[-1] / 3600.0 + 1e-9)
    assert pieces.design.shape[1] == len(np.unique(pieces.record)) + 1


def test_wander_without_contrasts_is_bounded_by_the_window():
    """One mean per record: nothing tells the wander, both terms written as the window's bound, never 0 as known."""
    means = RestMeans(residual=np.array([1e-4, -2e-4]), start_s=np.zeros(2), end_s=np.full(2, 10.0),
                      duration_s=np.full(2, 10.0), white=np.full(2, 0.1), record=np.array([0, 1]),
                      design=np.eye(2), extra=np.zeros(2))
    found = fit_wander(means, White(1e-4, 0.0), ceiling=(3e-4, 4e-5))
    assert found.contrasts == 0
    assert (found.flicker.value, found.flicker.bound) == (0.0, 3e-4)
    assert (found.walk.value, found.walk.bound) == (0.0, 4e-5)


def test_the_wander_of_one_long_stretch_over_seeds():
    """The simulator's flicker and walk in an hour's minute means: seen within 2.5 errors, or bounded above.

    Six seeds, both kinds; the likelihood of the means under the watch's own covariance.
    """
    covered, count = 0, 0
    for seed in range(6):
        flicker, walk = (4e-4, 0.0) if seed % 2 else (0.0, 2e-5)
        rng = np.random.default_rng(seed)
        rate, hours, density = 5.0, 1.5, 1.3e-3
        n = int(hours * 3600 * rate)
        signal = (bias_wander([seed, 3], n, rate, (flicker, 0.0, 0.0), (100.0, 1.0, 1.0), (walk, 0.0, 0.0))[:, 0]
                  + rng.standard_normal(n) * density * math.sqrt(rate))
        per = int(60 * rate)
        k = n // per
        start = np.arange(k) * 60.0
        temperature = np.linspace(-1.0, 1.0, k)
        means = RestMeans(residual=signal[:k * per].reshape(k, per).mean(axis=1), start_s=start,
                          end_s=start + 60.0 - 1.0 / rate, duration_s=np.full(k, 60.0), white=np.full(k, 1.0 / 60.0),
                          record=np.zeros(k, dtype=np.int64),
                          design=np.column_stack([temperature ** p for p in range(4)]), extra=np.zeros(k))
        found = fit_wander(means, White(density, 0.0))
        for term, truth in ((found.flicker, flicker), (found.walk, walk)):
            count += 1
            covered += abs(term.value - truth) <= 2.5 * term.error if term.seen else truth <= term.bound
        present = found.flicker if flicker else found.walk
        assert present.seen, (seed, found)  # an hour of minute means shows a term of this size
    assert covered >= count - 1, covered


def _covered(judged: dict) -> tuple[int, int]:
    flags = [flag for sensor in ('accel', 'gyro') for term in TERMS for flag in judged[sensor]['covered'][term]]
    return sum(flags), len(flags)


def _wander_not_understated(judged: dict) -> float:
    """The smallest ratio of the watch's wander with the file to the truth's (over sensors, axes, separations)."""
    return min(min(min(axis) for axis in judged[sensor]['wander_ratio']) for sensor in ('accel', 'gyro'))


def test_a_pools_noise_model_over_seeds_everyday_simulator():
    """Everyday pools (6 records of 10 minutes): the terms cover the truth; the watch's wander is never understated.

    Through the path ``fit`` takes (the rests found from each record, the pool's fit, its rests' noise).
    """
    from tak_thermo_ros.core.fit.handheld import HandheldSettings
    from tak_thermo_ros.core.fit.pool import fit_pool
    from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
    from tak_thermo_ros.passes.rest_noise import rests_noise
    covered = total = 0
    for seed in range(3):
        scenario, habits = month(seed, records=6, held_out=0, minutes=10.0, rate_hz=10.0)
        pool = pool_of([simulate_everyday_record(scenario, habits, index) for index in range(6)])
        fitted = fit_pool(pool, HandheldSettings())
        results = fitted.fit.results
        unit = UnitCalibration(InputKind.IMU, results['accel'].calibration, results['gyro'].calibration)
        found = rests_noise(fitted.record, unit, gravity=scenario.gravity, latitude=None)
        unit = replace(unit, accel=replace(unit.accel, noise=found['accel'].model),
                       gyro=replace(unit.gyro, noise=found['gyro'].model))
        judged = judge_file(unit, {sensor: scenario.noise_truth(sensor) for sensor in ('accel', 'gyro')})
        good, count = _covered(judged)
        covered, total = covered + good, total + count
        assert _wander_not_understated(judged) >= 0.75, judged
        assert found['accel'].shared and found['gyro'].records == 6
    assert covered >= 0.9 * total, (covered, total)


@pytest.fixture(scope='module')
def chamber_runs(tmp_path_factory):
    """Two chamber runs of the everyday unit (1.2 h at 10 Hz, six faces, a minute each), fitted by plain ``fit``."""
    root = tmp_path_factory.mktemp('chamber')
    scenario, _ = everyday_scenario({'sample_rate_hz': 10.0})
    out = []
    for seed in range(2):
        raw = {'output': 'imu', 'sample_rate_hz': 10.0, 'seed': seed, 'start_celsius': 5.0,
               'plateaus_celsius': [5.0, 35.0], 'ramp_celsius_per_minute': 1.0, 'plateau_hours': 0.1,
               'board_lag_s': 120.0, 'dwell_s': 60.0,
               'positions': [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
               **unit_yaml(scenario)}
        path = root / f'chamber{seed}.yaml'
        path.write_text(yaml.safe_dump(raw), encoding='utf-8')
        assert main(['simulate', str(root / f'run{seed}'), '--scenario', str(path)]) == 0
        assert main(['fit', str(root / f'run{seed}'), '-o', str(root / f'p{seed}.yaml'), '--no-progress']) == 0
        out.append(root / f'p{seed}.yaml')
    return scenario, out


def test_a_chamber_runs_noise_model_over_seeds_table_simulator(chamber_runs):
    """The chamber simulator (another generator): the terms cover the truth; the watch's wander not understated."""
    scenario, files = chamber_runs
    covered = total = 0
    for params in files:
        unit = load_unit(params)
        assert unit.accel.noise.source == unit.gyro.noise.source == 'fit'
        judged = judge_file(unit, {sensor: scenario.noise_truth(sensor) for sensor in ('accel', 'gyro')})
        good, count = _covered(judged)
        covered, total = covered + good, total + count
        assert _wander_not_understated(judged) >= 0.75, judged
    assert covered >= 0.9 * total, (covered, total)


def test_the_watch_counts_a_term_at_its_upper_limit_and_the_file_keeps_it():
    """A seen term at value + 1.645 errors, an unseen one at its bound; errors and bounds written and read back."""
    model = NoiseModel(white_noise_density=(1e-4,) * 3, bias_instability=(2e-5, 0.0, 1e-5),
                       bias_instability_tau=(math.inf,) * 3, random_walk=(0.0, 1e-6, 0.0), update_rate=50.0,
                       source='fit', random_walk_bound=(3e-6, 0.0, 2e-6), bias_instability_bound=(0.0, 4e-5, 0.0),
                       white_noise_density_error=(1e-6,) * 3, bias_instability_error=(5e-6, 0.0, 1e-5),
                       random_walk_error=(0.0, 4e-7, 0.0))
    upper = [ChannelNoise.axis(model, axis) for axis in range(3)]
    assert upper[0].flicker == pytest.approx(2e-5 + UPPER_SIGMAS * 5e-6) and upper[0].walk == 3e-6
    assert upper[1].flicker == 4e-5 and upper[1].walk == pytest.approx(1e-6 + UPPER_SIGMAS * 4e-7)
    mapping = noise_to_mapping(model)
    assert mapping['bias_instability_bound'] == [0.0, 4e-5, 0.0] and 'filter_share' not in mapping
    again = noise_model_from_mapping(mapping, 'noise')
    assert again == replace(model, bias_instability_tau=again.bias_instability_tau)
    assert 'random_walk_error' not in noise_to_mapping(replace(model, random_walk_error=(0.0,) * 3))


def _fit(capsys, *argv) -> list[str]:
    """``tak_calib fit ARGV``: its statements (a wrapped line joined)."""
    from tak_thermo_ros.cli.common import unwrap
    assert main(['fit', *argv, '--no-progress']) == 0
    return unwrap(capsys.readouterr().out)


def test_plain_fit_writes_a_noise_model_for_every_kind_of_record(capsys, tmp_path):
    """A pool, a hand-held record, a static run, a flight log: each file holds both sensors' noise (source ``fit``).

    The line says where it came from; ``validate`` runs the watch with the file; ``--noise`` still overrides.
    """
    from tak_thermo_ros.formats.kalibr import write_kalibr
    docs = REPO / 'docs' / 'scenarios'
    scenario, habits = everyday_scenario({'sample_rate_hz': 10.0, 'seed': 5,
                                          'everyday': {'records': 3, 'record_minutes': 8.0}})
    (tmp_path / 'pool').mkdir()
    for index in range(3):
        write_driver_record(tmp_path / 'pool' / f'rec{index}', simulate_everyday_record(scenario, habits, index).record)
    assert main(['simulate', str(tmp_path / 'handheld'), '--scenario', str(docs / 'handheld_six_faces.yaml')]) == 0
    assert main(['simulate', str(tmp_path / 'static'), '--scenario', str(docs / 'pipeline_static.yaml')]) == 0
    assert main(['simulate', str(tmp_path / 'warm.ulg'), '--scenario', str(docs / 'px4_warm_up.yaml')]) == 0
    capsys.readouterr()
    for name, record, where in (('pool', tmp_path / 'pool', 'rests of 3 records'),
                                ('handheld', tmp_path / 'handheld', 'rests'),
                                ('static', tmp_path / 'static', 'stretches'),
                                ('ulog', tmp_path / 'warm.ulg', 'stretches')):
        params = tmp_path / f'{name}.yaml'
        lines = _fit(capsys, str(record), '-o', str(params))
        said = next(line for line in lines if line.startswith('noise model of the accelerometer and gyroscope'))
        assert where in said, (name, said)
        unit = load_unit(params)
        for sensor in ('accel', 'gyro'):
            noise = unit.sensor(sensor).noise
            assert noise is not None and noise.source == 'fit', (name, sensor)
            assert all(v > 0.0 for v in noise.white_noise_density) and all(e > 0.0 for e in
                                                                           noise.white_noise_density_error)
            for term in ('bias_instability', 'random_walk'):  # known, or bounded: never a 0 that reads as known
                values, bounds = getattr(noise, term), getattr(noise, f'{term}_bound')
                assert all(v > 0.0 or b > 0.0 for v, b in zip(values, bounds)), (name, sensor, term)
        if name != 'ulog':  # a log of separate sensor stamps: the watch takes messages that carry both
            one = record / 'rec0' if name == 'pool' else record
            assert main(['validate', str(one), '--params', str(params), '--no-progress']) == 0
            out = capsys.readouterr().out
            assert 'calibration watch' in out and 'calibration watch: off' not in out, (name, out[-400:])
    kalibr = tmp_path / 'imu.yaml'
    write_kalibr(kalibr, {sensor: replace(load_unit(tmp_path / 'static.yaml').sensor(sensor).noise, source='file')
                          for sensor in ('accel', 'gyro')}, rostopic='/imu/data_raw')
    lines = _fit(capsys, str(tmp_path / 'static'), '-o', str(tmp_path / 'given.yaml'), '--noise', str(kalibr))
    assert any(line.startswith(f'noise model: accel, gyro from {kalibr}') for line in lines), lines
    assert load_unit(tmp_path / 'given.yaml').gyro.noise.source == 'file'
