"""``tak_calib``: simulate chamber runs, fit, apply and validate the correction link.

Every deliberate failure prints one line ``tak_calib: error: ...`` and exits with status 2;
no traceback reaches the user.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Callable, Sequence

from tak_thermo_ros.core.calibration_file import load_calibration, save_calibration, write_text_atomic
from tak_thermo_ros.core.correction import Corrector, OutOfRange, acceleration_variance
from tak_thermo_ros.core.fit import fit_calibration
from tak_thermo_ros.core.model import AXES
from tak_thermo_ros.core.record import align
from tak_thermo_ros.core.simulate import STANDARD_GRAVITY, Scenario, load_scenario, simulate
from tak_thermo_ros.core.validate import validate_gravity
from tak_thermo_ros.errors import TakError

EXIT_ERROR = 2


def _topics(args: argparse.Namespace):
    from tak_thermo_ros.bagio import Topics
    return Topics(counts=args.counts_topic, temp_code=args.temp_topic,
                  reference=args.reference_topic, imu=getattr(args, 'imu_topic', Topics.imu))


def _add_topic_options(parser: argparse.ArgumentParser, *, imu: bool = False) -> None:
    parser.add_argument('--counts-topic', default='/tak/counts', help='channel codes (Vector3Stamped)')
    parser.add_argument('--temp-topic', default='/tak/temp_code', help='temperature-sensor codes (Temperature)')
    parser.add_argument('--reference-topic', default='/tak/reference', help='true specific force (Vector3Stamped)')
    if imu:
        parser.add_argument('--imu-topic', default='/tak/imu/data_raw', help='corrected output (Imu)')
    parser.add_argument('--no-progress', action='store_true', help='no progress bar even on a terminal')


def _out_of_range(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--out-of-range', choices=[p.value for p in OutOfRange], default=OutOfRange.CLAMP.value,
                        help='temperature codes outside the calibrated range: clamp to the edge (default) '
                             'or extrapolate the polynomials; either way the count is reported')


def cmd_simulate(args: argparse.Namespace) -> int:
    """Simulate a chamber run into a bag."""
    from tak_thermo_ros.bagio import write_record
    scenario = load_scenario(args.scenario) if args.scenario else Scenario()
    if args.seed is not None:
        from dataclasses import replace
        scenario = replace(scenario, seed=args.seed)
    run = simulate(scenario)
    write_record(args.out_bag, run.record, topics=_topics(args), storage=args.storage)
    record = run.record
    print(f'wrote {args.out_bag}: {len(record.counts_stamp_ns)} counts, {len(record.temp_stamp_ns)} temperature codes, '
          f'{len(record.reference_stamp_ns)} reference changes, {scenario.duration_s() / 3600.0:.2f} h '
          f'at {scenario.sample_rate_hz:g} Hz ({args.storage}); temperature code '
          f'{record.temp_code.min():.0f}..{record.temp_code.max():.0f}')
    return 0


def _describe_dropped(dropped: dict[str, int]) -> str:
    return ', '.join(f'{count} {reason.replace("_", " ")}' for reason, count in sorted(dropped.items()))


def cmd_fit(args: argparse.Namespace) -> int:
    """Fit the correction link to a calibration bag."""
    from tak_thermo_ros.bagio import read_record
    record = read_record(args.bag, topics=_topics(args), require_reference=True, progress=not args.no_progress)
    samples = align(record, settle_time_s=args.settle_time)
    nominal = record.nominal_scale
    if args.nominal_scale is not None:
        nominal = tuple(args.nominal_scale * 3 if len(args.nominal_scale) == 1 else args.nominal_scale)
        if len(nominal) != 3:
            raise TakError('--nominal-scale takes one value or three (x y z)')
    result = fit_calibration(samples, bias_order=args.bias_order, scale_order=args.scale_order,
                             temp_code_ref=args.temp_code_ref, nominal_scale=nominal)
    calibration = result.calibration
    header = (f'tak_thermo_ros calibration fitted from {args.bag}\n'
              f'{result.samples} samples, bias order {args.bias_order}, scale order {args.scale_order}\n'
              f'load with: ros2 run tak_thermo_ros compensator --ros-args --params-file {Path(args.output).name}')
    save_calibration(args.output, calibration, header=header)
    print(f'fitted {result.samples} samples from {args.bag}')
    if result.dropped:
        print(f'left out: {_describe_dropped(result.dropped)}')
    print(f'calibrated temperature-code range {calibration.temp_code_min:g}..{calibration.temp_code_max:g}, '
          f'reference {calibration.temp_code_ref:g}')
    for name, axis, stats in zip(AXES, calibration.axes, result.axes):
        print(f'  {name}: residual RMS {stats.residual_rms:.3f} counts '
              f'({stats.residual_rms / axis.scale * 1000.0:.3f} mm/s^2); scale {axis.scale:.4f} counts/(m/s^2), '
              f'offset {axis.offset:.3f}, offset span {axis.offset_span:.3f} counts')
    for note in calibration.notes:
        print(f'note: {note}')
    print(f'wrote {args.output}')
    return 0


def cmd_apply(args: argparse.Namespace) -> int:
    """Correct a bag's counts and write Imu messages."""
    from tak_thermo_ros.bagio import read_record, write_imu
    calibration = load_calibration(args.params)
    record = read_record(args.bag, topics=_topics(args), progress=not args.no_progress)
    samples = align(record, use_reference=False)
    corrector = Corrector(calibration, out_of_range=OutOfRange(args.out_of_range))
    acceleration = corrector.correct(samples.counts, samples.temp_code)
    write_imu(args.output, samples.stamp_ns, record.frame_id, acceleration,
              acceleration_variance(calibration), topic=args.imu_topic, storage=args.storage)
    print(f'wrote {len(samples)} Imu messages on {args.imu_topic} to {args.output}')
    if samples.dropped:
        print(f'dropped counts messages: {_describe_dropped(samples.dropped)}')
    outside = corrector.out_of_range_count(samples.temp_code)
    if outside:
        print(f'warning: {outside} samples had a temperature code outside the calibrated range '
              f'{calibration.temp_code_min:g}..{calibration.temp_code_max:g} ({args.out_of_range})')
    return 0


