"""``tak_calib import-csv``: a delimited log into a bag."""

from __future__ import annotations

import argparse

from tak_thermo_ros.cli import common, options
from tak_thermo_ros.formats.csv_log.options import MAG_UNITS
from tak_thermo_ros.formats.files import BAG
from tak_thermo_ros.core.records.static_run import STATIC_TOLERANCE_DEG
from tak_thermo_ros.core.values import STANDARD_GRAVITY
import numpy as np

NAME = 'import-csv'
OUTPUTS = (('output', BAG, '-o'),)
"""This command's outputs: ``(argument, kind, option)``, checked before any work is done."""


def add_parser(commands) -> argparse.ArgumentParser:
    """Add the command to ``tak_calib``'s subcommands."""
    parser = commands.add_parser('import-csv', help='convert a delimited log (a static thermal run, a driver log) '
                                                    'into a bag')
    parser.add_argument('log', metavar='LOG.csv')
    parser.add_argument('-o', '--output', required=True, metavar='OUT_BAG')
    parser.add_argument('--acc-columns', nargs=3, required=True, metavar=('X', 'Y', 'Z'),
                        help='the acceleration columns along the sensor axes x, y, z')
    parser.add_argument('--temp-column', help='the temperature column (degrees Celsius); optional with '
                                              '--gyro-columns (a driver that logs none), and may be constant')
    parser.add_argument('--time-column', default='timestamp', help='the time column (default: timestamp)')
    parser.add_argument('--time-unit', choices=['s', 'ms', 'us', 'ns'], default='s',
                        help='unit of the time column (default s)')
    parser.add_argument('--acc-unit', choices=['m/s^2', 'g'], default='m/s^2',
                        help='unit of the acceleration columns (1 g = 9.80665 m/s^2; default m/s^2)')
    parser.add_argument('--acc-resolution', type=options.positive, default=1e-3, metavar='M/S^2',
                        help='m/s^2 per channel count: counts = round(a / resolution) (default 0.001); '
                             'the nominal scale 1/resolution goes into the bag metadata')
    parser.add_argument('--temp-resolution', type=options.positive, default=0.01, metavar='CELSIUS',
                        help='degrees per temperature code: N_t = round(T / resolution) (default 0.01)')
    parser.add_argument('--gravity', type=options.gravity, default=STANDARD_GRAVITY,
                        help=f'local gravity, m/s^2 ({options.GRAVITY_MIN:g}..{options.GRAVITY_MAX:g}): magnitude '
                             'of the '
                             'estimated reference (default 9.80665)')
    parser.add_argument('--reference', type=options.specific_force, nargs=3, metavar=('X', 'Y', 'Z'),
                        help='the specific force in the sensor frame, m/s^2, if known (default: the mean '
                             'measured direction scaled to --gravity)')
    parser.add_argument('--delimiter', help='field delimiter: tab, comma, semicolon or one character '
                                            '(default: sniffed from the header line)')
    parser.add_argument('--frame-id', default='imu', help='frame_id of the counts messages (default imu)')
    parser.add_argument('--gyro-columns', nargs=3, metavar=('X', 'Y', 'Z'),
                        help='angular-rate columns along the sensor axes: the log becomes a driver bag '
                             '(Imu in m/s^2 and rad/s, temperature in C) instead of counts')
    parser.add_argument('--gyro-unit', choices=['rad/s', 'deg/s'], default='rad/s',
                        help='unit of the angular-rate columns (default rad/s)')
    parser.add_argument('--gyro-file', metavar='GYRO.csv',
                        help='the angular-rate columns are in this file, with its own time column (the gyroscope '
                             'logged apart at its own rate; each sensor keeps its own stamps, nothing is resampled)')
    parser.add_argument('--gyro-time-column', metavar='NAME',
                        help="--gyro-file's time column (default: --time-column), in --time-unit")
    parser.add_argument('--mag-columns', nargs=3, metavar=('X', 'Y', 'Z'),
                        help='magnetic-field columns along the sensor axes (with --gyro-columns): written as '
                             '/imu/mag in tesla at the same stamps')
    parser.add_argument('--mag-unit', choices=list(MAG_UNITS), default='T',
                        help='unit of the magnetic-field columns (1 gauss = 1e-4 T; default T)')
    parser.add_argument('--storage', choices=['mcap', 'sqlite3'], default='mcap')
    options.add_topic_options(parser)
    parser.set_defaults(handler=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Convert a delimited log of a static thermal run into a bag (counts, or a driver bag with a gyroscope)."""
    from tak_thermo_ros.formats.bag import write_driver_record, write_record
    from tak_thermo_ros.formats.csv_log.options import CsvImportOptions, delimiter_from_option
    from tak_thermo_ros.formats.csv_log.reader import read_csv_log
    options = CsvImportOptions(
        acc_columns=tuple(args.acc_columns), temp_column=args.temp_column, time_column=args.time_column,
        time_unit=args.time_unit, acc_unit=args.acc_unit, acc_resolution=args.acc_resolution,
        temp_resolution=args.temp_resolution, gravity=args.gravity,
        reference=tuple(args.reference) if args.reference else None,
        delimiter=delimiter_from_option(args.delimiter) if args.delimiter else None, frame_id=args.frame_id,
        gyro_columns=tuple(args.gyro_columns) if args.gyro_columns else None, gyro_unit=args.gyro_unit,
        gyro_file=args.gyro_file, gyro_time_column=args.gyro_time_column,
        mag_columns=tuple(args.mag_columns) if args.mag_columns else None, mag_unit=args.mag_unit)
    log = read_csv_log(args.log, options)
    record = log.record
    topics = common.topics(args)
    if log.driver is not None:
        write_driver_record(args.output, log.driver, topics=topics, storage=args.storage, force=args.force)
    else:
        write_record(args.output, record, topics=topics, storage=args.storage, force=args.force)
    print(f'read {args.log}: {log.rows} rows ({log.delimiter_name}-delimited), {log.duration_s:.1f} s '
          f'at {(log.rows - 1) / max(log.duration_s, 1e-9):.3g} Hz')
    if log.driver is not None and not log.driver.shared_stamps:
        counts = {sensor: log.driver.sensor_stamps(sensor) for sensor in ('accel', 'gyro')}
        print(f'each sensor on its own stamps, nothing resampled ({len(log.temperature)} temperatures):')
        for sensor, stamps in counts.items():
            print(f'  {common.SENSOR_NAMES[sensor]}: {len(stamps)} samples at '
                  f'{(len(stamps) - 1) / max((stamps[-1] - stamps[0]) * 1e-9, 1e-9):.3g} Hz')
    elif len(log.temperature) != log.rows or len(log.record.counts_stamp_ns) != log.rows:
        print(f'rows without a sample left empty: {len(log.record.counts_stamp_ns)} acceleration, '
              f'{len(log.temperature)} temperature samples')
    if log.driver is not None:
        _print_driver(log, options, topics)
        x, y, z = (float(v) for v in log.reference)
        if log.reference_estimated and log.max_tilt_deg > STATIC_TOLERANCE_DEG:
            print(f'no reference topic written; the board moves (up to {log.max_tilt_deg:.0f} deg from its mean '
                  f'direction): fit decides what it determines')
        elif log.reference_estimated:
            print('no reference topic written: fit takes the run as static, with zero rate and the mean direction '
                  'scaled to gravity')
            print(f'that reference here: ({x:.4f}, {y:.4f}, {z:.4f}) m/s^2; the board\'s largest deviation from it '
                  f'{log.max_tilt_deg:.2f} deg')
        else:
            print(f'reference (given): ({x:.4f}, {y:.4f}, {z:.4f}) m/s^2 on {topics.reference}, written once')
        print(f'wrote {args.output} ({args.storage})')
        return 0
    print(f'acceleration {" ".join(options.acc_columns)} in {options.acc_unit}: counts = round(a / '
          f'{options.acc_resolution:g} m/s^2), {record.counts.min():.0f}..{record.counts.max():.0f}')
    print(f'nominal scale {options.nominal_scale:g} counts/(m/s^2), in the bag\'s metadata')
    print(f'temperature {options.temp_column}: {log.temperature.min():.2f}..{log.temperature.max():.2f} C, '
          f'codes = round(T / {options.temp_resolution:g} C) = '
          f'{record.temp_code.min():.0f}..{record.temp_code.max():.0f}')
    x, y, z = (float(v) for v in log.reference)
    if log.reference_estimated:
        dx, dy, dz = (float(v) for v in log.mean_direction)
        print(f'reference (static run): mean measured direction ({dx:.5f}, {dy:.5f}, {dz:.5f}), written once')
        print(f'reference: that direction scaled to gravity {options.gravity:g} m/s^2 = '
              f'({x:.4f}, {y:.4f}, {z:.4f}) m/s^2')
        print(f'the board\'s largest deviation from that direction: {log.max_tilt_deg:.2f} deg')
    else:
        print(f'reference (given): ({x:.4f}, {y:.4f}, {z:.4f}) m/s^2 in the sensor frame, written once at the start')
    print(f'wrote {args.output} ({args.storage})')
    return 0


def _print_driver(log, options, topics) -> None:
    """What a driver bag holds: the Imu, the temperature (or none), the magnetometer; one statement a line."""
    rate = log.driver.gyro
    print(f'driver bag: {topics.raw_imu} (m/s^2, rad/s) from acceleration {" ".join(options.acc_columns)} in '
          f'{options.acc_unit}')
    print(f'driver bag: angular rate from {" ".join(options.gyro_columns)} in {options.gyro_unit}, '
          f'{rate.min():.4g}..{rate.max():.4g} rad/s')
    if not len(log.temperature):
        print(f'no temperature column: no {topics.temperature} (noise and the iron need none)')
    elif float(log.temperature.max() - log.temperature.min()) == 0.0:
        print(f'driver bag: {topics.temperature} from {options.temp_column}, constant at '
              f'{log.temperature[0]:.2f} C (no sweep)')
    else:
        print(f'driver bag: {topics.temperature} from {options.temp_column} in degrees C, '
              f'{log.temperature.min():.2f}..{log.temperature.max():.2f} C')
    if options.mag_columns:
        field = np.linalg.norm(log.driver.mag, axis=1) * 1e6
        print(f'magnetic field {" ".join(options.mag_columns)} in {options.mag_unit} as {topics.mag} in tesla '
              f'(|B| {field.min():.4g}..{field.max():.4g} uT)')
