"""``tak_calib validate``: the error before and after correction on a run the fit did not see."""

from __future__ import annotations

import argparse

from tak_thermo_ros.cli import common, options
from tak_thermo_ros.core.link.correction import OutOfRange
from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.core.link.model import UnitCalibration
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.formats.files import FILE
from tak_thermo_ros.formats.files import write_json
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import TakError
import numpy as np
from dataclasses import replace
from pathlib import Path

NAME = 'validate'
OUTPUTS = (('json', FILE, '--json'),)
"""This command's outputs: ``(argument, kind, option)``, checked before any work is done."""


def add_parser(commands) -> argparse.ArgumentParser:
    """Add the command to ``tak_calib``'s subcommands."""
    parser = commands.add_parser('validate', help='the error before and after correction on a record the fit did '
                                                  'not see: |g| and the rate against its references or at its rests')
    parser.add_argument('bag', metavar='BAG', nargs='+',
                        help='a record; several records, or a directory of them: a pool of everyday records, each '
                             'rest judged (docs/everyday.md)')
    parser.add_argument('--params', required=True, metavar='PARAMS.yaml')
    parser.add_argument('--gravity', type=options.gravity, default=None,
                        help=f'local gravity, m/s^2 ({options.GRAVITY_MIN:g}..{options.GRAVITY_MAX:g}; '
                             f'default: from --latitude, else {STANDARD_GRAVITY:g})')
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
    from tak_thermo_ros.passes.run import EverydayRecord, ImuLinkUndetermined
    from tak_thermo_ros.passes.validate import validate_bag
    from tak_thermo_ros.passes.magnetometer import has_mag
    unit = load_unit(args.params)
    from tak_thermo_ros.passes.pool_records import is_pool
    if is_pool(args.bag):
        return _validate_pool(args, unit)
    from tak_thermo_ros.formats.records import open_record
    args.bag = args.bag[0]
    options = common.stream_options(args)
    record = open_record(args.bag, topics=options.topics)
    document = {'bag': str(args.bag), 'params': str(args.params), 'gravity': args.gravity}
    watched = _calibration_watch(args, unit, record)
    try:
        run = validate_bag(record, unit, options, gravity=args.gravity,
                           latitude=getattr(args, 'latitude', None), out_of_range=OutOfRange(args.out_of_range),
                           expect_kind=lambda kind: common.check_kind(args, unit, kind))
    except EverydayRecord:  # rests in one orientation, motion between: its rests judged as a pool's
        print(f'{Path(args.bag).name}: {EverydayRecord.WORDS}')
        return _validate_pool(args, unit, [record], watched=watched)
    except (NotStatic, ImuLinkUndetermined):  # turned, one orientation; or never at rest
        # A record turned by hand has no reference for the accelerometer and gyroscope; its
        # magnetometer is still checked (|B| in every orientation). A record that moves and rests
        # in several poses without turns to fit is judged by the calibration watch.
        if watched is None and (unit.mag is None or not has_mag(record)):
            raise
        if watched is None:
            print('accelerometer and gyroscope: not validated (the board moved, no reference)')
        else:
            print('accelerometer and gyroscope: no reference (the board moved); the calibration watch judges them')
        run = None
    if run is not None:
        from tak_thermo_ros.core.records.provenance import in_sample_lines
        found = getattr(run, 'in_sample', None)
        for line in in_sample_lines(found, record=Path(args.bag).name, params=Path(args.params).name,
                                    command='validate'):
            print(line)
        document['in_sample'] = found.as_dict() if found is not None else None
        common.print_survey(run.survey, 'validate')
        if hasattr(run, 'gravity'):
            _validate_imu(args, unit, run, document)
        else:
            _validate_handheld(args, run, document)
    if watched is not None:
        for line in watched.lines():
            print(line)
        document['calibration_watch'] = _watch_document(watched)
    if unit.mag is not None and (run is None or run.input_kind is InputKind.IMU):
        document.update(_validate_magnetometer(args, unit, record))
    if args.json:
        write_json(args.json, document)
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
    print(result.summary(args.bag))
    print(f'  before: {_before_words(run.input_kind, unit, args.params)}')
    if result.out_of_range:
        print(f'warning: {result.out_of_range} samples outside the calibrated temperature range ({args.out_of_range})')
    # The corrected output is in SI units whatever the input kind: a file's model as it stands.
    given = common.given_noise_models(args, unit, InputKind.IMU, ('accel',) if unit.gyro is None else ('accel', 'gyro'))
    averaged = {'accel': _averaged_bias(result, given.get('accel'), 'accel', args.gravity)}
    document.update({'samples': result.samples, 'out_of_range': result.out_of_range,
                     'before': before.as_dict(), 'after': after.as_dict(),
                     'before_is': 'as_recorded' if run.input_kind is InputKind.IMU else 'nominal'})
    if unit.gyro is not None and run.rate is not None and not run.rate.samples:
        left_out = f' (left out: {common.describe_dropped(run.gyro_dropped)})' if run.gyro_dropped else ''
        print(f'gyroscope: no usable samples to validate{left_out}')
    elif unit.gyro is not None and run.rate is not None:
        for line in run.reference_lines:
            if line.startswith('rate reference'):
                print(line)
        rate = run.rate
        if run.gyro_dropped:
            print(f'gyroscope: left out: {common.describe_dropped(run.gyro_dropped)}')
        rate_before, rate_after = rate.before.rate_error(), rate.after.rate_error()
        print(rate.summary())
        print(f'  before: {_before_words(run.input_kind, unit, args.params)}')
        document['gyro'] = {'samples': rate.samples, 'before': rate_before.as_dict(), 'after': rate_after.as_dict()}
        averaged['gyro'] = _averaged_bias(rate, given.get('gyro'), 'gyro', args.gravity)
    for sensor, found in averaged.items():
        if found is None:
            continue
        for line in found['lines']:
            print(line)
        (document['gyro'] if sensor == 'gyro' else document)['averaged_bias_error'] = found['document']


