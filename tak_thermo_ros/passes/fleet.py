"""``tak_calib fit-fleet``: calibrate a production batch of units on Dask.

Every unit runs in a Dask worker through the same code path as the command line: the worker
calls :func:`tak_thermo_ros.cli.main` with ``fit``, ``diagnose --json`` and, when a validation
bag is given, ``validate --json``, so each ``params.yaml`` is byte for byte what
``tak_calib fit BAG -o params.yaml`` writes for that bag alone (given the same absolute bag
path). A unit that fails is reported with its one-line error; the batch goes on.

Outputs under ``OUT_DIR``: ``units/<unit>/{params.yaml, diagnose.json, validation.json,
log.txt}``, ``fleet.json`` (one row per unit, the batch's robust spread and the flags) and
``fleet.html`` (the spread of every coefficient, the flagged units). The statistics live in
:mod:`tak_thermo_ros.core.diagnose.fleet`, the report in :mod:`tak_thermo_ros.reports.fleet`.

A unit's BAG may be a directory of its everyday records: ``fit``, ``diagnose`` and ``validate``
take it as a pool (:mod:`tak_thermo_ros.passes.pool`), so a fleet's months run unit by unit on
the workers, each reading its own records.

The bags and ``OUT_DIR`` must be reachable under the same paths from every worker (a shared
file system when the scheduler runs elsewhere).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import math
import os
import re
import shlex
import socket
import stat
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence, TextIO

from tak_thermo_ros.formats.calibration_file import calibration_section, write_text_atomic
from tak_thermo_ros.formats.files import FILE, check_output, file_kind, write_json
from tak_thermo_ros.core.diagnose.fleet import (
    MIN_UNITS_FOR_SPREAD,
    batch_spreads,
    calibration_metrics,
    diagnosis_verdict,
    flag_units,
    majority_verdict,
)
from tak_thermo_ros.core.link.model import AXES
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import CalibrationError, OutputError, TakError
from tak_thermo_ros.optional import require

STATUS_OK = 'ok'
STATUS_FAILED = 'failed'
PARAMS_FILE = 'params.yaml'
DIAGNOSE_FILE = 'diagnose.json'
VALIDATION_FILE = 'validation.json'
LOG_FILE = 'log.txt'
FLEET_JSON = 'fleet.json'
FLEET_HTML = 'fleet.html'
DEFAULT_WORKERS = 2
NOT_PASSED_TO_FIT = ('help', 'bag', 'output', 'no_progress')
"""``tak_calib fit`` options that fit-fleet sets itself; every other fit option is passed through."""
TOPIC_OPTIONS = ('counts_topic', 'raw_imu_topic', 'temp_topic', 'reference_topic', 'reference_rate_topic', 'latitude')
"""Options of fit that diagnose and validate take too (topics; a static driver bag's latitude)."""

_CLI_LOCK = threading.Lock()
"""``cli.main`` prints to ``sys.stdout``: units in threads of one worker process take turns."""


@dataclass(frozen=True)
class UnitTask:
    """What a worker needs to calibrate one unit (plain strings: it travels to the worker).

    :param unit: the unit's name (its directory under ``units/``).
    :param bag: absolute path of its calibration bag.
    :param validation_bag: absolute path of its validation bag, or ``None``.
    :param directory: absolute path of ``OUT_DIR/units/<unit>``.
    :param fit_options: ``tak_calib fit`` options after ``BAG -o PARAMS``.
    :param diagnose_options: ``tak_calib diagnose`` options after ``BAG --params PARAMS --json OUT``.
    :param validate_options: ``tak_calib validate`` options after ``BAG --params PARAMS --json OUT``.
    """

    unit: str
    bag: str
    validation_bag: str | None
    directory: str
    fit_options: tuple[str, ...] = ()
    diagnose_options: tuple[str, ...] = ()
    validate_options: tuple[str, ...] = ()


@dataclass
class UnitOutcome:
    """What happened to one unit.

    :param status: :data:`STATUS_OK` or :data:`STATUS_FAILED`.
    :param error: the one-line error of the step that failed (``fit: ...``), else ``None``.
    :param calibration: the ``calibration`` mapping of its ``params.yaml``.
    :param diagnosis: its ``diagnose --json`` document.
    :param validation: its ``validate --json`` document.
    :param worker: ``host:pid`` of the process that ran it.
    :param openblas_threads: ``OPENBLAS_NUM_THREADS`` in that process.
    """

    unit: str
    bag: str
    validation_bag: str | None
    status: str
    error: str | None = None
    seconds: float = 0.0
    calibration: dict[str, Any] | None = None
    diagnosis: dict[str, Any] | None = None
    validation: dict[str, Any] | None = None
    worker: str = ''
    openblas_threads: str | None = None
    files: dict[str, str] = field(default_factory=dict)


# ------------------------------------------------------------------------------ in the worker

Command = Callable[[list[str]], int]
"""``tak_calib``'s entry point (:func:`tak_thermo_ros.cli.main`), handed in by the command line
that registers fit-fleet, so that this module never imports it back."""


def _run_cli(command: Command, argv: list[str]) -> tuple[int, str, str]:
    """``tak_calib ARGV`` in this process: exit status, stdout, stderr."""
    out, err = io.StringIO(), io.StringIO()
    with _CLI_LOCK, contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = command(argv)
        except SystemExit as stop:  # argparse rejected an option
            status = stop.code if isinstance(stop.code, int) else 2
        except Exception as error:  # a bug, not a TakError: keep the unit's traceback in its log
            traceback.print_exc(file=err)
            print(f'tak_calib: error: {type(error).__name__}: {error}', file=err)
            status = 1
    return status, out.getvalue(), err.getvalue()


def _error_line(stderr: str, status: int) -> str:
    """The one line that says why a step failed."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    for line in reversed(lines):
        if line.startswith('tak_calib: error: '):
            return line[len('tak_calib: error: '):]
    return lines[-1] if lines else f'exit status {status}'


def run_unit(task: UnitTask, command: Command) -> UnitOutcome:
    """Fit, diagnose and validate one unit in this process with ``command``; never raises for a bad unit."""
    start = time.perf_counter()
    directory = Path(task.directory)
    outcome = UnitOutcome(unit=task.unit, bag=task.bag, validation_bag=task.validation_bag,
                          status=STATUS_OK, worker=f'{socket.gethostname()}:{os.getpid()}',
                          openblas_threads=os.environ.get('OPENBLAS_NUM_THREADS'))
    directory.mkdir(parents=True, exist_ok=True)
    for name in (PARAMS_FILE, DIAGNOSE_FILE, VALIDATION_FILE, LOG_FILE):
        # a failed step must not leave last run's file; only a regular file goes (check_outputs
        # refused anything else before the batch started)
        path = directory / name
        if path.is_file() and not path.is_symlink():
            path.unlink()
    params, diagnose_json, validation_json = (str(directory / name)
                                              for name in (PARAMS_FILE, DIAGNOSE_FILE, VALIDATION_FILE))
    steps = [('fit', ['fit', task.bag, '-o', params, *task.fit_options, '--no-progress']),
             ('diagnose', ['diagnose', task.bag, '--params', params, '--json', diagnose_json,
                           *task.diagnose_options, '--no-progress'])]
    if task.validation_bag is not None:
        steps.append(('validate', ['validate', task.validation_bag, '--params', params, '--json', validation_json,
                                   *task.validate_options, '--no-progress']))
    log = [f'unit {task.unit} on {outcome.worker} (OPENBLAS_NUM_THREADS={outcome.openblas_threads})\n']
    for step, argv in steps:
        step_start = time.perf_counter()
        status, stdout, stderr = _run_cli(command, argv)
        log.append(f'\n$ tak_calib {shlex.join(argv)}\n{stdout}{stderr}'
                   f'exit status {status} after {time.perf_counter() - step_start:.2f} s\n')
        if status != 0:
            outcome.status = STATUS_FAILED
            outcome.error = f'{step}: {_error_line(stderr, status)}'
            break
    try:
        if outcome.status == STATUS_OK:
            import yaml
            document = yaml.safe_load(Path(params).read_text(encoding='utf-8'))
            outcome.calibration = calibration_section(document)['calibration']
            outcome.diagnosis = json.loads(Path(diagnose_json).read_text(encoding='utf-8'))
            outcome.files = {'params': params, 'diagnose': diagnose_json}
            if task.validation_bag is not None:
                outcome.validation = json.loads(Path(validation_json).read_text(encoding='utf-8'))
                outcome.files['validation'] = validation_json
    except (OSError, ValueError, KeyError, TypeError, CalibrationError) as error:
        outcome.status = STATUS_FAILED
        outcome.error = f'reading the outputs back: {type(error).__name__}: {error}'
        log.append(f'\n{outcome.error}\n')
    outcome.seconds = time.perf_counter() - start
    log.append(f'\n{outcome.status}{": " + outcome.error if outcome.error else ""} '
               f'after {outcome.seconds:.2f} s\n')
    write_text_atomic(directory / LOG_FILE, ''.join(log))
    outcome.files['log'] = str(directory / LOG_FILE)
    return outcome


# ------------------------------------------------------------------------------ on the client

def unit_names(bags: Sequence[str | os.PathLike[str]]) -> list[str]:
    """A directory name per bag: its own name, with parent directories prepended while two clash.

    ``lineA/unit7/calib`` and ``lineA/unit8/calib`` become ``unit7_calib`` and ``unit8_calib``.

    :raises TakError: when a bag is given twice.
    """
    parts = [Path(os.path.abspath(bag)).parts for bag in bags]
    seen: dict[tuple[str, ...], int] = {}
    for index, path in enumerate(parts):
        if path in seen:
            msg = f'{bags[index]}: given twice (also as BAG number {seen[path] + 1})'
            raise TakError(msg)
        seen[path] = index
    depth = [1] * len(parts)
    while True:
        names = ['_'.join(path[-d:]).lstrip('/') for path, d in zip(parts, depth)]
        clashing = {name for name in names if names.count(name) > 1}
        if not clashing:
            break
        depth = [d + 1 if name in clashing and d < len(path) else d for path, d, name in zip(parts, depth, names)]
    return [re.sub(r'[^A-Za-z0-9._-]+', '_', name).strip('.') or f'unit{index + 1}' for index, name in enumerate(names)]


def _option_argv(action: argparse.Action, value: Any) -> list[str]:
    """The command-line words that give ``value`` to ``action`` (none for the default)."""
    if value == action.default:
        return []
    option = action.option_strings[-1]
    if action.nargs == 0:  # store_true / store_false / store_const
        return [option]
    if isinstance(value, (list, tuple)):
        return [option, *(str(item) for item in value)]
    return [f'{option}={value}']


def _link_coefficients(link: dict[str, Any], stem: str) -> dict[str, Any]:
    """One link's coefficients for the fleet table (``stem``: ``temp_code`` or ``temperature``)."""
    return {**{axis: {key: link[axis][key] for key in ('scale', 'offset', 'offset_span', 'offset_shape', 'scale_shape')}
               for axis in AXES},
            'effects': link.get('effects', {}),
            f'{stem}_ref': link[f'{stem}_ref'],
            f'{stem}_range': [link[f'{stem}_min'], link[f'{stem}_max']]}


def pass_through(actions: Sequence[argparse.Action], args: argparse.Namespace) -> tuple[str, ...]:
    """``args``' values of ``actions`` as command-line words (``str(float)`` round-trips exactly)."""
    words: list[str] = []
    for action in actions:
        words += _option_argv(action, getattr(args, action.dest))
    return tuple(words)


def _connect(scheduler: str | None, workers: int) -> tuple[Any, Any]:
    """A Dask client on ``scheduler``, or on a new local cluster of ``workers`` processes."""
    from dask.distributed import Client, LocalCluster
    if scheduler:
        try:
            return Client(scheduler, timeout='30s'), None
        except (OSError, TimeoutError, ValueError) as error:
            msg = f'--scheduler {scheduler}: cannot connect ({type(error).__name__}: {error})'
            raise TakError(msg) from None
    # One thread per process: the fits are numpy/scipy work that holds the GIL in between. No dashboard;
    # the scheduler's HTTP server (it starts one anyway) on a free port: 8787 may be another cluster's.
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host='127.0.0.1',
                           dashboard_address='127.0.0.1:0', scheduler_kwargs={'dashboard': False},
                           silence_logs=logging.ERROR, env={'OPENBLAS_NUM_THREADS': '1'})
    return Client(cluster), cluster


