"""The calibration's own uncertainty: the file's section, its covariance over seeds, and what the watch makes of it."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from everyday_watch import LATITUDE, everyday_runs, watch_run
from tak_thermo_ros.core.fit.link_uncertainty import HeldSpreads, link_uncertainty
from tak_thermo_ros.core.link.uncertainty import LinkUncertainty
from tak_thermo_ros.core.link.watch import WatchSettings
from tak_thermo_ros.core.simulation.everyday import SECOND_HABITS, everyday_scenario, everyday_truth
from tak_thermo_ros.errors import CalibrationError
from tak_thermo_ros.formats.calibration_file import load_unit, save_unit

NAMES = ('x.offset', 'x.offset_T1', 'x.offset_T2', 'x.scale', 'x.scale_T1')
KINDS = ('offset', 'offset_T', 'offset_T', 'scale', 'scale_T')


def _fit(seed: int, held: list[int], spreads: HeldSpreads, *,
         drawn: bool = True) -> tuple[np.ndarray, np.ndarray, LinkUncertainty]:
    """One axis at one input (1 g) over a temperature span; the held columns at their values: the errors, the section.

    The truth's held terms are drawn with the default spreads (what the section claims of them);
    ``drawn=False``: the truth's own (a curvature of -0.004).
    """
    rng = np.random.default_rng([seed, 39])
    u = np.linspace(-1.0, 1.0, 80)
    force = np.full_like(u, 9.8)  # one input: the scale and its drift act as the offset and its slope
    design = np.column_stack([np.ones_like(u), u, u * u, force, force * u])
    truth = np.array([0.05, 0.01, -0.004, 1.0, 0.0])
    for j in held if drawn else ():
        truth[j] += rng.standard_normal() * spreads.spread('accel', KINDS[j], 1.0)
    sigma = 2e-3
    target = design @ truth + sigma * rng.standard_normal(len(u))
    free = [j for j in range(5) if j not in held]
    values = np.array([0.0, 0.0, 0.0, 1.0, 0.0])
    solved, *_ = np.linalg.lstsq(design[:, free], target - design[:, held] @ values[held], rcond=None)
    values[free] = solved
    residual = target - design @ values
    variance = float(residual @ residual) / (len(u) - len(free))
    normal = design.T @ design
    covariance = variance * np.linalg.inv(normal[np.ix_(free, free)])
    section = link_uncertainty(NAMES, KINDS, normal, design.T @ residual, free, covariance, np.full(5, variance),
                               held, sensor='accel', temperature_scale=1.0, spreads=spreads)
    order = [NAMES.index(name) for name in section.terms]
    return values[order] - truth[order], truth, section


def test_the_files_covariance_covers_its_errors_held_terms_included():
    """Over 400 fits each term's error lies within 2 of its standard deviations about 95 % of the time.

    The held scale and its drift at 1 g act as the offset and its slope: the fitted terms take them
    up (``A D A'``), which the fitted terms' covariance alone misses (it covers far less).
    """
    spreads = HeldSpreads(accel_scale=5e-3, accel_scale_drift=1e-3)
    covered, alone = [], []
    for seed in range(400):
        error, _, section = _fit(seed, [3, 4], spreads)
        assert section.held_from == ('default', 'default')
        covered.append(np.abs(error) <= 2.0 * np.sqrt(np.diag(section.covariance)))
        alone.append(abs(error[0]) <= 2.0 * math.sqrt(_free_only(seed, [3, 4], spreads)))
    rate = np.mean(covered, axis=0)
    assert np.all((rate > 0.92) & (rate < 0.98)), rate
    assert np.mean(alone) < 0.5


def _free_only(seed: int, held: list[int], spreads: HeldSpreads) -> float:
    """The offset's variance a fit's covariance alone gives (the held terms taken as exact)."""
    tiny = HeldSpreads(accel_scale=1e-12, accel_scale_drift=1e-12, accel_offset_drift=1e-12)
    _, _, section = _fit(seed, held, tiny)
    return float(section.covariance[section.terms.index('x.offset'), section.terms.index('x.offset')])


def test_a_term_the_records_bound_takes_its_spread_from_them():
    """A held curvature the records see is spread by what they say of it (``sqrt(d^2 + s^2)``), not the default.

    Conservative: over 200 fits its error lies within 2 of its spreads more often than 95 %.
    """
    covered = []
    for seed in range(200):
        error, truth, section = _fit(seed, [2], HeldSpreads(accel_offset_drift=1.0), drawn=False)
        index = section.terms.index('x.offset_T2')
        assert section.held == ('x.offset_T2',) and section.held_from == ('records',)
        spread = math.sqrt(section.covariance[index, index])
        assert spread < 0.05  # the default (1 m/s^2 per C at the edge) would be 1
        covered.append(np.abs(error) <= 2.0 * np.sqrt(np.diag(section.covariance)))
    assert np.all(np.mean(covered, axis=0) >= 0.94), np.mean(covered, axis=0)


def test_the_section_round_trips_and_refuses_what_is_no_covariance(tmp_path):
    """Written and read back equal; a bad term, a short triangle, a held term not among the terms: one line each."""
    scenario, habits = everyday_scenario({'everyday': {'records': 2}})
    truth = everyday_truth(scenario, habits)
    section = LinkUncertainty.of(('x.offset', 'x.scale', 'c_zx'), np.diag([1e-6, 1e-5, 1e-4]), 12.5, ('c_zx',),
                                 ('default',))
    unit = replace(truth, accel=replace(truth.accel, uncertainty=section))
    save_unit(tmp_path / 'p.yaml', unit)
    assert load_unit(tmp_path / 'p.yaml').accel.uncertainty == section
    for terms, upper, held, words in ((('x.bias',), (1.0,), (), 'unknown term'),
                                      (('x.offset', 'y.offset'), (1.0, 0.0), (), 'the upper triangle'),
                                      (('x.offset',), (1.0,), ('y.offset',), 'held'),
                                      (('x.offset',), (-1.0,), (), 'negative variance')):
        with pytest.raises(CalibrationError, match=words):
            LinkUncertainty(terms, upper, 1.0, held, ('default',) * len(held))


def _tilted_runs(count: int):
    """Everyday runs on ground tilted up to 15 deg (the second setting's habits), 10 minutes at 10 Hz.

    The unit's accelerometer scales x and y are off by +0.6 % and -0.6 %.
    """
    scenario, habits = everyday_scenario({'sample_rate_hz': 10.0, 'seed': 5,
                                          'accel_unit': {'x': {'scale': 1.006}, 'y': {'scale': 0.994}},
                                          'everyday': {**SECOND_HABITS, 'records': count, 'record_minutes': 10.0}})
    return scenario, habits, [everyday_runs(index, ('healthy',), scenario, habits)['healthy'] for index in range(count)]


def test_a_held_scale_at_a_tilt_is_said_undetermined_not_stale():
    """A file holding the x and y scales at 1 (a unit 0.6 % off): tilted rests are said, not called stale.

    Without the section the watch counts the held scales as exact and calls the healthy unit stale
    (``g s u_x^2``: 0.4 mg at 15 deg); with it (the held scales' spread 0.5 %), the rests where the
    file leaves ``|f|`` undetermined are said and left out, and no run is stale.
    """
    scenario, habits, runs = _tilted_runs(6)
    truth = everyday_truth(scenario, habits)
    noise = {sensor: scenario.noise_truth(sensor) for sensor in ('accel', 'gyro')}
    from tak_thermo_ros.core.link.model import TurnOn
    turn_on = {sensor: TurnOn(tuple(habits.turn_on(sensor)), tuple(0.2 * habits.turn_on(sensor)), 16)
               for sensor in ('accel', 'gyro')}
    axes = tuple(replace(axis, scale=1.0) if index < 2 else axis for index, axis in enumerate(truth.accel.axes))
    accel = replace(truth.accel, axes=axes, noise=noise['accel'], turn_on=turn_on['accel'])
    unit = replace(truth, accel=accel, gyro=replace(truth.gyro, noise=noise['gyro'], turn_on=turn_on['gyro']))
    section = LinkUncertainty.of(('x.scale', 'y.scale'), np.diag([5e-3, 5e-3]) ** 2, 1.0, ('x.scale', 'y.scale'),
                                 ('default', 'default'))
    stated = replace(unit, accel=replace(unit.accel, uncertainty=section))
    stale_without, stale_with, said = 0, 0, 0
    for run in runs:
        stale_without += watch_run(run, unit, WatchSettings(latitude=LATITUDE))[0].stale
        watch = watch_run(run, stated, WatchSettings(latitude=LATITUDE))[0]
        stale_with += watch.stale
        said += bool(watch.undetermined)
        assert all(uncertainty > noise for _, uncertainty, noise in watch.undetermined)
    assert stale_without >= 3 and stale_with == 0 and said >= 3, (stale_without, stale_with, said)
