"""The carrier method: recovery, the reported uncertainties' coverage, identifiability, bad input, the CLI."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tak_thermo_ros.cli import main
from tak_thermo_ros.core.magnetometer.budget import monte_carlo, within_two_sigma
from tak_thermo_ros.core.magnetometer.carrier import (
    CarrierModel,
    CarrierTruth,
    Gauge,
    InstrumentErrors,
    axis_rotation,
    predict,
)
from tak_thermo_ros.core.magnetometer.carrier_fit import fit_carrier
from tak_thermo_ros.core.simulation.carrier import (
    CSV_COLUMNS,
    CarrierScenario,
    parse_record_csv,
    record_csv,
    simulate_carrier,
    stage_design,
)
from tak_thermo_ros.errors import CarrierError, FitError

SEED_MODEL = CarrierModel()  # D[z, z] free, the declination known (7 deg, the scenario's)


def _truth_values(truth: CarrierTruth) -> dict[str, float]:
    values = {f'B_{name}': truth.earth_uT[i] for i, name in enumerate(('north', 'east', 'down'))}
    values |= {f'p_{a}': truth.hard_iron_uT[i] for i, a in enumerate('xyz')}
    values |= {f'o_{a}': truth.sensor_offset_uT[i] for i, a in enumerate('xyz')}
    values['D_zz'] = truth.poisson[2, 2]
    return values


def test_the_seed_stages_recover_earth_poisson_and_hard_iron():
    """Every estimate lies within 4 of its reported sigmas of the truth, and the sigmas are the noise's size."""
    record, truth = simulate_carrier(CarrierScenario(seed=11))
    fit = fit_carrier(record, SEED_MODEL)
    true = _truth_values(truth)
    for estimate in fit.estimates:
        assert abs(estimate.value - true[estimate.name]) < 4.0 * estimate.sigma, estimate
    sigma = fit.by_name()
    # dA 3e-3 rad and dG 0.1 deg on 50 uT over ~100 readings: tens of nT on the field, ~1e-3 on D_zz
    assert sigma['B_north'].sigma < 0.05 and sigma['B_down'].sigma < 0.1
    assert sigma['D_zz'].sigma < 0.005 and sigma['o_x'].sigma < 0.001
    assert 0.7 < fit.chi2_per_dof < 1.3


def test_the_reported_uncertainties_cover_the_errors_over_many_seeds():
    """Over 60 seeds about 95 % of the estimates lie within 2 reported sigma (the linearisation gives ~92 %)."""
    scenario = CarrierScenario()
    covered, z = [], []
    for seed in range(60):
        record, truth = simulate_carrier(replace(scenario, seed=1000 + seed))
        fit = fit_carrier(record, SEED_MODEL)
        covered.append(within_two_sigma(fit, truth))
        true = _truth_values(truth)
        z.append([(e.value - true[e.name]) / e.sigma for e in fit.estimates])
    fraction = float(np.mean(covered))
    rms_z = np.sqrt(np.mean(np.square(z), axis=0))
    assert 0.88 <= fraction <= 0.995, fraction
    assert np.all((rms_z > 0.7) & (rms_z < 1.35)), rms_z


def test_one_tilt_axis_without_a_gauge_is_refused_naming_what_moves_together():
    """Pitch only, heading fixed: the Earth field along the tilt axis and the hard iron along it are one."""
    record, _ = simulate_carrier(CarrierScenario(seed=2))
    with pytest.raises(FitError, match=r'cannot separate .*p_y'):
        fit_carrier(record, CarrierModel(('zz',), Gauge()))
    with pytest.raises(FitError, match=r'cannot separate .*D_yy.*p_y|cannot separate .*p_y.*D_yy'):
        fit_carrier(record, CarrierModel(('yy',), Gauge(declination_deg=7.0)))


def test_a_record_without_a_tilt_is_refused():
    """The carrier never tilts (its attitude only scatters within the error): induced and permanent are one."""
    record, _ = simulate_carrier(CarrierScenario(seed=8))
    scatter = np.random.default_rng(8).uniform(-1.7e-3, 1.7e-3, len(record))
    with pytest.raises(FitError, match=r'cannot separate .*needs a tilt of the carrier'):
        fit_carrier(replace(record, pitch_rad=scatter), SEED_MODEL)


def test_a_second_tilt_axis_needs_no_gauge():
    """Tilting about roll as well separates everything without outside knowledge."""
    record, truth = simulate_carrier(CarrierScenario(seed=3, second_tilt_axis='roll'))
    fit = fit_carrier(record, CarrierModel(('zz',), Gauge()))
    true = _truth_values(truth)
    for estimate in fit.estimates:
        assert abs(estimate.value - true[estimate.name]) < 4.0 * estimate.sigma, estimate


