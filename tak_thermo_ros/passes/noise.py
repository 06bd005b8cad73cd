"""A bag's noise model in one streamed pass (``tak_calib noise``), and the three sources of a noise model.

:func:`noise_bag` reads a bag once in blocks (:mod:`tak_thermo_ros.passes`), takes each
sensor's residual (measured minus reference; the thermally compensated output minus the
reference when a calibration is given) and feeds it to an
:class:`~tak_thermo_ros.core.noise.allan.AllanAccumulator` (bounded memory), then fits the
noise model per axis (:func:`~tak_thermo_ros.core.noise.fit.fit_noise`, which says how it follows the measurement).

:func:`noise_models` gives the per-sensor models from the sources in the order of preference
of issue 16: a Kalibr-style file (``--noise FILE``), a static constant-temperature run
(``--noise-run BAG``), the calibration file's own ``noise`` sections, else the calibration
run's own residual after the fitted model (``source='residual'``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from tak_thermo_ros.core.link.correction import OutOfRange
from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.link.stream_correction import BlockCorrector
from tak_thermo_ros.core.noise.allan import AllanAccumulator, AllanVariance
from tak_thermo_ros.core.noise.constancy import TemperatureTrend, compensated_static, temperature_trend
from tak_thermo_ros.core.noise.fit import NoiseFit, fit_noise
from tak_thermo_ros.core.noise.model import NoiseModel
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import NoiseError
from tak_thermo_ros.passes.run import StreamOptions, sensors_of

GAP_FACTOR = 1.5
"""A step between two samples' stamps longer than this many sampling intervals is a gap."""
CONSTANT_TEMPERATURE_C = 2.0
"""A driver run whose temperature spans at most this many degrees C is a run at constant
temperature (``source='static_run'``: a chamber holds its setpoint to about +-0.5 C), compensated
or not. A wider span is a static run only when a calibration compensates it and what the
compensation leaves is noise (:mod:`tak_thermo_ros.core.noise.constancy`: a powered unit that
warms itself by a few degrees); else the model is ``residual``."""
CONSTANT_TEMPERATURE_FRACTION = 0.05
"""The same for a counts run, whose codes have no unit: at most this share of the calibrated
temperature-code range (1.5 C of a 5..35 C chamber calibration)."""
TREND_CHUNKS = 4096
"""A compensated run's residual is kept as the means of about this many equal chunks (bounded memory)
for the trend test (:mod:`tak_thermo_ros.core.noise.constancy`)."""
PER_OCTAVE = 2
"""Averaging times per doubling of ``tak_calib noise``'s Allan deviation."""


