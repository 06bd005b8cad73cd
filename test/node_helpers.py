"""Helpers for tests that run the real ``compensator`` node and talk to it with rclpy.

The node runs as a subprocess in its own session (stopped by SIGINT to its group, then
SIGKILL); the test process has its own rclpy context on the same, test-specific, domain.
Every wait is on a condition (matched endpoints, a message received, a log line), never a
fixed sleep.

Every process a test starts goes through :func:`start_process`: its own session, killed by the
kernel when the test process dies (a crashed or killed pytest worker runs no ``finally``: a node
in its own session would run on for ever), and its group recorded, so that ``conftest.py``'s
guard finds and kills any group a test left running, and fails that test.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import rclpy
from geometry_msgs.msg import Vector3Stamped
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, Temperature

from tak_thermo_ros.formats.bag import play_order

NANOSECONDS = 1_000_000_000
RELIABLE = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
_PR_SET_PDEATHSIG = 1
_PRCTL = ctypes.CDLL(None, use_errno=True).prctl
"""Resolved here, not in the child between fork and exec."""
STARTED_GROUPS: list[int] = []
"""The process group of every process :func:`start_process` started, in order (each leads its own)."""


def _child_setup(parent: int) -> Callable[[], None]:
    """What the child does before exec: die with the test process, SIGINT at its default."""
    def setup() -> None:
        _PRCTL(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        if os.getppid() != parent:  # the test process died before the line above
            os._exit(1)
        # A shell that runs `make test` in the background ignores SIGINT, and a child inherits
        # that: the tests that send SIGINT expect the default (Python's KeyboardInterrupt).
        signal.signal(signal.SIGINT, signal.SIG_DFL)
    return setup


def start_process(command: Sequence[str], **popen: Any) -> subprocess.Popen:
    """``subprocess.Popen`` in a session of its own, killed (SIGKILL) when the test process dies; its group recorded."""
    process = subprocess.Popen(list(command), start_new_session=True, preexec_fn=_child_setup(os.getpid()),
                               **popen)
    STARTED_GROUPS.append(process.pid)
    return process


def group_running(group: int) -> bool:
    """Whether a process of process group ``group`` runs (a zombie does not)."""
    for entry in os.scandir('/proc'):
        if not entry.name.isdigit():
            continue
        try:
            fields = Path(entry.path, 'stat').read_text().rsplit(')', 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[2]) == group and fields[0] not in 'ZX':
            return True
    return False


def kill_leftovers(since: int = 0, timeout: float = 10.0) -> list[int]:
    """SIGKILL every group :func:`start_process` started (from index ``since`` on) that still runs; those groups."""
    left = [group for group in STARTED_GROUPS[since:] if group_running(group)]
    for group in left:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(group, signal.SIGKILL)
    wait_until(lambda: not any(group_running(group) for group in left), timeout, what='the leftovers to die')
    return left


def domain_id(index: int) -> int:
    """A ROS domain for test ``index``, from the process id: in 1..100 (safe for Fast DDS ports)."""
    return 1 + (os.getpid() * 7 + index * 31) % 100


def ros_environment(tmp_path: Path, domain: int) -> dict[str, str]:
    """Environment of a ROS process confined to this host, this domain and ``tmp_path``."""
    home = tmp_path / 'ros_home'
    home.mkdir(exist_ok=True)
    return {
        **os.environ,
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        'ROS_DOMAIN_ID': str(domain),
        'ROS_HOME': str(home),
        'ROS_LOG_DIR': str(home / 'log'),
        'RCUTILS_COLORIZED_OUTPUT': '0',
        'PYTHONUNBUFFERED': '1',
    }


def node_command(*ros_args: str) -> list[str]:
    """Command line running the node (its entry point, ``ros.main``) with this interpreter."""
    return [sys.executable, '-m', 'tak_thermo_ros.ros.main', '--ros-args', *ros_args]


class NodeProcess:
    """A node subprocess in its own session, its output in a file.

    :param command: the command line.
    :param env: its environment.
    :param log_path: file collecting stdout and stderr.
    :param cwd: working directory (default: this one).
    """

    def __init__(self, command: Sequence[str], env: dict[str, str], log_path: Path, *,
                 cwd: Path | None = None) -> None:
        self.log_path = log_path
        self._log = open(log_path, 'wb')  # noqa: SIM115 - closed in stop()
        self.process = start_process(command, env=env, stdout=self._log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, cwd=cwd)

    def log(self) -> str:
        """Everything the node printed so far."""
        return self.log_path.read_text(encoding='utf-8', errors='replace')

    def stop(self, timeout: float = 10.0) -> int:
        """SIGINT to the process group, SIGKILL after ``timeout``; the exit code."""
        if self.process.poll() is None:
            try:
                os.killpg(self.process.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait()
        self._log.close()
        return self.process.returncode

    def __enter__(self) -> NodeProcess:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()


def run_to_exit(command: Sequence[str], env: dict[str, str], timeout: float = 60.0) -> subprocess.CompletedProcess:
    """Run a command that should exit by itself (in its own session, killed on timeout)."""
    with start_process(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                       stdin=subprocess.DEVNULL) as process:
        try:
            out, err = process.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            out, err = process.communicate()
        return subprocess.CompletedProcess(process.args, process.returncode, out, err)


def wait_until(condition: Callable[[], bool], timeout: float, *, step: Callable[[], None] | None = None,
               what: str = 'condition') -> None:
    """Call ``step`` (or sleep briefly) until ``condition()`` holds; fail after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            msg = f'timed out after {timeout} s waiting for {what}'
            raise AssertionError(msg)
        if step is not None:
            step()
        else:
            time.sleep(0.01)


