"""Benchmark: ``tak_calib fit`` of a month of one unit's everyday records against rosbags reading them.

Target (issue 32): a month of one unit, 30 records of 30 minutes at 200 Hz (10.8 M Imu messages),
fits in less CPU time than rosbags needs to read the bags, in bounded memory. The records: the
everyday simulator's (``docs/scenarios/everyday_month.yaml`` with 30 records at 200 Hz; rests
within 3 deg of level, motions with vibration, a turn-on offset per power-up, coloured noise),
mcap bags written once into the work directory. Measured, each in its own process (CPU = user +
system, peak RSS from ``wait4``): rosbags' own message-by-message deserialisation of every bag
(``bench_fit.BASELINE_SCRIPT``'s loop over the records), then ``tak_calib fit DIR``; and the fit
of the first two thirds of the records, to show the peak memory does not grow with the pool (each
record is read alone; the pool keeps at most 2 M rest samples and 0.2 M motion samples, which
twenty such records fill already).

Run: ``nice -n 10 .venv/bin/python bench/bench_pool.py [--records 30] [--minutes 30] [--rate 200]
[--workdir /tmp/tak_bench]``; writes ``bench/results/pool.json``.

``--tiny`` (issue 44): the pool's cost against its number of records. Months of 30, 100 and 300
tiny records (0.3 min at 10 Hz, one or two rests each: a vehicle that flies several times a day)
are fitted, each month in its own process (``--repeat`` times, the least CPU kept: a busy machine
only adds); the target: 300 records in at most 3.5x the CPU of 100 (linear: 3x; the REML and the
solves were cubic in the records). Writes ``bench/results/pool_tiny.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fit import BASELINE_SCRIPT, run_child  # noqa: E402
from benchlib import machine, tak_calib_command  # noqa: E402
from tak_thermo_ros.formats.calibration_file import write_text_atomic  # noqa: E402

RESULTS = Path(__file__).resolve().parent / 'results'


def build(directory: Path, records: int, minutes: float, rate: float) -> None:
    """The month's bags, written once (``tak_calib simulate`` with an everyday scenario)."""
    if directory.is_dir() and len(list(directory.iterdir())) == records:
        return
    directory.parent.mkdir(parents=True, exist_ok=True)
    scenario = directory.parent / f'{directory.name}.yaml'
    scenario.write_text(f'sample_rate_hz: {rate}\ntemp_code_every: 20\nseed: 1\n'
                        f'everyday: {{records: {records}, record_minutes: {minutes}}}\n')
    subprocess.run([*tak_calib_command(), 'simulate', str(directory), '--scenario', str(scenario), '--force'],
                   check=True)


TINY_COUNTS = (30, 100, 300)
TINY_MINUTES = 0.3
TINY_RATE = 10.0
LINEAR_BOUND = 3.5
"""300 tiny records fit in at most this many times the CPU of 100 (linear: 3)."""


def tiny(args: argparse.Namespace) -> int:
    """Fit months of 30, 100 and 300 tiny records; write ``pool_tiny.json``; 0 when 300 take <= 3.5x 100's CPU."""
    fits = {}
    for count in TINY_COUNTS:
        month = args.workdir / f'pool_tiny_{count}'
        build(month, count, TINY_MINUTES, TINY_RATE)
        runs = []
        for _ in range(args.repeat):
            wall, cpu, rss, out = run_child([*tak_calib_command(), 'fit', str(month), '-o',
                                             str(args.workdir / f'pool_tiny_{count}.yaml'), '--force', '--no-progress'])
            runs.append({'process_wall_s': wall, 'process_cpu_s': cpu, 'peak_rss_bytes': rss,
                         'load_average_1min': os.getloadavg()[0]})
        best = min(runs, key=lambda run: run['process_cpu_s'])
        fits[str(count)] = {**best, 'runs': runs,
                            'lines': [line for line in out.splitlines() if line.startswith('pool:')]}
        print(f'tak_calib fit of {count} tiny records: {best["process_cpu_s"]:.1f} s CPU '
              f'({best["process_wall_s"]:.1f} s wall), {best["peak_rss_bytes"] / 2 ** 20:.0f} MiB peak', flush=True)
    ratio = fits['300']['process_cpu_s'] / fits['100']['process_cpu_s']
    wall_ratio = fits['300']['process_wall_s'] / fits['100']['process_wall_s']
    result = {'machine': machine(), 'minutes': TINY_MINUTES, 'rate_hz': TINY_RATE, 'repeat': args.repeat,
              'fit': fits, 'cpu_300_over_100': ratio, 'wall_300_over_100': wall_ratio, 'bound': LINEAR_BOUND}
    write_text_atomic(args.output or RESULTS / 'pool_tiny.json', json.dumps(result, indent=1) + '\n')
    print(f'300 / 100 records: {ratio:.2f}x CPU, {wall_ratio:.2f}x wall (linear: 3x; bound {LINEAR_BOUND:g}x)')
    return 0 if ratio <= LINEAR_BOUND else 3


