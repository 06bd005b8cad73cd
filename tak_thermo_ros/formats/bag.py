"""Bag I/O: the only module that imports rosbags.

The bag contract (each topic name is an option):

- ``/tak/counts``: ``geometry_msgs/msg/Vector3Stamped``, x, y, z = channel codes N.
- ``/tak/temp_code``: ``sensor_msgs/msg/Temperature``, ``temperature`` = raw code N_t.
- ``/tak/reference``: ``geometry_msgs/msg/Vector3Stamped``, true specific force (m/s^2),
  calibration runs only, published at least whenever it changes.
- ``/tak/imu/data_raw``: ``sensor_msgs/msg/Imu`` written by ``apply``.
- any other topic of a type in :data:`AUX_FIELDS` (a supply voltage, a pressure, a plain
  ``std_msgs`` number): an auxiliary signal ``aux:TOPIC`` (its obvious number) or
  ``aux:TOPIC:FIELD`` (another numeric field), read into the record's ``aux``. A stamped message
  is placed at its header stamp; a ``std_msgs`` number, which has no header, at its bag time.

Both rosbag2 storages (mcap, sqlite3) are read; bags are written to a temporary directory
beside the target and renamed into place, so a failed write leaves nothing behind; an existing
output is refused unless ``force`` (:mod:`tak_thermo_ros.formats.files`).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sqlite3
from dataclasses import dataclass
from itertools import islice
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from rosbags.rosbag2 import Reader, StoragePlugin, Writer, WriterError
from rosbags.typesys import Stores, get_typestore

from tak_thermo_ros.formats.cdr import MessageArrays, decode_messages, encode_imus, encode_messages
from tak_thermo_ros.core.effects import aux_signal
from tak_thermo_ros.core.link.correction import NOT_PROVIDED, NOT_PROVIDED_COVARIANCE, imu_covariances
from tak_thermo_ros.formats.files import BAG, check_output, install_directory, staging_directory
from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.core.records.record import NANOSECONDS, ChannelRecord, DriverRecord, rows_at, sensor_messages
from tak_thermo_ros.errors import BagError, CdrError, OutputError
from tak_thermo_ros.progress import Progress

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
VECTOR3_STAMPED = 'geometry_msgs/msg/Vector3Stamped'
TEMPERATURE = 'sensor_msgs/msg/Temperature'
IMU = 'sensor_msgs/msg/Imu'
MAGNETIC_FIELD = 'sensor_msgs/msg/MagneticField'
NOMINAL_SCALE_KEY = 'tak_thermo_ros.nominal_scale'
"""Bag metadata ``custom_data`` key: nominal K0 per axis as ``'x,y,z'`` (counts per m/s^2)."""
STORAGES = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
DECODERS = ('block', 'rosbags')
"""``block``: raw messages decoded chunk by chunk into arrays (:mod:`tak_thermo_ros.formats.cdr`);
``rosbags``: one ``deserialize_cdr`` call per message (the reference)."""
ENCODERS = ('block', 'rosbags')
"""``block``: a block of Imu messages serialised at once into arrays (:func:`tak_thermo_ros.formats.cdr.encode_imus`);
``rosbags``: one message object and one ``serialize_cdr`` call per message (the reference). Both
give the same bytes."""
IMU_ENCODER = 'block'
"""The encoder :func:`write_imu` and :class:`ImuBagWriter` use unless told otherwise."""
CHUNK_MESSAGES = 65536
"""Raw messages the block decoder reads and decodes at once."""
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
AUX_FIELDS = aux_signal.AUX_FIELDS
AUX_TYPES = {'battery_state': BATTERY_STATE, 'float64': FLOAT64}
"""Message types a simulated auxiliary signal can be written as (scenario ``record_supply_type``)."""


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
    mag: str = '/imu/mag'
    reference_field: str = '/tak/reference_field'
    compensated_mag: str = '/imu/mag_compensated'
    instance: int = 0
    """A flight log's sensor instance (PX4 ``multi_id``, ArduPilot ``I``); a bag has none."""


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
    :param msgtype: the topic's expected type, one of :data:`tak_thermo_ros.formats.cdr.SCHEMAS`.
    :param chunk: raw messages decoded at once (default :data:`CHUNK_MESSAGES`).
    :returns: one :class:`~tak_thermo_ros.formats.cdr.MessageArrays` per chunk, in bag order.
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
    header (``std_msgs``). Decoded by the block decoder (:mod:`tak_thermo_ros.formats.cdr`).
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