def run_batch(tasks: Sequence[UnitTask], command: Command, *, scheduler: str | None = None,
              workers: int = DEFAULT_WORKERS,
              progress: TextIO | None = None) -> list[UnitOutcome]:
    """Run every unit on Dask; the outcomes in the order of ``tasks``.

    :param command: ``tak_calib``'s entry point, run per unit in the workers.
    :param scheduler: address of a running Dask scheduler; ``None`` = a local cluster.
    :param workers: worker processes of the local cluster (one thread each).
    :param progress: where to print one line per finished unit (default stderr).
    """
    require('distributed', 'fit-fleet')  # one line naming dask[distributed] when it is missing
    from dask.distributed import as_completed
    stream = progress if progress is not None else sys.stderr
    client, cluster = _connect(scheduler, workers)
    outcomes: dict[str, UnitOutcome] = {}
    try:
        futures = {client.submit(run_unit, task, command, pure=False): task for task in tasks}
        for done, future in enumerate(as_completed(futures), start=1):
            task = futures[future]
            try:
                outcome = future.result()
            except Exception as error:  # the worker died or could not run the task
                outcome = UnitOutcome(unit=task.unit, bag=task.bag, validation_bag=task.validation_bag,
                                      status=STATUS_FAILED, error=f'dask: {type(error).__name__}: {error}')
            outcomes[task.unit] = outcome
            detail = f': {outcome.error}' if outcome.error else ''
            print(f'[{done}/{len(tasks)}] {outcome.unit} {outcome.status} {outcome.seconds:.1f} s{detail}',
                  file=stream, flush=True)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return [outcomes[task.unit] for task in tasks]


