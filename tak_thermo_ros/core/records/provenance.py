"""What a calibration was fitted from, and whether a record is (part of) it: in-sample or not.

A calibration file keeps one :class:`RecordPrint` per record it was fitted from (``fitted_from``):
the record's first and last stamps, its samples per sensor, a digest of every sample (each
sensor's stamps and values, in record order, whatever the blocks a reader cut them into), and
short digests of the samples in equal time segments of it. :class:`PrintCollector` gathers the
same from the blocks of any pass (``fit``, ``validate``, ``diagnose``), so recognising a record
costs no pass of its own.

:func:`recognise` then says whether a record is the one a calibration was fitted from (the same
digest), a part of it (its stamps inside the fitted span, and every time segment it covers whole
holds the same samples), overlaps it, or is another record. A file written before the print
existed holds none: no claim either way.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

DIGEST_HEX = 32
"""Hex digits kept of a record's SHA-256 digest (128 bits)."""
SEGMENT_HEX = 8
"""Hex digits kept of a segment's digest (32 bits: one chance in four billion that two differ unseen)."""
MAX_SEGMENTS = 64
"""A record's time segments: the finest power-of-two length in nanoseconds that cuts it into at most this many."""
SEGMENT_LEVELS = range(20, 51)
"""Segment lengths ``2**k`` ns tried: about 1 ms to 13 days."""
NO_SEGMENT = '-'
"""A segment without samples in a print's ``segments``."""
_SAMPLE = np.dtype([('stamp', '<i8'), ('value', '<f8', (3,))])


@dataclass(frozen=True)
class RecordPrint:
    """Enough of one record to recognise it again.

    :param name: the record's file name (for messages; not compared: the same record renamed, or in
        another storage, has the same print).
    :param first_stamp_ns: the earliest sample stamp of any sensor; ``last_stamp_ns`` the latest.
    :param samples: ``(sensor, count)`` of each sensor's samples in the record.
    :param digest: SHA-256 (first :data:`DIGEST_HEX` hex digits) of every sensor's samples.
    :param segment_ns: the length of the time segments (a power of two, ns).
    :param segment_first: the index ``stamp // segment_ns`` of the first segment.
    :param segments: per segment from the first, its digest (:data:`SEGMENT_HEX` hex digits), or
        :data:`NO_SEGMENT` when no sample falls in it.
    """

    name: str = field(compare=False)
    first_stamp_ns: int
    last_stamp_ns: int
    samples: tuple[tuple[str, int], ...]
    digest: str
    segment_ns: int
    segment_first: int
    segments: tuple[str, ...]

    @property
    def duration_s(self) -> float:
        """Seconds from the first stamp to the last."""
        return (self.last_stamp_ns - self.first_stamp_ns) * 1e-9

    def segment_digests(self) -> dict[int, str]:
        """Segment index -> digest, for the segments that hold samples."""
        return {self.segment_first + i: digest for i, digest in enumerate(self.segments) if digest != NO_SEGMENT}


