"""The block Imu encoder against rosbags' per-message serialisation, byte for byte, and apply's output."""

from __future__ import annotations

import math
import struct
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from rosbags.rosbag2 import Reader

from conftest import SHORT
from tak_thermo_ros.formats import bag as bagio
from tak_thermo_ros.formats.bag import writer as bag_writer
from tak_thermo_ros.formats.bag import TYPESTORE, read_imu_messages, write_driver_record, write_record
from tak_thermo_ros.formats.cdr.decoder import decode_messages
from tak_thermo_ros.formats.cdr.encoder import encode_imus, encode_messages
from tak_thermo_ros.cli import main
from tak_thermo_ros.formats.calibration_file import save_calibration, save_unit
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.errors import CdrError

IMU = 'sensor_msgs/msg/Imu'
TYPES = TYPESTORE.types
FIELDS = {'orientation': 4, 'orientation_covariance': 9, 'angular_velocity': 3, 'angular_velocity_covariance': 9,
          'linear_acceleration': 3, 'linear_acceleration_covariance': 9}
SPECIAL = [math.nan, -math.nan, math.inf, -math.inf, -1.0, 0.0, -0.0, 1e308, 5e-324,
           struct.unpack('<d', struct.pack('<Q', 0x7FF0_0000_0000_0001))[0]]  # a NaN with a payload
NANOSECONDS = 1_000_000_000


