"""Whole-file reading of a bag: its kind, a record's streams into whole arrays, a topic chunk by chunk.

Both rosbags storages (mcap, sqlite3) are read; whatever rosbags or the storage libraries raise
becomes one :class:`~tak_thermo_ros.errors.BagError` naming the bag.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass
from itertools import islice
from pathlib import Path
from typing import Iterator

import numpy as np
from rosbags.rosbag2 import Reader

from tak_thermo_ros.formats.bag.contract import (
    AUX_FIELDS,
    IMU,
    NOMINAL_SCALE_KEY,
    TEMPERATURE,
    TYPESTORE,
    VECTOR3_STAMPED,
    Topics,
)
from tak_thermo_ros.formats.bag.decoding import (
    _aux_arrays,
    _FrameCheck,
    _imu_columns,
    _stamp_ns,
    _temperature_columns,
    _vector_columns,
    decode_imus,
    decode_temperatures,
    decode_vector3_stamped,
    driver_sensors,
)
from tak_thermo_ros.formats.cdr.decoder import MessageArrays, decode_messages
from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.core.records.record import ChannelRecord, DriverRecord
from tak_thermo_ros.errors import BagError, CdrError
from tak_thermo_ros.progress import Progress

DECODERS = ('block', 'rosbags')
"""``block``: raw messages decoded chunk by chunk into arrays (:mod:`tak_thermo_ros.formats.cdr.decoder`);
``rosbags``: one ``deserialize_cdr`` call per message (the reference)."""
CHUNK_MESSAGES = 65536
"""Raw messages the block decoder reads and decodes at once."""


def bag_input_kind(path: str | os.PathLike[str], *, topics: Topics = Topics()) -> InputKind:
    """Which contract a bag follows: the paper's counts topic, or a driver's Imu topic.

    :raises BagError: missing bag, or neither topic in it.
    """
    path = Path(path)
    with _reading(path) as reader:
        names = {c.topic for c in reader.connections}
    if topics.counts in names:
        return InputKind.COUNTS
    if topics.raw_imu in names:
        return InputKind.IMU
    msg = (f'{path}: topic {topics.counts} not found (channel codes), nor {topics.raw_imu} (a driver\'s Imu) '
           f'(topics in the bag: {", ".join(sorted(names)) or "none"})')
    raise BagError(msg)


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

    def batches(self, progress: Progress, chunk: int | None = None) -> Iterator[list[bytes]]:
        """The topic's raw messages ``chunk`` (default :data:`CHUNK_MESSAGES`) at a time."""
        if not self.connections:
            return
        raws = (raw for _, _, raw in self.reader.messages(connections=self.connections))
        while batch := list(islice(raws, chunk or CHUNK_MESSAGES)):
            yield batch
            progress.advance(len(batch))

    def arrays(self, progress: Progress, path: Path, chunk: int | None = None) -> Iterator[MessageArrays]:
        """The topic's messages decoded ``chunk`` (default :data:`CHUNK_MESSAGES`) at a time."""
        first_index = 0
        for batch in self.batches(progress, chunk):
            try:
                arrays = decode_messages(batch, self.msgtype, first_index=first_index)
            except CdrError as err:
                raise CdrError(f'{path}: {self.topic} {err}', err.index) from None
            first_index += len(batch)
            yield arrays


