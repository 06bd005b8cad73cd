"""What ``tak_calib``'s commands share: the bag's topics, the lines they print, the units they print in.

Each command lives in a module of its own (:mod:`tak_thermo_ros.cli.fit`, ...); what two or
more of them need is here, and their shared options are in :mod:`tak_thermo_ros.cli.options`.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import re
import sys
import textwrap
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.records.record import REFERENCE_LIMIT, TEMPERATURE_RANGE, AlignedSamples
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import TakError
from tak_thermo_ros.streaming import SENSOR_NAMES  # noqa: F401  (re-exported: each command prints it)

UNITS = {(InputKind.COUNTS, 'accel'): 'counts', (InputKind.IMU, 'accel'): 'm/s^2', (InputKind.IMU, 'gyro'): 'rad/s',
         (InputKind.IMU, 'mag'): 'T'}
"""The unit of a sensor's residuals and offsets, by input kind."""

DEG = 180.0 / math.pi
"""Degrees per radian."""
SOURCE_WORDS = {'file': 'from a file', 'static_run': 'from a run at constant temperature',
                'residual': 'from a run whose temperature moves'}
"""What each ``source`` of a noise model says (:data:`~tak_thermo_ros.core.noise.model.SOURCES`)."""
WIDTH = 100
"""The longest line ``tak_calib`` prints (an error, one line by rule, excepted)."""
HANG = '    '
"""The indent of a wrapped statement's further lines, beyond its own."""


def wrap(line: str, width: int = WIDTH) -> list[str]:
    """One printed statement as lines of at most ``width`` characters, its further lines indented.

    The statement's own indent is kept; its further lines get :data:`HANG` more. A word longer
    than the line (a path) stays whole.
    """
    if len(line) <= width:
        return [line]
    indent = line[:len(line) - len(line.lstrip())]
    return textwrap.wrap(line.strip(), width=width, initial_indent=indent, subsequent_indent=indent + HANG,
                         break_long_words=False, break_on_hyphens=False) or [line]


def unwrap(text: str) -> list[str]:
    """The statements of wrapped output, one per line: the inverse of :func:`wrap`, for a script that reads it.

    A line indented by exactly :data:`HANG` more than the statement it follows goes on that statement.
    """
    statements: list[str] = []
    indent = -1
    for line in text.splitlines():
        own = len(line) - len(line.lstrip())
        if statements and line.strip() and own == indent + len(HANG):
            statements[-1] += ' ' + line.strip()
        else:
            statements.append(line)
            indent = own
    return statements


class _Wrapping(io.TextIOBase):
    """A text stream that wraps every line longer than :data:`WIDTH` before it passes it on."""

    def __init__(self, target) -> None:
        super().__init__()
        self.target = target
        self.pending = ''

    def write(self, text: str) -> int:
        self.pending += text
        *lines, self.pending = self.pending.split('\n')
        for line in lines:
            self.target.write('\n'.join(wrap(line)) + '\n')
        return len(text)

    def flush(self) -> None:
        if self.pending:
            self.target.write('\n'.join(wrap(self.pending)))
            self.pending = ''
        self.target.flush()

    def isatty(self) -> bool:
        return self.target.isatty()

    def writable(self) -> bool:
        return True


@contextlib.contextmanager
def wrapped_output() -> Iterator[None]:
    """Within: every line printed to stdout wrapped to :data:`WIDTH` columns (a terminal of 80-100)."""
    stream = _Wrapping(sys.stdout)
    with contextlib.redirect_stdout(stream):
        try:
            yield
        finally:
            stream.flush()


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
                  compensated_mag=getattr(args, 'mag_output_topic', None) or defaults.compensated_mag)


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


def reader_unit(unit: str) -> tuple[str, float] | None:
    """The unit a person reads a sensor's small values in, and the factor from the data's unit.

    Accelerometer errors in mg beside m/s^2, gyroscope biases and errors in deg/h beside rad/s;
    ``None`` for the magnetometer (printed in uT, :func:`display_unit`) and for codes.
    """
    return {'m/s^2': ('mg', 1e3 / STANDARD_GRAVITY), 'rad/s': ('deg/h', DEG * 3600.0)}.get(unit)


def display_unit(unit: str) -> tuple[str, float]:
    """The unit a sensor's values are printed in, and the factor from the data's unit (tesla -> uT)."""
    return ('uT', 1e6) if unit == 'T' else (unit, 1.0)


def significant(value: float, digits: int = 4, *, sign: bool = False) -> str:
    """A value to ``digits`` significant figures: ``0.000397``, ``1.64e-05``, ``1003`` (not ``1e+03``)."""
    value = float(value) + 0.0  # no -0
    plus = '+' if sign else ''
    if math.isfinite(value) and 10.0 ** digits <= abs(value) < 1e15:
        return f'{value:{plus}.0f}'
    return f'{value:{plus}.{digits}g}'


def numbers(values, digits: int = 4, *, sign: bool = False) -> str:
    """Values to ``digits`` significant figures (:func:`significant`), space-separated."""
    return ' '.join(significant(v, digits, sign=sign) for v in np.atleast_1d(values))


def amount(value, unit: str, digits: int = 4) -> str:
    """One value or a triple in a sensor's unit, with the unit a person reads beside it.

    ``0.001756 rad/s (362 deg/h)``, ``0.00397 0.00401 0.00495 m/s^2 (0.405 0.409 0.505 mg)``,
    ``0.1954 uT`` (a magnetometer's tesla printed in uT), ``1.521 counts``.
    """
    shown, factor = display_unit(unit)
    values = np.atleast_1d(np.asarray(value, dtype=float)) * factor
    text = f'{numbers(values, digits)} {shown}'
    reader = reader_unit(unit)
    if reader is not None:
        text += f' ({numbers(values * reader[1], 3)} {reader[0]})'
    return text


