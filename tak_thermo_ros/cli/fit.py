"""``tak_calib fit``: the correction link of every sensor in a record, written as a calibration file."""

from __future__ import annotations

import argparse

from dataclasses import replace

import numpy as np
from pathlib import Path
from tak_thermo_ros.cli import common, options
from tak_thermo_ros.core.fit.link_uncertainty import HeldSpreads
from tak_thermo_ros.core.fit.summary import axes_lines
from tak_thermo_ros.core.link.model import AXES
from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.core.link.model import UnitCalibration
from tak_thermo_ros.formats.calibration_file import save_unit
from tak_thermo_ros.formats.files import FILE
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import TakError
from tak_thermo_ros.passes.run import EFFECT_FIT_MAX_SAMPLES

NAME = 'fit'
OUTPUTS = (('output', FILE, '-o'),)
BIAS_ORDER = 3
SCALE_ORDER = 2
"""The orders of the offset and scale polynomials when none is given."""
"""This command's outputs: ``(argument, kind, option)``, checked before any work is done."""


def add_parser(commands) -> argparse.ArgumentParser:
    """Add the command to ``tak_calib``'s subcommands."""
    parser = commands.add_parser('fit', help='fit the correction link to a calibration bag, or to a pool of '
                                             'everyday records of one unit')
    parser.add_argument('bag', metavar='BAG', nargs='+',
                        help='a record; several records, or a directory of them, are a pool of one unit\'s '
                             'everyday records (docs/everyday.md)')
    parser.add_argument('-o', '--output', required=True, metavar='PARAMS.yaml')
    parser.add_argument('--bias-order', type=options.polynomial_order, default=BIAS_ORDER,
                        help=f'order q of F_s (default {BIAS_ORDER})')
    parser.add_argument('--scale-order', type=options.polynomial_order, default=SCALE_ORDER,
                        help=f'order p of F_c (default {SCALE_ORDER}; 0 = no scale drift)')
    parser.add_argument('--temp-code-ref', type=options.temp_code,
                        help='N_t,ref (default: middle of the calibrated range)')
    parser.add_argument('--nominal-scale', type=options.nominal_scale, nargs='+', action=options.OneOrThree,
                        metavar='K0',
                        help='nominal counts per m/s^2 (one value or x y z), held for an axis that sees one '
                             'input only; default: the bag metadata written by simulate / import-csv')
    parser.add_argument('--effects', type=options.effect_specs, metavar='NAME[,NAME...]',
                        help='effects to fit beyond the paper\'s model: thermal_lag, hysteresis, scale_nonlinearity, '
                             'cross_axis, warmup, temperature_shape, step, the per-axis forms thermal_lag_per_axis, '
                             'hysteresis_per_axis, warmup_per_axis, a recorded signal aux:TOPIC[:FIELD] '
                             '(e.g. aux:/power/battery_state), or module:Class; NAME[AXES] fits an offset effect '
                             'on those axes only, e.g. thermal_lag[xz] (see docs/effects.md)')
    parser.add_argument('--gyro-effects', type=options.effect_specs, metavar='NAME[,NAME...]',
                        help='effects to fit on the gyroscope (driver bags), the same names as --effects')
    parser.add_argument('--effect-samples', type=options.sample_budget, default=EFFECT_FIT_MAX_SAMPLES, metavar='N',
                        help=f'search the effects\' shapes on at most about N samples spread evenly over the run '
                             f'(default {EFFECT_FIT_MAX_SAMPLES:,}; the amplitudes use every sample)')
    parser.add_argument('--mag-effects', type=options.effect_specs, metavar='NAME[,NAME...]',
                        help="effects on the magnetometer's thermal link, as --effects (what diagnose names)")
    parser.add_argument('--iron-run', metavar='BAG',
                        help="the magnetometer's rotation record (installed, turned through every orientation): "
                             'hard and soft iron by an ellipsoid fit, after the thermal link (default: not fitted)')
    parser.add_argument('--settle-time', type=options.seconds_not_negative, default=0.0, metavar='SECONDS',
                        help='leave out samples this long after each reference change (turntable settling)')
    parser.add_argument('--held-spread', type=options.held_spread, action='append', default=[], metavar='NAME=VALUE',
                        help='the spread a held term is written with where the records do not bound it (the file\'s '
                             'uncertainty, the calibration watch\'s), as a data sheet gives it: accel_offset=20 (mg), '
                             'accel_scale=0.5 (%%), accel_coupling=10 (mrad), gyro_offset=3600 (deg/h), '
                             '..._offset_drift, ..._scale_drift (per C); default a consumer MEMS data sheet\'s '
                             '(docs/calibration_file.md)')
    noise_group = parser.add_argument_group('noise model written with the calibration (the node\'s Imu covariances)')
    noise_group.add_argument('--noise', metavar='IMU.yaml',
                             help='a Kalibr-style imu.yaml (noise densities, random walks)')
    noise_group.add_argument('--noise-run', metavar='BAG', help='a static, constant-temperature run: its noise model '
                                                                '(compensated with the fitted calibration)')
    noise_group.add_argument('--noise-from-residual', action='store_true',
                             help='the noise model of this run\'s residual after the fit (one more pass over the bag)')
    parser.add_argument('--prior', metavar='PRIOR.yaml',
                        help='a fleet\'s prior (tak_calib fit-fleet --everyday writes it): the records, however few, '
                             'combined with what units of their kind say (docs/fleet.md); the records are a pool')
    options.add_static_options(parser)
    options.add_topic_options(parser)
    parser.set_defaults(handler=run)
    return parser


