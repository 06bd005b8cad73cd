"""Benchmark: peak memory of ``tak_calib import-csv`` on a ~200 MB log.

Target (issue 9): the import reads the log in chunks, so that its peak resident set, less the
interpreter with its imports, stays under twice the size of the file plus the arrays the
import keeps (the run as the bag contract holds it, and the measured acceleration and
temperature: 72 bytes per row). Before the chunked reader, a 200 MB log peaked at 1.3 GB.

The log imitates the real one in ``data/`` (tab-delimited, microsecond stamps, gyro, acceleration
in m/s^2, a status and a temperature column; a static board and a temperature sweep). It is
generated in a child process under ``--workdir`` and removed afterwards unless ``--keep``.
Each measured command runs in its own child; its peak RSS is ``wait4``'s ``ru_maxrss``:

- interpreter: ``python -c 'import tak_thermo_ros.cli, tak_thermo_ros.formats.bag'``;
- import: ``tak_calib import-csv LOG -o BAG --time-unit us ...``;
- ``--compare TAK_CALIB``: the same import with another installation (e.g. before the change).

Run: ``.venv/bin/python bench/bench_csv_import.py [--megabytes 200] [--compare PATH]``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchlib import machine, tak_calib_command
from tak_thermo_ros.formats.calibration_file import write_text_atomic

RESULTS = Path(__file__).resolve().parent / 'results'
TARGET_MISSED = 3
"""Exit status when a target is missed (bench/run_all.py); 0 when all hold."""
KEPT_BYTES_PER_ROW = 72
"""counts (24) + temperature code (8) + two stamp arrays (16) + acceleration (24) per row."""
HEADER = 'timestamp\timu.gyro.x\timu.gyro.y\timu.gyro.z\timu.acc.x\timu.acc.y\timu.acc.z\timu.status\timu.temperature\n'
COLUMNS = ['--time-unit', 'us', '--acc-columns', 'imu.acc.x', 'imu.acc.y', 'imu.acc.z',
           '--temp-column', 'imu.temperature', '--no-progress']


def generate(path: Path, megabytes: float, seed: int = 3) -> int:
    """Write a static thermal log of about ``megabytes`` MB; the number of rows."""
    rng = np.random.default_rng(seed)
    rows_per_chunk = 100_000
    rows = 0
    stamp0 = 256_551_281_491_968
    with path.open('w', encoding='utf-8') as stream:
        stream.write(HEADER)
        while stream.tell() < megabytes * 1e6:
            index = np.arange(rows, rows + rows_per_chunk)
            stamp = stamp0 + index * 5_000  # 200 Hz
            hours = index / 200.0 / 3600.0
            temperature = 25.0 + 20.0 * np.sin(2.0 * np.pi * hours / 4.0)
            gyro = rng.normal(0.0, 0.02, (rows_per_chunk, 3))
            acc = np.array([0.17, -0.10, -9.6]) + rng.normal(0.0, 0.01, (rows_per_chunk, 3))
            acc += 0.002 * (temperature - 25.0)[:, None]
            lines = [f'{s}\t{g0:.10g}\t{g1:.10g}\t{g2:.10g}\t{a0:.10g}\t{a1:.10g}\t{a2:.10g}\t0\t{t:.10g}\n'
                     for s, (g0, g1, g2), (a0, a1, a2), t
                     in zip(stamp.tolist(), gyro.tolist(), acc.tolist(), temperature.tolist())]
            stream.write(''.join(lines))
            rows += rows_per_chunk
    return rows


def run_child(command: list[str]) -> tuple[float, int, str, str, int]:
    """Wall seconds, own peak RSS (bytes), stdout, stderr and exit status of one subprocess."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        start = time.perf_counter()
        process = subprocess.Popen(command, stdout=out, stderr=err)
        _, status, usage = os.wait4(process.pid, 0)  # this child's rusage only
        wall = time.perf_counter() - start
        out.seek(0)
        err.seek(0)
        return (wall, int(usage.ru_maxrss) * 1024, out.read().decode(errors='replace'),
                err.read().decode(errors='replace'), os.waitstatus_to_exitcode(status))


