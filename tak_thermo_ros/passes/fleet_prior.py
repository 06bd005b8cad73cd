"""``tak_calib fit-fleet --everyday DIR``: a fleet's prior from its units' everyday records, then each unit with it.

``DIR`` holds a folder per unit, each with that unit's everyday records (bags, flight logs, mixed:
what ``tak_calib fit FOLDER`` takes as a pool, :mod:`~tak_thermo_ros.passes.pool`). On Dask (the
scheduler ``fit-fleet`` uses, :func:`~tak_thermo_ros.passes.fleet.run_batch`'s):

1. **map**, on the workers: each unit's folder read once as ``fit`` reads a pool and fitted at the
   fleet's orders (the pool fit, its orders not chosen), reduced to its **statistics**
   (:func:`~tak_thermo_ros.core.fit.prior_fit.statistics_of`: its information on its curve terms, a few
   hundred numbers whatever the records) beside its calibration as that fit gives it;
2. **reduce**, on the client: the prior (:func:`~tak_thermo_ros.core.fit.prior_fit.fleet_from_units`),
   written to ``OUT/prior.yaml`` (:mod:`~tak_thermo_ros.formats.prior_file`);
3. **map again**, on the client: each unit's statistics solved with the prior's rows
   (:func:`~tak_thermo_ros.core.fit.prior_fit.unit_with_prior`: the unit's system, as its normal matrix,
   with the prior's precision added; no record is read twice), written to ``OUT/<unit>.yaml``, what the
   first map and this step said in ``OUT/logs/<unit>.txt``. A unit far outside the fleet keeps its fit
   from its own records alone.

A worker lost mid-run loses nothing: every task is a function of its unit's folder alone, and the
scheduler runs the task of a lost worker again on another (Dask keeps what each task needs; up to
``distributed.scheduler.allowed-failures`` times); the first map writes nothing.
"""

from __future__ import annotations

import argparse
import os
import re
import socket
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Sequence

from tak_thermo_ros.errors import OutputError, TakError
from tak_thermo_ros.optional import require
from tak_thermo_ros.passes.prior_lines import far_lines, prior_table, source_lines, unit_line

PRIOR_FILE = 'prior.yaml'
LOGS = 'logs'


# ----- the first map, in the workers -------------------------------------------------------------------


@dataclass(frozen=True)
class StatisticsOutcome:
    """What the first map gives back for a unit: its statistics and calibration, or the one line why not.

    :param unit_calibration: the unit's calibration as its pool fit at the fleet's orders gives it.
    :param lines: what reading and fitting the pool said (the unit's log).
    :param seconds: the task's CPU time; ``peak_bytes``: its worker's peak resident memory so far.
    """

    unit: str
    statistics: Any = None
    unit_calibration: Any = None
    lines: tuple[str, ...] = ()
    error: str = ''
    seconds: float = 0.0
    worker: str = ''
    peak_bytes: int = 0


def _peak_bytes() -> int:
    """This process's peak resident memory (Linux reports KiB)."""
    import resource
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


def unit_statistics_task(unit: str, directory: str, settings, options) -> StatisticsOutcome:
    """In a worker: a unit's folder read as a pool, fitted at the fleet's orders, reduced; never raises for a bad unit.

    :param settings: ``fit``'s :class:`~tak_thermo_ros.passes.run.FitSettings` (their orders are the fleet's).
    """
    from tak_thermo_ros.core.fit.prior import CurvePrior
    from tak_thermo_ros.core.fit.prior_fit import statistics_of
    from tak_thermo_ros.passes.pool_fit import fit_records, pool_unit
    from tak_thermo_ros.passes.pool_lines import coverage_lines
    start = time.process_time()
    worker = f'{socket.gethostname()}:{os.getpid()}'
    read: list[str] = []
    try:
        fitted = fit_records([directory], settings, options,
                             prior=CurvePrior(None, settings.bias_order, settings.scale_order), say=read.append)
        statistics = statistics_of(unit, fitted.fit)
        left_out = [left.name for left in fitted.fit.left_out]
        lines = (*read, *coverage_lines(fitted.opened, left_out=left_out), *fitted.fit.fit.lines)
    except TakError as error:
        return StatisticsOutcome(unit, error=str(error), seconds=time.process_time() - start, worker=worker,
                                 peak_bytes=_peak_bytes())
    # the noise model as plain fit finds it at the pool's rests (--noise gives every unit another, on the client)
    from tak_thermo_ros.passes.rest_noise import rests_noise
    own = pool_unit(fitted)
    found = rests_noise(fitted.fit.record, own, gravity=settings.gravity, latitude=settings.latitude)
    own = replace(own, **{sensor: replace(own.sensor(sensor), noise=noise.model) for sensor, noise in found.items()})
    return StatisticsOutcome(unit, statistics, own, lines, seconds=time.process_time() - start,
                             worker=worker, peak_bytes=_peak_bytes())


# ----- fit-fleet --everyday, on the client ------------------------------------------------------------


def everyday_units(directory: str | os.PathLike[str]) -> tuple[list[tuple[str, Path]], list[str]]:
    """The unit folders in ``directory`` (sorted by name), and one line per entry that is none.

    :raises TakError: no such directory, or no unit folder in it.
    """
    from tak_thermo_ros.passes.pool_records import is_bag
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


