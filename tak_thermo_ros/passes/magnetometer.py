"""``tak_calib``'s passes over the magnetometer of a driver bag, in blocks (as :mod:`tak_thermo_ros.passes`).

The magnetometer is its own stream (``/imu/mag``, ``sensor_msgs/msg/MagneticField``, tesla),
aligned on its own stamps with the same temperature held
(:class:`~tak_thermo_ros.core.records.blocks.BlockAligner`), fitted by the same blocked fit
(:class:`~tak_thermo_ros.core.fit.stream.StreamingFit`) and corrected by
:class:`~tak_thermo_ros.core.magnetometer.channel.MagCorrector`.

- The thermal link comes from the calibration bag: with a reference field
  (``/tak/reference_field``, a coil or a table in a surveyed field) the scale is fitted as
  on a rate table; without one the run must be static (one orientation): the reference is
  the mean measured field, the scale is held at 1 and said, and the sensor's constant
  offset goes into the hard iron (the thermal link keeps only the drift about the run's mean).
- The iron comes from a separate rotation record (``--iron-run BAG``): the iron belongs to
  the installation, measured by turning the vehicle at whatever temperature, while the
  chamber run is of a unit that stays still; the rotation record is corrected by the thermal
  link just fitted before the ellipsoid is fitted to it.
- A record whose field turns (:func:`survey_field`: a unit turned by hand, no reference field)
  is itself the rotation record: the iron, and the thermal link where its temperature
  determines one (the ellipsoid's centre follows the temperature), come from it alone
  (:func:`~tak_thermo_ros.core.magnetometer.rotation.fit_rotation`); a temperature is optional.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Sequence

import numpy as np

from tak_thermo_ros.core.fit import FitResult, fit_model
from tak_thermo_ros.core.fit.stream import StreamingFit
from tak_thermo_ros.core.link.correction import Corrector, OutOfRange
from tak_thermo_ros.core.link.model import IDENTITY_3X3, InputKind, MagnetometerCalibration
from tak_thermo_ros.core.magnetometer.channel import MagCorrector, check_tesla
from tak_thermo_ros.core.magnetometer.iron import EllipsoidFit, fit_ellipsoid
from tak_thermo_ros.core.fit.model import AxisFit
from tak_thermo_ros.core.records.blocks import BlockAligner, Subsample, stride_for
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.errors import BagError, FitError, TakError
from tak_thermo_ros.passes.run import held_result, prefixed

if TYPE_CHECKING:
    from tak_thermo_ros.formats.records import Record

MAX_STATIC_TURN_DEG = 10.0
"""Largest angle between a sample of a static run's field and its mean (the unit moved)."""
CORRUPT_FIELD_T = 1e6
"""A field component at or beyond this is a corrupt message, whatever unit a driver mistook for tesla
(microtesla-sized numbers reach some 1e3; those, and gauss-sized ones, are refused by :func:`check_tesla`)."""
MAX_ROTATION_SAMPLES = 100_000
"""A rotation record's fit takes at most about this many samples, spread evenly over it."""
NO_IRON_NOTE = 'hard and soft iron not fitted (no --iron-run): hard_iron 0, soft_iron identity'


def has_mag(record: Record) -> bool:
    """Whether a driver record holds magnetometer messages."""
    streams = record.streams
    return streams.kind is InputKind.IMU and streams.mag > 0


def _mag_blocks(record: Record, options, *, references: bool):
    """The bag's blocks as the magnetometer's :class:`ChannelRecord` (its stamps, tesla).

    The first block with finite values is checked to be in tesla (:func:`check_tesla`): a topic
    in gauss-sized numbers is refused before anything is computed from it. A sample with a
    component of :data:`CORRUPT_FIELD_T` or more is a corrupt message, not a field: it is made
    NaN, so that the alignment leaves it out and counts it (``non_finite``) as it does a NaN.
    """
    checked = False
    for block in record.blocks(kind=InputKind.IMU, block_samples=options.block_samples, references=references,
                               progress=options.progress):
        mag = corrupt_as_nan(block.channel('mag'))
        if not checked:
            finite = mag.counts[np.all(np.isfinite(mag.counts), axis=1)]
            if len(finite):
                check_tesla(finite, f'{record.path}: {options.topics.mag}')
                checked = True
        yield mag


