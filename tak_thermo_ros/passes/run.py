"""``tak_calib``'s passes over a bag in blocks: fit, apply, validate and diagnose in bounded memory.

Each pass reads the bag once in log order (:func:`tak_thermo_ros.formats.bag.iter_blocks`), aligns
each block on the main stream with the held values carried over
(:class:`~tak_thermo_ros.core.records.blocks.BlockAligner`) and hands the block to an accumulator:
the blocked-QR fit (:class:`~tak_thermo_ros.core.fit.stream.StreamingFit`), the corrector
that carries the effects' state (:class:`~tak_thermo_ros.core.link.stream_correction.BlockUnitCorrector`)
and an open bag writer, the validation sums, or a bounded, evenly spread subsample (the
effects' shape search, ``diagnose``). A driver bag without reference topics is surveyed in one
extra pass first (:mod:`tak_thermo_ros.core.records.survey`), whose blocks are kept up to
:data:`SURVEY_REPLAY_SAMPLES` messages and replayed instead of a second read: a static run takes
its mean measured direction as the reference, a hand-held record goes to
:mod:`tak_thermo_ros.passes.handheld`. See docs/streaming.md.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator, Sequence

import numpy as np

from tak_thermo_ros.core.records.blocks import BlockAligner, add_counts
from tak_thermo_ros.core.fit import FitResult, ShortRecord
from tak_thermo_ros.core.fit.link_uncertainty import HeldSpreads
from tak_thermo_ros.core.fit.model import AxisFit
from tak_thermo_ros.core.link.model import InputKind, held_link
from tak_thermo_ros.core.records.record import AlignedSamples, ChannelRecord, DriverRecord, require_signals
from tak_thermo_ros.core.records.provenance import PrintCollector, RecordPrint
from tak_thermo_ros.core.records.survey import Plan, RecordSurvey, SurveyCollector
from tak_thermo_ros.core.records.static_run import (
    StaticReference,
    check_static,
    rate_line,
    reference_line,
    static_reference,
)
from tak_thermo_ros.core.values import SENSOR_NAMES, STANDARD_GRAVITY
from tak_thermo_ros.errors import BagError, FitError, TakError

if TYPE_CHECKING:
    from tak_thermo_ros.formats.bag import Topics
    from tak_thermo_ros.formats.records import Record

EFFECT_FIT_MAX_SAMPLES = 1_000_000
"""``fit --effects`` searches the effects' shapes on at most about this many samples."""


def sensors_of(kind: InputKind) -> tuple[str, ...]:
    """The sensors a bag of this kind holds."""
    return ('accel',) if kind is InputKind.COUNTS else ('accel', 'gyro')


# ----- reading: blocks per sensor, a static run's reference ----------------------------------------------


@dataclass(frozen=True)
class StreamOptions:
    """How a pass reads the bag.

    :param topics: the bag's topic names (:class:`tak_thermo_ros.formats.bag.Topics`).
    :param progress: show a progress bar on a terminal.
    :param block_samples: main-stream messages per block.
    """

    topics: Topics
    progress: bool = True
    block_samples: int = 65536


