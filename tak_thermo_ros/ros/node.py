"""The ``compensator`` node: online temperature-drift correction in a ROS 2 INS pipeline.

::

    ros2 run tak_thermo_ros compensator --ros-args --params-file tak_params.yaml

The calibration's input kind chooses the topics (relative names: namespaces and remapping work):

- a driver calibration (file version 2, ``input: imu``): subscribes ``imu/data_raw``
  (``sensor_msgs/msg/Imu``) and ``imu/temperature`` (``sensor_msgs/msg/Temperature``, degrees
  C); publishes ``imu/data_compensated`` (``sensor_msgs/msg/Imu``, accelerometer and gyroscope
  corrected, exactly as ``tak_calib apply`` writes it; a message that carries one sensor, the
  other's covariance[0] = -1, is published with that one corrected and the other still marked);
  with a magnetometer in the calibration (``mag``), also subscribes ``imu/mag``
  (``sensor_msgs/msg/MagneticField``, tesla) and publishes ``imu/mag_compensated`` (corrected for
  temperature and iron, covariance from the calibration, exactly as ``tak_calib apply``);
- a counts calibration (version 1, the paper's codes): subscribes ``tak/counts``
  (``geometry_msgs/msg/Vector3Stamped``, channel codes) and ``tak/temp_code``
  (``sensor_msgs/msg/Temperature``, the raw temperature-sensor code); publishes
  ``tak/imu/data_raw`` (``sensor_msgs/msg/Imu``).

Both publish ``/diagnostics`` at 1 Hz; a driver calibration with noise sections adds the
calibration watch's status (``<node>: calibration watch``: OK "calibration holds ...", WARN
"calibration stale: gyro x offset +812 deg/h ..."; docs/watch.md), judged in the same timer.

When the calibration holds a recorded-signal term (``aux:TOPIC``, e.g. the supply voltage on
``/power/battery_state``), the node also subscribes that topic, with the type its publisher
advertises (waiting up to :data:`SIGNAL_DISCOVERY_S` at start-up, then looked up again every
diagnostics period); the value is held like the temperature (:mod:`tak_thermo_ros.core.link.online`).

This is a thin wrapper: callbacks turn messages into numbers, hand them to
:class:`~tak_thermo_ros.core.link.online.OnlineCompensator` (no ROS in it) and turn the result
back into a message. By default (``message_path: raw``) the messages are their serialised bytes
(``raw=True`` subscriptions; :class:`~tak_thermo_ros.formats.cdr.FixedReader` reads the numbers at
fixed offsets, :class:`~tak_thermo_ros.formats.cdr.FixedWriter` writes the output, published as
bytes): no rclpy message object on the hot path. The only module of the package that imports
rclpy (with the player).
"""

from __future__ import annotations

import array
import inspect
import math
import os
import signal
import sys
import time
from dataclasses import replace
from typing import Any, Iterable, Sequence

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Vector3Stamped
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.event_handler import PublisherEventCallbacks, QoSMessageLostInfo, SubscriptionEventCallbacks
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import Imu, MagneticField, Temperature

from tak_thermo_ros.formats.cdr import FixedReader, FixedWriter, frame_id
from tak_thermo_ros.formats.calibration_file import (
    NODE_NAME,
    flatten_parameters,
    load_unit,
    nest_parameters,
    unit_from_mapping,
    unit_to_mapping,
)
from tak_thermo_ros.core.link.correction import NOT_PROVIDED_COVARIANCE, OutOfRange
from tak_thermo_ros.core.effects.aux_signal import AUX_FIELDS, signal_field, split_signal_name
from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.link.online import SENSORS, Level, OneSensor, OnlineCompensator, StaleTemperature
from tak_thermo_ros.core.link.watch import (
    DEG_PER_H,
    MG,
    LearnedState,
    WatchSettings,
    turn_on_unavailable,
    watch_unavailable,
)
from tak_thermo_ros.formats.files import not_regular
from tak_thermo_ros.formats.learned_file import LEARNED_KEY, load_learned, save_learned
from tak_thermo_ros.errors import CalibrationError, CdrError, TakError
from tak_thermo_ros.ros.signals import SignalGuard

COUNTS_TOPIC = 'tak/counts'
TEMP_TOPIC = 'tak/temp_code'
IMU_TOPIC = 'tak/imu/data_raw'
RAW_IMU_TOPIC = 'imu/data_raw'
TEMPERATURE_TOPIC = 'imu/temperature'
COMPENSATED_IMU_TOPIC = 'imu/data_compensated'
MAG_TOPIC = 'imu/mag'
COMPENSATED_MAG_TOPIC = 'imu/mag_compensated'
DIAGNOSTICS_TOPIC = '/diagnostics'
DIAGNOSTICS_PERIOD_S = 1.0
EXIT_ERROR = 2
QOS_CHOICES = ('sensor_data', 'reliable')
EXECUTOR_CHOICES = ('events', 'single_threaded')
MESSAGE_PATHS = ('raw', 'decoded')
"""``message_path``: the serialised bytes read and written by the package's CDR codec, or rclpy's messages."""
IMU_TYPE = 'sensor_msgs/msg/Imu'
MAG_TYPE = 'sensor_msgs/msg/MagneticField'
ZEROS = (0.0, 0.0, 0.0)
SPIN_PERIOD_S = 0.1
"""Longest wait of one ``spin_once``: how soon the loop notices a shutdown (SIGINT, SIGTERM)."""
CALIBRATION_PREFIX = 'calibration'
SIGNAL_DISCOVERY_S = 5.0
"""At start-up, how long the node waits for the publisher of a recorded signal it needs."""

_DIAGNOSTIC_LEVELS = {Level.OK: DiagnosticStatus.OK, Level.WARN: DiagnosticStatus.WARN,
                      Level.ERROR: DiagnosticStatus.ERROR}
_WITH_MESSAGE_INFO = inspect.Signature([inspect.Parameter(name, inspect.Parameter.POSITIONAL_ONLY)
                                        for name in ('message', 'info')])
"""A callback of this signature is handed the MessageInfo by rclpy (``Subscription.callback``)."""


