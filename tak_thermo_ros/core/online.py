"""Online correction, one message at a time: the ``compensator`` node's logic without ROS.

:class:`OnlineCompensator` holds a :class:`~tak_thermo_ros.core.correction.Corrector`, the last
temperature code and when it arrived, the policies for bad input, and a counter for every
outcome, so that every counts message received is either published or dropped with a reason::

    received == published + sum(dropped.values())

It imports nothing from ROS (like imu_tools' ``imu_filter.h``): the node converts messages to
plain numbers, calls :meth:`OnlineCompensator.process_counts` and converts the result back.
The same drop rules as ``tak_calib apply`` hold (:func:`~tak_thermo_ros.core.record.counts_problem`),
and the correction is :meth:`Corrector.correct_sample`, bit-identical to the vectorised path.

Bad input, each with a defined outcome:

- counts NaN / infinite / not whole / at a 16-bit rail: dropped (``non_finite``,
  ``non_integer``, ``saturated``), never corrected;
- no temperature code yet: dropped (``waiting_for_temperature``) and a throttled warning;
- temperature code older than ``temp_timeout`` (on the arrival clock): held (``hold``) or the
  counts dropped (``drop``: ``stale_temperature``); diagnostics at ERROR either way;
- temperature code outside the calibrated range: clamped or extrapolated (the Corrector's
  policy), counted, and a throttled warning naming the code and the range;
- a stamp earlier than, or equal to, the previous counts stamp: passed through and counted;
- a non-finite temperature code: ignored (the last good code stays) and counted.
- a calibration with a recorded-signal term (``aux:TOPIC``): that signal follows the
  temperature's rules: held at its last value; none yet: dropped (``waiting_for_signal``);
  older than ``temp_timeout``: held or dropped (``stale_signal``) by the same policy; a
  non-finite value ignored and counted.

Warnings are throttled but never silent: the first of a kind is reported at once, later ones
at most every ``warn_period_s`` with the number that occurred in between.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Callable

from tak_thermo_ros.core.correction import Corrector, OutOfRange, acceleration_variance
from tak_thermo_ros.core.model import Calibration
from tak_thermo_ros.core.record import DROP_REASONS, NANOSECONDS, counts_problem, seconds

WAITING_FOR_TEMPERATURE = 'waiting_for_temperature'
STALE_TEMPERATURE = 'stale_temperature'
ONLINE_DROP_REASONS: tuple[str, ...] = (*DROP_REASONS, WAITING_FOR_TEMPERATURE, STALE_TEMPERATURE)
"""Why a counts message is not published, in the order the checks run."""
WAITING_FOR_SIGNAL = 'waiting_for_signal'
STALE_SIGNAL = 'stale_signal'
SIGNAL_DROP_REASONS: tuple[str, ...] = (WAITING_FOR_SIGNAL, STALE_SIGNAL)
"""Why a counts message is not published when the calibration needs a recorded signal (checked last)."""

WARN_PERIOD_S = 5.0
"""Default least time between two reports of the same kind of problem."""


class StaleTemperature(str, enum.Enum):
    """What to do with counts while the last temperature code is older than ``temp_timeout``."""

    HOLD = 'hold'
    """Correct with the last code (the board temperature changes over minutes)."""
    DROP = 'drop'
    """Publish nothing until a fresh code arrives."""


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
    """First report at once, then at most one per period, counting what was held back."""

    __slots__ = ('period_s', 'next_s', 'held_back')

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.next_s = -math.inf
        self.held_back = 0

    def due(self, now_s: float) -> bool:
        if now_s >= self.next_s:
            self.next_s = now_s + self.period_s
            return True
        self.held_back += 1
        return False

    def take_held_back(self) -> int:
        held, self.held_back = self.held_back, 0
        return held


class OnlineCompensator:
    """Correct counts messages one by one, with defined behaviour on every bad input.

    Times ``now_s`` are seconds on a monotonic clock of the caller's choice (the node uses the
    arrival time); stamps are the messages' header stamps (``sec``, ``nanosec``).

    :param calibration: the correction link in force.
    :param out_of_range: temperature codes outside the calibrated range: clamp or extrapolate.
    :param stale_temperature: counts while the temperature code is stale: hold or drop.
    :param temp_timeout_s: age beyond which the last temperature code is stale, > 0.
    :param temp_topic: name of the temperature-code stream, used in messages.
    :param warn_period_s: least time between two reports of the same kind.
    """

    def __init__(self, calibration: Calibration, *, out_of_range: OutOfRange = OutOfRange.CLAMP,
                 stale_temperature: StaleTemperature = StaleTemperature.HOLD,
                 temp_timeout_s: float = 1.0, temp_topic: str = 'tak/temp_code',
                 warn_period_s: float = WARN_PERIOD_S) -> None:
        self.temp_topic = temp_topic
        self.warn_period_s = warn_period_s
        self.received = 0
        self.published = 0
        self.dropped: dict[str, int] = dict.fromkeys((*ONLINE_DROP_REASONS, *SIGNAL_DROP_REASONS), 0)
        self.time_backwards = 0
        self.duplicate_stamps = 0
        self.out_of_range = 0
        self.temperature_messages = 0
        self.temperature_rejected = 0
        self.calibration_updates = 0
        self.notices: list[Notice] = []
        """Log lines due; the caller empties it (:meth:`take_notices`)."""
        self._throttles = {kind: _Throttle(warn_period_s) for kind in (
            WAITING_FOR_TEMPERATURE, STALE_TEMPERATURE, 'out_of_range', 'temperature_rejected',
            WAITING_FOR_SIGNAL, STALE_SIGNAL, 'signal_rejected')}
        self._signal_values: dict[str, float] = {}
        self._signal_arrival_s: dict[str, float] = {}
        self.signal_messages: dict[str, int] = {}
        self.signal_rejected: dict[str, int] = {}
        self._last_stamp_ns: int | None = None
        self._temp_code: float | None = None
        self._temp_arrival_s = -math.inf
        self._temp_outside = False
        self._stale_reported = False
        self._previous: dict[str, int] = {}
        self.set_policies(out_of_range=out_of_range, stale_temperature=stale_temperature,
                          temp_timeout_s=temp_timeout_s, calibration=calibration)

    # -- configuration -------------------------------------------------------------------

    @property
    def calibration(self) -> Calibration:
        """The calibration in force."""
        return self._corrector.calibration

    @property
    def corrector(self) -> Corrector:
        """The corrector in force."""
        return self._corrector

    @property
    def out_of_range_policy(self) -> OutOfRange:
        """The policy for temperature codes outside the calibrated range."""
        return self._corrector.out_of_range

    @property
    def stale_policy(self) -> StaleTemperature:
        """The policy for counts while the temperature code is stale."""
        return self._stale_policy

    @property
    def temp_timeout_s(self) -> float:
        """Age beyond which the last temperature code is stale."""
        return self._timeout_s

    @property
    def temp_code(self) -> float | None:
        """The last temperature code accepted, or ``None`` before the first."""
        return self._temp_code

    @property
    def waiting_for_temperature(self) -> bool:
        """Whether no temperature code has arrived yet (nothing is published meanwhile)."""
        return self._temp_code is None

    @property
    def variance(self) -> tuple[float, float, float]:
        """Per-axis variance of the corrected specific force for the Imu covariance, (m/s^2)^2."""
        return self._variance

    def set_policies(self, *, out_of_range: OutOfRange | None = None,
                     stale_temperature: StaleTemperature | None = None,
                     temp_timeout_s: float | None = None,
                     calibration: Calibration | None = None) -> None:
        """Change any of the policies (and the calibration) in one step, between two messages.

        :raises ValueError: on an unknown policy or a timeout that is not a positive number.
        """
        current = getattr(self, '_corrector', None)
        new_out_of_range = OutOfRange(out_of_range if out_of_range is not None else current.out_of_range)
        new_stale = StaleTemperature(stale_temperature if stale_temperature is not None
                                     else self._stale_policy)
        new_timeout = float(temp_timeout_s if temp_timeout_s is not None else self._timeout_s)
        if not (new_timeout > 0.0 and math.isfinite(new_timeout)):
            msg = f'temp_timeout: must be a finite number > 0, got {new_timeout}'
            raise ValueError(msg)
        new_calibration = calibration if calibration is not None else current.calibration
        corrector = (current if current is not None and new_calibration is current.calibration
                     and new_out_of_range is current.out_of_range
                     else Corrector(new_calibration, out_of_range=new_out_of_range))
        # Everything is built first; the assignments below cannot fail.
        self._stale_policy = new_stale
        self._timeout_s = new_timeout
        self._drop_stale = new_stale is StaleTemperature.DROP
        self._corrector = corrector
        self._correct: Callable[..., tuple[float, float, float]] = corrector.correct_sample
        self._signals = corrector.signals
        for name in self._signals:
            self.signal_messages.setdefault(name, 0)
            self.signal_rejected.setdefault(name, 0)
        self._variance = acceleration_variance(new_calibration)
        self._low = float(new_calibration.temp_code_min)
        self._high = float(new_calibration.temp_code_max)
        if self._temp_code is not None:
            self._temp_outside = not self._low <= self._temp_code <= self._high

    def swap_calibration(self, calibration: Calibration) -> None:
        """Put a new (validated) calibration in force; the next message uses it."""
        self.set_policies(calibration=calibration)
        self.calibration_updates += 1

    # -- the per-message path --------------------------------------------------------------

    def process_temperature(self, temp_code: float, now_s: float) -> bool:
        """Take a temperature code that arrived at ``now_s``; ``False`` if it was rejected."""
        self.temperature_messages += 1
        if temp_code != temp_code or temp_code in (math.inf, -math.inf):
            self.temperature_rejected += 1
            if self._throttles['temperature_rejected'].due(now_s):
                self._notice(Level.WARN, 'temperature_rejected',
                             f'non-finite temperature code {temp_code} on {self.temp_topic} ignored; '
                             f'keeping the last code ({self.temperature_rejected} so far)')
            return False
        self._temp_code = temp_code
        self._temp_arrival_s = now_s
        self._temp_outside = not self._low <= temp_code <= self._high
        if self._stale_reported:
            self._stale_reported = False
            self._notice(Level.OK, STALE_TEMPERATURE,
                         f'temperature code on {self.temp_topic} fresh again ({temp_code:g})')
        return True

    @property
    def signals(self) -> tuple[str, ...]:
        """Names ``aux:TOPIC[:FIELD]`` of the recorded signals the calibration in force needs."""
        return self._signals

    def process_signal(self, name: str, value: float, now_s: float) -> bool:
        """Take a value of recorded signal ``name`` that arrived at ``now_s``; ``False`` if rejected
        (non-finite: the last good value stays, as for the temperature)."""
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

    def _signal_problem(self, now_s: float) -> str | None:
        """Why the counts cannot be corrected for want of a recorded signal, or ``None``."""
        for name in self._signals:
            if name not in self._signal_values:
                if self._throttles[WAITING_FOR_SIGNAL].due(now_s):
                    self._notice(Level.WARN, WAITING_FOR_SIGNAL, f'waiting for {name}: publishing nothing '
                                 f'({self.dropped[WAITING_FOR_SIGNAL] + 1} counts messages dropped so far)')
                return WAITING_FOR_SIGNAL
            age = now_s - self._signal_arrival_s[name]
            if age > self._timeout_s:
                if self._throttles[STALE_SIGNAL].due(now_s):
                    action = 'dropping counts' if self._drop_stale else 'holding the last value'
                    self._notice(Level.ERROR, STALE_SIGNAL, f'{name} is stale: {age:.2f} s old > temp_timeout '
                                 f'{self._timeout_s:g} s; {action}')
                if self._drop_stale:
                    return STALE_SIGNAL
        return None

    def process_counts(self, sec: int, nanosec: int, x: float, y: float, z: float,
                       now_s: float) -> tuple[float, float, float] | str:
        """Correct one counts message, or tell why it is dropped.

        :param sec: header stamp, whole seconds (``builtin_interfaces/Time.sec``).
        :param nanosec: header stamp, nanoseconds part.
        :param x: channel code of axis x (y, z alike).
        :param now_s: arrival time on the caller's monotonic clock, seconds.
        :returns: the specific force ``(fx, fy, fz)`` in m/s^2 as plain floats, or the drop
            reason (a ``str`` of :data:`ONLINE_DROP_REASONS`).
        """
        self.received += 1
        stamp_ns = sec * NANOSECONDS + nanosec
        last = self._last_stamp_ns
        if last is not None and stamp_ns <= last:
            if stamp_ns == last:
                self.duplicate_stamps += 1
            else:
                self.time_backwards += 1
        self._last_stamp_ns = stamp_ns
        problem = counts_problem(x, y, z)
        if problem is not None:
            self.dropped[problem] += 1
            return problem
        temp_code = self._temp_code
        if temp_code is None:
            self.dropped[WAITING_FOR_TEMPERATURE] += 1
            if self._throttles[WAITING_FOR_TEMPERATURE].due(now_s):
                self._report_waiting()
            return WAITING_FOR_TEMPERATURE
        if now_s - self._temp_arrival_s > self._timeout_s:
            self._report_stale(now_s)
            if self._drop_stale:
                self.dropped[STALE_TEMPERATURE] += 1
                return STALE_TEMPERATURE
        aux = None
        if self._signals:
            signal_problem = self._signal_problem(now_s)
            if signal_problem is not None:
                self.dropped[signal_problem] += 1
                return signal_problem
            aux = self._signal_values
        if self._temp_outside:
            self.out_of_range += 1
            if self._throttles['out_of_range'].due(now_s):
                self._report_out_of_range()
        self.published += 1
        # The stamp in seconds exactly as the offline path computes it (seconds_from_ns).
        if aux is None:
            return self._correct(x, y, z, temp_code, stamp_s=seconds(sec, nanosec))
        return self._correct(x, y, z, temp_code, stamp_s=seconds(sec, nanosec), aux=aux)

    # -- reports ----------------------------------------------------------------------------

    def take_notices(self) -> list[Notice]:
        """The log lines due, oldest first; the list is emptied."""
        notices, self.notices = self.notices, []
        return notices

    def _notice(self, level: Level, kind: str, text: str) -> None:
        self.notices.append(Notice(level, kind, text))

    @staticmethod
    def _since(held_back: int) -> str:
        return f'; {held_back} more since the last report' if held_back else ''

    def _report_waiting(self) -> None:
        held = self._throttles[WAITING_FOR_TEMPERATURE].take_held_back()
        self._notice(Level.WARN, WAITING_FOR_TEMPERATURE,
                     f'waiting for temperature code on {self.temp_topic}: publishing nothing '
                     f'({self.dropped[WAITING_FOR_TEMPERATURE]} counts messages dropped so far'
                     f'{self._since(held)})')

    def _report_stale(self, now_s: float) -> None:
        if not self._throttles[STALE_TEMPERATURE].due(now_s):
            return
        self._throttles[STALE_TEMPERATURE].take_held_back()
        self._stale_reported = True
        action = ('dropping counts' if self._drop_stale
                  else f'holding the last code {self._temp_code:g}')
        self._notice(Level.ERROR, STALE_TEMPERATURE,
                     f'temperature code on {self.temp_topic} is stale: '
                     f'{now_s - self._temp_arrival_s:.2f} s old > temp_timeout {self._timeout_s:g} s; '
                     f'{action} ({self.dropped[STALE_TEMPERATURE]} dropped so far)')

    def _report_out_of_range(self) -> None:
        held = self._throttles['out_of_range'].take_held_back()
        action = ('clamped to the range edge' if self.out_of_range_policy is OutOfRange.CLAMP
                  else 'extrapolating the polynomials')
        self._notice(Level.WARN, 'out_of_range',
                     f'temperature code {self._temp_code:g} outside the calibrated range '
                     f'{self._low:g}..{self._high:g}: {action} ({self.out_of_range} samples so far'
                     f'{self._since(held)})')

    def temperature_age_s(self, now_s: float) -> float:
        """Seconds since the last temperature code arrived (``inf`` before the first)."""
        return now_s - self._temp_arrival_s

    def is_stale(self, now_s: float) -> bool:
        """Whether the last temperature code is older than ``temp_timeout`` (or none came)."""
        return self._temp_code is not None and now_s - self._temp_arrival_s > self._timeout_s

    def tick(self, now_s: float) -> None:
        """Periodic checks that need no message (the node calls it with its diagnostics)."""
        if self._temp_code is None:
            if self._throttles[WAITING_FOR_TEMPERATURE].due(now_s):
                self._report_waiting()
        elif self.is_stale(now_s):
            self._report_stale(now_s)

    def dropped_total(self) -> int:
        """Counts messages dropped, all reasons."""
        return sum(self.dropped.values())

    def status(self, now_s: float, *, imu_subscribers: int | None = None) -> Status:
        """The diagnostics status now; its level covers what happened since the previous call.

        :param imu_subscribers: how many subscriptions the output is matched with, if known
            (reported only: running without one is legitimate).
        """
        counters = {'received': self.received, 'published': self.published,
                    'time_backwards': self.time_backwards, 'duplicate_stamps': self.duplicate_stamps,
                    'out_of_range': self.out_of_range, 'temperature_rejected': self.temperature_rejected,
                    **{f'dropped.{reason}': count for reason, count in self.dropped.items()}}
        new = {key: count - self._previous.get(key, 0) for key, count in counters.items()}
        self._previous = counters
        level = Level.OK
        problems: list[str] = []

        def worse(at_least: Level, text: str) -> None:
            nonlocal level
            level = max(level, at_least)
            problems.append(text)

        if self._temp_code is None:
            worse(Level.WARN, f'waiting for temperature code on {self.temp_topic}')
        elif self.is_stale(now_s):
            action = 'dropping counts' if self._drop_stale else 'holding the last code'
            worse(Level.ERROR, f'temperature code stale ({self.temperature_age_s(now_s):.1f} s > '
                               f'{self._timeout_s:g} s), {action}')
        for name in self._signals:
            if name not in self._signal_values:
                worse(Level.WARN, f'waiting for {name}')
            elif now_s - self._signal_arrival_s[name] > self._timeout_s:
                action = 'dropping counts' if self._drop_stale else 'holding the last value'
                worse(Level.ERROR, f'{name} stale ({now_s - self._signal_arrival_s[name]:.1f} s > '
                                   f'{self._timeout_s:g} s), {action}')
        if self.received == 0:
            worse(Level.WARN, 'no counts messages yet')
        if new['out_of_range']:
            worse(Level.WARN, f'{new["out_of_range"]} samples outside the calibrated temperature-code '
                              f'range ({self.out_of_range_policy.value})')
        dropped_now = {reason: new[f'dropped.{reason}'] for reason in self.dropped
                       if new[f'dropped.{reason}']}
        if dropped_now:
            worse(Level.WARN, 'dropped ' + ', '.join(f'{n} {reason}' for reason, n in dropped_now.items()))
        if new['time_backwards'] or new['duplicate_stamps']:
            worse(Level.WARN, f'{new["time_backwards"]} stamps going backwards, '
                              f'{new["duplicate_stamps"]} duplicate stamps (passed through)')
        if new['temperature_rejected']:
            worse(Level.WARN, f'{new["temperature_rejected"]} non-finite temperature codes ignored')
        message = '; '.join(problems) if problems else 'correcting'
        age = self.temperature_age_s(now_s)
        values: list[tuple[str, str]] = [
            ('received', str(self.received)),
            ('published', str(self.published)),
            ('dropped', str(self.dropped_total())),
            *((f'dropped.{reason}', str(count)) for reason, count in self.dropped.items()),
            ('time_backwards', str(self.time_backwards)),
            ('duplicate_stamps', str(self.duplicate_stamps)),
            ('out_of_range', str(self.out_of_range)),
            ('temperature_code', 'none' if self._temp_code is None else f'{self._temp_code:g}'),
            ('temperature_code_age_s', 'inf' if math.isinf(age) else f'{age:.3f}'),
            ('temperature_messages', str(self.temperature_messages)),
            ('temperature_rejected', str(self.temperature_rejected)),
            ('calibrated_range', f'{self._low:g}..{self._high:g}'),
            ('temp_code_ref', f'{self.calibration.temp_code_ref:g}'),
            ('out_of_range_policy', self.out_of_range_policy.value),
            ('stale_temperature_policy', self._stale_policy.value),
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
