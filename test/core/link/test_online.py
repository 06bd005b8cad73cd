"""The node's logic without ROS: OnlineCompensator, one message at a time."""

from __future__ import annotations

import math
import re
from dataclasses import replace

import numpy as np
import pytest

from paths import REPO
from tak_thermo_ros.core.link.correction import (
    Corrector,
    OutOfRange,
    UnitCorrector,
    acceleration_variance,
    imu_covariances,
)
from tak_thermo_ros.core.link.online import OnlineCompensator
from tak_thermo_ros.core.link.online_reports import Level
from tak_thermo_ros.core.link.online_rules import ONLINE_DROP_REASONS, StaleTemperature
from tak_thermo_ros.core.records.drops import TEMP_CODE_LIMIT, TEMPERATURE_RANGE, counts_problems
from tak_thermo_ros.core.records.stamps import STAMP_DROP_REASONS, seconds_from_ns, stamp_problems
from tak_thermo_ros.core.simulation.scenario import Scenario

CALIBRATION = Scenario().truth()  # temperature-code range 7600..8800
SEC = 1_700_000_000


def make(**kwargs) -> OnlineCompensator:
    """A compensator on the default unit, topic '/tak/temp_code'."""
    return OnlineCompensator(CALIBRATION, temp_topic='/tak/temp_code', **kwargs)


def kinds(core: OnlineCompensator) -> list[str]:
    """The kinds of the notices due (and empty the list)."""
    return [notice.kind for notice in core.take_notices()]


def balanced(core: OnlineCompensator) -> bool:
    """`received` == published + sum(dropped)."""
    return core.received == core.published + sum(core.dropped.values())


def test_waiting_for_temperature_publishes_nothing_and_warns_with_topic():
    """Before the first code: dropped as waiting, a WARN naming the topic, status WARN."""
    core = make()
    assert core.waiting_for_temperature
    assert core.process_counts(SEC, 0, 10.0, 20.0, 30.0, now_s=0.0) == 'waiting_for_temperature'
    notices = core.take_notices()
    assert [(n.level, n.kind) for n in notices] == [(Level.WARN, 'waiting_for_temperature')]
    assert 'waiting for temperature code on /tak/temp_code' in notices[0].text
    assert core.process_counts(SEC, 1, 10.0, 20.0, 30.0, now_s=1.0) == 'waiting_for_temperature'
    assert kinds(core) == []  # throttled ...
    core.tick(6.0)
    notices = core.take_notices()
    assert len(notices) == 1 and '1 more since the last report' in notices[0].text  # ... never silent
    status = core.status(6.0)
    assert status.level is Level.WARN and 'waiting for temperature code on /tak/temp_code' in status.message
    assert status.value('dropped.waiting_for_temperature') == '2' and status.value('published') == '0'
    assert core.process_temperature(8200.0, now_s=6.5)
    assert not core.waiting_for_temperature
    assert isinstance(core.process_counts(SEC, 2, 10.0, 20.0, 30.0, now_s=6.6), tuple)
    assert balanced(core)


def test_the_docs_state_the_temperature_bounds_the_code_applies():
    """docs/node.md's bad-input table gives the plausible temperatures of each input kind as the code has them."""
    docs = (REPO / 'docs' / 'node.md').read_text(encoding='utf-8')
    row = next(line for line in docs.splitlines() if line.startswith('| temperature NaN'))
    low, high = TEMPERATURE_RANGE['imu']
    assert f'outside {low:g}..{high:g} C' in row and f'{TEMP_CODE_LIMIT:.0e}'.replace('e+0', 'e') in row
    assert TEMPERATURE_RANGE['counts'] == (-TEMP_CODE_LIMIT, TEMP_CODE_LIMIT)


def test_a_throttled_report_counts_messages_not_its_own_ticks():
    """A report's "N more since the last report" is its "so far" less the previous one's, ticks or not.

    Messages at 10 Hz without a temperature, the diagnostics ticking at 1 Hz in between.
    """
    core = OnlineCompensator(DRIVER)
    reports = []
    for k in range(200):  # 20 s
        now = 0.1 * k
        core.process_values(SEC, k, (0.1, -0.2, 9.8, 0.01, 0.02, -0.03), now_s=now)
        if k % 10 == 5:
            core.tick(now)
        reports += [n.text for n in core.take_notices()]
    pattern = re.compile(r'\((\d+) Imu messages dropped so far(?:; (\d+) more since the last report)?\)')
    counts = [tuple(int(g) if g else 0 for g in pattern.search(text).groups()) for text in reports]
    assert len(counts) == 4 and counts[0] == (1, 0) and counts[-1][0] <= 200
    assert all(now[1] == now[0] - before[0] for before, now in zip(counts, counts[1:])), reports
    assert core.dropped['waiting_for_temperature'] == 200


@pytest.mark.parametrize(('counts', 'reason'), [
    ((math.nan, 0.0, 0.0), 'non_finite'),
    ((0.0, math.inf, 0.0), 'non_finite'),
    ((0.0, 0.0, -math.inf), 'non_finite'),
    ((0.5, 0.0, 0.0), 'non_integer'),
    ((0.0, 12.25, 1.5), 'non_integer'),
    ((32767.0, 0.0, 0.0), 'saturated'),
    ((0.0, -32768.0, 0.0), 'saturated'),
    ((math.nan, 32767.0, 0.5), 'non_finite'),
    ((0.5, 32767.0, 0.0), 'non_integer'),
])
def test_bad_counts_dropped_by_reason_as_apply_drops_them(counts, reason):
    """NaN, infinite, non-integer and saturated counts: dropped with apply's reason, never numbers."""
    core = make()
    core.process_temperature(8200.0, now_s=0.0)
    assert core.process_counts(SEC, 0, *counts, now_s=0.1) == reason
    offline = counts_problems(np.array([counts]))
    assert [name for name, mask in offline.items() if mask[0]] == [reason]
    assert core.dropped[reason] == 1 and core.published == 0 and balanced(core)


