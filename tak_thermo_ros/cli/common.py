"""What ``tak_calib``'s commands share: the bag's topics, the lines they print, the units they print in.

Each command lives in a module of its own (:mod:`tak_thermo_ros.cli.fit`, ...); what two or
more of them need is here, and their shared options are in :mod:`tak_thermo_ros.cli.options`.
"""

from __future__ import annotations

import argparse
import json
import math
import re
from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.records.record import REFERENCE_LIMIT, TEMPERATURE_RANGE, AlignedSamples
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import TakError
from tak_thermo_ros.streaming import SENSOR_NAMES  # noqa: F401  (re-exported: each command prints it)
from tak_thermo_ros.units import READABLE, readable

UNITS = {(InputKind.COUNTS, 'accel'): 'counts', (InputKind.IMU, 'accel'): 'm/s^2', (InputKind.IMU, 'gyro'): 'rad/s',
         (InputKind.IMU, 'mag'): 'T'}
"""The unit of a sensor's residuals and offsets, by input kind."""

DEG = 180.0 / math.pi
"""Degrees per radian."""


def topics(args: argparse.Namespace):
    """The bag's topics from the command's topic options (:func:`~tak_thermo_ros.cli.options.add_topic_options`)."""
    from tak_thermo_ros.formats.bag import Topics
    defaults = Topics()
    return Topics(counts=args.counts_topic, temp_code=args.temp_topic or defaults.temp_code,
                  reference=args.reference_topic, imu=getattr(args, 'imu_topic', None) or defaults.imu,
                  raw_imu=args.raw_imu_topic, temperature=args.temp_topic or defaults.temperature,
                  reference_rate=args.reference_rate_topic,
                  compensated_imu=getattr(args, 'imu_topic', None) or defaults.compensated_imu,
                  mag=getattr(args, 'mag_topic', defaults.mag),
                  reference_field=getattr(args, 'reference_field_topic', defaults.reference_field),
                  compensated_mag=getattr(args, 'mag_output_topic', None) or defaults.compensated_mag,
                  instance=getattr(args, 'instance', defaults.instance))


def stream_options(args: argparse.Namespace):
    """The streamed passes' options: the topics and whether to draw a progress bar."""
    from tak_thermo_ros.streaming import StreamOptions
    return StreamOptions(topics=topics(args), progress=not args.no_progress)


def describe_dropped(dropped: dict[str, int]) -> str:
    """``3 time backwards, 1 non finite``: the samples left out, by reason."""
    return ', '.join(f'{count} {reason.replace("_", " ")}' for reason, count in sorted(dropped.items()))


@dataclass(frozen=True)
class IgnoredCounts:
    """Temperature and reference messages ignored (not held), by reason, as :class:`AlignedSamples` counts them."""

    ignored_temp_codes: dict[str, int]
    ignored_references: dict[str, int]


def print_ignored(samples: AlignedSamples | IgnoredCounts, args: argparse.Namespace,
                  input_kind: InputKind = InputKind.COUNTS, sensor: str = 'accel') -> None:
    """One line per reason a temperature or reference message was ignored (not held), if any was."""
    names = topics(args)
    low, high = TEMPERATURE_RANGE[input_kind.value]
    if input_kind is InputKind.COUNTS:
        temperature = ('temperature codes', names.temp_code, f'implausible (|code| >= {high:g})')
    else:
        temperature = ('temperatures', names.temperature, f'implausible (outside {low:g}..{high:g} C)')
    reference_topic = names.reference_rate if sensor == 'gyro' else names.reference
    for what, ignored, topic, words in (
            (temperature[0], samples.ignored_temp_codes, temperature[1], {'implausible': temperature[2]}),
            ('reference messages', samples.ignored_references, reference_topic,
             {'implausible': f'implausible (a component >= {REFERENCE_LIMIT:g})'})):
        for reason, count in sorted(ignored.items()):
            print(f'ignored {count} {words.get(reason, "non-finite")} {what} on {topic} (the last good one held)')