@dataclass
class _SensorNoise:
    """One sensor's residual, streamed into an Allan accumulator; the stamps' gaps counted."""

    calibration: object | None
    out_of_range: OutOfRange
    per_octave: int
    accumulator: AllanAccumulator | None = None
    interval_ns: float | None = None
    last_stamp_ns: int | None = None
    gaps: int = 0
    missing: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    outside: int = 0
    temperature: tuple[float, float] | None = None
    chunk: int = 1
    _chunks: list[np.ndarray] = field(default_factory=list)
    _leftover: np.ndarray | None = None

    def __post_init__(self) -> None:
        from tak_thermo_ros.passes.run import Required
        self.corrector = BlockCorrector(self.calibration, out_of_range=self.out_of_range) \
            if self.calibration is not None else None
        self.required = Required(self.corrector.signals if self.corrector is not None else ())
        self.dropped = self.required.dropped

    def __call__(self, aligned: AlignedSamples) -> None:
        samples = self.required(aligned)
        if not len(samples):
            return
        if samples.reference is None:
            msg = 'noise: the run has no reference for this sensor'
            raise NoiseError(msg)
        measured = samples.counts
        if self.corrector is not None:
            measured = self.corrector.correct(samples.counts, samples.temp_code, stamp_s=samples.stamp_s,
                                              aux=samples.aux)
            self.outside += self.corrector.out_of_range_count(samples.temp_code)
        stamps = samples.stamp_ns
        steps = np.diff(stamps if self.last_stamp_ns is None else np.concatenate([[self.last_stamp_ns], stamps]))
        if self.interval_ns is None and len(steps):
            self.interval_ns = float(np.median(steps))
        if self.interval_ns is not None and self.interval_ns > 0.0:
            long = steps[steps > GAP_FACTOR * self.interval_ns]
            self.gaps += len(long)
            self.missing += int(np.sum(np.round(long / self.interval_ns) - 1))
        self.last_stamp_ns = int(stamps[-1])
        finite = samples.temp_code[np.isfinite(samples.temp_code)]
        if len(finite):  # a record without a temperature holds none
            low, high = float(np.min(finite)), float(np.max(finite))
            self.temperature = (low, high) if self.temperature is None else (min(low, self.temperature[0]),
                                                                             max(high, self.temperature[1]))
        if self.accumulator is None:
            self.accumulator = AllanAccumulator(1.0, 3, per_octave=self.per_octave)
        residual = measured - samples.reference
        self.accumulator.add(residual)
        if self.corrector is not None:
            self._keep_means(samples.stamp_s, samples.temp_code, residual)

    def _keep_means(self, stamp_s: np.ndarray, temperature: np.ndarray, residual: np.ndarray) -> None:
        """Means of every ``chunk`` samples (time, temperature, residual): the trend test's input, bounded."""
        rows = np.column_stack([stamp_s, temperature, residual])
        if self._leftover is not None:
            rows = np.concatenate([self._leftover, rows])
        whole = len(rows) // self.chunk * self.chunk
        if whole:
            self._chunks.append(rows[:whole].reshape(-1, self.chunk, rows.shape[1]).mean(axis=1))
        self._leftover = rows[whole:] if whole < len(rows) else None

    def trend(self) -> TemperatureTrend | None:
        """What the compensation leaves of a drift with temperature (``None`` without a calibration)."""
        if self.corrector is None:
            return None
        parts = list(self._chunks)
        if self._leftover is not None and len(self._leftover):
            parts.append(self._leftover.mean(axis=0, keepdims=True))
        if not parts:
            return None
        means = np.concatenate(parts)
        return temperature_trend(means[:, 0], means[:, 1], means[:, 2:])

    def allan(self) -> AllanVariance | None:
        """The Allan variance with averaging times in seconds (the rate from the stamps' median step)."""
        if self.accumulator is None or self.interval_ns is None or self.interval_ns <= 0.0:
            return None
        result = self.accumulator.result()
        rate = 1e9 / self.interval_ns
        return replace(result, taus=result.clusters / rate, rate=rate)


@dataclass(frozen=True)
class SensorNoise:
    """One sensor's noise from a bag.

    :param model: the fitted model (SI units of the corrected output; counts without
        a calibration on a counts bag are refused).
    :param allan: the residual's Allan variance (the per-axis measurement behind the model).
    :param gaps: steps between stamps longer than 1.5 sampling intervals (the samples are
        taken as evenly spaced: said in one line); ``missing``: samples those gaps lack.
    :param dropped: samples left out by the alignment, by reason.
    :param out_of_range: samples corrected outside the calibrated temperature range.
    :param fit: the fit behind ``model``: how it follows the measurement, IEEE 952's slope lines.
    :param temperature: the lowest and highest temperature of the samples (degrees C; codes for a
        counts run), which decide the model's ``source``; ``None`` for a run that records none.
    :param temperature_unit: ``C``, or ``codes``.
    """

    model: NoiseModel
    allan: AllanVariance
    gaps: int
    missing: int
    dropped: dict[str, int]
    out_of_range: int
    fit: NoiseFit | None = None
    temperature: tuple[float, float] | None = (0.0, 0.0)
    temperature_unit: str = 'C'
    why: str = ''
    """Why a compensated run whose temperature moved is a static run, or is not (a few words)."""

    @property
    def span_words(self) -> str:
        """`` (19.98..20.02 C)``: the temperature span behind the source, to print beside it (and why)."""
        if self.temperature is None:
            return ' (no temperature recorded: taken as constant)'
        low, high = self.temperature
        why = f'; {self.why}' if self.why else ''
        if self.temperature_unit == 'C':
            return f' ({low:.2f}..{high:.2f} C{why})'
        return f' (temperature code {low:.0f}..{high:.0f}{why})'


