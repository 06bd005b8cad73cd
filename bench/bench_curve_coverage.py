"""Benchmark: whether the gyroscope curve's stated +- in the files plain ``tak_calib fit`` writes covers the truth.

The calibration watch (``core/link/watch.py``) judges a rest's offset against the file's curve with
the file's own ``uncertainty`` section in its covariance: a curve off by more than it states is a
healthy unit called stale. Per seed of both everyday settings (``everyday_check.SETTINGS``) the two
files of ``everyday_files.seed_files`` (a pool of 16 records, ``tak_calib fit DIR``; the same unit's
chamber run, static z up, ``tak_calib fit BAG``), at eight temperatures across each file's calibrated
range: the curve's error against the simulated truth, relative to the range's middle (a record's own
turn-on offset takes any constant), over the standard error the file states for that difference. Per
file and setting: the share of ``|z| > 2`` (about 5 % when the +- is right) and ``> 3``, the RMS of
``z`` (1 when right), and the RMS error itself in deg/h.

Run: ``nice -n 10 .venv/bin/python bench/bench_curve_coverage.py [--seeds 20] [--settings first second]``
(the files are fitted once and cached, shared with ``bench_watch.py``: ``TAK_EVERYDAY_FILES``); writes
``bench/results/curve_coverage.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import machine  # noqa: E402
from everyday_check import SETTINGS  # noqa: E402
from everyday_files import seed_files  # noqa: E402
from tak_thermo_ros.core.link.correction import UnitCorrector  # noqa: E402
from tak_thermo_ros.core.simulation.everyday import everyday_truth  # noqa: E402
from tak_thermo_ros.core.values import DEG_PER_H  # noqa: E402
from tak_thermo_ros.formats.calibration_file import write_text_atomic  # noqa: E402

RESULTS = Path(__file__).resolve().parent / 'results'
TEMPERATURES = 8
"""Temperatures per file, evenly over its calibrated range less half a degree at each edge."""


def curve_z(unit, truth) -> tuple[np.ndarray, np.ndarray]:
    """``(TEMPERATURES, 3)`` per temperature and axis the gyro curve's error (rad/s) and its ``z``, from the middle."""
    gyro = unit.gyro
    low, high = gyro.temp_code_min, gyro.temp_code_max
    temperatures = np.linspace(low + 0.5, high - 0.5, TEMPERATURES)
    middle = 0.5 * (low + high)
    level = np.zeros((TEMPERATURES + 1, 6))
    level[:, 2] = 9.81  # z up, at rest: the gyroscope's offsets alone (its scales times zero)
    at = np.append(temperatures, middle)
    error = (UnitCorrector(unit).correct(level, at) - UnitCorrector(truth).correct(level, at))[:, 3:]
    error = error[:-1] - error[-1]
    uncertainty = gyro.uncertainty
    z = np.full_like(error, np.nan)
    for axis in range(3):
        variance = uncertainty.offset_change_variance(axis, middle - gyro.temp_code_ref,
                                                      temperatures - gyro.temp_code_ref)
        deviation = np.sqrt(np.maximum(variance, 0.0)) / abs(gyro.axes[axis].scale)
        z[:, axis] = error[:, axis] / np.maximum(deviation, 1e-300)
    return error, z


def summary(errors: list[np.ndarray], zs: list[np.ndarray]) -> dict[str, object]:
    """The shares, RMS of ``z`` (per axis too) and the RMS error in deg/h over the seeds."""
    z = np.vstack(zs)
    error = np.vstack(errors) * DEG_PER_H
    return {'points': int(z.size), 'share_beyond_2_sigma': float(np.mean(np.abs(z) > 2.0)),
            'share_beyond_3_sigma': float(np.mean(np.abs(z) > 3.0)),
            'rms_z': float(np.sqrt(np.mean(z ** 2))), 'rms_z_per_axis': np.sqrt(np.mean(z ** 2, axis=0)).tolist(),
            'rms_error_deg_h': float(np.sqrt(np.mean(error ** 2))),
            'median_abs_z_per_seed': [float(np.median(np.abs(one))) for one in zs]}


def main(argv: list[str] | None = None) -> int:
    """Measure every seed of the settings and write the results."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', type=int, default=20)
    parser.add_argument('--settings', nargs='+', choices=SETTINGS, default=list(SETTINGS))
    parser.add_argument('--output', default=str(RESULTS / 'curve_coverage.json'))
    args = parser.parse_args(argv)
    started = time.time()
    settings = {}
    for setting in args.settings:
        found = {'pool': ([], []), 'chamber': ([], [])}
        for seed in range(1, args.seeds + 1):
            files = seed_files(setting, seed)
            truth = everyday_truth(files.scenario, files.habits)
            for name, unit in files.units().items():
                error, z = curve_z(unit, truth)
                found[name][0].append(error)
                found[name][1].append(z)
        settings[setting] = {name: summary(*pair) for name, pair in found.items()}
        for name, row in settings[setting].items():
            print(f'{setting}, {name}: beyond 2 sigma {100 * row["share_beyond_2_sigma"]:.1f} % of '
                  f'{row["points"]} (about 5 % if right)')
            print(f'{setting}, {name}: RMS of z {row["rms_z"]:.2f} (1 if right), x y z '
                  f'{" ".join(f"{v:.2f}" for v in row["rms_z_per_axis"])}; RMS error '
                  f'{row["rms_error_deg_h"]:.1f} deg/h')
    document = {'machine': machine(), 'seeds': args.seeds, 'temperatures': TEMPERATURES, 'settings': settings,
                'wall_s': time.time() - started}
    write_text_atomic(args.output, json.dumps(document, indent=1) + '\n')
    print(f'wrote {args.output}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
