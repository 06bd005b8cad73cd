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
:mod:`tak_thermo_ros.streaming_handheld`. See docs/streaming.md.
"""

from __future__ import annotations

import itertools
import math
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator, Sequence

import numpy as np

from tak_thermo_ros.core.records.blocks import BlockAligner, Subsample, add_counts, stride_for
from tak_thermo_ros.core.records.extremes import RunExtremes
from tak_thermo_ros.core.link.correction import Corrector, OutOfRange, acceleration_variance
from tak_thermo_ros.core.fit import FitResult, fit_model
from tak_thermo_ros.core.fit.model import AxisFit
from tak_thermo_ros.core.link.model import InputKind, UnitCalibration, held_link
from tak_thermo_ros.core.records.record import AlignedSamples, ChannelRecord, DriverRecord, require_signals
from tak_thermo_ros.core.records.survey import Plan, RecordSurvey, SurveyCollector
from tak_thermo_ros.core.records.static_run import (
    NotStatic,
    StaticReference,
    check_static,
    rate_line,
    reference_line,
    static_reference,
)
from tak_thermo_ros.core.link.stream_correction import BlockCorrector, BlockUnitCorrector, GravityCheck, RateCheck
from tak_thermo_ros.core.fit.stream import StreamingEffectFit, StreamingFit
from tak_thermo_ros.core.values import SENSOR_NAMES, STANDARD_GRAVITY
from tak_thermo_ros.errors import FitError, TakError

if TYPE_CHECKING:
    from tak_thermo_ros.formats.bag import Topics

DIAGNOSE_MAX_SAMPLES = 1_000_000
"""``diagnose`` works on at most about this many samples, spread evenly over the run."""
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

    def __init__(self, path: Path, options: StreamOptions, *, recorded_reference: bool, recorded_rate: bool,
                 gravity: float, latitude: float | None, survey: RecordSurvey | None = None) -> None:
        from tak_thermo_ros.formats.records import record_blocks
        topics = options.topics
        self.path = path
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
            for block in record_blocks(path, topics=topics, kind=InputKind.IMU, block_samples=options.block_samples,
                                       references=False, progress=options.progress):
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
        """Whether the survey found a hand-held record (its passes: :mod:`tak_thermo_ros.streaming_handheld`)."""
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


def open_calibration_run(path: Path, options: StreamOptions, streams, *, gravity: float, latitude: float | None,
                         require_reference: bool, decide: bool = True) -> OpenedRun:
    """Open ``path`` for a calibration-run pass.

    Its input kind, the number of main messages, and for driver bags the static-run reference
    (the specific force and rate at each turntable position, recorded or estimated).

    :param streams: the record's :class:`~tak_thermo_ros.formats.bag.BagStreams`, as the command read them.
    :param decide: refuse a surveyed record that determines no link (:func:`decided`); ``False``: the
        caller refuses what it cannot take in its own words (``noise``).
    """
    from tak_thermo_ros.formats.records import record_streams
    if require_reference and streams.kind is InputKind.COUNTS:
        streams = record_streams(path, topics=options.topics, require_reference=True)
    listed = stream_list(streams, options.topics)
    static = None
    survey = None
    replay = None
    if streams.kind is InputKind.IMU:
        if not streams.reference:
            # Without references the record itself says what it is (static, hand-held): one pass first.
            survey, replay = survey_record(path, options, streams.kind, listed,
                                           keep=streams.main <= SURVEY_REPLAY_SAMPLES)
            if decide:
                decided(path, survey)
        if survey is None or survey.plan is Plan.STATIC:
            static = _StaticRun(path, options, recorded_reference=streams.reference > 0,
                                recorded_rate=streams.rate_reference > 0, gravity=gravity, latitude=latitude,
                                survey=survey)
    collector = None if survey is not None else SurveyCollector(streams.kind.value)
    if survey is not None and not (survey.plan is Plan.HANDHELD
                                   or survey.plan is Plan.STATIC and not streams.rate_reference):
        replay = None  # the kept blocks hold no reference topics: a recorded rate reference is read again
    return OpenedRun(streams.kind, streams.main, static, survey, collector, listed, replay)


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


def survey_record(path: Path, options: StreamOptions, kind: InputKind, listed: tuple[tuple[str, str, int], ...],
                  *, keep: bool = False) -> tuple[RecordSurvey, tuple[DriverRecord, ...] | None]:
    """What a record holds, from one pass over its main and temperature streams; its blocks if ``keep``.

    The kept blocks hold what a later pass over a driver record needs (stamps, the two sensors, the
    temperature and recorded signals), not the orientation the driver passes through.
    """
    from tak_thermo_ros.formats.records import record_blocks
    collector = SurveyCollector(kind.value)
    kept: list[DriverRecord] | None = [] if keep and kind is InputKind.IMU else None
    for block in record_blocks(path, topics=options.topics, kind=kind, block_samples=options.block_samples,
                               references=False, progress=options.progress):
        collector.add(block)
        if kept is not None:
            kept.append(replace(block, orientation=np.zeros((0, 4)), orientation_covariance=np.zeros((0, 9)),
                                mag_stamp_ns=np.zeros(0, dtype=np.int64), mag=np.zeros((0, 3))))
    return collector.finish(listed), tuple(kept) if kept is not None else None


def run_passes(path: Path, options: StreamOptions, opened: OpenedRun, passes: Sequence[SensorPass]) -> list[str]:
    """Read the bag once (or replay the survey's blocks), feeding each sensor's pass; the reference lines."""
    from tak_thermo_ros.formats.records import record_blocks
    if opened.static is not None:
        opened.static.rewind()
    blocks = opened.replay if opened.replay is not None else record_blocks(
        path, topics=options.topics, kind=opened.kind, block_samples=options.block_samples, progress=options.progress)
    for block in blocks:
        if opened.collector is not None:
            opened.collector.add(block)
        if opened.static is not None:
            block = opened.static.check_block(block)
        records = _sensor_records(block, opened.kind)
        for sensor_pass in passes:
            sensor_pass.feed(records[sensor_pass.sensor])
    for sensor_pass in passes:
        sensor_pass.finish()
    return opened.static.finish(options.topics) if opened.static is not None else []


# ----- fit ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FitSettings:
    """The options of ``tak_calib fit``.

    :param effects: effect specs per sensor.
    :param nominal_scale: the held-axis nominal scale per sensor (``None``: none known).
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


def fit_bag(path: str | Path, settings: FitSettings, options: StreamOptions,
            nominal_for: Callable[[InputKind, tuple[float, float, float] | None], tuple[float, float, float] | None]
            | None = None) -> StreamedFit:
    """The fit of ``tak_calib fit`` in one pass over the bag (a static driver run: after its survey).

    Without effects each sensor's fit is :class:`StreamingFit` (equal to
    :func:`fit_calibration` to rounding). With effects, the fit of :func:`fit_model` runs on
    every m-th sample so that at most ``settings.max_effect_samples`` remain (all of a
    shorter run).

    :param nominal_for: ``(kind, the bag's nominal scale) -> nominal scale`` (counts bags;
        the command line may override the bag's metadata).
    :raises FitError: as :func:`fit_model`, prefixed with the sensor on driver bags.
    :raises ImuLinkUndetermined: a driver bag that today's paths cannot fit (no reference and the
        board moved; no temperature): see :func:`fit_imu`.
    """
    from tak_thermo_ros.formats.records import record_streams
    path = Path(path)
    streams = record_streams(path, topics=options.topics)
    if streams.kind is InputKind.IMU and not streams.temperature:
        reason = f'no temperature on {options.topics.temperature}'
        raise ImuLinkUndetermined(f'{path}: {reason}: no thermal link of the accelerometer and gyroscope', reason)
    try:
        opened = open_calibration_run(path, options, streams, gravity=settings.gravity, latitude=settings.latitude,
                                      require_reference=True)
    except NotStatic as err:
        raise ImuLinkUndetermined(str(err), MOVED) from None
    if opened.handheld:
        from tak_thermo_ros.streaming_handheld import fit_handheld_bag
        return fit_handheld_bag(path, settings, options, opened.survey, replay=opened.replay)
    kind = opened.kind
    sensors = sensors_of(kind)
    if kind is InputKind.COUNTS and settings.effects.get('gyro'):
        msg = f'--gyro-effects: {path} holds channel codes of the accelerometer only'
        raise TakError(msg)
    nominal = dict(settings.nominal_scale)
    if kind is InputKind.COUNTS and nominal_for is not None:
        nominal['accel'] = nominal_for(kind, streams.nominal_scale)
    elif kind is InputKind.IMU:
        nominal = {sensor: (1.0, 1.0, 1.0) for sensor in sensors}

    def aligner() -> BlockAligner:
        return BlockAligner(use_reference=True, reference_expected=True, settle_time_s=settings.settle_time_s)

    def required(sensor: str) -> Required:
        return Required([spec for spec in settings.effects.get(sensor, ()) if spec.startswith('aux:')])

    passes, fits, subsamples, requirements = [], {}, {}, {}
    extremes = {sensor: RunExtremes() for sensor in sensors}
    for sensor in sensors:
        fits[sensor] = StreamingFit(bias_order=settings.bias_order, scale_order=settings.scale_order,
                                    temp_code_ref=settings.temp_code_ref, nominal_scale=nominal.get(sensor))
        requirements[sensor] = required(sensor)
        consumers = [fits[sensor].add, extremes[sensor]]
        if settings.effects.get(sensor):
            stride = stride_for(opened.main, settings.max_effect_samples)
            subsamples[sensor] = Subsample(stride, expected=opened.main // stride + 1)
            consumers.append(subsamples[sensor])
        passes.append(SensorPass(sensor, aligner(), [_feeding(requirements[sensor], consumers)]))
    try:
        lines = run_passes(path, options, opened, passes)
    except NotStatic as err:
        raise ImuLinkUndetermined(str(err), MOVED) from None
    results: dict[str, FitResult] = {}
    usable: dict[str, int] = {}
    second: dict[str, tuple[StreamingEffectFit, FitResult]] = {}
    for sensor_pass in passes:
        sensor = sensor_pass.sensor
        dropped = _summed(sensor_pass.aligner.dropped, requirements[sensor].dropped)
        usable[sensor] = sensor_pass.aligner.kept - sum(requirements[sensor].dropped.values())
        with _sensor_errors(kind, sensor):
            if sensor not in subsamples:
                results[sensor] = fits[sensor].result(dropped=dropped)
                continue
            samples = subsamples[sensor].samples(dropped)
            if not len(samples):
                samples = replace(samples, reference=np.zeros((0, 3)))
            shaped = fit_model(samples, effects=settings.effects[sensor], bias_order=settings.bias_order,
                               scale_order=settings.scale_order, temp_code_ref=settings.temp_code_ref,
                               nominal_scale=nominal.get(sensor))
            if subsamples[sensor].stride == 1:
                results[sensor] = shaped
            else:
                second[sensor] = (StreamingEffectFit(shaped.calibration.effects, fits[sensor]), shaped)
    if second:
        # The shapes are fixed now: a second pass solves every amplitude over the whole run.
        again = {sensor: required(sensor) for sensor in second}
        amplitude_passes = [SensorPass(sensor, aligner(), [_feeding(again[sensor], [amplitudes.add])])
                            for sensor, (amplitudes, _) in second.items()]
        run_passes(path, options, OpenedRun(kind, opened.main, opened.static, replay=opened.replay), amplitude_passes)
        for sensor_pass in amplitude_passes:
            sensor = sensor_pass.sensor
            amplitudes, shaped = second[sensor]
            shape_names = {f'{e.name}.{name}' for e in shaped.calibration.effects for name in e.shape_names()}
            with _sensor_errors(kind, sensor):
                result = amplitudes.result(
                    dropped=_summed(sensor_pass.aligner.dropped, again[sensor].dropped),
                    parameters=[axis.parameters for axis in shaped.axes],
                    shape_errors={k: v for k, v in shaped.parameter_errors.items() if k in shape_names})
            results[sensor] = replace(result, parameter_errors=_with_shape_uncertainty(
                result.parameter_errors, shaped, shape_names, result.samples))
    return StreamedFit(input_kind=kind, sensors=sensors, results=results, usable=usable,
                       effect_stride={sensor: subsample.stride for sensor, subsample in subsamples.items()},
                       reference_lines=tuple(lines),
                       ignored_temp_codes={p.sensor: dict(p.aligner.ignored_temp_codes) for p in passes},
                       ignored_references={p.sensor: dict(p.aligner.ignored_references) for p in passes},
                       temperature_rate_max=extremes['accel'].temperature_rate_max,
                       rate_max=extremes['gyro'].reference_max if 'gyro' in extremes else 0.0,
                       survey=opened.finished_survey())


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
HELD_IMU_NOTE = 'held at nominal (offset 0, scale 1): {reason}'
"""The note of a sensor held at nominal by :func:`fit_imu`, in the file and in one line of ``fit``."""


def fit_imu(path: str | Path, settings: FitSettings, options: StreamOptions,
            nominal_for: Callable[[InputKind, tuple[float, float, float] | None], tuple[float, float, float] | None]
            | None = None, *, hold_undetermined: bool = False) -> StreamedFit:
    """The accelerometer's and gyroscope's link from a record (:func:`fit_bag`), or held at nominal.

    THE decision point for a driver record that today's paths cannot fit
    (:class:`ImuLinkUndetermined`: no reference and the board moved, or no temperature): with
    ``hold_undetermined`` (the record determines something else, its magnetometer) both sensors
    are held at nominal (offset 0, scale 1, no temperature terms) and one line says why;
    otherwise the record is refused as before. A hand-held fit (still intervals, issue 22)
    takes this point's place.
    """
    try:
        return fit_bag(path, settings, options, nominal_for)
    except ImuLinkUndetermined as err:
        if not hold_undetermined:
            raise
        reason, survey = err.reason, err.survey
    results = {}
    for sensor in ('accel', 'gyro'):
        link = held_link(notes=(HELD_IMU_NOTE.format(reason=reason),))
        results[sensor] = FitResult(calibration=link, axes=(AxisFit(0.0, 0, 0.0),) * 3, samples=0,  # type: ignore
                                    dropped={})
    return StreamedFit(input_kind=InputKind.IMU, sensors=('accel', 'gyro'), results=results, usable={},
                       effect_stride={}, reference_lines=(), ignored_temp_codes={'accel': {}, 'gyro': {}},
                       ignored_references={'accel': {}, 'gyro': {}}, held=('accel', 'gyro'), survey=survey)


def decided(path: Path, survey: RecordSurvey) -> Plan:
    """The plan of a record without reference topics (:func:`~tak_thermo_ros.core.records.survey.fit_plan`).

    The one place a reference-less record is taken as hand-held or static. A record that never
    rests, and a hand-held record whose sensors come at their own stamps (a flight log: the
    turns need both sensors in every message), determine no link of the accelerometer and
    gyroscope (:class:`ImuLinkUndetermined`: :func:`fit_imu` holds them when the record determines
    its magnetometer, else refuses it in one line).
    """
    from tak_thermo_ros.core.records.still import MIN_STILL_S
    plan = survey.plan
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


def _with_shape_uncertainty(errors: dict[str, float], shaped: FitResult, shape_names: set[str],
                            samples: int) -> dict[str, float]:
    """The amplitudes' standard errors with the shapes' uncertainty in them.

    The second pass solves the amplitudes with the shapes held, so its errors leave out how
    far the shapes are known; the subsample's joint errors hold it. Scaled to the whole run
    (white noise: errors fall as one over the square root of the samples), the larger of the two
    is reported.
    """
    scale = math.sqrt(shaped.samples / max(samples, 1))
    joint = {key: max(value, shaped.parameter_errors[key] * scale) if key in shaped.parameter_errors else value
             for key, value in errors.items() if key not in shape_names}
    return {**errors, **joint}


def _summed(first: dict[str, int], second: dict[str, int]) -> dict[str, int]:
    total = dict(first)
    add_counts(total, second)
    return total


def _feeding(required: Required, consumers: Sequence[Callable[[AlignedSamples], None]]
             ) -> Callable[[AlignedSamples], None]:
    """One consumer: the aligned block with the recorded signals held (:class:`Required`), to each of ``consumers``."""
    def feed(aligned: AlignedSamples) -> None:
        samples = required(aligned) if required.signals else aligned
        for consume in consumers:
            consume(samples)
    return feed


@contextmanager
def _sensor_errors(kind: InputKind, sensor: str) -> Iterator[None]:
    """A fit error names the sensor on driver bags."""
    try:
        yield
    except FitError as err:
        if kind is InputKind.COUNTS:
            raise
        msg = f'{SENSOR_NAMES[sensor]}: {err}'
        raise FitError(msg) from None


# ----- apply ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Applied:
    """What ``apply`` wrote.

    Messages, the drops by reason, samples outside the calibrated range, and the temperature messages ignored (not
    held) by reason.
    """

    written: int
    dropped: dict[str, int]
    out_of_range: int
    topic: str
    ignored_temp_codes: dict[str, int] = field(default_factory=dict)
    ignored_references: dict[str, int] = field(default_factory=dict)
    mag_written: int = 0
    mag_topic: str = ''
    mag_dropped: dict[str, int] = field(default_factory=dict)
    sensor_written: dict[str, int] = field(default_factory=dict)
    """With sensors at their own stamps: per sensor the messages that carry it (else empty)."""
    sensor_dropped: dict[str, dict[str, int]] = field(default_factory=dict)
    """With sensors at their own stamps: per sensor its samples left out, by reason."""
    survey: RecordSurvey | None = None


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


class _RowsBuffer:
    """Per-message fields that pass through (a driver's orientation), until their rows are aligned."""

    def __init__(self) -> None:
        self.start = 0
        self.chunks: list[tuple[np.ndarray, np.ndarray]] = []
        self.read = 0

    def add(self, orientation: np.ndarray, covariance: np.ndarray) -> None:
        self.chunks.append((orientation, covariance))
        self.read += len(orientation)

    def take(self, rows: np.ndarray, done: int) -> tuple[np.ndarray, np.ndarray]:
        orientation = np.concatenate([c[0] for c in self.chunks]) if self.chunks else np.zeros((0, 4))
        covariance = np.concatenate([c[1] for c in self.chunks]) if self.chunks else np.zeros((0, 9))
        picked = orientation[rows - self.start], covariance[rows - self.start]
        while self.chunks and self.start + len(self.chunks[0][0]) <= done:
            self.start += len(self.chunks.pop(0)[0])
        return picked


class _OwnStamps:
    """``apply`` of a driver record whose sensors come at their own stamps.

    Each sensor is aligned and corrected on its own samples (no resampling); the corrected
    samples are merged into Imu messages by stamp
    (:func:`~tak_thermo_ros.core.records.record.sensor_messages`): an accelerometer and a
    gyroscope sample with the same stamp share a message, any other message carries one sensor
    and marks the other absent (zeros, its covariance[0] = -1, as ``sensor_msgs/msg/Imu``
    says). A message's orientation is passed through from the input message at that stamp.
    Messages are written once both sensors' alignments have moved past their stamps.
    """

    SENSORS = ('accel', 'gyro')

    def __init__(self, unit: UnitCalibration, *, out_of_range: OutOfRange, output: Path,
                 temperature_expected: bool = True) -> None:
        self.correctors = {sensor: BlockCorrector(unit.sensor(sensor), out_of_range=out_of_range)
                           for sensor in self.SENSORS}
        self.variances = {sensor: acceleration_variance(unit.sensor(sensor)) for sensor in self.SENSORS}
        self.aligners = {sensor: BlockAligner(use_reference=False, temperature_expected=temperature_expected)
                         for sensor in self.SENSORS}
        self.required = {sensor: Required(self.correctors[sensor].signals) for sensor in self.SENSORS}
        self.ready: dict[str, tuple[np.ndarray, np.ndarray]] = {
            sensor: (np.zeros(0, dtype=np.int64), np.zeros((0, 3))) for sensor in self.SENSORS}
        self.last_read: dict[str, int | None] = {sensor: None for sensor in self.SENSORS}
        self.messages = (np.zeros(0, dtype=np.int64), np.zeros((0, 4)), np.zeros((0, 9)))
        self.output = output
        self.outside = 0
        self.written = {sensor: 0 for sensor in self.SENSORS}
        self.frame_id = ''

    def push(self, writer, block: DriverRecord) -> None:
        """Align, correct and hold one block's samples; write the messages that became final."""
        self.frame_id = self.frame_id or block.frame_id
        stamps, orientation, covariance = self.messages
        self.messages = (np.concatenate([stamps, block.stamp_ns]), np.concatenate([orientation, block.orientation]),
                         np.concatenate([covariance, block.orientation_covariance]))
        for sensor in self.SENSORS:
            record = block.channel(sensor)
            if len(record.counts_stamp_ns):
                top = int(record.counts_stamp_ns.max())
                last = self.last_read[sensor]
                self.last_read[sensor] = top if last is None else max(last, top)
            self._correct(sensor, self.aligners[sensor].push(record))
        self._write(writer, final=False)

    def finish(self, writer) -> None:
        """The samples still pending at the end of the run."""
        for sensor in self.SENSORS:
            self._correct(sensor, self.aligners[sensor].finish())
        self._write(writer, final=True)

    def _correct(self, sensor: str, aligned: AlignedSamples) -> None:
        samples = self.required[sensor](aligned)
        if not len(samples):
            return
        corrector = self.correctors[sensor]
        corrected = corrector.correct(samples.counts, samples.temp_code, stamp_s=samples.stamp_s, aux=samples.aux)
        bad = int(np.count_nonzero(~np.isfinite(corrected)))
        if bad:
            msg = f'{self.output}: corrected values: {bad} values are not finite (NaN or infinite); nothing written'
            raise TakError(msg)
        self.outside += corrector.out_of_range_count(samples.temp_code)
        stamps, values = self.ready[sensor]
        self.ready[sensor] = (np.concatenate([stamps, samples.stamp_ns]), np.concatenate([values, corrected]))

    def _horizon(self, sensor: str) -> float:
        """Every sample of ``sensor`` stamped at or before this is corrected (stamps read in order)."""
        pending = self.aligners[sensor].state.pending_stamp_ns
        if len(pending):
            return float(pending.min()) - 1.0
        last = self.last_read[sensor]
        return math.inf if last is None else float(last)

    def _write(self, writer, *, final: bool) -> None:
        from tak_thermo_ros.core.records.record import rows_at, sensor_messages
        horizon = math.inf if final else min(self._horizon(sensor) for sensor in self.SENSORS)
        parts = {}
        for sensor in self.SENSORS:
            stamps, values = self.ready[sensor]
            now = stamps <= horizon
            parts[sensor] = (stamps[now], values[now])
            self.ready[sensor] = (stamps[~now], values[~now])
        (accel_stamps, accel), (gyro_stamps, gyro) = parts['accel'], parts['gyro']
        paired = sensor_messages(accel_stamps, gyro_stamps)
        if not len(paired.stamp_ns):
            return
        stamps, orientation, covariance = self.messages
        row = rows_at(stamps, paired.stamp_ns)
        known = row >= 0
        quaternion = np.where(known[:, None], orientation[np.maximum(row, 0)] if len(stamps) else 0.0,
                              np.array([0.0, 0.0, 0.0, 1.0]))
        orientation_covariance = np.where(known[:, None], covariance[np.maximum(row, 0)] if len(stamps) else 0.0,
                                          np.array([-1.0, *[0.0] * 8]))
        keep = stamps > paired.stamp_ns[-1]
        self.messages = (stamps[keep], orientation[keep], covariance[keep])
        accel_present, gyro_present = paired.accel_row >= 0, paired.gyro_row >= 0
        writer.write(paired.stamp_ns, self.frame_id, accel[np.maximum(paired.accel_row, 0)] if len(accel) else
                     np.zeros((len(paired.stamp_ns), 3)), self.variances['accel'],
                     angular_velocity=gyro[np.maximum(paired.gyro_row, 0)] if len(gyro) else
                     np.zeros((len(paired.stamp_ns), 3)), angular_variance=self.variances['gyro'],
                     orientation=quaternion, orientation_covariance=orientation_covariance,
                     accel_present=accel_present, gyro_present=gyro_present)
        self.written['accel'] += int(np.count_nonzero(accel_present))
        self.written['gyro'] += int(np.count_nonzero(gyro_present))

    def dropped(self) -> dict[str, dict[str, int]]:
        """Per sensor, its samples left out by reason."""
        return {sensor: dict(self.required[sensor].dropped) for sensor in self.SENSORS}


def apply_bag(path: str | Path, unit: UnitCalibration, output: str | Path, options: StreamOptions, *,
              storage: str = 'mcap', out_of_range: OutOfRange = OutOfRange.CLAMP, force: bool = False) -> Applied:
    """Correct a bag block by block into an Imu bag that stays open (``tak_calib apply``).

    A driver record whose sensors have their own stamps (a flight log, Imu messages that carry
    one sensor) is corrected per sensor (:class:`_OwnStamps`); otherwise a message is corrected
    or dropped whole, as in the node.

    :param force: replace an existing output bag (:func:`tak_thermo_ros.formats.files.check_output`).
    :raises TakError: a corrected value is not finite (nothing is written).
    """
    from tak_thermo_ros.formats.bag import ImuBagWriter
    from tak_thermo_ros.formats.records import record_blocks, record_streams
    path = Path(path)
    topics = options.topics
    streams = record_streams(path, topics=topics)
    kind = streams.kind
    survey = SurveyCollector(kind.value)
    expected = temperature_expected(path, streams, options, needed=unit.needs_temperature, what='the calibration')
    blocks = record_blocks(path, topics=topics, kind=kind, block_samples=options.block_samples, references=False,
                           progress=options.progress)
    first = next(blocks, None)
    magnetometer = None
    if kind is InputKind.IMU and unit.mag is not None and streams.mag:
        from tak_thermo_ros.streaming_mag import MagApplier
        magnetometer = MagApplier(unit.mag, out_of_range=out_of_range, topic=topics.compensated_mag,
                                  temperature_expected=temperature_expected(
                                      path, streams, options, needed=unit.mag.thermal.needs_temperature,
                                      what="the calibration's magnetometer"))
    if isinstance(first, DriverRecord) and not first.shared_stamps:
        return _apply_own_stamps(unit, output, options, first, blocks, magnetometer, storage=storage,
                                 out_of_range=out_of_range, force=force, holding=expected)
    blocks = itertools.chain([] if first is None else [first], blocks)
    topic = topics.imu if kind is InputKind.COUNTS else topics.compensated_imu
    aligner = BlockAligner(use_reference=False, temperature_expected=expected)
    corrector = BlockUnitCorrector(unit, out_of_range=out_of_range)
    required = Required(corrector.signals)
    accel_variance = acceleration_variance(unit.accel)
    gyro_variance = acceleration_variance(unit.gyro) if unit.gyro is not None else None
    passing = _RowsBuffer()
    outside = 0
    frame_id = ''
    with ImuBagWriter(output, topic=topic, storage=storage, force=force) as writer:

        def write(aligned: AlignedSamples) -> None:
            nonlocal outside
            samples = required(aligned)
            if not len(samples):
                if kind is InputKind.IMU and samples.rows is not None:
                    passing.take(samples.rows, aligner.state.rows_done)
                return
            corrected = corrector.correct(samples.counts, samples.temp_code, stamp_s=samples.stamp_s, aux=samples.aux)
            bad = int(np.count_nonzero(~np.isfinite(corrected)))
            if bad:
                msg = f'{output}: corrected values: {bad} values are not finite (NaN or infinite); nothing written'
                raise TakError(msg)
            outside += corrector.out_of_range_count(samples.temp_code)
            extra = {}
            if kind is InputKind.IMU:
                orientation, covariance = passing.take(samples.rows, aligner.state.rows_done)
                extra = dict(angular_velocity=corrected[:, 3:6], angular_variance=gyro_variance,
                             orientation=orientation, orientation_covariance=covariance)
            writer.write(samples.stamp_ns, frame_id, corrected[:, :3], accel_variance, **extra)

        for block in blocks:
            survey.add(block)
            if isinstance(block, DriverRecord):
                if not block.shared_stamps:
                    msg = (f'{path}: its first Imu messages carry both sensors, later ones one sensor each: a '
                           f'record that changes so is not supported (split it)')
                    raise TakError(msg)
                passing.add(block.orientation, block.orientation_covariance)
                record = block.six_channels()
                if magnetometer is not None:
                    magnetometer.push(writer, block.channel('mag'), output)
            else:
                record = block
            frame_id = frame_id or record.frame_id
            write(aligner.push(record))
        write(aligner.finish())
        if magnetometer is not None:
            magnetometer.finish(writer, frame_id, output)
        written = writer.written
    return Applied(written=written, dropped=required.dropped, out_of_range=outside, topic=topic,
                   ignored_temp_codes=dict(aligner.ignored_temp_codes),
                   ignored_references=dict(aligner.ignored_references),
                   mag_written=writer.written_mag, mag_topic=topics.compensated_mag if magnetometer else '',
                   mag_dropped=dict(magnetometer.aligner.dropped) if magnetometer else {},
                   survey=survey.finish(stream_list(streams, topics)))


def _apply_own_stamps(unit: UnitCalibration, output: str | Path, options: StreamOptions, first: DriverRecord,
                      blocks: Iterator, magnetometer, *, storage: str, out_of_range: OutOfRange, force: bool,
                      holding: bool = True) -> Applied:
    """``apply`` of a driver record whose sensors have their own stamps (:class:`_OwnStamps`).

    :param magnetometer: ``apply_bag``'s :class:`~tak_thermo_ros.streaming_mag.MagApplier`, or ``None``.
    :param holding: the pass reads a temperature (:func:`temperature_expected`).
    """
    from tak_thermo_ros.formats.bag import ImuBagWriter
    topics = options.topics
    applier = _OwnStamps(unit, out_of_range=out_of_range, output=Path(output), temperature_expected=holding)
    with ImuBagWriter(output, topic=topics.compensated_imu, storage=storage, force=force) as writer:
        for block in itertools.chain([first], blocks):
            applier.push(writer, block)
            if magnetometer is not None:
                magnetometer.push(writer, block.channel('mag'), output)
        applier.finish(writer)
        if magnetometer is not None:
            magnetometer.finish(writer, applier.frame_id, output)
        written = writer.written
    accel_aligner = applier.aligners['accel']
    return Applied(written=written, dropped={}, out_of_range=applier.outside, topic=topics.compensated_imu,
                   ignored_temp_codes=dict(accel_aligner.ignored_temp_codes),
                   ignored_references=dict(accel_aligner.ignored_references),
                   mag_written=writer.written_mag, mag_topic=topics.compensated_mag if magnetometer else '',
                   mag_dropped=dict(magnetometer.aligner.dropped) if magnetometer else {},
                   sensor_written=dict(applier.written), sensor_dropped=applier.dropped())


# ----- validate -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Validated:
    """The sums of ``validate``: |g| (accelerometer) and, on driver bags, the rate error."""

    input_kind: InputKind
    gravity: GravityCheck
    rate: RateCheck | None
    reference_lines: tuple[str, ...]
    accel_dropped: dict[str, int] = field(default_factory=dict)
    accel_ignored_temp_codes: dict[str, int] = field(default_factory=dict)
    accel_ignored_references: dict[str, int] = field(default_factory=dict)
    survey: RecordSurvey | None = None


def validate_bag(path: str | Path, unit: UnitCalibration, options: StreamOptions, *, gravity: float,
                 latitude: float | None = None, out_of_range: OutOfRange = OutOfRange.CLAMP,
                 expect_kind: Callable[[InputKind], None] | None = None) -> Validated | Any:
    """``tak_calib validate`` in one pass (after the survey for a static driver run or a hand-held record).

    A hand-held record gives a :class:`~tak_thermo_ros.streaming_handheld.HandheldValidated`.

    :param expect_kind: called with the bag's kind before the pass (raises on a mismatch).
    """
    from tak_thermo_ros.formats.records import record_streams
    path = Path(path)
    streams = record_streams(path, topics=options.topics)
    kind = streams.kind
    if expect_kind is not None:
        expect_kind(kind)
    holding = temperature_expected(path, streams, options, needed=unit.needs_temperature, what='the calibration')
    calibration_run = kind is InputKind.IMU
    opened = open_calibration_run(path, options, streams, gravity=gravity, latitude=latitude, require_reference=False)
    if opened.handheld:
        from tak_thermo_ros.streaming_handheld import validate_handheld_bag
        return validate_handheld_bag(path, unit, options, opened.survey, gravity=gravity, latitude=latitude,
                                     out_of_range=out_of_range, replay=opened.replay)
    # Before correction: a driver's values as recorded; codes through the file's nominal scale and offset.
    gravity_check = GravityCheck(unit.accel, gravity=gravity, out_of_range=out_of_range, raw_before=calibration_run)
    rate_check = (RateCheck(unit.gyro, out_of_range=out_of_range, raw_before=True)
                  if unit.gyro is not None else None)
    accel_required = Required(Corrector(unit.accel).signals)

    def add_gravity(aligned: AlignedSamples) -> None:
        samples = accel_required(aligned)
        gravity_check.add(samples.counts, samples.temp_code, samples.stamp_s, aux=samples.aux)

    accel_pass = SensorPass('accel', BlockAligner(use_reference=calibration_run, reference_expected=calibration_run,
                                                  temperature_expected=holding), [add_gravity])
    passes = [accel_pass]
    if calibration_run:
        gyro_pass = SensorPass('gyro', BlockAligner(use_reference=True, reference_expected=True,
                                                    temperature_expected=holding))
        if rate_check is not None:
            gyro_required = Required(Corrector(unit.gyro).signals)  # type: ignore[arg-type]

            def add_rate(aligned: AlignedSamples) -> None:
                samples = gyro_required(aligned)
                rate_check.add(samples.counts, samples.temp_code, samples.reference, samples.stamp_s,
                               aux=samples.aux)
            gyro_pass.consumers.append(add_rate)
        passes.append(gyro_pass)
    lines = run_passes(path, options, opened, passes)
    return Validated(input_kind=kind, gravity=gravity_check, rate=rate_check, reference_lines=tuple(lines),
                     accel_dropped=accel_required.dropped,
                     accel_ignored_temp_codes=dict(accel_pass.aligner.ignored_temp_codes),
                     accel_ignored_references=dict(accel_pass.aligner.ignored_references),
                     survey=opened.finished_survey())


# ----- diagnose -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BoundedRun:
    """A calibration run's samples for ``diagnose``: every ``stride``-th stream row, at most about ``max_samples``.

    :param samples: per sensor, the kept samples (``dropped`` counts the whole run's drops).
    :param usable: per sensor, the usable samples of the whole run.
    """

    input_kind: InputKind
    samples: dict[str, AlignedSamples]
    usable: dict[str, int]
    stride: int
    reference_lines: tuple[str, ...]
    survey: RecordSurvey | None = None
    handheld: Any = None


def bounded_run(path: str | Path, options: StreamOptions, *, settle_time_s: float = 0.0,
                gravity: float = STANDARD_GRAVITY,
                latitude: float | None = None, max_samples: int = DIAGNOSE_MAX_SAMPLES,
                unit: UnitCalibration | None = None) -> BoundedRun:
    """One pass collecting a bounded subsample spread evenly over the run, references held.

    A hand-held record (no reference topics, several still orientations) gives its still
    samples with the references it has (gravity along each rest's up direction as ``unit``
    corrects it, zero rate) and ``handheld``, the turns' closure (``unit`` required).

    :raises TakError: a driver record without a temperature (the diagnosis looks at the residual
        against the temperature).
    """
    from tak_thermo_ros.formats.records import record_streams
    path = Path(path)
    streams = record_streams(path, topics=options.topics)
    if streams.kind is InputKind.IMU and not streams.temperature:
        msg = f'{path}: no temperature on {options.topics.temperature}: diagnose looks at the residual against it'
        raise TakError(msg)
    opened = open_calibration_run(path, options, streams, gravity=gravity, latitude=latitude, require_reference=True)
    if opened.handheld:
        from tak_thermo_ros.streaming_handheld import handheld_record, rest_samples
        if unit is None:
            msg = f'{path}: a hand-held record: its references come from a calibration (give one)'
            raise TakError(msg)
        record, _ = handheld_record(path, options, opened.survey, budget=max_samples, replay=opened.replay)
        samples, check = rest_samples(record, unit, gravity=gravity, latitude=latitude)
        usable = {sensor: int(opened.survey.still.samples.sum()) for sensor in samples}
        return BoundedRun(input_kind=InputKind.IMU, samples=samples, usable=usable, stride=record.stride,
                          reference_lines=(), survey=opened.survey, handheld=check)
    stride = stride_for(opened.main, max_samples)
    passes, subsamples = [], {}
    for sensor in sensors_of(opened.kind):
        subsamples[sensor] = Subsample(stride, expected=opened.main // stride + 1)
        passes.append(SensorPass(sensor, BlockAligner(use_reference=True, reference_expected=True,
                                                      settle_time_s=settle_time_s), [subsamples[sensor]]))
    lines = run_passes(path, options, opened, passes)
    return BoundedRun(input_kind=opened.kind,
                      samples={p.sensor: subsamples[p.sensor].samples(p.aligner.dropped) for p in passes},
                      usable={p.sensor: p.aligner.kept for p in passes}, stride=stride,
                      reference_lines=tuple(lines), survey=opened.finished_survey())
