"""Write a bag whose header stamps differ from its bag (receive) times, as a real recorder can."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Writer

from tak_thermo_ros.formats.bag import TEMPERATURE, TYPESTORE, VECTOR3_STAMPED, Topics
from tak_thermo_ros.core.records.record import ChannelRecord
from tak_thermo_ros.core.records.stamps import NANOSECONDS

_types = TYPESTORE.types


def _header(stamp_ns: int, frame_id: str):
    sec, nanosec = divmod(int(stamp_ns), NANOSECONDS)
    return _types['std_msgs/msg/Header'](stamp=_types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec),
                                         frame_id=frame_id)


def write_with_header_stamps(path: Path, record: ChannelRecord, counts_header_ns: np.ndarray, *,
                             storage: str = 'mcap') -> None:
    """Write ``record`` in the bag contract with bag times = the record's stamps.

    (increasing), but the counts messages' header stamps = ``counts_header_ns``.
    """
    from rosbags.rosbag2 import StoragePlugin
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    events = sorted([(int(s), 0, i) for i, s in enumerate(record.temp_stamp_ns)]
                    + [(int(s), 1, i) for i, s in enumerate(record.reference_stamp_ns)]
                    + [(int(s), 2, i) for i, s in enumerate(record.counts_stamp_ns)])
    vector3, stamped, temperature = (_types['geometry_msgs/msg/Vector3'], _types[VECTOR3_STAMPED],
                                     _types[TEMPERATURE])
    topics = Topics()
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        connections = [writer.add_connection(topics.temp_code, TEMPERATURE, typestore=TYPESTORE),
                       writer.add_connection(topics.reference, VECTOR3_STAMPED, typestore=TYPESTORE),
                       writer.add_connection(topics.counts, VECTOR3_STAMPED, typestore=TYPESTORE)]
        for stamp, stream, row in events:
            if stream == 0:
                message = temperature(header=_header(stamp, record.frame_id),
                                      temperature=float(record.temp_code[row]), variance=0.0)
                writer.write(connections[0], stamp, TYPESTORE.serialize_cdr(message, TEMPERATURE))
                continue
            values = record.reference[row] if stream == 1 else record.counts[row]
            header_stamp = stamp if stream == 1 else int(counts_header_ns[row])
            message = stamped(header=_header(header_stamp, record.frame_id),
                              vector=vector3(x=float(values[0]), y=float(values[1]), z=float(values[2])))
            writer.write(connections[stream], stamp, TYPESTORE.serialize_cdr(message, VECTOR3_STAMPED))
