"""``tak_calib``'s pass over a pool of records: the rests of many records of one unit, each read once.

Weeks of ordinary records (bags, CSV-made bags, ULogs, DataFlash logs, mixed; a directory of them
too) are one more kind of record: each is read once (its blocks kept when it is small enough,
:data:`~tak_thermo_ros.passes.run.SURVEY_REPLAY_SAMPLES`), its rests found from the record itself
(:mod:`~tak_thermo_ros.core.records.still`), its rest and turn samples kept within a share of
the pool's budget (:class:`~tak_thermo_ros.core.records.handheld.HandheldCollector`), and the
records' samples pooled with a record index (:func:`~tak_thermo_ros.core.records.handheld.pooled`):
the same aligned samples the hand-held fit takes, through the same fit
(:func:`~tak_thermo_ros.core.fit.pool.fit_pool`). A flight log whose sensors come at their own
stamps gives its rests only (the gyroscope held on the accelerometer's stamps: at rest it does not
move; its motions are not integrated). A firmware's corrections are undone by the readers, as
for one record.

A record that is not one unit's is never pooled silently: a flight log whose sensors' device IDs
differ from the pool's is left out (a pool of two devices in equal numbers is refused), and the
fit leaves out a record whose turn-on offset lies far beyond the pool's spread. A record without
a rest, or without a temperature, contributes nothing and says

The pool's other rooms: finding its records (:mod:`~tak_thermo_ros.passes.pool_records`), fitting it
(:mod:`~tak_thermo_ros.passes.pool_fit`), checking a calibration on it (``validate``, ``diagnose``:
:mod:`~tak_thermo_ros.passes.pool_check`), and the lines a person reads of it
(:mod:`~tak_thermo_ros.passes.pool_lines`).
"""

from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator, Sequence

import numpy as np

from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.core.records.extremes import temperature_course
from tak_thermo_ros.core.records.handheld import HandheldRecord, empty_samples, pooled
from tak_thermo_ros.core.records.provenance import PrintCollector, Recognition, RecordPrint
from tak_thermo_ros.core.records.record import DriverRecord, hold_last_index, no_orientation
from tak_thermo_ros.core.records.still import MIN_STILL_S
from tak_thermo_ros.core.records.survey import SurveyCollector
from tak_thermo_ros.errors import TakError
from tak_thermo_ros.passes.handheld import handheld_record
from tak_thermo_ros.passes.pool_records import PoolError, _spelled, distinct_records, record_paths
from tak_thermo_ros.passes.run import SURVEY_REPLAY_SAMPLES, StreamOptions, record_streams_listed, stripped_block

if TYPE_CHECKING:
    from tak_thermo_ros.formats.records import Record

POOL_SAMPLES = 2_000_000
"""A pool keeps at most about this many rest samples, shared among its records ..."""
POOL_TURN_SAMPLES = 200_000
"""... and this many samples of its motions short enough to be integrated (the gyroscope's scale and
misalignment; every n-th motion beyond) ..."""
MIN_RECORD_SAMPLES = 20_000
"""... but at least this many rest samples of each record (and a tenth as many of its motions)."""


