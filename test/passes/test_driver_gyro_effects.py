"""Every library effect works on the gyroscope of a driver bag (rad/s, degrees C), through ``--gyro-effects``.

Each effect is hidden in the gyroscope of a short rate-table run with amplitudes several times the
gyro noise; ``tak_calib fit --gyro-effects NAME`` must recover its parameters within five of the
fit's own standard errors. The hysteresis play is 0.5 C wide: narrower than one unit of the
temperature input, which a search space starting at "one code" could not reach.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tak_thermo_ros.formats.bag import write_driver_record
from tak_thermo_ros.cli import main
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.core.effects import LIBRARY
from tak_thermo_ros.core.fit import fit_model
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.simulation.truth import RATE_TABLE_POSITIONS, RATE_TABLE_RATES

SIGMAS = 5.0
RUN = Scenario(output='imu', plateaus_celsius=(5.0, 35.0, 5.0, 35.0), ramp_celsius_per_minute=2.0,
               plateau_hours=0.2, board_lag_s=300.0, dwell_s=30.0, positions=RATE_TABLE_POSITIONS,
               table_rates=RATE_TABLE_RATES, temp_code_every=1, seed=8)
"""About 1.7 h on the rate table with fast ramps (lag, play and warm-up all show); the temperature
comes with every Imu message, so the fit sees the temperature the effects were driven by, up to
the driver's 1/256 C quantum."""

GYRO_EFFECTS = {
    'thermal_lag': {'tau_s': 300.0, 'slope_x': 4e-4, 'slope_z': -5e-4},
    'hysteresis': {'width_codes': 0.5, 'amplitude_y': 3e-3, 'amplitude_z': -2e-3},
    'warmup': {'tau_s': 600.0, 'amplitude_x': 5e-3, 'amplitude_z': -4e-3},
    'temperature_shape': {'slope_x_1': 8e-4, 'slope_y_1': -6e-4},
    'cross_axis': {'c_xy': 3e-3, 'c_zx': -4e-3, 'c_yz': 2e-3},
    'scale_nonlinearity': {'k2_x': 3e-3, 'k2_y': -2e-3, 'k2_z': 2.5e-3},
    'step': {'at_s': 2500.5, 'amplitude_x': 2e-3, 'amplitude_y': -1.5e-3},
}
"""Hidden gyroscope effects, in the driver's units: rad/s, rad/s per degree C, (rad/s)/(rad/s), 1/(rad/s)."""


def test_every_library_effect_is_covered():
    """A new library effect must be added here."""
    assert set(GYRO_EFFECTS) == set(LIBRARY)


def _hidden(name: str) -> dict[str, float]:
    values = dict(GYRO_EFFECTS[name])
    if name == 'step':  # counted from the first sample, as the fit counts it
        values['origin_s'] = RUN.start_time_s
    if name == 'temperature_shape':
        # one knot where the fit puts a single knot: the middle of the run's temperature range
        temperature = simulate(RUN).driver.temperature
        values['knot_1'] = round(float(temperature.min() + temperature.max()) / 2.0, 2)
    return values


@pytest.mark.parametrize('name', sorted(GYRO_EFFECTS))
def test_gyro_effect_is_recovered_through_the_command_line(name, tmp_path, capsys):
    """`fit` --gyro-effects NAME: the file's gyro effect matches the truth within 5 standard errors."""
    scenario = replace(RUN, gyro_effects={name: _hidden(name)})
    run = simulate(scenario)
    write_driver_record(tmp_path / 'cal', run.driver)
    assert main(['fit', str(tmp_path / 'cal'), '-o', str(tmp_path / 'p.yaml'), '--gyro-effects', name,
                 '--no-progress']) == 0
    stdout = capsys.readouterr().out
    assert f'effect {name}:' in stdout and 'counts' not in stdout.split('gyroscope, per axis x y z:')[1]
    unit = load_unit(tmp_path / 'p.yaml')
    assert unit.accel.effects == ()
    (fitted,) = unit.gyro.effects
    truth = run.unit_truth.gyro.effects[0]
    # the same fit in-process gives the parameters' standard errors
    samples = align(run.driver.channel('gyro'))
    result = fit_model(samples, effects=[name])
    assert result.calibration.effects[0].values == pytest.approx(fitted.values, rel=1e-12, abs=1e-15)
    errors = result.parameter_errors
    checked = 0
    for parameter in fitted.parameters:
        key = f'{name}.{parameter.name}'
        if not parameter.vary or key not in errors:
            assert fitted[parameter.name] == truth[parameter.name], key  # e.g. the knot: placed, not fitted
            continue
        assert abs(fitted[parameter.name] - truth[parameter.name]) < SIGMAS * errors[key], key
        checked += 1
        if truth[parameter.name] != 0.0:  # a hidden amplitude or shape far beyond its error
            assert abs(truth[parameter.name]) > 5.0 * SIGMAS * errors[key], key
    assert checked >= 3
    # with the effect in the model the gyro residual is the white noise
    for axis, truth_axis in zip(unit.gyro.axes, scenario.gyro_unit):
        assert axis.residual_rms == pytest.approx(truth_axis.noise_counts,
                                                  rel=SIGMAS / math.sqrt(2.0 * len(samples)) + 0.01)
    assert np.isfinite([p.value for p in fitted.parameters]).all()