def corrupt_as_nan(record):
    """The magnetometer's record with each sample of a component at :data:`CORRUPT_FIELD_T` or more made NaN.

    (A corrupt message, not a field: the alignment leaves it out and counts it as a NaN, in every pass.)
    """
    with np.errstate(invalid='ignore'):
        corrupt = np.any(np.abs(record.counts) >= CORRUPT_FIELD_T, axis=1)
    if not corrupt.any():
        return record
    return replace(record, counts=np.where(corrupt[:, None], np.nan, record.counts))


@dataclass(frozen=True)
class FieldSurvey:
    """What one pass over a record's magnetometer shows: its mean field and whether it turns.

    :param mean: the mean measured field, tesla.
    :param spread: the field's largest standard deviation along one direction, tesla.
    :param magnitude: the RMS of ``|B|``, tesla.
    :param count: finite samples.
    """

    mean: np.ndarray
    spread: float
    magnitude: float
    count: int

    @property
    def turned(self) -> bool:
        """Whether the field turns as a rotation record's does (beyond a static run's tolerance).

        A static run's field wanders by its noise and drift only; one turned through orientations
        spreads by a good part of its magnitude (about 0.58 of it over the whole sphere).
        """
        return self.spread > math.sin(math.radians(MAX_STATIC_TURN_DEG)) * self.magnitude


def survey_field(record: Record, options) -> FieldSurvey:
    """The mean field and its spread (one pass, sums only); refuses a topic not in tesla."""
    total, squares, count, energy = np.zeros(3), np.zeros((3, 3)), 0, 0.0
    shift = None
    for mag in _mag_blocks(record, options, references=False):
        finite = mag.counts[np.all(np.isfinite(mag.counts), axis=1)]
        if not len(finite):
            continue
        if shift is None:
            shift = finite[0].copy()
        centred = finite - shift
        total += centred.sum(axis=0)
        squares += centred.T @ centred
        energy += float(np.sum(finite * finite))
        count += len(finite)
    if not count or shift is None:
        msg = f'{record.path}: no finite messages on {options.topics.mag}'
        raise BagError(msg)
    mean_centred = total / count
    covariance = squares / count - np.outer(mean_centred, mean_centred)
    spread = math.sqrt(max(float(np.linalg.eigvalsh((covariance + covariance.T) / 2.0)[-1]), 0.0))
    return FieldSurvey(mean=mean_centred + shift, spread=spread, magnitude=math.sqrt(energy / count), count=count)


@dataclass(frozen=True)
class _CalibrationPass:
    """One pass over a calibration run's magnetometer with its reference held (see :func:`_calibration_pass`)."""

    static: bool
    mean: np.ndarray | None
    max_turn_deg: float
    aligner: BlockAligner


def _calibration_pass(record: Record, options, consumers, survey: FieldSurvey | None = None) -> _CalibrationPass:
    """Align the magnetometer on its reference and hand each block to ``consumers``.

    The reference is the recorded field, or a static run's mean field (``survey``'s, or one pass
    more); refuses a static run that turned, one without a temperature and a topic not in tesla.
    """
    path, topics, streams = record.path, options.topics, record.streams
    static = streams.mag_reference == 0
    if not streams.temperature:
        msg = f'magnetometer: {path}: no temperature on {topics.temperature}: a static run fits the link against it'
        raise FitError(msg)
    mean = (survey or survey_field(record, options)).mean if static else None
    aligner = BlockAligner(use_reference=True, reference_expected=True)
    max_turn = 0.0
    first = True

    def hand_on(aligned: AlignedSamples) -> None:
        for consume in consumers:
            consume(aligned)

    for mag in _mag_blocks(record, options, references=True):
        if static:
            finite = mag.counts[np.all(np.isfinite(mag.counts), axis=1)]
            if len(finite):
                cosine = (finite @ mean) / (np.linalg.norm(finite, axis=1) * np.linalg.norm(mean))
                max_turn = max(max_turn, float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))).max()))
            if first:
                # The static run's reference, held from before the first sample.
                mag = replace(mag, reference_stamp_ns=np.zeros(1, dtype=np.int64), reference=mean.reshape(1, 3))
                first = False
        hand_on(aligner.push(mag))
    hand_on(aligner.finish())
    if static and max_turn > MAX_STATIC_TURN_DEG:
        msg = (f'magnetometer: {path}: the field turns by up to {max_turn:.1f} deg from its mean '
               f'(at most {MAX_STATIC_TURN_DEG:g}): the thermal fit takes a static run, or a reference field '
               f'on {topics.reference_field}; a rotation record goes to --iron-run')
        raise FitError(msg)
    return _CalibrationPass(static, mean, max_turn, aligner)


