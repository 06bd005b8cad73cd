"""What an online compensator tells: its configuration in force, its counters, its log lines and its status.

:class:`CompensatorReports` is a base of :class:`~tak_thermo_ros.core.link.online.OnlineCompensator`:
the read-only views of the configuration in force, the messages lost in transport and the gaps in
the publishers' sequence numbers (counted apart from the messages received), the throttled log
lines (:class:`Notice`) and the diagnostics status (:class:`Status`), the calibration watch's
verdict among them. It judges no message itself.

Warnings are throttled but never silent: the first of a kind is reported at once, later ones
at most every ``warn_period_s`` with the number that occurred in between (:class:`_Throttle`).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from tak_thermo_ros.core.link.correction import OutOfRange, UnitCorrector
from tak_thermo_ros.core.link.model import Calibration, InputKind, UnitCalibration
from tak_thermo_ros.core.link.online_rules import (
    CORRECTION_FAILED,
    DUPLICATE_STAMP,
    NON_FINITE_OUTPUT,
    STALE_TEMPERATURE,
    STAMP_JUMP,
    TIME_BACKWARDS,
    WAITING_FOR_TEMPERATURE,
    Configuration,
    StaleTemperature,
    _StampRule,
    _Stream,
    channel_sensors,
)
from tak_thermo_ros.core.link.watch import ANOTHER_CALIBRATION, CalibrationWatch
from tak_thermo_ros.core.records.stamps import STAMP_JUMP_S
from tak_thermo_ros.core.values import SENSOR_NAMES

WARN_PERIOD_S = 5.0
"""Default least time between two reports of the same kind of problem."""


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


class CompensatorReports:
    """The configuration in force as read, the losses, the log lines and the status of a compensator (see the module).

    A base of :class:`~tak_thermo_ros.core.link.online.OnlineCompensator`; what it reads is the
    compensator's (set in its ``__init__``, :meth:`~tak_thermo_ros.core.link.online.OnlineCompensator.install`
    and the per-message path), annotated below.
    """

    channel: str
    input_kind: InputKind
    temp_topic: str
    watch: CalibrationWatch | None
    watch_off: str
    _config: Configuration
    _message_word: str
    _temperature_word: str
    _sensors_apart: bool
    received: int
    published: int
    dropped: dict[str, int]
    one_sensor_messages: int
    sensor_dropped: dict[str, int]
    own_stamps_since: int | None
    lost: dict[str, int]
    sequence_gaps: dict[str, int] | None
    _last_sequence: dict[str, int]
    out_of_range: int
    temperature_messages: int
    temperature_rejected: int
    calibration_updates: int
    notices: list[Notice]
    _throttles: dict[str, _Throttle]
    _signals: tuple[str, ...]
    _signal_values: dict[str, float]
    _signal_arrival_s: dict[str, float]
    signal_messages: dict[str, int]
    signal_rejected: dict[str, int]
    _temperature: float | None
    _temp_arrival_s: float
    _stale_reported: bool
    _previous: dict[str, int]
    _needs_temperature: bool
    _drop_stale: bool
    _timeout_s: float
    _low: float
    _high: float

    # -- the configuration in force ----------------------------------------------------------

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

    # -- losses and failures ----------------------------------------------------------------

    def _count_out_of_range(self, now_s: float) -> None:
        self.out_of_range += 1
        if self._throttles['out_of_range'].due(now_s):
            self._report_out_of_range()

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
