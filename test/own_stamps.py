"""A driver record whose sensors come at their own stamps, and the node's logic played over its bag.

Shared by the core's test against ``tak_calib apply`` (``test/core/link/test_online.py``, no ROS) and the real
node's (``test/ros/test_node.py``): the same record, the same play order.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from tak_thermo_ros.core.link.correction import NOT_PROVIDED
from tak_thermo_ros.core.link.online import OnlineCompensator
from tak_thermo_ros.core.link.online_rules import OneSensor
from tak_thermo_ros.core.records.record import DriverRecord
from tak_thermo_ros.core.records.stamps import NANOSECONDS
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.simulation.powered import PoweredRun, simulate_powered
from tak_thermo_ros.formats.bag import ImuMessages, read_driver_record, read_imu_messages

SHARED_FIRST = 5
"""The record's first messages carry both sensors (the node starts on shared stamps)."""
RUN = PoweredRun(duration_s=20.0, accel_rate_hz=4.0, gyro_rate_hz=6.0, gyro_phase_s=0.0, start_celsius=4.0,
                 board_tau_s=20.0, self_heating_tau_s=5.0, seed=4)
"""20 s of a board warming from 4 C into the calibrated 5..35 C: the accelerometer at 4 Hz, the
gyroscope at 6 Hz; their stamps meet every half second (messages that carry both), and the
record's first :data:`SHARED_FIRST` gyroscope samples are put on the accelerometer's stamps."""
UNIT_EFFECTS = {'effects': {'hysteresis': {'width_codes': 0.5, 'amplitude_x': 0.02, 'amplitude_z': -0.01}},
                'gyro_effects': {'thermal_lag': {'tau_s': 5.0, 'slope_x': 0.002, 'slope_z': -0.0015}}}
"""Effects with memory on each sensor: its state must step on that sensor's own samples only."""
RAW_TOPIC = '/imu/data_raw'


def own_stamps_unit(*, accel_memory: bool = True):
    """The driver calibration (5..35 C), a thermal lag on the gyroscope, hysteresis on the accelerometer."""
    effects = UNIT_EFFECTS if accel_memory else {'gyro_effects': UNIT_EFFECTS['gyro_effects']}
    return Scenario(output='imu', **effects).driver_truth()


def own_stamps_record(*, shared_fault: bool = False) -> DriverRecord:
    """The run's record, faults on each sensor's own samples after the sensors came apart.

    A NaN gyroscope sample in a message that carries both (apply and the node keep its
    accelerometer sample), a non-physical accelerometer sample in a message of its own, and an
    accelerometer sample stamped as the one before it (a duplicate, its message also carrying
    the gyroscope's sample at that stamp). ``shared_fault``: also a NaN gyroscope sample among
    the first messages, before any message marks a sensor absent (the documented difference).
    """
    record = simulate_powered(RUN).record
    accel_stamps, accel = record.accel_stamp_ns.copy(), record.accel.copy()
    later = record.gyro_stamp_ns > accel_stamps[SHARED_FIRST - 1]
    gyro_stamps = np.concatenate([accel_stamps[:SHARED_FIRST], record.gyro_stamp_ns[later]])
    gyro = np.concatenate([record.gyro[:SHARED_FIRST], record.gyro[later]])
    both_later = int(np.flatnonzero(np.isin(gyro_stamps, accel_stamps[20:]))[0])  # a shared stamp after the start
    gyro[both_later, 1] = np.nan
    accel_alone = int(np.flatnonzero(~np.isin(accel_stamps, gyro_stamps))[5])
    accel[accel_alone, 2] = 1e308
    duplicate = int(np.flatnonzero(np.isin(accel_stamps, gyro_stamps))[-3])
    accel_stamps[duplicate + 1] = accel_stamps[duplicate]
    if shared_fault:
        gyro[2, 0] = np.nan
    messages = np.union1d(accel_stamps, gyro_stamps)
    orientation = np.random.default_rng(7).normal(size=(len(messages), 4))
    orientation /= np.linalg.norm(orientation, axis=1, keepdims=True)
    covariance = np.random.default_rng(8).uniform(0.0, 1e-3, (len(messages), 9))
    return replace(record, stamp_ns=messages, accel=accel, gyro=gyro, accel_stamp_ns=accel_stamps,
                   gyro_stamp_ns=gyro_stamps, orientation=orientation, orientation_covariance=covariance)


def play_order(bag: Path) -> tuple[ImuMessages, DriverRecord, list[tuple[int, int, int]]]:
    """The bag's raw Imu messages, its record, and the order to play them: ``(stamp, stream, row)``.

    Stamp order, the temperature (stream 0) before the Imu (stream 2) at equal stamps, the Imu
    messages in log order.
    """
    raw = read_imu_messages(bag, topic=RAW_TOPIC)
    record = read_driver_record(bag, progress=False)
    events = sorted([(int(s), 0, i) for i, s in enumerate(record.temp_stamp_ns)]
                    + [(int(s), 2, i) for i, s in enumerate(raw.stamp_ns)])
    return raw, record, events


def absent_marks(raw: ImuMessages) -> int:
    """How many of the raw messages mark a sensor absent."""
    return int(np.count_nonzero((raw.linear_acceleration_covariance[:, 0] == NOT_PROVIDED)
                                | (raw.angular_velocity_covariance[:, 0] == NOT_PROVIDED)))


def core_output(bag: Path, unit) -> tuple[OnlineCompensator, dict[str, np.ndarray], list]:
    """The node's logic (no ROS) over the bag, as the node gets it: the core, what it publishes, every result.

    What it publishes as the node fills the Imu: per published message its stamp, the six
    values (an absent sensor's zeros) and the two marks (covariance[0]: -1 where absent).
    """
    raw, record, events = play_order(bag)
    core = OnlineCompensator(unit, temp_topic='/imu/temperature')
    rows, results = [], []
    for stamp, stream, row in events:
        now = (stamp - events[0][0]) * 1e-9
        if stream == 0:
            core.process_temperature(float(record.temperature[row]), now_s=now)
            continue
        values = (*raw.linear_acceleration[row].tolist(), *raw.angular_velocity[row].tolist())
        result = core.process_values(*divmod(stamp, NANOSECONDS), values, now,
                                     raw.linear_acceleration_covariance[row, 0],
                                     raw.angular_velocity_covariance[row, 0])
        results.append(result)
        if isinstance(result, OneSensor):
            six = (*result.values, 0.0, 0.0, 0.0) if result.sensor == 'accel' else (0.0, 0.0, 0.0, *result.values)
            marks = (0.0, NOT_PROVIDED) if result.sensor == 'accel' else (NOT_PROVIDED, 0.0)
            rows.append((stamp, six, marks, row))
        elif isinstance(result, tuple):
            rows.append((stamp, result, (0.0, 0.0), row))
    output = {'stamp_ns': np.array([r[0] for r in rows], dtype=np.int64),
              'accel': np.array([r[1][:3] for r in rows]).reshape(-1, 3),
              'gyro': np.array([r[1][3:] for r in rows]).reshape(-1, 3),
              'accel_absent': np.array([r[2][0] == NOT_PROVIDED for r in rows]),
              'gyro_absent': np.array([r[2][1] == NOT_PROVIDED for r in rows]),
              'orientation': raw.orientation[[r[3] for r in rows]].reshape(-1, 4)}
    return core, output, results
