"""Benchmark: ``tak_calib fit`` on a 15-hour run at 100 Hz against rosbags alone.

Targets (issue 2): the fit, end to end as the user runs it, takes no more than 3x the wall
time rosbags alone needs to deserialise every message of the same bag, measured in the same
run; its peak memory stays under 2 GB.

The bag (5.4 million counts messages by default) is simulated once and cached under
``--workdir``. Both sides run in their own subprocess, so that each one's peak resident set
(``wait4`` rusage ``ru_maxrss``) is its own and the page cache is equally warm for both:

- baseline: ``rosbags.rosbag2.Reader`` + ``typestore.deserialize_cdr`` on every message of
  every connection, nothing else (timed inside the subprocess, interpreter start excluded);
- fit: ``tak_calib fit BAG -o PARAMS --no-progress`` (timed from outside, interpreter start,
  imports and writing the file included).

Run: ``.venv/bin/python bench/bench_fit.py [--repeat 3] [--storage mcap|sqlite3]``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


from benchlib import machine, stretched, tak_calib_command
from tak_thermo_ros.formats.calibration_file import write_text_atomic
from tak_thermo_ros.core.simulation.scenario import Scenario

RESULTS = Path(__file__).resolve().parent / 'results'
TARGET_MISSED = 3
"""Exit status when a target is missed (bench/run_all.py); 0 when all hold."""
WALL_RATIO_TARGET = 3.0
MEMORY_TARGET_BYTES = 2 * 1024 ** 3

BASELINE_SCRIPT = """
import json, sys, time
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
typestore = get_typestore(Stores.ROS2_JAZZY)
deserialize = typestore.deserialize_cdr
start = time.perf_counter()
messages = 0
for path in sys.argv[1:]:
    with Reader(path) as reader:
        for connection, _, raw in reader.messages(connections=reader.connections):
            deserialize(raw, connection.msgtype)
            messages += 1
print(json.dumps({'seconds': time.perf_counter() - start, 'messages': messages}))
"""
"""rosbags alone over the bags given as arguments (one, or a month's): ``{"seconds", "messages"}`` as JSON."""


def bench_scenario(hours: float, rate_hz: float) -> Scenario:
    """The default chamber protocol stretched to ``hours`` at ``rate_hz`` counts messages."""
    return stretched(Scenario(sample_rate_hz=rate_hz, temp_code_every=10), hours)


def bag_path(workdir: Path, hours: float, rate_hz: float, storage: str) -> Path:
    """Where the bench bag of these settings is cached."""
    return workdir / f'fit_{hours:g}h_{rate_hz:g}hz_{storage}'


def build_bag(workdir: Path, hours: float, rate_hz: float, storage: str) -> Path:
    """Simulate and write the bench bag once; later runs reuse it (the write is atomic)."""
    bag = bag_path(workdir, hours, rate_hz, storage)
    if bag.exists():
        return bag
    from tak_thermo_ros.formats.bag import write_record
    from tak_thermo_ros.core.simulation.imu import simulate
    workdir.mkdir(parents=True, exist_ok=True)
    scenario = bench_scenario(hours, rate_hz)
    start = time.perf_counter()
    run = simulate(scenario)
    print(f'bag: simulated {len(run.record.counts_stamp_ns)} counts messages '
          f'({scenario.duration_s() / 3600.0:g} h at {rate_hz:g} Hz) in {time.perf_counter() - start:.1f} s')
    start = time.perf_counter()
    write_record(bag, run.record, storage=storage)
    print(f'bag: wrote {bag} in {time.perf_counter() - start:.1f} s')
    return bag


def run_child(command: list[str]) -> tuple[float, float, int, str]:
    """Run one subprocess: its wall seconds, CPU seconds (user + system), own peak RSS (bytes), stdout."""
    with tempfile.TemporaryFile() as stderr:
        start = time.perf_counter()
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=stderr)
        stdout = process.stdout.read()  # type: ignore[union-attr]
        # wait4, not wait: the rusage of this one child, not the maximum over all children.
        _, status, usage = os.wait4(process.pid, 0)
        wall = time.perf_counter() - start
        process.returncode = os.waitstatus_to_exitcode(status)
        process.stdout.close()  # type: ignore[union-attr]
        if process.returncode != 0:
            stderr.seek(0)
            msg = f'{" ".join(command)} failed ({process.returncode}):\n{stderr.read().decode(errors="replace")}'
            raise SystemExit(msg)
    # Linux reports ru_maxrss in KiB.
    return wall, usage.ru_utime + usage.ru_stime, int(usage.ru_maxrss) * 1024, stdout.decode()