def _calibration_watch(args: argparse.Namespace, unit: UnitCalibration, record):
    """The node's calibration watch over a driver record.

    ``None``: a counts record, or a calibration without the noise models the watch judges
    against. With ``--latitude`` as the node's ``latitude``; ``--gravity`` does not enter it
    (the node has none).
    """
    from tak_thermo_ros.core.link.watch import WatchSettings, watch_unavailable
    from tak_thermo_ros.passes.watch import watch_bag
    if unit.input_kind is not InputKind.IMU or watch_unavailable(unit):
        return None
    options = common.stream_options(args)
    if record.kind is not InputKind.IMU:
        return None
    return watch_bag(record, unit, options, settings=WatchSettings(latitude=getattr(args, 'latitude', None)),
                     out_of_range=OutOfRange(args.out_of_range))


def _watch_document(watched) -> dict:
    """The JSON entry ``calibration_watch``: the verdict, what moved, the figures at the last rest."""
    watch = watched.watch
    if watch is None:
        return {'off': watched.off}
    return {'verdict': watch.verdict(), 'stale': watch.stale, 'rests': watch.rests_judged,
            'rest_hours': watch.rest_hours, 'false_alarms_per_hour': watch.false_alarms_per_hour,
            'findings': [{'channel': f.channel, 'axis': f.axis, 'kind': f.kind, 'size': f.size, 'sigma': f.z,
                          'rest': f.rest, 'turn_on': f.turn_on, 'text': f.text()} for f in watch.findings.values()],
            'values': dict(watch.values()), 'messages': watched.messages, 'published': watched.published}


def _validate_magnetometer(args: argparse.Namespace, unit: UnitCalibration, record) -> dict:
    """``validate``'s field error before and after, in microtesla; the JSON entry ``mag``."""
    from tak_thermo_ros.passes.magnetometer import has_mag, validate_mag
    options = common.stream_options(args)
    if not has_mag(record):
        print(f'magnetometer: {args.bag} holds no messages on {options.topics.mag}; not validated')
        return {}
    result = validate_mag(record, unit.mag, options, out_of_range=OutOfRange(args.out_of_range))
    rotation = result.reference == 'rotation'
    if rotation:
        print(f'magnetometer: a rotation record, {result.samples} samples: the spread of |B| about its mean')
        print('magnetometer: its direction is not checked (that takes a reference field)')
    else:
        against = ('about the run\'s mean field (static run)' if result.reference == 'static'
                   else f'against {result.reference}')
        print(f'magnetometer field error over {result.samples} samples, {against}:')
    for label, values in (('before', result.before), ('after ', result.after)):
        if rotation:
            print(f'  {label} correction: spread of |B|, RMS about its mean {values[3] * 1e6:.4g} uT')
        else:
            print(f'  {label} correction: RMS per axis x y z '
                  f'{common.numbers(np.asarray(values[:3]) * 1e6)} uT, |B| {values[3] * 1e6:.4g} uT')
    print('  before: the field as recorded; after: the thermal link, then the hard and soft iron')
    if result.out_of_range:
        print(f'warning: {result.out_of_range} magnetometer samples outside the calibrated temperature range '
              f'({args.out_of_range})')
    axes = {} if rotation else {'before_rms_t': list(result.before[:3]), 'after_rms_t': list(result.after[:3])}
    return {'mag': {'samples': result.samples, 'reference': result.reference, **axes,
                    'before_magnitude_rms_t': result.before[3], 'after_magnitude_rms_t': result.after[3]}}


