"""Benchmark: throughput of the correction link, per sample and vectorised.

Targets (issue 2): ``Corrector.correct_sample`` (plain floats, one sample per call, the
node's path) at least 200k samples/s; ``Corrector.correct`` (numpy arrays) at least 10M
samples/s. The calibration is the simulator's default unit: cubic offset shape ``F_s``
(q = 3) and quadratic scale factor ``F_c`` (p = 2), no effects, clamp policy.

Each figure is timed ``--repeat`` times; the best run is what the code can do (the
``timeit`` convention: slower runs measure other processes on the machine) and is the figure
held against the target; the median is reported beside it. Both paths are also checked to
agree bit for bit on the benchmark data.

Run: ``.venv/bin/python bench/bench_correction.py [--repeat 7]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from tak_thermo_ros.formats.calibration_file import write_text_atomic
from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.simulation.scenario import Scenario

RESULTS = Path(__file__).resolve().parent / 'results'
TARGET_MISSED = 3
"""Exit status when a target is missed (bench/run_all.py); 0 when all hold."""
PER_SAMPLE_TARGET = 200_000.0
VECTORISED_TARGET = 10_000_000.0
VECTORISED_SIZES = (100_000, 1_000_000, 5_400_000)
"""Array lengths timed: a short bag, a long one, the 15-hour run at 100 Hz."""


def bench_data(calibration, size: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whole-number codes ``(size, 3)``.

    Temperature codes ``(size,)`` reaching 5 % beyond the calibrated range on both sides (so that the clamp runs),
    stamps in seconds ``(size,)``.
    """
    rng = np.random.default_rng(seed)
    counts = np.round(rng.uniform(-20000.0, 20000.0, (size, 3)))
    low, high = calibration.temp_code_min, calibration.temp_code_max
    margin = 0.05 * (high - low)
    temp_code = np.round(rng.uniform(low - margin, high + margin, size))
    stamp_s = 1.7e9 + np.arange(size) * 0.01
    return counts, temp_code, stamp_s


def time_per_sample(corrector: Corrector, size: int, repeat: int) -> list[float]:
    """Seconds per pass over ``size`` samples, one ``correct_sample`` call each, as the node does."""
    counts, temp_code, stamp_s = bench_data(corrector.calibration, size)
    rows = list(zip(*counts.T.tolist(), temp_code.tolist(), stamp_s.tolist()))
    correct_sample = corrector.correct_sample
    runs = []
    for _ in range(repeat):
        start = time.perf_counter()
        for x, y, z, code, stamp in rows:
            correct_sample(x, y, z, code, stamp_s=stamp)
        runs.append(time.perf_counter() - start)
    return runs


def time_vectorised(corrector: Corrector, size: int, repeat: int) -> list[float]:
    """Seconds per ``correct`` call on ``size`` samples."""
    counts, temp_code, _ = bench_data(corrector.calibration, size)
    corrector.correct(counts[:1000], temp_code[:1000])  # warm up
    runs = []
    for _ in range(repeat):
        start = time.perf_counter()
        corrector.correct(counts, temp_code)
        runs.append(time.perf_counter() - start)
    return runs


def paths_agree(corrector: Corrector, size: int = 20_000) -> bool:
    """Whether ``correct`` and ``correct_sample`` give the same bits on the benchmark data."""
    counts, temp_code, stamp_s = bench_data(corrector.calibration, size, seed=1)
    vectorised = corrector.correct(counts, temp_code, stamp_s=stamp_s)
    per_sample = np.array([corrector.correct_sample(x, y, z, code, stamp_s=stamp)
                           for x, y, z, code, stamp in zip(*counts.T.tolist(), temp_code.tolist(),
                                                           stamp_s.tolist())])
    return bool(np.array_equal(vectorised.view(np.int64), per_sample.view(np.int64)))


def summary(size: int, runs: list[float], target: float) -> dict[str, object]:
    """Throughput figures of one timed case."""
    best = size / min(runs)
    return {'samples': size, 'runs_s': runs, 'best_samples_per_s': best,
            'median_samples_per_s': size / statistics.median(runs), 'target_samples_per_s': target,
            'holds': best >= target}


def main(argv: list[str] | None = None) -> int:
    """Time both paths, print the figures and write ``correction.json``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeat', type=int, default=7, help='timed runs per case (default 7)')
    parser.add_argument('--per-sample-size', type=int, default=200_000, help='samples per pass (default 200000)')
    parser.add_argument('--output', type=Path, default=RESULTS / 'correction.json')
    args = parser.parse_args(argv)

    calibration = Scenario().truth()
    corrector = Corrector(calibration)
    load_before = os.getloadavg()
    agree = paths_agree(corrector)
    per_sample = summary(args.per_sample_size, time_per_sample(corrector, args.per_sample_size, args.repeat),
                         PER_SAMPLE_TARGET)
    vectorised = [summary(size, time_vectorised(corrector, size, args.repeat), VECTORISED_TARGET)
                  for size in VECTORISED_SIZES]
    load_after = os.getloadavg()

    holds = agree and per_sample['holds'] and all(case['holds'] for case in vectorised)
    document = {
        'benchmark': 'correction',
        'calibration': {'offset_order': len(calibration.axes[0].offset_shape),
                        'scale_order': len(calibration.axes[0].scale_shape),
                        'out_of_range': corrector.out_of_range.value},
        'machine': {'cpus': os.cpu_count(), 'python': platform.python_version(), 'numpy': np.__version__,
                    'platform': platform.platform(), 'load_average_before': load_before,
                    'load_average_after': load_after},
        'repeat': args.repeat,
        'paths_bit_identical': agree,
        'per_sample': per_sample,
        'vectorised': vectorised,
        'holds': holds,
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.output, json.dumps(document, indent=2) + '\n')

    def line(label: str, case: dict[str, object], unit: float, suffix: str) -> str:
        verdict = 'holds' if case['holds'] else 'MISSED'
        return (f'{label}: best {case["best_samples_per_s"] / unit:8.2f}{suffix} samples/s, median '
                f'{case["median_samples_per_s"] / unit:8.2f}{suffix}  (target >= '
                f'{case["target_samples_per_s"] / unit:g}{suffix}: {verdict})')

    print(f'load average {load_before[0]:.2f} before, {load_after[0]:.2f} after, {os.cpu_count()} cpus; '
          f'best and median of {args.repeat} runs')
    print(f'correct and correct_sample agree bit for bit: {"yes" if agree else "NO"}')
    print(line(f'correct_sample, {args.per_sample_size} calls      ', per_sample, 1e3, 'k'))
    for case in vectorised:
        print(line(f'correct, {case["samples"]:>9} samples per call', case, 1e6, 'M'))
    print(f'wrote {args.output}')
    return 0 if holds else TARGET_MISSED


if __name__ == '__main__':
    sys.exit(main())
