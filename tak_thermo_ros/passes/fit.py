"""``tak_calib fit``'s pass: the link of each sensor from one record (:mod:`tak_thermo_ros.passes.run`)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numpy as np

from tak_thermo_ros.core.records.blocks import BlockAligner, Subsample, add_counts, stride_for
from tak_thermo_ros.core.records.extremes import RunExtremes
from tak_thermo_ros.core.records.provenance import PrintCollector
from tak_thermo_ros.core.fit import FitResult, ShortRecord, fit_model
from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.core.noise.rests import StretchWindows
from tak_thermo_ros.core.records.static_run import (
    NotStatic,
)
from tak_thermo_ros.core.fit.stream import StreamingEffectFit, StreamingFit
from tak_thermo_ros.errors import TakError
from tak_thermo_ros.passes.run import (
    FitSettings,
    HELD_IMU_NOTE,
    ImuLinkUndetermined,
    MOVED,
    OpenedRun,
    Required,
    SensorPass,
    StreamOptions,
    StreamedFit,
    check_temperature_unit,
    feeding,
    held_result,
    sensor_errors,
    open_calibration_run,
    run_passes,
    sensors_of,
)


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
        from tak_thermo_ros.passes.handheld import fit_handheld_bag
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
    windows = {sensor: StretchWindows(opened.main) for sensor in sensors}
    for sensor in sensors:
        fits[sensor] = StreamingFit(bias_order=settings.bias_order, scale_order=settings.scale_order,
                                    temp_code_ref=settings.temp_code_ref, nominal_scale=nominal.get(sensor))
        requirements[sensor] = required(sensor)
        consumers = [fits[sensor].add, extremes[sensor], windows[sensor]]
        if settings.effects.get(sensor):
            stride = stride_for(opened.main, settings.max_effect_samples)
            subsamples[sensor] = Subsample(stride, expected=opened.main // stride + 1)
            consumers.append(subsamples[sensor])
        passes.append(SensorPass(sensor, aligner(), [feeding(requirements[sensor], consumers)]))
    prints = PrintCollector(sensors)
    try:
        lines = run_passes(path, options, opened, passes, prints=prints)
    except NotStatic as err:
        raise ImuLinkUndetermined(str(err), MOVED) from None
    survey = opened.finished_survey()
    check_temperature_unit(path, options, survey)
    results: dict[str, FitResult] = {}
    usable: dict[str, int] = {}
    second: dict[str, tuple[StreamingEffectFit, FitResult]] = {}
    short: dict[str, ShortRecord] = {}
    for sensor_pass in passes:
        sensor = sensor_pass.sensor
        dropped = _summed(sensor_pass.aligner.dropped, requirements[sensor].dropped)
        usable[sensor] = sensor_pass.aligner.kept - sum(requirements[sensor].dropped.values())
        try:
            with sensor_errors(kind, sensor):
                if sensor not in subsamples:
                    results[sensor] = fits[sensor].result(dropped=dropped)
                    if kind is InputKind.IMU:  # the link's own uncertainty, for the calibration watch
                        taken = (sensor == 'accel' and opened.static is not None
                                 and not opened.static.recorded_reference)  # the board's tilt took them
                        uncertainty = fits[sensor].uncertainty(sensor, settings.held_spreads, direction_taken=taken)
                        results[sensor] = replace(results[sensor], calibration=replace(
                            results[sensor].calibration, uncertainty=uncertainty))
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
        except ShortRecord as err:  # one sensor's shortage: held below when another sensor is fitted
            if kind is InputKind.COUNTS:
                raise
            short[sensor] = err
    if short and len(short) == len(sensors):
        first = short[sensors[0]]
        raise ImuLinkUndetermined(f'{path}: {first}', first.reason, survey)
    for sensor, err in short.items():
        results[sensor] = held_result(HELD_IMU_NOTE.format(reason=err.reason))
    if second:
        # The shapes are fixed now: a second pass solves every amplitude over the whole run.
        again = {sensor: required(sensor) for sensor in second}
        amplitude_passes = [SensorPass(sensor, aligner(), [feeding(again[sensor], [amplitudes.add])])
                            for sensor, (amplitudes, _) in second.items()]
        run_passes(path, options, OpenedRun(kind, opened.main, opened.static, replay=opened.replay), amplitude_passes)
        for sensor_pass in amplitude_passes:
            sensor = sensor_pass.sensor
            amplitudes, shaped = second[sensor]
            shape_names = {f'{e.name}.{name}' for e in shaped.calibration.effects for name in e.shape_names()}
            with sensor_errors(kind, sensor):
                result = amplitudes.result(
                    dropped=_summed(sensor_pass.aligner.dropped, again[sensor].dropped),
                    parameters=[axis.parameters for axis in shaped.axes],
                    shape_errors={k: v for k, v in shaped.parameter_errors.items() if k in shape_names})
            results[sensor] = replace(result, parameter_errors=_with_shape_uncertainty(
                result.parameter_errors, shaped, shape_names, result.samples), error_basis=shaped.error_basis)
    return StreamedFit(input_kind=kind, sensors=sensors, results=results, usable=usable,
                       effect_stride={sensor: subsample.stride for sensor, subsample in subsamples.items()},
                       reference_lines=tuple(lines),
                       ignored_temp_codes={p.sensor: dict(p.aligner.ignored_temp_codes) for p in passes},
                       ignored_references={p.sensor: dict(p.aligner.ignored_references) for p in passes},
                       temperature_rate_max=extremes['accel'].temperature_rate_max,
                       rate_max=extremes['gyro'].reference_max if 'gyro' in extremes else 0.0,
                       survey=survey, record_print=prints.finish(path.name),
                       held=tuple(sensor for sensor in sensors if sensor in short), noise_windows=windows)


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
    results = {sensor: held_result(HELD_IMU_NOTE.format(reason=reason)) for sensor in ('accel', 'gyro')}
    return StreamedFit(input_kind=InputKind.IMU, sensors=('accel', 'gyro'), results=results, usable={},
                       effect_stride={}, reference_lines=(), ignored_temp_codes={'accel': {}, 'gyro': {}},
                       ignored_references={'accel': {}, 'gyro': {}}, held=('accel', 'gyro'), survey=survey)


def _with_shape_uncertainty(errors: dict[str, float], shaped: FitResult, shape_names: set[str],
                            samples: int) -> dict[str, float]:
    """The amplitudes' standard errors with the shapes' uncertainty and the residual's correlation in them.

    The second pass solves the amplitudes with the shapes held and takes the residual as white,
    so its errors leave out how far the shapes are known and what the residual's correlation
    adds; the subsample's joint errors hold both. Their white part scales to the whole run as one
    over the square root of the samples (the larger of that and the second pass's is kept); the
    part the correlated noise makes does not fall with denser sampling and is added as it is.
    """
    scale = math.sqrt(shaped.samples / max(samples, 1))
    correlated = shaped.error_basis.correlated_errors if shaped.error_basis is not None else {}
    joint = {}
    for key, value in errors.items():
        if key in shape_names or key not in shaped.parameter_errors:
            continue
        slow = correlated.get(key, 0.0)
        white = math.sqrt(max(shaped.parameter_errors[key] ** 2 - slow ** 2, 0.0)) * scale
        joint[key] = math.sqrt(max(value, white) ** 2 + slow ** 2)
    return {**errors, **joint}


def _summed(first: dict[str, int], second: dict[str, int]) -> dict[str, int]:
    total = dict(first)
    add_counts(total, second)
    return total
