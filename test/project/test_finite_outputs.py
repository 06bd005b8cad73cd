"""No JSON or YAML ``tak_calib`` writes holds a NaN or an infinity (issue 34, item 4).

One check before every write (``formats/files.py``: ``check_finite``, ``json_text``,
``check_finite_yaml``, ``write_texts``) refuses one in a line naming the file and the key; where
a figure is not defined, the command says so (``null`` with its meaning documented, ``-`` in a
table) instead of writing NaN: ``carrier-budget`` without a free Poisson coefficient or whose
runs the fit all refuses, ``noise -o`` on an axis whose Allan deviation has no floor.
"""

from __future__ import annotations

import ast
import json
import math
import warnings
from pathlib import Path

import pytest
import yaml

from paths import REPO
from tak_thermo_ros.cli import main
from tak_thermo_ros.core.noise.model import NoiseModel
from tak_thermo_ros.errors import OutputError
from tak_thermo_ros.formats.files import check_finite, json_text, non_finite_number, write_json, write_texts
from tak_thermo_ros.formats.kalibr import kalibr_from_mapping, read_kalibr, write_kalibr

PACKAGE = REPO / 'tak_thermo_ros'


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('tak_calib: error: '), err
    return lines[0]


def _strict_json(path: Path) -> object:
    def refuse(constant: str) -> float:
        raise AssertionError(f'{path}: {constant} in the JSON')
    return json.loads(path.read_text(), parse_constant=refuse)


def test_the_one_check_names_the_file_and_the_key_and_writes_nothing(tmp_path):
    """A NaN or infinity anywhere in a document: refused naming the path and the key; nothing on disk."""
    document = {'table': {'rms_percent': {'earth': 0.1, 'poisson': math.nan}}, 'runs': [1.0, 2.0]}
    assert non_finite_number(document) == ('table.rms_percent.poisson', document['table']['rms_percent']['poisson'])
    assert non_finite_number({'a': [[1.0, math.inf]]})[0] == 'a[0][1]'
    assert non_finite_number({'a': [None, 1, 'nan', 2.5]}) is None  # null, text and whole numbers are fine
    with pytest.raises(OutputError, match=r'b.json: table.rms_percent.poisson is nan \(not a finite number\); '
                                          r'not written'):
        write_json(tmp_path / 'b.json', document)
    with pytest.raises(OutputError, match=r'x.yaml: the document is inf'):
        check_finite(math.inf, 'x.yaml')
    with pytest.raises(OutputError, match=r'design.json: separation\[1\] is'):
        write_texts(tmp_path / 'design', {'scenario.yaml': 'a: 1\n', 'design.json': '{"separation": [1, NaN]}'})
    with pytest.raises(OutputError, match=r'scenario.yaml: a is inf'):
        write_texts(tmp_path / 'design', {'scenario.yaml': 'a: .inf\n'})
    assert list(tmp_path.iterdir()) == []
    assert json.loads(json_text({'a': None, 'b': 1.5}, 'ok.json')) == {'a': None, 'b': 1.5}


def test_every_json_and_yaml_writer_goes_through_the_check():
    """A ``json.dumps`` or ``yaml.dump`` in the package is the checked writer's, or its text is checked before writing.

    (calibration YAML: ``save_unit``; a fleet's prior: ``save_prior``; the design files: ``write_texts``;
    Kalibr's rostopic: a string).
    """
    allowed = {('formats/files.py', 'json.dumps'), ('formats/calibration_file.py', 'yaml.safe_dump'),
               ('core/diagnose/design.py', 'yaml.safe_dump'), ('core/diagnose/design.py', 'json.dumps'),
               ('formats/kalibr.py', 'json.dumps'), ('formats/prior_file.py', 'yaml.safe_dump')}
    found = set()
    for path in PACKAGE.rglob('*.py'):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) \
                    and isinstance(node.func.value, ast.Name) and node.func.value.id in ('json', 'yaml') \
                    and node.func.attr in ('dumps', 'dump', 'safe_dump'):
                found.add((str(path.relative_to(PACKAGE)), f'{node.func.value.id}.{node.func.attr}'))
    assert found <= allowed, found - allowed


