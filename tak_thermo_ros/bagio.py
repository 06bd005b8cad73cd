"""Bag I/O: the only module that imports rosbags.

The bag contract (each topic name is an option):

- ``/tak/counts``: ``geometry_msgs/msg/Vector3Stamped``, x, y, z = channel codes N.
- ``/tak/temp_code``: ``sensor_msgs/msg/Temperature``, ``temperature`` = raw code N_t.
- ``/tak/reference``: ``geometry_msgs/msg/Vector3Stamped``, true specific force (m/s^2),
  calibration runs only, published at least whenever it changes.
- ``/tak/imu/data_raw``: ``sensor_msgs/msg/Imu`` written by ``apply``.

Both rosbag2 storages (mcap, sqlite3) are read; bags are written to a temporary directory
beside the target and renamed into place, so a failed write leaves nothing behind.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from tak_thermo_ros.core.correction import imu_covariances
from tak_thermo_ros.core.model import InputKind
from tak_thermo_ros.core.record import NANOSECONDS, ChannelRecord, DriverRecord
from tak_thermo_ros.errors import BagError
from tak_thermo_ros.progress import Progress

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
VECTOR3_STAMPED = 'geometry_msgs/msg/Vector3Stamped'
TEMPERATURE = 'sensor_msgs/msg/Temperature'
IMU = 'sensor_msgs/msg/Imu'
NOMINAL_SCALE_KEY = 'tak_thermo_ros.nominal_scale'
"""Bag metadata ``custom_data`` key: nominal K0 per axis as ``'x,y,z'`` (counts per m/s^2)."""
STORAGES = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}

_Header = TYPESTORE.types['std_msgs/msg/Header']
_Time = TYPESTORE.types['builtin_interfaces/msg/Time']
_Vector3 = TYPESTORE.types['geometry_msgs/msg/Vector3']
_Vector3Stamped = TYPESTORE.types[VECTOR3_STAMPED]
_Quaternion = TYPESTORE.types['geometry_msgs/msg/Quaternion']
_Temperature = TYPESTORE.types[TEMPERATURE]
_Imu = TYPESTORE.types[IMU]


@dataclass(frozen=True)
class Topics:
    """Topic names of the bag contract (counts input) and of a driver bag (Imu input)."""

    counts: str = '/tak/counts'
    temp_code: str = '/tak/temp_code'
    reference: str = '/tak/reference'
    imu: str = '/tak/imu/data_raw'
    raw_imu: str = '/imu/data_raw'
    temperature: str = '/imu/temperature'
    reference_rate: str = '/tak/reference_rate'
    compensated_imu: str = '/imu/data_compensated'


def bag_input_kind(path: str | os.PathLike[str], *, topics: Topics = Topics()) -> InputKind:
    """Which contract a bag follows: the paper's counts topic, or a driver's Imu topic.

    :raises BagError: missing bag, or neither topic in it.
    """
    path = Path(path)
    if not path.exists():
        msg = f'{path}: no such bag'
        raise BagError(msg)
    try:
        with Reader(path) as reader:
            names = {c.topic for c in reader.connections}
    except Exception as err:  # rosbags and the storage libraries raise many kinds
        detail = str(err).splitlines()[0] if str(err) else type(err).__name__
        msg = f'{path}: cannot read bag ({detail})'
        raise BagError(msg) from None
    if topics.counts in names:
        return InputKind.COUNTS
    if topics.raw_imu in names:
        return InputKind.IMU
    msg = (f'{path}: topic {topics.counts} not found (channel codes), nor {topics.raw_imu} (a driver\'s Imu) '
           f'(topics in the bag: {", ".join(sorted(names)) or "none"})')
    raise BagError(msg)


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


def read_driver_record(path: str | os.PathLike[str], *, topics: Topics = Topics(),
                       progress: bool = True) -> DriverRecord:
    """Read a driver bag: the Imu, the temperature (degrees C) and the optional references.

    :raises BagError: missing bag or topic, wrong type, empty topic, a frame_id that changes,
        unreadable or truncated file.
    """
    path = Path(path)
    if not path.exists():
        msg = f'{path}: no such bag'
        raise BagError(msg)
    try:
        with Reader(path) as reader:
            imu_topic = _TopicReader(reader, path, topics.raw_imu, IMU, required=True)
            temp_topic = _TopicReader(reader, path, topics.temperature, TEMPERATURE, required=True)
            reference_topic = _TopicReader(reader, path, topics.reference, VECTOR3_STAMPED, required=False)
            rate_topic = _TopicReader(reader, path, topics.reference_rate, VECTOR3_STAMPED, required=False)
            for topic in (imu_topic, temp_topic):
                if topic.count == 0:
                    msg = f'{path}: no messages on {topic.topic}'
                    raise BagError(msg)
            total = imu_topic.count + temp_topic.count + reference_topic.count + rate_topic.count
            with Progress(total, f'reading {path.name}', enabled=None if progress else False) as bar:
                imu = _read_imu_messages(imu_topic, bar, path)
                temp_stamp, temperature = _read_temperatures(temp_topic, bar, path)
                reference_stamp, reference, _ = _read_vectors(reference_topic, bar, path, check_frame=False)
                rate_stamp, rate, _ = _read_vectors(rate_topic, bar, path, check_frame=False)
    except BagError:
        raise
    except Exception as err:  # rosbags and the storage libraries raise many kinds
        detail = str(err).splitlines()[0] if str(err) else type(err).__name__
        msg = f'{path}: cannot read bag ({detail})'
        raise BagError(msg) from None
    stamps, accel, gyro, orientation, orientation_covariance, frame_id = imu
    return DriverRecord(stamp_ns=stamps, accel=accel, gyro=gyro, orientation=orientation,
                        orientation_covariance=orientation_covariance, temp_stamp_ns=temp_stamp,
                        temperature=temperature, reference_stamp_ns=reference_stamp, reference=reference,
                        rate_reference_stamp_ns=rate_stamp, rate_reference=rate, frame_id=frame_id)


def _read_temperatures(topic: _TopicReader, bar: Progress, path: Path) -> tuple[np.ndarray, np.ndarray]:
    stamps = np.empty(topic.count, dtype=np.int64)
    values = np.empty(topic.count)
    filled = 0
    for filled, message in enumerate(topic.messages(bar), start=1):
        stamps[filled - 1] = _stamp_ns(message.header)
        values[filled - 1] = message.temperature
    if filled != topic.count:
        msg = f'{path}: {topic.topic} holds {filled} of the {topic.count} messages its index lists (truncated bag?)'
        raise BagError(msg)
    return stamps, values


def _read_imu_messages(topic: _TopicReader, bar: Progress, path: Path):
    count = topic.count
    stamps = np.empty(count, dtype=np.int64)
    accel = np.empty((count, 3))
    gyro = np.empty((count, 3))
    orientation = np.empty((count, 4))
    orientation_covariance = np.empty((count, 9))
    frame_id = ''
    filled = 0
    for filled, message in enumerate(topic.messages(bar), start=1):
        row = filled - 1
        header = message.header
        stamps[row] = header.stamp.sec * NANOSECONDS + header.stamp.nanosec
        acc = message.linear_acceleration
        rate = message.angular_velocity
        quaternion = message.orientation
        accel[row] = (acc.x, acc.y, acc.z)
        gyro[row] = (rate.x, rate.y, rate.z)
        orientation[row] = (quaternion.x, quaternion.y, quaternion.z, quaternion.w)
        orientation_covariance[row] = message.orientation_covariance
        if row == 0:
            frame_id = header.frame_id
        elif header.frame_id != frame_id:
            msg = (f'{path}: frame_id on {topic.topic} changes from {frame_id!r} to '
                   f'{header.frame_id!r} at message {filled}; one frame per run is supported')
            raise BagError(msg)
    if filled != count:
        msg = f'{path}: {topic.topic} holds {filled} of the {count} messages its index lists (truncated bag?)'
        raise BagError(msg)
    return stamps, accel, gyro, orientation, orientation_covariance, frame_id


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
    """A Writer into a temporary directory that is renamed to ``path`` on success."""

    def __init__(self, path: str | os.PathLike[str], storage: str) -> None:
        self.path = Path(path)
        if storage not in STORAGES:
            msg = f'unknown storage {storage!r} (mcap or sqlite3)'
            raise BagError(msg)
        if self.path.exists():
            msg = f'{self.path}: exists already, not overwriting'
            raise BagError(msg)
        parent = self.path.parent
        if not parent.is_dir():
            msg = f'{self.path}: directory {parent} does not exist'
            raise BagError(msg)
        self.staging = Path(tempfile.mkdtemp(prefix=f'.{self.path.name}.', suffix='.partial', dir=parent))
        # rosbags writes the bag *into* a path that must not exist yet; its files are named after it.
        self.inner = self.staging / self.path.name
        self.writer = Writer(self.inner, version=9, storage_plugin=STORAGES[storage])

    def __enter__(self) -> Writer:
        self.writer.open()
        return self.writer

    def __exit__(self, exc_type, exc, traceback) -> None:
        try:
            self.writer.close()
            if exc_type is None:
                os.rename(self.inner, self.path)
        finally:
            shutil.rmtree(self.staging, ignore_errors=True)


def write_record(path: str | os.PathLike[str], record: ChannelRecord, *, topics: Topics = Topics(),
                 storage: str = 'mcap') -> None:
    """Write a run in the bag contract (messages in stamp order, bag time = header stamp)."""
    serialize = TYPESTORE.serialize_cdr
    events: list[tuple[int, int, int]] = []  # (stamp, stream, row): streams 0 temp, 1 ref, 2 counts
    events += [(int(s), 0, i) for i, s in enumerate(record.temp_stamp_ns)]
    events += [(int(s), 1, i) for i, s in enumerate(record.reference_stamp_ns)]
    events += [(int(s), 2, i) for i, s in enumerate(record.counts_stamp_ns)]
    events.sort()
    with _AtomicBag(path, storage) as writer:
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
            else:
                x, y, z = (float(v) for v in record.counts[row])
                message = _Vector3Stamped(header=header, vector=_Vector3(x=x, y=y, z=z))
                writer.write(counts_conn, stamp, serialize(message, VECTOR3_STAMPED))


def write_driver_record(path: str | os.PathLike[str], record: DriverRecord, *, topics: Topics = Topics(),
                        storage: str = 'mcap') -> None:
    """Write a driver run (Imu, temperature in C, references if any) in stamp order."""
    serialize = TYPESTORE.serialize_cdr
    events: list[tuple[int, int, int]] = []  # (stamp, stream, row): 0 temperature, 1 ref, 2 rate ref, 3 Imu
    events += [(int(s), 0, i) for i, s in enumerate(record.temp_stamp_ns)]
    events += [(int(s), 1, i) for i, s in enumerate(record.reference_stamp_ns)]
    events += [(int(s), 2, i) for i, s in enumerate(record.rate_reference_stamp_ns)]
    events += [(int(s), 3, i) for i, s in enumerate(record.stamp_ns)]
    events.sort()
    zero_covariance = np.zeros(9)
    with _AtomicBag(path, storage) as writer:
        imu_conn = writer.add_connection(topics.raw_imu, IMU, typestore=TYPESTORE)
        temp_conn = writer.add_connection(topics.temperature, TEMPERATURE, typestore=TYPESTORE)
        reference_conn = (writer.add_connection(topics.reference, VECTOR3_STAMPED, typestore=TYPESTORE)
                          if len(record.reference_stamp_ns) else None)
        rate_conn = (writer.add_connection(topics.reference_rate, VECTOR3_STAMPED, typestore=TYPESTORE)
                     if len(record.rate_reference_stamp_ns) else None)
        for stamp, stream, row in events:
            header = _header(stamp, record.frame_id)
            if stream == 0:
                message = _Temperature(header=header, temperature=float(record.temperature[row]), variance=0.0)
                writer.write(temp_conn, stamp, serialize(message, TEMPERATURE))
            elif stream in (1, 2):
                values = record.reference if stream == 1 else record.rate_reference
                x, y, z = (float(v) for v in values[row])
                message = _Vector3Stamped(header=header, vector=_Vector3(x=x, y=y, z=z))
                writer.write(reference_conn if stream == 1 else rate_conn, stamp,
                             serialize(message, VECTOR3_STAMPED))
            else:
                qx, qy, qz, qw = (float(v) for v in record.orientation[row])
                ax, ay, az = (float(v) for v in record.accel[row])
                gx, gy, gz = (float(v) for v in record.gyro[row])
                message = _Imu(header=header, orientation=_Quaternion(x=qx, y=qy, z=qz, w=qw),
                               orientation_covariance=np.asarray(record.orientation_covariance[row], dtype=float),
                               angular_velocity=_Vector3(x=gx, y=gy, z=gz),
                               angular_velocity_covariance=zero_covariance,
                               linear_acceleration=_Vector3(x=ax, y=ay, z=az),
                               linear_acceleration_covariance=zero_covariance)
                writer.write(imu_conn, stamp, serialize(message, IMU))


def write_imu(path: str | os.PathLike[str], stamp_ns: np.ndarray, frame_id: str,
              acceleration: np.ndarray, variance: tuple[float, float, float], *,
              topic: str = Topics.imu, storage: str = 'mcap', angular_velocity: np.ndarray | None = None,
              angular_variance: tuple[float, float, float] | None = None,
              orientation: np.ndarray | None = None, orientation_covariance: np.ndarray | None = None) -> None:
    """Write corrected samples as ``sensor_msgs/msg/Imu`` (REP 103 axes, m/s^2, rad/s).

    Counts input: the specific force only, orientation and angular velocity marked not
    provided (:func:`~tak_thermo_ros.core.correction.imu_covariances`). Driver input: also the
    corrected angular velocity, and the driver's orientation and its covariance passed through
    per message.
    """
    with _AtomicBag(path, storage) as writer:
        connection = writer.add_connection(topic, IMU, typestore=TYPESTORE)
        _write_imu_messages(writer, connection, stamp_ns, frame_id, acceleration, variance,
                            angular_velocity=angular_velocity, angular_variance=angular_variance,
                            orientation=orientation, orientation_covariance=orientation_covariance)


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


@dataclass(frozen=True)
class ImuMessages:
    """An Imu topic read back as arrays (what ``apply`` wrote, or what the node published).

    :param stamp_ns: ``(k,)`` header stamps.
    :param frame_ids: frame of each message.
    :param orientation: ``(k, 4)`` ``(x, y, z, w)``.
    :param orientation_covariance: ``(k, 9)``.
    :param angular_velocity: ``(k, 3)`` rad/s.
    :param angular_velocity_covariance: ``(k, 9)``.
    :param linear_acceleration: ``(k, 3)`` m/s^2.
    :param linear_acceleration_covariance: ``(k, 9)``.
    """

    stamp_ns: np.ndarray
    frame_ids: list[str]
    orientation: np.ndarray
    orientation_covariance: np.ndarray
    angular_velocity: np.ndarray
    angular_velocity_covariance: np.ndarray
    linear_acceleration: np.ndarray
    linear_acceleration_covariance: np.ndarray


def read_imu_messages(path: str | os.PathLike[str], *, topic: str) -> ImuMessages:
    """Every field of an Imu topic that the correction touches or passes through."""
    path = Path(path)
    rows: list[tuple] = []
    try:
        with Reader(path) as reader:
            connections = [c for c in reader.connections if c.topic == topic]
            if not connections:
                msg = f'{path}: topic {topic} not found'
                raise BagError(msg)
            for connection, _, raw in reader.messages(connections=connections):
                m = TYPESTORE.deserialize_cdr(raw, connection.msgtype)
                q, w, a = m.orientation, m.angular_velocity, m.linear_acceleration
                rows.append((_stamp_ns(m.header), m.header.frame_id, (q.x, q.y, q.z, q.w),
                             np.asarray(m.orientation_covariance), (w.x, w.y, w.z),
                             np.asarray(m.angular_velocity_covariance), (a.x, a.y, a.z),
                             np.asarray(m.linear_acceleration_covariance)))
    except BagError:
        raise
    except Exception as err:
        msg = f'{path}: cannot read bag ({err})'
        raise BagError(msg) from None
    columns = list(zip(*rows)) if rows else [()] * 8
    return ImuMessages(stamp_ns=np.asarray(columns[0], dtype=np.int64), frame_ids=list(columns[1]),
                       orientation=np.asarray(columns[2], dtype=float).reshape(-1, 4),
                       orientation_covariance=np.asarray(columns[3], dtype=float).reshape(-1, 9),
                       angular_velocity=np.asarray(columns[4], dtype=float).reshape(-1, 3),
                       angular_velocity_covariance=np.asarray(columns[5], dtype=float).reshape(-1, 9),
                       linear_acceleration=np.asarray(columns[6], dtype=float).reshape(-1, 3),
                       linear_acceleration_covariance=np.asarray(columns[7], dtype=float).reshape(-1, 9))


# ----- streaming: blocks of messages in log order, and an Imu writer that stays open ----------

STREAM_BLOCK_SAMPLES = 65536
"""Main-stream messages per block of :func:`iter_blocks`."""


@dataclass(frozen=True)
class BagStreams:
    """What a bag holds for a streamed read: its kind and the message count of each stream.

    :param kind: the paper's counts topic, or a driver's Imu.
    :param main: messages on the counts (or Imu) topic.
    :param temperature: messages on the temperature topic.
    :param reference: messages on the specific-force reference topic (0 when absent).
    :param rate_reference: messages on the rate reference topic (driver bags; 0 when absent).
    :param nominal_scale: the bag metadata's nominal K0 (counts bags), or ``None``.
    """

    kind: InputKind
    main: int
    temperature: int
    reference: int
    rate_reference: int
    nominal_scale: tuple[float, float, float] | None


def _stream_topics(kind: InputKind, topics: Topics) -> list[tuple[str, str, str]]:
    """``(role, topic, type)`` of the streams a streamed read takes, main stream first."""
    if kind is InputKind.COUNTS:
        return [('main', topics.counts, VECTOR3_STAMPED), ('temperature', topics.temp_code, TEMPERATURE),
                ('reference', topics.reference, VECTOR3_STAMPED)]
    return [('main', topics.raw_imu, IMU), ('temperature', topics.temperature, TEMPERATURE),
            ('reference', topics.reference, VECTOR3_STAMPED),
            ('rate_reference', topics.reference_rate, VECTOR3_STAMPED)]


def _cannot_read(path: Path, err: Exception) -> BagError:
    detail = str(err).splitlines()[0] if str(err) else type(err).__name__
    return BagError(f'{path}: cannot read bag ({detail})')


def bag_streams(path: str | os.PathLike[str], *, topics: Topics = Topics(),
                require_reference: bool = False) -> BagStreams:
    """The kind and message counts of a bag, its topics' types checked, without reading messages.

    :raises BagError: missing bag or topic, wrong type, an empty main, temperature or (when
        required) reference topic.
    """
    path = Path(path)
    kind = bag_input_kind(path, topics=topics)
    try:
        with Reader(path) as reader:
            counts = {}
            for role, topic, msgtype in _stream_topics(kind, topics):
                required = role in ('main', 'temperature') or (role == 'reference' and require_reference)
                stream = _TopicReader(reader, path, topic, msgtype, required=required)
                if required and stream.count == 0:
                    msg = f'{path}: no messages on {topic}'
                    raise BagError(msg)
                counts[role] = stream.count
            nominal_scale = _nominal_scale(reader, path) if kind is InputKind.COUNTS else None
    except BagError:
        raise
    except Exception as err:  # rosbags and the storage libraries raise many kinds
        raise _cannot_read(path, err) from None
    return BagStreams(kind=kind, main=counts['main'], temperature=counts['temperature'],
                      reference=counts['reference'], rate_reference=counts.get('rate_reference', 0),
                      nominal_scale=nominal_scale)


def decode_vector3_stamped(raws: list[bytes]) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Stamps ``(k,)``, vectors ``(k, 3)`` and frame ids of serialised ``Vector3Stamped`` messages."""
    deserialize = TYPESTORE.deserialize_cdr
    stamps, values, frames = [], [], []
    for raw in raws:
        message = deserialize(raw, VECTOR3_STAMPED)
        header = message.header
        stamps.append(header.stamp.sec * NANOSECONDS + header.stamp.nanosec)
        vector = message.vector
        values.append((vector.x, vector.y, vector.z))
        frames.append(header.frame_id)
    return np.array(stamps, dtype=np.int64), np.array(values, dtype=float).reshape(-1, 3), frames