def measure_import(tak_calib: list[str], log: Path, bag: Path) -> dict[str, object]:
    """Run one import into ``bag`` (removed afterwards) and return its figures."""
    shutil.rmtree(bag, ignore_errors=True)
    wall, rss, stdout, stderr, status = run_child([*tak_calib, 'import-csv', str(log), '-o', str(bag), *COLUMNS])
    if status != 0:
        msg = f'{" ".join(tak_calib)} import-csv failed ({status}):\n{stderr}'
        raise SystemExit(msg)
    shutil.rmtree(bag, ignore_errors=True)
    return {'command': tak_calib, 'wall_s': wall, 'peak_rss_bytes': rss, 'output': stdout.strip().splitlines()}


def main(argv: list[str] | None = None) -> int:
    """Generate the log, measure, print and write ``bench/results/csv_import.json``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--workdir', type=Path, default=Path(tempfile.gettempdir()) / 'tak_bench_csv')
    parser.add_argument('--megabytes', type=float, default=200.0, help='size of the generated log (default 200)')
    parser.add_argument('--compare', metavar='TAK_CALIB', help='also measure this tak_calib executable')
    parser.add_argument('--keep', action='store_true', help='keep the generated log for the next run')
    parser.add_argument('--output', type=Path, default=RESULTS / 'csv_import.json')
    parser.add_argument('--generate-only', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    args.workdir.mkdir(parents=True, exist_ok=True)
    log = args.workdir / f'log_{args.megabytes:g}MB.tsv'
    if args.generate_only:
        rows = generate(log, args.megabytes)
        print(rows)
        return 0
    if not log.exists():
        # In a child: this process stays small, so the children's figures are their own.
        subprocess.run([sys.executable, __file__, '--generate-only', '--workdir', str(args.workdir),
                        '--megabytes', repr(args.megabytes)], check=True, stdout=subprocess.DEVNULL)
    file_bytes = log.stat().st_size
    with log.open('rb') as stream:
        rows = sum(1 for _ in stream) - 1
    _, interpreter, _, _, _ = run_child([sys.executable, '-c', 'import tak_thermo_ros.cli, tak_thermo_ros.formats.bag'])
    bag = args.workdir / 'imported'
    this = measure_import(tak_calib_command(), log, bag)
    kept = rows * KEPT_BYTES_PER_ROW
    budget = 2 * file_bytes + kept
    used = int(this['peak_rss_bytes']) - interpreter  # type: ignore[arg-type]
    document = {
        'benchmark': 'csv_import',
        'log': {'bytes': file_bytes, 'rows': rows},
        'machine': machine(),
        'interpreter_peak_rss_bytes': interpreter,
        'import': this,
        'import_above_interpreter_bytes': used,
        'peak_over_file_size': int(this['peak_rss_bytes']) / file_bytes,  # type: ignore[arg-type]
        'kept_array_bytes': kept,
        'target_bytes': budget,
        'target': 'peak RSS less the interpreter < 2 x file size + kept arrays',
        'holds': used < budget,
    }
    if args.compare:
        other = measure_import([args.compare], log, bag)
        document['compare'] = other
    if not args.keep:
        log.unlink()
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.output, json.dumps(document, indent=2) + '\n')
    mib = 2 ** 20
    print(f'log: {file_bytes / mib:.0f} MiB, {rows} rows')
    print(f'interpreter with imports: {interpreter / mib:.0f} MiB')
    peak_mib = int(this['peak_rss_bytes']) / mib  # type: ignore[arg-type]
    print(f'tak_calib import-csv: {this["wall_s"]:.1f} s, peak {peak_mib:.0f} MiB '
          f'({document["peak_over_file_size"]:.2f}x the file); above the interpreter {used / mib:.0f} MiB, '
          f'target < {budget / mib:.0f} MiB (2 x file + {kept / mib:.0f} MiB kept arrays): '
          f'{"holds" if document["holds"] else "MISSED"}')
    if args.compare:
        other = document['compare']
        print(f'{args.compare} import-csv: {other["wall_s"]:.1f} s, '  # type: ignore[index]
              f'peak {int(other["peak_rss_bytes"]) / mib:.0f} MiB')  # type: ignore[index]
    return 0 if document['holds'] else TARGET_MISSED


if __name__ == '__main__':
    sys.exit(main())
