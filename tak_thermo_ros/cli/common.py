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


PLAN_WORDS = {
    'fit': {'table': 'a table run (reference topics): offset and scale against temperature per axis',
            'static': 'a static run (no reference topics, one orientation)\noffsets against temperature, scales held',
            'handheld': 'a hand-held record (no reference topics, {orientations} orientations at rest)\n'
                        'offset, scale and misalignment of both sensors {against}',
            'moving': 'the unit never rests and there is no reference: no accelerometer or gyroscope link'},
    'apply': {plan: 'every message corrected with the calibration'
              for plan in ('table', 'static', 'handheld', 'moving')},
    'validate': {'table': '|g| and the rate against the recorded references',
                 'static': '|g| and the rate at rest (one orientation)',
                 'handheld': "|g| and the rate at the rests, and the turns' closure"},
    'diagnose': {'table': 'the residual against the recorded references',
                 'static': 'the residual at rest (one orientation)',
                 'handheld': "the residual at the rests (gravity along each rest, zero rate), the turns' closure"},
    'noise': {'table': "each sensor's residual against the references (Allan deviation)",
              'static': "each sensor's residual at rest (Allan deviation)",
              'handheld': 'the unit moves (a hand-held record): a noise model needs a static record'},
}
"""What each command does with each kind of record (:class:`~tak_thermo_ros.core.records.survey.Plan`); a newline
starts a second line."""


def duration_text(seconds: float) -> str:
    """A duration in the unit a person reads: s, min or h."""
    if seconds < 120.0:
        return f'{seconds:.3g} s'
    if seconds < 7200.0:
        return f'{seconds / 60.0:.3g} min'
    return f'{seconds / 3600.0:.3g} h'


def survey_lines(survey, command: str) -> list[str]:
    """The first lines of a command: what the record holds, and what the command will therefore do."""
    from tak_thermo_ros.core.fit.handheld import SPAN_PER_ORDER_C
    from tak_thermo_ros.core.records.still import FACE_DEG
    streams = [f'{s.topic} {s.count:,}' + (f' at {s.rate_hz:.3g} Hz' if s.rate_hz else '') for s in survey.streams]
    lines = [f'record: {", ".join(streams[:2])}; {duration_text(survey.duration_s)}']
    if len(streams) > 2:
        lines.append(f'record: also {", ".join(streams[2:])}')
    counts = survey.kind == 'counts'
    if survey.temperature is None:
        lines.append('record: no plausible temperature')
    else:
        low, high = survey.temperature
        unit = '' if counts else ' C'
        lines.append(f'record: temperature{" code" if counts else ""} {low:.4g}..{high:.4g}{unit} '
                     f'(span {high - low:.3g}{unit})')
    still = survey.still
    if len(still):
        seconds = still.interval_s
        lines.append(f'record: at rest {100.0 * still.still_fraction:.0f} % of the time, {len(still)} rests of '
                     f'{seconds.min():.2g} to {seconds.max():.3g} s (median {np.median(seconds):.2g} s)')
        faces = still.faces()
        lines.append(f'record: {still.orientations()} orientations at rest; faces up within {FACE_DEG:g} deg: '
                     f'{" ".join(faces) or "none"} ({len(faces)} of 6)')
    else:
        lines.append(f'record: never at rest for 2 s or more ({100.0 * still.still_fraction:.0f} % of the windows '
                     f'still)')
    if survey.has_reference:
        lines.append(f'record: the reference holds {survey.reference_directions} directions')
    plan = survey.plan.value
    words = PLAN_WORDS.get(command, {}).get(plan)
    if words:
        span = survey.temperature_span
        against = 'against temperature' if span >= SPAN_PER_ORDER_C else 'at one temperature'
        text = words.format(orientations=still.orientations(), against=against)
        lines += [f'{command}: {part}' for part in text.split('\n')]
    return lines


def print_survey(survey, command: str) -> None:
    """Print :func:`survey_lines` (nothing without a survey)."""
    if survey is None:
        return
    for line in survey_lines(survey, command):
        print(line)
