"""Bag I/O: the only package that imports rosbags; this ``__init__`` names its public API.

As rosbags' own ``rosbag2/__init__.py`` does, the names the rest of the package, the tests and
the benches use are imported here (``from tak_thermo_ros.formats.bag import write_record``); each
lives in one of the modules:

- :mod:`~tak_thermo_ros.formats.bag.contract`: the topic names (:class:`Topics`), message types
  and the rosbags typestore;
- :mod:`~tak_thermo_ros.formats.bag.reader`: whole-file reading (a record's streams into whole
  arrays, an Imu topic, a topic chunk by chunk);
- :mod:`~tak_thermo_ros.formats.bag.blocks`: reading blocks (what a bag holds, its messages in
  log order, a block at a time, for the streamed passes);
- :mod:`~tak_thermo_ros.formats.bag.decoding`: serialised messages into arrays, shared by the two
  readers;
- :mod:`~tak_thermo_ros.formats.bag.writer`: writing (a record in the bag contract, corrected Imu
  messages whole or block by block, atomically) and the order ``tak_calib play`` publishes in.

A setting a test changes (``CHUNK_MESSAGES``, ``IMU_ENCODER``) is read where it lives: patch it
in its module, not here.
"""

from tak_thermo_ros.formats.bag.blocks import STREAM_BLOCK_SAMPLES, BagStreams, bag_streams, iter_blocks
from tak_thermo_ros.formats.bag.contract import (
    IMU,
    MAGNETIC_FIELD,
    NOMINAL_SCALE_KEY,
    TEMPERATURE,
    TYPESTORE,
    VECTOR3_STAMPED,
    Topics,
)
from tak_thermo_ros.formats.bag.reader import (
    DECODERS,
    ImuMessages,
    bag_input_kind,
    iter_topic_arrays,
    read_driver_record,
    read_imu,
    read_imu_messages,
    read_record,
)
from tak_thermo_ros.formats.bag.writer import (
    AUX_TYPES,
    ENCODERS,
    STORAGES,
    ImuBagWriter,
    ImuRows,
    imu_messages,
    play_order,
    write_driver_record,
    write_imu,
    write_record,
)

__all__ = [
    'AUX_TYPES', 'DECODERS', 'ENCODERS', 'IMU', 'MAGNETIC_FIELD', 'NOMINAL_SCALE_KEY', 'STORAGES',
    'STREAM_BLOCK_SAMPLES', 'TEMPERATURE', 'TYPESTORE', 'VECTOR3_STAMPED', 'BagStreams', 'ImuBagWriter',
    'ImuMessages', 'ImuRows', 'Topics', 'bag_input_kind', 'bag_streams', 'imu_messages', 'iter_blocks',
    'iter_topic_arrays', 'play_order', 'read_driver_record', 'read_imu', 'read_imu_messages', 'read_record',
    'write_driver_record', 'write_imu', 'write_record',
]
