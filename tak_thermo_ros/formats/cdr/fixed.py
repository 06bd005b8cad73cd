"""One CDR message at a time, at fixed offsets: the ``compensator`` node's raw path.

The serialised bytes rclpy hands a ``raw=True`` subscription: :class:`FixedReader` reads chosen
numbers of a stamped message at fixed offsets and :class:`FixedWriter` serialises one whose header
is copied from it. A stamped message's offsets depend on its byte order and its frame_id's length
only, so the first message of each is checked in full
(:func:`~tak_thermo_ros.formats.cdr.schema._layout`, the rules rosbags applies) and the rest are
read with one ``struct`` call.
"""

from __future__ import annotations

import struct
from operator import itemgetter
from typing import Sequence

from tak_thermo_ros.formats.cdr.encoder import _template
from tak_thermo_ros.formats.cdr.schema import _HEADER, _SIZE, _STRUCT, ENCAPSULATION_BYTES, Field, _layout, schema
from tak_thermo_ros.errors import CdrError

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