def require_finite(values, what: str) -> None:
    """Refuse to print or write a non-finite number with exit 0."""
    bad = int(np.count_nonzero(~np.isfinite(np.asarray(values, dtype=float))))
    if bad:
        msg = f'{what}: {bad} values are not finite (NaN or infinite); nothing written'
        raise TakError(msg)


def json_text(document: object, path: str) -> str:
    """A JSON document's text; a non-finite number is refused (JSON has none)."""
    try:
        return json.dumps(document, indent=2, allow_nan=False) + '\n'
    except ValueError:
        msg = f'{path}: the figures hold a non-finite number (NaN or infinite); not written'
        raise TakError(msg) from None


def effect_list(text: str | None) -> list[str]:
    """``--effects a,b`` as a list of specs."""
    return [spec.strip() for spec in (text or '').split(',') if spec.strip()]


def check_kind(args: argparse.Namespace, unit: UnitCalibration, kind: InputKind) -> None:
    """Refuse a calibration for one input kind given with a bag of the other."""
    if kind is not unit.input_kind:
        msg = (f'{args.params} is a calibration for {unit.input_kind.value} input, {args.bag} holds '
               f'{"channel codes" if kind is InputKind.COUNTS else "a driver Imu"}')
        raise TakError(msg)


def given_noise_models(args: argparse.Namespace, unit: UnitCalibration, kind: InputKind,
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
        found = noise_models(unit=unit, options=stream_options(args), noise_file=getattr(args, 'noise', None),
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


def amount(value: float, unit: str) -> str:
    """A residual or offset: counts to three decimals; SI to four digits beside the reader's unit (mg, deg/h, uT)."""
    if unit == 'counts':
        return f'{value:.3f} counts'
    if unit == 'T':
        return readable(value, unit, 4)
    if unit in READABLE:
        return f'{value:.4g} {unit} ({readable(value, unit)})'
    return f'{value:.4g} {unit}'


def in_si(value: float, unit: str) -> str:
    """A counts residual in mm/s^2 beside it (nothing for a driver's SI units)."""
    return f' ({value * 1000.0:.3f} mm/s^2)' if unit == 'counts' else ''


def effect_unit(unit: str, sensor_unit: str) -> str:
    """An effect parameter's unit for the sensor's input: the library states it for codes.

    With a driver's input, counts are the sensor's unit (m/s^2 or rad/s), its input is in the
    same unit, and the temperature code is the temperature in degrees C.
    """
    if sensor_unit == 'counts':
        return unit
    unit = re.sub(r'\bm/s\^2\b', '@', unit)
    unit = re.sub(r'\bcodes?\b', 'C', unit)
    return unit.replace('counts', sensor_unit).replace('@', sensor_unit)


def print_effects(calibration, result, unit_name: str) -> None:
    """One line per fitted effect: its parameters with their standard errors and units."""
    errors = result.parameter_errors
    for effect in calibration.effects:
        shown = ', '.join(f'{p.name} {p.value:.4g}' + (f' +- {errors[effect.name + "." + p.name]:.2g}'
                                                       if effect.name + '.' + p.name in errors else '')
                          + (f' {effect_unit(p.unit, unit_name)}' if p.unit else '') for p in effect.parameters)
        print(f'  effect {effect.name}: {shown}')


def in_driver_words(text: str) -> str:
    """A diagnosis written for the paper's codes, said of a driver's temperature in degrees C."""
    text = re.sub(r'\btemperature codes\b', 'temperatures', text)
    text = re.sub(r'\btemperature code\b', 'temperature', text)
    return re.sub(r'\b(\w+)_codes\b', r'\1_codes (in C here)', text)


NOISE_UNITS = {
    'rad/s': {'rate': ('rad/s', DEG * 3600.0, 'deg/h'), 'density': ('rad/s/sqrt(Hz)', DEG * 60.0, 'deg/sqrt(h)'),
              'walk': ('rad/s^2/sqrt(Hz)', DEG * 3600.0 * 60.0, 'deg/h/sqrt(h)'), 'angle': 'rad', 'ramp': 'rad/s^2'},
    'm/s^2': {'rate': ('m/s^2', 1e3 / STANDARD_GRAVITY, 'mg'),
              'density': ('m/s^2/sqrt(Hz)', 1e6 / STANDARD_GRAVITY, 'ug/sqrt(Hz)'),
              'walk': ('m/s^3/sqrt(Hz)', 1e3 * 60.0 / STANDARD_GRAVITY, 'mg/sqrt(h)'), 'angle': 'm/s', 'ramp': 'm/s^3'},
}
"""Per output unit, the SI unit of each noise quantity, the factor to a data sheet's unit, and that unit."""


def _noise_amount(value: float, kind: str, unit: str) -> str:
    """``'4.831e-05 rad/s (9.96 deg/h)'``: SI and data-sheet units (a counts calibration's output is m/s^2)."""
    units = NOISE_UNITS.get('m/s^2' if unit == 'counts' else unit)
    if units is None:
        return f'{value:.4g} ({unit})'
    si, factor, sheet = units[kind]
    return f'{value:.4g} {si} ({value * factor:.3g} {sheet})'


def noise_axis_lines(sensor: str, model, axis: int, unit: str, fit=None) -> list[str]:
    """One axis of a noise model, one statement per line, in SI and in the units of a data sheet.

    White density, random walk (or the bound the record allows), IEEE 952's bias instability
    ``B`` and the Allan deviation's minimum with its averaging time (the convention of data
    sheets), the terms beyond (quantisation, ramp, the driver's filter, Gauss-Markov
    processes); with ``fit`` (:class:`~tak_thermo_ros.core.noise.fit.NoiseFit`) how the model
    follows the measurement (:func:`noise_fit_lines`).
    """
    units = NOISE_UNITS.get('m/s^2' if unit == 'counts' else unit, {})
    lines = [f'white {_noise_amount(model.white_noise_density[axis], "density", unit)}']
    if unit in ('m/s^2', 'counts'):
        lines[0] += f', {model.white_noise_density[axis] * 60.0:.3g} m/s/sqrt(h)'
    walk, bound = model.random_walk[axis], model.random_walk_bound[axis]
    if walk > 0.0 or bound == 0.0:
        lines.append(f'random walk {_noise_amount(walk, "walk", unit)}')
    else:
        lines.append(f'random walk at most {_noise_amount(bound, "walk", unit)}: none shown')
    lines.append(f'bias instability B {_noise_amount(model.bias_instability[axis], "rate", unit)} (IEEE 952)')
    tau = model.bias_instability_tau[axis]
    if math.isfinite(tau):
        lines.append(f'floor {_noise_amount(model.floor()[axis], "rate", unit)} at {tau:.3g} s '
                     f'(Allan deviation minimum)')
    else:
        lines.append('floor: none within the averaging times (the Allan deviation still falls)')
    extra = []
    if model.quantization[axis] > 0.0:
        extra.append(f'quantization {model.quantization[axis]:.3g} {units.get("angle", "")}'.rstrip())
    if model.rate_ramp[axis] > 0.0:
        extra.append(f'rate ramp {model.rate_ramp[axis]:.3g} {units.get("ramp", "")}'.rstrip())
    if model.filter_share[axis] > 0.0:
        extra.append(f'driver filter {model.filter_time_constant[axis]:.3g} s on '
                     f'{100.0 * model.filter_share[axis]:.0f} % of the white noise')
    if extra:
        lines.append('; '.join(extra))
    for sigma, time in zip(model.gauss_markov, model.gauss_markov_time):
        if sigma[axis] > 0.0:
            lines.append(f'Gauss-Markov {_noise_amount(sigma[axis], "rate", unit)}, correlation time '
                         f'{time[axis]:.3g} s')
    if fit is not None:
        lines += noise_fit_lines(fit, axis, unit)
    return lines


def noise_fit_lines(fit, axis: int, unit: str) -> list[str]:
    """How an axis's model follows its measured Allan deviation: within the band, or where and how not."""
    found = fit.axes[axis]
    lines = []
    worst = f'worst {found.worst_ratio:.3g}x at {found.worst_tau:.3g} s'
    if found.within:
        lines.append(f'fit: within the 95 % band from {fit.band_from:.3g} s (2 samples) on; {worst}')
    else:
        lines.append(f'fit: OUTSIDE the 95 % band of the measurement; {worst} '
                     f'(band {found.band_low:.3g}-{found.band_high:.3g}x)')
        ranked = sorted(found.misfits, key=lambda m: -abs(math.log(m.ratio)))[:3]
        for misfit in sorted(ranked, key=lambda m: m.low):
            span = f'{misfit.low:.3g} s' if misfit.low == misfit.high else f'{misfit.low:.3g}-{misfit.high:.3g} s'
            if misfit.kind == 'bump':
                lines.append(f'a bump at {span} no term follows: the measurement {1.0 / misfit.ratio:.3g}x '
                             f'the model at {misfit.at:.3g} s')
            else:
                lines.append(f'a dip at {span} under every term: the measurement {1.0 / misfit.ratio:.3g}x '
                             f'the model at {misfit.at:.3g} s')
        period = periodic(found)
        if period is not None:
            lines.append(f'a periodic disturbance? period about {period[0]:.3g}-{period[1]:.3g} s, '
                         f'where a sinusoid\'s Allan deviation vanishes')
    step = found.step
    if step is not None:
        lines.append(f'a step at {step.time_s:.4g} s into the record: {step.sigmas:.3g} sigmas, standing out '
                     f'from {step.low:.3g} to {step.high:.3g} s')
        lines.append(f'its size: {step.tau:.3g} s averages before and after differ by '
                     f'{_noise_amount(step.size, "rate", unit)}')
        if fit.model.random_walk[axis] > 0.0:
            lines.append('the random walk fitted may be that step\'s, not the sensor\'s')
    return lines


def periodic(found) -> tuple[float, float] | None:
    """The averaging times that would hold a sinusoid's period, from the misfits; ``None`` without the pattern.

    A sinusoid's Allan deviation peaks at 0.37 times its period and vanishes at the period: the
    largest bump no term follows, then a dip at 1.5 to 7 times its averaging time (the one
    nearest 2.7 times).
    """
    dips = [m for m in found.misfits if m.kind == 'dip']
    for bump in sorted((m for m in found.misfits if m.kind == 'bump'), key=lambda m: abs(math.log(m.ratio)),
                       reverse=True):
        after = [dip for dip in dips if 1.5 * bump.at <= dip.at <= 7.0 * bump.at]
        if after:
            dip = min(after, key=lambda d: abs(math.log(d.at / (2.7 * bump.at))))
            return dip.low, dip.high
    return None


def noise_slope_line(fit) -> str:
    """IEEE 952's slope lines as a cross-check: the fit's white noise and random walk over theirs, per axis.

    A line under the curve bounds its term from above where nothing lowers the curve: 1 where
    the term dominates somewhere, less where it never does; above 1 on the white noise where a
    driver's filter lowers the shortest averaging times (the slope-line reading is then low).
    """
    def ratios(name: str) -> str:
        fitted = getattr(fit.model, name)
        lines = fit.slope_lines.values[name]
        return ' '.join(f'{f / l:.2g}' if l > 0.0 and math.isfinite(l) else '-' for f, l in zip(fitted, lines))
    return (f'fit / IEEE 952 slope line: white {ratios("white_noise_density")}, '
            f'walk {ratios("random_walk")} (x y z)')
