"""Benchmark: the verdict judged against the sensor's noise model, over many seeds (issue 16).

Simulated driver runs on the rate table (about 1.7 h, 2 C/min ramps, 1 Hz) of a unit whose
sensors wander like a consumer MEMS part (the simulator's bias instability and random walk, the
values of ``test/core/diagnose/test_verdict.py``), each diagnosed against its true noise model
(``Scenario.noise_truth``, as ``--noise FILE`` gives it):

- **false alarms**: bias wander and no thermal effect, with that white noise and with ten times
  less, on both sensors: the share of verdicts other than ``none`` (target at most 5 %);
- **the small lag** (tau 300 s, 3e-5 rad/s per C on x and -3e-5 on z: a few deg/h after the
  base fit, below the per-sample floor at 5 Hz): the share of runs on which the gyroscope's
  verdict is ``thermal_lag`` (or its form held at zero on y, ``thermal_lag[xz]``: the lag is on
  x and z), and of those whose refit with it is then ``none``;
- **the large lag** (five times larger): the same.

Without a noise model (``--own-noise``; what ``tak_calib diagnose`` does with no ``--noise`` or
``--noise-run``: white noise and bias instability fitted to the run's own residual up to 30 s,
then the residual's Allan deviation judged beyond that), on the same runs:

- **bias instability alone** (no random walk): the share of ``none`` on both sensors;
- **with the random walk**: the verdicts, and the least rate random walk that the message says
  would explain the excess (``AllanCheck.walk_to_explain``) over the simulator's true one;
- **a supply-voltage drift** on the accelerometer: the share of ``unexplained``.

**Against a fitted model** (``--fitted``, issue 25): the same runs, each diagnosed against the
noise model fitted (``core/noise/fit.py``) to a simulated 3 h static run of the same unit at
20 C (another seed), as ``--noise-run`` gives it, instead of the true model.

Run: ``.venv/bin/python bench/bench_noise_verdicts.py [--seeds 20] [--own-noise | --fitted]``.
Writes ``bench/results/noise_verdicts.json`` (``noise_verdicts_own.json`` with ``--own-noise``,
``noise_verdicts_fitted.json`` with ``--fitted``).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
import sys
import time
from pathlib import Path

import numpy as np

from benchlib import machine

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))

from core.diagnose.test_verdict import ACCEL, GYRO, _diagnose, wandering_run  # noqa: E402

from tak_thermo_ros.core.diagnose import diagnose  # noqa: E402
from tak_thermo_ros.core.fit import fit_model  # noqa: E402
from tak_thermo_ros.core.noise.allan import allan_variance  # noqa: E402
from tak_thermo_ros.core.noise.fit import fit_noise  # noqa: E402
from tak_thermo_ros.core.noise.residual import RESIDUAL_LONGEST_TAU_S  # noqa: E402
from tak_thermo_ros.core.records.record import align  # noqa: E402
from tak_thermo_ros.core.simulation.imu import simulate  # noqa: E402

FITTED = False
"""``--fitted``: diagnose against the model fitted to a static run of the unit, not the truth."""


def static_model(scenario, sensor: str):
    """The noise model fitted to a 3 h static run of the unit at 20 C (another seed), as ``--noise-run`` gives it."""
    static = replace(scenario, plateaus_celsius=(20.0,), start_celsius=20.0, plateau_hours=3.0,
                     positions=((0.0, 0.0, 1.0),), table_rates=(), record_references=False, gyro_effects={},
                     effects={}, seed=scenario.seed + 5000)
    driver = simulate(static).driver
    values = driver.gyro if sensor == 'gyro' else driver.accel
    allan = allan_variance(values - values.mean(axis=0), scenario.sample_rate_hz, per_octave=2)
    return fit_noise(allan, source='static_run').model


def _judged(scenario, sensor: str, effects=()):
    """The diagnosis against the true model, or with ``--fitted`` against the static run's fitted model."""
    if not FITTED:
        return _diagnose(scenario, sensor, effects)
    samples = align(simulate(scenario).driver.channel(sensor))
    calibration = fit_model(samples, effects=effects).calibration
    return diagnose(calibration, samples, noise=static_model(scenario, sensor))


RESULTS = Path(__file__).resolve().parent / 'results'


def false_alarms(seeds: int, quiet: float) -> dict[str, object]:
    """Verdicts on runs with bias wander and nothing thermal missing, both sensors."""
    rows = []
    for seed in range(seeds):
        for sensor in ('gyro', 'accel'):
            result = _judged(wandering_run(seed=1000 + seed, quiet=quiet), sensor)
            rows.append({'seed': 1000 + seed, 'sensor': sensor, 'verdict': result.verdict})
            print(f'wander, white x{quiet:g}, seed {1000 + seed}, {sensor}: {result.verdict}', flush=True)
    alarms = sum(row['verdict'] != 'none' for row in rows)
    return {'runs': len(rows), 'alarms': alarms, 'rate': alarms / len(rows), 'rows': rows}


