"""The online pipeline's input rules: what each input message must be to be corrected, and what becomes of it.

:class:`~tak_thermo_ros.core.link.online.OnlineCompensator` runs them on every message, so that
every input message received is either published or dropped with a reason (one of
:data:`ONLINE_DROP_REASONS`, :data:`SIGNAL_DROP_REASONS`, :data:`IMU_DROP_REASONS`,
:data:`RAW_DROP_REASONS`). The same rules as offline: ``counts`` (calibration file version 1)
input by :func:`~tak_thermo_ros.core.records.record.counts_problem`, a driver's ``imu`` values by
:func:`~tak_thermo_ros.core.records.record.values_problem`, stamps by
:func:`~tak_thermo_ros.core.records.record.stamp_kept`.

Bad input, each with a defined outcome, checks in this order:

- a header stamp that does not go on from the previous input message's (whatever became of
  that one) nor from the last kept one's: equal (``duplicate_stamp``), earlier
  (``time_backwards``) or later by more than 10 s and 100 steps of the stream (``stamp_jump``: a
  message stamped in the future is dropped alone; after a real jump the next message goes on
  from it): dropped, by :func:`~tak_thermo_ros.core.records.record.stamp_kept`, as ``align()``
  does offline;
- values NaN / infinite (``non_finite``), for counts also not whole (``non_integer``) or at
  a 16-bit rail (``saturated``), for a driver of magnitude 1e4 or more (``non_physical``):
  dropped, never corrected;
- no temperature yet: dropped (``waiting_for_temperature``) and a throttled warning; a
  calibration without temperature terms (``thermal: held`` or ``none`` on every sensor the
  channel corrects) reads no temperature: it neither waits for one nor calls one stale;
- temperature older than ``temp_timeout`` (on the arrival clock): held (``hold``) or the
  message dropped (``drop``: ``stale_temperature``); diagnostics at ERROR either way;
- temperature outside the calibrated range (of any sensor): clamped or extrapolated (the
  corrector's policy), counted, and a throttled warning naming the value and the range;
- the correction raises (a user effect) or gives a non-finite number (``correction_failed``,
  ``non_finite_output``): dropped, never published;
- a non-finite temperature, or one outside the plausible range of the input kind
  (:func:`~tak_thermo_ros.core.records.record.temp_code_problem`, the offline rule): ignored (the
  last good one stays) and counted;
- a calibration with a recorded-signal term (``aux:TOPIC``): that signal follows the
  temperature's rules: held at its last value; none yet: dropped (``waiting_for_signal``);
  older than ``temp_timeout``: held or dropped (``stale_signal``) by the same policy; a
  non-finite value ignored and counted.

A driver's Imu message may carry one sensor (a flight log's ``sensor_accel`` and
``sensor_gyro`` at their own times): ``sensor_msgs/msg/Imu`` marks the other absent by its
covariance[0] = -1 (:data:`~tak_thermo_ros.core.link.correction.NOT_PROVIDED`), the caller hands
the two marks over with the values, and the rule is ``tak_calib apply``'s for a record whose
sensors have their own stamps:

- from the first message that marks a sensor absent on, each sensor is a stream of its own:
  the stamp rule runs on each sensor's own stamps (the messages that carry it), a sensor's
  values are checked alone, each sensor's effects with memory (a thermal lag, hysteresis) step
  on its own samples only, and a recorded signal is waited for by the sensors whose terms need
  it; the temperature (and its staleness) is the message's;
- the published message carries what survived: both sensors, or one (:class:`OneSensor`; the
  node publishes the other marked absent: zeros, covariance[0] = -1); a carried sensor left out
  of a published message is counted in
  :attr:`~tak_thermo_ros.core.link.online.OnlineCompensator.sensor_dropped`; a message none of
  whose sensors survives is dropped for the first one's reason (the accelerometer's, then the
  gyroscope's), a message that marks both absent as ``no_sensor``;
- before that first message the node cannot know that the stream carries its sensors apart
  (``apply`` reads the whole record first): a message one of whose two sensors cannot be
  corrected (a non-finite or non-physical value, a recorded signal one sensor's terms need and
  that has not arrived) is dropped whole, where ``apply`` keeps the other sensor's sample.

Here too: the policies (:class:`StaleTemperature`), a calibration tried out over its range before
it is put in force (:func:`check_correction`, :class:`Configuration`), the stamp rule's state
over a stream (:class:`_StampRule`) and the streams of a message (:class:`_Stream`).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Callable, NamedTuple

from tak_thermo_ros.core.link.correction import OutOfRange, UnitCorrector, acceleration_variance, imu_covariances
from tak_thermo_ros.core.link.model import Calibration, InputKind, UnitCalibration
from tak_thermo_ros.core.records.record import StampHistory
from tak_thermo_ros.core.records.drops import DROP_REASONS
from tak_thermo_ros.core.records.stamps import going_on_step, stamp_problem
from tak_thermo_ros.errors import CalibrationError

DUPLICATE_STAMP = 'duplicate_stamp'
TIME_BACKWARDS = 'time_backwards'
STAMP_JUMP = 'stamp_jump'
WAITING_FOR_TEMPERATURE = 'waiting_for_temperature'
STALE_TEMPERATURE = 'stale_temperature'
CORRECTION_FAILED = 'correction_failed'
NON_FINITE_OUTPUT = 'non_finite_output'
STAMP_DROP_REASONS: tuple[str, ...] = (DUPLICATE_STAMP, TIME_BACKWARDS, STAMP_JUMP)
ONLINE_DROP_REASONS: tuple[str, ...] = (*STAMP_DROP_REASONS, *DROP_REASONS, WAITING_FOR_TEMPERATURE,
                                        STALE_TEMPERATURE, CORRECTION_FAILED, NON_FINITE_OUTPUT)
"""Why an input message is not published, in the order the checks run."""
WAITING_FOR_SIGNAL = 'waiting_for_signal'
STALE_SIGNAL = 'stale_signal'
SIGNAL_DROP_REASONS: tuple[str, ...] = (WAITING_FOR_SIGNAL, STALE_SIGNAL)
"""Why an input message is not published when the calibration needs a recorded signal
(checked after the temperature)."""

NO_SENSOR = 'no_sensor'
IMU_DROP_REASONS: tuple[str, ...] = (NO_SENSOR,)
"""Why a driver's Imu message is not published besides :data:`ONLINE_DROP_REASONS`: it marks
both sensors absent (covariance[0] = -1 on both), so it carries nothing to correct."""
MALFORMED = 'malformed'
RAW_DROP_REASONS: tuple[str, ...] = (MALFORMED,)
"""Why a message taken as its serialised bytes (the node's raw path) is not published: the bytes
are no message of its type (truncated, a bad encapsulation or string length); see
:meth:`~tak_thermo_ros.core.link.online.OnlineCompensator.malformed`."""
SENSORS: tuple[str, str] = ('accel', 'gyro')
"""The sensors of a driver's Imu message, in the order of its six values."""

PROBE_TEMPERATURES = 33
"""Temperatures across each calibrated range at which a new calibration is tried out."""


class StaleTemperature(str, enum.Enum):
    """What to do with input messages while the last temperature is older than ``temp_timeout``."""

    HOLD = 'hold'
    """Correct with the last temperature (the board temperature changes over minutes)."""
    DROP = 'drop'
    """Publish nothing until a fresh temperature arrives."""


@dataclass(frozen=True)
class Configuration:
    """A validated set of policies and calibration, ready to be put in force.

    :meth:`~tak_thermo_ros.core.link.online.OnlineCompensator.install` puts it in force (and cannot fail).

    Built by :meth:`~tak_thermo_ros.core.link.online.OnlineCompensator.prepare`; every number later computed from the
    calibration (covariances, the correction over the calibrated range) was computed once.
    """

    unit: UnitCalibration
    corrector: UnitCorrector
    out_of_range: OutOfRange
    stale: StaleTemperature
    timeout_s: float
    covariances: tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]
    low: float
    high: float
    needs_temperature: bool = True