class _StaticRun:
    """A driver bag's missing references, estimated as a static run (the mean: the survey's, or a pass if used)."""

    def __init__(self, record: Record, options: StreamOptions, *, recorded_reference: bool, recorded_rate: bool,
                 gravity: float, latitude: float | None, survey: RecordSurvey | None = None) -> None:
        topics = options.topics
        path = self.path = record.path
        self.recorded_reference = recorded_reference
        self.recorded_rate = recorded_rate
        self.gravity = gravity
        self.latitude = latitude
        self.lines: list[str] = []
        self.static: StaticReference | None = None
        self.max_tilt_deg = 0.0
        self._first_block = True
        if recorded_reference and recorded_rate:
            self.lines.append(f'reference: {topics.reference} and {topics.reference_rate} as recorded')
            return
        if survey is not None:  # the survey's pass took the mean already
            total, count = survey.mean * survey.samples, survey.samples
        elif recorded_reference and latitude is None:  # the mean would only turn the Earth rate: no pass
            total, count = np.zeros(3), 0
        else:
            total = np.zeros(3)
            count = 0
            for block in record.blocks(kind=InputKind.IMU, block_samples=options.block_samples, references=False,
                                       progress=options.progress):
                finite = np.all(np.isfinite(block.accel), axis=1)  # type: ignore[union-attr]
                total += block.accel[finite].sum(axis=0)  # type: ignore[union-attr]
                count += int(np.count_nonzero(finite))
        mean = total / count if count else np.zeros(3)
        self.static = static_reference(mean.reshape(1, 3) if count else np.zeros((0, 3)), gravity=gravity,
                                       latitude_deg=latitude)
        static = self.static
        if recorded_reference:
            self.lines.append(f'reference: {topics.reference} as recorded')
        else:
            check_static(static, gravity=gravity, max_tilt_deg=0.0, where=str(path), reference_topic=topics.reference)

    def rewind(self) -> None:
        """Before another pass: the references go into its first block again."""
        self._first_block = True

    def check_block(self, block: DriverRecord) -> DriverRecord:
        """The block with the estimated references (first block), its tilt checked."""
        if self.static is None:
            return block
        if not self.recorded_reference:
            accel = block.accel[np.all(np.isfinite(block.accel), axis=1)]
            if len(accel):
                norms = np.linalg.norm(accel, axis=1)
                cosine = np.clip((accel @ self.static.direction) / np.where(norms > 0.0, norms, 1.0), -1.0, 1.0)
                self.max_tilt_deg = max(self.max_tilt_deg, float(np.degrees(np.arccos(cosine)).max()))
        if not self._first_block or block.first_stamp_ns is None:
            return block
        self._first_block = False
        # held from the first sample of either sensor (their own stamps: the earlier one)
        first = block.stamp_ns[:1].copy() if block.shared_stamps else np.array([block.first_stamp_ns], dtype=np.int64)
        if not self.recorded_reference:
            block = replace(block, reference_stamp_ns=first, reference=self.static.specific_force.reshape(1, 3))
        if not self.recorded_rate:
            block = replace(block, rate_reference_stamp_ns=first, rate_reference=self.static.rate.reshape(1, 3))
        return block

    def finish(self, topics) -> list[str]:
        """The lines that say how the references were obtained; refuses a run that moved."""
        if self.static is None:
            return self.lines
        static, gravity, latitude = self.static, self.gravity, self.latitude
        lines = list(self.lines)
        if not self.recorded_reference:
            check_static(static, gravity=gravity, max_tilt_deg=self.max_tilt_deg, where=str(self.path),
                         reference_topic=topics.reference)
            lines.append(reference_line(static, gravity=gravity, max_tilt_deg=self.max_tilt_deg))
        if self.recorded_rate:
            lines.append(f'rate reference: {topics.reference_rate} as recorded')
        else:
            lines.append(rate_line(static, latitude))
        return lines


@dataclass
class SensorPass:
    """One sensor's alignment over the blocks and what it feeds."""

    sensor: str
    aligner: BlockAligner
    consumers: list[Callable[[AlignedSamples], None]] = field(default_factory=list)

    def feed(self, record: ChannelRecord) -> None:
        """Align a block and hand what became ready to the consumers."""
        self._hand_on(self.aligner.push(record))

    def finish(self) -> None:
        """Align the samples still waiting at the end of the run."""
        self._hand_on(self.aligner.finish())

    def _hand_on(self, aligned: AlignedSamples) -> None:
        for consume in self.consumers:
            consume(aligned)


def _sensor_records(block: ChannelRecord | DriverRecord, kind: InputKind) -> dict[str, ChannelRecord]:
    if kind is InputKind.COUNTS:
        return {'accel': block}  # type: ignore[dict-item]
    return {sensor: block.channel(sensor) for sensor in ('accel', 'gyro')}  # type: ignore[union-attr]


