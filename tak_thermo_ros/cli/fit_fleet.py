"""``tak_calib fit-fleet``: a production batch of units fitted, diagnosed and validated on Dask.

The orchestration is :mod:`tak_thermo_ros.passes.fleet`; this module is the command line.
"""

from __future__ import annotations

import argparse
import copy
from typing import Any

from tak_thermo_ros.cli import common, options
from tak_thermo_ros.core.diagnose.fleet import DEFAULT_FLAG_SIGMA
from tak_thermo_ros.core.link.correction import OutOfRange
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.passes.fleet import cmd_fit_fleet, Command, DEFAULT_WORKERS, NOT_PASSED_TO_FIT

NAME = 'fit-fleet'


def add_parser(commands: Any, fit_parser: argparse.ArgumentParser, command: Command) -> argparse.ArgumentParser:
    """Add ``fit-fleet`` to the ``tak_calib`` subcommands; it takes over every option of ``fit_parser``.

    The fit options are copied from the ``fit`` subcommand (so that a new fit option is at once
    a fleet option) and handed to ``tak_calib fit`` for every unit.
    """
    fleet = commands.add_parser(
        'fit-fleet', help='calibrate a batch of units on Dask, with a spread report and outlier flags',
        description='Fit, diagnose and (optionally) validate every unit of a production batch on Dask workers; '
                    'write OUT_DIR/units/<unit>/, OUT_DIR/fleet.json and OUT_DIR/fleet.html (see docs/fleet.md). '
                    'Exit status 0 when at least one unit was calibrated (failed units are listed in fleet.json), '
                    '2 when none was.')
    fleet.add_argument('bags', nargs='*', metavar='BAG',
                       help='one calibration bag per unit (the unit is named after it), or a directory of its '
                            'everyday records (a pool, docs/everyday.md)')
    fleet.add_argument('-o', '--output', required=True, metavar='OUT_DIR')
    fleet.add_argument('--everyday', metavar='DIR',
                       help='a folder per unit in DIR, each with its everyday records: a prior of the fleet from '
                            'them (OUT_DIR/prior.yaml), then each unit fitted with it (OUT_DIR/<unit>.yaml); '
                            'in place of BAGs (docs/fleet.md)')
    fleet.add_argument('--groups', type=options.int_within(1, 3), default=3, metavar='K',
                       help='--everyday: the units may fall in up to K groups of curves (default 3; 1: one)')
    fleet.add_argument('--validate', nargs='+', metavar='BAG',
                       help='one validation bag per unit, in the order of the BAGs (|g| error after correction); '
                            'a directory of records for a pool')
    where = fleet.add_mutually_exclusive_group()
    where.add_argument('--scheduler', metavar='ADDRESS',
                       help='a running Dask scheduler, e.g. tcp://host:8786 (default: a local cluster)')
    where.add_argument('--workers', type=options.int_within(1, options.MAX_WORKERS), metavar='N',
                       help=f'worker processes of the local cluster, one thread each (default {DEFAULT_WORKERS})')
    fleet.add_argument('--flag-sigma', type=options.positive, default=DEFAULT_FLAG_SIGMA, metavar='K',
                       help='flag a unit whose coefficient or residual lies more than K robust sigmas '
                            f'(1.4826 x MAD) from the batch median (default {DEFAULT_FLAG_SIGMA:g})')
    fleet.add_argument('--force', action='store_true', help='replace an existing OUT_DIR/fleet.json')
    diagnose = fleet.add_argument_group('diagnose and validate options (every unit)')
    diagnose.add_argument('--folds', type=options.folds, default=5,
                          help=f'cross-validation folds of diagnose, 2..{options.MAX_FOLDS} (default 5)')
    diagnose.add_argument('--candidates', type=options.candidates, metavar='NAME[,NAME...]',
                          help='effects diagnose tries (see diagnose)')
    diagnose.add_argument('--gravity', type=options.gravity, default=STANDARD_GRAVITY,
                          help=f'local gravity, m/s^2 ({options.GRAVITY_MIN:g}..{options.GRAVITY_MAX:g})')
    diagnose.add_argument('--out-of-range', choices=[p.value for p in OutOfRange], default=OutOfRange.CLAMP.value,
                          help='validate: temperature codes outside the calibrated range (default clamp)')
    fit_group = fleet.add_argument_group('fit options (passed to tak_calib fit for every unit)')
    # Copies of fit's own option actions (argparse offers no public way to share them). One whose
    # name fit-fleet already uses is left out rather than breaking every command (a test checks).
    taken = set(fleet._option_string_actions)
    fit_actions = [copy.copy(action) for action in fit_parser._actions
                   if action.option_strings and action.dest not in NOT_PASSED_TO_FIT
                   and not taken.intersection(action.option_strings)]
    for action in fit_actions:
        fit_group._add_action(action)
    fleet.set_defaults(handler=lambda args: _run(args, fit_actions, command))
    return fleet


def _run(args: argparse.Namespace, fit_actions, command: Command) -> int:
    """A batch of calibration bags, or with ``--everyday`` a fleet's prior and its units fitted with it."""
    from tak_thermo_ros.errors import TakError
    if args.everyday is not None:
        from tak_thermo_ros.cli.fit import fit_settings
        from tak_thermo_ros.passes.fleet_prior import run_everyday
        from tak_thermo_ros.passes.run import StreamOptions
        return run_everyday(args, fit_settings(args), StreamOptions(topics=common.topics(args), progress=False))
    if not args.bags:
        msg = 'give one BAG per unit, or --everyday DIR (a folder per unit)'
        raise TakError(msg)
    return cmd_fit_fleet(args, fit_actions, command, common.topics(args))
