"""Bag I/O: round trips in both storages, a table of bad bags, atomic writes."""

from __future__ import annotations

import sqlite3
from dataclasses import replace

import numpy as np
import pytest
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from conftest import SHORT
from tak_thermo_ros.formats.bag import Topics, read_imu, read_record, write_imu, write_record
from tak_thermo_ros.core.records.record import ChannelRecord
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.errors import BagError

TINY = replace(SHORT, plateaus_celsius=(10.0, 30.0), plateau_hours=0.02, ramp_celsius_per_minute=20.0, seed=3)


@pytest.fixture(scope='module')
def tiny_record() -> ChannelRecord:
    """A run of a few hundred samples."""
    return simulate(TINY).record


def _assert_same(read: ChannelRecord, written: ChannelRecord) -> None:
    assert np.array_equal(read.counts_stamp_ns, written.counts_stamp_ns)
    assert np.array_equal(read.counts, written.counts)
    assert np.array_equal(read.temp_stamp_ns, written.temp_stamp_ns)
    assert np.array_equal(read.temp_code, written.temp_code)
    assert np.array_equal(read.reference_stamp_ns, written.reference_stamp_ns)
    assert np.array_equal(read.reference, written.reference)
    assert read.frame_id == written.frame_id
    assert read.nominal_scale == written.nominal_scale


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_record_round_trip(tmp_path, tiny_record, storage):
    """write_record then read_record gives the same arrays, in both storages."""
    path = tmp_path / 'run'
    write_record(path, tiny_record, storage=storage)
    assert len(tiny_record.counts) > 100
    _assert_same(read_record(path, require_reference=True, progress=False), tiny_record)


def test_topic_names_are_options(tmp_path, tiny_record):
    """Other topic names round-trip when given on both sides."""
    topics = Topics(counts='/a/counts', temp_code='/a/t', reference='/a/ref')
    write_record(tmp_path / 'run', tiny_record, topics=topics)
    _assert_same(read_record(tmp_path / 'run', topics=topics, progress=False), tiny_record)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_imu_round_trip(tmp_path, storage):
    """write_imu stores stamps, frame, acceleration and REP 145 covariances."""
    stamps = np.array([1_700_000_000_000_000_000, 1_700_000_000_010_000_000], dtype=np.int64)
    acceleration = np.array([[0.1, -0.2, 9.8], [0.3, 0.4, -9.7]])
    write_imu(tmp_path / 'imu', stamps, 'tak_imu', acceleration, (1e-4, 2e-4, 3e-4), storage=storage)
    got_stamps, got_acc, frames, covariance = read_imu(tmp_path / 'imu')
    assert np.array_equal(got_stamps, stamps) and np.array_equal(got_acc, acceleration)
    assert frames == ['tak_imu', 'tak_imu']
    assert np.array_equal(covariance[0], [1e-4, 0, 0, 0, 2e-4, 0, 0, 0, 3e-4])


def test_existing_output_is_not_overwritten(tmp_path, tiny_record):
    """Writing onto an existing path is refused and leaves it alone."""
    (tmp_path / 'run').mkdir()
    with pytest.raises(BagError, match='exists already, not overwriting'):
        write_record(tmp_path / 'run', tiny_record)
    assert list((tmp_path / 'run').iterdir()) == []


def test_failed_write_leaves_nothing(tmp_path, tiny_record):
    """A write that fails half way leaves neither the bag nor a temporary directory."""
    broken = replace(tiny_record, temp_code=tiny_record.temp_code[:3])  # rows missing: IndexError mid-write
    with pytest.raises(IndexError):
        write_record(tmp_path / 'run', broken)
    assert list(tmp_path.iterdir()) == []


