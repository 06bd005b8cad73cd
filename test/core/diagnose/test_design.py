"""``tak_calib diagnose --design-run`` on driver bags: one chamber run for both sensors (issue 10).

A short rate-table run whose gyroscope hides a thermal lag, on the paper's staircase (heating
mostly, so a lag and a hysteresis both open loops): the design is written, its scenario is a
driver run the simulator runs, its schedule follows the chamber profile, and the proposed run
separates the two candidates far better than the diagnosed run. A run whose accelerometer
follows a recorded supply voltage: the recorded signal is among the two best candidates, which no
temperature profile separates; the command says so in one line and exits 0.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from conftest import SHORT
from tak_thermo_ros.formats.bag import bag_input_kind, read_driver_record, write_driver_record, write_record
from tak_thermo_ros.cli import main
from tak_thermo_ros.cli.common import unwrap
from tak_thermo_ros.core.diagnose import design_driver_run, diagnose
from tak_thermo_ros.core.diagnose.design import driver_table
from tak_thermo_ros.core.fit import fit_model
from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.simulation.imu import chamber_profile, simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.simulation.truth import RATE_TABLE_POSITIONS, RATE_TABLE_RATES
from tak_thermo_ros.formats.scenario import load_scenario

GYRO_LAG = {'tau_s': 900.0, 'slope_x': 4.0e-4, 'slope_y': 0.0, 'slope_z': -5.0e-4}
"""rad/s of bias per degree C of lag: at 1 C/min and tau 900 s, several times the gyro noise on x and z."""

RUN = Scenario(output='imu', plateau_hours=0.5, ramp_celsius_per_minute=1.0, board_lag_s=300.0, dwell_s=30.0,
               positions=RATE_TABLE_POSITIONS, table_rates=RATE_TABLE_RATES, sample_rate_hz=0.2,
               gyro_effects={'thermal_lag': GYRO_LAG}, seed=3)
"""3.25 h of the paper's staircase on the rate table at 0.2 Hz (about 2300 samples)."""

PAIR = 'thermal_lag,hysteresis'


@pytest.fixture(scope='module')
def designed(tmp_path_factory):
    """The bag fitted without effects, diagnosed with --design-run; the printed text and the directory."""
    root = tmp_path_factory.mktemp('design_driver')
    write_driver_record(root / 'run', simulate(RUN).driver)
    assert main(['fit', str(root / 'run'), '-o', str(root / 'base.yaml'), '--no-progress']) == 0
    return root


def test_driver_design_is_written_for_the_gyroscope_and_separates_better_than_the_run(designed, capsys):
    """One line per sensor; the files: a driver scenario, a schedule on the profile, the separations."""
    root = designed
    code = main(['diagnose', str(root / 'run'), '--params', str(root / 'base.yaml'), '--candidates', PAIR,
                 '--design-run', str(root / 'design'), '--no-progress'])
    out = capsys.readouterr().out
    assert code == 0
    assert 'accelerometer: nothing to separate (verdict none)' in out
    gyro_lines = [line for line in out.splitlines() if line.startswith('gyroscope: to tell ')]
    assert len(gyro_lines) == 1 and 'thermal_lag' in gyro_lines[0] and 'hysteresis' in gyro_lines[0]
    document = json.loads((root / 'design' / 'design.json').read_text())
    gyro = document['sensors']['gyro']
    assert set(gyro['candidates']) == {'thermal_lag', 'hysteresis'} and 'accel' not in document['sensors']
    # One sensor to separate: the proposed profile is its own best, and beats the diagnosed run.
    assert gyro['proposed'] == gyro['own_best']
    assert gyro['proposed']['separation_sigmas'] == max(p['separation_sigmas'] for p in gyro['tried'])
    assert gyro['proposed']['separation_sigmas'] > 2.0 * gyro['diagnosed_run']['separation_sigmas'], gyro
    assert f"{gyro['proposed']['separation_sigmas']:.0f} noise sigmas" in gyro_lines[0]

    proposed = load_scenario(root / 'design' / 'scenario.yaml')
    assert proposed.output == 'imu'
    assert proposed.positions == RATE_TABLE_POSITIONS and proposed.table_rates == RATE_TABLE_RATES
    assert proposed.dwell_s == RUN.dwell_s and proposed.sample_rate_hz == pytest.approx(RUN.sample_rate_hz)
    assert proposed.duration_s() / 3600.0 == pytest.approx(gyro['proposed']['hours'])
    schedule = np.loadtxt(root / 'design' / 'schedule.csv', delimiter=',', skiprows=1)
    assert schedule[0, 0] == 0.0 and np.all(np.diff(schedule[:, 0]) > 0.0)
    assert schedule[-1, 0] == pytest.approx(proposed.duration_s())
    np.testing.assert_allclose(schedule[:, 1], chamber_profile(proposed, schedule[:, 0]))
    # The diagnosed run's temperatures are degrees C: the profile spans the run's board range.
    temperature = read_driver_record(root / 'run').temperature
    assert min(proposed.plateaus_celsius) == pytest.approx(temperature.min(), abs=0.1)
    assert max(proposed.plateaus_celsius) == pytest.approx(temperature.max(), abs=0.1)

    assert main(['simulate', str(root / 'proposed'), '--scenario', str(root / 'design' / 'scenario.yaml')]) == 0
    assert bag_input_kind(root / 'proposed') is InputKind.IMU