def test_a_future_stamped_outlier_is_dropped_and_said_not_the_good_message_after_it():
    """1, 2, 3, 3603, 4, 5 s: the 3603 alone is dropped (stamp_jump), and said.

    A real jump (a pause, a clock step) costs its first message, the next goes on from it; the
    offline rule drops the same.
    """
    core = make()
    core.process_temperature(8200.0, now_s=0.0)
    seconds = [1, 2, 3, 3603, 4, 5, 500, 501, 502, 50, 51]  # steps of 1 s: a jump is beyond 100 s
    results = [core.process_counts(SEC + t, 0, 1.0, 2.0, 3.0, now_s=0.1) for t in seconds]
    reasons = [r if isinstance(r, str) else 'published' for r in results]
    assert reasons == ['published', 'published', 'published', 'stamp_jump', 'published', 'published',
                       'stamp_jump', 'published', 'published', 'time_backwards', 'published']
    offline, _ = stamp_problems(np.array([(SEC + t) * 1_000_000_000 for t in seconds], dtype=np.int64))
    assert [next((r for r, mask in offline.items() if mask[i]), 'published') for i in range(len(seconds))] == reasons
    notice = core.take_notices()[0]
    assert notice.kind == 'stamp_order' and 'header stamp 3600.000000 s (> 10 s) after the previous one' in notice.text
    assert core.status(0.2).value('dropped.stamp_jump') == '2' and balanced(core)
    # A sparse stream (a message every 30 s) goes on 30 s at a time; an hour ahead is still a jump.
    sparse = make()
    sparse.process_temperature(8200.0, now_s=0.0)
    seconds = [0, 30, 60, 90, 3690, 120, 150]
    results = [sparse.process_counts(SEC + t, 0, 1.0, 2.0, 3.0, now_s=0.1) for t in seconds]
    assert [r if isinstance(r, str) else 'published' for r in results] == ['published'] * 4 + [
        'stamp_jump', 'published', 'published']


def _outcomes(stamps_ns: list[int]) -> tuple[list[str], list[str]]:
    """Online (the core of the node, message by message) and offline (stamp_problems) outcome per message."""
    core = make()
    core.process_temperature(8200.0, now_s=0.0)
    online = [r if isinstance(r, str) else 'published'
              for r in (core.process_counts(*divmod(t, 1_000_000_000), 1.0, 2.0, 3.0, now_s=0.1) for t in stamps_ns)]
    masks, _ = stamp_problems(np.array(stamps_ns, dtype=np.int64))
    offline = [next((r for r, mask in masks.items() if mask[i]), 'published') for i in range(len(stamps_ns))]
    return online, offline


@pytest.mark.parametrize('where', ['third_ever', 'middle', 'first_after_a_pause', 'second_after_a_pause',
                                   'third_after_a_pause', 'last'])
@pytest.mark.parametrize('rate_hz', [1, 100])
def test_a_lone_message_stamped_an_hour_ahead_costs_itself_alone_wherever_it_comes(where, rate_hz):
    """A steady stream with one message stamped an hour ahead: that one dropped (stamp_jump), every other kept.

    Wherever it comes: mid-stream, or just after a real pause (whose first message the rule drops,
    as said in docs/node.md): the second message after it (the one before it was dropped) or the
    third (the stream's step is the step by which the last kept message went on, not the pause).
    Online and offline drop the same. (The second message ever is not judged: docs/node.md.)
    """
    step = 1_000_000_000 // rate_hz
    start = SEC * 1_000_000_000
    stamps = [start + i * step for i in range(40)] + [start + 1000 * 1_000_000_000 + i * step for i in range(40)]
    index = {'third_ever': 2, 'middle': 20, 'first_after_a_pause': 40, 'second_after_a_pause': 41,
             'third_after_a_pause': 42, 'last': 79}[where]
    stamps[index] += 3600 * 1_000_000_000
    online, offline = _outcomes(stamps)
    assert online == offline
    assert online[index] == 'stamp_jump'
    # The pause costs its own first message (a real jump, docs/node.md), whatever the outlier does.
    pause_cost = 41 if index == 40 else 40
    assert online[pause_cost] in ('stamp_jump', 'time_backwards')
    assert [i for i, outcome in enumerate(online) if outcome != 'published'] == sorted([index, pause_cost])


def test_the_stamp_rule_across_blocks_is_the_rule_over_the_whole_run():
    """stamp_problems over a run cut in blocks (its history carried) drops what it drops over the whole run."""
    rng = np.random.default_rng(3)
    steps = rng.choice([1_000_000, 2_000_000, 0, -3_000_000, 3_600_000_000_000, -3_600_000_000_000,
                        30_000_000_000], size=400, p=[0.6, 0.2, 0.04, 0.04, 0.04, 0.04, 0.04])
    stamps = SEC * 1_000_000_000 + np.cumsum(steps)
    whole, _ = stamp_problems(stamps)
    assert all(whole[reason].any() for reason in STAMP_DROP_REASONS)
    cuts = sorted(rng.choice(np.arange(1, 400), size=12, replace=False).tolist())
    history, parts = None, []
    for start, end in zip([0, *cuts], [*cuts, 400]):
        masks, history = stamp_problems(stamps[start:end], history=history)
        parts.append(masks)
    for reason in STAMP_DROP_REASONS:
        assert np.array_equal(np.concatenate([part[reason] for part in parts]), whole[reason])


def test_backwards_and_duplicate_stamps_dropped_counted():
    """A stamp equal to or before the previous message's (whatever became of it) is dropped and counted."""
    core = make()
    core.process_temperature(8200.0, now_s=0.0)
    stamps = [(SEC, 0), (SEC, 100), (SEC, 100), (SEC - 1, 999_999_999), (SEC, 200), (SEC, 200),
              (SEC, 150), (SEC, 160)]
    results = [core.process_counts(sec, nsec, 1.0, 2.0, 3.0, now_s=0.1) for sec, nsec in stamps]
    assert [r if isinstance(r, str) else 'published' for r in results] == [
        'published', 'published', 'duplicate_stamp', 'time_backwards', 'published', 'duplicate_stamp',
        'time_backwards', 'published']  # 160 > 150, the previous message's stamp
    assert (core.dropped['duplicate_stamp'], core.dropped['time_backwards'], core.published) == (2, 2, 4)
    notices = core.take_notices()
    assert [n.kind for n in notices] == ['stamp_order'] and 'dropped' in notices[0].text
    status = core.status(0.2)
    assert status.level is Level.WARN and '2 duplicate_stamp' in status.message
    assert status.value('dropped.time_backwards') == '2' and balanced(core)
    assert core.status(0.3).level is Level.OK  # the level covers what is new since the last status