@dataclass(frozen=True)
class OpenedRun:
    """A bag opened for a calibration-run pass (references held).

    :param survey: what the record holds, when a first pass was needed to know it (a driver
        bag without reference topics); else ``collector`` gathers it during the pass.
    :param streams: ``(role, topic, messages)`` of the record's streams (for the survey).
    :param replay: the survey's blocks, kept when the record holds at most
        :data:`SURVEY_REPLAY_SAMPLES` messages (a hand-held record, or a static run without a
        recorded rate reference, is then not read again: :func:`run_passes` replays them).
    """

    kind: InputKind
    main: int
    static: _StaticRun | None
    survey: RecordSurvey | None = None
    collector: SurveyCollector | None = None
    streams: tuple[tuple[str, str, int], ...] = ()
    replay: tuple[DriverRecord, ...] | None = None

    @property
    def handheld(self) -> bool:
        """Whether the survey found a hand-held record (its passes: :mod:`tak_thermo_ros.passes.handheld`)."""
        return self.survey is not None and self.survey.plan is Plan.HANDHELD

    def finished_survey(self) -> RecordSurvey:
        """The survey, after the pass (the one taken first, else what the pass gathered)."""
        if self.survey is not None:
            return self.survey
        assert self.collector is not None
        return self.collector.finish(self.streams)


def temperature_expected(path: Path, streams, options: StreamOptions, *, needed: bool, what: str) -> bool:
    """Whether a pass holds the record's temperature: it needs one and the record has one.

    :param streams: the record's :class:`~tak_thermo_ros.formats.bag.BagStreams`.
    :param needed: the pass reads a temperature (a correction with temperature terms).
    :param what: what needs it, for the message (``'the calibration'``).
    :raises TakError: it is needed and the record holds none.
    """
    present = streams.kind is InputKind.COUNTS or streams.temperature > 0
    if needed and not present:
        msg = f'{path}: no temperature on {options.topics.temperature}, and {what} has temperature terms'
        raise TakError(msg)
    return needed and present


def open_calibration_run(record: Record, options: StreamOptions, *, gravity: float, latitude: float | None,
                         require_reference: bool, decide: bool = True) -> OpenedRun:
    """Ready ``record`` for a calibration-run pass.

    Its input kind, the number of main messages, and for driver bags the static-run reference
    (the specific force and rate at each turntable position, recorded or estimated).

    :param decide: refuse a surveyed record that determines no link (:func:`decided`); ``False``: the
        caller refuses what it cannot take in its own words (``noise``).
    """
    path, streams = record.path, record.streams
    if require_reference and record.reference_refusal is not None:  # a counts bag's, in the bag's words
        raise BagError(record.reference_refusal)
    listed = record_streams_listed(record, options.topics)
    static = None
    survey = None
    replay = None
    if streams.kind is InputKind.IMU:
        if not streams.reference:
            # Without references the record itself says what it is (static, hand-held): one pass first.
            survey, replay = survey_record(record, options, streams.kind, listed,
                                           keep=streams.main <= SURVEY_REPLAY_SAMPLES)
            check_temperature_unit(path, options, survey)
            if decide:
                decided(path, survey)
        if survey is None or survey.plan is Plan.STATIC:
            static = _StaticRun(record, options, recorded_reference=streams.reference > 0,
                                recorded_rate=streams.rate_reference > 0, gravity=gravity, latitude=latitude,
                                survey=survey)
    collector = None if survey is not None else SurveyCollector(streams.kind.value)
    if survey is not None and not (survey.plan is Plan.HANDHELD
                                   or survey.plan is Plan.STATIC and not streams.rate_reference):
        replay = None  # the kept blocks hold no reference topics: a recorded rate reference is read again
    return OpenedRun(streams.kind, streams.main, static, survey, collector, listed, replay)


