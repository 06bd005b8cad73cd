"""The everyday-records simulator: a unit's month of ordinary runs, each power-up with its own turn-on offset."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tak_thermo_ros import cli
from tak_thermo_ros.core.records.still import find_still
from tak_thermo_ros.core.rotation import integrate_segments
from tak_thermo_ros.core.simulation.everyday import (
    Everyday,
    everyday_scenario,
    everyday_truth,
    simulate_everyday,
    simulate_everyday_record,
)
from tak_thermo_ros.errors import ScenarioError
from tak_thermo_ros.formats.bag import Topics, read_imu_messages

SCENARIO, HABITS = everyday_scenario({'sample_rate_hz': 20.0, 'seed': 7,
                                      'everyday': {'records': 4, 'record_minutes': 12.0}})
"""Four records of about 12 minutes at 20 Hz (about 15,000 Imu messages each)."""


@pytest.fixture(scope='module')
def month():
    """The four records."""
    return list(simulate_everyday(SCENARIO, HABITS))


def run_cli(capsys, *argv) -> tuple[int, list[str]]:
    """``tak_calib argv``: its exit status and the lines it printed."""
    status = cli.main([*argv, '--no-progress'])
    out = capsys.readouterr()
    return status, (out.out + out.err).splitlines()


def test_a_record_is_the_same_alone_or_in_its_month(month):
    """Record 2 drawn alone equals record 2 of the month; another seed changes it."""
    alone = simulate_everyday_record(SCENARIO, HABITS, 2)
    assert np.array_equal(alone.record.gyro, month[2].record.gyro)
    assert np.array_equal(alone.record.temperature, month[2].record.temperature)
    other = simulate_everyday_record(replace(SCENARIO, seed=8), HABITS, 2)
    assert not np.array_equal(other.turn_on['gyro'], alone.turn_on['gyro'])
    with pytest.raises(ScenarioError, match='record 4 of 4'):
        simulate_everyday_record(SCENARIO, HABITS, 4)


def test_each_power_up_has_its_own_turn_on_offset_constant_over_the_record(month):
    """At the true rests the gyroscope reads the link's offset plus the record's turn-on offset, within the noise."""
    for simulated in month:
        rest = simulated.rest >= 0
        error = simulated.record.gyro[rest] - simulated.true_offsets('gyro')[rest] - simulated.turn_on['gyro']
        # white noise over the rest samples, bias instability and random walk: a few 1e-5 rad/s
        assert np.all(np.abs(error.mean(axis=0)) < 1.5e-4)
        first, last = error[:len(error) // 2].mean(axis=0), error[len(error) // 2:].mean(axis=0)
        assert np.all(np.abs(first - last) < 2e-4)  # constant over the record: no step
    offsets = np.array([simulated.turn_on['gyro'] for simulated in month])
    assert np.all(np.ptp(offsets, axis=0) > 0.0)


def test_turn_on_offsets_are_drawn_with_the_stated_repeatability():
    """Over 120 short power-ups the turn-on offsets' spread matches ``turn_on_*`` (chi-square bounds)."""
    habits = replace(HABITS, records=120, record_minutes=0.3, rest_s=(5.0, 6.0), motion_s=(3.0, 4.0))
    scenario = replace(SCENARIO, sample_rate_hz=10.0)
    draws = {sensor: np.array([simulate_everyday_record(scenario, habits, index).turn_on[sensor]
                               for index in range(0, 120, 1)]) for sensor in ('gyro',)}
    spread = draws['gyro'].std(axis=0, ddof=1) / habits.turn_on('gyro')
    # 119 degrees of freedom: the ratio lies within 0.78 .. 1.22 with probability > 0.999 per axis
    assert np.all((spread > 0.78) & (spread < 1.22))
    assert np.all(np.abs(draws['gyro'].mean(axis=0)) < 4.0 * habits.turn_on('gyro') / np.sqrt(120))


def test_rests_are_near_level_and_found_from_the_record_the_motions_are_not(month):
    """Every rest's up lies within tilt_deg of the mount's; the detector finds the rests and no rest in a motion."""
    for simulated in month:
        tilt = np.degrees(np.arccos(np.clip(simulated.up[:, 2], -1.0, 1.0)))
        assert np.all(tilt <= HABITS.tilt_deg + 1e-9)
        record = simulated.record
        found = find_still(record.stamp_ns, np.hstack([record.accel, record.gyro]))
        inside = found.index_of(record.stamp_ns) >= 0
        assert not np.any(inside & (simulated.rest < 0))  # no motion taken for a rest
        rest_time = np.count_nonzero(simulated.rest >= 0)
        assert np.count_nonzero(inside) > 0.8 * rest_time  # a rest loses its edges only
        assert len(found) >= 0.8 * len(simulated.up)


