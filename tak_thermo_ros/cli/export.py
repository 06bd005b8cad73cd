"""``tak_calib export``: a calibration as PX4's or ArduPilot's temperature parameters, and what they cannot carry."""

from __future__ import annotations

import argparse

from tak_thermo_ros.cli import options
from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.errors import TakError
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.formats.files import FILE

NAME = 'export'
OUTPUTS = (('output', FILE, '-o'),)
"""This command's outputs: ``(argument, kind, option)``, checked before any work is done."""
FORMATS = {'px4': 'PX4 TC_* parameters (QGroundControl .params)', 'ardupilot': 'ArduPilot INS_TCALn_* parameters'}
SLOTS = {'px4': ('PX4', 'TC_A0..3 and TC_G0..3', 4), 'ardupilot': ('ArduPilot', 'INS_TCAL1..3', 3)}
"""Per format the firmware, its sets of temperature parameters and how many (instances 0..n-1): the one bound
of ``--instance`` and of the calibration's ``source.instance``."""


def add_parser(commands) -> argparse.ArgumentParser:
    """Add the command to ``tak_calib``'s subcommands."""
    parser = commands.add_parser('export', help="write a calibration as PX4's or ArduPilot's temperature parameters")
    parser.add_argument('params', metavar='PARAMS.yaml', help='a driver calibration (tak_calib fit)')
    parser.add_argument('--format', required=True, choices=sorted(FORMATS),
                        help='px4: TC_A/TC_G parameters with the device IDs (QGroundControl .params); '
                             'ardupilot: INS_TCALn_* (NAME VALUE)')
    parser.add_argument('-o', '--output', required=True, metavar='FILE', help='FILE.params (px4) or FILE.parm')
    parser.add_argument('--instance', type=options.int_within(0, max(n for _, _, n in SLOTS.values()) - 1),
                        metavar='N',
                        help="the firmware's sensor slot: TC_An/TC_Gn (PX4, 0..3), INS_TCAL<N+1> (ArduPilot, 0..2); "
                             "default: the flight log's instance the calibration was fitted from, else 0")
    parser.add_argument('--force', action='store_true', help='replace an existing output file')
    parser.add_argument('--debug', action='store_true', default=argparse.SUPPRESS,
                        help='show the traceback of an error')
    parser.set_defaults(handler=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Write the parameters; one line for each thing the firmware's parameters leave out, with its size."""
    from tak_thermo_ros.formats.ardupilot_params import ardupilot_parameters, write_ardupilot_params
    from tak_thermo_ros.formats.px4_params import px4_parameters, write_px4_params
    unit = load_unit(args.params)
    if unit.input_kind is not InputKind.IMU:
        msg = (f'{args.params} is a calibration of the paper\'s channel codes: PX4 and ArduPilot take a driver\'s '
               f'm/s^2 and rad/s (fit a driver bag or a flight log)')
        raise TakError(msg)
    if not any(unit.sensor(sensor).needs_temperature for sensor in ('accel', 'gyro')):
        msg = (f'{args.params}: neither the accelerometer nor the gyroscope has temperature terms '
               f'({unit.accel.notes[0] if unit.accel.notes else "thermal: " + unit.accel.thermal}): nothing to export')
        raise TakError(msg)
    source = unit.source or {}
    instance = args.instance if args.instance is not None else int(source.get('instance', 0))
    firmware, sets, slots = SLOTS[args.format]
    if not 0 <= instance < slots:
        given = (f'--instance {instance}' if args.instance is not None
                 else f'{args.params}: source.instance {instance} (the flight log\'s sensor instance)')
        hint = '' if args.instance is not None else '; choose the slot with --instance N'
        msg = f'{given}: {firmware} has {sets} (instances 0..{slots - 1}){hint}'
        raise TakError(msg)
    header = (f'tak_thermo_ros: {FORMATS[args.format]} from {args.params} '
              f'(fitted from {source.get("format", "a record")}, instance {source.get("instance", "-")})')
    if args.format == 'px4':
        parameters = px4_parameters(unit, instance=instance)
        write_px4_params(args.output, parameters, header=header)
    else:
        parameters = ardupilot_parameters(unit, instance=instance)
        write_ardupilot_params(args.output, parameters, header=header)
    for line in parameters.lines:
        print(line)
    print(f'wrote {len(parameters.values)} parameters to {args.output}')
    if args.format == 'px4':
        for line in px4_loading_lines(parameters, instance):
            print(line)
    return 0


def px4_loading_lines(parameters, instance: int) -> list[str]:
    """How PX4 takes the file: loaded in QGroundControl, a reboot, then its own calibrations redone.

    After a thermal calibration PX4's standard accelerometer and gyroscope calibrations write the
    constant offset into ``TC_*_X0`` (the thermal parameters then hold every calibration); the
    polynomial's drift terms stay as exported.
    """
    low = max(cubic.low for cubic in parameters.cubics.values())
    high = min(cubic.high for cubic in parameters.cubics.values())
    return ['PX4: load it in QGroundControl (Parameters, Tools, Load from file), then reboot the board',
            f'PX4: then redo the accelerometer and gyroscope calibrations, the board at {low:.1f}..{high:.1f} C',
            f'PX4: they write the constant offset into TC_A{instance}_X0_* and TC_G{instance}_X0_* (X0 '
            f'holds it here)',
            'PX4: the drift with temperature, X1..X3, stays as exported']
