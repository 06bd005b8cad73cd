"""``tak_calib``: simulate chamber runs, fit, apply and validate the correction link.

Every deliberate failure prints one line ``tak_calib: error: ...`` and exits with status 2;
no traceback reaches the user.
"""

from __future__ import annotations

import os

# Small least-squares problems on a 2-core machine run fastest single-threaded; competing
# OpenBLAS threads made `diagnose` up to 8x slower. Set before numpy loads; a user's value wins.
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Callable, Sequence  # noqa: E402

from tak_thermo_ros.core.calibration_file import load_calibration, save_calibration, write_text_atomic
from tak_thermo_ros.core.correction import Corrector, OutOfRange, acceleration_variance
from tak_thermo_ros.core.fit import fit_model
from tak_thermo_ros.core.model import AXES
from tak_thermo_ros.core.record import AlignedSamples, ChannelRecord, align
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


def _read_samples(args: argparse.Namespace, *, calibration_run: bool,
                  settle_time_s: float = 0.0) -> tuple[ChannelRecord, AlignedSamples]:
    """Read the bag named by ``args.bag`` and align its streams on the counts stamps.

    :param calibration_run: the reference stream is required and held on the samples.
    """
    from tak_thermo_ros.bagio import read_record
    record = read_record(args.bag, topics=_topics(args), require_reference=calibration_run,
                         progress=not args.no_progress)
    return record, align(record, use_reference=calibration_run, settle_time_s=settle_time_s)


def _describe_dropped(dropped: dict[str, int]) -> str:
    return ', '.join(f'{count} {reason.replace("_", " ")}' for reason, count in sorted(dropped.items()))


def cmd_fit(args: argparse.Namespace) -> int:
    """Fit the correction link to a calibration bag."""
    record, samples = _read_samples(args, calibration_run=True, settle_time_s=args.settle_time)
    nominal = record.nominal_scale
    if args.nominal_scale is not None:
        nominal = tuple(args.nominal_scale * 3 if len(args.nominal_scale) == 1 else args.nominal_scale)
        if len(nominal) != 3:
            msg = f'--nominal-scale takes one value or three (x y z), got {len(args.nominal_scale)}'
            raise TakError(msg)
    effects = [spec.strip() for spec in (args.effects or '').split(',') if spec.strip()]
    result = fit_model(samples, effects=effects, bias_order=args.bias_order, scale_order=args.scale_order,
                       temp_code_ref=args.temp_code_ref, nominal_scale=nominal)
    calibration = result.calibration
    header = (f'tak_thermo_ros calibration fitted from {args.bag}\n'
              f'{result.samples} samples, bias order {args.bias_order}, scale order {args.scale_order}'
              f'{", effects " + ", ".join(e.name for e in calibration.effects) if calibration.effects else ""}\n'
              f'load with: ros2 run tak_thermo_ros compensator --ros-args --params-file {Path(args.output).name}')
    save_calibration(args.output, calibration, header=header)
    print(f'fitted {result.samples} samples from {args.bag}')
    if result.dropped:
        print(f'left out: {_describe_dropped(result.dropped)}')
    print(f'calibrated temperature-code range {calibration.temp_code_min:g}..{calibration.temp_code_max:g}, '
          f'reference {calibration.temp_code_ref:g}')
    for name, axis, stats in zip(AXES, calibration.axes, result.axes):
        print(f'  {name}: residual RMS {stats.residual_rms:.3f} counts '
              f'({stats.residual_rms / axis.scale * 1000.0:.3f} mm/s^2); scale {axis.scale:.4f} counts/(m/s^2)'
              f'{"" if axis.scale_observable else " (held)"}, '
              f'offset {axis.offset:.3f}, offset span {axis.offset_span:.3f} counts')
    for effect in calibration.effects:
        errors = result.parameter_errors
        shown = ', '.join(f'{p.name} {p.value:.4g}' + (f' +- {errors[effect.name + "." + p.name]:.2g}'
                                                       if effect.name + '.' + p.name in errors else '')
                          + (f' {p.unit}' if p.unit else '') for p in effect.parameters)
        print(f'  effect {effect.name}: {shown}')
    for note in calibration.notes:
        print(f'note: {note}')
    print(f'wrote {args.output}')
    return 0