def bounded_mag_run(record: Record, options, *, max_samples: int,
                    survey: FieldSurvey | None = None) -> tuple[AlignedSamples, int, str]:
    """``diagnose``'s magnetometer samples, the usable count of the whole run and the reference's line.

    Every n-th sample, at most about ``max_samples``, the reference held as for the fit.

    :param survey: the record's :func:`survey_field`, when the caller took it (else one pass more
        for a static run).
    """
    count = record.streams.mag
    stride = stride_for(count, max_samples)
    subsample = Subsample(stride, expected=count // stride + 1)
    calibration_pass = _calibration_pass(record, options, [subsample], survey)
    line = (f'magnetometer: reference field {options.topics.reference_field} as recorded' if not calibration_pass.static
            else f'magnetometer: static run, reference the mean field x y z {_microtesla(calibration_pass.mean)} uT')
    return subsample.samples(calibration_pass.aligner.dropped), calibration_pass.aligner.kept, line


@dataclass(frozen=True)
class MagFit:
    """What ``fit`` prints and writes for the magnetometer.

    :param calibration: the magnetometer's correction.
    :param thermal: the thermal link's fit.
    :param iron: the ellipsoid fit, or ``None`` without a rotation record.
    :param lines: how the reference was obtained (one line each).
    :param max_turn_deg: a static run's largest angle from the mean field.
    """

    calibration: MagnetometerCalibration
    thermal: FitResult
    iron: EllipsoidFit | None
    lines: tuple[str, ...]
    max_turn_deg: float = 0.0
    held: bool = False


HELD_MAG_NOTE = 'held at nominal (offset 0, scale 1, no iron): {reason}'
"""The note of a magnetometer the record is too short for, while its other sensors are fitted."""


def held_mag_fit(reason: str) -> MagFit:
    """The magnetometer held at nominal, said in its note and one line: one sensor's shortage (``fit``)."""
    note = HELD_MAG_NOTE.format(reason=reason)
    thermal = held_result(note)
    calibration = MagnetometerCalibration(thermal.calibration, (0.0, 0.0, 0.0), IDENTITY_3X3)  # type: ignore[arg-type]
    return MagFit(calibration=calibration, thermal=thermal, iron=None, lines=(f'magnetometer: {note}',), held=True)


def fit_mag_bag(record: Record, options, *, bias_order: int = 3, scale_order: int = 2,
                temp_code_ref: float | None = None, iron_run: Record | None = None,
                effects: Sequence[str] = (), max_effect_samples: int = 1_000_000) -> MagFit:
    """Fit the magnetometer: its thermal link from ``record``, its iron from ``iron_run``.

    With ``effects`` (library names, as ``--effects``) the link and the effects are fitted by
    :func:`~tak_thermo_ros.core.fit.fit_model` on every n-th sample, at most about
    ``max_effect_samples`` (all of a shorter run; said in a line otherwise).

    :raises FitError: one line prefixed ``magnetometer:`` (a run that moved, a fit that cannot
        be determined, a rotation record that fails the ellipsoid's checks).
    :raises TakError: a topic not in tesla.
    """
    path, topics = record.path, options.topics
    survey = survey_field(record, options) if record.streams.mag_reference == 0 else None
    if survey is not None and survey.turned:
        for given, option in ((iron_run is not None, '--iron-run'), (bool(effects), '--mag-effects')):
            if given:
                msg = (f'magnetometer: {option}: {path} is itself a rotation record (its field turns), whose iron and '
                       f'thermal drift are fitted from it; {option} goes with a static chamber run')
                raise FitError(msg)
        return fit_rotation_bag(record, options, survey, bias_order=bias_order, scale_order=scale_order,
                                temp_code_ref=temp_code_ref)
    fit = StreamingFit(bias_order=bias_order, scale_order=scale_order, temp_code_ref=temp_code_ref,
                       nominal_scale=(1.0, 1.0, 1.0))
    consumers = [fit.add]
    subsample = None
    if effects:
        count = record.streams.mag
        subsample = Subsample(stride_for(count, max_effect_samples), expected=count)
        consumers.append(subsample)
    calibration_pass = _calibration_pass(record, options, consumers, survey)
    static, mean, max_turn, aligner = (calibration_pass.static, calibration_pass.mean, calibration_pass.max_turn_deg,
                                       calibration_pass.aligner)
    try:
        if subsample is None:
            thermal = fit.result(dropped=aligner.dropped)
        else:
            thermal = fit_model(subsample.samples(aligner.dropped), effects=list(effects), bias_order=bias_order,
                                scale_order=scale_order, temp_code_ref=temp_code_ref, nominal_scale=(1.0, 1.0, 1.0))
    except FitError as err:
        raise prefixed(err, 'magnetometer') from None
    lines = [f'magnetometer: reference field {topics.reference_field} as recorded' if not static else
             f'magnetometer: static run, reference the mean field x y z {_microtesla(mean)} uT']
    if static:
        lines.append(f'magnetometer: |B| {np.linalg.norm(mean) * 1e6:.2f} uT; the field turned from its mean by at '
                     f'most {max_turn:.2f} deg')
    if subsample is not None and subsample.stride > 1:
        lines.append(f'magnetometer: the link and its effects fitted on 1 sample in {subsample.stride} '
                     f'({subsample.count} of {subsample.usable})')
    link = thermal.calibration
    notes = [_in_microtesla(note, link, mean) if static else note for note in link.notes]
    iron = None
    if iron_run is None:
        notes.append(NO_IRON_NOTE)
        hard, soft = (0.0, 0.0, 0.0), IDENTITY_3X3
    else:
        iron, outside = _fit_iron(iron_run, options, link)
        hard, soft = iron.hard_iron, iron.soft_iron
        lines.append(f'magnetometer: iron from {iron_run} ({iron.samples} samples)')
        if outside:
            lines.append(f'warning: magnetometer: {outside} samples of {iron_run} outside the calibrated temperature '
                         f'range {link.temp_code_min:.2f}..{link.temp_code_max:.2f} C (clamped to its edge)')
    link = replace(link, notes=tuple(notes))
    calibration = MagnetometerCalibration(link, hard, soft)  # type: ignore[arg-type]
    return MagFit(calibration=calibration, thermal=replace(thermal, calibration=link), iron=iron, lines=tuple(lines),
                  max_turn_deg=max_turn)


def fit_rotation_bag(record: Record, options, survey: FieldSurvey, *, bias_order: int = 3, scale_order: int = 2,
                     temp_code_ref: float | None = None) -> MagFit:
    """The magnetometer of a rotation record: the iron, and its thermal link where the temperature determines it.

    One pass collects at most about :data:`MAX_ROTATION_SAMPLES` samples (spread evenly) with the
    temperature held (none when the record holds none), for
    :func:`~tak_thermo_ros.core.magnetometer.rotation.fit_rotation`.

    :raises FitError: one line prefixed ``magnetometer:`` (too few orientations, the acceptance checks).
    """
    from tak_thermo_ros.core.magnetometer.rotation import fit_rotation
    path, topics, streams = record.path, options.topics, record.streams
    stride = stride_for(streams.mag, MAX_ROTATION_SAMPLES)
    subsample = Subsample(stride, expected=streams.mag // stride + 1)
    aligner = BlockAligner(use_reference=False, temperature_expected=streams.temperature > 0)
    largest_turn = 0.0
    direction = survey.mean / max(float(np.linalg.norm(survey.mean)), 1e-300)
    for mag in _mag_blocks(record, options, references=False):
        finite = mag.counts[np.all(np.isfinite(mag.counts), axis=1)]
        if len(finite):
            cosine = (finite @ direction) / np.maximum(np.linalg.norm(finite, axis=1), 1e-300)
            largest_turn = max(largest_turn, float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))).max()))
        subsample(aligner.push(mag))
    subsample(aligner.finish())
    samples = subsample.samples(aligner.dropped)
    temperature = samples.temp_code if streams.temperature else None
    where = f'magnetometer: {path}'
    rotation = fit_rotation(samples.counts, temperature, bias_order=bias_order, scale_order=scale_order,
                            temp_ref=temp_code_ref, where=where,
                            held_because=f'no temperature on {topics.temperature}')
    ellipsoid = rotation.ellipsoid
    thermal = FitResult(calibration=rotation.calibration.thermal,
                        axes=(AxisFit(ellipsoid.residual_rms, 0, 0.0),) * 3,  # type: ignore[arg-type]
                        samples=len(samples), dropped=dict(aligner.dropped))
    lines = [f'magnetometer: a rotation record (the field turns up to {largest_turn:.0f} deg): the iron from it alone',
             *(f'magnetometer: {line}' for line in rotation.lines)]
    if stride > 1:
        lines.append(f'magnetometer: fitted on 1 sample in {stride} ({len(samples)} of {subsample.usable})')
    return MagFit(calibration=rotation.calibration, thermal=thermal, iron=ellipsoid, lines=tuple(lines),
                  max_turn_deg=largest_turn)


