"""Benchmark: ``tak_calib fit-fleet`` throughput, units per minute with 1 and 2 local workers.

A batch of simulated units (default 8; the default unit with a production spread of its
offsets, seeded) is written once under ``--workdir``. Then ``tak_calib fit-fleet BAG... -o OUT
--workers N --validate ...`` runs as the user runs it, once per worker count (``--repeat``
times each, median reported), timed from outside: interpreter start, Dask cluster start and
stop, every unit's fit + diagnose + validate, ``fleet.json`` and ``fleet.html`` included. The
per-unit seconds (inside the workers) come from ``fleet.json``.

No target: the figures are reported (speed-up of 2 workers over 1 on this machine, and the
fixed cost of the cluster, which a batch of a few units does not amortise).

Run: ``.venv/bin/python bench/bench_fleet.py [--units 8] [--hours 6] [--rate 2] [--repeat 1]``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchlib import machine, stretched, tak_calib_command
from tak_thermo_ros.formats.calibration_file import write_text_atomic
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.simulation.truth import DEFAULT_UNIT

RESULTS = Path(__file__).resolve().parent / 'results'
WORKER_COUNTS = (1, 2)


def unit_scenario(index: int, hours: float, rate_hz: float) -> Scenario:
    """Unit ``index`` of the batch: the default unit, offsets spread by 3 counts, the paper's protocol."""
    rng = np.random.default_rng([2026, index])
    unit = tuple(replace(axis, offset=axis.offset + rng.normal(0.0, 3.0), scale=axis.scale + rng.normal(0.0, 0.3))
                 for axis in DEFAULT_UNIT)
    base = Scenario(sample_rate_hz=rate_hz, ramp_celsius_per_minute=1.0, board_lag_s=300.0, dwell_s=30.0,
                    unit=unit, seed=index)  # type: ignore[arg-type]
    return stretched(base, hours)


def build_batch(workdir: Path, units: int, hours: float, rate_hz: float) -> tuple[list[Path], list[Path]]:
    """Write (or reuse) the calibration and validation bags of every unit."""
    from tak_thermo_ros.formats.bag import write_record
    from tak_thermo_ros.core.simulation.imu import simulate
    batch = workdir / f'fleet_{units}u_{hours:g}h_{rate_hz:g}hz'
    (batch / 'bags').mkdir(parents=True, exist_ok=True)
    (batch / 'validation').mkdir(parents=True, exist_ok=True)
    bags, checks = [], []
    start = time.perf_counter()
    for index in range(units):
        bag, check = batch / 'bags' / f'unit{index:03d}', batch / 'validation' / f'unit{index:03d}'
        scenario = unit_scenario(index, hours, rate_hz)
        if not bag.exists():
            write_record(bag, simulate(scenario).record)
        if not check.exists():
            validation = replace(scenario, plateaus_celsius=(12.0, 30.0), plateau_hours=0.25, seed=1000 + index)
            write_record(check, simulate(validation).record)
        bags.append(bag)
        checks.append(check)
    print(f'batch: {units} units of {hours:g} h at {rate_hz:g} Hz in {batch} ({time.perf_counter() - start:.1f} s)')
    return bags, checks


def run_fleet(bags: list[Path], checks: list[Path], out: Path, workers: int) -> dict[str, object]:
    """One ``tak_calib fit-fleet`` run: wall seconds from outside and what fleet.json says."""
    shutil.rmtree(out, ignore_errors=True)
    command = [*tak_calib_command(), 'fit-fleet', *map(str, bags), '-o', str(out), '--workers', str(workers),
               '--validate', *map(str, checks)]
    start = time.perf_counter()
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - start
    if result.returncode != 0:
        raise SystemExit(f'{" ".join(command[:3])} ... failed ({result.returncode}):\n{result.stderr}')
    document = json.loads((out / 'fleet.json').read_text())
    failed = document['units_failed']
    if failed:
        raise SystemExit(f'{failed} units failed:\n{result.stdout}')
    unit_seconds = [row['seconds'] for row in document['units']]
    return {'wall_s': wall, 'batch_wall_s': document['wall_seconds'], 'units_per_minute': 60.0 * len(bags) / wall,
            'unit_seconds_median': statistics.median(unit_seconds), 'unit_seconds_sum': sum(unit_seconds),
            'units_flagged': document['units_flagged'], 'majority_verdict': document['majority_verdict']}


def main(argv: list[str] | None = None) -> int:
    """Build (or reuse) the batch, time fit-fleet with 1 and 2 workers, write ``fleet.json``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--workdir', type=Path, default=Path('/tmp/tak_bench'), help='bag cache directory')
    parser.add_argument('--units', type=int, default=8, help='units in the batch (default 8)')
    parser.add_argument('--hours', type=float, default=6.0, help='length of each calibration run (default 6)')
    parser.add_argument('--rate', type=float, default=2.0, help='counts messages per second (default 2)')
    parser.add_argument('--repeat', type=int, default=1, help='runs per worker count; medians reported')
    parser.add_argument('--output', type=Path, default=RESULTS / 'fleet.json', help='JSON output')
    args = parser.parse_args(argv)
    load_start = os.getloadavg()
    bags, checks = build_batch(args.workdir, args.units, args.hours, args.rate)
    runs: dict[int, list[dict[str, object]]] = {workers: [] for workers in WORKER_COUNTS}
    for attempt in range(1, args.repeat + 1):
        for workers in WORKER_COUNTS:
            figures = run_fleet(bags, checks, args.workdir / f'fleet_out_{workers}', workers)
            runs[workers].append(figures)
            print(f'run {attempt}/{args.repeat}, {workers} worker(s): {figures["wall_s"]:.1f} s, '
                  f'{figures["units_per_minute"]:.1f} units/min (median unit {figures["unit_seconds_median"]:.2f} s)')
    summary = {}
    for workers, figures in runs.items():
        wall = statistics.median(float(f['wall_s']) for f in figures)  # type: ignore[arg-type]
        summary[str(workers)] = {'wall_s': wall, 'units_per_minute': 60.0 * args.units / wall,
                                 'batch_wall_s': statistics.median(
                                     float(f['batch_wall_s']) for f in figures),  # type: ignore[arg-type]
                                 'unit_seconds_median': statistics.median(
                                     float(f['unit_seconds_median']) for f in figures)}  # type: ignore[arg-type]
    speedup = summary['1']['wall_s'] / summary['2']['wall_s']
    document = {
        'benchmark': 'fleet',
        'batch': {'units': args.units, 'hours': args.hours, 'rate_hz': args.rate,
                  'samples_per_unit': int(args.hours * 3600 * args.rate), 'validation_bag_per_unit': True},
        'machine': {**machine(), 'load_average_start': load_start, 'load_average_end': os.getloadavg()},
        'repeat': args.repeat,
        'workers': summary,
        'speedup_2_over_1': speedup,
        'runs': {str(workers): figures for workers, figures in runs.items()},
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.output, json.dumps(document, indent=2) + '\n')
    for workers in WORKER_COUNTS:
        entry = summary[str(workers)]
        print(f'{workers} worker(s): {entry["units_per_minute"]:.1f} units/min ({args.units} units in '
              f'{entry["wall_s"]:.1f} s end to end, {entry["batch_wall_s"]:.1f} s from cluster start to the last '
              f'unit; median unit {entry["unit_seconds_median"]:.2f} s in its worker)')
    print(f'speed-up of 2 workers over 1: {speedup:.2f}x on {os.cpu_count()} CPUs '
          f'(load average {load_start[0]:.1f} at the start)')
    print(f'wrote {args.output}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
