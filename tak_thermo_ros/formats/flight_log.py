"""What a flight log holds, read into the same blocks as a bag: PX4 ULog and ArduPilot DataFlash.

:mod:`tak_thermo_ros.formats.ulog` and :mod:`tak_thermo_ros.formats.dataflash` read their
files into one :class:`FlightLog`: one instance of the accelerometer, the gyroscope and (when
logged) the magnetometer, each on its own stamps (no resampling), the IMU's temperature in
degrees C, the sensors' device IDs and what the reader undid. :mod:`tak_thermo_ros.formats.records`
hands it to the passes as the same :class:`~tak_thermo_ros.formats.bag.BagStreams` and
:class:`~tak_thermo_ros.core.records.record.DriverRecord` blocks a driver bag gives, so every
command reads it through the same passes and the same fit.

Stamps are the log's own (microseconds since boot, as nanoseconds), each sensor's in log order:
the passes apply the stamp rule of a bag to them (a stamp that repeats, goes back or jumps far
ahead is left out and counted, :func:`~tak_thermo_ros.core.records.record.stamp_kept`), and the
readers' shared checks (:mod:`~tak_thermo_ros.core.records.plausible`: a stamp a bag cannot
hold, a clock step, a temperature not in degrees C) refuse the rest in one line. A NaN or
infinite temperature is kept, and ignored and counted by the passes as a bag's is. A log holds
no reference: the passes take it as a static run (gravity along the mean measured direction,
zero rate), as for a driver bag recorded without one.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from tak_thermo_ros.core.records.plausible import (
    clock_step_words,
    refuse_clock_step,
    temperature_unit_problem,
)
from tak_thermo_ros.core.records.record import DriverRecord, no_orientation, sensor_messages
from tak_thermo_ros.errors import FlightLogError

FLIGHT_SENSORS = ('accel', 'gyro', 'mag')
"""The sensors a flight log's instance can hold."""


