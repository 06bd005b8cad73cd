"""Every kind of record file read the same way: a :class:`Record`, opened once and handed down.

A command opens each record it names once (:func:`open_record`, near where it parses its
arguments) and hands the :class:`Record` to its passes (:mod:`tak_thermo_ros.passes`); a pool
opens each of its records once. The record works out its format from its first bytes once,
reads a flight log once and holds it, and reads what it holds (:attr:`Record.streams`) once;
each pass then reads its messages in blocks (:meth:`Record.blocks`), as rosbags' ``AnyReader``
gives its connections once and its messages per call. So a new file format is one reader that
gives the same :class:`~tak_thermo_ros.formats.bag.BagStreams` and the same blocks
(:class:`~tak_thermo_ros.core.records.record.ChannelRecord` or
:class:`~tak_thermo_ros.core.records.record.DriverRecord`), and goes through the same fit.

A record is a rosbag2 bag (:mod:`tak_thermo_ros.formats.bag`), a PX4 ULog
(:mod:`tak_thermo_ros.formats.ulog`) or an ArduPilot DataFlash log
(:mod:`tak_thermo_ros.formats.dataflash`), told apart by their first bytes; a flight log's
sensor instance is ``topics.instance`` (``--instance N``). Nothing is read when it is opened:
each part is read when first asked for, so that a record that cannot be read says so where the
command first reads it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import cached_property
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


def open_record(path: str | os.PathLike[str], *, topics) -> Record:
    """The record at ``path``, opened once: the one way into a record (see the module's description).

    :param topics: the record's topic names and a flight log's instance
        (:class:`~tak_thermo_ros.formats.bag.Topics`).
    """
    return Record(path, topics)


class Record:
    """One record file opened: its format, what it holds and its messages in blocks (:func:`open_record`).

    Each part is read once, when first asked for, and kept: the format (first bytes), a flight
    log (:class:`~tak_thermo_ros.formats.flight_log.FlightLog`, the whole file), a bag's kind and
    streams (its index); the messages are read by each pass (:meth:`blocks`).

    :param path: the file or bag directory (``str()`` of the record, and its ``os.fspath``: as the user spelled
        it, so that a command's record goes where a path goes, a pool's list of records).
    :param topics: its topic names and a flight log's instance.
    """

    def __init__(self, path: str | os.PathLike[str], topics) -> None:
        self.path = Path(path)
        self.topics = topics
        self._spelled = os.fspath(path)

    def __str__(self) -> str:
        return self._spelled

    def __fspath__(self) -> str:
        return self._spelled

    def __repr__(self) -> str:
        return f'Record({self._spelled!r})'

    @cached_property
    def format(self) -> str:
        """``'bag'``, ``'ulog'`` or ``'dataflash'`` (by its first bytes).

        :raises FlightLogError: a file named as a flight log (``.ulg``, ``.bin``) that is none.
        """
        return flight_log_format(self.path) or 'bag'

    @cached_property
    def log(self):
        """The record as a :class:`~tak_thermo_ros.formats.flight_log.FlightLog` (read once), ``None`` for a bag."""
        if self.format == 'bag':
            return None
        instance = int(getattr(self.topics, 'instance', 0))
        if self.format == 'ulog':
            from tak_thermo_ros.formats.ulog import read_ulog
            return read_ulog(self.path, instance)
        from tak_thermo_ros.formats.dataflash import read_dataflash
        return read_dataflash(self.path, instance)

    @cached_property
    def kind(self) -> InputKind:
        """Which contract it follows: the paper's channel codes, or a driver's Imu (a flight log)."""
        if self.log is not None:
            return InputKind.IMU
        from tak_thermo_ros.formats.bag import bag_input_kind
        return bag_input_kind(self.path, topics=self.topics)

    @cached_property
    def streams(self):
        """The kind and message count of each stream (a :class:`~tak_thermo_ros.formats.bag.BagStreams`), unread."""
        if self.log is not None:
            return self.log.streams()
        from tak_thermo_ros.formats.bag import bag_streams
        return bag_streams(self.path, topics=self.topics, kind=self.kind)

    @cached_property
    def reference_refusal(self) -> str | None:
        """Why a fit cannot take a counts bag's reference, in the bag's words; ``None``: it can, or needs none.

        A counts bag without messages on its reference topic: the topic missing (the bag's topics named)
        or empty, worded from its index when first asked for (:func:`~tak_thermo_ros.formats.bag.bag_streams`).
        A driver record and a flight log need no reference topic (the passes take them without): ``None``.
        A pass that requires the reference raises :class:`~tak_thermo_ros.errors.BagError` with it.
        """
        if self.log is not None or self.kind is not InputKind.COUNTS or self.streams.reference:
            return None
        from tak_thermo_ros.errors import BagError
        from tak_thermo_ros.formats.bag import bag_streams
        try:
            bag_streams(self.path, topics=self.topics, kind=self.kind, require_reference=True)
        except BagError as err:
            return str(err)
        return None  # pragma: no cover - a reference counted 0 is refused by bag_streams

    def blocks(self, *, kind: InputKind, **options) -> Iterator[ChannelRecord | DriverRecord]:
        """Its messages in log order, one block per ``block_samples`` main-stream messages (one pass).

        :param options: as :func:`~tak_thermo_ros.formats.bag.iter_blocks`'s (a flight log takes ``block_samples``).
        """
        from tak_thermo_ros.formats.bag import STREAM_BLOCK_SAMPLES, iter_blocks
        if self.log is not None:
            yield from self.log.blocks(int(options.get('block_samples', STREAM_BLOCK_SAMPLES)))
            return
        yield from iter_blocks(self.path, topics=self.topics, kind=kind, streams=self.streams, **options)

    @property
    def stream_list(self) -> tuple[tuple[str, str, int], ...] | None:
        """A flight log's streams, each sensor on its own (:meth:`FlightLog.stream_list`); ``None`` for a bag."""
        return None if self.log is None else self.log.stream_list()

    @property
    def source(self) -> dict[str, object] | None:
        """What a calibration file records of a flight log (format, instance, device IDs), ``None`` for a bag."""
        return None if self.log is None else self.log.source()

    @property
    def lines(self) -> tuple[str, ...]:
        """What the reader of a flight log says about it (one statement each); nothing for a bag."""
        return () if self.log is None else self.log.lines

    @cached_property
    def identity(self) -> RecordIdentity | None:
        """Its :class:`RecordIdentity` from its streams and its first block; ``None``: it cannot be read.

        Reads :data:`IDENTITY_SAMPLES` messages, not the record (a record that cannot be read says why when read).
        """
        from tak_thermo_ros.core.records.provenance import PrintCollector
        from tak_thermo_ros.errors import TakError
        try:
            streams = self.streams
            blocks = self.blocks(kind=streams.kind, block_samples=IDENTITY_SAMPLES, references=False,
                                 progress=False)
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
        head = collector.finish(str(self.path))
        if head is None:
            return None
        return RecordIdentity(kind=streams.kind.value, messages=int(streams.main), end_ns=int(streams.end_ns),
                              first_stamp_ns=head.first_stamp_ns, digest=head.digest)


@dataclass(frozen=True)
class RecordIdentity:
    """A record known by its content, not its spelling (:attr:`Record.identity`).

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
