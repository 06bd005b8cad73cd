"""Block decoding of CDR-serialised ROS 2 messages into numpy arrays (numpy only, no rosbags).

A rosbag2 topic stores each message as its CDR bytes: a 4-byte encapsulation header (``00 01``
little endian, ``00 00`` big endian, two option bytes) followed by the fields, each aligned to
its own size counted from the end of the encapsulation header. Messages of one type whose
variable-length parts (strings, sequences) have the same lengths share one byte layout, so a
chunk of them is read at once with :func:`numpy.frombuffer` and a structured dtype.

:func:`decode_messages` groups a chunk by message length, derives the layout of each group from
its first message with the plain-Python decoder (:func:`decode_message`), checks in one vectorised
pass that every message of the group has the same structural bytes (encapsulation, length
prefixes, string terminators), reads the matching messages as arrays and repeats with the rest.
The result keeps the order of the input. A message that rosbags' ``deserialize_cdr`` refuses
(bad encapsulation, truncated, bad string or sequence length, missing terminator, invalid UTF-8,
more than 3 trailing bytes) raises :class:`~tak_thermo_ros.errors.CdrError` naming the first such
message; CDR has no checksum, so a flipped bit inside a number is read as that other number,
as rosbags reads it.

Strings come back as category codes: ``arrays['frame_id']`` is an ``int32`` array indexing
``arrays.labels['frame_id']`` (labels in order of first appearance). Sequences
(``BatteryState.cell_voltage``, ``cell_temperature``) are checked but not returned by the block
decoder.

One message at a time (the ``compensator`` node's raw path, the serialised bytes rclpy hands a
``raw=True`` subscription): :class:`FixedReader` reads chosen numbers of a stamped message at
fixed offsets and :class:`FixedWriter` serialises one whose header is copied from it. A stamped
message's offsets depend on its byte order and its frame_id's length only, so the first message of
each is checked in full (:func:`_layout`, the rules above) and the rest are read with one
``struct`` call.
"""

from __future__ import annotations

import struct
import sys
from dataclasses import dataclass
from operator import itemgetter
from typing import Sequence

import numpy as np

from tak_thermo_ros.errors import CdrError

NANOSECONDS = 1_000_000_000
ENCAPSULATION_BYTES = 4
TRAILING_BYTES_ALLOWED = 3
"""rosbags accepts up to 3 bytes after the last field (padding to a multiple of 4)."""
MAX_LAYOUT_ROUNDS = 8
"""Layouts tried per length group before the rest of the group is decoded message by message."""

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


@dataclass(frozen=True)
class MessageArrays:
    """A chunk of messages of one type as arrays, one row per message in input order.

    ``fields`` maps each numeric field to a ``(k,)`` or ``(k, n)`` array (``stamp_ns`` int64 for
    stamped types) and each string field to ``int32`` codes into ``labels[name]``.
    """

    msgtype: str
    fields: dict[str, np.ndarray]
    labels: dict[str, tuple[str, ...]]

    def __len__(self) -> int:
        return len(next(iter(self.fields.values())))

    def __getitem__(self, name: str) -> np.ndarray:
        return self.fields[name]

    def strings(self, name: str) -> list[str]:
        """The values of string field ``name``, one per message."""
        labels = self.labels[name]
        return [labels[code] for code in self.fields[name].tolist()]


def _output_fields(fields: tuple[Field, ...]) -> list[Field]:
    return [f for f in fields if f.kind != 'seq_f4']


class _Builder:
    """Output arrays of a chunk, filled group by group."""

    def __init__(self, msgtype: str, fields: tuple[Field, ...], count: int) -> None:
        self.msgtype = msgtype
        self.arrays: dict[str, np.ndarray] = {}
        self.codes: dict[str, dict[str, int]] = {}
        for field in _output_fields(fields):
            if field.kind == 'string':
                self.arrays[field.name] = np.zeros(count, dtype=np.int32)
                self.codes[field.name] = {}
            else:
                shape = (count,) if field.count == 1 else (count, field.count)
                self.arrays[field.name] = np.zeros(shape, dtype=_NUMPY[field.kind])

    def code(self, name: str, text: str) -> int:
        codes = self.codes[name]
        return codes.setdefault(text, len(codes))

    def finish(self) -> MessageArrays:
        arrays = dict(self.arrays)
        labels: dict[str, tuple[str, ...]] = {}
        for name, codes in self.codes.items():
            texts = list(codes)
            values = arrays[name]
            if len(values) and len(texts) > 1:  # renumber by first appearance
                present, first = np.unique(values, return_index=True)
                ordered = present[np.argsort(first)]
                renumber = np.zeros(len(texts), dtype=np.int32)
                renumber[ordered] = np.arange(len(ordered), dtype=np.int32)
                arrays[name] = renumber[values]
                texts = [texts[code] for code in ordered.tolist()]
            labels[name] = tuple(texts)
        if 'stamp_sec' in arrays:
            stamp_ns = arrays.pop('stamp_sec').astype(np.int64) * NANOSECONDS
            stamp_ns += arrays.pop('stamp_nanosec')
            arrays = {'stamp_ns': stamp_ns, **arrays}
        return MessageArrays(self.msgtype, arrays, labels)


