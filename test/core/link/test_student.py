"""Student's t thresholds without scipy (the node's path) against scipy's, and the watch's use of them."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import given, settings, strategies as st
from scipy import stats

from tak_thermo_ros.core.link.model import TurnOn
from tak_thermo_ros.core.link.student import t_two_sided_threshold, two_sided_threshold
from tak_thermo_ros.core.link.watch import WatchSettings
from tak_thermo_ros.core.values import DEG_PER_H

from everyday_watch import LATITUDE, everyday_runs, watch_run, watch_unit


@settings(max_examples=300, deadline=None)
@given(st.integers(min_value=1, max_value=100_000), st.floats(min_value=1e-12, max_value=0.5))
def test_the_threshold_is_scipys_for_every_whole_number_of_degrees(degrees, probability):
    """Within 1e-7 relative of ``scipy.stats.t.isf`` from 1 to 100,000 degrees of freedom, 1e-12 to 0.5."""
    expected = stats.t.isf(probability / 2.0, degrees)
    assert abs(t_two_sided_threshold(probability, degrees) - expected) <= 1e-7 * expected


def test_the_threshold_falls_to_the_normals_as_the_power_ups_grow():
    """Heavier than the normal's for every count, falling with it, the normal's within 1e-5 at 10^7."""
    thresholds = [t_two_sided_threshold(1e-6, degrees) for degrees in (1, 2, 4, 15, 100, 10_000)]
    assert all(a > b for a, b in zip(thresholds, thresholds[1:])) and thresholds[-1] > two_sided_threshold(1e-6)
    assert abs(t_two_sided_threshold(1e-6, 10_000_000) - two_sided_threshold(1e-6)) <= 1e-5


def test_a_repeatability_from_few_power_ups_judges_a_turn_on_as_a_students_t():
    """A power-up 4.6 sigma from the curve: stale against a spread from 10,000 power-ups, held against 16's.

    The run's own turn-on (1.4 sigma) and 3 spreads added: 4.6 sigma with the spread taken as known,
    beyond the first rest's threshold (3.7); estimated from 16 records (a pool's), a new power-up's
    offset over it is Student's t with 15 degrees of freedom, whose tail there is 30 times the
    normal's: not said (issue 39's second everyday setting: a pool's file called healthy runs stale
    so). 30 spreads out: said by both.
    """
    unit = watch_unit()
    spread = tuple(float(v) for v in unit.gyro.known_turn_on.repeatability)
    simulated = everyday_runs(0, ('healthy',))['healthy']
    verdicts = {}
    for shift in (3.0, 30.0):
        moved = replace(simulated, record=replace(simulated.record, gyro=simulated.record.gyro + np.array(
            [shift * spread[0], 0.0, 0.0])))
        for records in (16, 10_000):
            turn_on = TurnOn(spread, tuple(0.2 * v for v in spread), records)
            file = replace(unit, gyro=replace(unit.gyro, turn_on=turn_on))
            watch, _, _ = watch_run(moved, file, WatchSettings(latitude=LATITUDE))
            verdicts[shift, records] = [(f.kind, f.rest) for f in watch.findings.values() if f.channel == 'gyro x']
    assert verdicts[3.0, 10_000] == [('offset', 1)] and verdicts[3.0, 16] == [], verdicts
    assert verdicts[30.0, 10_000] == [('offset', 1)] and verdicts[30.0, 16] == [('offset', 1)], verdicts
    assert spread[0] * DEG_PER_H > 10.0
