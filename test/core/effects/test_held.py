"""An effect fitted on some axes only (``thermal_lag[xz]``): names, fit, file, correction, the judged ladder."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import yaml
from hypothesis import given, settings, strategies as st

from tak_thermo_ros.cli import main
from tak_thermo_ros.core.diagnose.crossval import _settings_of
from tak_thermo_ros.core.diagnose.heldout import RungJudgement, narrowed
from tak_thermo_ros.core.effects import LIBRARY, PER_AXIS, ThermalLag, held_form, resolve_effect
from tak_thermo_ros.core.effects.held import axes_text, parse_axes
from tak_thermo_ros.core.fit import fit_calibration, fit_model, residual_counts
from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.errors import CalibrationError, FitError
from tak_thermo_ros.formats.calibration_file import flatten_parameters, load_calibration, nest_parameters
from tak_thermo_ros.formats.calibration_link import effects_from_mapping, effects_to_mapping

RUN = Scenario(plateau_hours=0.5, ramp_celsius_per_minute=1.0, board_lag_s=300.0, dwell_s=30.0,
               sample_rate_hz=0.5, temp_code_every=1)
"""As ``test/core/fit/test_effects.py``: a chamber cycle with the temperature code on every sample."""
LAG = {'tau_s': 900.0, 'slope_x': 0.02, 'slope_z': -0.03}
"""A lag on x and z only: y has none."""
STANDARD_ERRORS = 4.5


def test_a_held_form_is_named_by_its_axes_and_made_once():
    form = resolve_effect('thermal_lag[xz]')
    assert form.name == 'thermal_lag[xz]' and form.fitted_axes == (0, 2) and form.held_base is ThermalLag
    assert resolve_effect('thermal_lag[zx]') is form and resolve_effect(form) is form
    assert held_form(ThermalLag, (0, 1, 2)) is ThermalLag and held_form(form, (0, 1, 2)) is ThermalLag
    effect = form(tau_s=100.0, slope_x=1.0, slope_z=2.0)
    assert effect.amplitude_names() == (('slope_x',), (), ('slope_z',))
    assert effect.axis_columns() == ((0,), (), (0,)) and effect.held_names() == ('slope_y',)
    assert effect.amplitudes() == ((1.0,), (0.0,), (2.0,))
    shape = resolve_effect('temperature_shape[y]').from_values({'knot_1': 1.0, 'knot_2': 2.0}, complete=False)
    assert shape.held_names() == ('slope_x_1', 'slope_x_2', 'slope_z_1', 'slope_z_2')


@pytest.mark.parametrize(('spec', 'words'), [
    ('thermal_lag[]', 'expected one to three of x, y, z'),
    ('thermal_lag[xx]', 'each once'),
    ('thermal_lag[w]', 'expected one to three of x, y, z'),
    ('cross_axis[xy]', 'an input effect is fitted on every axis'),
    ('thermal_lag_per_axis[xz]', 'a per-axis form is fitted on every axis'),
    ('aux:/supply[x]', 'an effect of a recorded signal'),
    ('no_such_effect[x]', 'unknown'),
])
def test_a_wrong_held_form_is_one_line(spec, words):
    with pytest.raises(FitError, match=words) as caught:
        resolve_effect(spec)
    assert '\n' not in str(caught.value) and len(str(caught.value)) <= 200


def test_an_amplitude_on_a_held_axis_must_be_zero():
    with pytest.raises(CalibrationError, match=r'slope_y: 0.5, but the effect is fitted on x, z only'):
        resolve_effect('thermal_lag[xz]')(slope_y=0.5)


@settings(max_examples=60, deadline=None)
@given(axes=st.sets(st.integers(0, 2), min_size=1, max_size=3),
       amplitudes=st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3),
       tau=st.floats(1.0, 1e5), steps=st.lists(st.floats(0.0, 50.0), min_size=2, max_size=40))
def test_a_held_form_adds_exactly_what_the_full_form_with_zeros_adds(axes, amplitudes, tau, steps):
    """Any axes, amplitudes, shape and stamps: the same offsets, bit for bit; the axes' text round-trips."""
    assert parse_axes(axes_text(axes), 'axes') == tuple(sorted(axes))
    form = held_form(ThermalLag, axes)
    values = {f'slope_{a}': (amplitudes[i] if i in axes else 0.0) for i, a in enumerate('xyz')}
    held = form(tau_s=tau, **values)
    full = ThermalLag(tau_s=tau, **values)
    stamps = np.cumsum(np.asarray(steps))
    codes = np.linspace(20.0, 40.0, len(steps))
    assert np.array_equal(held.offsets(stamps, codes), full.offsets(stamps, codes))
    assert effects_from_mapping(effects_to_mapping([held])) == (held,)