def decode_temperatures(raws: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """Stamps ``(k,)`` and values ``(k,)`` of serialised ``Temperature`` messages."""
    deserialize = TYPESTORE.deserialize_cdr
    stamps, values = [], []
    for raw in raws:
        message = deserialize(raw, TEMPERATURE)
        stamps.append(_stamp_ns(message.header))
        values.append(message.temperature)
    return np.array(stamps, dtype=np.int64), np.array(values, dtype=float)


def decode_imus(raws: list[bytes]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """Stamps, accel ``(k, 3)``, gyro ``(k, 3)``, orientation ``(k, 4)``, its covariance ``(k, 9)``, frame ids."""
    deserialize = TYPESTORE.deserialize_cdr
    count = len(raws)
    stamps = np.empty(count, dtype=np.int64)
    accel = np.empty((count, 3))
    gyro = np.empty((count, 3))
    orientation = np.empty((count, 4))
    covariance = np.empty((count, 9))
    frames = []
    for row, raw in enumerate(raws):
        message = deserialize(raw, IMU)
        header = message.header
        stamps[row] = header.stamp.sec * NANOSECONDS + header.stamp.nanosec
        acc, rate, quaternion = message.linear_acceleration, message.angular_velocity, message.orientation
        accel[row] = (acc.x, acc.y, acc.z)
        gyro[row] = (rate.x, rate.y, rate.z)
        orientation[row] = (quaternion.x, quaternion.y, quaternion.z, quaternion.w)
        covariance[row] = message.orientation_covariance
        frames.append(header.frame_id)
    return stamps, accel, gyro, orientation, covariance, frames


class _FrameCheck:
    """One frame_id per run on the main stream, as the whole-bag readers require."""

    def __init__(self, path: Path, topic: str) -> None:
        self.path, self.topic = path, topic
        self.frame_id: str | None = None
        self.seen = 0

    def check(self, frames: list[str]) -> str:
        if frames and self.frame_id is None:
            self.frame_id = frames[0]
        for offset, frame in enumerate(frames):
            if frame != self.frame_id:
                msg = (f'{self.path}: frame_id on {self.topic} changes from {self.frame_id!r} to '
                       f'{frame!r} at message {self.seen + offset + 1}; one frame per run is supported')
                raise BagError(msg)
        self.seen += len(frames)
        return self.frame_id or ''


def iter_blocks(path: str | os.PathLike[str], *, topics: Topics = Topics(), kind: InputKind,
                block_samples: int = STREAM_BLOCK_SAMPLES, references: bool = True,
                progress: bool = True) -> Iterator[ChannelRecord | DriverRecord]:
    """The bag's messages in log order, one block per ``block_samples`` main-stream messages.

    Each block holds its main-stream messages and the temperature and reference messages
    logged since the previous block, as a :class:`ChannelRecord` (counts bags: the
    metadata's nominal scale attached) or a :class:`DriverRecord` (driver bags), for
    :func:`tak_thermo_ros.core.blocks.align_block`. The raw messages of a block are collected
    per topic and decoded together (``decode_*``), so that a decoder of whole chunks can take
    the place of the per-message one.

    :param references: also read the reference topics (``False``: ``apply``).
    :raises BagError: as the whole-bag readers (missing topic, wrong type, changing frame_id,
        truncated or unreadable file).
    """
    path = Path(path)
    streams = bag_streams(path, topics=topics)
    roles = [(role, topic, msgtype) for role, topic, msgtype in _stream_topics(kind, topics)
             if references or role in ('main', 'temperature')]
    try:
        with Reader(path) as reader:
            by_connection = {}
            for role, topic, _ in roles:
                for connection in reader.connections:
                    if connection.topic == topic:
                        by_connection[connection.id] = role
            connections = [c for c in reader.connections if c.id in by_connection]
            frames = _FrameCheck(path, roles[0][1])
            total = sum(c.msgcount for c in connections)
            read_main = 0
            raws: dict[str, list[bytes]] = {role: [] for role, _, _ in roles}
            with Progress(total, f'reading {path.name}', enabled=None if progress else False) as bar:
                for connection, _, raw in reader.messages(connections=connections):
                    role = by_connection[connection.id]
                    bucket = raws[role]
                    bucket.append(raw)
                    if role == 'main' and len(bucket) == block_samples:
                        read_main += len(bucket)
                        bar.advance(sum(len(v) for v in raws.values()))
                        yield _decode_block(kind, raws, frames, streams.nominal_scale)
                        raws = {r: [] for r in raws}
                read_main += len(raws['main'])
                yield _decode_block(kind, raws, frames, streams.nominal_scale)
    except BagError:
        raise
    except Exception as err:  # rosbags and the storage libraries raise many kinds
        raise _cannot_read(path, err) from None
    if read_main != streams.main:
        msg = f'{path}: {roles[0][1]} holds {read_main} of the {streams.main} messages its index lists (truncated bag?)'
        raise BagError(msg)


def _decode_block(kind: InputKind, raws: dict[str, list[bytes]], frames: _FrameCheck,
                  nominal_scale: tuple[float, float, float] | None) -> ChannelRecord | DriverRecord:
    temp_stamp, temperature = decode_temperatures(raws['temperature'])
    reference_stamp, reference, _ = decode_vector3_stamped(raws.get('reference', []))
    if kind is InputKind.COUNTS:
        stamps, counts, frame_ids = decode_vector3_stamped(raws['main'])
        return ChannelRecord(counts_stamp_ns=stamps, counts=counts, temp_stamp_ns=temp_stamp, temp_code=temperature,
                             reference_stamp_ns=reference_stamp, reference=reference,
                             frame_id=frames.check(frame_ids), nominal_scale=nominal_scale)
    stamps, accel, gyro, orientation, covariance, frame_ids = decode_imus(raws['main'])
    rate_stamp, rate, _ = decode_vector3_stamped(raws.get('rate_reference', []))
    return DriverRecord(stamp_ns=stamps, accel=accel, gyro=gyro, orientation=orientation,
                        orientation_covariance=covariance, temp_stamp_ns=temp_stamp, temperature=temperature,
                        reference_stamp_ns=reference_stamp, reference=reference,
                        rate_reference_stamp_ns=rate_stamp, rate_reference=rate, frame_id=frames.check(frame_ids))


class ImuBagWriter:
    """An Imu bag written block by block (``apply`` streaming), atomically as :func:`write_imu`.

    Use as a context manager; :meth:`write` takes the arguments of :func:`write_imu` for one
    block of samples. The bag appears at ``path`` only when the block ``with`` ends without
    an exception.
    """

    def __init__(self, path: str | os.PathLike[str], *, topic: str = Topics.imu, storage: str = 'mcap') -> None:
        self._bag = _AtomicBag(path, storage)
        self._topic = topic
        self._writer: Writer | None = None
        self._connection = None
        self.written = 0

    def __enter__(self) -> ImuBagWriter:
        self._writer = self._bag.__enter__()
        self._connection = self._writer.add_connection(self._topic, IMU, typestore=TYPESTORE)
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        self._bag.__exit__(exc_type, exc, traceback)

    def write(self, stamp_ns: np.ndarray, frame_id: str, acceleration: np.ndarray,
              variance: tuple[float, float, float], *, angular_velocity: np.ndarray | None = None,
              angular_variance: tuple[float, float, float] | None = None, orientation: np.ndarray | None = None,
              orientation_covariance: np.ndarray | None = None) -> None:
        """Append one block of corrected samples (see :func:`write_imu`)."""
        assert self._writer is not None, 'ImuBagWriter.write outside its with block'
        _write_imu_messages(self._writer, self._connection, stamp_ns, frame_id, acceleration, variance,
                            angular_velocity=angular_velocity, angular_variance=angular_variance,
                            orientation=orientation, orientation_covariance=orientation_covariance)
        self.written += len(stamp_ns)


def _write_imu_messages(writer: Writer, connection, stamp_ns: np.ndarray, frame_id: str, acceleration: np.ndarray,
                        variance: tuple[float, float, float], *, angular_velocity: np.ndarray | None,
                        angular_variance: tuple[float, float, float] | None, orientation: np.ndarray | None,
                        orientation_covariance: np.ndarray | None) -> None:
    serialize = TYPESTORE.serialize_cdr
    orientation_cov, angular_cov, linear_cov = (np.array(c) for c in imu_covariances(variance, angular_variance))
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
                       angular_velocity_covariance=angular_cov,
                       linear_acceleration=_Vector3(x=x, y=y, z=z),
                       linear_acceleration_covariance=linear_cov)
        writer.write(connection, stamp, serialize(message, IMU))
