"""``tak_calib simulate``: a simulated chamber, table or hand-held run into a bag."""

from __future__ import annotations

import argparse

from tak_thermo_ros.cli import common, options
from tak_thermo_ros.formats.files import BAG
from tak_thermo_ros.core.simulation.imu import Scenario, simulate
from tak_thermo_ros.formats.scenario import load_scenario
from dataclasses import replace

import numpy as np

NAME = 'simulate'
OUTPUTS = (('out_bag', BAG, 'OUT_BAG'),)
"""This command's outputs: ``(argument, kind, option)``, checked before any work is done."""


def add_parser(commands) -> argparse.ArgumentParser:
    """Add the command to ``tak_calib``'s subcommands."""
    parser = commands.add_parser('simulate', help='simulate a thermal-chamber run into a bag')
    parser.add_argument('out_bag', metavar='OUT_BAG')
    parser.add_argument('--scenario', metavar='FILE.yaml',
                        help='scenario overrides, every key optional (README: The simulator)')
    parser.add_argument('--seed', type=options.seed, help='random seed, 0 .. 2**63-1 (overrides the scenario)')
    parser.add_argument('--storage', choices=['mcap', 'sqlite3'], default='mcap')
    options.add_topic_options(parser)
    parser.set_defaults(handler=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Simulate a chamber run into a bag (the paper's counts, or a driver's Imu)."""
    from tak_thermo_ros.formats.bag import write_driver_record, write_record
    scenario = load_scenario(args.scenario) if args.scenario else Scenario()
    if args.seed is not None:
        scenario = replace(scenario, seed=args.seed)
    run = simulate(scenario)
    from tak_thermo_ros.formats.bag import AUX_TYPES
    from tak_thermo_ros.core.simulation.imu import supply_signal_name
    aux_types = ({supply_signal_name(scenario): AUX_TYPES[scenario.record_supply_type]}
                 if scenario.record_supply else None)
    if run.driver is not None:
        driver = run.driver
        write_driver_record(args.out_bag, driver, topics=common.topics(args), storage=args.storage, force=args.force,
                            aux_types=aux_types)
        hours = ((driver.stamp_ns[-1] - driver.stamp_ns[0]) * 1e-9 if scenario.rotation or scenario.handheld
                 else scenario.duration_s()) / 3600.0
        print(f'wrote {args.out_bag}: {len(driver.stamp_ns)} Imu, {len(driver.temp_stamp_ns)} temperature, '
              f'{len(driver.reference_stamp_ns)} reference changes, {hours:.2f} h at '
              f'{scenario.sample_rate_hz:g} Hz ({args.storage}); temperature '
              f'{driver.temperature.min():.2f}..{driver.temperature.max():.2f} C')
        if scenario.handheld is not None:
            motion = scenario.handheld
            print(f'  hand-held: {len(run.trajectory.poses)} rests ({motion.pattern}), turns about a point '
                  f'{1e3 * float(np.linalg.norm(motion.lever_arm_m)):.0f} mm from the sensor; no reference topics')
        if len(driver.mag_stamp_ns):
            print(f'  magnetometer: {len(driver.mag_stamp_ns)} MagneticField on {common.topics(args).mag}'
                  f'{f" ({scenario.rotation} rotation record)" if scenario.rotation else ""}, '
                  f'{len(driver.mag_reference_stamp_ns)} reference field changes')
        return 0
    write_record(args.out_bag, run.record, topics=common.topics(args), storage=args.storage, force=args.force,
                 aux_types=aux_types)
    record = run.record
    print(f'wrote {args.out_bag}: {len(record.counts_stamp_ns)} counts, {len(record.temp_stamp_ns)} temperature codes, '
          f'{len(record.reference_stamp_ns)} reference changes, {scenario.duration_s() / 3600.0:.2f} h '
          f'at {scenario.sample_rate_hz:g} Hz ({args.storage}); temperature code '
          f'{record.temp_code.min():.0f}..{record.temp_code.max():.0f}')
    return 0
