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

from dataclasses import dataclass, replace  # noqa: E402

import numpy as np  # noqa: E402

from tak_thermo_ros.core.calibration_file import load_unit, save_unit, write_text_atomic
from tak_thermo_ros.core.correction import OutOfRange, UnitCorrector, acceleration_variance
from tak_thermo_ros.core.fit import FitResult
from tak_thermo_ros.core.model import AXES, InputKind, UnitCalibration
from tak_thermo_ros.core.record import AlignedSamples, ChannelRecord, DriverRecord, align
from tak_thermo_ros.core.simulate import STANDARD_GRAVITY, Scenario, load_scenario, simulate
from tak_thermo_ros.core.static_run import STATIC_TOLERANCE_DEG, static_reference
from tak_thermo_ros.errors import TakError

EXIT_ERROR = 2


UNITS = {(InputKind.COUNTS, 'accel'): 'counts', (InputKind.IMU, 'accel'): 'm/s^2', (InputKind.IMU, 'gyro'): 'rad/s'}
"""The unit of a sensor's residuals and offsets, by input kind."""
SENSOR_NAMES = {'accel': 'accelerometer', 'gyro': 'gyroscope'}


def _topics(args: argparse.Namespace):
    from tak_thermo_ros.bagio import Topics
    defaults = Topics()
    return Topics(counts=args.counts_topic, temp_code=args.temp_topic or defaults.temp_code,
                  reference=args.reference_topic, imu=getattr(args, 'imu_topic', None) or defaults.imu,
                  raw_imu=args.raw_imu_topic, temperature=args.temp_topic or defaults.temperature,
                  reference_rate=args.reference_rate_topic,
                  compensated_imu=getattr(args, 'imu_topic', None) or defaults.compensated_imu)


def _add_topic_options(parser: argparse.ArgumentParser, *, imu: bool = False) -> None:
    group = parser.add_argument_group('topics (the input kind is taken from the bag: counts topic or driver Imu)')
    group.add_argument('--counts-topic', default='/tak/counts', help='channel codes (Vector3Stamped)')
    group.add_argument('--raw-imu-topic', default='/imu/data_raw', help="a driver's Imu (default /imu/data_raw)")
    group.add_argument('--temp-topic', help='temperature (Temperature): codes /tak/temp_code with counts, '
                                            'degrees C /imu/temperature with a driver Imu')
    group.add_argument('--reference-topic', default='/tak/reference', help='true specific force (Vector3Stamped)')
    group.add_argument('--reference-rate-topic', default='/tak/reference_rate',
                       help='true angular rate, rad/s (Vector3Stamped; driver bags)')
    if imu:
        group.add_argument('--imu-topic', help='corrected output (Imu): default /tak/imu/data_raw with counts, '
                                               '/imu/data_compensated with a driver Imu')
    parser.add_argument('--no-progress', action='store_true', help='no progress bar even on a terminal')


def _add_static_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group('driver bags without reference topics (a static run)')
    group.add_argument('--gravity', type=float, default=STANDARD_GRAVITY,
                       help='local gravity, m/s^2: the magnitude of the estimated specific-force reference')
    group.add_argument('--latitude', type=float, metavar='DEG',
                       help="adds the Earth rate's vertical component (Omega_E sin(latitude), along the "
                            'measured up direction) to the rate reference; default zero')


def _out_of_range(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--out-of-range', choices=[p.value for p in OutOfRange], default=OutOfRange.CLAMP.value,
                        help='temperature codes outside the calibrated range: clamp to the edge (default) '
                             'or extrapolate the polynomials; either way the count is reported')


