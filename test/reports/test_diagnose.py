"""The diagnosis report: PNG figures and one self-contained HTML page."""

from __future__ import annotations

import base64
import html
import re
from dataclasses import replace

import pytest

from conftest import SHORT
from tak_thermo_ros.core.diagnose import diagnose
from tak_thermo_ros.core.effects import LIBRARY
from tak_thermo_ros.core.fit import fit_model
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.reports.diagnose import write_report

HYSTERESIS = {'width_codes': 40.0, 'amplitude_x': 3.0, 'amplitude_y': -2.5, 'amplitude_z': 2.0}
PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'


def _diagnosed(effects: dict, seed: int):
    samples = align(simulate(replace(SHORT, sample_rate_hz=0.25, seed=seed, effects=effects)).record)
    calibration = fit_model(samples).calibration
    return diagnose(calibration, samples, candidates=['hysteresis', 'thermal_lag']), samples


@pytest.fixture(scope='module')
def hysteresis_report(tmp_path_factory):
    """A report on a run with a hidden hysteresis."""
    result, samples = _diagnosed({'hysteresis': HYSTERESIS}, seed=21)
    directory = tmp_path_factory.mktemp('report')
    return result, write_report(result, samples, directory / 'out', source='hidden_hysteresis.bag')


def test_report_is_one_self_contained_page_holding_every_figure(hysteresis_report):
    """report.html exists, loads nothing from outside, and embeds each PNG written beside it."""
    _, files = hysteresis_report
    page = files.html.read_text(encoding='utf-8')
    assert files.html.name == 'report.html'
    assert len(files.figures) >= 7
    sources = re.findall(r'\b(?:src|href)\s*=\s*["\']([^"\']*)', page, flags=re.IGNORECASE)
    assert sources, 'the page should hold its images'
    assert all(source.startswith('data:image/png;base64,') for source in sources), sources
    assert not re.search(r'url\s*\(|@import|<script|<link|<iframe', page, flags=re.IGNORECASE)
    for figure in files.figures:
        data = figure.read_bytes()
        assert data.startswith(PNG_SIGNATURE), figure
        assert base64.b64encode(data).decode('ascii') in page, f'{figure.name} is not embedded'


def test_report_states_the_verdict_the_physics_and_the_ladder(hysteresis_report):
    """The page names the verdict, gives the effect's physics and confirming run, and the ladder."""
    result, files = hysteresis_report
    page = files.html.read_text(encoding='utf-8')
    assert result.verdict == 'hysteresis'
    assert 'Verdict: hysteresis' in page
    effect = LIBRARY['hysteresis']
    assert html.escape(effect.summary) in page
    assert html.escape(effect.confirm) in page
    assert 'base + hysteresis' in page
    assert 'hidden_hysteresis.bag' in page
    assert '--effects hysteresis' in page


def test_report_of_a_run_at_the_floor_says_none(tmp_path):
    """Without a hidden effect the page says 'none' and still draws every figure."""
    result, samples = _diagnosed({}, seed=22)
    files = write_report(result, samples, tmp_path)
    page = files.html.read_text(encoding='utf-8')
    assert result.verdict == 'none'
    assert 'Verdict: none' in page
    assert len(files.figures) >= 7
    assert all(figure.stat().st_size > 10_000 for figure in files.figures)


def test_tak_calib_diagnose_writes_json_and_report(tmp_path, capsys):
    """The command prints the verdict, writes the JSON the issue asks for and the HTML page."""
    import json

    from tak_thermo_ros.formats.bag import write_record
    from tak_thermo_ros.cli import main

    run = simulate(replace(SHORT, sample_rate_hz=0.25, seed=23,
                           effects={'warmup': {'tau_s': 1200.0, 'amplitude_x': 12.0, 'amplitude_y': -9.0,
                                               'amplitude_z': 15.0}}))
    write_record(tmp_path / 'run', run.record)
    assert main(['fit', str(tmp_path / 'run'), '-o', str(tmp_path / 'base.yaml'), '--no-progress']) == 0
    code = main(['diagnose', str(tmp_path / 'run'), '--params', str(tmp_path / 'base.yaml'), '--json',
                 str(tmp_path / 'out.json'), '--report', str(tmp_path / 'report'), '--no-progress'])
    printed = capsys.readouterr().out
    assert code == 0
    assert 'verdict: warmup' in printed
    document = json.loads((tmp_path / 'out.json').read_text())
    assert document['verdict'] == 'warmup'
    for axis in ('x', 'y', 'z'):
        assert document['axes'][axis]['rms'] > document['axes'][axis]['noise_floor'] > 0.0
    assert document['candidates'][0]['effect'] == 'warmup'
    assert len(document['candidates']) == len(LIBRARY) - 1  # the step only where the scan finds one
    assert document['steps'] == []
    for candidate in document['candidates']:
        assert set(candidate['rms_after']) == {'x', 'y', 'z'}
        assert candidate['evidence']
    assert (tmp_path / 'report' / 'report.html').exists()


def test_tak_calib_diagnose_without_reference_is_one_line_error(tmp_path, capsys):
    """A bag without the reference stream cannot be diagnosed: one line, exit status 2."""
    from tak_thermo_ros.formats.bag import write_record
    from tak_thermo_ros.cli import main

    run = simulate(replace(SHORT, sample_rate_hz=0.25, seed=24))
    write_record(tmp_path / 'run', run.record)
    assert main(['fit', str(tmp_path / 'run'), '-o', str(tmp_path / 'base.yaml'), '--no-progress']) == 0
    bare = replace(run.record, reference_stamp_ns=run.record.reference_stamp_ns[:0],
                   reference=run.record.reference[:0])
    write_record(tmp_path / 'bare', bare)
    capsys.readouterr()
    code = main(['diagnose', str(tmp_path / 'bare'), '--params', str(tmp_path / 'base.yaml'), '--no-progress'])
    error = capsys.readouterr().err
    assert code == 2
    assert error.startswith('tak_calib: error:') and error.count('\n') == 1
