"""The calibration watch (core/link/watch.py): rests online, the tests over seeds, learning, the turn-on offset."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from everyday_watch import (
    FAULTS,
    HABITS,
    LATITUDE,
    OFFSET_MOVED,
    SCENARIO,
    SLOPE_GROWTH,
    core_published,
    corrected_run,
    everyday_runs,
    learning_ratios,
    rest_ends_ns,
    watch_run,
    watch_unit,
)
from tak_thermo_ros import cli
from tak_thermo_ros.cli.common import unwrap
from tak_thermo_ros.core.link.correction import UnitCorrector
from tak_thermo_ros.core.link.online import OnlineCompensator
from tak_thermo_ros.core.link.learning import Adjustment, LearnedState, adjust, calibration_digest
from tak_thermo_ros.core.link.rests import REST_MAX_S, RestFinder, chi2_quantile_ratio
from tak_thermo_ros.core.link.watch import WatchSettings, WatchUnavailable
from tak_thermo_ros.core.values import DEG_PER_H
from tak_thermo_ros.core.records.stamps import NANOSECONDS
from tak_thermo_ros.formats.bag import read_imu_messages, write_driver_record
from tak_thermo_ros.formats.calibration_file import load_unit, save_unit
from tak_thermo_ros.formats.learned_file import load_learned, save_learned

SEEDS = range(20)
UNIT = watch_unit()
RATE = 0.05
"""The stated false-alarm rate per hour of rests (:data:`~tak_thermo_ros.core.link.watch.FALSE_ALARMS_PER_HOUR`)."""


def test_the_windows_threshold_is_the_offline_detectors_chi_square_quantile():
    """The node's quantile (no scipy) is scipy's, at most 2 % above it from 7 degrees of freedom."""
    from scipy.special import chdtri
    for dof in (7, 9, 19, 49, 99, 499, 999):
        assert 1.0 <= chi2_quantile_ratio(dof) / (chdtri(dof, 1e-4) / dof) <= 1.02


def test_rests_found_online_lie_in_the_true_rests_and_bounded_memory():
    """Rests found lie within the true rests, every true rest of 4 s or more is found, memory stays a window.

    Within a window's margin; a stillness longer than a minute is cut; the window buffer never
    holds more than a window.
    """
    simulated = everyday_runs(3, ('healthy',))['healthy']
    stamps, values, temperature = corrected_run(simulated, UNIT)
    found = []
    finder = RestFinder(UNIT.accel.noise, UNIT.gyro.noise, found.append)
    largest = 0
    for stamp, row, temp in zip(stamps.tolist(), values.tolist(), temperature.tolist()):
        finder.take(stamp, row, temp)
        largest = max(largest, len(finder._buffer))  # noqa: SLF001 - the bound itself
    finder.finish()
    assert largest <= finder.window_ns // finder.period_ns + 1
    true = [(simulated.record.stamp_ns[rows[0]], simulated.record.stamp_ns[rows[-1]])
            for rows in (np.flatnonzero(simulated.rest == k) for k in range(int(simulated.rest.max()) + 1))]
    margin = finder.window_ns
    for rest in found:
        assert any(start - margin <= rest.start_ns and rest.end_ns <= end + margin for start, end in true), rest
        assert rest.duration_s <= REST_MAX_S + 1.0
    for start, end in true:
        if (end - start) * 1e-9 >= 4.0:
            assert any(start - margin <= rest.start_ns <= end for rest in found), (start, end)
    assert any((end - start) * 1e-9 > REST_MAX_S for start, end in true)
    assert len(found) > len(true)  # the longest stillness is cut into rests of a minute at most


@pytest.fixture(scope='module')
def over_seeds():
    """The watch over 20 records per unit (healthy, offset moved, slope grown), and with learning on the faulty ones."""
    results = {fault: [] for fault in FAULTS}
    learned = {fault: [] for fault in ('offset', 'slope')}
    for seed in SEEDS:
        runs = everyday_runs(seed)
        for fault, simulated in runs.items():
            watch, fired, _ = watch_run(simulated, UNIT)
            results[fault].append((simulated, watch, fired))
        for fault in learned:
            simulated = runs[fault]
            watch, _, output = watch_run(simulated, UNIT, WatchSettings(latitude=LATITUDE, learn=LearnedState()))
            learned[fault].append(learning_ratios(simulated, output, UNIT, SCENARIO.sample_rate_hz))
    return results, learned


def test_a_healthy_unit_is_never_said_stale(over_seeds):
    """20 runs of a unit whose file holds: no "stale"; the false alarms measured (0) within the stated rate."""
    results, _ = over_seeds
    hours = sum(watch.rest_hours for _, watch, _ in results['healthy'])
    stale = [watch.verdict() for _, watch, _ in results['healthy'] if watch.stale]
    assert hours > 1.5 and not stale, stale
    assert all(watch.verdict().startswith('calibration holds at') for _, watch, _ in results['healthy'])
    assert len(stale) <= RATE * hours + 1e-9  # measured 0 in about 2 hours of rests, stated 0.05 per hour


def test_a_moved_offset_is_said_stale_at_the_first_rest(over_seeds):
    """800 deg/h on gyro x: said stale at the first rest's judgement in every run, named and sized."""
    results, _ = over_seeds
    for simulated, watch, fired in results['offset']:
        finding = watch.findings['gyro x']
        assert finding.kind == 'offset' and finding.turn_on and finding.rest == 1
        assert fired is not None and fired <= rest_ends_ns(simulated)[0] + 2 * NANOSECONDS
        assert finding.size * DEG_PER_H == pytest.approx(OFFSET_MOVED * DEG_PER_H, abs=250.0)  # the turn-on: 62 deg/h
        assert 'gyro x offset +' in watch.verdict() and list(watch.findings) == ['gyro x']


