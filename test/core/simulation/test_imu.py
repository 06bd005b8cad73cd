"""The chamber simulator: deterministic, the paper's protocol, 16-bit codes, scenario files."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from conftest import SHORT
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.formats.scenario import load_scenario
from tak_thermo_ros.errors import ScenarioError


def test_same_seed_same_run_other_seed_other_noise():
    """A seed fixes the run; another seed changes the noise only."""
    first, again, other = (simulate(replace(SHORT, seed=s)) for s in (1, 1, 2))
    assert np.array_equal(first.record.counts, again.record.counts)
    assert np.array_equal(first.record.temp_code, again.record.temp_code)
    assert not np.array_equal(first.record.counts, other.record.counts)
    assert np.array_equal(first.record.temp_code, other.record.temp_code)


def test_default_protocol_is_the_papers():
    """Plateaus at 5, 15, 20, 30, 35 C, three hours each, joined by ramps."""
    scenario = Scenario()
    assert scenario.plateaus_celsius == (5.0, 15.0, 20.0, 30.0, 35.0)
    ramps_h = (15 + 10 + 5 + 10 + 5) / scenario.ramp_celsius_per_minute / 60.0
    assert scenario.duration_s() == pytest.approx((5 * 3.0 + ramps_h) * 3600.0)


def test_board_follows_the_chamber_through_a_first_order_lag(short_run):
    """During a ramp the board lags the chamber by rate x tau; on a long plateau it catches up."""
    scenario = short_run.scenario
    gap = short_run.chamber_celsius - short_run.board_celsius
    rate = scenario.ramp_celsius_per_minute / 60.0
    longest_ramp_s = 15.0 / rate  # 20 C down to 5 C
    steady_gap = rate * scenario.board_lag_s * (1.0 - np.exp(-longest_ramp_s / scenario.board_lag_s))
    assert np.max(np.abs(gap)) == pytest.approx(steady_gap, rel=0.01)
    assert abs(gap[-1]) < 0.01


def test_codes_are_rounded_16_bit_integers_and_saturate():
    """Counts are whole numbers in int16; a huge offset saturates at 32767."""
    loud = replace(SHORT.unit[0], offset=31000.0)
    run = simulate(replace(SHORT, unit=(loud, *SHORT.unit[1:])))
    counts = run.record.counts
    assert np.array_equal(counts, np.round(counts))
    assert counts.min() >= -32768 and counts.max() <= 32767
    assert np.any(counts[:, 0] == 32767)


def test_temperature_codes_come_at_a_lower_rate(short_run):
    """One temperature code per temp_code_every counts; rounded affine in board temperature."""
    record = short_run.record
    assert len(record.temp_code) == -(-len(record.counts) // SHORT.temp_code_every)
    expected = np.round(SHORT.temp_code_ref + SHORT.codes_per_celsius
                        * (short_run.board_celsius[::SHORT.temp_code_every] - SHORT.reference_celsius))
    assert np.array_equal(record.temp_code, expected)


def test_turntable_gives_every_axis_zero_and_mixed_inputs(short_run):
    """Each axis sees +g, -g, 0 g and tilted inputs; the reference is published on change."""
    reference = short_run.record.reference
    for axis in range(3):
        values = np.round(reference[:, axis] / SHORT.gravity, 6)
        assert {1.0, -1.0, 0.0} <= set(values)
        assert len(set(values)) >= 4
    assert np.all(np.any(reference[1:] != reference[:-1], axis=1))


def test_scenario_file_overrides_defaults(tmp_path):
    """Keys in a scenario YAML override the defaults, including one axis of the unit."""
    path = tmp_path / 'scenario.yaml'
    path.write_text('sample_rate_hz: 2\nplateaus_celsius: [10, 30]\nunit: {y: {noise_counts: 0.5}}\n')
    scenario = load_scenario(path)
    assert scenario.sample_rate_hz == 2.0 and scenario.plateaus_celsius == (10.0, 30.0)
    assert scenario.unit[1].noise_counts == 0.5 and scenario.unit[0] == Scenario().unit[0]


@pytest.mark.parametrize(('text', 'message'), [
    ('sample_rte_hz: 2', 'sample_rte_hz: unknown scenario key'),
    ('sample_rate_hz: fast', 'sample_rate_hz: expected a finite number'),
    ('sample_rate_hz: -1', 'sample_rate_hz: must be > 0'),
    ('plateaus_celsius: 20', 'plateaus_celsius: expected a list of numbers'),
    ('positions: [[1, 1, 0]]', r'positions: \[1.0, 1.0, 0.0\] is not a unit vector'),
    ('unit: {w: {scale: 1}}', 'unit.w: unknown axis'),
    ('unit: {x: {gain: 1}}', 'unit.x.gain: unknown key'),
    ('temp_code_every: 2.5', 'temp_code_every: expected an integer'),
    ('- 1\n- 2', 'scenario: expected a mapping'),
])
def test_bad_scenarios_name_the_key(tmp_path, text, message):
    """A bad scenario names the file and the key."""
    path = tmp_path / 'scenario.yaml'
    path.write_text(text)
    with pytest.raises(ScenarioError, match=message) as error:
        load_scenario(path)
    assert str(error.value).startswith(str(path))
