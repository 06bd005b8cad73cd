"""Online correction, one message at a time: the ``compensator`` node's logic without ROS.

:class:`OnlineCompensator` holds a :class:`~tak_thermo_ros.core.link.correction.UnitCorrector`, the
last temperature and when it arrived, the policies for bad input, and a counter for every
outcome, so that every input message received is either published or dropped with a reason::

    received == published + sum(dropped.values())

Messages lost before they reach the node are counted apart: those the middleware reports lost
in :attr:`OnlineCompensator.lost`, and, when the caller has the publishers' sequence numbers,
the gaps in them in :attr:`OnlineCompensator.sequence_gaps`.

It imports nothing from ROS (like imu_tools' ``imu_filter.h``): the node converts messages to
plain numbers, calls :meth:`OnlineCompensator.process_values` (or :meth:`process_counts`)
and converts the result back. Two inputs, one set of policies:

- ``counts`` (calibration file version 1): three channel codes and a temperature-sensor code;
  the drop rules of :func:`~tak_thermo_ros.core.records.record.counts_problem`;
- ``imu`` (version 2): a driver's six values (accelerometer x y z in m/s^2, gyroscope x y z in
  rad/s) and a temperature in degrees C; the drop rule of
  :func:`~tak_thermo_ros.core.records.record.values_problem` (a non-finite value drops the whole
  message, as ``tak_calib apply`` does).

The correction is :meth:`UnitCorrector.correct_sample`, bit-identical to the vectorised path.

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
  of a published message is counted in :attr:`OnlineCompensator.sensor_dropped`; a message
  none of whose sensors survives is dropped for the first one's reason (the accelerometer's,
  then the gyroscope's), a message that marks both absent as ``no_sensor``;
- before that first message the node cannot know that the stream carries its sensors apart
  (``apply`` reads the whole record first): a message one of whose two sensors cannot be
  corrected (a non-finite or non-physical value, a recorded signal one sensor's terms need and
  that has not arrived) is dropped whole, where ``apply`` keeps the other sensor's sample.

The magnetometer (``channel='mag'``, a driver calibration holding ``mag``) is a second
instance on its own topic: three values in tesla corrected by
:class:`~tak_thermo_ros.core.magnetometer.channel.MagCorrector` (the thermal link, then the
iron), the same temperature, the same rules and the same counters.

Warnings are throttled but never silent: the first of a kind is reported at once, later ones
at most every ``warn_period_s`` with the number that occurred in between.

The calibration watch (:mod:`tak_thermo_ros.core.link.watch`, ``watch=WatchSettings(...)``; the
node's default, off here) extends the pipeline once: every message published with all its
values goes to the watch (a comparison and an append), which finds the rests; :meth:`tick`
(the node's timer, outside the message path) judges them. With ``turn_on`` or learning, the
output loses the watch's adjustment (the run's turn-on offset, the learned curve). The watch
takes messages that carry both sensors: it is off from the first message that marks one absent.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from operator import sub
from typing import Callable, NamedTuple

from tak_thermo_ros.core.link.correction import (
    NOT_PROVIDED,
    OutOfRange,
    UnitCorrector,
    acceleration_variance,
    imu_covariances,
)
from tak_thermo_ros.core.link.model import Calibration, InputKind, UnitCalibration
from tak_thermo_ros.core.link.watch import (
    ANOTHER_CALIBRATION,
    CalibrationWatch,
    RestFinder,
    WatchSettings,
    WatchUnavailable,
    adjustment_at,
)
from tak_thermo_ros.core.records.record import (
    DROP_REASONS,
    NANOSECONDS,
    STAMP_JUMP_NS,
    STAMP_JUMP_S,
    StampHistory,
    counts_problem,
    going_on_step,
    seconds,
    stamp_problem,
    temp_code_problem,
    values_problem,
)
from tak_thermo_ros.core.values import SENSOR_NAMES
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
:meth:`OnlineCompensator.malformed`."""
SENSORS: tuple[str, str] = ('accel', 'gyro')
"""The sensors of a driver's Imu message, in the order of its six values."""

WARN_PERIOD_S = 5.0
"""Default least time between two reports of the same kind of problem."""

PROBE_TEMPERATURES = 33
"""Temperatures across each calibrated range at which a new calibration is tried out."""


class StaleTemperature(str, enum.Enum):
    """What to do with input messages while the last temperature is older than ``temp_timeout``."""

    HOLD = 'hold'
    """Correct with the last temperature (the board temperature changes over minutes)."""
    DROP = 'drop'
    """Publish nothing until a fresh temperature arrives."""


class Level(enum.IntEnum):
    """Diagnostic levels (the values of ``diagnostic_msgs/msg/DiagnosticStatus``)."""

    OK = 0
    WARN = 1
    ERROR = 2


@dataclass(frozen=True)
class Notice:
    """A log line the node should emit now.

    :param level: severity (``OK`` is logged as INFO).
    :param kind: what it is about (``waiting_for_temperature``, ``out_of_range``, ...).
    :param text: the message, one line.
    """

    level: Level
    kind: str
    text: str


@dataclass(frozen=True)
class Status:
    """The diagnostics status as plain data; the node converts it to ``DiagnosticStatus``.

    :param level: worst condition since the previous status.
    :param message: one-line summary.
    :param values: ``(key, value)`` pairs, values already formatted.
    """

    level: Level
    message: str
    values: tuple[tuple[str, str], ...]

    def value(self, key: str) -> str:
        """The value of one key."""
        return dict(self.values)[key]


