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
a rest, or without a temperature, contributes nothing and says so.
"""

from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator, Sequence

import numpy as np

from tak_thermo_ros.core.fit.pool import own_offsets, record_means
from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.records.extremes import temperature_course
from tak_thermo_ros.core.records.handheld import HandheldRecord, empty_samples, pooled
from tak_thermo_ros.core.records.provenance import PrintCollector, Recognition, RecordPrint
from tak_thermo_ros.core.records.record import DriverRecord, hold_last_index, no_orientation
from tak_thermo_ros.core.records.still import MIN_STILL_S
from tak_thermo_ros.core.records.survey import SurveyCollector
from tak_thermo_ros.core.values import SENSOR_NAMES
from tak_thermo_ros.errors import FitError, TakError
from tak_thermo_ros.passes.handheld import handheld_record, handheld_settings
from tak_thermo_ros.passes.run import SURVEY_REPLAY_SAMPLES, StreamOptions, record_streams_listed, stripped_block
from tak_thermo_ros.units import numbers, reader_unit

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


RECORD_SUFFIXES = ('.ulg', '.bin')
"""A file in a directory of records is a record when it is named so (a bag is a directory with metadata.yaml)."""
TREND_C_PER_MIN = 0.05
"""A rest warming (cooling) faster than this is heating (cooling); slower, steady."""
BIN_C = 1.0
"""The pool's temperature coverage is counted in bins this wide."""


class PoolError(FitError):
    """A pool that cannot be fitted as one unit's records (in one line)."""


def is_bag(path: Path) -> bool:
    """A rosbag2 directory (its metadata.yaml)."""
    return path.is_dir() and (path / 'metadata.yaml').is_file()


def record_paths(paths: Sequence[str | os.PathLike[str]]) -> tuple[list[Path], list[str]]:
    """The records named: each path a record, or a directory of records (bags, ``.ulg``, ``.bin``, sorted by name).

    :returns: the records, and one line per directory that holds entries that are no record.
    :raises PoolError: a path that does not exist, a directory without a record.
    """
    records: list[Path] = []
    lines: list[str] = []
    for given in paths:
        path = Path(given)
        if not path.exists():
            msg = f'{path}: no such record or directory'
            raise PoolError(msg)
        if not path.is_dir() or is_bag(path):
            records.append(path)
            continue
        found, other = [], []
        for entry in sorted(path.iterdir()):
            if is_bag(entry) or (entry.is_file() and entry.suffix.lower() in RECORD_SUFFIXES):
                found.append(entry)
            else:
                other.append(entry.name)
        if not found:
            msg = f'{path}: no record in it (bags, .ulg or .bin logs)'
            raise PoolError(msg)
        if other:
            shown = ', '.join(other[:3]) + (', ...' if len(other) > 3 else '')
            lines.append(f'{path}: {len(other)} entries are no record, not read ({shown})')
        records += found
    return records, lines


def _spelled(paths: Sequence[str | os.PathLike[str]], records: Sequence[Path]) -> list[str]:
    """Each record as the user spelled it (``./month/rec00/``); a directory's records by their paths."""
    given: dict[Path, list[str]] = {}
    for path in paths:
        given.setdefault(Path(path), []).append(os.fspath(path))
    return [given[path].pop(0) if given.get(path) else str(path) for path in records]


def same_how(path: str | os.PathLike[str], earlier: str | os.PathLike[str], content: str) -> str:
    """How a second copy is the first: ``through a link``, ``the same path``, else ``content`` (a copy)."""
    if os.path.realpath(path) != os.path.realpath(earlier):
        return content or 'the same content'
    return 'through a link' if os.path.realpath(path) != os.path.abspath(path) else 'the same path'