def _aux_signal_names(topic: str, msgtype: str) -> list[str]:
    """The signal names a topic of an auxiliary type gives, its obvious number first."""
    from tak_thermo_ros.core.effects.aux_signal import signal_name
    return [signal_name(topic, '' if position == 0 else field) for position, field in enumerate(AUX_FIELDS[msgtype])]


def _aux_arrays(path: Path, topic: str, msgtype: str, raws: list[bytes],
                bag_times: list[int]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Name -> ``(stamp_ns, values)`` of one auxiliary topic's raw messages (header stamp, or bag time)."""
    try:
        arrays = decode_messages(raws, msgtype)
    except CdrError as err:
        raise CdrError(f'{path}: {topic} {err}', err.index) from None
    stamps = arrays['stamp_ns'] if 'stamp_ns' in arrays.fields else np.asarray(bag_times, dtype=np.int64)
    stamps = np.asarray(stamps, dtype=np.int64)
    return {name: (stamps, np.asarray(arrays[field], dtype=float))
            for name, field in zip(_aux_signal_names(topic, msgtype), AUX_FIELDS[msgtype])}


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


# ----- streaming: blocks of messages in log order, and an Imu writer that stays open ----------

STREAM_BLOCK_SAMPLES = 65536
"""Main-stream messages per block of :func:`iter_blocks`."""


@dataclass(frozen=True)
class BagStreams:
    """What a bag holds for a streamed read: its kind and the message count of each stream.

    :param kind: the paper's counts topic, or a driver's Imu.
    :param main: messages on the counts (or Imu) topic.
    :param temperature: messages on the temperature topic (a driver bag may hold none: 0).
    :param reference: messages on the specific-force reference topic (0 when absent).
    :param rate_reference: messages on the rate reference topic (driver bags; 0 when absent).
    :param nominal_scale: the bag metadata's nominal K0 (counts bags), or ``None``.
    :param mag: messages on the magnetometer topic (driver bags; 0 when absent).
    :param mag_reference: messages on the reference field topic (0 when absent).
    :param end_ns: when its last message was logged (a flight log: its last sample's stamp); 0: unknown.
    """

    kind: InputKind
    main: int
    temperature: int
    reference: int
    rate_reference: int
    nominal_scale: tuple[float, float, float] | None
    mag: int = 0
    mag_reference: int = 0
    end_ns: int = 0


def _stream_topics(kind: InputKind, topics: Topics) -> list[tuple[str, str, str]]:
    """``(role, topic, type)`` of the streams a streamed read takes, main stream first."""
    if kind is InputKind.COUNTS:
        return [('main', topics.counts, VECTOR3_STAMPED), ('temperature', topics.temp_code, TEMPERATURE),
                ('reference', topics.reference, VECTOR3_STAMPED)]
    return [('main', topics.raw_imu, IMU), ('temperature', topics.temperature, TEMPERATURE),
            ('reference', topics.reference, VECTOR3_STAMPED),
            ('rate_reference', topics.reference_rate, VECTOR3_STAMPED),
            ('mag', topics.mag, MAGNETIC_FIELD), ('mag_reference', topics.reference_field, VECTOR3_STAMPED)]


def _cannot_read(path: Path, err: Exception) -> BagError:
    detail = str(err).splitlines()[0] if str(err) else type(err).__name__
    return BagError(f'{path}: cannot read bag ({detail})')


def bag_streams(path: str | os.PathLike[str], *, topics: Topics = Topics(),
                require_reference: bool = False) -> BagStreams:
    """The kind and message counts of a bag, its topics' types checked, without reading messages.

    A driver bag's temperature is optional (a driver that publishes none): its count is then 0,
    and each pass decides whether it needs one.

    :raises BagError: missing bag or topic, wrong type, an empty main, counts temperature-code or
        (when required) reference topic.
    """
    path = Path(path)
    kind = bag_input_kind(path, topics=topics)
    try:
        with Reader(path) as reader:
            counts = {}
            for role, topic, msgtype in _stream_topics(kind, topics):
                required = (role == 'main' or (role == 'temperature' and kind is InputKind.COUNTS)
                            or (role == 'reference' and require_reference))
                stream = _TopicReader(reader, path, topic, msgtype, required=required)
                if required and stream.count == 0:
                    msg = f'{path}: no messages on {topic}'
                    raise BagError(msg)
                counts[role] = stream.count
            nominal_scale = _nominal_scale(reader, path) if kind is InputKind.COUNTS else None
            end_ns = int(reader.end_time)
    except BagError:
        raise
    except Exception as err:  # rosbags and the storage libraries raise many kinds
        raise _cannot_read(path, err) from None
    return BagStreams(kind=kind, main=counts['main'], temperature=counts['temperature'],
                      reference=counts['reference'], rate_reference=counts.get('rate_reference', 0),
                      nominal_scale=nominal_scale, mag=counts.get('mag', 0),
                      mag_reference=counts.get('mag_reference', 0), end_ns=end_ns)


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


def decode_imus(raws: list[bytes]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[str],
                                            np.ndarray, np.ndarray]:
    """Stamps, accel ``(k, 3)``, gyro ``(k, 3)``, orientation ``(k, 4)``, its covariance ``(k, 9)``, frame ids.

    Then the first element of the linear-acceleration and angular-velocity covariances, ``(k,)``
    each: -1 marks a message that carries no such sample (:func:`driver_sensors`).
    """
    deserialize = TYPESTORE.deserialize_cdr
    count = len(raws)
    stamps = np.empty(count, dtype=np.int64)
    accel = np.empty((count, 3))
    gyro = np.empty((count, 3))
    orientation = np.empty((count, 4))
    covariance = np.empty((count, 9))
    accel_mark = np.empty(count)
    gyro_mark = np.empty(count)
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
        accel_mark[row] = message.linear_acceleration_covariance[0]
        gyro_mark[row] = message.angular_velocity_covariance[0]
        frames.append(header.frame_id)
    return stamps, accel, gyro, orientation, covariance, frames, accel_mark, gyro_mark


def driver_sensors(stamps: np.ndarray, accel: np.ndarray, gyro: np.ndarray, accel_mark: np.ndarray,
                   gyro_mark: np.ndarray) -> dict[str, Any]:
    """A driver record's sensor fields from Imu messages, each sensor on its own stamps where they differ.

    A message whose linear-acceleration (angular-velocity) covariance[0] is -1 carries no
    accelerometer (gyroscope) sample: that sensor has its own stamps then, the messages that
    carry it (``DriverRecord.accel_stamp_ns``, ``gyro_stamp_ns``). Where every message carries
    both, both share the messages' stamps.
    """
    accel_present = np.asarray(accel_mark) != NOT_PROVIDED
    gyro_present = np.asarray(gyro_mark) != NOT_PROVIDED
    if accel_present.all() and gyro_present.all():
        return {'accel': accel, 'gyro': gyro}
    return {'accel': accel[accel_present], 'gyro': gyro[gyro_present],
            'accel_stamp_ns': stamps[accel_present], 'gyro_stamp_ns': stamps[gyro_present]}


class _FrameCheck:
    """One frame_id per run on the main stream, as the whole-bag readers require."""

    def __init__(self, path: Path, topic: str) -> None:
        self.path, self.topic = path, topic
        self.frame_id: str | None = None
        self.seen = 0

    def check(self, frames: list[str] | MessageArrays) -> str:
        if isinstance(frames, MessageArrays):
            codes, labels = frames['frame_id'], frames.labels['frame_id']
            if len(labels) == 1 and (self.frame_id is None or labels[0] == self.frame_id):
                self.frame_id = labels[0]
                self.seen += len(codes)
                return self.frame_id
            frames = frames.strings('frame_id')
        if frames and self.frame_id is None:
            self.frame_id = frames[0]
        for offset, frame in enumerate(frames):
            if frame != self.frame_id:
                msg = (f'{self.path}: frame_id on {self.topic} changes from {self.frame_id!r} to '
                       f'{frame!r} at message {self.seen + offset + 1}; one frame per run is supported')
                raise BagError(msg)
        self.seen += len(frames)
        return self.frame_id or ''


def _aux_topics(reader: Reader, path: Path, exclude: tuple[str, ...]) -> dict[str, str]:
    """Topic -> type of the auxiliary signal topics of an open bag (as :func:`read_aux_signals`)."""
    types: dict[str, set[str]] = {}
    for connection in reader.connections:
        if connection.topic not in exclude and connection.msgtype in AUX_FIELDS:
            types.setdefault(connection.topic, set()).add(connection.msgtype)
    for topic, found in types.items():
        if len(found) > 1:
            msg = f'{path}: topic {topic} has more than one type ({", ".join(sorted(found))})'
            raise BagError(msg)
    return {topic: next(iter(found)) for topic, found in sorted(types.items())}


def iter_blocks(path: str | os.PathLike[str], *, topics: Topics = Topics(), kind: InputKind,
                block_samples: int = STREAM_BLOCK_SAMPLES, references: bool = True,
                progress: bool = True, decoder: str = 'block') -> Iterator[ChannelRecord | DriverRecord]:
    """The bag's messages in log order, one block per ``block_samples`` main-stream messages.

    Each block holds its main-stream messages and the temperature, reference and auxiliary
    signal messages logged since the previous block, as a :class:`ChannelRecord` (counts bags:
    the metadata's nominal scale attached) or a :class:`DriverRecord` (driver bags), for
    :func:`tak_thermo_ros.core.records.blocks.align_block`. Every block's ``aux`` names every auxiliary
    signal of the bag (empty arrays where the block has none of its messages). The raw messages
    of a block are collected per topic and decoded together.

    :param references: also read the reference topics (``False``: ``apply``).
    :param decoder: one of :data:`DECODERS`: ``block`` (:func:`tak_thermo_ros.formats.cdr.decode_messages`)
        or ``rosbags`` (``decode_*``, one ``deserialize_cdr`` per message, the reference); both
        give the same blocks.
    :raises BagError: as the whole-bag readers (missing topic, wrong type, changing frame_id,
        truncated or unreadable file).
    """
    if decoder not in DECODERS:
        msg = f'decoder must be one of {DECODERS}, got {decoder!r}'
        raise ValueError(msg)
    path = Path(path)
    streams = bag_streams(path, topics=topics)
    roles = [(role, topic, msgtype) for role, topic, msgtype in _stream_topics(kind, topics)
             if references or role in ('main', 'temperature', 'mag')]
    temperature_topic = topics.temp_code if kind is InputKind.COUNTS else topics.temperature
    try:
        with Reader(path) as reader:
            by_connection: dict[int, str] = {}
            for role, topic, _ in roles:
                for connection in reader.connections:
                    if connection.topic == topic:
                        by_connection[connection.id] = role
            aux_topics = _aux_topics(reader, path, (temperature_topic,))
            for connection in reader.connections:
                if connection.topic in aux_topics and connection.id not in by_connection:
                    by_connection[connection.id] = f'aux {connection.topic}'
            connections = [c for c in reader.connections if c.id in by_connection]
            frames = _FrameCheck(path, roles[0][1])
            mag_frames = _FrameCheck(path, topics.mag)
            names = {role: topic for role, topic, _ in roles}
            total = sum(c.msgcount for c in connections)
            read_main = 0
            buckets = [role for role, _, _ in roles] + [f'aux {topic}' for topic in aux_topics]
            raws: dict[str, list[bytes]] = {role: [] for role in buckets}
            bag_times: dict[str, list[int]] = {role: [] for role in buckets}
            with Progress(total, f'reading {path.name}', enabled=None if progress else False) as bar:
                for connection, timestamp, raw in reader.messages(connections=connections):
                    role = by_connection[connection.id]
                    bucket = raws[role]
                    bucket.append(raw)
                    bag_times[role].append(timestamp)
                    if role == 'main' and len(bucket) == block_samples:
                        read_main += len(bucket)
                        bar.advance(sum(len(v) for v in raws.values()))
                        yield _decode_block(path, kind, raws, bag_times, aux_topics, frames, streams.nominal_scale,
                                            decoder, names, mag_frames)
                        raws = {r: [] for r in buckets}
                        bag_times = {r: [] for r in buckets}
                read_main += len(raws['main'])
                yield _decode_block(path, kind, raws, bag_times, aux_topics, frames, streams.nominal_scale, decoder,
                                    names, mag_frames)
    except BagError:
        raise
    except Exception as err:  # rosbags and the storage libraries raise many kinds
        raise _cannot_read(path, err) from None
    if read_main != streams.main:
        msg = f'{path}: {roles[0][1]} holds {read_main} of the {streams.main} messages its index lists (truncated bag?)'
        raise BagError(msg)


def _block_arrays(path: Path, raws: list[bytes], msgtype: str, topic: str) -> MessageArrays:
    try:
        return decode_messages(raws, msgtype)
    except CdrError as err:
        raise CdrError(f'{path}: {topic} {err}', err.index) from None


def _vector_columns(arrays: MessageArrays) -> tuple[np.ndarray, np.ndarray, MessageArrays]:
    """:func:`decode_vector3_stamped`'s columns of block-decoded ``Vector3Stamped`` messages (frames: the arrays)."""
    return np.asarray(arrays['stamp_ns'], dtype=np.int64), np.asarray(arrays['vector'], dtype=float), arrays


def _temperature_columns(arrays: MessageArrays) -> tuple[np.ndarray, np.ndarray]:
    """:func:`decode_temperatures`'s columns of block-decoded ``Temperature`` messages."""
    return np.asarray(arrays['stamp_ns'], dtype=np.int64), np.asarray(arrays['temperature'], dtype=float)


def _imu_columns(arrays: MessageArrays) -> tuple:
    """:func:`decode_imus`'s columns of block-decoded ``Imu`` messages (frames: the arrays)."""
    return (np.asarray(arrays['stamp_ns'], dtype=np.int64), np.asarray(arrays['linear_acceleration'], dtype=float),
            np.asarray(arrays['angular_velocity'], dtype=float), np.asarray(arrays['orientation'], dtype=float),
            np.asarray(arrays['orientation_covariance'], dtype=float), arrays,
            np.asarray(arrays['linear_acceleration_covariance'], dtype=float).reshape(-1, 9)[:, 0],
            np.asarray(arrays['angular_velocity_covariance'], dtype=float).reshape(-1, 9)[:, 0])


def _decode_vectors(path: Path, raws: list[bytes], topic: str,
                    decoder: str) -> tuple[np.ndarray, np.ndarray, list[str] | MessageArrays]:
    if decoder == 'rosbags' or not raws:
        return decode_vector3_stamped(raws)
    return _vector_columns(_block_arrays(path, raws, VECTOR3_STAMPED, topic))


def _decode_block(path: Path, kind: InputKind, raws: dict[str, list[bytes]], bag_times: dict[str, list[int]],
                  aux_topics: dict[str, str], frames: _FrameCheck, nominal_scale: tuple[float, float, float] | None,
                  decoder: str, names: dict[str, str], mag_frames: _FrameCheck | None = None
                  ) -> ChannelRecord | DriverRecord:
    temperature_raws = raws['temperature']
    if decoder == 'rosbags' or not temperature_raws:
        temp_stamp, temperature = decode_temperatures(temperature_raws)
    else:
        temp_stamp, temperature = _temperature_columns(
            _block_arrays(path, temperature_raws, TEMPERATURE, names['temperature']))
    reference_stamp, reference, _ = _decode_vectors(path, raws.get('reference', []), names.get('reference', ''),
                                                    decoder)
    aux: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for topic, msgtype in aux_topics.items():
        role = f'aux {topic}'
        if raws[role]:
            aux.update(_aux_arrays(path, topic, msgtype, raws[role], bag_times[role]))
        else:
            aux.update({name: (np.zeros(0, dtype=np.int64), np.zeros(0))
                        for name in _aux_signal_names(topic, msgtype)})
    if kind is InputKind.COUNTS:
        stamps, counts, frame_ids = _decode_vectors(path, raws['main'], names['main'], decoder)
        return ChannelRecord(counts_stamp_ns=stamps, counts=counts, temp_stamp_ns=temp_stamp, temp_code=temperature,
                             reference_stamp_ns=reference_stamp, reference=reference,
                             frame_id=frames.check(frame_ids), nominal_scale=nominal_scale, aux=aux)
    if decoder == 'rosbags' or not raws['main']:
        stamps, accel, gyro, orientation, covariance, frame_ids, accel_mark, gyro_mark = decode_imus(raws['main'])
    else:
        stamps, accel, gyro, orientation, covariance, frame_ids, accel_mark, gyro_mark = _imu_columns(
            _block_arrays(path, raws['main'], IMU, names['main']))
    rate_stamp, rate, _ = _decode_vectors(path, raws.get('rate_reference', []), names.get('rate_reference', ''),
                                          decoder)
    mag_stamp, mag, mag_frame = _decode_mag(path, raws.get('mag', []), names.get('mag', ''), decoder, mag_frames)
    field_stamp, field, _ = _decode_vectors(path, raws.get('mag_reference', []), names.get('mag_reference', ''),
                                            decoder)
    return DriverRecord(stamp_ns=stamps, orientation=orientation, orientation_covariance=covariance,
                        temp_stamp_ns=temp_stamp, temperature=temperature,
                        reference_stamp_ns=reference_stamp, reference=reference,
                        rate_reference_stamp_ns=rate_stamp, rate_reference=rate, frame_id=frames.check(frame_ids),
                        aux=aux, mag_stamp_ns=mag_stamp, mag=mag, mag_reference_stamp_ns=field_stamp,
                        mag_reference=field, mag_frame_id=mag_frame,
                        **driver_sensors(stamps, accel, gyro, accel_mark, gyro_mark))


def decode_magnetic_fields(raws: list[bytes]) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Stamps ``(k,)``, fields ``(k, 3)`` (tesla) and frame ids of serialised ``MagneticField`` messages."""
    deserialize = TYPESTORE.deserialize_cdr
    stamps, values, frames = [], [], []
    for raw in raws:
        message = deserialize(raw, MAGNETIC_FIELD)
        stamps.append(_stamp_ns(message.header))
        vector = message.magnetic_field
        values.append((vector.x, vector.y, vector.z))
        frames.append(message.header.frame_id)
    return np.array(stamps, dtype=np.int64), np.array(values, dtype=float).reshape(-1, 3), frames


def _decode_mag(path: Path, raws: list[bytes], topic: str, decoder: str,
                frames: _FrameCheck | None) -> tuple[np.ndarray, np.ndarray, str]:
    """A block's magnetometer messages: stamps, fields (tesla), the frame (one per run)."""
    if decoder == 'rosbags' or not raws:
        stamps, values, frame_ids = decode_magnetic_fields(raws)
    else:
        arrays = _block_arrays(path, raws, MAGNETIC_FIELD, topic)
        stamps, values = (np.asarray(arrays['stamp_ns'], dtype=np.int64),
                          np.asarray(arrays['magnetic_field'], dtype=float))
        frame_ids = arrays
    if frames is None:
        return stamps, values, ''
    if not raws:
        return stamps, values, frames.frame_id or ''
    return stamps, values, frames.check(frame_ids)


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
