"""Issue 31, item 6: a powered static run that warms itself, compensated, is the yardstick again.

A static noise run of a powered unit in a 20 C chamber warms by itself to 26 C. Compensated by a
calibration that covers that span, what is left is the sensor's noise: ``noise --params`` labels
it ``static_run`` and ``diagnose --noise-run`` judges against it. With it, a small gyroscope lag
under the white floor is named, and ordinary bias wander is ``none``, not ``unexplained`` (both
held with a run at constant temperature, and were lost when every run whose temperature moved by
more than 2 C was labelled ``residual``). Uncompensated, or compensated by a link that leaves a
trend with temperature, the same run is no static run; nor is a sweep across the calibrated range.

Two seeds each here; ``bench/bench_self_heating.py`` runs 20. The ladder is judged on whole
excursions (issue 31, item 2): where y (no lag there) pays held out for the slope its fit gives y's
wander, the lag is refused with ``worse on y``, and since its fit cannot tell y's slope from zero
it is judged again held at zero there, ``thermal_lag[xz]`` (``core/effects/held.py``): the lag is
named either way, and a held form holds y only, where the unit has no lag.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from core.diagnose.test_verdict import wandering_run
from tak_thermo_ros import cli
from tak_thermo_ros.core.diagnose.excursions import GAIN_SIGMAS
from tak_thermo_ros.core.noise.constancy import TREND_T, temperature_trend
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.formats.bag import Topics, write_driver_record
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.passes.noise import noise_bag
from tak_thermo_ros.passes.run import StreamOptions
from tak_thermo_ros.formats.records import open_record

OPTIONS = StreamOptions(topics=Topics(), progress=False)
LAG_SLOPE = 3e-5
"""The small gyroscope lag of ``test/core/diagnose/test_verdict.py`` (rad/s per C, tau 300 s, on x and -z)."""


def self_heating(scenario, seed: int):
    """The same unit powered in a 20 C chamber for an hour, warming by itself to 26 C (time constant 10 min)."""
    return replace(scenario, plateaus_celsius=(26.0,), start_celsius=20.0, plateau_hours=1.0,
                   ramp_celsius_per_minute=60.0, board_lag_s=600.0, positions=((0.0, 0.0, 1.0),), table_rates=(),
                   record_references=False, gyro_effects={}, effects={}, seed=seed + 500)


def story(root: Path, seed: int, slope: float) -> dict:
    """Fit the rate-table run, take the self-heating run as the noise run, diagnose: the JSON."""
    cal = wandering_run(seed=seed, rate_hz=5.0, slope=slope)
    root.mkdir(parents=True, exist_ok=True)
    write_driver_record(root / 'cal', simulate(cal).driver)
    write_driver_record(root / 'heat', simulate(self_heating(cal, seed)).driver)
    assert cli.main(['fit', str(root / 'cal'), '-o', str(root / 'base.yaml'), '--no-progress']) == 0
    assert cli.main(['diagnose', str(root / 'cal'), '--params', str(root / 'base.yaml'), '--noise-run',
                     str(root / 'heat'), '--json', str(root / 'out.json'), '--no-progress']) == 0
    return json.loads((root / 'out.json').read_text())


@pytest.mark.parametrize('seed', [0, 1])
def test_with_a_self_heating_static_run_a_small_lag_is_named_and_wander_is_none(seed, tmp_path):
    lag = story(tmp_path / 'lag', seed, LAG_SLOPE)
    sources = {s: v['noise']['source'] for s, v in lag['sensors'].items()}
    assert sources == {'accel': 'static_run', 'gyro': 'static_run'}
    gyro = lag['sensors']['gyro']
    assert gyro['verdict'] in ('thermal_lag', 'thermal_lag[xz]'), gyro['message']
    rungs = gyro['held_out_excursions']['rungs']
    if gyro['verdict'] == 'thermal_lag[xz]':
        # The lag acts on x and z. Held out whole, an excursion found y worse by the slope the fit
        # gave y's bias wander: refused there, and held at zero on y, where the fit cannot tell it
        # from zero. It must not call x or z worse.
        assert rungs[0]['effect'] == 'thermal_lag' and not rungs[0]['kept'], rungs[0]
        assert rungs[0]['narrowed_to'] == 'thermal_lag[xz]', rungs[0]
        assert {worse['axis'] for worse in rungs[0]['worse']} == {'y'}, rungs[0]
        rungs = rungs[1:]
    assert rungs[0]['kept'] and rungs[0]['gain_sigmas'] > GAIN_SIGMAS and not rungs[0]['worse'], rungs[0]
    assert lag['sensors']['accel']['verdict'] == 'none'
    for axis in ('x', 'z'):  # per sample the lag hides in the white noise
        summary = lag['sensors']['gyro']['axes'][axis]
        assert summary['rms'] < 1.25 * summary['white_floor']
    wander = story(tmp_path / 'wander', seed, 0.0)
    assert {s: v['verdict'] for s, v in wander['sensors'].items()} == {'accel': 'none', 'gyro': 'none'}


def test_the_same_run_is_no_static_run_uncompensated_or_badly_compensated_and_a_sweep_is_none(tmp_path):
    cal = wandering_run(seed=7, rate_hz=1.0)
    write_driver_record(tmp_path / 'cal', simulate(cal).driver)
    write_driver_record(tmp_path / 'heat', simulate(self_heating(cal, 7)).driver)
    write_driver_record(tmp_path / 'sweep', simulate(replace(cal, seed=70)).driver)
    assert cli.main(['fit', str(tmp_path / 'cal'), '-o', str(tmp_path / 'base.yaml'), '--no-progress']) == 0
    unit = load_unit(tmp_path / 'base.yaml')
    compensated = noise_bag(open_record(tmp_path / 'heat', topics=OPTIONS.topics), OPTIONS, unit=unit)
    assert {n.model.source for n in compensated.sensors.values()} == {'static_run'}
    assert 'compensated: no trend with temperature left' in compensated.sensors['gyro'].span_words
    raw = noise_bag(open_record(tmp_path / 'heat', topics=OPTIONS.topics), OPTIONS)
    assert {n.model.source for n in raw.sensors.values()} == {'residual'}
    # A link without its temperature terms leaves the drift: what the compensation leaves decides.
    flat = replace(unit, **{sensor: replace(calibration, axes=tuple(
        replace(axis, offset_shape=(0.0,), scale_shape=(0.0,)) for axis in calibration.axes))
        for sensor, calibration in unit.sensors})
    bad = noise_bag(open_record(tmp_path / 'heat', topics=OPTIONS.topics), OPTIONS, unit=flat)
    assert {n.model.source for n in bad.sensors.values()} == {'residual'}
    assert 'leaves a trend with temperature' in bad.sensors['gyro'].span_words
    sweep = noise_bag(open_record(tmp_path / 'sweep', topics=OPTIONS.topics), OPTIONS, unit=unit)
    assert {n.model.source for n in sweep.sensors.values()} == {'residual'}
    assert 'a sweep over' in sweep.sensors['gyro'].span_words


def test_the_trend_test_holds_a_random_walk_along_a_monotone_warm_up():
    """A random walk follows any monotone temperature in levels; in differences it does not: |t| <= 4 over seeds."""
    import numpy as np
    time_s = np.arange(7200.0)
    temperature = 20.0 + 6.0 * (1.0 - np.exp(-time_s / 600.0))
    largest = []
    for seed in range(200):
        rng = np.random.default_rng(seed)
        walk = np.cumsum(rng.standard_normal((7200, 3)), axis=0) + rng.standard_normal((7200, 3))
        largest.append(temperature_trend(time_s, temperature, walk).largest_t)
    assert sum(value > TREND_T for value in largest) <= 4  # 1 % of 200 runs with three axes each
    drift = np.random.default_rng(1).standard_normal((7200, 3)) + 0.2 * (temperature - 20.0)[:, None]
    assert temperature_trend(time_s, temperature, drift).largest_t > 10.0
