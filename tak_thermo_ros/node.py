"""The ``compensator`` node: online temperature-drift correction in a ROS 2 INS pipeline.

::

    ros2 run tak_thermo_ros compensator --ros-args --params-file tak_params.yaml

Subscribes ``tak/counts`` (``geometry_msgs/msg/Vector3Stamped``, channel codes) and
``tak/temp_code`` (``sensor_msgs/msg/Temperature``, the raw temperature-sensor code); publishes
``tak/imu/data_raw`` (``sensor_msgs/msg/Imu``, exactly as ``tak_calib apply`` writes it) and
``/diagnostics`` at 1 Hz. Topic names are relative: namespaces and remapping work.

When the calibration holds a recorded-signal term (``aux:TOPIC``, e.g. the supply voltage on
``/power/battery_state``), the node also subscribes that topic, with the type its publisher
advertises (looked up again every diagnostics period until one appears); the value is held like
the temperature (see :mod:`tak_thermo_ros.core.online`).

This is a thin wrapper: callbacks turn messages into numbers, hand them to
:class:`~tak_thermo_ros.core.online.OnlineCompensator` (no ROS in it) and turn the result
back into a message. The only module of the package that imports rclpy.
"""

from __future__ import annotations

import array
import sys
import time
from typing import Any, Sequence

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Vector3Stamped
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, Temperature

from tak_thermo_ros.core.calibration_file import (
    NODE_NAME,
    calibration_from_mapping,
    calibration_to_mapping,
    flatten_parameters,
    load_calibration,
    nest_parameters,
)
from tak_thermo_ros.core.correction import OutOfRange, imu_covariances
from tak_thermo_ros.core.effects.aux_signal import AUX_FIELDS, signal_field, split_signal_name
from tak_thermo_ros.core.model import Calibration
from tak_thermo_ros.core.online import Level, OnlineCompensator, StaleTemperature
from tak_thermo_ros.errors import CalibrationError, TakError

COUNTS_TOPIC = 'tak/counts'
TEMP_TOPIC = 'tak/temp_code'
IMU_TOPIC = 'tak/imu/data_raw'
DIAGNOSTICS_TOPIC = '/diagnostics'
DIAGNOSTICS_PERIOD_S = 1.0
EXIT_ERROR = 2
QOS_CHOICES = ('sensor_data', 'reliable')
SIGNAL_DISCOVERY_S = 5.0
"""At start-up, how long the node waits for the publisher of a recorded signal it needs."""
CALIBRATION_PREFIX = 'calibration'

_DIAGNOSTIC_LEVELS = {Level.OK: DiagnosticStatus.OK, Level.WARN: DiagnosticStatus.WARN,
                      Level.ERROR: DiagnosticStatus.ERROR}


