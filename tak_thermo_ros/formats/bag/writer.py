"""Writing bags: a whole record in the bag contract, corrected Imu messages (whole, or block by block).

Bags are written to a temporary directory beside the target and renamed into place, so a failed
write leaves nothing behind; an existing output is refused unless ``force``
(:mod:`tak_thermo_ros.formats.files`). Also the order ``tak_calib play`` publishes a record in.
"""

from __future__ import annotations

import os
import shutil
import sqlite3
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError

from tak_thermo_ros.formats.bag.contract import (
    AUX_FIELDS,
    IMU,
    MAGNETIC_FIELD,
    NOMINAL_SCALE_KEY,
    TEMPERATURE,
    TYPESTORE,
    VECTOR3_STAMPED,
    Topics,
)
from tak_thermo_ros.formats.cdr.encoder import encode_imus, encode_messages
from tak_thermo_ros.core.link.correction import NOT_PROVIDED_COVARIANCE, imu_covariances
from tak_thermo_ros.formats.files import BAG, check_output, install_directory, staging_directory
from tak_thermo_ros.core.records.record import NANOSECONDS, ChannelRecord, DriverRecord, rows_at, sensor_messages
from tak_thermo_ros.errors import BagError, OutputError

STORAGES = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
ENCODERS = ('block', 'rosbags')
"""``block``: a block of Imu messages serialised at once into arrays
(:func:`tak_thermo_ros.formats.cdr.encoder.encode_imus`); ``rosbags``: one message object and one
``serialize_cdr`` call per message (the reference). Both give the same bytes."""
IMU_ENCODER = 'block'
"""The encoder :func:`write_imu` and :class:`ImuBagWriter` use unless told otherwise."""
STORAGE_ERRORS: tuple[type[Exception], ...] = (OSError, sqlite3.Error, WriterError)
"""What a bag write raises when the storage fails (a full disk, no permission)."""

_Header = TYPESTORE.types['std_msgs/msg/Header']
_Time = TYPESTORE.types['builtin_interfaces/msg/Time']
_Vector3 = TYPESTORE.types['geometry_msgs/msg/Vector3']
_Vector3Stamped = TYPESTORE.types[VECTOR3_STAMPED]
_Quaternion = TYPESTORE.types['geometry_msgs/msg/Quaternion']
_Temperature = TYPESTORE.types[TEMPERATURE]
_Imu = TYPESTORE.types[IMU]
_MagneticField = TYPESTORE.types[MAGNETIC_FIELD]
BATTERY_STATE = 'sensor_msgs/msg/BatteryState'
FLOAT64 = 'std_msgs/msg/Float64'
AUX_TYPES = {'battery_state': BATTERY_STATE, 'float64': FLOAT64}
"""Message types a simulated auxiliary signal can be written as (scenario ``record_supply_type``)."""


