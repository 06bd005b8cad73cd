"""Every kind of record file read the same way: what it holds, then its messages in blocks.

The commands' passes (:mod:`tak_thermo_ros.passes`, :mod:`tak_thermo_ros.passes.magnetometer`,
:mod:`tak_thermo_ros.passes.noise`) read a record only through these functions, so that a new
file format is one reader that gives the same :class:`~tak_thermo_ros.formats.bag.BagStreams`
and the same blocks (:class:`~tak_thermo_ros.core.records.record.ChannelRecord` or
:class:`~tak_thermo_ros.core.records.record.DriverRecord`), and goes through the same fit.

A record is a rosbag2 bag (:mod:`tak_thermo_ros.formats.bag`), a PX4 ULog
(:mod:`tak_thermo_ros.formats.ulog`) or an ArduPilot DataFlash log
(:mod:`tak_thermo_ros.formats.dataflash`), told apart by their first bytes; a flight log's
sensor instance is ``topics.instance`` (``--instance N``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.core.records.record import ChannelRecord, DriverRecord

LOG_SUFFIXES = ('.ulg', '.bin')
"""A file named so is meant as a flight log: one that is none is refused as such, not taken for a bag."""
IDENTITY_SAMPLES = 256
"""A record's identity digests the first this many samples of each of its sensors (stamps and values)."""


def flight_log_format(path: str | os.PathLike[str]) -> str | None:
    """``'ulog'`` or ``'dataflash'`` for a flight log (by its first bytes), ``None`` for anything else (a bag)."""
    from tak_thermo_ros.formats.dataflash import is_dataflash
    from tak_thermo_ros.formats.ulog import is_ulog
    if is_ulog(path):
        return 'ulog'
    if is_dataflash(path):
        return 'dataflash'
    if Path(path).suffix.lower() in LOG_SUFFIXES and not Path(path).is_dir():
        from tak_thermo_ros.errors import FlightLogError
        what = 'no such file' if not Path(path).exists() else 'neither a ULog nor a DataFlash log (its first bytes)'
        msg = f'{path}: {what}'
        raise FlightLogError(msg)
    return None


def flight_log(path: str | os.PathLike[str], *, topics):
    """The record as a :class:`~tak_thermo_ros.formats.flight_log.FlightLog`, or ``None`` when it is a bag."""
    kind = flight_log_format(path)
    if kind is None:
        return None
    instance = int(getattr(topics, 'instance', 0))
    if kind == 'ulog':
        from tak_thermo_ros.formats.ulog import read_ulog
        return read_ulog(path, instance)
    from tak_thermo_ros.formats.dataflash import read_dataflash
    return read_dataflash(path, instance)


def input_kind(path: str | os.PathLike[str], *, topics) -> InputKind:
    """Which contract a record follows: the paper's channel codes, or a driver's Imu (a flight log)."""
    if flight_log(path, topics=topics) is not None:
        return InputKind.IMU
    from tak_thermo_ros.formats.bag import bag_input_kind
    return bag_input_kind(path, topics=topics)


def record_streams(path: str | os.PathLike[str], *, topics, require_reference: bool = False):
    """The kind and message count of each stream of a record, without reading its messages."""
    log = flight_log(path, topics=topics)
    if log is not None:
        return log.streams()
    from tak_thermo_ros.formats.bag import bag_streams
    return bag_streams(path, topics=topics, require_reference=require_reference)


def record_blocks(path: str | os.PathLike[str], *, topics, kind: InputKind, **options
                  ) -> Iterator[ChannelRecord | DriverRecord]:
    """A record's messages in log order, one block per ``block_samples`` main-stream messages."""
    log = flight_log(path, topics=topics)
    if log is not None:
        from tak_thermo_ros.formats.bag import STREAM_BLOCK_SAMPLES
        yield from log.blocks(int(options.get('block_samples', STREAM_BLOCK_SAMPLES)))
        return
    from tak_thermo_ros.formats.bag import iter_blocks
    yield from iter_blocks(path, topics=topics, kind=kind, **options)


