"""Everyday runs for the calibration watch: a healthy unit, one whose gyro offset moved, one whose slope grew.

Shared by the core's statistics over seeds (``test/core/link/test_watch.py``) and the real node's tests
(``test/ros/test_node_watch.py``): the same records, the same calibration file.

The records are the everyday simulator's (power-up at the day's ambient, self-heating, rests on
uneven ground at any heading, motion with vibration between, a new turn-on offset at every
power-up), with the Earth's rotation at :data:`LATITUDE` added at the rests (the simulator's
rates are the attitude's alone). A faulty unit is the same record with its fault added to the
raw gyroscope: the offset of x moved by 800 deg/h, or the offset's drift against temperature of
y grown by a quarter (the same noise, the same rests: a paired comparison).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from tak_thermo_ros.core.link.correction import UnitCorrector
from tak_thermo_ros.core.link.model import TurnOn, UnitCalibration
from tak_thermo_ros.core.link.online import OnlineCompensator
from tak_thermo_ros.core.link.learning import adjust
from tak_thermo_ros.core.link.rest_noise import ChannelNoise
from tak_thermo_ros.core.link.watch import CalibrationWatch, WatchSettings
from tak_thermo_ros.core.values import DEG_PER_H
from tak_thermo_ros.core.records.record import DriverRecord
from tak_thermo_ros.core.records.stamps import NANOSECONDS
from tak_thermo_ros.core.simulation.everyday import (
    EverydayRecord,
    _rest_poses,
    _schedule,
    everyday_scenario,
    everyday_truth,
    simulate_everyday_record,
)
from tak_thermo_ros.core.values import EARTH_RATE
from tak_thermo_ros.formats.bag import play_order

LATITUDE = 45.0
"""Where the simulated unit lives (the node's and validate's ``latitude``)."""
SCENARIO, HABITS = everyday_scenario({'sample_rate_hz': 10.0, 'seed': 11,
                                      'everyday': {'records': 40, 'record_minutes': 20.0}})
"""Records of about 20 minutes at 20 Hz (about 24,000 Imu messages, 10 to 16 rests each)."""
OFFSET_MOVED = 800.0 / DEG_PER_H
"""rad/s: the gyro x offset of the faulty unit moved by 800 deg/h."""
SLOPE_GROWTH = 0.25
"""The gyro y offset's drift against temperature of the other faulty unit grew by a quarter."""
FAULTS = ('healthy', 'offset', 'slope')


def watch_unit(scenario=SCENARIO, habits=HABITS) -> UnitCalibration:
    """The unit's calibration file: its true links, its noise models, the turn-on repeatability of its power-ups."""
    truth = everyday_truth(scenario, habits)
    sensors = {}
    for name in ('accel', 'gyro'):
        spread = tuple(float(v) for v in habits.turn_on(name))
        sensors[name] = replace(truth.sensor(name), noise=scenario.noise_truth(name),
                                turn_on=TurnOn(spread, tuple(0.2 * v for v in spread), 16))  # type: ignore[arg-type]
    return replace(truth, accel=sensors['accel'], gyro=sensors['gyro'])