def test_the_rates_of_a_motion_carry_one_rests_up_onto_the_next(month):
    """The true rates, vibration included, integrate over each motion to the turn between the rests' poses."""
    simulated = month[0]
    moving = simulated.rest < 0
    edges = np.flatnonzero(np.diff(moving.astype(int)) != 0)
    stamp_s = (simulated.record.stamp_ns - simulated.record.stamp_ns[0]) * 1e-9
    for start, end in zip(edges[::2], edges[1::2]):
        rows = np.arange(start, end + 2)  # the last rest sample before and the first after
        rotation, _ = integrate_segments(simulated.rate[rows], stamp_s[rows], np.zeros(len(rows), dtype=int), 1)
        before, after = simulated.rest[start], simulated.rest[end + 1]
        carried = rotation[0] @ simulated.up[after]
        angle = np.arccos(np.clip(carried @ simulated.up[before], -1.0, 1.0))
        assert angle < 2e-3  # rad: the trapezoid's error on the vibration only


def test_a_month_meets_its_temperatures_heating_and_cooling(month):
    """Each record starts at its day's ambient; over the month the rests see the temperature rise and fall."""
    rises = falls = 0
    for simulated in month:
        assert simulated.board_celsius[0] == pytest.approx(simulated.ambient_celsius, abs=1e-6)
        slope = np.gradient(simulated.board_celsius) * SCENARIO.sample_rate_hz * 60.0  # C per minute
        rest = simulated.rest >= 0
        rises += np.count_nonzero(slope[rest] > 0.05)
        falls += np.count_nonzero(slope[rest] < -0.05)
    assert rises > 1000 and falls > 1000
    low, high = HABITS.temperature_span()
    everything = np.concatenate([s.board_celsius for s in month])
    assert low <= everything.min() and everything.max() <= high
    truth = everyday_truth(SCENARIO, HABITS)
    assert (truth.gyro.temp_code_min, truth.gyro.temp_code_max) == pytest.approx((low, high))


def test_coloured_noise_comes_from_the_scenarios_units(month):
    """The records carry the units' bias instability and random walk: slow wander beside the white noise."""
    quiet_units = {name: tuple(replace(axis, bias_instability=0.0, random_walk=0.0) for axis in getattr(SCENARIO, name))
                   for name in ('accel_unit', 'gyro_unit')}
    coloured = month[1]
    white = simulate_everyday_record(replace(SCENARIO, **quiet_units), HABITS, 1)
    wander = coloured.record.gyro - white.record.gyro
    assert np.all(np.std(wander, axis=0) > 5e-6)  # rad/s: the bias instability of 2e-5 and the walk
    for axis in range(3):  # slow, not white: successive samples almost equal
        assert np.corrcoef(wander[:-1, axis], wander[1:, axis])[0, 1] > 0.95


def test_simulate_writes_one_bag_per_record_under_the_overwrite_rule(tmp_path, capsys):
    """``simulate DIR --scenario`` with an everyday section: DIR/rec00.. as bags; an existing month needs --force."""
    scenario = tmp_path / 'month.yaml'
    scenario.write_text('sample_rate_hz: 10.0\nseed: 3\neveryday: {records: 2, record_minutes: 4.0}\n')
    status, lines = run_cli(capsys, 'simulate', str(tmp_path / 'month'), '--scenario', str(scenario))
    assert status == 0, lines
    assert lines[0].startswith(f'wrote {tmp_path / "month"}: 2 records')
    assert sorted(p.name for p in (tmp_path / 'month').iterdir()) == ['rec00', 'rec01']
    scenario_, habits = everyday_scenario({'sample_rate_hz': 10.0, 'seed': 3,
                                           'everyday': {'records': 2, 'record_minutes': 4.0}})
    expected = simulate_everyday_record(scenario_, habits, 1).record
    read = read_imu_messages(tmp_path / 'month' / 'rec01', topic=Topics().raw_imu)
    assert np.array_equal(read.angular_velocity, expected.gyro)
    # What the rests' count is (issue 43): the rests as drawn; fit counts those it finds, and a rest can split.
    drawn = [int(simulate_everyday_record(scenario_, habits, index).rest.max()) + 1 for index in range(2)]
    from tak_thermo_ros.cli.common import unwrap
    said = unwrap('\n'.join(lines) + '\n')
    assert f'{min(drawn)}..{max(drawn)} rests per record as drawn, within 3 deg of level' in said[1]
    assert said[2] == "  (fit finds each record's rests itself: a rest that one noisy window breaks counts as two)"
    status, lines = run_cli(capsys, 'simulate', str(tmp_path / 'month'), '--scenario', str(scenario))
    assert status == 2 and lines == [f'tak_calib: error: {tmp_path / "month"} (OUT_BAG): exists and holds 2 bags; '
                                     f'--force replaces them']
    assert run_cli(capsys, 'simulate', str(tmp_path / 'month'), '--scenario', str(scenario), '--force')[0] == 0
    (tmp_path / 'month' / 'notes.txt').write_text('mine')
    status, lines = run_cli(capsys, 'simulate', str(tmp_path / 'month'), '--scenario', str(scenario), '--force')
    assert status == 2 and 'notes.txt' in lines[0] and 'refusing to touch it' in lines[0]
    assert (tmp_path / 'month' / 'notes.txt').read_text() == 'mine'