def test_a_gauge_value_s_uncertainty_is_carried_into_the_estimates():
    """A declination known to 1 deg widens the east component's sigma to about |B_H| x 1 deg."""
    record, _ = simulate_carrier(CarrierScenario(seed=4))
    exact = fit_carrier(record, SEED_MODEL).by_name()
    loose = fit_carrier(record, CarrierModel(('zz',), Gauge(declination_deg=7.0, declination_sigma_deg=1.0))).by_name()
    horizontal = math.hypot(exact['B_north'].value, exact['B_east'].value)
    assert loose['B_east'].sigma == pytest.approx(horizontal * math.radians(1.0), rel=0.1)
    assert exact['B_east'].sigma < 0.1 * loose['B_east'].sigma


@settings(max_examples=40, deadline=None)
@given(turn=st.floats(-math.pi, math.pi), shift=st.floats(-math.pi, math.pi),
       pitch=st.floats(-0.5, 0.5), roll=st.floats(-0.5, 0.5))
def test_turning_heading_and_the_earth_field_together_changes_no_reading(turn, shift, pitch, roll):
    """Poisson's model depends on heading only through C^T b: heading + s with b turned by s about down is the same."""
    record = stage_design(CarrierScenario())
    record = replace(record, turn_angle_rad=record.turn_angle_rad + turn, roll_rad=record.roll_rad + roll,
                     pitch_rad=record.pitch_rad + pitch)
    truth = CarrierScenario().truth()
    truth = replace(truth, poisson=np.array([[0.02, -0.01, 0.03], [0.0, 0.05, 0.01], [0.02, 0.0, 0.1]]))
    turned = replace(truth, earth_uT=axis_rotation(2, shift) @ truth.earth_uT)
    np.testing.assert_allclose(predict(turned, replace(record, heading_rad=record.heading_rad + shift)),
                               predict(truth, record), atol=1e-9)


@pytest.mark.parametrize('shift_deg', [-40.0, 25.0])
def test_the_estimate_turns_with_heading_and_declination(shift_deg):
    """Heading and declination both shifted: the same readings, the Earth field's estimate turned about down."""
    base = CarrierScenario(seed=9)
    shifted = replace(base, heading_deg=base.heading_deg + shift_deg, declination_deg=base.declination_deg + shift_deg)
    record, _ = simulate_carrier(base)
    record_shifted, _ = simulate_carrier(shifted)
    np.testing.assert_allclose(record_shifted.field_uT, record.field_uT, atol=1e-9)
    fit = fit_carrier(record, SEED_MODEL)
    fit_shifted = fit_carrier(record_shifted, CarrierModel(('zz',), Gauge(declination_deg=7.0 + shift_deg)))
    earth = np.array([fit.value(f'B_{n}') for n in ('north', 'east', 'down')])
    earth_shifted = np.array([fit_shifted.value(f'B_{n}') for n in ('north', 'east', 'down')])
    # equal to the fit's convergence: a thousandth of the smallest sigma
    sigmas = np.array([fit.by_name()[f'B_{n}'].sigma for n in ('north', 'east', 'down')])
    assert np.all(np.abs(earth_shifted - axis_rotation(2, math.radians(shift_deg)) @ earth) < 1e-3 * sigmas.max())
    for name in ('D_zz', 'p_x', 'p_y', 'p_z', 'o_x', 'o_y', 'o_z'):
        sigma = fit.by_name()[name].sigma
        assert fit_shifted.value(name) == pytest.approx(fit.value(name), abs=1e-3 * sigma)
        assert fit_shifted.by_name()[name].sigma == pytest.approx(sigma, rel=1e-3)


_cell = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                  st.sampled_from(['x', 'z', '', 'nan', 'gauss']),
                  st.floats(-100, 100).map(lambda v: f'{v:.3f}'))


@settings(max_examples=80, deadline=None)
@given(rows=st.lists(st.lists(_cell, min_size=10, max_size=10), min_size=1, max_size=12))
def test_the_record_parser_returns_finite_values_or_one_clear_error(rows):
    """Whatever the cells, the parser returns an all-finite record or raises CarrierError in one line."""
    text = ','.join(CSV_COLUMNS) + '\n' + '\n'.join(','.join(row) for row in rows) + '\n'
    try:
        record = parse_record_csv(text)
    except CarrierError as err:
        assert '\n' not in str(err)
        return
    for name in record.__dataclass_fields__:
        assert np.all(np.isfinite(np.asarray(getattr(record, name), dtype=float)))


def _csv(scale: float = 1.0, **changes) -> str:
    record, _ = simulate_carrier(CarrierScenario(seed=5))
    return record_csv(replace(record, field_uT=record.field_uT * scale, **changes))


def _with_cell(text: str, line: int, column: int, value: str) -> str:
    lines = text.splitlines()
    cells = lines[line - 1].split(',')
    cells[column] = value
    lines[line - 1] = ','.join(cells)
    return '\n'.join(lines) + '\n'