def decode_messages(raws: Sequence[bytes | memoryview], msgtype: str, *, first_index: int = 0) -> MessageArrays:
    """Decode a chunk of raw CDR messages of one type into arrays, keeping their order.

    :param raws: serialised messages, each with its 4-byte encapsulation header (as
        ``rosbags.rosbag2.Reader.messages`` yields them); little or big endian.
    :param msgtype: one of :data:`SCHEMAS`, e.g. ``'geometry_msgs/msg/Vector3Stamped'``.
    :param first_index: position of ``raws[0]`` in its topic; errors name ``first_index + i``.
    :raises CdrError: a message is malformed or truncated (the first such message is named).
    """
    fields = schema(msgtype)
    count = len(raws)
    builder = _Builder(msgtype, fields, count)
    if count == 0:
        return builder.finish()
    lengths = np.fromiter(map(len, raws), dtype=np.int64, count=count)
    failures: list[CdrError] = []
    if np.all(lengths == lengths[0]):
        rows = np.frombuffer(b''.join(raws), dtype=np.uint8).reshape(count, int(lengths[0]))
        _decode_group(builder, fields, np.arange(count), rows, first_index, failures)
    else:
        order = np.argsort(lengths, kind='stable')
        bounds = np.flatnonzero(np.diff(lengths[order])) + 1
        for members in np.split(order, bounds):
            joined = b''.join([raws[member] for member in members.tolist()])
            rows = np.frombuffer(joined, dtype=np.uint8).reshape(len(members), int(lengths[members[0]]))
            _decode_group(builder, fields, members, rows, first_index, failures)
    if failures:
        raise min(failures, key=lambda err: err.index)
    return builder.finish()


def _decode_group(builder: _Builder, fields: tuple[Field, ...], members: np.ndarray, rows: np.ndarray,
                  first_index: int, failures: list[CdrError]) -> None:
    """Decode the messages of one length: ``rows[i]`` is message ``members[i]`` of the chunk."""
    pending = np.arange(len(members))
    for _ in range(MAX_LAYOUT_ROUNDS):
        if not pending.size:
            return
        head = int(pending[0])
        first_raw = rows[head].tobytes()
        try:
            layout = _layout(first_raw, fields, first_index + int(members[head]))
        except CdrError as err:
            failures.append(err)
            pending = pending[1:]
            continue
        block = rows if pending.size == len(rows) else rows[pending]
        columns = np.asarray(layout.structural)
        same = np.all(block[:, columns] == rows[head, columns], axis=1)
        if not same.all():
            block = block[same]
        _decode_block(builder, layout, members[pending[same]], block, first_index, failures)
        pending = pending[~same]
    for position in pending.tolist():  # many layouts of one length: decode one by one
        _decode_single(builder, fields, rows[position].tobytes(), int(members[position]), first_index, failures)


def _decode_block(builder: _Builder, layout: _Layout, members: np.ndarray, block: np.ndarray,
                  first_index: int, failures: list[CdrError]) -> None:
    """Read the messages of one layout (rows of ``block``) into the builder's rows ``members``."""
    order = '<' if layout.little_endian else '>'
    names, formats, offsets = [], [], []
    for field, offset in layout.numbers:
        names.append(field.name)
        dtype = np.dtype(_NUMPY[field.kind]).newbyteorder(order)
        formats.append(dtype if field.count == 1 else (dtype, (field.count,)))
        offsets.append(offset)
    structured = np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                           'itemsize': block.shape[1]})
    records = np.ascontiguousarray(block).reshape(-1).view(structured)
    rows: np.ndarray | slice = members
    if len(members) and int(members[-1]) - int(members[0]) + 1 == len(members):  # ascending, no gaps
        rows = slice(int(members[0]), int(members[-1]) + 1)
    for field, _ in layout.numbers:
        builder.arrays[field.name][rows] = records[field.name]
    for field, offset, count in layout.strings:
        if count == 0:
            builder.arrays[field.name][rows] = builder.code(field.name, '')
            continue
        text_bytes = block[:, offset:offset + count]
        if np.all(text_bytes == text_bytes[0]):
            distinct, inverse = text_bytes[:1], np.zeros(len(block), dtype=np.intp)
        else:
            keys = np.ascontiguousarray(text_bytes).view(f'V{count}').ravel()
            _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
            distinct = text_bytes[first]
        codes = np.empty(len(distinct), dtype=np.int32)
        bad = np.zeros(len(distinct), dtype=bool)
        for position, row in enumerate(distinct):
            try:
                codes[position] = builder.code(field.name, row.tobytes().decode())
            except UnicodeDecodeError as err:
                bad[position] = True
                index = first_index + int(members[np.flatnonzero(inverse == position)].min())
                failures.append(_fail(index, f'{field.name} is not UTF-8 ({err.reason})'))
        builder.arrays[field.name][rows] = np.where(bad[inverse], 0, codes[inverse])


