"""Bag I/O: the only module that imports rosbags.

The bag contract (each topic name is an option):

- ``/tak/counts``: ``geometry_msgs/msg/Vector3Stamped``, x, y, z = channel codes N.
- ``/tak/temp_code``: ``sensor_msgs/msg/Temperature``, ``temperature`` = raw code N_t.
- ``/tak/reference``: ``geometry_msgs/msg/Vector3Stamped``, true specific force (m/s^2),
  calibration runs only, published at least whenever it changes.
- ``/tak/imu/data_raw``: ``sensor_msgs/msg/Imu`` written by ``apply``.

Both rosbag2 storages (mcap, sqlite3) are read; bags are written to a temporary directory
beside the target and renamed into place, so a failed write leaves nothing behind; an existing
output is refused unless ``force`` (:mod:`tak_thermo_ros.core.files`).
"""

from __future__ import annotations

import os
import shutil
import sqlite3
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
from rosbags.rosbag2 import Reader, StoragePlugin, Writer, WriterError
from rosbags.typesys import Stores, get_typestore

from tak_thermo_ros.core.correction import imu_covariances
from tak_thermo_ros.core.files import BAG, check_output, install_directory, staging_directory
from tak_thermo_ros.core.record import NANOSECONDS, ChannelRecord
from tak_thermo_ros.errors import BagError, OutputError
from tak_thermo_ros.progress import Progress

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
VECTOR3_STAMPED = 'geometry_msgs/msg/Vector3Stamped'
TEMPERATURE = 'sensor_msgs/msg/Temperature'
IMU = 'sensor_msgs/msg/Imu'
NOMINAL_SCALE_KEY = 'tak_thermo_ros.nominal_scale'
"""Bag metadata ``custom_data`` key: nominal K0 per axis as ``'x,y,z'`` (counts per m/s^2)."""
STORAGES = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
STORAGE_ERRORS: tuple[type[Exception], ...] = (OSError, sqlite3.Error, WriterError)
"""What a bag write raises when the storage fails (a full disk, no permission)."""

_Header = TYPESTORE.types['std_msgs/msg/Header']
_Time = TYPESTORE.types['builtin_interfaces/msg/Time']
_Vector3 = TYPESTORE.types['geometry_msgs/msg/Vector3']
_Vector3Stamped = TYPESTORE.types[VECTOR3_STAMPED]
_Quaternion = TYPESTORE.types['geometry_msgs/msg/Quaternion']
_Temperature = TYPESTORE.types[TEMPERATURE]
_Imu = TYPESTORE.types[IMU]


@dataclass(frozen=True)
class Topics:
    """Topic names of the bag contract."""

    counts: str = '/tak/counts'
    temp_code: str = '/tak/temp_code'
    reference: str = '/tak/reference'
    imu: str = '/tak/imu/data_raw'