def cmd_simulate(args: argparse.Namespace) -> int:
    """Simulate a chamber run into a bag (the paper's counts, or a driver's Imu)."""
    from tak_thermo_ros.bagio import write_driver_record, write_record
    scenario = load_scenario(args.scenario) if args.scenario else Scenario()
    if args.seed is not None:
        scenario = replace(scenario, seed=args.seed)
    run = simulate(scenario)
    if run.driver is not None:
        driver = run.driver
        write_driver_record(args.out_bag, driver, topics=_topics(args), storage=args.storage)
        print(f'wrote {args.out_bag}: {len(driver.stamp_ns)} Imu, {len(driver.temp_stamp_ns)} temperature, '
              f'{len(driver.reference_stamp_ns)} reference changes, {scenario.duration_s() / 3600.0:.2f} h at '
              f'{scenario.sample_rate_hz:g} Hz ({args.storage}); temperature '
              f'{driver.temperature.min():.2f}..{driver.temperature.max():.2f} C')
        return 0
    write_record(args.out_bag, run.record, topics=_topics(args), storage=args.storage)
    record = run.record
    print(f'wrote {args.out_bag}: {len(record.counts_stamp_ns)} counts, {len(record.temp_stamp_ns)} temperature codes, '
          f'{len(record.reference_stamp_ns)} reference changes, {scenario.duration_s() / 3600.0:.2f} h '
          f'at {scenario.sample_rate_hz:g} Hz ({args.storage}); temperature code '
          f'{record.temp_code.min():.0f}..{record.temp_code.max():.0f}')
    return 0


@dataclass(frozen=True)
class SensorRun:
    """One sensor's streams of a bag, aligned on its stamps.

    :param sensor: ``'accel'`` or ``'gyro'``.
    :param record: the streams.
    :param samples: the usable samples, reference held (calibration runs).
    """

    sensor: str
    record: ChannelRecord
    samples: AlignedSamples


@dataclass(frozen=True)
class BagRun:
    """A bag read for fit, diagnose or validate: one :class:`SensorRun` per sensor.

    :param input_kind: counts (the paper's bag contract) or a driver's Imu.
    :param sensors: the accelerometer, then (driver bags) the gyroscope.
    :param reference_lines: how the reference was obtained, one line each (driver bags).
    """

    input_kind: InputKind
    sensors: tuple[SensorRun, ...]
    reference_lines: tuple[str, ...] = ()

    def sensor(self, name: str) -> SensorRun:
        """The run of ``'accel'`` or ``'gyro'``."""
        return next(run for run in self.sensors if run.sensor == name)


def _read_run(args: argparse.Namespace, *, calibration_run: bool, settle_time_s: float = 0.0) -> BagRun:
    """Read the bag named by ``args.bag``, whichever contract it follows, and align its streams.

    :param calibration_run: the reference is required (counts bags) or estimated (driver
        bags without reference topics: a static run), and held on the samples.
    """
    from tak_thermo_ros.bagio import bag_input_kind, read_driver_record, read_record
    topics = _topics(args)
    kind = bag_input_kind(args.bag, topics=topics)
    if kind is InputKind.COUNTS:
        record = read_record(args.bag, topics=topics, require_reference=calibration_run,
                             progress=not args.no_progress)
        samples = align(record, use_reference=calibration_run, settle_time_s=settle_time_s)
        return BagRun(kind, (SensorRun('accel', record, samples),))
    driver = read_driver_record(args.bag, topics=topics, progress=not args.no_progress)
    driver, lines = _with_references(driver, args, topics)
    runs = []
    for sensor in ('accel', 'gyro'):
        record = driver.channel(sensor)
        runs.append(SensorRun(sensor, record, align(record, use_reference=True, settle_time_s=settle_time_s)))
    return BagRun(kind, tuple(runs), tuple(lines))