@dataclass(frozen=True)
class Configuration:
    """A validated set of policies and calibration, ready to be put in force.

    :meth:`OnlineCompensator.install` puts it in force (and cannot fail).

    Built by :meth:`OnlineCompensator.prepare`; every number later computed from the
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
    pipeline (:meth:`OnlineCompensator.process_values`) runs over the streams a message carries.

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


class _Throttle:
    """First report at once, then at most one per period, counting what happened since the last one.

    What it counts is what the report's "so far" counts (messages, samples, messages lost), the
    occurrence that makes a report due included, so that a report's "N more since the last
    report" is its "so far" less the previous report's. A periodic check that makes a report due
    (a tick) counts nothing.
    """

    __slots__ = ('period_s', 'next_s', 'held_back')

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.next_s = -math.inf
        self.held_back = 0

    def due(self, now_s: float, count: int = 1) -> bool:
        """Count ``count`` occurrences (0: a tick); whether a report is due now."""
        if self.next_s > -math.inf:  # the first report has nothing "since the last report"
            self.held_back += count
        if now_s >= self.next_s:
            self.next_s = now_s + self.period_s
            return True
        return False

    def take_held_back(self) -> int:
        """What was counted since the last report, and start again."""
        held, self.held_back = self.held_back, 0
        return held


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
"""What an :class:`OnlineCompensator` corrects: the unit's Imu (or counts), or its magnetometer."""
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