def cmd_validate(args: argparse.Namespace) -> int:
    """|g| from the three channels before and after correction."""
    from tak_thermo_ros.bagio import read_record
    calibration = load_calibration(args.params)
    record = read_record(args.bag, topics=_topics(args), progress=not args.no_progress)
    samples = align(record, use_reference=False)
    result = validate_gravity(calibration, samples.counts, samples.temp_code, gravity=args.gravity,
                              out_of_range=OutOfRange(args.out_of_range))
    before, after = result.before, result.after
    print(f'|g| error over {len(samples)} samples of {args.bag} (gravity {args.gravity:g} m/s^2):')
    print(f'  before (nominal scale and offset): RMS {before.rms:.5f} m/s^2 ({before.rms / args.gravity * 1e3:.3f} mg), '
          f'max {before.max:.5f} m/s^2')
    print(f'  after  (full correction link):     RMS {after.rms:.5f} m/s^2 ({after.rms / args.gravity * 1e3:.3f} mg), '
          f'max {after.max:.5f} m/s^2')
    if result.out_of_range:
        print(f'warning: {result.out_of_range} samples outside the calibrated temperature-code range ({args.out_of_range})')
    if args.json:
        document = {'bag': str(args.bag), 'params': str(args.params), 'gravity': args.gravity,
                    'samples': len(samples), 'out_of_range': result.out_of_range,
                    'before': before.as_dict(), 'after': after.as_dict()}
        write_text_atomic(args.json, json.dumps(document, indent=2) + '\n')
        print(f'wrote {args.json}')
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The ``tak_calib`` argument parser."""
    parser = argparse.ArgumentParser(prog='tak_calib', description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')

    sim = commands.add_parser('simulate', help='simulate a thermal-chamber run into a bag')
    sim.add_argument('out_bag', metavar='OUT_BAG')
    sim.add_argument('--scenario', metavar='FILE.yaml', help='scenario overrides (see config/scenario_example.yaml)')
    sim.add_argument('--seed', type=int, help='random seed (overrides the scenario)')
    sim.add_argument('--storage', choices=['mcap', 'sqlite3'], default='mcap')
    _add_topic_options(sim)
    sim.set_defaults(handler=cmd_simulate)

    fit = commands.add_parser('fit', help='fit the correction link to a calibration bag')
    fit.add_argument('bag', metavar='BAG')
    fit.add_argument('-o', '--output', required=True, metavar='PARAMS.yaml')
    fit.add_argument('--bias-order', type=int, default=3, help='order q of F_s (default 3)')
    fit.add_argument('--scale-order', type=int, default=2, help='order p of F_c (default 2; 0 = no scale drift)')
    fit.add_argument('--temp-code-ref', type=float, help='N_t,ref (default: middle of the calibrated range)')
    fit.add_argument('--nominal-scale', type=float, nargs='+', metavar='K0',
                     help='nominal counts per m/s^2 (one value or x y z), held for an axis that sees one '
                          'input only; default: the bag metadata written by simulate / import-csv')
    fit.add_argument('--settle-time', type=float, default=0.0, metavar='SECONDS',
                     help='leave out samples this long after each reference change (turntable settling)')
    _add_topic_options(fit)
    fit.set_defaults(handler=cmd_fit)

    app = commands.add_parser('apply', help='correct a bag, writing sensor_msgs/msg/Imu')
    app.add_argument('bag', metavar='BAG')
    app.add_argument('--params', required=True, metavar='PARAMS.yaml')
    app.add_argument('-o', '--output', required=True, metavar='OUT_BAG')
    app.add_argument('--storage', choices=['mcap', 'sqlite3'], default='mcap')
    _out_of_range(app)
    _add_topic_options(app, imu=True)
    app.set_defaults(handler=cmd_apply)

    val = commands.add_parser('validate', help='|g| from the three channels before and after correction')
    val.add_argument('bag', metavar='BAG')
    val.add_argument('--params', required=True, metavar='PARAMS.yaml')
    val.add_argument('--gravity', type=float, default=STANDARD_GRAVITY, help='local gravity, m/s^2')
    val.add_argument('--json', metavar='OUT.json', help='also write the figures as JSON')
    _out_of_range(val)
    _add_topic_options(val)
    val.set_defaults(handler=cmd_validate)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``tak_calib``."""
    parser = build_parser()
    args = parser.parse_args(argv)
    handler: Callable[[argparse.Namespace], int] = args.handler
    try:
        return handler(args)
    except TakError as err:
        print(f'tak_calib: error: {err}', file=sys.stderr)
        return EXIT_ERROR
    except OSError as err:
        where = f'{err.filename}: ' if err.filename else ''
        print(f'tak_calib: error: {where}{err.strerror or err}', file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print('tak_calib: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
