"""The block CDR decoder against rosbags' per-message deserialisation, message for message."""

from __future__ import annotations

import math
import sqlite3
import struct
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rosbags.rosbag2 import Reader, Writer
from rosbags.serde import SerdeError

from conftest import SHORT
from tak_thermo_ros.formats import bag as bagio
from tak_thermo_ros.formats.bag import reader as bag_reader
from tak_thermo_ros.formats.bag import TYPESTORE, iter_topic_arrays, read_record, write_record
from tak_thermo_ros.formats.cdr.decoder import MAX_LAYOUT_ROUNDS, MessageArrays, concatenate, decode_messages
from tak_thermo_ros.formats.cdr.schema import SCHEMAS, decode_message
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.errors import BagError, CdrError

VECTOR3_STAMPED = 'geometry_msgs/msg/Vector3Stamped'
TEMPERATURE = 'sensor_msgs/msg/Temperature'
IMU = 'sensor_msgs/msg/Imu'
BATTERY = 'sensor_msgs/msg/BatteryState'
TYPES = TYPESTORE.types
INTEGER_RANGES = {'Int8': (-2**7, 2**7 - 1), 'Int16': (-2**15, 2**15 - 1), 'Int32': (-2**31, 2**31 - 1),
                  'Int64': (-2**63, 2**63 - 1), 'UInt8': (0, 2**8 - 1), 'UInt16': (0, 2**16 - 1),
                  'UInt32': (0, 2**32 - 1), 'UInt64': (0, 2**64 - 1)}
SPECIAL = [math.nan, math.inf, -math.inf, 0.0, -0.0, 1e308, -1e-308, 5e-324]


# ---- message construction and the rosbags reference -------------------------------------------