def distinct_records(records: Sequence[Record], spelled: Sequence[str] | None = None) -> tuple[list[int], list[str]]:
    """The records that are not a second copy of an earlier one, by content (:attr:`Record.identity`).

    A record given twice (another spelling of its path, a link, a copy, a bag's ``.mcap`` beside its
    folder, one flight as ``.ulg`` and ``.bin``) is one power-up: counted once, the second named.

    Only records of the same message count and last log time are read for their identity (the others
    cannot be the same).

    :returns: the indices of the records kept, and one line per second copy (an unreadable record is said
        when it is read).
    """
    names = list(spelled) if spelled is not None else [str(record) for record in records]
    counted = []
    for record in records:
        try:
            streams = record.streams
        except TakError:  # unreadable: said when it is read
            streams = None
        counted.append(streams)
    counts = Counter((s.kind, s.main, s.end_ns) for s in counted if s is not None)
    first: dict[object, int] = {}
    kept, lines = [], []
    for index, (record, streams) in enumerate(zip(records, counted)):
        alone = streams is None or counts[streams.kind, streams.main, streams.end_ns] == 1
        identity = None if alone else record.identity
        key = identity if identity is not None else ('path', os.path.realpath(record.path))
        if key in first:
            earlier = first[key]
            how = same_how(record.path, records[earlier].path,
                           f'the same {identity.messages} messages' if identity else '')
            lines.append(f'{names[index]}: the same record as {names[earlier]} ({how}): counted once')
            continue
        first[key] = index
        kept.append(index)
    return kept, lines


def is_pool(paths: Sequence[str | os.PathLike[str]]) -> bool:
    """Whether the records given make a pool: several, or a directory that is not a bag."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    return len(paths) > 1 or (Path(paths[0]).is_dir() and not is_bag(Path(paths[0])))


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


def check_driver_unit(unit, params: str) -> None:
    """A pool is checked against a driver calibration only (accelerometer and gyroscope).

    :raises TakError: ``unit`` (read from ``params``) is not one.
    """
    if unit.input_kind is not InputKind.IMU or unit.gyro is None:
        msg = f'{params}: a pool of records takes a driver calibration (accelerometer and gyroscope)'
        raise TakError(msg)


def coverage_lines(opened: OpenedPool, left_out: Sequence[str] = ()) -> list[str]:
    """What the pool covers: records, rests, the temperature span and its bins, heating and cooling.

    :param left_out: the names of records the fit left out after reading (counted as not pooled).
    """
    used = [opened.entries[i] for i in opened.used if opened.entries[i].name not in left_out]
    temperatures = np.concatenate([e.rest_temperatures for e in used])
    trends = np.concatenate([e.rest_trends for e in used])
    rests = len(temperatures)
    hours = sum(e.rest_s for e in used) / 3600.0
    low, high = float(temperatures.min()), float(temperatures.max())
    bins = np.floor(temperatures / BIN_C)
    span_bins = int(np.floor(high / BIN_C) - np.floor(low / BIN_C)) + 1
    lines = [f'pool: {len(used)} of {len(opened.entries)} records, {rests} rests, {hours:.2f} h at rest, '
             f'{low:.1f}..{high:.1f} C ({len(np.unique(bins))} of {span_bins} {BIN_C:g}-C bins hold a rest)']
    parts = []
    for word, mask in (('heating', trends > TREND_C_PER_MIN), ('cooling', trends < -TREND_C_PER_MIN)):
        if mask.any():
            parts.append(f'{word} at {int(mask.sum())} rests ({temperatures[mask].min():.1f}..'
                         f'{temperatures[mask].max():.1f} C)')
        else:
            parts.append(f'{word} at no rest')
    steady = int(np.sum(np.abs(trends) <= TREND_C_PER_MIN))
    both = _both_ways(temperatures, trends)
    lines.append(f'pool: {", ".join(parts)}, steady at {steady}; both ways within {both}')
    return lines


def _both_ways(temperatures: np.ndarray, trends: np.ndarray) -> str:
    """The temperature span where rests were seen both heating and cooling (what tells hysteresis and lag)."""
    heating, cooling = temperatures[trends > TREND_C_PER_MIN], temperatures[trends < -TREND_C_PER_MIN]
    if not len(heating) or not len(cooling):
        return 'no span'
    low, high = max(heating.min(), cooling.min()), min(heating.max(), cooling.max())
    return f'{low:.1f}..{high:.1f} C' if high > low else 'no span'


@dataclass(frozen=True)
class FittedPool:
    """``tak_calib fit`` of a pool: the records as read, the fit, and what goes into the file's ``source``."""

    opened: OpenedPool
    fit: object
    source: dict[str, str | int | float]
    lines: tuple[str, ...] = ()
    """With a prior: the unit's group, the turn-on repeatability taken, what came from the records and the prior."""
    fitted_from: tuple[RecordPrint, ...] = ()
    """The prints of the records fitted (the pooled ones the fit did not leave out): the file's ``fitted_from``."""