def _reference(stamp_ns: int, frame_id: str, values: dict[str, list[float]], *, little_endian: bool) -> bytes:
    """One message serialised by rosbags, built as bagio's per-message path builds it."""
    sec, nanosec = divmod(stamp_ns, NANOSECONDS)
    header = TYPES['std_msgs/msg/Header'](stamp=TYPES['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec),
                                          frame_id=frame_id)
    vector = TYPES['geometry_msgs/msg/Vector3']
    message = TYPES[IMU](
        header=header, orientation=TYPES['geometry_msgs/msg/Quaternion'](*values['orientation']),
        orientation_covariance=np.array(values['orientation_covariance']),
        angular_velocity=vector(*values['angular_velocity']),
        angular_velocity_covariance=np.array(values['angular_velocity_covariance']),
        linear_acceleration=vector(*values['linear_acceleration']),
        linear_acceleration_covariance=np.array(values['linear_acceleration_covariance']))
    return bytes(TYPESTORE.serialize_cdr(message, IMU, little_endian=little_endian))


def _bits(values: np.ndarray) -> np.ndarray:
    """The IEEE bit patterns, so that NaN compares equal to the same NaN."""
    return np.ascontiguousarray(values, dtype=np.float64).view(np.uint64)


floats = st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from(SPECIAL)
frame_ids = (st.integers(0, 9).map(lambda n: 'abcdefghi'[:n])  # every padding of the string
             | st.text(alphabet=st.characters(codec='utf-8', exclude_categories=['Cs']), max_size=9))
stamps = st.integers(-2**31, 2**31 - 1).flatmap(
    lambda sec: st.sampled_from([0, 1, NANOSECONDS - 1]).map(lambda ns: sec * NANOSECONDS + ns)) | st.sampled_from(
    [0, NANOSECONDS - 1, (2**31 - 1) * NANOSECONDS + NANOSECONDS - 1, -2**31 * NANOSECONDS, -1])


@st.composite
def blocks(draw):
    """A block: stamps, one frame id, each field per message or shared, in either byte order."""
    count = draw(st.integers(0, 6))
    values = {}
    for name, width in FIELDS.items():
        shared = draw(st.booleans())
        rows = draw(st.lists(st.lists(floats, min_size=width, max_size=width), min_size=1 if shared else count,
                             max_size=1 if shared else count))
        values[name] = rows[0] if shared else rows
    return (draw(st.lists(stamps, min_size=count, max_size=count)), draw(frame_ids), values, draw(st.booleans()))


PROPERTY = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
ROW = [1.5, -1.0, math.nan, math.inf, -math.inf, 0.0, -0.0, 2.0, 3.0]


@PROPERTY
@given(block=blocks())
@example(block=([0, (2**31 - 1) * NANOSECONDS + 999_999_999], 'imu_link',
                {name: [ROW[:width]] * 2 for name, width in FIELDS.items()}, True))
@example(block=([-1, 1_700_000_000_123_456_789], '', {
    'orientation': [0.0, 0.0, 0.0, 1.0],
    'orientation_covariance': [-1.0] + [0.0] * 8,
    'angular_velocity': [[math.nan] * 3, [1.0, 2.0, 3.0]],
    'angular_velocity_covariance': [-1.0] + [0.0] * 8,
    'linear_acceleration': [[9.8, -0.0, math.inf]] * 2,
    'linear_acceleration_covariance': ROW}, False))
def test_block_encoder_equals_rosbags_and_decodes_back(block):
    """Every message of a block is rosbags' bytes (any frame id length, any stamp, NaN/inf/-1, both byte orders).

    The block decoder reads the block back as given.
    """
    stamp_list, frame_id, values, little = block
    count = len(stamp_list)
    arrays = {name: np.array(rows, dtype=np.float64).reshape(-1, FIELDS[name])
              if len(rows) != FIELDS[name] or isinstance(rows[0], list) else np.array(rows, dtype=np.float64)
              for name, rows in values.items()}
    raws = encode_imus(np.array(stamp_list, dtype=np.int64), frame_id, **arrays, little_endian=little)
    assert len(raws) == count
    for row, (stamp, raw) in enumerate(zip(stamp_list, raws)):
        per_message = {name: rows[row] if arrays[name].ndim == 2 else rows for name, rows in values.items()}
        assert raw == _reference(stamp, frame_id, per_message, little_endian=little), row
    if count:
        decoded = decode_messages(raws, IMU)
        assert decoded['stamp_ns'].tolist() == stamp_list
        assert decoded.strings('frame_id') == [frame_id] * count
        for name, given_values in arrays.items():
            expected = np.broadcast_to(given_values, (count, FIELDS[name]))
            assert np.array_equal(_bits(decoded[name]), _bits(expected)), name


def test_block_encoder_refuses_a_stamp_outside_int32_seconds_and_a_wrong_shape():
    """`rosbags` cannot serialise seconds beyond int32 either; the encoder names the message."""
    shared = {name: np.zeros(width) for name, width in FIELDS.items()}
    with pytest.raises(CdrError, match='message 2: stamp .* seconds outside int32') as caught:
        encode_imus(np.array([0, 2**31 * NANOSECONDS]), 'imu', **shared)
    assert caught.value.index == 1
    with pytest.raises(CdrError, match=r'linear_acceleration has shape \(2, 2\), expected \(2, 3\) or \(3,\)'):
        encode_imus(np.array([0, 1]), 'imu', **{**shared, 'linear_acceleration': np.zeros((2, 2))})


@pytest.mark.parametrize('little', [True, False])
@pytest.mark.parametrize('frame_id', ['', 'a', 'abcde'])
def test_other_fixed_layout_types_equal_rosbags(frame_id, little):
    """encode_messages serves every fixed-layout type of the decoder.

    Stamped types with per-message and shared values, and std_msgs numbers of every width (no trailing padding, as
    rosbags).
    """
    stamp = TYPES['builtin_interfaces/msg/Time'](sec=1, nanosec=3)
    header = TYPES['std_msgs/msg/Header'](stamp=stamp, frame_id=frame_id)
    vector = encode_messages('geometry_msgs/msg/Vector3Stamped', np.array([5, NANOSECONDS + 3]),
                             {'vector': np.array([[1.0, 2.0, 3.0], [4.0, math.nan, -math.inf]])},
                             {'frame_id': frame_id}, little_endian=little)
    message = TYPES['geometry_msgs/msg/Vector3Stamped'](
        header=header, vector=TYPES['geometry_msgs/msg/Vector3'](4.0, math.nan, -math.inf))
    expected = TYPESTORE.serialize_cdr(message, 'geometry_msgs/msg/Vector3Stamped', little_endian=little)
    assert vector[1] == bytes(expected)
    temperature = encode_messages('sensor_msgs/msg/Temperature', np.array([NANOSECONDS + 3]),
                                  {'temperature': np.array([3.5]), 'variance': 0.25}, {'frame_id': frame_id},
                                  little_endian=little)
    message = TYPES['sensor_msgs/msg/Temperature'](header=header, temperature=3.5, variance=0.25)
    assert temperature == [bytes(TYPESTORE.serialize_cdr(message, 'sensor_msgs/msg/Temperature', little_endian=little))]
    for type_name, value in [('UInt8', 200), ('Int16', -5), ('Float32', 1.5), ('UInt32', 2**32 - 1), ('Int64', -2**60)]:
        msgtype = f'std_msgs/msg/{type_name}'
        raws = encode_messages(msgtype, None, {'data': np.array([value, 0])}, little_endian=little)
        assert raws[0] == bytes(TYPESTORE.serialize_cdr(TYPES[msgtype](data=value), msgtype, little_endian=little))


# ---- tak_calib apply: the bag written with the block encoder equals the per-message one -------------

TINY = replace(SHORT, plateaus_celsius=(10.0, 30.0), plateau_hours=0.02, ramp_celsius_per_minute=20.0, seed=3)


def _apply(root, bag: str, params: str, output: str) -> None:
    assert main(['apply', str(root / bag), '--params', str(root / params), '-o', str(root / output),
                 '--no-progress']) == 0


def _raw_messages(path, topic: str) -> list[tuple[int, bytes]]:
    with Reader(path) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        return [(stamp, bytes(raw)) for _, stamp, raw in reader.messages(connections=connections)]


@pytest.mark.parametrize('output', ['counts', 'imu'])
def test_apply_writes_the_same_messages_with_either_encoder(tmp_path, monkeypatch, output):
    """Counts bag.

    (orientation and rate marked not provided) and driver bag (orientation passed through, rate corrected): every
    field of every message equal with both encoders.
    """
    run = simulate(replace(TINY, output=output, frame_id='imu_link'))
    if output == 'counts':
        write_record(tmp_path / 'bag', run.record)
        save_calibration(tmp_path / 'p.yaml', run.truth)
        topic = bagio.Topics.imu
    else:
        rng = np.random.default_rng(5)
        quaternion = rng.standard_normal((len(run.driver.stamp_ns), 4))
        quaternion /= np.linalg.norm(quaternion, axis=1, keepdims=True)
        covariance = rng.uniform(1e-4, 1e-2, (len(run.driver.stamp_ns), 9))
        write_driver_record(tmp_path / 'bag', replace(run.driver, orientation=quaternion,
                                                      orientation_covariance=covariance))
        save_unit(tmp_path / 'p.yaml', run.unit_truth)
        topic = bagio.Topics.compensated_imu
    _apply(tmp_path, 'bag', 'p.yaml', 'block')
    monkeypatch.setattr(bag_writer, 'IMU_ENCODER', 'rosbags')
    _apply(tmp_path, 'bag', 'p.yaml', 'rosbags')
    got = read_imu_messages(tmp_path / 'block', topic=topic)
    want = read_imu_messages(tmp_path / 'rosbags', topic=topic)
    assert len(got.stamp_ns) == len(want.stamp_ns) > 100
    assert _raw_messages(tmp_path / 'block', topic) == _raw_messages(tmp_path / 'rosbags', topic)
    assert got.frame_ids == want.frame_ids == ['imu_link'] * len(got.stamp_ns)
    for name in ('stamp_ns', *FIELDS):
        assert np.array_equal(_bits(getattr(got, name)) if name != 'stamp_ns' else got.stamp_ns,
                              _bits(getattr(want, name)) if name != 'stamp_ns' else want.stamp_ns), name
