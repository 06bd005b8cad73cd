"""Benchmark: block CDR decoding (``tak_thermo_ros.formats.cdr``) against rosbags' per-message deserialisation.

Two measurements, each side in its own subprocess so that its peak resident set (``VmHWM`` of
``/proc/self/status``, which starts afresh at ``exec``, unlike ``ru_maxrss``) is its own:

- ``decode``: raw messages at 1 kHz (stamps 1 ms apart, random values, frame ``imu_link``) of
  ``Vector3Stamped``, ``Temperature`` and ``Imu``, 1e6 and 5e6 of each, generated chunk by chunk
  in memory (generation not timed). ``rosbags``: ``typestore.deserialize_cdr`` on every message,
  nothing else (a lower bound for any per-message reader). ``block``:
  ``cdr.decode_messages`` on chunks of 65536 messages, plus copying the stamps and the main
  field into arrays of all messages. Storage reading is excluded on both sides.
- ``read_record``: ``bagio.read_record`` end to end on a simulated 1 kHz run
  (``core.simulate`` with short plateaus) written to an mcap and a sqlite3 bag, with
  ``decoder='rosbags'`` and ``decoder='block'`` (storage reading by rosbags included).

Results: ``bench/results/decode.json``. There is no target: the script reports the speed-up.

Run: ``.venv/bin/python bench/bench_decode.py [--messages 1000000 5000000] [--record-messages 1000000]``
(``--keep-decode`` re-measures ``read_record`` only and keeps the decode rows of the results file).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchlib import machine

RESULTS = Path(__file__).resolve().parent / 'results'
MSGTYPES = ('geometry_msgs/msg/Vector3Stamped', 'sensor_msgs/msg/Temperature', 'sensor_msgs/msg/Imu')
MAIN_FIELD = {'geometry_msgs/msg/Vector3Stamped': 'vector', 'sensor_msgs/msg/Temperature': 'temperature',
              'sensor_msgs/msg/Imu': 'linear_acceleration'}
CHUNK = 65536
RATE_HZ = 1000.0
START_NS = 1_700_000_000_000_000_000


def _template(msgtype: str) -> tuple[bytes, int, int]:
    """One serialised message, the byte offset of its main field and that field's width in float64s."""
    from tak_thermo_ros.formats.bag import TYPESTORE
    from tak_thermo_ros.formats.cdr.schema import decode_message
    types = TYPESTORE.types
    header = types['std_msgs/msg/Header'](stamp=types['builtin_interfaces/msg/Time'](sec=0, nanosec=0),
                                          frame_id='imu_link')
    marks = (1.25, 2.5, 3.75)
    vector = types['geometry_msgs/msg/Vector3'](x=marks[0], y=marks[1], z=marks[2])
    if msgtype.endswith('Vector3Stamped'):
        message = types[msgtype](header=header, vector=vector)
    elif msgtype.endswith('Temperature'):
        message = types[msgtype](header=header, temperature=marks[0], variance=0.0)
    else:
        covariance = np.zeros(9)
        message = types[msgtype](
            header=header, orientation=types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=covariance, angular_velocity=types['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0),
            angular_velocity_covariance=covariance, linear_acceleration=vector,
            linear_acceleration_covariance=covariance)
    raw = bytes(TYPESTORE.serialize_cdr(message, msgtype, little_endian=True))
    width = 1 if msgtype.endswith('Temperature') else 3
    offset = raw.find(np.array(marks[:width]).astype('<f8').tobytes())
    assert offset > 0 and decode_message(raw, msgtype)['stamp_ns'] == 0
    return raw, offset, width


def _chunks(msgtype: str, total: int, seed: int = 1):
    """Lists of raw messages (at most CHUNK each) of a 1 kHz stream, with their stamps and values."""
    raw, offset, width = _template(msgtype)
    template = np.frombuffer(raw, dtype=np.uint8)
    rng = np.random.default_rng(seed)
    for first in range(0, total, CHUNK):
        count = min(CHUNK, total - first)
        rows = np.tile(template, (count, 1))
        stamps = START_NS + np.round((first + np.arange(count)) * (1e9 / RATE_HZ)).astype(np.int64)
        rows[:, 4:8] = (stamps // 1_000_000_000).astype('<i4').view(np.uint8).reshape(count, 4)
        rows[:, 8:12] = (stamps % 1_000_000_000).astype('<u4').view(np.uint8).reshape(count, 4)
        values = rng.normal(0.0, 1000.0, (count, width))
        rows[:, offset:offset + 8 * width] = values.astype('<f8').view(np.uint8).reshape(count, 8 * width)
        yield [row.tobytes() for row in rows], stamps, values


def worker_decode(msgtype: str, total: int, decoder: str) -> dict[str, object]:
    """Decode ``total`` messages with one decoder; timing excludes the generation of raw bytes."""
    from tak_thermo_ros.formats.bag import TYPESTORE
    from tak_thermo_ros.formats.cdr.decoder import decode_messages
    deserialize = TYPESTORE.deserialize_cdr
    field = MAIN_FIELD[msgtype]
    width = 1 if field == 'temperature' else 3
    stamp_out = np.empty(total, dtype=np.int64)
    value_out = np.empty((total, width)) if width > 1 else np.empty(total)
    seconds = 0.0
    filled = 0
    checked = True
    for raws, stamps, values in _chunks(msgtype, total):
        rows = slice(filled, filled + len(raws))
        start = time.perf_counter()
        if decoder == 'rosbags':
            for raw in raws:
                deserialize(raw, msgtype)
        else:
            arrays = decode_messages(raws, msgtype, first_index=filled)
            stamp_out[rows] = arrays['stamp_ns']
            value_out[rows] = arrays[field]
        seconds += time.perf_counter() - start
        if decoder == 'block':
            checked &= bool(np.array_equal(stamp_out[rows], stamps)
                            and np.array_equal(value_out[rows], values.reshape(value_out[rows].shape)))
        filled = rows.stop
    if decoder == 'rosbags':  # spot check that the stream is what rosbags reads
        message = deserialize(raws[-1], msgtype)
        checked = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec == int(stamps[-1])
    return {'seconds': seconds, 'messages': filled, 'values_checked': checked}


def worker_record(bag: str, decoder: str) -> dict[str, object]:
    """``read_record`` of a bag with one decoder, timed."""
    from tak_thermo_ros.formats.bag import read_record
    start = time.perf_counter()
    record = read_record(bag, progress=False, decoder=decoder)
    seconds = time.perf_counter() - start
    return {'seconds': seconds, 'counts_messages': len(record.counts), 'temp_messages': len(record.temp_code),
            'reference_messages': len(record.reference),
            'checksum': float(np.nansum(record.counts)) + float(np.nansum(record.temp_code))}


def _peak_rss_kib() -> int:
    """Peak resident set of this process image (``VmHWM``), in KiB."""
    for line in Path('/proc/self/status').read_text().splitlines():
        if line.startswith('VmHWM:'):
            return int(line.split()[1])
    msg = 'no VmHWM in /proc/self/status'
    raise RuntimeError(msg)


def _run_worker(*arguments: str) -> dict[str, object]:
    """One worker in its own interpreter; its figures and peak resident set."""
    command = [sys.executable, str(Path(__file__).resolve()), '--worker', *arguments]
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise SystemExit(f'worker {arguments} failed:\n{result.stderr}')
    figures = json.loads(result.stdout.strip().splitlines()[-1])
    figures['peak_rss_bytes'] = figures.pop('own_peak_rss_kib') * 1024
    return figures


def _best(runs: list[dict[str, object]]) -> dict[str, object]:
    best = min(runs, key=lambda run: run['seconds'])
    return {**best, 'runs_s': [run['seconds'] for run in runs],
            'median_s': statistics.median(run['seconds'] for run in runs)}


def bench_decode(totals: list[int], repeat: int) -> list[dict[str, object]]:
    rows = []
    for msgtype in MSGTYPES:
        for total in totals:
            sides = {}
            for decoder in ('rosbags', 'block'):
                sides[decoder] = _best([_run_worker('decode', msgtype, str(total), decoder) for _ in range(repeat)])
            speedup = sides['rosbags']['seconds'] / sides['block']['seconds']
            rows.append({'msgtype': msgtype, 'messages': total, **sides, 'speedup': speedup,
                         'rosbags_us_per_message': 1e6 * sides['rosbags']['seconds'] / total,
                         'block_us_per_message': 1e6 * sides['block']['seconds'] / total})
            print(f'{msgtype:34s} {total:>9d}  rosbags {sides["rosbags"]["seconds"]:7.2f} s  '
                  f'block {sides["block"]["seconds"]:6.2f} s  x{speedup:5.1f}  peak RSS '
                  f'{sides["rosbags"]["peak_rss_bytes"] / 2**20:.0f} / '
                  f'{sides["block"]["peak_rss_bytes"] / 2**20:.0f} MiB',
                  flush=True)
    return rows


def bench_record(messages: int, storages: list[str], repeat: int, workdir: Path) -> list[dict[str, object]]:
    from tak_thermo_ros.formats.bag import write_record
    from tak_thermo_ros.core.simulation.imu import simulate
    from tak_thermo_ros.core.simulation.scenario import Scenario
    base = Scenario(sample_rate_hz=RATE_HZ, plateaus_celsius=(10.0, 30.0), ramp_celsius_per_minute=20.0)
    ramps_s = base.duration_s() - len(base.plateaus_celsius) * base.plateau_hours * 3600.0
    plateau_hours = max(messages / RATE_HZ - ramps_s, 60.0) / 3600.0 / len(base.plateaus_celsius)
    record = simulate(replace(base, plateau_hours=plateau_hours)).record
    rows = []
    for storage in storages:
        bag = workdir / f'run_{storage}'
        start = time.perf_counter()
        write_record(bag, record, storage=storage)
        write_s = time.perf_counter() - start
        sides = {decoder: _best([_run_worker('record', str(bag), decoder) for _ in range(repeat)])
                 for decoder in ('rosbags', 'block')}
        same = sides['rosbags']['checksum'] == sides['block']['checksum']
        speedup = sides['rosbags']['seconds'] / sides['block']['seconds']
        rows.append({'storage': storage, 'counts_messages': len(record.counts), 'write_s': write_s, **sides,
                     'same_arrays_checksum': same, 'speedup': speedup})
        print(f'read_record {storage:8s} {len(record.counts):>9d} counts msgs  rosbags '
              f'{sides["rosbags"]["seconds"]:7.2f} s  block {sides["block"]["seconds"]:6.2f} s  x{speedup:5.1f}  '
              f'peak RSS {sides["rosbags"]["peak_rss_bytes"] / 2**20:.0f} / '
              f'{sides["block"]["peak_rss_bytes"] / 2**20:.0f} MiB', flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--messages', type=int, nargs='+', default=[1_000_000, 5_000_000])
    parser.add_argument('--record-messages', type=int, default=1_000_000,
                        help='counts messages of the simulated run read by read_record (0: skip)')
    parser.add_argument('--storages', nargs='+', default=['mcap', 'sqlite3'])
    parser.add_argument('--repeat', type=int, default=1)
    parser.add_argument('--keep-decode', action='store_true',
                        help='skip the decode measurement, keep its rows from bench/results/decode.json')
    parser.add_argument('--worker', nargs='+', help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        kind, *rest = args.worker
        figures = (worker_decode(rest[0], int(rest[1]), rest[2]) if kind == 'decode'
                   else worker_record(rest[0], rest[1]))
        figures['own_peak_rss_kib'] = _peak_rss_kib()
        print(json.dumps(figures))
        return 0
    before = machine()
    if args.keep_decode:
        decode = json.loads((RESULTS / 'decode.json').read_text(encoding='utf-8'))['decode']
    else:
        decode = bench_decode(args.messages, args.repeat)
    record = []
    if args.record_messages:
        with tempfile.TemporaryDirectory(prefix='bench_decode.') as workdir:
            record = bench_record(args.record_messages, args.storages, args.repeat, Path(workdir))
    RESULTS.mkdir(exist_ok=True)
    result = {'benchmark': 'decode', 'machine': before, 'load_average_1min_after': machine()['load_average_1min'],
              'chunk_messages': CHUNK, 'rate_hz': RATE_HZ, 'repeat': args.repeat, 'decode': decode,
              'read_record': record}
    (RESULTS / 'decode.json').write_text(json.dumps(result, indent=2) + '\n', encoding='utf-8')
    print(f'wrote {RESULTS / "decode.json"}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