class OnlineCompensator:
    """Correct input messages one by one, with defined behaviour on every bad input.

    Times ``now_s`` are seconds on a monotonic clock of the caller's choice (the node uses the
    arrival time); stamps are the messages' header stamps (``sec``, ``nanosec``).

    :param calibration: the correction in force (a bare :class:`Calibration` is the counts input).
    :param out_of_range: temperatures outside the calibrated range: clamp or extrapolate.
    :param stale_temperature: input while the temperature is stale: hold or drop.
    :param temp_timeout_s: age beyond which the last temperature is stale, > 0.
    :param temp_topic: name of the temperature stream, used in messages.
    :param warn_period_s: least time between two reports of the same kind.
    :param channel: ``'imu'`` (the Imu or the counts) or ``'mag'`` (the magnetometer of a driver
        calibration: three values in tesla on its own topic).
    :raises CalibrationError: when the calibration fails :meth:`prepare`'s checks.
    :raises ValueError: on an invalid policy.
    """

    def __init__(self, calibration: UnitCalibration | Calibration, *, out_of_range: OutOfRange = OutOfRange.CLAMP,
                 stale_temperature: StaleTemperature = StaleTemperature.HOLD,
                 temp_timeout_s: float = 1.0, temp_topic: str = 'tak/temp_code',
                 warn_period_s: float = WARN_PERIOD_S, channel: str = 'imu',
                 watch: WatchSettings | None = None) -> None:
        unit = as_unit(calibration)
        if channel not in CHANNELS:
            msg = f'channel: expected one of {", ".join(CHANNELS)}, got {channel!r}'
            raise ValueError(msg)
        self.channel = channel
        self.input_kind = unit.input_kind
        self.temp_topic = temp_topic
        self.warn_period_s = warn_period_s
        counts = self.input_kind is InputKind.COUNTS
        self._message_word = 'counts' if counts else ('MagneticField' if channel == MAG_CHANNEL else 'Imu')
        self._temperature_word = 'temperature code' if counts else 'temperature'
        self._problem: Callable[..., str | None] = counts_problem if counts else values_problem
        self.received = 0
        self.published = 0
        self._sensors_apart = channel != MAG_CHANNEL and not counts
        """Whether the input is a driver's Imu, whose messages may carry one sensor each."""
        self.dropped: dict[str, int] = dict.fromkeys(
            (*ONLINE_DROP_REASONS, *SIGNAL_DROP_REASONS, *(IMU_DROP_REASONS if self._sensors_apart else ()),
             *RAW_DROP_REASONS), 0)
        self.one_sensor_messages = 0
        """Driver Imu messages received that mark one sensor (or both) absent."""
        self.sensor_dropped: dict[str, int] = {}
        """``'<sensor>.<reason>'`` -> samples of a sensor left out of messages published with the other."""
        self.own_stamps_since: int | None = None
        """The number of the first message that marked a sensor absent (from it on each sensor
        is a stream of its own), or ``None``."""
        self.lost: dict[str, int] = {}
        """Messages lost in transport (reported by the middleware), per input stream."""
        self.sequence_gaps: dict[str, int] | None = None
        """Messages never received, from gaps in the publisher's sequence numbers, per input
        stream; ``None`` while the caller gives no sequence numbers (:meth:`sequence`)."""
        self._last_sequence: dict[str, int] = {}
        self.out_of_range = 0
        self.temperature_messages = 0
        self.temperature_rejected = 0
        self.calibration_updates = 0
        self.notices: list[Notice] = []
        """Log lines due; the caller empties it (:meth:`take_notices`)."""
        self._throttles = {kind: _Throttle(warn_period_s) for kind in (
            WAITING_FOR_TEMPERATURE, STALE_TEMPERATURE, 'out_of_range', 'temperature_rejected',
            'stamp_order', 'correction', 'message_lost', 'sequence_gap', WAITING_FOR_SIGNAL, STALE_SIGNAL,
            'signal_rejected', MALFORMED)}
        self._signals: tuple[str, ...] = ()
        self._signal_values: dict[str, float] = {}
        self._signal_arrival_s: dict[str, float] = {}
        self.signal_messages: dict[str, int] = {}
        self.signal_rejected: dict[str, int] = {}
        self._streams: tuple[_Stream, ...] = (_Stream('', slice(None), _StampRule()),)
        """The streams of every message: the message's, or (apart) the sensors' in the order of the values."""
        self._apart = False
        """Whether each sensor is a stream of its own (from the first message that marked one absent on)."""
        self._carried_streams: dict[tuple[bool, bool], tuple[_Stream, ...]] = {}
        """Apart: the streams a message carries, by its two marks (accelerometer, gyroscope)."""
        self._temperature: float | None = None
        self._temp_arrival_s = -math.inf
        self._temp_outside = False
        self._stale_reported = False
        self._previous: dict[str, int] = {}
        self._config: Configuration | None = None
        self.watch: CalibrationWatch | None = None
        """The calibration watch in force (:mod:`tak_thermo_ros.core.link.watch`), or ``None``."""
        self.watch_settings: WatchSettings | None = None
        """The watch's settings, ``None`` while it is off (:meth:`_use_settings`)."""
        self.watch_off = ''
        """Why there is no watch, or ``''``."""
        self._use_settings(watch)
        self._watch_finder: RestFinder | None = None
        self._adjustment: tuple[tuple[float, ...], tuple[float, ...]] | None = None
        self._adjusted_at: tuple[float, tuple[float, ...]] | None = None
        """``(T, a + b (T - T_ref))`` of the adjustment in force at the last temperature it was taken at."""
        self.install(self.prepare(calibration=unit, out_of_range=out_of_range,
                                  stale_temperature=stale_temperature, temp_timeout_s=temp_timeout_s))

    # -- configuration -------------------------------------------------------------------

    @property
    def unit(self) -> UnitCalibration:
        """The calibration in force, every sensor."""
        return self._config.unit

    @property
    def calibration(self) -> Calibration:
        """The accelerometer's calibration in force (the whole of a counts calibration).

        On the ``mag`` channel: the magnetometer's thermal link.
        """
        return channel_sensors(self._config.unit, self.channel)[0][1]

    @property
    def corrector(self) -> UnitCorrector:
        """The corrector in force."""
        return self._config.corrector

    @property
    def channels(self) -> int:
        """Values per input message: 3 (counts) or 6 (a driver's accelerometer and gyroscope)."""
        return self._config.corrector.channels

    @property
    def out_of_range_policy(self) -> OutOfRange:
        """The policy for temperatures outside the calibrated range."""
        return self._config.out_of_range

    @property
    def stale_policy(self) -> StaleTemperature:
        """The policy for input while the temperature is stale."""
        return self._config.stale

    @property
    def temp_timeout_s(self) -> float:
        """Age beyond which the last temperature is stale."""
        return self._config.timeout_s

    @property
    def temperature(self) -> float | None:
        """The last temperature input accepted, or ``None`` before the first."""
        return self._temperature

    temp_code = temperature

    @property
    def waiting_for_temperature(self) -> bool:
        """Whether the calibration needs a temperature and none has arrived yet (nothing is published meanwhile)."""
        return self._needs_temperature and self._temperature is None

    @property
    def needs_temperature(self) -> bool:
        """Whether the calibration in force reads the temperature (a link with temperature terms)."""
        return self._needs_temperature

    @property
    def covariances(self) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
        """Orientation, angular-velocity and linear-acceleration covariances of the Imu output."""
        return self._config.covariances

    @property
    def variance(self) -> tuple[float, float, float]:
        """Per-axis variance of the corrected specific force for the Imu covariance, (m/s^2)^2."""
        linear = self._config.covariances[2]
        return linear[0], linear[4], linear[8]

    @property
    def calibrated_range(self) -> tuple[float, float]:
        """The temperatures inside every sensor's calibrated range (``low``, ``high``)."""
        return self._config.low, self._config.high

    def prepare(self, *, out_of_range: OutOfRange | str | None = None,
                stale_temperature: StaleTemperature | str | None = None,
                temp_timeout_s: float | None = None,
                calibration: UnitCalibration | Calibration | None = None,
                key: str = 'calibration') -> Configuration:
        """Validate a change of any of the policies (and the calibration); nothing changes yet.

        A new calibration must have the input kind in force; its covariances must be finite
        and its correction finite over its calibrated range (:func:`check_correction`).

        :raises ValueError: on an unknown policy or a timeout that is not a positive number.
        :raises CalibrationError: on a calibration that fails the checks, naming ``key``.
        """
        current = self._config
        new_out_of_range = OutOfRange(out_of_range if out_of_range is not None else current.out_of_range)
        new_stale = StaleTemperature(stale_temperature if stale_temperature is not None else current.stale)
        timeout = temp_timeout_s if temp_timeout_s is not None else current.timeout_s
        if isinstance(timeout, bool) or not isinstance(timeout, (int, float)):
            msg = f'temp_timeout: must be a finite number > 0, got {timeout!r}'
            raise ValueError(msg)
        new_timeout = float(timeout)
        if not (new_timeout > 0.0 and math.isfinite(new_timeout)):
            msg = f'temp_timeout: must be a finite number > 0, got {new_timeout}'
            raise ValueError(msg)
        if calibration is None:
            if new_out_of_range is current.out_of_range:
                return Configuration(current.unit, current.corrector, new_out_of_range, new_stale, new_timeout,
                                     current.covariances, current.low, current.high, current.needs_temperature)
            unit = current.unit
        else:
            unit = as_unit(calibration)
            if unit.input_kind is not self.input_kind:
                msg = (f'{key}: a {unit.input_kind.value}-input calibration cannot replace the '
                       f'{self.input_kind.value}-input one in force (the topics differ): restart the node')
                raise CalibrationError(msg)
            if self.channel == MAG_CHANNEL and unit.mag is None:
                msg = f'{key}.mag: missing (the magnetometer channel needs it; without it restart the node)'
                raise CalibrationError(msg)
        corrector = channel_corrector(unit, self.channel, new_out_of_range)
        if calibration is not None:
            check_correction(unit, corrector, key=key, channel=self.channel)
            covariances = _covariances(unit, key, self.channel)
        else:
            covariances = current.covariances
        thermal = [calibration for _, calibration in channel_sensors(unit, self.channel)
                   if calibration.needs_temperature]
        # Without temperature terms no temperature is outside the range (and none is read).
        low = max((c.temp_code_min for c in thermal), default=-math.inf)
        high = min((c.temp_code_max for c in thermal), default=math.inf)
        return Configuration(unit, corrector, new_out_of_range, new_stale, new_timeout, covariances,
                             float(low), float(high), bool(thermal))

    def install(self, configuration: Configuration) -> None:
        """Put a prepared configuration in force; the next message uses it. Cannot fail."""
        previous, self._config = self._config, configuration
        self._drop_stale = configuration.stale is StaleTemperature.DROP
        self._signals = configuration.corrector.signals
        self._channels = configuration.corrector.channels
        self._install_streams()
        for name in self._signals:
            self.signal_messages.setdefault(name, 0)
            self.signal_rejected.setdefault(name, 0)
        self._low, self._high = configuration.low, configuration.high
        self._needs_temperature = configuration.needs_temperature
        self._timeout_s = configuration.timeout_s
        if self._temperature is not None:
            self._temp_outside = not self._low <= self._temperature <= self._high
        if previous is not None and configuration.unit is not previous.unit:
            self.calibration_updates += 1
        if previous is None or configuration.unit is not previous.unit:
            self._start_watch(configuration.unit)

    def set_watch(self, settings: WatchSettings | None) -> None:
        """New watch settings (learning switched on or off at run time): a new watch of the calibration in force."""
        self._use_settings(settings)
        self._start_watch(self._config.unit)

    def _use_settings(self, settings: WatchSettings | None) -> None:
        """Keep the watch's settings: ``None`` when it is off (not enabled, or the magnetometer's channel)."""
        enabled = settings is not None and settings.enabled and self.channel != MAG_CHANNEL
        self.watch_settings = settings if enabled else None
        self.watch_off = '' if enabled else 'off (watch: false)'

    def _start_watch(self, unit: UnitCalibration) -> None:
        """A watch of the calibration in force (a new one with a new calibration: its rests start afresh)."""
        self._stop_watch()
        settings = self.watch_settings
        if settings is None or self._apart:
            return
        try:
            self.watch = settings.watch(unit)
        except WatchUnavailable as err:
            self.watch_off = f'off: {err}'
            return
        self.watch_off = ''
        self._watch_finder = self.watch.finder
        self._take_adjustment(self.watch.adjustment)
        self.watch.on_adjustment = self._take_adjustment

    def _stop_watch(self) -> None:
        self.watch = self._watch_finder = self._adjustment = self._adjusted_at = None

    def _take_adjustment(self, adjustment: tuple[tuple[float, ...], tuple[float, ...]] | None) -> None:
        self._adjustment = adjustment
        self._adjusted_at = None

    def set_policies(self, *, out_of_range: OutOfRange | str | None = None,
                     stale_temperature: StaleTemperature | str | None = None,
                     temp_timeout_s: float | None = None,
                     calibration: UnitCalibration | Calibration | None = None) -> None:
        """:meth:`prepare` and :meth:`install` in one step, between two messages.

        :raises ValueError: on an unknown policy or a bad timeout (nothing changes).
        :raises CalibrationError: on a calibration that fails the checks (nothing changes).
        """
        self.install(self.prepare(out_of_range=out_of_range, stale_temperature=stale_temperature,
                                  temp_timeout_s=temp_timeout_s, calibration=calibration))

    def swap_calibration(self, calibration: UnitCalibration | Calibration) -> None:
        """Put a new calibration in force (checked first); the next message uses it."""
        self.set_policies(calibration=calibration)

    # -- the per-message path --------------------------------------------------------------

    def process_temperature(self, temperature: float, now_s: float) -> bool:
        """Take a temperature (code or degrees C) that arrived at ``now_s``; ``False`` if rejected."""
        self.temperature_messages += 1
        problem = temp_code_problem(temperature, self.input_kind.value)
        if problem is not None:
            self.temperature_rejected += 1
            if self._throttles['temperature_rejected'].due(now_s):
                what = problem.replace('_', '-')
                self._notice(Level.WARN, 'temperature_rejected',
                             f'{what} {self._temperature_word} {temperature:g} on {self.temp_topic} ignored; '
                             f'keeping the last one ({self.temperature_rejected} so far)')
            return False
        self._temperature = temperature
        self._temp_arrival_s = now_s
        self._temp_outside = not self._low <= temperature <= self._high
        if self._stale_reported:
            self._stale_reported = False
            self._notice(Level.OK, STALE_TEMPERATURE,
                         f'{self._temperature_word} on {self.temp_topic} fresh again ({temperature:g})')
        return True

    def malformed(self, temperature: bool, detail: str, now_s: float) -> None:
        """A message whose bytes are no message of its type arrived at ``now_s`` (the node's raw path).

        An input message is received and dropped (``malformed``); a temperature message is received and
        rejected (the last good one stays). Reported (WARN, throttled) with ``detail``, one line.
        """
        if temperature:
            self.temperature_messages += 1
            self.temperature_rejected += 1
            kind, count, outcome = ('temperature_rejected', self.temperature_rejected,
                                    f'ignored; keeping the last {self._temperature_word}')
        else:
            self.received += 1
            self.dropped[MALFORMED] += 1
            kind, count, outcome = MALFORMED, self.dropped[MALFORMED], 'dropped'
        throttle = self._throttles[kind]
        if throttle.due(now_s):
            held = throttle.take_held_back()
            self._notice(Level.WARN, kind, f'{detail}: {outcome} ({count} so far{self._since(held)})')

    @property
    def signals(self) -> tuple[str, ...]:
        """Names ``aux:TOPIC[:FIELD]`` of the recorded signals the calibration in force needs."""
        return self._signals

    def process_signal(self, name: str, value: float, now_s: float) -> bool:
        """Take a value of recorded signal ``name`` that arrived at ``now_s``.

        ``False`` if rejected (non-finite: the last good value stays, as for the temperature).
        """
        self.signal_messages[name] = self.signal_messages.get(name, 0) + 1
        if value != value or value in (math.inf, -math.inf):
            self.signal_rejected[name] = self.signal_rejected.get(name, 0) + 1
            if self._throttles['signal_rejected'].due(now_s):
                self._notice(Level.WARN, 'signal_rejected', f'non-finite value {value} of {name} ignored; '
                             f'keeping the last value ({self.signal_rejected[name]} so far)')
            return False
        self._signal_values[name] = float(value)
        self._signal_arrival_s[name] = now_s
        return True

    def _signal_problem(self, now_s: float, names: tuple[str, ...] | None = None) -> str | None:
        """Why the input cannot be corrected for want of a recorded signal (of ``names``: all), or ``None``."""
        for name in self._signals if names is None else names:
            if name not in self._signal_values:
                if self._throttles[WAITING_FOR_SIGNAL].due(now_s):
                    self._notice(Level.WARN, WAITING_FOR_SIGNAL, f'waiting for {name}: publishing nothing '
                                 f'({self.dropped[WAITING_FOR_SIGNAL] + 1} {self._message_word} messages '
                                 f'dropped so far)')
                return WAITING_FOR_SIGNAL
            age = now_s - self._signal_arrival_s[name]
            if age > self._timeout_s:
                if self._throttles[STALE_SIGNAL].due(now_s):
                    action = f'dropping {self._message_word} messages' if self._drop_stale else 'holding the last value'
                    self._notice(Level.ERROR, STALE_SIGNAL, f'{name} is stale: {age:.2f} s old > temp_timeout '
                                 f'{self._timeout_s:g} s; {action}')
                if self._drop_stale:
                    return STALE_SIGNAL
        return None

    def _temperature_now(self, now_s: float) -> float | str:
        """The temperature to correct a message with now, or why it is dropped (counted and reported)."""
        temperature = self._temperature
        if not self._needs_temperature:
            # The correction reads no temperature: the calibration's reference (or the last one) stands in.
            return self.calibration.temp_code_ref if temperature is None else temperature
        if temperature is None:
            self.dropped[WAITING_FOR_TEMPERATURE] += 1
            if self._throttles[WAITING_FOR_TEMPERATURE].due(now_s):
                self._report_waiting()
            return WAITING_FOR_TEMPERATURE
        if now_s - self._temp_arrival_s > self._timeout_s:
            self._report_stale(now_s)
            if self._drop_stale:
                self.dropped[STALE_TEMPERATURE] += 1
                return STALE_TEMPERATURE
        return temperature

    def _count_out_of_range(self, now_s: float) -> None:
        self.out_of_range += 1
        if self._throttles['out_of_range'].due(now_s):
            self._report_out_of_range()

    def process_counts(self, sec: int, nanosec: int, x: float, y: float, z: float,
                       now_s: float) -> tuple[float, ...] | str:
        """:meth:`process_values` of one counts message (three channel codes)."""
        return self.process_values(sec, nanosec, (x, y, z), now_s)

    def process_values(self, sec: int, nanosec: int, values: tuple[float, ...], now_s: float,
                       accel_mark: float = 0.0, gyro_mark: float = 0.0) -> tuple[float, ...] | OneSensor | str:
        """Correct one input message, or tell why it is dropped.

        One pipeline over the streams the message carries (:class:`_Stream`: the message's, or
        each sensor's once they came apart): per stream the stamp rule and the values' check; the
        message's temperature; per stream its recorded signals; per stream the correction.

        :param sec: header stamp, whole seconds (``builtin_interfaces/Time.sec``).
        :param nanosec: header stamp, nanoseconds part.
        :param values: the message's values, :attr:`channels` plain floats (counts x y z; or
            the driver's accelerometer x y z then gyroscope x y z).
        :param now_s: arrival time on the caller's monotonic clock, seconds.
        :param accel_mark: a driver's Imu: its ``linear_acceleration_covariance[0]``;
            :data:`~tak_thermo_ros.core.link.correction.NOT_PROVIDED` (-1) says the message
            carries no accelerometer sample (its values are then not read).
        :param gyro_mark: likewise its ``angular_velocity_covariance[0]`` for the gyroscope.
        :returns: the corrected values as plain floats, a :class:`OneSensor` when the message is
            published with one sensor, or the drop reason (a ``str`` of
            :data:`ONLINE_DROP_REASONS`, :data:`SIGNAL_DROP_REASONS` or :data:`IMU_DROP_REASONS`).
        """
        if accel_mark == NOT_PROVIDED or gyro_mark == NOT_PROVIDED or self._apart:
            streams = self._carried(accel_mark != NOT_PROVIDED, gyro_mark != NOT_PROVIDED)
            if not streams:
                self.dropped[NO_SENSOR] += 1
                return NO_SENSOR
        else:
            self.received += 1
            streams = self._streams
        stamp_ns = sec * NANOSECONDS + nanosec
        live = 0
        for stream in streams:
            stamps = stream.stamps
            last = stamps.last_ns
            if last is not None and 0 < stamp_ns - last <= STAMP_JUMP_NS:
                # _StampRule.problem's usual case inline (a step forward within 10 s): the per-message cost
                stamps.step_ns, stamps.before_ns = stamp_ns - last, last
                stamps.last_ns = stamps.kept_ns = stamp_ns
            else:
                reason = stamps.problem(stamp_ns)
                if reason is not None:
                    self._report_stamp_order(reason, stamp_ns, last, stamps, now_s, stream.sensor)
                    stream.reason = reason
                    continue
            stream.reason = reason = self._problem(*values[stream.span])
            if reason is None:
                live += 1
        if not live:
            return self._drop(streams)
        temperature = self._temperature
        if temperature is None or now_s - self._temp_arrival_s > self._timeout_s or not self._needs_temperature:
            temperature = self._temperature_now(now_s)  # none yet, stale, or not read
            if temperature.__class__ is str:
                return temperature
        aux = None
        if self._signals:
            for stream in streams:
                if stream.reason is None and stream.signals:
                    stream.reason = reason = self._signal_problem(now_s, stream.signals)
                    if reason is not None:
                        live -= 1
            if not live:
                return self._drop(streams)
            aux = self._signal_values
        if self._temp_outside:
            self._count_out_of_range(now_s)
        # The stamp in seconds exactly as the offline path computes it (seconds_from_ns).
        stamp_s = seconds(sec, nanosec)
        output = failures = None
        for stream in streams:
            if stream.reason is not None:
                continue
            try:
                result = stream.correct(values[stream.span], temperature, stamp_s=stamp_s, aux=aux)
            except Exception as err:  # a user effect may raise anything: the sample is left out, never the node
                stream.reason = CORRECTION_FAILED
                failures = [*(failures or ()), (stream, f'{type(err).__name__}: {err}')]
                continue
            for value in result:
                if not -math.inf < value < math.inf:
                    stream.reason = NON_FINITE_OUTPUT
                    failures = [*(failures or ()), (stream, f'output {result}')]
                    break
            else:  # both sensors of a message, apart: in the order of the values
                output = result if output is None else output + result
        if output is None:
            reason = self._drop(streams)
            self._report_failures(failures, now_s)
            return reason
        if failures:
            self._report_failures(failures, now_s)
        self.published += 1
        if len(output) == self._channels:  # every value of the message
            finder = self._watch_finder
            if finder is not None:  # the calibration watch: RestFinder.take inline (the per-message cost)
                if not finder.start_ns <= stamp_ns < finder.end_ns:
                    finder.next_window(stamp_ns, temperature)
                finder.append(output)
                adjustment = self._adjustment
                if adjustment is not None:  # the run's turn-on offset, or what the watch learned: adjust()
                    at = self._adjusted_at
                    if at is None or at[0] != temperature:  # recomputed when the temperature changes only
                        at = self._adjusted_at = (temperature, adjustment_at(temperature, adjustment,
                                                                             self.watch.reference))  # type: ignore
                    output = tuple(map(sub, output, at[1]))
            return output
        for stream in streams:  # one sensor's values: a carried sensor left out, or the only one carried
            if stream.reason is None:
                survivor = stream.sensor
            else:
                key = f'{stream.sensor}.{stream.reason}'
                self.sensor_dropped[key] = self.sensor_dropped.get(key, 0) + 1
        return OneSensor(survivor, output)

    def _carried(self, accel: bool, gyro: bool) -> tuple[_Stream, ...]:
        """The streams of a driver message carrying the sensors its marks say (each sensor's own, apart).

        The first message that marks a sensor absent sets each sensor apart; counts the message.
        """
        if not self._sensors_apart:
            msg = f'{self._message_word} messages carry no sensor marks (a driver Imu only)'
            raise ValueError(msg)
        self.received += 1
        if not self._apart:
            self._start_own_stamps((accel, gyro))
        if not (accel and gyro):
            self.one_sensor_messages += 1
        return self._carried_streams[accel, gyro]

    def _install_streams(self) -> None:
        """Each stream's correction and recorded signals from the configuration in force."""
        corrector = self._config.corrector
        if self._apart:
            for stream, sensor_corrector in zip(self._streams, corrector.correctors):
                stream.correct = sensor_corrector.correct_values
                stream.signals = sensor_corrector.signals
        else:
            stream, = self._streams
            stream.correct = corrector.correct_sample
            stream.signals = corrector.signals

    def _start_own_stamps(self, carried: tuple[bool, bool]) -> None:
        """The first message that marks a sensor absent: from it on each sensor is a stream of its own."""
        self._apart = True
        if self.watch is not None:
            self._stop_watch()
            self.watch_off = (f'off from {self._message_word} message {self.received} on: the sensors come at their '
                              f'own stamps (the watch takes messages that carry both)')
        self.own_stamps_since = self.received
        # Every message so far carried both sensors: each sensor's stamps were the message's.
        stamps = self._streams[0].stamps
        accel, gyro = (_Stream(sensor, slice(3 * index, 3 * index + 3), stamps.copy())
                       for index, sensor in enumerate(SENSORS))
        self._streams = (accel, gyro)
        self._carried_streams = {(True, True): (accel, gyro), (True, False): (accel,), (False, True): (gyro,),
                                 (False, False): ()}
        self._install_streams()
        absent = ' and the '.join(SENSOR_NAMES[sensor] for sensor, there in zip(SENSORS, carried) if not there)
        self._notice(Level.OK, 'own_stamps',
                     f'{self._message_word} message {self.received} marks the {absent} absent (covariance[0] = -1): '
                     f'from it on each sensor is corrected on its own samples and stamps, an absent one '
                     f'published marked')

    def _drop(self, streams: tuple[_Stream, ...]) -> str:
        """Drop a message none of whose streams survived, for the first one's reason."""
        reason = streams[0].reason
        self.dropped[reason] += 1
        return reason

    def _report_failures(self, failures: list[tuple[_Stream, str]], now_s: float) -> None:
        """The log lines of the streams whose correction failed (once the message is counted)."""
        for stream, detail in failures:
            self._report_failed(stream.reason, detail, now_s, stream.sensor)

    def message_lost(self, stream: str, count: int, now_s: float) -> None:
        """Count ``count`` messages of input ``stream`` that the middleware reports lost in transport."""
        if count <= 0:
            return
        self.lost[stream] = self.lost.get(stream, 0) + count
        if self._throttles['message_lost'].due(now_s, count):
            held = self._throttles['message_lost'].take_held_back()
            self._notice(Level.WARN, 'message_lost',
                         f'{count} {stream} messages lost in transport ({self.lost_total()} so far'
                         f'{self._since(held)})')

    def sequence(self, stream: str, number: int, now_s: float) -> None:
        """Take the publication sequence number of a message of input ``stream`` as it arrives.

        A number more than one above the previous one counts the messages in between as never
        received (``sequence_gap``); a number not above it (another publisher, or one that
        restarted) starts afresh. Meant for one publisher per topic (a driver).
        """
        if self.sequence_gaps is None:
            self.sequence_gaps = {}
        last = self._last_sequence.get(stream)
        self._last_sequence[stream] = number
        if last is None or number <= last + 1:
            return
        gap = number - last - 1
        self.sequence_gaps[stream] = self.sequence_gaps.get(stream, 0) + gap
        if self._throttles['sequence_gap'].due(now_s, gap):
            held = self._throttles['sequence_gap'].take_held_back()
            self._notice(Level.WARN, 'sequence_gap',
                         f'{gap} {stream} messages never received (publication sequence numbers '
                         f'{last + 1}..{number - 1}; {self.sequence_gap_total()} so far{self._since(held)})')

    def sequence_gap_total(self) -> int:
        """Messages never received according to the sequence numbers, every input stream (0 without them)."""
        return sum(self.sequence_gaps.values()) if self.sequence_gaps else 0

    def lost_total(self) -> int:
        """Messages lost in transport, every input stream."""
        return sum(self.lost.values())

    def _report_stamp_order(self, reason: str, stamp_ns: int, last_ns: int, rule: _StampRule, now_s: float,
                            sensor: str = '') -> None:
        """The throttled log line of a message (or, ``sensor``, one sensor's sample) left out for its stamp."""
        if not self._throttles['stamp_order'].due(now_s):
            return
        held = self._throttles['stamp_order'].take_held_back()
        relation = ('equal to' if reason == DUPLICATE_STAMP
                    else f'{abs(stamp_ns - last_ns) * 1e-9:.6f} s '
                         f'{"before" if reason == TIME_BACKWARDS else f"(> {STAMP_JUMP_S:g} s) after"}')
        what, previous = ((f"{self._message_word} {SENSOR_NAMES[sensor]} sample's", "the previous one's")
                          if sensor else (self._message_word, 'the previous one'))
        counts = rule.dropped
        self._notice(Level.WARN, 'stamp_order',
                     f'{what} header stamp {relation} {previous}: dropped ({counts[DUPLICATE_STAMP]} duplicate, '
                     f'{counts[TIME_BACKWARDS]} backwards, {counts[STAMP_JUMP]} jumped ahead so far'
                     f'{self._since(held)})')

    def _report_failed(self, reason: str, detail: str, now_s: float, sensor: str = '') -> str:
        """The throttled log line of a message (or, ``sensor``, one sensor's sample) whose correction failed."""
        if self._throttles['correction'].due(now_s):
            held = self._throttles['correction'].take_held_back()
            what, so_far = ((f'{self._message_word} {SENSOR_NAMES[sensor]} sample left out', '') if sensor else
                            (f'{self._message_word} message dropped',
                             f'; {self.dropped[CORRECTION_FAILED] + self.dropped[NON_FINITE_OUTPUT]} so far'))
            self._notice(Level.ERROR, reason,
                         f'{what}, the correction gave no finite number at {self._temperature_word} '
                         f'{self._temperature_text()} ({reason}: {detail}{so_far}{self._since(held)})')
        return reason

    # -- reports ----------------------------------------------------------------------------

    def take_notices(self) -> list[Notice]:
        """The log lines due, oldest first; the list is emptied."""
        notices, self.notices = self.notices, []
        return notices

    def _notice(self, level: Level, kind: str, text: str) -> None:
        self.notices.append(Notice(level, kind, text))

    def _temperature_text(self) -> str:
        """The last temperature for a message, ``none`` before the first."""
        return 'none' if self._temperature is None else f'{self._temperature:g}'

    @staticmethod
    def _since(held_back: int) -> str:
        return f'; {held_back} more since the last report' if held_back else ''

    def _report_waiting(self) -> None:
        held = self._throttles[WAITING_FOR_TEMPERATURE].take_held_back()
        self._notice(Level.WARN, WAITING_FOR_TEMPERATURE,
                     f'waiting for {self._temperature_word} on {self.temp_topic}: publishing nothing '
                     f'({self.dropped[WAITING_FOR_TEMPERATURE]} {self._message_word} messages dropped so far'
                     f'{self._since(held)})')

    def _report_stale(self, now_s: float, count: int = 1) -> None:
        if not self._throttles[STALE_TEMPERATURE].due(now_s, count):
            return
        self._throttles[STALE_TEMPERATURE].take_held_back()
        self._stale_reported = True
        action = (f'dropping {self._message_word} messages' if self._drop_stale
                  else f'holding the last {"code" if self.input_kind is InputKind.COUNTS else "temperature"} '
                       f'{self._temperature:g}')
        self._notice(Level.ERROR, STALE_TEMPERATURE,
                     f'{self._temperature_word} on {self.temp_topic} is stale: '
                     f'{now_s - self._temp_arrival_s:.2f} s old > temp_timeout {self._timeout_s:g} s; '
                     f'{action} ({self.dropped[STALE_TEMPERATURE]} dropped so far)')

    def _report_out_of_range(self) -> None:
        held = self._throttles['out_of_range'].take_held_back()
        action = ('clamped to the range edge' if self.out_of_range_policy is OutOfRange.CLAMP
                  else 'extrapolating the polynomials')
        self._notice(Level.WARN, 'out_of_range',
                     f'{self._temperature_word} {self._temperature:g} outside the calibrated range '
                     f'{self._low:g}..{self._high:g}: {action} ({self.out_of_range} samples so far'
                     f'{self._since(held)})')

    def temperature_age_s(self, now_s: float) -> float:
        """Seconds since the last temperature arrived (``inf`` before the first)."""
        return now_s - self._temp_arrival_s

    def is_stale(self, now_s: float) -> bool:
        """Whether the last temperature is older than ``temp_timeout``.

        ``False`` before the first, and when the calibration reads none.
        """
        return (self._needs_temperature and self._temperature is not None
                and now_s - self._temp_arrival_s > self._timeout_s)

    def tick(self, now_s: float) -> None:
        """Periodic checks that need no message (the node calls it with its diagnostics).

        A tick is not a message: it holds nothing back (the reports count messages).
        """
        if self.waiting_for_temperature:
            if self._throttles[WAITING_FOR_TEMPERATURE].due(now_s, 0):
                self._report_waiting()
        elif self.is_stale(now_s):
            self._report_stale(now_s, 0)
        self.judge_watch()

    def judge_watch(self, *, finish: bool = False) -> None:
        """Judge the rests the watch found since the last call, outside the message path (the node's timer).

        :param finish: the stream ended (shutdown, end of a record): a rest in progress ends first.
        """
        watch = self.watch
        if watch is None:
            return
        if finish:
            watch.finish()
        elif watch.pending:
            watch.judge()
        for line in watch.notices:
            warn = line.startswith(('calibration stale', ANOTHER_CALIBRATION))
            self._notice(Level.WARN if warn else Level.OK, 'calibration_watch', line)
        watch.notices.clear()

    def watch_status(self) -> Status:
        """The calibration watch's diagnostics: WARN with "calibration stale: ..." once a test fired, else OK."""
        watch = self.watch
        if watch is None:
            return Status(Level.OK, f'calibration watch {self.watch_off}', (('calibration_watch', self.watch_off),))
        level = Level.WARN if watch.stale else Level.OK
        return Status(level, watch.verdict(), (('calibration_watch', 'on'), *watch.values()))

    def _sensor_values(self) -> list[tuple[str, str]]:
        """The status values of a driver's messages that carry one sensor (:meth:`status`)."""
        return [('sensor_stamps', 'shared' if self.own_stamps_since is None
                 else f'own (each sensor apart from message {self.own_stamps_since} on)'),
                ('one_sensor_messages', str(self.one_sensor_messages)),
                ('sensor_dropped', str(sum(self.sensor_dropped.values()))),
                *((f'sensor_dropped.{key}', str(count)) for key, count in sorted(self.sensor_dropped.items()))]

    def dropped_total(self) -> int:
        """Input messages dropped, all reasons."""
        return sum(self.dropped.values())

    def status(self, now_s: float, *, imu_subscribers: int | None = None) -> Status:
        """The diagnostics status now; its level covers what happened since the previous call.

        :param imu_subscribers: how many subscriptions the output is matched with, if known
            (reported only: running without one is legitimate).
        """
        counters = {'received': self.received, 'published': self.published,
                    'out_of_range': self.out_of_range, 'temperature_rejected': self.temperature_rejected,
                    'message_lost': self.lost_total(), 'sequence_gap': self.sequence_gap_total(),
                    **{f'dropped.{reason}': count for reason, count in self.dropped.items()},
                    **{f'sensor_dropped.{key}': count for key, count in self.sensor_dropped.items()}}
        new = {key: count - self._previous.get(key, 0) for key, count in counters.items()}
        self._previous = counters
        level = Level.OK
        problems: list[str] = []

        def worse(at_least: Level, text: str) -> None:
            nonlocal level
            level = max(level, at_least)
            problems.append(text)

        word, what = self._message_word, self._temperature_word
        if self.waiting_for_temperature:
            worse(Level.WARN, f'waiting for {what} on {self.temp_topic}')
        elif self.is_stale(now_s):
            action = (f'dropping {word} messages' if self._drop_stale
                      else f'holding the last {"code" if self.input_kind is InputKind.COUNTS else "temperature"}')
            worse(Level.ERROR, f'{what} stale ({self.temperature_age_s(now_s):.1f} s > '
                               f'{self._timeout_s:g} s), {action}')
        for name in self._signals:
            if name not in self._signal_values:
                worse(Level.WARN, f'waiting for {name}')
            elif now_s - self._signal_arrival_s[name] > self._timeout_s:
                action = f'dropping {word} messages' if self._drop_stale else 'holding the last value'
                worse(Level.ERROR, f'{name} stale ({now_s - self._signal_arrival_s[name]:.1f} s > '
                                   f'{self._timeout_s:g} s), {action}')
        if self.received == 0:
            worse(Level.WARN, f'no {word} messages yet')
        if new['out_of_range']:
            worse(Level.WARN, f'{new["out_of_range"]} samples outside the calibrated {what} '
                              f'range ({self.out_of_range_policy.value})')
        dropped_now = {reason: new[f'dropped.{reason}'] for reason in self.dropped
                       if new[f'dropped.{reason}']}
        if dropped_now:
            failed = dropped_now.keys() & {CORRECTION_FAILED, NON_FINITE_OUTPUT}
            worse(Level.ERROR if failed else Level.WARN,
                  'dropped ' + ', '.join(f'{n} {reason}' for reason, n in dropped_now.items()))
        left_out = {key: new[f'sensor_dropped.{key}'] for key in self.sensor_dropped if new[f'sensor_dropped.{key}']}
        if left_out:
            failed = any(key.endswith((f'.{CORRECTION_FAILED}', f'.{NON_FINITE_OUTPUT}')) for key in left_out)
            worse(Level.ERROR if failed else Level.WARN, 'left out of published messages: ' + ', '.join(
                f'{n} {key.replace(".", " ")}' for key, n in left_out.items()))
        if new['message_lost']:
            worse(Level.WARN, f'{new["message_lost"]} messages lost in transport')
        if new['sequence_gap']:
            worse(Level.WARN, f'{new["sequence_gap"]} messages never received (sequence gaps)')
        if new['temperature_rejected']:
            worse(Level.WARN, f'{new["temperature_rejected"]} implausible or non-finite {what}s ignored')
        message = '; '.join(problems) if problems else 'correcting'
        age = self.temperature_age_s(now_s)
        counts = self.input_kind is InputKind.COUNTS
        stem = 'temperature_code' if counts else 'temperature'
        reference = self.calibration.temp_code_ref
        values: list[tuple[str, str]] = [
            ('input', self.input_kind.value),
            ('received', str(self.received)),
            ('published', str(self.published)),
            ('dropped', str(self.dropped_total())),
            *((f'dropped.{reason}', str(count)) for reason, count in self.dropped.items()),
            *(self._sensor_values() if self._sensors_apart else ()),
            ('message_lost', str(self.lost_total())),
            *((f'message_lost.{stream}', str(count)) for stream, count in sorted(self.lost.items())),
            ('sequence_gap', 'unavailable' if self.sequence_gaps is None else str(self.sequence_gap_total())),
            *((f'sequence_gap.{stream}', str(count)) for stream, count in sorted((self.sequence_gaps or {}).items())),
            ('out_of_range', str(self.out_of_range)),
            (stem, 'none' if self._temperature is None else f'{self._temperature:g}'),
            (f'{stem}_age_s', 'inf' if math.isinf(age) else f'{age:.3f}'),
            ('temperature_messages', str(self.temperature_messages)),
            ('temperature_rejected', str(self.temperature_rejected)),
            ('calibrated_range', f'{self._low:g}..{self._high:g}' if self._needs_temperature
             else 'any (no temperature terms: the temperature is not read)'),
            ('temp_code_ref' if counts else 'temperature_ref', f'{reference:g}'),
            ('out_of_range_policy', self.out_of_range_policy.value),
            ('stale_temperature_policy', self.stale_policy.value),
            ('temp_timeout_s', f'{self._timeout_s:g}'),
            ('calibration_updates', str(self.calibration_updates)),
        ]
        for name in self._signals:
            held = self._signal_values.get(name)
            signal_age = now_s - self._signal_arrival_s[name] if name in self._signal_arrival_s else math.inf
            values += [(f'signal {name}', 'none' if held is None else f'{held:g}'),
                       (f'signal {name} age_s', 'inf' if math.isinf(signal_age) else f'{signal_age:.3f}'),
                       (f'signal {name} messages', str(self.signal_messages.get(name, 0))),
                       (f'signal {name} rejected', str(self.signal_rejected.get(name, 0)))]
        if imu_subscribers is not None:
            values.append(('imu_subscribers', str(imu_subscribers)))
        return Status(level=level, message=message, values=tuple(values))