def detection(seeds: int, slope: float) -> dict[str, object]:
    """The gyroscope's verdict with a hidden lag, and the refit's."""
    rows = []
    for seed in range(seeds):
        scenario = wandering_run(seed=2000 + seed, slope=slope)
        first = _judged(scenario, 'gyro')
        lag = first.verdict in LAG_NAMES
        refit = _judged(scenario, 'gyro', effects=(first.verdict,)) if lag else None
        rows.append({'seed': 2000 + seed, 'verdict': first.verdict, 'refit': refit.verdict if refit else None})
        print(f'lag {slope:g}, seed {2000 + seed}: {first.verdict} -> {refit.verdict if refit else "-"}', flush=True)
    named = sum(row['verdict'] in LAG_NAMES for row in rows)
    held = sum(row['verdict'] == 'thermal_lag[xz]' for row in rows)
    closed = sum(row['refit'] == 'none' for row in rows)
    return {'runs': len(rows), 'named': named, 'named_held_on_y': held, 'refit_none': closed, 'rows': rows}


LAG_NAMES = ('thermal_lag', 'thermal_lag[xz]')
"""The lag named: on every axis, or held at zero on y, where the simulated unit has none."""


def own_noise(seeds: int) -> dict[str, object]:
    """Verdicts without a noise model: bias instability alone, with the walk, and a supply drift."""
    rows = []
    for seed in range(seeds):
        for walks in (False, True):
            for quiet in (1.0, 0.1):
                for sensor in ('gyro', 'accel'):
                    result = _diagnose(wandering_run(seed=1000 + seed, quiet=quiet, walks=walks), sensor,
                                       own_noise=True)
                    check = result.allan[0][1]
                    true_walk = (GYRO if sensor == 'gyro' else ACCEL)[2]
                    implied = check.walk_to_explain(RESIDUAL_LONGEST_TAU_S)
                    rows.append({'seed': 1000 + seed, 'walks': walks, 'quiet': quiet, 'sensor': sensor,
                                 'verdict': result.verdict, 'consistent': check.consistent,
                                 'walk_over_truth': (implied / true_walk).tolist()})
                    print(f'own noise, walk {walks}, white x{quiet:g}, seed {1000 + seed}, {sensor}: '
                          f'{result.verdict}; implied walk / true {" ".join(f"{v:.2f}" for v in implied / true_walk)}',
                          flush=True)
    supply = []
    for seed in range(seeds):
        result = _diagnose(replace(wandering_run(seed=2000 + seed), supply_voltage_drift=0.02), 'accel',
                           own_noise=True)
        supply.append({'seed': 2000 + seed, 'verdict': result.verdict})
        print(f'own noise, supply drift, seed {2000 + seed}: {result.verdict}', flush=True)
    alone = [row for row in rows if not row['walks']]
    walking = [row for row in rows if row['walks']]
    ratios = np.array([v for row in walking for v in row['walk_over_truth']])
    return {'bias_instability_alone': {'runs': len(alone), 'none': sum(r['verdict'] == 'none' for r in alone)},
            'with_walk': {'runs': len(walking), 'none': sum(r['verdict'] == 'none' for r in walking),
                          'unexplained': sum(r['verdict'] == 'unexplained' for r in walking),
                          'walk_over_truth_quartiles': np.percentile(ratios, [25, 50, 75]).tolist()},
            'supply_drift': {'runs': len(supply), 'unexplained': sum(r['verdict'] == 'unexplained' for r in supply)},
            'rows': rows, 'supply_rows': supply}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seeds', type=int, default=20)
    parser.add_argument('--own-noise', action='store_true', help='the runs without a noise model only')
    parser.add_argument('--fitted', action='store_true', help='against the model fitted to a static run of the unit')
    args = parser.parse_args()
    global FITTED
    FITTED = args.fitted
    start = time.perf_counter()
    if args.own_noise:
        found = own_noise(args.seeds)
        found.update(machine=machine(), seconds=time.perf_counter() - start)
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / 'noise_verdicts_own.json').write_text(json.dumps(found, indent=2) + '\n')
        alone, walking, supply = found['bias_instability_alone'], found['with_walk'], found['supply_drift']
        print(f'bias instability alone: none in {alone["none"]} of {alone["runs"]}; with the walk: none '
              f'{walking["none"]}, unexplained {walking["unexplained"]} of {walking["runs"]}, implied walk / true '
              f'quartiles {" ".join(f"{v:.2f}" for v in walking["walk_over_truth_quartiles"])}; supply drift: '
              f'unexplained in {supply["unexplained"]} of {supply["runs"]}')
        return 0
    result = {
        'machine': machine(),
        'false_alarms': {'consumer_white': false_alarms(args.seeds, 1.0),
                         'white_ten_times_lower': false_alarms(args.seeds, 0.1)},
        'small_lag': detection(args.seeds, 3e-5),
        'large_lag': detection(max(args.seeds // 2, 1), 1.5e-4),
    }
    result['seconds'] = time.perf_counter() - start
    RESULTS.mkdir(exist_ok=True)
    name = 'noise_verdicts_fitted.json' if args.fitted else 'noise_verdicts.json'
    (RESULTS / name).write_text(json.dumps(result, indent=2) + '\n')
    for case, found in result['false_alarms'].items():
        print(f'false alarms, {case}: {found["alarms"]} of {found["runs"]} ({100 * found["rate"]:.1f} %)')
    for case in ('small_lag', 'large_lag'):
        found = result[case]
        print(f'{case}: named in {found["named"]} of {found["runs"]} ({found["named_held_on_y"]} as thermal_lag[xz]), '
              f'refit none in {found["refit_none"]}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