def fit_records(paths: Sequence[str | os.PathLike[str]], settings, options: StreamOptions, prior=None, *,
                say: Callable[[str], None] | None = None) -> FittedPool:
    """Read a pool once and fit it (:func:`~tak_thermo_ros.core.fit.pool.fit_pool`).

    :param settings: ``tak_calib fit``'s :class:`~tak_thermo_ros.passes.run.FitSettings`.
    :param prior: a fleet's prior (:func:`~tak_thermo_ros.core.fit.prior_fit.fit_with_prior`), a
        :class:`~tak_thermo_ros.core.fit.prior.CurvePrior` that only fixes the orders (a fleet's first pass), or
        ``None``.
    :param say: each line of reading the pool as soon as it is known (:func:`open_pool`).
    :raises PoolError: as :func:`open_pool`; ``FitError`` as the fit.
    """
    from tak_thermo_ros.core.fit.pool import TwoUnits, fit_pool
    from tak_thermo_ros.core.fit.prior import CurvePrior
    opened = open_pool(paths, options, say=say)
    assert opened.record is not None
    lines: tuple[str, ...] = ()
    try:
        if prior is None:
            fitted = fit_pool(opened.record, handheld_settings(settings))
        elif isinstance(prior, CurvePrior):  # the orders only (a fleet's first pass)
            fitted = fit_pool(opened.record, replace(handheld_settings(settings), prior=prior))
        else:
            from tak_thermo_ros.core.fit.prior_fit import fit_with_prior
            from tak_thermo_ros.passes.prior_lines import with_source_notes
            fitted, lines = with_source_notes(fit_with_prior(opened.record, handheld_settings(settings), prior))
    except TwoUnits as err:
        small, factor = _reader(err.sensor)
        sides = [f'{numbers(centre * factor, 3)} {small} ({", ".join(group)})'
                 for centre, group in zip(err.centres, err.groups)]
        msg = (f'the pool looks like two units: {SENSOR_NAMES[err.sensor]} {"xyz"[err.axis]} turn-on offsets near '
               f'{sides[0]} and near {sides[1]}, {err.spreads:.0f} spreads apart: give the records of one unit')
        raise PoolError(msg) from None
    used = [opened.entries[i] for i in opened.used]
    source: dict[str, str | int | float] = {
        'format': 'pool', 'temperature_rate_max': round(max(e.temperature_rate_max for e in used), 9),
        'rate_max': round(max(e.rate_max for e in used), 9)}
    devices = {(e.source or {}).get('accel_device_id'): e for e in used}
    if len(devices) == 1 and all(e.source is not None for e in used):
        for key in ('accel_device_id', 'gyro_device_id'):
            source[key] = int(used[0].source.get(key, 0))  # type: ignore[union-attr]
    left = {left.name for left in fitted.left_out}
    prints = tuple(e.record_print for e in used if e.name not in left and e.record_print is not None)
    return FittedPool(opened, fitted, source, lines, prints)


def pool_unit(fitted: FittedPool) -> UnitCalibration:
    """A pool's fit as the calibration file holds it: both sensors, the pool's source, what was pooled in its notes."""
    from tak_thermo_ros.core.fit.pool import order_line
    pool = fitted.fit
    results = pool.fit.results  # type: ignore[attr-defined]
    names = ', '.join(pool.record.record_names)  # type: ignore[attr-defined]
    notes = [f'pooled from {pool.record.records} records: {names}',  # type: ignore[attr-defined]
             *(order_line(sensor, choice) for sensor, choice in pool.orders.items()),  # type: ignore[attr-defined]
             *(left_out_line(left) for left in pool.left_out)]  # type: ignore[attr-defined]
    accel, gyro = (replace(results[sensor].calibration, notes=(*results[sensor].calibration.notes, *notes))
                   for sensor in ('accel', 'gyro'))
    return UnitCalibration(InputKind.IMU, accel=accel, gyro=gyro, source=fitted.source,
                           fitted_from=fitted.fitted_from)


def pool_header(records: int, output: str, prior: str = '') -> str:
    """The header of a pool's calibration file (``prior``: its label, when fitted with one)."""
    return (f'tak_thermo_ros calibration fitted from a pool of {records} records (everyday records of one unit)\n'
            f'3 axes per sensor, a turn-on offset per record' + (f'\nwith the prior {prior}' if prior else '')
            + f'\nload with: ros2 run tak_thermo_ros compensator --ros-args --params-file {Path(output).name}')


