"""``tak_calib fit-fleet --everyday DIR`` and ``fit --prior``: a fleet's prior from its units' everyday records.

``DIR`` holds a folder per unit, each with that unit's everyday records (bags, flight logs, mixed:
what ``tak_calib fit FOLDER`` takes as a pool, :mod:`~tak_thermo_ros.passes.pool`). On Dask (the
scheduler ``fit-fleet`` uses, :func:`~tak_thermo_ros.passes.fleet.run_batch`'s):

1. **map**: each unit's folder read once as ``fit`` reads a pool, fitted at the fleet's orders and
   reduced to its statistics (:func:`~tak_thermo_ros.core.fit.prior_fit.unit_statistics`: its
   information on its curve terms, a few hundred numbers whatever the records);
2. **reduce**, on the client: the prior (:func:`~tak_thermo_ros.core.fit.prior_fit.fleet_from_units`),
   written to ``OUT/prior.yaml`` (:mod:`~tak_thermo_ros.formats.prior_file`);
3. **map**: each unit fitted with the prior by the command line itself, ``tak_calib fit FOLDER
   --prior OUT/prior.yaml -o OUT/<unit>.yaml`` (byte for byte what a user's command writes; its output
   in ``OUT/logs/<unit>.txt``). A unit far outside the fleet is fitted from its own records alone.

A worker lost mid-run loses nothing: every task is a function of its unit's folder alone, and the
scheduler runs the task of a lost worker again on another (Dask keeps what each task needs; up to
``distributed.scheduler.allowed-failures`` times); the first map writes nothing.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import socket
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from tak_thermo_ros.core.link.model import AXES
from tak_thermo_ros.core.values import SENSOR_NAMES
from tak_thermo_ros.errors import OutputError, TakError
from tak_thermo_ros.optional import require
from tak_thermo_ros.units import reader_unit, significant

PRIOR_FILE = 'prior.yaml'
LOGS = 'logs'
SENSOR_UNITS = {'accel': 'm/s^2', 'gyro': 'rad/s'}
TABLE_TEMPERATURES = 5
"""The prior's table shows its curves at this many temperatures over the fleet's span."""
POWER_NAMES = ('offset', 'slope', 'curvature', 'cubic', 'T^4', 'T^5', 'T^6', 'T^7', 'T^8')
"""The raw coefficients of an offset curve, by power of ``T - T_ref``."""


# ----- what a person reads -----------------------------------------------------------------------------


def _reader(sensor: str) -> tuple[str, float]:
    return reader_unit(SENSOR_UNITS[sensor])  # type: ignore[return-value]


def source_lines(sensor: str, calibration) -> list[str]:
    """What came from the records and what from the prior: each axis's +- within the records' span, and beyond it.

    Within: the largest +- over the records' temperatures; beyond: at each end of the calibrated range
    the records did not reach (half a degree or more).
    """
    uncertainty = calibration.uncertainty
    if uncertainty is None:
        return []
    small, factor = _reader(sensor)
    low, high = uncertainty.records_min, uncertainty.records_max
    axes = [i for i in range(3) if uncertainty.offset_variance(i, 0.0) > 0.0]

    def sd(index: int, temperatures: np.ndarray) -> float:
        n = np.asarray(temperatures, dtype=float) - calibration.temp_code_ref
        return math.sqrt(max(float(np.max(uncertainty.offset_variance(index, n))), 0.0)) * factor

    name = SENSOR_NAMES[sensor]
    within = ', '.join(f'{AXES[i]} {significant(sd(i, np.linspace(low, high, 9)), 3)}' for i in axes)
    lines = [f'{name}: curve +- ({small}) from the records, within {low:.1f}..{high:.1f} C: {within}']
    for edge in (calibration.temp_code_min, calibration.temp_code_max):
        if low - 0.5 <= edge <= high + 0.5:
            continue
        beyond = ', '.join(f'{AXES[i]} {significant(sd(i, np.array([edge])), 3)}' for i in axes)
        lines.append(f'{name}: curve +- ({small}) from the prior, at {edge:.1f} C: {beyond}')
    return lines


def prior_table(prior) -> list[str]:
    """The prior as a person reads it: per sensor the mean curve +- the units' spread, each term's spread.

    The curve at :data:`TABLE_TEMPERATURES` temperatures over the fleet's span (each group's when
    the units fall in groups); per axis the units' spread of each raw coefficient (offset, per C,
    per C^2, ...): what they disagree on.
    """
    from tak_thermo_ros.core.fit.fleet_prior import offset_band
    lines = []
    for sensor, fleet in prior.sensors.items():
        small, factor = _reader(sensor)
        temperatures = np.linspace(fleet.low, fleet.high, TABLE_TEMPERATURES)
        groups = len(fleet.groups)
        lines.append(f'{SENSOR_NAMES[sensor]} prior, {small}: mean curve +- the units\' spread, '
                     f'{len(fleet.units)} units' + (f', {groups} groups' if groups > 1 else ''))
        lines.append('  ' + ' ' * 9 + ''.join(f'{f"{t:.1f} C":>14}' for t in temperatures))
        for axis in AXES:
            if not any(name.startswith(f'{axis}.offset') for name in fleet.names):
                continue
            for k in range(groups):
                weights = np.eye(groups)[k] if groups > 1 else None
                band = offset_band(fleet, axis, temperatures, weights)
                label = f'{axis}' + (f' group {k + 1}' if groups > 1 else '')
                cells = ''.join(f'{significant(m * factor, 3, sign=True) + "+-" + significant(s * factor, 2):>14}'
                                for m, s in zip(band.mean, band.sd))
                lines.append(f'  {label:<9}{cells}')
        for axis in AXES:
            index = [i for i, name in enumerate(fleet.names) if name.startswith(f'{axis}.offset')]
            if not index:
                continue
            raw = [fleet.spread[i] * factor / fleet.basis.n_scale ** power for power, i in enumerate(index)]
            terms = ', '.join(f'{POWER_NAMES[power]} {significant(value, 2)}' for power, value in enumerate(raw))
            lines.append(f'  {axis} spread ({small}, per C^k): {terms}')
    return lines


def band_lines(check, calibration) -> tuple[list[str], dict[str, Any]]:
    """``validate`` of a pool against a calibration with its uncertainty: are the rests' shapes within its +-?

    Per group of rests (within the records' span, beyond it: where the prior told the curve) the
    gyroscope's bias shape (each record's own offset off), beside what the file's +- and the white noise
    give for it: the curve's error at each rest less its record's mean (``phi_r' C phi_r - 2 phi_r' C
    phi_bar + phi_bar' C phi_bar``) and the white noise of the rest's mean less its record's. A shape well
    beyond it: the +- is too small there (or the unit has changed).

    :returns: the lines, and the same for the JSON document.
    """
    uncertainty = calibration.uncertainty
    if uncertainty is None or not len(check.temperature):
        return [], {}
    small, factor = _reader('gyro')
    low, high = uncertainty.records_min, uncertainty.records_max
    n = check.temperature - calibration.temp_code_ref
    samples = np.maximum(1.0 / np.maximum(check.white[:, 0], 1e-300), 1.0)  # weights: the rests' lengths
    curve = np.zeros((len(n), 3))
    for record in np.unique(check.record):
        rows = np.flatnonzero(check.record == record)
        weights = samples[rows] / samples[rows].sum()
        for axis in range(3):
            # the curve's error at a rest less its record's weighted mean: C_rr - 2 (C w)_r + w' C w
            between = uncertainty.offset_covariance_between(axis, n[rows][:, None], n[rows][None, :])
            carried = between @ weights
            curve[rows, axis] = np.diag(between) - 2.0 * carried + weights @ carried
    beyond = (check.temperature < low - 0.5) | (check.temperature > high + 0.5)
    lines, document = [], {}
    for label, rests in (('within', ~beyond), ('beyond', beyond)):
        if not rests.any():
            continue
        shape = np.sqrt(np.mean(check.shape[rests] ** 2, axis=0))
        expected = np.sqrt(np.mean(curve[rests] + check.white[rests], axis=0))
        lines.append(f'gyroscope: {int(rests.sum())} rests {label} the records\' {low:.1f}..{high:.1f} C: shape RMS '
                     f'{numbers_of(shape * factor)} {small} x y z')
        lines.append(f'gyroscope:   the file\'s +- and the white noise give {numbers_of(expected * factor)} '
                     f'(the +- alone {numbers_of(np.sqrt(np.mean(curve[rests], axis=0)) * factor)})')
        document[label] = {'rests': int(rests.sum()), 'shape_rms': shape.tolist(), 'expected_rms': expected.tolist(),
                           'curve_rms': np.sqrt(np.mean(curve[rests], axis=0)).tolist()}
    return lines, document


def numbers_of(values) -> str:
    """Three significant figures each, space-separated."""
    return ' '.join(significant(float(v), 3) for v in values)


def far_lines(prior) -> list[str]:
    """One statement per unit left out of a sensor's prior."""
    return [f'{far.name}: far outside the fleet ({far.term} {far.sigmas:+.1f} sigmas): not in its '
            f'{SENSOR_NAMES[far.sensor]} prior' for fleet in prior.sensors.values() for far in fleet.left_out]


# ----- fit --prior -------------------------------------------------------------------------------------


def with_source_notes(fitted) -> tuple[Any, tuple[str, ...]]:
    """A :class:`~tak_thermo_ros.core.fit.prior_fit.PriorFit`'s pool with each sensor's source lines in its notes.

    :returns: the pool's fit, and what a person reads: the unit's group, the turn-on taken, each axis's source.
    """
    results = {}
    sources: list[str] = []
    for sensor, result in fitted.pool.fit.results.items():
        calibration = result.calibration
        lines = source_lines(sensor, calibration)
        sources += lines
        results[sensor] = replace(result, calibration=replace(calibration, notes=(*calibration.notes, *lines)))
    return replace(fitted.pool, fit=replace(fitted.pool.fit, results=results)), (*fitted.lines, *sources)


# ----- fit-fleet --everyday ----------------------------------------------------------------------------


@dataclass(frozen=True)
class StatisticsOutcome:
    """What the first map gives back for a unit: its statistics, or the one line why not.

    :param seconds: the task's CPU time; ``peak_bytes``: its worker's peak resident memory so far.
    """

    unit: str
    statistics: Any = None
    error: str = ''
    seconds: float = 0.0
    worker: str = ''
    peak_bytes: int = 0


def _peak_bytes() -> int:
    """This process's peak resident memory (Linux reports KiB)."""
    import resource
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


def unit_statistics_task(unit: str, directory: str, settings, options) -> StatisticsOutcome:
    """In a worker: a unit's folder read as a pool and reduced to its statistics; never raises for a bad unit."""
    from tak_thermo_ros.core.fit.prior_fit import unit_statistics
    from tak_thermo_ros.passes.pool import open_pool
    start = time.process_time()
    worker = f'{socket.gethostname()}:{os.getpid()}'
    try:
        opened = open_pool([directory], options)
        statistics = unit_statistics(unit, opened.record, settings)
    except TakError as error:
        return StatisticsOutcome(unit, error=str(error), seconds=time.process_time() - start, worker=worker,
                                 peak_bytes=_peak_bytes())
    return StatisticsOutcome(unit, statistics, seconds=time.process_time() - start, worker=worker,
                             peak_bytes=_peak_bytes())


def everyday_units(directory: str | os.PathLike[str]) -> tuple[list[tuple[str, Path]], list[str]]:
    """The unit folders in ``directory`` (sorted by name), and one line per entry that is none.

    :raises TakError: no such directory, or no unit folder in it.
    """
    from tak_thermo_ros.passes.pool import is_bag
    root = Path(directory)
    if not root.is_dir():
        msg = f'{root} (--everyday): no such directory (a folder per unit, each with its records)'
        raise TakError(msg)
    units, lines = [], []
    for entry in sorted(root.iterdir()):
        if entry.is_dir() and not is_bag(entry):
            name = re.sub(r'[^A-Za-z0-9._-]+', '_', entry.name).strip('.') or 'unit'
            if name in (Path(PRIOR_FILE).stem, LOGS):
                msg = f'{entry}: a unit may not be named {name!r} (fit-fleet writes {PRIOR_FILE} and {LOGS}/)'
                raise TakError(msg)
            units.append((name, entry))
        else:
            lines.append(f'{entry.name}: not a unit folder (a bag or a file directly in {root}), not read')
    names = [name for name, _ in units]
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        msg = f'{root}: two unit folders make the same name {twice[0]!r}'
        raise TakError(msg)
    if not units:
        msg = f'{root} (--everyday): no unit folder in it (a folder per unit, each with its records)'
        raise TakError(msg)
    return units, lines


def check_everyday_outputs(out_dir: Path, units: Sequence[str], *, force: bool) -> None:
    """The overwrite rule for ``OUT/prior.yaml``, ``OUT/<unit>.yaml`` and ``OUT/logs/<unit>.txt``, before any work."""
    from tak_thermo_ros.formats.files import FILE, check_output
    from tak_thermo_ros.passes.fleet import _own_directory
    _own_directory(out_dir, '-o')
    _own_directory(out_dir / LOGS, '-o')
    for path in (out_dir / PRIOR_FILE, *(out_dir / f'{unit}.yaml' for unit in units),
                 *(out_dir / LOGS / f'{unit}.txt' for unit in units)):
        if os.path.lexists(path):
            check_output(path, FILE, force=force, option='-o')


@dataclass(frozen=True)
class RefitOutcome:
    """What the second map gives back for a unit: its file and log, or the one line why not."""

    unit: str
    params: str = ''
    error: str = ''
    seconds: float = 0.0
    peak_bytes: int = 0


def refit_task(unit: str, argv: list[str], log: str, command) -> RefitOutcome:
    """In a worker: ``tak_calib ARGV`` (the unit's ``fit``), its output into ``log``; never raises for a bad unit."""
    from tak_thermo_ros.formats.files import write_text_atomic
    from tak_thermo_ros.passes.fleet import _error_line, _run_cli
    start = time.process_time()
    status, stdout, stderr = _run_cli(command, argv)
    write_text_atomic(log, f'$ tak_calib {" ".join(argv)}\n{stdout}{stderr}exit status {status}\n')
    seconds = time.process_time() - start
    if status != 0:
        return RefitOutcome(unit, error=f'fit: {_error_line(stderr, status)}', seconds=seconds,
                            peak_bytes=_peak_bytes())
    return RefitOutcome(unit, params=argv[argv.index('-o') + 1], seconds=seconds, peak_bytes=_peak_bytes())


def _gathered(client, futures: dict, stream, what: str) -> dict[str, Any]:
    """Each future's result as it completes (a line per unit on ``stream``); a task that failed: its error."""
    from dask.distributed import as_completed
    out = {}
    for done, future in enumerate(as_completed(futures), start=1):
        unit = futures[future]
        try:
            out[unit] = future.result()
        except Exception as error:  # the task could not run (its workers died too often)
            kind = StatisticsOutcome if what == 'statistics' else RefitOutcome
            out[unit] = kind(unit, error=f'dask: {type(error).__name__}: {error}')
        result = out[unit]
        detail = f': {result.error}' if result.error else ''
        print(f'[{done}/{len(futures)}] {unit} {what} {result.seconds:.1f} s CPU{detail}', file=stream, flush=True)
    return out


def unit_line(unit: str, path: str, records: int | None) -> str:
    """One statement per unit fitted: its records and their span, each sensor's worst +- over the range, its file."""
    from tak_thermo_ros.formats.calibration_file import load_unit
    calibration = load_unit(path)
    parts = []
    for sensor in ('gyro', 'accel'):
        link = calibration.sensor(sensor)
        uncertainty = link.uncertainty
        if uncertainty is None:
            continue
        small, factor = _reader(sensor)
        grid = np.linspace(link.temp_code_min, link.temp_code_max, 9) - link.temp_code_ref
        worst = max(math.sqrt(max(float(np.max(uncertainty.offset_variance(i, grid))), 0.0)) * factor
                    for i in range(3) if uncertainty.offset_variance(i, 0.0) > 0.0)
        parts.append(f'{sensor} {significant(worst, 3)} {small}')
    told = f'{records} records' if records is not None else 'its records'
    shown = Path(path).name  # in OUT_DIR, named once at the end
    if not parts:
        return f'{unit}: {told}, far from the fleet: fitted from its own records alone -> {shown}'
    uncertainty = calibration.accel.uncertainty or calibration.gyro.uncertainty  # type: ignore[union-attr]
    return (f'{unit}: {told} {uncertainty.records_min:.1f}..{uncertainty.records_max:.1f} C, worst +- '
            f'{", ".join(parts)} -> {shown}')


def run_everyday(args: argparse.Namespace, fit_actions: Sequence[argparse.Action], command) -> int:
    """``fit-fleet --everyday DIR -o OUT`` (see the module's description)."""
    from tak_thermo_ros.cli.fit import fit_settings
    from tak_thermo_ros.core.fit.prior_fit import fleet_from_units
    from tak_thermo_ros.formats.prior_file import save_prior
    from tak_thermo_ros.passes.fleet import DEFAULT_WORKERS, _connect, pass_through
    from tak_thermo_ros.passes.handheld import handheld_settings
    from tak_thermo_ros.passes.run import StreamOptions
    from tak_thermo_ros.cli.common import topics
    if args.validate:
        msg = '--validate: not with --everyday (validate a unit with tak_calib validate FOLDER --params OUT/UNIT.yaml)'
        raise TakError(msg)
    if args.bags:
        msg = f'{args.bags[0]}: BAGs and --everyday exclude each other (--everyday DIR holds a folder per unit)'
        raise TakError(msg)
    if getattr(args, 'prior', None):
        msg = '--prior: not with --everyday, which makes the prior (OUT_DIR/prior.yaml) and fits each unit with it'
        raise TakError(msg)
    out_dir = Path(os.path.abspath(args.output))
    units, lines = everyday_units(args.everyday)
    names = [name for name, _ in units]
    check_everyday_outputs(out_dir, names, force=args.force)
    require('distributed', 'fit-fleet')
    settings = handheld_settings(fit_settings(args))
    options = StreamOptions(topics=topics(args), progress=False)
    fit_words = pass_through(fit_actions, args)
    workers = args.workers or DEFAULT_WORKERS
    where = f'scheduler {args.scheduler}' if args.scheduler else f'a local cluster of {workers} workers'
    print(f'fit-fleet --everyday: {len(units)} units on {where}', file=sys.stderr, flush=True)
    for line in lines:
        print(line)
    start = time.perf_counter()
    client, cluster = _connect(args.scheduler, workers)
    try:
        futures = {client.submit(unit_statistics_task, name, str(path), settings, options, pure=False): name
                   for name, path in units}
        found = _gathered(client, futures, sys.stderr, 'statistics')
        statistics = [found[name].statistics for name in names if found[name].statistics is not None]
        failed = {name: found[name].error for name in names if found[name].statistics is None}
        try:
            prior = fleet_from_units(statistics, bias_order=settings.bias_order, scale_order=settings.scale_order,
                                     groups=args.groups)
        except TakError as error:
            detail = '; '.join(f'{name}: {why}' for name, why in list(failed.items())[:2])
            msg = f'no prior: {error}' + (f' ({len(failed)} units failed: {detail})' if failed else '')
            raise TakError(msg) from None
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / LOGS).mkdir(exist_ok=True)
        prior_path = out_dir / PRIOR_FILE
        save_prior(prior_path, prior, header=f'tak_thermo_ros fleet prior from {len(statistics)} units of '
                                             f'{args.everyday} (tak_calib fit-fleet --everyday)\n'
                                             f'use with: tak_calib fit RECORDS --prior {PRIOR_FILE} -o PARAMS.yaml')
        far = {f.name for fleet in prior.sensors.values() for f in fleet.left_out}
        refits = {}
        for name, path in units:
            if name in failed:
                continue
            argv = ['fit', str(path), '-o', str(out_dir / f'{name}.yaml'), *fit_words, '--no-progress', '--force']
            if name not in far:
                argv += ['--prior', str(prior_path)]
            refits[client.submit(refit_task, name, argv, str(out_dir / LOGS / f'{name}.txt'), command,
                                 pure=False)] = name
        done = _gathered(client, refits, sys.stderr, 'fit')
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    for line in prior.lines():
        print(line)
    for line in far_lines(prior):
        print(line)
    records = {unit.name: unit.records for unit in statistics}
    ok = 0
    for name in names:
        if name in failed:
            print(f'{name}: failed: {failed[name]}')
            continue
        outcome = done[name]
        if outcome.error:
            print(f'{name}: failed: {outcome.error}')
            continue
        ok += 1
        print(unit_line(name, outcome.params, records.get(name)))
    for line in prior_table(prior):
        print(line)
    cpu = sum(found[name].seconds for name in names) + sum(outcome.seconds for outcome in done.values())
    peak = max(outcome.peak_bytes for outcome in (*found.values(), *done.values()))
    print(f'{ok} of {len(units)} units fitted with the prior in {time.perf_counter() - start:.1f} s')
    print(f'workers: {cpu / max(len(units), 1):.1f} s CPU per unit, at most {peak / 2 ** 20:.0f} MiB each')
    print(f'wrote {prior_path} and the units\' files beside it')
    if ok == 0:
        msg = f'no unit was fitted (see {out_dir / LOGS})'
        raise OutputError(msg)
    return 0