@pytest.mark.parametrize('policy', list(StaleTemperature))
def test_stale_temperature_error_and_policy(policy):
    """A code older than temp_timeout: status ERROR; hold corrects with it, drop drops."""
    core = make(stale_temperature=policy, temp_timeout_s=0.5)
    core.process_temperature(8400.0, now_s=10.0)
    fresh = core.process_counts(SEC, 0, 100.0, 200.0, 300.0, now_s=10.5)
    assert fresh == Corrector(CALIBRATION).correct_sample(100.0, 200.0, 300.0, 8400.0)
    assert core.status(10.5).level is Level.OK
    late = core.process_counts(SEC, 1, 100.0, 200.0, 300.0, now_s=10.6)
    notices = core.take_notices()
    assert [(n.level, n.kind) for n in notices] == [(Level.ERROR, 'stale_temperature')]
    assert '0.60 s old > temp_timeout 0.5 s' in notices[0].text
    if policy is StaleTemperature.HOLD:
        assert late == fresh and 'holding the last code 8400' in notices[0].text
    else:
        assert late == 'stale_temperature' and core.dropped['stale_temperature'] == 1
    status = core.status(10.7)
    assert status.level is Level.ERROR and 'temperature code stale' in status.message
    assert core.is_stale(10.7)
    core.process_temperature(8401.0, now_s=11.0)
    assert [n.level for n in core.take_notices()] == [Level.OK]  # "fresh again"
    assert not core.is_stale(11.0) and isinstance(core.process_counts(SEC, 2, 1.0, 1.0, 1.0, 11.1), tuple)
    core.status(11.1)
    assert core.status(11.2).level is Level.OK and balanced(core)


def test_stale_reported_by_tick_without_counts():
    """The periodic tick reports a stale code even when no counts arrive."""
    core = make(temp_timeout_s=1.0)
    core.process_temperature(8200.0, now_s=0.0)
    core.tick(0.5)
    assert kinds(core) == []
    core.tick(1.5)
    assert kinds(core) == ['stale_temperature']


@pytest.mark.parametrize('policy', list(OutOfRange))
def test_out_of_range_clamped_or_extrapolated_and_never_silent(policy):
    """Outside the calibrated range: the Corrector's policy, counted, WARN with code and range."""
    core = make(out_of_range=policy, temp_timeout_s=100.0)
    core.process_temperature(9500.0, now_s=0.0)
    result = core.process_counts(SEC, 0, 200.0, 200.0, 200.0, now_s=0.1)
    reference = Corrector(CALIBRATION, out_of_range=policy)
    assert result == reference.correct_sample(200.0, 200.0, 200.0, 9500.0)
    at_edge = Corrector(CALIBRATION).correct_sample(200.0, 200.0, 200.0, 8800.0)
    assert (result == at_edge) is (policy is OutOfRange.CLAMP)
    notices = core.take_notices()
    assert len(notices) == 1 and notices[0].level is Level.WARN
    assert 'temperature code 9500 outside the calibrated range 7600..8800' in notices[0].text
    assert ('clamped' if policy is OutOfRange.CLAMP else 'extrapolating') in notices[0].text
    for k in range(1, 4):
        core.process_counts(SEC, k, 200.0, 200.0, 200.0, now_s=0.1 + k)
    assert kinds(core) == []
    core.process_counts(SEC, 9, 200.0, 200.0, 200.0, now_s=5.2)
    notices = core.take_notices()
    # "so far" less the previous report's "so far" (1): the samples since the last report, this one included
    assert len(notices) == 1 and '(5 samples so far; 4 more since the last report)' in notices[0].text
    status = core.status(5.3)
    assert status.level is Level.WARN and status.value('out_of_range') == '5'
    assert status.value('out_of_range_policy') == policy.value
    core.process_temperature(8000.0, now_s=5.4)
    core.process_counts(SEC, 10, 200.0, 200.0, 200.0, now_s=5.5)
    assert core.out_of_range == 5 and kinds(core) == []


def test_non_finite_temperature_code_ignored_and_counted():
    """A NaN or infinite code is refused; the last good code stays in force."""
    core = make()
    core.process_temperature(8300.0, now_s=0.0)
    assert not core.process_temperature(math.nan, now_s=0.1)
    assert not core.process_temperature(-math.inf, now_s=0.2)
    assert core.temp_code == 8300.0 and core.temperature_rejected == 2
    assert kinds(core) == ['temperature_rejected']
    result = core.process_counts(SEC, 0, 5.0, 6.0, 7.0, now_s=0.3)
    assert result == Corrector(CALIBRATION).correct_sample(5.0, 6.0, 7.0, 8300.0)
    assert core.status(0.4).value('temperature_rejected') == '2'


def test_online_equals_vectorised_correction_bit_for_bit():
    """process_counts gives Corrector.correct's float64 values, in and out of range."""
    rng = np.random.default_rng(3)
    counts = np.round(rng.uniform(-3000.0, 3000.0, (500, 3)))
    codes = np.round(rng.uniform(7400.0, 9000.0, 500))
    for policy in OutOfRange:
        core = make(out_of_range=policy)
        online = []
        for k, ((x, y, z), code) in enumerate(zip(counts.tolist(), codes.tolist())):
            core.process_temperature(code, now_s=k * 0.01)
            online.append(core.process_counts(SEC, k, x, y, z, now_s=k * 0.01))
        offline = Corrector(CALIBRATION, out_of_range=policy).correct(counts, codes)
        assert np.array_equal(np.array(online), offline)
        assert core.out_of_range == Corrector(CALIBRATION).out_of_range_count(codes) > 0


def test_counters_balance_and_appear_in_status():
    """Over a random mix of inputs: received == published + dropped, and the status says so."""
    rng = np.random.default_rng(7)
    core = make(stale_temperature=StaleTemperature.DROP, temp_timeout_s=0.05)
    now, step_ahead = 0.0, 0
    bad = [math.nan, math.inf, 0.5, 32767.0, -32768.0]
    for k in range(3000):
        now += float(rng.uniform(0.0, 0.02))
        if rng.random() < 0.1:
            core.process_temperature(float(rng.choice([8000.0, 9000.0, math.nan])), now_s=now)
        x, y, z = (float(v) for v in np.round(rng.uniform(-100.0, 100.0, 3)))
        if rng.random() < 0.05:
            x = float(rng.choice(bad))
        if rng.random() < 0.01:  # the clock steps 20 s ahead: one stamp_jump, then the stream goes on
            step_ahead += 20_000_000_000
        stamp = SEC * 1_000_000_000 + step_ahead + k * 1_000_000 - int(rng.integers(0, 3)) * 1_000_000
        core.process_counts(*divmod(stamp, 1_000_000_000), x, y, z, now_s=now)
    assert balanced(core)
    assert all(core.dropped[reason] > 0 for reason in ONLINE_DROP_REASONS
               if reason not in ('correction_failed', 'non_finite_output', 'non_physical'))  # counts: rails
    assert core.out_of_range > 0
    values = dict(core.status(now).values)
    dropped = sum(int(values[f'dropped.{reason}']) for reason in ONLINE_DROP_REASONS)
    assert int(values['received']) == 3000 == int(values['published']) + dropped
    assert int(values['dropped']) == dropped


