"""A hand-held record as the fit takes it: the samples of its still intervals and of its turns.

The still intervals come from :mod:`~tak_thermo_ros.core.records.still`. A *turn* runs from the
last sample of one still interval to the first sample of the next; its gyroscope samples are
kept whole (the rotation they integrate to needs every one). A turn that crosses a gap in the
stamps is not used (the rotation during the gap is unknown), nor one longer than
:data:`MAX_TURN_S` (the unit was not carried from one rest to the next; the integrated noise
would hide the scale). The still samples are kept every ``stride``-th (of each interval), so
that at most a given budget stays in memory, and beyond as many turn samples every n-th turn is
used; each sample keeps its held temperature.

Both come as :class:`~tak_thermo_ros.core.records.record.AlignedSamples` of six channels
(accelerometer x y z, gyroscope x y z): :func:`sensor_samples` takes one sensor's three.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from tak_thermo_ros.core.records.blocks import add_counts, concatenate
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.core.records.still import StillIntervals
from tak_thermo_ros.core.rotation import hat, tangent_basis
from tak_thermo_ros.core.values import EARTH_RATE

MAX_TURN_S = 60.0
"""The longest turn whose rotation is used, seconds."""
SENSOR_COLUMNS = {'accel': slice(0, 3), 'gyro': slice(3, 6)}


@dataclass(frozen=True)
class HandheldRecord:
    """The still and turn samples of a hand-held record.

    :param intervals: the still intervals found in the record.
    :param still: the kept still samples, six channels, time order.
    :param still_interval: ``(n,)`` the interval of each (indices into ``intervals``).
    :param turn: the turns' samples, six channels, time order (a turn's end samples are the
        still intervals' last and first).
    :param turn_index: ``(m,)`` the turn of each turn sample.
    :param turns: ``(t, 2)`` the still intervals before and after each turn used.
    :param skipped_turns: reason -> turns not used (``gap``, ``long``).
    :param stride: every how many still samples one was kept.
    :param dropped: reason -> samples left out by the alignment.
    :param interval_record: ``(k,)`` for a pool of records (:func:`pooled`), the record each still
        interval comes from (``0 .. records - 1``); ``None``: one record.
    :param record_names: a pool's records, in that numbering.
    :param temperature_track: ``(stamp_ns (t,), celsius (t,))`` the temperature between the kept samples
        too (a pool's long motions: an effect with memory follows the temperature through them), or ``None``.
    """

    intervals: StillIntervals
    still: AlignedSamples
    still_interval: np.ndarray
    turn: AlignedSamples
    turn_index: np.ndarray
    turns: np.ndarray
    skipped_turns: dict[str, int] = field(default_factory=dict)
    stride: int = 1
    dropped: dict[str, int] = field(default_factory=dict)
    interval_record: np.ndarray | None = None
    record_names: tuple[str, ...] = ()
    temperature_track: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def records(self) -> int:
        """The number of power-ups the samples come from (1 unless a pool)."""
        return 1 if self.interval_record is None else max(len(self.record_names), 1)

    @property
    def still_record(self) -> np.ndarray:
        """``(n,)`` the record of each still sample (zeros for one record)."""
        if self.interval_record is None:
            return np.zeros(len(self.still_interval), dtype=np.int64)
        return self.interval_record[self.still_interval]

    def interval_counts(self) -> np.ndarray:
        """``(k,)`` kept still samples per interval."""
        return np.bincount(self.still_interval, minlength=len(self.intervals))

    def turn_seconds(self) -> np.ndarray:
        """``(t,)`` each turn's length, seconds."""
        starts = self.intervals.end_ns[self.turns[:, 0]]
        ends = self.intervals.start_ns[self.turns[:, 1]]
        return (ends - starts) * 1e-9


def numbered_rests(record: HandheldRecord) -> tuple[np.ndarray, int, np.ndarray, np.ndarray]:
    """The intervals that kept a still sample, numbered ``0 .. k - 1``, and the turns between two of them.

    :returns: each still sample's number ``(n,)``, ``k``, each turn's pair of numbers ``(t, 2)`` (``-1``:
        an interval without a kept sample), and whether both of a turn's intervals are numbered ``(t,)``.
    """
    kept, number = np.unique(record.still_interval, return_inverse=True)
    mapping = np.full(len(record.intervals), -1)
    mapping[kept] = np.arange(len(kept))
    pairs = mapping[record.turns] if len(record.turns) else np.zeros((0, 2), dtype=np.int64)
    return number, len(kept), pairs, np.all(pairs >= 0, axis=1)


def rest_records(record: HandheldRecord) -> np.ndarray:
    """``(k,)`` the record of each rest in :func:`numbered_rests`'s numbering (zeros for one record)."""
    kept = np.unique(record.still_interval)
    if record.interval_record is None:
        return np.zeros(len(kept), dtype=np.int64)
    return record.interval_record[kept]


def sensor_samples(samples: AlignedSamples, sensor: str, reference: np.ndarray | None = None) -> AlignedSamples:
    """One sensor's three channels of six-channel samples, with ``reference`` ``(n, 3)`` if given."""
    columns = SENSOR_COLUMNS[sensor]
    return replace(samples, counts=samples.counts[:, columns], reference=reference)


def planned_turns(intervals: StillIntervals, *, budget: int = 10 ** 9) -> tuple[np.ndarray, dict[str, int]]:
    """``(t, 2)`` the pairs of consecutive still intervals whose turn is used, and the others by reason.

    :param budget: keep about this many turn samples at most: beyond it, every n-th turn is used
        (the others are counted as ``budget``).
    """
    pairs = []
    skipped: dict[str, int] = {}
    for before in range(len(intervals) - 1):
        start, end = intervals.end_ns[before], intervals.start_ns[before + 1]
        gaps = intervals.gaps
        if len(gaps) and np.any((gaps[:, 0] >= start) & (gaps[:, 1] <= end)):
            skipped['gap'] = skipped.get('gap', 0) + 1
        elif (end - start) * 1e-9 > MAX_TURN_S:
            skipped['long'] = skipped.get('long', 0) + 1
        else:
            pairs.append((before, before + 1))
    pairs_array = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    if len(pairs_array) and intervals.period_s > 0.0:
        seconds = (intervals.start_ns[pairs_array[:, 1]] - intervals.end_ns[pairs_array[:, 0]]) * 1e-9
        samples = seconds / intervals.period_s
        stride = max(1, math.ceil(float(np.sum(samples + 1.0)) / max(budget, 1)))
        if stride > 1:
            skipped['budget'] = len(pairs_array) - len(pairs_array[::stride])
            pairs_array = pairs_array[::stride]
    return pairs_array, skipped


def still_stride(intervals: StillIntervals, budget: int) -> int:
    """Every how many still samples to keep so that at most about ``budget`` stay."""
    return max(1, math.ceil(int(intervals.samples.sum()) / max(budget, 1)))


class HandheldCollector:
    """Gathers a :class:`HandheldRecord` from aligned six-channel blocks in time order.

    :param intervals: the still intervals (a first pass over the record).
    :param budget: keep at most about this many still samples (every ``stride``-th), and as many
        turn samples (every n-th turn).
    :param turn_budget: keep at most about this many turn samples instead (``None``: ``budget``).
    """

    def __init__(self, intervals: StillIntervals, *, budget: int, turn_budget: int | None = None) -> None:
        self.intervals = intervals
        self.turns, self.skipped = planned_turns(intervals, budget=budget if turn_budget is None else turn_budget)
        self.stride = still_stride(intervals, budget)
        self._turn_start = intervals.end_ns[self.turns[:, 0]] if len(self.turns) else np.zeros(0, dtype=np.int64)
        self._turn_end = intervals.start_ns[self.turns[:, 1]] if len(self.turns) else np.zeros(0, dtype=np.int64)
        self._still: list[AlignedSamples] = []
        self._still_index: list[np.ndarray] = []
        self._turn: list[AlignedSamples] = []
        self._turn_index: list[np.ndarray] = []
        self._seen = 0
        self.dropped: dict[str, int] = {}

    def add(self, aligned: AlignedSamples) -> None:
        """One aligned block (six channels, the temperature held)."""
        add_counts(self.dropped, aligned.dropped)
        if not len(aligned):
            return
        stamps = aligned.stamp_ns
        interval = self.intervals.index_of(stamps)
        order = self._seen + np.arange(len(stamps))
        self._seen += len(stamps)
        keep = (interval >= 0) & (order % self.stride == 0)
        if keep.any():
            self._still.append(_rows(aligned, keep))
            self._still_index.append(interval[keep])
        if len(self.turns):
            position = np.searchsorted(self._turn_start, stamps, side='right') - 1
            inside = (position >= 0) & (stamps <= self._turn_end[np.maximum(position, 0)])
            if inside.any():
                self._turn.append(_rows(aligned, inside))
                self._turn_index.append(position[inside])

    def record(self) -> HandheldRecord:
        """Everything added, the intervals without a kept sample left out."""
        still = concatenate(self._still) if self._still else empty_samples()
        index = np.concatenate(self._still_index) if self._still_index else np.zeros(0, dtype=np.int64)
        turn = concatenate(self._turn) if self._turn else empty_samples()
        turn_index = np.concatenate(self._turn_index) if self._turn_index else np.zeros(0, dtype=np.int64)
        return HandheldRecord(intervals=self.intervals, still=replace(still, dropped=dict(self.dropped)),
                              still_interval=index, turn=turn, turn_index=turn_index, turns=self.turns,
                              skipped_turns=dict(self.skipped), stride=self.stride, dropped=dict(self.dropped))


def _rows(samples: AlignedSamples, mask: np.ndarray) -> AlignedSamples:
    return AlignedSamples(stamp_ns=samples.stamp_ns[mask], counts=samples.counts[mask],
                          temp_code=samples.temp_code[mask], reference=None, dropped={},
                          rows=samples.rows[mask] if samples.rows is not None else np.flatnonzero(mask),
                          aux={name: values[mask] for name, values in samples.aux.items()})


def empty_samples() -> AlignedSamples:
    """No six-channel sample (a record's still or turn samples when it kept none)."""
    return AlignedSamples(stamp_ns=np.zeros(0, dtype=np.int64), counts=np.zeros((0, 6)), temp_code=np.zeros(0),
                          reference=None, dropped={}, rows=np.zeros(0, dtype=np.int64))


def collect(intervals: StillIntervals, samples: AlignedSamples, *, budget: int = 10 ** 9) -> HandheldRecord:
    """A :class:`HandheldRecord` of a record held in memory (:class:`HandheldCollector` in one block)."""
    collector = HandheldCollector(intervals, budget=budget)
    collector.add(samples)
    return collector.record()


@dataclass(frozen=True)
class TurnClosure:
    """How well the turns close: the angle between ``R u_b`` and ``u_a`` per turn, and what noise gives.

    :param angle_rad: ``(t,)`` the angle per turn.
    :param expected_rad: ``(t,)`` its expected RMS from the noise (the two directions and the rate's).
    :param seconds: ``(t,)`` each turn's length.
    """

    angle_rad: np.ndarray
    expected_rad: np.ndarray
    seconds: np.ndarray

    @property
    def rms_rad(self) -> float:
        """RMS angle over the turns (0 without turns)."""
        return float(np.sqrt(np.mean(self.angle_rad ** 2))) if len(self.angle_rad) else 0.0

    @property
    def floor_rad(self) -> float:
        """RMS of the expected angles (what a perfect calibration shows on these turns)."""
        return float(np.sqrt(np.mean(self.expected_rad ** 2))) if len(self.expected_rad) else 0.0


@dataclass(frozen=True)
class ClosureTerms:
    """A turn's closure as a residual: ``r = E_a^T R u_b`` (two components), its covariance from the noise.

    :param residual: ``(t, 2)``; ``basis``: ``(t, 3, 2)`` the tangent vectors ``E_a`` at ``u_a``;
        ``carried``: ``(t, 3)`` ``R u_b``; ``covariance``: ``(t, 2, 2)``; ``closure``: the angles.
    """

    residual: np.ndarray
    basis: np.ndarray
    carried: np.ndarray
    covariance: np.ndarray
    closure: TurnClosure


def closure_terms(rotations: np.ndarray, jacobians: np.ndarray, turn_index: np.ndarray, pairs: np.ndarray,
                  up: np.ndarray, up_noise: np.ndarray, rate_noise: np.ndarray) -> ClosureTerms:
    """Each turn's closure and its covariance: the rate's white noise over the turn and the two directions' errors.

    :param rotations: ``(t, 3, 3)`` what each turn's rates integrate to; ``jacobians``: ``(m, 3, 3)`` per
        turn sample (:func:`~tak_thermo_ros.core.rotation.integrate_segments`).
    :param up: ``(k, 3)`` each interval's up direction; ``up_noise``: ``(k,)`` its error per tangent component.
    :param rate_noise: ``(3,)`` the gyroscope's noise per sample and axis.
    """
    count = len(pairs)
    starts = np.flatnonzero(np.diff(turn_index, prepend=-1) != 0)
    arw = np.zeros((count, 3, 3))
    if len(starts):
        arw[turn_index[starts]] = np.add.reduceat(
            jacobians @ (np.diag(np.asarray(rate_noise, dtype=float) ** 2) @ np.swapaxes(jacobians, 1, 2)),
            starts, axis=0)
    before, after = up[pairs[:, 0]], up[pairs[:, 1]]
    carried = np.einsum('tab,tb->ta', rotations, after)
    basis = tangent_basis(before)
    residual = np.einsum('tab,ta->tb', basis, carried)
    projected = np.einsum('tab,tac->tbc', basis, hat(carried))
    covariance = projected @ arw @ np.swapaxes(projected, 1, 2)
    covariance = covariance + (up_noise[pairs[:, 0]] ** 2 + up_noise[pairs[:, 1]] ** 2)[:, None, None] * np.eye(2)
    angles = np.arctan2(np.linalg.norm(np.cross(carried, before), axis=1), np.sum(carried * before, axis=1))
    closure = TurnClosure(angle_rad=angles, expected_rad=np.sqrt(np.trace(covariance, axis1=1, axis2=2)),
                          seconds=np.zeros(count))
    return ClosureTerms(residual, basis, carried, covariance, closure)


def earth_reference(up: np.ndarray, interval: np.ndarray, latitude: float | None) -> np.ndarray:
    """``(n, 3)`` the rate at rest: zero, or the Earth rate's vertical component along each interval's up direction.

    Only the vertical component is known: the horizontal one needs the heading, which a record
    turned by hand does not give.
    """
    if latitude is None or not len(interval):
        return np.zeros((len(interval), 3))
    return EARTH_RATE * math.sin(math.radians(latitude)) * up[interval]


def merged_samples(record: HandheldRecord) -> tuple[AlignedSamples, np.ndarray, np.ndarray]:
    """The still and turn samples as one series in time order (a turn's end samples once).

    With a ``temperature_track``, its points join the series as samples of their own (zero
    counts), so that what follows the temperature over time sees it between the kept samples.

    :returns: the series, and where each still sample and each turn sample lies in it.
    """
    if record.temperature_track is not None and len(record.temperature_track[0]):
        track_stamps, track_celsius = record.temperature_track
        track = AlignedSamples(stamp_ns=np.asarray(track_stamps, dtype=np.int64),
                               counts=np.zeros((len(track_stamps), record.still.counts.shape[1])),
                               temp_code=np.asarray(track_celsius, dtype=float), reference=None, dropped={},
                               rows=np.zeros(len(track_stamps), dtype=np.int64))
        with_track = replace(record, temperature_track=None,
                             turn=concatenate([replace(record.turn, aux={}), track]) if len(record.turn) else track)
        series, still_rows, turn_rows = merged_samples(with_track)
        return series, still_rows, turn_rows[:len(record.turn)]
    stamps = np.concatenate([record.still.stamp_ns, record.turn.stamp_ns])
    order = np.argsort(stamps, kind='stable')
    _, first, inverse = np.unique(stamps[order], return_index=True, return_inverse=True)
    position = np.empty(len(stamps), dtype=np.int64)
    position[order] = inverse
    rows = order[first]
    names = sorted(set(record.still.aux) & set(record.turn.aux)) if len(record.turn) else sorted(record.still.aux)

    def pick(still: np.ndarray, turn: np.ndarray) -> np.ndarray:
        return np.concatenate([still, turn])[rows]

    series = AlignedSamples(stamp_ns=stamps[rows], counts=pick(record.still.counts, record.turn.counts),
                            temp_code=pick(record.still.temp_code, record.turn.temp_code), reference=None,
                            dropped=dict(record.dropped),
                            aux={name: pick(record.still.aux[name], record.turn.aux.get(name, np.zeros(0)))
                                 for name in names})
    count = len(record.still)
    return series, position[:count], position[count:]


POOL_GAP_NS = 3_600_000_000_000
"""Records whose stamps overlap (a flight log counts from boot) are set one after the other, this far apart."""


def _shifted(record: HandheldRecord, shift: int) -> HandheldRecord:
    """The record with every stamp ``shift`` ns later."""
    if not shift:
        return record
    intervals = replace(record.intervals, start_ns=record.intervals.start_ns + shift,
                        end_ns=record.intervals.end_ns + shift, gaps=record.intervals.gaps + shift,
                        first_ns=None if record.intervals.first_ns is None else record.intervals.first_ns + shift,
                        last_ns=None if record.intervals.last_ns is None else record.intervals.last_ns + shift)
    track = record.temperature_track
    return replace(record, intervals=intervals, still=replace(record.still, stamp_ns=record.still.stamp_ns + shift),
                   turn=replace(record.turn, stamp_ns=record.turn.stamp_ns + shift),
                   temperature_track=None if track is None else (track[0] + shift, track[1]))


def sequential(records: list[HandheldRecord]) -> list[HandheldRecord]:
    """The records in time one after the other: one that starts before the previous ends is moved after it.

    Records on a clock (a bag's) keep their stamps; what has memory over time (an effect's state)
    then never runs across two power-ups as if they overlapped.
    """
    out, end = [], None
    for record in records:
        stamps = np.concatenate([record.still.stamp_ns, record.turn.stamp_ns])
        if not len(stamps):
            out.append(record)
            continue
        shift = 0 if end is None or stamps.min() > end else int(end + POOL_GAP_NS - stamps.min())
        out.append(_shifted(record, shift))
        end = int(stamps.max()) + shift
    return out


def pooled(records: list[HandheldRecord], names: list[str]) -> HandheldRecord:
    """Several records' still and turn samples as one record, each interval knowing its record.

    The records' intervals are numbered on (record 0's first); their noise is the pool's (the
    samples' mean square over the records); a turn stays within its record; records whose stamps
    overlap are set one after the other (:func:`sequential`).
    """
    records = sequential(records)
    offsets = np.cumsum([0] + [len(r.intervals) for r in records])
    parts = [r.intervals for r in records]
    counts = np.array([max(p.count, 1) for p in parts], dtype=float)
    noise = np.sqrt(np.average(np.vstack([p.noise[:6] ** 2 for p in parts]), axis=0, weights=counts))
    firsts = [p.first_ns for p in parts if p.first_ns is not None]
    lasts = [p.last_ns for p in parts if p.last_ns is not None]
    intervals = StillIntervals(
        start_ns=np.concatenate([p.start_ns for p in parts]), end_ns=np.concatenate([p.end_ns for p in parts]),
        samples=np.concatenate([p.samples for p in parts]),
        mean=np.vstack([p.mean[:, :6].reshape(-1, 6) if p.mean.shape[1] >= 6 else
                        np.hstack([p.mean, np.zeros((len(p.mean), 6 - p.mean.shape[1]))]) for p in parts]),
        noise=noise, window_samples=min(p.window_samples for p in parts),
        period_s=float(np.median([p.period_s for p in parts])), windows=sum(p.windows for p in parts),
        still_windows=sum(p.still_windows for p in parts), gaps=np.vstack([p.gaps for p in parts]),
        first_ns=min(firsts) if firsts else None, last_ns=max(lasts) if lasts else None,
        count=sum(p.count for p in parts),
        short_allan=None if any(p.short_allan is None for p in parts) else np.concatenate(
            [p.short_allan[:, :, :6] for p in parts]),  # type: ignore[index]
        short_terms=None if any(p.short_terms is None for p in parts) else np.concatenate(
            [p.short_terms for p in parts]))  # type: ignore[misc]
    turn_offsets = np.cumsum([0] + [len(r.turns) for r in records])
    dropped: dict[str, int] = {}
    skipped: dict[str, int] = {}
    for record in records:
        add_counts(dropped, record.dropped)
        add_counts(skipped, record.skipped_turns)
    # a pool fits no recorded signal (each record may hold others): the samples without them
    still = concatenate([replace(r.still, aux={}) for r in records]) if records else empty_samples()
    turn = concatenate([replace(r.turn, aux={}) for r in records]) if records else empty_samples()
    return HandheldRecord(
        intervals=intervals, still=replace(still, dropped=dict(dropped)),
        still_interval=np.concatenate([r.still_interval + o for r, o in zip(records, offsets)]).astype(np.int64),
        turn=turn,
        turn_index=np.concatenate([r.turn_index + o for r, o in zip(records, turn_offsets)]).astype(np.int64),
        turns=np.vstack([r.turns + o for r, o in zip(records, offsets)]).astype(np.int64).reshape(-1, 2),
        skipped_turns=skipped, stride=max(r.stride for r in records), dropped=dropped,
        interval_record=np.concatenate([np.full(len(r.intervals), i, dtype=np.int64) for i, r in enumerate(records)]),
        record_names=tuple(names),
        temperature_track=None if any(r.temperature_track is None for r in records) else (
            np.concatenate([r.temperature_track[0] for r in records]),  # type: ignore[index]
            np.concatenate([r.temperature_track[1] for r in records])))  # type: ignore[index]


def records_subset(record: HandheldRecord, keep: np.ndarray) -> HandheldRecord:
    """A pool with only the records where ``keep`` ``(records,)`` (their numbers and names kept in order)."""
    keep = np.asarray(keep, dtype=bool)
    if record.interval_record is None:
        return record
    intervals = keep[record.interval_record]
    number = np.cumsum(intervals) - 1
    renumber = np.cumsum(keep) - 1
    still_rows = intervals[record.still_interval]
    turn_keep = intervals[record.turns[:, 0]] if len(record.turns) else np.zeros(0, dtype=bool)
    turn_number = np.cumsum(turn_keep) - 1
    turn_rows = turn_keep[record.turn_index] if len(record.turn_index) else np.zeros(0, dtype=bool)
    parts = record.intervals
    kept = StillIntervals(start_ns=parts.start_ns[intervals], end_ns=parts.end_ns[intervals],
                          samples=parts.samples[intervals], mean=parts.mean[intervals], noise=parts.noise,
                          window_samples=parts.window_samples, period_s=parts.period_s, windows=parts.windows,
                          still_windows=parts.still_windows, gaps=parts.gaps, first_ns=parts.first_ns,
                          last_ns=parts.last_ns, count=parts.count,
                          short_allan=None if parts.short_allan is None else parts.short_allan[intervals],
                          short_terms=None if parts.short_terms is None else parts.short_terms[intervals])
    return replace(record, intervals=kept, still=_rows(record.still, still_rows),
                   still_interval=number[record.still_interval[still_rows]],
                   turn=_rows(record.turn, turn_rows), turn_index=turn_number[record.turn_index[turn_rows]],
                   turns=number[record.turns[turn_keep]].reshape(-1, 2),
                   interval_record=renumber[record.interval_record[intervals]],
                   record_names=tuple(name for name, k in zip(record.record_names, keep) if k))