def _before_words(kind: InputKind, unit: UnitCalibration, params: str) -> str:
    """What *before* is: a driver's values as recorded; codes through the file's flat scale and offset."""
    if kind is InputKind.IMU:
        return "the driver's values as recorded (the same whatever calibration is given)"
    return f"codes through {params}'s scale and offset at N_t,ref {unit.accel.temp_code_ref:.0f}, no temperature term"


def _averaged_bias(check, noise, sensor: str, gravity: float) -> dict | None:
    """``validate``'s bias error of the corrected output averaged over 1, 60 and 600 s.

    In deg/h for the gyroscope per axis, mg for |g|, next to what the noise model predicts (its
    Allan deviation). A given model's per-axis Allan variance is projected onto |g| by the mean
    squares of the measured direction's components; without one, white noise and bias
    instability are fitted to the error itself (the |g| error, whatever the orientations of the
    run) up to 30 s: what its short-term noise alone predicts.
    """
    rms, windows = check.noise.averaged.rms(), check.noise.averaged.windows()
    own = False
    if noise is None and check.noise.allan is not None:
        from tak_thermo_ros.core.noise.residual import short_term_model
        allan = check.noise.allan.result()
        if allan.axes == 1:  # the |g| error: fitted as three equal axes, read on the first
            per_axis = ('avar', 'peak', 'peak_index')
            allan = replace(allan, **{name: np.repeat(getattr(allan, name), 3, axis=1) for name in per_axis
                                      if getattr(allan, name) is not None})
        try:
            noise, own = short_term_model(allan), True
        except TakError:
            noise = None
    taus = np.array(sorted(rms))
    predicted = None
    if noise is not None:
        avar = noise.allan_variance(taus)
        if sensor == 'accel':
            predicted = np.sqrt(avar[:, :1] if own else avar @ check.direction_squares[:, None])
        else:
            predicted = np.sqrt(avar)
    if sensor == 'gyro':
        (unit, factor), name = common.reader_unit('rad/s'), 'gyroscope bias error x y z'
    else:  # mg of the local gravity
        factor, unit, name = 1000.0 / gravity, 'mg', '|g| error'
    lines = [f"{name}: RMS of the corrected output's means over 1 s, 60 s and 600 s, in {unit}:"]
    if predicted is not None:
        words = ('white noise and bias instability fitted to it up to 30 s' if own
                 else f'the one given, {common.SOURCE_WORDS[noise.source]}')
        lines.append(f'  noise model (its Allan deviation): {words}')
    document = {}
    for t, tau in enumerate(taus):
        values = np.atleast_1d(rms[tau]) * factor
        text = common.numbers(values, 3) if windows[tau] else 'run shorter than one window'
        # not defined for a run shorter than one window: null in the JSON, as the line says
        entry = {'windows': windows[tau], 'rms': [float(v) for v in values] if windows[tau] else None, 'unit': unit}
        if predicted is not None:
            text += f'   noise model: {common.numbers(predicted[t] * factor, 3)}'
            entry['noise_model'] = [float(v * factor) for v in predicted[t]]
        lines.append(f'  at {tau:g} s: {text}')
        document[f'{tau:g}'] = entry
    return {'lines': lines, 'document': {'source': noise.source if predicted is not None else None,
                                         'taus': document}}


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
    small, factor = common.reader_unit('rad/s')
    for label, rms in (('before (nominal scale and offset):', before.rate_rms),
                       ('after  (full correction link):', after.rate_rms), ('the noise alone:', after.rate_floor)):
        print(f'  {label:<35}' + ' '.join(f'{v:.3g}' for v in rms) + ' rad/s ('
              + ' '.join(f'{v * factor:.3g}' for v in rms) + f' {small})')
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


