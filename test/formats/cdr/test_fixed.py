"""The node's raw path codec (``FixedReader``, ``FixedWriter``): every field at fixed offsets, bad bytes refused.

References: the block encoder (byte for byte what rosbags' ``serialize_cdr`` gives,
test/formats/cdr/test_encoder.py), the plain ``struct`` decoder (``decode_message``, what rosbags reads), and
rclpy's own serialisation (Fast CDR, whose padding bytes are not zero).
"""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tak_thermo_ros.errors import CdrError
from tak_thermo_ros.formats.cdr.encoder import encode_messages
from tak_thermo_ros.formats.cdr.fixed import FixedReader, FixedWriter, frame_id
from tak_thermo_ros.formats.cdr.schema import SCHEMAS, decode_message

IMU = 'sensor_msgs/msg/Imu'
VECTOR3_STAMPED = 'geometry_msgs/msg/Vector3Stamped'
TYPES = (IMU, VECTOR3_STAMPED, 'sensor_msgs/msg/Temperature', 'sensor_msgs/msg/MagneticField',
         'sensor_msgs/msg/FluidPressure')
"""The stamped types the fixed-offset codec serves (the node's four and one more)."""
NANOSECONDS = 1_000_000_000
SPECIAL = [math.nan, math.inf, -math.inf, -1.0, 0.0, -0.0, 1e308, 5e-324,
           struct.unpack('<d', struct.pack('<Q', 0x7FF0_0000_0000_0001))[0]]  # a NaN with a payload
PROPERTY = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])

floats = st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from(SPECIAL)
frame_ids = (st.integers(0, 17).map(lambda n: 'abcdefghijklmnopq'[:n])  # every padding of the string
             | st.text(alphabet=st.characters(codec='utf-8', exclude_categories=['Cs']), max_size=9))
stamps = st.tuples(st.integers(-2**31, 2**31 - 1), st.integers(0, NANOSECONDS - 1))


def numeric(msgtype: str) -> list[tuple[str, int]]:
    """The numeric fields of a stamped type after its header, ``(name, count)`` in byte order."""
    return [(field.name, field.count) for field in SCHEMAS[msgtype][3:]]


def bits(values) -> list[int]:
    """Float64 bit patterns (NaN equals the same NaN); integers as they are."""
    return [struct.unpack('<Q', struct.pack('<d', v))[0] if isinstance(v, float) else v for v in values]


@st.composite
def messages(draw, msgtype=None):
    """``(msgtype, stamp, frame_id, {field: values}, little_endian, raw)``: one message by the block encoder."""
    msgtype = msgtype or draw(st.sampled_from(TYPES))
    sec, nanosec = draw(stamps)
    frame = draw(frame_ids)
    values = {name: draw(st.lists(floats, min_size=count, max_size=count)) for name, count in numeric(msgtype)}
    little_endian = draw(st.booleans())
    raw = encode(msgtype, sec, nanosec, frame, values, little_endian)
    return msgtype, (sec, nanosec), frame, values, little_endian, raw


def encode(msgtype: str, sec: int, nanosec: int, frame: str, values: dict, little_endian: bool) -> bytes:
    """One message serialised by the block encoder (rosbags' bytes)."""
    shaped = {name: np.array(v if len(v) > 1 else v[0]) for name, v in values.items()}
    return encode_messages(msgtype, np.array([sec * NANOSECONDS + nanosec]), shaped, {'frame_id': frame},
                           little_endian=little_endian)[0]


@PROPERTY
@given(message=messages(), data=st.data())
def test_every_field_read_as_encoded_in_any_order_either_byte_order(message, data):
    """Every numeric field, and the stamp, read from the encoded bytes bit for bit, in the order asked for."""
    msgtype, (sec, nanosec), frame, values, _, raw = message
    wanted = ['stamp_sec', 'stamp_nanosec', *(name for name, _ in numeric(msgtype))]
    order = data.draw(st.permutations(wanted))
    reader = FixedReader(msgtype, order)
    expected = {'stamp_sec': [sec], 'stamp_nanosec': [nanosec], **values}
    for _ in range(2):  # the first read learns the layout, the second takes it
        got = reader.read(raw)
        assert bits(got) == bits([v for name in order for v in expected[name]])
    assert frame_id(raw) == frame
    first = [(name, 1) for name, count in numeric(msgtype)]  # a field's first elements only
    assert bits(FixedReader(msgtype, first).read(raw)) == bits([values[name][0] for name, _ in first])