def main(argv: list[str] | None = None) -> int:
    """Build (or reuse) the month, time rosbags' read and the fits, write ``pool.json``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--workdir', type=Path, default=Path('/tmp/tak_bench'))
    parser.add_argument('--records', type=int, default=30)
    parser.add_argument('--minutes', type=float, default=30.0)
    parser.add_argument('--rate', type=float, default=200.0)
    parser.add_argument('--output', type=Path, default=None)
    parser.add_argument('--tiny', action='store_true', help='30, 100 and 300 tiny records: the cost per record')
    parser.add_argument('--repeat', type=int, default=2, help='--tiny: fits per month, the least CPU kept')
    args = parser.parse_args(argv)
    if args.tiny:
        return tiny(args)
    args.output = args.output or RESULTS / 'pool.json'
    month = args.workdir / f'pool_{args.records}x{args.minutes:g}min_{args.rate:g}hz'
    build(month, args.records, args.minutes, args.rate)
    bags = sorted(str(path) for path in month.iterdir())
    wall, cpu, rss, out = run_child([sys.executable, '-c', BASELINE_SCRIPT, *bags])
    figures = json.loads(out)
    baseline = {'process_wall_s': wall, 'process_cpu_s': cpu, 'peak_rss_bytes': rss, **figures}
    print(f'rosbags reads {figures["messages"]:,} messages of {len(bags)} bags: {cpu:.1f} s CPU, '
          f'{rss / 2 ** 20:.0f} MiB', flush=True)
    fits = {}
    for label, given in (('two_thirds', bags[:max(2, 2 * len(bags) // 3)]), ('month', [str(month)])):
        params = args.workdir / f'pool_{label}.yaml'
        wall, cpu, rss, out = run_child([*tak_calib_command(), 'fit', *given, '-o', str(params), '--force',
                                         '--no-progress'])
        fits[label] = {'records': len(bags) if label == 'month' else len(given), 'process_wall_s': wall,
                       'process_cpu_s': cpu, 'peak_rss_bytes': rss,
                       'lines': [line for line in out.splitlines() if 'turn-on repeatability' in line
                                 or line.startswith('pool:') or 'offset order' in line]}
        print(f'tak_calib fit of {fits[label]["records"]} records: {cpu:.1f} s CPU ({wall:.1f} s wall), '
              f'{rss / 2 ** 20:.0f} MiB peak', flush=True)
    result = {'machine': machine(), 'records': args.records, 'minutes': args.minutes, 'rate_hz': args.rate,
              'rosbags_read': baseline, 'fit': fits,
              'fit_cpu_over_rosbags_cpu': fits['month']['process_cpu_s'] / baseline['process_cpu_s'],
              'peak_rss_month_over_two_thirds': (fits['month']['peak_rss_bytes']
                                                 / fits['two_thirds']['peak_rss_bytes'])}
    write_text_atomic(args.output, json.dumps(result, indent=1) + '\n')
    print(f'fit / rosbags read CPU: {result["fit_cpu_over_rosbags_cpu"]:.2f}; peak memory month / two thirds: '
          f'{result["peak_rss_month_over_two_thirds"]:.2f}')
    bounded = result['peak_rss_month_over_two_thirds'] < 1.2
    return 0 if result['fit_cpu_over_rosbags_cpu'] < 1.0 and bounded else 3


if __name__ == '__main__':
    sys.exit(main())