def _sample_bytes(stamp_ns: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The samples as one record array: each stamp beside its three values (the bytes hashed)."""
    rows = np.empty(len(stamp_ns), dtype=_SAMPLE)
    rows['stamp'] = np.asarray(stamp_ns, dtype=np.int64)
    rows['value'] = np.asarray(values, dtype=float).reshape(-1, 3)
    return rows


class _Level:
    """Per-segment hashers of one segment length (per sensor)."""

    def __init__(self, shift: int) -> None:
        self.length = 1 << shift
        self.hashers: dict[int, dict[str, Any]] = {}

    def add(self, sensor: str, stamp_ns: np.ndarray, rows: np.ndarray, *, limit: tuple[int, int] | None) -> None:
        index = np.floor_divide(stamp_ns, self.length)
        keep = np.ones(len(index), dtype=bool) if limit is None else (index >= limit[0]) & (index < limit[1])
        if not keep.any():
            return
        index, rows = index[keep], rows[keep]
        order = np.argsort(index, kind='stable')
        index, rows = index[order], rows[order]
        cuts = np.flatnonzero(np.diff(index)) + 1
        for start, stop in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [len(index)]])):
            hashers = self.hashers.setdefault(int(index[start]), {})
            hashers.setdefault(sensor, hashlib.sha256()).update(rows[start:stop].tobytes())

    def digests(self, sensors: Sequence[str]) -> dict[int, str]:
        out = {}
        for index, hashers in self.hashers.items():
            joined = hashlib.sha256()
            for sensor in sensors:
                joined.update(hashers[sensor].digest() if sensor in hashers else b'')
            out[index] = joined.hexdigest()[:SEGMENT_HEX]
        return out


@dataclass
class PrintCollector:
    """The print of a record from its blocks, in any pass (:meth:`add` each block's sensors).

    :param sensors: the sensors hashed, in this order (``('accel',)`` or ``('accel', 'gyro')``).
    :param against: prints of records a calibration was fitted from: the segments of this record
        are also hashed on each one's grid (:func:`recognise`).
    :param own_segments: hash this record's own time segments for its print (a fit writes them);
        ``False`` to recognise it only (its whole digest and the grids of ``against``).
    """

    sensors: tuple[str, ...]
    against: Sequence[RecordPrint] = ()
    own_segments: bool = True
    _whole: dict[str, Any] = field(default_factory=dict)
    _counts: dict[str, int] = field(default_factory=dict)
    _first: int | None = None
    _last: int | None = None
    _levels: dict[int, _Level] = field(default_factory=dict)
    _grids: list[tuple[_Level, tuple[int, int]]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._whole = {sensor: hashlib.sha256() for sensor in self.sensors}
        self._counts = {sensor: 0 for sensor in self.sensors}
        self._levels = {shift: _Level(shift) for shift in SEGMENT_LEVELS} if self.own_segments else {}
        for stored in self.against:
            level = _Level(max(int(stored.segment_ns), 1).bit_length() - 1)
            self._grids.append((level, (stored.segment_first, stored.segment_first + len(stored.segments))))

    def add(self, channels: Mapping[str, object]) -> None:
        """One block: per sensor a record with ``counts_stamp_ns`` and ``counts`` (``(k, 3)``)."""
        for sensor in self.sensors:
            channel = channels.get(sensor)
            if channel is None:
                continue
            stamps = np.asarray(channel.counts_stamp_ns, dtype=np.int64)  # type: ignore[attr-defined]
            if not len(stamps):
                continue
            rows = _sample_bytes(stamps, channel.counts)  # type: ignore[attr-defined]
            self._whole[sensor].update(rows.tobytes())
            self._counts[sensor] += len(stamps)
            low, high = int(stamps.min()), int(stamps.max())
            self._first = low if self._first is None else min(self._first, low)
            self._last = high if self._last is None else max(self._last, high)
            for shift in list(self._levels):
                level = self._levels[shift]
                first, last = low // level.length, high // level.length
                if level.hashers:
                    first, last = min(first, min(level.hashers)), max(last, max(level.hashers))
                if last - first >= MAX_SEGMENTS:
                    # too fine for this record: its segments (every one from the first to the last, empty
                    # ones too) would be too many; a record that spans years keeps its whole digest only
                    del self._levels[shift]
                    continue
                level.add(sensor, stamps, rows, limit=None)
            for level, limit in self._grids:
                level.add(sensor, stamps, rows, limit=limit)

    @property
    def first_stamp_ns(self) -> int | None:
        """The earliest sample stamp seen so far (``None``: none)."""
        return self._first

    def finish(self, name: str) -> RecordPrint | None:
        """The record's print (``None`` when it holds no samples)."""
        if self._first is None or self._last is None:
            return None
        joined = hashlib.sha256()
        for sensor in self.sensors:
            joined.update(self._whole[sensor].digest())
        level = self._levels[min(self._levels)] if self._levels else _Level(max(SEGMENT_LEVELS))
        digests = level.digests(self.sensors)
        first = min(digests) if digests else self._first // level.length
        last = max(digests) if digests else first
        segments = tuple(digests.get(index, NO_SEGMENT) for index in range(first, last + 1))
        return RecordPrint(name=name, first_stamp_ns=self._first, last_stamp_ns=self._last,
                           samples=tuple((sensor, self._counts[sensor]) for sensor in self.sensors),
                           digest=joined.hexdigest()[:DIGEST_HEX], segment_ns=level.length, segment_first=first,
                           segments=segments)

    def segments_against(self) -> list[dict[int, str]]:
        """Per print of :attr:`against`, this record's segment digests on its grid."""
        return [level.digests(self.sensors) for level, _ in self._grids]

    def recognition(self, name: str) -> Recognition | None:
        """Whether this record is (part of) one of :attr:`against` (:func:`recognise`)."""
        return recognise(self.against, self.finish(name), self.segments_against())


IN_SAMPLE_WHOLE = 'whole'
IN_SAMPLE_PART = 'part'
IN_SAMPLE_OVERLAP = 'overlap'
IN_SAMPLE_SPAN = 'span'


@dataclass(frozen=True)
class Recognition:
    """How a record relates to one a calibration was fitted from.

    :param kind: :data:`IN_SAMPLE_WHOLE` (the same samples), :data:`IN_SAMPLE_PART` (inside the
        fitted span, every segment compared the same), :data:`IN_SAMPLE_OVERLAP` (partly inside,
        every segment of the overlap compared the same), :data:`IN_SAMPLE_SPAN` (inside the fitted
        span, too short to compare a whole segment: may be in-sample).
    :param fitted: the print of the record the calibration was fitted from.
    :param overlap_s: seconds of this record inside the fitted record's span.
    :param duration_s: this record's length, seconds.
    :param start_s: where the overlap starts, seconds after the fitted record's first stamp.
    :param compared: segments compared (each held whole by this record).
    """

    kind: str
    fitted: RecordPrint
    overlap_s: float
    duration_s: float
    start_s: float
    compared: int

    def as_dict(self) -> dict[str, object]:
        """For ``--json``."""
        return {'kind': self.kind, 'fitted_from': self.fitted.name, 'overlap_s': self.overlap_s,
                'duration_s': self.duration_s, 'start_s': self.start_s, 'segments_compared': self.compared}


def recognise(fitted_from: Sequence[RecordPrint], seen: RecordPrint | None,
              segments: Sequence[Mapping[int, str]]) -> Recognition | None:
    """Whether ``seen`` is, or holds part of, a record of ``fitted_from``; ``None``: another record.

    :param segments: per print of ``fitted_from``, ``seen``'s segment digests on its grid
        (:meth:`PrintCollector.segments_against`).
    """
    if seen is None:
        return None
    for stored in fitted_from:
        if seen.digest == stored.digest:
            return Recognition(IN_SAMPLE_WHOLE, stored, seen.duration_s, seen.duration_s, 0.0, len(stored.segments))
    for stored, own in zip(fitted_from, segments):
        low, high = max(seen.first_stamp_ns, stored.first_stamp_ns), min(seen.last_stamp_ns, stored.last_stamp_ns)
        if low > high:
            continue
        # Only the segments both records hold whole: those strictly inside the stamps they share (a
        # record that holds the fitted one and more differs from it in the fitted one's edge segments).
        first = low // stored.segment_ns + 1
        last = high // stored.segment_ns
        reference = stored.segment_digests()
        inner = [index for index in range(first, last) if index in reference or index in own]
        if any(reference.get(index) != own.get(index) for index in inner):
            continue
        inside = seen.first_stamp_ns >= stored.first_stamp_ns and seen.last_stamp_ns <= stored.last_stamp_ns
        shorter = (seen.first_stamp_ns, seen.last_stamp_ns) != (stored.first_stamp_ns, stored.last_stamp_ns)
        if inner:
            kind = IN_SAMPLE_PART if inside else IN_SAMPLE_OVERLAP
        elif inside and shorter and seen.last_stamp_ns - seen.first_stamp_ns < 2 * stored.segment_ns:
            kind = IN_SAMPLE_SPAN
        else:
            continue
        return Recognition(kind, stored, (high - low) * 1e-9, seen.duration_s,
                           (low - stored.first_stamp_ns) * 1e-9, len(inner))
    return None


IN_SAMPLE_MEANS = {
    'validate': 'so "after" is the fit\'s own residual: it does not show the error on a record never fitted',
    'diagnose': 'its residual RMS is the fit\'s own and its held-out blocks are of it: no word on a new record',
}
"""What an in-sample figure does and does not show, per command (the second line)."""


def pool_in_sample_lines(found: Sequence[tuple[str, Recognition | None]], *, params: str, command: str,
                         records: int) -> list[str]:
    """The first lines of ``validate`` of a pool that holds records a calibration was fitted from (none otherwise).

    :param found: each record's name and :func:`recognise` (``None``: not one of them).
    :param records: how many records the calibration was fitted from.
    """
    inside = [(name, recognition) for name, recognition in found if recognition is not None]
    if len(found) == 1 or not inside:
        return [] if not inside else in_sample_lines(inside[0][1], record=inside[0][0], params=params,
                                                     command=command, records=records)
    if len(inside) == len(found) and all(recognition.kind == IN_SAMPLE_WHOLE for _, recognition in inside):
        fitted = 'the pool' if len(found) == records else f'{len(found)} of the {records} records'
        first = f'in-sample: these {len(found)} records are {fitted} {params} was fitted from (the same samples)'
    else:
        names = ', '.join(name for name, _ in inside[:3]) + (', ...' if len(inside) > 3 else '')
        verb = 'holds' if len(inside) == 1 else 'hold'
        first = (f'in-sample: {len(inside)} of the {len(found)} records {verb} samples {params} was fitted from '
                 f'({names})')
    return [first, f'  {IN_SAMPLE_MEANS[command]}']


def in_sample_lines(found: Recognition | None, *, record: str, params: str, command: str,
                    records: int = 1) -> list[str]:
    """The first lines of ``validate`` and ``diagnose`` of a record a calibration was fitted from (none otherwise).

    :param records: how many records the calibration was fitted from (a pool: one of them).
    """
    if found is None:
        return []
    fitted = found.fitted.name
    if found.kind == IN_SAMPLE_WHOLE:
        which = 'the record' if records == 1 else f'one of the {records} records'
        first = f'in-sample: {record} is {which} {params} was fitted from (the same samples)'
    elif found.kind == IN_SAMPLE_PART:
        start = found.start_s / 60.0
        first = (f'in-sample: {record} is {start:.1f}..{start + found.overlap_s / 60.0:.1f} min of {fitted}, '
                 f'which {params} was fitted from')
    elif found.kind == IN_SAMPLE_OVERLAP:
        first = (f'in-sample: {found.overlap_s / 60.0:.1f} of the {found.duration_s / 60.0:.1f} min of {record} '
                 f'are from {fitted}, which {params} was fitted from')
    else:
        first = (f'may be in-sample: {record} lies inside {fitted}, which {params} was fitted from (too short '
                 f'to compare)')
    return [first, f'  {IN_SAMPLE_MEANS[command]}']
