"""Effect library: correction throughput with each effect, and fit time per effect on a long run.

Prints the figures and writes bench/results/effects.json. ``--quick`` uses a shorter run.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.effects import LIBRARY, seconds_from_ns
from tak_thermo_ros.core.fit import fit_calibration, fit_model, residual_counts
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario

EXAMPLES = {
    'thermal_lag': {'tau_s': 1800.0, 'slope_z': 0.03},
    'hysteresis': {'width_codes': 60.0, 'amplitude_y': 4.0},
    'scale_nonlinearity': {'k2_x': 0.02},
    'cross_axis': {'c_xy': 0.5, 'c_zx': -0.4},
    'warmup': {'tau_s': 1200.0, 'amplitude_x': 15.0},
    'temperature_shape': {'knot_1': 8300.0, 'knot_2': 8500.0, 'slope_x_1': 0.04},
}


def _timed(function):
    wall, cpu = time.perf_counter(), time.process_time()
    value = function()
    return value, time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    """Run the benchmark."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--quick', action='store_true', help='a 3-hour run instead of 15 hours')
    args = parser.parse_args()
    scenario = Scenario(sample_rate_hz=5.0)
    if args.quick:
        scenario = replace(scenario, plateau_hours=0.5)
    results: dict = {'samples': 0, 'per_sample': {}, 'series': {}, 'fit': {}}

    truth = scenario.truth()
    samples = align(simulate(scenario).record)
    stamps = seconds_from_ns(samples.stamp_ns)
    results['samples'] = len(samples)
    rows = samples.counts[:50_000].tolist()
    codes = samples.temp_code[:50_000].tolist()
    stamp_list = stamps[:50_000].tolist()
    for name in ('none', *EXAMPLES, 'all'):
        effects = () if name == 'none' else tuple(
            LIBRARY[n](**EXAMPLES[n]) for n in (EXAMPLES if name == 'all' else (name,)))
        corrector = Corrector(replace(truth, effects=effects))
        correct = corrector.correct_sample

        def per_sample():
            for (x, y, z), code, stamp in zip(rows, codes, stamp_list):
                correct(x, y, z, code, stamp_s=stamp)
        _, wall, cpu = _timed(per_sample)
        _, series_wall, series_cpu = _timed(lambda: corrector.correct(samples.counts, samples.temp_code,
                                                                      stamp_s=stamps))
        results['per_sample'][name] = len(rows) / cpu
        results['series'][name] = series_cpu
        print(f'{name:18s} per sample {len(rows) / cpu:9.0f} samples/s (CPU)   series of {len(samples)}: '
              f'{series_cpu:.3f} s CPU')

    _, wall, cpu = _timed(lambda: fit_calibration(samples))
    results['fit']['base'] = {'wall_s': wall, 'cpu_s': cpu}
    print(f'fit base model: {cpu:.2f} s CPU ({wall:.2f} s wall)')
    for name in EXAMPLES:
        hidden = align(simulate(replace(scenario, effects={name: EXAMPLES[name]})).record)
        result, wall, cpu = _timed(lambda: fit_model(hidden, effects=[name]))
        base = fit_calibration(hidden)
        rms = [axis.residual_rms for axis in result.axes]
        base_rms = [axis.residual_rms for axis in base.axes]
        _, residual_wall, residual_cpu = _timed(lambda: residual_counts(result.calibration, hidden))
        results['fit'][name] = {'wall_s': wall, 'cpu_s': cpu, 'residual_rms': rms, 'base_residual_rms': base_rms,
                                'residual_cpu_s': residual_cpu,
                                'fitted': result.calibration.effects[0].values}
        print(f'fit + {name:18s}: {cpu:6.2f} s CPU ({wall:.2f} s wall); residual RMS counts base '
              f'{"/".join(f"{v:.2f}" for v in base_rms)} -> {"/".join(f"{v:.2f}" for v in rms)}')
    out = Path(__file__).parent / 'results' / 'effects.json'
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2) + '\n')
    print(f'wrote {out}')


if __name__ == '__main__':
    main()