def record_budgets(records: int, samples: int = POOL_SAMPLES) -> tuple[int, int]:
    """Each record's share of the pool's rest and motion samples."""
    count = max(records, 1)
    return (max(MIN_RECORD_SAMPLES, samples // count),
            max(MIN_RECORD_SAMPLES // 10, POOL_TURN_SAMPLES * samples // POOL_SAMPLES // count))


@dataclass(frozen=True)
class PoolEntry:
    """One record of a pool, as read.

    :param rests: its rests (still intervals); ``rest_s`` their total time.
    :param temperature: the lowest and highest temperature at its rests (``None``: none).
    :param orientations: distinct orientations of its rests.
    :param source: a flight log's format and device IDs (``None``: a bag).
    :param lines: what the reader did (a firmware's corrections undone, ...).
    :param reason: why it contributes nothing or was left out (``''``: pooled).
    :param held_gyro: the gyroscope was held on the accelerometer's stamps (a log of separate stamps).
    :param stamps_back: how often its stamps go back in log order, and by how much at most (seconds).
    """

    path: Path
    name: str
    rests: int = 0
    rest_s: float = 0.0
    temperature: tuple[float, float] | None = None
    orientations: int = 0
    source: dict[str, object] | None = None
    lines: tuple[str, ...] = ()
    reason: str = ''
    held_gyro: bool = False
    rest_temperatures: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    rest_trends: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    temperature_rate_max: float = 0.0
    rate_max: float = 0.0
    record_print: RecordPrint | None = None
    """What a calibration fitted from the pool keeps of the record (``fitted_from``)."""
    in_sample: Recognition | None = None
    """Whether the record is (part of) one a calibration was fitted from (:func:`read_record`'s ``against``)."""
    stamps_back: tuple[int, float] = (0, 0.0)


@dataclass(frozen=True)
class OpenedPool:
    """A pool read: every record's entry, and the pooled samples of those that contribute.

    :param used: the entries pooled, in the pooled record's numbering.
    """

    entries: tuple[PoolEntry, ...]
    record: HandheldRecord | None
    used: tuple[int, ...]
    lines: tuple[str, ...] = ()


def _shared(blocks: Iterator[DriverRecord]) -> Iterator[tuple[DriverRecord, bool]]:
    """Each block with both sensors in every message: a gyroscope on its own stamps held on the accelerometer's."""
    last: np.ndarray | None = None
    for block in blocks:
        if block.shared_stamps:
            yield block, False
            continue
        accel_stamps, gyro_stamps = block.sensor_stamps('accel'), block.sensor_stamps('gyro')
        index = hold_last_index(gyro_stamps, accel_stamps)
        gyro = np.full((len(accel_stamps), 3), np.nan)
        inside = index >= 0
        gyro[inside] = block.gyro[index[inside]]
        if last is not None:
            gyro[~inside] = last
        if len(block.gyro):
            last = block.gyro[-1]
        keep = np.all(np.isfinite(gyro), axis=1)
        orientation, covariance = no_orientation(int(keep.sum()))
        yield DriverRecord(stamp_ns=accel_stamps[keep], accel=block.accel[keep], gyro=gyro[keep],
                           orientation=orientation, orientation_covariance=covariance,
                           temp_stamp_ns=block.temp_stamp_ns, temperature=block.temperature,
                           frame_id=block.frame_id), True


def read_record(opened: Record, options: StreamOptions, *, budget: int, turn_budget: int | None = None,
                against: Sequence[RecordPrint] | None = None) -> tuple[PoolEntry, HandheldRecord | None]:
    """One record of a pool: its rests and turns (about ``budget`` and ``turn_budget`` samples at most), and more.

    :param against: the prints of the records a calibration was fitted from: the entry says whether
        this record is (part of) one of them; ``None``: for a calibration fitted from it (the entry's
        print is its whole digest either way).
    """
    path = opened.path
    name = path.name
    try:
        streams = opened.streams
    except TakError as err:
        return PoolEntry(path, name, reason=f'not read ({err})'), None
    if streams.kind is not InputKind.IMU:
        return PoolEntry(path, name, reason='the paper\'s channel codes: a pool takes a driver\'s records'), None
    source, lines = opened.source, opened.lines
    if not streams.temperature:
        return PoolEntry(path, name, source=source, lines=lines,
                         reason=f'no temperature on {options.topics.temperature}: contributes nothing'), None
    keep = streams.main <= SURVEY_REPLAY_SAMPLES

    def raw_blocks() -> Iterator[DriverRecord]:
        return opened.blocks(kind=InputKind.IMU,  # type: ignore[return-value]
                             block_samples=options.block_samples, references=False, progress=options.progress)

    def blocks() -> Iterator[tuple[DriverRecord, bool]]:
        return _shared(raw_blocks())

    # The record's whole digest, as one record's, and its segments on the grids of ``against``; not its
    # own time segments at every length (1.3 s of CPU per 30 min at 200 Hz: about what the rest of a
    # pool's fit costs per record), so a pool's records are recognised whole.
    prints = PrintCollector(('accel', 'gyro'), against=against or (), own_segments=False)

    def printed() -> Iterator[DriverRecord]:
        for block in raw_blocks():
            prints.add({sensor: block.channel(sensor) for sensor in ('accel', 'gyro')})
            yield block

    survey = SurveyCollector('imu')
    kept: list[tuple[DriverRecord, bool]] = []
    held_gyro = False
    temperature_stamps, temperatures = [], []
    back = _StampsBack()
    for block, held in _shared(printed()):
        held_gyro = held_gyro or held
        back.add(block.stamp_ns)
        survey.add(block)
        temperature_stamps.append(block.temp_stamp_ns)
        temperatures.append(block.temperature)
        if keep:
            kept.append((stripped_block(block), held))
    surveyed = survey.finish(record_streams_listed(opened, options.topics))
    known = {'record_print': prints.finish(name), 'in_sample': prints.recognition(name) if against else None}
    if surveyed.temperature_problem is not None:  # the one rule of a record's temperatures (check_temperature_unit)
        reason = f'{options.topics.temperature}: {surveyed.temperature_problem}: contributes nothing'
        return PoolEntry(path, name, source=source, lines=lines, reason=reason, held_gyro=held_gyro), None
    still = surveyed.still
    if not len(still):
        reason = (f'no rest (never still {MIN_STILL_S:g} s or more; still {100.0 * still.still_fraction:.0f} % of '
                  f'the time): contributes nothing')
        return PoolEntry(path, name, source=source, lines=lines, reason=reason, held_gyro=held_gyro), None
    record, _ = handheld_record(opened, options, surveyed, budget=budget, turn_budget=turn_budget,
                                replay=(block for block, _ in (kept if keep else blocks())))
    rate_max = 0.0
    stamps = np.concatenate(temperature_stamps)
    celsius = np.concatenate(temperatures)
    finite = np.isfinite(celsius)
    course = temperature_course(stamps[finite] * 1e-9, celsius[finite])
    record = replace(record, temperature_track=track(stamps[finite], celsius[finite]))
    if held_gyro:  # a held gyroscope integrates to nothing: its rests only
        record = replace(record, turn=empty_samples(), turn_index=np.zeros(0, dtype=np.int64),
                         turns=np.zeros((0, 2), dtype=np.int64))
    if len(record.turn):
        rate_max = float(np.max(np.linalg.norm(record.turn.counts[:, 3:6], axis=1)))
    if not len(record.still):
        reason = 'no rest sample with a temperature: contributes nothing'
        return PoolEntry(path, name, source=source, lines=lines, reason=reason, held_gyro=held_gyro), None
    temperatures, trends = rest_temperatures(record)
    entry = PoolEntry(path, name, rests=len(still), rest_s=float(still.interval_s.sum()),
                      temperature=(float(record.still.temp_code.min()), float(record.still.temp_code.max())),
                      orientations=still.orientations(), source=source, lines=lines, held_gyro=held_gyro,
                      rest_temperatures=temperatures, rest_trends=trends,
                      temperature_rate_max=course.rate_max, rate_max=rate_max,
                      stamps_back=(back.count, back.most_s), **known)
    return entry, record


class _StampsBack:
    """How often a record's stamps go back in log order (a clock reset, a log spliced), and by how much."""

    def __init__(self) -> None:
        self.count = 0
        self.most_s = 0.0
        self._last: int | None = None

    def add(self, stamps: np.ndarray) -> None:
        if not len(stamps):
            return
        steps = np.diff(stamps) if self._last is None else np.diff(stamps, prepend=self._last)
        back = steps[steps < 0]
        if len(back):
            self.count += len(back)
            self.most_s = max(self.most_s, float(-back.min()) * 1e-9)
        self._last = int(stamps[-1])


TRACK_S = 1.0
"""A pool's temperature track keeps one temperature per this many seconds (an effect's time constant is minutes)."""


def track(stamp_ns: np.ndarray, celsius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A record's temperature between its rests, one point per :data:`TRACK_S` (in stamp order)."""
    order = np.argsort(stamp_ns, kind='stable')
    stamp_ns, celsius = stamp_ns[order], celsius[order]
    if not len(stamp_ns):
        return stamp_ns, celsius
    slot = (stamp_ns - stamp_ns[0]) // int(TRACK_S * 1e9)
    first = np.flatnonzero(np.diff(slot, prepend=-1) != 0)
    return stamp_ns[first], celsius[first]


def rest_temperatures(record: HandheldRecord) -> tuple[np.ndarray, np.ndarray]:
    """Each rest's mean temperature and its trend (C per minute, a line through its samples)."""
    _, number = np.unique(record.still_interval, return_inverse=True)
    count = int(number.max()) + 1 if len(number) else 0
    stamp = record.still.stamp_s
    temperature = record.still.temp_code
    samples = np.bincount(number, minlength=count)

    def mean(values: np.ndarray) -> np.ndarray:
        return np.bincount(number, weights=values, minlength=count) / np.maximum(samples, 1)

    means = mean(temperature)
    centred = stamp - mean(stamp)[number]
    low, high = np.full(count, np.inf), np.full(count, -np.inf)
    np.minimum.at(low, number, stamp)
    np.maximum.at(high, number, stamp)
    sloped = (samples > 2) & (high > low)
    spread = np.where(sloped, np.bincount(number, weights=centred * centred, minlength=count), 1.0)
    trends = np.bincount(number, weights=centred * (temperature - means[number]), minlength=count) / spread * 60.0
    return means, np.where(sloped, trends, 0.0)


RESTLESS_RATIO = 3.0
"""A record whose quietest windows' noise is this many times the pool's never rested (its "rests" moved)."""


def _restless(entries: list[PoolEntry], read: list[HandheldRecord | None]) -> list[PoolEntry]:
    """Records that never rested: the still detector takes a record's own quietest windows for its noise.

    A record that moved all the time has no quiet window, and its "rests" are motion: its noise
    beside the pool's (the median of the records') tells it.
    """
    noises = {i: record.intervals.noise[:6] for i, record in enumerate(read) if record is not None
              and not entries[i].reason and len(record.intervals.noise) >= 6}
    if len(noises) < 2:
        return entries
    pool = np.median(np.vstack(list(noises.values())), axis=0)
    out = list(entries)
    for index, noise in noises.items():
        ratio = float(np.max(noise / np.maximum(pool, 1e-300)))
        if ratio > RESTLESS_RATIO:
            reason = (f'no rest: its quietest windows move {ratio:.0f}x the pool\'s noise (it never rested): '
                      f'contributes nothing')
            out[index] = replace(out[index], reason=reason)
    return out


def _device_check(entries: list[PoolEntry]) -> list[PoolEntry]:
    """Flight logs whose sensors' device IDs are not the pool's: left out; two devices in equal numbers: refused."""
    keys = {i: (int(e.source.get('accel_device_id', 0)), int(e.source.get('gyro_device_id', 0)))  # type: ignore
            for i, e in enumerate(entries) if e.source is not None and not e.reason}
    keys = {i: key for i, key in keys.items() if any(key)}
    counts = Counter(keys.values())
    if len(counts) < 2:
        return entries
    (first, most), (_, second) = counts.most_common(2)
    if most == second:
        devices = '; '.join(f'accel {a} gyro {g}: {n} records' for (a, g), n in counts.most_common())
        msg = (f'the pool holds records of {len(counts)} devices in equal numbers ({devices}): give the records of '
               f'one unit')
        raise PoolError(msg)
    out = list(entries)
    for index, key in keys.items():
        if key != first:
            sensor, theirs, ours = (('gyroscope', key[1], first[1]) if key[1] != first[1]
                                    else ('accelerometer', key[0], first[0]))
            out[index] = replace(out[index], reason=f'left out: another device ({sensor} device_id {theirs}, '
                                                    f'the pool\'s {ours})')
    return out


def open_pool(paths: Sequence[str | os.PathLike[str]], options: StreamOptions, *,
              samples: int = POOL_SAMPLES, against: Sequence[RecordPrint] | None = None,
              say: Callable[[str], None] | None = None) -> OpenedPool:
    """Read every record of a pool once (see the module's description).

    A second copy of a record is counted once (:func:`distinct_records`).

    :param paths: the records' paths, or a record a command opened (read, not opened again: a pool of one).
    :param against: as :func:`read_record`'s (a calibration's ``fitted_from``; ``None``: for a fit).
    :param say: called with each line as soon as it is known: the directories' and the second copies' lines
        (:attr:`OpenedPool.lines`), each record's once it is read, a record's changed by the checks after.
    :raises PoolError: a path that is no record, no record that contributes a rest.
    """
    say = say or (lambda line: None)
    from tak_thermo_ros.formats.records import Record, open_record
    found, lines = record_paths(paths)
    given = {record.path: record for record in paths if isinstance(record, Record)}  # opened by the command
    records = [given.get(path) or open_record(path, topics=options.topics) for path in found]  # each opened once
    kept, same = distinct_records(records, _spelled(paths, found))
    records, lines = [records[i] for i in kept], lines + same
    for line in lines:
        say(line)
    budget, turn_budget = record_budgets(len(records), samples)
    entries: list[PoolEntry] = []
    read: list[HandheldRecord | None] = []
    names = Counter(opened.path.name for opened in records)
    for opened in records:
        entry, record = read_record(opened, options, budget=budget, turn_budget=turn_budget, against=against)
        if names[opened.path.name] > 1:  # the same name in two directories: the path tells them apart
            entry = replace(entry, name=str(opened.path))
        entries.append(entry)
        read.append(record)
        for line in _record_lines(entry):
            say(line)
    checked = _restless(_device_check(entries), read)
    for before, after in zip(entries, checked):
        if after.reason != before.reason:
            say(entry_line(after))
    entries = checked
    used = tuple(i for i, (entry, record) in enumerate(zip(entries, read)) if record is not None and not entry.reason)
    if not used:
        msg = f'no record of the {len(records)} given holds a rest with a temperature: nothing to fit'
        raise PoolError(msg)
    record = pooled([read[i] for i in used], [entries[i].name for i in used])  # type: ignore[misc]
    return OpenedPool(tuple(entries), record, used, tuple(lines))


def entry_line(entry: PoolEntry) -> str:
    """One line per record: its rests, their time, temperature span, orientations (or why it adds nothing)."""
    if entry.reason:
        return f'{entry.name}: {entry.reason}'
    low, high = entry.temperature  # type: ignore[misc]
    held = ', gyroscope held on the accelerometer\'s stamps (rests only)' if entry.held_gyro else ''
    count, most = entry.stamps_back
    times = 'once' if count == 1 else f'{count} times'
    back = f'; its stamps go back {times} (by up to {most:.3g} s): no rest spans a jump' if count else ''
    return (f'{entry.name}: {entry.rests} rests, {entry.rest_s / 60.0:.1f} min at rest, {low:.1f}..{high:.1f} C, '
            f'{entry.orientations} orientation{"s" if entry.orientations != 1 else ""}{held}{back}')


def _record_lines(entry: PoolEntry) -> list[str]:
    """What its reader did, then :func:`entry_line`."""
    return [*(f'{entry.name}: {line}' for line in entry.lines), entry_line(entry)]
