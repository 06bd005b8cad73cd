"""``tak_calib``: simulate, fit, apply, validate, diagnose; the noise model; a batch on Dask; the carrier method.

One module per command (:mod:`tak_thermo_ros.cli.fit`, ...), each with ``add_parser`` and
``run``; the options they share are in :mod:`tak_thermo_ros.cli.options`. Every deliberate
failure prints one line ``tak_calib: error: ...`` and exits with status 2; no traceback reaches
the user (``tak_calib --debug`` shows it). Interrupted by SIGINT or SIGTERM, it removes what it
was writing and exits with 130 or 143. Every output obeys one overwrite rule
(:mod:`tak_thermo_ros.formats.files`): an existing output is refused unless ``--force``,
and only regular files, bags and report directories are ever replaced.
"""

from __future__ import annotations

import argparse
import signal
import sys
import traceback
from typing import Callable, Sequence

from tak_thermo_ros.cli import (apply, carrier, common, diagnose, export, fit, fit_fleet, import_csv, noise, play,
                                options, simulate, validate)
from tak_thermo_ros.formats.files import check_output
from tak_thermo_ros.errors import TakError

EXIT_ERROR = 2
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143

COMMANDS = (simulate, fit, apply, validate, import_csv, diagnose, noise, export, play)
"""The commands with a module of their own, in the order ``tak_calib --help`` lists them."""

OUTPUTS: dict[str, tuple[tuple[str, object, str], ...]] = {
    **{command.NAME: command.OUTPUTS for command in COMMANDS}, **carrier.OUTPUTS}
"""Each command's outputs: ``(argument, kind, option)``, checked before any work is done."""


class _Parser(argparse.ArgumentParser):
    """argparse with the tool's one-line error: ``tak_calib: error: ...``, exit status 2."""

    def error(self, message: str):  # type: ignore[override]
        command = self.prog.removeprefix('tak_calib').strip()
        where = f'{command}: ' if command else ''
        self.exit(EXIT_ERROR, f'tak_calib: error: {where}{message} (see {self.prog} --help)\n')


def build_parser() -> argparse.ArgumentParser:
    """The ``tak_calib`` argument parser."""
    parser = _Parser(prog='tak_calib', description=__doc__.splitlines()[0].strip('`').replace('``', ''))
    parser.add_argument('--debug', action='store_true', help='show the traceback of an error')
    parser.add_argument('-v', '--verbose', action='store_true',
                        help='print the detail too (the physics behind a verdict, ...)')
    commands = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    parsers = {command.NAME: command.add_parser(commands) for command in COMMANDS}
    fit_fleet.add_parser(commands, parsers[fit.NAME], main)
    carrier.add_parsers(commands)
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
            # a command whose output is a bag or a file by its name (simulate) says so per call;
            # None: the command checks that output itself (simulate's directory of everyday records)
            kind = kind(args) if callable(kind) else kind
            if kind is not None:
                check_output(path, kind, force=args.force, option=option)


def _report(message: str, err: BaseException, debug: bool) -> None:
    if debug:
        traceback.print_exception(err)
    print(f'tak_calib: error: {message}', file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``tak_calib``."""
    parser = build_parser()
    args = parser.parse_args(argv)
    options.resolve_gravity(args)
    handler: Callable[[argparse.Namespace], int] = args.handler
    debug = bool(getattr(args, 'debug', False))
    previous = None
    try:
        previous = signal.signal(signal.SIGTERM, _raise_terminated)
    except ValueError:  # not the main thread: SIGTERM keeps its meaning
        previous = None
    try:
        _check_outputs(args)
        with common.wrapped_output():
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
