"""Benchmark: peak memory and wall time of ``tak_calib fit`` and ``apply`` against the run's length.

Target (issue 11, bounded memory): the streamed passes hold a bounded amount of the bag, so the
peak resident set does not grow with the run's length (15 h at 1 kHz, 54 million counts
messages: below 1 GB). Reported per length: ``fit`` and ``apply`` peak RSS (``wait4`` rusage of
each subprocess) and wall time, against rosbags' own message-by-message deserialisation of the
same bag (``bench_fit.BASELINE_SCRIPT``), and the growth of memory per hour of run.

The bags (counts contract, 1 kHz counts, temperature codes at 100 Hz, a reference that changes
every minute, the default unit's true link plus white noise) are generated chunk by chunk
with a template serialiser (the CDR bytes of one message, fields patched in numpy), so that
building them needs little memory; they are cached under ``--workdir``. Writing still goes
through rosbags' writer, one message at a time (about 20 us each on an idle core).

Run: ``.venv/bin/python bench/bench_memory.py [--hours 1 5 15] [--apply-hours 1 5] [--diagnose-hours 1 5]``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bench_fit import BASELINE_SCRIPT, run_child
from benchlib import machine, tak_calib_command
from tak_thermo_ros.formats.calibration_file import write_text_atomic

RESULTS = Path(__file__).resolve().parent / 'results'
MEMORY_TARGET_BYTES = 1024 ** 3
RATE_HZ = 1000.0
TEMP_EVERY = 10
DWELL_S = 60.0
START_NS = 1_700_000_000 * 1_000_000_000
CHUNK_S = 60.0

WRITER_SCRIPT = """
import sys
sys.path.insert(0, sys.argv[1])
from bench_memory import write_bag
write_bag(sys.argv[2], float(sys.argv[3]))
"""


def bag_path(workdir: Path, hours: float) -> Path:
    """Where the bench bag of this length is cached."""
    return workdir / f'memory_{hours:g}h_1khz_mcap'


def temperature_code(t_s: np.ndarray, duration_s: float, low: float, high: float) -> np.ndarray:
    """Five plateaus from ``low`` to ``high`` and back, joined by ramps (30 % of the time)."""
    levels = np.array([0.5, 0.0, 0.25, 0.75, 1.0, 0.5])
    segment = duration_s / (len(levels) - 1)
    position = np.clip(t_s / segment, 0.0, len(levels) - 1 - 1e-12)
    index = position.astype(int)
    within = position - index
    ramp = np.clip((within - 0.7) / 0.3, 0.0, 1.0)
    level = levels[index] + (levels[index + 1] - levels[index]) * ramp
    return np.round(low + (high - low) * level)


def write_bag(path: str | os.PathLike[str], hours: float, *, seed: int = 1) -> None:
    """Generate and write a counts-contract bag of ``hours`` at 1 kHz, chunk by chunk."""
    from rosbags.rosbag2 import StoragePlugin, Writer  # the bench only: the package reads bags via bagio
    from tak_thermo_ros.formats.bag import NOMINAL_SCALE_KEY, TEMPERATURE, TYPESTORE, VECTOR3_STAMPED, Topics
    from tak_thermo_ros.core.simulation.scenario import Scenario
    truth = Scenario().truth()
    noise = Scenario().unit[0].noise_counts
    rng = np.random.default_rng(seed)
    topics = Topics()
    types = TYPESTORE.types
    header = types['std_msgs/msg/Header'](stamp=types['builtin_interfaces/msg/Time'](sec=0, nanosec=0), frame_id='imu')
    vector_template = np.frombuffer(bytes(TYPESTORE.serialize_cdr(types[VECTOR3_STAMPED](
        header=header, vector=types['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0)), VECTOR3_STAMPED)), np.uint8)
    temp_template = np.frombuffer(bytes(TYPESTORE.serialize_cdr(types[TEMPERATURE](
        header=header, temperature=0.0, variance=0.0), TEMPERATURE)), np.uint8)
    vector_offset = len(vector_template) - 24  # x, y, z: the last 24 bytes
    temp_offset = len(temp_template) - 16  # temperature, variance: the last 16 bytes

    def serialise(template: np.ndarray, stamps: np.ndarray, values: np.ndarray, offset: int) -> np.ndarray:
        rows = np.tile(template, (len(stamps), 1))
        rows[:, 4:8] = (stamps // 1_000_000_000).astype('<i4').view(np.uint8).reshape(-1, 4)
        rows[:, 8:12] = (stamps % 1_000_000_000).astype('<u4').view(np.uint8).reshape(-1, 4)
        width = values.shape[1] * 8
        rows[:, offset:offset + width] = np.ascontiguousarray(values, dtype='<f8').view(np.uint8).reshape(-1, width)
        return rows

    positions = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float) * 9.80665
    duration_s = hours * 3600.0
    total = int(round(duration_s * RATE_HZ))
    period_ns = int(round(1e9 / RATE_HZ))
    per_chunk = int(CHUNK_S * RATE_HZ)
    writer = Writer(Path(path), version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_custom_data(NOMINAL_SCALE_KEY, ','.join(repr(a.scale) for a in truth.axes))
    writer.open()
    try:
        temp_conn = writer.add_connection(topics.temp_code, TEMPERATURE, typestore=TYPESTORE)
        reference_conn = writer.add_connection(topics.reference, VECTOR3_STAMPED, typestore=TYPESTORE)
        counts_conn = writer.add_connection(topics.counts, VECTOR3_STAMPED, typestore=TYPESTORE)
        connections = (temp_conn, reference_conn, counts_conn)
        for first in range(0, total, per_chunk):
            index = np.arange(first, min(first + per_chunk, total))
            stamps = START_NS + index * period_ns
            t_s = index / RATE_HZ
            codes = temperature_code(t_s, duration_s, truth.temp_code_min, truth.temp_code_max)
            force = positions[(t_s // DWELL_S).astype(int) % len(positions)]
            n = codes - truth.temp_code_ref
            counts = np.column_stack([axis.forward(force[:, i], n) for i, axis in enumerate(truth.axes)])
            counts = np.round(counts + rng.normal(0.0, noise, counts.shape))
            temp_rows = index % TEMP_EVERY == 0
            changed = np.ones(len(index), dtype=bool)
            changed[1:] = np.any(force[1:] != force[:-1], axis=1)
            if first:
                changed[0] = (index[0] / RATE_HZ) % DWELL_S == 0.0
            streams = [serialise(temp_template, stamps[temp_rows], codes[temp_rows, None], temp_offset),
                       serialise(vector_template, stamps[changed], force[changed], vector_offset),
                       serialise(vector_template, stamps, counts, vector_offset)]
            event_stamps = np.concatenate([stamps[temp_rows], stamps[changed], stamps])
            kinds = np.concatenate([np.zeros(temp_rows.sum(), int), np.ones(changed.sum(), int),
                                    np.full(len(stamps), 2)])
            rows = np.concatenate([np.arange(temp_rows.sum()), np.arange(changed.sum()), np.arange(len(stamps))])
            order = np.lexsort((kinds, event_stamps))
            write = writer.write
            for stamp, kind, row in zip(event_stamps[order].tolist(), kinds[order].tolist(), rows[order].tolist()):
                write(connections[kind], stamp, streams[kind][row].tobytes())
    finally:
        writer.close()


def build_bag(workdir: Path, hours: float) -> Path:
    """The cached bag of this length, generated (in a child process, atomically) when missing."""
    bag = bag_path(workdir, hours)
    if bag.exists():
        print(f'bag: reusing {bag}')
        return bag
    workdir.mkdir(parents=True, exist_ok=True)
    staging = workdir / f'.{bag.name}.partial'
    shutil.rmtree(staging, ignore_errors=True)
    start = time.perf_counter()
    subprocess.run([sys.executable, '-c', WRITER_SCRIPT, str(Path(__file__).resolve().parent), str(staging),
                    repr(hours)], check=True)
    os.rename(staging, bag)
    print(f'bag: wrote {bag} in {time.perf_counter() - start:.0f} s')
    return bag


def measure(bag: Path, workdir: Path, *, apply: bool, diagnose: bool) -> dict[str, object]:
    """Baseline deserialisation, ``fit``, optionally ``apply`` and ``diagnose`` of one bag, each in its own process."""
    wall, cpu, rss, out = run_child([sys.executable, '-c', BASELINE_SCRIPT, str(bag)])
    baseline = json.loads(out)
    params = workdir / f'{bag.name}_params.yaml'
    params.unlink(missing_ok=True)
    fit_wall, fit_cpu, fit_rss, fit_out = run_child([*tak_calib_command(), 'fit', str(bag), '-o', str(params),
                                                     '--no-progress'])
    row: dict[str, object] = {
        'messages': baseline['messages'], 'bag_bytes': sum(f.stat().st_size for f in bag.rglob('*') if f.is_file()),
        'baseline_rosbags_deserialise_s': baseline['seconds'], 'baseline_cpu_s': cpu, 'baseline_peak_rss_bytes': rss,
        'fit_wall_s': fit_wall, 'fit_cpu_s': fit_cpu, 'fit_peak_rss_bytes': fit_rss,
        'fit_over_baseline': fit_wall / baseline['seconds'], 'fit_cpu_over_baseline_cpu': fit_cpu / cpu,
        'fit_output': fit_out.strip().splitlines(),
    }
    print(f'{bag.name}: {baseline["messages"]} messages; rosbags deserialise {baseline["seconds"]:.1f} s; '
          f'fit {fit_wall:.1f} s ({fit_wall / baseline["seconds"]:.2f}x), peak {fit_rss / 2**20:.0f} MiB')
    if apply:
        output = workdir / f'{bag.name}_applied'
        shutil.rmtree(output, ignore_errors=True)
        apply_wall, apply_cpu, apply_rss, _ = run_child([*tak_calib_command(), 'apply', str(bag), '--params',
                                                         str(params), '-o', str(output), '--no-progress'])
        shutil.rmtree(output, ignore_errors=True)
        row.update(apply_wall_s=apply_wall, apply_cpu_s=apply_cpu, apply_peak_rss_bytes=apply_rss)
        print(f'  apply {apply_wall:.1f} s, peak {apply_rss / 2**20:.0f} MiB')
    if diagnose:
        report = workdir / f'{bag.name}_diagnose.json'
        report.unlink(missing_ok=True)
        diagnose_wall, diagnose_cpu, diagnose_rss, diagnose_out = run_child(
            [*tak_calib_command(), 'diagnose', str(bag), '--params', str(params), '--json', str(report),
             '--no-progress'])
        row.update(diagnose_wall_s=diagnose_wall, diagnose_cpu_s=diagnose_cpu, diagnose_peak_rss_bytes=diagnose_rss,
                   diagnose_output=diagnose_out.strip().splitlines()[:3])
        print(f'  diagnose {diagnose_wall:.1f} s, peak {diagnose_rss / 2**20:.0f} MiB')
    return row


def growth_per_hour(rows: dict[float, dict[str, object]], key: str) -> float | None:
    """Least-squares slope of peak memory against hours, bytes per hour (None with fewer than two)."""
    points = [(hours, float(row[key])) for hours, row in rows.items() if key in row]  # type: ignore[arg-type]
    if len(points) < 2:
        return None
    hours, peaks = np.array(points).T
    return float(np.polyfit(hours, peaks, 1)[0])


def main(argv: list[str] | None = None) -> int:
    """Build (or reuse) the bags, measure, print and write ``memory.json``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--workdir', type=Path, default=Path('/tmp/tak_bench'), help='bag cache directory')
    parser.add_argument('--hours', type=float, nargs='+', default=[1.0, 5.0, 15.0], help='run lengths')
    parser.add_argument('--apply-hours', type=float, nargs='*', default=[1.0, 5.0],
                        help='lengths on which apply is measured too (writing is slow)')
    parser.add_argument('--diagnose-hours', type=float, nargs='*', default=[1.0, 5.0],
                        help='lengths on which diagnose is measured too')
    parser.add_argument('--build-only', action='store_true', help='generate the bags and stop')
    parser.add_argument('--output', type=Path, default=RESULTS / 'memory.json')
    parser.add_argument('--combine', type=Path, nargs='+', metavar='PART.json',
                        help='merge the runs of earlier outputs (lengths measured separately) into --output')
    args = parser.parse_args(argv)
    load_start = os.getloadavg()
    if args.combine:
        parts = [json.loads(part.read_text()) for part in args.combine]
        rows = {}
        for part in parts:  # a later part's figures replace an earlier one's, key by key
            for name, row in part['runs'].items():
                rows.setdefault(float(name[:-1]), {}).update(row)
        machines = [part['machine'] for part in parts]
    else:
        bags = {hours: build_bag(args.workdir, hours) for hours in args.hours}
        if args.build_only:
            return 0
        rows = {hours: measure(bag, args.workdir, apply=hours in args.apply_hours,
                               diagnose=hours in args.diagnose_hours) for hours, bag in bags.items()}
        machines = [{**machine(), 'load_average_start': load_start, 'load_average_end': os.getloadavg()}]
    rows = dict(sorted(rows.items()))
    peak = max(float(row[key]) for row in rows.values() for key in row  # type: ignore[arg-type]
               if key.endswith('peak_rss_bytes') and not key.startswith('baseline'))
    document = {
        'benchmark': 'memory',
        'bags': {'contract': 'counts', 'rate_hz': RATE_HZ, 'temperature_every': TEMP_EVERY, 'dwell_s': DWELL_S,
                 'storage': 'mcap'},
        'machine': machines[0] if len(machines) == 1 else machines,
        'runs': {f'{hours:g}h': row for hours, row in rows.items()},
        'fit_peak_growth_bytes_per_hour': growth_per_hour(rows, 'fit_peak_rss_bytes'),
        'apply_peak_growth_bytes_per_hour': growth_per_hour(rows, 'apply_peak_rss_bytes'),
        'diagnose_peak_growth_bytes_per_hour': growth_per_hour(rows, 'diagnose_peak_rss_bytes'),
        'memory_target_bytes': MEMORY_TARGET_BYTES,
        'memory_holds': peak < MEMORY_TARGET_BYTES,
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.output, json.dumps(document, indent=2) + '\n')
    for key in ('fit', 'apply', 'diagnose'):
        slope = document[f'{key}_peak_growth_bytes_per_hour']
        if slope is not None:
            print(f'{key}: peak memory grows {slope / 2**20:+.1f} MiB per hour of run')
    print(f'wrote {args.output}')
    return 0 if peak < MEMORY_TARGET_BYTES else 3


if __name__ == '__main__':
    sys.exit(main())