def in_si(value, unit: str) -> str:
    """A counts residual (already divided by the scale, so in m/s^2) in mg beside it; nothing for SI units."""
    if unit != 'counts':
        return ''
    return f' ({numbers(np.asarray(value, dtype=float) * 1e3 / STANDARD_GRAVITY, 3)} mg)'


def walk_unit(unit: str) -> str:
    """The unit of a random walk (``K``, Allan variance ``K^2 tau / 3``) of a sensor in ``unit``: one spelling each."""
    from tak_thermo_ros.core.values import random_walk_unit
    return random_walk_unit(display_unit(unit)[0])


def effect_unit(unit: str, sensor_unit: str) -> str:
    """An effect parameter's unit for the sensor's input: the library states it for codes.

    With a driver's input, counts are the sensor's unit (m/s^2, rad/s, or uT for a magnetometer's
    tesla), its input is in the same unit, and the temperature code is the temperature in degrees C.
    """
    if sensor_unit == 'counts':
        return unit
    sensor_unit = display_unit(sensor_unit)[0]
    unit = re.sub(r'\bm/s\^2\b', '@', unit)
    unit = re.sub(r'\bcodes?\b', 'C', unit)
    return unit.replace('counts', sensor_unit).replace('@', sensor_unit)


def print_effects(calibration, result, unit_name: str) -> None:
    """One line per fitted effect parameter: its value with its standard error and unit.

    A parameter in the sensor's unit (an amplitude, a slope per degree) is printed as the sensor
    is: a magnetometer's in uT, with mg or deg/h beside m/s^2 or rad/s.
    """
    errors = result.parameter_errors
    shown_unit, factor = display_unit(unit_name)
    reader = reader_unit(unit_name)
    for effect in calibration.effects:
        for p in effect.parameters:
            unit = effect_unit(p.unit, unit_name) if p.unit else ''
            in_sensor_unit = unit_name != 'counts' and 'counts' in (p.unit or '')
            scale = factor if in_sensor_unit else 1.0
            error = errors.get(f'{effect.name}.{p.name}')
            text = f'{p.value * scale:.4g}' + (f' +- {error * scale:.2g}' if error is not None else '')
            text += f' {unit}' if unit else ''
            if in_sensor_unit and reader is not None:
                rest = unit[len(shown_unit):] if unit.startswith(shown_unit) else ''
                spread = f' +- {error * scale * reader[1]:.2g}' if error is not None else ''
                text += f' ({p.value * scale * reader[1]:.3g}{spread} {reader[0]}{rest})'
            print(f'  effect {effect.name}: {p.name} {text}')


def in_driver_words(text: str) -> str:
    """A diagnosis written for the paper's codes, said of a driver's temperature in degrees C."""
    text = re.sub(r'\btemperature codes\b', 'temperatures', text)
    text = re.sub(r'\btemperature code\b', 'temperature', text)
    return re.sub(r'\b(\w+)_codes\b', r'\1_codes (in C here)', text)


def noise_lines(model, unit: str) -> list[str]:
    """A noise model, one term per line, x y z, in SI and in the units of a data sheet.

    White noise density (deg/sqrt(h); ug/sqrt(Hz)), bias instability (deg/h; mg) and the averaging
    time of its floor, random walk (deg/h/sqrt(h); mg/sqrt(h)); quantisation and ramp when present.
    ``unit``: the sensor's data unit (``rad/s``, ``m/s^2``; ``counts`` for a counts calibration,
    whose corrected output is m/s^2).
    """
    unit = 'm/s^2' if unit == 'counts' else unit
    shown, factor = display_unit(unit)
    g = STANDARD_GRAVITY
    white, bias = np.asarray(model.white_noise_density) * factor, np.asarray(model.bias_instability) * factor
    walk, taus = np.asarray(model.random_walk) * factor, np.asarray(model.bias_instability_tau)
    reader = {'rad/s': (('deg/sqrt(h)', DEG * 60.0), ('deg/h', DEG * 3600.0), ('deg/h/sqrt(h)', DEG * 3600.0 * 60.0)),
              'm/s^2': (('ug/sqrt(Hz)', 1e6 / g), ('mg', 1e3 / g), ('mg/sqrt(h)', 1e3 / g * 60.0))}.get(unit)

    def beside(values, which: int) -> str:
        return f' ({numbers(values * reader[which][1], 3)} {reader[which][0]})' if reader else ''
    floor = ' '.join(significant(tau, 3) if math.isfinite(tau) else 'inf' for tau in taus)
    lines = [f'  white noise density  {numbers(white, 3)} {shown}/sqrt(Hz){beside(white, 0)}',
             f'  bias instability     {numbers(bias, 3)} {shown}{beside(bias, 1)}',
             f'  its floor at         {floor} s' + (' (inf: still falling at the longest averaging time)'
                                                    if not np.all(np.isfinite(taus)) else ''),
             f'  random walk          {numbers(walk, 3)} {walk_unit(unit)}{beside(walk, 2)}']
    integrated = {'rad/s': 'rad', 'm/s^2': 'm/s'}.get(unit, f'{shown}*s')
    ramp = {'rad/s': 'rad/s^2', 'm/s^2': 'm/s^3'}.get(unit, f'{shown}/s')
    for name, term_unit in (('quantization', integrated), ('rate_ramp', ramp)):
        values = np.asarray(getattr(model, name)) * factor
        if np.any(values > 0.0):
            lines.append(f'  {name.replace("_", " "):<20} {numbers(values, 3)} {term_unit}')
    return lines
