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
FLIGHT_LOG_SUFFIXES = {'.ulg': 'ulog', '.bin': 'dataflash'}
"""An output named so is a flight log (a powered board's record, ``powered:`` in the scenario), not a bag."""


def output_kind(args: argparse.Namespace) -> str | None:
    """A bag directory, or a file for a flight log (by the output's suffix).

    ``None`` for a scenario with an ``everyday:`` section: a directory of bags, checked by
    :func:`_everyday` itself (each record's bag under the overwrite rule).
    """
    from pathlib import Path
    from tak_thermo_ros.formats.files import FILE
    if Path(args.out_bag).suffix.lower() in FLIGHT_LOG_SUFFIXES:
        return FILE
    return None if _everyday_scenario(args) is not None else BAG


def _everyday_scenario(args: argparse.Namespace):
    """The scenario file's ``(Scenario, Everyday)`` when it has an ``everyday:`` section, else ``None``."""
    from tak_thermo_ros.formats.scenario import load_everyday
    return load_everyday(args.scenario) if args.scenario else None


OUTPUTS = (('out_bag', output_kind, 'OUT_BAG'),)
"""This command's outputs: ``(argument, kind, option)``, checked before any work is done."""


def add_parser(commands) -> argparse.ArgumentParser:
    """Add the command to ``tak_calib``'s subcommands."""
    parser = commands.add_parser('simulate', help='simulate a thermal-chamber run into a bag, a powered board '
                                                  'into a flight log (OUT.ulg, OUT.bin), or a unit\'s everyday records')
    parser.add_argument('out_bag', metavar='OUT_BAG',
                        help='a bag directory; or OUT.ulg (a PX4 ULog) / OUT.bin (an ArduPilot DataFlash log): a '
                             "powered board (the scenario's powered: section); a directory of bags, one per record, "
                             "for a scenario with an everyday: section (docs/everyday.md)")
    parser.add_argument('--scenario', metavar='FILE.yaml',
                        help='scenario overrides, every key optional (docs/cli.md: The simulator)')
    parser.add_argument('--seed', type=options.seed, help='random seed, 0 .. 2^63 - 1 (overrides the scenario)')
    parser.add_argument('--storage', choices=['mcap', 'sqlite3'], default='mcap')
    options.add_topic_options(parser)
    parser.set_defaults(handler=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Simulate a chamber run into a bag (the paper's counts, or a driver's Imu)."""
    from pathlib import Path
    if Path(args.out_bag).suffix.lower() in FLIGHT_LOG_SUFFIXES:
        return _flight_log(args, FLIGHT_LOG_SUFFIXES[Path(args.out_bag).suffix.lower()])
    from tak_thermo_ros.formats.scenario import load_fleet
    fleet = load_fleet(args.scenario)  # a fleet needs an everyday section: said first
    everyday = _everyday_scenario(args)
    if everyday is not None:
        if fleet is not None:
            return _fleet(args, *everyday, fleet)
        return _everyday(args, *everyday)
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
        span = (f'temperature {driver.temperature.min():.2f}..{driver.temperature.max():.2f} C'
                if len(driver.temperature) else 'no temperature published')
        print(f'wrote {args.out_bag} ({args.storage}): {hours:.2f} h at {scenario.sample_rate_hz:g} Hz, {span}')
        print(f'  {len(driver.stamp_ns)} Imu, {len(driver.temp_stamp_ns)} temperature and '
              f'{len(driver.reference_stamp_ns)} reference messages')
        if scenario.handheld is not None:
            motion = scenario.handheld
            print(f'  hand-held: {len(run.trajectory.poses)} rests ({motion.pattern}), turns about a point '
                  f'{1e3 * float(np.linalg.norm(motion.lever_arm_m)):.0f} mm from the sensor; no reference topics')
        if len(driver.mag_stamp_ns):
            print(f'  magnetometer: {len(driver.mag_stamp_ns)} MagneticField on {common.topics(args).mag}'
                  f'{f" ({scenario.rotation} rotation record)" if scenario.rotation else ""}, '
                  f'{len(driver.mag_reference_stamp_ns)} reference field messages')
        return 0
    write_record(args.out_bag, run.record, topics=common.topics(args), storage=args.storage, force=args.force,
                 aux_types=aux_types)
    record = run.record
    print(f'wrote {args.out_bag} ({args.storage}): {scenario.duration_s() / 3600.0:.2f} h at '
          f'{scenario.sample_rate_hz:g} Hz, temperature code '
          f'{record.temp_code.min():.0f}..{record.temp_code.max():.0f}')
    print(f'  {len(record.counts_stamp_ns)} counts, {len(record.temp_stamp_ns)} temperature-code and '
          f'{len(record.reference_stamp_ns)} reference messages')
    return 0


def _flight_log(args: argparse.Namespace, kind: str) -> int:
    """A powered board (:mod:`tak_thermo_ros.core.simulation.powered`) as PX4 or ArduPilot logs it."""
    from tak_thermo_ros.core.simulation.powered import simulate_powered
    from tak_thermo_ros.formats.scenario import load_powered
    run = load_powered(args.scenario)
    if args.seed is not None:
        run = replace(run, seed=args.seed)
    if kind == 'dataflash':  # an IMU message holds both sensors: the gyroscope on the accelerometer's stamps
        run = replace(run, gyro_rate_hz=run.accel_rate_hz, gyro_phase_s=0.0)
    record = simulate_powered(run).record
    if kind == 'ulog':
        from tak_thermo_ros.formats.ulog import driver_topics, write_ulog
        write_ulog(args.out_bag, driver_topics(record, instance=args.instance), info={'sys_name': 'PX4'})
        what = (f'{len(record.accel)} sensor_accel ({run.accel_rate_hz:g} Hz), {len(record.gyro)} sensor_gyro '
                f'({run.gyro_rate_hz:g} Hz)')
    else:
        from tak_thermo_ros.formats.dataflash import driver_messages, write_dataflash
        write_dataflash(args.out_bag, driver_messages(record, instance=args.instance),
                        parameters={'AHRS_ORIENTATION': 0})
        what = f'{len(record.accel)} IMU messages ({run.accel_rate_hz:g} Hz)'
    print(f'wrote {args.out_bag}: {what}, instance {args.instance}, {run.duration_s / 60.0:.0f} min')
    print(f'temperature {record.temperature.min():.1f}..{record.temperature.max():.1f} C, the sensing elements '
          f'{run.element_lag_s:g} s behind the thermometer')
    return 0


def _write_month(out, scenario, habits, args: argparse.Namespace) -> tuple[float, float, list[int], list[float]]:
    """A unit's records into the directory ``out``: the month's temperatures, rests and minutes per record."""
    from tak_thermo_ros.core.simulation.everyday import simulate_everyday
    from tak_thermo_ros.formats.bag import write_driver_record
    low, high, rests, minutes = np.inf, -np.inf, [], []
    for simulated in simulate_everyday(scenario, habits):
        record = simulated.record
        write_driver_record(out / f'rec{simulated.index:02d}', record, topics=common.topics(args),
                            storage=args.storage)
        low, high = min(low, float(record.temperature.min())), max(high, float(record.temperature.max()))
        rests.append(len(simulated.up))
        minutes.append(simulated.duration_s / 60.0)
    return low, high, rests, minutes


def _everyday(args: argparse.Namespace, scenario, habits) -> int:
    """A unit's everyday records (:mod:`tak_thermo_ros.core.simulation.everyday`): one bag per record in a directory.

    The directory may exist when it holds only bags (``--force`` replaces them all); each record
    is written atomically as ``recNN``.
    """
    from tak_thermo_ros.passes.pool_records import bag_directory
    from tak_thermo_ros.units import numbers, reader_unit
    if args.seed is not None:
        scenario = replace(scenario, seed=args.seed)
    out = bag_directory(args.out_bag, force=args.force, option='OUT_BAG')
    low, high, rests, minutes = _write_month(out, scenario, habits, args)
    print(f'wrote {out}: {habits.records} records ({args.storage} bags rec00..rec{habits.records - 1:02d}) over '
          f'{habits.days:g} days, {min(minutes):.0f}..{max(minutes):.0f} min each at {scenario.sample_rate_hz:g} Hz')
    print(f'  temperature {low:.1f}..{high:.1f} C over the month; {min(rests)}..{max(rests)} rests per record as '
          f'drawn, within {habits.tilt_deg:g} deg of level' + (f' ({100 * habits.face_share:.0f} % on another face)'
                                                               if habits.face_share else ''))
    print('  (fit finds each record\'s rests itself: a rest that one noisy window breaks counts as two)')
    accel, gyro = (reader_unit(unit) for unit in ('m/s^2', 'rad/s'))
    print(f'  turn-on offset per power-up (true repeatability x y z): '
          f'{numbers(habits.turn_on("accel") * accel[1], 3)} {accel[0]}, '
          f'{numbers(habits.turn_on("gyro") * gyro[1], 3)} {gyro[0]}')
    return 0


def _fleet(args: argparse.Namespace, scenario, habits, fleet) -> int:
    """A fleet's units (:mod:`tak_thermo_ros.core.simulation.fleet`): a folder per unit ``unitNN``, its records in it.

    The directory may exist when it holds only such folders of bags (``--force`` replaces them all).
    """
    from pathlib import Path
    from tak_thermo_ros.core.simulation.fleet import fleet_unit
    from tak_thermo_ros.errors import OutputError
    from tak_thermo_ros.passes.pool_records import bag_directory
    from tak_thermo_ros.units import reader_unit
    if args.seed is not None:
        scenario = replace(scenario, seed=args.seed)
    out = Path(args.out_bag)
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        msg = f'{out} (OUT_BAG): exists and is not a directory; a fleet is written into a directory'
        raise OutputError(msg)
    names = [f'unit{index:02d}' for index in range(fleet.units)]
    if out.exists():
        others = sorted(entry.name for entry in out.iterdir() if entry.name not in names or not entry.is_dir())
        if others:
            msg = f'{out} (OUT_BAG): holds {others[0]}, which is no unit folder of this fleet; refusing to touch it'
            raise OutputError(msg)
    out.mkdir(exist_ok=True)
    low, high = np.inf, -np.inf
    for index, name in enumerate(names):
        directory = bag_directory(out / name, force=args.force, option='OUT_BAG')
        unit_low, unit_high, _, _ = _write_month(directory, fleet_unit(scenario, fleet, index), habits, args)
        low, high = min(low, unit_low), max(high, unit_high)
    small, factor = reader_unit('rad/s')  # type: ignore[misc]
    spread = ' '.join(f'{value * factor:.3g}' for value in fleet.gyro)
    print(f'wrote {out}: {fleet.units} units (unit00..unit{fleet.units - 1:02d}), {habits.records} records each at '
          f'{scenario.sample_rate_hz:g} Hz, {low:.1f}..{high:.1f} C')
    print(f'  gyroscope curves about the part\'s: spread {spread} {small} per C^0..3'
          + (f'; {fleet.groups} groups of slopes' if fleet.groups > 1 else '')
          + (f'; units {" ".join(str(i) for i in fleet.other_part)} of another part' if fleet.other_part else ''))
    return 0
