"""Block encoding of CDR messages: a block of messages of one type serialised at once, as rosbags serialises them.

One template message per set of strings (its numbers zero, laid out by the alignment rule of
:func:`~tak_thermo_ros.formats.cdr.schema._layout` and read back with it as a check), copied
once per message, the numbers written column by column.
"""

from __future__ import annotations

import struct
import sys
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from tak_thermo_ros.formats.cdr.schema import _NUMPY, _SIZE, NANOSECONDS, Field, _align, _layout, schema
from tak_thermo_ros.errors import CdrError


@dataclass(frozen=True)
class _Template:
    """One serialised message of a fixed layout.

    Its bytes with every number zero, and where the numbers lie (byte offsets from the start of the raw message, as
    :func:`_layout` finds them).
    """

    row: np.ndarray
    numbers: dict[str, tuple[Field, int]]


def _template(msgtype: str, strings: tuple[tuple[str, bytes], ...], little_endian: bool) -> _Template:
    """The template of ``msgtype`` whose string fields hold ``strings`` (name, UTF-8 bytes).

    Laid out by the alignment rule of :func:`_layout` (each field aligned to its own size counted
    from the end of the encapsulation header), then read back with :func:`_layout` as a check.
    """
    fields = schema(msgtype)
    texts = dict(strings)
    uint32 = struct.Struct('<I' if little_endian else '>I')
    body = bytearray()
    for field in fields:
        if field.kind == 'seq_f4':
            msg = f'no block encoder for {msgtype} (sequence field {field.name})'
            raise CdrError(msg, -1)
        if field.kind == 'string':
            body += bytes(_align(len(body), 4) - len(body))
            text = texts[field.name]
            body += uint32.pack(len(text) + 1) + text + b'\0'
        else:
            item = _SIZE[field.kind]
            body += bytes(_align(len(body), item) - len(body)) + bytes(item * field.count)
    raw = bytes((0, 1 if little_endian else 0, 0, 0)) + bytes(body)
    layout = _layout(raw, fields, 0)
    read_back = [(field.name, count) for field, _, count in layout.strings]
    if layout.little_endian != little_endian or read_back != [(name, len(text)) for name, text in strings]:
        msg = f'{msgtype}: the encoder template does not read back as laid out'
        raise AssertionError(msg)
    numbers = {field.name: (field, offset) for field, offset in layout.numbers}
    return _Template(np.frombuffer(raw, dtype=np.uint8), numbers)