def main(argv: list[str] | None = None) -> int:
    """Build (or reuse) the bag, time baseline and fit, print and write ``fit.json``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--workdir', type=Path, default=Path('/tmp/tak_bench'), help='bag cache directory')
    parser.add_argument('--hours', type=float, default=15.0, help='run length (default 15)')
    parser.add_argument('--rate', type=float, default=100.0, help='counts messages per second (default 100)')
    parser.add_argument('--storage', choices=['mcap', 'sqlite3'], default='mcap')
    parser.add_argument('--repeat', type=int, default=1, help='baseline/fit pairs to run; medians reported')
    parser.add_argument('--output', type=Path, default=None,
                        help='JSON output (default bench/results/fit.json, fit_sqlite3.json for sqlite3)')
    parser.add_argument('--build-only', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    output = args.output or RESULTS / ('fit.json' if args.storage == 'mcap' else f'fit_{args.storage}.json')

    if args.build_only:
        build_bag(args.workdir, args.hours, args.rate, args.storage)
        return 0
    # The bag is built in a child process: a process's peak RSS includes the peak of the
    # parent it was forked from (Linux carries the old memory map's high-water mark through
    # exec), so this process must stay small for the children's figures to be their own.
    load_start = os.getloadavg()
    bag = bag_path(args.workdir, args.hours, args.rate, args.storage)
    if not bag.exists():
        subprocess.run([sys.executable, __file__, '--build-only', '--workdir', str(args.workdir),
                        '--hours', repr(args.hours), '--rate', repr(args.rate), '--storage', args.storage],
                       check=True)
    else:
        print(f'bag: reusing {bag}')
    params = args.workdir / 'bench_fit_params.yaml'
    baseline_runs, fit_runs = [], []
    messages = 0
    for attempt in range(1, args.repeat + 1):
        wall, cpu, rss, out = run_child([sys.executable, '-c', BASELINE_SCRIPT, str(bag)])
        figures = json.loads(out)
        messages = figures['messages']
        baseline_runs.append({'seconds': figures['seconds'], 'process_wall_s': wall, 'process_cpu_s': cpu,
                              'peak_rss_bytes': rss})
        params.unlink(missing_ok=True)
        wall, cpu, rss, out = run_child([*tak_calib_command(), 'fit', str(bag), '-o', str(params), '--no-progress'])
        if not params.exists():
            raise SystemExit(f'tak_calib fit wrote no {params}:\n{out}')
        fit_runs.append({'seconds': wall, 'process_cpu_s': cpu, 'peak_rss_bytes': rss})
        print(f'run {attempt}/{args.repeat}: rosbags deserialise {baseline_runs[-1]["seconds"]:.2f} s '
              f'(process {baseline_runs[-1]["process_wall_s"]:.2f} s, '
              f'{baseline_runs[-1]["peak_rss_bytes"] / 2**20:.0f} MiB); '
              f'tak_calib fit {wall:.2f} s ({rss / 2**20:.0f} MiB)')
    fit_summary = out.strip().splitlines()

    baseline_s = statistics.median(r['seconds'] for r in baseline_runs)
    fit_s = statistics.median(r['seconds'] for r in fit_runs)
    peak = max(r['peak_rss_bytes'] for r in fit_runs)
    # Each fit is held against the baseline run just before it (the machine's load drifts).
    pair_ratios = [f['seconds'] / b['seconds'] for b, f in zip(baseline_runs, fit_runs)]
    ratio = statistics.median(pair_ratios)
    # CPU time (whole processes) is far less sensitive to other load on the machine: a cross-check.
    cpu_ratio = statistics.median(f['process_cpu_s'] / b['process_cpu_s'] for b, f in zip(baseline_runs, fit_runs))
    document = {
        'benchmark': 'fit',
        'bag': {'path': str(bag), 'storage': args.storage, 'hours': args.hours, 'rate_hz': args.rate,
                'messages': messages, 'bytes': sum(f.stat().st_size for f in bag.rglob('*') if f.is_file())},
        'machine': {**machine(), 'load_average_start': load_start, 'load_average_end': os.getloadavg()},
        'repeat': args.repeat,
        'baseline_rosbags_deserialise_s': baseline_s,
        'fit_wall_s': fit_s,
        'wall_ratio': ratio,
        'wall_ratio_per_run': pair_ratios,
        'cpu_ratio': cpu_ratio,
        'wall_ratio_target': WALL_RATIO_TARGET,
        'wall_ratio_holds': ratio <= WALL_RATIO_TARGET,
        'fit_peak_rss_bytes': peak,
        'memory_target_bytes': MEMORY_TARGET_BYTES,
        'memory_holds': peak < MEMORY_TARGET_BYTES,
        'bench_process_peak_rss_bytes': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
        'runs': {'baseline': baseline_runs, 'fit': fit_runs},
        'fit_output': fit_summary,
    }
    output.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(output, json.dumps(document, indent=2) + '\n')
    print(f'bag: {messages} messages ({args.storage}, {document["bag"]["bytes"] / 2**20:.0f} MiB)')
    print(f'rosbags alone, deserialise every message: {baseline_s:.2f} s (median of {args.repeat})')
    print(f'tak_calib fit, end to end:                {fit_s:.2f} s (median of {args.repeat})')
    print(f'fit / rosbags, per run:                   {", ".join(f"{r:.2f}x" for r in pair_ratios)}; '
          f'median {ratio:.2f}x  '
          f'(target <= {WALL_RATIO_TARGET:g}x: {"holds" if ratio <= WALL_RATIO_TARGET else "MISSED"})')
    print(f'cross-check, CPU time of the processes:   {cpu_ratio:.2f}x (median)')
    print(f'tak_calib fit, peak memory:               {peak / 2**20:.0f} MiB  '
          f'(target < 2048 MiB: {"holds" if peak < MEMORY_TARGET_BYTES else "MISSED"})')
    print(f'wrote {output}')
    return 0 if ratio <= WALL_RATIO_TARGET and peak < MEMORY_TARGET_BYTES else TARGET_MISSED


if __name__ == '__main__':
    sys.exit(main())
