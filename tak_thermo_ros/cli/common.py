"""What ``tak_calib``'s commands share: the bag's topics, the lines they print, the units they print in.

Each command lives in a module of its own (:mod:`tak_thermo_ros.cli.fit`, ...); what two or
more of them need is here, and their shared options are in :mod:`tak_thermo_ros.cli.options`.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import re
import sys
import textwrap
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.records.record import REFERENCE_LIMIT, TEMPERATURE_RANGE, AlignedSamples
from tak_thermo_ros.core.values import SENSOR_NAMES, STANDARD_GRAVITY  # noqa: F401  (re-exported)
from tak_thermo_ros.errors import TakError
from tak_thermo_ros.units import (  # noqa: F401
    DEG, amount, display_unit, in_driver_words, in_si, numbers, reader_unit, significant, with_error)

UNITS = {(InputKind.COUNTS, 'accel'): 'counts', (InputKind.IMU, 'accel'): 'm/s^2', (InputKind.IMU, 'gyro'): 'rad/s',
         (InputKind.IMU, 'mag'): 'T'}
"""The unit of a sensor's residuals and offsets, by input kind."""

SOURCE_WORDS = {'file': 'from a file', 'static_run': 'from a run at constant temperature',
                'residual': 'from a run whose temperature moves', 'fit': "from the fit's own rests"}
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
                  compensated_mag=getattr(args, 'mag_output_topic', None) or defaults.compensated_mag,
                  instance=getattr(args, 'instance', defaults.instance))


def stream_options(args: argparse.Namespace):
    """The streamed passes' options: the topics and whether to draw a progress bar."""
    from tak_thermo_ros.passes.run import StreamOptions
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

    As :func:`~tak_thermo_ros.passes.noise.noise_models` gives them (in SI; in codes for ``kind``
    counts); empty when none is given.
    """
    from tak_thermo_ros.errors import NoiseError
    from tak_thermo_ros.core.noise.residual import in_counts
    from tak_thermo_ros.passes.noise import noise_models
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

    A line before them says what the errors assume (:class:`~tak_thermo_ros.core.fit.uncertainty.ErrorBasis`).

    A parameter in the sensor's unit (an amplitude, a slope per degree) is printed as the sensor
    is: a magnetometer's in uT, with mg or deg/h beside m/s^2 or rad/s.
    """
    errors = result.parameter_errors
    shown_unit, factor = display_unit(unit_name)
    reader = reader_unit(unit_name)
    basis = getattr(result, 'error_basis', None)
    if calibration.effects and errors:
        print(f'  effects, +- {basis.text() if basis is not None else "1 sigma, residual taken as white"}:')
    for effect in calibration.effects:
        held = effect.held_names()
        for p in effect.parameters:
            if p.name in held:
                print(f'  effect {effect.name}: {p.name} held at 0 (fitted on {effect.fitted_axes_text()} only)')
                continue
            unit = effect_unit(p.unit, unit_name) if p.unit else ''
            in_sensor_unit = unit_name != 'counts' and 'counts' in (p.unit or '')
            scale = factor if in_sensor_unit else 1.0
            error = errors.get(f'{effect.name}.{p.name}')
            text = with_error(p.value * scale, error * scale if error is not None else None)
            text += f' {unit}' if unit else ''
            if in_sensor_unit and reader is not None:
                rest = unit[len(shown_unit):] if unit.startswith(shown_unit) else ''
                value = p.value * scale * reader[1]
                shown = (with_error(value, error * scale * reader[1], 3) if error is not None
                         else significant(value, 3))
                text += f' ({shown} {reader[0]}{rest})'
            # A driver's temperature is in degrees C: a parameter the library names in codes is named by it.
            name = p.name.removesuffix('_codes') if unit_name != 'counts' and p.name.endswith('_codes') else p.name
            print(f'  effect {effect.name}: {name} {text}')


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
    instability = model.bias_instability[axis]
    line = fit.slope_lines.values.get('bias_instability') if fit is not None and fit.slope_lines else None
    if instability == 0.0 and line is not None and line[axis] > 0.0:
        # The fit dropped it: the record does not show it beside the white noise and the walk. It is
        # not 0: what the record allows is at most IEEE 952's flat line under the measured curve.
        lines.append(f'bias instability B at most {_noise_amount(line[axis], "rate", unit)}: none shown')
    else:
        lines.append(f'bias instability B {_noise_amount(instability, "rate", unit)} (IEEE 952)')
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