@dataclass(frozen=True)
class NoiseRun:
    """What :func:`noise_bag` found: per sensor its noise, and how the references were obtained."""

    input_kind: InputKind
    sensors: dict[str, SensorNoise]
    compensated: bool
    reference_lines: tuple[str, ...]
    topic: str
    survey: object = None

    @property
    def models(self) -> dict[str, NoiseModel]:
        """Per sensor the noise model."""
        return {sensor: noise.model for sensor, noise in self.sensors.items()}


def noise_bag(path: str | Path, options: StreamOptions, *, unit: UnitCalibration | None = None,
              source: str | None = None, gravity: float = STANDARD_GRAVITY, latitude: float | None = None,
              out_of_range: OutOfRange = OutOfRange.CLAMP, per_octave: int = PER_OCTAVE,
              settle_time_s: float = 0.0, expect_kind: Callable[[InputKind], None] | None = None) -> NoiseRun:
    """Each sensor's noise model from one streamed pass (a static driver run: after its survey, see :func:`run_passes`).

    :param unit: a calibration: the residual is the corrected output minus the reference (the
        thermally compensated signal). Without it: the measured value minus the reference
        (driver bags only; a counts bag's codes are not in SI).
    :param source: the models' ``source``; by default it follows the run's temperature:
        ``static_run`` when it spans at most :data:`CONSTANT_TEMPERATURE_C` (a counts run: at most
        :data:`CONSTANT_TEMPERATURE_FRACTION` of the calibrated code range), else ``residual`` (the
        model holds what the temperature model, or its absence, leaves of the thermal drift),
        with a calibration or without.
    :param settle_time_s: leave out the samples this long after each reference change (a table
        settling, as ``fit --settle-time``); the gaps this leaves are counted, the rest taken as
        evenly spaced.
    :param expect_kind: called with the bag's kind before the pass (raises on a mismatch).
    :raises NoiseError: a counts bag without a calibration, a run too short for five averaging times.
    """
    from tak_thermo_ros.formats.records import record_streams
    from tak_thermo_ros.passes.run import SensorPass, open_calibration_run, run_passes, temperature_expected
    from tak_thermo_ros.core.records.blocks import BlockAligner
    path = Path(path)
    streams = record_streams(path, topics=options.topics)
    kind = streams.kind
    if expect_kind is not None:
        expect_kind(kind)
    if unit is not None and kind is not unit.input_kind:
        msg = (f'{path}: holds {"channel codes" if kind is InputKind.COUNTS else "a driver Imu"}, the calibration is '
               f'for {unit.input_kind.value} input')
        raise NoiseError(msg)
    if kind is InputKind.COUNTS and unit is None:
        msg = (f'{path}: a counts bag holds channel codes, not SI values: '
               'give --params (the calibration) to take its noise')
        raise NoiseError(msg)
    # The raw output's noise needs no temperature (held as before where the record has one); a
    # correction with temperature terms needs it.
    holding = (temperature_expected(path, streams, options, needed=unit.needs_temperature, what='the calibration')
               if unit is not None else streams.kind is InputKind.COUNTS or streams.temperature > 0)
    opened = open_calibration_run(path, options, streams, gravity=gravity, latitude=latitude, require_reference=True,
                                  decide=False)
    if opened.survey is not None and opened.static is None:
        orientations = opened.survey.still.orientations()
        msg = (f'{path}: no reference topics and the unit moves ({orientations} orientation'
               f'{"s" if orientations != 1 else ""} at rest, {100.0 * opened.survey.still.still_fraction:.0f} % of '
               f'the time): a noise model needs a static record')
        raise NoiseError(msg)
    sensors = sensors_of(opened.kind)
    chunk = max(1, opened.main // TREND_CHUNKS)
    noises = {sensor: _SensorNoise(unit.sensor(sensor) if unit is not None else None, out_of_range, per_octave,
                                   chunk=chunk)
              for sensor in sensors}
    passes = [SensorPass(sensor, BlockAligner(use_reference=True, reference_expected=True,
                                              settle_time_s=settle_time_s, temperature_expected=holding),
                         [noises[sensor]])
              for sensor in sensors]
    lines = run_passes(path, options, opened, passes)
    spans = [noises[sensor].temperature for sensor in sensors if noises[sensor].temperature is not None]
    temperature = (min(low for low, _ in spans), max(high for _, high in spans)) if spans else None
    why = ''
    if source is None:
        trends = [trend for trend in (noises[sensor].trend() for sensor in sensors) if trend is not None]
        source, why = run_source_why(temperature, kind, unit, trends)
    found = {}
    for sensor_pass in passes:
        stream = noises[sensor_pass.sensor]
        allan = stream.allan()
        if allan is None:
            msg = f'{path}: no usable samples of the {sensor_pass.sensor} to take the noise of'
            raise NoiseError(msg)
        try:
            fit = fit_noise(allan, source=source)
        except NoiseError as err:
            msg = f'{path}: {sensor_pass.sensor}: {err}'
            raise NoiseError(msg) from None
        dropped = dict(sensor_pass.aligner.dropped)
        for reason, count in stream.dropped.items():
            dropped[reason] = dropped.get(reason, 0) + count
        found[sensor_pass.sensor] = SensorNoise(model=fit.model, allan=allan, gaps=stream.gaps,
                                                missing=stream.missing, dropped=dropped, out_of_range=stream.outside,
                                                fit=fit, temperature=temperature,
                                                temperature_unit='codes' if kind is InputKind.COUNTS else 'C',
                                                why=why)
    topic = options.topics.counts if opened.kind is InputKind.COUNTS else options.topics.raw_imu
    return NoiseRun(input_kind=opened.kind, sensors=found, compensated=unit is not None,
                    reference_lines=tuple(lines), topic=topic, survey=opened.finished_survey())


def run_source_why(temperature: tuple[float, float] | None, kind: InputKind, unit: UnitCalibration | None,
                   trends: list[TemperatureTrend]) -> tuple[str, str]:
    """``static_run`` for a static run, else ``residual``; and why, when the temperature moved.

    A run that records no temperature is taken as one at constant temperature (said beside the
    source), as is one whose temperature stays within :data:`CONSTANT_TEMPERATURE_C` (a counts
    run: :data:`CONSTANT_TEMPERATURE_FRACTION` of the calibrated range). A run whose temperature
    moves more is a static run when a calibration compensates it and what the compensation leaves
    says so (:func:`~tak_thermo_ros.core.noise.constancy.compensated_static`: no trend with
    temperature left, not a sweep, inside the calibrated range); without a calibration it is not.
    """
    if temperature is None:
        return 'static_run', ''
    span = temperature[1] - temperature[0]
    if kind is InputKind.COUNTS and unit is not None:
        calibrated = unit.accel.temp_code_max - unit.accel.temp_code_min
        constant = span <= CONSTANT_TEMPERATURE_FRACTION * calibrated
    else:
        constant = span <= CONSTANT_TEMPERATURE_C
    if constant:
        return 'static_run', ''
    if unit is None or not trends:
        return 'residual', 'not compensated (no --params)' if unit is None else ''
    calibrations = [calibration for _, calibration in unit.sensors]
    calibrated = (max(c.temp_code_min for c in calibrations), min(c.temp_code_max for c in calibrations))
    static, why = compensated_static(temperature, calibrated, trends)
    return ('static_run' if static else 'residual'), why


@dataclass(frozen=True)
class NoiseSource:
    """Per-sensor noise models and where they come from (one line to print)."""

    models: dict[str, NoiseModel]
    source: str
    line: str


def noise_models(*, unit: UnitCalibration | None, options: StreamOptions, noise_file: str | Path | None = None,
                 noise_run: str | Path | None = None, calibration_run: str | Path | None = None,
                 use_stored: bool = True, gravity: float = STANDARD_GRAVITY,
                 latitude: float | None = None) -> NoiseSource:
    """The noise models of a unit's sensors, from the first source that is given, in this order.

    1. ``noise_file``: a Kalibr-style imu.yaml (``source='file'``);
    2. ``noise_run``: a static, constant-temperature run, compensated with ``unit`` when given
       (``source='static_run'``; ``residual`` when its temperature is not constant, and said);
    3. ``use_stored`` and every sensor of ``unit`` carries a ``noise`` section that ``tak_calib fit``
       was given (``--noise``, ``--noise-run``, ``--noise-from-residual``): those (their own ``source``).
       Not a model the fit estimated from its own rests (``source: fit``): that is the node's yardstick
       at the rests; a verdict on a run is judged against that run's own noise, as before;
    4. ``calibration_run``: its residual after ``unit``'s correction (``source='residual'``).

    A sensor the file does not cover is taken from the next source that can give it.

    :raises NoiseError: no source can give a model of every sensor.
    """
    sensors = ('accel',) if unit is None or unit.input_kind is InputKind.COUNTS else ('accel', 'gyro')
    models: dict[str, NoiseModel] = {}
    said: list[str] = []
    if noise_file is not None:
        from tak_thermo_ros.formats.kalibr import read_kalibr
        from_file = read_kalibr(noise_file)
        models.update({s: m for s, m in from_file.items() if s in sensors})
        said.append(f'{", ".join(sorted(models))} from {noise_file}')
    if noise_run is not None and any(s not in models for s in sensors):
        run = noise_bag(noise_run, options, unit=unit, gravity=gravity, latitude=latitude)
        new = {s: m for s, m in run.models.items() if s not in models}
        models.update(new)
        span = next(iter(run.sensors.values())).span_words
        if all(model.source == 'static_run' for model in new.values()):
            said.append(f'{", ".join(sorted(new))} from the static run {noise_run}{span}')
        else:
            said.append(f'{", ".join(sorted(new))} from {noise_run}, which is NOT at constant temperature{span}: '
                        f'labelled residual, no independent yardstick')
    if use_stored and unit is not None and any(s not in models for s in sensors):
        stored = {s: unit.sensor(s).noise for s in sensors if s not in models and unit.sensor(s).noise is not None
                  and unit.sensor(s).noise.source != 'fit'}
        models.update(stored)  # type: ignore[arg-type]
        if stored:
            said.append(f'{", ".join(sorted(stored))} from the calibration file')
    if calibration_run is not None and unit is not None and any(s not in models for s in sensors):
        run = noise_bag(calibration_run, options, unit=unit, source='residual', gravity=gravity, latitude=latitude)
        new = {s: m for s, m in run.models.items() if s not in models}
        models.update(new)
        said.append(f'{", ".join(sorted(new))} from the residual of {calibration_run} after the calibration')
    missing = [s for s in sensors if s not in models]
    if missing:
        msg = (f'no noise model of the {", ".join(missing)}: give --noise FILE (Kalibr imu.yaml), --noise-run BAG '
               f'(a static run) or the calibration run')
        raise NoiseError(msg)
    sources = {models[s].source for s in sensors}
    return NoiseSource(models={s: models[s] for s in sensors}, source=sources.pop() if len(sources) == 1 else 'mixed',
                       line='noise model: ' + '; '.join(said))


def noise_document(noise: SensorNoise) -> dict[str, object]:
    """JSON of one sensor's noise.

    The model's terms (lists, SI; a floor time at infinity is null), its source and update rate,
    the samples and gaps, the Allan deviation behind it, and how the model follows it (``fit``:
    per axis within the band or not, the worst ratio, bumps, dips, a step; IEEE 952's slope
    lines; the floor, the Allan deviation's minimum).
    """
    document: dict[str, object] = noise.model.to_json()
    allan = noise.allan
    document.update(samples=allan.samples, gaps=noise.gaps, missing_samples=noise.missing,
                    allan={'taus': allan.taus.tolist(), 'adev': allan.adev.tolist(), 'counts': allan.counts.tolist()})
    if noise.fit is not None:
        document['fit'] = noise.fit.as_dict()
    return document