@PROPERTY
@given(first=messages(IMU), second=messages(IMU))
def test_a_reader_follows_frame_ids_of_other_lengths_and_byte_orders(first, second):
    """One reader, messages of two layouts in turn: each read by its own layout."""
    reader = FixedReader(IMU, ['linear_acceleration', 'angular_velocity', 'stamp_nanosec'])
    for message in (first, second, first, second):
        *_, values, _, raw = message
        got = reader.read(raw)
        assert bits(got) == bits([*values['linear_acceleration'], *values['angular_velocity'], message[1][1]])


@st.composite
def writes(draw):
    """A source message, an output type and what of it is variable, constant or copied from the source."""
    source = draw(messages())
    msgtype = source[0] if draw(st.booleans()) else draw(st.sampled_from(TYPES))
    fields = numeric(msgtype)
    copied = ()
    if msgtype == source[0] and len(fields) > 1 and draw(st.booleans()):
        start = draw(st.integers(0, len(fields) - 1))
        copied = tuple(name for name, _ in fields[start:draw(st.integers(start + 1, len(fields)))])
    rest = [name for name, _ in fields if name not in copied]
    variable = draw(st.permutations(rest)).copy()[:draw(st.integers(0, len(rest)))]
    values = {name: draw(st.lists(floats, min_size=count, max_size=count)) for name, count in fields}
    return source, msgtype, variable, copied, values


@PROPERTY
@given(case=writes(), options=st.binary(min_size=2, max_size=2))
def test_writer_gives_the_block_encoders_bytes_header_and_copies_from_the_source(case, options):
    """Header copied, variable fields packed, constants and copied fields in place: rosbags' bytes exactly.

    The source's encapsulation options (a serialiser's padding bits) are not copied: the output's are zero.
    """
    source, msgtype, variable, copied, values = case
    source_type, (sec, nanosec), frame, source_values, little_endian, raw = source
    raw = raw[:2] + options + raw[4:]
    constants = {name: v for name, v in values.items() if name not in variable and name not in copied}
    writer = FixedWriter(msgtype, variable, constants, copied)
    reader = FixedReader(source_type, ['stamp_sec'])
    reader.read(raw)
    flat = tuple(v for name in variable for v in values[name])
    expected = encode(msgtype, sec, nanosec, frame,
                      {**values, **{name: source_values[name] for name in copied}}, little_endian)
    assert writer.write(raw, reader.layout, flat) == expected
    assert writer.write(raw, reader.layout, flat) == expected  # the plan kept


@pytest.mark.parametrize('length', range(0, 10))
def test_rclpy_serialised_messages_read_and_written_back(length):
    """The bytes rclpy serialises (Fast CDR: padding not zero) read field for field; the writer's read by rclpy."""
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import Imu
    message = Imu()
    message.header.frame_id = 'frame_id_'[:length]
    message.header.stamp.sec, message.header.stamp.nanosec = -7, 999_999_999
    rng = np.random.default_rng(length)
    orientation = rng.normal(size=4)
    message.orientation.x, message.orientation.y, message.orientation.z, message.orientation.w = orientation
    message.orientation_covariance = rng.normal(size=9)
    message.linear_acceleration.x, message.linear_acceleration.y, message.linear_acceleration.z = rng.normal(size=3)
    message.angular_velocity.x, message.angular_velocity.y, message.angular_velocity.z = rng.normal(size=3)
    message.linear_acceleration_covariance = rng.normal(size=9)
    message.angular_velocity_covariance[0] = -1.0
    raw = serialize_message(message)
    reader = FixedReader(IMU, ['stamp_sec', 'stamp_nanosec', 'linear_acceleration', 'angular_velocity',
                               ('linear_acceleration_covariance', 1), ('angular_velocity_covariance', 1)])
    a, w = message.linear_acceleration, message.angular_velocity
    assert reader.read(raw) == (-7, 999_999_999, a.x, a.y, a.z, w.x, w.y, w.z,
                                message.linear_acceleration_covariance[0], -1.0)
    writer = FixedWriter(IMU, ['linear_acceleration', 'angular_velocity'],
                         {'angular_velocity_covariance': [2.0] * 9, 'linear_acceleration_covariance': [3.0] * 9},
                         ['orientation', 'orientation_covariance'])
    back = deserialize_message(writer.write(raw, reader.layout, (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)), Imu)
    assert back.header == message.header and back.orientation == message.orientation
    assert np.array_equal(back.orientation_covariance, message.orientation_covariance)
    assert (back.linear_acceleration.x, back.linear_acceleration.z, back.angular_velocity.y) == (1.0, 3.0, 5.0)
    assert list(back.angular_velocity_covariance) == [2.0] * 9
    assert list(back.linear_acceleration_covariance) == [3.0] * 9


