"""Run every benchmark script ``bench/bench_*.py`` with its default options, then summarise.

Each script prints its figures, writes ``bench/results/<name>.json`` and exits 0 when its
targets hold, 3 (``TARGET_MISSED``) when one is missed; any other status is a failure (a
Python traceback exits 1, an argparse error 2). ``make bench`` runs this.

Run: ``.venv/bin/python bench/run_all.py [NAME ...]`` (names like ``fit`` or ``bench_fit``
select scripts; default all).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

BENCH = Path(__file__).resolve().parent
TARGET_MISSED = 3


def discover(names: list[str]) -> list[Path]:
    """The benchmark scripts to run, sorted; ``names`` filters them (``fit`` = ``bench_fit``)."""
    scripts = sorted(BENCH.glob('bench_*.py'))
    if not names:
        return scripts
    wanted = {name.removesuffix('.py') for name in names}
    wanted |= {f'bench_{name}' for name in wanted}
    chosen = [script for script in scripts if script.stem in wanted]
    unknown = sorted(name for name in names
                     if not any(script.stem in (name.removesuffix('.py'), f'bench_{name}') for script in chosen))
    if unknown:
        available = ', '.join(script.stem for script in scripts) or 'none'
        msg = f'no benchmark {", ".join(unknown)} (available: {available})'
        raise SystemExit(msg)
    return chosen


def main(argv: list[str] | None = None) -> int:
    """Run the scripts one after the other (they time themselves: never in parallel)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('names', nargs='*', metavar='NAME', help='benchmarks to run (default all)')
    args = parser.parse_args(argv)
    scripts = discover(args.names)
    if not scripts:
        print(f'no bench_*.py in {BENCH}')
        return 1
    outcomes = []
    for script in scripts:
        print(f'=== {script.name} ===', flush=True)
        start = time.perf_counter()
        status = subprocess.run([sys.executable, str(script)], check=False).returncode
        outcomes.append((script.stem, status, time.perf_counter() - start))
        print(flush=True)
    print('=== summary ===')
    verdicts = {0: 'targets hold', TARGET_MISSED: 'TARGET MISSED'}
    for name, status, seconds in outcomes:
        print(f'{name:24s} {verdicts.get(status, f"FAILED (exit {status})"):24s} {seconds:8.1f} s')
    print(f'results in {BENCH / "results"}')
    return 0 if all(status == 0 for _, status, _ in outcomes) else 1


if __name__ == '__main__':
    sys.exit(main())