def test_a_grown_slope_is_said_stale_within_four_rests_in_most_runs(over_seeds):
    """A quarter more drift on gyro y: stale in every run, in 15 of 20 by their 4th rest's end; named a slope.

    The runs it misses by the 4th rest warmed by 2 to 3 C over their first rests (a slope shows
    only as the temperature moves; the rests' noise, the Earth rate's unknown horizontal part
    included, is 5 to 10 deg/h); one of them is named a step of the offset since a rest.
    """
    results, _ = over_seeds
    by_fourth = said = slopes = 0
    expected = SLOPE_GROWTH * SCENARIO.gyro_unit[1].offset_coeffs[0] * DEG_PER_H  # deg/h per C, about -11
    for simulated, watch, fired in results['slope']:
        if fired is None:
            continue
        said += 1
        by_fourth += fired <= rest_ends_ns(simulated)[3] + 2 * NANOSECONDS
        finding = watch.findings['gyro y']
        assert list(watch.findings) == ['gyro y']
        if finding.kind == 'slope':
            slopes += 1
            assert finding.size * DEG_PER_H == pytest.approx(expected, abs=6.0)
    assert said == len(SEEDS) and by_fourth >= 15 and slopes >= 19, (said, by_fourth, slopes)


def test_learning_brings_the_rate_at_rests_to_the_noise_floor(over_seeds):
    """With learning, from the 5th rest on the rate at rests is within 2.5 times the floor of such a mean.

    The RMS over the runs' rests, each axis, the moved offset and the grown slope alike.
    """
    _, learned = over_seeds
    for fault, errors in learned.items():
        ratios = np.vstack(errors)
        rms = np.sqrt(np.mean(ratios ** 2, axis=0))
        assert len(ratios) > 100 and np.all(rms <= 2.5), (fault, rms)


def test_the_learned_file_is_a_calibration_file_that_goes_on_from_where_it_stopped(tmp_path):
    """The learned file round-trips, every command reads it, it corrects as the learned curve does.

    Its correction is the original less the learned curve; a learned file of another calibration
    is not applied.
    """
    state = LearnedState(offset=(1e-4, -2e-4, 3e-5), offset_variance=(1e-10, 1e-10, 1e-10), slope=(1e-6, -5e-5, 0.0),
                         slope_variance=(1e-12, 1e-12, 1e-12), reference=UNIT.gyro.temp_code_ref, runs=2, rests=17,
                         rejected=1, original=calibration_digest(UNIT))
    path = tmp_path / 'learned.yaml'
    save_learned(path, UNIT, state, source='unit.yaml')
    assert load_learned(path) == state and load_learned(tmp_path / 'none.yaml') is None
    learned = load_unit(path)  # what validate, diagnose and export read
    assert cli.main(['export', str(path), '--format', 'px4', '-o', str(tmp_path / 'px4.params')]) == 0
    assert 'learned by the calibration watch from 17 rests over 2 runs' in learned.gyro.notes[-1]
    low, high = UNIT.gyro.temp_code_min, UNIT.gyro.temp_code_max
    temperature = np.linspace(low, high, 50)
    rate = np.zeros((50, 6))
    original = UnitCorrector(UNIT).correct(rate, temperature)
    folded = UnitCorrector(learned).correct(rate, temperature)
    adjusted = np.array([adjust(tuple(row), t, Adjustment((0.0,) * 3 + state.offset, (0.0,) * 3 + state.slope),
                                state.reference) for row, t in zip(original, temperature)])
    # the curve's scale drift F_c(n) divides the folded correction: within 2e-3 of it
    assert np.all(np.abs(folded - adjusted) <= 2e-3 * np.abs(original - adjusted) + 1e-15)
    moved = tuple(replace(axis, offset=axis.offset + 1e-3) for axis in UNIT.gyro.axes)
    other = replace(UNIT, gyro=replace(UNIT.gyro, axes=moved))
    watch = WatchSettings(learn=state).watch(other)
    assert watch.learner.start.runs == 0 and watch.adjustment is None
    assert WatchSettings(learn=state).watch(UNIT).learner.start == state


