"""Benchmark: the streamed Allan deviation of 15 h at 1 kHz (54 million samples per axis, 3 axes).

Target (issue 16): bounded memory (peak resident set < 1 GB) and less than 0.3x the time
rosbags needs to read such a bag. The baseline is the README's measured figure (bench_memory /
bench_fit: rosbags alone deserialises the 59.4 million messages of a 15 h, 1 kHz bag in
645 s on this machine); it is not measured again here (reading it takes 11 minutes).

What is timed: :class:`~tak_thermo_ros.core.noise.allan.AllanAccumulator` ``add`` over blocks of
65,536 samples (the block size of ``tak_calib``'s passes), its ``result`` and the five-term fit
(``tak_calib noise``'s settings: two averaging times per octave). The samples (white noise,
bias instability and random walk of a consumer MEMS gyroscope, from the simulator's noise
processes) are generated block by block in the same process; their generation is timed
separately and not counted. The peak resident set is the child process's ``ru_maxrss``.

Run: ``.venv/bin/python bench/bench_allan.py [--hours 15] [--rate 1000]``; writes bench/results/allan.json;
exits 0 when both targets hold, 3 when one is missed.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from benchlib import machine

RESULTS = Path(__file__).resolve().parent / 'results'
BLOCK = 65536
ROSBAGS_15H_S = 645.0
"""README (Performance): rosbags' own deserialisation of the 59.4 M messages of 15 h at 1 kHz."""
MEMORY_TARGET_BYTES = 1024 ** 3
WHITE = 1.7e-4      # rad/s/sqrt(Hz)
BIAS = 4.8e-5       # rad/s (10 deg/h)
BIAS_TAU = 100.0    # s
WALK = 3e-6         # rad/s^2/sqrt(Hz)


def child(hours: float, rate: float) -> dict[str, float]:
    """Stream ``hours`` of three-axis samples at ``rate`` into the accumulator; time and memory."""
    from scipy.signal import lfilter

    from tak_thermo_ros.core.noise.allan import AllanAccumulator
    from tak_thermo_ros.core.noise.model import fit_noise_model
    from tak_thermo_ros.core.simulation.noise import bias_instability_poles, bias_instability_variance
    total = int(hours * 3600.0 * rate)
    rng = np.random.default_rng(16)
    poles = bias_instability_poles(BIAS_TAU)
    variance = bias_instability_variance(BIAS, BIAS_TAU)
    decays = np.exp(-1.0 / (rate * poles))
    states = rng.standard_normal((len(poles), 3)) * math.sqrt(variance)
    walk = np.zeros(3)
    accumulator = AllanAccumulator(rate, 3, per_octave=2)
    generate_s = accumulate_s = 0.0
    done = 0
    while done < total:
        count = min(BLOCK, total - done)
        start = time.perf_counter()
        block = rng.standard_normal((count, 3)) * (WHITE * math.sqrt(rate))
        for p, decay in enumerate(decays):  # the simulator's Gauss-Markov sum, carried across blocks
            drive = rng.standard_normal((count, 3)) * math.sqrt(variance * (1.0 - decay * decay))
            out, final = lfilter([1.0], [1.0, -decay], drive, axis=0, zi=(decay * states[p])[None, :])
            states[p] = final[0]
            block += out
        steps = np.cumsum(rng.standard_normal((count, 3)) * (WALK / math.sqrt(rate)), axis=0) + walk
        walk = steps[-1]
        block += steps
        middle = time.perf_counter()
        accumulator.add(block)
        accumulate_s += time.perf_counter() - middle
        generate_s += middle - start
        done += count
    start = time.perf_counter()
    result = accumulator.result()
    model = fit_noise_model(result, source='static_run')
    finish_s = time.perf_counter() - start
    return {'samples_per_axis': total, 'accumulate_s': accumulate_s, 'result_and_fit_s': finish_s,
            'allan_s': accumulate_s + finish_s, 'generate_s': generate_s, 'averaging_times': len(result.taus),
            'exact_averaging_times': int(np.count_nonzero(result.strides == 1)), 'bin_size': int(accumulator.bin_size),
            'peak_rss_bytes': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
            'fitted_white': list(model.white_noise_density), 'fitted_bias_instability': list(model.bias_instability),
            'fitted_random_walk': list(model.random_walk)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--hours', type=float, default=15.0)
    parser.add_argument('--rate', type=float, default=1000.0)
    parser.add_argument('--child', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.hours, args.rate)))
        return 0
    started = time.perf_counter()
    done = subprocess.run([sys.executable, __file__, '--child', '--hours', str(args.hours), '--rate', str(args.rate)],
                          capture_output=True, text=True, check=True)
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    baseline = ROSBAGS_15H_S * (args.hours / 15.0) * (args.rate / 1000.0)
    figures.update(hours=args.hours, rate_hz=args.rate, wall_s=time.perf_counter() - started,
                   rosbags_baseline_s=baseline,
                   baseline_source='README: rosbags deserialises 15 h at 1 kHz in 645 s (scaled linearly to this length and rate)',
                   ratio_to_rosbags=figures['allan_s'] / baseline, target_ratio=0.3,
                   memory_target_bytes=MEMORY_TARGET_BYTES,
                   truth={'white': WHITE, 'bias_instability': BIAS, 'random_walk': WALK},
                   machine=machine())
    figures['meets_targets'] = figures['ratio_to_rosbags'] < 0.3 and figures['peak_rss_bytes'] < MEMORY_TARGET_BYTES
    RESULTS.mkdir(exist_ok=True)
    name = 'allan.json' if args.hours == 15.0 and args.rate == 1000.0 else f'allan_{args.hours:g}h.json'
    (RESULTS / name).write_text(json.dumps(figures, indent=2) + '\n')
    print(f'{figures["samples_per_axis"]:,} samples x 3 axes: Allan deviation (accumulate + fit) '
          f'{figures["allan_s"]:.1f} s = {figures["ratio_to_rosbags"]:.3f}x rosbags ({baseline:.0f} s); '
          f'peak RSS {figures["peak_rss_bytes"] / 1e6:.0f} MB; generating the samples took {figures["generate_s"]:.1f} s')
    return 0 if figures['meets_targets'] else 3


if __name__ == '__main__':
    sys.exit(main())
