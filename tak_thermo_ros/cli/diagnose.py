"""``tak_calib diagnose``: where the model fails against a run, and which effect is missing."""

from __future__ import annotations

import argparse

from dataclasses import dataclass, replace
from pathlib import Path
from tak_thermo_ros.cli import common, options
from tak_thermo_ros.core.effects.aux_signal import signals_with_values
from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.link.model import AXES
from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.core.link.model import UnitCalibration
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.formats.files import FILE
from tak_thermo_ros.formats.files import REPORT
from tak_thermo_ros.formats.files import atomic_directory
from tak_thermo_ros.formats.files import check_output
from tak_thermo_ros.formats.files import write_json
from tak_thermo_ros.core.records.extremes import TemperatureCourse, temperature_course
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.core.records.record import require_signals
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import FitError, TakError
from tak_thermo_ros.passes.diagnose import DIAGNOSE_MAX_SAMPLES
import numpy as np
import sys

NAME = 'diagnose'
OUTPUTS = (('json', FILE, '--json'), ('report', REPORT, '--report'))
"""This command's outputs: ``(argument, kind, option)``, checked before any work is done."""


def add_parser(commands) -> argparse.ArgumentParser:
    """Add the command to ``tak_calib``'s subcommands."""
    parser = commands.add_parser('diagnose', help='compare a calibration with a run and find the missing effect')
    parser.add_argument('bag', metavar='BAG', nargs='+',
                        help='a record; several records, or a directory of them: a pool of everyday records, whole '
                             'records held out (docs/everyday.md)')
    parser.add_argument('--params', required=True, metavar='PARAMS.yaml')
    parser.add_argument('--json', metavar='OUT.json', help='write the verdict, RMS, floor and candidates as JSON')
    parser.add_argument('--report', metavar='DIR', help='write PNG figures and report.html into DIR')
    parser.add_argument('--candidates', type=options.candidates, metavar='NAME[,NAME...]',
                        help='effects to try (default: every library effect the calibration lacks and every '
                             'recorded signal aux:TOPIC in the bag); '
                             "module:Class for a user-defined effect (see docs/effects.md); 'library' "
                             "stands for every library effect, e.g. library,mymodule:MyEffect")
    parser.add_argument('--folds', type=options.folds, default=5,
                        help=f'cross-validation folds, 2..{options.MAX_FOLDS} (default 5)')
    parser.add_argument('--settle-time', type=options.seconds_not_negative, default=0.0, metavar='SECONDS',
                        help='leave out samples this long after each reference change (as for fit)')
    parser.add_argument('--max-samples', type=options.sample_budget, default=DIAGNOSE_MAX_SAMPLES, metavar='N',
                        help=f'diagnose at most about N samples, spread evenly over the run '
                             f'(default {DIAGNOSE_MAX_SAMPLES:,})')
    parser.add_argument('--gravity', type=options.gravity, default=None,
                        help=f'local gravity for the |g| figure and a static reference, m/s^2 '
                             f'({options.GRAVITY_MIN:g}..{options.GRAVITY_MAX:g}; default: from --latitude, '
                             f'else {STANDARD_GRAVITY:g})')
    parser.add_argument('--latitude', type=options.latitude, metavar='DEG',
                        help="driver bags without a rate reference: add the Earth rate's vertical component")
    parser.add_argument('--design-run', metavar='DIR',
                        help='propose the chamber run that tells the two best candidates apart (driver bags: '
                             'one run for both sensors): writes DIR/scenario.yaml (for tak_calib simulate), '
                             'DIR/schedule.csv (time_s, setpoint_C) and DIR/design.json with the simulated separation')
    parser.add_argument('--noise', metavar='IMU.yaml',
                        help="the sensors' noise model, a Kalibr-style imu.yaml (as tak_calib noise writes): the "
                             'verdict is judged against it at every averaging time (docs/discovery.md)')
    parser.add_argument('--noise-run', metavar='BAG',
                        help='a static run at constant temperature: its Allan variance gives the noise model')
    parser.add_argument('--held-out', metavar='BAG2',
                        help='a second record of the same unit: each model of the ladder is fitted on BAG and '
                             'judged on the thermal excursions of BAG2 (instead of BAG\'s own, held out one by one)')
    options.add_topic_options(parser)
    parser.set_defaults(handler=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Compare a calibration with a run: noise floor, residual views, the missing effect, per sensor."""
    from tak_thermo_ros.formats.records import open_record
    from tak_thermo_ros.core.diagnose import diagnose
    from tak_thermo_ros.passes.diagnose import bounded_run
    unit = load_unit(args.params)
    from tak_thermo_ros.passes.pool_records import is_pool
    pool = is_pool(args.bag)
    if not pool:
        from tak_thermo_ros.passes.run import EverydayRecord
        args.bag = args.bag[0]
        record = open_record(args.bag, topics=common.topics(args))
        common.check_kind(args, unit, record.kind)
        try:
            run = bounded_run(record, common.stream_options(args), settle_time_s=args.settle_time,
                              gravity=getattr(args, 'gravity', STANDARD_GRAVITY),
                              latitude=getattr(args, 'latitude', None), max_samples=args.max_samples, unit=unit)
        except EverydayRecord:  # rests in one orientation, motion between: a pool of one
            print(f'{Path(args.bag).name}: {EverydayRecord.WORDS}')
            args.bag, pool = [record], True  # the pool of one takes the record opened
    if pool:
        run = _pool_run(args, unit)
    else:
        from tak_thermo_ros.core.records.provenance import in_sample_lines
        for line in in_sample_lines(run.in_sample, record=Path(args.bag).name, params=Path(args.params).name,
                                    command='diagnose'):
            print(line)
    common.print_survey(run.survey, 'diagnose')
    set_aside: dict[str, tuple[str, ...]] = {}
    if run.handheld is not None:
        from tak_thermo_ros.passes.handheld import at_rest
        rest = at_rest(unit.gyro)
        set_aside['gyro'] = tuple(e.name for e in unit.gyro.effects if e not in rest.effects)
        unit = replace(unit, gyro=rest)
        closure = run.handheld.closure
        if len(closure.angle_rad):
            print(f'turns: closure RMS {np.degrees(closure.rms_rad):.3g} deg over {len(closure.angle_rad)} turns, '
                  f'{closure.rms_rad / max(closure.floor_rad, 1e-300):.2f}x what the noise alone leaves '
                  f'({np.degrees(closure.floor_rad):.3g} deg)')
            if not any(axis.scale_observable for axis in unit.gyro.axes):  # a pool in one orientation
                print('turns: not in the verdict, which judges the rests: no turn was fitted (gyro scales held)')
    if not pool:
        _add_magnetometer(args, unit, run, record)
    progress_shown = not args.no_progress and sys.stderr.isatty()
    verbose = bool(getattr(args, 'verbose', False))
    candidates = expand_candidates(args.candidates) if args.candidates else None
    for line in run.reference_lines:
        print(line)
    noise_models = common.given_noise_models(args, unit, run.input_kind, tuple(run.samples))
    held_out = _held_out_samples(args, unit, run)
    results = {}
    used: dict[str, AlignedSamples] = {}
    if run.stride > 1:
        print(f'diagnosing 1 sample in {run.stride}, spread evenly over the run '
              f'(at most about {args.max_samples:,} samples, --max-samples; {max(run.usable.values()):,} usable in the '
              f'bag)')
    for sensor, samples in run.samples.items():
        tried = (signals_with_values(samples.aux) if candidates is None
                 else [spec for spec in candidates if spec.startswith('aux:')])
        sensor_candidates = candidates
        if run.handheld is not None and sensor == 'gyro' and candidates is None:
            sensor_candidates = [*_rest_candidates(), *tried]
        samples = require_signals(samples, [*Corrector(unit.sensor(sensor)).signals, *tried])
        used[sensor] = samples
        unit_name = common.UNITS[run.input_kind, sensor]
        shown_unit, scale = common.display_unit(unit_name)
        label = '' if run.input_kind is InputKind.COUNTS else f'{common.SENSOR_NAMES[sensor]}: '

        def progress(text: str, label: str = label) -> None:
            if progress_shown:
                print(f'{label}cross-validating {text} ...', file=sys.stderr)

        noise = noise_models.get(sensor)
        if noise is None or noise.source == 'residual':
            # A stored model fitted to the calibration run's residual at every averaging time is
            # no yardstick: diagnose fits its own, at short averaging times only.
            from tak_thermo_ros.core.fit import residual_counts
            from tak_thermo_ros.core.noise.residual import model_from_residual
            noise = model_from_residual(residual_counts(unit.sensor(sensor), samples), samples.stamp_ns)
        groups = run.groups[sensor] if run.groups else None
        second = held_out.get(sensor)
        if second is not None:
            second = require_signals(second, [*Corrector(unit.sensor(sensor)).signals, *tried])
        try:
            result = diagnose(unit.sensor(sensor), samples, candidates=sensor_candidates,
                              folds=args.folds if groups is None else min(args.folds, int(groups.max()) + 1),
                              progress=progress, noise=noise, unit=shown_unit, unit_scale=scale, groups=groups,
                              temperature_unit='' if run.input_kind is InputKind.COUNTS else 'C',
                              start_s=run.first_stamp_ns * 1e-9 if run.first_stamp_ns is not None else None,
                              held_out=second)
        except FitError as err:  # one sensor's shortage (a short magnetometer): said, the others diagnosed
            if sensor == 'accel':
                raise
            print(f'{common.SENSOR_NAMES[sensor]}: not diagnosed: {err}')
            del used[sensor]
            continue
        results[sensor] = result
        aside = set_aside.get(sensor)
        held = (f'; {", ".join(aside)} in the file, not diagnosed: no rate at rest' if aside else '')
        print(f'{label}diagnosed {len(samples)} samples of {args.bag} against {args.params} '
              f'(model: {result.ladder[0].label}{held})')
        if samples.dropped:
            print(f'  left out: {common.describe_dropped(samples.dropped)}')
        common.print_ignored(samples, args, run.input_kind)
        for line in _noise_lines(noise, unit_name, result.averaging_time_s, verbose):
            print(line)
        print(result.summary(unit_name, label=label, verbose=verbose, driver_words=run.input_kind is InputKind.IMU))
        walk = _walk_line(result, sensor, run.input_kind)
        if walk:
            print(walk)
    if not pool:  # a pool's records each have their own clock: a step's moment is said per record
        for line in step_lines(results, used, run.input_kind, run.first_stamp_ns):
            print(line)
    record = _one_way_lines(unit, used) if run.input_kind is InputKind.IMU and not pool else None
    for line in record.lines if record is not None else ():
        print(line)
    if args.json:
        first = 'accel' if 'accel' in results else 'gyro'  # a pool in one orientation: the gyroscope only
        document = {**results[first].as_dict(), 'samples_diagnosed': len(used[first]),
                    'samples_usable': run.usable[first], 'subsample_stride': run.stride,
                    'in_sample': run.in_sample.as_dict() if run.in_sample is not None else None}
        if run.input_kind is InputKind.IMU:
            document['sensors'] = {sensor: {**result.as_dict(), 'unit': common.UNITS[run.input_kind, sensor],
                                            'samples_diagnosed': len(used[sensor]),
                                            'samples_usable': run.usable[sensor]}
                                   for sensor, result in results.items()}
            if record is not None:
                document['record'] = record.as_dict()
        if run.handheld is not None:
            closure = run.handheld.closure
            document['handheld'] = {'turns': len(closure.angle_rad), 'closure_rms_rad': closure.rms_rad,
                                    'closure_floor_rad': closure.floor_rad}
        write_json(args.json, document)
        print(f'wrote {args.json}')
    if getattr(args, 'design_run', None):
        _design_run(args, run, results, used, progress_shown)
    if args.report:
        _write_report(args, run, results, used)
    return 0


def _pool_run(args: argparse.Namespace, unit: UnitCalibration):
    """A pool of everyday records for ``diagnose``: one line per record; the samples with each record's offset off."""
    from tak_thermo_ros.passes.pool_check import bounded_pool, check_driver_unit
    check_driver_unit(unit, args.params)
    if getattr(args, 'design_run', None):
        msg = '--design-run: not with a pool of records (a chamber run is designed from one record)'
        raise TakError(msg)
    if getattr(args, 'held_out', None):
        msg = '--held-out: not with a pool of records (its folds already hold whole records out)'
        raise TakError(msg)
    gravity = getattr(args, 'gravity', STANDARD_GRAVITY)
    run, opened = bounded_pool(args.bag, common.stream_options(args), gravity=gravity,
                               latitude=getattr(args, 'latitude', None), max_samples=args.max_samples, unit=unit,
                               say=print)
    records = len(opened.used)
    if records > 1:
        print(f'pool: {records} records; each record\'s own turn-on offset taken off; the folds hold whole records '
              f'out')
    else:
        print('pool: 1 record; its own turn-on offset taken off; the folds hold time blocks out')
    if not any(axis.scale_observable for axis in unit.accel.axes):
        # one orientation: the refits would fit scales that its rests cannot tell from the offsets
        print('accelerometer: not diagnosed: its scales are held (every rest in one orientation)')
        del run.samples['accel']
    args.bag = f'the pool of {records} records' if records > 1 else opened.entries[opened.used[0]].name
    return run


def _held_out_samples(args: argparse.Namespace, unit: UnitCalibration, run) -> dict[str, AlignedSamples]:
    """``--held-out BAG2``: the second record's samples per sensor (the diagnosed record's kind), said in one line."""
    path = getattr(args, 'held_out', None)
    if path is None:
        return {}
    from tak_thermo_ros.formats.records import open_record
    from tak_thermo_ros.passes.diagnose import bounded_run
    record = open_record(path, topics=common.topics(args))
    kind = record.kind
    if kind is not run.input_kind:
        msg = (f'--held-out: {path} holds {kind.value} data, {args.bag} {run.input_kind.value}: '
               f'not the same kind of record')
        raise TakError(msg)
    second = bounded_run(record, common.stream_options(args), settle_time_s=args.settle_time,
                         gravity=getattr(args, 'gravity', STANDARD_GRAVITY), latitude=getattr(args, 'latitude', None),
                         max_samples=args.max_samples, unit=unit)
    if second.handheld is not None or run.handheld is not None:
        which = path if second.handheld is not None else args.bag
        msg = f'--held-out: {which} is a hand-held record (no thermal excursions)'
        raise TakError(msg)
    print(f'held out: {path}, {len(second.samples["accel"]):,} samples: each model is fitted on {args.bag} '
          f'and judged on its excursions')
    return dict(second.samples)


def _design_run(args: argparse.Namespace, run, results: dict, used: dict[str, AlignedSamples],
                progress_shown: bool) -> None:
    """``--design-run``: the chamber run that tells the two best candidates apart, written to its directory."""
    if run.handheld is not None:
        print(f'--design-run: a hand-held record: no chamber run to propose; nothing written to {args.design_run}')
        return
    from tak_thermo_ros.formats.files import write_texts
    from tak_thermo_ros.core.diagnose import (
        design_driver_run,
        design_run,
        recorded_signal_note,
        design_files,
        driver_design_files,
    )
    note = recorded_signal_note(results['accel']) if run.input_kind is InputKind.COUNTS else None
    if note is not None:
        print(note)
    elif run.input_kind is InputKind.COUNTS:
        design = design_run(results['accel'], run.samples['accel'])
        paths = write_texts(args.design_run, design_files(design))
        print(design.message())
        print('wrote ' + ', '.join(str(path) for path in paths))
    else:
        def design_progress(text: str) -> None:
            if progress_shown:
                print(f'design: {text} ...', file=sys.stderr)

        imu_results = {sensor: result for sensor, result in results.items() if sensor != 'mag'}
        driver_design = design_driver_run(imu_results, used, progress=design_progress)
        for line in driver_design.lines():
            print(line)
        if driver_design.designed:
            paths = write_texts(args.design_run, driver_design_files(driver_design))
            print('wrote ' + ', '.join(str(path) for path in paths))
        else:
            print(f'--design-run: no chamber run to propose; nothing written to {args.design_run}')


def _write_report(args: argparse.Namespace, run, results: dict, used: dict[str, AlignedSamples]) -> None:
    """``--report``: the figures and report.html (one page per sensor of a driver record) into its directory."""
    from tak_thermo_ros.reports.diagnose import write_report, write_sensor_index
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
                                     source=f'{Path(args.bag).name}, {common.SENSOR_NAMES[sensor]}',
                                     gravity=args.gravity, sensor=sensor, unit=common.UNITS[run.input_kind, sensor])
                pages[sensor] = (files, result)
            index = write_sensor_index(pages, staging, source=Path(args.bag).name)
            written = (f'{Path(args.report) / index.name} ({" and ".join(common.SENSOR_NAMES[s] for s in pages)}, '
                       f'{sum(len(files.figures) for files, _ in pages.values())} figures)')
    print(f'wrote {written}')