def encode_messages(msgtype: str, stamp_ns: np.ndarray | None, values: dict[str, np.ndarray | Sequence[float] | float],
                    strings: dict[str, str] | None = None, *,
                    little_endian: bool = sys.byteorder == 'little') -> list[bytes]:
    """Serialise a block of messages of one type and one set of strings, as rosbags' ``serialize_cdr`` does.

    (the same bytes, padding zero).

    :param msgtype: one of :data:`SCHEMAS` without sequence fields.
    :param stamp_ns: ``(k,)`` header stamps (ns) of a stamped type (None otherwise); the
        header holds ``divmod(stamp_ns, 10**9)`` as ``sec`` and ``nanosec``.
    :param values: every numeric field except the stamp: an ``(k, n)`` (or ``(k,)``) array of
        per-message values, or an ``(n,)`` array (a scalar for a scalar field) shared by all.
    :param strings: every string field (``frame_id``), one value shared by all messages.
    :param little_endian: byte order of the output (rosbags' default: the machine's).
    :returns: ``k`` serialised messages, each with its 4-byte encapsulation header.
    :raises CdrError: a stamp's seconds do not fit ``int32``, or a field is missing.
    """
    fields = schema(msgtype)
    strings = strings or {}
    try:
        encoded = tuple((f.name, strings[f.name].encode()) for f in fields if f.kind == 'string')
    except KeyError as err:
        msg = f'{msgtype}: string field {err.args[0]} not given'
        raise CdrError(msg, -1) from None
    template = _template(msgtype, encoded, little_endian)
    order = '<' if little_endian else '>'
    count = None if stamp_ns is None else len(stamp_ns)
    per_message: list[tuple[Field, int, np.ndarray]] = []
    row = template.row.copy()
    columns = dict(values)
    if 'stamp_sec' in template.numbers:
        if stamp_ns is None:
            msg = f'{msgtype}: stamps not given'
            raise CdrError(msg, -1)
        stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
        sec, nanosec = np.divmod(stamp_ns, NANOSECONDS)
        outside = np.flatnonzero((sec < np.iinfo(np.int32).min) | (sec > np.iinfo(np.int32).max))
        if outside.size:
            index = int(outside[0])
            msg = f'message {index + 1}: stamp {int(stamp_ns[index])} ns: seconds outside int32'
            raise CdrError(msg, index)
        columns['stamp_sec'], columns['stamp_nanosec'] = sec, nanosec
    for name, (field, offset) in template.numbers.items():
        if name not in columns:
            msg = f'{msgtype}: field {name} not given'
            raise CdrError(msg, -1)
        dtype = np.dtype(_NUMPY[field.kind]).newbyteorder(order)
        column = np.asarray(columns[name])
        shared = () if field.count == 1 else (field.count,)
        if column.shape == shared:  # the same in every message: into the template
            row[offset:offset + _SIZE[field.kind] * field.count] = np.ascontiguousarray(
                column, dtype=dtype).reshape(-1).view(np.uint8)
            continue
        if count is None:
            count = len(column)
        if column.shape != (count, *shared):
            msg = f'{msgtype}: field {name} has shape {column.shape}, expected {(count, *shared)} or {shared}'
            raise CdrError(msg, -1)
        per_message.append((field, offset, np.ascontiguousarray(column, dtype=dtype).reshape(count, field.count)))
    count = count or 0
    block = np.empty((count, len(row)), dtype=np.uint8)
    block[:] = row
    for field, offset, column in per_message:
        block[:, offset:offset + _SIZE[field.kind] * field.count] = column.view(np.uint8)
    size = len(row)
    return block.view(f'V{size}').reshape(count).tolist()  # one bytes object per row


def encode_imus(stamp_ns: np.ndarray, frame_id: str, *, orientation: np.ndarray | Sequence[float],
                orientation_covariance: np.ndarray | Sequence[float], angular_velocity: np.ndarray | Sequence[float],
                angular_velocity_covariance: np.ndarray | Sequence[float],
                linear_acceleration: np.ndarray | Sequence[float],
                linear_acceleration_covariance: np.ndarray | Sequence[float],
                little_endian: bool = sys.byteorder == 'little') -> list[bytes]:
    """Serialise a block of ``sensor_msgs/msg/Imu`` of one frame (:func:`encode_messages`).

    :param stamp_ns: ``(k,)`` header stamps (ns).
    :param orientation: ``(k, 4)`` ``(x, y, z, w)`` per message, or ``(4,)`` shared.
    :param orientation_covariance: ``(k, 9)`` or ``(9,)``.
    :param angular_velocity: ``(k, 3)`` or ``(3,)``.
    :param angular_velocity_covariance: ``(k, 9)`` or ``(9,)``.
    :param linear_acceleration: ``(k, 3)`` or ``(3,)``.
    :param linear_acceleration_covariance: ``(k, 9)`` or ``(9,)``.
    :returns: ``k`` messages, byte for byte what rosbags' ``serialize_cdr`` gives.
    """
    values = {'orientation': orientation, 'orientation_covariance': orientation_covariance,
              'angular_velocity': angular_velocity, 'angular_velocity_covariance': angular_velocity_covariance,
              'linear_acceleration': linear_acceleration,
              'linear_acceleration_covariance': linear_acceleration_covariance}
    return encode_messages('sensor_msgs/msg/Imu', stamp_ns, values, {'frame_id': frame_id},
                           little_endian=little_endian)
