"""``tak_calib apply``: correct a record with a calibration file, writing a bag."""

from __future__ import annotations

import argparse

from tak_thermo_ros.cli import common, options
from tak_thermo_ros.core.link.correction import OutOfRange
from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.formats.files import BAG
from tak_thermo_ros.errors import TakError

NAME = 'apply'


def output_kind(args: argparse.Namespace) -> str | None:
    """A bag; ``None`` for a pool of records (a directory of bags, one per record, checked by :func:`_apply_pool`)."""
    from tak_thermo_ros.passes.pool_records import is_pool
    return None if is_pool(args.bag) else BAG


OUTPUTS = (('output', output_kind, '-o'),)
"""This command's outputs: ``(argument, kind, option)``, checked before any work is done."""


def add_parser(commands) -> argparse.ArgumentParser:
    """Add the command to ``tak_calib``'s subcommands."""
    parser = commands.add_parser('apply', help='correct a bag, writing sensor_msgs/msg/Imu')
    parser.add_argument('bag', metavar='BAG', nargs='+',
                        help='a record; several records, or a directory of them: each corrected into OUT_BAG/NAME')
    parser.add_argument('--params', required=True, metavar='PARAMS.yaml')
    parser.add_argument('-o', '--output', required=True, metavar='OUT_BAG',
                        help='the corrected bag (several records: a directory of corrected bags)')
    parser.add_argument('--storage', choices=['mcap', 'sqlite3'], default='mcap')
    options.add_out_of_range(parser)
    group = parser.add_argument_group("a run's turn-on offset (the node's turn_on and latitude)")
    group.add_argument('--turn-on', choices=['none', 'first-rest'], default='none',
                       help="first-rest: take the run's turn-on offset at its first rest (judged against the "
                            "calibration's turn_on repeatability) and subtract it from then on, as the node does")
    group.add_argument('--latitude', type=options.latitude, metavar='DEG',
                       help="the Earth rate's vertical part and gravity at rest (with --turn-on; the node's latitude)")
    options.add_topic_options(parser, imu=True)
    parser.set_defaults(handler=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Correct a bag's counts or driver Imu and write Imu messages (block by block, bounded memory)."""
    from tak_thermo_ros.formats.records import open_record
    from tak_thermo_ros.passes.apply import TurnOnSettings, apply_bag
    from tak_thermo_ros.passes.pool_records import is_pool
    unit = load_unit(args.params)
    if is_pool(args.bag):
        return _apply_pool(args, unit)
    args.bag = args.bag[0]
    topics = common.topics(args)
    record = open_record(args.bag, topics=topics)
    kind = record.kind
    common.check_kind(args, unit, kind)
    applied = apply_bag(record, unit, args.output, common.stream_options(args), storage=args.storage,
                        out_of_range=OutOfRange(args.out_of_range), force=args.force,
                        turn_on=TurnOnSettings(args.latitude) if args.turn_on == 'first-rest' else None)
    common.print_survey(applied.survey, 'apply')
    print(f'wrote {applied.written} Imu messages on {applied.topic} to {args.output}')
    if args.turn_on == 'first-rest':
        for line in applied.turn_on or ('turn-on offset: no rest found, nothing taken',):
            print(line)
    if applied.sensor_written:
        carried = ', '.join(f'{count} {common.SENSOR_NAMES[sensor]}'
                            for sensor, count in applied.sensor_written.items())
        print(f'each sensor on its own stamps: messages carry {carried} samples')
        print('a message without a sensor marks it absent: its covariance[0] = -1 (sensor_msgs/Imu)')
        for sensor, dropped in applied.sensor_dropped.items():
            if dropped:
                print(f'dropped {common.SENSOR_NAMES[sensor]} samples: {common.describe_dropped(dropped)}')
    if kind is InputKind.IMU and unit.mag is None:
        from tak_thermo_ros.passes.magnetometer import has_mag
        if has_mag(record):
            print(f'note: {args.params} holds no magnetometer: {topics.mag} is not corrected (nothing written for it)')
    if applied.mag_written or applied.mag_topic:
        print(f'wrote {applied.mag_written} MagneticField messages on {applied.mag_topic}')
        if applied.mag_dropped:
            print(f'dropped MagneticField messages: {common.describe_dropped(applied.mag_dropped)}')
    common.print_ignored(applied, args, kind)
    if applied.dropped:
        what = 'counts' if kind is InputKind.COUNTS else 'Imu'
        print(f'dropped {what} messages: {common.describe_dropped(applied.dropped)}')
    outside = applied.out_of_range
    if outside:
        low, high = unit.accel.temp_code_min, unit.accel.temp_code_max
        what = 'temperature code' if kind is InputKind.COUNTS else 'temperature'
        print(f'warning: {outside} samples had a {what} outside the calibrated range '
              f'{low:g}..{high:g} ({args.out_of_range})')
    return 0


def _apply_pool(args: argparse.Namespace, unit) -> int:
    """Each record of a pool corrected into its own bag, ``OUT/NAME``: one line per record."""
    from pathlib import Path
    from tak_thermo_ros.formats.records import open_record
    from tak_thermo_ros.passes.apply import TurnOnSettings, apply_bag
    from tak_thermo_ros.passes.pool_records import RECORD_SUFFIXES, bag_directory, record_paths
    records, lines = record_paths(args.bag)
    opened = [open_record(path, topics=common.topics(args)) for path in records]
    for path, record in zip(records, opened):
        common.check_kind(argparse.Namespace(**{**vars(args), 'bag': str(path)}), unit, record.kind)
    names = [Path(path).stem if Path(path).suffix.lower() in RECORD_SUFFIXES else Path(path).name for path in records]
    if len(set(names)) < len(names):
        msg = f'{args.output} (-o): two records are named alike ({", ".join(sorted(names))}): rename one'
        raise TakError(msg)
    out = bag_directory(args.output, force=args.force, option='-o')
    for line in lines:
        print(line)
    for record, name in zip(opened, names):
        applied = apply_bag(record, unit, out / name, common.stream_options(args), storage=args.storage,
                            out_of_range=OutOfRange(args.out_of_range),
                            turn_on=TurnOnSettings(args.latitude) if args.turn_on == 'first-rest' else None)
        outside = f', {applied.out_of_range} outside the calibrated range' if applied.out_of_range else ''
        dropped = f', dropped {common.describe_dropped(applied.dropped)}' if applied.dropped else ''
        print(f'{name}: wrote {applied.written} Imu messages on {applied.topic} to {out / name}{outside}{dropped}')
        if args.turn_on == 'first-rest':  # each record is a power-up of its own: its own turn-on offset
            for line in applied.turn_on or ('turn-on offset: no rest found, nothing taken',):
                print(f'{name}: {line}')
    return 0