def test_the_watch_needs_the_files_noise_models():
    """Without a noise model the watch says so in one line (and the node runs without it)."""
    bare = replace(UNIT, gyro=replace(UNIT.gyro, noise=None))
    with pytest.raises(WatchUnavailable, match='no noise model for the gyro'):
        WatchSettings().watch(bare)
    core = OnlineCompensator(bare, watch=WatchSettings())
    assert core.watch is None and 'no noise model' in core.watch_status().message


@pytest.fixture(scope='module')
def moved_bag(tmp_path_factory):
    """Six minutes of the unit whose gyro x offset moved, as a bag; its calibration file."""
    directory = tmp_path_factory.mktemp('watch_bag')
    simulated = everyday_runs(1, ('offset',), habits=replace(HABITS, record_minutes=6.0))['offset']
    bag, params = directory / 'moved.mcap', directory / 'unit.yaml'
    write_driver_record(bag, simulated.record)
    save_unit(params, UNIT)
    return bag, params, simulated


def test_validate_prints_the_nodes_verdict_on_an_everyday_record(moved_bag, tmp_path, capsys):
    """``validate REC --params P``: the watch's verdict on the record, as the node's core gives it."""
    import json
    bag, params, simulated = moved_bag
    report = tmp_path / 'v.json'
    assert cli.main(['validate', str(bag), '--params', str(params), '--latitude', str(LATITUDE), '--json',
                     str(report), '--no-progress']) == 0
    lines = capsys.readouterr().out.splitlines()
    watch, _, _ = watch_run(simulated, UNIT)
    assert watch.verdict() in lines and watch.verdict().startswith('calibration stale: gyro x offset +')
    # rests near level, motion between: its rests judged as a pool of one's first (issue 43), the watch after
    assert lines[0] == ('moved.mcap: an everyday record (rests in one orientation, motion between): taken as a pool '
                        'of one')
    assert lines.index(watch.verdict()) > max(i for i, line in enumerate(lines) if line.startswith('gyroscope: '))
    document = json.loads(report.read_text())['calibration_watch']
    assert document['stale'] and document['findings'][0]['text'].startswith('gyro x offset +')
    assert all(len(line) <= 100 for line in lines)


def test_apply_takes_the_turn_on_offset_as_the_node_does(moved_bag, tmp_path, capsys):
    """``apply --turn-on first-rest`` is the node's core on the same messages, float64 for float64.

    One line (exit 2) without the file's turn-on repeatability.
    """
    bag, params, simulated = moved_bag
    out = tmp_path / 'applied.mcap'
    assert cli.main(['apply', str(bag), '--params', str(params), '-o', str(out), '--turn-on', 'first-rest',
                     '--latitude', str(LATITUDE), '--no-progress']) == 0
    said = '\n'.join(unwrap(capsys.readouterr().out))
    assert ("turn-on offset not taken at rest 1, beyond 5 sigma of the file's repeatability and the rest's noise: "
            'gyro x +') in said
    assert 'changed curve' not in said  # a cause the offset alone cannot tell
    applied = read_imu_messages(out, topic='/imu/data_compensated')
    core = OnlineCompensator(UNIT, temp_timeout_s=1e9, watch=WatchSettings(latitude=LATITUDE, turn_on=True))
    record = simulated.record
    published = core_published(core, record)
    assert core.watch.adjustment is not None and core.watch.turn_on_offset[3] == 0.0  # x refused, y z taken
    assert np.array_equal(applied.linear_acceleration, published[:, :3])
    assert np.array_equal(applied.angular_velocity, published[:, 3:])
    plain = UnitCorrector(UNIT).correct(np.hstack([record.accel, record.gyro])[-5:], record.temperature[-1:].repeat(5))
    assert not np.allclose(applied.angular_velocity[-5:, 1:], plain[:, 4:], atol=1e-9, rtol=0.0)
    no_turn_on = tmp_path / 'bare.yaml'
    save_unit(no_turn_on, replace(UNIT, gyro=replace(UNIT.gyro, turn_on=None)))
    assert cli.main(['apply', str(bag), '--params', str(no_turn_on), '-o', str(tmp_path / 'x.mcap'), '--turn-on',
                     'first-rest', '--no-progress']) == 2
    assert 'no gyro turn_on section' in capsys.readouterr().err


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 2_000_000_000), st.floats(-50.0, 50.0), st.booleans()), min_size=30,
                max_size=400), st.integers(0, 2 ** 31))