def _validate_pool(args: argparse.Namespace, unit: UnitCalibration, paths=None, *, watched=None) -> int:
    """``validate`` of a pool of everyday records: each rest's |g| and rate, each record's turn-on offset apart.

    :param paths: the records (default: the command's); ``watched``: the calibration watch over one
        record, said after the rests.
    """
    from tak_thermo_ros.core.records.provenance import pool_in_sample_lines
    from tak_thermo_ros.passes.pool_check import check_driver_unit, outside_lines, validate_records
    check_driver_unit(unit, args.params)
    policy = OutOfRange(args.out_of_range)
    read: list[str] = []  # each record's lines, said after what the reader must know first (in-sample)
    check = validate_records(paths or args.bag, unit, common.stream_options(args), gravity=args.gravity,
                             latitude=getattr(args, 'latitude', None), out_of_range=policy, say=read.append)
    opened, before, after = check.opened, check.before, check.after
    pooled = [opened.entries[i] for i in opened.used]
    for line in pool_in_sample_lines([(entry.name, entry.in_sample) for entry in pooled],
                                     params=Path(args.params).name, command='validate',
                                     records=len(unit.fitted_from)):
        print(line)
    for line in read:
        print(line)
    beyond = outside_lines(check, unit, policy)
    for line in beyond:
        print(line)
    g = args.gravity
    small, factor = common.reader_unit('rad/s')
    records = f'{len(opened.used)} record{"s" if len(opened.used) != 1 else ""}'
    print(f'|g| error of the {len(after.gravity_error)} rests\' mean specific force of {records}:')
    for label, value in (('before (nominal scale and offset):', before.gravity_rms),
                         ('after  (full correction link):', after.gravity_rms),
                         ('the noise alone:', after.gravity_floor)):
        print(f'  {label:<35}RMS {value:.3g} m/s^2 ({value / g * 1e3:.3g} mg)')
    print('gyroscope: the rests\' mean rate, RMS per axis x y z:')
    rows = (('before (nominal scale and offset):', before.rate_rms), ('after  (full correction link):', after.rate_rms),
            ('after, each record\'s own offset off:', check.shape_rms), ('the white noise alone:', after.rate_floor))
    for label, rms in rows:
        print(f'  {label:<37}{common.numbers(rms, 3)} rad/s ({common.numbers(np.asarray(rms) * factor, 3)} {small})')
    known = unit.gyro.known_turn_on
    said = (f'the file\'s repeatability {common.numbers(np.asarray(known.repeatability) * factor, 3)}'
            if known is not None else f'the file\'s repeatability: {unit.gyro.turn_on.why_not()}'
            if unit.gyro.turn_on is not None else 'the file holds no turn-on repeatability')
    if len(check.own) > 1:
        spread = check.own.std(axis=0, ddof=1)
        print(f'gyroscope: these records\' turn-on offsets spread {common.numbers(spread * factor, 3)} {small} x y z '
              f'({said})')
    else:  # one record: its own offset, not a spread
        print(f'gyroscope: this record\'s turn-on offset {common.numbers(check.own[0] * factor, 3)} {small} x y z '
              f'({said})')
    from tak_thermo_ros.passes.prior_lines import band_lines
    lines, band = band_lines(check, unit.gyro)
    for line in lines:
        print(line)
    if after.out_of_range and not beyond:  # outside in the motions only, none at a rest
        print(f'warning: {after.out_of_range} samples outside the calibrated temperature range ({args.out_of_range})')
    document = {'records': [entry.name for entry in opened.entries], 'params': str(args.params), 'gravity': g,
                'record': 'pool', 'rests': len(after.gravity_error),
                'before': {'gravity_rms': before.gravity_rms, 'rate_rms': [float(v) for v in before.rate_rms]},
                'after': {'gravity_rms': after.gravity_rms, 'rate_rms': [float(v) for v in after.rate_rms],
                          'rate_shape_rms': [float(v) for v in check.shape_rms]},
                'floor': {'gravity_rms': after.gravity_floor, 'rate_rms': [float(v) for v in after.rate_floor]},
                'turn_on_offsets': check.own.tolist(), 'out_of_range': after.out_of_range,
                'in_sample': {entry.name: entry.in_sample.as_dict() for entry in pooled if entry.in_sample}}
    if band:
        document['uncertainty'] = band
    if watched is not None:
        for line in watched.lines():
            print(line)
        document['calibration_watch'] = _watch_document(watched)
    if args.json:
        write_json(args.json, document)
        print(f'wrote {args.json}')
    return 0
