"""Real records: the noise model's fit against the measured Allan deviation, allantools beside it (issue 25).

1. **A static record of a real IMU** of a permissive licence: ``tomisuarez2/ImuCalibration``
   (MIT; an MPU-6050 at 100 Hz, raw 16-bit codes, its digital low-pass off: DLPF mode 0, the
   gyroscope sampled at 8 kHz and decimated, full scale +-2 g and +-250 deg/s), its two static
   records ``calibration data/example_data_tinit_calc.csv`` (7.5 min) and ``results test
   data/imu_static_test.csv`` (100 s). Never committed: the script takes the path of the
   fetched snapshot (a git directory, as ``fetch`` brings it, or a checkout).
2. **The repository's own log** (``data/tofupilot-imu-thermal``, MIT): a thermal cycle, not a
   static run; its residual after the paper's polynomials (``import-csv``, ``fit``, ``noise
   --params``) serves as a record of the sensor's noise plus what the polynomials leave.

Per record and axis: the Allan deviation beside ``allantools.oadev`` (LGPL, optional: ``pip
install allantools``; its largest relative difference), the fit's goodness (within the 95 %
band from two samples on, the worst ratio and where), the terms, and the five-term fit of
``main`` before issue 25 (``bench_noise_fit.five_term_fit``) on the same curve; every imu.yaml
checked against Kalibr's own conditions (``core.noise.test_fit.kalibr_accepts``).

Run: ``.venv/bin/python bench/real_static_noise.py /work/.mirror/tomisuarez2+ImuCalibration/repo``.
Writes ``bench/results/real_static_noise.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

from benchlib import import_real_log, machine, run_tak_calib as run

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))

from bench_noise_fit import band_figures, five_term_fit  # noqa: E402
from core.noise.test_fit import kalibr_accepts  # noqa: E402

from tak_thermo_ros.cli.common import noise_axis_lines  # noqa: E402
from tak_thermo_ros.core.noise.allan import allan_variance  # noqa: E402
from tak_thermo_ros.core.noise.fit import fit_noise  # noqa: E402
from tak_thermo_ros.core.values import STANDARD_GRAVITY  # noqa: E402
from tak_thermo_ros.formats.kalibr import kalibr_text  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / 'bench' / 'results'
RECORDS = {'static_7.5min': 'calibration data/example_data_tinit_calc.csv',
           'static_100s': 'results test data/imu_static_test.csv'}
ACCEL_LSB = 16384.0
"""MPU-6050 codes per g at +-2 g (the driver's default full scale)."""
GYRO_LSB = 131.0
"""MPU-6050 codes per deg/s at +-250 deg/s."""


def read_record(snapshot: Path, name: str) -> tuple[float, np.ndarray]:
    """The sample rate and the ``(n, 6)`` codes ``ax ay az gx gy gz`` of a record of the snapshot."""
    if (snapshot / name).exists():
        text = (snapshot / name).read_text()
    else:  # a bare git directory, as fetch brings it
        text = subprocess.run(['git', '--git-dir', str(snapshot), 'show', f'HEAD:{name}'], capture_output=True,
                              text=True, check=True).stdout
    lines = text.splitlines()
    rate = float(lines[0].split(',')[1])
    header = next(i for i, line in enumerate(lines) if line.startswith('ax,'))
    return rate, np.loadtxt(lines[header + 1:], delimiter=',')


def beside_allantools(samples: np.ndarray, rate: float, allan) -> float | None:
    """The largest relative difference of our Allan deviation from ``allantools.oadev`` at the same taus."""
    try:
        import allantools
    except ImportError:
        return None
    worst = 0.0
    for axis in range(samples.shape[1]):
        taus, adev, _error, _count = allantools.oadev(samples[:, axis], rate=rate, data_type='freq',
                                                      taus=allan.taus)
        ours = np.interp(taus, allan.taus, allan.adev[:, axis])
        worst = max(worst, float(np.max(np.abs(ours / adev - 1.0))))
    return worst


def describe(fit, allan, sensor: str, unit: str) -> dict[str, object]:
    """Per axis what the fit says, and the five-term fit's worst ratio on the same curve."""
    old = five_term_fit(allan)
    judged = (allan.counts >= 2) & (allan.clusters >= 2)
    old_ratio = np.sqrt(old.allan_variance(allan.taus[judged]) / allan.avar[judged])
    # one yardstick for both: the flicker-rate degrees of freedom, joint 95 % (bench_noise_fit.band_figures)
    common = {'fit': band_figures(allan, fit.model)['inside'], 'five_term': band_figures(allan, old)['inside']}
    axes = {}
    for axis, name in enumerate('xyz'):
        found = fit.axes[axis]
        worst = int(np.argmax(np.abs(np.log(old_ratio[:, axis]))))
        axes[name] = {'lines': noise_axis_lines(sensor, fit.model, axis, unit, fit),
                      'within': found.within, 'worst_ratio': found.worst_ratio, 'worst_tau_s': found.worst_tau,
                      'band': [found.band_low, found.band_high],
                      'inside_common_band': common['fit'][axis],
                      'five_term_inside_common_band': common['five_term'][axis],
                      'five_term_worst_ratio': float(old_ratio[worst, axis]),
                      'five_term_worst_tau_s': float(allan.taus[judged][worst])}
    model = fit.model.to_json()
    model['floor'] = [v if math.isfinite(v) else None for v in fit.model.floor()]
    return {'axes': axes, 'model': model}


def static_records(snapshot: Path) -> dict[str, object]:
    """The MIT records: per sensor the fit, allantools beside ours, the Kalibr file checked."""
    out: dict[str, object] = {}
    for label, name in RECORDS.items():
        rate, codes = read_record(snapshot, name)
        sensors = {'accel': (codes[:, :3] / ACCEL_LSB * STANDARD_GRAVITY, 'm/s^2'),
                   'gyro': (np.radians(codes[:, 3:] / GYRO_LSB), 'rad/s')}
        found: dict[str, object] = {'file': name, 'samples': int(len(codes)), 'rate_hz': rate,
                                    'minutes': len(codes) / rate / 60.0}
        models = {}
        for sensor, (values, unit) in sensors.items():
            samples = values - values.mean(axis=0)
            allan = allan_variance(samples, rate, per_octave=2)
            fit = fit_noise(allan, source='static_run')
            models[sensor] = fit.model
            found[sensor] = {**describe(fit, allan, sensor, unit),
                             'allantools_largest_difference': beside_allantools(samples, rate, allan),
                             'averaging_times_s': [float(allan.taus[0]), float(allan.taus[-1])]}
            print(f'{label} {sensor}:', flush=True)
            for axis in 'xyz':
                for line in found[sensor]['axes'][axis]['lines']:  # type: ignore[index]
                    print(f'  {axis}: {line}')
        kalibr_accepts(yaml.safe_load(kalibr_text(models, rostopic='/imu')))
        found['kalibr_accepts'] = True
        out[label] = found
    return out


def own_log() -> dict[str, object]:
    """The repository's real log: its residual after the paper's polynomials, through ``tak_calib noise --params``."""
    with tempfile.TemporaryDirectory() as directory:
        def at(name: str) -> str:
            return str(Path(directory) / name)
        import_real_log(at('real'))
        run('fit', at('real'), '-o', at('base.yaml'))
        printed = run('noise', at('real'), '--params', at('base.yaml'), '--json', at('noise.json'), '-o',
                      at('imu.yaml'), '--no-progress')
        document = json.loads(Path(at('noise.json')).read_text())
        kalibr_accepts(yaml.safe_load(Path(at('imu.yaml')).read_text()))
    print(printed)
    out: dict[str, object] = {'printed': printed.splitlines(), 'kalibr_accepts': True}
    for sensor, found in document['sensors'].items():
        out[sensor] = {'fit': found['fit'], 'samples': found['samples'],
                       'averaging_times_s': [found['allan']['taus'][0], found['allan']['taus'][-1]]}
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('snapshot', type=Path,
                        help='the fetched tomisuarez2/ImuCalibration (git directory or checkout)')
    args = parser.parse_args()
    result = {'machine': machine(), 'source': 'github.com/tomisuarez2/ImuCalibration (MIT)',
              'snapshot_commit': subprocess.run(['git', '--git-dir', str(args.snapshot), 'rev-parse', 'HEAD'],
                                                capture_output=True, text=True).stdout.strip() or None,
              'static': static_records(args.snapshot), 'own_log': own_log()}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / 'real_static_noise.json').write_text(json.dumps(result, indent=2) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