def _diagnostic(level: Level, name: str, message: str, hardware_id: str,
                values: Iterable[tuple[str, str]]) -> DiagnosticStatus:
    """One ``DiagnosticStatus`` of the node's ``/diagnostics`` array."""
    return DiagnosticStatus(level=_DIAGNOSTIC_LEVELS[level], name=name, message=message, hardware_id=hardware_id,
                            values=[KeyValue(key=key, value=value) for key, value in values])


def _tunables() -> dict[str, tuple[Any, str, bool]]:
    """Name -> (default, description, read only) of the node's own parameters."""
    return {
        'calibration_file': ('', 'calibration parameters YAML to load instead of calibration.* '
                                 '(the file tak_calib fit writes); empty: use calibration.*', True),
        'qos': ('sensor_data', "input QoS: 'sensor_data' (best effort, REP 2003 consumer; matches "
                               "every publisher) or 'reliable' (retransmits, needs a reliable publisher; "
                               "a driver faster than the node still loses messages at the history depth)",
                True),
        'qos_depth': (1000, 'history depth of the subscriptions and the Imu publisher (1000: 250 ms of a 4 kHz '
                            'stream)', True),
        'executor': ('events', "'events' (rclpy.experimental.EventsExecutor, about half the CPU per "
                               "message) or 'single_threaded' (rclpy's default executor)", True),
        'message_path': ('raw', "'raw': the messages' serialised bytes, read and written at fixed offsets by the "
                                "package's CDR codec (no rclpy message objects: the least CPU per message); "
                                "'decoded': rclpy's message objects (for comparison)", True),
        'temp_timeout': (1.0, 'seconds after which the last temperature is stale '
                              '(diagnostics ERROR)', False),
        'stale_temperature': ('hold', "input while the temperature is stale: 'hold' the last "
                                      "temperature or 'drop' the messages", False),
        'out_of_range': ('clamp', "temperatures outside the calibrated range: 'clamp' to the "
                                  "edge or 'extrapolate' (always counted and logged)", False),
        'hardware_id': ('', "the unit's identifier (e.g. its serial number) in /diagnostics; empty: "
                            "the input's frame_id", True),
        'watch': (True, 'the calibration watch: rests found online, the calibration judged at each against the '
                        "file's noise model (/diagnostics '...: calibration watch'); needs the file's noise "
                        'sections', True),
        'latitude': ('', "degrees: the Earth rate's vertical part and gravity the watch expects at rest; "
                         "empty: unknown (counted as noise)", True),
        'turn_on': ('none', "'first_rest': take each run's turn-on offset at its first rest (judged against "
                            "the file's turn_on repeatability) and subtract it from then on, as tak_calib apply "
                            "--turn-on first-rest does; 'none': not", True),
        'learn': (False, 'learn the gyroscope curve at the rests (offset and slope per axis, bounded) and apply '
                         'it, writing learned_file; false returns to the calibration file at once', False),
        'learned_file': ('', 'where learning writes what it learned (a calibration file tak_calib reads), '
                             'read at the next start; never the calibration file itself', True),
        'gyro_turn_on_repeatability': ('', "deg/h (one value or x y z): the gyroscope's turn-on repeatability "
                                           "(a data sheet's bias repeatability) when the file holds none; empty: "
                                           "the first rest is unjudged, until learning has seen 5 runs", True),
        'accel_turn_on_repeatability': ('', "mg (one value or x y z): the accelerometer's, likewise", True),
    }


def _plain(value: Any) -> Any:
    """A parameter value as the calibration validator expects it (lists, not arrays)."""
    if isinstance(value, (array.array, tuple)) or hasattr(value, 'tolist'):
        return list(value)
    return value


def _choice(value: Any, name: str, choices: Sequence[str]) -> str:
    if value not in choices:
        msg = f'{name}: expected one of {", ".join(repr(c) for c in choices)}, got {value!r}'
        raise ValueError(msg)
    return value