def test_the_rest_finder_takes_any_stream(steps, seed):
    """Any stamps (some going back) and values: no error, every rest has samples and finite means, a bounded buffer."""
    rng = np.random.default_rng(seed)
    found = []
    finder = RestFinder(UNIT.accel.noise, UNIT.gyro.noise, found.append)
    stamp = 1_700_000_000 * NANOSECONDS
    for step, level, moving in steps:
        stamp += step if rng.uniform() > 0.05 else -step  # a few steps back
        values = [0.0, 0.0, 9.8 + level * 1e-3, 1e-4, 0.0, 0.0]
        if moving:
            values = list(rng.normal(0.0, 5.0, 6))
        finder.take(stamp, values, 20.0)
    finder.finish()
    for rest in found:
        assert rest.samples > 0 and all(math.isfinite(v) for v in rest.mean)
    assert len(finder._buffer) <= max(1, finder.window_ns // max(finder.period_ns, 1) + 1)  # noqa: SLF001


def test_with_learning_off_the_watch_leaves_the_output_as_apply_writes_it(moved_bag):
    """Watch on (the node's default), no turn-on, no learning: the published values are apply's, float for float."""
    _, _, simulated = moved_bag
    core = OnlineCompensator(UNIT, temp_timeout_s=1e9, watch=WatchSettings(latitude=LATITUDE))
    published = core_published(core, simulated.record, judge=True)
    stamps, expected, _ = corrected_run(simulated, UNIT)
    assert core.watch.stale and core.watch.rests_judged >= 3
    assert np.array_equal(published, expected)


def test_learning_follows_a_shift_beyond_a_flat_axis_own_span():
    """A unit whose gyro x curve is flat (a few deg/h over its range) still learns an 800 deg/h shift of x.

    Learning bounds its corrections; bounded by the x curve's own span (and 6 turn-on spreads, a few
    hundred deg/h) it held the shift at that bound and the rests stayed 10-30x the floor (issue 39's
    second everyday setting). The bound is the unit's widest axis's: from the 5th rest on the rate
    at rests is within 2.5x the floor again.
    """
    flat = replace(SCENARIO, gyro_unit=(replace(SCENARIO.gyro_unit[0], offset_coeffs=(0.0,)),
                                        *SCENARIO.gyro_unit[1:]))
    unit = watch_unit(flat)
    ratios = []
    for seed in SEEDS[:4]:
        simulated = everyday_runs(seed, ('offset',), scenario=flat)['offset']
        _, _, output = watch_run(simulated, unit, WatchSettings(latitude=LATITUDE, learn=LearnedState()))
        ratios.append(learning_ratios(simulated, output, unit, flat.sample_rate_hz))
    rms = np.sqrt(np.mean(np.vstack(ratios) ** 2, axis=0))
    assert len(np.vstack(ratios)) > 15 and np.all(rms <= 2.5), rms


def test_learning_takes_the_slope_beyond_the_files_range():
    """A file calibrated up to 22 C on a unit used up to 33 C: learning takes the curve's slope beyond the edge.

    The correction holds the edge's value beyond the calibrated range (it clamps), so the rests above
    22 C lie tens of times the floor from the truth; learning's offset and slope alone, one line over
    the whole range, rejected those rests as outliers and jumped to new levels (issue 39's pool files,
    whose records span less than the month's: 8-12x the floor). With a slope beyond each edge (its
    prior the watch's own: the curve's slope there and the file's ``beyond``) the rests from the 5th on
    lie within 3x the floor (a line beyond the edge leaves the curve's curvature there), 10x better.
    """
    narrow = replace(UNIT, gyro=replace(UNIT.gyro, temp_code_max=22.0))
    learned, plain = [], []
    for seed in SEEDS[:4]:
        simulated = everyday_runs(seed, ('healthy',))['healthy']
        for watching, ratios in ((WatchSettings(latitude=LATITUDE, learn=LearnedState()), learned),
                                 (WatchSettings(latitude=LATITUDE), plain)):
            watch, _, output = watch_run(simulated, narrow, watching)
            ratios.append(learning_ratios(simulated, output, narrow, SCENARIO.sample_rate_hz))
            if watch.learner is not None:
                state = watch.learner.state()
    learned_rms, plain_rms = (np.sqrt(np.mean(np.vstack(r) ** 2, axis=0)) for r in (learned, plain))
    assert len(np.vstack(learned)) > 15 and np.all(learned_rms <= 3.0), learned_rms
    assert np.all(plain_rms >= 10.0 * learned_rms) or np.all(plain_rms >= 15.0), (plain_rms, learned_rms)
    assert any(state.above) and not any(state.below) and len(state.above_variance) == 3
    again = LearnedState.from_mapping(state.to_mapping(), 'learned')
    assert again == state
    older = {key: value for key, value in state.to_mapping().items() if not key.startswith(('below', 'above'))}
    assert LearnedState.from_mapping(older, 'learned').above_variance == ()
