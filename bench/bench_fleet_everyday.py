"""Benchmark: ``fit-fleet --everyday`` at scale: CPU per unit against ``fit`` of its records alone, memory per worker.

Target (issue 40): 100 units x 30 records x 30 min at 200 Hz on a local Dask cluster, the CPU time per
unit no more than ``tak_calib fit`` of its records alone, memory bounded per worker. That fleet's bags
would fill 390 GB here (131 MB a record) and take this shared 2-core machine days, so it is measured at
full size per unit and extrapolated (said so in the output):

1. one unit at full size (``--records`` x ``--minutes`` at ``--rate``, 10.8 M messages by default):
   ``tak_calib fit DIR`` in its own process (CPU = user + system, peak RSS from ``wait4``);
2. the fleet's work for that unit: the first map in its own process (the pool read and fitted at the
   fleet's orders, reduced to its statistics), the second (its statistics solved with the prior's rows)
   timed here; beside, ``tak_calib fit DIR --prior`` in its own process (what a user's command costs);
3. the reduce for ``--fleet-units`` units (100): the unit's statistics copied with each copy's curve
   moved by a draw of ten times its own errors, the prior estimated from them (timed);
4. ``fit-fleet --everyday`` end to end on Dask (2 workers) over ``--dask-units`` unit folders that each
   link the one unit's records (identical units: their prior degenerate, the work the same): the CPU per
   unit in the workers, the peak memory of a worker, the wall time;
5. the extrapolation: 100 units' wall time on 2 workers = 100 x the CPU per unit / 2 + the reduce.

Run: ``nice -n 10 .venv/bin/python bench/bench_fleet_everyday.py [--records 30] [--minutes 30] [--rate 200]
[--workdir /tmp/tak_bench_fleet]``; writes ``bench/results/fleet_everyday.json``.
"""

from __future__ import annotations

import argparse
import os
import pickle
import re
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fit import run_child  # noqa: E402
from benchlib import machine, tak_calib_command  # noqa: E402

from tak_thermo_ros.formats.files import write_json  # noqa: E402

RESULTS = Path(__file__).resolve().parent / 'results'
STATISTICS_SCRIPT = '''
import pickle, sys
from tak_thermo_ros.formats.bag import Topics
from tak_thermo_ros.passes.fleet_prior import unit_statistics_task
from tak_thermo_ros.passes.run import FitSettings, StreamOptions
outcome = unit_statistics_task('unit00', sys.argv[1], FitSettings(effects={}), StreamOptions(Topics(), progress=False))
assert not outcome.error, outcome.error
with open(sys.argv[2], 'wb') as out:
    pickle.dump(outcome, out)
'''


def build(directory: Path, records: int, minutes: float, rate: float) -> Path:
    """One unit's month at full size, written once (:func:`bench_pool.build`: ``tak_calib simulate``)."""
    from bench_pool import build as build_month
    build_month(directory, records, minutes, rate)
    return directory


def copies(statistics, count: int, seed: int = 0) -> list:
    """``count`` units like ``statistics``, each curve moved by ten times its own errors (the reduce's load)."""
    from tak_thermo_ros.core.fit.prior_fit import UnitStatistics
    rng = np.random.default_rng(seed)
    out = []
    for index in range(count):
        information = {}
        for sensor, info in statistics.information.items():
            _, covariance = info.estimate()
            errors = np.sqrt(np.where(np.isfinite(np.diag(covariance)), np.diag(covariance), 0.0))
            shift = 10.0 * errors * rng.standard_normal(len(errors))
            normal = info.normal.copy()
            normal[:-1, -1] += info.hessian @ shift
            normal[-1, :-1] = normal[:-1, -1]
            information[sensor] = replace(info, normal=normal)
        out.append(UnitStatistics(f'unit{index:03d}', statistics.records, information, statistics.turn_on))
    return out