def iter_topic_arrays(source: str | os.PathLike[str] | Reader, topic: str, msgtype: str, *,
                      chunk: int | None = None) -> Iterator[MessageArrays]:
    """Decode one topic of a bag chunk by chunk into arrays (rosbags reads the storage only).

    :param source: a bag directory, or a :class:`rosbags.rosbag2.Reader` that is open.
    :param msgtype: the topic's expected type, one of :data:`tak_thermo_ros.formats.cdr.schema.SCHEMAS`.
    :param chunk: raw messages decoded at once (default :data:`CHUNK_MESSAGES`).
    :returns: one :class:`~tak_thermo_ros.formats.cdr.decoder.MessageArrays` per chunk, in bag order.
    :raises BagError: missing bag or topic, wrong type, malformed message
        (:class:`~tak_thermo_ros.errors.CdrError`), unreadable file.
    """
    if chunk is not None and chunk < 1:
        msg = f'chunk must be at least 1 message, got {chunk}'
        raise ValueError(msg)
    quiet = Progress(0, topic, enabled=False)
    if isinstance(source, Reader):
        path = Path(source.path)
        with _wrapped(path):
            yield from _TopicReader(source, path, topic, msgtype, required=True).arrays(quiet, path, chunk)
    else:
        path = Path(source)
        with _reading(path) as reader:
            yield from _TopicReader(reader, path, topic, msgtype, required=True).arrays(quiet, path, chunk)


@contextlib.contextmanager
def _reading(path: Path, decoder: str = 'block') -> Iterator[Reader]:
    """An open :class:`Reader` of ``path``; whatever rosbags or the storage raise becomes one :class:`BagError`."""
    if decoder not in DECODERS:
        msg = f'decoder must be one of {DECODERS}, got {decoder!r}'
        raise ValueError(msg)
    if not path.exists():
        msg = f'{path}: no such bag'
        raise BagError(msg)
    with _wrapped(path), Reader(path) as reader:
        yield reader


@contextlib.contextmanager
def _wrapped(path: Path) -> Iterator[None]:
    """Whatever rosbags or the storage libraries raise becomes one :class:`BagError` naming ``path``."""
    try:
        yield
    except BagError:
        raise
    except Exception as err:  # rosbags and the storage libraries raise many kinds
        detail = str(err).splitlines()[0] if str(err) else type(err).__name__
        msg = f'{path}: cannot read bag ({detail})'
        raise BagError(msg) from None


def read_record(path: str | os.PathLike[str], *, topics: Topics = Topics(),
                require_reference: bool = False, progress: bool = True,
                decoder: str = 'block') -> ChannelRecord:
    """Read the counts, temperature-code and (optional) reference streams of a bag.

    :param decoder: one of :data:`DECODERS`; both give the same arrays.
    :raises BagError: missing bag or topic, wrong type, empty topic, unreadable or truncated file.
    """
    path = Path(path)
    with _reading(path, decoder) as reader:
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
            counts_stamp, counts, frame_id = _read_vectors(counts_topic, bar, path, check_frame=True,
                                                           decoder=decoder)
            temp_stamp, temp_code = _read_temperatures(temp_topic, bar, path, decoder=decoder)
            reference_stamp, reference, _ = _read_vectors(reference_topic, bar, path, check_frame=False,
                                                          decoder=decoder)
        aux = read_aux_signals(reader, path, exclude=(topics.temp_code,))
    return ChannelRecord(counts_stamp_ns=counts_stamp, counts=counts, temp_stamp_ns=temp_stamp,
                         temp_code=temp_code, reference_stamp_ns=reference_stamp,
                         reference=reference, frame_id=frame_id, nominal_scale=nominal_scale, aux=aux)