def _model(tau_z: float) -> NoiseModel:
    return NoiseModel(white_noise_density=(1e-3, 1e-3, 1e-3), bias_instability=(1e-4, 1e-4, 0.0),
                      bias_instability_tau=(20.0, 30.0, tau_z), random_walk=(1e-5, 1e-5, 0.0), update_rate=100.0,
                      source='static_run', random_walk_bound=(0.0, 0.0, 2e-6))


def test_an_axis_without_a_floor_is_null_in_the_kalibr_file_said_and_read_back(tmp_path):
    """``allan_floor_xyz`` and ``bias_instability_tau_xyz`` hold ``null`` there (was ``.nan``, ``.inf``).

    Said in the line's comment; read back as no floor (an infinite floor time); files written
    before, with ``.nan`` and ``.inf``, still read.
    """
    path = tmp_path / 'imu.yaml'
    write_kalibr(path, {'accel': _model(math.inf)}, rostopic='/imu/data_raw')
    text = path.read_text()
    raw = yaml.safe_load(text)
    assert non_finite_number(raw) is None and '.nan' not in text and '.inf' not in text
    assert raw['accelerometer_allan_floor_xyz'][2] is None and raw['accelerometer_bias_instability_tau_xyz'][2] is None
    line = next(line for line in text.splitlines() if line.startswith('accelerometer_bias_instability_tau_xyz'))
    assert line.endswith('# null: no floor (still falling at the longest averaging time)')
    back = read_kalibr(path)['accel']
    assert back.bias_instability_tau[2] == math.inf and back.bias_instability_tau[:2] == pytest.approx((20.0, 30.0))
    old = text.replace('null]', '.nan]', 1).replace('null]', '.inf]', 1)  # the floor, then its time
    assert kalibr_from_mapping(yaml.safe_load(old))[0]['accel'].bias_instability_tau[2] == math.inf
    finite = tmp_path / 'finite.yaml'
    write_kalibr(finite, {'accel': _model(40.0)}, rostopic='/imu/data_raw')
    assert 'null' not in finite.read_text()


def test_carrier_budget_whose_runs_the_fit_all_refuses_is_one_line_and_writes_nothing(tmp_path, capsys):
    """``--no-gauge`` with a tilt about one axis: every run refused; was exit 0 with ``"earth": NaN``."""
    out = tmp_path / 'b.json'
    assert main(['carrier-budget', '--runs', '3', '--json', str(out), '--no-gauge']) == 2
    captured = capsys.readouterr()
    line = _one_line(captured.err)
    assert 'the fit refused every one of the 3 runs' in line and 'cannot separate' in line
    assert captured.out == '' and list(tmp_path.iterdir()) == []


def test_carrier_budget_without_a_free_poisson_coefficient_says_it_and_writes_null(tmp_path, capsys):
    """``--poisson ''``: the Poisson figures are not defined: ``-`` in the table, a line, ``null`` in the JSON.

    With the sweeps too (``--report``): ``null`` per point, no warning from a library.
    """
    out = tmp_path / 'b.json'
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        assert main(['carrier-budget', '--runs', '8', '--poisson', '', '--json', str(out), '--report',
                     str(tmp_path / 'report'), '--quiet']) == 0
    captured = capsys.readouterr()
    assert [str(w.message) for w in caught] == [] and captured.err == ''
    printed = captured.out
    assert 'nan' not in printed.lower() and 'Poisson coefficient(s): none free, so no figure (-)' in printed
    row = next(line for line in printed.splitlines() if line.startswith('Poisson coefficient(s)  '))
    assert row.split()[-3:] == ['-', '-', '-']
    document = _strict_json(out)
    table = document['table']
    assert table['rms_percent']['poisson'] is None and table['p95_percent']['poisson'] is None
    assert math.isfinite(table['rms_percent']['earth']) and table['failed'] == 0
    points = [point for sweep in document['sweeps'].values() for point in sweep]
    assert points and all(point['rms_percent']['poisson'] is None for point in points)
