"""A magnetometer turned while it warms: the iron and the thermal drift from that one record, over many seeds.

For each seed, a simulated unit (the simulator's default magnetometer: 0.2 uT noise, 1.9-3.8 uT
of offset drift and 2-3e-4 per C of scale drift over 5..35 C, hard and soft iron) is turned
through every orientation while it warms from 12 to 38 C (2000 samples), fitted by
:func:`~tak_thermo_ros.core.magnetometer.rotation.fit_rotation`, and a second record of the same
unit (warming from 15 to 35 C, other orientations) is corrected. Scored against the simulated
truth: the field error per axis after the one isotropic factor no rotation record can see, over
the noise; the direction error over the noise's (``sqrt(2) sigma / |B|``); ``|B|``'s spread over
the noise. Beside it, the ellipsoid of the same record without its temperature (the drift left
in), and a unit never flipped (turned within 40 deg of upright): refused, in how many seeds.

Run: ``.venv/bin/python bench/bench_rotation.py [--seeds 20]``; writes ``bench/results/rotation.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from benchlib import machine

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = 2000


def held_temperature(record) -> np.ndarray:
    from tak_thermo_ros.core.records.record import hold_last_index
    return record.temperature[np.maximum(hold_last_index(record.temp_stamp_ns, record.mag_stamp_ns), 0)]


def scores(mag, record, truth_field, noise: float) -> dict[str, float]:
    from tak_thermo_ros.core.magnetometer.rotation import corrected_field
    corrected = corrected_field(mag, record.mag, held_temperature(record))
    factor = float(np.sum(corrected * truth_field) / np.sum(truth_field * truth_field))
    error = corrected / factor - truth_field
    cosine = np.sum(corrected * truth_field, axis=1) / np.linalg.norm(corrected, axis=1) / np.linalg.norm(
        truth_field, axis=1)
    direction = float(np.sqrt(np.mean(np.arccos(np.clip(cosine, -1.0, 1.0)) ** 2)))
    magnitude = float(np.linalg.norm(truth_field, axis=1).mean())
    return {'field_error_over_noise': float(np.max(np.sqrt(np.mean(error ** 2, axis=0))) / noise),
            'direction_over_noise': direction / (math.sqrt(2.0) * noise / magnitude),
            'magnitude_spread_over_noise': float(np.linalg.norm(corrected, axis=1).std()) / noise}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', type=int, default=20)
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    from tak_thermo_ros.core.magnetometer.rotation import fit_rotation
    from tak_thermo_ros.core.simulation.magnetometer import MagnetometerTruth, rotation_record, rotation_truth
    from tak_thermo_ros.errors import FitError
    truth = MagnetometerTruth()
    joint, blind, seconds, refused = [], [], [], 0
    for seed in range(args.seeds):
        first = rotation_record(truth, samples=SAMPLES, seed=2 * seed, temperature_celsius=12.0, warm_to_celsius=38.0)
        second = rotation_record(truth, samples=SAMPLES, seed=2 * seed + 1, temperature_celsius=15.0,
                                 warm_to_celsius=35.0)
        field = rotation_truth(truth, samples=SAMPLES, seed=2 * seed + 1)
        start = time.process_time()
        fitted = fit_rotation(first.mag, held_temperature(first))
        seconds.append(time.process_time() - start)
        joint.append(scores(fitted.calibration, second, field, truth.noise))
        blind.append(scores(fit_rotation(first.mag, None).calibration, second, field, truth.noise))
        cap = rotation_record(truth, samples=SAMPLES, seed=1000 + seed, turn='cap')
        try:
            fit_rotation(cap.mag, held_temperature(cap))
        except FitError:
            refused += 1

    def summary(rows: list[dict[str, float]]) -> dict[str, dict[str, float]]:
        return {key: {'median': float(np.median([r[key] for r in rows])), 'max': float(np.max([r[key] for r in rows]))}
                for key in rows[0]}
    result = {'machine': machine(), 'seeds': args.seeds, 'samples_per_record': SAMPLES,
              'joint_fit_second_record': summary(joint), 'ellipsoid_without_temperature_second_record': summary(blind),
              'never_flipped_refused': f'{refused} of {args.seeds}',
              'fit_cpu_seconds_median': float(np.median(seconds))}
    (ROOT / 'bench' / 'results').mkdir(parents=True, exist_ok=True)
    (ROOT / 'bench' / 'results' / 'rotation.json').write_text(json.dumps(result, indent=2) + '\n')
    print(json.dumps(result, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