def _header(sec: int, nanosec: int, frame_id: str):
    return TYPES['std_msgs/msg/Header'](stamp=TYPES['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec),
                                        frame_id=frame_id)


def _vector3(values):
    x, y, z = values
    return TYPES['geometry_msgs/msg/Vector3'](x=x, y=y, z=z)


def _message(msgtype: str, sec: int, nanosec: int, frame_id: str, numbers: list[float]):
    """A message of ``msgtype`` whose floating-point fields take ``numbers`` in turn."""
    take = iter(numbers * 64).__next__
    header = _header(sec, nanosec, frame_id)
    if msgtype == VECTOR3_STAMPED:
        return TYPES[msgtype](header=header, vector=_vector3((take(), take(), take())))
    if msgtype in (TEMPERATURE, 'sensor_msgs/msg/FluidPressure', 'sensor_msgs/msg/RelativeHumidity'):
        value = SCHEMAS[msgtype][3].name
        return TYPES[msgtype](header=header, **{value: take(), 'variance': take()})
    if msgtype == IMU:
        def covariance():
            return np.array([take() for _ in range(9)])
        return TYPES[msgtype](
            header=header, orientation=TYPES['geometry_msgs/msg/Quaternion'](x=take(), y=take(), z=take(), w=take()),
            orientation_covariance=covariance(), angular_velocity=_vector3((take(), take(), take())),
            angular_velocity_covariance=covariance(), linear_acceleration=_vector3((take(), take(), take())),
            linear_acceleration_covariance=covariance())
    raise AssertionError(msgtype)


def _battery(sec: int, nanosec: int, frame_id: str, numbers: list[float], cells: int, location: str,
             serial: str, flags: tuple[int, int, int, bool]):
    take = iter(numbers * 64).__next__
    with np.errstate(over='ignore'):  # huge float64 values become float32 infinities
        values = {name: float(np.float32(take())) for name in
                  ('voltage', 'temperature', 'current', 'charge', 'capacity', 'design_capacity', 'percentage')}
        cell_voltage = np.array([take() for _ in range(cells)], dtype=np.float32)
        cell_temperature = np.array([take() for _ in range(cells // 2)], dtype=np.float32)
    return TYPES[BATTERY](header=_header(sec, nanosec, frame_id), **values, power_supply_status=flags[0],
                          power_supply_health=flags[1], power_supply_technology=flags[2], present=flags[3],
                          cell_voltage=cell_voltage, cell_temperature=cell_temperature,
                          location=location, serial_number=serial)


def _serialize(message, msgtype: str, *, little_endian: bool = True) -> bytes:
    return bytes(TYPESTORE.serialize_cdr(message, msgtype, little_endian=little_endian))


def _reference(message, msgtype: str) -> dict[str, object]:
    """The block decoder's fields of one message, read from rosbags' message object."""
    values: dict[str, object] = {}
    for field in SCHEMAS[msgtype]:
        if field.name in ('stamp_sec', 'stamp_nanosec'):
            stamp = message.header.stamp
            values['stamp_ns'] = stamp.sec * 1_000_000_000 + stamp.nanosec
        elif field.name == 'frame_id':
            values['frame_id'] = message.header.frame_id
        elif field.kind != 'seq_f4':
            value = getattr(message, field.name)
            if hasattr(value, 'x'):
                value = tuple(getattr(value, axis) for axis in ('x', 'y', 'z', 'w') if hasattr(value, axis))
            elif isinstance(value, np.ndarray):
                value = tuple(value.tolist())
            values[field.name] = value
    return values


def _same_number(got, expected) -> bool:
    """Bit for bit for floats (NaN and -0.0 included), exact for integers and booleans."""
    if isinstance(expected, float):
        return struct.pack('<d', float(got)) == struct.pack('<d', expected)
    return got == expected and type(expected)(got) == expected


def _assert_rows_equal(arrays: MessageArrays, expected: list[dict[str, object]]) -> None:
    assert len(arrays) == len(expected)
    for name in expected[0] if expected else ():
        if name in arrays.labels:
            assert arrays.strings(name) == [row[name] for row in expected], name
            continue
        column = arrays[name]
        for row, values in enumerate(expected):
            got = column[row].tolist()
            want = values[name]
            if isinstance(want, tuple):
                assert len(got) == len(want) and all(map(_same_number, got, want)), (name, row, got, want)
            else:
                assert _same_number(got, want), (name, row, got, want)


def _assert_decodes_like_rosbags(raws: list[bytes], msgtype: str) -> MessageArrays:
    arrays = decode_messages(raws, msgtype)
    _assert_rows_equal(arrays, [_reference(TYPESTORE.deserialize_cdr(raw, msgtype), msgtype) for raw in raws])
    return arrays


# ---- decode_messages on raw bytes ---------------------------------------------------------------

FRAMES = ['imu', 'imu', '', 'imu_link', 'imx', 'a', 'imu_link_with_a_long_name', 'ü∂', 'imu', 'abc']


@pytest.mark.parametrize('msgtype', [VECTOR3_STAMPED, TEMPERATURE, IMU, 'sensor_msgs/msg/FluidPressure',
                                     'sensor_msgs/msg/RelativeHumidity'])
def test_mixed_frames_special_values_and_both_byte_orders(msgtype):
    """Frame ids of every length (empty, non-ASCII), NaN/inf/-0.0/subnormals, both byte orders, in order."""
    raws = [_serialize(_message(msgtype, 1_700_000_000 + row, (row * 7919) % 1_000_000_000, frame,
                                SPECIAL[row % len(SPECIAL):] + [row * 0.25]), msgtype,
                       little_endian=row % 3 != 1)
            for row, frame in enumerate(FRAMES * 5)]
    arrays = _assert_decodes_like_rosbags(raws, msgtype)
    assert arrays.labels['frame_id'][0] == 'imu'  # labels in order of first appearance
    assert arrays['stamp_ns'].dtype == np.int64


@pytest.mark.parametrize('count', [0, 1])
@pytest.mark.parametrize('msgtype', [VECTOR3_STAMPED, TEMPERATURE, IMU])
def test_zero_and_one_message(msgtype, count):
    """Empty and single-message chunks give arrays of the right shapes."""
    raws = [_serialize(_message(msgtype, 5, 6, 'f', [1.5, -2.5]), msgtype)] * count
    arrays = _assert_decodes_like_rosbags(raws, msgtype)
    vector_shapes = {VECTOR3_STAMPED: {'vector': (count, 3)}, TEMPERATURE: {'temperature': (count,)},
                     IMU: {'orientation': (count, 4), 'linear_acceleration_covariance': (count, 9)}}
    for name, shape in vector_shapes[msgtype].items():
        assert arrays[name].shape == shape
    assert arrays['stamp_ns'].shape == (count,)


def test_same_length_with_different_layouts():
    """Messages of equal length whose frame ids differ in length (trailing padding) are told apart."""
    # 'ab' ends the string 1 byte later than 'a' but both pad to the same float64 offset: same length
    # and layout; 'abcde' moves the vector by 8 bytes. Serialised lengths: check the premise.
    raws = [_serialize(_message(VECTOR3_STAMPED, row, row, frame, [row + 0.5]), VECTOR3_STAMPED)
            for row, frame in enumerate(['a', 'ab', 'abc', 'abcd', 'abcde', 'a', 'abcd'] * 3)]
    assert len({len(raw) for raw in raws}) == 2
    _assert_decodes_like_rosbags(raws, VECTOR3_STAMPED)


def test_trailing_padding_bytes_are_accepted_as_rosbags_does():
    """Up to 3 extra bytes after the last field are accepted, 4 are refused, in both decoders."""
    raw = _serialize(_message(TEMPERATURE, 1, 2, 'f', [3.0, 4.0]), TEMPERATURE)
    padded = [raw + b'\0' * extra for extra in range(4)]
    _assert_decodes_like_rosbags([raw, *padded], TEMPERATURE)
    with pytest.raises(SerdeError):
        TYPESTORE.deserialize_cdr(raw + b'\0' * 4, TEMPERATURE)
    with pytest.raises(CdrError, match='message 3: 4 bytes after the last field'):
        decode_messages([raw, raw, raw + b'\0' * 4], TEMPERATURE)


@pytest.mark.parametrize('msgtype', [VECTOR3_STAMPED, TEMPERATURE, IMU])
def test_every_truncation_is_refused_with_the_message_index(msgtype):
    """A message cut at any byte, among intact ones, raises CdrError naming it, as rosbags refuses it."""
    intact = _serialize(_message(msgtype, 9, 10, 'imu_link', [0.1, -0.2, 9.81]), msgtype)
    for cut in range(len(intact) - 3):  # the last 3 bytes of a float64-ended message are payload
        broken = intact[:cut]
        with pytest.raises(SerdeError):
            TYPESTORE.deserialize_cdr(broken, msgtype)
        with pytest.raises(CdrError, match=r'^message 4: ') as caught:
            decode_messages([intact] * 3 + [broken] + [intact] * 4, msgtype, first_index=0)
        assert caught.value.index == 3


@pytest.mark.parametrize('msgtype', [VECTOR3_STAMPED, TEMPERATURE, IMU])
def test_every_single_bit_flip_is_refused_or_read_as_rosbags_reads_it(msgtype):
    """A flipped bit either raises CdrError naming the message.

    (exactly when rosbags refuses it) or gives rosbags' values: structural damage is never read as a number.
    """
    intact = _serialize(_message(msgtype, 9, 10, 'imu_link', [0.1, -0.2, 9.81, math.nan]), msgtype)
    refused = 0
    for bit in range(8 * len(intact)):
        flipped = bytearray(intact)
        flipped[bit // 8] ^= 1 << (bit % 8)
        flipped = bytes(flipped)
        raws = [intact] * 5 + [flipped] + [intact] * 2
        try:
            expected = TYPESTORE.deserialize_cdr(flipped, msgtype)
        except SerdeError:
            refused += 1
            with pytest.raises(CdrError, match=r'^message 106: ') as caught:
                decode_messages(raws, msgtype, first_index=100)
            assert caught.value.index == 105
            continue
        arrays = decode_messages(raws, msgtype, first_index=100)
        reference = _reference(TYPESTORE.deserialize_cdr(intact, msgtype), msgtype)
        _assert_rows_equal(arrays, [reference] * 5 + [_reference(expected, msgtype)] + [reference] * 2)
    assert refused >= 8 * 6  # the encapsulation byte 1 and the string length prefix, at least


def test_first_bad_message_is_named_whatever_its_length_group():
    """With several bad messages in a chunk the earliest is named, not the first of a length group."""
    good = _serialize(_message(VECTOR3_STAMPED, 1, 2, 'f', [1.0]), VECTOR3_STAMPED)
    short = good[:-1]
    long_bad = bytearray(_serialize(_message(VECTOR3_STAMPED, 1, 2, 'frame_x', [1.0]), VECTOR3_STAMPED))
    long_bad[1] = 7  # unsupported encapsulation
    with pytest.raises(CdrError, match=r'^message 3: invalid or unsupported CDR encapsulation'):
        decode_messages([good, good, bytes(long_bad), good, short], VECTOR3_STAMPED)


def test_invalid_utf8_and_unknown_type_are_refused():
    """A frame id that is not UTF-8 and a type without a block decoder raise CdrError."""
    raw = bytearray(_serialize(_message(TEMPERATURE, 1, 2, 'ab', [3.0]), TEMPERATURE))
    raw[raw.index(b'ab')] = 0xFF
    with pytest.raises(SerdeError):
        TYPESTORE.deserialize_cdr(bytes(raw), TEMPERATURE)
    good = _serialize(_message(TEMPERATURE, 1, 2, 'cd', [3.0]), TEMPERATURE)
    with pytest.raises(CdrError, match=r'^message 2: frame_id is not UTF-8'):
        decode_messages([good, bytes(raw), good], TEMPERATURE)
    with pytest.raises(CdrError, match=r'message 2: frame_id is not UTF-8'):
        decode_message(bytes(raw), TEMPERATURE, index=1)
    with pytest.raises(CdrError, match='no block decoder for sensor_msgs/msg/Image'):
        decode_messages([good], 'sensor_msgs/msg/Image')


def test_many_layouts_of_one_length_fall_back_to_single_messages():
    """More layouts per length than the block rounds allow are decoded one by one, still in order."""
    # BatteryState: cells and location length trade bytes, so many layouts share one total length.
    raws = []
    for row in range(40):
        cells = row % 12
        location = 'x' * (4 * (12 - cells) + 4 * (6 - cells // 2))
        message = _battery(row, row, 'bat', [row + 0.5, 3.25], cells, location, 'sn', (1, 2, 3, True))
        raws.append(_serialize(message, BATTERY))
    assert len({len(raw) for raw in raws}) == 1 and 12 > MAX_LAYOUT_ROUNDS
    arrays = _assert_decodes_like_rosbags(raws, BATTERY)
    assert arrays.strings('location') == [TYPESTORE.deserialize_cdr(raw, BATTERY).location for raw in raws]


def test_concatenate_merges_string_codes():
    """Chunks with different frame-id tables join into one table."""
    def chunk(frames):
        return decode_messages([_serialize(_message(TEMPERATURE, 1, 2, frame, [1.0]), TEMPERATURE)
                                for frame in frames], TEMPERATURE)
    joined = concatenate([chunk(['a', 'b']), chunk([]), chunk(['c', 'a'])])
    assert joined.strings('frame_id') == ['a', 'b', 'c', 'a']
    assert joined.labels['frame_id'] == ('a', 'b', 'c')


# ---- property tests ---------------------------------------------------------------------------

floats = st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from(SPECIAL)
frame_ids = (st.text(alphabet=st.characters(codec='utf-8', exclude_categories=['Cs']), max_size=12)
             | st.text(alphabet='ab', max_size=3)  # equal lengths, different bytes
             | st.sampled_from(['imu', '', 'imu_link']))
stamps = st.tuples(st.integers(-2**31, 2**31 - 1), st.integers(0, 2**32 - 1))
PROPERTY = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@PROPERTY
@given(msgtype=st.sampled_from([VECTOR3_STAMPED, TEMPERATURE, IMU, 'sensor_msgs/msg/FluidPressure',
                                'sensor_msgs/msg/RelativeHumidity']),
       rows=st.lists(st.tuples(stamps, frame_ids, st.lists(floats, min_size=1, max_size=40), st.booleans()),
                     max_size=30))
def test_stamped_streams_match_rosbags_and_round_trip(msgtype, rows):
    """Random streams.

    (stamps over the whole int32/uint32 range, any UTF-8 frame ids, NaN/inf/huge values, mixed byte order) decode as
    rosbags decodes them, and serialise back to the same bytes.
    """
    messages = [_message(msgtype, sec, nanosec, frame, numbers) for (sec, nanosec), frame, numbers, _ in rows]
    raws = [_serialize(m, msgtype, little_endian=little) for m, (*_, little) in zip(messages, rows)]
    arrays = _assert_decodes_like_rosbags(raws, msgtype)
    _assert_rows_equal(arrays, [_reference(m, msgtype) for m in messages])
    for row, (raw, ((_, nanosec), *_, little)) in enumerate(zip(raws, rows)):
        if nanosec < 1_000_000_000:  # stamp_ns keeps the instant, not an unnormalised (sec, nanosec) pair
            assert _serialize(_rebuild(arrays, row, msgtype), msgtype, little_endian=little) == raw


def _rebuild(arrays: MessageArrays, row: int, msgtype: str):
    """The message of ``row`` rebuilt from the decoded arrays (for the serialisation round trip)."""
    sec, nanosec = divmod(int(arrays['stamp_ns'][row]), 1_000_000_000)
    frame = arrays.strings('frame_id')[row]
    numbers = [value for name, column in arrays.fields.items() if name not in ('stamp_ns', 'frame_id')
               for value in np.atleast_1d(column[row]).tolist()]
    return _message(msgtype, sec, nanosec, frame, numbers)


@PROPERTY
@given(type_name=st.sampled_from(sorted(INTEGER_RANGES) + ['Float32', 'Float64']), data=st.data())
def test_std_msgs_data_matches_rosbags(type_name, data):
    """std_msgs numbers over their whole range decode as rosbags decodes them."""
    msgtype = f'std_msgs/msg/{type_name}'
    if type_name in INTEGER_RANGES:
        values = st.integers(*INTEGER_RANGES[type_name])
    else:
        values = st.floats(width=32 if type_name == 'Float32' else 64)
    rows = data.draw(st.lists(st.tuples(values, st.booleans()), max_size=20))
    raws = [_serialize(TYPES[msgtype](data=value), msgtype, little_endian=little) for value, little in rows]
    arrays = _assert_decodes_like_rosbags(raws, msgtype)
    assert arrays['data'].dtype == np.dtype(SCHEMAS[msgtype][0].kind if type_name in INTEGER_RANGES
                                            else ('f4' if type_name == 'Float32' else 'f8'))


@PROPERTY
@given(rows=st.lists(st.tuples(stamps, frame_ids, st.lists(floats, min_size=1, max_size=20),
                               st.integers(0, 6), frame_ids, frame_ids,
                               st.tuples(st.integers(0, 255), st.integers(0, 255), st.integers(0, 255),
                                         st.booleans())), max_size=20))
def test_battery_state_matches_rosbags(rows):
    """`BatteryState` with sequences and strings of any length decodes as rosbags decodes it."""
    raws = [_serialize(_battery(sec, nanosec, frame, numbers, cells, location, serial, flags), BATTERY)
            for (sec, nanosec), frame, numbers, cells, location, serial, flags in rows]
    _assert_decodes_like_rosbags(raws, BATTERY)


@PROPERTY
@given(rows=st.lists(st.tuples(stamps, frame_ids, st.lists(floats, min_size=1, max_size=5)), min_size=1,
                     max_size=12),
       position=st.integers(0, 11), cut=st.integers(0, 80), flip=st.integers(0, 8 * 80 - 1))
def test_damaged_message_is_refused_or_read_as_rosbags_reads_it(rows, position, cut, flip):
    """A truncated and bit-flipped message anywhere in a stream.

    CdrError naming it exactly when rosbags refuses it, otherwise rosbags' values.
    """
    raws = [_serialize(_message(VECTOR3_STAMPED, sec, nanosec, frame, numbers), VECTOR3_STAMPED)
            for (sec, nanosec), frame, numbers in rows]
    position %= len(raws)
    damaged = bytearray(raws[position][:max(len(raws[position]) - cut, 0)])
    if damaged:
        damaged[(flip // 8) % len(damaged)] ^= 1 << (flip % 8)
    raws[position] = bytes(damaged)
    try:
        expected = [_reference(TYPESTORE.deserialize_cdr(raw, VECTOR3_STAMPED), VECTOR3_STAMPED) for raw in raws]
    except SerdeError:
        with pytest.raises(CdrError) as caught:
            decode_messages(raws, VECTOR3_STAMPED)
        assert caught.value.index == position
        return
    _assert_rows_equal(decode_messages(raws, VECTOR3_STAMPED), expected)


# ---- bags in both storages ------------------------------------------------------------------

def _write_bag(path, storage: str, topics: dict[str, tuple[str, list[bytes]]]) -> None:
    with Writer(path, version=9, storage_plugin=bagio.STORAGES[storage]) as writer:
        for topic, (msgtype, raws) in topics.items():
            connection = writer.add_connection(topic, msgtype, typestore=TYPESTORE)
            for stamp, raw in enumerate(raws):
                writer.write(connection, stamp, raw)


def _stream(msgtype: str, count: int, frames: list[str]) -> list[bytes]:
    return [_serialize(_message(msgtype, 1_700_000_000 + row // 1000, row % 1000 * 1_000_000,
                                frames[row % len(frames)], [row * 0.5, SPECIAL[row % len(SPECIAL)], -row]),
                       msgtype)
            for row in range(count)]


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
@pytest.mark.parametrize('chunk', [1, 7, 1000])
def test_bag_topics_match_rosbags(tmp_path, storage, chunk):
    """iter_topic_arrays over a bag equals rosbags message for message, at every chunk size."""
    topics = {'/v': (VECTOR3_STAMPED, _stream(VECTOR3_STAMPED, 300, ['imu', '', 'imu_link_2', 'imx'])),
              '/t': (TEMPERATURE, _stream(TEMPERATURE, 50, ['t'])),
              '/i': (IMU, _stream(IMU, 40, ['imu'] * 9 + ['other'])),
              '/empty': (IMU, [])}
    _write_bag(tmp_path / 'bag', storage, topics)
    with Reader(tmp_path / 'bag') as reader:
        for topic, (msgtype, _) in topics.items():
            connections = [c for c in reader.connections if c.topic == topic]
            expected = [_reference(TYPESTORE.deserialize_cdr(raw, msgtype), msgtype)
                        for _, _, raw in reader.messages(connections=connections)]
            chunks = list(iter_topic_arrays(reader, topic, msgtype, chunk=chunk))
            assert all(len(part) <= chunk for part in chunks)
            if expected:
                _assert_rows_equal(concatenate(chunks), expected)
            else:
                assert chunks == []
    assert len(list(iter_topic_arrays(tmp_path / 'bag', '/v', VECTOR3_STAMPED))) == 1


def test_bag_topic_errors(tmp_path):
    """Missing bag, missing topic and wrong type are BagErrors naming them."""
    _write_bag(tmp_path / 'bag', 'mcap', {'/t': (TEMPERATURE, _stream(TEMPERATURE, 3, ['t']))})
    with pytest.raises(BagError, match='no such bag'):
        list(iter_topic_arrays(tmp_path / 'absent', '/t', TEMPERATURE))
    with pytest.raises(BagError, match='topic /x not found'):
        list(iter_topic_arrays(tmp_path / 'bag', '/x', TEMPERATURE))
    with pytest.raises(BagError, match='topic /t has type sensor_msgs/msg/Temperature, expected'):
        list(iter_topic_arrays(tmp_path / 'bag', '/t', IMU))


TINY = replace(SHORT, plateaus_celsius=(10.0, 30.0), plateau_hours=0.02, ramp_celsius_per_minute=20.0, seed=3)


@pytest.fixture(scope='module')
def tiny_record():
    """A run of a few hundred samples."""
    return simulate(TINY).record


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_read_record_decoders_agree(tmp_path, tiny_record, storage, monkeypatch):
    """read_record gives the same arrays with the block decoder (small chunks) and with rosbags."""
    write_record(tmp_path / 'run', tiny_record, storage=storage)
    monkeypatch.setattr(bag_reader, 'CHUNK_MESSAGES', 37)
    block = read_record(tmp_path / 'run', progress=False, decoder='block')
    reference = read_record(tmp_path / 'run', progress=False, decoder='rosbags')
    for name in ('counts_stamp_ns', 'counts', 'temp_stamp_ns', 'temp_code', 'reference_stamp_ns', 'reference'):
        assert np.array_equal(getattr(block, name), getattr(reference, name)), name
        assert np.array_equal(getattr(block, name), getattr(tiny_record, name)), name
    assert block.frame_id == reference.frame_id == tiny_record.frame_id


@pytest.mark.parametrize('changed_at', [5, 36, 37, 38, 120])
def test_read_record_refuses_a_frame_change_with_its_message_number(tmp_path, changed_at, monkeypatch):
    """A frame_id change on the counts topic, inside a chunk or at its edge, is refused alike by both decoders."""
    frames = ['imu'] * (changed_at - 1) + ['imu_b'] * (150 - changed_at + 1)
    counts = [_serialize(_message(VECTOR3_STAMPED, row, 0, frame, [1.0, 2.0, 3.0]), VECTOR3_STAMPED)
              for row, frame in enumerate(frames)]
    _write_bag(tmp_path / 'run', 'mcap', {'/tak/counts': (VECTOR3_STAMPED, counts),
                                          '/tak/temp_code': (TEMPERATURE, _stream(TEMPERATURE, 5, ['t']))})
    monkeypatch.setattr(bag_reader, 'CHUNK_MESSAGES', 37)
    expected = (f"frame_id on /tak/counts changes from 'imu' to 'imu_b' at message {changed_at}; "
                'one frame per run is supported')
    for decoder in bagio.DECODERS:
        with pytest.raises(BagError, match=expected):
            read_record(tmp_path / 'run', progress=False, decoder=decoder)


def test_read_record_names_a_corrupt_message(tmp_path, tiny_record):
    """A message whose bytes were damaged in the storage is named by path, topic and number."""
    write_record(tmp_path / 'run', tiny_record, storage='sqlite3')
    with sqlite3.connect(tmp_path / 'run' / 'run.db3') as connection:
        topic_id = connection.execute("SELECT id FROM topics WHERE name = '/tak/temp_code'").fetchone()[0]
        rows = connection.execute('SELECT id, data FROM messages WHERE topic_id = ? ORDER BY timestamp, id',
                                  (topic_id,)).fetchall()
        victim, data = rows[3]
        connection.execute('UPDATE messages SET data = ? WHERE id = ?', (data[:-5], victim))
    with pytest.raises(CdrError, match=r'run: /tak/temp_code message 4: truncated'):
        read_record(tmp_path / 'run', progress=False)
    with pytest.raises(BagError, match='cannot read bag'):
        read_record(tmp_path / 'run', progress=False, decoder='rosbags')


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_driver_bag_block_decoder_equals_rosbags(tmp_path, storage):
    """A driver bag (Imu, temperature, both references) reads the same through both decoders."""
    from tak_thermo_ros.formats.bag import read_driver_record, write_driver_record
    from tak_thermo_ros.core.simulation.imu import simulate
    from tak_thermo_ros.core.simulation.scenario import Scenario
    from tak_thermo_ros.core.simulation.truth import RATE_TABLE_POSITIONS, RATE_TABLE_RATES
    scenario = Scenario(output='imu', plateaus_celsius=(10.0, 30.0), plateau_hours=0.05, ramp_celsius_per_minute=4.0,
                        dwell_s=20.0, positions=RATE_TABLE_POSITIONS, table_rates=RATE_TABLE_RATES, seed=5)
    driver = simulate(scenario).driver
    orientation = driver.orientation.copy()
    orientation[::7] = (0.1, 0.2, 0.3, 0.9273618495495703)  # not all identity: passed through as given
    driver = replace(driver, orientation=orientation)
    write_driver_record(tmp_path / 'bag', driver, storage=storage)
    block = read_driver_record(tmp_path / 'bag', decoder='block', progress=False)
    reference = read_driver_record(tmp_path / 'bag', decoder='rosbags', progress=False)
    for name in ('stamp_ns', 'accel', 'gyro', 'orientation', 'orientation_covariance', 'temp_stamp_ns',
                 'temperature', 'reference_stamp_ns', 'reference', 'rate_reference_stamp_ns', 'rate_reference'):
        assert np.array_equal(getattr(block, name), getattr(reference, name)), name
        assert np.array_equal(getattr(block, name), getattr(driver, name)), name
    assert block.frame_id == reference.frame_id == driver.frame_id