def _bag_with(path, topics: dict[str, tuple[str, list]]) -> None:
    """A bag with given topics: name -> (msgtype, messages)."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with Writer(path, version=9) as writer:
        for topic, (msgtype, messages) in topics.items():
            connection = writer.add_connection(topic, msgtype, typestore=typestore)
            for stamp, message in messages:
                writer.write(connection, stamp, typestore.serialize_cdr(message, msgtype))


def _temperature(stamp: int, code: float):
    types = get_typestore(Stores.ROS2_JAZZY).types
    header = types['std_msgs/msg/Header'](stamp=types['builtin_interfaces/msg/Time'](sec=stamp, nanosec=0),
                                          frame_id='f')
    return types['sensor_msgs/msg/Temperature'](header=header, temperature=code, variance=0.0)


def test_missing_topic(tmp_path, tiny_record):
    """A bag without the temperature topic names the topic and lists what is there."""
    write_record(tmp_path / 'run', tiny_record, topics=Topics(temp_code='/other/temp'))
    with pytest.raises(BagError, match=r'topic /tak/temp_code not found \(topics in the bag: '):
        read_record(tmp_path / 'run', progress=False)


def test_missing_reference_for_a_fit(tmp_path, tiny_record):
    """A calibration read without reference topic says so."""
    write_record(tmp_path / 'run', replace(tiny_record, reference_stamp_ns=np.zeros(0, dtype=np.int64),
                                           reference=np.zeros((0, 3))))
    with pytest.raises(BagError, match='topic /tak/reference not found'):
        read_record(tmp_path / 'run', require_reference=True, progress=False)
    assert not read_record(tmp_path / 'run', progress=False).has_reference


def test_empty_topic(tmp_path):
    """A counts topic without messages is refused."""
    _bag_with(tmp_path / 'run', {'/tak/counts': ('geometry_msgs/msg/Vector3Stamped', []),
                                 '/tak/temp_code': ('sensor_msgs/msg/Temperature', [(1, _temperature(1, 8000.0))])})
    with pytest.raises(BagError, match='no messages on /tak/counts'):
        read_record(tmp_path / 'run', progress=False)


def test_wrong_message_type(tmp_path):
    """A topic of the wrong type is named with both types."""
    _bag_with(tmp_path / 'run', {'/tak/counts': ('sensor_msgs/msg/Temperature', [(1, _temperature(1, 1.0))]),
                                 '/tak/temp_code': ('sensor_msgs/msg/Temperature', [(1, _temperature(1, 8000.0))])})
    with pytest.raises(BagError, match='topic /tak/counts has type sensor_msgs/msg/Temperature, expected '
                                       'geometry_msgs/msg/Vector3Stamped'):
        read_record(tmp_path / 'run', progress=False)


def test_missing_bag(tmp_path):
    """A path that does not exist is named."""
    with pytest.raises(BagError, match='no such bag'):
        read_record(tmp_path / 'absent', progress=False)


def test_directory_without_metadata(tmp_path):
    """A directory that is not a bag is refused with the reader's reason."""
    (tmp_path / 'run').mkdir()
    with pytest.raises(BagError, match=r'run: cannot read bag \('):
        read_record(tmp_path / 'run', progress=False)


@pytest.mark.parametrize(('storage', 'data_file'), [('mcap', 'run.mcap'), ('sqlite3', 'run.db3')])
def test_truncated_bag(tmp_path, tiny_record, storage, data_file):
    """A storage file cut in the middle is refused, not half read, in both storages."""
    write_record(tmp_path / 'run', tiny_record, storage=storage)
    path = tmp_path / 'run' / data_file
    content = path.read_bytes()
    path.write_bytes(content[: len(content) // 2])
    with pytest.raises(BagError, match=r'run: (cannot read bag|.*truncated)'):
        read_record(tmp_path / 'run', progress=False)


def test_sqlite3_with_rows_deleted_is_detected(tmp_path, tiny_record):
    """Fewer messages than the bag's index lists are reported, not silently fitted."""
    write_record(tmp_path / 'run', tiny_record, storage='sqlite3')
    with sqlite3.connect(tmp_path / 'run' / 'run.db3') as connection:
        connection.execute('DELETE FROM messages WHERE id % 2 = 0')
    with pytest.raises(BagError, match='(holds .* of the .* messages its index lists|cannot read bag)'):
        read_record(tmp_path / 'run', progress=False)