def read_driver_record(path: str | os.PathLike[str], *, topics: Topics = Topics(),
                       progress: bool = True, decoder: str = 'block') -> DriverRecord:
    """Read a driver bag: the Imu, the temperature (degrees C; optional) and the optional references.

    :param decoder: one of :data:`DECODERS`; both give the same arrays.

    :raises BagError: missing bag or topic, wrong type, empty topic, a frame_id that changes,
        unreadable or truncated file.
    """
    path = Path(path)
    with _reading(path, decoder) as reader:
        imu_topic = _TopicReader(reader, path, topics.raw_imu, IMU, required=True)
        temp_topic = _TopicReader(reader, path, topics.temperature, TEMPERATURE, required=False)
        reference_topic = _TopicReader(reader, path, topics.reference, VECTOR3_STAMPED, required=False)
        rate_topic = _TopicReader(reader, path, topics.reference_rate, VECTOR3_STAMPED, required=False)
        for topic in (imu_topic,):
            if topic.count == 0:
                msg = f'{path}: no messages on {topic.topic}'
                raise BagError(msg)
        total = imu_topic.count + temp_topic.count + reference_topic.count + rate_topic.count
        with Progress(total, f'reading {path.name}', enabled=None if progress else False) as bar:
            imu = _read_imu_messages(imu_topic, bar, path, decoder=decoder)
            temp_stamp, temperature = _read_temperatures(temp_topic, bar, path, decoder=decoder)
            reference_stamp, reference, _ = _read_vectors(reference_topic, bar, path, check_frame=False,
                                                          decoder=decoder)
            rate_stamp, rate, _ = _read_vectors(rate_topic, bar, path, check_frame=False, decoder=decoder)
        aux = read_aux_signals(reader, path, exclude=(topics.temperature,))
    stamps, accel, gyro, orientation, orientation_covariance, frame_id, accel_mark, gyro_mark = imu
    return DriverRecord(stamp_ns=stamps, orientation=orientation,
                        orientation_covariance=orientation_covariance, temp_stamp_ns=temp_stamp,
                        temperature=temperature, reference_stamp_ns=reference_stamp, reference=reference,
                        rate_reference_stamp_ns=rate_stamp, rate_reference=rate, frame_id=frame_id, aux=aux,
                        **driver_sensors(stamps, accel, gyro, accel_mark, gyro_mark))


def read_aux_signals(reader: Reader, path: Path, *,
                     exclude: tuple[str, ...] = ()) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every auxiliary scalar signal of an open bag: name -> ``(stamp_ns, values)``.

    Each topic of a type in :data:`AUX_FIELDS` (except the topics in ``exclude``, e.g. the
    temperature in use) gives ``aux:TOPIC`` (its obvious number) and ``aux:TOPIC:FIELD`` for its
    other numeric fields. Stamps are the header stamps, or the bag time for a type without a
    header (``std_msgs``). Decoded by the block decoder (:mod:`tak_thermo_ros.formats.cdr.decoder`).
    """
    by_topic: dict[str, list] = {}
    for connection in reader.connections:
        if connection.topic not in exclude and connection.msgtype in AUX_FIELDS:
            by_topic.setdefault(connection.topic, []).append(connection)
    signals: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for topic, connections in sorted(by_topic.items()):
        msgtype = connections[0].msgtype
        if any(c.msgtype != msgtype for c in connections):
            types = ', '.join(sorted({c.msgtype for c in connections}))
            msg = f'{path}: topic {topic} has more than one type ({types})'
            raise BagError(msg)
        bag_times, raws = [], []
        for _, timestamp, raw in reader.messages(connections=connections):
            bag_times.append(timestamp)
            raws.append(raw)
        if not raws:
            continue
        signals.update(_aux_arrays(path, topic, msgtype, raws, bag_times))
    return signals


def _read_imu_messages(topic: _TopicReader, bar: Progress, path: Path, *, decoder: str):
    """The Imu topic as :func:`decode_imus`'s columns (one frame_id per run), chunk by chunk into whole arrays."""
    count = topic.count
    stamps = np.empty(count, dtype=np.int64)
    accel = np.empty((count, 3))
    gyro = np.empty((count, 3))
    orientation = np.empty((count, 4))
    orientation_covariance = np.empty((count, 9))
    accel_mark = np.empty(count)
    gyro_mark = np.empty(count)
    frames = _FrameCheck(path, topic.topic)
    filled = 0
    chunks = topic.arrays(bar, path) if decoder == 'block' else topic.batches(bar)
    for chunk in chunks:
        rows = _fill_rows(topic, path, filled, len(chunk))
        (stamps[rows], accel[rows], gyro[rows], orientation[rows], orientation_covariance[rows], frame_ids,
         accel_mark[rows], gyro_mark[rows]) = _imu_columns(chunk) if decoder == 'block' else decode_imus(chunk)
        frames.check(frame_ids)
        filled = rows.stop
    _check_filled(topic, path, filled)
    return stamps, accel, gyro, orientation, orientation_covariance, frames.frame_id or '', accel_mark, gyro_mark


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