def _decode_single(builder: _Builder, fields: tuple[Field, ...], raw: bytes, member: int,
                   first_index: int, failures: list[CdrError]) -> None:
    try:
        values = _values(raw, builder.msgtype, first_index + member)
    except CdrError as err:
        failures.append(err)
        return
    for field in _output_fields(fields):
        value = values[field.name]
        if field.kind == 'string':
            value = builder.code(field.name, value)
        builder.arrays[field.name][member] = value


def concatenate(parts: Sequence[MessageArrays]) -> MessageArrays:
    """Join chunks of one message type into one :class:`MessageArrays` (string codes merged)."""
    if not parts:
        msg = 'concatenate needs at least one chunk'
        raise ValueError(msg)
    msgtype = parts[0].msgtype
    fields: dict[str, np.ndarray] = {}
    labels: dict[str, tuple[str, ...]] = {}
    for name in parts[0].fields:
        if name in parts[0].labels:
            merged: dict[str, int] = {}
            pieces = []
            for part in parts:
                remap = np.array([merged.setdefault(t, len(merged)) for t in part.labels[name]] or [0],
                                 dtype=np.int32)
                pieces.append(remap[part.fields[name]])
            fields[name] = np.concatenate(pieces)
            labels[name] = tuple(merged)
        else:
            fields[name] = np.concatenate([part.fields[name] for part in parts])
    return MessageArrays(msgtype, fields, labels)


# ----- block encoding -------------------------------------------------------------------------

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


# ----- one message at a time, at fixed offsets (the node's raw path) --------------------------

STRING_LENGTH_BYTES = slice(ENCAPSULATION_BYTES + 8, ENCAPSULATION_BYTES + 12)
"""Where a stamped message's frame_id length lies (after the encapsulation, ``sec`` and ``nanosec``)."""
FRAME_ID_START = ENCAPSULATION_BYTES + 12
MAX_LAYOUTS = 64
"""Layouts a reader (or writer) keeps: one per frame_id length and byte order seen."""


def _stamped_fields(msgtype: str) -> tuple[Field, ...]:
    """The fields of a stamped type whose only string is the header's frame_id (its offsets are fixed by it)."""
    fields = schema(msgtype)
    if fields[:len(_HEADER)] != _HEADER or any(f.kind in ('string', 'seq_f4') for f in fields[len(_HEADER):]):
        msg = f'no fixed-offset codec for {msgtype} (a header and numbers only)'
        raise CdrError(msg, -1)
    return fields


class FixedLayout:
    """Where the numbers of one stamped message lie, for one byte order and frame_id length.

    Compared by identity: a :class:`FixedReader` keeps one per frame_id length, and a
    :class:`FixedWriter` keys its own layouts by it.
    """

    __slots__ = ('little_endian', 'size', 'frame_id_bytes', 'terminator', 'offsets', 'unpack')

    def __init__(self, raw: bytes, fields: tuple[Field, ...], wanted: tuple[tuple[str, int], ...]) -> None:
        layout = _layout(raw, fields, -1)  # the whole message checked: a CdrError otherwise
        self.little_endian = layout.little_endian
        self.size = len(raw)
        _, start, count = layout.strings[0]
        self.frame_id_bytes = count + 1
        """The frame_id's length in the message, its NUL included (the string length CDR stores)."""
        self.terminator = start + count
        self.offsets = {field.name: offset for field, offset in layout.numbers}
        """Byte offset of each numeric field, from the start of the message."""
        kinds = {field.name: field.kind for field, _ in layout.numbers}
        # One struct over the wanted fields in byte order, skipping the rest; the values are then
        # put in the order asked for.
        spans = sorted((self.offsets[name], index, name, count) for index, (name, count) in enumerate(wanted))
        code, position, order = '<' if layout.little_endian else '>', 0, []
        for offset, index, name, count in spans:
            if offset < position:
                msg = f'fields overlap at {name}'
                raise ValueError(msg)
            code += f'{offset - position}x{count}{_STRUCT[kinds[name]]}'
            position = offset + count * _SIZE[kinds[name]]
            order.append((index, count))
        unpack = struct.Struct(code).unpack_from
        starts, first = {}, 0
        for index, count in order:
            starts[index] = first
            first += count
        picks = [position for index in range(len(wanted))
                 for position in range(starts[index], starts[index] + wanted[index][1])]
        if picks == sorted(picks):
            self.unpack = unpack
        else:
            pick = itemgetter(*picks)
            self.unpack = lambda raw: pick(unpack(raw))


