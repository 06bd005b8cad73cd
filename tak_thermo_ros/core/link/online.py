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

The correction is :meth:`~tak_thermo_ros.core.link.correction.UnitCorrector.correct_sample`,
bit-identical to the vectorised path.

The input rules (what each message must be, the drop reasons, the policies, a calibration tried
out before it is put in force, one sensor per message) are
:mod:`tak_thermo_ros.core.link.online_rules`'s; the configuration in force as read, the counters,
the log lines and the status :mod:`tak_thermo_ros.core.link.online_reports`'s (a base of
:class:`OnlineCompensator`).

The magnetometer (``channel='mag'``, a driver calibration holding ``mag``) is a second
instance on its own topic: three values in tesla corrected by
:class:`~tak_thermo_ros.core.magnetometer.channel.MagCorrector` (the thermal link, then the
iron), the same temperature, the same rules and the same counters.

The calibration watch (:mod:`tak_thermo_ros.core.link.watch`, ``watch=WatchSettings(...)``; the
node's default, off here) extends the pipeline once: every message published with all its
values goes to the watch (a comparison and an append), which finds the rests; :meth:`tick`
(the node's timer, outside the message path) judges them. With ``turn_on`` or learning, the
output loses the watch's adjustment (the run's turn-on offset, the learned curve). The watch
takes messages that carry both sensors: it is off from the first message that marks one absent.
"""

from __future__ import annotations

import math
from operator import sub
from typing import Callable

from tak_thermo_ros.core.link.correction import NOT_PROVIDED, OutOfRange
from tak_thermo_ros.core.link.learning import Adjustment, adjustment_at
from tak_thermo_ros.core.link.model import Calibration, InputKind, UnitCalibration
from tak_thermo_ros.core.link.online_reports import WARN_PERIOD_S, CompensatorReports, Level, Notice, _Throttle
from tak_thermo_ros.core.link.online_rules import (
    CHANNELS,
    CORRECTION_FAILED,
    IMU_DROP_REASONS,
    MAG_CHANNEL,
    MALFORMED,
    NO_SENSOR,
    NON_FINITE_OUTPUT,
    ONLINE_DROP_REASONS,
    RAW_DROP_REASONS,
    SENSORS,
    SIGNAL_DROP_REASONS,
    STALE_SIGNAL,
    STALE_TEMPERATURE,
    WAITING_FOR_SIGNAL,
    WAITING_FOR_TEMPERATURE,
    Configuration,
    OneSensor,
    StaleTemperature,
    _covariances,
    _StampRule,
    _Stream,
    as_unit,
    channel_corrector,
    channel_sensors,
    check_correction,
)
from tak_thermo_ros.core.link.rests import RestFinder
from tak_thermo_ros.core.link.watch import CalibrationWatch, WatchSettings, WatchUnavailable
from tak_thermo_ros.core.records.record import NANOSECONDS
from tak_thermo_ros.core.records.stamps import STAMP_JUMP_NS, seconds
from tak_thermo_ros.core.records.drops import counts_problem, temp_code_problem, values_problem
from tak_thermo_ros.core.values import SENSOR_NAMES
from tak_thermo_ros.errors import CalibrationError


class OnlineCompensator(CompensatorReports):
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
        self._adjustment: Adjustment | None = None
        self._adjusted_at: tuple[float, tuple[float, ...]] | None = None
        """``(T, a + b (T - T_ref))`` of the adjustment in force at the last temperature it was taken at."""
        self.install(self.prepare(calibration=unit, out_of_range=out_of_range,
                                  stale_temperature=stale_temperature, temp_timeout_s=temp_timeout_s))

    # -- configuration -------------------------------------------------------------------

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

    def _take_adjustment(self, adjustment: Adjustment | None) -> None:
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
