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
import os
import re
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence


from tak_thermo_ros.errors import OutputError, TakError
from tak_thermo_ros.optional import require
from tak_thermo_ros.passes.prior_lines import far_lines, prior_table, unit_line

PRIOR_FILE = 'prior.yaml'
LOGS = 'logs'


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


def run_everyday(args: argparse.Namespace, fit_actions: Sequence[argparse.Action], command, settings,
                 options) -> int:
    """``fit-fleet --everyday DIR -o OUT`` (see the module's description).

    :param settings: ``fit``'s :class:`~tak_thermo_ros.passes.run.FitSettings` of the options given;
        ``options``: how the records are read (their topics).
    """
    from tak_thermo_ros.core.fit.prior_fit import fleet_from_units
    from tak_thermo_ros.formats.prior_file import save_prior
    from tak_thermo_ros.passes.fleet import DEFAULT_WORKERS, _connect, pass_through
    from tak_thermo_ros.passes.handheld import handheld_settings
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
    settings = handheld_settings(settings)
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