class OneSensor(NamedTuple):
    """An Imu message published with one sensor; the caller marks the other absent (covariance[0] = -1).

    A tuple subclass: a caller tells it from the six values of a message with both by its class.

    :param sensor: the sensor it carries, ``'accel'`` or ``'gyro'``.
    :param values: its three corrected values.
    """

    sensor: str
    values: tuple[float, float, float]


class _StampRule:
    """The stamp rule's state over one stream (:func:`~tak_thermo_ros.core.records.record.stamp_kept`).

    The messages', or, once a driver's sensors come apart, one sensor's own samples. It counts
    its drops by reason (for the log line).
    """

    __slots__ = ('last_ns', 'before_ns', 'kept_ns', 'step_ns', 'dropped')

    def __init__(self) -> None:
        self.last_ns: int | None = None
        self.before_ns: int | None = None
        self.kept_ns: int | None = None
        self.step_ns: int | None = None
        """The stream's step (:class:`~tak_thermo_ros.core.records.record.StampHistory`)."""
        self.dropped = dict.fromkeys(STAMP_DROP_REASONS, 0)

    def problem(self, stamp_ns: int) -> str | None:
        """Why the next message, stamped ``stamp_ns``, is dropped, or ``None``; the state moves on."""
        last, before = self.last_ns, self.before_ns
        self.before_ns, self.last_ns = last, stamp_ns
        step = None
        # the usual case (a step forward within 10 s) never comes here: the caller takes it inline
        if last is not None:
            step = going_on_step(stamp_ns, StampHistory(last, self.kept_ns, self.step_ns, before))
            if step is None:
                reason = stamp_problem(stamp_ns - last)
                self.dropped[reason] += 1
                return reason
        self.step_ns = step
        self.kept_ns = stamp_ns
        return None

    def copy(self) -> _StampRule:
        """The same state, to go on apart."""
        twin = _StampRule()
        twin.last_ns, twin.before_ns = self.last_ns, self.before_ns
        twin.kept_ns, twin.step_ns = self.kept_ns, self.step_ns
        twin.dropped = dict(self.dropped)
        return twin