def test_swap_calibration_takes_effect_on_the_next_message():
    """A new calibration is used from the next message on, with its own range and covariance."""
    core = make()
    core.process_temperature(9000.0, now_s=0.0)
    before = core.process_counts(SEC, 0, 50.0, 60.0, 70.0, now_s=0.1)
    assert core.out_of_range == 1
    x = CALIBRATION.axes[0]
    wider = replace(CALIBRATION, temp_code_max=9400.0,
                    axes=(replace(x, offset=x.offset + 1.0, residual_rms=3.0), *CALIBRATION.axes[1:]))
    core.swap_calibration(wider)
    after = core.process_counts(SEC, 1, 50.0, 60.0, 70.0, now_s=0.2)
    assert after == Corrector(wider).correct_sample(50.0, 60.0, 70.0, 9000.0) != before
    assert core.out_of_range == 1  # 9000 lies inside the new range
    assert core.variance == acceleration_variance(wider) != acceleration_variance(CALIBRATION)
    assert core.calibration_updates == 1 and core.calibration is wider
    assert core.out_of_range_policy is OutOfRange.CLAMP


@pytest.mark.parametrize('change', [
    {'temp_timeout_s': 0.0}, {'temp_timeout_s': math.nan}, {'temp_timeout_s': -1.0},
    {'stale_temperature': 'forget'}, {'out_of_range': 'wrap'},
    {'out_of_range': OutOfRange.EXTRAPOLATE, 'temp_timeout_s': math.inf},
])
def test_bad_policy_change_refused_and_nothing_changes(change):
    """An invalid policy change raises and leaves every policy as it was."""
    core = make(temp_timeout_s=2.0)
    corrector = core.corrector
    with pytest.raises(ValueError):  # noqa: PT011 - the message is checked by the node tests
        core.set_policies(**change)
    assert core.corrector is corrector and core.out_of_range_policy is OutOfRange.CLAMP
    assert core.temp_timeout_s == 2.0 and core.stale_policy is StaleTemperature.HOLD


def test_status_ok_when_all_is_well_and_lists_every_counter():
    """Fresh code, good counts: OK; every drop reason has a key."""
    core = make()
    core.process_temperature(8200.0, now_s=0.0)
    core.process_counts(SEC, 0, 1.0, 2.0, 3.0, now_s=0.1)
    status = core.status(0.2, imu_subscribers=2)
    assert status.level is Level.OK and status.message == 'correcting'
    keys = dict(status.values)
    assert {f'dropped.{reason}' for reason in ONLINE_DROP_REASONS} <= set(keys)
    assert keys['imu_subscribers'] == '2' and keys['calibrated_range'] == '7600..8800'
    assert keys['temperature_code'] == '8200' and keys['published'] == '1'


def test_no_counts_yet_is_a_warning():
    """A status before any counts message is WARN (is the driver running?)."""
    core = make()
    core.process_temperature(8200.0, now_s=0.0)
    status = core.status(0.1)
    assert status.level is Level.WARN and 'no counts messages yet' in status.message


def test_imu_covariance_layout():
    """REP 145 markers and the fit's diagonal (one layout for node and apply; test_node compares their output)."""
    variance = acceleration_variance(CALIBRATION)
    orientation, angular, linear = imu_covariances(variance)
    assert orientation[0] == angular[0] == -1.0 and not any(orientation[1:]) and not any(angular[1:])
    assert (linear[0], linear[4], linear[8]) == variance and variance[0] > 0.0


# -- driver input (six channels, temperature in degrees C) ----------------------------------------

DRIVER = Scenario(output='imu').driver_truth()  # temperature range 5..35 C, no effects
LAGGED = Scenario(output='imu', gyro_effects={'thermal_lag': {'tau_s': 20.0, 'slope_x': 0.002,
                                                              'slope_z': -0.001}}).driver_truth()


def test_driver_input_corrects_six_channels_as_the_vectorised_path_with_memory():
    """Accelerometer and gyroscope through UnitCorrector, float64-equal to correct(), lag state included."""
    rng = np.random.default_rng(11)
    values = rng.normal(0.0, 3.0, (400, 6))
    temperature = np.linspace(3.0, 38.0, 400)  # crosses both ends of 5..35
    stamps = SEC * 1_000_000_000 + np.arange(400, dtype=np.int64) * 10_000_000
    core = OnlineCompensator(LAGGED, temp_topic='/imu/temperature')
    assert core.channels == 6 and core.unit is LAGGED
    online = []
    for k in range(400):
        core.process_temperature(float(temperature[k]), now_s=k * 0.01)
        online.append(core.process_values(*divmod(int(stamps[k]), 1_000_000_000), tuple(values[k].tolist()),
                                          now_s=k * 0.01))
    offline = UnitCorrector(LAGGED).correct(values, temperature, stamp_s=seconds_from_ns(stamps))
    assert np.array_equal(np.array(online), offline)
    assert core.out_of_range == UnitCorrector(LAGGED).out_of_range_count(temperature) > 0
    notice = next(n for n in core.take_notices() if n.kind == 'out_of_range')
    assert 'temperature 3 outside the calibrated range 5..35' in notice.text
    status = core.status(5.0)
    assert status.value('input') == 'imu' and status.value('calibrated_range') == '5..35'
    assert status.value('temperature') == '38' and status.value('temperature_ref') == '20'
    orientation, angular, linear = core.covariances
    assert (angular[0], angular[4], angular[8]) == acceleration_variance(LAGGED.gyro)
    assert (linear[0], linear[4], linear[8]) == acceleration_variance(LAGGED.accel)


@pytest.mark.parametrize('index', range(6))
@pytest.mark.parametrize('bad', [math.nan, math.inf, -math.inf])
def test_driver_message_with_one_non_finite_value_dropped_whole(index, bad):
    """Any of the six values NaN or infinite: the whole message is dropped, as apply drops it."""
    core = OnlineCompensator(DRIVER)
    core.process_temperature(20.0, now_s=0.0)
    values = [0.1, -0.2, 9.8, 0.01, 0.02, -0.03]
    values[index] = bad
    assert core.process_values(SEC, 0, tuple(values), now_s=0.1) == 'non_finite'
    assert core.published == 0 and balanced(core)
    # Rails and fractions mean nothing for a driver's SI values: corrected (below the physical limit).
    assert isinstance(core.process_values(SEC, 1, (3276.7, 0.5, 1.25, -3276.8, 0.0, 0.0), now_s=0.2), tuple)