def fit_settings(args: argparse.Namespace):
    """``fit``'s :class:`~tak_thermo_ros.passes.run.FitSettings` from its options (fit-fleet's too)."""
    from tak_thermo_ros.passes.run import FitSettings
    effects = {'accel': common.effect_list(args.effects), 'gyro': common.effect_list(args.gyro_effects)}
    return FitSettings(effects=effects, bias_order=args.bias_order, scale_order=args.scale_order,
                       temp_code_ref=args.temp_code_ref, settle_time_s=args.settle_time,
                       gravity=getattr(args, 'gravity', STANDARD_GRAVITY), latitude=getattr(args, 'latitude', None),
                       max_effect_samples=args.effect_samples, held_spreads=HeldSpreads(**dict(args.held_spread)))


def run(args: argparse.Namespace) -> int:
    """Fit the correction link to a calibration bag (counts, or a driver's Imu: both sensors), block by block."""
    from tak_thermo_ros.formats.records import open_record
    from tak_thermo_ros.passes.fit import fit_imu
    from tak_thermo_ros.passes.magnetometer import has_mag
    settings = fit_settings(args)
    effects = settings.effects
    from tak_thermo_ros.passes.pool_records import is_pool
    from tak_thermo_ros.passes.run import EverydayRecord
    if is_pool(args.bag) or args.prior:
        return _fit_pool(args, settings)
    # A record that determines the magnetometer alone (turned by hand, or without a temperature)
    # holds the accelerometer and gyroscope at nominal, said in one line; else it is refused.
    # An everyday record (rests in one orientation, motion between) is a pool of one.
    options = common.stream_options(args)
    record = open_record(args.bag[0], topics=options.topics)
    try:
        fitted = fit_imu(record, settings, options,
                         nominal_for=lambda kind, bag_nominal: _nominal(args, bag_nominal),
                         hold_undetermined=has_mag(record))
    except EverydayRecord:
        print(f'{Path(args.bag[0]).name}: {EverydayRecord.WORDS}')
        return _fit_pool(args, settings, [record])
    args.bag = args.bag[0]
    for line in record.lines:
        print(line)
    both_held = set(fitted.held) >= {'accel', 'gyro'}
    for option, given, sensors in (('--effects', bool(effects['accel']), ('accel',)),
                                   ('--gyro-effects', bool(effects['gyro']), ('gyro',)),
                                   ('--noise-from-residual', args.noise_from_residual, ('accel', 'gyro'))):
        held = [sensor for sensor in sensors if sensor in fitted.held]
        if given and held:
            what = 'the accelerometer and gyroscope' if both_held else f'the {common.SENSOR_NAMES[held[0]]}'
            msg = (f'{option}: {what} of {args.bag} {"are" if both_held else "is"} not fitted '
                   f'({fitted.results[held[0]].calibration.notes[0]})')
            raise TakError(msg)
    results = fitted.results
    magnetometer = _fit_magnetometer(args, record, fitted.input_kind, imu_fitted=not both_held)
    unit = UnitCalibration(fitted.input_kind, results['accel'].calibration,
                           results['gyro'].calibration if 'gyro' in results else None,
                           magnetometer.calibration if magnetometer is not None else None,
                           _source(record, fitted),
                           fitted_from=(fitted.record_print,) if fitted.record_print is not None else ())
    if args.noise or args.noise_run or args.noise_from_residual:
        unit, noise_line = _with_noise(args, unit, record)
    else:
        unit, noise_line = _with_fitted_noise(unit, _fitted_noise(fitted, unit, settings))
    applied = ', '.join(f'{sensor} {", ".join(e.name for e in calibration.effects)}'
                        for sensor, calibration in unit.sensors if calibration.effects)
    handheld = fitted.handheld
    orders = handheld.fit.orders if handheld is not None else (args.bias_order, args.scale_order)
    fitted_sensor = next((sensor for sensor in fitted.sensors if sensor not in fitted.held), 'accel')
    fitted_what = (f'{results[fitted_sensor].samples} samples' if not both_held else
                   f'magnetometer only ({magnetometer.thermal.samples} samples; accelerometer and gyroscope held)')
    header = (f'tak_thermo_ros calibration fitted from {args.bag}'
              f'{" (a hand-held record)" if handheld is not None else ""}\n'
              f'{fitted_what}, bias order {orders[0]}, scale order {orders[1]}'
              f'{", effects " + applied if applied else ""}\n'
              f'load with: ros2 run tak_thermo_ros compensator --ros-args --params-file {Path(args.output).name}')
    save_unit(args.output, unit, header=header)
    kind = fitted.input_kind
    common.print_survey(fitted.survey, 'fit')
    if both_held:
        print(f'accelerometer and gyroscope: {results["accel"].calibration.notes[0]}')
    else:
        print(f'fitted {results[fitted_sensor].samples} samples from {args.bag}'
              f'{" (driver Imu: accelerometer and gyroscope)" if kind is InputKind.IMU else ""}')
        for sensor in fitted.held:
            print(f'{common.SENSOR_NAMES[sensor]}: {results[sensor].calibration.notes[0]}')
    for line in fitted.reference_lines:
        print(line)
    if handheld is not None:
        _print_handheld(handheld)
    for sensor in fitted.sensors:
        if sensor in fitted.held:
            continue
        result = results[sensor]
        calibration = result.calibration
        unit_name = common.UNITS[kind, sensor]
        prefix = '' if kind is InputKind.COUNTS else f'{common.SENSOR_NAMES[sensor]}: '
        if result.dropped:
            print(f'{prefix}left out: {common.describe_dropped(result.dropped)}')
        ignored = common.IgnoredCounts(fitted.ignored_temp_codes[sensor], fitted.ignored_references[sensor])
        common.print_ignored(ignored, args, kind, sensor)
        stride = fitted.effect_stride.get(sensor, 1)
        if stride > 1:
            print(f'{prefix}effect shapes searched on 1 sample in {stride} '
                  f'(about {fitted.usable[sensor] // stride} of {fitted.usable[sensor]}); '
                  f'amplitudes and the paper\'s link fitted on all of them')
        if kind is InputKind.COUNTS:
            print(f'calibrated temperature-code range {calibration.temp_code_min:.0f}..'
                  f'{calibration.temp_code_max:.0f}, reference {calibration.temp_code_ref:.0f}')
        elif sensor == fitted_sensor:
            print(f'calibrated temperature range {calibration.temp_code_min:.2f}..{calibration.temp_code_max:.2f} C, '
                  f'reference {calibration.temp_code_ref:.3g} C')
        if handheld is not None:
            print('\n'.join(axes_lines(common.SENSOR_NAMES[sensor], calibration, result.residual_rms, unit_name)))
            _print_handheld_terms(sensor, calibration, result)
        else:
            print(result.summary(common.SENSOR_NAMES[sensor], unit_name, calibration=calibration))
        if handheld is None:
            for note in calibration.notes:
                print(f'note: {prefix}{note}')
        _print_noise(unit.sensor(sensor).noise, unit_name)
    _print_noise_source(noise_line)
    if magnetometer is not None:
        _print_magnetometer(magnetometer, args)
    print(f'wrote {args.output}')
    return 0