@pytest.mark.parametrize('text, match', [
    (_with_cell(_csv(), 2, 5, 'nan'), r'line 2: pitch_deg is not finite'),
    (_with_cell(_csv(), 3, 8, 'inf'), r'line 3: field_y_uT is not finite'),
    (_csv(scale=0.01), r'look like gauss'),
    (_csv(scale=1000.0), r'look like nanotesla'),
])
def test_bad_records_get_one_clear_line(text, match):
    """NaN, gauss-sized and nanotesla-sized fields: refused in one line naming the cause."""
    with pytest.raises(CarrierError, match=match) as info:
        parse_record_csv(text, 'rec.csv')
    assert '\n' not in str(info.value) and str(info.value).startswith('rec.csv')


def test_a_record_without_a_turn_of_the_sensor_is_refused():
    """The sensor never turned on its mount: its offset cannot be told from the carrier's field."""
    record, _ = simulate_carrier(CarrierScenario(seed=6))
    text = record_csv(replace(record, turn_angle_rad=np.zeros(len(record))))
    with pytest.raises(CarrierError, match='never turned'):
        parse_record_csv(text)


def test_tesla_columns_read_as_microtesla():
    """The same record in tesla (field_*_T columns) parses to the same microtesla values."""
    text = _csv()
    record = parse_record_csv(text)
    header, *rows = text.splitlines()
    tesla_rows = []
    for row in rows:
        cells = row.split(',')
        cells[7:] = [repr(float(v) * 1e-6) for v in cells[7:]]
        tesla_rows.append(','.join(cells))
    tesla = header.replace('_uT', '_T') + '\n' + '\n'.join(tesla_rows) + '\n'
    np.testing.assert_allclose(parse_record_csv(tesla).field_uT, record.field_uT, rtol=1e-12)


def test_cli_simulate_fit_json_and_errors(tmp_path, capsys):
    """carrier-simulate, carrier-fit --json; a bad record: exit 2, one line, nothing written."""
    record = tmp_path / 'record.csv'
    assert main(['carrier-simulate', '-o', str(record), '--seed', '7']) == 0
    assert main(['carrier-simulate', '-o', str(record)]) == 2  # the overwrite rule
    assert 'exists already' in capsys.readouterr().err
    out = tmp_path / 'fit.json'
    assert main(['carrier-fit', str(record), '--declination', '7', '--json', str(out)]) == 0
    printed = capsys.readouterr().out
    assert 'D_zz' in printed and 'condition number' in printed
    document = json.loads(out.read_text())
    truth = CarrierScenario().truth()
    estimate = document['estimates']['B_down']
    assert abs(estimate['value'] - truth.earth_uT[2]) < 4 * estimate['sigma']
    bad = tmp_path / 'bad.csv'
    bad.write_text(record.read_text().replace('_uT', '_T'))  # microtesla numbers under tesla names
    json_out = tmp_path / 'bad.json'
    assert main(['carrier-fit', str(bad), '--declination', '7', '--json', str(json_out)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith('tak_calib: error: ') and not json_out.exists()
    assert main(['carrier-fit', str(record)]) == 2  # no gauge given
    assert '--declination' in capsys.readouterr().err


def test_cli_budget_prints_the_seed_table_and_writes_the_report(tmp_path, capsys):
    """carrier-budget: the table with the seed's figures, the JSON and the sweeps' report."""
    report, out = tmp_path / 'report', tmp_path / 'budget.json'
    assert main(['carrier-budget', '--runs', '4', '--report', str(report), '--json', str(out), '--quiet']) == 0
    printed = capsys.readouterr().out
    assert '4.44' in printed and '0.35' in printed and 'Earth-field components' in printed
    assert (report / 'report.html').exists() and (report / 'sweeps.png').stat().st_size > 1000
    document = json.loads(out.read_text())
    assert set(document['sweeps']) == {'tilt_range_deg', 'tilt_step_deg', 'field_uT', 'turn_rad', 'attitude_deg'}


def test_monte_carlo_errors_match_the_predicted_sigma_and_grow_with_the_attitude_error():
    """The budget's RMS relative errors agree with the reported sigmas; a 3x attitude error raises them."""
    scenario = CarrierScenario()
    seed = monte_carlo(scenario, SEED_MODEL, runs=20)
    for name in ('earth', 'poisson', 'hard_iron'):
        assert 0.6 < seed.rms_percent[name] / seed.mean_sigma_percent[name] < 1.6, name
    worse = monte_carlo(replace(scenario, errors=InstrumentErrors(attitude_rad=math.radians(0.3))), SEED_MODEL, runs=20)
    assert worse.mean_sigma_percent['poisson'] > 1.5 * seed.mean_sigma_percent['poisson']