def test_one_run_for_both_sensors_maximises_the_weaker_separation():
    """Both sensors lag: the proposed profile is the one whose smaller separation is largest."""
    lag = {'tau_s': 900.0, 'slope_x': 3e-3, 'slope_z': 4e-3}
    scenario = replace(RUN, sample_rate_hz=0.1, effects={'thermal_lag': lag})
    driver = simulate(scenario).driver
    samples = {sensor: align(driver.channel(sensor)) for sensor in ('accel', 'gyro')}
    diagnoses = {sensor: diagnose(fit_model(s).calibration, s, candidates=PAIR.split(','))
                 for sensor, s in samples.items()}
    assert all(d.verdict == 'thermal_lag' for d in diagnoses.values()), {k: d.verdict for k, d in diagnoses.items()}
    design = design_driver_run(diagnoses, samples)
    assert [d.sensor for d in design.sensors] == ['accel', 'gyro'] and not design.notes
    weaker = [min(d.tried[i].separation_sigmas for d in design.sensors) for i in range(len(design.sensors[0].tried))]
    assert weaker[design.choice] == max(weaker)
    assert design.best.separation_sigmas == max(weaker)
    for sensor in design.sensors:
        assert sensor.tried[design.choice].separation_sigmas > sensor.baseline_sigmas, sensor


def _diagnose_with_supply_candidate(tmp_path, capsys) -> str:
    """fit, then diagnose --design-run with the lag and the recorded supply as candidates; its output (exit 0)."""
    assert main(['fit', str(tmp_path / 'run'), '-o', str(tmp_path / 'base.yaml'), '--no-progress']) == 0
    capsys.readouterr()
    code = main(['diagnose', str(tmp_path / 'run'), '--params', str(tmp_path / 'base.yaml'), '--candidates',
                 'thermal_lag,aux:/power/battery_state', '--design-run', str(tmp_path / 'design'), '--no-progress'])
    out = capsys.readouterr().out
    assert code == 0, out
    return out


def test_a_recorded_signal_on_top_gets_one_clear_line_and_no_design(tmp_path, capsys):
    """The accelerometer follows the recorded supply voltage: no temperature run is designed, exit 0."""
    scenario = replace(RUN, gyro_effects={}, supply_voltage_drift=0.03, record_supply='/power/battery_state',
                       sample_rate_hz=0.1)
    write_driver_record(tmp_path / 'run', simulate(scenario).driver)
    out = _diagnose_with_supply_candidate(tmp_path, capsys)
    lines = [line for line in unwrap(out) if line.startswith('accelerometer: no chamber run designed')]
    assert len(lines) == 1, out
    assert 'aux:/power/battery_state' in lines[0] and 'independently of the temperature' in lines[0]
    assert 'gyroscope: nothing to separate (verdict none)' in out
    assert 'nothing written' in out and not (tmp_path / 'design').exists()


