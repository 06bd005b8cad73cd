"""Benchmark: the step scan (issue 31) over many seeds of coloured noise: false steps, and steps found.

Per case (white noise of 1 per sample at 2 Hz, plus the simulator's bias instability and random
walk: the cases of ``test/core/records/test_steps.py``), ``--seeds`` runs of 8,400 samples (the real cycle's
length) on three channels:

- **false steps**: the runs on which :func:`~tak_thermo_ros.core.records.steps.find_steps` names
  any step (target: at most 1 %), and the largest change over the record's own spread seen;
- **steps found**: a step on two channels at a random sample, 12 times the spread of the noise's
  own level changes over 8 samples on each side: the share found within 2 samples of it, with
  both channels named and the sizes within 4 of their sigmas.

Run: ``.venv/bin/python bench/bench_steps.py [--seeds 500]``. Writes ``bench/results/steps.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from benchlib import machine

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))

from core.records.test_steps import WANDERS, coloured, with_step  # noqa: E402

from tak_thermo_ros.core.records.steps import find_steps  # noqa: E402

COUNT = 8400
RESULTS = Path(__file__).resolve().parent / 'results'


def case(name: str, seeds: int) -> dict[str, object]:
    """False steps and steps found over ``seeds`` runs of one case."""
    instability, walk = WANDERS[name]
    false_steps, largest, found = 0, 0.0, 0
    for seed in range(seeds):
        noise = coloured(10_000 + seed, COUNT, instability, walk)
        steps = find_steps(noise, threshold=0.0, max_steps=1)
        largest = max(largest, float(np.abs(steps[0].z).max()) if steps else 0.0)
        false_steps += bool(find_steps(noise))
        with_noise, index, size = with_step(noise, seed)
        stepped = find_steps(with_noise)
        hit = [s for s in stepped if abs(s.index - index) <= 2]
        found += bool(hit and set(hit[0].named) == {0, 2}
                      and np.all(np.abs(hit[0].amplitude - size) < 4.0 * hit[0].sigma))
    result = {'runs': seeds, 'false_steps': false_steps, 'false_rate': false_steps / seeds,
              'largest_null_z': largest, 'found': found, 'found_rate': found / seeds}
    print(f'{name}: false steps {false_steps}/{seeds}, largest null z {largest:.2f}, '
          f'found {found}/{seeds}', flush=True)
    return result


def main() -> None:
    """Run every case and write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', type=int, default=500)
    args = parser.parse_args()
    start = time.perf_counter()
    results = {name: case(name, args.seeds) for name in WANDERS}
    document = {'machine': machine(), 'samples': COUNT, 'seconds': time.perf_counter() - start, 'cases': results}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / 'steps.json').write_text(json.dumps(document, indent=2) + '\n')
    print(f'wrote {RESULTS / "steps.json"}')


if __name__ == '__main__':
    main()