def record_stream_list(path: str | os.PathLike[str], *, topics) -> tuple[tuple[str, str, int], ...] | None:
    """A flight log's streams, each sensor on its own (:meth:`FlightLog.stream_list`); ``None`` for a bag."""
    log = flight_log(path, topics=topics)
    return None if log is None else log.stream_list()


def record_source(path: str | os.PathLike[str], *, topics) -> dict[str, object] | None:
    """What a calibration file records of a flight log (format, instance, device IDs), ``None`` for a bag."""
    log = flight_log(path, topics=topics)
    return None if log is None else log.source()


def record_lines(path: str | os.PathLike[str], *, topics) -> tuple[str, ...]:
    """What the reader of a flight log says about it (one statement each); nothing for a bag."""
    log = flight_log(path, topics=topics)
    return () if log is None else log.lines


@dataclass(frozen=True)
class RecordIdentity:
    """A record known by its content, not its spelling (:func:`record_identity`).

    The same messages under another path, through a link, copied, renamed, in another bag storage
    (a bag's ``.mcap`` beside its folder) or another log format (one flight as ``.ulg`` and ``.bin``)
    have the same identity; a record cut shorter or longer, or another power-up, has another.

    :param kind: the paper's channel codes or a driver's Imu.
    :param messages: messages on its main stream (the counts or Imu topic; a flight log's accelerometer).
    :param end_ns: when its last message was logged (a bag's log time; a flight log's last stamp).
    :param first_stamp_ns: its first sample's stamp.
    :param digest: SHA-256 (32 hex digits) of its first :data:`IDENTITY_SAMPLES` samples of each sensor as
        read (stamps and values: :class:`~tak_thermo_ros.core.records.provenance.PrintCollector`).
    """

    kind: str
    messages: int
    end_ns: int
    first_stamp_ns: int
    digest: str


@dataclass(frozen=True)
class _Head:
    """The first samples of one sensor, as :class:`~tak_thermo_ros.core.records.provenance.PrintCollector` reads."""

    counts_stamp_ns: object
    counts: object


def record_identity(path: str | os.PathLike[str], *, topics, streams=None) -> RecordIdentity | None:
    """A record's :class:`RecordIdentity` from its streams and its first block; ``None``: it cannot be read.

    Reads :data:`IDENTITY_SAMPLES` messages, not the record (a record that cannot be read says why when read).

    :param streams: its :func:`record_streams`, when known.
    """
    from tak_thermo_ros.core.records.provenance import PrintCollector
    from tak_thermo_ros.errors import TakError
    try:
        streams = streams if streams is not None else record_streams(path, topics=topics)
        blocks = record_blocks(path, topics=topics, kind=streams.kind, block_samples=IDENTITY_SAMPLES,
                               references=False, progress=False)
        try:
            first = next(blocks, None)
        finally:
            blocks.close()  # type: ignore[attr-defined]
    except TakError:
        return None
    if first is None:
        return None
    sensors = ('accel',) if streams.kind is InputKind.COUNTS else ('accel', 'gyro')
    channels = {'accel': first} if streams.kind is InputKind.COUNTS else {
        sensor: first.channel(sensor) for sensor in sensors}  # type: ignore[union-attr]
    collector = PrintCollector(sensors, own_segments=False)
    collector.add({sensor: _Head(channel.counts_stamp_ns[:IDENTITY_SAMPLES], channel.counts[:IDENTITY_SAMPLES])
                   for sensor, channel in channels.items()})
    head = collector.finish(str(path))
    if head is None:
        return None
    return RecordIdentity(kind=streams.kind.value, messages=int(streams.main), end_ns=int(streams.end_ns),
                          first_stamp_ns=head.first_stamp_ns, digest=head.digest)