@pytest.mark.parametrize(('table', 'expected'), [
    ({'positions': ((0.0, 0.0, 1.0),), 'table_rates': ()},
     {'positions': ((0.0, 0.0, 1.0),), 'table_rates': (), 'record_references': False}),
    ({'positions': RATE_TABLE_POSITIONS, 'table_rates': RATE_TABLE_RATES},
     {'positions': RATE_TABLE_POSITIONS, 'table_rates': RATE_TABLE_RATES, 'dwell_s': RUN.dwell_s}),
    ({'positions': Scenario().positions, 'table_rates': ()},
     {'positions': Scenario().positions, 'table_rates': (), 'dwell_s': RUN.dwell_s}),
])
def test_the_design_is_simulated_on_the_table_of_the_diagnosed_run(table, expected):
    """Static (one attitude, no rate): that attitude, no reference topics; a rate table; a tilt table."""
    driver = simulate(replace(RUN, plateaus_celsius=(25.0,), plateau_hours=0.3, gyro_effects={}, **table)).driver
    found = driver_table(align(driver.channel('accel')), align(driver.channel('gyro')))
    assert found.keys() == expected.keys()
    for key, value in expected.items():
        np.testing.assert_allclose(np.array(found[key], dtype=float), np.array(value, dtype=float), atol=1e-9,
                                   err_msg=key)


def test_counts_bag_with_a_recorded_signal_on_top_gets_the_same_line(tmp_path, capsys):
    """The paper's counts: the recorded-signal line instead of a design (no error, nothing written)."""
    scenario = replace(SHORT, sample_rate_hz=0.1, supply_voltage_drift=6.0, record_supply='/power/battery_state',
                       seed=5)
    write_record(tmp_path / 'run', simulate(scenario).record)
    out = _diagnose_with_supply_candidate(tmp_path, capsys)
    lines = [line for line in out.splitlines() if line.startswith('no chamber run designed')]
    assert len(lines) == 1 and 'aux:/power/battery_state' in lines[0], out
    assert not (tmp_path / 'design').exists()


def test_a_model_that_follows_a_recorded_signal_is_designed_with_the_signal_steady():
    """The accelerometer's model holds the supply voltage (aux) and misses a lag.

    The simulated runs record no voltage, so that effect is left out there; what the other candidate cannot absorb is
    then at most the whole lag (slope x ramp rate x tau), not the whole signal of a failed fit.
    """
    lag = {'tau_s': 900.0, 'slope_x': 3e-3, 'slope_z': 4e-3}
    scenario = replace(RUN, gyro_effects={}, sample_rate_hz=0.1, supply_voltage_drift=0.03,
                       record_supply='/power/battery_state', effects={'thermal_lag': lag})
    driver = simulate(scenario).driver
    samples = {sensor: align(driver.channel(sensor)) for sensor in ('accel', 'gyro')}
    calibrations = {'accel': fit_model(samples['accel'], effects=['aux:/power/battery_state']).calibration,
                    'gyro': fit_model(samples['gyro']).calibration}
    diagnoses = {sensor: diagnose(calibrations[sensor], s, candidates=PAIR.split(',')) for sensor, s in samples.items()}
    assert diagnoses['accel'].verdict == 'thermal_lag' and diagnoses['gyro'].verdict == 'none'
    design = design_driver_run(diagnoses, samples)
    (accel,) = design.sensors
    assert accel.sensor == 'accel' and 'gyro' in design.notes
    ramp = max(p['ramp_celsius_per_minute'] for p in (s.scenario for s in accel.tried)) / 60.0
    whole_lag = max(abs(lag['slope_x']), abs(lag['slope_z'])) * ramp * lag['tau_s']
    for score in accel.tried:
        assert np.all(np.array(score.rms_over_floor) < whole_lag / diagnoses['accel'].noise_floor), score
    assert accel.tried[design.choice].separation_sigmas > accel.baseline_sigmas