def _header(stamp_ns: int, frame_id: str):
    sec, nanosec = divmod(int(stamp_ns), NANOSECONDS)
    return _Header(stamp=_Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def _aux_message(msgtype: str, stamp: int, frame_id: str, value: float):
    """A message of an auxiliary signal type carrying ``value`` in its obvious field."""
    if msgtype == BATTERY_STATE:
        nan = float('nan')
        return TYPESTORE.types[BATTERY_STATE](
            header=_header(stamp, frame_id), voltage=value, temperature=nan, current=nan, charge=nan,
            capacity=nan, design_capacity=nan, percentage=nan, power_supply_status=0, power_supply_health=0,
            power_supply_technology=0, present=True, cell_voltage=np.zeros(0, dtype=np.float32),
            cell_temperature=np.zeros(0, dtype=np.float32), location='', serial_number='')
    return TYPESTORE.types[msgtype](data=value)


class _AtomicBag:
    """A Writer into a temporary directory that is renamed to ``path`` on success.

    The overwrite rule of :mod:`tak_thermo_ros.formats.files` holds: an existing output is
    refused unless ``force``, and only a bag directory is ever replaced. A failure (a full
    disk, no permission) or an interruption removes the temporary directory; the error names
    ``path``.
    """

    def __init__(self, path: str | os.PathLike[str], storage: str, *, force: bool = False) -> None:
        self.path = Path(path)
        if storage not in STORAGES:
            msg = f'unknown storage {storage!r} (mcap or sqlite3)'
            raise BagError(msg)
        try:
            check_output(self.path, BAG, force=force)
        except OutputError as err:
            raise BagError(str(err)) from None
        self.staging = staging_directory(self.path)
        # rosbags writes the bag *into* a path that must not exist yet; its files are named after it.
        self.inner = self.staging / self.path.name
        self.writer = Writer(self.inner, version=9, storage_plugin=STORAGES[storage])

    def _failure(self, err: BaseException) -> BagError:
        if isinstance(err, OSError):
            detail = err.strerror or type(err).__name__
        else:
            detail = str(err).splitlines()[0] if str(err) else type(err).__name__
        return BagError(f'{self.path}: cannot write bag ({detail})')

    def __enter__(self) -> Writer:
        try:
            self.writer.open()
        except BaseException as err:
            shutil.rmtree(self.staging, ignore_errors=True)
            if isinstance(err, STORAGE_ERRORS):
                raise self._failure(err) from err
            raise
        return self.writer

    def __exit__(self, exc_type, exc, traceback) -> None:
        failure: BaseException | None = None
        try:
            try:
                self.writer.close()
            except Exception as err:  # a full disk shows here first for buffered storages
                failure = err
            if exc_type is None and failure is None:
                try:
                    install_directory(self.inner, self.path)
                except OSError as err:
                    failure = err
        finally:
            shutil.rmtree(self.staging, ignore_errors=True)
        if exc is not None:
            if isinstance(exc, STORAGE_ERRORS):
                raise self._failure(exc) from exc
            return
        if failure is not None:
            raise self._failure(failure) from failure


def _chunked(order: np.ndarray, *columns: np.ndarray, size: int = 65_536) -> Iterator[tuple]:
    """Rows ``order`` of equally long arrays as tuples of Python numbers, ``size`` at a time."""
    for start in range(0, len(order), size):
        chunk = order[start:start + size]
        yield from zip(*(column[chunk].tolist() for column in columns))


def write_record(path: str | os.PathLike[str], record: ChannelRecord, *, topics: Topics = Topics(),
                 storage: str = 'mcap', force: bool = False, aux_types: dict[str, str] | None = None) -> None:
    """Write a run in the bag contract (messages in stamp order, bag time = header stamp).

    :param force: replace an existing bag at ``path`` (:func:`tak_thermo_ros.formats.files.check_output`).
    :param aux_types: message type of each of the record's auxiliary signals ``aux:TOPIC``
        (default ``std_msgs/msg/Float64``); each is written on its topic, bag time = its stamp.
    """
    serialize = TYPESTORE.serialize_cdr
    # Messages in (stamp, stream, row) order, streams 0 temp, 1 ref, 2 counts; as arrays, so that
    # a long run costs a few bytes per message here, not Python tuples.
    aux_streams = list(record.aux.items())
    # streams 0 temp, 1 ref, then the auxiliary signals, then counts: at equal stamps a signal's
    # value comes before the counts it is held for, as the temperature does.
    events = _merged_order((record.temp_stamp_ns, record.reference_stamp_ns,
                            *(stamps for _, (stamps, _) in aux_streams), record.counts_stamp_ns))
    counts_stream = 2 + len(aux_streams)
    with _AtomicBag(path, storage, force=force) as writer:
        aux_writes = _aux_writers(writer, aux_streams, aux_types, record.frame_id)
        counts_conn = writer.add_connection(topics.counts, VECTOR3_STAMPED, typestore=TYPESTORE)
        temp_conn = writer.add_connection(topics.temp_code, TEMPERATURE, typestore=TYPESTORE)
        reference_conn = (writer.add_connection(topics.reference, VECTOR3_STAMPED, typestore=TYPESTORE)
                          if record.has_reference else None)
        if record.nominal_scale is not None:
            writer.set_custom_data(NOMINAL_SCALE_KEY, ','.join(repr(float(v)) for v in record.nominal_scale))
        for stamp, stream, row in events:
            header = _header(stamp, record.frame_id)
            if stream == 0:
                message = _Temperature(header=header, temperature=float(record.temp_code[row]), variance=0.0)
                writer.write(temp_conn, stamp, serialize(message, TEMPERATURE))
            elif stream == 1:
                x, y, z = (float(v) for v in record.reference[row])
                message = _Vector3Stamped(header=header, vector=_Vector3(x=x, y=y, z=z))
                writer.write(reference_conn, stamp, serialize(message, VECTOR3_STAMPED))
            elif stream == counts_stream:
                x, y, z = (float(v) for v in record.counts[row])
                message = _Vector3Stamped(header=header, vector=_Vector3(x=x, y=y, z=z))
                writer.write(counts_conn, stamp, serialize(message, VECTOR3_STAMPED))
            else:
                aux_writes[stream - 2](stamp, row)


def _merged_order(parts: tuple[np.ndarray, ...]) -> Iterator[tuple[int, int, int]]:
    """``(stamp, stream, row)`` of every message of several streams, in stamp order (ties: stream order)."""
    stamps = np.concatenate([np.asarray(part, dtype=np.int64) for part in parts])
    streams = np.concatenate([np.full(len(part), stream, dtype=np.int8) for stream, part in enumerate(parts)])
    rows = np.concatenate([np.arange(len(part), dtype=np.int64) for part in parts])
    order = np.lexsort((rows, streams, stamps))
    return _chunked(order, stamps, streams, rows)


def write_driver_record(path: str | os.PathLike[str], record: DriverRecord, *, topics: Topics = Topics(),
                        storage: str = 'mcap', force: bool = False, aux_types: dict[str, str] | None = None) -> None:
    """Write a driver run (Imu, temperature in C, references if any) in stamp order.

    :param force: replace an existing bag at ``path`` (:func:`tak_thermo_ros.formats.files.check_output`).
    :param aux_types: as :func:`write_record`.
    """
    serialize = TYPESTORE.serialize_cdr
    aux_streams = list(record.aux.items())
    messages = imu_messages(record)
    # streams 0 temperature, 1 reference, 2 rate reference, then the auxiliary signals, then the Imu,
    # then the magnetometer and its reference field
    events = _merged_order((record.temp_stamp_ns, record.reference_stamp_ns, record.rate_reference_stamp_ns,
                            *(stamps for _, (stamps, _) in aux_streams), messages.stamp_ns,
                            record.mag_stamp_ns, record.mag_reference_stamp_ns))
    imu_stream = 3 + len(aux_streams)
    mag_stream, field_stream = imu_stream + 1, imu_stream + 2
    zero_covariance = np.zeros(9)
    absent = np.array(NOT_PROVIDED_COVARIANCE)
    identity = np.array([0.0, 0.0, 0.0, 1.0])
    with _AtomicBag(path, storage, force=force) as writer:
        aux_writes = _aux_writers(writer, aux_streams, aux_types, record.frame_id)
        imu_conn = writer.add_connection(topics.raw_imu, IMU, typestore=TYPESTORE)
        temp_conn = (writer.add_connection(topics.temperature, TEMPERATURE, typestore=TYPESTORE)
                     if len(record.temp_stamp_ns) else None)
        reference_conn = (writer.add_connection(topics.reference, VECTOR3_STAMPED, typestore=TYPESTORE)
                          if len(record.reference_stamp_ns) else None)
        rate_conn = (writer.add_connection(topics.reference_rate, VECTOR3_STAMPED, typestore=TYPESTORE)
                     if len(record.rate_reference_stamp_ns) else None)
        mag_conn = (writer.add_connection(topics.mag, MAGNETIC_FIELD, typestore=TYPESTORE)
                    if len(record.mag_stamp_ns) else None)
        field_conn = (writer.add_connection(topics.reference_field, VECTOR3_STAMPED, typestore=TYPESTORE)
                      if len(record.mag_reference_stamp_ns) else None)
        for stamp, stream, row in events:
            header = _header(stamp, record.frame_id)
            if stream == mag_stream:
                x, y, z = (float(v) for v in record.mag[row])
                message = _MagneticField(header=_header(stamp, record.mag_frame_id or record.frame_id),
                                         magnetic_field=_Vector3(x=x, y=y, z=z),
                                         magnetic_field_covariance=zero_covariance)
                writer.write(mag_conn, stamp, serialize(message, MAGNETIC_FIELD))
            elif stream == field_stream:
                x, y, z = (float(v) for v in record.mag_reference[row])
                message = _Vector3Stamped(header=header, vector=_Vector3(x=x, y=y, z=z))
                writer.write(field_conn, stamp, serialize(message, VECTOR3_STAMPED))
            elif stream == 0:
                message = _Temperature(header=header, temperature=float(record.temperature[row]), variance=0.0)
                writer.write(temp_conn, stamp, serialize(message, TEMPERATURE))
            elif stream in (1, 2):
                values = record.reference if stream == 1 else record.rate_reference
                x, y, z = (float(v) for v in values[row])
                message = _Vector3Stamped(header=header, vector=_Vector3(x=x, y=y, z=z))
                writer.write(reference_conn if stream == 1 else rate_conn, stamp,
                             serialize(message, VECTOR3_STAMPED))
            elif stream != imu_stream:
                aux_writes[stream - 3](stamp, row)
            else:
                message_row, accel_row, gyro_row = (int(messages.message_row[row]), int(messages.accel_row[row]),
                                                    int(messages.gyro_row[row]))
                quaternion = record.orientation[message_row] if message_row >= 0 else identity
                qx, qy, qz, qw = (float(v) for v in quaternion)
                ax, ay, az = (float(v) for v in record.accel[accel_row]) if accel_row >= 0 else (0.0, 0.0, 0.0)
                gx, gy, gz = (float(v) for v in record.gyro[gyro_row]) if gyro_row >= 0 else (0.0, 0.0, 0.0)
                message = _Imu(header=header, orientation=_Quaternion(x=qx, y=qy, z=qz, w=qw),
                               orientation_covariance=(
                                   np.asarray(record.orientation_covariance[message_row], dtype=float)
                                   if message_row >= 0 else absent),
                               angular_velocity=_Vector3(x=gx, y=gy, z=gz),
                               angular_velocity_covariance=zero_covariance if gyro_row >= 0 else absent,
                               linear_acceleration=_Vector3(x=ax, y=ay, z=az),
                               linear_acceleration_covariance=zero_covariance if accel_row >= 0 else absent)
                writer.write(imu_conn, stamp, serialize(message, IMU))


@dataclass(frozen=True)
class ImuRows:
    """The Imu messages a driver record is written as: per message its stamp and the rows it carries.

    ``message_row`` is the record's message (orientation) at that stamp, ``accel_row`` and
    ``gyro_row`` the sensors' samples; ``-1`` where there is none (a sensor absent: its
    covariance[0] = -1).
    """

    stamp_ns: np.ndarray
    message_row: np.ndarray
    accel_row: np.ndarray
    gyro_row: np.ndarray


def imu_messages(record: DriverRecord) -> ImuRows:
    """The Imu messages of a driver record: one per message when the sensors share them.

    Otherwise the sensors' samples paired by stamp (:func:`~tak_thermo_ros.core.records.record.sensor_messages`).
    """
    if record.shared_stamps:
        rows = np.arange(len(record.stamp_ns))
        return ImuRows(np.asarray(record.stamp_ns, dtype=np.int64), rows, rows, rows)
    paired = sensor_messages(record.sensor_stamps('accel'), record.sensor_stamps('gyro'))
    return ImuRows(paired.stamp_ns, rows_at(record.stamp_ns, paired.stamp_ns), paired.accel_row, paired.gyro_row)


def play_order(temperature_ns: Any, input_ns: Any, *others: Any) -> list[tuple[int, int, int]]:
    """``(stamp, stream, row)`` of every message in the order ``tak_calib play`` publishes them to the node.

    Stream 0 is the temperature, 1 the input (Imu or counts), ``2 + k`` the ``k``-th of ``others``:
    in stamp order, at equal stamps the temperature first, then the input, then the others.
    """
    streams = (temperature_ns, input_ns, *others)
    return sorted((int(s), stream, row) for stream, stamps in enumerate(streams) for row, s in enumerate(stamps))


def _aux_writers(writer: Writer, aux_streams: list, aux_types: dict[str, str] | None, frame_id: str) -> list:
    """Per auxiliary signal ``aux:TOPIC`` a function ``(stamp, row) -> None`` writing one message of it."""
    from tak_thermo_ros.core.effects.aux_signal import split_signal_name
    serialize = TYPESTORE.serialize_cdr
    writes = []
    for name, (_, values) in aux_streams:
        topic, field = split_signal_name(name)
        msgtype = (aux_types or {}).get(name, FLOAT64)
        if field or msgtype not in AUX_FIELDS:
            msg = f'{name}: only the obvious number of a known auxiliary type can be written'
            raise BagError(msg)
        connection = writer.add_connection(topic, msgtype, typestore=TYPESTORE)

        def write(stamp: int, row: int, connection=connection, msgtype=msgtype, values=values) -> None:
            message = _aux_message(msgtype, stamp, frame_id, float(values[row]))
            writer.write(connection, stamp, serialize(message, msgtype))
        writes.append(write)
    return writes


def write_imu(path: str | os.PathLike[str], stamp_ns: np.ndarray, frame_id: str,
              acceleration: np.ndarray, variance: tuple[float, float, float], *,
              topic: str = Topics.imu, storage: str = 'mcap', force: bool = False,
              angular_velocity: np.ndarray | None = None,
              angular_variance: tuple[float, float, float] | None = None,
              orientation: np.ndarray | None = None, orientation_covariance: np.ndarray | None = None,
              encoder: str | None = None) -> None:
    """Write corrected samples as ``sensor_msgs/msg/Imu`` (REP 103 axes, m/s^2, rad/s).

    Counts input: the specific force only, orientation and angular velocity marked not
    provided (:func:`~tak_thermo_ros.core.link.correction.imu_covariances`). Driver input: also the
    corrected angular velocity, and the driver's orientation and its covariance passed through
    per message.

    :param force: replace an existing bag at ``path`` (:func:`tak_thermo_ros.formats.files.check_output`).
    :param encoder: one of :data:`ENCODERS` (default :data:`IMU_ENCODER`).
    """
    with _AtomicBag(path, storage, force=force) as writer:
        connection = writer.add_connection(topic, IMU, typestore=TYPESTORE)
        _write_imu_messages(writer, connection, stamp_ns, frame_id, acceleration, variance,
                            angular_velocity=angular_velocity, angular_variance=angular_variance,
                            orientation=orientation, orientation_covariance=orientation_covariance,
                            encoder=encoder or IMU_ENCODER)


class ImuBagWriter:
    """An Imu bag written block by block (``apply`` streaming), atomically as :func:`write_imu`.

    Use as a context manager; :meth:`write` takes the arguments of :func:`write_imu` for one
    block of samples. The bag appears at ``path`` only when the block ``with`` ends without
    an exception.

    :param encoder: one of :data:`ENCODERS` (default :data:`IMU_ENCODER`).
    """

    def __init__(self, path: str | os.PathLike[str], *, topic: str = Topics.imu, storage: str = 'mcap',
                 force: bool = False, encoder: str | None = None) -> None:
        self._bag = _AtomicBag(path, storage, force=force)
        self._topic = topic
        self._encoder = encoder or IMU_ENCODER
        self._writer: Writer | None = None
        self._connection = None
        self._mag_connections: dict[str, Any] = {}
        self.written = 0
        self.written_mag = 0

    def __enter__(self) -> ImuBagWriter:
        self._writer = self._bag.__enter__()
        self._connection = self._writer.add_connection(self._topic, IMU, typestore=TYPESTORE)
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        self._bag.__exit__(exc_type, exc, traceback)

    def write_mag(self, topic: str, stamp_ns: np.ndarray, frame_id: str, field: np.ndarray,
                  covariance: tuple[float, ...]) -> None:
        """Append one block of corrected magnetometer samples as ``sensor_msgs/msg/MagneticField`` on ``topic``."""
        assert self._writer is not None, 'ImuBagWriter.write_mag outside its with block'
        if topic not in self._mag_connections:
            self._mag_connections[topic] = self._writer.add_connection(topic, MAGNETIC_FIELD, typestore=TYPESTORE)
        connection = self._mag_connections[topic]
        raws = encode_messages(MAGNETIC_FIELD, np.asarray(stamp_ns, dtype=np.int64),
                               {'magnetic_field': field,
                                'magnetic_field_covariance': np.asarray(covariance, dtype=float)},
                               {'frame_id': frame_id})
        for stamp, raw in zip(np.asarray(stamp_ns).tolist(), raws):
            self._writer.write(connection, stamp, raw)
        self.written_mag += len(stamp_ns)

    def write(self, stamp_ns: np.ndarray, frame_id: str, acceleration: np.ndarray,
              variance: tuple[float, float, float], *, angular_velocity: np.ndarray | None = None,
              angular_variance: tuple[float, float, float] | None = None, orientation: np.ndarray | None = None,
              orientation_covariance: np.ndarray | None = None, accel_present: np.ndarray | None = None,
              gyro_present: np.ndarray | None = None) -> None:
        """Append one block of corrected samples (see :func:`write_imu`)."""
        assert self._writer is not None, 'ImuBagWriter.write outside its with block'
        _write_imu_messages(self._writer, self._connection, stamp_ns, frame_id, acceleration, variance,
                            angular_velocity=angular_velocity, angular_variance=angular_variance,
                            orientation=orientation, orientation_covariance=orientation_covariance,
                            encoder=self._encoder, accel_present=accel_present, gyro_present=gyro_present)
        self.written += len(stamp_ns)


def _write_imu_messages(writer: Writer, connection, stamp_ns: np.ndarray, frame_id: str, acceleration: np.ndarray,
                        variance: tuple[float, float, float], *, angular_velocity: np.ndarray | None,
                        angular_variance: tuple[float, float, float] | None, orientation: np.ndarray | None,
                        orientation_covariance: np.ndarray | None, encoder: str = 'block',
                        accel_present: np.ndarray | None = None, gyro_present: np.ndarray | None = None) -> None:
    orientation_cov, angular_cov, linear_cov = (np.array(c) for c in imu_covariances(variance, angular_variance))
    # a message without one sensor's sample: zeros, its covariance[0] = -1 (not provided)
    absent = np.array(NOT_PROVIDED_COVARIANCE)
    if accel_present is not None and not np.all(accel_present):
        acceleration = np.where(accel_present[:, None], acceleration, 0.0)
        linear_cov = np.where(accel_present[:, None], linear_cov, absent)
    if gyro_present is not None and not np.all(gyro_present) and angular_velocity is not None:
        angular_velocity = np.where(gyro_present[:, None], angular_velocity, 0.0)
        angular_cov = np.where(gyro_present[:, None], angular_cov, absent)
    if encoder == 'block':
        raws = encode_imus(stamp_ns, frame_id,
                           orientation=(0.0, 0.0, 0.0, 1.0) if orientation is None else orientation,
                           orientation_covariance=orientation_cov if orientation is None else orientation_covariance,
                           angular_velocity=(0.0, 0.0, 0.0) if angular_velocity is None else angular_velocity,
                           angular_velocity_covariance=angular_cov, linear_acceleration=acceleration,
                           linear_acceleration_covariance=linear_cov)
        for stamp, raw in zip(stamp_ns.tolist(), raws):
            writer.write(connection, stamp, raw)
        return
    if encoder != 'rosbags':
        msg = f'unknown Imu encoder {encoder!r} (known: {", ".join(ENCODERS)})'
        raise ValueError(msg)
    serialize = TYPESTORE.serialize_cdr
    identity = _Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
    zero = _Vector3(x=0.0, y=0.0, z=0.0)
    rates = angular_velocity.tolist() if angular_velocity is not None else None
    quaternions = orientation.tolist() if orientation is not None else None
    for row, (stamp, (x, y, z)) in enumerate(zip(stamp_ns.tolist(), acceleration.tolist())):
        rate = zero if rates is None else _Vector3(x=rates[row][0], y=rates[row][1], z=rates[row][2])
        if quaternions is None:
            quaternion, covariance = identity, orientation_cov
        else:
            qx, qy, qz, qw = quaternions[row]
            quaternion = _Quaternion(x=qx, y=qy, z=qz, w=qw)
            covariance = np.asarray(orientation_covariance[row], dtype=float)
        message = _Imu(header=_header(stamp, frame_id), orientation=quaternion,
                       orientation_covariance=covariance, angular_velocity=rate,
                       angular_velocity_covariance=angular_cov if angular_cov.ndim == 1 else angular_cov[row],
                       linear_acceleration=_Vector3(x=x, y=y, z=z),
                       linear_acceleration_covariance=linear_cov if linear_cov.ndim == 1 else linear_cov[row])
        writer.write(connection, stamp, serialize(message, IMU))
