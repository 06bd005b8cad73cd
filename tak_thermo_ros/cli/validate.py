"""``tak_calib validate``: the error before and after correction on a run the fit did not see."""

from __future__ import annotations

import argparse

from tak_thermo_ros.cli import common, options
from tak_thermo_ros.core.link.correction import OutOfRange
from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.core.link.model import UnitCalibration
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.formats.files import FILE
from tak_thermo_ros.formats.files import write_text_atomic
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import TakError
from tak_thermo_ros.units import in_reader_unit, readables
import numpy as np

NAME = 'validate'
OUTPUTS = (('json', FILE, '--json'),)
"""This command's outputs: ``(argument, kind, option)``, checked before any work is done."""


def add_parser(commands) -> argparse.ArgumentParser:
    """Add the command to ``tak_calib``'s subcommands."""
    parser = commands.add_parser('validate', help='|g| from the three channels before and after correction')
    parser.add_argument('bag', metavar='BAG')
    parser.add_argument('--params', required=True, metavar='PARAMS.yaml')
    parser.add_argument('--gravity', type=options.gravity, default=STANDARD_GRAVITY,
                        help=f'local gravity, m/s^2 ({options.GRAVITY_MIN:g}..{options.GRAVITY_MAX:g})')
    parser.add_argument('--json', metavar='OUT.json', help='also write the figures as JSON')
    parser.add_argument('--latitude', type=options.latitude, metavar='DEG',
                        help="driver bags without a rate reference: the Earth rate's vertical component at this "
                             'latitude is the true rate (default: zero)')
    options.add_out_of_range(parser)
    options.add_topic_options(parser)
    parser.add_argument('--noise', metavar='IMU.yaml',
                        help="the sensors' noise model (Kalibr-style imu.yaml): "
                             "the averaged bias error is shown next to it")
    parser.add_argument('--noise-run', metavar='BAG', help='a static run at constant temperature for the noise model')
    parser.set_defaults(handler=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """|g| from the three accelerometer channels (and the gyroscope's rate error) before and after correction.

    The bag is read block by block (bounded memory); the errors are accumulated as sums.
    """
    from tak_thermo_ros.core.records.static_run import NotStatic
    from tak_thermo_ros.streaming import ImuLinkUndetermined, validate_bag
    from tak_thermo_ros.streaming_mag import has_mag
    unit = load_unit(args.params)
    options = common.stream_options(args)
    document = {'bag': str(args.bag), 'params': str(args.params), 'gravity': args.gravity}
    try:
        run = validate_bag(args.bag, unit, options, gravity=args.gravity,
                           latitude=getattr(args, 'latitude', None), out_of_range=OutOfRange(args.out_of_range),
                           expect_kind=lambda kind: common.check_kind(args, unit, kind))
    except (NotStatic, ImuLinkUndetermined):  # turned, one orientation; or never at rest
        # A record turned by hand has no reference for the accelerometer and gyroscope; its
        # magnetometer is still checked (|B| in every orientation).
        if unit.mag is None or not has_mag(args.bag, options.topics):
            raise
        print('accelerometer and gyroscope: not validated (the board moved, no reference)')
        run = None
    if run is not None:
        common.print_survey(run.survey, 'validate')
        if hasattr(run, 'gravity'):
            _validate_imu(args, unit, run, document)
        else:
            _validate_handheld(args, run, document)
    if unit.mag is not None and (run is None or run.input_kind is InputKind.IMU):
        document.update(_validate_magnetometer(args, unit))
    if args.json:
        write_text_atomic(args.json, common.json_text(document, args.json))
        print(f'wrote {args.json}')
    return 0


def _validate_imu(args: argparse.Namespace, unit: UnitCalibration, run, document: dict) -> None:
    """``validate``'s |g| and rate error before and after the correction (into ``document``)."""
    result = run.gravity
    if not result.samples:
        left_out = f' (left out: {common.describe_dropped(run.accel_dropped)})' if run.accel_dropped else ''
        msg = f'{args.bag}: no usable samples to validate{left_out}'
        raise TakError(msg)
    before, after = result.before.gravity_error(), result.after.gravity_error()
    common.require_finite([before.rms, before.max, after.rms, after.max], f'{args.bag}: |g| error')
    common.print_ignored(common.IgnoredCounts(run.accel_ignored_temp_codes, run.accel_ignored_references), args,
                         run.input_kind)
    if run.accel_dropped:
        print(f'left out: {common.describe_dropped(run.accel_dropped)}')
    print(f'|g| error over {result.samples} samples of {args.bag} (gravity {args.gravity:g} m/s^2):')
    print(f'  before (nominal scale and offset): RMS {before.rms:.5f} m/s^2 '
          f'({before.rms / args.gravity * 1e3:.3f} mg), '
          f'max {before.max:.5f} m/s^2')
    print(f'  after  (full correction link):     RMS {after.rms:.5f} m/s^2 ({after.rms / args.gravity * 1e3:.3f} mg), '
          f'max {after.max:.5f} m/s^2')
    if result.out_of_range:
        print(f'warning: {result.out_of_range} samples outside the calibrated temperature range ({args.out_of_range})')
    # The corrected output is in SI units whatever the input kind: a file's model as it stands.
    given = common.given_noise_models(args, unit, InputKind.IMU, ('accel',) if unit.gyro is None else ('accel', 'gyro'))
    averaged = {'accel': _averaged_bias(result, given.get('accel'), 'accel', args.gravity)}
    document.update({'samples': result.samples, 'out_of_range': result.out_of_range,
                     'before': before.as_dict(), 'after': after.as_dict()})
    if unit.gyro is not None and run.rate is not None:
        for line in run.reference_lines:
            if line.startswith('rate reference'):
                print(line)
        rate = run.rate
        rate_before, rate_after = rate.before.rate_error(), rate.after.rate_error()
        print(f'gyroscope bias error over {rate.samples} samples (rate minus reference, per axis x y z):')
        for label, stats in (('before (nominal scale and offset):', rate_before),
                             ('after  (full correction link):', rate_after)):
            print(f'  {label:<35}RMS {readables(stats.rms, "rad/s")}; mean '
                  + ' '.join(f'{in_reader_unit(v, "rad/s"):+.3g}' for v in stats.mean) + ' deg/h')
        document['gyro'] = {'samples': rate.samples, 'before': rate_before.as_dict(), 'after': rate_after.as_dict()}
        averaged['gyro'] = _averaged_bias(rate, given.get('gyro'), 'gyro', args.gravity)
    for sensor, found in averaged.items():
        if found is None:
            continue
        for line in found['lines']:
            print(line)
        (document['gyro'] if sensor == 'gyro' else document)['averaged_bias_error'] = found['document']


def _validate_magnetometer(args: argparse.Namespace, unit: UnitCalibration) -> dict:
    """``validate``'s field error before and after, in microtesla; the JSON entry ``mag``."""
    from tak_thermo_ros.streaming_mag import has_mag, validate_mag
    options = common.stream_options(args)
    if not has_mag(args.bag, options.topics):
        print(f'magnetometer: {args.bag} holds no messages on {options.topics.mag}; not validated')
        return {}
    result = validate_mag(args.bag, unit.mag, options, out_of_range=OutOfRange(args.out_of_range))
    rotation = result.reference == 'rotation'
    if rotation:
        print(f'magnetometer: a rotation record, {result.samples} samples: |B| about its mean (one in every '
              f'orientation)')
        print('magnetometer: its direction is not checked (that takes a reference field)')
    else:
        against = ('about the run\'s mean field (static run)' if result.reference == 'static'
                   else f'against {result.reference}')
        print(f'magnetometer field error over {result.samples} samples, {against} (per axis x y z, |B|):')
    for label, values in (('before (raw field):', result.before), ('after  (thermal link and iron):', result.after)):
        axes = '' if rotation else 'RMS ' + ' '.join(f'{v * 1e6:.3f}' for v in values[:3]) + ' uT; '
        print(f'  {label:<35}{axes}|B| {values[3] * 1e6:.3f} uT')
    if result.out_of_range:
        print(f'warning: {result.out_of_range} magnetometer samples outside the calibrated temperature range '
              f'({args.out_of_range})')
    axes = {} if rotation else {'before_rms_t': list(result.before[:3]), 'after_rms_t': list(result.after[:3])}
    return {'mag': {'samples': result.samples, 'reference': result.reference, **axes,
                    'before_magnitude_rms_t': result.before[3], 'after_magnitude_rms_t': result.after[3]}}


def _averaged_bias(check, noise, sensor: str, gravity: float) -> dict | None:
    """``validate``'s bias error of the corrected output averaged over 1, 60 and 600 s.

    In deg/h for the gyroscope per axis, mg for |g|, next to what the noise model predicts (its
    Allan deviation).
    """
    import math
    rms = check.gravity_averaged.rms() if sensor == 'accel' else check.noise.averaged.rms()
    windows = check.gravity_averaged.windows() if sensor == 'accel' else check.noise.averaged.windows()
    source = 'given'
    if noise is None and check.noise.allan is not None:
        from tak_thermo_ros.core.noise.residual import short_term_model
        try:
            noise = short_term_model(check.noise.allan.result())
        except TakError:
            noise = None
    taus = np.array(sorted(rms))
    predicted = None
    if noise is not None:
        avar = noise.allan_variance(taus)
        if sensor == 'accel':
            direction = check.direction / max(float(np.linalg.norm(check.direction)), 1e-300)
            predicted = np.sqrt(avar @ direction ** 2)[:, None]
        else:
            predicted = np.sqrt(avar)
        source = noise.source
    if sensor == 'gyro':
        factor, unit, name = 180.0 / math.pi * 3600.0, 'deg/h', 'gyroscope bias error (x y z)'
    else:
        factor, unit, name = 1000.0 / gravity, 'mg', '|g| error'
    said = {'file': 'the noise model from the file', 'static_run': 'the noise model from the static run',
            'residual': "white noise and bias instability fitted to this run's corrected output up to 30 s"}
    lines = [f'{name} of the corrected output averaged over 1 s, 60 s, 600 s, RMS of the averages in {unit}'
             + (f' (next to what {said[source]} predicts, its Allan deviation):' if predicted is not None else ':')]
    document = {}
    for t, tau in enumerate(taus):
        values = np.atleast_1d(rms[tau]) * factor
        text = ' '.join(f'{v:.3g}' for v in values) if windows[tau] else 'run shorter than one window'
        entry = {'windows': windows[tau], 'rms': [float(v) for v in values], 'unit': unit}
        if predicted is not None:
            text += '   noise model: ' + ' '.join(f'{v * factor:.3g}' for v in predicted[t])
            entry['noise_model'] = [float(v * factor) for v in predicted[t]]
        lines.append(f'  {tau:5.0f} s: {text}')
        document[f'{tau:g}'] = entry
    return {'lines': lines, 'document': {'source': source if predicted is not None else None, 'taus': document}}


def _validate_handheld(args: argparse.Namespace, run, document: dict) -> None:
    """``validate`` of a hand-held record: the rests' |g| and rate, the turns' closure, before and after."""
    before, after = run.before, run.after
    if not after.samples:
        msg = f'{args.bag}: no usable still samples to validate'
        raise TakError(msg)
    g = args.gravity
    common.require_finite([before.gravity_rms, after.gravity_rms, *after.rate_rms], f'{args.bag}: the errors')
    print(f'|g| error of the {len(after.gravity_error)} rests\' mean specific force (gravity {g:g} m/s^2):')
    for label, check in (('before (nominal scale and offset):', before), ('after  (full correction link):', after)):
        print(f'  {label:<35}RMS {check.gravity_rms:.3g} m/s^2 ({check.gravity_rms / g * 1e3:.3g} mg), '
              f'max {np.max(np.abs(check.gravity_error)):.3g} m/s^2')
    print(f'  the noise alone:                   RMS {after.gravity_floor:.3g} m/s^2 '
          f'({after.gravity_floor / g * 1e3:.3g} mg)')
    rest = 'the Earth rate\'s vertical component' if args.latitude is not None else 'zero'
    print(f'gyroscope: the rests\' mean rate against {rest}, RMS per axis x y z:')
    for label, check in (('before (nominal scale and offset):', before), ('after  (full correction link):', after)):
        rms = check.rate_rms
        print(f'  {label:<35}' + ' '.join(f'{v:.3g}' for v in rms) + ' rad/s ('
              + ' '.join(f'{v * 180.0 / np.pi * 3600.0:.3g}' for v in rms) + ' deg/h)')
    floor = after.rate_floor
    print(f'  {"the noise alone:":<35}' + ' '.join(f'{v:.3g}' for v in floor) + ' rad/s ('
          + ' '.join(f'{v * 180.0 / np.pi * 3600.0:.3g}' for v in floor) + ' deg/h)')
    closure = after.closure
    if len(closure.angle_rad):
        angles = [np.degrees(value) for value in (before.closure.rms_rad, closure.rms_rad, closure.floor_rad)]
        print(f'turns: closure of {len(closure.angle_rad)} turns, RMS {angles[0]:.3g} deg before, {angles[1]:.3g} deg '
              f'after (the noise alone {angles[2]:.3g} deg)')
    if after.out_of_range:
        print(f'warning: {after.out_of_range} samples outside the calibrated temperature range ({args.out_of_range})')
    document.update({'record': 'handheld', 'rests': len(after.gravity_error), 'samples': after.samples,
                     'out_of_range': after.out_of_range,
                     'before': {'gravity_rms': before.gravity_rms, 'rate_rms': [float(v) for v in before.rate_rms],
                                'closure_rms_rad': before.closure.rms_rad},
                     'after': {'gravity_rms': after.gravity_rms, 'rate_rms': [float(v) for v in after.rate_rms],
                               'closure_rms_rad': after.closure.rms_rad},
                     'floor': {'gravity_rms': after.gravity_floor, 'rate_rms': [float(v) for v in after.rate_floor],
                               'closure_rms_rad': closure.floor_rad}})
