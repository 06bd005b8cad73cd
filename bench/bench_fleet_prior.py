"""Benchmark: a new unit's first hour with its fleet's prior, over seeds, beside the hour alone, the mean, the chamber.

Issue 40's Done-when: simulated fleets (units of one part, their offsets, slopes, curvatures and cubic
terms drawn around the part's; everyday records), at least 20 seeds: a new unit's first hour with the
prior, applied to its later held-out records (most outside the hour's temperatures): the gyroscope's
bias shape at rests within 2.5x the floor, the accelerometer's ``|f|`` no worse than its own chamber
calibration; beside the hour alone and the fleet's mean alone. Leaving each unit out in turn: the
coverage of the prior's band. The figures per seed come from :mod:`fleet_prior_check` (read it for
what is measured).

Cases (``--case``): ``default``, the everyday simulator's habits the feature was built on;
``other``, another setting of the habits (shorter rests, longer motions that cool the board, more
self-heating, a faster board, more tilt: the judge of the claim); ``shapes``, a fleet whose
curvatures and cubic terms differ three to five times more (what one warm-up cannot pin is then
larger: the limit of borrowing); ``groups`` (not run by default), 16 units in two groups of slopes 8
spreads apart (the mixture, and the new unit placed in its group by its first hour).

Run: ``nice -n 10 .venv/bin/python bench/bench_fleet_prior.py [--seeds 20] [--case default other shapes]``;
writes ``bench/results/fleet_prior.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import machine  # noqa: E402
from fleet_prior_check import check_seed, show, summary  # noqa: E402

from tak_thermo_ros.core.simulation.fleet import Fleet  # noqa: E402
from tak_thermo_ros.formats.files import write_json  # noqa: E402

RESULTS = Path(__file__).resolve().parent / 'results'
CASES = {
    'default': ('default', Fleet(), {}),
    'other': ('other', Fleet(), {}),
    'shapes': ('default', Fleet(gyro=(5.0e-4, 6.5e-5, 6.0e-7, 1.5e-8), accel=(0.02, 4.0e-4, 5.4e-6, 1.2e-7)), {}),
    'groups': ('default', Fleet(groups=2, group_slope=8.0), {'units': 16, 'records': 3}),
}
"""Per case: the habits' setting, the fleet, what it changes of ``--units`` and ``--records``."""


def main(argv: list[str] | None = None) -> int:
    """Run the cases over the seeds; print and write the summary."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', type=int, default=20)
    parser.add_argument('--first-seed', type=int, default=1)
    parser.add_argument('--units', type=int, default=8)
    parser.add_argument('--records', type=int, default=5)
    parser.add_argument('--minutes', type=float, default=30.0)
    parser.add_argument('--rate', type=float, default=10.0, help='Hz (the rests\' noise is per rest: the ratios hold)')
    parser.add_argument('--case', nargs='+', default=['default', 'other', 'shapes'], choices=list(CASES))
    parser.add_argument('--output', type=Path, default=RESULTS / 'fleet_prior.json')
    args = parser.parse_args(argv)
    document = {'machine': machine(), 'units': args.units, 'records': args.records, 'minutes': args.minutes,
                'rate_hz': args.rate, 'cases': {}}
    for case in args.case:
        setting, fleet, sizes = CASES[case]
        units, records = sizes.get('units', args.units), sizes.get('records', args.records)
        rows = []
        start = time.process_time()
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            rows.append(check_seed(seed, units=units, records=records, setting=setting, minutes=args.minutes,
                                   rate_hz=args.rate, fleet=Fleet(**{**fleet.__dict__, 'units': units + 1})))
            print(f'{case} seed {seed}: prior {rows[-1]["figures"]["prior"]["gyro_shape_rms"] * 206264.8:.1f} '
                  f'deg/h, floor {rows[-1]["figures"]["truth"]["gyro_shape_rms"] * 206264.8:.1f} deg/h', flush=True)
        result = summary(rows)
        result['cpu_s'] = time.process_time() - start
        result['fleet'] = {'gyro': list(fleet.gyro), 'accel': list(fleet.accel)}
        result['rows'] = rows
        document['cases'][case] = result
        print(f'{case}:')
        for line in show(result):
            print(line)
        write_json(args.output, document)
    return 0


if __name__ == '__main__':
    sys.exit(main())