def _with_references(driver: DriverRecord, args: argparse.Namespace, topics) -> tuple[DriverRecord, list[str]]:
    """The driver record with both references: recorded, or those of a static run."""
    lines = []
    if len(driver.reference_stamp_ns) and len(driver.rate_reference_stamp_ns):
        return driver, [f'reference: {topics.reference} and {topics.reference_rate} as recorded']
    finite = np.all(np.isfinite(driver.accel), axis=1)
    gravity = getattr(args, 'gravity', STANDARD_GRAVITY)
    latitude = getattr(args, 'latitude', None)
    static = static_reference(driver.accel[finite], gravity=gravity, latitude_deg=latitude)
    first = driver.stamp_ns[:1].copy()
    if len(driver.reference_stamp_ns):
        lines.append(f'reference: {topics.reference} as recorded')
    else:
        if static.magnitude < 0.1 * gravity:
            msg = (f'{args.bag}: no {topics.reference} and the mean acceleration |{static.magnitude:.4g}| m/s^2 is '
                   f'far below gravity: not a static run; record the reference')
            raise TakError(msg)
        if static.max_tilt_deg > STATIC_TOLERANCE_DEG:
            msg = (f'{args.bag}: no {topics.reference} and the board moved (a sample {static.max_tilt_deg:.1f} deg '
                   f'from the mean direction): a static run needs one orientation; record the reference')
            raise TakError(msg)
        x, y, z = (float(v) for v in static.specific_force)
        lines.append(f'reference (static run): mean measured direction scaled to gravity {gravity:g} m/s^2 = '
                     f'({x:.4f}, {y:.4f}, {z:.4f}) m/s^2 (largest deviation {static.max_tilt_deg:.2f} deg)')
        driver = replace(driver, reference_stamp_ns=first, reference=static.specific_force.reshape(1, 3))
    if len(driver.rate_reference_stamp_ns):
        lines.append(f'rate reference: {topics.reference_rate} as recorded')
    else:
        x, y, z = (float(v) for v in static.rate)
        lines.append(f'rate reference (static run): zero' if latitude is None else
                     f'rate reference (static run): the Earth rate\'s vertical component at latitude {latitude:g} deg '
                     f'= ({x:.3e}, {y:.3e}, {z:.3e}) rad/s')
        driver = replace(driver, rate_reference_stamp_ns=first, rate_reference=static.rate.reshape(1, 3))
    return driver, lines


def _stream_options(args: argparse.Namespace):
    from tak_thermo_ros.streaming import StreamOptions
    return StreamOptions(topics=_topics(args), progress=not args.no_progress)


def _describe_dropped(dropped: dict[str, int]) -> str:
    return ', '.join(f'{count} {reason.replace("_", " ")}' for reason, count in sorted(dropped.items()))


def _nominal(args: argparse.Namespace, record: ChannelRecord) -> tuple[float, float, float] | None:
    nominal = record.nominal_scale
    if args.nominal_scale is not None and record.input_kind == InputKind.COUNTS.value:
        nominal = tuple(args.nominal_scale * 3 if len(args.nominal_scale) == 1 else args.nominal_scale)
        if len(nominal) != 3:
            msg = f'--nominal-scale takes one value or three (x y z), got {len(args.nominal_scale)}'
            raise TakError(msg)
    return nominal


def _effect_list(text: str | None) -> list[str]:
    return [spec.strip() for spec in (text or '').split(',') if spec.strip()]