class FixedReader:
    """Chosen numbers of one stamped message type, read from its serialised bytes at fixed offsets.

    :param msgtype: a stamped type of :data:`SCHEMAS` whose only string is the frame_id
        (``sensor_msgs/msg/Imu``, ``Temperature``, ``MagneticField``,
        ``geometry_msgs/msg/Vector3Stamped``, ...).
    :param wanted: the numeric fields to read, in the order :meth:`read` returns them: a name
        (``'stamp_sec'``, ``'linear_acceleration'``: every element) or ``(name, n)``, its first
        ``n`` elements (``('linear_acceleration_covariance', 1)``).
    :raises CdrError: a type without a fixed-offset codec.
    :raises ValueError: a field the type does not have, or one that is not a number.
    """

    def __init__(self, msgtype: str, wanted: Sequence[str | tuple[str, int]]) -> None:
        self.msgtype = msgtype
        self._fields = _stamped_fields(msgtype)
        counts = {field.name: field.count for field in self._fields if field.kind != 'string'}
        pairs = []
        for item in wanted:
            name, count = (item, None) if isinstance(item, str) else item
            if name not in counts or not 1 <= (count or 1) <= counts[name]:
                msg = f'{msgtype} has no numeric field {name}' + (f' of {count} elements' if count else '')
                raise ValueError(msg)
            pairs.append((name, count or counts[name]))
        self._wanted = tuple(pairs)
        self._layouts: dict[bytes, FixedLayout] = {}
        self.layout: FixedLayout | None = None
        """The layout of the last message read (what :meth:`FixedWriter.write` takes with it)."""

    def read(self, raw: bytes) -> tuple:
        """The wanted numbers of one message, flat, in the order asked for (a field of n elements gives n).

        :raises CdrError: the message is malformed or truncated (one line, without a traceback's worth of detail).
        """
        layout = self._layouts.get(raw[STRING_LENGTH_BYTES])
        if layout is None or len(raw) != layout.size or raw[1] != layout.little_endian or raw[0] \
                or raw[layout.terminator]:
            layout = self._learn(raw)
        self.layout = layout
        return layout.unpack(raw)

    def _learn(self, raw: bytes) -> FixedLayout:
        """The layout of a message the known ones do not fit, checked in full; kept for the next ones."""
        try:
            layout = FixedLayout(bytes(raw), self._fields, self._wanted)
        except CdrError as err:
            msg = f'malformed {self.msgtype} ({len(raw)} bytes): {err}'
            raise CdrError(msg, -1) from None
        if len(self._layouts) >= MAX_LAYOUTS:  # a stream of ever new frame_id lengths: keep the cache bounded
            self._layouts.clear()
        self._layouts[raw[STRING_LENGTH_BYTES]] = layout
        return layout


def frame_id(raw: bytes) -> str:
    """The frame_id of a stamped message :meth:`FixedReader.read` took (bytes that are not UTF-8 replaced)."""
    length = int.from_bytes(raw[STRING_LENGTH_BYTES], 'little' if raw[1] else 'big')
    return bytes(raw[FRAME_ID_START:FRAME_ID_START + length - 1]).decode(errors='replace')