def noise_lines(model, unit: str) -> list[str]:
    """A noise model, one term per line, x y z, in SI and in the units of a data sheet.

    White noise density (deg/sqrt(h); ug/sqrt(Hz)), bias instability (deg/h; mg) and the averaging
    time of its floor, random walk (deg/h/sqrt(h); mg/sqrt(h)); quantisation and ramp when present.
    ``unit``: the sensor's data unit (``rad/s``, ``m/s^2``; ``counts`` for a counts calibration,
    whose corrected output is m/s^2).
    """
    unit = 'm/s^2' if unit == 'counts' else unit
    shown, factor = display_unit(unit)
    units = NOISE_UNITS.get(unit)
    white, bias = np.asarray(model.white_noise_density) * factor, np.asarray(model.bias_instability) * factor
    walk, taus = np.asarray(model.random_walk) * factor, np.asarray(model.bias_instability_tau)

    def beside(values, kind: str) -> str:
        if units is None:
            return ''
        _, to_sheet, sheet = units[kind]
        return f' ({numbers(values * to_sheet, 3)} {sheet})'
    floor = ' '.join(significant(tau, 3) if math.isfinite(tau) else 'inf' for tau in taus)
    if any(model.bias_instability_bound) or any(model.random_walk_bound) or any(model.white_noise_density_error):
        return _noise_lines_with_errors(model, unit, factor, shown, units)
    lines = [f'  white noise density  {numbers(white, 3)} {shown}/sqrt(Hz){beside(white, "density")}',
             f'  bias instability     {numbers(bias, 3)} {shown}{beside(bias, "rate")}',
             f'  its floor at         {floor} s' + (' (inf: still falling at the longest averaging time)'
                                                    if not np.all(np.isfinite(taus)) else ''),
             f'  random walk          {numbers(walk, 3)} {walk_unit(unit)}{beside(walk, "walk")}']
    integrated = units['angle'] if units else f'{shown}*s'
    ramp = units['ramp'] if units else f'{shown}/s'
    for name, term_unit in (('quantization', integrated), ('rate_ramp', ramp)):
        values = np.asarray(getattr(model, name)) * factor
        if np.any(values > 0.0):
            lines.append(f'  {name.replace("_", " "):<20} {numbers(values, 3)} {term_unit}')
    return lines


def _noise_lines_with_errors(model, unit: str, factor: float, shown: str, units) -> list[str]:
    """A model that states its errors and bounds (``source: fit``): each term per axis ``value+-error`` or ``<=bound``.

    The data sheet's units where the sensor has them (deg/h, mg), else the model's.
    """
    def terms(name: str, kind: str, si_unit: str) -> str:
        values, errors = getattr(model, name), getattr(model, f'{name}_error')
        bounds = getattr(model, f'{name}_bound', (0.0, 0.0, 0.0))
        scale, sheet = (units[kind][1], units[kind][2]) if units is not None else (1.0, si_unit)
        scale *= factor
        tokens = []
        for value, error, bound in zip(values, errors, bounds):
            if value == 0.0 and bound > 0.0:
                tokens.append(f'<={significant(bound * scale, 2)}')
            elif error > 0.0:
                tokens.append(f'{significant(value * scale, 2)}+-{significant(error * scale, 2)}')
            else:
                tokens.append(significant(value * scale, 3))
        return f'{" ".join(tokens)} {sheet}'

    lines = [f'  white noise density  {terms("white_noise_density", "density", f"{shown}/sqrt(Hz)")}',
             f'  bias instability     {terms("bias_instability", "rate", shown)}',
             f'  random walk          {terms("random_walk", "walk", walk_unit(unit))}']
    if any(model.bias_instability_bound) or any(model.random_walk_bound):
        lines.append('  (<=: not seen between the rests, at most that: the watch takes the bound)')
    integrated = units['angle'] if units else f'{shown}*s'
    for name, term_unit in (('quantization', integrated), ('filter_time_constant', 's')):
        values = np.asarray(getattr(model, name)) * (factor if name == 'quantization' else 1.0)
        if np.any(values > 0.0):
            lines.append(f'  {name.replace("_", " "):<20} {numbers(values, 3)} {term_unit}')
    return lines


PLAN_WORDS = {
    'fit': {'table': 'a table run (reference topics): offset and scale against temperature per axis',
            'static': 'a static run ({reference}, one orientation)\noffsets against temperature, scales held',
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
    """The first lines of a command: which kind of record, what it holds, and what the command will therefore do."""
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
        rests = (f'{len(still)} rests of {duration_text(seconds.min())} to {duration_text(seconds.max())} '
                 f'(median {duration_text(float(np.median(seconds)))})')
        if len(still) == 1:
            rests = f'1 rest of {duration_text(seconds[0])}'
        lines.append(f'record: at rest {100.0 * still.still_fraction:.0f} % of the time, {rests}')
        faces = still.faces()
        orientations = still.orientations()
        lines.append(f'record: {orientations} orientation{"s" if orientations != 1 else ""} at rest; faces up '
                     f'within {FACE_DEG:g} deg: '
                     f'{" ".join(faces) or "none"} ({len(faces)} of 6)')
    else:
        lines.append(f'record: never at rest for 2 s or more ({100.0 * still.still_fraction:.0f} % of the windows '
                     f'still)')
    if survey.has_reference:
        directions = survey.reference_directions
        lines.append(f'record: the reference holds {directions} direction{"s" if directions != 1 else ""}')
    plan = survey.plan.value
    words = PLAN_WORDS.get(command, {}).get(plan)
    if words:
        span = survey.temperature_span
        against = 'against temperature' if span >= SPAN_PER_ORDER_C else 'at one temperature'
        reference = 'its reference in one direction' if survey.has_reference else 'no reference topics'
        text = words.format(orientations=still.orientations(), against=against, reference=reference)
        # The first line says which kind of record it is; what the record holds follows, then what is done.
        first, *rest = [f'{command}: {part}' for part in text.split('\n')]
        lines = [first, *lines, *rest]
    return lines


def print_survey(survey, command: str) -> None:
    """Print :func:`survey_lines` (nothing without a survey)."""
    if survey is None:
        return
    for line in survey_lines(survey, command):
        print(line)
