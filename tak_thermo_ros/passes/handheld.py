"""``tak_calib``'s passes over a hand-held record: its still and turn samples gathered, then fit, validate, diagnose.

A record without reference topics whose unit rests in two or more orientations
(:func:`~tak_thermo_ros.core.records.survey.fit_plan`) is read once by the survey, which finds
the still intervals (:mod:`tak_thermo_ros.passes`) and keeps the blocks of a record of at most
2 M messages; then one pass (over those blocks, else over the record again) aligns the six channels
block by block with the temperature held and keeps the still samples (every ``stride``-th, at
most :data:`HANDHELD_MAX_STILL_SAMPLES`) and every sample of the turns
(:class:`~tak_thermo_ros.core.records.handheld.HandheldCollector`). The fit, the validation and
the diagnosis work on what was kept (:mod:`tak_thermo_ros.core.fit.handheld`,
:mod:`tak_thermo_ros.core.link.handheld_check`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from tak_thermo_ros.core.effects.base import INPUT
from tak_thermo_ros.core.fit.handheld import HandheldFit, HandheldSettings, fit_handheld
from tak_thermo_ros.core.link.correction import OutOfRange
from tak_thermo_ros.core.link.handheld_check import HandheldCheck, check_handheld
from tak_thermo_ros.core.link.model import Calibration, InputKind, UnitCalibration
from tak_thermo_ros.core.records.blocks import BlockAligner
from tak_thermo_ros.core.records.handheld import HandheldCollector, HandheldRecord, earth_reference, sensor_samples
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.core.records.survey import RecordSurvey
from tak_thermo_ros.passes.run import FitSettings, StreamedFit, StreamOptions

HANDHELD_MAX_STILL_SAMPLES = 500_000
"""A hand-held fit keeps at most about this many still samples (every n-th, spread evenly), and as many
turn samples (whole turns: beyond, every n-th turn)."""


@dataclass(frozen=True)
class HandheldBag:
    """A hand-held record as read, and its fit (``None`` for validate and diagnose)."""

    record: HandheldRecord
    fit: HandheldFit | None = None
    ignored_temp_codes: dict[str, int] | None = None


def handheld_record(path: str | Path, options: StreamOptions, survey: RecordSurvey, *,
                    budget: int = HANDHELD_MAX_STILL_SAMPLES, turn_budget: int | None = None,
                    replay=None) -> tuple[HandheldRecord, dict[str, int]]:
    """The still and turn samples of a record, and the temperature messages ignored by reason.

    :param budget: about this many still samples at most; ``turn_budget`` turn samples (``None``: ``budget``).
    :param replay: the survey's blocks (then the record is not read again), or ``None`` (one pass).
    """
    from tak_thermo_ros.formats.records import record_blocks
    collector = HandheldCollector(survey.still, budget=budget, turn_budget=turn_budget)
    aligner = BlockAligner(use_reference=False)
    blocks = replay if replay is not None else record_blocks(
        path, topics=options.topics, kind=InputKind.IMU, block_samples=options.block_samples, references=False,
        progress=options.progress)
    for block in blocks:
        collector.add(aligner.push(block.six_channels()))  # type: ignore[union-attr]
    collector.add(aligner.finish())
    return collector.record(), dict(aligner.ignored_temp_codes)


def handheld_settings(settings: FitSettings) -> HandheldSettings:
    """The hand-held fit's settings of ``tak_calib fit``'s."""
    return HandheldSettings(bias_order=settings.bias_order, scale_order=settings.scale_order,
                            temp_code_ref=settings.temp_code_ref, gravity=settings.gravity,
                            latitude=settings.latitude, held_spreads=settings.held_spreads,
                            effects={sensor: tuple(specs) for sensor, specs in settings.effects.items()})


def fit_handheld_bag(path: str | Path, settings: FitSettings, options: StreamOptions, survey: RecordSurvey, *,
                     replay=None) -> StreamedFit:
    """``tak_calib fit`` of a hand-held record: both sensors from its still intervals and turns."""
    record, ignored = handheld_record(path, options, survey, replay=replay)
    fitted = fit_handheld(record, handheld_settings(settings))
    sensors = ('accel', 'gyro')
    return StreamedFit(input_kind=InputKind.IMU, sensors=sensors, results=fitted.results,
                       usable={sensor: len(record.still) for sensor in sensors}, effect_stride={},
                       reference_lines=(), ignored_temp_codes={sensor: ignored for sensor in sensors},
                       ignored_references={sensor: {} for sensor in sensors}, survey=survey,
                       handheld=HandheldBag(record, fitted, ignored))


@dataclass(frozen=True)
class HandheldValidated:
    """``validate`` of a hand-held record: the nominal scale and offset (*before*) and the whole link (*after*)."""

    before: HandheldCheck
    after: HandheldCheck
    record: HandheldRecord
    survey: RecordSurvey
    ignored_temp_codes: dict[str, int]
    input_kind: InputKind = InputKind.IMU


def nominal_unit(unit: UnitCalibration) -> UnitCalibration:
    """Every sensor with its nominal scale and offset only (temperature terms and effects off)."""
    return UnitCalibration(unit.input_kind, unit.accel.nominal(), unit.gyro.nominal() if unit.gyro else None)


def validate_handheld_bag(path: str | Path, unit: UnitCalibration, options: StreamOptions, survey: RecordSurvey, *,
                          gravity: float, latitude: float | None, out_of_range: OutOfRange,
                          replay=None) -> HandheldValidated:
    """The rests' |g| and rate errors and the turns' closure, before and after correction."""
    record, ignored = handheld_record(path, options, survey, replay=replay)
    before = check_handheld(record, nominal_unit(unit), gravity=gravity, latitude=latitude, out_of_range=out_of_range)
    after = check_handheld(record, unit, gravity=gravity, latitude=latitude, out_of_range=out_of_range)
    return HandheldValidated(before, after, record, survey, ignored)


def at_rest(calibration: Calibration) -> Calibration:
    """A gyroscope's calibration as its rests see it: the input effects (misalignment) left out.

    At rest the rate is (almost) zero, so the refits of ``diagnose`` cannot see the input
    terms; the offsets and their effects are what a rest shows.
    """
    return replace(calibration, effects=tuple(effect for effect in calibration.effects if effect.kind != INPUT))


def rest_samples(record: HandheldRecord, unit: UnitCalibration, *, gravity: float, latitude: float | None,
                 out_of_range: OutOfRange = OutOfRange.CLAMP) -> tuple[dict[str, AlignedSamples], HandheldCheck]:
    """Each sensor's still samples with the reference a hand-held record has (what ``diagnose`` takes).

    The accelerometer's: local gravity along each interval's corrected up direction; the
    gyroscope's: zero, the Earth rate's vertical component (with ``latitude``) taken off the values.
    """
    check = check_handheld(record, unit, gravity=gravity, latitude=latitude, out_of_range=out_of_range)
    _, interval = np.unique(record.still_interval, return_inverse=True)
    accel = sensor_samples(record.still, 'accel', gravity * check.up[interval])
    gyro = sensor_samples(record.still, 'gyro', np.zeros((len(interval), 3)))
    gyro = replace(gyro, counts=gyro.counts - earth_reference(check.up, interval, latitude))
    return {'accel': accel, 'gyro': gyro}, check