@pytest.mark.parametrize(('key', 'change', 'reason'), [
    ('residual_rms', {'residual_rms': 1e200}, 'calibration.gyro.x.residual_rms'),
    ('offset', {'offset': 1e308}, 'calibration.gyro.x.offset'),
    ('scale', {'scale': 1e-300}, 'calibration.gyro.x.scale'),
])
def test_absurd_driver_calibration_values_refused_by_the_one_parser(key, change, reason):
    """Values that pass a type check but would overflow later are refused, with the key."""
    from tak_thermo_ros.formats.calibration_file import unit_from_mapping, unit_to_mapping
    from tak_thermo_ros.errors import CalibrationError
    mapping = unit_to_mapping(DRIVER)
    mapping['gyro']['x'].update(change)
    with pytest.raises(CalibrationError, match=reason.replace('.', r'\.')):
        unit_from_mapping(mapping)


def test_counts_calibration_whose_covariance_or_correction_overflows_is_refused():
    """prepare() computes what the node later computes: a tiny scale that the parser allows is refused."""
    from tak_thermo_ros.errors import CalibrationError
    core = make()
    x = CALIBRATION.axes[0]
    tiny = replace(CALIBRATION, axes=(replace(x, scale=1e-300, residual_rms=1.0), *CALIBRATION.axes[1:]))
    with pytest.raises(CalibrationError, match='calibration'):
        core.prepare(calibration=tiny)
    with pytest.raises(CalibrationError, match='cannot replace'):
        core.prepare(calibration=DRIVER)
    assert core.calibration is CALIBRATION and core.calibration_updates == 0


# -- property test: generated message streams ----------------------------------------------------

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_value = st.one_of(st.floats(-50.0, 50.0), st.sampled_from([math.nan, math.inf, -math.inf, 0.0, 1e6, 1e308]))
_event = st.one_of(
    st.tuples(st.just('imu'), st.integers(-3, 4) | st.sampled_from([3_600_000, -3_600_000, 20_000]),  # ms
              st.tuples(*[_value] * 6), st.floats(0.0, 0.3)),
    st.tuples(st.just('temp'), st.one_of(st.floats(-10.0, 50.0), st.sampled_from([math.nan, -math.inf, 2e7])),
              st.floats(0.0, 0.3)),
    st.tuples(st.just('param'), st.sampled_from(['offset', 'range', 'extrapolate', 'clamp', 'drop', 'hold',
                                                 'absurd_rms', 'absurd_offset', 'tiny_scale', 'timeout'])),
)


def _changed(unit, what: str):
    """A calibration change, valid or absurd."""
    accel, gyro = unit.accel, unit.gyro
    x = gyro.axes[0]
    if what == 'offset':
        return replace(unit, gyro=replace(gyro, axes=(replace(x, offset=x.offset + 0.01), *gyro.axes[1:])))
    if what == 'range':
        return replace(unit, accel=replace(accel, temp_code_min=accel.temp_code_min - 5.0))
    value = {'absurd_rms': {'residual_rms': 1e200}, 'absurd_offset': {'offset': 1e308},
             'tiny_scale': {'scale': 1e-300}}[what]
    return replace(unit, gyro=replace(gyro, axes=(replace(x, **value), *gyro.axes[1:])))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_event, min_size=1, max_size=120))
def test_generated_streams_keep_every_invariant(events):
    """NaN, rails, stamps backwards, temperature gaps, parameter updates in the middle.

    Received == published + dropped, outputs finite and equal to UnitCorrector.correct on the published subset (per
    calibration in force), stamps (with jumps of an hour either way) dropped exactly as the offline rule drops them.
    """
    from tak_thermo_ros.formats.calibration_file import unit_from_mapping, unit_to_mapping
    from tak_thermo_ros.errors import CalibrationError
    core = OnlineCompensator(DRIVER, temp_timeout_s=0.5)
    now, stamp = 0.0, SEC * 1_000_000_000
    published: dict[int, tuple] = {}
    stamps_sent: list[int] = []
    stamp_drops: list[str | None] = []
    for event in events:
        if event[0] == 'temp':
            now += event[2]
            core.process_temperature(event[1], now_s=now)
        elif event[0] == 'imu':
            now += event[3]
            stamp += event[1] * 1_000_000
            result = core.process_values(*divmod(stamp, 1_000_000_000), event[2], now_s=now)
            stamps_sent.append(stamp)
            stamp_drops.append(result if result in STAMP_DROP_REASONS else None)
            if isinstance(result, tuple):
                assert all(math.isfinite(v) for v in result)
                group = published.setdefault(id(core.corrector), (core.corrector, [], [], [], []))
                group[1].append(event[2])
                group[2].append(core.temperature)
                group[3].append(stamp)
                group[4].append(result)
            else:
                assert result in ONLINE_DROP_REASONS
        else:
            what = event[1]
            if what in ('extrapolate', 'clamp'):
                core.set_policies(out_of_range=what)
            elif what in ('drop', 'hold'):
                core.set_policies(stale_temperature=what)
            elif what == 'timeout':
                core.set_policies(temp_timeout_s=0.2)
            else:
                before = core.unit
                candidate = _changed(core.unit, what)
                try:  # as the node: the one parser, then prepare(); install only what passed both
                    unit = unit_from_mapping(unit_to_mapping(candidate))
                    core.install(core.prepare(calibration=unit))
                except CalibrationError:
                    assert what.startswith(('absurd', 'tiny')) and core.unit is before
        assert balanced(core)
    offline, _ = stamp_problems(np.array(stamps_sent, dtype=np.int64))
    assert stamp_drops == [next((reason for reason, mask in offline.items() if mask[i]), None)
                           for i in range(len(stamps_sent))]
    for corrector, values, temperatures, stamps, results in published.values():
        offline = UnitCorrector(corrector.unit, out_of_range=corrector.correctors[0].out_of_range).correct(
            np.array(values), np.array(temperatures), stamp_s=seconds_from_ns(np.array(stamps, dtype=np.int64)))
        assert np.array_equal(np.array(results), offline)
    values = dict(core.status(now).values)
    assert int(values['received']) == int(values['published']) + int(values['dropped'])


def test_sequence_gaps_count_every_message_never_received():
    """Publication sequence numbers: each gap counted once, a restart starts afresh, status says it."""
    core = OnlineCompensator(DRIVER)
    assert core.status(0.0).value('sequence_gap') == 'unavailable'
    for number in (1, 2, 5, 6, 10, 3, 4, 8):  # 3..4 missing, 7..9 missing; 3 = another publisher or a restart
        core.sequence('imu', number, now_s=0.1)
    assert core.sequence_gaps == {'imu': 2 + 3 + 3} and core.sequence_gap_total() == 8
    notice = core.take_notices()[0]
    assert notice.kind == 'sequence_gap' and 'sequence numbers 3..4' in notice.text
    status = core.status(0.2)
    assert status.value('sequence_gap') == '8' and status.value('sequence_gap.imu') == '8'
    assert status.level is Level.WARN and '8 messages never received' in status.message
    core.message_lost('temperature', 4, now_s=0.3)
    assert core.status(0.4).value('message_lost.temperature') == '4' and core.lost_total() == 4
    # A loss the middleware reports does not hold back the log line of a gap, nor the other way round.
    assert [n.kind for n in core.take_notices()] == ['message_lost']
    core.sequence('imu', 12, now_s=100.0)
    assert [n.kind for n in core.take_notices()] == ['sequence_gap']