def cmd_apply(args: argparse.Namespace) -> int:
    """Correct a bag's counts and write Imu messages."""
    from tak_thermo_ros.bagio import write_imu
    calibration = load_calibration(args.params)
    record, samples = _read_samples(args, calibration_run=False)
    corrector = Corrector(calibration, out_of_range=OutOfRange(args.out_of_range))
    acceleration = corrector.correct(samples.counts, samples.temp_code, stamp_s=samples.stamp_s)
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
    calibration = load_calibration(args.params)
    _, samples = _read_samples(args, calibration_run=False)
    result = validate_gravity(calibration, samples.counts, samples.temp_code, gravity=args.gravity,
                              stamp_s=samples.stamp_s,
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


def cmd_import_csv(args: argparse.Namespace) -> int:
    """Convert a delimited log of a static thermal run into a bag."""
    from tak_thermo_ros.bagio import write_record
    from tak_thermo_ros.core.csv_log import CsvImportOptions, delimiter_from_option, read_csv_log
    options = CsvImportOptions(
        acc_columns=tuple(args.acc_columns), temp_column=args.temp_column, time_column=args.time_column,
        time_unit=args.time_unit, acc_unit=args.acc_unit, acc_resolution=args.acc_resolution,
        temp_resolution=args.temp_resolution, gravity=args.gravity,
        reference=tuple(args.reference) if args.reference else None,
        delimiter=delimiter_from_option(args.delimiter) if args.delimiter else None, frame_id=args.frame_id)
    log = read_csv_log(args.log, options)
    record = log.record
    write_record(args.output, record, topics=_topics(args), storage=args.storage)
    print(f'read {args.log}: {log.rows} rows ({log.delimiter_name}-delimited), {log.duration_s:.1f} s '
          f'at {(log.rows - 1) / max(log.duration_s, 1e-9):.3g} Hz')
    print(f'acceleration {" ".join(options.acc_columns)} in {options.acc_unit}: counts = round(a / '
          f'{options.acc_resolution:g} m/s^2), {record.counts.min():.0f}..{record.counts.max():.0f}; '
          f'nominal scale {options.nominal_scale:g} counts/(m/s^2) (bag metadata)')
    print(f'temperature {options.temp_column}: {log.temperature.min():.2f}..{log.temperature.max():.2f} C, '
          f'codes = round(T / {options.temp_resolution:g} C) = {record.temp_code.min():.0f}..{record.temp_code.max():.0f}')
    x, y, z = (float(v) for v in log.reference)
    if log.reference_estimated:
        dx, dy, dz = (float(v) for v in log.mean_direction)
        print(f'reference (static run): mean measured direction ({dx:.5f}, {dy:.5f}, {dz:.5f}) scaled to gravity '
              f'{options.gravity:g} m/s^2 = ({x:.4f}, {y:.4f}, {z:.4f}) m/s^2 in the sensor frame '
              f'(largest deviation {log.max_tilt_deg:.2f} deg), written once at the start')
    else:
        print(f'reference (given): ({x:.4f}, {y:.4f}, {z:.4f}) m/s^2 in the sensor frame, written once at the start')
    print(f'wrote {args.output} ({args.storage})')
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    """Compare a calibration with a run: noise floor, residual views, the missing effect."""
    from tak_thermo_ros.core.diagnose import diagnose
    calibration = load_calibration(args.params)
    _, samples = _read_samples(args, calibration_run=True, settle_time_s=args.settle_time)
    verbose = not args.no_progress and sys.stderr.isatty()

    def progress(text: str) -> None:
        if verbose:
            print(f'cross-validating {text} ...', file=sys.stderr)

    candidates = expand_candidates(args.candidates) if args.candidates else None
    result = diagnose(calibration, samples, candidates=candidates, folds=args.folds, progress=progress)
    print(f'diagnosed {len(samples)} samples of {args.bag} against {args.params} '
          f'(model: {result.ladder[0].label})')
    if samples.dropped:
        print(f'left out: {_describe_dropped(samples.dropped)}')
    for name, axis in zip(AXES, result.axes):
        print(f'  {name}: residual RMS {axis.rms:.3f} counts, noise floor {axis.noise_floor:.3f}; held-out '
              f'{axis.heldout_rms:.3f} ({axis.heldout_rms / axis.noise_floor:.2f}x the floor)')
    if result.candidates:
        print('candidates, best first (held-out RMS x y z in counts; share of the excess over the floor removed):')
        for candidate in result.candidates:
            rms = ' '.join(f'{v:8.3f}' for v in candidate.rms_after)
            print(f'  {candidate.effect:<20} {rms}  {round(100.0 * candidate.explained):5d}%')
    for name, reason in result.skipped.items():
        print(f'  {name:<20} not tried: {reason}')
    if len(result.ladder) > 1:
        print('model ladder (held-out RMS x y z): ' + '; '.join(
            f'{step.label}: {" ".join(f"{v:.3f}" for v in step.heldout_rms)}' for step in result.ladder))
    print(f'verdict: {result.verdict}')
    print(result.message)
    if args.json:
        write_text_atomic(args.json, json.dumps(result.as_dict(), indent=2) + '\n')
        print(f'wrote {args.json}')
    if getattr(args, 'design_run', None):
        from tak_thermo_ros.core.diagnose import design_run, write_design
        design = design_run(result, samples, progress=progress)
        paths = write_design(design, args.design_run)
        print(design.message())
        print('wrote ' + ', '.join(str(path) for path in paths))
    if args.report:
        from tak_thermo_ros.report import write_report
        files = write_report(result, samples, args.report, source=Path(args.bag).name, gravity=args.gravity)
        print(f'wrote {files.html} ({len(files.figures)} figures)')
    return 0


def expand_candidates(text: str) -> list[str]:
    """``--candidates`` as a list: comma-separated specs, ``library`` = every library effect."""
    from tak_thermo_ros.core.effects import LIBRARY
    candidates: list[str] = []
    for spec in (part.strip() for part in text.split(',')):
        names = list(LIBRARY) if spec == 'library' else [spec] if spec else []
        candidates += [name for name in names if name not in candidates]
    return candidates


def build_parser() -> argparse.ArgumentParser:
    """The ``tak_calib`` argument parser."""
    parser = argparse.ArgumentParser(prog='tak_calib', description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')

    sim = commands.add_parser('simulate', help='simulate a thermal-chamber run into a bag')
    sim.add_argument('out_bag', metavar='OUT_BAG')
    sim.add_argument('--scenario', metavar='FILE.yaml', help='scenario overrides, every key optional (README: The simulator)')
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
    fit.add_argument('--effects', metavar='NAME[,NAME...]',
                     help='effects to fit beyond the paper\'s model: thermal_lag, hysteresis, scale_nonlinearity, '
                          'cross_axis, warmup, temperature_shape, the per-axis forms thermal_lag_per_axis, '
                          'hysteresis_per_axis, warmup_per_axis, or module:Class (see docs/effects.md)')
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
    imp = commands.add_parser('import-csv', help='convert a delimited log of a static thermal run into a bag')
    imp.add_argument('log', metavar='LOG.csv')
    imp.add_argument('-o', '--output', required=True, metavar='OUT_BAG')
    imp.add_argument('--acc-columns', nargs=3, required=True, metavar=('X', 'Y', 'Z'),
                     help='the acceleration columns along the sensor axes x, y, z')
    imp.add_argument('--temp-column', required=True, help='the temperature column (degrees Celsius)')
    imp.add_argument('--time-column', default='timestamp', help='the time column (default: timestamp)')
    imp.add_argument('--time-unit', choices=['s', 'ms', 'us', 'ns'], default='s', help='unit of the time column (default s)')
    imp.add_argument('--acc-unit', choices=['m/s^2', 'g'], default='m/s^2',
                     help='unit of the acceleration columns (1 g = 9.80665 m/s^2; default m/s^2)')
    imp.add_argument('--acc-resolution', type=float, default=1e-3, metavar='M/S^2',
                     help='m/s^2 per channel count: counts = round(a / resolution) (default 0.001); '
                          'the nominal scale 1/resolution goes into the bag metadata')
    imp.add_argument('--temp-resolution', type=float, default=0.01, metavar='CELSIUS',
                     help='degrees per temperature code: N_t = round(T / resolution) (default 0.01)')
    imp.add_argument('--gravity', type=float, default=STANDARD_GRAVITY,
                     help='local gravity, m/s^2: magnitude of the estimated reference (default 9.80665)')
    imp.add_argument('--reference', type=float, nargs=3, metavar=('X', 'Y', 'Z'),
                     help='the specific force in the sensor frame, m/s^2, if known (default: the mean '
                          'measured direction scaled to --gravity)')
    imp.add_argument('--delimiter', help='field delimiter: tab, comma, semicolon or one character '
                                         '(default: sniffed from the header line)')
    imp.add_argument('--frame-id', default='imu', help='frame_id of the counts messages (default imu)')
    imp.add_argument('--storage', choices=['mcap', 'sqlite3'], default='mcap')
    _add_topic_options(imp)
    imp.set_defaults(handler=cmd_import_csv)
    diag = commands.add_parser('diagnose', help='compare a calibration with a run and find the missing effect')
    diag.add_argument('bag', metavar='BAG')
    diag.add_argument('--params', required=True, metavar='PARAMS.yaml')
    diag.add_argument('--json', metavar='OUT.json', help='write the verdict, RMS, floor and candidates as JSON')
    diag.add_argument('--report', metavar='DIR', help='write PNG figures and report.html into DIR')
    diag.add_argument('--candidates', metavar='NAME[,NAME...]',
                      help='effects to try (default: every library effect the calibration lacks); '
                           "module:Class for a user-defined effect (see docs/effects.md); 'library' "
                           "stands for every library effect, e.g. library,mymodule:MyEffect")
    diag.add_argument('--folds', type=int, default=5, help='cross-validation folds (default 5)')
    diag.add_argument('--settle-time', type=float, default=0.0, metavar='SECONDS',
                      help='leave out samples this long after each reference change (as for fit)')
    diag.add_argument('--gravity', type=float, default=STANDARD_GRAVITY, help='local gravity for the |g| figure, m/s^2')
    diag.add_argument('--design-run', metavar='DIR',
                      help='propose the chamber run that tells the two best candidates apart: writes '
                           'DIR/scenario.yaml (for tak_calib simulate), DIR/schedule.csv (time_s, setpoint_C) '
                           'and DIR/design.json with the simulated separation')
    _add_topic_options(diag)
    diag.set_defaults(handler=cmd_diagnose)
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