def _gathered(futures: dict, stream) -> dict[str, StatisticsOutcome]:
    """Each future's result as it completes (a line per unit on ``stream``); a task that failed: its error."""
    from dask.distributed import as_completed
    out = {}
    for done, future in enumerate(as_completed(futures), start=1):
        unit = futures[future]
        try:
            out[unit] = future.result()
        except Exception as error:  # the task could not run (its workers died too often)
            out[unit] = StatisticsOutcome(unit, error=f'dask: {type(error).__name__}: {error}')
        result = out[unit]
        detail = f': {result.error}' if result.error else ''
        print(f'[{done}/{len(futures)}] {unit} {result.seconds:.1f} s CPU{detail}', file=stream, flush=True)
    return out


@dataclass(frozen=True)
class FleetRun:
    """What ``fit-fleet --everyday`` did: the prior, and per unit its file's path or why it has none."""

    prior: Any
    written: dict[str, str] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)
    records: dict[str, int] = field(default_factory=dict)


def _unit_files(out_dir: Path, found: dict[str, StatisticsOutcome], prior, noise: Any = None) -> dict[str, str]:
    """The second map: each unit with the prior (a far one alone), its file and its log; the files written."""
    from tak_thermo_ros.core.fit.prior_fit import unit_with_prior
    from tak_thermo_ros.formats.calibration_file import save_unit
    from tak_thermo_ros.formats.files import write_text_atomic
    from tak_thermo_ros.passes.pool_lines import pool_header
    far = {f.name for fleet in prior.sensors.values() for f in fleet.left_out}
    written = {}
    for name, outcome in found.items():
        if outcome.statistics is None:
            continue
        unit, lines = outcome.unit_calibration, list(outcome.lines)
        if name in far:
            note = 'far outside its fleet: fitted from its own records alone, at the fleet\'s orders'
            unit = replace(unit, **{s: replace(c, notes=(*c.notes, note)) for s, c in unit.sensors})
            lines.append(note)
        else:
            borrowed = unit_with_prior(unit, outcome.statistics, prior)
            unit = borrowed.unit
            said = [line for sensor, calibration in unit.sensors for line in source_lines(sensor, calibration)]
            unit = replace(unit, **{s: replace(c, notes=(*c.notes, *source_lines(s, c))) for s, c in unit.sensors})
            lines += [*borrowed.lines, *said]
        if noise is not None:  # (noise file, stream options): every unit's noise model from the file
            from tak_thermo_ros.passes.noise import noise_models
            models = noise_models(unit=unit, options=noise[1], noise_file=noise[0]).models
            unit = replace(unit, **{s: replace(c, noise=models[s]) for s, c in unit.sensors if s in models})
        path = out_dir / f'{name}.yaml'
        save_unit(path, unit, header=pool_header(outcome.statistics.records, str(path),
                                                 '' if name in far else prior.label))
        write_text_atomic(out_dir / LOGS / f'{name}.txt', ''.join(f'{line}\n' for line in lines))
        written[name] = str(path)
    return written


def run_everyday(args: argparse.Namespace, settings, options) -> int:
    """``fit-fleet --everyday DIR -o OUT`` (see the module's description).

    :param settings: ``fit``'s :class:`~tak_thermo_ros.passes.run.FitSettings` of the options given;
        ``options``: how the records are read (their topics).
    """
    from tak_thermo_ros.core.fit.prior_fit import fleet_from_units
    from tak_thermo_ros.formats.prior_file import save_prior
    from tak_thermo_ros.passes.fleet import DEFAULT_WORKERS, _connect
    for option, given in (('--validate', args.validate), ('--prior', getattr(args, 'prior', None)),
                          ('--noise-run', getattr(args, 'noise_run', None)),
                          ('--noise-from-residual', getattr(args, 'noise_from_residual', False))):
        if given:
            msg = (f'{option}: not with --everyday (it makes OUT_DIR/prior.yaml and fits each unit with it; '
                   f'validate a unit with tak_calib validate FOLDER --params OUT_DIR/UNIT.yaml)')
            raise TakError(msg)
    if args.bags:
        msg = f'{args.bags[0]}: BAGs and --everyday exclude each other (--everyday DIR holds a folder per unit)'
        raise TakError(msg)
    out_dir = Path(os.path.abspath(args.output))
    units, lines = everyday_units(args.everyday)
    names = [name for name, _ in units]
    check_everyday_outputs(out_dir, names, force=args.force)
    noise = (args.noise, options) if getattr(args, 'noise', None) else None
    require('distributed', 'fit-fleet')
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
        found = _gathered(futures, sys.stderr)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
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
    prior = replace(prior, label=f'{PRIOR_FILE}: {len(prior.units)} units, {prior.records} records')
    save_prior(prior_path, prior, header=f'tak_thermo_ros fleet prior from {len(statistics)} units of '
                                         f'{args.everyday} (tak_calib fit-fleet --everyday)\n'
                                         f'use with: tak_calib fit RECORDS --prior {PRIOR_FILE} -o PARAMS.yaml')
    written = _unit_files(out_dir, found, prior, noise)
    for line in prior.lines():
        print(line)
    for line in far_lines(prior):
        print(line)
    for name in names:
        if name in failed:
            print(f'{name}: failed: {failed[name]}')
        else:
            print(unit_line(name, written[name], found[name].statistics.records))
    for line in prior_table(prior):
        print(line)
    cpu = sum(outcome.seconds for outcome in found.values())
    peak = max(outcome.peak_bytes for outcome in found.values())
    print(f'{len(written)} of {len(units)} units fitted with the prior in {time.perf_counter() - start:.1f} s')
    print(f'workers: {cpu / max(len(units), 1):.1f} s CPU per unit, at most {peak / 2 ** 20:.0f} MiB each')
    print(f'wrote {prior_path} and the units\' files beside it')
    if not written:
        msg = f'no unit was fitted (see {out_dir / LOGS})'
        raise OutputError(msg)
    return 0