def _in_microtesla(note: str, link, mean) -> str:
    """A held-scale note of the fit, whose inputs are tesla, said in uT (the static run's mean field is the input)."""
    from tak_thermo_ros.core.fit import held_scale_note
    if not note.startswith('scale held at nominal'):
        return note
    held = [not axis.scale_observable for axis in link.axes]
    return held_scale_note(held, [f'{name} input {value * 1e6:.4g} uT at nominal scale 1'
                                  for name, value, is_held in zip('xyz', mean, held) if is_held])


def _microtesla(values) -> str:
    return ' '.join(f'{v * 1e6:+.3f}' for v in values)


def _fit_iron(record: Record, options, link) -> tuple[EllipsoidFit, int]:
    """The ellipsoid of a rotation record, corrected by the thermal link first; samples out of its range."""
    path, topic, streams = record.path, options.topics.mag, record.streams
    if streams.kind is not InputKind.IMU or streams.mag == 0:
        msg = f'{path}: no messages on {topic} (the rotation record for --iron-run)'
        raise BagError(msg)
    corrector = Corrector(link)
    aligner = BlockAligner(use_reference=False)
    parts: list[np.ndarray] = []
    outside = 0

    def take(aligned: AlignedSamples) -> None:
        nonlocal outside
        if len(aligned):
            parts.append(corrector.correct(aligned.counts, aligned.temp_code, stamp_s=aligned.stamp_s))
            outside += corrector.out_of_range_count(aligned.temp_code)

    for mag in _mag_blocks(record, options, references=False):
        take(aligner.push(mag))
    take(aligner.finish())
    values = np.concatenate(parts) if parts else np.zeros((0, 3))
    try:
        return fit_ellipsoid(values, where=f'{path}: {topic}'), outside
    except FitError as err:
        raise FitError(f'magnetometer: {err}') from None


