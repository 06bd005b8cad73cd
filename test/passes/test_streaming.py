"""The streamed passes over a bag equal the whole-bag path: reader blocks, fit, apply, diagnose subsample."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from conftest import SHORT
from tak_thermo_ros.formats.bag import (
    AUX_TYPES,
    DECODERS,
    Topics,
    iter_blocks,
    read_driver_record,
    read_imu_messages,
    read_record,
    write_driver_record,
    write_imu,
    write_record,
)
from tak_thermo_ros.core.link.correction import UnitCorrector, acceleration_variance
from tak_thermo_ros.core.effects import ThermalLag, Warmup
from tak_thermo_ros.core.fit import fit_calibration, fit_model
from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.passes.apply import apply_bag
from tak_thermo_ros.passes.diagnose import bounded_run
from tak_thermo_ros.passes.fit import fit_bag
from tak_thermo_ros.passes.run import FitSettings, StreamOptions
from tak_thermo_ros.formats.records import open_record

SMALL = StreamOptions(topics=Topics(), progress=False, block_samples=500)
DRIVER = replace(SHORT, output='imu', plateau_hours=0.1, seed=8,
                 positions=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (-1.0, 0.0, 0.0)),
                 table_rates=(0.0, 1.0, -1.0, 0.5))


@pytest.fixture(scope='module', params=['mcap', 'sqlite3'])
def counts_bag(request, tmp_path_factory):
    run = simulate(replace(SHORT, plateau_hours=0.1, seed=7))
    path = tmp_path_factory.mktemp('counts') / 'run'
    write_record(path, run.record, storage=request.param)
    return path, run


@pytest.fixture(scope='module')
def driver_bag(tmp_path_factory):
    run = simulate(DRIVER)
    path = tmp_path_factory.mktemp('driver') / 'run'
    write_driver_record(path, run.driver)
    return path, run


def test_blocks_hold_every_message_in_log_order(counts_bag):
    """Concatenated blocks give the arrays of read_record, both storages."""
    path, _ = counts_bag
    whole = read_record(path, progress=False)
    blocks = list(iter_blocks(path, kind=InputKind.COUNTS, block_samples=333, progress=False))
    assert max(len(b.counts) for b in blocks) == 333
    assert np.array_equal(np.concatenate([b.counts_stamp_ns for b in blocks]), whole.counts_stamp_ns)
    assert np.array_equal(np.concatenate([b.counts for b in blocks]), whole.counts)
    assert np.array_equal(np.concatenate([b.temp_code for b in blocks]), whole.temp_code)
    assert np.array_equal(np.concatenate([b.reference for b in blocks]), whole.reference)
    assert all(b.nominal_scale == whole.nominal_scale and b.frame_id == whole.frame_id for b in blocks)


def test_driver_blocks_hold_every_message(driver_bag):
    path, _ = driver_bag
    whole = read_driver_record(path, progress=False)
    blocks = list(iter_blocks(path, kind=InputKind.IMU, block_samples=1000, progress=False))
    for name in ('stamp_ns', 'accel', 'gyro', 'orientation', 'orientation_covariance', 'temperature',
                 'reference', 'rate_reference'):
        assert np.array_equal(np.concatenate([getattr(b, name) for b in blocks]), getattr(whole, name)), name


def test_streamed_fit_of_a_bag_equals_the_in_memory_fit(counts_bag):
    """fit_bag in blocks of 500 messages equals fit_calibration of the whole bag to 1e-9."""
    path, _ = counts_bag
    record = read_record(path, progress=False)
    expected = fit_calibration(align(record, settle_time_s=20.0), nominal_scale=record.nominal_scale)
    got = fit_bag(open_record(path, topics=SMALL.topics), FitSettings(effects={}, settle_time_s=20.0),
                  SMALL).results['accel']
    assert got.samples == expected.samples and got.dropped == expected.dropped
    for a, b in zip(got.calibration.axes, expected.calibration.axes):
        for name in ('scale', 'offset', 'offset_span', 'residual_rms'):
            assert getattr(a, name) == pytest.approx(getattr(b, name), rel=1e-9)
        np.testing.assert_allclose(a.offset_shape, b.offset_shape, rtol=1e-9, atol=1e-12)


def test_streamed_apply_writes_what_the_whole_bag_path_writes(driver_bag, tmp_path):
    """Driver bag with effects with memory: every message field equal to one correction of the whole run."""
    path, run = driver_bag
    truth = run.unit_truth
    unit = UnitCalibration(InputKind.IMU, replace(truth.accel, effects=(ThermalLag(tau_s=200.0, slope_x=0.01),)),
                           replace(truth.gyro, effects=(Warmup(tau_s=300.0, amplitude_z=0.001),)))
    driver = read_driver_record(path, progress=False)
    record = driver.six_channels()
    samples = align(record, use_reference=False)
    corrected = UnitCorrector(unit).correct(samples.counts, samples.temp_code, stamp_s=samples.stamp_s)
    expected_path = tmp_path / 'expected'
    write_imu(expected_path, samples.stamp_ns, record.frame_id, corrected[:, :3], acceleration_variance(unit.accel),
              topic=Topics.compensated_imu, angular_velocity=corrected[:, 3:6],
              angular_variance=acceleration_variance(unit.gyro), orientation=driver.orientation[samples.rows],
              orientation_covariance=driver.orientation_covariance[samples.rows])
    applied = apply_bag(open_record(path, topics=SMALL.topics), unit, tmp_path / 'streamed', SMALL)
    assert applied.written == len(samples)
    got = read_imu_messages(tmp_path / 'streamed', topic=Topics.compensated_imu)
    want = read_imu_messages(expected_path, topic=Topics.compensated_imu)
    for name in ('stamp_ns', 'orientation', 'orientation_covariance', 'angular_velocity',
                 'angular_velocity_covariance', 'linear_acceleration', 'linear_acceleration_covariance'):
        assert np.array_equal(getattr(got, name), getattr(want, name)), name
    assert got.frame_ids == want.frame_ids


def test_diagnose_subsample_is_bounded_and_spread(driver_bag):
    """At most about max_samples samples, from the whole run, with the whole run's drop counts."""
    path, _ = driver_bag
    driver = read_driver_record(path, progress=False)
    bounded = bounded_run(open_record(path, topics=SMALL.topics), SMALL, max_samples=300)
    whole = align(driver.channel('accel'))
    samples = bounded.samples['accel']
    assert bounded.stride == -(-len(driver.stamp_ns) // 300)
    assert 0.9 * 300 * len(whole) / len(driver.stamp_ns) < len(samples) <= 300
    assert samples.stamp_ns[0] - whole.stamp_ns[0] < bounded.stride * 2e9
    assert whole.stamp_ns[-1] - samples.stamp_ns[-1] < bounded.stride * 2e9
    assert np.all(np.isin(samples.stamp_ns, whole.stamp_ns))
    assert samples.dropped == whole.dropped and bounded.usable['accel'] == len(whole)


def test_effects_on_a_long_run_shapes_from_a_subsample_amplitudes_from_every_sample(tmp_path):
    """Two passes: tau_s searched on one sample in four, then every amplitude over the whole run.

    The streamed fit recovers the hidden effect within the noise (tau_s within 4.5 standard errors
    of the subsample's search, amplitudes within 4.5 standard errors of the whole run, the shape's
    error included), its residual sits at the noise floor, and it agrees with the in-memory fit of
    the whole run within the same errors.
    """
    truth = {'tau_s': 900.0, 'slope_x': 0.02, 'slope_z': -0.03}
    scenario = Scenario(plateau_hours=0.5, ramp_celsius_per_minute=1.0, board_lag_s=300.0, dwell_s=30.0,
                        sample_rate_hz=1.0, temp_code_every=1, seed=4, effects={'thermal_lag': truth})
    run = simulate(scenario)
    path = tmp_path / 'lag'
    write_record(path, run.record)
    samples = align(run.record)
    whole = fit_model(samples, effects=['thermal_lag'])
    streamed = fit_bag(open_record(path, topics=SMALL.topics),
                       FitSettings(effects={'accel': ['thermal_lag']}, max_effect_samples=len(samples) // 4), SMALL)
    result = streamed.results['accel']
    assert streamed.effect_stride['accel'] == 5 and result.samples == len(samples)
    effect = result.calibration.effects[0]
    errors = result.parameter_errors
    assert abs(effect['tau_s'] - truth['tau_s']) <= 4.5 * errors['thermal_lag.tau_s']
    for name in ('slope_x', 'slope_y', 'slope_z'):
        joint = whole.parameter_errors[f'thermal_lag.{name}']
        assert abs(effect[name] - truth.get(name, 0.0)) <= 4.5 * joint * 2.0, name
        assert abs(effect[name] - whole.calibration.effects[0][name]) <= 4.5 * joint * 2.0, name
    floor = np.array([math.sqrt(axis.noise_counts ** 2 + 1.0 / 12.0) for axis in scenario.unit])
    assert np.all(np.array([axis.residual_rms for axis in result.axes]) <= 1.1 * floor)
    for mine, theirs in zip(result.calibration.axes, whole.calibration.axes):
        assert mine.scale == pytest.approx(theirs.scale, rel=1e-4)


@pytest.mark.parametrize('supply_type', ['battery_state', 'float64'])
def test_block_decoder_equals_per_message_decoder_and_blocks_carry_the_recorded_signals(tmp_path, supply_type):
    """decoder='block' (cdr.decode_messages) and 'rosbags' give the same blocks; their aux joins to read_record's."""
    run = simulate(replace(SHORT, plateau_hours=0.05, plateaus_celsius=(10.0, 30.0), supply_voltage_drift=1.0,
                           record_supply='/power/battery_state', record_supply_type=supply_type, seed=9))
    path = tmp_path / 'run'
    write_record(path, run.record, aux_types={name: AUX_TYPES[supply_type] for name in run.record.aux})
    whole = read_record(path, progress=False)
    assert whole.aux
    by_decoder = {decoder: list(iter_blocks(path, kind=InputKind.COUNTS, block_samples=777, progress=False,
                                            decoder=decoder)) for decoder in DECODERS}
    fast, reference = by_decoder['block'], by_decoder['rosbags']
    assert len(fast) == len(reference) > 2
    for a, b in zip(fast, reference):
        for name in ('counts_stamp_ns', 'counts', 'temp_stamp_ns', 'temp_code', 'reference_stamp_ns', 'reference'):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert a.frame_id == b.frame_id and sorted(a.aux) == sorted(whole.aux) == sorted(b.aux)
    for name, (stamps, values) in whole.aux.items():
        assert np.array_equal(np.concatenate([block.aux[name][0] for block in fast]), stamps)
        assert np.array_equal(np.concatenate([block.aux[name][1] for block in fast]), values, equal_nan=True)


def test_streamed_apply_holds_a_recorded_signal_across_blocks(tmp_path):
    """An aux.

    Effect: blocks of 500 write the messages of one whole-run correction, the samples before the signal's first value
    dropped by name.
    """
    from tak_thermo_ros.core.records.record import require_signals
    run = simulate(replace(SHORT, plateau_hours=0.05, plateaus_celsius=(10.0, 30.0), supply_voltage_drift=2.0,
                           record_supply='/p', record_supply_type='float64', seed=12))
    record = run.record
    stamps, volts = record.aux['aux:/p']
    record = replace(record, aux={'aux:/p': (stamps[3:], volts[3:])})
    bag = tmp_path / 'run'
    write_record(bag, record)
    samples = require_signals(align(record), ['aux:/p'])
    unit = UnitCalibration(InputKind.COUNTS, fit_model(samples, effects=['aux:/p']).calibration)
    whole = require_signals(align(record, use_reference=False), ['aux:/p'])
    expected = UnitCorrector(unit).correct(whole.counts, whole.temp_code, stamp_s=whole.stamp_s, aux=whole.aux)
    applied = apply_bag(open_record(bag, topics=SMALL.topics), unit, tmp_path / 'imu', SMALL)
    assert applied.dropped == whole.dropped and applied.dropped['before_first_aux:/p'] > 0
    assert applied.written == len(whole)
    written = read_imu_messages(tmp_path / 'imu', topic=Topics().imu)
    assert np.array_equal(written.stamp_ns, whole.stamp_ns)
    assert np.array_equal(written.linear_acceleration, expected)


def test_a_recorded_signal_effect_on_a_long_run_is_fitted_in_two_passes(tmp_path):
    """``aux:`` terms: the shapes on one sample in four, the slopes over every sample with the signal held.

    The samples before the signal's first value are left out and counted, as in memory; the
    slopes recover the simulator's supply drift within 4.5 standard errors, and agree with the
    in-memory fit of the whole run.
    """
    from core.effects.test_aux_signal import supply_truth
    from tak_thermo_ros.core.records.record import require_signals
    run = simulate(replace(SHORT, plateau_hours=0.1, plateaus_celsius=(10.0, 30.0), supply_voltage_drift=3.0,
                           record_supply='/p', record_supply_type='float64', seed=14))
    stamps, volts = run.record.aux['aux:/p']
    record = replace(run.record, aux={'aux:/p': (stamps[5:], volts[5:])})
    bag = tmp_path / 'run'
    write_record(bag, record)
    samples = require_signals(align(record), ['aux:/p'])
    whole = fit_model(samples, effects=['aux:/p'])
    streamed = fit_bag(open_record(bag, topics=SMALL.topics),
                       FitSettings(effects={'accel': ['aux:/p']}, max_effect_samples=len(samples) // 4), SMALL)
    result = streamed.results['accel']
    assert streamed.effect_stride['accel'] > 1
    assert result.samples == len(samples) == streamed.usable['accel']
    assert result.dropped == samples.dropped and result.dropped['before_first_aux:/p'] > 0
    effect, truth = result.calibration.effects[0], supply_truth(3.0)
    for axis in 'xyz':
        name = f'aux:/p.slope_{axis}'
        joint = whole.parameter_errors[name]
        assert result.parameter_errors[name] >= 0.9 * joint, 'the shape\'s uncertainty is in the amplitude\'s error'
        assert abs(effect[f'slope_{axis}'] - truth[f'slope_{axis}']) <= 4.5 * joint, axis
        assert abs(effect[f'slope_{axis}'] - whole.calibration.effects[0][f'slope_{axis}']) <= 4.5 * joint, axis


def test_subsample_arrays_grow_beyond_the_expected_size_and_keep_every_stride_row(driver_bag):
    """The subsample's arrays double when a run holds more rows than expected.

    The rows kept are those of every_nth on the whole alignment, with the whole run's ignored counts.
    """
    from tak_thermo_ros.core.records.blocks import BlockAligner
    from tak_thermo_ros.core.records.blocks import Subsample, every_nth
    path, _ = driver_bag
    driver = read_driver_record(path, progress=False)
    whole = every_nth(align(driver.channel('accel')), 3)
    subsample, aligner = Subsample(3, expected=1), BlockAligner(use_reference=True, reference_expected=True)
    for block in iter_blocks(path, kind=InputKind.IMU, block_samples=200, progress=False):
        subsample(aligner.push(block.channel('accel')))
    subsample(aligner.finish())
    got = subsample.samples(aligner.dropped)
    assert subsample.capacity >= len(got) == len(whole) > 1
    for name in ('stamp_ns', 'counts', 'temp_code', 'reference', 'rows'):
        assert np.array_equal(getattr(got, name), getattr(whole, name)), name
    assert got.ignored_temp_codes == whole.ignored_temp_codes and got.dropped == whole.dropped
