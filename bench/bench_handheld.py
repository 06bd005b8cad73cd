"""Benchmark: ``tak_calib fit`` of a long hand-held record, its peak memory and time against rosbags reading the bag.

Target (issue 22): the fit of a 2 h hand-held record at 100 Hz in bounded memory and in less
time than rosbags needs to read the bag. The record: a cold unit (5 C) warming towards 35 C
with a 30 min time constant, turned by hand through still orientations (8 s rests, 2 s turns,
random orientations, a 0.12 m lever arm), the default driver unit plus a misalignment of both
sensors; no reference topics, an mcap bag. Per length (default 1, 2 and 6 h): rosbags' own
message-by-message deserialisation of the bag (``bench_fit.BASELINE_SCRIPT``), then
``tak_calib fit`` (wall and CPU time, peak RSS from ``wait4``), and the growth of the fit's peak
memory per hour. The fit reads the bag once when it holds at most 2 M messages (the survey finds
the still intervals and keeps its blocks, which then give the rests' samples, at most 500,000,
and the turns', at most 500,000), else twice.

Run: ``.venv/bin/python bench/bench_handheld.py [--hours 1 2 6] [--workdir /tmp/tak_bench]``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

from bench_fit import BASELINE_SCRIPT, run_child
from benchlib import machine, tak_calib_command
from tak_thermo_ros.formats.calibration_file import write_text_atomic

RESULTS = Path(__file__).resolve().parent / 'results'
RATE_HZ = 100.0

WRITER_SCRIPT = """
import sys
sys.path.insert(0, sys.argv[1])
from bench_handheld import write_bag
write_bag(sys.argv[2], float(sys.argv[3]))
"""


def scenario(hours: float):
    """The hand-held record of ``hours`` (see the module's description)."""
    from tak_thermo_ros.core.simulation.scenario import Scenario
    from tak_thermo_ros.core.simulation.motion import HandheldMotion
    rests = int(hours * 3600.0 / 10.0)
    return Scenario(output='imu', sample_rate_hz=RATE_HZ, temp_code_every=50, start_celsius=5.0, seed=1,
                    effects={'cross_axis': {'c_xy': 0.002, 'c_yx': 0.001, 'c_zx': -0.002, 'c_zy': 0.0012}},
                    gyro_effects={'cross_axis': {'c_xy': -0.003, 'c_xz': 0.002, 'c_yz': -0.001, 'c_zx': 0.0025}},
                    handheld=HandheldMotion(orientations=rests, still_s=8.0, turn_s=2.0, final_celsius=35.0,
                                            warmup_tau_s=1800.0))


def write_bag(path: str, hours: float) -> None:
    """Simulate the record and write it as an mcap bag (in a child process: its memory is not the fit's)."""
    from tak_thermo_ros.core.simulation.imu import simulate
    from tak_thermo_ros.formats.bag import write_driver_record
    write_driver_record(path, simulate(scenario(hours)).driver)


def build_bag(workdir: Path, hours: float) -> Path:
    """The cached bench bag of ``hours``."""
    path = workdir / f'handheld_{hours:g}h_100hz_mcap'
    if not path.exists():
        workdir.mkdir(parents=True, exist_ok=True)
        subprocess.run([sys.executable, '-c', WRITER_SCRIPT, str(Path(__file__).resolve().parent), str(path),
                        str(hours)], check=True)
    return path


def measure(bag: Path, workdir: Path) -> dict[str, object]:
    """Time rosbags reading the bag, then ``tak_calib fit``: times, peak memory, what the fit printed."""
    wall, cpu, rss, out = run_child([sys.executable, '-c', BASELINE_SCRIPT, str(bag)])
    baseline = json.loads(out)
    params = workdir / 'handheld_params.yaml'
    params.unlink(missing_ok=True)
    fit_wall, fit_cpu, fit_rss, fit_out = run_child([*tak_calib_command(), 'fit', str(bag), '-o', str(params),
                                                     '--no-progress'])
    lines = fit_out.strip().splitlines()
    return {'messages': baseline['messages'], 'rosbags_deserialise_s': baseline['seconds'],
            'rosbags_process_cpu_s': cpu, 'rosbags_peak_rss_bytes': rss,
            'fit_wall_s': fit_wall, 'fit_cpu_s': fit_cpu, 'fit_peak_rss_bytes': fit_rss,
            'fit_over_rosbags_cpu': fit_cpu / cpu,
            'fit_lines': [line for line in lines if line.startswith(('record:', 'fit:', 'hand-held:', 'turns:'))]}


def main(argv: list[str] | None = None) -> int:
    """Build (or reuse) the bags, measure each length, print and write ``handheld.json``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--workdir', type=Path, default=Path('/tmp/tak_bench'), help='bag cache directory')
    parser.add_argument('--hours', type=float, nargs='+', default=[1.0, 2.0, 6.0],
                        help='record lengths (default 1 2 6)')
    args = parser.parse_args(argv)
    rows = {}
    for hours in args.hours:
        bag = build_bag(args.workdir, hours)
        rows[hours] = measure(bag, args.workdir)
        row = rows[hours]
        print(f'{hours:g} h: {row["messages"]:,} messages; rosbags deserialise {row["rosbags_deserialise_s"]:.1f} s '
              f'(process CPU {row["rosbags_process_cpu_s"]:.1f} s); tak_calib fit {row["fit_wall_s"]:.1f} s wall, '
              f'{row["fit_cpu_s"]:.1f} s CPU ({row["fit_over_rosbags_cpu"]:.2f}x rosbags), '
              f'peak {row["fit_peak_rss_bytes"] / 2 ** 20:.0f} MiB')
        for line in row['fit_lines']:
            print(f'  {line}')
    lengths = sorted(rows)
    growth = None
    if len(lengths) > 1:
        first, last = rows[lengths[0]], rows[lengths[-1]]
        growth = (last['fit_peak_rss_bytes'] - first['fit_peak_rss_bytes']) / (lengths[-1] - lengths[0])
        print(f'fit peak memory grows {growth / 2 ** 20:+.1f} MiB per hour of record')
    document = {'machine': machine(), 'rate_hz': RATE_HZ, 'runs': {f'{hours:g}h': row for hours, row in rows.items()},
                'fit_peak_growth_bytes_per_hour': growth,
                'command': 'python bench/bench_handheld.py --hours ' + ' '.join(f'{h:g}' for h in args.hours)}
    RESULTS.mkdir(exist_ok=True)
    write_text_atomic(RESULTS / 'handheld.json', json.dumps(document, indent=2) + '\n')
    print(f'wrote {RESULTS / "handheld.json"}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