def main(argv: list[str] | None = None) -> int:
    """Measure, extrapolate, print and write ``fleet_everyday.json``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--workdir', type=Path, default=Path('/tmp/tak_bench_fleet'))
    parser.add_argument('--records', type=int, default=30)
    parser.add_argument('--minutes', type=float, default=30.0)
    parser.add_argument('--rate', type=float, default=200.0)
    parser.add_argument('--fleet-units', type=int, default=100)
    parser.add_argument('--dask-units', type=int, default=4)
    parser.add_argument('--repeat', type=int, default=3, help='fit alone and the first map, alternated, medians')
    parser.add_argument('--output', type=Path, default=RESULTS / 'fleet_everyday.json')
    args = parser.parse_args(argv)
    from tak_thermo_ros.core.fit.prior_fit import fleet_from_units
    from tak_thermo_ros.formats.prior_file import save_prior
    # one BLAS thread in every child, as tak_calib and the Dask workers run (threads spinning on a loaded
    # 2-core machine would be counted as CPU time)
    os.environ['OPENBLAS_NUM_THREADS'] = '1'
    work = args.workdir
    unit = build(work / f'unit_{args.records}x{args.minutes:g}min_{args.rate:g}hz', args.records, args.minutes,
                 args.rate)
    result: dict = {'machine': machine(), 'records': args.records, 'minutes': args.minutes, 'rate_hz': args.rate}
    stats_path = work / 'statistics.pickle'
    runs: dict[str, list] = {'fit_alone': [], 'statistics': []}
    for _ in range(args.repeat):  # alternated: the machine's load moves between them alike
        for label, command in (('fit_alone', [*tak_calib_command(), 'fit', str(unit), '-o', str(work / 'alone.yaml'),
                                              '--force', '--no-progress']),
                               ('statistics', [sys.executable, '-c', STATISTICS_SCRIPT, str(unit), str(stats_path)])):
            wall, cpu, rss, _ = run_child(command)
            runs[label].append({'cpu_s': cpu, 'wall_s': wall, 'peak_rss_bytes': rss})
            print(f'{label}: {cpu:.1f} s CPU, {rss / 2 ** 20:.0f} MiB', flush=True)
    for label, values in runs.items():
        result[label] = {'cpu_s': float(np.median([v['cpu_s'] for v in values])),
                         'peak_rss_bytes': max(v['peak_rss_bytes'] for v in values), 'runs': values}
    print(f'fit of one unit ({args.records} records): {result["fit_alone"]["cpu_s"]:.1f} s CPU (median of '
          f'{args.repeat}); the unit\'s statistics (first map): {result["statistics"]["cpu_s"]:.1f} s', flush=True)
    with open(stats_path, 'rb') as source:
        outcome = pickle.load(source)
    statistics = outcome.statistics
    units = copies(statistics, args.fleet_units)
    start = time.process_time()
    prior = fleet_from_units(units, bias_order=3, scale_order=2)
    reduce_s = time.process_time() - start
    prior_path = work / 'prior.yaml'
    save_prior(prior_path, prior)
    result['reduce'] = {'units': args.fleet_units, 'cpu_s': reduce_s}
    print(f'the prior from {args.fleet_units} units\' statistics (reduce): {reduce_s:.1f} s CPU', flush=True)
    wall, cpu, rss, _ = run_child([*tak_calib_command(), 'fit', str(unit), '--prior', str(prior_path), '-o',
                                   str(work / 'with_prior.yaml'), '--force', '--no-progress'])
    result['fit_with_prior'] = {'cpu_s': cpu, 'wall_s': wall, 'peak_rss_bytes': rss}
    print(f'fit --prior of the unit (a user\'s command): {cpu:.1f} s CPU, {rss / 2 ** 20:.0f} MiB', flush=True)
    from tak_thermo_ros.core.fit.prior_fit import unit_with_prior
    start = time.process_time()
    for _ in range(10):
        unit_with_prior(outcome.unit_calibration, statistics, prior)
    result['second_map_cpu_s'] = (time.process_time() - start) / 10
    print(f'the unit solved with the prior (second map): {result["second_map_cpu_s"]:.3f} s CPU', flush=True)
    per_unit = result['statistics']['cpu_s'] + result['second_map_cpu_s']
    result['fleet_cpu_per_unit_s'] = per_unit
    result['fleet_over_fit_alone'] = per_unit / result['fit_alone']['cpu_s']
    fleet_dir = work / 'dask_fleet'
    shutil.rmtree(fleet_dir, ignore_errors=True)
    fleet_dir.mkdir(parents=True)
    for index in range(args.dask_units):
        (fleet_dir / f'unit{index:02d}').mkdir()
        for record in sorted(unit.iterdir()):
            (fleet_dir / f'unit{index:02d}' / record.name).symlink_to(record)
    out = work / 'dask_out'
    wall, cpu, rss, text = run_child([*tak_calib_command(), 'fit-fleet', '--everyday', str(fleet_dir), '-o', str(out),
                                      '--workers', '2', '--force'])
    found = re.search(r'workers: ([\d.]+) s CPU per unit, at most (\d+) MiB each', text)
    dask = {'units': args.dask_units, 'wall_s': wall, 'client_cpu_s': cpu, 'client_peak_rss_bytes': rss,
            'worker_cpu_per_unit_s': float(found.group(1)) if found else None,
            'worker_peak_mib': int(found.group(2)) if found else None}
    result['dask'] = dask
    print(f'fit-fleet --everyday of {args.dask_units} units on 2 workers: {wall:.0f} s wall, '
          f'{dask["worker_cpu_per_unit_s"]} s CPU per unit in the workers, at most {dask["worker_peak_mib"]} MiB a '
          f'worker', flush=True)
    measured = dask['worker_cpu_per_unit_s'] or per_unit
    result['extrapolated_100_units_wall_s_on_2_workers'] = 100 * measured / 2 + reduce_s
    result['note'] = ('measured per unit at full size; the 100-unit wall time is extrapolated (100 x CPU per unit / 2 '
                      'workers + the reduce measured on 100 units), not run: its bags would fill 390 GB here')
    write_json(args.output, result)
    print(f'CPU per unit: fleet {per_unit:.1f} s (the two maps) vs fit alone '
          f'{result["fit_alone"]["cpu_s"]:.1f} s: {result["fleet_over_fit_alone"]:.2f}; 100 units on 2 workers: '
          f'about {result["extrapolated_100_units_wall_s_on_2_workers"] / 3600:.1f} h (extrapolated)')
    return 0 if result['fleet_over_fit_alone'] <= 1.0 else 3


if __name__ == '__main__':
    sys.exit(main())
