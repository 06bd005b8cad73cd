"""Results report themselves: a fit's, a diagnosis's and validate's sums print from the result alone (issue 41)."""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest

from conftest import SHORT
from tak_thermo_ros.core.diagnose import diagnose
from tak_thermo_ros.core.fit import fit_model
from tak_thermo_ros.core.link.correction import OutOfRange
from tak_thermo_ros.core.link.stream_correction import GravityCheck
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.units import reader_unit

WIDTH = 100
"""What the CLI prints is read by a person: at most this many characters a line."""


def _numbers(line: str) -> list[float]:
    return [float(v) for v in re.findall(r'[-+]?\d+\.?\d*(?:e[-+]?\d+)?', line.split(':', 1)[-1])]


@pytest.fixture(scope='module')
def lagging():
    """A short run of a unit with a thermal lag, fitted with the lag (an effect with errors) and without."""
    scenario = replace(SHORT, seed=41, effects={'thermal_lag': {'tau_s': 1200.0, 'slope_x': 0.04, 'slope_y': -0.03,
                                                                'slope_z': 0.05}})
    samples = align(simulate(scenario).record)
    return samples, fit_model(samples, effects=['thermal_lag']), fit_model(samples)


def test_a_fit_summary_states_the_link_per_axis_in_the_sensors_units(lagging):
    """The residual, scale, offset and span lines carry the fit's own values x y z; every line fits 100 columns."""
    _, fitted, _ = lagging
    lines = fitted.summary('accelerometer', 'counts').splitlines()
    assert lines[0] == 'accelerometer, per axis x y z:'
    residual = _numbers(lines[1])
    np.testing.assert_allclose(residual[:3], fitted.residual_rms, rtol=1e-3)
    scale = _numbers(lines[2])[:3]
    np.testing.assert_allclose(scale, [axis.scale for axis in fitted.calibration.axes], rtol=1e-5)
    offsets = _numbers(lines[3])[:3]
    np.testing.assert_allclose(offsets, [axis.offset for axis in fitted.calibration.axes], rtol=1e-3)
    assert all(len(line) <= WIDTH for line in lines), [line for line in lines if len(line) > WIDTH]


def test_a_fit_summary_gives_each_effect_parameter_with_its_error(lagging):
    """One line per effect parameter, value +- error as :meth:`FitResult.parameters` has them; none without effects."""
    _, fitted, plain = lagging
    parameters = fitted.parameters()
    assert set(parameters) == {f'thermal_lag.{name}' for name in ('tau_s', 'slope_x', 'slope_y', 'slope_z')}
    lines = fitted.summary('accelerometer', 'counts').splitlines()
    assert lines[5].startswith('  effects, +- ')
    for name, (value, error) in parameters.items():
        line = next(line for line in lines if line.startswith(f'  effect thermal_lag: {name.split(".")[1]} '))
        shown = _numbers(line)
        assert shown[0] == pytest.approx(value, rel=0.01, abs=1e-3)
        assert error is not None and shown[1] == pytest.approx(error, rel=0.06)
    assert not any('effect' in line for line in plain.summary('accelerometer', 'counts').splitlines())
    assert plain.parameters() == {}


def test_a_driver_units_summary_shows_the_readers_unit_beside_si(lagging):
    """A gyroscope's link in rad/s with deg/h beside: the two agree through the reader's factor."""
    _, fitted, _ = lagging
    line = fitted.summary('gyroscope', 'rad/s').splitlines()[1]
    si, reader = line.split('(')
    shown_si, shown_reader = _numbers(si)[:3], _numbers('x:' + reader)[:3]
    factor = reader_unit('rad/s')[1]
    np.testing.assert_allclose(shown_reader, np.array(shown_si) * factor, rtol=0.01)
    assert 'deg/h' in reader


def test_a_diagnosis_summary_ends_with_its_verdict_and_statements(lagging):
    """The verdict line carries the label; the statements follow; the candidates' table names each candidate tried."""
    samples, _, plain = lagging
    found = diagnose(plain.calibration, samples, candidates=['thermal_lag', 'hysteresis'])
    lines = found.summary('counts', label='x: ').splitlines()
    verdict = lines.index(f'x: verdict: {found.verdict}')
    assert verdict > 0 and len(lines) > verdict + 1
    assert lines[0].startswith('  residual RMS x y z ')
    for candidate in found.candidates:
        assert any(line.startswith(f'  {candidate.effect} ') for line in lines[:verdict])
    assert all(len(line) <= WIDTH for line in lines[:verdict])  # the statements: wrapped where printed


def test_validates_gravity_sums_print_their_own_figures(short_samples, short_run):
    """The |g| error block's RMS before and after are the sums' own, in m/s^2."""
    check = GravityCheck(short_run.truth, gravity=9.80665, out_of_range=OutOfRange.CLAMP)
    check.add(short_samples.counts, short_samples.temp_code, short_samples.stamp_ns * 1e-9)
    lines = check.summary('run.bag').splitlines()
    assert lines[0] == f'|g| error over {len(short_samples)} samples of run.bag (gravity 9.80665 m/s^2):'
    before, after = (_numbers(line) for line in lines[1:3])
    assert before[0] == pytest.approx(check.before.gravity_error().rms, rel=1e-3)
    assert after[0] == pytest.approx(check.after.gravity_error().rms, rel=1e-3)
    assert after[0] < before[0]