def _lag_run(seed: int):
    return align(simulate(replace(RUN, seed=seed, effects={'thermal_lag': LAG})).record)


@pytest.fixture(scope='module')
def lag_run():
    return _lag_run(3)


def test_the_fit_holds_y_at_zero_and_recovers_x_and_z(lag_run):
    result = fit_model(lag_run, effects=['thermal_lag[xz]'])
    effect = result.calibration.effects[0]
    assert effect.name == 'thermal_lag[xz]' and effect['slope_y'] == 0.0
    assert 'thermal_lag[xz].slope_y' not in result.parameter_errors
    truth = ThermalLag.from_values(LAG, complete=False)
    for name in ('tau_s', 'slope_x', 'slope_z'):
        error = result.parameter_errors[f'thermal_lag[xz].{name}']
        assert 0.0 < error < math.inf
        assert abs(effect[name] - truth[name]) <= STANDARD_ERRORS * error, (name, effect[name], error)
    # y's fit is the paper's model alone: the same residual as a fit without the effect.
    base = fit_calibration(lag_run).calibration
    assert np.allclose(residual_counts(result.calibration, lag_run)[:, 1], residual_counts(base, lag_run)[:, 1],
                       atol=1e-9 * np.abs(lag_run.counts[:, 1]).max())


def test_the_file_keeps_the_axes_and_the_node_path_reads_them(lag_run, tmp_path):
    from tak_thermo_ros.formats.calibration_file import save_calibration
    calibration = fit_model(lag_run, effects=['thermal_lag[xz]']).calibration
    path = tmp_path / 'held.yaml'
    save_calibration(path, calibration)
    text = path.read_text()
    entry = next(iter(yaml.safe_load(text).values()))['ros__parameters']['calibration']['effects']['thermal_lag']
    assert entry['axes'] == 'xz' and entry['slope_y'] == 0.0
    loaded = load_calibration(path)
    assert loaded.effects == calibration.effects and type(loaded.effects[0]).name == 'thermal_lag[xz]'
    # The node reads its parameters flattened (one ROS 2 parameter each) and nests them again.
    mapping = effects_to_mapping(calibration.effects)
    flat = flatten_parameters(mapping, 'effects')
    assert flat['effects.thermal_lag.axes'] == 'xz'
    assert effects_from_mapping(nest_parameters(flat, 'effects')) == calibration.effects
    stamp_s = lag_run.stamp_s
    held = Corrector(loaded).correct(lag_run.counts, lag_run.temp_code, stamp_s=stamp_s)
    full_effect = ThermalLag.from_values(calibration.effects[0].values)
    full_corrector = Corrector(replace(loaded, effects=(full_effect,)))
    full = full_corrector.correct(lag_run.counts, lag_run.temp_code, stamp_s=stamp_s)
    assert np.array_equal(held, full)


@pytest.mark.parametrize(('axes', 'words'), [
    ("'q'", 'calibration.effects.thermal_lag.axes'),
    ('3', 'calibration.effects.thermal_lag.axes: expected a string'),
])
def test_a_wrong_axes_entry_in_the_file_is_one_line(lag_run, tmp_path, axes, words):
    from tak_thermo_ros.formats.calibration_file import save_calibration
    calibration = fit_model(lag_run, effects=['thermal_lag[xz]'], errors=False).calibration
    path = tmp_path / 'held.yaml'
    save_calibration(path, calibration)
    path.write_text(path.read_text().replace('axes: xz', f'axes: {axes}'))
    with pytest.raises(CalibrationError, match=words):
        load_calibration(path)
    path.write_text(path.read_text().replace(f'axes: {axes}', 'axes: xz').replace('slope_y: 0.0', 'slope_y: 0.01'))
    with pytest.raises(CalibrationError, match='held axis is 0'):
        load_calibration(path)