def header_stamp(message: Any, stamp_ns: int) -> None:
    """Set a message's header stamp from integer nanoseconds."""
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(int(stamp_ns), NANOSECONDS)


def stamp_of(message: Any) -> int:
    """A message's header stamp in integer nanoseconds."""
    return message.header.stamp.sec * NANOSECONDS + message.header.stamp.nanosec


class Harness:
    """The test side: publishers of counts and temperature codes, subscribers of the outputs.

    With ``driver=True``, the driver-input topics instead: Imu on ``imu/data_raw`` and degrees C
    on ``imu/temperature`` out, the corrected Imu from ``imu/data_compensated`` in.

    :param domain: ROS domain id (the node's).
    :param namespace: namespace of the node under test (topics are relative to it).
    :param driver: whether the node runs a driver (version-2) calibration.
    :param input_qos: QoS of the test's input publishers.
    """

    def __init__(self, domain: int, *, namespace: str = '', driver: bool = False,
                 input_qos: QoSProfile = RELIABLE) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node('compensator_test', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        prefix = f'/{namespace.strip("/")}/' if namespace.strip('/') else '/'
        input_type, input_topic, temp_topic, output_topic = (
            (Imu, 'imu/data_raw', 'imu/temperature', 'imu/data_compensated') if driver
            else (Vector3Stamped, 'tak/counts', 'tak/temp_code', 'tak/imu/data_raw'))
        self.prefix = prefix
        """The namespace's prefix: /diagnostics is not namespaced, so a status is ours when its name starts so."""
        self.counts = self.node.create_publisher(input_type, prefix + input_topic, input_qos)
        self.temperature = self.node.create_publisher(Temperature, prefix + temp_topic, input_qos)
        self.imu: list[Imu] = []
        self.imu_subscription = self.node.create_subscription(Imu, prefix + output_topic,
                                                              self.imu.append, RELIABLE)
        self.temperatures_sent = 0
        self.diagnostics: list[Any] = []
        from diagnostic_msgs.msg import DiagnosticArray
        self.diagnostics_subscription = self.node.create_subscription(
            DiagnosticArray, '/diagnostics', self.diagnostics.append, 10)

    def spin_once(self) -> None:
        """Handle what is ready (waiting at most 10 ms)."""
        self.executor.spin_once(timeout_sec=0.01)

    def wait(self, condition: Callable[[], bool], timeout: float = 20.0, what: str = 'condition') -> None:
        """Spin until ``condition()`` holds."""
        wait_until(condition, timeout, step=self.spin_once, what=what)

    def wait_matched(self, timeout: float = 30.0) -> None:
        """Wait until the node's endpoints are matched with ours."""
        self.wait(lambda: (self.counts.get_subscription_count() >= 1
                           and self.temperature.get_subscription_count() >= 1
                           and self.imu_subscription.get_publisher_count() >= 1
                           and self.diagnostics_subscription.get_publisher_count() >= 1),
                  timeout, 'the compensator node to match the test endpoints')
        # Discovery is not symmetric: the node's Imu writer may match our reader later than our
        # reader matched it. The node reports its matched count in diagnostics.
        self.wait(lambda: self.latest_status() is not None
                  and int(status_values(self.latest_status()).get('imu_subscribers', '0')) >= 1,
                  timeout, 'the compensator Imu publisher to match the test subscription')

    def send_temperature(self, stamp_ns: int, code: float) -> None:
        """Publish one temperature code."""
        message = Temperature()
        header_stamp(message, stamp_ns)
        message.temperature = float(code)
        self.temperature.publish(message)
        self.temperatures_sent += 1

    def send_temperature_and_wait(self, stamp_ns: int, code: float, timeout: float = 10.0) -> None:
        """Publish one temperature code and wait until the node's diagnostics show it taken.

        The code and the next counts message travel on different topics: waiting makes sure the
        node has the code before that counts message arrives.
        """
        self.send_temperature(stamp_ns, code)
        sent = self.temperatures_sent
        self.wait(lambda: self.latest_status() is not None
                  and int(status_values(self.latest_status())['temperature_messages']) >= sent,
                  timeout, 'the node to take the temperature code')

    def send_counts(self, stamp_ns: int, x: float, y: float, z: float, frame_id: str = 'tak_imu') -> None:
        """Publish one counts message."""
        message = Vector3Stamped()
        header_stamp(message, stamp_ns)
        message.header.frame_id = frame_id
        message.vector.x, message.vector.y, message.vector.z = float(x), float(y), float(z)
        self.counts.publish(message)

    def send_imu(self, stamp_ns: int, values: Sequence[float], *, frame_id: str = 'imu_link',
                 orientation: Sequence[float] = (0.0, 0.0, 0.0, 1.0),
                 orientation_covariance: Sequence[float] = (-1.0, 0, 0, 0, 0, 0, 0, 0, 0),
                 linear_acceleration_covariance: Sequence[float] = (7.0,) * 9,
                 angular_velocity_covariance: Sequence[float] = (7.0,) * 9) -> None:
        """Publish one driver Imu: accelerometer x y z, gyroscope x y z, orientation (x y z w).

        The sensors' covariances default to 7 (the node replaces them with the fit's); a
        covariance[0] of -1 marks that sensor absent (the message carries the other only).
        """
        message = Imu()
        header_stamp(message, stamp_ns)
        message.header.frame_id = frame_id
        a, w, q = message.linear_acceleration, message.angular_velocity, message.orientation
        a.x, a.y, a.z, w.x, w.y, w.z = (float(v) for v in values)
        q.x, q.y, q.z, q.w = (float(v) for v in orientation)
        message.orientation_covariance = [float(v) for v in orientation_covariance]
        message.angular_velocity_covariance = [float(v) for v in angular_velocity_covariance]
        message.linear_acceleration_covariance = [float(v) for v in linear_acceleration_covariance]
        self.counts.publish(message)

    def set_parameters(self, values: dict[str, Any], *, atomically: bool = False,
                       node_name: str = '/compensator') -> list[Any]:
        """Call the node's SetParameters (or SetParametersAtomically) service; the results."""
        from rcl_interfaces.srv import SetParameters, SetParametersAtomically
        from rclpy.parameter import Parameter
        kind, service = ((SetParametersAtomically, 'set_parameters_atomically') if atomically
                         else (SetParameters, 'set_parameters'))
        client = self.node.create_client(kind, f'{node_name}/{service}')
        try:
            self.wait(client.service_is_ready, 20.0, f'service {node_name}/{service}')
            request = kind.Request(parameters=[Parameter(name, value=value).to_parameter_msg()
                                               for name, value in values.items()])
            future = client.call_async(request)
            self.wait(future.done, 20.0, f'the answer of {node_name}/{service}')
        finally:
            self.node.destroy_client(client)
        response = future.result()
        return [response.result] if atomically else list(response.results)

    def latest_status(self, name: str = 'temperature compensation') -> Any | None:
        """The last diagnostics status of our compensator received whose name holds ``name``, or ``None``.

        Ours: its name starts with our namespace (two nodes in two namespaces share /diagnostics; one's
        ``imu_subscribers`` taken for the other's let the test play before the node's Imu writer matched
        our reader, and the first outputs were lost to it).
        """
        for array_message in reversed(self.diagnostics):
            for status in array_message.status:
                if name in status.name and status.name.startswith(self.prefix):
                    return status
        return None

    def close(self) -> None:
        """Tear the test node and context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> Harness:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def play_driver(ros: Harness, driver: Any) -> None:
    """Publish a driver run in stamp order (temperature before Imu at equal stamps), losing nothing."""
    sent = 0
    for stamp, stream, row in play_order(driver.temp_stamp_ns, driver.stamp_ns):
        if stream == 0:
            ros.wait(lambda: len(ros.imu) >= sent, 20.0, f'the node to catch up ({len(ros.imu)} of {sent})')
            ros.send_temperature(stamp, driver.temperature[row])
        else:
            ros.wait(lambda: len(ros.imu) >= sent - 50, 20.0, f'the node to catch up ({len(ros.imu)} of {sent})')
            ros.send_imu(stamp, (*driver.accel[row], *driver.gyro[row]), frame_id=driver.frame_id,
                         orientation=driver.orientation[row], orientation_covariance=driver.orientation_covariance[row])
            sent += 1
    ros.wait(lambda: len(ros.imu) >= sent, 20.0, 'the last Imu')


def status_values(status: Any) -> dict[str, str]:
    """A diagnostics status's key/value pairs as a dict."""
    return {pair.key: pair.value for pair in status.values}


PACKAGE_SOURCES = ('setup.py', 'setup.cfg', 'package.xml', 'resource', 'tak_thermo_ros', 'config', 'launch')
"""What a colcon workspace's ``src/tak_thermo_ros`` holds (the package as a user clones it)."""


def copy_package(workspace: Path) -> Path:
    """Copy the package's sources into ``workspace/src/tak_thermo_ros``; that folder."""
    import shutil
    repo = Path(__file__).resolve().parent.parent
    source = workspace / 'src' / 'tak_thermo_ros'
    source.mkdir(parents=True)
    for name in PACKAGE_SOURCES:
        if (repo / name).is_dir():
            shutil.copytree(repo / name, source / name, ignore=shutil.ignore_patterns('__pycache__', '*.pyc'))
        else:
            shutil.copy2(repo / name, source / name)
    return source


def fitted_driver_params(directory: Path, name: str) -> Path:
    """The params file ``directory/name`` that ``tak_calib fit`` wrote from a short simulated driver bag."""
    from tak_thermo_ros import cli
    from tak_thermo_ros.formats.bag import write_driver_record
    from tak_thermo_ros.core.simulation.imu import simulate
    from tak_thermo_ros.core.simulation.scenario import Scenario
    run = simulate(Scenario(output='imu', sample_rate_hz=10.0, plateaus_celsius=(10.0, 30.0), plateau_hours=0.005,
                            ramp_celsius_per_minute=10.0, board_lag_s=5.0, dwell_s=1.0))
    write_driver_record(directory / 'driver.mcap', run.driver)
    params = directory / name
    assert cli.main(['fit', str(directory / 'driver.mcap'), '-o', str(params), '--no-progress']) == 0
    return params
