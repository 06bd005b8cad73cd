"""``tak_calib``: simulate chamber runs, fit, apply and validate the correction link.

Every deliberate failure prints one line ``tak_calib: error: ...`` and exits with status 2;
no traceback reaches the user (``tak_calib --debug`` shows it). Interrupted by SIGINT or
SIGTERM, it removes what it was writing and exits with 130 or 143. Every output obeys one
overwrite rule (:mod:`tak_thermo_ros.core.records.files`): an existing output is refused unless
``--force``, and only regular files, bags and report directories are ever replaced.
"""

from __future__ import annotations

import os

# Small least-squares problems on a 2-core machine run fastest single-threaded; competing
# OpenBLAS threads made `diagnose` up to 8x slower. Set before numpy loads; a user's value wins.
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import argparse  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
import traceback  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Callable, Sequence  # noqa: E402

from dataclasses import dataclass, replace  # noqa: E402

import numpy as np  # noqa: E402

from tak_thermo_ros import options as bounds  # noqa: E402
from tak_thermo_ros.core.records.calibration_file import load_unit, save_unit  # noqa: E402
from tak_thermo_ros.core.records.files import (  # noqa: E402
    BAG,
    FILE,
    REPORT,
    atomic_directory,
    check_output,
    write_text_atomic,
)
from tak_thermo_ros.core.link.correction import Corrector, OutOfRange  # noqa: E402
from tak_thermo_ros.core.effects.aux_signal import signals_with_values  # noqa: E402
from tak_thermo_ros.core.link.model import AXES, InputKind, UnitCalibration  # noqa: E402
from tak_thermo_ros.core.records.record import REFERENCE_LIMIT, TEMPERATURE_RANGE, AlignedSamples  # noqa: E402
from tak_thermo_ros.core.records.record import require_signals  # noqa: E402
from tak_thermo_ros.core.simulation.imu import STANDARD_GRAVITY, Scenario, load_scenario, simulate  # noqa: E402
from tak_thermo_ros.errors import TakError  # noqa: E402
from tak_thermo_ros.streaming import DIAGNOSE_MAX_SAMPLES, EFFECT_FIT_MAX_SAMPLES, SENSOR_NAMES  # noqa: E402

EXIT_ERROR = 2
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143

OUTPUTS: dict[str, tuple[tuple[str, str, str], ...]] = {
    'simulate': (('out_bag', BAG, 'OUT_BAG'),),
    'fit': (('output', FILE, '-o'),),
    'apply': (('output', BAG, '-o'),),
    'validate': (('json', FILE, '--json'),),
    'import-csv': (('output', BAG, '-o'),),
    'diagnose': (('json', FILE, '--json'), ('report', REPORT, '--report')),
    'noise': (('output', FILE, '-o'), ('json', FILE, '--json')),
}
"""Each command's outputs: ``(argument, kind, option)``, checked before any work is done."""


UNITS = {(InputKind.COUNTS, 'accel'): 'counts', (InputKind.IMU, 'accel'): 'm/s^2', (InputKind.IMU, 'gyro'): 'rad/s',
         (InputKind.IMU, 'mag'): 'T'}
"""The unit of a sensor's residuals and offsets, by input kind."""


def _topics(args: argparse.Namespace):
    from tak_thermo_ros.bagio import Topics
    defaults = Topics()
    return Topics(counts=args.counts_topic, temp_code=args.temp_topic or defaults.temp_code,
                  reference=args.reference_topic, imu=getattr(args, 'imu_topic', None) or defaults.imu,
                  raw_imu=args.raw_imu_topic, temperature=args.temp_topic or defaults.temperature,
                  reference_rate=args.reference_rate_topic,
                  compensated_imu=getattr(args, 'imu_topic', None) or defaults.compensated_imu,
                  mag=getattr(args, 'mag_topic', defaults.mag),
                  reference_field=getattr(args, 'reference_field_topic', defaults.reference_field),
                  compensated_mag=getattr(args, 'mag_output_topic', None) or defaults.compensated_mag)


def _add_topic_options(parser: argparse.ArgumentParser, *, imu: bool = False) -> None:
    group = parser.add_argument_group('topics (the input kind is taken from the bag: counts topic or driver Imu)')
    group.add_argument('--counts-topic', default='/tak/counts', help='channel codes (Vector3Stamped)')
    group.add_argument('--raw-imu-topic', default='/imu/data_raw', help="a driver's Imu (default /imu/data_raw)")
    group.add_argument('--temp-topic', help='temperature (Temperature): codes /tak/temp_code with counts, '
                                            'degrees C /imu/temperature with a driver Imu')
    group.add_argument('--reference-topic', default='/tak/reference', help='true specific force (Vector3Stamped)')
    group.add_argument('--mag-topic', default='/imu/mag', help="a driver's magnetometer (MagneticField, tesla)")
    group.add_argument('--reference-field-topic', default='/tak/reference_field',
                       help='true magnetic field along the sensor axes, tesla (Vector3Stamped; a coil)')
    group.add_argument('--reference-rate-topic', default='/tak/reference_rate',
                       help='true angular rate, rad/s (Vector3Stamped; driver bags)')
    if imu:
        group.add_argument('--imu-topic', help='corrected output (Imu): default /tak/imu/data_raw with counts, '
                                               '/imu/data_compensated with a driver Imu')
    parser.add_argument('--no-progress', action='store_true', help='no progress bar even on a terminal')
    parser.add_argument('--force', action='store_true',
                        help='replace an existing output (a regular file, a bag or a report directory; '
                             'nothing else is ever replaced)')
    parser.add_argument('--debug', action='store_true', default=argparse.SUPPRESS,
                        help='show the traceback of an error')