def _finite(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


def unit_metrics(outcome: UnitOutcome) -> dict[str, float]:
    """The metrics of one succeeded unit that the batch flags: its coefficients, residual and |g| error."""
    metrics = calibration_metrics(outcome.calibration or {})
    if outcome.validation is not None:
        after = _finite(outcome.validation.get('after', {}).get('rms'))
        if after is not None:
            metrics['validation.rms'] = after
    return metrics


def fleet_document(outcomes: Sequence[UnitOutcome], *, flag_sigma: float,
                   options: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``fleet.json`` document: the batch's spread and one row per unit with its flags."""
    succeeded = [o for o in outcomes if o.status == STATUS_OK]
    table = {o.unit: unit_metrics(o) for o in succeeded}
    verdicts = {o.unit: diagnosis_verdict(o.diagnosis) for o in succeeded}
    flags = flag_units(table, verdicts, k=flag_sigma)
    rows = []
    for outcome in outcomes:
        row: dict[str, Any] = {'unit': outcome.unit, 'bag': outcome.bag, 'validation_bag': outcome.validation_bag,
                               'status': outcome.status, 'error': outcome.error,
                               'seconds': round(outcome.seconds, 3), 'worker': outcome.worker}
        if outcome.status == STATUS_OK and outcome.calibration is not None:
            calibration = outcome.calibration
            if 'accel' in calibration:  # a driver calibration: both sensors
                row['coefficients'] = {sensor: _link_coefficients(calibration[sensor], 'temperature')
                                       for sensor in ('accel', 'gyro')}
                row['residual_rms'] = {sensor: {axis: calibration[sensor][axis].get('residual_rms') for axis in AXES}
                                       for sensor in ('accel', 'gyro')}
            else:
                row['coefficients'] = _link_coefficients(calibration, 'temp_code')
                row['residual_rms'] = {axis: calibration[axis].get('residual_rms') for axis in AXES}
            row['verdict'] = verdicts[outcome.unit]
            row['validation_rms'] = (outcome.validation or {}).get('after', {}).get('rms')
            row['validation_rms_before'] = (outcome.validation or {}).get('before', {}).get('rms')
            row['metrics'] = table[outcome.unit]
            row['flags'] = [flag.as_dict() for flag in flags.get(outcome.unit, [])]
        else:
            row.update(coefficients=None, residual_rms=None, verdict=None, validation_rms=None,
                       validation_rms_before=None, metrics={}, flags=[])
        row['flagged'] = bool(row['flags'])
        row['files'] = {name: os.path.relpath(path, start=Path(path).parents[2])
                        for name, path in outcome.files.items()}
        rows.append(row)
    return {
        'options': dict(options or {}),
        'units_total': len(outcomes),
        'units_ok': len(succeeded),
        'units_failed': len(outcomes) - len(succeeded),
        'units_flagged': sum(1 for row in rows if row['flagged']),
        'flag_sigma': flag_sigma,
        'flag_rule': (f'a unit is flagged when a metric lies more than {flag_sigma:g} x 1.4826 x MAD from the '
                      f'batch median (metrics with values from at least {MIN_UNITS_FOR_SPREAD} units), or when its '
                      'diagnosis verdict differs from the verdict of more than half of the diagnosed units'),
        'majority_verdict': majority_verdict(verdicts),
        'spread': {metric: spread.as_dict() for metric, spread in batch_spreads(table).items()},
        'units': rows,
    }


def distinct_units(bags: Sequence[str], topics) -> tuple[list[int], list[str]]:
    """The BAGs that are not a second copy of an earlier one: the same records by content, however spelled.

    A unit's records (its bag, or the records of its directory) by
    :attr:`~tak_thermo_ros.formats.records.Record.identity`: the same directory through a link, a
    copy of it, the same bag spelled otherwise is one unit, counted once, the second named.

    :returns: the indices of the BAGs kept, and one line per second copy.
    """
    from tak_thermo_ros.formats.records import open_record
    from tak_thermo_ros.passes.pool_records import record_paths, same_how
    first: dict[frozenset, int] = {}
    kept, lines = [], []
    for index, bag in enumerate(bags):
        try:
            records = record_paths([bag])[0]
        except TakError:  # no such path, no record in it: the unit's fit says so
            records = [Path(bag)]
        key = frozenset(open_record(path, topics=topics).identity or ('path', os.path.realpath(path))
                        for path in records)
        if key in first:
            earlier = bags[first[key]]
            how = same_how(bag, earlier, 'the same records')
            lines.append(f'{bag}: the same unit as {earlier} ({how}): counted once')
            continue
        first[key] = index
        kept.append(index)
    return kept, lines


def _tasks(args: argparse.Namespace, fit_actions: Sequence[argparse.Action], units_dir: Path,
           topics) -> tuple[list[UnitTask], list[str]]:
    """One task per distinct unit, and one line per BAG that is a second copy of another (:func:`distinct_units`)."""
    bags = [str(Path(os.path.abspath(bag))) for bag in args.bags]
    validation = [str(Path(os.path.abspath(bag))) for bag in args.validate] if args.validate else [None] * len(bags)
    if len(validation) != len(bags):
        msg = (f'--validate: {len(validation)} validation bags for {len(bags)} calibration bags '
               '(give one per BAG, in the same order)')
        raise TakError(msg)
    kept, lines = distinct_units(args.bags, topics)
    given = [args.bags[i] for i in kept]
    bags, validation = [bags[i] for i in kept], [validation[i] for i in kept]
    topics: list[str] = []
    for dest in TOPIC_OPTIONS:
        if getattr(args, dest, None) is not None:
            topics.append(f'--{dest.replace("_", "-")}={getattr(args, dest)}')
    diagnose = [*topics, f'--settle-time={args.settle_time}', f'--folds={args.folds}', f'--gravity={args.gravity}']
    if args.candidates:
        diagnose.append(f'--candidates={args.candidates}')
    validate = [*topics, f'--gravity={args.gravity}', f'--out-of-range={args.out_of_range}']
    fit_options = pass_through(fit_actions, args)
    if args.gravity != STANDARD_GRAVITY:  # fit's own --gravity (a static driver bag's reference) is fleet's
        fit_options += (f'--gravity={args.gravity}',)
    return [UnitTask(unit=name, bag=bag, validation_bag=check, directory=str(units_dir / name),
                     fit_options=fit_options, diagnose_options=tuple(diagnose), validate_options=tuple(validate))
            for name, bag, check in zip(unit_names(given), bags, validation)], lines


def _own_directory(path: Path, option: str) -> None:
    """A directory fit-fleet writes into: absent, or a directory itself (a link to one elsewhere is refused)."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if not stat.S_ISDIR(mode):
        msg = (f'{path} ({option}): exists and is {file_kind(mode)}; fit-fleet writes only into a directory, '
               'not through a link, refusing to touch it')
        raise OutputError(msg)


def check_outputs(out_dir: Path, units: Sequence[str], *, validating: bool, force: bool) -> None:
    """The overwrite rule (:mod:`tak_thermo_ros.formats.files`) for every file a batch will write, before it starts.

    ``OUT_DIR``, ``OUT_DIR/units`` and each unit's directory: absent or a directory (not a link);
    ``fleet.json``, ``fleet.html`` and each unit's ``params.yaml``, ``diagnose.json``,
    ``validation.json`` (with ``--validate``) and ``log.txt``: absent, or a regular file, replaced
    only with ``--force``; anything else (a link, a FIFO, a device) is refused, ``--force`` or not.

    :raises OutputError: one line naming the first path that may not be written.
    """
    def check_file(path: Path) -> None:
        if os.path.lexists(path):  # absent: its directory is made when the batch starts
            check_output(path, FILE, force=force)

    _own_directory(out_dir, '-o')
    for name in (FLEET_JSON, FLEET_HTML):
        check_file(out_dir / name)
    units_dir = out_dir / 'units'
    _own_directory(units_dir, '-o')
    files = (PARAMS_FILE, DIAGNOSE_FILE, *((VALIDATION_FILE,) if validating else ()), LOG_FILE)
    for unit in units:
        _own_directory(units_dir / unit, '-o')
        for name in files:
            check_file(units_dir / unit / name)


def cmd_fit_fleet(args: argparse.Namespace, fit_actions: Sequence[argparse.Action], command: Command,
                  topics=None) -> int:
    """Calibrate a batch of units on Dask; write per-unit outputs, ``fleet.json`` and ``fleet.html``.

    Every option and every output is checked before the cluster starts (:func:`check_outputs`); a BAG
    that is a second copy of another unit is named and counted once (:func:`distinct_units`).

    :param topics: the records' topics (:class:`~tak_thermo_ros.formats.bag.Topics`; default: the usual ones).
    """
    from tak_thermo_ros.formats.bag import Topics
    from tak_thermo_ros.reports.fleet import write_fleet_report
    out_dir = Path(os.path.abspath(args.output))
    fleet_json = out_dir / FLEET_JSON
    tasks, same = _tasks(args, fit_actions, out_dir / 'units', topics if topics is not None else Topics())
    for line in same:
        print(line)
    check_outputs(out_dir, [task.unit for task in tasks], validating=args.validate is not None, force=args.force)
    require('distributed', 'fit-fleet')  # one line naming dask[distributed] when it is missing
    out_dir.mkdir(parents=True, exist_ok=True)
    workers = args.workers or DEFAULT_WORKERS
    where = f'scheduler {args.scheduler}' if args.scheduler else f'a local cluster of {workers} workers'
    print(f'fit-fleet: {len(tasks)} units on {where}', file=sys.stderr, flush=True)
    start = time.perf_counter()
    outcomes = run_batch(tasks, command, scheduler=args.scheduler, workers=workers)
    options = {key: value for key, value in vars(args).items() if key not in ('handler', 'command', 'bags', 'validate')}
    document = fleet_document(outcomes, flag_sigma=args.flag_sigma, options=options)
    document['wall_seconds'] = round(time.perf_counter() - start, 3)
    write_json(fleet_json, document)
    html_path = write_fleet_report(document, out_dir / FLEET_HTML)
    for row in document['units']:
        if row['status'] != STATUS_OK:
            print(f'{row["unit"]}: failed: {row["error"]}')
        for flag in row['flags']:
            print(f'{row["unit"]}: flagged: {flag["reason"]}')
    print(f'{document["units_ok"]} of {document["units_total"]} units calibrated, {document["units_failed"]} failed, '
          f'{document["units_flagged"]} flagged (majority verdict {document["majority_verdict"]}) '
          f'in {document["wall_seconds"]:.1f} s')
    print(f'wrote {fleet_json}')
    print(f'wrote {html_path}')
    if document['units_ok'] == 0:
        msg = (f'all {document["units_total"]} units failed (first: {outcomes[0].unit}: {outcomes[0].error}); '
               f'see {fleet_json}')
        raise TakError(msg)
    return 0
