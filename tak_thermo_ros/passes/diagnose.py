"""``tak_calib diagnose``'s pass: a bounded subsample spread evenly over the record, references held."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np


from tak_thermo_ros.core.records.blocks import BlockAligner, Subsample, stride_for
from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.core.records.provenance import PrintCollector, Recognition
from tak_thermo_ros.core.records.survey import RecordSurvey
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import TakError
from tak_thermo_ros.passes.run import (
    SensorPass,
    StreamOptions,
    check_temperature_unit,
    open_calibration_run,
    run_passes,
    sensors_of,
)

if TYPE_CHECKING:
    from tak_thermo_ros.formats.records import Record


DIAGNOSE_MAX_SAMPLES = 1_000_000
"""``diagnose`` works on at most about this many samples, spread evenly over the run."""


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
    groups: dict[str, np.ndarray] | None = None
    """A pool of records: per sensor each sample's record (``diagnose`` holds whole records out)."""
    in_sample: Recognition | None = None
    """Whether the record is (part of) one the calibration was fitted from (``None``: not, or no claim)."""
    first_stamp_ns: int | None = None
    """The record's first sample stamp (before any sample is left out), ns."""


def bounded_run(record: Record, options: StreamOptions, *, settle_time_s: float = 0.0,
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
    path, streams = record.path, record.streams
    if streams.kind is InputKind.IMU and not streams.temperature:
        msg = f'{path}: no temperature on {options.topics.temperature}: diagnose looks at the residual against it'
        raise TakError(msg)
    opened = open_calibration_run(record, options, gravity=gravity, latitude=latitude, require_reference=True)
    if opened.handheld:
        from tak_thermo_ros.passes.handheld import handheld_record, rest_samples
        if unit is None:
            msg = f'{path}: a hand-held record: its references come from a calibration (give one)'
            raise TakError(msg)
        held, _ = handheld_record(record, options, opened.survey, budget=max_samples, replay=opened.replay)
        samples, check = rest_samples(held, unit, gravity=gravity, latitude=latitude)
        usable = {sensor: int(opened.survey.still.samples.sum()) for sensor in samples}
        return BoundedRun(input_kind=InputKind.IMU, samples=samples, usable=usable, stride=held.stride,
                          reference_lines=(), survey=opened.survey, handheld=check)
    stride = stride_for(opened.main, max_samples)
    passes, subsamples = [], {}
    for sensor in sensors_of(opened.kind):
        subsamples[sensor] = Subsample(stride, expected=opened.main // stride + 1)
        passes.append(SensorPass(sensor, BlockAligner(use_reference=True, reference_expected=True,
                                                      settle_time_s=settle_time_s), [subsamples[sensor]]))
    prints = PrintCollector(sensors_of(opened.kind), against=unit.fitted_from if unit is not None else (),
                            own_segments=False)
    lines = run_passes(record, options, opened, passes, prints=prints)
    survey = opened.finished_survey()
    check_temperature_unit(path, options, survey)
    return BoundedRun(input_kind=opened.kind,
                      samples={p.sensor: subsamples[p.sensor].samples(p.aligner.dropped) for p in passes},
                      usable={p.sensor: p.aligner.kept for p in passes}, stride=stride,
                      reference_lines=tuple(lines), survey=survey,
                      in_sample=prints.recognition(path.name), first_stamp_ns=prints.first_stamp_ns)