def _add_static_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group('driver bags without reference topics (a static run)')
    group.add_argument('--gravity', type=bounds.gravity, default=STANDARD_GRAVITY,
                       help='local gravity, m/s^2: the magnitude of the estimated specific-force reference')
    group.add_argument('--latitude', type=bounds.latitude, metavar='DEG',
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
    from tak_thermo_ros.bagio import AUX_TYPES
    from tak_thermo_ros.core.simulation.imu import supply_signal_name
    aux_types = ({supply_signal_name(scenario): AUX_TYPES[scenario.record_supply_type]}
                 if scenario.record_supply else None)
    if run.driver is not None:
        driver = run.driver
        write_driver_record(args.out_bag, driver, topics=_topics(args), storage=args.storage, force=args.force,
                            aux_types=aux_types)
        hours = ((driver.stamp_ns[-1] - driver.stamp_ns[0]) * 1e-9 if scenario.rotation
                 else scenario.duration_s()) / 3600.0
        print(f'wrote {args.out_bag}: {len(driver.stamp_ns)} Imu, {len(driver.temp_stamp_ns)} temperature, '
              f'{len(driver.reference_stamp_ns)} reference changes, {hours:.2f} h at '
              f'{scenario.sample_rate_hz:g} Hz ({args.storage}); temperature '
              f'{driver.temperature.min():.2f}..{driver.temperature.max():.2f} C')
        if len(driver.mag_stamp_ns):
            print(f'  magnetometer: {len(driver.mag_stamp_ns)} MagneticField on {_topics(args).mag}'
                  f'{f" ({scenario.rotation} rotation record)" if scenario.rotation else ""}, '
                  f'{len(driver.mag_reference_stamp_ns)} reference field changes')
        return 0
    write_record(args.out_bag, run.record, topics=_topics(args), storage=args.storage, force=args.force,
                 aux_types=aux_types)
    record = run.record
    print(f'wrote {args.out_bag}: {len(record.counts_stamp_ns)} counts, {len(record.temp_stamp_ns)} temperature codes, '
          f'{len(record.reference_stamp_ns)} reference changes, {scenario.duration_s() / 3600.0:.2f} h '
          f'at {scenario.sample_rate_hz:g} Hz ({args.storage}); temperature code '
          f'{record.temp_code.min():.0f}..{record.temp_code.max():.0f}')
    return 0


def _describe_dropped(dropped: dict[str, int]) -> str:
    return ', '.join(f'{count} {reason.replace("_", " ")}' for reason, count in sorted(dropped.items()))


@dataclass(frozen=True)
class _IgnoredCounts:
    """Temperature and reference messages ignored (not held), by reason, as :class:`AlignedSamples` counts them."""

    ignored_temp_codes: dict[str, int]
    ignored_references: dict[str, int]


def _stream_options(args: argparse.Namespace):
    from tak_thermo_ros.streaming import StreamOptions
    return StreamOptions(topics=_topics(args), progress=not args.no_progress)


def _print_ignored(samples: AlignedSamples | _IgnoredCounts, args: argparse.Namespace,
                   input_kind: InputKind = InputKind.COUNTS, sensor: str = 'accel') -> None:
    """One line per reason a temperature or reference message was ignored (not held), if any was."""
    topics = _topics(args)
    low, high = TEMPERATURE_RANGE[input_kind.value]
    if input_kind is InputKind.COUNTS:
        temperature = ('temperature codes', topics.temp_code, f'implausible (|code| >= {high:g})')
    else:
        temperature = ('temperatures', topics.temperature, f'implausible (outside {low:g}..{high:g} C)')
    reference_topic = topics.reference_rate if sensor == 'gyro' else topics.reference
    for what, ignored, topic, words in (
            (temperature[0], samples.ignored_temp_codes, temperature[1], {'implausible': temperature[2]}),
            ('reference messages', samples.ignored_references, reference_topic,
             {'implausible': f'implausible (a component >= {REFERENCE_LIMIT:g})'})):
        for reason, count in sorted(ignored.items()):
            print(f'ignored {count} {words.get(reason, "non-finite")} {what} on {topic} (the last good one held)')


def _require_finite(values, what: str) -> None:
    """Refuse to print or write a non-finite number with exit 0."""
    bad = int(np.count_nonzero(~np.isfinite(np.asarray(values, dtype=float))))
    if bad:
        msg = f'{what}: {bad} values are not finite (NaN or infinite); nothing written'
        raise TakError(msg)


def _json_text(document: object, path: str) -> str:
    try:
        return json.dumps(document, indent=2, allow_nan=False) + '\n'
    except ValueError:
        msg = f'{path}: the figures hold a non-finite number (NaN or infinite); not written'
        raise TakError(msg) from None


def _nominal(args: argparse.Namespace, nominal: tuple[float, float, float] | None
             ) -> tuple[float, float, float] | None:
    """A counts bag's nominal scale: ``--nominal-scale`` (one value or x y z), else the bag's metadata."""
    if args.nominal_scale is not None:
        nominal = tuple(args.nominal_scale * 3 if len(args.nominal_scale) == 1 else args.nominal_scale)
        if len(nominal) != 3:
            msg = f'--nominal-scale takes one value or three (x y z), got {len(args.nominal_scale)}'
            raise TakError(msg)
    return nominal


def _effect_list(text: str | None) -> list[str]:
    return [spec.strip() for spec in (text or '').split(',') if spec.strip()]


def cmd_fit(args: argparse.Namespace) -> int:
    """Fit the correction link to a calibration bag (counts, or a driver's Imu: both sensors), block by block."""
    from tak_thermo_ros.streaming import FitSettings, fit_bag
    effects = {'accel': _effect_list(args.effects), 'gyro': _effect_list(args.gyro_effects)}
    settings = FitSettings(effects=effects, bias_order=args.bias_order, scale_order=args.scale_order,
                           temp_code_ref=args.temp_code_ref, settle_time_s=args.settle_time,
                           gravity=getattr(args, 'gravity', STANDARD_GRAVITY), latitude=getattr(args, 'latitude', None),
                           max_effect_samples=args.effect_samples)
    fitted = fit_bag(args.bag, settings, _stream_options(args),
                     nominal_for=lambda kind, bag_nominal: _nominal(args, bag_nominal))
    results = fitted.results
    magnetometer = _fit_magnetometer(args, fitted.input_kind)
    unit = UnitCalibration(fitted.input_kind, results['accel'].calibration,
                           results['gyro'].calibration if 'gyro' in results else None,
                           magnetometer.calibration if magnetometer is not None else None)
    noise_line = ''
    if args.noise or args.noise_run or args.noise_from_residual:
        unit, noise_line = _with_noise(args, unit)
    applied = ', '.join(f'{sensor} {", ".join(e.name for e in calibration.effects)}'
                        for sensor, calibration in unit.sensors if calibration.effects)
    header = (f'tak_thermo_ros calibration fitted from {args.bag}\n'
              f'{results["accel"].samples} samples, bias order {args.bias_order}, scale order {args.scale_order}'
              f'{", effects " + applied if applied else ""}\n'
              f'load with: ros2 run tak_thermo_ros compensator --ros-args --params-file {Path(args.output).name}')
    save_unit(args.output, unit, header=header)
    kind = fitted.input_kind
    print(f'fitted {results["accel"].samples} samples from {args.bag}'
          f'{" (driver Imu: accelerometer and gyroscope)" if kind is InputKind.IMU else ""}')
    for line in fitted.reference_lines:
        print(line)
    for sensor in fitted.sensors:
        result = results[sensor]
        calibration = result.calibration
        unit_name = UNITS[kind, sensor]
        prefix = '' if kind is InputKind.COUNTS else f'{SENSOR_NAMES[sensor]}: '
        if result.dropped:
            print(f'{prefix}left out: {_describe_dropped(result.dropped)}')
        _print_ignored(_IgnoredCounts(fitted.ignored_temp_codes[sensor], fitted.ignored_references[sensor]),
                       args, kind, sensor)
        stride = fitted.effect_stride.get(sensor, 1)
        if stride > 1:
            print(f'{prefix}effect shapes searched on 1 sample in {stride} '
                  f'(about {fitted.usable[sensor] // stride} of {fitted.usable[sensor]}); '
                  f'amplitudes and the paper\'s link fitted on all of them')
        if kind is InputKind.COUNTS:
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
        _print_effects(calibration, result, unit_name)
        for note in calibration.notes:
            print(f'note: {prefix}{note}')
        noise = unit.sensor(sensor).noise
        if noise is not None:
            print(f'  noise ({noise.source}):')
            for i, name in enumerate(AXES):
                print(f'  {name}: {noise_axis_line(sensor, noise, i, unit_name)}')
    if noise_line:
        print(f'{noise_line} (written with the calibration: the node\'s Imu covariances come from it)')
    if magnetometer is not None:
        _print_magnetometer(magnetometer, args)
    print(f'wrote {args.output}')
    return 0


def _with_noise(args: argparse.Namespace, unit: UnitCalibration) -> tuple[UnitCalibration, str]:
    """The fitted unit with each sensor's noise model (``fit --noise / --noise-run / --noise-from-residual``)."""
    from tak_thermo_ros.noise_run import noise_models
    found = noise_models(unit=unit, options=_stream_options(args), noise_file=args.noise, noise_run=args.noise_run,
                         calibration_run=args.bag if args.noise_from_residual else None, use_stored=False,
                         gravity=getattr(args, 'gravity', STANDARD_GRAVITY), latitude=getattr(args, 'latitude', None))
    accel = replace(unit.accel, noise=found.models['accel'])
    gyro = replace(unit.gyro, noise=found.models['gyro']) if unit.gyro is not None else None
    return UnitCalibration(unit.input_kind, accel, gyro, unit.mag), found.line


DEG = 180.0 / 3.141592653589793


def noise_axis_line(sensor: str, model, axis: int, unit: str) -> str:
    """One axis of a noise model in SI and in the units of a data sheet.

    White density, bias instability at its floor time, random walk (deg/sqrt(h), deg/h; ug/sqrt(Hz), mg).
    """
    white, bias = model.white_noise_density[axis], model.bias_instability[axis]
    tau, walk = model.bias_instability_tau[axis], model.random_walk[axis]
    at = f'{tau:.3g} s' if tau < float('inf') else 'no floor within the averaging times'
    if unit == 'rad/s':
        text = (f'white {white:.3e} rad/s/sqrt(Hz) ({white * DEG * 60.0:.3g} deg/sqrt(h)); '
                f'bias instability {bias:.3e} rad/s ({bias * DEG * 3600.0:.3g} deg/h) at {at}; '
                f'random walk {walk:.3e} rad/s^2/sqrt(Hz) ({walk * DEG * 3600.0 * 60.0:.3g} deg/h/sqrt(h))')
    elif unit in ('m/s^2', 'counts'):  # a counts calibration's corrected output is m/s^2
        g = STANDARD_GRAVITY
        text = (f'white {white:.3e} m/s^2/sqrt(Hz) ({white / g * 1e6:.3g} ug/sqrt(Hz), '
                f'{white * 60.0:.3g} m/s/sqrt(h)); '
                f'bias instability {bias:.3e} m/s^2 ({bias / g * 1e3:.3g} mg) at {at}; '
                f'random walk {walk:.3e} m/s^3/sqrt(Hz) ({walk / g * 1e3 * 60.0:.3g} mg/sqrt(h))')
    else:
        text = f'white {white:.3e}; bias instability {bias:.3e} at {at}; random walk {walk:.3e} ({unit})'
    extra_units = {'rad/s': ('rad', 'rad/s^2')}.get(unit, ('m/s', 'm/s^3') if unit in ('m/s^2', 'counts') else ('', ''))
    extra = [f'{name} {getattr(model, name)[axis]:.3e} {extra_unit}'.rstrip()
             for name, extra_unit in zip(('quantization', 'rate_ramp'), extra_units)
             if getattr(model, name)[axis] > 0.0]
    return text + (f'; {", ".join(extra)}' if extra else '')


def cmd_noise(args: argparse.Namespace) -> int:
    """Each sensor's per-axis noise model (Allan deviation, IEEE 952 fit), streamed; a Kalibr-style imu.yaml."""
    from tak_thermo_ros.core.noise.kalibr import write_kalibr
    from tak_thermo_ros.noise_run import noise_bag, noise_document
    unit = load_unit(args.params) if args.params else None
    run = noise_bag(args.bag, _stream_options(args), unit=unit, gravity=args.gravity,
                    latitude=getattr(args, 'latitude', None), out_of_range=OutOfRange(args.out_of_range),
                    settle_time_s=args.settle_time,
                    expect_kind=(lambda kind: _check_kind(args, unit, kind)) if unit is not None else None)
    for line in run.reference_lines:
        print(line)
    what = ('the thermally compensated output (--params) minus the reference' if run.compensated else
            'the measured output minus the reference, NOT compensated (no --params): thermal drift counts as '
            'bias wander here')
    print(f'noise of {args.bag}: {what}')
    document: dict[str, object] = {'bag': str(args.bag), 'params': args.params, 'compensated': run.compensated,
                                   'sensors': {}}
    for sensor, noise in run.sensors.items():
        allan, model = noise.allan, noise.model
        unit_name = 'm/s^2' if sensor == 'accel' else 'rad/s'
        print(f'{SENSOR_NAMES[sensor]}: {allan.samples} samples at {allan.rate:.6g} Hz, averaging times '
              f'{allan.taus[0]:.3g} to {allan.taus[-1]:.4g} s, source {model.source}')
        if noise.dropped:
            print(f'  left out: {_describe_dropped(noise.dropped)}')
        if noise.gaps:
            print(f'  {noise.gaps} gaps in the stamps (about {noise.missing} samples missing): the samples are '
                  f'taken as evenly spaced')
        if noise.out_of_range:
            print(f'  warning: {noise.out_of_range} samples outside the calibrated temperature range '
                  f'({args.out_of_range})')
        for i, name in enumerate(AXES):
            print(f'  {name}: {noise_axis_line(sensor, model, i, unit_name)}')
        document['sensors'][sensor] = noise_document(noise)  # type: ignore[index]
    if args.output:
        header = (f'noise model of {args.bag} ('
                  f'{"thermally compensated with " + args.params if run.compensated else "not compensated"}), '
                  f'tak_calib noise\nKalibr keys: the largest axis; per axis (x, y, z) under *_xyz')
        write_kalibr(args.output, run.models, rostopic=run.topic, header=header, force=args.force)
        print(f'wrote {args.output}')
    if args.json:
        write_text_atomic(args.json, _json_text(document, args.json))
        print(f'wrote {args.json}')
    return 0


def _print_effects(calibration, result, unit_name: str) -> None:
    """One line per fitted effect: its parameters with their standard errors and units."""
    errors = result.parameter_errors
    for effect in calibration.effects:
        shown = ', '.join(f'{p.name} {p.value:.4g}' + (f' +- {errors[effect.name + "." + p.name]:.2g}'
                                                       if effect.name + '.' + p.name in errors else '')
                          + (f' {_effect_unit(p.unit, unit_name)}' if p.unit else '') for p in effect.parameters)
        print(f'  effect {effect.name}: {shown}')


def _fit_magnetometer(args: argparse.Namespace, kind: InputKind):
    """The magnetometer's fit when the driver bag holds one (``--iron-run``: its rotation record)."""
    from tak_thermo_ros.streaming_mag import fit_mag_bag, has_mag
    iron_run = getattr(args, 'iron_run', None)
    effects = _effect_list(getattr(args, 'mag_effects', None))
    options = _stream_options(args)
    if kind is not InputKind.IMU or not has_mag(args.bag, options.topics):
        for option, given in (('--iron-run', iron_run is not None), ('--mag-effects', bool(effects))):
            if given:
                msg = f'{option}: {args.bag} holds no magnetometer on {options.topics.mag} to calibrate'
                raise TakError(msg)
        return None
    return fit_mag_bag(args.bag, options, bias_order=args.bias_order, scale_order=args.scale_order,
                       temp_code_ref=args.temp_code_ref, iron_run=iron_run, effects=effects,
                       max_effect_samples=args.effect_samples)


def _print_magnetometer(fitted, args: argparse.Namespace) -> None:
    """``fit``'s lines for the magnetometer, in microtesla."""
    thermal, link = fitted.thermal, fitted.calibration.thermal
    for line in fitted.lines:
        print(line)
    if thermal.dropped:
        print(f'magnetometer: left out: {_describe_dropped(thermal.dropped)}')
    print(f'magnetometer ({_topics(args).mag}), {thermal.samples} samples:')
    for name, axis, stats in zip(AXES, link.axes, thermal.axes):
        print(f'  {name}: residual RMS {stats.residual_rms * 1e6:.4g} uT; scale {axis.scale:.6g}'
              f'{"" if axis.scale_observable else " (held)"}, offset {axis.offset * 1e6:.4g} uT, '
              f'offset span {axis.offset_span * 1e6:.4g} uT')
    _print_effects(link, thermal, 'T')
    iron = fitted.iron
    mag = fitted.calibration
    if iron is not None:
        rows = '; '.join(' '.join(f'{v:.4f}' for v in mag.soft_iron[3 * i:3 * i + 3]) for i in range(3))
        print(f'  hard iron {" ".join(f"{v * 1e6:+.3f}" for v in mag.hard_iron)} uT; soft iron [{rows}]')
        print(f'  ellipsoid: radius {iron.radius * 1e6:.3f} uT, residual RMS {iron.residual_rms * 1e6:.3f} uT, '
              f'{iron.sections} of 20 sections, spread {iron.spread:.2f}')
    for note in link.notes:
        print(f'note: magnetometer: {note}')


def _effect_unit(unit: str, sensor_unit: str) -> str:
    """An effect parameter's unit for the sensor's input: the library states it for codes.

    With a driver's input, counts are the sensor's unit (m/s^2 or rad/s), its input is in the
    same unit, and the temperature code is the temperature in degrees C.
    """
    if sensor_unit == 'counts':
        return unit
    unit = re.sub(r'\bm/s\^2\b', '@', unit)
    unit = re.sub(r'\bcodes?\b', 'C', unit)
    return unit.replace('counts', sensor_unit).replace('@', sensor_unit)


def _in_driver_words(text: str) -> str:
    """A diagnosis written for the paper's codes, said of a driver's temperature in degrees C."""
    text = re.sub(r'\btemperature codes\b', 'temperatures', text)
    text = re.sub(r'\btemperature code\b', 'temperature', text)
    return re.sub(r'\b(\w+)_codes\b', r'\1_codes (in C here)', text)


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
    """Correct a bag's counts or driver Imu and write Imu messages (block by block, bounded memory)."""
    from tak_thermo_ros.bagio import bag_input_kind
    from tak_thermo_ros.streaming import apply_bag
    unit = load_unit(args.params)
    topics = _topics(args)
    kind = bag_input_kind(args.bag, topics=topics)
    _check_kind(args, unit, kind)
    applied = apply_bag(args.bag, unit, args.output, _stream_options(args), storage=args.storage,
                        out_of_range=OutOfRange(args.out_of_range), force=args.force)
    print(f'wrote {applied.written} Imu messages on {applied.topic} to {args.output}')
    if kind is InputKind.IMU and unit.mag is None:
        from tak_thermo_ros.streaming_mag import has_mag
        if has_mag(args.bag, topics):
            print(f'note: {args.params} holds no magnetometer: {topics.mag} is not corrected (nothing written for it)')
    if applied.mag_written or applied.mag_topic:
        print(f'wrote {applied.mag_written} MagneticField messages on {applied.mag_topic}')
        if applied.mag_dropped:
            print(f'dropped MagneticField messages: {_describe_dropped(applied.mag_dropped)}')
    _print_ignored(applied, args, kind)
    if applied.dropped:
        what = 'counts' if kind is InputKind.COUNTS else 'Imu'
        print(f'dropped {what} messages: {_describe_dropped(applied.dropped)}')
    outside = applied.out_of_range
    if outside:
        low, high = unit.accel.temp_code_min, unit.accel.temp_code_max
        what = 'temperature code' if kind is InputKind.COUNTS else 'temperature'
        print(f'warning: {outside} samples had a {what} outside the calibrated range '
              f'{low:g}..{high:g} ({args.out_of_range})')
    return 0


def cmd_validate(args: argparse.Namespace) -> int:
    """|g| from the three accelerometer channels (and the gyroscope's rate error) before and after correction.

    The bag is read block by block (bounded memory); the errors are accumulated as sums.
    """
    from tak_thermo_ros.streaming import validate_bag
    unit = load_unit(args.params)
    run = validate_bag(args.bag, unit, _stream_options(args), gravity=args.gravity,
                       latitude=getattr(args, 'latitude', None), out_of_range=OutOfRange(args.out_of_range),
                       expect_kind=lambda kind: _check_kind(args, unit, kind))
    result = run.gravity
    if not result.samples:
        left_out = f' (left out: {_describe_dropped(run.accel_dropped)})' if run.accel_dropped else ''
        msg = f'{args.bag}: no usable samples to validate{left_out}'
        raise TakError(msg)
    before, after = result.before.gravity_error(), result.after.gravity_error()
    _require_finite([before.rms, before.max, after.rms, after.max], f'{args.bag}: |g| error')
    _print_ignored(_IgnoredCounts(run.accel_ignored_temp_codes, run.accel_ignored_references), args, run.input_kind)
    if run.accel_dropped:
        print(f'left out: {_describe_dropped(run.accel_dropped)}')
    print(f'|g| error over {result.samples} samples of {args.bag} (gravity {args.gravity:g} m/s^2):')
    print(f'  before (nominal scale and offset): RMS {before.rms:.5f} m/s^2 '
          f'({before.rms / args.gravity * 1e3:.3f} mg), '
          f'max {before.max:.5f} m/s^2')
    print(f'  after  (full correction link):     RMS {after.rms:.5f} m/s^2 ({after.rms / args.gravity * 1e3:.3f} mg), '
          f'max {after.max:.5f} m/s^2')
    if result.out_of_range:
        print(f'warning: {result.out_of_range} samples outside the calibrated temperature range ({args.out_of_range})')
    # The corrected output is in SI units whatever the input kind: a file's model as it stands.
    given = _given_noise_models(args, unit, InputKind.IMU, ('accel',) if unit.gyro is None else ('accel', 'gyro'))
    averaged = {'accel': _averaged_bias(result, given.get('accel'), 'accel', args.gravity)}
    document = {'bag': str(args.bag), 'params': str(args.params), 'gravity': args.gravity,
                'samples': result.samples, 'out_of_range': result.out_of_range,
                'before': before.as_dict(), 'after': after.as_dict()}
    if unit.gyro is not None and run.rate is not None:
        for line in run.reference_lines:
            if line.startswith('rate reference'):
                print(line)
        rate = run.rate
        rate_before, rate_after = rate.before.rate_error(), rate.after.rate_error()
        print(f'gyroscope bias error over {rate.samples} samples (rate minus reference, per axis x y z):')
        for label, stats in (('before (nominal scale and offset):', rate_before),
                             ('after  (full correction link):', rate_after)):
            print(f'  {label:<35}RMS ' + ' '.join(f'{v:.3e}' for v in stats.rms) + ' rad/s; mean '
                  + ' '.join(f'{v:+.3e}' for v in stats.mean) + ' rad/s')
        document['gyro'] = {'samples': rate.samples, 'before': rate_before.as_dict(), 'after': rate_after.as_dict()}
        averaged['gyro'] = _averaged_bias(rate, given.get('gyro'), 'gyro', args.gravity)
    for sensor, found in averaged.items():
        if found is None:
            continue
        for line in found['lines']:
            print(line)
        (document['gyro'] if sensor == 'gyro' else document)['averaged_bias_error'] = found['document']
    if unit.mag is not None and run.input_kind is InputKind.IMU:
        document.update(_validate_magnetometer(args, unit))
    if args.json:
        write_text_atomic(args.json, _json_text(document, args.json))
        print(f'wrote {args.json}')
    return 0


def _validate_magnetometer(args: argparse.Namespace, unit: UnitCalibration) -> dict:
    """``validate``'s field error before and after, in microtesla; the JSON entry ``mag``."""
    from tak_thermo_ros.streaming_mag import has_mag, validate_mag
    options = _stream_options(args)
    if not has_mag(args.bag, options.topics):
        print(f'magnetometer: {args.bag} holds no messages on {options.topics.mag}; not validated')
        return {}
    result = validate_mag(args.bag, unit.mag, options, out_of_range=OutOfRange(args.out_of_range))
    against = ('about the run\'s mean field (static run)' if result.reference == 'static'
               else f'against {result.reference}')
    print(f'magnetometer field error over {result.samples} samples, {against} (per axis x y z, |B|):')
    for label, values in (('before (raw field):', result.before), ('after  (thermal link and iron):', result.after)):
        print(f'  {label:<35}RMS ' + ' '.join(f'{v * 1e6:.3f}' for v in values[:3])
              + f' uT; |B| {values[3] * 1e6:.3f} uT')
    if result.out_of_range:
        print(f'warning: {result.out_of_range} magnetometer samples outside the calibrated temperature range '
              f'({args.out_of_range})')
    return {'mag': {'samples': result.samples, 'reference': result.reference,
                    'before_rms_t': list(result.before[:3]), 'before_magnitude_rms_t': result.before[3],
                    'after_rms_t': list(result.after[:3]), 'after_magnitude_rms_t': result.after[3]}}


def _check_kind(args: argparse.Namespace, unit: UnitCalibration, kind: InputKind) -> None:
    if kind is not unit.input_kind:
        msg = (f'{args.params} is a calibration for {unit.input_kind.value} input, {args.bag} holds '
               f'{"channel codes" if kind is InputKind.COUNTS else "a driver Imu"}')
        raise TakError(msg)


def cmd_import_csv(args: argparse.Namespace) -> int:
    """Convert a delimited log of a static thermal run into a bag (counts, or a driver bag with a gyroscope)."""
    from tak_thermo_ros.bagio import write_driver_record, write_record
    from tak_thermo_ros.core.records.csv_log import CsvImportOptions, delimiter_from_option, read_csv_log
    options = CsvImportOptions(
        acc_columns=tuple(args.acc_columns), temp_column=args.temp_column, time_column=args.time_column,
        time_unit=args.time_unit, acc_unit=args.acc_unit, acc_resolution=args.acc_resolution,
        temp_resolution=args.temp_resolution, gravity=args.gravity,
        reference=tuple(args.reference) if args.reference else None,
        delimiter=delimiter_from_option(args.delimiter) if args.delimiter else None, frame_id=args.frame_id,
        gyro_columns=tuple(args.gyro_columns) if args.gyro_columns else None, gyro_unit=args.gyro_unit)
    log = read_csv_log(args.log, options)
    record = log.record
    topics = _topics(args)
    if log.driver is not None:
        write_driver_record(args.output, log.driver, topics=topics, storage=args.storage, force=args.force)
    else:
        write_record(args.output, record, topics=topics, storage=args.storage, force=args.force)
    print(f'read {args.log}: {log.rows} rows ({log.delimiter_name}-delimited), {log.duration_s:.1f} s '
          f'at {(log.rows - 1) / max(log.duration_s, 1e-9):.3g} Hz')
    if log.driver is not None:
        rate = log.driver.gyro
        print(f'driver bag: acceleration {" ".join(options.acc_columns)} in {options.acc_unit} and angular rate '
              f'{" ".join(options.gyro_columns)} in {options.gyro_unit} written as {topics.raw_imu} (m/s^2, rad/s: '
              f'{rate.min():.4g}..{rate.max():.4g} rad/s), temperature {options.temp_column} as {topics.temperature} '
              f'in degrees C ({log.temperature.min():.2f}..{log.temperature.max():.2f})')
        x, y, z = (float(v) for v in log.reference)
        if log.reference_estimated:
            print(f'no reference topic written: fit takes the run as static (mean direction scaled to gravity, '
                  f'here ({x:.4f}, {y:.4f}, {z:.4f}) m/s^2, largest deviation {log.max_tilt_deg:.2f} deg; rate zero)')
        else:
            print(f'reference (given): ({x:.4f}, {y:.4f}, {z:.4f}) m/s^2 on {topics.reference}, written once')
        print(f'wrote {args.output} ({args.storage})')
        return 0
    print(f'acceleration {" ".join(options.acc_columns)} in {options.acc_unit}: counts = round(a / '
          f'{options.acc_resolution:g} m/s^2), {record.counts.min():.0f}..{record.counts.max():.0f}; '
          f'nominal scale {options.nominal_scale:g} counts/(m/s^2) (bag metadata)')
    print(f'temperature {options.temp_column}: {log.temperature.min():.2f}..{log.temperature.max():.2f} C, '
          f'codes = round(T / {options.temp_resolution:g} C) = '
          f'{record.temp_code.min():.0f}..{record.temp_code.max():.0f}')
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
    from tak_thermo_ros.bagio import bag_input_kind
    from tak_thermo_ros.core.diagnose import diagnose
    from tak_thermo_ros.streaming import bounded_run
    unit = load_unit(args.params)
    _check_kind(args, unit, bag_input_kind(args.bag, topics=_topics(args)))
    run = bounded_run(args.bag, _stream_options(args), settle_time_s=args.settle_time,
                      gravity=getattr(args, 'gravity', STANDARD_GRAVITY), latitude=getattr(args, 'latitude', None),
                      max_samples=args.max_samples)
    _add_magnetometer(args, unit, run)
    verbose = not args.no_progress and sys.stderr.isatty()
    candidates = expand_candidates(args.candidates) if args.candidates else None
    for line in run.reference_lines:
        print(line)
    noise_models = _given_noise_models(args, unit, run.input_kind, tuple(run.samples))
    results = {}
    used: dict[str, AlignedSamples] = {}
    if run.stride > 1:
        print(f'diagnosing 1 sample in {run.stride}, spread evenly over the run '
              f'(at most about {args.max_samples:,} samples, --max-samples; {run.usable["accel"]:,} usable in the bag)')
    for sensor, samples in run.samples.items():
        tried = (signals_with_values(samples.aux) if candidates is None
                 else [spec for spec in candidates if spec.startswith('aux:')])
        samples = require_signals(samples, [*Corrector(unit.sensor(sensor)).signals, *tried])
        used[sensor] = samples
        unit_name = UNITS[run.input_kind, sensor]
        label = '' if run.input_kind is InputKind.COUNTS else f'{SENSOR_NAMES[sensor]}: '

        def progress(text: str, label: str = label) -> None:
            if verbose:
                print(f'{label}cross-validating {text} ...', file=sys.stderr)

        noise = noise_models.get(sensor)
        if noise is None or noise.source == 'residual':
            # A stored model fitted to the calibration run's residual at every averaging time is
            # no yardstick: diagnose fits its own, at short averaging times only.
            from tak_thermo_ros.core.fit import residual_counts
            from tak_thermo_ros.core.noise.residual import model_from_residual
            noise = model_from_residual(residual_counts(unit.sensor(sensor), samples), samples.stamp_ns)
        result = diagnose(unit.sensor(sensor), samples, candidates=candidates, folds=args.folds, progress=progress,
                          noise=noise)
        results[sensor] = result
        print(f'{label}diagnosed {len(samples)} samples of {args.bag} against {args.params} '
              f'(model: {result.ladder[0].label})')
        print(_noise_line(noise, unit_name, result.averaging_time_s))
        if samples.dropped:
            print(f'left out: {_describe_dropped(samples.dropped)}')
        _print_ignored(samples, args, run.input_kind)
        for name, axis in zip(AXES, result.axes):
            if result.averaging_time_s:
                print(f'  {name}: residual RMS {axis.rms:.4g} {unit_name}, white floor {axis.white_floor:.4g}; '
                      f'held-out {result.averaging_time_s:.3g} s means {axis.heldout_rms:.4g} '
                      f'({axis.heldout_rms / axis.noise_floor:.2f}x the noise model\'s {axis.noise_floor:.4g})')
            else:
                print(f'  {name}: residual RMS {axis.rms:.4g} {unit_name}, noise floor {axis.noise_floor:.4g}; '
                      f'held-out {axis.heldout_rms:.4g} ({axis.heldout_rms / axis.noise_floor:.2f}x the floor)')
        if result.allan:
            check = result.allan[-1][1]
            print(f'  against the noise model, {"after the ladder" if len(result.allan) > 1 else "the residual"}: '
                  f'{check.describe()} ({"inside" if check.consistent else "beyond"} '
                  f'the bound {check.worst_bound():.2f}x)'
                  if len(check.taus) else '  Allan deviation: the run is too short to estimate it')
        if result.candidates:
            print(f'candidates, best first (held-out RMS x y z in {unit_name}; '
                  f'share of the excess over the floor removed):')
            for candidate in result.candidates:
                rms = ' '.join(f'{v:8.4g}' for v in candidate.rms_after)
                print(f'  {candidate.effect:<20} {rms}  {round(100.0 * candidate.explained):5d}%')
        for name, reason in result.skipped.items():
            print(f'  {name:<20} not tried: {reason}')
        if len(result.ladder) > 1:
            print('model ladder (held-out RMS x y z): ' + '; '.join(
                f'{step.label}: {" ".join(f"{v:.4g}" for v in step.heldout_rms)}' for step in result.ladder))
        print(f'{label}verdict: {result.verdict}')
        print(_in_driver_words(result.message) if run.input_kind is InputKind.IMU else result.message)
        walk = _walk_line(result, sensor, run.input_kind)
        if walk:
            print(walk)
    if args.json:
        document = {**results['accel'].as_dict(), 'samples_diagnosed': len(used['accel']),
                    'samples_usable': run.usable['accel'], 'subsample_stride': run.stride}
        if run.input_kind is InputKind.IMU:
            document['sensors'] = {sensor: {**result.as_dict(), 'unit': UNITS[run.input_kind, sensor],
                                            'samples_diagnosed': len(used[sensor]),
                                            'samples_usable': run.usable[sensor]}
                                   for sensor, result in results.items()}
        write_text_atomic(args.json, _json_text(document, args.json))
        print(f'wrote {args.json}')
    if getattr(args, 'design_run', None):
        from tak_thermo_ros.core.diagnose import (
            design_driver_run,
            design_run,
            recorded_signal_note,
            write_design,
            write_driver_design,
        )
        note = recorded_signal_note(results['accel']) if run.input_kind is InputKind.COUNTS else None
        if note is not None:
            print(note)
        elif run.input_kind is InputKind.COUNTS:
            design = design_run(results['accel'], run.samples['accel'])
            paths = write_design(design, args.design_run)
            print(design.message())
            print('wrote ' + ', '.join(str(path) for path in paths))
        else:
            def design_progress(text: str) -> None:
                if verbose:
                    print(f'design: {text} ...', file=sys.stderr)

            imu_results = {sensor: result for sensor, result in results.items() if sensor != 'mag'}
            driver_design = design_driver_run(imu_results, used, progress=design_progress)
            for line in driver_design.lines():
                print(line)
            if driver_design.designed:
                print('wrote ' + ', '.join(str(path) for path in write_driver_design(driver_design, args.design_run)))
            else:
                print(f'--design-run: no chamber run to propose; nothing written to {args.design_run}')
    if args.report:
        from tak_thermo_ros.report import write_report, write_sensor_index
        check_output(args.report, REPORT, force=args.force, option='--report')
        with atomic_directory(args.report) as staging:
            if run.input_kind is InputKind.COUNTS:
                files = write_report(results['accel'], used['accel'], staging,
                                     source=Path(args.bag).name, gravity=args.gravity)
                written = f'{Path(args.report) / files.html.name} ({len(files.figures)} figures)'
            else:
                pages = {}
                for sensor, result in results.items():
                    files = write_report(result, used[sensor], Path(staging) / sensor,
                                         source=f'{Path(args.bag).name}, {SENSOR_NAMES[sensor]}',
                                         gravity=args.gravity, sensor=sensor, unit=UNITS[run.input_kind, sensor])
                    pages[sensor] = (files, result)
                index = write_sensor_index(pages, staging, source=Path(args.bag).name)
                written = (f'{Path(args.report) / index.name} ({" and ".join(SENSOR_NAMES[s] for s in pages)}, '
                           f'{sum(len(files.figures) for files, _ in pages.values())} figures)')
        print(f'wrote {written}')
    return 0


def _walk_line(result, sensor: str, kind: InputKind) -> str:
    """The rate random walk that would explain an excess over a short-term model, in a gyro's units."""
    from tak_thermo_ros.core.noise.residual import RESIDUAL_LONGEST_TAU_S
    check = result.allan[0][1] if result.allan else None
    if (result.verdict != 'unexplained' or check is None or check.source != 'residual' or check.consistent
            or sensor != 'gyro' or kind is not InputKind.IMU):
        return ''
    walk = check.walk_to_explain(RESIDUAL_LONGEST_TAU_S) * np.degrees(1.0) * 3600.0 * 60.0
    return f'  that rate random walk in deg/h/sqrt(h): {" ".join(f"{value:.3g}" for value in walk)} (x y z)'


def _add_magnetometer(args: argparse.Namespace, unit: UnitCalibration, run) -> None:
    """``diagnose``'s magnetometer (its thermal link) when the calibration and the bag hold one."""
    from tak_thermo_ros.streaming_mag import bounded_mag_run, has_mag
    options = _stream_options(args)
    if run.input_kind is not InputKind.IMU or unit.mag is None:
        return
    if not has_mag(args.bag, options.topics):
        print(f'magnetometer: {args.bag} holds no messages on {options.topics.mag}; not diagnosed')
        return
    samples, usable, line = bounded_mag_run(args.bag, options, max_samples=args.max_samples)
    print(line)
    run.samples['mag'] = samples
    run.usable['mag'] = usable


def _given_noise_models(args: argparse.Namespace, unit: UnitCalibration, kind: InputKind,
                        sensors: tuple[str, ...]) -> dict:
    """The sensors' noise models from ``--noise FILE``, ``--noise-run BAG`` or the calibration file's noise section.

    As :func:`~tak_thermo_ros.noise_run.noise_models` gives them (in SI; in codes for ``kind``
    counts); empty when none is given.
    """
    from tak_thermo_ros.errors import NoiseError
    from tak_thermo_ros.core.noise.residual import in_counts
    from tak_thermo_ros.noise_run import noise_models
    if getattr(args, 'noise', None) and getattr(args, 'noise_run', None):
        msg = '--noise and --noise-run: give one noise model source, not both'
        raise TakError(msg)
    try:
        found = noise_models(unit=unit, options=_stream_options(args), noise_file=getattr(args, 'noise', None),
                             noise_run=getattr(args, 'noise_run', None), gravity=args.gravity,
                             latitude=getattr(args, 'latitude', None))
    except NoiseError:
        if getattr(args, 'noise', None) or getattr(args, 'noise_run', None):
            raise
        return {}
    print(found.line)
    models = {sensor: model for sensor, model in found.models.items() if sensor in sensors}
    if kind is InputKind.COUNTS:
        models = {sensor: in_counts(model, [axis.scale for axis in unit.sensor(sensor).axes])
                  for sensor, model in models.items()}
    return models


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


def _noise_line(noise, unit: str, averaging_s: float) -> str:
    """One line: the noise model per axis and where it comes from."""
    if noise is None:
        return '  noise model: none (the run is too short for an Allan fit): judged against the white floor'

    def triple(values) -> str:
        return ' '.join(f'{float(v):.3g}' for v in values)
    said = {'file': 'from the file', 'static_run': 'from the static run',
            'residual': "fitted to this run's own residual up to 30 s (no --noise or --noise-run: "
                        "the verdict uses the white floor, then the Allan deviation beyond 30 s)"}
    text = (f'  noise model {said[noise.source]}: white {triple(noise.white_noise_density)} {unit}/sqrt(Hz), '
            f'bias instability {triple(noise.bias_instability)} {unit}, random walk {triple(noise.random_walk)} '
            f'{unit}*sqrt(Hz) (x y z)')
    if averaging_s:
        text += f'; judged on held-out {averaging_s:.3g} s means'
    return text


def expand_candidates(text: str) -> list[str]:
    """``--candidates`` as a list: comma-separated specs, ``library`` = every library effect."""
    from tak_thermo_ros.core.effects import LIBRARY
    candidates: list[str] = []
    for spec in (part.strip() for part in text.split(',')):
        names = list(LIBRARY) if spec == 'library' else [spec] if spec else []
        candidates += [name for name in names if name not in candidates]
    return candidates


class _Parser(argparse.ArgumentParser):
    """argparse with the tool's one-line error: ``tak_calib: error: ...``, exit status 2."""

    def error(self, message: str):  # type: ignore[override]
        command = self.prog.removeprefix('tak_calib').strip()
        where = f'{command}: ' if command else ''
        self.exit(EXIT_ERROR, f'tak_calib: error: {where}{message} (see {self.prog} --help)\n')


def build_parser() -> argparse.ArgumentParser:
    """The ``tak_calib`` argument parser."""
    parser = _Parser(prog='tak_calib', description=__doc__.splitlines()[0])
    parser.add_argument('--debug', action='store_true', help='show the traceback of an error')
    commands = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')

    sim = commands.add_parser('simulate', help='simulate a thermal-chamber run into a bag')
    sim.add_argument('out_bag', metavar='OUT_BAG')
    sim.add_argument('--scenario', metavar='FILE.yaml',
                     help='scenario overrides, every key optional (README: The simulator)')
    sim.add_argument('--seed', type=bounds.seed, help='random seed, 0 .. 2**63-1 (overrides the scenario)')
    sim.add_argument('--storage', choices=['mcap', 'sqlite3'], default='mcap')
    _add_topic_options(sim)
    sim.set_defaults(handler=cmd_simulate)

    fit = commands.add_parser('fit', help='fit the correction link to a calibration bag')
    fit.add_argument('bag', metavar='BAG')
    fit.add_argument('-o', '--output', required=True, metavar='PARAMS.yaml')
    fit.add_argument('--bias-order', type=bounds.polynomial_order, default=3, help='order q of F_s (default 3)')
    fit.add_argument('--scale-order', type=bounds.polynomial_order, default=2,
                     help='order p of F_c (default 2; 0 = no scale drift)')
    fit.add_argument('--temp-code-ref', type=bounds.temp_code, help='N_t,ref (default: middle of the calibrated range)')
    fit.add_argument('--nominal-scale', type=bounds.nominal_scale, nargs='+', metavar='K0',
                     help='nominal counts per m/s^2 (one value or x y z), held for an axis that sees one '
                          'input only; default: the bag metadata written by simulate / import-csv')
    fit.add_argument('--effects', metavar='NAME[,NAME...]',
                     help='effects to fit beyond the paper\'s model: thermal_lag, hysteresis, scale_nonlinearity, '
                          'cross_axis, warmup, temperature_shape, the per-axis forms thermal_lag_per_axis, '
                          'hysteresis_per_axis, warmup_per_axis, a recorded signal aux:TOPIC[:FIELD] '
                          '(e.g. aux:/power/battery_state), or module:Class (see docs/effects.md)')
    fit.add_argument('--gyro-effects', metavar='NAME[,NAME...]',
                     help='effects to fit on the gyroscope (driver bags), the same names as --effects')
    fit.add_argument('--effect-samples', type=bounds.sample_budget, default=EFFECT_FIT_MAX_SAMPLES, metavar='N',
                     help=f'search the effects\' shapes on at most about N samples spread evenly over the run '
                          f'(default {EFFECT_FIT_MAX_SAMPLES:,}; the amplitudes use every sample)')
    fit.add_argument('--mag-effects', metavar='NAME[,NAME...]',
                     help="effects on the magnetometer's thermal link, as --effects (what diagnose names)")
    fit.add_argument('--iron-run', metavar='BAG',
                     help="the magnetometer's rotation record (installed, turned through every orientation): "
                          'hard and soft iron by an ellipsoid fit, after the thermal link (default: not fitted)')
    fit.add_argument('--settle-time', type=bounds.seconds_not_negative, default=0.0, metavar='SECONDS',
                     help='leave out samples this long after each reference change (turntable settling)')
    noise_group = fit.add_argument_group('noise model written with the calibration (the node\'s Imu covariances)')
    noise_group.add_argument('--noise', metavar='IMU.yaml',
                             help='a Kalibr-style imu.yaml (noise densities, random walks)')
    noise_group.add_argument('--noise-run', metavar='BAG', help='a static, constant-temperature run: its noise model '
                                                                '(compensated with the fitted calibration)')
    noise_group.add_argument('--noise-from-residual', action='store_true',
                             help='the noise model of this run\'s residual after the fit (one more pass over the bag)')
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
    val.add_argument('--gravity', type=bounds.gravity, default=STANDARD_GRAVITY,
                     help=f'local gravity, m/s^2 ({bounds.GRAVITY_MIN:g}..{bounds.GRAVITY_MAX:g})')
    val.add_argument('--json', metavar='OUT.json', help='also write the figures as JSON')
    val.add_argument('--latitude', type=bounds.latitude, metavar='DEG',
                     help="driver bags without a rate reference: the Earth rate's vertical component at this "
                          'latitude is the true rate (default: zero)')
    _out_of_range(val)
    _add_topic_options(val)
    val.add_argument('--noise', metavar='IMU.yaml',
                     help="the sensors' noise model (Kalibr-style imu.yaml): "
                          "the averaged bias error is shown next to it")
    val.add_argument('--noise-run', metavar='BAG', help='a static run at constant temperature for the noise model')
    val.set_defaults(handler=cmd_validate)
    imp = commands.add_parser('import-csv', help='convert a delimited log of a static thermal run into a bag')
    imp.add_argument('log', metavar='LOG.csv')
    imp.add_argument('-o', '--output', required=True, metavar='OUT_BAG')
    imp.add_argument('--acc-columns', nargs=3, required=True, metavar=('X', 'Y', 'Z'),
                     help='the acceleration columns along the sensor axes x, y, z')
    imp.add_argument('--temp-column', required=True, help='the temperature column (degrees Celsius)')
    imp.add_argument('--time-column', default='timestamp', help='the time column (default: timestamp)')
    imp.add_argument('--time-unit', choices=['s', 'ms', 'us', 'ns'], default='s',
                     help='unit of the time column (default s)')
    imp.add_argument('--acc-unit', choices=['m/s^2', 'g'], default='m/s^2',
                     help='unit of the acceleration columns (1 g = 9.80665 m/s^2; default m/s^2)')
    imp.add_argument('--acc-resolution', type=bounds.positive, default=1e-3, metavar='M/S^2',
                     help='m/s^2 per channel count: counts = round(a / resolution) (default 0.001); '
                          'the nominal scale 1/resolution goes into the bag metadata')
    imp.add_argument('--temp-resolution', type=bounds.positive, default=0.01, metavar='CELSIUS',
                     help='degrees per temperature code: N_t = round(T / resolution) (default 0.01)')
    imp.add_argument('--gravity', type=bounds.gravity, default=STANDARD_GRAVITY,
                     help=f'local gravity, m/s^2 ({bounds.GRAVITY_MIN:g}..{bounds.GRAVITY_MAX:g}): magnitude of the '
                          'estimated reference (default 9.80665)')
    imp.add_argument('--reference', type=bounds.specific_force, nargs=3, metavar=('X', 'Y', 'Z'),
                     help='the specific force in the sensor frame, m/s^2, if known (default: the mean '
                          'measured direction scaled to --gravity)')
    imp.add_argument('--delimiter', help='field delimiter: tab, comma, semicolon or one character '
                                         '(default: sniffed from the header line)')
    imp.add_argument('--frame-id', default='imu', help='frame_id of the counts messages (default imu)')
    imp.add_argument('--gyro-columns', nargs=3, metavar=('X', 'Y', 'Z'),
                     help='angular-rate columns along the sensor axes: the log becomes a driver bag '
                          '(Imu in m/s^2 and rad/s, temperature in C) instead of counts')
    imp.add_argument('--gyro-unit', choices=['rad/s', 'deg/s'], default='rad/s',
                     help='unit of the angular-rate columns (default rad/s)')
    imp.add_argument('--storage', choices=['mcap', 'sqlite3'], default='mcap')
    _add_topic_options(imp)
    imp.set_defaults(handler=cmd_import_csv)
    diag = commands.add_parser('diagnose', help='compare a calibration with a run and find the missing effect')
    diag.add_argument('bag', metavar='BAG')
    diag.add_argument('--params', required=True, metavar='PARAMS.yaml')
    diag.add_argument('--json', metavar='OUT.json', help='write the verdict, RMS, floor and candidates as JSON')
    diag.add_argument('--report', metavar='DIR', help='write PNG figures and report.html into DIR')
    diag.add_argument('--candidates', metavar='NAME[,NAME...]',
                      help='effects to try (default: every library effect the calibration lacks and every '
                           'recorded signal aux:TOPIC in the bag); '
                           "module:Class for a user-defined effect (see docs/effects.md); 'library' "
                           "stands for every library effect, e.g. library,mymodule:MyEffect")
    diag.add_argument('--folds', type=bounds.folds, default=5,
                      help=f'cross-validation folds, 2..{bounds.MAX_FOLDS} (default 5)')
    diag.add_argument('--settle-time', type=bounds.seconds_not_negative, default=0.0, metavar='SECONDS',
                      help='leave out samples this long after each reference change (as for fit)')
    diag.add_argument('--max-samples', type=bounds.sample_budget, default=DIAGNOSE_MAX_SAMPLES, metavar='N',
                      help=f'diagnose at most about N samples, spread evenly over the run '
                           f'(default {DIAGNOSE_MAX_SAMPLES:,})')
    diag.add_argument('--gravity', type=bounds.gravity, default=STANDARD_GRAVITY,
                      help=f'local gravity for the |g| figure and a static reference, m/s^2 '
                           f'({bounds.GRAVITY_MIN:g}..{bounds.GRAVITY_MAX:g})')
    diag.add_argument('--latitude', type=bounds.latitude, metavar='DEG',
                      help="driver bags without a rate reference: add the Earth rate's vertical component")
    diag.add_argument('--design-run', metavar='DIR',
                      help='propose the chamber run that tells the two best candidates apart (driver bags: '
                           'one run for both sensors): writes DIR/scenario.yaml (for tak_calib simulate), '
                           'DIR/schedule.csv (time_s, setpoint_C) and DIR/design.json with the simulated separation')
    diag.add_argument('--noise', metavar='IMU.yaml',
                      help="the sensors' noise model, a Kalibr-style imu.yaml (as tak_calib noise writes): the "
                           'verdict is judged against it at every averaging time (docs/discovery.md)')
    diag.add_argument('--noise-run', metavar='BAG',
                      help='a static run at constant temperature: its Allan variance gives the noise model')
    _add_topic_options(diag)
    diag.set_defaults(handler=cmd_diagnose)
    noise = commands.add_parser('noise', help='per-axis noise model (Allan deviation) of each sensor; Kalibr imu.yaml')
    noise.add_argument('bag', metavar='BAG')
    noise.add_argument('--params', metavar='PARAMS.yaml',
                       help='a calibration: the noise of the thermally compensated output (default: the raw output)')
    noise.add_argument('-o', '--output', metavar='IMU.yaml', help='write the models as a Kalibr-style imu.yaml')
    noise.add_argument('--json', metavar='OUT.json', help='write the models and the Allan deviations as JSON')
    noise.add_argument('--settle-time', type=bounds.seconds_not_negative, default=0.0, metavar='SECONDS',
                       help='leave out samples this long after each reference change (a table settling; '
                            'the gaps are counted, the samples taken as evenly spaced)')
    _add_static_options(noise)
    _out_of_range(noise)
    _add_topic_options(noise)
    noise.set_defaults(handler=cmd_noise)
    from tak_thermo_ros.fleet import add_fleet_parser
    add_fleet_parser(commands, fit, main)
    from tak_thermo_ros.magnetometer_cli import add_carrier_parsers  # the carrier method (docs/magnetometer.md)
    add_carrier_parsers(commands, OUTPUTS)
    return parser


class _Terminated(KeyboardInterrupt):
    """SIGTERM, handled like SIGINT (the partial output is removed), exit status 143."""


def _raise_terminated(signum: int, frame: object) -> None:
    raise _Terminated


def _check_outputs(args: argparse.Namespace) -> None:
    """Apply the overwrite rule to every output of the command before any work is done."""
    for name, kind, option in OUTPUTS.get(args.command, ()):
        path = getattr(args, name, None)
        if path is not None:
            check_output(path, kind, force=args.force, option=option)


def _report(message: str, err: BaseException, debug: bool) -> None:
    if debug:
        traceback.print_exception(err)
    print(f'tak_calib: error: {message}', file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``tak_calib``."""
    parser = build_parser()
    args = parser.parse_args(argv)
    handler: Callable[[argparse.Namespace], int] = args.handler
    debug = bool(getattr(args, 'debug', False))
    previous = None
    try:
        previous = signal.signal(signal.SIGTERM, _raise_terminated)
    except ValueError:  # not the main thread: SIGTERM keeps its meaning
        previous = None
    try:
        _check_outputs(args)
        return handler(args)
    except TakError as err:
        _report(str(err), err, debug)
        return EXIT_ERROR
    except OSError as err:
        where = f'{err.filename}: ' if err.filename else ''
        _report(f'{where}{err.strerror or err}', err, debug)
        return EXIT_ERROR
    except MemoryError as err:
        _report('out of memory', err, debug)
        return EXIT_ERROR
    except _Terminated:
        print('tak_calib: terminated', file=sys.stderr)
        return EXIT_TERMINATED
    except KeyboardInterrupt:
        print('tak_calib: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as err:  # a bug: still one line for the user, the traceback with --debug
        detail = str(err).splitlines()[0] if str(err) else ''
        _report(f'internal error, please report it: {type(err).__name__}: {detail} '
                f'(tak_calib --debug shows the traceback)', err, debug)
        return EXIT_ERROR
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == '__main__':
    sys.exit(main())