def one_line(error: CdrError, msgtype: str) -> str:
    """The error's text, checked to be one line naming the type."""
    text = str(error)
    assert '\n' not in text and text.startswith(f'malformed {msgtype} (')
    return text


@PROPERTY
@given(message=messages())
def test_every_truncation_refused_and_trailing_bytes_as_rosbags(message):
    """Each shorter buffer is refused in one line; up to 3 trailing bytes are read as rosbags reads them, 4 refused."""
    msgtype, _, _, values, _, raw = message
    reader = FixedReader(msgtype, [name for name, _ in numeric(msgtype)])
    expected = bits([v for name, _ in numeric(msgtype) for v in values[name]])
    for end in range(len(raw)):
        with pytest.raises(CdrError) as caught:
            reader.read(raw[:end])
        assert f'({end} bytes)' in one_line(caught.value, msgtype)
    for extra in range(1, 4):
        assert bits(reader.read(raw + bytes(extra))) == expected
    with pytest.raises(CdrError, match='bytes after the last field'):
        reader.read(raw + bytes(4))
    assert bits(reader.read(raw)) == expected  # and the layout still serves the whole message


@PROPERTY
@given(message=messages(), position=st.integers(0, 24) | st.integers(0, 400), value=st.integers(0, 255),
       flip_order=st.booleans())
def test_damaged_message_refused_or_read_as_the_reference_decoder_reads_it(message, position, value, flip_order):
    """A byte changed (or the byte-order flag flipped) after the reader learned it: refused, or read as rosbags reads.

    ``decode_message`` is the reference (rosbags' reading); only a frame_id that is no longer UTF-8
    is read where rosbags refuses it (the raw path passes the frame_id's bytes through unread).
    """
    msgtype, *_, raw = message
    names = [name for name, _ in numeric(msgtype)]
    reader = FixedReader(msgtype, ['stamp_sec', 'stamp_nanosec', *names])
    reader.read(raw)
    damaged = bytearray(raw)
    if flip_order:
        damaged[1] ^= 1
    else:
        damaged[position % len(raw)] = value
    damaged = bytes(damaged)
    try:
        reference = decode_message(damaged, msgtype)
    except CdrError as err:
        reference = err
    try:
        got = reader.read(damaged)
    except CdrError as err:
        one_line(err, msgtype)
        assert isinstance(reference, CdrError)
        return
    if isinstance(reference, CdrError):
        assert 'not UTF-8' in str(reference)
        return
    assert got[0] * NANOSECONDS + got[1] == reference['stamp_ns']  # a nanosec of 1e9 or more is read as stored
    expected = [v for name in names for v in np.atleast_1d(reference[name]).tolist()]
    assert bits(got[2:]) == bits(expected)


@PROPERTY
@given(garbage=st.binary(max_size=400), msgtype=st.sampled_from(TYPES))
def test_any_bytes_give_numbers_or_one_cdr_error(garbage, msgtype):
    """Whatever the bytes, the reader returns numbers or raises ``CdrError`` (never another exception)."""
    reader = FixedReader(msgtype, [name for name, _ in numeric(msgtype)])
    try:
        got = reader.read(garbage)
    except CdrError as err:
        one_line(err, msgtype)
    else:
        assert len(got) == sum(count for _, count in numeric(msgtype))


def test_what_the_codec_cannot_serve_is_refused_when_built():
    """A type with more strings or sequences, a field the type lacks, a writer that leaves a field out."""
    with pytest.raises(CdrError, match='no fixed-offset codec for sensor_msgs/msg/BatteryState'):
        FixedReader('sensor_msgs/msg/BatteryState', ['voltage'])
    with pytest.raises(CdrError, match='no fixed-offset codec for std_msgs/msg/Float64'):
        FixedReader('std_msgs/msg/Float64', ['data'])
    with pytest.raises(ValueError, match='no numeric field frame_id'):
        FixedReader(IMU, ['frame_id'])
    with pytest.raises(ValueError, match='no numeric field vector of 4 elements'):
        FixedReader(VECTOR3_STAMPED, [('vector', 4)])
    with pytest.raises(ValueError, match='every field but the header once'):
        FixedWriter(VECTOR3_STAMPED, [], {})
    with pytest.raises(ValueError, match='3 values, got 2'):
        FixedWriter(VECTOR3_STAMPED, [], {'vector': (1.0, 2.0)})
