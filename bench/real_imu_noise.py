"""The real IMU log (data/tofupilot-imu-thermal) judged against a noise model (issue 16).

Runs the user's commands in a temporary directory: ``import-csv`` (both sensors), ``fit``,
``diagnose`` (no static run or data sheet exists for this unit: the noise model is fitted to the
log's own residual up to 30 s), ``fit`` with what the diagnosis names, ``diagnose`` again, and
``validate`` with either calibration. Prints and writes to ``bench/results/real_imu_noise.json``:
per sensor and model, the residual's Allan deviation over the noise model at 65 s and 259 s per
axis, the verdicts, and the bias error averaged over 60 s; copies the final report's Allan
deviation figures to ``docs/figures/real_imu_allan_{gyro,accel}.png``.

Run: ``.venv/bin/python bench/real_imu_noise.py``.
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
from pathlib import Path

from benchlib import import_real_log, machine, run_tak_calib as run

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / 'bench' / 'results'
FIGURES = ROOT / 'docs' / 'figures'
TAUS = (65.0, 259.0)


def allan_at(check: dict, tau: float) -> list[float]:
    """The ratio residual / model per axis at the averaging time nearest ``tau``."""
    index = min(range(len(check['taus'])), key=lambda i: abs(check['taus'][i] - tau))
    return [check['residual_adev'][axis][index] / check['model_adev'][axis][index] for axis in 'xyz']


def main() -> int:
    result: dict[str, object] = {'machine': machine()}
    with tempfile.TemporaryDirectory() as directory:
        def at(name: str) -> str:
            return str(Path(directory) / name)
        import_real_log(at('real'))
        run('fit', at('real'), '-o', at('base.yaml'))
        run('diagnose', at('real'), '--params', at('base.yaml'), '--json', at('base.json'), '--no-progress')
        base = json.loads(Path(at('base.json')).read_text())
        named = {sensor: [step['effects'][-1] for step in base['sensors'][sensor]['ladder'][1:]]
                 for sensor in ('accel', 'gyro')}
        run('fit', at('real'), '-o', at('final.yaml'), '--effects', ','.join(named['accel']),
            '--gyro-effects', ','.join(named['gyro']))
        said = run('diagnose', at('real'), '--params', at('final.yaml'), '--json', at('final.json'), '--no-progress',
                   '--report', at('report'))
        result['final_walk_lines'] = [line.strip() for line in said.splitlines() if 'rate random walk in' in line]
        FIGURES.mkdir(parents=True, exist_ok=True)
        for sensor in ('gyro', 'accel'):
            shutil.copyfile(Path(at('report')) / sensor / 'allan.png', FIGURES / f'real_imu_allan_{sensor}.png')
        final = json.loads(Path(at('final.json')).read_text())
        for label, params in (('base', 'base.yaml'), ('final', 'final.yaml')):
            run('validate', at('real'), '--params', at(params), '--json', at(f'validate_{label}.json'))
        validation = {label: json.loads(Path(at(f'validate_{label}.json')).read_text()) for label in ('base', 'final')}
    rows = []
    for sensor in ('gyro', 'accel'):
        for label, document in (('base', base), ('final', final)):
            found = document['sensors'][sensor]
            check = found['allan'][0]
            averaged = (validation[label]['gyro'] if sensor == 'gyro' else validation[label])['averaged_bias_error']
            row = {'sensor': sensor, 'model': found['ladder'][0]['model'], 'verdict': found['verdict'],
                   'ladder': [step['model'] for step in found['ladder']],
                   'allan_ratio': {f'{tau:g}': allan_at(check, tau) for tau in TAUS},
                   'noise': found['noise'], 'bias_error_60s': averaged['taus']['60'],
                   'message': found['message']}
            rows.append(row)
            ratios = '; '.join(f'{tau:g} s ' + ' '.join(f'{v:.2f}' for v in row['allan_ratio'][f'{tau:g}'])
                               for tau in TAUS)
            error = averaged['taus']['60']
            print(f'{sensor}, {row["model"]}: Allan deviation / noise model {ratios}; verdict {row["verdict"]}; '
                  f'60 s bias error {" ".join(f"{v:.3g}" for v in error["rms"])} {error["unit"]}')
    result['rows'] = rows
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / 'real_imu_noise.json').write_text(json.dumps(result, indent=2) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