def cmd_fit(args: argparse.Namespace) -> int:
    """Fit the correction link to a calibration bag (counts, or a driver's Imu: both sensors)."""
    from tak_thermo_ros.streaming import FitSettings, fit_bag
    effects = {'accel': _effect_list(args.effects), 'gyro': _effect_list(args.gyro_effects)}
    settings = FitSettings(effects=effects, bias_order=args.bias_order, scale_order=args.scale_order,
                           temp_code_ref=args.temp_code_ref, settle_time_s=args.settle_time,
                           gravity=getattr(args, 'gravity', STANDARD_GRAVITY), latitude=getattr(args, 'latitude', None))
    run = fit_bag(args.bag, settings, _stream_options(args), nominal_for=lambda kind, scale: _nominal(
        args, ChannelRecord(counts_stamp_ns=np.zeros(0, dtype=np.int64), counts=np.zeros((0, 3)),
                            temp_stamp_ns=np.zeros(0, dtype=np.int64), temp_code=np.zeros(0),
                            nominal_scale=scale, input_kind=kind.value)))
    results: dict[str, FitResult] = run.results
    unit = UnitCalibration(run.input_kind, results['accel'].calibration,
                           results['gyro'].calibration if 'gyro' in results else None)
    applied = ', '.join(f'{sensor} {", ".join(e.name for e in calibration.effects)}'
                        for sensor, calibration in unit.sensors if calibration.effects)
    header = (f'tak_thermo_ros calibration fitted from {args.bag}\n'
              f'{results["accel"].samples} samples, bias order {args.bias_order}, scale order {args.scale_order}'
              f'{", effects " + applied if applied else ""}\n'
              f'load with: ros2 run tak_thermo_ros compensator --ros-args --params-file {Path(args.output).name}')
    save_unit(args.output, unit, header=header)
    print(f'fitted {results["accel"].samples} samples from {args.bag}'
          f'{" (driver Imu: accelerometer and gyroscope)" if run.input_kind is InputKind.IMU else ""}')
    for line in run.reference_lines:
        print(line)
    for sensor in run.sensors:
        result = results[sensor]
        calibration = result.calibration
        unit_name = UNITS[run.input_kind, sensor]
        prefix = '' if run.input_kind is InputKind.COUNTS else f'{SENSOR_NAMES[sensor]}: '
        if result.dropped:
            print(f'{prefix}left out: {_describe_dropped(result.dropped)}')
        if run.effect_stride.get(sensor, 1) > 1:
            print(f'{prefix}effects fitted on one sample in {run.effect_stride[sensor]} ({result.samples} of '
                  f'{run.usable[sensor]} usable; docs/streaming.md)')
        if run.input_kind is InputKind.COUNTS:
            print(f'calibrated temperature-code range {calibration.temp_code_min:g}..{calibration.temp_code_max:g}, '
                  f'reference {calibration.temp_code_ref:g}')
        elif sensor == 'accel':
            print(f'calibrated temperature range {calibration.temp_code_min:g}..{calibration.temp_code_max:g} C, '
                  f'reference {calibration.temp_code_ref:g} C')
        if prefix:
            print(prefix.rstrip())
        for name, axis, stats in zip(AXES, calibration.axes, result.axes):
            print(f'  {name}: residual RMS {_amount(stats.residual_rms, unit_name)}'
                  f'{_in_si(stats.residual_rms / axis.scale, unit_name)}; '
                  f'scale {axis.scale:.6g}{" counts/(m/s^2)" if unit_name == "counts" else ""}'
                  f'{"" if axis.scale_observable else " (held)"}, '
                  f'offset {_amount(axis.offset, unit_name)}, offset span {_amount(axis.offset_span, unit_name)}')
        for effect in calibration.effects:
            errors = result.parameter_errors
            shown = ', '.join(f'{p.name} {p.value:.4g}' + (f' +- {errors[effect.name + "." + p.name]:.2g}'
                                                           if effect.name + '.' + p.name in errors else '')
                              + (f' {p.unit}' if p.unit else '') for p in effect.parameters)
            print(f'  effect {effect.name}: {shown}')
        for note in calibration.notes:
            print(f'note: {prefix}{note}')
    print(f'wrote {args.output}')
    return 0


def _amount(value: float, unit: str) -> str:
    """A residual or offset in a sensor's unit (counts to three decimals, SI to four digits)."""
    if unit == 'counts':
        return f'{value:.3f} counts'
    if unit == 'rad/s':
        return f'{value:.4g} rad/s ({value * 180.0 / 3.141592653589793:.4g} deg/s)'
    return f'{value:.4g} {unit}'


def _in_si(value: float, unit: str) -> str:
    return f' ({value * 1000.0:.3f} mm/s^2)' if unit == 'counts' else ''


def cmd_apply(args: argparse.Namespace) -> int:
    """Correct a bag's counts or driver Imu and write Imu messages."""
    from tak_thermo_ros.bagio import bag_input_kind
    from tak_thermo_ros.streaming import apply_bag
    unit = load_unit(args.params)
    topics = _topics(args)
    kind = bag_input_kind(args.bag, topics=topics)
    if kind is not unit.input_kind:
        msg = (f'{args.params} is a {unit.input_kind.value} calibration, {args.bag} holds '
               f'{"channel codes" if kind is InputKind.COUNTS else "a driver Imu"}')
        raise TakError(msg)
    applied = apply_bag(args.bag, unit, args.output, _stream_options(args), storage=args.storage,
                        out_of_range=OutOfRange(args.out_of_range))
    print(f'wrote {applied.written} Imu messages on {applied.topic} to {args.output}')
    if applied.dropped:
        print(f'dropped {"counts" if kind is InputKind.COUNTS else "Imu"} messages: {_describe_dropped(applied.dropped)}')
    outside = applied.out_of_range
    if outside:
        low, high = unit.accel.temp_code_min, unit.accel.temp_code_max
        what = 'temperature code' if kind is InputKind.COUNTS else 'temperature'
        print(f'warning: {outside} samples had a {what} outside the calibrated range '
              f'{low:g}..{high:g} ({args.out_of_range})')
    return 0


