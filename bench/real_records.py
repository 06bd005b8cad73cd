"""Real records other people made, through the paths of issue 23 (temperature optional, the magnetometer from a turn).

1. ``CK-Explorer/Magnetometer-and-Accelerometer-Calibration`` (Apache-2.0), ``Data Examples/acc_mag_log.csv``:
   an accelerometer (g) and a magnetometer (gauss) turned by hand through every orientation,
   12,000 rows, no time column, no gyroscope, no temperature. ``import-csv`` needs a time column
   and gyroscope columns for a driver bag: this script writes the rows at an assumed 50 Hz
   (the file states no rate; the magnetometer's fit does not read it) with a zero angular rate
   (the record holds none; nothing in the magnetometer's fit reads it), then runs
   ``import-csv --mag-columns ... --mag-unit gauss``, ``fit`` and ``apply``: the iron from the
   record alone, its thermal link held (no temperature). Hold-out: the first half is fitted,
   the second half corrected, and the other way round. The sensor's own noise on ``|B|`` is
   taken from the successive differences of the corrected ``|B|`` (which the turning does not
   move): ``std(diff) / sqrt(2)``.
2. ``data/tofupilot-imu-thermal`` (MIT, in this repository): the log imported *without* its
   temperature column (``import-csv`` with no ``--temp-column``), then ``noise`` writes a Kalibr
   file; and ``fit`` refuses it in one line (no temperature, no magnetometer: nothing to fit).

Run: ``.venv/bin/python bench/real_records.py --ck-explorer GIT_DIR``, ``GIT_DIR`` the git directory of a
snapshot of the repository (here ``/work/.mirror/CK-Explorer+Magnetometer-and-Accelerometer-Calibration/repo``,
as ``fetch`` gave it); the data are read with ``git show`` and never copied into this repository.
Writes ``bench/results/real_records.json`` with the commands run.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchlib import machine, tak_calib_command

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / 'bench' / 'results'
TOFUPILOT = ROOT / 'data' / 'tofupilot-imu-thermal' / 'imu_raw_data.csv'
CK_FILE = 'Data Examples/acc_mag_log.csv'
ASSUMED_RATE_HZ = 50.0


def run(commands: list[str], *args: str, check: bool = True) -> subprocess.CompletedProcess:
    """``tak_calib ARGS`` (recorded in ``commands`` as a user types it)."""
    commands.append('tak_calib ' + ' '.join(a if ' ' not in a else repr(a) for a in args))
    return subprocess.run([*tak_calib_command(), *args], capture_output=True, text=True, check=check)


def field_spread(bag: Path) -> tuple[float, float]:
    """``|B|``'s standard deviation of a bag's corrected field and its noise from successive differences, tesla."""
    sys.path.insert(0, str(ROOT))
    from tak_thermo_ros.formats.bag import MAGNETIC_FIELD, iter_topic_arrays
    field = np.concatenate([a['magnetic_field'] for a in iter_topic_arrays(bag, '/imu/mag_compensated',
                                                                           MAGNETIC_FIELD)])
    magnitude = np.linalg.norm(field, axis=1)
    return float(magnitude.std()), float(np.diff(magnitude).std() / np.sqrt(2.0))


def ck_explorer(snapshot: Path, directory: Path, commands: list[str]) -> dict:
    text = subprocess.run(['git', '--git-dir', str(snapshot), 'show', f'HEAD:{CK_FILE}'], capture_output=True,
                          text=True, check=True).stdout
    rows = [line for line in text.splitlines()[1:] if line.strip()]
    halves = {'all': rows, 'first': rows[:len(rows) // 2], 'second': rows[len(rows) // 2:]}
    for name, part in halves.items():
        lines = ['t,ax,ay,az,gx,gy,gz,mx,my,mz']
        for index, row in enumerate(part):
            ax, ay, az, mx, my, mz = row.split(',')
            lines.append(f'{index / ASSUMED_RATE_HZ:.3f},{ax},{ay},{az},0,0,0,{mx},{my},{mz}')
        (directory / f'{name}.csv').write_text('\n'.join(lines) + '\n')
        run(commands, 'import-csv', str(directory / f'{name}.csv'), '-o', str(directory / name), '--time-column', 't',
            '--acc-columns', 'ax', 'ay', 'az', '--acc-unit', 'g', '--gyro-columns', 'gx', 'gy', 'gz',
            '--mag-columns', 'mx', 'my', 'mz', '--mag-unit', 'gauss')
    raw = np.array([[float(v) for v in row.split(',')[3:]] for row in rows]) * 1e-4
    result: dict = {'source': 'https://github.com/CK-Explorer/Magnetometer-and-Accelerometer-Calibration',
                    'file': CK_FILE, 'licence': 'Apache-2.0', 'rows': len(rows),
                    'raw_magnitude_std_uT': float(np.linalg.norm(raw, axis=1).std() * 1e6)}
    fitted = run(commands, 'fit', str(directory / 'all'), '-o', str(directory / 'all.yaml'), '--no-progress')
    result['fit_lines'] = [line for line in fitted.stdout.splitlines() if 'magnetometer' in line or 'held' in line
                           or 'ellipsoid' in line or 'hard iron' in line]
    run(commands, 'apply', str(directory / 'all'), '--params', str(directory / 'all.yaml'), '-o',
        str(directory / 'all_out'), '--no-progress')
    spread, noise = field_spread(directory / 'all_out')
    result['in_sample'] = {'magnitude_std_uT': spread * 1e6, 'noise_from_differences_uT': noise * 1e6}
    for fit_on, check_on in (('first', 'second'), ('second', 'first')):
        run(commands, 'fit', str(directory / fit_on), '-o', str(directory / f'{fit_on}.yaml'), '--no-progress')
        run(commands, 'apply', str(directory / check_on), '--params', str(directory / f'{fit_on}.yaml'), '-o',
            str(directory / f'{check_on}_out'), '--no-progress')
        spread, noise = field_spread(directory / f'{check_on}_out')
        raw_half = raw[:len(rows) // 2] if check_on == 'first' else raw[len(rows) // 2:]
        result[f'fitted_on_{fit_on}_half'] = {
            'held_out_raw_magnitude_std_uT': float(np.linalg.norm(raw_half, axis=1).std() * 1e6),
            'held_out_magnitude_std_uT': spread * 1e6, 'noise_from_differences_uT': noise * 1e6}
    return result


def tofupilot(directory: Path, commands: list[str]) -> dict:
    run(commands, 'import-csv', str(TOFUPILOT), '-o', str(directory / 'no_temperature'), '--time-unit', 'us',
        '--acc-columns', 'imu.acc.x', 'imu.acc.y', 'imu.acc.z', '--gyro-columns', 'imu.gyro.x', 'imu.gyro.y',
        'imu.gyro.z')
    said = run(commands, 'noise', str(directory / 'no_temperature'), '-o', str(directory / 'imu.yaml'),
               '--no-progress').stdout
    refused = run(commands, 'fit', str(directory / 'no_temperature'), '-o', str(directory / 'p.yaml'),
                  '--no-progress', check=False)
    import yaml
    kalibr = yaml.safe_load((directory / 'imu.yaml').read_text())
    return {'source': 'data/tofupilot-imu-thermal (in this repository)', 'licence': 'MIT',
            'noise_lines': [line for line in said.splitlines() if line.startswith(('accelerometer:', 'gyroscope:'))],
            'kalibr': {key: kalibr[key] for key in ('accelerometer_noise_density', 'gyroscope_noise_density',
                                                    'rostopic', 'update_rate')},
            'fit_exit': refused.returncode, 'fit_said': refused.stderr.strip(),
            'fit_wrote': (directory / 'p.yaml').exists()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--ck-explorer', type=Path, required=True,
                        help="the git directory of a fetched CK-Explorer/Magnetometer-and-Accelerometer-Calibration")
    args = parser.parse_args()
    commands: list[str] = []
    result: dict = {'machine': machine()}
    with tempfile.TemporaryDirectory() as name:
        directory = Path(name)
        result['ck_explorer_acc_mag'] = ck_explorer(args.ck_explorer, directory, commands)
        result['tofupilot_without_temperature'] = tofupilot(directory, commands)
    result['commands'] = [command.replace(str(directory), 'DIR') for command in commands]
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / 'real_records.json').write_text(json.dumps(result, indent=2) + '\n')
    print(json.dumps({key: value for key, value in result.items() if key != 'commands'}, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
