"""``tak_calib validate``'s pass: |g| and the rate error of a corrected record, summed block by block."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable


from tak_thermo_ros.core.records.blocks import BlockAligner
from tak_thermo_ros.core.link.correction import Corrector, OutOfRange
from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.core.records.provenance import PrintCollector, Recognition
from tak_thermo_ros.core.records.survey import RecordSurvey
from tak_thermo_ros.core.link.stream_correction import GravityCheck, RateCheck
from tak_thermo_ros.passes.run import (
    Required,
    SensorPass,
    StreamOptions,
    check_temperature_unit,
    open_calibration_run,
    run_passes,
    sensors_of,
    temperature_expected,
)

if TYPE_CHECKING:
    from tak_thermo_ros.formats.records import Record


@dataclass(frozen=True)
class Validated:
    """The sums of ``validate``: |g| (accelerometer) and, on driver bags, the rate error."""

    input_kind: InputKind
    gravity: GravityCheck
    rate: RateCheck | None
    reference_lines: tuple[str, ...]
    accel_dropped: dict[str, int] = field(default_factory=dict)
    """The accelerometer's samples left out, by reason (the stamp and value rules, a recorded signal missing);
    ``gyro_dropped`` the gyroscope's."""
    gyro_dropped: dict[str, int] = field(default_factory=dict)
    accel_ignored_temp_codes: dict[str, int] = field(default_factory=dict)
    accel_ignored_references: dict[str, int] = field(default_factory=dict)
    survey: RecordSurvey | None = None
    in_sample: Recognition | None = None
    """Whether the record is (part of) one the calibration was fitted from (``None``: not, or no claim)."""


def validate_bag(record: Record, unit: UnitCalibration, options: StreamOptions, *, gravity: float,
                 latitude: float | None = None, out_of_range: OutOfRange = OutOfRange.CLAMP,
                 expect_kind: Callable[[InputKind], None] | None = None) -> Validated | Any:
    """``tak_calib validate`` in one pass (after the survey for a static driver run or a hand-held record).

    A hand-held record gives a :class:`~tak_thermo_ros.passes.handheld.HandheldValidated`.

    :param expect_kind: called with the bag's kind before the pass (raises on a mismatch).
    """
    path, streams = record.path, record.streams
    kind = streams.kind
    if expect_kind is not None:
        expect_kind(kind)
    holding = temperature_expected(path, streams, options, needed=unit.needs_temperature, what='the calibration')
    calibration_run = kind is InputKind.IMU
    opened = open_calibration_run(record, options, gravity=gravity, latitude=latitude, require_reference=False)
    if opened.handheld:
        from tak_thermo_ros.passes.handheld import validate_handheld_bag
        return validate_handheld_bag(record, unit, options, opened.survey, gravity=gravity, latitude=latitude,
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
    prints = PrintCollector(sensors_of(kind), against=unit.fitted_from, own_segments=False)
    lines = run_passes(record, options, opened, passes, prints=prints)
    survey = opened.finished_survey()
    check_temperature_unit(path, options, survey)
    return Validated(input_kind=kind, gravity=gravity_check, rate=rate_check, reference_lines=tuple(lines),
                     accel_dropped=accel_required.dropped,
                     gyro_dropped=gyro_required.dropped if calibration_run and rate_check is not None else {},
                     accel_ignored_temp_codes=dict(accel_pass.aligner.ignored_temp_codes),
                     accel_ignored_references=dict(accel_pass.aligner.ignored_references),
                     survey=survey, in_sample=prints.recognition(path.name))
