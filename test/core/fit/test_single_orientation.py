"""Calibration from one static orientation: the offset shape is fitted, the scale held at nominal, and said so."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from tak_thermo_ros.formats.bag import write_record
from tak_thermo_ros.cli import main
from tak_thermo_ros.cli.common import unwrap
from tak_thermo_ros.formats.calibration_file import load_calibration, save_calibration
from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.fit import fit_calibration
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.errors import FitError

STATIC = Scenario(positions=((0.0, 0.0, 1.0),), start_celsius=20.0, plateaus_celsius=(-10.0, 50.0),
                  plateau_hours=0.25, ramp_celsius_per_minute=1.0, board_lag_s=60.0, temp_code_every=1, seed=5)
"""A board lying still (z up) while the chamber sweeps -10..50 C: two hours at 1 Hz. A temperature code
with every sample, so that the held code adds no lag bias to the fitted curve (only noise is tested)."""


@pytest.fixture(scope='module')
def static_fit():
    """The static run and its fit with the scale held at the recorded nominal value."""
    run = simulate(STATIC)
    samples = align(run.record)
    return run, samples, fit_calibration(samples, nominal_scale=run.record.nominal_scale)


def _apparent_drift(calibration, force: float, n: np.ndarray, nominal: float, axis: int) -> np.ndarray:
    """What a static run can observe: N - K0_nominal f, as a function of the code offset n."""
    return calibration.axes[axis].forward(force, n) - nominal * force


def test_static_fit_recovers_the_offset_shape_within_the_noise(static_fit):
    """The fitted N - K0 f curve matches the truth to 5 standard errors of a cubic fit to this noise."""
    run, samples, result = static_fit
    fitted, truth = result.calibration, run.truth
    codes = np.linspace(fitted.temp_code_min, fitted.temp_code_max, 201)
    # Standard error of the fitted cubic at each code, from the design and the noise (plus code rounding).
    ref = fitted.temp_code_ref
    scale = max(abs(fitted.temp_code_min - ref), abs(fitted.temp_code_max - ref))
    design = np.vander((samples.temp_code - ref) / scale, 4, increasing=True)
    grid = np.vander((codes - ref) / scale, 4, increasing=True)
    leverage = np.sqrt(np.einsum('ij,jk,ik->i', grid, np.linalg.inv(design.T @ design), grid))
    for axis, unit in enumerate(STATIC.unit):
        force = STATIC.gravity * STATIC.positions[0][axis]
        sigma = math.sqrt(unit.noise_counts ** 2 + 1.0 / 12.0)
        got = _apparent_drift(fitted, force, codes - fitted.temp_code_ref, STATIC.nominal_scale[axis], axis)
        want = _apparent_drift(truth, force, codes - truth.temp_code_ref, STATIC.nominal_scale[axis], axis)
        assert np.all(np.abs(got - want) < 5.0 * sigma * leverage), f'axis {"xyz"[axis]}'
        assert np.ptp(want) > 50.0 * sigma  # a drift well above the noise, so the check means something
        assert math.isclose(result.axes[axis].residual_rms, sigma, rel_tol=0.05)


def test_static_fit_holds_the_scale_and_records_it(static_fit, tmp_path):
    """Scale = nominal, scale_observable false on every axis, one note saying so; both survive the file."""
    _, _, result = static_fit
    calibration = result.calibration
    for axis, nominal in zip(calibration.axes, STATIC.nominal_scale):
        assert axis.scale == nominal and not axis.scale_observable and axis.scale_shape == (0.0,)
    assert len(calibration.notes) == 1 and calibration.notes[0].startswith('scale held at nominal on x, y, z')
    path = tmp_path / 'static.yaml'
    save_calibration(path, calibration)
    entry = yaml.safe_load(path.read_text())['/**/compensator']['ros__parameters']['calibration']
    assert entry['z']['scale_observable'] is False and entry['notes'] == list(calibration.notes)
    loaded = load_calibration(path)
    assert loaded.notes == calibration.notes and not any(axis.scale_observable for axis in loaded.axes)


def test_static_correction_gives_gravity_back(static_fit):
    """Corrected specific force equals the reference within the noise over the whole sweep."""
    run, samples, result = static_fit
    corrected = Corrector(result.calibration).correct(samples.counts, samples.temp_code)
    error = corrected - samples.reference
    for axis, unit in enumerate(STATIC.unit):
        sigma = math.sqrt(unit.noise_counts ** 2 + 1.0 / 12.0) / STATIC.nominal_scale[axis]
        assert abs(float(np.sqrt(np.mean(error[:, axis] ** 2))) - sigma) < 0.05 * sigma


def test_only_the_axes_with_one_input_are_held():
    """`z` up and z down: x and y see 0 g only and are held; z sees +/-g and its scale is fitted."""
    run = simulate(Scenario(positions=((0.0, 0.0, 1.0), (0.0, 0.0, -1.0)), plateaus_celsius=(0.0, 40.0),
                            plateau_hours=0.25, ramp_celsius_per_minute=1.0, board_lag_s=60.0, seed=6))
    result = fit_calibration(align(run.record), nominal_scale=run.record.nominal_scale)
    x, y, z = result.calibration.axes
    assert not x.scale_observable and not y.scale_observable and z.scale_observable
    assert math.isclose(z.scale, STATIC.unit[2].scale, rel_tol=1e-3)
    assert result.calibration.notes[0].startswith('scale held at nominal on x, y: one input only')


def test_static_fit_without_a_nominal_scale_is_refused():
    """Without a nominal scale an axis with one input cannot be fitted: FitError naming the axis."""
    samples = align(simulate(STATIC).record)
    with pytest.raises(FitError, match='axis x sees one input only'):
        fit_calibration(samples)


def test_cli_fit_says_in_one_line_that_it_held_the_scale(static_fit, tmp_path, capsys):
    """tak_calib fit on a static bag: exit 0, exactly one 'note: scale held at nominal' line, '(held)' per axis."""
    run, _, _ = static_fit
    bag = tmp_path / 'static'
    write_record(bag, run.record)
    assert main(['fit', str(bag), '-o', str(tmp_path / 'static.yaml'), '--no-progress']) == 0
    lines = unwrap(capsys.readouterr().out)
    held = [line for line in lines if line.startswith('note: scale held at nominal on x, y, z')]
    assert len(held) == 1 and 'scale and offset drift cannot be told apart' in held[0]
    assert sum('counts/(m/s^2) (held on x y z: see the note)' in line for line in lines) == 1
