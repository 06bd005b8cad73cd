"""CDR messages one at a time: the schemas, a message's layout checked as rosbags checks it, the reference decoder.

A rosbag2 topic stores each message as its CDR bytes: a 4-byte encapsulation header (``00 01``
little endian, ``00 00`` big endian, two option bytes) followed by the fields, each aligned to
its own size counted from the end of the encapsulation header. :data:`SCHEMAS` names the fields
of each message type the package reads, in CDR order; :func:`_layout` finds where they lie in one
message and refuses what rosbags' ``deserialize_cdr`` refuses (bad encapsulation, truncated, bad
string or sequence length, missing terminator, more than 3 trailing bytes) with a
:class:`~tak_thermo_ros.errors.CdrError`; :func:`decode_message` reads one message with
:mod:`struct` (the reference for the block decoder, :mod:`tak_thermo_ros.formats.cdr.decoder`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.errors import CdrError

NANOSECONDS = 1_000_000_000
ENCAPSULATION_BYTES = 4
TRAILING_BYTES_ALLOWED = 3
"""rosbags accepts up to 3 bytes after the last field (padding to a multiple of 4)."""
_STRUCT = {'f8': 'd', 'f4': 'f', 'i1': 'b', 'u1': 'B', 'i2': 'h', 'u2': 'H', 'i4': 'i', 'u4': 'I',
           'i8': 'q', 'u8': 'Q', 'bool': '?'}
_SIZE = {kind: struct.calcsize(code) for kind, code in _STRUCT.items()}
_NUMPY = {'f8': np.float64, 'f4': np.float32, 'i1': np.int8, 'u1': np.uint8, 'i2': np.int16,
          'u2': np.uint16, 'i4': np.int32, 'u4': np.uint32, 'i8': np.int64, 'u8': np.uint64,
          'bool': np.bool_}


@dataclass(frozen=True)
class Field:
    """One field of a message in CDR order.

    :param kind: a primitive (``'f8'``, ``'f4'``, ``'i1'`` ... ``'u8'``, ``'bool'``), ``'string'``
        or ``'seq_f4'`` (a ``float32[]`` sequence).
    :param count: number of elements of a fixed-size array (1 for a scalar).
    """

    name: str
    kind: str
    count: int = 1


_HEADER = (Field('stamp_sec', 'i4'), Field('stamp_nanosec', 'u4'), Field('frame_id', 'string'))


def _data(kind: str) -> tuple[Field, ...]:
    return (Field('data', kind),)


SCHEMAS: dict[str, tuple[Field, ...]] = {
    'geometry_msgs/msg/Vector3Stamped': (*_HEADER, Field('vector', 'f8', 3)),
    'sensor_msgs/msg/Temperature': (*_HEADER, Field('temperature', 'f8'), Field('variance', 'f8')),
    'sensor_msgs/msg/Imu': (
        *_HEADER, Field('orientation', 'f8', 4), Field('orientation_covariance', 'f8', 9),
        Field('angular_velocity', 'f8', 3), Field('angular_velocity_covariance', 'f8', 9),
        Field('linear_acceleration', 'f8', 3), Field('linear_acceleration_covariance', 'f8', 9)),
    'sensor_msgs/msg/MagneticField': (*_HEADER, Field('magnetic_field', 'f8', 3),
                                      Field('magnetic_field_covariance', 'f8', 9)),
    'sensor_msgs/msg/FluidPressure': (*_HEADER, Field('fluid_pressure', 'f8'), Field('variance', 'f8')),
    'sensor_msgs/msg/RelativeHumidity': (*_HEADER, Field('relative_humidity', 'f8'),
                                         Field('variance', 'f8')),
    'sensor_msgs/msg/BatteryState': (
        *_HEADER, Field('voltage', 'f4'), Field('temperature', 'f4'), Field('current', 'f4'),
        Field('charge', 'f4'), Field('capacity', 'f4'), Field('design_capacity', 'f4'),
        Field('percentage', 'f4'), Field('power_supply_status', 'u1'),
        Field('power_supply_health', 'u1'), Field('power_supply_technology', 'u1'),
        Field('present', 'bool'), Field('cell_voltage', 'seq_f4'),
        Field('cell_temperature', 'seq_f4'), Field('location', 'string'),
        Field('serial_number', 'string')),
    'std_msgs/msg/Float32': _data('f4'),
    'std_msgs/msg/Float64': _data('f8'),
    'std_msgs/msg/Int8': _data('i1'),
    'std_msgs/msg/Int16': _data('i2'),
    'std_msgs/msg/Int32': _data('i4'),
    'std_msgs/msg/Int64': _data('i8'),
    'std_msgs/msg/UInt8': _data('u1'),
    'std_msgs/msg/UInt16': _data('u2'),
    'std_msgs/msg/UInt32': _data('u4'),
    'std_msgs/msg/UInt64': _data('u8'),
}
"""The message types the block decoder knows, field by field in CDR order."""


def schema(msgtype: str) -> tuple[Field, ...]:
    """Fields of ``msgtype`` in CDR order.

    :raises CdrError: the type is not one of :data:`SCHEMAS`.
    """
    try:
        return SCHEMAS[msgtype]
    except KeyError:
        known = ', '.join(sorted(SCHEMAS))
        msg = f'no block decoder for {msgtype} (known: {known})'
        raise CdrError(msg, -1) from None


@dataclass(frozen=True)
class _Layout:
    """Where the fields of one message lie (byte offsets from the start of the raw message)."""

    little_endian: bool
    numbers: tuple[tuple[Field, int], ...]
    strings: tuple[tuple[Field, int, int], ...]  # (field, first byte, byte count without NUL)
    sequences: tuple[tuple[Field, int, int], ...]  # (field, first element byte, element count)
    structural: tuple[int, ...]  # bytes every message of this layout must share


def _fail(index: int, reason: str) -> CdrError:
    """The error of message ``index`` (``-1``: a message on its own, not named by a position)."""
    return CdrError(reason if index < 0 else f'message {index + 1}: {reason}', index)


def _align(position: int, size: int) -> int:
    return (position + size - 1) // size * size


def _layout(raw: bytes, fields: tuple[Field, ...], index: int) -> _Layout:
    """The layout of one message, checked as rosbags checks it.

    :raises CdrError: the message is malformed or truncated.
    """
    if len(raw) < ENCAPSULATION_BYTES or raw[0] != 0 or raw[1] not in (0, 1):
        raise _fail(index, f'invalid or unsupported CDR encapsulation {bytes(raw[:4]).hex() or "(empty)"}')
    little_endian = raw[1] == 1
    uint32 = struct.Struct('<I' if little_endian else '>I')
    size = len(raw) - ENCAPSULATION_BYTES
    numbers, strings, sequences = [], [], []
    structural = [0, 1]
    position = 0  # counted from the end of the encapsulation header, as CDR aligns
    for field in fields:
        if field.kind in ('string', 'seq_f4'):
            position = _align(position, 4)
            if position + 4 > size:
                raise _fail(index, f'truncated: {field.name} length at byte {position} of {size}')
            length = uint32.unpack_from(raw, ENCAPSULATION_BYTES + position)[0]
            structural += range(ENCAPSULATION_BYTES + position, ENCAPSULATION_BYTES + position + 4)
            position += 4
            if field.kind == 'string':
                if length < 1 or position + length > size:
                    raise _fail(index, f'invalid {field.name} string length {length} at byte {position - 4}')
                terminator = ENCAPSULATION_BYTES + position + length - 1
                if raw[terminator] != 0:
                    raise _fail(index, f'{field.name} string lacks its terminating NUL')
                structural.append(terminator)
                strings.append((field, ENCAPSULATION_BYTES + position, length - 1))
                position += length
            else:
                if position + 4 * length > size:
                    raise _fail(index, f'invalid {field.name} sequence length {length} at byte {position - 4}')
                sequences.append((field, ENCAPSULATION_BYTES + position, length))
                position += 4 * length
        else:
            item = _SIZE[field.kind]
            position = _align(position, item)
            if position + item * field.count > size:
                raise _fail(index, f'truncated: {field.name} at byte {position} of {size}')
            numbers.append((field, ENCAPSULATION_BYTES + position))
            position += item * field.count
    if size - position > TRAILING_BYTES_ALLOWED:
        raise _fail(index, f'{size - position} bytes after the last field (size mismatch)')
    return _Layout(little_endian, tuple(numbers), tuple(strings), tuple(sequences), tuple(structural))


def _text(raw: bytes, start: int, count: int, field: Field, index: int) -> str:
    try:
        return bytes(raw[start:start + count]).decode()
    except UnicodeDecodeError as err:
        raise _fail(index, f'{field.name} is not UTF-8 ({err.reason})') from None


def decode_message(raw: bytes | memoryview, msgtype: str, *, index: int = 0) -> dict[str, object]:
    """Decode one raw CDR message with :mod:`struct` (the reference for :func:`decode_messages`).

    :param raw: the serialised message including its 4-byte encapsulation header.
    :param index: the message's position, named in errors.
    :returns: field name to value: numbers (tuples for arrays and sequences), strings as ``str``,
        and ``stamp_ns`` for stamped types.
    :raises CdrError: the message is malformed or truncated.
    """
    values = _values(bytes(raw), msgtype, index)
    if 'stamp_sec' in values:
        values['stamp_ns'] = int(values.pop('stamp_sec')) * NANOSECONDS + int(values.pop('stamp_nanosec'))
    return values


def _values(raw: bytes, msgtype: str, index: int) -> dict[str, object]:
    layout = _layout(raw, schema(msgtype), index)
    order = '<' if layout.little_endian else '>'
    values: dict[str, object] = {}
    for field, offset in layout.numbers:
        unpacked = struct.unpack_from(f'{order}{field.count}{_STRUCT[field.kind]}', raw, offset)
        values[field.name] = unpacked[0] if field.count == 1 else unpacked
    for field, offset, count in layout.strings:
        values[field.name] = _text(raw, offset, count, field, index)
    for field, offset, count in layout.sequences:
        values[field.name] = struct.unpack_from(f'{order}{count}f', raw, offset)
    return values
