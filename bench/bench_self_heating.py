"""Benchmark: a self-heating static run, compensated, as the yardstick (issue 31, item 6), over many seeds.

Per seed the story of ``test/passes/test_self_heating.py``: the rate-table run of a wandering unit at 5 Hz
(with the small gyroscope lag, and without it), fitted; an hour's static run of the same unit
warming by itself from 20 to 26 C; ``diagnose --noise-run`` of the fitted run against it:

- **the lag named**: the share of seeds whose gyroscope verdict is ``thermal_lag``, or its form held
  at zero on y, ``thermal_lag[xz]`` (the unit's lag is on x and z; the noise run labelled
  ``static_run``); how many of them are the held form, and whether any holds an axis with the lag;
- **wander alone**: the share of seeds whose verdicts are ``none`` on both sensors, and how many
  are ``unexplained``.

Run: ``.venv/bin/python bench/bench_self_heating.py [--seeds 20]``. Writes
``bench/results/self_heating.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from benchlib import machine

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))

from passes.test_self_heating import LAG_SLOPE, story  # noqa: E402

RESULTS = Path(__file__).resolve().parent / 'results'


def main() -> None:
    """Every seed's two stories, and the shares."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', type=int, default=20)
    args = parser.parse_args()
    start = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for seed in range(100, 100 + args.seeds):
            lag = story(Path(scratch) / f'lag{seed}', seed, LAG_SLOPE)
            wander = story(Path(scratch) / f'wander{seed}', seed, 0.0)
            row = {'seed': seed, 'sources': sorted({v['noise']['source'] for v in lag['sensors'].values()}),
                   'lag': {s: v['verdict'] for s, v in lag['sensors'].items()},
                   'wander': {s: v['verdict'] for s, v in wander['sensors'].items()}}
            rows.append(row)
            print(f'seed {seed}: noise run {row["sources"]}, lag {row["lag"]}, wander {row["wander"]}', flush=True)
    named = sum(row['lag']['gyro'] in ('thermal_lag', 'thermal_lag[xz]') for row in rows)
    held = sum(row['lag']['gyro'] == 'thermal_lag[xz]' for row in rows)
    wrong_hold = sum(row['lag']['gyro'].startswith('thermal_lag[') and row['lag']['gyro'] != 'thermal_lag[xz]'
                     for row in rows)
    quiet = sum(set(row['wander'].values()) == {'none'} for row in rows)
    unexplained = sum('unexplained' in row['wander'].values() for row in rows)
    static = sum(row['sources'] == ['static_run'] for row in rows)
    document = {'machine': machine(), 'seconds': time.perf_counter() - start, 'seeds': args.seeds,
                'noise_run_static': static, 'lag_named': named, 'lag_named_held_on_y': held,
                'lag_held_on_an_axis_with_the_lag': wrong_hold, 'wander_none': quiet,
                'wander_unexplained': unexplained, 'rows': rows}
    print(f'noise run static_run {static}/{args.seeds}; lag named {named}/{args.seeds} ({held} as thermal_lag[xz], '
          f'{wrong_hold} held on an axis with the lag); wander none '
          f'{quiet}/{args.seeds}, unexplained {unexplained}/{args.seeds}')
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / 'self_heating.json').write_text(json.dumps(document, indent=2) + '\n')
    print(f'wrote {RESULTS / "self_heating.json"}')


if __name__ == '__main__':
    main()