class _Stream:
    """One stream of samples through the pipeline, with its own stamps, values, correction and signals.

    A message is one stream (every value it carries, its stamps, the whole correction) until a
    driver's message marks a sensor absent; from then on each sensor is a stream of its own (its
    three values, its own stamps, its own correction and recorded signals). The per-message
    pipeline (:meth:`~tak_thermo_ros.core.link.online.OnlineCompensator.process_values`) runs over the
    streams a message carries.

    :param sensor: ``''`` for the message's stream, else the sensor (``'accel'``, ``'gyro'``).
    :param span: the stream's values in the message's.
    :param stamps: the stamp rule's state over the stream.
    """

    __slots__ = ('sensor', 'span', 'stamps', 'correct', 'signals', 'reason')

    def __init__(self, sensor: str, span: slice, stamps: _StampRule) -> None:
        self.sensor = sensor
        self.span = span
        self.stamps = stamps
        self.correct: Callable[..., tuple[float, ...]] | None = None
        """The correction of the stream's values, ``correct(values, temperature, stamp_s=, aux=)`` (set by install)."""
        self.signals: tuple[str, ...] = ()
        """The recorded signals the stream's correction needs."""
        self.reason: str | None = None
        """Why the stream's sample in the message at hand is left out, ``None`` while it is not."""


def as_unit(calibration: UnitCalibration | Calibration) -> UnitCalibration:
    """A :class:`UnitCalibration`; a bare :class:`Calibration` is the counts input's accelerometer."""
    if isinstance(calibration, UnitCalibration):
        return calibration
    return UnitCalibration(InputKind.COUNTS, calibration)


PROBE_INPUT = {InputKind.COUNTS: 4096.0, InputKind.IMU: 16.0}
"""Magnitude of the inputs at which a new calibration is tried out: 16 m/s^2 in codes of the
paper's unit (about 256 per m/s^2); 16 m/s^2 or 16 rad/s for a driver's values."""


def probe_values(input_kind: InputKind) -> tuple[float, ...]:
    """Input values at which a new calibration is tried out: zero and :data:`PROBE_INPUT` either way."""
    magnitude = PROBE_INPUT[input_kind]
    return (-magnitude, 0.0, magnitude)