class FixedWriter:
    """One stamped message type serialised at fixed offsets, its header (stamp, frame_id) copied from a message read.

    As :func:`encode_messages` lays it out (padding zero), so the bytes are those rosbags'
    ``serialize_cdr`` gives for the same values; in the byte order of the message the header
    comes from.

    :param msgtype: the type written (a stamped type of :data:`SCHEMAS` whose only string is the frame_id).
    :param variable: the fields given per message, in the order of :meth:`write`'s ``values``.
    :param constants: the value of every other field, but ``copied``: a number or a sequence.
    :param copied: fields copied byte for byte from the message read (of the same type), e.g.
        an orientation passed through.
    :raises CdrError: a type without a fixed-offset codec.
    :raises ValueError: a field left out, given twice, or of the wrong size.
    """

    def __init__(self, msgtype: str, variable: Sequence[str], constants: dict[str, Sequence[float] | float],
                 copied: Sequence[str] = ()) -> None:
        self.msgtype = msgtype
        fields = _stamped_fields(msgtype)[len(_HEADER):]
        named = [*variable, *constants, *copied]
        if sorted(named) != sorted(field.name for field in fields):
            msg = f'{msgtype}: every field but the header once, variable, constant or copied (got {named})'
            raise ValueError(msg)
        self._counts = counts = {field.name: field.count for field in fields}
        self._kinds = {field.name: field.kind for field in fields}
        self._constants = {}
        for name, value in constants.items():
            values = (value,) if isinstance(value, (int, float)) else tuple(value)
            if len(values) != counts[name]:
                msg = f'{msgtype}.{name}: {counts[name]} values, got {len(values)}'
                raise ValueError(msg)
            self._constants[name] = values
        self._variable = tuple((name, counts[name]) for name in variable)
        self._copied = tuple(copied)
        self._plans: dict[FixedLayout, tuple] = {}

    def write(self, raw: bytes, layout: FixedLayout, values: tuple[float, ...]) -> bytes:
        """The message with the header of ``raw`` (read with ``layout``) and ``values``, the variable fields' flat."""
        plan = self._plans.get(layout)
        if plan is None:
            plan = self._plan(layout)
        encapsulation, head, pack, pick, constants, copy = plan
        if copy is None:
            return encapsulation + raw[ENCAPSULATION_BYTES:head] + pack(*pick(values + constants))
        return encapsulation + raw[ENCAPSULATION_BYTES:head] + pack(*pick(values + constants + (raw[copy[0]:copy[1]],)))

    def _plan(self, layout: FixedLayout) -> tuple:
        """What :meth:`write` does for messages of ``layout``: the header's end, one struct over the rest.

        The encapsulation is the writer's own (its options zero: the message needs no padding at its
        end), the stamp and frame_id the message read's. The struct packs the body in byte order,
        padding zero: the variable fields as numbers, each constant field as its bytes (packed here
        once), the copied fields as one slice of ``raw``; ``pick`` puts ``values + constants +
        (copied,)`` in that order.
        """
        text = b'-' * (layout.frame_id_bytes - 1)  # any text of that length: the offsets follow from its length
        target = _template(self.msgtype, (('frame_id', text),), layout.little_endian)
        order = '<' if layout.little_endian else '>'
        head = layout.terminator + 1  # encapsulation, stamp and frame_id, its NUL included: copied
        items = []  # (offset, size, struct code, argument index) in byte order
        first = 0
        for name, count in self._variable:
            _, offset = target.numbers[name]
            items += [(offset + k * _SIZE[self._kinds[name]], _SIZE[self._kinds[name]], _STRUCT[self._kinds[name]],
                       first + k) for k in range(count)]
            first += count
        constants = []
        for name, values in self._constants.items():
            _, offset = target.numbers[name]
            data = struct.pack(f'{order}{len(values)}{_STRUCT[self._kinds[name]]}', *values)
            items.append((offset, len(data), f'{len(data)}s', first + len(constants)))
            constants.append(data)
        copy = None
        if self._copied:
            spans = sorted((target.numbers[name][1], _SIZE[self._kinds[name]] * self._counts[name])
                           for name in self._copied)
            start, stop = spans[0][0], spans[-1][0] + spans[-1][1]
            if sum(size for _, size in spans) != stop - start or any(
                    layout.offsets.get(name) != target.numbers[name][1] for name in self._copied):
                msg = f'{self.msgtype}: copied fields must be adjacent and lie where they lie in the message read'
                raise ValueError(msg)
            copy = (start, stop)
            items.append((start, stop - start, f'{stop - start}s', first + len(constants)))
        items.sort()
        code, position = order, head
        for offset, size, item_code, _ in items:
            code += f'{offset - position}x{item_code}' if offset > position else item_code
            position = offset + size
        if position != len(target.row):
            msg = f'{self.msgtype}: the writer does not cover the message'
            raise AssertionError(msg)
        indices = [index for *_, index in items]
        pick = itemgetter(*indices) if len(indices) > 1 else (lambda every: (every[indices[0]],))
        plan = bytes(target.row[:ENCAPSULATION_BYTES]), head, struct.Struct(code).pack, pick, tuple(constants), copy
        if len(self._plans) >= MAX_LAYOUTS:
            self._plans.clear()
        self._plans[layout] = plan
        return plan