def earth_rates(simulated: EverydayRecord, habits=HABITS, latitude: float = LATITUDE) -> np.ndarray:
    """``(r, 3)`` the Earth's rotation in the sensor frame at each rest (its pose, hence its heading)."""
    own = simulated.scenario
    lengths = _schedule(habits, np.random.default_rng([own.seed, 1]))
    poses = _rest_poses(habits, (len(lengths) + 1) // 2, np.random.default_rng([own.seed, 2]))
    earth = EARTH_RATE * np.array([0.0, math.cos(math.radians(latitude)), math.sin(math.radians(latitude))])
    return np.array([pose.T @ earth for pose in poses])


def everyday_runs(index: int, faults: tuple[str, ...] = FAULTS, scenario=SCENARIO, habits=HABITS
                  ) -> dict[str, EverydayRecord]:
    """Record ``index`` with the Earth's rotation at its rests, of a healthy unit and of the faulty ones.

    One simulation: each faulty unit is the record with its fault added to the raw gyroscope.
    """
    simulated = simulate_everyday_record(scenario, habits, index)
    gyro = simulated.record.gyro.copy()
    earth = earth_rates(simulated, habits)
    for rest, rate in enumerate(earth):
        gyro[simulated.rest == rest] += rate
    runs = {}
    for fault in faults:
        faulty = gyro.copy()
        if fault == 'offset':
            faulty[:, 0] += OFFSET_MOVED
        elif fault == 'slope':
            axis = scenario.gyro_unit[1]
            n = simulated.board_celsius - scenario.reference_celsius
            faulty[:, 1] += SLOPE_GROWTH * sum(c * n ** (k + 1) for k, c in enumerate(axis.offset_coeffs))
        runs[fault] = replace(simulated, record=replace(simulated.record, gyro=faulty))
    return runs


def held_temperature(simulated: EverydayRecord) -> tuple[np.ndarray, np.ndarray]:
    """The Imu rows from the first temperature on and the temperature each is corrected with (the last before it)."""
    record = simulated.record
    latest = np.searchsorted(record.temp_stamp_ns, record.stamp_ns, side='right') - 1
    rows = np.flatnonzero(latest >= 0)
    return rows, record.temperature[latest[rows]]


def corrected_run(simulated: EverydayRecord, unit: UnitCalibration) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(stamps, (k, 6) corrected values, temperatures)`` as the node corrects the record."""
    record = simulated.record
    rows, temperature = held_temperature(simulated)
    values = np.hstack([record.accel, record.gyro])[rows]
    stamps = record.stamp_ns[rows]
    return stamps, UnitCorrector(unit).correct(values, temperature, stamp_s=stamps * 1e-9), temperature


def watch_run(simulated: EverydayRecord, unit: UnitCalibration, settings: WatchSettings | None = None
              ) -> tuple[CalibrationWatch, int | None, np.ndarray]:
    """The watch over a record as the node runs it (judging each rest as it ends).

    :returns: the watch at the end, the stamp of the message after which it first said stale
        (``None``: never), and the output the node publishes (``(k, 6)``: with learning, adjusted).
    """
    settings = settings or WatchSettings(latitude=LATITUDE)
    stamps, values, temperature = corrected_run(simulated, unit)
    watch = settings.watch(unit)
    take = watch.take
    fired = None
    adjusting = settings.turn_on or settings.learn is not None
    published: list = []
    publish = published.append
    for stamp, sample, temp in zip(stamps.tolist(), values.tolist(), temperature.tolist()):
        take(stamp, sample, temp)
        if adjusting:
            adjustment = watch.adjustment
            publish(sample if adjustment is None else adjust(tuple(sample), temp, adjustment, watch.reference))
        if watch.pending:
            watch.judge()
            if fired is None and watch.stale:
                fired = stamp
    watch.finish()
    if fired is None and watch.stale:
        fired = int(stamps[-1])
    return watch, fired, np.array(published) if adjusting else values


def rest_ends_ns(simulated: EverydayRecord) -> np.ndarray:
    """``(r,)`` the stamp of each true rest's last sample."""
    return np.array([simulated.record.stamp_ns[np.flatnonzero(simulated.rest == rest)[-1]]
                     for rest in range(int(simulated.rest.max()) + 1)])


def learning_ratios(simulated: EverydayRecord, output: np.ndarray, unit: UnitCalibration, rate_hz: float,
                    habits=HABITS) -> np.ndarray:
    """``(r, 3)`` from the 5th true rest on: the published rate's mean less the true Earth rate, over its floor.

    ``output`` is what the node publishes from the first temperature on (:func:`watch_run`'s);
    a rest's edges (the motion's fading vibration) are left out, a rest of fewer than 40 samples
    then skipped.
    """
    rows_kept, _ = held_temperature(simulated)
    earth = earth_rates(simulated, habits)
    rest = simulated.rest[rows_kept]
    out = []
    for index in range(4, int(rest.max()) + 1):
        rows = np.flatnonzero(rest == index)[10:-10]
        if len(rows) < 40:
            continue
        duration = len(rows) / rate_hz
        floor = np.array([math.sqrt(ChannelNoise.axis(unit.gyro.noise, axis).level(duration)) for axis in range(3)])
        out.append((output[rows, 3:].mean(axis=0) - earth[index]) / floor)
    return np.array(out).reshape(-1, 3)


def core_published(core: OnlineCompensator, record: DriverRecord, *, judge: bool = False) -> np.ndarray:
    """``(k, 6)`` what the node's core publishes from the record, played in ``tak_calib play``'s order.

    Every message's receive time is 0 (``core`` built with a long ``temp_timeout_s``); with
    ``judge`` the watch judges after every message.
    """
    published = []
    for stamp, stream, row in play_order(record.temp_stamp_ns, record.stamp_ns):
        if stream == 0:
            core.process_temperature(float(record.temperature[row]), 0.0)
        else:
            result = core.process_values(*divmod(stamp, NANOSECONDS), (*record.accel[row], *record.gyro[row]), 0.0)
            if isinstance(result, tuple):
                published.append(result)
        if judge:
            core.judge_watch()
    return np.array(published)