def step_lines(results: dict, used: dict[str, AlignedSamples], kind: InputKind,
               first_stamp_ns: int | None = None) -> list[str]:
    """One line per step of the record, every sensor's channels that change at its moment, in each one's units.

    A step one sensor's scan found is looked for in the other sensors at the nearest sample (a test
    at one moment: :data:`~tak_thermo_ros.core.records.steps.NAME_SIGMAS`). Moments in minutes
    from the record's first stamp ``first_stamp_ns`` (default: the first sample diagnosed).
    """
    from tak_thermo_ros.core.records.steps import change_at, step_scales
    sensors = [sensor for sensor in results if sensor != 'mag' and results[sensor].steps]
    if not sensors:
        return []
    start = first_stamp_ns if first_stamp_ns is not None else min(
        int(used[sensor].stamp_ns[0]) for sensor in results if sensor != 'mag')
    events: list[tuple[int, str, object]] = []
    for sensor in sensors:
        stamps = used[sensor].stamp_ns
        for step in results[sensor].steps:
            events.append(((int(stamps[step.index - 1]) + int(stamps[step.index])) // 2, sensor, step))
    events.sort(key=lambda event: (-float(np.abs(event[2].z).max())))
    period = max(float(np.median(np.diff(used[s].stamp_ns))) for s in results if s != 'mag')
    lines, said = [], []
    scales: dict[str, list] = {}  # per sensor its residual's level changes, scanned once
    for moment, sensor, step in events:
        if any(abs(moment - other) <= 2.0 * period for other in said):
            continue
        said.append(moment)
        parts = []
        temperature = ''
        for other in (s for s in ('gyro', 'accel') if s in results):
            samples = used[other]
            index = int(np.searchsorted(samples.stamp_ns, moment))
            if other == sensor:
                change = step
            elif 1 <= index < len(samples):
                if other not in scales:
                    scales[other] = step_scales(results[other].residual, breaks=results[other].views.breaks)
                change = change_at(results[other].residual, index, scale=step.scale, scales=scales[other])
            else:
                change = None
            if change is None:
                continue
            if not temperature and 0 < index < len(samples):
                code = float(samples.temp_code[index])
                temperature = f'{code:.1f} C' if kind is InputKind.IMU else f'temperature code {code:.0f}'
            unit = common.UNITS[kind, other]
            reader = common.reader_unit(unit)
            for c in change.named:
                value = float(change.amplitude[c])
                text = f'{common.significant(value, 3, sign=True)} {unit}'
                if reader is not None:
                    text += f' ({common.significant(value * reader[1], 3, sign=True)} {reader[0]})'
                name = f'{other} ' if kind is InputKind.IMU else ''
                parts.append(f'{name}{AXES[c]} {text}')
        lines.append(f'step: at {(moment - start) * 1e-9 / 60.0:.2f} min ({temperature}): {", ".join(parts)}')
    return lines


def _walk_line(result, sensor: str, kind: InputKind) -> str:
    """The rate random walk that would explain an excess over a short-term model, in a gyro's units."""
    from tak_thermo_ros.core.noise.residual import RESIDUAL_LONGEST_TAU_S
    if not result.allan:
        return ''
    # The check the message speaks of: the calibration as given when no effect is named, else the ladder's.
    check = result.allan[0][1] if result.verdict in ('none', 'unexplained') else result.allan[-1][1]
    if check.source != 'residual' or check.consistent or sensor != 'gyro' or kind is not InputKind.IMU:
        return ''
    _, factor, sheet = common.NOISE_UNITS['rad/s']['walk']
    walk = check.walk_to_explain(RESIDUAL_LONGEST_TAU_S) * factor
    return f'  that rate random walk in {sheet}: {" ".join(f"{value:.3g}" for value in walk)} (x y z)'


def _add_magnetometer(args: argparse.Namespace, unit: UnitCalibration, run, record) -> None:
    """``diagnose``'s magnetometer (its thermal link) when the calibration and the bag hold one."""
    from tak_thermo_ros.passes.magnetometer import bounded_mag_run, has_mag, survey_field
    options = common.stream_options(args)
    if run.input_kind is not InputKind.IMU or unit.mag is None:
        return
    if not has_mag(record):
        print(f'magnetometer: {args.bag} holds no messages on {options.topics.mag}; not diagnosed')
        return
    field = None if record.streams.mag_reference else survey_field(record, options)
    if field is not None and field.turned:
        print(f'magnetometer: not diagnosed: {args.bag} is a rotation record (its field turns); the thermal '
              f'diagnosis takes a static run or a reference field')
        return
    samples, usable, line = bounded_mag_run(record, options, max_samples=args.max_samples, survey=field)
    print(line)
    run.samples['mag'] = samples
    run.usable['mag'] = usable


def _noise_lines(noise, unit: str, averaging_s: float, verbose: bool) -> list[str]:
    """Where the noise model comes from, one line; its terms per axis with ``--verbose`` (the JSON holds them)."""
    if noise is None:
        return ['  noise model: none (the run is too short for an Allan fit): judged against the white floor']
    said = {'file': 'from the file given', 'static_run': 'from the static run given',
            'residual': "fitted to this run's own residual up to 30 s (no --noise, no --noise-run)"}
    lines = [f'  noise model {said.get(noise.source, noise.source)}']
    if noise.source == 'residual':
        lines.append('  the verdict uses the white floor, then the Allan deviation beyond 30 s')
    if averaging_s:
        lines.append(f'  judged on held-out {averaging_s:.3g} s means')
    if verbose:
        lines += ['  noise model, per axis x y z:', *(f'  {line}' for line in common.noise_lines(noise, unit))]
    return lines


@dataclass(frozen=True)
class OneWay:
    """A record whose temperature moved one way only, and what a lag it cannot show would do to its curve.

    :param bend_per_minute: per sensor, the largest offset error each minute of lag between the
        sensing element and its thermometer leaves at the record's fastest rate (sensor units).
    """

    course: TemperatureCourse
    bend_per_minute: dict[str, float]
    lines: tuple[str, ...]

    def as_dict(self) -> dict[str, object]:
        """For ``--json``: the course and the bend per minute of lag."""
        return {'one_way': self.course.one_way, 'low_c': self.course.low, 'high_c': self.course.high,
                'rate_max_c_per_s': self.course.rate_max, 'lag_bend_per_minute': self.bend_per_minute}


def _one_way_lines(unit: UnitCalibration, used: dict[str, AlignedSamples]) -> OneWay | None:
    """A warm-up (or cool-down) only: a lag of the elements behind the thermometer hides in its curve; its size."""
    from tak_thermo_ros.core.link.offset_cubic import offset_cubic
    from tak_thermo_ros.formats.firmware import size
    samples = used['accel']
    course = temperature_course(samples.stamp_s, samples.temp_code)
    if not course.one_way or course.high - course.low < 1.0:
        return None
    bend = {}
    for sensor in ('accel', 'gyro'):
        cubic = offset_cubic(unit.sensor(sensor), about=unit.sensor(sensor).temp_code_ref)
        bend[sensor] = float(cubic.steepest.max()) * course.rate_max * 60.0
    verb = 'rose' if course.rise >= course.fall else 'fell'
    lines = (f'record: the temperature only {verb}, {course.low:.1f}..{course.high:.1f} C, at up to '
             f'{course.rate_max * 60.0:.3g} C/min',
             'record: a lag of the sensing elements behind the thermometer cannot be told from the curve here',
             f'record: each minute of such a lag bends the gyroscope\'s curve by up to {size(bend["gyro"], "gyro")}',
             f'record: and the accelerometer\'s by up to {size(bend["accel"], "accel")}',
             f'record: to determine a lag, record the way back too ({"cooled" if verb == "rose" else "warmed"}, '
             f'powered), or go slower')
    return OneWay(course, bend, lines)


def expand_candidates(text: str) -> list[str]:
    """``--candidates`` as a list: comma-separated specs, ``library`` = every library effect."""
    from tak_thermo_ros.core.effects import LIBRARY
    candidates: list[str] = []
    for spec in (part.strip() for part in text.split(',')):
        names = list(LIBRARY) if spec == 'library' else [spec] if spec else []
        candidates += [name for name in names if name not in candidates]
    return candidates


def _rest_candidates() -> list:
    """A gyroscope at rest (a hand-held record): the library's offset effects and the recorded signals.

    Its rate is zero there, so the input effects (a scale nonlinearity, the misalignment) cannot show.
    """
    from tak_thermo_ros.core.effects import INPUT, LIBRARY
    return [name for name, cls in LIBRARY.items() if cls.kind != INPUT]