def check_temperature_unit(path: Path, options: StreamOptions, survey: RecordSurvey) -> None:
    """Refuse a driver record whose temperatures are not degrees Celsius (the readers' one rule, :mod:`.plausible`).

    :raises TakError: one line naming the record and the temperature topic.
    """
    if survey.temperature_problem is not None:
        msg = f'{path}: {options.topics.temperature}: {survey.temperature_problem}'
        raise TakError(msg)


def record_streams_listed(record: Record, topics) -> tuple[tuple[str, str, int], ...]:
    """``(role, topic, messages)`` of a record's streams as every command's survey lists them.

    A flight log lists each sensor on its own (:meth:`~tak_thermo_ros.formats.flight_log.FlightLog.stream_list`);
    a bag its topics (:func:`stream_list`).
    """
    streams = record.streams
    listed = record.stream_list if streams.kind is InputKind.IMU else None
    return listed or stream_list(streams, topics)


def stream_list(streams, topics) -> tuple[tuple[str, str, int], ...]:
    """``(role, topic, messages)`` of a record's streams (:class:`~tak_thermo_ros.formats.bag.BagStreams`)."""
    if streams.kind is InputKind.COUNTS:
        return (('main', topics.counts, streams.main), ('temperature', topics.temp_code, streams.temperature),
                ('reference', topics.reference, streams.reference))
    return (('main', topics.raw_imu, streams.main), ('temperature', topics.temperature, streams.temperature),
            ('reference', topics.reference, streams.reference),
            ('rate_reference', topics.reference_rate, streams.rate_reference), ('mag', topics.mag, streams.mag),
            ('mag_reference', topics.reference_field, streams.mag_reference))


SURVEY_REPLAY_SAMPLES = 2_000_000
"""A record of at most this many main messages keeps its survey's blocks (about 60 bytes a message)."""


def survey_record(record: Record, options: StreamOptions, kind: InputKind, listed: tuple[tuple[str, str, int], ...],
                  *, keep: bool = False) -> tuple[RecordSurvey, tuple[DriverRecord, ...] | None]:
    """What a record holds, from one pass over its main and temperature streams; its blocks if ``keep``.

    The kept blocks hold what a later pass over a driver record needs (stamps, the two sensors, the
    temperature and recorded signals), not the orientation the driver passes through.
    """
    collector = SurveyCollector(kind.value)
    kept: list[DriverRecord] | None = [] if keep and kind is InputKind.IMU else None
    for block in record.blocks(kind=kind, block_samples=options.block_samples, references=False,
                               progress=options.progress):
        collector.add(block)
        if kept is not None:
            kept.append(stripped_block(block))
    return collector.finish(listed), tuple(kept) if kept is not None else None


def stripped_block(block: DriverRecord) -> DriverRecord:
    """What a later pass over a driver record needs of a block kept from its first pass.

    Its stamps, the two sensors, the temperature and recorded signals: not the orientation the
    driver passes through, not the magnetometer.
    """
    return replace(block, orientation=np.zeros((0, 4)), orientation_covariance=np.zeros((0, 9)),
                   mag_stamp_ns=np.zeros(0, dtype=np.int64), mag=np.zeros((0, 3)))


def run_passes(record: Record, options: StreamOptions, opened: OpenedRun, passes: Sequence[SensorPass], *,
               prints: PrintCollector | None = None) -> list[str]:
    """Read the bag once (or replay the survey's blocks), feeding each sensor's pass; the reference lines.

    :param prints: also gathers the record's print (what a calibration keeps of the record it was
        fitted from, :mod:`~tak_thermo_ros.core.records.provenance`) from every block as read.
    """
    if opened.static is not None:
        opened.static.rewind()
    blocks = opened.replay if opened.replay is not None else record.blocks(
        kind=opened.kind, block_samples=options.block_samples, progress=options.progress)
    for block in blocks:
        if opened.collector is not None:
            opened.collector.add(block)
        if prints is not None:
            prints.add(_sensor_records(block, opened.kind))
        if opened.static is not None:
            block = opened.static.check_block(block)
        records = _sensor_records(block, opened.kind)
        for sensor_pass in passes:
            sensor_pass.feed(records[sensor_pass.sensor])
    for sensor_pass in passes:
        sensor_pass.finish()
    return opened.static.finish(options.topics) if opened.static is not None else []


