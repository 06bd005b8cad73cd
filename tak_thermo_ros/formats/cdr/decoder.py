"""Block decoding of CDR-serialised ROS 2 messages into numpy arrays (numpy only, no rosbags).

Messages of one type whose variable-length parts (strings, sequences) have the same lengths share
one byte layout, so a chunk of them is read at once with :func:`numpy.frombuffer` and a structured
dtype. :func:`decode_messages` groups a chunk by message length, derives the layout of each group
from its first message (:func:`~tak_thermo_ros.formats.cdr.schema._layout`, the rules of the
plain-Python decoder :func:`~tak_thermo_ros.formats.cdr.schema.decode_message`), checks in one
vectorised pass that every message of the group has the same structural bytes (encapsulation,
length prefixes, string terminators), reads the matching messages as arrays and repeats with the
rest. The result keeps the order of the input. A message that rosbags' ``deserialize_cdr``
refuses (bad encapsulation, truncated, bad string or sequence length, missing terminator, invalid
UTF-8, more than 3 trailing bytes) raises :class:`~tak_thermo_ros.errors.CdrError` naming the
first such message; CDR has no checksum, so a flipped bit inside a number is read as that other
number, as rosbags reads it.

Strings come back as category codes: ``arrays['frame_id']`` is an ``int32`` array indexing
``arrays.labels['frame_id']`` (labels in order of first appearance). Sequences
(``BatteryState.cell_voltage``, ``cell_temperature``) are checked but not returned by the block
decoder.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from tak_thermo_ros.formats.cdr.schema import (
    _NUMPY,
    NANOSECONDS,
    Field,
    _fail,
    _Layout,
    _layout,
    _values,
    schema,
)
from tak_thermo_ros.errors import CdrError

MAX_LAYOUT_ROUNDS = 8
"""Layouts tried per length group before the rest of the group is decoded message by message."""


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
