"""``tak_calib noise``: each sensor's per-axis noise model (Allan deviation), a Kalibr imu.yaml."""

from __future__ import annotations

import argparse

from tak_thermo_ros.cli import common, options
from tak_thermo_ros.core.link.model import AXES
from tak_thermo_ros.core.diagnose.yardstick import tau_text
from tak_thermo_ros.core.link.correction import OutOfRange
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.formats.files import FILE
from tak_thermo_ros.formats.files import write_json

NAME = 'noise'
OUTPUTS = (('output', FILE, '-o'), ('json', FILE, '--json'))
"""This command's outputs: ``(argument, kind, option)``, checked before any work is done."""


def add_parser(commands) -> argparse.ArgumentParser:
    """Add the command to ``tak_calib``'s subcommands."""
    parser = commands.add_parser('noise', help='per-axis noise model (Allan deviation) of each sensor; Kalibr imu.yaml')
    parser.add_argument('bag', metavar='BAG')
    parser.add_argument('--params', metavar='PARAMS.yaml',
                        help='a calibration: the noise of the thermally compensated output (default: the raw output)')
    parser.add_argument('-o', '--output', metavar='IMU.yaml', help='write the models as a Kalibr-style imu.yaml')
    parser.add_argument('--json', metavar='OUT.json', help='write the models and the Allan deviations as JSON')
    parser.add_argument('--settle-time', type=options.seconds_not_negative, default=0.0, metavar='SECONDS',
                        help='leave out samples this long after each reference change (a table settling; '
                             'the gaps are counted, the samples taken as evenly spaced)')
    options.add_static_options(parser)
    options.add_out_of_range(parser)
    options.add_topic_options(parser)
    parser.set_defaults(handler=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Each sensor's per-axis noise model (Allan deviation, IEEE 952 fit), streamed; a Kalibr-style imu.yaml."""
    from tak_thermo_ros.formats.kalibr import write_kalibr
    from tak_thermo_ros.formats.records import open_record
    from tak_thermo_ros.passes.noise import noise_bag, noise_document
    unit = load_unit(args.params) if args.params else None
    run = noise_bag(open_record(args.bag, topics=common.topics(args)), common.stream_options(args), unit=unit,
                    gravity=args.gravity, latitude=getattr(args, 'latitude', None),
                    out_of_range=OutOfRange(args.out_of_range), settle_time_s=args.settle_time,
                    expect_kind=(lambda kind: common.check_kind(args, unit, kind)) if unit is not None else None)
    common.print_survey(run.survey, 'noise')
    for line in run.reference_lines:
        print(line)
    what = ('the thermally compensated output (--params) minus the reference' if run.compensated else
            'the measured output minus the reference, NOT compensated (no --params)')
    print(f'noise of {args.bag}: {what}')
    if not run.compensated:
        print('not compensated: any thermal drift in the run counts as bias wander here')
    document: dict[str, object] = {'bag': str(args.bag), 'params': args.params, 'compensated': run.compensated,
                                   'sensors': {}}
    for sensor, noise in run.sensors.items():
        allan, model = noise.allan, noise.model
        unit_name = 'm/s^2' if sensor == 'accel' else 'rad/s'
        print(f'{common.SENSOR_NAMES[sensor]}: {allan.samples} samples at {allan.rate:.3g} Hz, averaging times '
              f'{tau_text(allan.taus[0])} to {tau_text(allan.taus[-1])}')
        print(f'  source {model.source}: {common.SOURCE_WORDS[model.source]}{noise.span_words}')
        if model.source == 'residual':
            print('  what no thermal model removes of its drift counts as noise here')
        if noise.dropped:
            print(f'  left out: {common.describe_dropped(noise.dropped)}')
        if noise.gaps:
            print(f'  {noise.gaps} gaps in the stamps (about {noise.missing} samples missing): the samples are '
                  f'taken as evenly spaced')
        if noise.out_of_range:
            print(f'  warning: {noise.out_of_range} samples outside the calibrated temperature range '
                  f'({args.out_of_range})')
        for i, name in enumerate(AXES):
            for line in common.noise_axis_lines(sensor, model, i, unit_name, noise.fit):
                print(f'  {name}: {line}')
        if noise.fit is not None:
            print(f'  {common.noise_slope_line(noise.fit)}')
        document['sensors'][sensor] = noise_document(noise)  # type: ignore[index]
    if args.output:
        header = (f'noise model of {args.bag} ('
                  f'{"thermally compensated with " + args.params if run.compensated else "not compensated"}), '
                  f'tak_calib noise\nKalibr keys: the largest axis; per axis (x, y, z) under *_xyz')
        write_kalibr(args.output, run.models, rostopic=run.topic, header=header, force=args.force)
        print(f'wrote {args.output}')
    if args.json:
        write_json(args.json, document)
        print(f'wrote {args.json}')
    return 0