def test_fit_on_the_command_line_prints_the_held_amplitude_as_held(tmp_path, capsys):
    from tak_thermo_ros.formats.bag import write_record
    write_record(tmp_path / 'run', simulate(replace(RUN, seed=4, effects={'thermal_lag': LAG})).record)
    assert main(['fit', str(tmp_path / 'run'), '-o', str(tmp_path / 'p.yaml'), '--effects', 'thermal_lag[xz]',
                 '--no-progress']) == 0
    out = capsys.readouterr().out
    assert '  effect thermal_lag[xz]: slope_y held at 0 (fitted on x, z only)' in out.splitlines()
    assert 'effect thermal_lag[xz]: slope_x' in out


def _rung(worse_axis: str) -> RungJudgement:
    return RungJudgement(effect='thermal_lag', better=3, judged=3, sigmas=20.0,
                         worse=(('heating 5..35 C', worse_axis),), rms_before=(1.0, 1.0, 1.0),
                         rms_after=(0.5, 1.1, 0.5), kept=False)


def test_a_refused_rung_is_narrowed_only_where_the_fit_cannot_tell_the_amplitude_from_zero(lag_run):
    """The y axis has no lag: held there; x has one the fit resolves: a refusal on x is not narrowed away."""
    calibration = fit_calibration(lag_run).calibration
    specs = (LIBRARY['thermal_lag'],)
    swap = narrowed(lag_run, _settings_of(calibration, None, None), (), specs, _rung('y'))
    assert swap is not None and swap[0] is LIBRARY['thermal_lag'] and swap[1].name == 'thermal_lag[xz]'
    assert narrowed(lag_run, _settings_of(calibration, None, None), (), specs, _rung('x')) is None
    # A second look needs something left to judge it on: three excursions, better on most of them.
    assert narrowed(lag_run, _settings_of(calibration, None, None), (), specs,
                    replace(_rung('y'), better=1, judged=2)) is None
    assert narrowed(lag_run, _settings_of(calibration, None, None), (), specs,
                    replace(_rung('y'), better=1, judged=3)) is None
    # A per-axis form is not narrowed (its held axis would keep shape parameters with nothing to fit).
    per_axis = (PER_AXIS['thermal_lag_per_axis'],)
    assert narrowed(lag_run, _settings_of(calibration, None, None), (), per_axis, _rung('y')) is None


def test_a_user_effect_has_held_forms_stored_with_its_class(tmp_path, monkeypatch, capsys):
    """``module:Class[z]`` through the command line: the file keeps ``class`` and ``axes``, validate reads it."""
    from conftest import CREEP_MODULE
    from tak_thermo_ros.formats.bag import write_record
    (tmp_path / 'user_creep.py').write_text(CREEP_MODULE)
    monkeypatch.chdir(tmp_path)
    scenario = replace(RUN, seed=8, sample_rate_hz=0.2)
    write_record(tmp_path / 'run', simulate(scenario).record)
    assert main(['fit', 'run', '-o', 'params.yaml', '--effects', 'user_creep:Creep[z]', '--no-progress']) == 0
    out = capsys.readouterr().out
    assert '  effect creep[z]: rate_x held at 0 (fitted on z only)' in out.splitlines()
    entry = yaml.safe_load((tmp_path / 'params.yaml').read_text())[
        '/**/compensator']['ros__parameters']['calibration']['effects']['creep']
    assert entry['class'] == 'user_creep:Creep' and entry['axes'] == 'z'
    assert entry['rate_x'] == 0.0 and entry['rate_y'] == 0.0
    assert main(['validate', 'run', '--params', 'params.yaml', '--no-progress']) == 0
    capsys.readouterr()
    assert main(['fit', 'run', '-o', 'both.yaml', '--effects', 'user_creep:Creep,user_creep:Creep[z]',
                 '--no-progress']) != 0
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        'tak_calib: error: effect creep[z]: give either creep or creep[z], not both (the same effect on other axes)')
    assert not (tmp_path / 'both.yaml').exists()