# -- a driver's messages that carry one sensor (covariance[0] = -1 marks the other absent) ---------

from own_stamps import absent_marks, core_output, own_stamps_record, own_stamps_unit  # noqa: E402

from tak_thermo_ros.core.effects import Effect, ParameterSpec, aux_effect_class  # noqa: E402
from tak_thermo_ros.core.link.correction import NOT_PROVIDED  # noqa: E402
from tak_thermo_ros.core.link.online_rules import (  # noqa: E402
    IMU_DROP_REASONS,
    SENSORS,
    SIGNAL_DROP_REASONS,
    OneSensor,
)
from tak_thermo_ros.core.records.drops import temp_code_problem  # noqa: E402
from tak_thermo_ros.core.records.record import sensor_messages  # noqa: E402

APART = own_stamps_unit()
"""The driver unit with an effect with memory on each sensor (accelerometer hysteresis, gyroscope lag)."""
NAN3 = (math.nan, math.nan, math.nan)
STEP_NS = 10_000_000


def _sensor_series(unit, sensor: str, samples: list[tuple]) -> np.ndarray:
    """``correct`` of one sensor's samples ``(values, temperature, stamp_ns)`` from the effects' initial state."""
    values, temperatures, stamps = (np.array(column) for column in zip(*samples))
    return Corrector(unit.sensor(sensor)).correct(values, temperatures,
                                                  stamp_s=seconds_from_ns(stamps.astype(np.int64)))


def test_one_sensor_messages_are_corrected_on_each_sensors_own_samples_and_published_marked():
    """A mark starts per-sensor streams: own stamps, own effect state; absent values never read, published marked."""
    core = OnlineCompensator(APART)
    core.process_temperature(20.0, now_s=0.0)
    first = (0.1, -0.2, 9.8, 0.01, 0.02, -0.03)
    assert isinstance(core.process_values(SEC, 0, first, 0.1), tuple) and core.own_stamps_since is None
    accel_only = core.process_values(SEC, STEP_NS, (0.2, -0.1, 9.7, *NAN3), 0.2, 0.5, NOT_PROVIDED)
    assert isinstance(accel_only, OneSensor) and accel_only.sensor == 'accel'
    notice = core.take_notices()[0]
    assert notice.kind == 'own_stamps' and 'Imu message 2 marks the gyroscope absent' in notice.text
    core.process_temperature(24.0, now_s=0.25)
    # The gyroscope's own stream: the accelerometer's stamp is no duplicate of it; its absent values are not read.
    gyro_only = core.process_values(SEC, STEP_NS, (*NAN3, 0.03, 0.01, 0.02), 0.3, NOT_PROVIDED, 0.0)
    assert isinstance(gyro_only, OneSensor) and gyro_only.sensor == 'gyro'
    # One message out per message in; apply's writer puts the two samples of one stamp in one message (docs/node.md).
    assert len(sensor_messages(np.array([SEC * 10**9 + STEP_NS]), np.array([SEC * 10**9 + STEP_NS])).stamp_ns) == 1
    assert core.process_values(SEC, STEP_NS, (0.3, 0.0, 9.9, *NAN3), 0.35, 0.0, NOT_PROVIDED) == 'duplicate_stamp'
    assert 'Imu accelerometer sample\'s header stamp equal to the previous one\'s' in core.take_notices()[0].text
    last = (0.0, 0.1, 9.6, -0.01, 0.0, 0.04)
    both = core.process_values(SEC, 2 * STEP_NS, last, 0.4)  # no mark: both, each on its own stream now
    assert both.__class__ is tuple and len(both) == 6
    accel = [(first[:3], 20.0, SEC * 10**9), ((0.2, -0.1, 9.7), 20.0, SEC * 10**9 + STEP_NS),
             (last[:3], 24.0, SEC * 10**9 + 2 * STEP_NS)]
    gyro = [(first[3:], 20.0, SEC * 10**9), ((0.03, 0.01, 0.02), 24.0, SEC * 10**9 + STEP_NS),
            (last[3:], 24.0, SEC * 10**9 + 2 * STEP_NS)]
    assert np.array_equal(_sensor_series(APART, 'accel', accel)[1:], [accel_only.values, both[:3]])
    assert np.array_equal(_sensor_series(APART, 'gyro', gyro)[1:], [gyro_only.values, both[3:]])
    status = core.status(0.5)
    assert status.value('sensor_stamps') == 'own (each sensor apart from message 2 on)'
    assert status.value('one_sensor_messages') == '3' and status.value('sensor_dropped') == '0'
    assert status.value('dropped.duplicate_stamp') == '1' and status.value('dropped.no_sensor') == '0'
    assert (core.received, core.published) == (5, 4) and balanced(core)


def test_before_any_mark_a_bad_sensor_drops_the_whole_message_after_it_only_that_sensor():
    """The one difference from apply (docs/node.md): the node cannot know the sensors come apart before a mark."""
    core = OnlineCompensator(APART)
    core.process_temperature(20.0, now_s=0.0)
    bad_gyro = (0.1, -0.2, 9.8, 0.01, math.nan, -0.03)
    assert core.process_values(SEC, 0, bad_gyro, 0.1) == 'non_finite'  # shared: dropped whole, as ever
    assert isinstance(core.process_values(SEC, STEP_NS, (*NAN3, 0.0, 0.0, 0.0), 0.2, NOT_PROVIDED, 0.0), OneSensor)
    kept = core.process_values(SEC, 2 * STEP_NS, bad_gyro, 0.3)  # apart: the accelerometer is published
    assert kept == OneSensor('accel', kept.values) and core.sensor_dropped == {'gyro.non_finite': 1}
    both_bad = (1e308, 0.0, 9.8, math.inf, 0.0, 0.0)
    assert core.process_values(SEC, 3 * STEP_NS, both_bad, 0.4) == 'non_physical'  # the first sensor's reason
    assert core.process_values(SEC, 4 * STEP_NS, (*NAN3, *NAN3), 0.5, NOT_PROVIDED, NOT_PROVIDED) == 'no_sensor'
    status = core.status(0.6)
    assert status.level is Level.WARN and 'left out of published messages: 1 gyro non_finite' in status.message
    assert status.value('sensor_dropped.gyro.non_finite') == '1' and status.value('dropped.no_sensor') == '1'
    assert (status.value('dropped.non_finite'), status.value('dropped.non_physical')) == ('1', '1')
    assert int(status.value('received')) == 5 == int(status.value('published')) + int(status.value('dropped'))


