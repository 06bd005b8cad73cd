"""The files plain ``tak_calib fit`` writes, per seed of an everyday setting: a pool of records and a chamber run.

Issue 39's benches judge the ordinary path: per seed (``everyday_check.month``: the setting the
pool was built on, or the second one) the month's first ``records`` records are written as 50 Hz
driver bags into a directory and ``tak_calib fit DIR -o pool.yaml`` fits them (the command's own
code, in process: no other option); the same unit's chamber run (a static run z up through six
plateaus over the month's temperatures at the records' rate, no reference topics: its own
power-up, so its own turn-on offset) is written and ``tak_calib fit chamber -o chamber.yaml``
fits it. The records
after the pool's are the held-out ones (never seen by a fit). The bags are removed once fitted; the
files and what ``fit`` printed are kept in a cache directory (``TAK_EVERYDAY_FILES``, default
the system's temporary directory) so that both benches share them.

``noise``: a Kalibr file of the unit's true noise models given as ``--noise`` (the interim path of
issue 39 before every fit writes its own noise model); ``None``: plain ``fit``.
"""

from __future__ import annotations

import contextlib
import io
import os
import shutil
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from everyday_check import month
from tak_thermo_ros import cli
from tak_thermo_ros.core.simulation.everyday import simulate_everyday_record
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.formats.bag import write_driver_record
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.formats.kalibr import write_kalibr

CACHE = Path(os.environ.get('TAK_EVERYDAY_FILES', Path(tempfile.gettempdir()) / 'tak_everyday_files'))
CHAMBER_PLATEAUS = 6


@dataclass(frozen=True)
class SeedFiles:
    """One seed's files and what ``fit`` printed writing them; the scenario and habits of its month."""

    pool: Path
    chamber: Path
    pool_lines: tuple[str, ...]
    chamber_lines: tuple[str, ...]
    scenario: object
    habits: object

    def units(self):
        """The two files as ``tak_calib`` reads them (``pool``, ``chamber``)."""
        return {'pool': load_unit(self.pool), 'chamber': load_unit(self.chamber)}


def _fit(arguments: list[str]) -> tuple[str, ...]:
    """``tak_calib fit ARGUMENTS`` in process; what it printed (a failure raises with it)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        status = cli.main(['fit', *arguments])
    if status != 0:
        msg = f'tak_calib fit {" ".join(arguments)}: exit {status}\n{out.getvalue()}'
        raise RuntimeError(msg)
    return tuple(out.getvalue().splitlines())


def chamber_run(scenario, habits, seed: int):
    """The unit's chamber run: static z up, six plateaus over the month's span, its own power-up, no reference."""
    low, high = habits.temperature_span()
    rng = np.random.default_rng([seed, 78])
    units = {}
    for name, sensor in (('accel_unit', 'accel'), ('gyro_unit', 'gyro')):
        draw = rng.standard_normal(3) * habits.turn_on(sensor)
        units[name] = tuple(replace(axis, offset=axis.offset + d) for axis, d in zip(getattr(scenario, name), draw))
    plateaus = tuple(float(t) for t in np.linspace(low, high, CHAMBER_PLATEAUS))
    run = replace(scenario, **units, temp_code_every=1, start_celsius=low,
                  plateaus_celsius=plateaus, plateau_hours=0.25, ramp_celsius_per_minute=1.0, board_lag_s=300.0,
                  positions=((0.0, 0.0, 1.0),), record_references=False, seed=seed + 200_003)
    return simulate(run).driver


def seed_files(setting: str, seed: int, *, records: int = 16, held_out: int = 4, minutes: float = 30.0,
               rate_hz: float = 50.0, noise: bool = False, cache: Path = CACHE) -> SeedFiles:
    """The pool's and the chamber run's files of one seed (written once, then read from ``cache``)."""
    scenario, habits = month(seed, records=records, held_out=held_out, minutes=minutes, rate_hz=rate_hz,
                             setting=setting)
    where = cache / f'{setting}_{seed}_{records}x{minutes:g}min_{rate_hz:g}hz{"_noise" if noise else ""}'
    pool, chamber = where / 'pool.yaml', where / 'chamber.yaml'
    lines = {name: where / f'{name}.txt' for name in ('pool', 'chamber')}
    if not (pool.exists() and chamber.exists()):
        where.mkdir(parents=True, exist_ok=True)
        bags = Path(tempfile.mkdtemp(prefix='tak_everyday_', dir=where))
        try:
            given = []
            if noise:
                write_kalibr(bags / 'imu.yaml', {sensor: scenario.noise_truth(sensor) for sensor in ('accel', 'gyro')},
                             rostopic='/imu/data_raw')
                given = ['--noise', str(bags / 'imu.yaml')]
            if not pool.exists():
                month_dir = bags / 'month'
                month_dir.mkdir()
                for index in range(records):
                    write_driver_record(month_dir / f'rec{index:02d}',
                                        simulate_everyday_record(scenario, habits, index).record)
                lines['pool'].write_text('\n'.join(_fit([str(month_dir), '-o', str(pool), *given])) + '\n')
                shutil.rmtree(month_dir)
            if not chamber.exists():
                write_driver_record(bags / 'chamber', chamber_run(scenario, habits, seed))
                lines['chamber'].write_text('\n'.join(_fit([str(bags / 'chamber'), '-o', str(chamber), *given]))
                                            + '\n')
        finally:
            shutil.rmtree(bags, ignore_errors=True)
    return SeedFiles(pool, chamber, tuple(lines['pool'].read_text().splitlines()),
                     tuple(lines['chamber'].read_text().splitlines()), scenario, habits)