def _source(record, fitted) -> dict[str, str | int | float] | None:
    """The calibration file's ``source``: the record's format, a flight log's instance and device IDs, its extremes."""
    if fitted.input_kind is not InputKind.IMU:
        return None
    found = record.source
    source: dict[str, str | int | float] = dict(found or {'format': 'bag'})
    source['temperature_rate_max'] = round(float(fitted.temperature_rate_max), 9)
    source['rate_max'] = round(float(fitted.rate_max), 9)
    return source


def _with_noise(args: argparse.Namespace, unit: UnitCalibration, record=None) -> tuple[UnitCalibration, str]:
    """The fitted unit with each sensor's noise model (``fit --noise / --noise-run / --noise-from-residual``)."""
    from tak_thermo_ros.formats.records import open_record
    from tak_thermo_ros.passes.noise import noise_models
    found = noise_models(unit=unit, options=common.stream_options(args), noise_file=args.noise,
                         noise_run=open_record(args.noise_run, topics=common.topics(args)) if args.noise_run else None,
                         calibration_run=record if args.noise_from_residual else None, use_stored=False,
                         gravity=getattr(args, 'gravity', STANDARD_GRAVITY), latitude=getattr(args, 'latitude', None))
    accel = replace(unit.accel, noise=found.models['accel'])
    gyro = replace(unit.gyro, noise=found.models['gyro']) if unit.gyro is not None else None
    return replace(unit, accel=accel, gyro=gyro), found.line