# ----- apply and validate ---------------------------------------------------------------------------


class MagApplier:
    """The magnetometer's part of ``apply``: each block aligned, corrected, written (``/imu/mag_compensated``)."""

    def __init__(self, mag: MagnetometerCalibration, *, out_of_range: OutOfRange, topic: str,
                 temperature_expected: bool = True) -> None:
        from tak_thermo_ros.core.magnetometer.channel import magnetic_covariance
        self.corrector = MagCorrector(mag, out_of_range=out_of_range)
        self.covariance = magnetic_covariance(mag)
        self.aligner = BlockAligner(use_reference=False, temperature_expected=temperature_expected)
        self.topic = topic
        self.out_of_range = 0
        self.checked = False
        self.frame_id = ''

    def push(self, writer, record, output) -> None:
        """Align and correct one block's magnetometer record into ``writer``."""
        record = corrupt_as_nan(record)
        if not self.checked and len(record.counts):
            finite = record.counts[np.all(np.isfinite(record.counts), axis=1)]
            if len(finite):
                check_tesla(finite, f'{self.topic.replace("_compensated", "")}')
                self.checked = True
        self.frame_id = self.frame_id or record.frame_id
        self._write(writer, self.aligner.push(record), self.frame_id, output)

    def finish(self, writer, frame_id: str, output) -> None:
        """The samples still pending at the end of the run (``frame_id``: when no message had one)."""
        self._write(writer, self.aligner.finish(), self.frame_id or frame_id, output)

    def _write(self, writer, aligned: AlignedSamples, frame_id: str, output) -> None:
        if not len(aligned):
            return
        corrected = self.corrector.correct(aligned.counts, aligned.temp_code, stamp_s=aligned.stamp_s)
        if not np.all(np.isfinite(corrected)):
            msg = f'{output}: corrected magnetic field: values are not finite (NaN or infinite); nothing written'
            raise TakError(msg)
        self.out_of_range += self.corrector.out_of_range_count(aligned.temp_code)
        writer.write_mag(self.topic, aligned.stamp_ns, frame_id, corrected, self.covariance)


