"""tak_calib end to end: simulate, fit, validate, apply; exit codes and one-line errors."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import SHORT
from tak_thermo_ros.formats.bag import read_imu, read_record, write_record
from tak_thermo_ros.cli import main
from tak_thermo_ros.formats.calibration_file import load_calibration
from tak_thermo_ros.core.link.correction import Corrector, acceleration_variance
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.simulation.imu import simulate

TAK_CALIB = str(Path(sys.executable).with_name('tak_calib'))


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([TAK_CALIB, *args], capture_output=True, text=True, timeout=300)


@pytest.fixture(scope='module')
def workspace(tmp_path_factory):
    """A calibration bag, a second run of the same unit on another profile, and the fitted file."""
    root = tmp_path_factory.mktemp('cli')
    scenario = root / 'scenario.yaml'
    scenario.write_text(yaml.safe_dump({'plateau_hours': 0.5, 'ramp_celsius_per_minute': 1.0,
                                        'board_lag_s': 300.0, 'dwell_s': 30.0}))
    second = root / 'second.yaml'
    second.write_text(yaml.safe_dump({'plateau_hours': 0.4, 'ramp_celsius_per_minute': 1.0, 'board_lag_s': 300.0,
                                      'dwell_s': 30.0, 'plateaus_celsius': [12.0, 33.0, 8.0, 26.0]}))
    assert _run('simulate', str(root / 'cal'), '--scenario', str(scenario), '--seed', '1').returncode == 0
    assert _run('simulate', str(root / 'run2'), '--scenario', str(second), '--seed', '2',
                '--storage', 'sqlite3').returncode == 0
    fit = _run('fit', str(root / 'cal'), '-o', str(root / 'params.yaml'))
    assert fit.returncode == 0, fit.stderr
    return root, fit.stdout


def test_fit_prints_residuals_and_range_and_writes_a_loadable_file(workspace):
    """`fit` prints the residual RMS in counts (x y z, one line) and the calibrated range; the file loads."""
    root, stdout = workspace
    assert re.search(r'^  residual RMS  [\d.]+ [\d.]+ [\d.]+ counts \([\d.]+ [\d.]+ [\d.]+ mg\)$', stdout, re.MULTILINE)
    assert 'calibrated temperature-code range 7600..8800' in stdout
    calibration = load_calibration(root / 'params.yaml')
    assert calibration.temp_code_min == 7600.0 and calibration.temp_code_max == 8800.0


def test_validate_on_a_second_run_shows_the_error_fall(workspace):
    """|g| error after correction is far below the error before, on a run not used for the fit."""
    root, _ = workspace
    result = _run('validate', str(root / 'run2'), '--params', str(root / 'params.yaml'), '--json', str(root / 'v.json'))
    assert result.returncode == 0, result.stderr
    figures = json.loads((root / 'v.json').read_text())
    assert figures['after']['rms'] < figures['before']['rms'] / 4
    noise = np.hypot(1.5, 0.3) / 255.0
    assert figures['after']['rms'] < 1.5 * noise
    printed = ' '.join(result.stdout.split())
    assert f"before: codes through {root / 'params.yaml'}'s scale and offset at N_t,ref 8200" in printed


def test_apply_writes_one_imu_per_usable_counts_message(workspace):
    """`apply` writes Imu with the counts stamps and frame, REP 145 markers and the fit covariance."""
    root, _ = workspace
    result = _run('apply', str(root / 'run2'), '--params', str(root / 'params.yaml'), '-o', str(root / 'imu'))
    assert result.returncode == 0, result.stderr
    record = read_record(root / 'run2', progress=False)
    samples = align(record, use_reference=False)
    stamps, acceleration, frames, covariance = read_imu(root / 'imu')
    assert np.array_equal(stamps, samples.stamp_ns)
    assert set(frames) == {record.frame_id}
    calibration = load_calibration(root / 'params.yaml')
    assert np.array_equal(acceleration, Corrector(calibration).correct(samples.counts, samples.temp_code))
    variance = acceleration_variance(calibration)
    assert np.array_equal(covariance[0][[0, 4, 8]], variance) and min(variance) > 0


def test_bad_counts_are_dropped_and_reported(tmp_path):
    """NaN, non-integer and saturated counts are never corrected; apply says how many it dropped."""
    run = simulate(replace(SHORT, plateau_hours=0.02, ramp_celsius_per_minute=20.0, seed=9))
    counts = run.record.counts.copy()
    counts[10, 0] = np.nan
    counts[11, 1] = 12.5
    counts[12, 2] = 32767.0
    write_record(tmp_path / 'bad', replace(run.record, counts=counts))
    calibration = run.truth
    from tak_thermo_ros.formats.calibration_file import save_calibration
    save_calibration(tmp_path / 'p.yaml', calibration)
    result = _run('apply', str(tmp_path / 'bad'), '--params', str(tmp_path / 'p.yaml'), '-o', str(tmp_path / 'imu'))
    assert result.returncode == 0, result.stderr
    assert 'dropped counts messages: 1 non finite, 1 non integer, 1 saturated' in result.stdout
    stamps, acceleration, _, _ = read_imu(tmp_path / 'imu')
    assert len(stamps) == len(counts) - 3 and np.all(np.isfinite(acceleration))


@pytest.mark.parametrize(('args', 'message'), [
    (['fit', '{root}/absent', '-o', '{tmp}/p.yaml'], 'absent: no such bag'),
    (['apply', '{root}/run2', '--params', '{tmp}/absent.yaml', '-o', '{tmp}/imu'], 'no such calibration file'),
    (['validate', '{root}/run2', '--params', '{root}/params.yaml', '--counts-topic', '/nope'],
     'topic /nope not found'),
    (['fit', '{root}/run2', '-o', '{tmp}/p.yaml', '--bias-order', '0'], 'orders must be bias >= 1'),
    (['apply', '{root}/run2', '--params', '{root}/params.yaml', '-o', '{root}/cal'], 'exists already'),
    (['fit', '{root}/cal', '-o', '{tmp}/no/such/dir/p.yaml'], 'No such file or directory'),
])
def test_errors_are_one_line_with_exit_code_2(workspace, tmp_path, args, message):
    """Deliberate failures print one line naming the problem, exit 2, and write no output file."""
    root, _ = workspace
    argv = [a.format(root=root, tmp=tmp_path) for a in args]
    result = _run(*argv)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('tak_calib: error: ') and message in lines[0]
    assert 'Traceback' not in result.stderr
    assert not (tmp_path / 'p.yaml').exists() and not (tmp_path / 'imu').exists()


def test_fit_without_temperature_spread_writes_no_file(tmp_path):
    """An ill-posed calibration (one chamber temperature) ends with exit 2 and no file."""
    flat = replace(SHORT, start_celsius=20.0, plateaus_celsius=(20.0,), plateau_hours=0.1, seed=5)
    write_record(tmp_path / 'flat', simulate(flat).record)
    code = main(['fit', str(tmp_path / 'flat'), '-o', str(tmp_path / 'p.yaml'), '--no-progress'])
    assert code == 2 and not (tmp_path / 'p.yaml').exists()


def test_a_bad_calibration_file_names_the_key(workspace, tmp_path, capsys):
    """`apply` with a broken file names the file and the key."""
    root, _ = workspace
    document = yaml.safe_load((root / 'params.yaml').read_text())
    document['/**/compensator']['ros__parameters']['calibration']['y']['scale'] = -1.0
    (tmp_path / 'bad.yaml').write_text(yaml.safe_dump(document))
    code = main(['apply', str(root / 'run2'), '--params', str(tmp_path / 'bad.yaml'), '-o', str(tmp_path / 'imu')])
    assert code == 2
    assert f'{tmp_path / "bad.yaml"}: calibration.y.scale: must be > 0' in capsys.readouterr().err


def test_usage_errors_exit_2(capsys):
    """`argparse` usage errors also exit with 2."""
    with pytest.raises(SystemExit) as exit_info:
        main(['fit'])
    assert exit_info.value.code == 2


def test_diagnose_candidates_expand_library():
    """--candidates: comma-separated, 'library' stands for every library effect, no repeats."""
    from tak_thermo_ros.cli.diagnose import expand_candidates
    from tak_thermo_ros.core.effects import LIBRARY
    assert expand_candidates('mymodule:Creep') == ['mymodule:Creep']
    assert expand_candidates('library, mymodule:Creep,thermal_lag') == [*LIBRARY, 'mymodule:Creep']
    assert expand_candidates('hysteresis,,library') == ['hysteresis', *[n for n in LIBRARY if n != 'hysteresis']]


def test_long_runs_are_fitted_and_diagnosed_on_a_bounded_subsample(workspace, tmp_path):
    """``fit --effect-samples`` and ``diagnose --max-samples`` say the subsample in one line and keep to it."""
    root, _ = workspace
    fit = _run('fit', str(root / 'cal'), '--effects', 'thermal_lag', '--effect-samples', '1000',
               '-o', str(tmp_path / 'lag.yaml'))
    assert fit.returncode == 0, fit.stderr
    assert 'effect shapes searched on 1 sample in ' in fit.stdout
    assert 'amplitudes and the paper\'s link fitted on all of them' in ' '.join(fit.stdout.split())
    report = tmp_path / 'diagnose.json'
    diagnosed = _run('diagnose', str(root / 'cal'), '--params', str(root / 'params.yaml'), '--max-samples', '1000',
                     '--json', str(report))
    assert diagnosed.returncode == 0, diagnosed.stderr
    document = json.loads(report.read_text())
    stride = document['subsample_stride']
    assert stride > 1 and f'diagnosing 1 sample in {stride}, spread evenly over the run' in diagnosed.stdout
    assert document['samples_diagnosed'] <= 1000 < document['samples_usable']
    assert document['samples_diagnosed'] >= 0.9 * document['samples_usable'] / stride


def test_a_driver_bags_diagnosis_speaks_of_degrees_not_codes():
    """On driver bags the verdict's words name the temperature (degrees C), not the paper's codes."""
    from tak_thermo_ros.cli.common import in_driver_words as _in_driver_words
    text = _in_driver_words('no function of the temperature code predicts it; a play operator of width '
                            'width_codes; the temperature codes of this run')
    assert 'code ' not in text.replace('_codes', '') and 'temperatures of this run' in text
    assert 'width_codes (in C here)' in text