@dataclass(frozen=True)
class FlightLog:
    """One sensor instance of a flight log, each sensor on its own stamps.

    :param path: the file.
    :param format: ``'ulog'`` or ``'dataflash'``.
    :param instance: the sensor instance read (``--instance``).
    :param stamps: per sensor (``accel``, ``gyro``, ``mag``) its sample stamps, ns.
    :param values: per sensor ``(k, 3)`` its samples: m/s^2, rad/s, tesla.
    :param temp_stamp_ns: stamps of the temperature samples.
    :param temperature: the IMU's temperature, degrees C.
    :param device_ids: per sensor its device ID (0 where the log names none).
    :param lines: what the reader did that a user should know (one statement each).
    :param temperature_source: where the temperature comes from (``sensor_accel.temperature``, ...).
    """

    path: Path
    format: str
    instance: int
    stamps: dict[str, np.ndarray]
    values: dict[str, np.ndarray]
    temp_stamp_ns: np.ndarray
    temperature: np.ndarray
    device_ids: dict[str, int] = field(default_factory=dict)
    lines: tuple[str, ...] = ()
    temperature_source: str = ''

    @property
    def frame_id(self) -> str:
        """The frame written with the log's samples (``imu0`` for instance 0)."""
        return f'imu{self.instance}'

    @property
    def shared_stamps(self) -> bool:
        """Whether accelerometer and gyroscope come in the same messages (a DataFlash ``IMU``)."""
        accel, gyro = self.stamps['accel'], self.stamps['gyro']
        return len(accel) == len(gyro) and bool(np.array_equal(accel, gyro))

    def count(self, sensor: str) -> int:
        """Samples of ``sensor`` in the log."""
        return len(self.stamps.get(sensor, ()))

    def stream_list(self) -> tuple[tuple[str, str, int], ...]:
        """``(role, topic, samples)`` of each sensor's own stream and the temperature (a survey's first lines).

        Each sensor counted on its own (a ULog's ``sensor_accel`` and ``sensor_gyro`` at their own
        rates), not the messages a driver record would carry them in.
        """
        message = (self.temperature_source or 'IMU.T').split('.')[0]  # DataFlash: IMU, or TCLR
        names = ({'accel': 'sensor_accel', 'gyro': 'sensor_gyro', 'mag': 'sensor_mag'} if self.format == 'ulog'
                 else {'accel': message, 'gyro': message, 'mag': 'MAG'} if self.shared_stamps
                 else {'accel': f'{message} accelerometer', 'gyro': f'{message} gyroscope', 'mag': 'MAG'})
        sensors = [('main', 'accel'), *([] if self.shared_stamps else [('gyro', 'gyro')])]
        listed = [(role, names[sensor], self.count(sensor)) for role, sensor in sensors]
        listed.append(('temperature', self.temperature_source or 'temperature', len(self.temp_stamp_ns)))
        if self.count('mag'):
            listed.append(('mag', names['mag'], self.count('mag')))
        return tuple(listed)

    def blocks(self, block_samples: int) -> Iterator[DriverRecord]:
        """The log as :class:`DriverRecord` blocks of ``block_samples`` accelerometer samples.

        Each block holds the other sensors' and the temperature samples stamped up to its last
        accelerometer sample (the last block: all that remain), so that a block aligner never
        waits long for a held value.
        """
        accel_stamps = np.maximum.accumulate(self.stamps['accel'])  # log order: a stamp that goes back stays in place
        edges = [int(accel_stamps[min(end, len(accel_stamps)) - 1])
                 for end in range(block_samples, len(accel_stamps), block_samples)]
        cuts = {name: np.searchsorted(np.maximum.accumulate(stamps), edges, side='right') for name, stamps in
                (('temperature', self.temp_stamp_ns), *((s, self.stamps[s]) for s in FLIGHT_SENSORS))}
        starts = {name: 0 for name in cuts}
        for index in range(len(edges) + 1):
            ends = {name: (int(cut[index]) if index < len(edges) else None) for name, cut in cuts.items()}
            rows = {name: slice(starts[name], ends[name]) for name in cuts}
            yield self._block(rows)
            starts = {name: (ends[name] if ends[name] is not None else 0) for name in cuts}

    def _block(self, rows: dict[str, slice]) -> DriverRecord:
        accel_stamps, gyro_stamps = self.stamps['accel'][rows['accel']], self.stamps['gyro'][rows['gyro']]
        shared = self.shared_stamps
        messages = accel_stamps if shared else sensor_messages(accel_stamps, gyro_stamps).stamp_ns
        count = len(messages)
        orientation, covariance = no_orientation(count)  # a log gives no orientation
        own = {} if shared else {'accel_stamp_ns': accel_stamps, 'gyro_stamp_ns': gyro_stamps}
        return DriverRecord(stamp_ns=messages, accel=self.values['accel'][rows['accel']],
                            gyro=self.values['gyro'][rows['gyro']], orientation=orientation,
                            orientation_covariance=covariance, temp_stamp_ns=self.temp_stamp_ns[rows['temperature']],
                            temperature=self.temperature[rows['temperature']], frame_id=self.frame_id,
                            mag_stamp_ns=self.stamps['mag'][rows['mag']], mag=self.values['mag'][rows['mag']],
                            mag_frame_id=self.frame_id if self.count('mag') else '', **own)

    def streams(self):
        """The log's streams as a bag's :class:`~tak_thermo_ros.formats.bag.BagStreams` (no reference)."""
        from tak_thermo_ros.core.link.model import InputKind
        from tak_thermo_ros.formats.bag import BagStreams
        ends = [int(stamps.max()) for stamps in self.stamps.values() if len(stamps)]
        return BagStreams(kind=InputKind.IMU, main=self.count('accel'), temperature=len(self.temp_stamp_ns),
                          reference=0, rate_reference=0, nominal_scale=None, mag=self.count('mag'), mag_reference=0,
                          end_ns=max(ends, default=0))

    def source(self) -> dict[str, object]:
        """What the calibration file records of the log: format, instance, device IDs."""
        return {'format': self.format, 'instance': self.instance,
                **{f'{sensor}_device_id': int(self.device_ids.get(sensor, 0)) for sensor in FLIGHT_SENSORS}}