def test_a_recorded_signal_is_waited_for_by_the_sensor_whose_terms_need_it():
    """Apart, the accelerometer goes on while the gyroscope's aux term waits for its signal."""
    supply = aux_effect_class('aux:/power/battery_state')(tau_s=0.0, reference=12.0, slope_x=0.002)
    unit = replace(DRIVER, gyro=replace(DRIVER.gyro, effects=(supply,)))
    core = OnlineCompensator(unit)
    core.process_temperature(20.0, now_s=0.0)
    assert core.process_values(SEC, 0, (0.0, 0.0, 9.8, 0.0, 0.0, 0.0), 0.1) == 'waiting_for_signal'
    assert core.process_values(SEC, STEP_NS, (0.0, 0.0, 9.8, *NAN3), 0.2, 0.0, NOT_PROVIDED) == OneSensor(
        'accel', Corrector(unit.accel).correct_sample(0.0, 0.0, 9.8, 20.0))
    result = core.process_values(SEC, 2 * STEP_NS, (0.0, 0.0, 9.8, 0.0, 0.0, 0.0), 0.3)
    assert isinstance(result, OneSensor) and core.sensor_dropped == {'gyro.waiting_for_signal': 1}
    assert core.process_values(SEC, 3 * STEP_NS, (*NAN3, 0.0, 0.0, 0.0), 0.4, NOT_PROVIDED, 0.0) == \
        'waiting_for_signal'
    core.process_signal('aux:/power/battery_state', 12.5, now_s=0.45)
    assert core.process_values(SEC, 4 * STEP_NS, (0.0, 0.0, 9.8, 0.0, 0.0, 0.0), 0.5).__class__ is tuple
    assert balanced(core) and set(SIGNAL_DROP_REASONS) <= set(core.dropped)


class _Fragile(Effect):
    """A user effect that fails in service (a stamp after 2020), not over the calibrated range at start-up."""

    name = 'fragile'
    summary = 'Raises on a stamp after 2020.'
    confirm = 'None.'
    needs_stamps = True
    amplitude = ParameterSpec('rate', 0.0, -1.0, 1.0, 'counts')

    def step(self, state, stamp_s, temp_code):
        if stamp_s > 1.6e9:
            raise RuntimeError('fragile')
        return state, (0.0,)


def test_a_correction_that_fails_on_one_sensor_leaves_that_sensor_out():
    """Apart, the gyroscope's failing effect leaves its sample out; the accelerometer's is published."""
    unit = replace(DRIVER, gyro=replace(DRIVER.gyro, effects=(_Fragile(),)))
    core = OnlineCompensator(unit, warn_period_s=0.0)
    core.process_temperature(20.0, now_s=0.0)
    assert core.process_values(SEC, 0, (0.0, 0.0, 9.8, 0.0, 0.0, 0.0), 0.1) == 'correction_failed'
    assert core.process_values(SEC, STEP_NS, (*NAN3, 0.0, 0.0, 0.0), 0.2, NOT_PROVIDED, 0.0) == 'correction_failed'
    result = core.process_values(SEC, 2 * STEP_NS, (0.0, 0.0, 9.8, 0.0, 0.0, 0.0), 0.3)
    assert result == OneSensor('accel', Corrector(unit.accel).correct_sample(0.0, 0.0, 9.8, 20.0))
    assert core.sensor_dropped == {'gyro.correction_failed': 1} and core.dropped['correction_failed'] == 2
    status = core.status(0.4)
    assert status.level is Level.ERROR and 'left out of published messages: 1 gyro correction_failed' in status.message
    texts = [n.text for n in core.take_notices() if n.kind == 'correction_failed']
    assert texts[0].startswith('Imu message dropped') and texts[0].endswith('; 1 so far)')
    assert texts[1].startswith('Imu gyroscope sample left out, the correction gave no finite number')
    assert balanced(core)


def test_a_bag_whose_sensors_come_apart_is_corrected_as_apply_writes_it_but_the_documented_message(tmp_path):
    """Apply of a bag with its own stamps per sensor, and the core fed its messages: equal, marks included.

    Except the one message before the first mark whose gyroscope sample is NaN: apply keeps its
    accelerometer sample, the node drops it whole (the accelerometer has no effect with memory
    here, so nothing after it differs).
    """
    from tak_thermo_ros import cli
    from tak_thermo_ros.formats.bag import read_imu_messages, write_driver_record
    from tak_thermo_ros.formats.calibration_file import load_unit, save_unit
    bag, params, applied = tmp_path / 'apart.mcap', tmp_path / 'params.yaml', tmp_path / 'applied.mcap'
    write_driver_record(bag, own_stamps_record(shared_fault=True))
    save_unit(params, own_stamps_unit(accel_memory=False))
    assert cli.main(['apply', str(bag), '--params', str(params), '-o', str(applied), '--no-progress']) == 0
    expected = read_imu_messages(applied, topic='/imu/data_compensated')
    core, got, _ = core_output(bag, load_unit(params))
    only_apply = np.setdiff1d(expected.stamp_ns, got['stamp_ns'])
    assert len(only_apply) == 1 and only_apply[0] == expected.stamp_ns[2]  # the third message, before the mark
    assert expected.angular_velocity_covariance[2, 0] == NOT_PROVIDED  # apply: its accelerometer alone
    keep = expected.stamp_ns != only_apply[0]
    assert np.array_equal(got['stamp_ns'], expected.stamp_ns[keep])
    assert np.array_equal(got['accel'], expected.linear_acceleration[keep])
    assert np.array_equal(got['gyro'], expected.angular_velocity[keep])
    assert np.array_equal(got['accel_absent'], expected.linear_acceleration_covariance[keep, 0] == NOT_PROVIDED)
    assert np.array_equal(got['gyro_absent'], expected.angular_velocity_covariance[keep, 0] == NOT_PROVIDED)
    assert np.array_equal(got['orientation'], expected.orientation[keep])
    assert got['accel_absent'].sum() > 30 and got['gyro_absent'].sum() > 10 and core.own_stamps_since == 6
    assert core.dropped['non_finite'] == 1 and core.sensor_dropped == {'gyro.non_finite': 1}
    assert core.received == core.published + core.dropped_total() and core.received > absent_marks(
        read_imu_messages(bag, topic='/imu/data_raw'))


# The property: generated streams mixing both-sensor and one-sensor messages, the offline rule as the oracle.