@pytest.mark.parametrize('text, message', [
    ('everyday: {record: 3}', 'everyday.record: unknown key'),
    ('everyday: {rest_s: [10, 5]}', 'everyday.rest_s: expected [shortest, longest]'),
    ('everyday: {tilt_deg: 50}', 'everyday.tilt_deg: must lie within 0..45'),
    ('everyday: {}\noutput: counts', 'everyday: needs output: imu'),
    ('everyday: {}\nhandheld: {}', 'handheld: not with everyday'),
    ('everyday: [1]', 'everyday: expected a mapping'),
])
def test_a_bad_everyday_scenario_is_one_line(tmp_path, capsys, text, message):
    """Each mistake in the section is named in one line."""
    scenario = tmp_path / 'bad.yaml'
    scenario.write_text(text + '\n')
    status, lines = run_cli(capsys, 'simulate', str(tmp_path / 'month'), '--scenario', str(scenario))
    assert status == 2 and len(lines) == 1 and message in lines[0], lines
    assert not (tmp_path / 'month').exists()


def test_habits_defaults_describe_a_month():
    """The defaults: 16 records over 30 days, near level, a turn-on offset on every axis."""
    habits = Everyday()
    assert habits.records == 16 and habits.days == 30.0 and habits.face_share == 0.0
    assert np.all(habits.turn_on('gyro') > 0.0) and np.all(habits.turn_on('accel') > 0.0)


EVERYDAY_KEYS = ('records, days, record_minutes, ambient_celsius, ambient_drift_celsius, start_spread_celsius, '
                 'self_heating_celsius, board_tau_s, motion_heating_celsius, rest_s, motion_s, tilt_deg, face_share, '
                 'mount_up, vibration_rate, vibration_accel, vehicle_accel, turn_on_accel, turn_on_gyro')
"""The ``everyday`` section's keys, in the order its messages list them (:class:`Everyday`'s fields)."""


@pytest.mark.parametrize('section, message', [
    (3, f'everyday: expected a mapping (every key optional: {EVERYDAY_KEYS})'),
    ([1], f'everyday: expected a mapping (every key optional: {EVERYDAY_KEYS})'),
    ({'bogus': 1}, f'everyday.bogus: unknown key (known: {EVERYDAY_KEYS})'),
    ({'days': 'a', 'bogus': 1}, 'everyday.days: expected a number'),
    ({'bogus': 1, 'days': 'a'}, f'everyday.bogus: unknown key (known: {EVERYDAY_KEYS})'),
    ({'days': True}, 'everyday.days: expected a number'),
    ({'records': 1.5}, 'everyday.records: expected a whole number'),
    ({'records': True}, 'everyday.records: expected a whole number'),
    ({'ambient_celsius': [1]}, 'everyday.ambient_celsius: expected a list of 2 numbers'),
    ({'ambient_celsius': 5}, 'everyday.ambient_celsius: expected a list of 2 numbers'),
    ({'mount_up': [0, 0, True]}, 'everyday.mount_up: expected a list of 3 numbers'),
    ({'turn_on_gyro': [0, 0, 'a']}, 'everyday.turn_on_gyro: expected a list of 3 numbers'),
    ({'records': 0}, 'everyday.records: must be a whole number >= 1'),
])
def test_the_everyday_sections_mistakes_word_for_word(section, message):
    """Each mistake in the ``everyday`` mapping, word for word: the first bad key in the mapping's order."""
    with pytest.raises(ScenarioError) as caught:
        everyday_scenario({'everyday': section})
    assert str(caught.value) == message


def test_an_everyday_sections_values_are_read_as_its_defaults_kinds():
    """Numbers as floats, whole numbers as ints, lists as tuples of floats."""
    _, habits = everyday_scenario({'everyday': {'records': 3, 'days': 2, 'rest_s': [5, 60], 'mount_up': [1, 0, 0]}})
    assert habits == Everyday(records=3, days=2.0, rest_s=(5.0, 60.0), mount_up=(1.0, 0.0, 0.0))
    assert isinstance(habits.days, float) and all(isinstance(v, float) for v in habits.rest_s)


@pytest.mark.parametrize('raw', [3, 'seed', [('seed', 1)], ['seed'], 2.5])
def test_a_scenario_that_is_no_mapping_is_refused_in_one_line(raw):
    """``everyday_scenario`` of something that is no mapping: the scenario reader's words, not a TypeError."""
    with pytest.raises(ScenarioError) as caught:
        everyday_scenario(raw)
    assert str(caught.value) == 'scenario: expected a mapping of keys to values'
