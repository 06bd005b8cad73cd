"""Benchmark: the verdict judged against the sensor's noise model, over many seeds (issue 16).

Simulated driver runs on the rate table (about 1.7 h, 2 C/min ramps, 1 Hz) of a unit whose
sensors wander like a consumer MEMS part (the simulator's bias instability and random walk, the
values of ``test/test_noise_verdicts.py``), each diagnosed against its true noise model
(``Scenario.noise_truth``, as ``--noise FILE`` gives it):

- **false alarms**: bias wander and no thermal effect, with that white noise and with ten times
  less, on both sensors: the share of verdicts other than ``none`` (target at most 5 %);
- **the small lag** (tau 300 s, 3e-5 rad/s per C on x and -3e-5 on z: a few deg/h after the
  base fit, below the per-sample floor at 5 Hz): the share of runs on which the gyroscope's
  verdict is ``thermal_lag``, and of those whose refit is then ``none``;
- **the large lag** (five times larger): the same.

Run: ``.venv/bin/python bench/bench_noise_verdicts.py [--seeds 20]``. Writes
``bench/results/noise_verdicts.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from benchlib import machine

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))

from test_noise_verdicts import _diagnose, wandering_run  # noqa: E402

RESULTS = Path(__file__).resolve().parent / 'results'


def false_alarms(seeds: int, quiet: float) -> dict[str, object]:
    """Verdicts on runs with bias wander and nothing thermal missing, both sensors."""
    rows = []
    for seed in range(seeds):
        for sensor in ('gyro', 'accel'):
            result = _diagnose(wandering_run(seed=1000 + seed, quiet=quiet), sensor)
            rows.append({'seed': 1000 + seed, 'sensor': sensor, 'verdict': result.verdict})
            print(f'wander, white x{quiet:g}, seed {1000 + seed}, {sensor}: {result.verdict}', flush=True)
    alarms = sum(row['verdict'] != 'none' for row in rows)
    return {'runs': len(rows), 'alarms': alarms, 'rate': alarms / len(rows), 'rows': rows}


def detection(seeds: int, slope: float) -> dict[str, object]:
    """The gyroscope's verdict with a hidden lag, and the refit's."""
    rows = []
    for seed in range(seeds):
        scenario = wandering_run(seed=2000 + seed, slope=slope)
        first = _diagnose(scenario, 'gyro')
        refit = _diagnose(scenario, 'gyro', effects=('thermal_lag',)) if first.verdict == 'thermal_lag' else None
        rows.append({'seed': 2000 + seed, 'verdict': first.verdict, 'refit': refit.verdict if refit else None})
        print(f'lag {slope:g}, seed {2000 + seed}: {first.verdict} -> {refit.verdict if refit else "-"}', flush=True)
    named = sum(row['verdict'] == 'thermal_lag' for row in rows)
    closed = sum(row['refit'] == 'none' for row in rows)
    return {'runs': len(rows), 'named': named, 'refit_none': closed, 'rows': rows}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seeds', type=int, default=20)
    args = parser.parse_args()
    start = time.perf_counter()
    result = {
        'machine': machine(),
        'false_alarms': {'consumer_white': false_alarms(args.seeds, 1.0),
                         'white_ten_times_lower': false_alarms(args.seeds, 0.1)},
        'small_lag': detection(args.seeds, 3e-5),
        'large_lag': detection(max(args.seeds // 2, 1), 1.5e-4),
    }
    result['seconds'] = time.perf_counter() - start
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / 'noise_verdicts.json').write_text(json.dumps(result, indent=2) + '\n')
    for case, found in result['false_alarms'].items():
        print(f'false alarms, {case}: {found["alarms"]} of {found["runs"]} ({100 * found["rate"]:.1f} %)')
    for case in ('small_lag', 'large_lag'):
        found = result[case]
        print(f'{case}: named in {found["named"]} of {found["runs"]}, refit none in {found["refit_none"]}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
