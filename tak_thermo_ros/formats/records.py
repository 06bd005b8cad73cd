"""Every kind of record file read the same way: what it holds, then its messages in blocks.

The commands' passes (:mod:`tak_thermo_ros.streaming`, :mod:`tak_thermo_ros.streaming_mag`,
:mod:`tak_thermo_ros.noise_run`) read a record only through these three functions, so that a new
file format (a flight log, say) is one reader that gives the same
:class:`~tak_thermo_ros.formats.bag.BagStreams` and the same blocks
(:class:`~tak_thermo_ros.core.records.record.ChannelRecord` or
:class:`~tak_thermo_ros.core.records.record.DriverRecord`), and goes through the same fit.
Today every record is a rosbag2 bag (:mod:`tak_thermo_ros.formats.bag`).
"""

from __future__ import annotations

import os
from typing import Iterator

from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.core.records.record import ChannelRecord, DriverRecord


def input_kind(path: str | os.PathLike[str], *, topics) -> InputKind:
    """Which contract a record follows: the paper's channel codes, or a driver's Imu."""
    from tak_thermo_ros.formats.bag import bag_input_kind
    return bag_input_kind(path, topics=topics)


def record_streams(path: str | os.PathLike[str], *, topics, require_reference: bool = False):
    """The kind and message count of each stream of a record, without reading its messages."""
    from tak_thermo_ros.formats.bag import bag_streams
    return bag_streams(path, topics=topics, require_reference=require_reference)


def record_blocks(path: str | os.PathLike[str], *, topics, kind: InputKind, **options
                  ) -> Iterator[ChannelRecord | DriverRecord]:
    """A record's messages in log order, one block per ``block_samples`` main-stream messages."""
    from tak_thermo_ros.formats.bag import iter_blocks
    return iter_blocks(path, topics=topics, kind=kind, **options)