@dataclass
class _FieldSums:
    """Sums for an RMS per axis and of the magnitude, about a mean or against a reference (shifted sums)."""

    shift: np.ndarray | None = None
    count: int = 0
    total: np.ndarray | None = None
    squares: np.ndarray | None = None

    def add(self, error: np.ndarray) -> None:
        if not len(error):
            return
        if self.shift is None:
            self.shift = error[0].copy()
            self.total = np.zeros(error.shape[1])
            self.squares = np.zeros(error.shape[1])
        centred = error - self.shift
        self.total += centred.sum(axis=0)
        self.squares += (centred ** 2).sum(axis=0)
        self.count += len(error)

    def rms(self, *, about_mean: bool) -> np.ndarray:
        """RMS per column: about the mean (a static run) or of the error itself (against a reference)."""
        mean_centred = self.total / self.count
        if about_mean:
            return np.sqrt(np.maximum(self.squares / self.count - mean_centred ** 2, 0.0))
        # E[(c + s)^2] = E[c^2] + 2 s E[c] + s^2
        return np.sqrt(np.maximum(self.squares / self.count + 2 * self.shift * mean_centred + self.shift ** 2, 0.0))


@dataclass(frozen=True)
class MagValidated:
    """``validate``'s figures for the magnetometer, tesla.

    :param samples: samples compared.
    :param reference: ``'static'`` (error about the run's mean field), ``'rotation'`` (a record
        whose field turns: ``|B|`` about its mean only, the axes' figures NaN) or the reference topic.
    :param before: RMS per axis x, y, z and of ``|B|`` of the raw field.
    :param after: the same after the correction (thermal link and iron).
    """

    samples: int
    reference: str
    before: tuple[float, float, float, float]
    after: tuple[float, float, float, float]
    out_of_range: int = 0


def validate_mag(record: Record, mag: MagnetometerCalibration, options, *,
                 out_of_range: OutOfRange = OutOfRange.CLAMP) -> MagValidated:
    """The field error before and after the correction.

    Against ``/tak/reference_field`` when recorded, else about the run's mean: a static run's
    field per axis and ``|B|``, a rotation record's ``|B|`` alone (its spread: the field strength
    is one in every orientation, the direction needs a reference).
    """
    from tak_thermo_ros.passes.run import temperature_expected
    path, streams = record.path, record.streams
    with_reference = streams.mag_reference > 0
    rotation = not with_reference and survey_field(record, options).turned
    corrector = MagCorrector(mag, out_of_range=out_of_range)
    holding = temperature_expected(path, streams, options, needed=mag.thermal.needs_temperature,
                                   what="the calibration's magnetometer")
    aligner = BlockAligner(use_reference=with_reference, reference_expected=with_reference,
                           temperature_expected=holding)
    before, after = _FieldSums(), _FieldSums()
    outside = 0

    def add(aligned: AlignedSamples) -> None:
        nonlocal outside
        if not len(aligned):
            return
        corrected = corrector.correct(aligned.counts, aligned.temp_code, stamp_s=aligned.stamp_s)
        outside += corrector.out_of_range_count(aligned.temp_code)
        for sums, values in ((before, aligned.counts), (after, corrected)):
            if with_reference:
                error = values - aligned.reference
                magnitude = np.linalg.norm(values, axis=1) - np.linalg.norm(aligned.reference, axis=1)
            else:
                error, magnitude = values, np.linalg.norm(values, axis=1)
            sums.add(np.column_stack([error, magnitude]))

    for channel in _mag_blocks(record, options, references=with_reference):
        add(aligner.push(channel))
    add(aligner.finish())
    if not before.count:
        msg = f'{path}: no usable magnetometer samples to validate on {options.topics.mag}'
        raise TakError(msg)
    about_mean = not with_reference
    values_before = tuple(float(v) for v in before.rms(about_mean=about_mean))
    values_after = tuple(float(v) for v in after.rms(about_mean=about_mean))
    if not all(math.isfinite(v) for v in values_before + values_after):
        msg = f'{path}: magnetometer field error is not finite'
        raise TakError(msg)
    if rotation:  # per axis about the mean says nothing of a field that turns
        values_before = (math.nan,) * 3 + values_before[3:]
        values_after = (math.nan,) * 3 + values_after[3:]
    reference = options.topics.reference_field if with_reference else 'rotation' if rotation else 'static'
    return MagValidated(samples=before.count, reference=reference, before=values_before,  # type: ignore[arg-type]
                        after=values_after, out_of_range=outside)