def _reader(sensor: str) -> tuple[str, float]:
    """The unit a person reads a sensor's small values in (mg, deg/h) and its factor."""
    return reader_unit({'accel': 'm/s^2', 'gyro': 'rad/s'}[sensor])  # type: ignore[return-value]


def turn_on_line(sensor: str, fitted, records: int) -> str:
    """One statement: a sensor's turn-on repeatability per axis with its error (or which axes the records miss).

    From fewer records than :data:`~tak_thermo_ros.core.link.model.MIN_TURN_ON_RECORDS`: not determined, and why.
    """
    from tak_thermo_ros.core.link.model import MIN_TURN_ON_RECORDS, TurnOn
    variances = fitted.variances
    held = [name for name, ok in zip('xyz', variances.determined) if not ok]
    if records < MIN_TURN_ON_RECORDS:
        written = f'not written ({" ".join(held)}: not determined by these records)' if held else 'written so'
        return f'{SENSOR_NAMES[sensor]}: turn-on repeatability {TurnOn(None, None, records).why_not()}; {written}'
    small, factor = _reader(sensor)
    values = ' '.join('-' if not ok else numbers(v * factor, 3) + (f'+-{numbers(e * factor, 2)}' if np.isfinite(e)
                                                                   else '')
                      for v, e, ok in zip(variances.turn_on, variances.turn_on_error, variances.determined))
    tail = f' ({" ".join(held)}: not determined by these records)' if held else ''
    return f'{SENSOR_NAMES[sensor]}: turn-on repeatability x y z {values} {small}{tail}'


def left_out_line(left) -> str:
    """One statement: a record left out of the pool, and why."""
    small, factor = _reader(left.sensor)
    return (f'{left.name}: left out: another unit? its {SENSOR_NAMES[left.sensor]} {"xyz"[left.axis]} turn-on offset '
            f'{numbers(left.offset * factor, 3)} {small} lies {left.sigmas:.0f} times the other records\' spread '
            f'from their mean')


@dataclass(frozen=True)
class PoolCheck:
    """``validate`` of a pool: every rest's errors before (nominal) and after the calibration, by record.

    :param own: ``(r, 3)`` each record's mean rate error at rest after the calibration (its turn-on offset).
    :param shape: ``(k, 3)`` the rests' rate errors after, each record's own mean taken off.
    :param temperature: ``(k,)`` each rest's mean temperature; ``record`` its record; ``white`` ``(k, 3)`` the
        white noise's variance of its mean rate less its record's (what the shape holds of the noise).
    """

    opened: OpenedPool
    before: object
    after: object
    own: np.ndarray
    shape: np.ndarray
    temperature: np.ndarray = field(default_factory=lambda: np.zeros(0))
    record: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    white: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def shape_rms(self) -> np.ndarray:
        """``(3,)`` RMS of the rests' rate errors with each record's own offset taken off."""
        return np.sqrt(np.mean(self.shape ** 2, axis=0)) if len(self.shape) else np.zeros(3)


def validate_records(paths: Sequence[str | os.PathLike[str]], unit, options: StreamOptions, *, gravity: float,
                     latitude: float | None, out_of_range, say: Callable[[str], None] | None = None) -> PoolCheck:
    """The rests of a pool's records before and after ``unit`` (each record read once, as for ``fit``)."""
    from tak_thermo_ros.core.link.handheld_check import check_handheld
    from tak_thermo_ros.passes.handheld import nominal_unit
    opened = open_pool(paths, options, against=unit.fitted_from, say=say)
    record = opened.record
    assert record is not None
    before = check_handheld(record, nominal_unit(unit), gravity=gravity, latitude=latitude, out_of_range=out_of_range)
    after = check_handheld(record, unit, gravity=gravity, latitude=latitude, out_of_range=out_of_range)
    own, shape = own_offsets(record, after.rate_error)
    from tak_thermo_ros.core.fit.pool import _rests
    rest_record, samples, temperature = _rests(record)
    per_record = np.bincount(rest_record, weights=samples, minlength=record.records)
    # a rest's mean less its record's samples-weighted mean: s^2 / n - s^2 / N of white noise
    white = record.intervals.noise[3:6][None, :] ** 2 * (1.0 / samples - 1.0 / per_record[rest_record])[:, None]
    return PoolCheck(opened, before, after, own, shape, temperature, rest_record, white)