MAG_CHANNEL = 'mag'
CHANNELS = ('imu', MAG_CHANNEL)
"""What an online compensator corrects: the unit's Imu (or counts), or its magnetometer."""
MAG_PROBE_TESLA = 1e-4
"""Field at which a new magnetometer calibration is tried out (twice the Earth's)."""


def channel_sensors(unit: UnitCalibration, channel: str) -> tuple[tuple[str, Calibration], ...]:
    """``(name, link)`` of the sensors a channel corrects (the magnetometer: its thermal link)."""
    if channel == MAG_CHANNEL:
        return (('mag', unit.mag.thermal),) if unit.mag is not None else ()
    return unit.sensors


def channel_corrector(unit: UnitCalibration, channel: str, out_of_range: OutOfRange):
    """The corrector of a channel: :class:`UnitCorrector`, or the magnetometer's."""
    if channel == MAG_CHANNEL:
        from tak_thermo_ros.core.magnetometer.channel import MagCorrector
        return MagCorrector(unit.mag, out_of_range=out_of_range)
    return UnitCorrector(unit, out_of_range=out_of_range)


def check_correction(unit: UnitCalibration, corrector: UnitCorrector, *, key: str = 'calibration',
                     channel: str = 'imu') -> None:
    """Try the correction out over the calibrated range before it is put in force.

    Every sensor is corrected at :data:`PROBE_TEMPERATURES` temperatures across its range,
    with inputs at zero and of either sign (:func:`probe_values`), on a
    fresh corrector (effects with memory start afresh, one second apart).

    :raises CalibrationError: when the correction raises or gives a non-finite number.
    """
    sensors = channel_sensors(unit, channel)
    values = (-MAG_PROBE_TESLA, 0.0, MAG_PROBE_TESLA) if channel == MAG_CHANNEL else probe_values(unit.input_kind)
    channels = corrector.channels
    trial = channel_corrector(unit, channel, OutOfRange.CLAMP)
    # Recorded signals (aux:TOPIC) held at their terms' reference value (0 if a term has none).
    aux = {effect.needs_signal: float(effect.values.get('reference', 0.0))
           for _, calibration in sensors for effect in calibration.effects if effect.needs_signal} or None
    step = 0
    for name, calibration in sensors:
        low, high = calibration.temp_code_min, calibration.temp_code_max
        for index in range(PROBE_TEMPERATURES):
            temperature = low + (high - low) * index / (PROBE_TEMPERATURES - 1)
            for value in values:
                step += 1
                try:
                    result = trial.correct_sample((value,) * channels, temperature, stamp_s=float(step), aux=aux)
                except Exception as err:  # a user effect may raise anything: refuse the calibration
                    msg = (f'{key}: the correction fails at temperature {temperature:g} '
                           f'({type(err).__name__}: {err})')
                    raise CalibrationError(msg) from None
                if not all(math.isfinite(v) for v in result):
                    msg = (f'{key}.{name}: the correction is not finite at temperature {temperature:g} '
                           f'for input {value:g} (check scale, offsets and effects)')
                    raise CalibrationError(msg)


def _covariances(unit: UnitCalibration, key: str, channel: str = 'imu'
                 ) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
    """The Imu covariances of the unit (as ``tak_calib apply`` writes them), all finite.

    For the magnetometer: ``((), (), magnetic_field_covariance)``.
    """
    if channel == MAG_CHANNEL:
        from tak_thermo_ros.core.magnetometer.channel import magnetic_covariance
        return (), (), magnetic_covariance(unit.mag)
    try:
        accel = acceleration_variance(unit.accel)
        gyro = acceleration_variance(unit.gyro) if unit.gyro is not None else None
        covariances = imu_covariances(accel, gyro)
    except (OverflowError, ZeroDivisionError) as err:
        msg = f'{key}: residual_rms / scale gives no finite covariance ({err})'
        raise CalibrationError(msg) from None
    if not all(math.isfinite(v) for block in covariances for v in block):
        msg = f'{key}: residual_rms / scale gives no finite covariance'
        raise CalibrationError(msg)
    return covariances