def _fitted_noise(fitted, unit: UnitCalibration, settings) -> dict:
    """Each fitted sensor's noise model from the record's own stretches (:mod:`tak_thermo_ros.passes.rest_noise`)."""
    from tak_thermo_ros.passes.rest_noise import rests_noise, streamed_noise
    if fitted.handheld is not None:
        return rests_noise(fitted.handheld.record, unit, gravity=settings.gravity, latitude=settings.latitude)
    found = {}
    for sensor, windows in fitted.noise_windows.items():
        if sensor not in fitted.held:
            noise = streamed_noise(windows, unit.sensor(sensor))
            if noise is not None:
                found[sensor] = noise
    return found


def _with_fitted_noise(unit: UnitCalibration, found: dict) -> tuple[UnitCalibration, str]:
    """The unit with the noise models its fit found (``fit`` without ``--noise``), and the line that says so."""
    if not found:
        return unit, ''
    sensors = {sensor: replace(unit.sensor(sensor), noise=noise.model) for sensor, noise in found.items()}
    unit = replace(unit, **sensors)
    first = next(iter(found.values()))
    what = ' and '.join(common.SENSOR_NAMES[sensor] for sensor in found)
    where = f'{first.means} {first.kind}' + (f' of {first.records} records' if first.records > 1 else '')
    lines = [f'noise model of the {what}: from the fit\'s {where} (white noise within them, the wander '
             f'between them; --noise or --noise-run give another)']
    shared = [common.SENSOR_NAMES[sensor] for sensor, noise in found.items() if noise.shared]
    for name in shared:
        lines.append(f'{name}: its wander seen along the vertical at the rests (|f|): written on x y z alike')
    return unit, '\n'.join(lines)