def _header(stamp_ns: int, frame_id: str):
    sec, nanosec = divmod(int(stamp_ns), NANOSECONDS)
    return _Header(stamp=_Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def _stamp_ns(header) -> int:
    return header.stamp.sec * NANOSECONDS + header.stamp.nanosec


class _TopicReader:
    """Messages of one topic, deserialised, with a progress count."""

    def __init__(self, reader: Reader, path: Path, topic: str, msgtype: str, *, required: bool) -> None:
        self.connections = [c for c in reader.connections if c.topic == topic]
        self.topic = topic
        if not self.connections and required:
            available = ', '.join(sorted({c.topic for c in reader.connections})) or 'none'
            msg = f'{path}: topic {topic} not found (topics in the bag: {available})'
            raise BagError(msg)
        for connection in self.connections:
            if connection.msgtype != msgtype:
                msg = f'{path}: topic {topic} has type {connection.msgtype}, expected {msgtype}'
                raise BagError(msg)
        self.msgtype = msgtype
        self.count = sum(c.msgcount for c in self.connections)
        self.reader = reader

    def messages(self, progress: Progress) -> Iterator[object]:
        if not self.connections:
            return
        deserialize = TYPESTORE.deserialize_cdr
        msgtype = self.msgtype
        for step, (_, _, raw) in enumerate(self.reader.messages(connections=self.connections)):
            yield deserialize(raw, msgtype)
            if step % 4096 == 4095:
                progress.advance(4096)


def read_record(path: str | os.PathLike[str], *, topics: Topics = Topics(),
                require_reference: bool = False, progress: bool = True) -> ChannelRecord:
    """Read the counts, temperature-code and (optional) reference streams of a bag.

    :raises BagError: missing bag or topic, wrong type, empty topic, unreadable or truncated file.
    """
    path = Path(path)
    if not path.exists():
        msg = f'{path}: no such bag'
        raise BagError(msg)
    try:
        with Reader(path) as reader:
            counts_topic = _TopicReader(reader, path, topics.counts, VECTOR3_STAMPED, required=True)
            temp_topic = _TopicReader(reader, path, topics.temp_code, TEMPERATURE, required=True)
            nominal_scale = _nominal_scale(reader, path)
            reference_topic = _TopicReader(reader, path, topics.reference, VECTOR3_STAMPED,
                                           required=require_reference)
            for topic in (counts_topic, temp_topic, *((reference_topic,) if require_reference else ())):
                if topic.count == 0:
                    msg = f'{path}: no messages on {topic.topic}'
                    raise BagError(msg)
            total = counts_topic.count + temp_topic.count + reference_topic.count
            with Progress(total, f'reading {path.name}', enabled=None if progress else False) as bar:
                counts_stamp, counts, frame_id = _read_vectors(counts_topic, bar, path, check_frame=True)
                temp_stamp = np.empty(temp_topic.count, dtype=np.int64)
                temp_code = np.empty(temp_topic.count)
                filled = 0
                for filled, message in enumerate(temp_topic.messages(bar), start=1):
                    temp_stamp[filled - 1] = _stamp_ns(message.header)
                    temp_code[filled - 1] = message.temperature
                if filled != temp_topic.count:
                    msg = f'{path}: {temp_topic.topic} holds {filled} of the {temp_topic.count} messages its index lists (truncated bag?)'
                    raise BagError(msg)
                reference_stamp, reference, _ = _read_vectors(reference_topic, bar, path, check_frame=False)
    except BagError:
        raise
    except Exception as err:  # rosbags and the storage libraries raise many kinds
        detail = str(err).splitlines()[0] if str(err) else type(err).__name__
        msg = f'{path}: cannot read bag ({detail})'
        raise BagError(msg) from None
    return ChannelRecord(counts_stamp_ns=counts_stamp, counts=counts, temp_stamp_ns=temp_stamp,
                         temp_code=temp_code, reference_stamp_ns=reference_stamp,
                         reference=reference, frame_id=frame_id, nominal_scale=nominal_scale)


def _nominal_scale(reader: Reader, path: Path) -> tuple[float, float, float] | None:
    metadata = getattr(reader.storage, 'metadata', None)  # rosbags' parsed metadata.yaml
    custom = getattr(metadata, 'custom', None) or {}
    text = custom.get(NOMINAL_SCALE_KEY)
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in str(text).split(','))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(v > 0 for v in values):
        msg = f'{path}: metadata {NOMINAL_SCALE_KEY} must be three positive numbers, got {text!r}'
        raise BagError(msg)
    return values  # type: ignore[return-value]


def _read_vectors(topic: _TopicReader, bar: Progress, path: Path, *,
                  check_frame: bool) -> tuple[np.ndarray, np.ndarray, str]:
    stamps = np.empty(topic.count, dtype=np.int64)
    values = np.empty((topic.count, 3))
    frame_id = ''
    filled = 0
    for filled, message in enumerate(topic.messages(bar), start=1):
        row = filled - 1
        header = message.header
        stamps[row] = header.stamp.sec * NANOSECONDS + header.stamp.nanosec
        vector = message.vector
        values[row, 0] = vector.x
        values[row, 1] = vector.y
        values[row, 2] = vector.z
        if row == 0:
            frame_id = header.frame_id
        elif check_frame and header.frame_id != frame_id:
            msg = (f'{path}: frame_id on {topic.topic} changes from {frame_id!r} to '
                   f'{header.frame_id!r} at message {filled}; one frame per run is supported')
            raise BagError(msg)
    if filled != topic.count:
        msg = f'{path}: {topic.topic} holds {filled} of the {topic.count} messages its index lists (truncated bag?)'
        raise BagError(msg)
    return stamps, values, frame_id