def _timeout(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 < value < float('inf'):
        msg = f'temp_timeout: expected a number of seconds > 0, got {value!r}'
        raise ValueError(msg)
    return float(value)


def _depth(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        msg = f'qos_depth: expected an integer >= 1, got {value!r}'
        raise ValueError(msg)
    return value


def _flag(value: Any, name: str) -> bool:
    if not isinstance(value, bool):
        msg = f'{name}: expected true or false, got {value!r}'
        raise ValueError(msg)
    return value


def _path_value(value: Any, name: str, error: type[Exception] = ValueError) -> str:
    if not isinstance(value, str):
        msg = f'{name}: expected a path, got {value!r}'
        raise error(msg)
    return value


def _repeatability(value: Any, name: str, factor: float) -> tuple[float, float, float] | None:
    """A ``*_turn_on_repeatability`` parameter (one value or x y z, in ``1 / factor`` of SI) in SI, or ``None``."""
    if value == '' or value is None:
        return None
    items = list(value) if isinstance(value, (list, tuple)) or hasattr(value, 'tolist') else [value]
    if len(items) == 1:
        items = items * 3
    if len(items) != 3 or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
                              or v <= 0.0 for v in items):
        msg = f'{name}: expected one positive number or three (x y z), or empty; got {value!r}'
        raise ValueError(msg)
    return (items[0] / factor, items[1] / factor, items[2] / factor)


def _learning_start(learn: bool, path: str, unit: UnitCalibration) -> LearnedState | None:
    """What learning starts from: the learned file's state (a fresh one without the file), or ``None`` (false).

    Its corrections are judged against the bounds learning keeps on ``unit`` (:func:`load_learned`).
    """
    return (load_learned(path, unit) or LearnedState()) if learn else None


_UNCHANGED: Any = object()
"""A ``learn`` change not pending (:attr:`CompensatorNode._learn_pending`)."""


class CompensatorNode(Node):
    """The ``compensator`` node.

    :raises CalibrationError: when the calibration (file or ``calibration.*``) is invalid.
    :raises ValueError: when one of the node's own parameters is invalid.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, automatically_declare_parameters_from_overrides=True, **kwargs)
        try:
            self._setup()
        except BaseException:
            self.destroy_node()
            raise

    # -- start-up ---------------------------------------------------------------------------

    def _setup(self) -> None:
        self._declare_tunables()
        unit, source = self._load_calibration()
        depth = _depth(self._value('qos_depth'))
        qos_name = _choice(self._value('qos'), 'qos', QOS_CHOICES)
        self.executor_kind = _choice(self._value('executor'), 'executor', EXECUTOR_CHOICES)
        self.message_path = _choice(self._value('message_path'), 'message_path', MESSAGE_PATHS)
        raw = self.message_path == 'raw'  # the input, temperature and magnetometer taken and published as bytes
        reliability = (ReliabilityPolicy.BEST_EFFORT if qos_name == 'sensor_data'
                       else ReliabilityPolicy.RELIABLE)
        input_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability)
        # REP 2003: the Imu is published reliable, which matches reliable and best-effort readers.
        output_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                                reliability=ReliabilityPolicy.RELIABLE)
        driver = unit.input_kind is InputKind.IMU
        self._input_name = 'imu' if driver else 'counts'
        input_type, input_topic, temp_topic, output_topic = (
            (Imu, RAW_IMU_TOPIC, TEMPERATURE_TOPIC, COMPENSATED_IMU_TOPIC) if driver
            else (Vector3Stamped, COUNTS_TOPIC, TEMP_TOPIC, IMU_TOPIC))
        # The temperature subscription is created first: when a temperature and an input message
        # are ready at once, the executor takes them in creation order, the temperature first.
        self._temp_subscription = self.create_subscription(
            Temperature, temp_topic, self._on_raw_temperature if raw else self._on_temperature, input_qos,
            event_callbacks=SubscriptionEventCallbacks(message_lost=self._on_temperature_lost), raw=raw)
        policies = dict(
            out_of_range=OutOfRange(_choice(self._value('out_of_range'), 'out_of_range',
                                            [p.value for p in OutOfRange])),
            stale_temperature=StaleTemperature(_choice(self._value('stale_temperature'), 'stale_temperature',
                                                       [p.value for p in StaleTemperature])),
            temp_timeout_s=_timeout(self._value('temp_timeout')),
            temp_topic=self._temp_subscription.topic_name)
        self._source = source
        self._core = OnlineCompensator(unit, watch=self._watch_settings(unit, source), **policies)
        self._learned_written_s = time.monotonic()
        # The magnetometer: a second core on its own topic, the same temperature and rules.
        self._mag_core = (OnlineCompensator(unit, channel='mag', **policies)
                          if driver and unit.mag is not None else None)
        self._process_values = self._core.process_values
        self._process_temperature = self._core.process_temperature
        self._imu = Imu()
        self._imu.orientation.x = self._imu.orientation.y = self._imu.orientation.z = 0.0
        self._imu.orientation.w = 1.0
        self._acceleration = self._imu.linear_acceleration
        self._angular_velocity = self._imu.angular_velocity
        # A driver's message that carries one sensor is published with the other marked absent
        # (zeros, covariance[0] = -1): one message per sensor it carries, its absent one never written.
        self._imu_only: dict[str, tuple[Imu, Any]] = {}
        for sensor in SENSORS if driver else ():
            imu = Imu()
            self._imu_only[sensor] = imu, imu.linear_acceleration if sensor == 'accel' else imu.angular_velocity
        # The raw path: the package's CDR codec at fixed offsets (formats.cdr), one reader per input.
        self._temperature_reader = FixedReader('sensor_msgs/msg/Temperature', ('temperature',))
        self._input_reader = (
            FixedReader(IMU_TYPE, ('stamp_sec', 'stamp_nanosec', 'linear_acceleration', 'angular_velocity',
                                   ('linear_acceleration_covariance', 1), ('angular_velocity_covariance', 1)))
            if driver else FixedReader('geometry_msgs/msg/Vector3Stamped', ('stamp_sec', 'stamp_nanosec', 'vector')))
        self._input_source = self._mag_source = b''
        """The last input (magnetometer) message published on the raw path: its frame_id for /diagnostics."""
        self._set_covariances()
        self._imu_publisher = self.create_publisher(Imu, output_topic, output_qos)
        self._publish_imu = self._imu_publisher.publish
        # No QoS event handlers on /diagnostics: every waitable costs the executor time on
        # every input message, and a 1 Hz status needs no incompatible-QoS report.
        self._diagnostics_publisher = self.create_publisher(
            DiagnosticArray, DIAGNOSTICS_TOPIC, 10,
            event_callbacks=PublisherEventCallbacks(use_default_callbacks=False))
        # The input callbacks take the MessageInfo (either executor, _with_sequence), whose
        # publication sequence numbers show every message that never arrived (Fast DDS's
        # message-lost event shows only some).
        # Recorded-signal subscriptions before the input one too (same creation-order rule); a
        # signal topic not yet advertised is looked up again every diagnostics period.
        self._signal_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=reliability)
        self._signal_subscriptions: dict[str, Any] = {}
        deadline = time.monotonic() + SIGNAL_DISCOVERY_S
        self._subscribe_signals()
        while (len(self._signal_subscriptions) < len(self._core.signals) and time.monotonic() < deadline
               and self.context.ok()):
            time.sleep(0.05)
            self._subscribe_signals()
        if self._mag_core is not None:
            self._mag = MagneticField()
            self._mag_field = self._mag.magnetic_field
            self._mag_publisher = self.create_publisher(MagneticField, COMPENSATED_MAG_TOPIC, output_qos)
            self._publish_mag = self._mag_publisher.publish
            self._process_mag = self._mag_core.process_values
            self._mag_reader = FixedReader(MAG_TYPE, ('stamp_sec', 'stamp_nanosec', 'magnetic_field'))
            self._set_mag_covariance()
            self._mag_subscription = self.create_subscription(
                MagneticField, MAG_TOPIC,
                self._with_sequence(self._on_raw_mag if raw else self._on_mag, self._mag_core, 'mag'), input_qos,
                event_callbacks=SubscriptionEventCallbacks(message_lost=self._on_mag_lost), raw=raw)
        on_input = self._with_sequence((self._on_raw_imu if driver else self._on_raw_counts) if raw
                                       else (self._on_imu if driver else self._on_counts))
        self._input_subscription = self.create_subscription(
            input_type, input_topic, on_input, input_qos,
            event_callbacks=SubscriptionEventCallbacks(message_lost=self._on_input_lost), raw=raw)
        # Statuses named by the fully qualified node name: two compensators (/imu0, /imu1) differ.
        self._status_prefix = self.get_fully_qualified_name()
        self._hardware_id = str(self._value('hardware_id'))
        self._diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD_S, self._on_diagnostics_timer)
        self._pending: Any = None
        self._mag_pending: Any = None
        self._learn_pending: LearnedState | None = _UNCHANGED
        """A ``learn`` change validated, to put in force: the learned file's state, ``None`` (false), or
        :data:`_UNCHANGED`."""
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        low, high = self._core.calibrated_range
        what = 'accelerometer and gyroscope, temperature (C)' if driver else 'temperature-code'
        span = f'{what} range {low:g}..{high:g}' if self._core.needs_temperature else 'no temperature terms'
        self.get_logger().info(
            f'correcting {self._input_subscription.topic_name} with {self._temp_subscription.topic_name} '
            f'-> {self._imu_publisher.topic_name}; calibration ({unit.input_kind.value} input) from {source}, '
            f'{span}; qos {qos_name} (depth {depth}), executor {self.executor_kind}, {self.message_path} messages, '
            f'out_of_range {self._core.out_of_range_policy.value}, stale_temperature '
            f'{self._core.stale_policy.value} after {self._core.temp_timeout_s:g} s')
        if self._mag_core is not None:
            self.get_logger().info(f'correcting {self._mag_subscription.topic_name} (magnetometer: temperature and '
                                   f'iron) -> {self._mag_publisher.topic_name}')
        self.get_logger().info(self._watch_words())

    def _watch_settings(self, unit: UnitCalibration, source: str) -> WatchSettings:
        """The watch's parameters (and, learning, the learned file's state)."""
        latitude = self._value('latitude')
        if latitude == '':
            latitude = None
        elif isinstance(latitude, bool) or not isinstance(latitude, (int, float)) or not -90.0 <= latitude <= 90.0:
            msg = f'latitude: expected degrees within -90..90 or empty, got {latitude!r}'
            raise ValueError(msg)
        enabled = _flag(self._value('watch'), 'watch')
        turn_on = _choice(self._value('turn_on'), 'turn_on', TURN_ON_CHOICES) == 'first_rest'
        learn = _flag(self._value('learn'), 'learn')
        path = _path_value(self._value('learned_file'), 'learned_file')
        if path and source and os.path.exists(source) and os.path.exists(path) and os.path.samefile(path, source):
            msg = f'learned_file: {path} is the calibration file itself (the original is never overwritten)'
            raise CalibrationError(msg)
        if learn and not path:
            msg = 'learn: true needs learned_file:=PATH (where what is learned is written)'
            raise ValueError(msg)
        if (turn_on or learn) and not enabled:
            msg = 'turn_on and learn need the watch (watch: true)'
            raise ValueError(msg)
        off = watch_unavailable(unit) if turn_on or learn else ''
        if off:
            what = 'learn: true' if learn else 'turn_on: first_rest'
            msg = f'{what} needs the calibration watch, which cannot run: {off}'
            raise CalibrationError(msg)
        repeatabilities = tuple(_repeatability(self._value(f'{sensor}_turn_on_repeatability'),
                                               f'{sensor}_turn_on_repeatability', factor)
                                for sensor, factor in (('accel', MG), ('gyro', DEG_PER_H)))
        state = _learning_start(learn, path, unit)
        missing = turn_on_unavailable(unit) if turn_on else ''
        if missing:
            msg = f"turn_on: first_rest needs the calibration's {missing}"
            raise CalibrationError(msg)
        self._learned_path = path
        """``learned_file`` (read only): where learning, when on, writes."""
        return WatchSettings(enabled=enabled, latitude=latitude, turn_on=turn_on, learn=state,
                             turn_on_repeatability=repeatabilities)  # type: ignore[arg-type]

    def _watch_words(self) -> str:
        """The start-up line about the watch."""
        core = self._core
        if core.watch is None:
            return f'calibration watch {core.watch_off}'
        watch = core.watch
        learner = watch.learner
        words = [f'calibration watch on: false alarms at most {watch.false_alarms_per_hour:g} per hour of rests',
                 f'first rest {watch.first_rest_words().split(";")[0]}',
                 f'latitude {watch.latitude:g}' if watch.latitude is not None else 'latitude unknown']
        if watch.turn_on_enabled:
            words.append('turn-on offset taken at the first rest')
        if learner is not None:
            words.append(f'learning into {self._learned_path} (from {learner.start.runs} earlier runs)')
        return '; '.join(words)

    def save_learned(self) -> None:
        """Write what the watch learned to ``learned_file`` (atomically), when it changed."""
        watch = self._core.watch
        if not self._learned_path or watch is None or watch.learner is None:
            return
        learner = watch.learner
        if not learner.changed:
            return
        try:
            save_learned(self._learned_path, learner.unit, learner.state(), source=self._source)
        except (OSError, TakError) as err:
            line = f'learned_file: cannot write {self._learned_path} ({err})'
            try:
                self.get_logger().error(line)
            except Exception:  # shutting down: rosout is gone
                print(f'[ERROR] [{NODE_NAME}]: {line}', file=sys.stderr)
            return
        learner.changed = False
        self._learned_written_s = time.monotonic()

    def _set_learning(self, state: LearnedState | None) -> None:
        """``learn`` set at run time: a new watch, learning from ``state`` (read by :meth:`_check_parameters`) or not.

        ``None`` (false) returns to the calibration file at once (what was learned is written first); a
        state starts learning from it (the new watch's rests start afresh).
        """
        self._end_watch()
        settings = self._core.watch_settings
        self._core.set_watch(replace(settings, learn=state))
        self.get_logger().info(self._watch_words())

    def _end_watch(self) -> None:
        """End the watch's stream (shutdown, or a new watch replaces it): judge every rest, and write what it learned.

        The rest in progress is judged too, and the timer may not have judged the latest ones yet.
        """
        self._core.judge_watch(finish=True)
        self.save_learned()

    def finish(self) -> None:
        """At shutdown: the rest in progress judged, the verdict said once more, what was learned written."""
        self._end_watch()
        if self._core.watch is not None:
            line = f'calibration watch at shutdown: {self._core.watch.verdict()}'
            try:
                self.get_logger().info(line)
            except Exception:  # the context is gone (a signal): rosout has no publisher any more
                print(f'[INFO] [{NODE_NAME}]: {line}', file=sys.stderr)

    def _value(self, name: str) -> Any:
        return self.get_parameter(name).value

    def _declare_tunables(self) -> None:
        """Declare the node's own parameters with their descriptors, keeping overrides."""
        tunables = _tunables()
        for name, (default, description, read_only) in tunables.items():
            if self.has_parameter(name):  # declared from the overrides; declare again with a descriptor
                self.undeclare_parameter(name)
            self.declare_parameter(name, default, ParameterDescriptor(
                description=description, read_only=read_only, dynamic_typing=True))
        known = set(tunables) | {'use_sim_time', 'start_type_description_service'}
        for name in sorted(self.get_parameters_by_prefix('')):
            if name not in known and not name.startswith((CALIBRATION_PREFIX + '.', 'qos_overrides.',
                                                          LEARNED_KEY + '.')):
                self.get_logger().warning(f'unknown parameter {name!r} ignored '
                                          f'(known: {", ".join(sorted(tunables))}, calibration.*)')

    def _calibration_values(self) -> dict[str, Any]:
        return {f'{CALIBRATION_PREFIX}.{name}': _plain(parameter.value)
                for name, parameter in self.get_parameters_by_prefix(CALIBRATION_PREFIX).items()}

    def _load_calibration(self) -> tuple[UnitCalibration, str]:
        """The calibration from ``calibration_file`` or ``calibration.*``, declared as parameters."""
        path = _path_value(self._value('calibration_file'), 'calibration_file', CalibrationError)
        flat = self._calibration_values()
        if path:
            if flat:
                msg = (f'calibration_file ({path}) and calibration.* parameters ({next(iter(flat))}, ...) '
                       f'both given: use one')
                raise CalibrationError(msg)
            unit = load_unit(path)
            flat = flatten_parameters(unit_to_mapping(unit), CALIBRATION_PREFIX)
            source = path
        elif not flat:
            msg = (f'calibration: missing for node {self.get_fully_qualified_name()}; give the file '
                   f'tak_calib fit wrote with --params-file FILE (its key must match the node: '
                   f"'compensator:' at the root namespace, '/**/compensator:' in any) or "
                   f'-p calibration_file:=FILE')
            raise CalibrationError(msg)
        else:
            unit = unit_from_mapping(nest_parameters(flat, CALIBRATION_PREFIX), key=CALIBRATION_PREFIX)
            source = 'parameters calibration.*'
        # Dynamic typing: `ros2 param set ... calibration.x.scale 256` (an integer) is then checked
        # by the calibration validator like any other value, not refused for its type.
        for name, value in flat.items():
            if self.has_parameter(name):
                self.undeclare_parameter(name)
            self.declare_parameter(name, value, ParameterDescriptor(dynamic_typing=True),
                                   ignore_override=bool(path))
        return unit, source

    def _subscribe_signals(self) -> None:
        """Subscribe each recorded signal the calibration needs whose topic is advertised yet."""
        missing = [name for name in self._core.signals if name not in self._signal_subscriptions]
        if not missing:
            return
        advertised = dict(self.get_topic_names_and_types())
        for name in missing:
            topic = split_signal_name(name)[0]
            types = [t for t in advertised.get(topic, ()) if t in AUX_FIELDS]
            if not types:
                continue
            try:
                field = signal_field(types[0], name)
            except TakError as err:
                self.get_logger().error(str(err))
                continue
            package, _, message = types[0].split('/')
            message_type = getattr(__import__(f'{package}.msg', fromlist=[message]), message)

            def on_signal(msg: Any, name: str = name, field: str = field) -> None:
                self._core.process_signal(name, float(getattr(msg, field)), time.monotonic())
                if self._core.notices:
                    self._log_notices()

            self._signal_subscriptions[name] = self.create_subscription(message_type, topic, on_signal,
                                                                        self._signal_qos)
            self.get_logger().info(f'subscribed {topic} ({types[0]}.{field}) for {name}')

    def _set_covariances(self) -> None:
        orientation, angular, linear = self._core.covariances
        if self._core.input_kind is InputKind.COUNTS:
            self._imu.orientation_covariance = orientation
        self._imu.angular_velocity_covariance = angular
        self._imu.linear_acceleration_covariance = linear
        for sensor, (imu, _) in self._imu_only.items():
            imu.angular_velocity_covariance = angular if sensor == 'gyro' else NOT_PROVIDED_COVARIANCE
            imu.linear_acceleration_covariance = linear if sensor == 'accel' else NOT_PROVIDED_COVARIANCE
        # The raw path's writers: what is constant in the output Imu written once per layout.
        if self._core.input_kind is InputKind.COUNTS:
            self._imu_writer = FixedWriter(IMU_TYPE, ('linear_acceleration',), {
                'orientation': (0.0, 0.0, 0.0, 1.0), 'orientation_covariance': orientation, 'angular_velocity': ZEROS,
                'angular_velocity_covariance': angular, 'linear_acceleration_covariance': linear})
            return
        passed = ('orientation', 'orientation_covariance')  # the driver's, passed through
        self._imu_writer = FixedWriter(IMU_TYPE, ('linear_acceleration', 'angular_velocity'), {
            'angular_velocity_covariance': angular, 'linear_acceleration_covariance': linear}, passed)
        # A message that carries one sensor: the other marked absent (zeros, covariance[0] = -1).
        self._one_sensor_writers = {
            'accel': FixedWriter(IMU_TYPE, ('linear_acceleration',), {
                'angular_velocity': ZEROS, 'angular_velocity_covariance': NOT_PROVIDED_COVARIANCE,
                'linear_acceleration_covariance': linear}, passed),
            'gyro': FixedWriter(IMU_TYPE, ('angular_velocity',), {
                'linear_acceleration': ZEROS, 'linear_acceleration_covariance': NOT_PROVIDED_COVARIANCE,
                'angular_velocity_covariance': angular}, passed)}

    def _set_mag_covariance(self) -> None:
        covariance = self._mag_core.covariances[2]
        self._mag.magnetic_field_covariance = covariance
        self._mag_writer = FixedWriter(MAG_TYPE, ('magnetic_field',), {'magnetic_field_covariance': covariance})

    # -- messages ---------------------------------------------------------------------------

    def _on_temperature(self, message: Temperature) -> None:
        self._take_temperature(message.temperature)

    def _on_raw_temperature(self, raw: bytes) -> None:
        try:
            temperature, = self._temperature_reader.read(raw)
        except CdrError as err:
            self._core.malformed(True, f'{self._temp_subscription.topic_name}: {err}', time.monotonic())
            self._log_notices()
            return
        self._take_temperature(temperature)

    def _take_temperature(self, temperature: float) -> None:
        now = time.monotonic()
        self._process_temperature(temperature, now)
        if self._mag_core is not None:
            self._mag_core.process_temperature(temperature, now)
            if self._mag_core.notices:
                self._log_mag_notices()
        if self._core.notices:
            self._log_notices()

    def _on_mag(self, message: MagneticField) -> None:
        header = message.header
        stamp = header.stamp
        field = message.magnetic_field
        result = self._process_mag(stamp.sec, stamp.nanosec, (field.x, field.y, field.z), time.monotonic())
        if result.__class__ is tuple:
            mag = self._mag
            mag.header = header
            out = self._mag_field
            out.x, out.y, out.z = result
            self._publish_mag(mag)
        if self._mag_core.notices:
            self._log_mag_notices()

    def _on_raw_mag(self, raw: bytes) -> None:
        reader = self._mag_reader
        try:
            values = reader.read(raw)
        except CdrError as err:
            self._mag_core.malformed(False, f'{self._mag_subscription.topic_name}: {err}', time.monotonic())
            self._log_mag_notices()
            return
        result = self._process_mag(values[0], values[1], values[2:], time.monotonic())
        if result.__class__ is tuple:
            self._publish_mag(self._mag_writer.write(raw, reader.layout, result))
            self._mag_source = raw
        if self._mag_core.notices:
            self._log_mag_notices()

    def _on_mag_lost(self, info: QoSMessageLostInfo) -> None:
        self._mag_core.message_lost('mag', info.total_count_change, time.monotonic())
        if self._mag_core.notices:
            self._log_mag_notices()

    def _log_mag_notices(self) -> None:
        """The magnetometer core's log lines, but the temperature's own (the Imu core reports them)."""
        self._log_notices(self._mag_core, skip=('temperature_rejected',))

    def _on_counts(self, message: Vector3Stamped) -> None:
        header = message.header
        stamp = header.stamp
        vector = message.vector
        result = self._process_values(stamp.sec, stamp.nanosec, (vector.x, vector.y, vector.z), time.monotonic())
        if result.__class__ is tuple:
            self._imu.header = header
            acceleration = self._acceleration
            acceleration.x, acceleration.y, acceleration.z = result
            self._publish_imu(self._imu)
        if self._core.notices:
            self._log_notices()

    def _on_imu(self, message: Imu) -> None:
        header = message.header
        stamp = header.stamp
        a = message.linear_acceleration
        w = message.angular_velocity
        # covariance[0] = -1 marks a sensor the message does not carry (sensor_msgs): handed to the core
        result = self._process_values(stamp.sec, stamp.nanosec, (a.x, a.y, a.z, w.x, w.y, w.z), time.monotonic(),
                                      message.linear_acceleration_covariance[0], message.angular_velocity_covariance[0])
        if result.__class__ is tuple:
            imu = self._imu
            imu.header = header
            imu.orientation = message.orientation
            imu.orientation_covariance = message.orientation_covariance
            acceleration, rate = self._acceleration, self._angular_velocity
            acceleration.x, acceleration.y, acceleration.z, rate.x, rate.y, rate.z = result
            self._publish_imu(imu)
        elif result.__class__ is OneSensor:
            self._publish_one_sensor(message, result)
        if self._core.notices:
            self._log_notices()

    def _on_raw_counts(self, raw: bytes) -> None:
        """The counts message's bytes: stamp and codes read, corrected, the Imu written as bytes (the raw path)."""
        reader = self._input_reader
        try:
            values = reader.read(raw)
        except CdrError as err:
            self._input_malformed(err)
            return
        result = self._process_values(values[0], values[1], values[2:], time.monotonic())
        if result.__class__ is tuple:
            self._publish_imu(self._imu_writer.write(raw, reader.layout, result))
            self._input_source = raw
        if self._core.notices:
            self._log_notices()

    def _on_raw_imu(self, raw: bytes) -> None:
        """The driver Imu's bytes: stamp, both sensors and their marks read, corrected, the Imu written as bytes."""
        reader = self._input_reader
        try:  # (sec, nanosec, accel x y z, gyro x y z, accel mark, gyro mark): the marks are covariance[0]
            values = reader.read(raw)
        except CdrError as err:
            self._input_malformed(err)
            return
        result = self._process_values(values[0], values[1], values[2:8], time.monotonic(), values[8], values[9])
        if result.__class__ is tuple:
            self._publish_imu(self._imu_writer.write(raw, reader.layout, result))
            self._input_source = raw
        elif result.__class__ is OneSensor:
            self._publish_imu(self._one_sensor_writers[result.sensor].write(raw, reader.layout, result.values))
            self._input_source = raw
        if self._core.notices:
            self._log_notices()

    def _input_malformed(self, error: CdrError) -> None:
        self._core.malformed(False, f'{self._input_subscription.topic_name}: {error}', time.monotonic())
        self._log_notices()

    def _publish_one_sensor(self, message: Imu, result: OneSensor) -> None:
        """Publish a message that carries one sensor, the other marked absent (its template's covariance)."""
        imu, vector = self._imu_only[result.sensor]
        imu.header = message.header
        imu.orientation = message.orientation
        imu.orientation_covariance = message.orientation_covariance
        vector.x, vector.y, vector.z = result.values
        self._publish_imu(imu)

    def _with_sequence(self, on_message: Any, core: OnlineCompensator | None = None, name: str = '') -> Any:
        """``on_message`` preceded by the count of sequence gaps (a callback taking the MessageInfo).

        Its signature asks rclpy for the MessageInfo: the single-threaded executor then calls it
        with the message and the info, rclpy 7's EventsExecutor with one ``(message, info)``
        tuple; either way the publication sequence numbers are counted.
        """
        sequence = (core or self._core).sequence
        name = name or self._input_name

        def on_message_with_info(message: Any, info: Any = None) -> None:
            if info is None:  # the EventsExecutor: (message, info) in one tuple
                message, info = message
            number = info.get('publication_sequence_number')
            if number is not None:
                sequence(name, number, time.monotonic())
            on_message(message)

        on_message_with_info.__signature__ = _WITH_MESSAGE_INFO  # type: ignore[attr-defined]
        return on_message_with_info

    def _on_input_lost(self, info: QoSMessageLostInfo) -> None:
        self._core.message_lost(self._input_name, info.total_count_change, time.monotonic())
        if self._core.notices:
            self._log_notices()

    def _on_temperature_lost(self, info: QoSMessageLostInfo) -> None:
        self._core.message_lost('temperature', info.total_count_change, time.monotonic())
        if self._core.notices:
            self._log_notices()

    def _on_diagnostics_timer(self) -> None:
        if not self.context.ok():  # a SIGINT or SIGTERM shut rclpy down: publishers and rosout are gone
            return
        self._subscribe_signals()
        now = time.monotonic()
        self._core.tick(now)
        status = self._core.status(now, imu_subscribers=self._imu_publisher.get_subscription_count())
        diagnostics = DiagnosticArray()
        diagnostics.header.stamp = self.get_clock().now().to_msg()
        watch = self._core.watch_status()
        imu_frame = self._hardware_id or (frame_id(self._input_source) if self._input_source
                                          else self._imu.header.frame_id)
        diagnostics.status = [_diagnostic(status.level, f'{self._status_prefix}: temperature compensation',
                                          status.message, imu_frame, (*status.values, watch.values[0]))]
        if self._core.watch is not None:  # a status of its own while it runs (off: the value above says why)
            diagnostics.status.append(_diagnostic(watch.level, f'{self._status_prefix}: calibration watch',
                                                  watch.message, imu_frame, watch.values))
        if self._learned_path and now - self._learned_written_s >= LEARNED_WRITE_PERIOD_S:
            self.save_learned()  # outside the message path: the diagnostics timer
        if self._mag_core is not None:
            self._mag_core.tick(now)
            mag_status = self._mag_core.status(now, imu_subscribers=self._mag_publisher.get_subscription_count())
            diagnostics.status.append(_diagnostic(
                mag_status.level, f'{self._status_prefix}: magnetometer compensation', mag_status.message,
                self._hardware_id or (frame_id(self._mag_source) if self._mag_source else self._mag.header.frame_id),
                mag_status.values))
        try:
            self._diagnostics_publisher.publish(diagnostics)
        except Exception:
            if self.context.ok():
                raise
            return  # shut down since the check above
        if self._core.notices:
            self._log_notices()
        if self._mag_core is not None and self._mag_core.notices:
            self._log_mag_notices()

    def _log_notices(self, core: OnlineCompensator | None = None, skip: tuple[str, ...] = ()) -> None:
        logger = self.get_logger()
        for notice in (core or self._core).take_notices():
            if notice.kind in skip:
                continue
            try:  # one call site per severity: rclpy's logger keeps a severity per calling line
                if notice.level is Level.ERROR:
                    logger.error(notice.text)
                elif notice.level is Level.WARN:
                    logger.warning(notice.text)
                else:
                    logger.info(notice.text)
            except Exception:
                if self.context.ok():
                    raise
                return  # shut down between the check and the call: rosout has no publisher any more

    # -- runtime parameter updates -----------------------------------------------------------

    def _check_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """Validate a change: the whole resulting calibration and policies, before it is set.

        Everything later computed from the values is computed here (:meth:`OnlineCompensator.prepare`:
        the parser's limits, the covariances, the correction over the calibrated range), so that
        putting the change in force cannot fail. Any error refuses the change with its reason.
        """
        self._pending = None
        self._learn_pending = _UNCHANGED
        changes_learn = _UNCHANGED
        try:
            changes: dict[str, Any] = {}
            calibration_changed = False
            for parameter in parameters:
                value = parameter.value
                if parameter.name == 'temp_timeout':
                    changes['temp_timeout_s'] = _timeout(value)
                elif parameter.name == 'stale_temperature':
                    changes['stale_temperature'] = StaleTemperature(
                        _choice(value, 'stale_temperature', [p.value for p in StaleTemperature]))
                elif parameter.name == 'out_of_range':
                    changes['out_of_range'] = OutOfRange(
                        _choice(value, 'out_of_range', [p.value for p in OutOfRange]))
                elif parameter.name.startswith(CALIBRATION_PREFIX + '.'):
                    calibration_changed = True
                elif parameter.name == 'learn':
                    path = self._learned_path
                    if _flag(value, 'learn') and not path:
                        msg = 'learn: true needs learned_file:=PATH, given at start-up'
                        raise ValueError(msg)
                    if self._core.watch is None:
                        msg = f'learn: the calibration watch is {self._core.watch_off}'
                        raise ValueError(msg)
                    if value == (self._core.watch.learner is not None):
                        continue  # as it is: learning goes on (or stays off) untouched
                    changes_learn = _learning_start(value, path, self._core.unit)
            if calibration_changed:
                flat = self._calibration_values()
                for parameter in parameters:
                    if not parameter.name.startswith(CALIBRATION_PREFIX + '.'):
                        continue
                    if parameter.type_ is Parameter.Type.NOT_SET:
                        flat.pop(parameter.name, None)
                    else:
                        flat[parameter.name] = _plain(parameter.value)
                changes['calibration'] = unit_from_mapping(nest_parameters(flat, CALIBRATION_PREFIX),
                                                           key=CALIBRATION_PREFIX)
            prepared = self._core.prepare(**changes) if changes else None
            mag_prepared = (self._mag_core.prepare(**changes, key=CALIBRATION_PREFIX)
                            if changes and self._mag_core is not None else None)
        except Exception as err:  # noqa: BLE001 - a running node must never die of a parameter update
            reason = str(err) if isinstance(err, (TakError, ValueError)) else f'{type(err).__name__}: {err}'
            self.get_logger().warning(f'parameter update rejected, the previous values stay in force: {reason}')
            return SetParametersResult(successful=False, reason=reason)
        self._pending = prepared
        self._mag_pending = mag_prepared
        self._learn_pending = changes_learn
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        """Put the validated change in force: runs in the executor, between two messages."""
        prepared, self._pending = self._pending, None
        mag_prepared, self._mag_pending = self._mag_pending, None
        learn, self._learn_pending = self._learn_pending, _UNCHANGED
        if learn is not _UNCHANGED:
            self._set_learning(learn)
        if prepared is None:
            return
        if prepared.unit is not self._core.unit:  # a new calibration: a new watch, what was learned written first
            self._end_watch()
        self._core.install(prepared)
        self._set_covariances()
        if mag_prepared is not None:
            self._mag_core.install(mag_prepared)
            self._set_mag_covariance()
        names = ', '.join(p.name for p in parameters)
        self.get_logger().info(f'parameters updated ({names}): out_of_range {self._core.out_of_range_policy.value}, '
                               f'stale_temperature {self._core.stale_policy.value}, temp_timeout '
                               f'{self._core.temp_timeout_s:g} s, calibration updates '
                               f'{self._core.calibration_updates}')


LEARNED_WRITE_PERIOD_S = 60.0
"""How often, at most, learning writes ``learned_file`` (and at shutdown), from the diagnostics timer."""
TURN_ON_CHOICES = ('none', 'first_rest')


def make_executor(kind: str, context: Any) -> Executor:
    """The executor named by the ``executor`` parameter."""
    if kind == 'events':
        return EventsExecutor(context=context)
    return SingleThreadedExecutor(context=context)


def spin(node: Node, executor: Executor, signals: SignalGuard | None = None) -> bool:
    """Spin until a stop signal (``signals``: SIGINT or SIGTERM) or until the context shuts down.

    ``spin_once`` in a loop, not ``spin()``: the EventsExecutor's ``spin()`` stopped by a
    shutdown from another thread kept running at 100 % CPU in a trial; this loop notices the
    signal or the shutdown within :data:`SPIN_PERIOD_S`.

    :returns: whether the executor failed on the shutdown itself (it raised once the context was
        gone, e.g. while registering the node's entities): see :func:`main`.
    """
    executor.add_node(node)
    context = node.context
    while context.ok() and (signals is None or signals.received is None):
        try:
            executor.spin_once(timeout_sec=SPIN_PERIOD_S)
        except ExternalShutdownException:
            break
        except Exception:
            if context.ok():
                raise
            return True  # the executor noticed the shutdown first, in its own words
    return False


def _params_file_refused(args: Sequence[str]) -> str:
    """Why a ``--params-file`` of the command line is not read (a FIFO, socket, device, directory), or ``''``."""
    words = list(args)
    for word, value in zip(words, words[1:]):
        kind = not_regular(value) if word == '--params-file' else ''
        if kind:
            return f'--params-file {value}: is {kind}: only a regular file is read'
    return ''


def main(args: Sequence[str] | None = None, *, signals: SignalGuard | None = None) -> int:
    """Entry point of ``compensator`` (Jazzy node skeleton); 2 when it cannot start.

    A SIGINT or SIGTERM at any moment ends it with status 0 (``signals``, installed here when
    the caller has not: :mod:`tak_thermo_ros.ros.main`). One that comes while it starts stops
    the imports or ``rclpy.init``, or the node once built, said in one line, no traceback.
    rclpy installs no signal handler of its own: the guard's stops the spin, so the node ends
    (the watch's verdict logged, what it learned written) while its context still holds, and its
    last lines reach /rosout (rclpy's handlers shut the context down first, and every line logged
    at shutdown printed "Failed to publish log message to rosout").
    """
    signals = signals if signals is not None else SignalGuard().install()
    node = executor = None
    running = failed_on_shutdown = False
    try:
        if signals.received:  # arrived while the caller imported this module
            raise KeyboardInterrupt
        refused = _params_file_refused(sys.argv if args is None else args)
        if refused:  # rcl would wait on a FIFO's open inside rclpy.init
            print(f'[FATAL] [{NODE_NAME}]: cannot start: {refused}', file=sys.stderr)
            return EXIT_ERROR
        try:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        except Exception as err:  # rcl refuses bad --ros-args or an unreadable params file
            if signals.received:
                raise KeyboardInterrupt from None
            detail = str(err).strip().splitlines()
            print(f'[FATAL] [{NODE_NAME}]: cannot start: {detail[0] if detail else type(err).__name__}',
                  file=sys.stderr)
            return EXIT_ERROR
        signals.disarm()  # from now on a signal is remembered: the spin below stops on it
        try:
            node = CompensatorNode()
        except (TakError, ValueError) as err:
            if signals.received or not rclpy.ok():
                raise KeyboardInterrupt from None
            rclpy.logging.get_logger(NODE_NAME).fatal(f'cannot start: {err}')
            return EXIT_ERROR
        if signals.received:  # while the node was built
            raise KeyboardInterrupt
        executor = make_executor(node.executor_kind, node.context)
        running = True
        failed_on_shutdown = spin(node, executor, signals)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if signals.received is None and rclpy.ok():
            raise
        # a signal shut the context down under rclpy (RCLError: context is invalid)
    finally:
        # Ctrl-C under `ros2 launch` reaches the node twice (the terminal's process group, then
        # launch forwarding it): a second signal must not break the teardown with a traceback.
        signals.disarm()
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.finish()
            node.destroy_node()
        rclpy.try_shutdown()
        if not running and signals.received:
            signals.say_stopped(NODE_NAME)
        if failed_on_shutdown and node is not None and node.executor_kind == 'events':
            # rclpy's EventsExecutor that raised while registering the node's entities (a signal
            # shut the context down in the middle) can keep a callback it never recorded, and its
            # C++ destructor then aborts the process ("Destroying callback manager with callbacks
            # remaining"). Everything is torn down above; end here, before that destructor runs.
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(0)
    return 0


if __name__ == '__main__':
    sys.exit(main())