def _print_noise(noise, unit_name: str) -> None:
    """A sensor's noise model, one term per line (``fit`` prints it under the sensor's link)."""
    if noise is None:
        return
    print(f'  noise model ({common.SOURCE_WORDS[noise.source]}), per axis x y z:')
    for line in common.noise_lines(noise, unit_name):
        print(f'  {line}')


def _print_noise_source(noise_line: str) -> None:
    """Where the noise models written came from, and what reads them."""
    if noise_line:
        print(f'{noise_line}\nwritten with the calibration: the calibration watch and the Imu covariances use it')


def _nominal(args: argparse.Namespace, nominal: tuple[float, float, float] | None
             ) -> tuple[float, float, float] | None:
    """A counts bag's nominal scale: ``--nominal-scale`` (one value or x y z), else the bag's metadata."""
    if args.nominal_scale is not None:
        nominal = tuple(args.nominal_scale * 3 if len(args.nominal_scale) == 1 else args.nominal_scale)
        if len(nominal) != 3:
            msg = f'--nominal-scale takes one value or three (x y z), got {len(args.nominal_scale)}'
            raise TakError(msg)
    return nominal


def _fit_magnetometer(args: argparse.Namespace, record, kind: InputKind, *, imu_fitted: bool = True):
    """The magnetometer's fit when the driver bag holds one (``--iron-run``: its rotation record).

    Too few samples of it (one sensor's shortage), while the accelerometer or gyroscope is
    fitted and no option asks for it: held at nominal and said (:func:`held_mag_fit`).
    """
    from tak_thermo_ros.core.fit import ShortRecord
    from tak_thermo_ros.formats.records import open_record
    from tak_thermo_ros.passes.magnetometer import fit_mag_bag, has_mag, held_mag_fit
    iron_run = getattr(args, 'iron_run', None)
    effects = common.effect_list(getattr(args, 'mag_effects', None))
    options = common.stream_options(args)
    if kind is not InputKind.IMU or not has_mag(record):
        for option, given in (('--iron-run', iron_run is not None), ('--mag-effects', bool(effects))):
            if given:
                msg = f'{option}: {args.bag} holds no magnetometer on {options.topics.mag} to calibrate'
                raise TakError(msg)
        return None
    try:
        return fit_mag_bag(record, options, bias_order=args.bias_order, scale_order=args.scale_order,
                           temp_code_ref=args.temp_code_ref, effects=effects,
                           iron_run=open_record(iron_run, topics=options.topics) if iron_run is not None else None,
                           max_effect_samples=args.effect_samples)
    except ShortRecord as err:
        if not imu_fitted or iron_run is not None or effects:
            raise
        return held_mag_fit(err.reason or str(err))


def _print_magnetometer(fitted, args: argparse.Namespace) -> None:
    """``fit``'s lines for the magnetometer, in microtesla."""
    thermal, link = fitted.thermal, fitted.calibration.thermal
    for line in fitted.lines:
        print(line)
    if fitted.held:
        return
    if thermal.dropped:
        print(f'magnetometer: left out: {common.describe_dropped(thermal.dropped)}')
    print(f'magnetometer: {thermal.samples} samples on {common.topics(args).mag}')
    print(thermal.summary('magnetometer', 'T', calibration=link))
    iron = fitted.iron
    mag = fitted.calibration
    if iron is not None:
        rows = '; '.join(' '.join(f'{v:.4f}' for v in mag.soft_iron[3 * i:3 * i + 3]) for i in range(3))
        print(f'  hard iron x y z {" ".join(f"{v * 1e6:+.3f}" for v in mag.hard_iron)} uT')
        print(f'  soft iron [{rows}]')
        print(f'  ellipsoid: radius {iron.radius * 1e6:.3f} uT, residual RMS {iron.residual_rms * 1e6:.3f} uT')
        print(f'  ellipsoid: {iron.sections} of 20 sections of the sphere covered, spread {iron.spread:.2f}')
    for note in link.notes:
        print(f'note: magnetometer: {note}')