class _AtomicBag:
    """A Writer into a temporary directory that is renamed to ``path`` on success.

    The overwrite rule of :mod:`tak_thermo_ros.core.files` holds: an existing output is
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
                 storage: str = 'mcap', force: bool = False) -> None:
    """Write a run in the bag contract (messages in stamp order, bag time = header stamp).

    :param force: replace an existing bag at ``path`` (:func:`tak_thermo_ros.core.files.check_output`).
    """
    serialize = TYPESTORE.serialize_cdr
    # Messages in (stamp, stream, row) order, streams 0 temp, 1 ref, 2 counts; as arrays, so that
    # a long run costs a few bytes per message here, not Python tuples.
    parts = (record.temp_stamp_ns, record.reference_stamp_ns, record.counts_stamp_ns)
    stamps = np.concatenate([np.asarray(part, dtype=np.int64) for part in parts])
    streams = np.concatenate([np.full(len(part), stream, dtype=np.int8) for stream, part in enumerate(parts)])
    rows = np.concatenate([np.arange(len(part), dtype=np.int64) for part in parts])
    order = np.lexsort((rows, streams, stamps))
    with _AtomicBag(path, storage, force=force) as writer:
        counts_conn = writer.add_connection(topics.counts, VECTOR3_STAMPED, typestore=TYPESTORE)
        temp_conn = writer.add_connection(topics.temp_code, TEMPERATURE, typestore=TYPESTORE)
        reference_conn = (writer.add_connection(topics.reference, VECTOR3_STAMPED, typestore=TYPESTORE)
                          if record.has_reference else None)
        if record.nominal_scale is not None:
            writer.set_custom_data(NOMINAL_SCALE_KEY, ','.join(repr(float(v)) for v in record.nominal_scale))
        for stamp, stream, row in _chunked(order, stamps, streams, rows):
            header = _header(stamp, record.frame_id)
            if stream == 0:
                message = _Temperature(header=header, temperature=float(record.temp_code[row]), variance=0.0)
                writer.write(temp_conn, stamp, serialize(message, TEMPERATURE))
            elif stream == 1:
                x, y, z = (float(v) for v in record.reference[row])
                message = _Vector3Stamped(header=header, vector=_Vector3(x=x, y=y, z=z))
                writer.write(reference_conn, stamp, serialize(message, VECTOR3_STAMPED))
            else:
                x, y, z = (float(v) for v in record.counts[row])
                message = _Vector3Stamped(header=header, vector=_Vector3(x=x, y=y, z=z))
                writer.write(counts_conn, stamp, serialize(message, VECTOR3_STAMPED))


def write_imu(path: str | os.PathLike[str], stamp_ns: np.ndarray, frame_id: str,
              acceleration: np.ndarray, variance: tuple[float, float, float], *,
              topic: str = Topics.imu, storage: str = 'mcap', force: bool = False) -> None:
    """Write corrected specific force as ``sensor_msgs/msg/Imu`` (REP 103 axes, m/s^2).

    :param force: replace an existing bag at ``path`` (:func:`tak_thermo_ros.core.files.check_output`).
    """
    serialize = TYPESTORE.serialize_cdr
    orientation_cov, angular_cov, linear_cov = (np.array(c) for c in imu_covariances(variance))
    identity = _Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
    zero = _Vector3(x=0.0, y=0.0, z=0.0)
    with _AtomicBag(path, storage, force=force) as writer:
        connection = writer.add_connection(topic, IMU, typestore=TYPESTORE)
        for stamp, (x, y, z) in zip(stamp_ns.tolist(), acceleration.tolist()):
            message = _Imu(header=_header(stamp, frame_id), orientation=identity,
                           orientation_covariance=orientation_cov, angular_velocity=zero,
                           angular_velocity_covariance=angular_cov,
                           linear_acceleration=_Vector3(x=x, y=y, z=z),
                           linear_acceleration_covariance=linear_cov)
            writer.write(connection, stamp, serialize(message, IMU))


def read_imu(path: str | os.PathLike[str], *, topic: str = Topics.imu) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray]:
    """Read an Imu topic: stamps ``(k,)``, linear acceleration ``(k, 3)``, frame ids, covariances ``(k, 9)``."""
    path = Path(path)
    stamps, values, frames, covariances = [], [], [], []
    try:
        with Reader(path) as reader:
            connections = [c for c in reader.connections if c.topic == topic]
            if not connections:
                msg = f'{path}: topic {topic} not found'
                raise BagError(msg)
            for connection, _, raw in reader.messages(connections=connections):
                message = TYPESTORE.deserialize_cdr(raw, connection.msgtype)
                stamps.append(_stamp_ns(message.header))
                acc = message.linear_acceleration
                values.append((acc.x, acc.y, acc.z))
                frames.append(message.header.frame_id)
                covariances.append(np.asarray(message.linear_acceleration_covariance))
    except BagError:
        raise
    except Exception as err:
        msg = f'{path}: cannot read bag ({err})'
        raise BagError(msg) from None
    return (np.asarray(stamps, dtype=np.int64), np.asarray(values).reshape(-1, 3), frames,
            np.asarray(covariances).reshape(-1, 9))
