"""Benchmark: the magnetometer's ellipsoid fit over many seeds (recovery, acceptance, refusal).

For ``--seeds`` simulated rotation records of the default magnetometer (2000 samples, 0.2 uT
noise, at the reference temperature) of each kind:

- ``tumble`` (every orientation): the fit's error in the centre (hard iron plus the sensor's
  offset) and in ``W`` (``S^-1`` with determinant 1), against the standard errors predicted
  for k points on a sphere with noise s (centre ``s sqrt(3 / k)`` per component; ``W``
  ``s / r sqrt(15 / k)`` per element, the test's formulas); how many records are refused
  (a false refusal);
- ``yaw`` (about z only) and ``cap`` (within 40 deg of up): how many are accepted (a false
  acceptance) and by which check the others are refused.

Run: ``.venv/bin/python bench/bench_mag_iron.py [--seeds 200]``; writes
``bench/results/mag_iron.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from tak_thermo_ros.core.magnetometer.iron import fit_ellipsoid
from tak_thermo_ros.formats.calibration_file import write_text_atomic
from tak_thermo_ros.core.simulation.magnetometer import MagnetometerTruth, rotation_record
from tak_thermo_ros.errors import FitError

RESULTS = Path(__file__).resolve().parent / 'results'
SAMPLES = 2000


def main(argv: list[str] | None = None) -> int:
    """Run the seeds, print the summary, write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', type=int, default=200)
    args = parser.parse_args(argv)
    truth = MagnetometerTruth()
    inverse = np.linalg.inv(truth.soft_matrix())
    inverse /= np.linalg.det(inverse) ** (1.0 / 3.0)
    centre = np.array(truth.hard_iron) + np.array(truth.offset)
    radius = float(np.linalg.norm(truth.earth_field))
    centre_se = truth.noise * math.sqrt(3.0 / SAMPLES)
    soft_se = truth.noise / radius * math.sqrt(15.0 / SAMPLES)
    centre_errors, soft_errors, refused = [], [], []
    for seed in range(args.seeds):
        record = rotation_record(truth, samples=SAMPLES, seed=seed)
        try:
            fit = fit_ellipsoid(record.mag)
        except FitError as err:
            refused.append(str(err))
            continue
        centre_errors.append(np.array(fit.hard_iron) - centre)
        soft_errors.append((np.array(fit.soft_iron).reshape(3, 3) - inverse).ravel())
    centre_errors, soft_errors = np.array(centre_errors), np.array(soft_errors)
    outcome = {'tumble': {
        'records': args.seeds, 'refused': len(refused),
        'centre_rms_error_ut': (np.sqrt(np.mean(centre_errors ** 2, axis=0)) * 1e6).tolist(),
        'centre_predicted_se_ut': centre_se * 1e6,
        'centre_max_abs_z': float(np.max(np.abs(centre_errors)) / centre_se),
        'soft_rms_error': float(np.sqrt(np.mean(soft_errors ** 2))),
        'soft_predicted_se_bound': soft_se,
        'soft_max_abs_z': float(np.max(np.abs(soft_errors)) / soft_se),
    }}
    for turn in ('yaw', 'cap'):
        reasons: dict[str, int] = {}
        accepted = 0
        for seed in range(args.seeds):
            try:
                fit_ellipsoid(rotation_record(truth, samples=SAMPLES, seed=seed, turn=turn).mag)
                accepted += 1
            except FitError as err:
                reason = 'sections' if 'sections' in str(err) else 'spread' if 'spreads' in str(err) else str(err)
                reasons[reason] = reasons.get(reason, 0) + 1
        outcome[turn] = {'records': args.seeds, 'accepted': accepted, 'refused_by': reasons}
    tumble = outcome['tumble']
    print(f'tumble: {tumble["refused"]} of {args.seeds} refused; centre RMS error '
          f'{" ".join(f"{v:.4f}" for v in tumble["centre_rms_error_ut"])} uT (predicted {centre_se * 1e6:.4f}), '
          f'largest |z| {tumble["centre_max_abs_z"]:.2f}; W RMS error {tumble["soft_rms_error"]:.2e} '
          f'(bound {soft_se:.2e}), largest |z| {tumble["soft_max_abs_z"]:.2f}')
    for turn in ('yaw', 'cap'):
        print(f'{turn}: {outcome[turn]["accepted"]} of {args.seeds} accepted; refused by {outcome[turn]["refused_by"]}')
    RESULTS.mkdir(exist_ok=True)
    write_text_atomic(RESULTS / 'mag_iron.json', json.dumps({'seeds': args.seeds, 'samples': SAMPLES,
                                                             'noise_t': truth.noise, **outcome}, indent=2) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