def _read_temperatures(topic: _TopicReader, bar: Progress, path: Path, *,
                       decoder: str) -> tuple[np.ndarray, np.ndarray]:
    temp_stamp = np.empty(topic.count, dtype=np.int64)
    temp_code = np.empty(topic.count)
    filled = 0
    chunks = topic.arrays(bar, path) if decoder == 'block' else topic.batches(bar)
    for chunk in chunks:
        rows = _fill_rows(topic, path, filled, len(chunk))
        temp_stamp[rows], temp_code[rows] = (_temperature_columns(chunk) if decoder == 'block'
                                             else decode_temperatures(chunk))
        filled = rows.stop
    _check_filled(topic, path, filled)
    return temp_stamp, temp_code


def _fill_rows(topic: _TopicReader, path: Path, filled: int, count: int) -> slice:
    """Rows ``filled`` to ``filled + count`` of a topic's arrays, refused beyond the index's count."""
    if filled + count > topic.count:
        msg = f'{path}: {topic.topic} holds more than the {topic.count} messages its index lists'
        raise BagError(msg)
    return slice(filled, filled + count)


def _check_filled(topic: _TopicReader, path: Path, filled: int) -> None:
    """Refuse a topic that holds fewer messages than its index lists."""
    if filled != topic.count:
        msg = f'{path}: {topic.topic} holds {filled} of the {topic.count} messages its index lists (truncated bag?)'
        raise BagError(msg)


def _read_vectors(topic: _TopicReader, bar: Progress, path: Path, *,
                  check_frame: bool, decoder: str = 'rosbags') -> tuple[np.ndarray, np.ndarray, str]:
    """Stamps, vectors and (``check_frame``: one per run, else not read) the frame_id of a Vector3Stamped topic."""
    stamps = np.empty(topic.count, dtype=np.int64)
    values = np.empty((topic.count, 3))
    frames = _FrameCheck(path, topic.topic)
    filled = 0
    chunks = topic.arrays(bar, path) if decoder == 'block' else topic.batches(bar)
    for chunk in chunks:
        rows = _fill_rows(topic, path, filled, len(chunk))
        stamps[rows], values[rows], frame_ids = (_vector_columns(chunk) if decoder == 'block'
                                                 else decode_vector3_stamped(chunk))
        if check_frame:
            frames.check(frame_ids)
        filled = rows.stop
    _check_filled(topic, path, filled)
    return stamps, values, frames.frame_id or ''


def read_imu(path: str | os.PathLike[str], *,
             topic: str = Topics.imu) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray]:
    """Read an Imu topic: stamps ``(k,)``, linear acceleration ``(k, 3)``, frame ids, covariances ``(k, 9)``."""
    messages = read_imu_messages(path, topic=topic)
    return (messages.stamp_ns, messages.linear_acceleration, messages.frame_ids,
            messages.linear_acceleration_covariance)


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
    with _reading(path) as reader:
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
    columns = list(zip(*rows)) if rows else [()] * 8
    return ImuMessages(stamp_ns=np.asarray(columns[0], dtype=np.int64), frame_ids=list(columns[1]),
                       orientation=np.asarray(columns[2], dtype=float).reshape(-1, 4),
                       orientation_covariance=np.asarray(columns[3], dtype=float).reshape(-1, 9),
                       angular_velocity=np.asarray(columns[4], dtype=float).reshape(-1, 3),
                       angular_velocity_covariance=np.asarray(columns[5], dtype=float).reshape(-1, 9),
                       linear_acceleration=np.asarray(columns[6], dtype=float).reshape(-1, 3),
                       linear_acceleration_covariance=np.asarray(columns[7], dtype=float).reshape(-1, 9))