def outside_lines(check: PoolCheck, unit, policy) -> list[str]:
    """Per record whose rests reach beyond the calibrated temperature range: how many, how far, what was done.

    Said before the figures: a record beyond the range carries what the clamp (or the extrapolation)
    leaves in its rests' errors, which its turn-on offset would otherwise be blamed for.
    """
    from tak_thermo_ros.core.records.handheld import rest_records
    record = check.opened.record
    ranges = [(c.temp_code_min, c.temp_code_max) for _, c in unit.sensors if c.needs_temperature]
    if record is None or not ranges or not len(check.after.rest_outside):
        return []
    low, high = max(r[0] for r in ranges), min(r[1] for r in ranges)
    owner = rest_records(record)
    entries = {entry.name: entry for entry in check.opened.entries}
    done = 'clamped' if policy.value == 'clamp' else 'extrapolated'
    lines = []
    for index, name in enumerate(record.record_names):
        mine = owner == index
        outside = int(np.count_nonzero(check.after.rest_outside[mine] > 0.0))
        if outside:
            rests = entries[name].temperature or (low, high)
            lines.append(f'{name}: {outside} of its {int(mine.sum())} rests beyond the calibrated {low:.1f}..'
                         f'{high:.1f} C (its rests {rests[0]:.1f}..{rests[1]:.1f} C): {done}')
    return lines


def bounded_pool(paths: Sequence[str | os.PathLike[str]], options: StreamOptions, *, gravity: float,
                 latitude: float | None, max_samples: int, unit, say: Callable[[str], None] | None = None):
    """``diagnose`` of a pool: the rests' samples with their references, each record's own offset taken off.

    The references are a hand-held record's (gravity along each rest's corrected up direction, zero
    rate); each record's turn-on offset (its samples' mean residual after ``unit``, per axis) is
    taken off, so that what remains is the link's shape; ``groups`` give each sample's record
    (the folds hold whole records out; a pool of one record holds out time blocks).

    :returns: the :class:`~tak_thermo_ros.passes.diagnose.BoundedRun` and the pool as read.
    """
    from tak_thermo_ros.core.fit.model import residual_counts
    from tak_thermo_ros.passes.diagnose import BoundedRun
    from tak_thermo_ros.passes.handheld import rest_samples
    opened = open_pool(paths, options, samples=max_samples, say=say)
    record = opened.record
    assert record is not None
    samples, check = rest_samples(record, unit, gravity=gravity, latitude=latitude)
    groups = record.still_record
    for sensor, aligned in samples.items():
        own = record_means(residual_counts(unit.sensor(sensor), aligned), groups, record.records)
        samples[sensor] = replace(aligned, counts=aligned.counts - own[groups])
    usable = {sensor: len(aligned) for sensor, aligned in samples.items()}
    run = BoundedRun(input_kind=InputKind.IMU, samples=samples, usable=usable, stride=record.stride,
                     reference_lines=(), survey=None, handheld=check,
                     groups={sensor: groups for sensor in samples} if record.records > 1 else None)
    return run, opened


def bag_directory(path: str | os.PathLike[str], *, force: bool, option: str) -> Path:
    """A directory to write one bag per record into: made, or one that holds only bags (``force`` replaces them).

    :raises OutputError: ``path`` is no directory, holds something else than bags, or holds bags without ``force``.
    """
    import shutil
    from tak_thermo_ros.errors import OutputError
    from tak_thermo_ros.formats.files import BAG, check_output
    out = Path(path)
    if out.exists() or out.is_symlink():
        if out.is_symlink() or not out.is_dir():
            msg = f'{out} ({option}): exists and is not a directory; the records are written into a directory'
            raise OutputError(msg)
        entries = sorted(out.iterdir())
        for entry in entries:  # only bags this tool wrote may be replaced
            check_output(entry, BAG, force=True, option=option)
        if entries and not force:
            msg = f'{out} ({option}): exists and holds {len(entries)} bags; --force replaces them'
            raise OutputError(msg)
        for entry in entries:
            shutil.rmtree(entry)
    else:
        check_output(out, BAG, option=option)
        out.mkdir()
    return out
