"""Reading a bag in blocks: what it holds (:func:`bag_streams`), its messages in log order (:func:`iter_blocks`).

The streamed passes (fit, apply, validate) read a long run in bounded memory: one block per
:data:`STREAM_BLOCK_SAMPLES` main-stream messages, each block's raw messages decoded together.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
from rosbags.rosbag2 import Reader

from tak_thermo_ros.formats.bag.contract import (
    AUX_FIELDS,
    IMU,
    MAGNETIC_FIELD,
    TEMPERATURE,
    VECTOR3_STAMPED,
    Topics,
)
from tak_thermo_ros.formats.bag.decoding import (
    _aux_arrays,
    _aux_signal_names,
    _block_arrays,
    _FrameCheck,
    _imu_columns,
    _temperature_columns,
    _vector_columns,
    decode_imus,
    decode_magnetic_fields,
    decode_temperatures,
    decode_vector3_stamped,
    driver_sensors,
)
from tak_thermo_ros.formats.bag.reader import DECODERS, _nominal_scale, _TopicReader, bag_input_kind
from tak_thermo_ros.formats.cdr.decoder import MessageArrays
from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.core.records.record import ChannelRecord, DriverRecord
from tak_thermo_ros.errors import BagError
from tak_thermo_ros.progress import Progress

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
                require_reference: bool = False, kind: InputKind | None = None) -> BagStreams:
    """The kind and message counts of a bag, its topics' types checked, without reading messages.

    A driver bag's temperature is optional (a driver that publishes none): its count is then 0,
    and each pass decides whether it needs one.

    :param kind: its :func:`bag_input_kind`, when known.
    :raises BagError: missing bag or topic, wrong type, an empty main, counts temperature-code or
        (when required) reference topic.
    """
    path = Path(path)
    kind = kind if kind is not None else bag_input_kind(path, topics=topics)
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
                progress: bool = True, decoder: str = 'block',
                streams: BagStreams | None = None) -> Iterator[ChannelRecord | DriverRecord]:
    """The bag's messages in log order, one block per ``block_samples`` main-stream messages.

    Each block holds its main-stream messages and the temperature, reference and auxiliary
    signal messages logged since the previous block, as a :class:`ChannelRecord` (counts bags:
    the metadata's nominal scale attached) or a :class:`DriverRecord` (driver bags), for
    :func:`tak_thermo_ros.core.records.blocks.align_block`. Every block's ``aux`` names every auxiliary
    signal of the bag (empty arrays where the block has none of its messages). The raw messages
    of a block are collected per topic and decoded together.

    :param references: also read the reference topics (``False``: ``apply``).
    :param decoder: one of :data:`DECODERS`: ``block`` (:func:`tak_thermo_ros.formats.cdr.decoder.decode_messages`)
        or ``rosbags`` (``decode_*``, one ``deserialize_cdr`` per message, the reference); both
        give the same blocks.
    :param streams: its :func:`bag_streams`, when known (a :class:`~tak_thermo_ros.formats.records.Record`'s).
    :raises BagError: as the whole-bag readers (missing topic, wrong type, changing frame_id,
        truncated or unreadable file).
    """
    if decoder not in DECODERS:
        msg = f'decoder must be one of {DECODERS}, got {decoder!r}'
        raise ValueError(msg)
    path = Path(path)
    streams = streams if streams is not None else bag_streams(path, topics=topics)
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
