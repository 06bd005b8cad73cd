"""``tak_calib apply``'s pass: the record corrected block by block into a new bag."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from tak_thermo_ros.core.records.blocks import BlockAligner
from tak_thermo_ros.core.link.correction import OutOfRange, acceleration_variance
from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.records.record import AlignedSamples, DriverRecord
from tak_thermo_ros.core.records.survey import RecordSurvey, SurveyCollector
from tak_thermo_ros.core.link.stream_correction import BlockCorrector, BlockUnitCorrector
from tak_thermo_ros.errors import TakError
from tak_thermo_ros.passes.run import (
    Required,
    StreamOptions,
    check_temperature_unit,
    record_streams_listed,
    temperature_expected,
)


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
    turn_on: tuple[str, ...] = ()
    """With ``--turn-on first-rest``: what was taken (or not) at the first rest."""


@dataclass(frozen=True)
class TurnOnSettings:
    """``apply --turn-on first-rest``: the run's turn-on offset from its first rest, as the node's ``turn_on``.

    :param latitude: degrees (the node's ``latitude``), or ``None``.
    """

    latitude: float | None = None

    def watch(self, unit: UnitCalibration):
        """The watch that finds the first rest and takes the offset.

        :raises TakError: the calibration cannot give it (no noise model, no turn-on repeatability).
        """
        from tak_thermo_ros.core.link.watch import CalibrationWatch, turn_on_unavailable, watch_unavailable
        missing = turn_on_unavailable(unit)
        reason = watch_unavailable(unit) or (f'the calibration holds no {missing}' if missing else '')
        if reason:
            msg = f'--turn-on first-rest: {reason}'
            raise TakError(msg)
        return CalibrationWatch(unit, latitude=self.latitude, turn_on=True)


def turn_on_said(watch) -> tuple[str, ...]:
    """What the watch said of the run's turn-on offset; when it found no rest, why, in the file's own terms.

    The survey's rests are the record's own quietest stretches (one record has no other yardstick); the
    watch's are still within the calibration's noise model: a record that never rested has the former
    and not the latter (the pool calls it "never rested" so, against its other records).
    """
    if watch.turn_on_lines:
        return tuple(watch.turn_on_lines)
    finder = watch.finder
    return (f'turn-on offset: no rest within the calibration\'s noise model ({finder.still_windows} of '
            f'{finder.windows} windows still), nothing taken',)


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
              storage: str = 'mcap', out_of_range: OutOfRange = OutOfRange.CLAMP, force: bool = False,
              turn_on: TurnOnSettings | None = None) -> Applied:
    """Correct a bag block by block into an Imu bag that stays open (``tak_calib apply``).

    A driver record whose sensors have their own stamps (a flight log, Imu messages that carry
    one sensor) is corrected per sensor (:class:`_OwnStamps`); otherwise a message is corrected
    or dropped whole, as in the node.

    :param force: replace an existing output bag (:func:`tak_thermo_ros.formats.files.check_output`).
    :param turn_on: take the run's turn-on offset at its first rest (``--turn-on first-rest``), as the node's
        ``turn_on: first_rest`` does on the same messages; ``None``: not.
    :raises TakError: a corrected value is not finite (nothing is written); ``turn_on`` on a record the node
        would not take it from.
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
        from tak_thermo_ros.passes.magnetometer import MagApplier
        magnetometer = MagApplier(unit.mag, out_of_range=out_of_range, topic=topics.compensated_mag,
                                  temperature_expected=temperature_expected(
                                      path, streams, options, needed=unit.mag.thermal.needs_temperature,
                                      what="the calibration's magnetometer"))
    watch = turn_on.watch(unit) if turn_on is not None else None
    apart = isinstance(first, DriverRecord) and not first.shared_stamps
    if watch is not None and (kind is not InputKind.IMU or apart):
        msg = (f'{path}: --turn-on first-rest takes a driver\'s Imu whose messages carry both sensors (as the node '
               f'does); this record\'s sensors come at their own stamps')
        raise TakError(msg)
    if apart:
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
            if watch is not None:  # the node's turn-on offset: the same rests, the same floats
                corrected = watch.take_block(samples.stamp_ns, corrected, samples.temp_code)
                watch.pending.clear()  # only the first rest matters here: nothing is judged
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
        finished = survey.finish(record_streams_listed(path, streams, topics))
        check_temperature_unit(path, options, finished)  # before the bag is kept: nothing written
        written = writer.written
    if watch is not None:
        watch.finish()
    return Applied(written=written, dropped=required.dropped, out_of_range=outside, topic=topic,
                   turn_on=turn_on_said(watch) if watch is not None else (),
                   ignored_temp_codes=dict(aligner.ignored_temp_codes),
                   ignored_references=dict(aligner.ignored_references),
                   mag_written=writer.written_mag, mag_topic=topics.compensated_mag if magnetometer else '',
                   mag_dropped=dict(magnetometer.aligner.dropped) if magnetometer else {},
                   survey=finished)


def _apply_own_stamps(unit: UnitCalibration, output: str | Path, options: StreamOptions, first: DriverRecord,
                      blocks: Iterator, magnetometer, *, storage: str, out_of_range: OutOfRange, force: bool,
                      holding: bool = True) -> Applied:
    """``apply`` of a driver record whose sensors have their own stamps (:class:`_OwnStamps`).

    :param magnetometer: ``apply_bag``'s :class:`~tak_thermo_ros.passes.magnetometer.MagApplier`, or ``None``.
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