@dataclass(frozen=True)
class FitSettings:
    """The options of ``tak_calib fit``.

    :param effects: effect specs per sensor.
    :param nominal_scale: the held-axis nominal scale per sensor (``None``: none known).
    :param held_spreads: a held term's spread where the records do not bound it (the file's ``uncertainty``).
    """

    effects: dict[str, list[str]]
    bias_order: int = 3
    scale_order: int = 2
    temp_code_ref: float | None = None
    nominal_scale: dict[str, tuple[float, float, float] | None] = field(default_factory=dict)
    settle_time_s: float = 0.0
    gravity: float = STANDARD_GRAVITY
    latitude: float | None = None
    max_effect_samples: int = EFFECT_FIT_MAX_SAMPLES
    held_spreads: HeldSpreads = HeldSpreads()


@dataclass(frozen=True)
class StreamedFit:
    """What ``fit`` prints and writes.

    :param results: per sensor, the fit.
    :param usable: per sensor, the usable (aligned) samples of the whole run.
    :param effect_stride: per sensor fitted with effects, every how many stream rows the
        effects' fit used (1: all).
    :param ignored_temp_codes: per sensor, the temperature messages ignored (not held), by reason.
    :param ignored_references: per sensor, the reference messages ignored, by reason.
    :param held: the sensors held at nominal, not fitted (:func:`fit_imu`; their note says why).
    """

    input_kind: InputKind
    sensors: tuple[str, ...]
    results: dict[str, FitResult]
    usable: dict[str, int]
    effect_stride: dict[str, int]
    reference_lines: tuple[str, ...]
    ignored_temp_codes: dict[str, dict[str, int]] = field(default_factory=dict)
    ignored_references: dict[str, dict[str, int]] = field(default_factory=dict)
    survey: RecordSurvey | None = None
    handheld: Any = None
    temperature_rate_max: float = 0.0
    """The run's fastest temperature change over 60 s (the accelerometer's samples), per second."""
    rate_max: float = 0.0
    """The largest rate reference of a driver run, rad/s (0 for a static run without latitude)."""
    held: tuple[str, ...] = ()
    record_print: RecordPrint | None = None
    """What the calibration keeps of the record (:class:`~tak_thermo_ros.core.records.provenance.RecordPrint`)."""
    noise_windows: dict[str, Any] = field(default_factory=dict)
    """Per sensor its windows within the run's stretches (:class:`~tak_thermo_ros.core.noise.rests.StretchWindows`):
    the noise model the fit writes (:mod:`tak_thermo_ros.passes.rest_noise`)."""


class ImuLinkUndetermined(FitError):
    """A driver record from which today's fit paths cannot determine the accelerometer's and gyroscope's link.

    No reference topics and the board moved (turned by hand), or no temperature at all;
    ``reason`` says which in a few words.
    """

    def __init__(self, message: str, reason: str, survey: RecordSurvey | None = None) -> None:
        super().__init__(message)
        self.reason = reason
        self.survey = survey


MOVED = 'the board moved, no reference'


class EverydayRecord(ImuLinkUndetermined):
    """A record that rests in one orientation and moves between (:attr:`Plan.EVERYDAY`): a pool of one.

    ``fit``, ``validate`` and ``diagnose`` take it as a pool of one record
    (:mod:`~tak_thermo_ros.passes.pool`), as a directory holding only it; a record that
    determines its magnetometer holds the accelerometer and gyroscope instead (:func:`fit_imu`).
    """

    WORDS = 'an everyday record (rests in one orientation, motion between): taken as a pool of one'
    """What the commands say of such a record, after its name, before the pool's lines."""

    def __init__(self, path: Path, survey: RecordSurvey) -> None:
        super().__init__(f'{path}: {self.WORDS}', MOVED, survey)