_CARRIED = st.sampled_from([(True, True)] * 3 + [(True, False), (False, True)] * 2 + [(False, False)])
_apart_event = st.one_of(
    st.tuples(st.just('imu'), st.integers(-3, 4) | st.sampled_from([0, 3_600_000, -3_600_000, 20_000]),  # ms
              st.tuples(*[_value] * 6), _CARRIED, st.floats(0.0, 0.3)),
    st.tuples(st.just('temp'), st.one_of(st.floats(-10.0, 50.0), st.sampled_from([math.nan, 2e7])),
              st.floats(0.0, 0.3)),
)


def _offline_reasons(stamps: list[int], values: list[tuple]) -> list[str | None]:
    """Per sample of one stream, why the offline rule leaves it out (stamps, then values), or ``None``."""
    if not stamps:
        return []
    masks, _ = stamp_problems(np.array(stamps, dtype=np.int64))
    problems = counts_problems(np.array(values, dtype=float), whole_codes=False)
    return [next((reason for reason, mask in (*masks.items(), *problems.items()) if mask[i]), None)
            for i in range(len(stamps))]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_apart_event, min_size=1, max_size=120))
def test_generated_streams_of_one_and_two_sensor_messages_follow_the_offline_rule(events):
    """Received == published + dropped after every message; what is published, dropped and left out is apply's rule.

    The oracle: before the first mark, the shared rule over whole messages (stamps, then the six
    values); from it on, each sensor's stamps and values alone (``stamp_problems``,
    ``counts_problems`` per sensor stream); no temperature yet drops the message; each sensor's
    published values equal ``Corrector.correct`` of that sensor's published samples, effects with
    memory included.
    """
    core = OnlineCompensator(APART, temp_timeout_s=0.5)
    now, stamp = 0.0, SEC * 1_000_000_000
    messages, temperature_known = [], False
    for event in events:
        if event[0] == 'temp':
            now += event[2]
            core.process_temperature(event[1], now_s=now)
            temperature_known = temperature_known or temp_code_problem(event[1], 'imu') is None
        else:
            _, step_ms, values, carried, dt = event
            now += dt
            stamp += step_ms * 1_000_000
            marks = tuple(0.0 if there else NOT_PROVIDED for there in carried)
            result = core.process_values(*divmod(stamp, 1_000_000_000), values, now, *marks)
            messages.append((stamp, values, carried, temperature_known, core.temperature, result))
        assert balanced(core)
    apart_from = next((i for i, m in enumerate(messages) if not all(m[2])), len(messages))
    shared_reasons = _offline_reasons([m[0] for m in messages[:apart_from]], [m[1] for m in messages[:apart_from]])
    sensor_rows = [[i for i, m in enumerate(messages) if m[2][s]] for s in (0, 1)]
    sensor_reasons = [dict(zip(rows, _offline_reasons([messages[i][0] for i in rows],
                                                      [messages[i][1][3 * s:3 * s + 3] for i in rows])))
                      for s, rows in enumerate(sensor_rows)]
    published: list[list[tuple]] = [[], []]
    left_out: dict[str, int] = {}
    for i, (stamp_ns, values, carried, known, temperature, result) in enumerate(messages):
        if i < apart_from:
            reason = shared_reasons[i] or (None if known else 'waiting_for_temperature')
            expected = reason or 'both'
        elif not any(carried):
            expected = 'no_sensor'
        else:
            reasons = [sensor_reasons[s].get(i) if carried[s] else None for s in (0, 1)]
            live = [s for s in (0, 1) if carried[s] and reasons[s] is None]
            if not live:
                expected = reasons[0] if carried[0] else reasons[1]
            elif not known:
                expected = 'waiting_for_temperature'
            else:
                expected = 'both' if len(live) == 2 else SENSORS[live[0]]
                for s in (0, 1):
                    if carried[s] and s not in live:
                        key = f'{SENSORS[s]}.{reasons[s]}'
                        left_out[key] = left_out.get(key, 0) + 1
        got = ('both' if result.__class__ is tuple else result.sensor if isinstance(result, OneSensor) else result)
        assert got == expected, (i, messages[i])
        assert result in (*ONLINE_DROP_REASONS, *IMU_DROP_REASONS) if isinstance(result, str) else True
        outputs = result if result.__class__ is tuple else (
            (*result.values, None, None, None) if got == 'accel' else (None, None, None, *result.values)
            if got == 'gyro' else ())
        for s in (0, 1):
            if outputs and outputs[3 * s] is not None:
                published[s].append((values[3 * s:3 * s + 3], temperature, stamp_ns, outputs[3 * s:3 * s + 3]))
    assert core.sensor_dropped == left_out
    for s, sensor in enumerate(SENSORS):
        if published[s]:
            offline = _sensor_series(APART, sensor, [sample[:3] for sample in published[s]])
            assert np.array_equal(np.array([sample[3] for sample in published[s]]), offline)
    values = dict(core.status(now).values)
    assert int(values['received']) == int(values['published']) + int(values['dropped']) == len(messages)


def test_malformed_messages_are_counted_where_they_belong_and_said_throttled():
    """Bytes that are no message (the node's raw path): an input one dropped, a temperature one rejected; one line."""
    core = make()
    core.process_temperature(8200.0, now_s=0.0)
    core.malformed(False, '/tak/counts: malformed geometry_msgs/msg/Vector3Stamped (28 bytes): truncated', 0.1)
    core.malformed(False, '/tak/counts: malformed ...', 0.2)  # within the warning period: counted, not said
    core.malformed(True, '/tak/temp_code: malformed sensor_msgs/msg/Temperature (8 bytes): truncated', 0.3)
    assert core.process_counts(SEC, 0, 1.0, 2.0, 3.0, now_s=0.4).__class__ is tuple
    assert balanced(core) and core.received == 3 and core.dropped['malformed'] == 2 and core.published == 1
    assert core.temperature == 8200.0 and core.temperature_rejected == 1 and core.temperature_messages == 2
    lines = [notice.text for notice in core.take_notices()]
    assert lines == ['/tak/counts: malformed geometry_msgs/msg/Vector3Stamped (28 bytes): truncated: dropped '
                     '(1 so far)',
                     '/tak/temp_code: malformed sensor_msgs/msg/Temperature (8 bytes): truncated: ignored; keeping '
                     'the last temperature code (1 so far)']
    core.malformed(False, '/tak/counts: malformed ...', 10.0)
    assert core.take_notices()[0].text == '/tak/counts: malformed ...: dropped (3 so far; 2 more since the last report)'
    status = core.status(10.1)
    assert dict(status.values)['dropped.malformed'] == '3' and 'dropped 3 malformed' in status.message
