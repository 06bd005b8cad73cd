"""What the command line prints and writes, kept to compare two versions of the code (issue 41).

A change of the house (files split, a record opened once, results that print themselves) must
not change what a user sees. This script runs the ordinary paths in a fresh directory, with the
``tak_calib`` of the interpreter that runs it:

- the demo (``demo/demo.py``: the paper's codes and a driver's unit);
- a pool of everyday records (simulate, fit, validate, diagnose, one record by path);
- the real thermal cycle of ``data/`` (import, fit, diagnose, validate; the driver form, its noise);
- a PX4 ULog and an ArduPilot DataFlash log (simulate, fit, diagnose, export, apply);

and keeps every command's output and a digest of every file it wrote or changed::

    python bench/house_check.py record OUT_DIR        # OUT_DIR/outputs.json
    python bench/house_check.py compare A.json B.json  # the commands whose output or files differ

Lines that carry a wall time (the demo's last line) are kept without their figures.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TAK_CALIB = str(Path(sys.executable).with_name('tak_calib'))
SCENARIOS = ROOT / 'docs' / 'scenarios'
CSV = ROOT / 'data' / 'tofupilot-imu-thermal' / 'imu_raw_data.csv'
ACC = ['--time-unit', 'us', '--acc-columns', 'imu.acc.x', 'imu.acc.y', 'imu.acc.z', '--temp-column',
       'imu.temperature']

COMMANDS: list[tuple[str, list[str]]] = [
    ('demo', [sys.executable, str(ROOT / 'demo' / 'demo.py')]),
    # a pool of everyday records (docs/everyday.md)
    ('pool simulate', ['simulate', 'month', '--scenario', str(SCENARIOS / 'everyday_quick.yaml')]),
    ('pool move', ['!move', 'month/rec08', 'month/rec09', 'new']),
    ('pool fit', ['fit', 'month', '-o', 'unit.yaml']),
    ('pool validate', ['validate', 'new', '--params', 'unit.yaml']),
    ('pool validate in-sample', ['validate', 'month', '--params', 'unit.yaml']),
    ('pool diagnose', ['diagnose', 'month', '--params', 'unit.yaml']),
    ('pool one record', ['fit', 'month/rec02', '-o', 'one.yaml']),
    # the real thermal cycle (docs/real_imu.md)
    ('real import', ['import-csv', str(CSV), '-o', 'real', *ACC]),
    ('real fit', ['fit', 'real', '-o', 'base.yaml', '--settle-time', '60']),
    ('real diagnose', ['diagnose', 'real', '--params', 'base.yaml', '--settle-time', '60']),
    ('real validate', ['validate', 'real', '--params', 'base.yaml']),
    ('real driver import', ['import-csv', str(CSV), '-o', 'real_driver', *ACC, '--gyro-columns', 'imu.gyro.x',
                            'imu.gyro.y', 'imu.gyro.z']),
    ('real driver fit', ['fit', 'real_driver', '-o', 'real_driver.yaml']),
    ('real driver noise', ['noise', 'real_driver', '--params', 'real_driver.yaml']),
    ('real driver lag', ['fit', 'real_driver', '--effects', 'thermal_lag', '-o', 'real_driver_lag.yaml']),
    ('real driver diagnose', ['diagnose', 'real_driver', '--params', 'real_driver.yaml']),
    # flight logs (docs/flight_logs.md)
    ('ulog simulate', ['simulate', 'warm_up.ulg', '--scenario', str(SCENARIOS / 'px4_warm_up.yaml')]),
    ('ulog fit', ['fit', 'warm_up.ulg', '-o', 'imu.yaml']),
    ('ulog diagnose', ['diagnose', 'warm_up.ulg', '--params', 'imu.yaml']),
    ('ulog export', ['export', 'imu.yaml', '--format', 'px4', '-o', 'imu.params']),
    ('ulog apply', ['apply', 'warm_up.ulg', '--params', 'imu.yaml', '-o', 'corrected']),
    ('bin simulate', ['simulate', 'warm_up.bin', '--scenario', str(SCENARIOS / 'px4_warm_up.yaml')]),
    ('bin fit', ['fit', 'warm_up.bin', '-o', 'bin.yaml']),
    ('bin export', ['export', 'bin.yaml', '--format', 'ardupilot', '-o', 'bin.parm']),
    ('bin validate', ['validate', 'warm_up.bin', '--params', 'bin.yaml']),
]
"""Each command's name and its arguments (``tak_calib``'s, or a whole command line for the demo)."""

TIMES = re.compile(r'\d+(\.\d+)? s\b')


def _files(work: Path) -> dict[str, str]:
    """A digest of every regular file under ``work`` (the demo's outputs included)."""
    return {str(path.relative_to(work)): hashlib.sha256(path.read_bytes()).hexdigest()
            for path in sorted(work.rglob('*')) if path.is_file()}


def record(out: Path) -> None:
    """Run :data:`COMMANDS` in ``out/work`` and keep their outputs in ``out/outputs.json``."""
    work = out / 'work'
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    demo_out = ROOT / 'demo_out'
    results = []
    for name, args in COMMANDS:
        if args[0] == '!move':
            target = work / args[-1]
            target.mkdir(exist_ok=True)
            for source in args[1:-1]:
                shutil.move(str(work / source), str(target))
            continue
        command = args if name == 'demo' else [TAK_CALIB, *args]
        before = _files(work)
        done = subprocess.run(command, cwd=work, capture_output=True, text=True, check=False)
        stdout = done.stdout.replace(str(work), '<work>').replace(str(ROOT), '<root>')
        if name == 'demo':
            stdout = '\n'.join(TIMES.sub('<time>', line) if 'outputs in' in line else line
                               for line in stdout.splitlines())
            shutil.copytree(demo_out, work / 'demo_out', dirs_exist_ok=True)
        results.append({'name': name, 'status': done.returncode, 'stdout': stdout,
                        'stderr': done.stderr.replace(str(work), '<work>'),
                        'files': {k: v for k, v in _files(work).items() if before.get(k) != v}})
        print(f'{name}: exit {done.returncode}, {len(stdout.splitlines())} lines', flush=True)
    (out / 'outputs.json').write_text(json.dumps(results, indent=1))


def compare(first: Path, second: Path) -> int:
    """Say which commands printed or wrote something else; 0 when none did."""
    a, b = (json.loads(path.read_text()) for path in (first, second))
    differ = 0
    for one, other in zip(a, b):
        for key in ('status', 'stdout', 'stderr'):
            if one[key] != other[key]:
                differ += 1
                print(f'{one["name"]}: {key} differs')
                if key == 'stdout':
                    lines = [(x, y) for x, y in zip(one[key].splitlines(), other[key].splitlines()) if x != y]
                    for x, y in lines[:5]:
                        print(f'  - {x}\n  + {y}')
        changed = sorted(k for k in set(one['files']) | set(other['files'])
                         if one['files'].get(k) != other['files'].get(k))
        if changed:
            differ += 1
            print(f'{one["name"]}: files differ: {", ".join(changed[:8])}')
    if len(a) != len(b):
        differ += 1
        print(f'{len(a)} commands against {len(b)}')
    print('the same: every command printed and wrote the same' if not differ else f'{differ} differences')
    return 1 if differ else 0


def main() -> int:
    """``record OUT`` or ``compare A B``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest='verb', required=True)
    sub.add_parser('record').add_argument('out', type=Path)
    both = sub.add_parser('compare')
    both.add_argument('first', type=Path)
    both.add_argument('second', type=Path)
    args = parser.parse_args()
    if args.verb == 'record':
        args.out.mkdir(parents=True, exist_ok=True)
        record(args.out)
        return 0
    return compare(args.first, args.second)


if __name__ == '__main__':
    sys.exit(main())
