"""Serialised messages into arrays, shared by the whole-file reader and the block stream.

The reference decoders (``decode_*``: one rosbags ``deserialize_cdr`` per message), the block
decoder's columns (:func:`tak_thermo_ros.formats.cdr.decoder.decode_messages` arrays in the same shape),
a driver record's sensors from the Imu messages' marks, the one-frame-per-run check, and the
auxiliary signals of one topic.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tak_thermo_ros.formats.bag.contract import AUX_FIELDS, IMU, MAGNETIC_FIELD, TEMPERATURE, TYPESTORE, VECTOR3_STAMPED
from tak_thermo_ros.formats.cdr.decoder import MessageArrays, decode_messages
from tak_thermo_ros.core.link.correction import NOT_PROVIDED
from tak_thermo_ros.core.records.record import NANOSECONDS
from tak_thermo_ros.errors import BagError, CdrError


def _stamp_ns(header) -> int:
    return header.stamp.sec * NANOSECONDS + header.stamp.nanosec


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