def _print_handheld(handheld) -> None:
    """What a hand-held fit used and held, the turns' closure, the paper's +/- table on plateaus."""
    record, fitted = handheld.record, handheld.fit
    skipped = record.skipped_turns
    reasons = {'gap': 'across a gap in the stamps', 'long': 'longer than 60 s', 'budget': 'beyond the sample budget'}
    kept = 'every sample' if record.stride == 1 else f'1 sample in {record.stride}'
    print(f'hand-held: {len(record.still):,} still samples ({kept}) in {len(np.unique(record.still_interval))} rests, '
          f'{len(record.turns)} turns')
    for reason, count in sorted(skipped.items()):  # one line each: every reason fits in 100 characters
        print(f'hand-held: {count} turns not used ({reasons[reason]})')
    for line in fitted.lines:
        print(line)
    closure = fitted.closure
    if len(closure.angle_rad):
        angles = (fitted.closure_before.rms_rad, closure.rms_rad, closure.floor_rad)
        before, after, floor = (np.degrees(angle) for angle in angles)
        print(f'turns: closure RMS {before:.3g} deg before the fit, {after:.3g} deg after '
              f'(the noise alone: {floor:.3g} deg)')
    if fitted.plus_minus:
        print("the paper's +/- method per plateau with all six faces, (3) offset and (5) scale, beside the link:")
        for row in fitted.plus_minus:
            print(f'  {row.temperature:5.1f} C {AXES[row.axis]}: (3) {row.offset:+.5f} m/s^2, (5) {row.scale:.5f}; '
                  f'link {row.link_offset:+.5f} m/s^2, {row.link_scale:.5f}; faces tilted <= {row.tilt_deg:.1f} deg')


def _print_handheld_terms(sensor: str, calibration, result, *, records: int = 1) -> None:
    """A hand-held fit's scale and offset at the reference temperature and the misalignment, with 1-sigma errors.

    :param records: a pool's records: from :data:`~tak_thermo_ros.core.fit.handheld.system.MIN_ROBUST_RECORDS`
        on its errors are never below what leaving each record out says (``record_robust``).
    """
    from tak_thermo_ros.core.effects import CrossAxis
    from tak_thermo_ros.core.fit.handheld.system import MIN_ROBUST_RECORDS
    errors = result.parameter_errors
    unit = common.UNITS[InputKind.IMU, sensor]
    small, factor = common.reader_unit(unit)
    basis = ('never below what leaving each record out says' if records >= MIN_ROBUST_RECORDS
             else 'the noise within each rest taken as white')
    print(f'  at {calibration.temp_code_ref:g} C, +- 1 sigma ({basis}):')
    for name, axis in zip(AXES, calibration.axes):
        scale_error = errors.get(f'{name}.scale', float('nan'))
        offset_error = errors.get(f'{name}.offset', float('nan'))
        scale = f'{axis.scale:.6g} +- {scale_error:.2g}' if axis.scale_observable else f'{axis.scale:g} (held)'
        if not np.isfinite(offset_error):  # held: nothing to put a +- on
            print(f'  {name}: scale {scale}, offset {axis.offset:+.4g} {unit} (held)')
            continue
        print(f'  {name}: scale {scale}, offset {axis.offset:+.4g} +- {offset_error:.2g} {unit} '
              f'({axis.offset * factor:+.4g} +- {offset_error * factor:.2g} {small})')
    for effect in calibration.effects:
        if isinstance(effect, CrossAxis):
            terms = [f'{p.name} {p.value * 1e3:+.3f} +- {errors[f"{effect.name}.{p.name}"] * 1e3:.2g}'
                     for p in effect.parameters if f'{effect.name}.{p.name}' in errors]
            for start in range(0, len(terms), 3):
                print(f'  misalignment, mrad: {", ".join(terms[start:start + 3])}')
        else:
            for line in result.effect_lines(unit, calibration=replace(calibration, effects=(effect,))):
                print(line)


