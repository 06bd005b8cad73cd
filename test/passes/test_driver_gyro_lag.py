"""Issue 8's "Done when", offline: a hidden gyroscope thermal lag found, fitted, and corrected on a second run.

1. A rate-table run of a unit whose gyroscope hides a thermal lag (accelerometer without a hidden
   effect): ``diagnose`` names ``thermal_lag`` for the gyroscope and ``none`` for the accelerometer.
2. The refit with ``--gyro-effects thermal_lag``: ``diagnose`` again says ``none`` for both; the
   gyroscope's held-out residual is at the noise floor.
3. A second run of the same unit (static, no reference topics, another seed), corrected by
   ``apply``: its gyroscope bias error is at the floor (mean within a few noise/sqrt(n), RMS at the
   noise), by ``validate`` and on ``apply``'s own output.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from tak_thermo_ros.formats.bag import read_imu_messages, write_driver_record
from tak_thermo_ros.cli import main
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.simulation.truth import RATE_TABLE_POSITIONS, RATE_TABLE_RATES

SIGMAS = 4.0
LAG = {'tau_s': 300.0, 'slope_x': 4.0e-4, 'slope_y': 0.0, 'slope_z': -5.0e-4}
"""The hidden lag: rad/s of bias per degree C of lag; at 2 C/min and tau 300 s the lag reaches
about 10 C, so the bias error is about 4-5 mrad/s on x and z, five times the gyro noise, and none on y."""

CALIBRATION_RUN = Scenario(output='imu', plateaus_celsius=(5.0, 35.0, 5.0, 35.0), ramp_celsius_per_minute=2.0,
                           plateau_hours=0.2, board_lag_s=300.0, dwell_s=30.0, positions=RATE_TABLE_POSITIONS,
                           table_rates=RATE_TABLE_RATES, gyro_effects={'thermal_lag': LAG}, seed=3)
"""About 1.7 h on the rate table, fast ramps: the lag shows on every ramp."""

SECOND_RUN = replace(CALIBRATION_RUN, positions=((0.0, 0.0, 1.0),), table_rates=(), record_references=False,
                     dwell_s=60.0, seed=4)
"""The same unit, static and z up, recorded without reference topics."""


@pytest.fixture(scope='module')
def story(tmp_path_factory):
    """Bags, calibrations and diagnoses of the whole story, each command run once."""
    root = tmp_path_factory.mktemp('done_when')
    write_driver_record(root / 'cal', simulate(CALIBRATION_RUN).driver)
    write_driver_record(root / 'run2', simulate(SECOND_RUN).driver, storage='sqlite3')

    def at(name: str) -> str:
        return str(root / name)

    commands = [
        ['fit', at('cal'), '-o', at('base.yaml')],
        ['diagnose', at('cal'), '--params', at('base.yaml'), '--json', at('diagnose_base.json')],
        ['fit', at('cal'), '-o', at('lag.yaml'), '--gyro-effects', 'thermal_lag'],
        ['diagnose', at('cal'), '--params', at('lag.yaml'), '--json', at('diagnose_lag.json')],
        ['validate', at('run2'), '--params', at('lag.yaml'), '--json', at('validate_lag.json')],
        ['validate', at('run2'), '--params', at('base.yaml'), '--json', at('validate_base.json')],
        ['apply', at('run2'), '--params', at('lag.yaml'), '-o', at('run2_corrected')],
    ]
    for command in commands:
        assert main([*command, '--no-progress']) == 0, command
    return root


def _json(path):
    return json.loads(path.read_text())


def test_diagnose_names_the_gyro_thermal_lag_and_nothing_for_the_accelerometer(story):
    """sensors.gyro.verdict thermal_lag, sensors.accel.verdict none (and the top level is the accelerometer's)."""
    document = _json(story / 'diagnose_base.json')
    assert document['sensors']['gyro']['verdict'] == 'thermal_lag'
    assert document['sensors']['accel']['verdict'] == 'none'
    assert document['verdict'] == 'none' and document['sensors']['gyro']['unit'] == 'rad/s'
    best = document['sensors']['gyro']['candidates'][0]
    assert best['effect'] == 'thermal_lag' and best['explained_fraction'] > 0.9
    gyro_axes = document['sensors']['gyro']['axes']
    for axis in ('x', 'z'):  # the lag's axes: far above the floor
        assert gyro_axes[axis]['heldout_rms'] > 2.0 * gyro_axes[axis]['noise_floor']


def test_refit_brings_the_gyro_heldout_residual_to_the_noise_floor(story):
    """With the lag fitted, the gyroscope's held-out RMS is at its floor and the verdict is none."""
    document = _json(story / 'diagnose_lag.json')
    gyro = document['sensors']['gyro']
    assert gyro['verdict'] == 'none' and document['sensors']['accel']['verdict'] == 'none'
    assert gyro['model_effects'] == ['thermal_lag']
    samples = gyro['samples']
    for axis, noise in zip('xyz', (a.noise_counts for a in CALIBRATION_RUN.gyro_unit)):
        values = gyro['axes'][axis]
        # the floor estimates the simulated white noise (relative error ~ sqrt(3/n) for successive differences)
        assert values['noise_floor'] == pytest.approx(noise, rel=SIGMAS * math.sqrt(3.0 / samples))
        assert values['heldout_rms'] / values['noise_floor'] < 1.0 + SIGMAS * math.sqrt(1.0 / samples)
        assert not values['excess_significant']


def test_second_run_corrected_by_apply_has_its_gyro_bias_error_at_the_floor(story):
    """`validate`'s gyro mean within a few noise/sqrt(n), RMS at the noise; apply's output says the same."""
    after = _json(story / 'validate_lag.json')['gyro']
    without_lag = _json(story / 'validate_base.json')['gyro']
    samples = after['samples']
    fit_samples = _json(story / 'diagnose_lag.json')['sensors']['gyro']['samples']
    corrected = read_imu_messages(story / 'run2_corrected', topic='/imu/data_compensated')
    assert len(corrected.stamp_ns) == samples
    for i, (axis, unit) in enumerate(zip('xyz', SECOND_RUN.gyro_unit)):
        noise = unit.noise_counts
        # the mean error: this run's noise, plus the calibration's own error at the mean temperature
        band = SIGMAS * noise * math.sqrt(1.0 / samples + 1.0 / fit_samples)
        assert abs(after['after'][axis]['mean']) < band, axis
        assert after['after'][axis]['rms'] == pytest.approx(noise, rel=SIGMAS / math.sqrt(2.0 * samples)), axis
        rate = corrected.angular_velocity[:, i]  # the table is still: every corrected rate is the error
        assert abs(rate.mean() - after['after'][axis]['mean']) < 1e-12
        assert math.sqrt(np.mean(rate ** 2)) == pytest.approx(after['after'][axis]['rms'], rel=1e-9)
    # Without the lag in the model the ramps leave the lag on x and z: RMS far above the noise.
    for axis, unit in (('x', SECOND_RUN.gyro_unit[0]), ('z', SECOND_RUN.gyro_unit[2])):
        assert without_lag['after'][axis]['rms'] > 1.5 * unit.noise_counts
        assert after['before'][axis]['rms'] > 3.0 * unit.noise_counts