HELD_IMU_NOTE = 'held at nominal (offset 0, scale 1): {reason}'
"""The note of a sensor held at nominal by :func:`fit_imu`, in the file and in one line of ``fit``."""


def held_result(note: str) -> FitResult:
    """A sensor held at nominal (offset 0, scale 1, no temperature terms), ``note`` saying why."""
    link = held_link(notes=(note,))
    return FitResult(calibration=link, axes=(AxisFit(0.0, 0, 0.0),) * 3, samples=0, dropped={})  # type: ignore


def decided(path: Path, survey: RecordSurvey) -> Plan:
    """The plan of a record without reference topics (:func:`~tak_thermo_ros.core.records.survey.fit_plan`).

    The one place a reference-less record is taken as hand-held or static. A record that never
    rests, and a hand-held record whose sensors come at their own stamps (a flight log: the
    turns need both sensors in every message), determine no link of the accelerometer and
    gyroscope (:class:`ImuLinkUndetermined`: :func:`fit_imu` holds them when the record determines
    its magnetometer, else refuses it in one line); an everyday record goes to the pool
    (:class:`EverydayRecord`).
    """
    from tak_thermo_ros.core.records.still import MIN_STILL_S
    plan = survey.plan
    if plan is Plan.EVERYDAY:
        raise EverydayRecord(path, survey)
    if plan is Plan.MOVING:
        msg = (f'{path}: no reference topics and no still interval (the unit never rested {MIN_STILL_S:g} s or more, '
               f'still {100.0 * survey.still.still_fraction:.0f} % of the time): nothing to fit; rest 5-10 s in each '
               f'orientation (docs/handheld.md)')
        raise ImuLinkUndetermined(msg, MOVED, survey)
    if plan is Plan.HANDHELD and not survey.shared_stamps:
        reason = 'turned by hand, its sensors at their own stamps'
        msg = (f'{path}: {reason}: a hand-held fit takes both sensors in every message (a driver\'s Imu); '
               f'nothing to fit')
        raise ImuLinkUndetermined(msg, reason, survey)
    return plan


def feeding(required: Required, consumers: Sequence[Callable[[AlignedSamples], None]]
            ) -> Callable[[AlignedSamples], None]:
    """One consumer: the aligned block with the recorded signals held (:class:`Required`), to each of ``consumers``."""
    def feed(aligned: AlignedSamples) -> None:
        samples = required(aligned) if required.signals else aligned
        for consume in consumers:
            consume(samples)
    return feed


@contextmanager
def sensor_errors(kind: InputKind, sensor: str) -> Iterator[None]:
    """A fit error names the sensor on driver bags (:func:`prefixed`)."""
    try:
        yield
    except FitError as err:
        if kind is InputKind.COUNTS:
            raise
        raise prefixed(err, SENSOR_NAMES[sensor]) from None


def prefixed(err: FitError, prefix: str) -> FitError:
    """``err`` again, its message after ``prefix: `` and its own text kept as ``reason``.

    A :class:`~tak_thermo_ros.core.fit.ShortRecord` stays one (one sensor's shortage, held
    at nominal with ``reason`` in its note), any other fit error becomes a :class:`FitError`.
    """
    again = (ShortRecord if isinstance(err, ShortRecord) else FitError)(f'{prefix}: {err}')
    again.reason = str(err)
    return again


class Required:
    """Each aligned block with the recorded signals a correction needs held.

    (:func:`require_signals`), its drops (``before_first_<signal>`` included) summed over the run.
    """

    def __init__(self, signals: Sequence[str]) -> None:
        self.signals = tuple(signals)
        self.dropped: dict[str, int] = {}

    def __call__(self, aligned: AlignedSamples) -> AlignedSamples:
        samples = require_signals(aligned, self.signals)
        add_counts(self.dropped, samples.dropped)
        return samples