def _prior(args: argparse.Namespace):
    """``--prior``'s fleet prior (``None`` without); orders given beside it must be its own."""
    if not args.prior:
        return None
    from tak_thermo_ros.formats.prior_file import load_prior
    prior = load_prior(args.prior)
    for option, given, own in (('--bias-order', args.bias_order, prior.bias_order),
                               ('--scale-order', args.scale_order, prior.scale_order)):
        if given != own and given != {'--bias-order': BIAS_ORDER, '--scale-order': SCALE_ORDER}[option]:
            msg = f'{option} {given}: not with --prior, whose curves are of order {own} (its fleet\'s)'
            raise TakError(msg)
    return prior


def _fit_pool(args: argparse.Namespace, settings, records=None) -> int:
    """``fit`` of a pool of one unit's everyday records (:mod:`tak_thermo_ros.passes.pool`): a line per record first."""
    from tak_thermo_ros.core.fit.pool import order_line
    from tak_thermo_ros.passes.pool_fit import fit_records, pool_unit
    from tak_thermo_ros.passes.pool_lines import coverage_lines, left_out_line, pool_header, turn_on_line
    for option, given in (('--iron-run', args.iron_run), ('--mag-effects', args.mag_effects),
                          ('--noise-from-residual', args.noise_from_residual)):
        if given:
            msg = f'{option}: not with a pool of records (fit the pool, then its magnetometer or noise apart)'
            raise TakError(msg)
    prior = _prior(args)
    fitted = fit_records(records or args.bag, settings, common.stream_options(args), prior=prior, say=print)
    opened, pool = fitted.opened, fitted.fit
    handheld = pool.fit
    results = handheld.results
    unit = pool_unit(fitted)
    if args.noise or args.noise_run:
        unit, noise_line = _with_noise(args, unit)
    else:
        from tak_thermo_ros.passes.rest_noise import rests_noise
        unit, noise_line = _with_fitted_noise(unit, rests_noise(pool.record, unit, gravity=settings.gravity,
                                                                latitude=settings.latitude))
    label = prior.label if prior is not None else ''
    save_unit(args.output, unit, header=pool_header(pool.record.records, args.output, label))
    for left in pool.left_out:
        print(left_out_line(left))
    for line in coverage_lines(opened, left_out=[left.name for left in pool.left_out]):
        print(line)
    if prior is not None:
        for line in (*prior.lines(), *fitted.lines):
            print(line)
    for sensor, choice in pool.orders.items():
        print(order_line(sensor, choice))
    for line in handheld.lines:
        print(line)
    if pool.record.records < 2 and unit.gyro.turn_on is None:
        print('turn-on repeatability: not estimated, one record (it takes two power-ups or more); none written')
    for sensor in handheld.turn_on:
        if prior is None or not prior.gives_turn_on(opened.record.records, sensor):  # else the fleet's, said above
            print(turn_on_line(sensor, handheld.turn_on[sensor], pool.record.records))
    for sensor in ('accel', 'gyro'):
        result = results[sensor]
        calibration = unit.sensor(sensor)
        if sensor == 'accel':
            print(f'calibrated temperature range {calibration.temp_code_min:.2f}..{calibration.temp_code_max:.2f} C, '
                  f'reference {calibration.temp_code_ref:.3g} C')
        unit_name = common.UNITS[InputKind.IMU, sensor]
        print('\n'.join(axes_lines(common.SENSOR_NAMES[sensor], calibration, result.residual_rms, unit_name)))
        _print_handheld_terms(sensor, calibration, result, records=pool.record.records)
        _print_noise(calibration.noise, unit_name)
    _print_noise_source(noise_line)
    print(f'wrote {args.output}')
    return 0