def cmd_validate(args: argparse.Namespace) -> int:
    """|g| from the three accelerometer channels (and the gyroscope's rate error) before and after correction."""
    from tak_thermo_ros.streaming import validate_bag
    unit = load_unit(args.params)
    run = validate_bag(args.bag, unit, _stream_options(args), gravity=args.gravity,
                       latitude=getattr(args, 'latitude', None), out_of_range=OutOfRange(args.out_of_range),
                       expect_kind=lambda kind: _check_kind(args, unit, BagRun(kind, ())))
    result = run.gravity
    before, after = result.before.gravity_error(), result.after.gravity_error()
    print(f'|g| error over {result.samples} samples of {args.bag} (gravity {args.gravity:g} m/s^2):')
    print(f'  before (nominal scale and offset): RMS {before.rms:.5f} m/s^2 ({before.rms / args.gravity * 1e3:.3f} mg), '
          f'max {before.max:.5f} m/s^2')
    print(f'  after  (full correction link):     RMS {after.rms:.5f} m/s^2 ({after.rms / args.gravity * 1e3:.3f} mg), '
          f'max {after.max:.5f} m/s^2')
    if result.out_of_range:
        print(f'warning: {result.out_of_range} samples outside the calibrated temperature range ({args.out_of_range})')
    document = {'bag': str(args.bag), 'params': str(args.params), 'gravity': args.gravity,
                'samples': result.samples, 'out_of_range': result.out_of_range,
                'before': before.as_dict(), 'after': after.as_dict()}
    if unit.gyro is not None:
        for line in run.reference_lines:
            if line.startswith('rate reference'):
                print(line)
        rate = run.rate
        rate_before, rate_after = rate.before.rate_error(), rate.after.rate_error()
        print(f'gyroscope bias error over {rate.samples} samples (rate minus reference, per axis x y z):')
        for label, stats in (('before (nominal scale and offset)', rate_before), ('after  (full correction link)', rate_after)):
            print(f'  {label}: RMS ' + ' '.join(f'{v:.3e}' for v in stats.rms) + ' rad/s; mean '
                  + ' '.join(f'{v:+.3e}' for v in stats.mean) + ' rad/s')
        document['gyro'] = {'samples': rate.samples, 'before': rate_before.as_dict(), 'after': rate_after.as_dict()}
    if args.json:
        write_text_atomic(args.json, json.dumps(document, indent=2) + '\n')
        print(f'wrote {args.json}')
    return 0