def checked_sensor(path: Path, sensor: str, stamps: np.ndarray, values: np.ndarray, device_ids: np.ndarray | None,
                   where: str) -> tuple[np.ndarray, np.ndarray, int]:
    """A sensor's samples in log order and its device ID; refuses an ID that changes mid-log, a clock step.

    :param stamps: int64 nanoseconds (:func:`~tak_thermo_ros.core.records.plausible.stamp_ns_from_micros`).
    :param where: the topic or message named in an error (``sensor_accel instance 0``).
    :raises FlightLogError: the device ID changes (another sensor took this instance); the stamps
        the stamp rule keeps step by a year or more (:func:`~tak_thermo_ros.core.records.plausible.clock_step`).
    """
    device_id = 0
    if device_ids is not None and len(device_ids):
        device_ids = np.asarray(device_ids)
        if device_ids.dtype.kind not in 'iu' or device_ids.min() < 0 or device_ids.max() >= 2 ** 32:
            msg = f'{path}: {where}: device_id is not a whole number within 0..2**32-1'
            raise FlightLogError(msg)
        changed = np.flatnonzero(device_ids != device_ids[0])
        if changed.size:
            row = int(changed[0])
            msg = (f'{path}: {where}: device_id changes from {int(device_ids[0])} to {int(device_ids[row])} at sample '
                   f'{row + 1} of {len(device_ids)} (another sensor on this instance): split the log there')
            raise FlightLogError(msg)
        device_id = int(device_ids[0])
    stamps = np.asarray(stamps, dtype=np.int64)
    refuse_clock_step(stamps, FlightLogError, lambda row, step_ns: (
        f'{path}: {where}: time {clock_step_words(step_ns, f"at sample {row + 1} of {len(stamps)}")}'))
    return stamps, np.asarray(values, dtype=float).reshape(-1, 3), device_id


def checked_temperature(path: Path, stamps: np.ndarray, temperature: np.ndarray, where: str) -> tuple[np.ndarray,
                                                                                                      np.ndarray]:
    """The temperature samples in stamp order (held by stamp, as a bag's); refuses a log without a usable one.

    NaN and infinite values stay: the passes ignore and count them, as a bag's.

    :raises FlightLogError: no finite temperature (a sensor that reports none, an old log); temperatures
        not in degrees C (:func:`~tak_thermo_ros.core.records.plausible.temperature_unit_problem`).
    """
    temperature = np.asarray(temperature, dtype=float)
    if not np.isfinite(temperature).any():
        msg = (f'{path}: {where} holds no temperature (all {len(temperature)} values NaN or missing): a thermal '
               f'calibration needs the sensor\'s thermometer')
        raise FlightLogError(msg)
    problem = temperature_unit_problem(temperature)
    if problem is not None:
        msg = f'{path}: {where}: {problem}'
        raise FlightLogError(msg)
    stamps = np.asarray(stamps, dtype=np.int64)
    order = np.argsort(stamps, kind='stable')
    return stamps[order], temperature[order]


_CACHE: dict[tuple, FlightLog] = {}


def cached(reader, path: str | os.PathLike[str], instance: int) -> FlightLog:
    """``reader(path, instance)``, read once per file version in a process (each pass asks again)."""
    path = Path(path)
    try:
        stat = path.stat()
    except OSError as err:
        msg = f'{path}: cannot read ({err.strerror or err})'
        raise FlightLogError(msg) from None
    key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size, instance, reader.__module__)
    if key not in _CACHE:
        _CACHE.clear()  # one log at a time: a pass over another file drops the previous one
        _CACHE[key] = reader(path, instance)
    return _CACHE[key]