def _tunables() -> dict[str, tuple[Any, str, bool]]:
    """Name -> (default, description, read only) of the node's own parameters."""
    return {
        'calibration_file': ('', 'calibration parameters YAML to load instead of calibration.* '
                                 '(the file tak_calib fit writes); empty: use calibration.*', True),
        'qos': ('sensor_data', "input QoS: 'sensor_data' (best effort, REP 2003 consumer; matches "
                               "every publisher) or 'reliable' (lossless, needs a reliable publisher)",
                True),
        'qos_depth': (100, 'history depth of the subscriptions and the Imu publisher', True),
        'temp_timeout': (1.0, 'seconds after which the last temperature code is stale '
                              '(diagnostics ERROR)', False),
        'stale_temperature': ('hold', "counts while the temperature code is stale: 'hold' the last "
                                      "code or 'drop' the counts", False),
        'out_of_range': ('clamp', "temperature codes outside the calibrated range: 'clamp' to the "
                                  "edge or 'extrapolate' (always counted and logged)", False),
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
        calibration, source = self._load_calibration()
        depth = _depth(self._value('qos_depth'))
        qos_name = _choice(self._value('qos'), 'qos', QOS_CHOICES)
        reliability = (ReliabilityPolicy.BEST_EFFORT if qos_name == 'sensor_data'
                       else ReliabilityPolicy.RELIABLE)
        input_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability)
        # REP 2003: the Imu is published reliable, which matches reliable and best-effort readers.
        output_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                                reliability=ReliabilityPolicy.RELIABLE)
        # The temperature subscription is created first: when a code and a counts message are
        # ready at once, the executor takes them in creation order, the code first.
        self._temp_subscription = self.create_subscription(Temperature, TEMP_TOPIC, self._on_temperature,
                                                           input_qos)
        self._core = OnlineCompensator(
            calibration,
            out_of_range=OutOfRange(_choice(self._value('out_of_range'), 'out_of_range',
                                            [p.value for p in OutOfRange])),
            stale_temperature=StaleTemperature(_choice(self._value('stale_temperature'), 'stale_temperature',
                                                       [p.value for p in StaleTemperature])),
            temp_timeout_s=_timeout(self._value('temp_timeout')),
            temp_topic=self._temp_subscription.topic_name)
        self._process_counts = self._core.process_counts
        self._process_temperature = self._core.process_temperature
        self._imu = Imu()
        self._imu.orientation.x = self._imu.orientation.y = self._imu.orientation.z = 0.0
        self._imu.orientation.w = 1.0
        self._acceleration = self._imu.linear_acceleration
        self._set_covariances()
        self._imu_publisher = self.create_publisher(Imu, IMU_TOPIC, output_qos)
        self._publish_imu = self._imu_publisher.publish
        # No QoS event handlers on /diagnostics: every waitable costs the executor time on
        # every counts message, and a 1 Hz status needs no incompatible-QoS report.
        self._diagnostics_publisher = self.create_publisher(
            DiagnosticArray, DIAGNOSTICS_TOPIC, 10,
            event_callbacks=PublisherEventCallbacks(use_default_callbacks=False))
        # Recorded-signal subscriptions before the counts one too (same creation-order rule);
        # a signal topic not yet advertised is looked up again every diagnostics period.
        self._signal_subscriptions: dict[str, Any] = {}
        deadline = time.monotonic() + SIGNAL_DISCOVERY_S
        self._subscribe_signals()
        while len(self._signal_subscriptions) < len(self._core.signals) and time.monotonic() < deadline:
            time.sleep(0.05)
            self._subscribe_signals()
        self._counts_subscription = self.create_subscription(Vector3Stamped, COUNTS_TOPIC, self._on_counts,
                                                             input_qos)
        self._diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD_S, self._on_diagnostics_timer)
        self._pending: dict[str, Any] | None = None
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.get_logger().info(
            f'correcting {self._counts_subscription.topic_name} with {self._temp_subscription.topic_name} '
            f'-> {self._imu_publisher.topic_name}; calibration from {source}, temperature-code range '
            f'{calibration.temp_code_min:g}..{calibration.temp_code_max:g}; qos {qos_name} (depth {depth}), '
            f'out_of_range {self._core.out_of_range_policy.value}, stale_temperature '
            f'{self._core.stale_policy.value} after {self._core.temp_timeout_s:g} s')

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
            if name not in known and not name.startswith((CALIBRATION_PREFIX + '.', 'qos_overrides.')):
                self.get_logger().warning(f'unknown parameter {name!r} ignored '
                                          f'(known: {", ".join(sorted(tunables))}, calibration.*)')

    def _calibration_values(self) -> dict[str, Any]:
        return {f'{CALIBRATION_PREFIX}.{name}': _plain(parameter.value)
                for name, parameter in self.get_parameters_by_prefix(CALIBRATION_PREFIX).items()}

    def _load_calibration(self) -> tuple[Calibration, str]:
        """The calibration from ``calibration_file`` or ``calibration.*``, declared as parameters."""
        path = self._value('calibration_file')
        flat = self._calibration_values()
        if not isinstance(path, str):
            msg = f'calibration_file: expected a path, got {path!r}'
            raise CalibrationError(msg)
        if path:
            if flat:
                msg = (f'calibration_file ({path}) and calibration.* parameters ({next(iter(flat))}, ...) '
                       f'both given: use one')
                raise CalibrationError(msg)
            calibration = load_calibration(path)
            flat = flatten_parameters(calibration_to_mapping(calibration), CALIBRATION_PREFIX)
            source = path
        elif not flat:
            msg = (f'calibration: missing for node {self.get_fully_qualified_name()}; give the file '
                   f'tak_calib fit wrote with --params-file FILE (its key must match the node: '
                   f"'compensator:' at the root namespace, '/**/compensator:' in any) or "
                   f'-p calibration_file:=FILE')
            raise CalibrationError(msg)
        else:
            calibration = calibration_from_mapping(nest_parameters(flat, CALIBRATION_PREFIX),
                                                   key=CALIBRATION_PREFIX)
            source = 'parameters calibration.*'
        # Dynamic typing: `ros2 param set ... calibration.x.scale 256` (an integer) is then checked
        # by the calibration validator like any other value, not refused for its type.
        for name, value in flat.items():
            if self.has_parameter(name):
                self.undeclare_parameter(name)
            self.declare_parameter(name, value, ParameterDescriptor(dynamic_typing=True),
                                   ignore_override=bool(path))
        return calibration, source

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
            module = __import__(f'{package}.msg', fromlist=[message])
            message_type = getattr(module, message)

            def on_signal(msg: Any, name: str = name, field: str = field) -> None:
                self._core.process_signal(name, float(getattr(msg, field)), time.monotonic())
                if self._core.notices:
                    self._log_notices()

            self._signal_subscriptions[name] = self.create_subscription(
                message_type, topic, on_signal,
                QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                           reliability=self._temp_subscription.qos_profile.reliability))
            self.get_logger().info(f'subscribed {topic} ({types[0]}.{field}) for {name}')

    def _set_covariances(self) -> None:
        orientation, angular, linear = imu_covariances(self._core.variance)
        self._imu.orientation_covariance = orientation
        self._imu.angular_velocity_covariance = angular
        self._imu.linear_acceleration_covariance = linear

    # -- messages ---------------------------------------------------------------------------

    def _on_temperature(self, message: Temperature) -> None:
        self._process_temperature(message.temperature, time.monotonic())
        if self._core.notices:
            self._log_notices()

    def _on_counts(self, message: Vector3Stamped) -> None:
        header = message.header
        stamp = header.stamp
        vector = message.vector
        result = self._process_counts(stamp.sec, stamp.nanosec, vector.x, vector.y, vector.z, time.monotonic())
        if result.__class__ is tuple:
            self._imu.header = header
            acceleration = self._acceleration
            acceleration.x, acceleration.y, acceleration.z = result
            self._publish_imu(self._imu)
        if self._core.notices:
            self._log_notices()

    def _on_diagnostics_timer(self) -> None:
        self._subscribe_signals()
        now = time.monotonic()
        self._core.tick(now)
        status = self._core.status(now, imu_subscribers=self._imu_publisher.get_subscription_count())
        diagnostics = DiagnosticArray()
        diagnostics.header.stamp = self.get_clock().now().to_msg()
        diagnostics.status = [DiagnosticStatus(
            level=_DIAGNOSTIC_LEVELS[status.level],
            name=f'{self.get_name()}: temperature compensation',
            message=status.message,
            hardware_id=self._imu.header.frame_id,
            values=[KeyValue(key=key, value=value) for key, value in status.values])]
        self._diagnostics_publisher.publish(diagnostics)
        if self._core.notices:
            self._log_notices()

    def _log_notices(self) -> None:
        logger = self.get_logger()
        for notice in self._core.take_notices():
            if notice.level is Level.ERROR:
                logger.error(notice.text)
            elif notice.level is Level.WARN:
                logger.warning(notice.text)
            else:
                logger.info(notice.text)

    # -- runtime parameter updates -----------------------------------------------------------

    def _check_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """Validate a change: the whole resulting calibration and policies, before it is set."""
        self._pending = None
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
            if calibration_changed:
                flat = self._calibration_values()
                for parameter in parameters:
                    if not parameter.name.startswith(CALIBRATION_PREFIX + '.'):
                        continue
                    if parameter.type_ is Parameter.Type.NOT_SET:
                        flat.pop(parameter.name, None)
                    else:
                        flat[parameter.name] = _plain(parameter.value)
                changes['calibration'] = calibration_from_mapping(
                    nest_parameters(flat, CALIBRATION_PREFIX), key=CALIBRATION_PREFIX)
        except (TakError, ValueError) as err:
            reason = str(err)
            self.get_logger().warning(f'parameter update rejected, the previous values stay in force: {reason}')
            return SetParametersResult(successful=False, reason=reason)
        self._pending = changes
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        """Swap the validated change in: runs in the executor, between two messages."""
        changes, self._pending = self._pending, None
        if not changes:
            return
        calibration = changes.pop('calibration', None)
        self._core.set_policies(**changes)
        if calibration is not None:
            self._core.swap_calibration(calibration)
            self._set_covariances()
        names = ', '.join(p.name for p in parameters)
        self.get_logger().info(f'parameters updated ({names}): out_of_range {self._core.out_of_range_policy.value}, '
                               f'stale_temperature {self._core.stale_policy.value}, temp_timeout '
                               f'{self._core.temp_timeout_s:g} s, calibration updates '
                               f'{self._core.calibration_updates}')


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of ``compensator`` (Jazzy node skeleton); 2 when it cannot start."""
    try:
        rclpy.init(args=args)
    except Exception as err:  # rcl refuses bad --ros-args or an unreadable params file
        detail = str(err).strip().splitlines()
        print(f'[FATAL] [{NODE_NAME}]: cannot start: {detail[0] if detail else type(err).__name__}',
              file=sys.stderr)
        return EXIT_ERROR
    try:
        node = CompensatorNode()
    except (TakError, ValueError) as err:
        rclpy.logging.get_logger(NODE_NAME).fatal(f'cannot start: {err}')
        rclpy.try_shutdown()
        return EXIT_ERROR
    except KeyboardInterrupt:
        rclpy.try_shutdown()
        return 0
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