def _check_kind(args: argparse.Namespace, unit: UnitCalibration, run: BagRun) -> None:
    if run.input_kind is not unit.input_kind:
        msg = (f'{args.params} is a {unit.input_kind.value} calibration, {args.bag} holds '
               f'{"channel codes" if run.input_kind is InputKind.COUNTS else "a driver Imu"}')
        raise TakError(msg)


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
    """Compare a calibration with a run: noise floor, residual views, the missing effect, per sensor."""
    from tak_thermo_ros.core.diagnose import diagnose
    from tak_thermo_ros.streaming import bounded_run
    unit = load_unit(args.params)
    bounded = bounded_run(args.bag, _stream_options(args), settle_time_s=args.settle_time, gravity=args.gravity,
                          latitude=getattr(args, 'latitude', None))
    empty = ChannelRecord(counts_stamp_ns=np.zeros(0, dtype=np.int64), counts=np.zeros((0, 3)),
                          temp_stamp_ns=np.zeros(0, dtype=np.int64), temp_code=np.zeros(0))
    run = BagRun(bounded.input_kind, tuple(SensorRun(sensor, empty, samples) for sensor, samples in bounded.samples.items()),
                 bounded.reference_lines)
    _check_kind(args, unit, run)
    verbose = not args.no_progress and sys.stderr.isatty()
    candidates = expand_candidates(args.candidates) if args.candidates else None
    for line in run.reference_lines:
        print(line)
    results = {}
    for sensor_run in run.sensors:
        sensor, samples = sensor_run.sensor, sensor_run.samples
        unit_name = UNITS[run.input_kind, sensor]
        label = '' if run.input_kind is InputKind.COUNTS else f'{SENSOR_NAMES[sensor]}: '

        def progress(text: str, label: str = label) -> None:
            if verbose:
                print(f'{label}cross-validating {text} ...', file=sys.stderr)

        result = diagnose(unit.sensor(sensor), samples, candidates=candidates, folds=args.folds, progress=progress)
        results[sensor] = result
        print(f'{label}diagnosed {len(samples)} samples of {args.bag} against {args.params} '
              f'(model: {result.ladder[0].label})')
        if bounded.stride > 1:
            print(f'{label}one sample in {bounded.stride} of the run\'s {bounded.usable[sensor]} usable samples '
                  f'(diagnose works on a bounded subsample spread over the run)')
        if samples.dropped:
            print(f'left out: {_describe_dropped(samples.dropped)}')
        for name, axis in zip(AXES, result.axes):
            print(f'  {name}: residual RMS {axis.rms:.4g} {unit_name}, noise floor {axis.noise_floor:.4g}; held-out '
                  f'{axis.heldout_rms:.4g} ({axis.heldout_rms / axis.noise_floor:.2f}x the floor)')
        if result.candidates:
            print(f'candidates, best first (held-out RMS x y z in {unit_name}; share of the excess over the floor removed):')
            for candidate in result.candidates:
                rms = ' '.join(f'{v:8.4g}' for v in candidate.rms_after)
                print(f'  {candidate.effect:<20} {rms}  {round(100.0 * candidate.explained):5d}%')
        for name, reason in result.skipped.items():
            print(f'  {name:<20} not tried: {reason}')
        if len(result.ladder) > 1:
            print('model ladder (held-out RMS x y z): ' + '; '.join(
                f'{step.label}: {" ".join(f"{v:.4g}" for v in step.heldout_rms)}' for step in result.ladder))
        print(f'{label}verdict: {result.verdict}')
        print(result.message)
    if args.json:
        document = results['accel'].as_dict()
        if run.input_kind is InputKind.IMU:
            document['sensors'] = {sensor: {**result.as_dict(), 'unit': UNITS[run.input_kind, sensor]}
                                   for sensor, result in results.items()}
        write_text_atomic(args.json, json.dumps(document, indent=2) + '\n')
        print(f'wrote {args.json}')
    if args.report:
        from tak_thermo_ros.report import write_report, write_sensor_index
        if run.input_kind is InputKind.COUNTS:
            files = write_report(results['accel'], run.sensor('accel').samples, args.report,
                                 source=Path(args.bag).name, gravity=args.gravity)
            print(f'wrote {files.html} ({len(files.figures)} figures)')
        else:
            pages = {}
            for sensor, result in results.items():
                files = write_report(result, run.sensor(sensor).samples, Path(args.report) / sensor,
                                     source=f'{Path(args.bag).name}, {SENSOR_NAMES[sensor]}', gravity=args.gravity,
                                     sensor=sensor, unit=UNITS[run.input_kind, sensor])
                pages[sensor] = (files, result)
            index = write_sensor_index(pages, args.report, source=Path(args.bag).name)
            print(f'wrote {index} (accelerometer and gyroscope, '
                  f'{sum(len(files.figures) for files, _ in pages.values())} figures)')
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
                          'cross_axis, warmup, temperature_shape, or module:Class (see docs/effects.md)')
    fit.add_argument('--gyro-effects', metavar='NAME[,NAME...]',
                     help='effects to fit on the gyroscope (driver bags), the same names as --effects')
    fit.add_argument('--settle-time', type=float, default=0.0, metavar='SECONDS',
                     help='leave out samples this long after each reference change (turntable settling)')
    _add_static_options(fit)
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
    val.add_argument('--latitude', type=float, metavar='DEG',
                     help="driver bags without a rate reference: the Earth rate's vertical component at this "
                          'latitude is the true rate (default: zero)')
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
    diag.add_argument('--gravity', type=float, default=STANDARD_GRAVITY,
                      help='local gravity for the |g| figure and a static reference, m/s^2')
    diag.add_argument('--latitude', type=float, metavar='DEG',
                      help="driver bags without a rate reference: add the Earth rate's vertical component")
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
